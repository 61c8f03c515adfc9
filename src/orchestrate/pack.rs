//! `causalcity pack`: a folder dataset's scenarios packed into tar files
//! in a new folder, byte for byte what `gen --format tar` writes for its
//! spec. The dataset itself is only read.

use super::run::{keep_networks, sweep_partials, GenError};
use crate::dataset::Dataset;
use crate::output::claim::{claim, resolve, Writer};
use crate::output::manifest::{Manifest, ManifestRecord, Packing};
use crate::output::packs::{verify, PackWriter, Packs};
use crate::output::{scenario_dir, verify_scenario, write_atomically};
use crate::progress::{Progress, ProgressMode};
use rayon::prelude::*;
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

/// Packs the finished folder dataset `dataset` into `out`, `per_tar`
/// scenarios per tar, on `threads` threads (all cores when `None`).
/// Resumes: packs already in `out` and whole are kept. Returns what it did,
/// in words.
pub fn pack_dataset(
    dataset: &Path,
    out: &Path,
    per_tar: u32,
    threads: Option<usize>,
    progress: ProgressMode,
) -> Result<String, GenError> {
    let start = Instant::now();
    let opened = Dataset::open_complete(dataset).map_err(GenError::Input)?;
    if let Packing::Tar { per_tar } = opened.record.packing() {
        return Err(GenError::Input(format!(
            "{} is packed already ({per_tar} scenarios per tar): pack reads a dataset of scenario folders",
            dataset.display()
        )));
    }
    if resolve(out) == resolve(dataset) {
        return Err(GenError::Input(format!(
            "--out {} is the dataset itself: pack writes a new dataset and leaves its input as it is; nothing was written",
            out.display()
        )));
    }
    let _claim = claim(out, Writer::Pack, &format!("pack {}", dataset.display())).map_err(GenError::Claim)?;
    let spec = opened.spec();
    let (products, packing) = (opened.record.products(), Packing::Tar { per_tar: per_tar.max(1) });
    let manifest_path = out.join("manifest.json");
    if let Some(existing) = ManifestRecord::read(&manifest_path).map_err(GenError::Manifest)? {
        let differences = existing.differences(spec, products, packing);
        if !differences.is_empty() || existing.limit != opened.record.limit {
            return Err(GenError::Input(format!(
                "{} already holds another dataset ({}): pack into an empty folder; nothing was written",
                out.display(),
                if differences.is_empty() { "limit differs".to_string() } else { differences.join("; ") }
            )));
        }
    }
    let manifest = |complete| {
        Manifest::new(spec, &opened.expansion.camera, opened.record.limit, products, packing, complete, None).to_json()
    };
    write_atomically(&manifest_path, &manifest(false))?;
    sweep_partials(out, spec)?;
    keep_networks(spec, out)?;

    let packs = Packs::new(opened.key_sequence(), per_tar);
    let threads =
        threads.filter(|&t| t > 0).unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| GenError::Threads { threads, reason: e.to_string() })?;
    let bar = Progress::new(packs.len() as u64, progress);
    let (kept, bytes) = (AtomicU64::new(0), AtomicU64::new(0));
    pool.install(|| {
        (0..packs.len()).into_par_iter().try_for_each(|number| {
            let pack = packs.pack(number);
            let keys = packs.keys(&pack);
            let target = packs.path(out, &pack);
            if target.is_file() && verify(&target, &keys).is_ok() {
                kept.fetch_add(1, Ordering::Relaxed);
                bar.inc();
                return Ok(());
            }
            for key in &keys {
                let dir = scenario_dir(&opened.dir, &key.group, key.split.name(), &key.folder_name());
                verify_scenario(&dir).map_err(|why| {
                    GenError::Input(format!(
                        "{why}: {} is damaged or unfinished (validate says what else is); rerun its gen command, \
                         which rewrites damaged scenarios, then pack again",
                        dataset.display()
                    ))
                })?;
            }
            let writer = PackWriter::begin(&opened.dir, keys, &target)?;
            bytes.fetch_add(writer.commit(false)?, Ordering::Relaxed);
            bar.inc();
            Ok::<(), GenError>(())
        })
    })?;
    bar.finish();
    write_atomically(&manifest_path, &manifest(true))?;
    let kept = kept.load(Ordering::Relaxed);
    Ok(format!(
        "packed {} scenarios of {} into {} tar files in {} ({:.1} MB written, {kept} packs already there kept) in {:.1} s",
        opened.key_sequence().len(),
        dataset.display(),
        packs.len(),
        out.display(),
        bytes.load(Ordering::Relaxed) as f64 / 1e6,
        start.elapsed().as_secs_f64()
    ))
}
