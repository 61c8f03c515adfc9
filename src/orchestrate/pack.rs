//! `causalcity pack`: a folder dataset's scenarios packed into tar files
//! in a new folder, byte for byte what `gen --format tar` writes for its
//! spec; or a counterfactual sweep's pairs, byte for byte what
//! `counterfactual --sweep --format tar` writes. The input is only read.

use super::handwritten::complete_pair;
use super::run::{keep_networks, sweep_partials, GenError};
use crate::dataset::{Dataset, Sweep, SWEEP_RECORD};
use crate::output::claim::{claim, resolve, Writer};
use crate::output::manifest::{Manifest, ManifestRecord, Packing};
use crate::output::packs::{verify_of, PackUnit, PackWriter, Packs};
use crate::output::{scenario_dir, verify_scenario, write_atomically};
use crate::progress::{Progress, ProgressMode};
use rayon::prelude::*;
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

/// Packs the finished folder dataset (or counterfactual sweep) `dataset`
/// into `out`, `per_tar` scenarios (pairs) per tar, on `threads` threads
/// (all cores when `None`). Resumes: packs already in `out` and whole are
/// kept. Returns what it did, in words.
pub fn pack_dataset(
    dataset: &Path,
    out: &Path,
    per_tar: u32,
    threads: Option<usize>,
    progress: ProgressMode,
) -> Result<String, GenError> {
    let start = Instant::now();
    if !dataset.join("manifest.json").exists() {
        if let Some(sweep) = Sweep::open(dataset).map_err(GenError::Input)? {
            return pack_sweep(&sweep, out, per_tar, threads, progress);
        }
    }
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
    let whole = |dir: &Path| {
        verify_scenario(dir).map_err(|why| {
            format!(
                "{why}: {} is damaged or unfinished (validate says what else is); rerun its gen command, \
                 which rewrites damaged scenarios, then pack again",
                dataset.display()
            )
        })
    };
    let (kept, bytes) = pack_all(&opened.dir, out, &packs, PackUnit::Scenario, &whole, threads, progress)?;
    write_atomically(&manifest_path, &manifest(true))?;
    Ok(format!(
        "packed {} scenarios of {} into {} tar files in {} ({:.1} MB written, {kept} packs already there kept) in {:.1} s",
        opened.key_sequence().len(),
        dataset.display(),
        packs.len(),
        out.display(),
        bytes as f64 / 1e6,
        start.elapsed().as_secs_f64()
    ))
}

/// Packs the finished sweep `sweep` into `out` as `counterfactual --sweep
/// --format tar` would have written it: its sweep.json with
/// `scenarios_per_tar`, and its pairs in packs.
fn pack_sweep(
    sweep: &Sweep,
    out: &Path,
    per_tar: u32,
    threads: Option<usize>,
    progress: ProgressMode,
) -> Result<String, GenError> {
    let start = Instant::now();
    let input = &sweep.dir;
    if let Packing::Tar { per_tar } = sweep.packing {
        return Err(GenError::Input(format!(
            "{} is packed already ({per_tar} pairs per tar): pack reads a sweep of pair folders",
            input.display()
        )));
    }
    if resolve(out) == resolve(input) {
        return Err(GenError::Input(format!(
            "--out {} is the sweep itself: pack writes a new sweep and leaves its input as it is; nothing was written",
            out.display()
        )));
    }
    let _claim = claim(out, Writer::Sweep, &format!("pack {}", input.display())).map_err(GenError::Claim)?;
    // The input's record, as the packed sweep's: the same fields, and how
    // it is packed. (Only a finished sweep opens.)
    let path = input.join(SWEEP_RECORD);
    let read = |path: &Path| -> Result<serde_json::Value, GenError> {
        let bytes = std::fs::read(path).map_err(|e| GenError::Input(format!("cannot read {}: {e}", path.display())))?;
        serde_json::from_slice(&bytes).map_err(|e| GenError::Input(format!("{}: not JSON: {e}", path.display())))
    };
    let mut record = read(&path)?;
    record["scenarios_per_tar"] = per_tar.max(1).into();
    let record_path = out.join(SWEEP_RECORD);
    if record_path.exists() {
        let old = read(&record_path)?;
        let same = |field: &str| old[field] == record[field];
        let differs: Vec<&str> =
            ["format", "version", "spec", "limit", "kinds", "images", "lights", "scenarios_per_tar"]
                .into_iter()
                .filter(|field| !same(field))
                .collect();
        if !differs.is_empty() {
            return Err(GenError::Input(format!(
                "{} already holds another sweep (differs: {}): pack into an empty folder; nothing was written",
                out.display(),
                differs.join(", ")
            )));
        }
    }
    let json = |complete: bool| {
        let mut record = record.clone();
        record["complete"] = complete.into();
        let mut json = serde_json::to_vec_pretty(&record).expect("a record read from JSON serialises");
        json.push(b'\n');
        json
    };
    write_atomically(&record_path, &json(false))?;
    keep_networks(&sweep.expansion.spec, out)?;
    let packs = Packs::new(sweep.key_sequence(), per_tar);
    let whole = |dir: &Path| match complete_pair(dir) {
        Some(_) => Ok(()),
        None => Err(format!(
            "{}: the pair is missing, damaged or unfinished (validate says what else is); rerun its counterfactual \
             --sweep command, which rewrites it, then pack again",
            dir.display()
        )),
    };
    let (kept, bytes) = pack_all(input, out, &packs, PackUnit::Pair, &whole, threads, progress)?;
    write_atomically(&record_path, &json(true))?;
    Ok(format!(
        "packed {} counterfactual pairs of {} into {} tar files in {} ({:.1} MB written, {kept} packs already there \
         kept) in {:.1} s",
        sweep.key_sequence().len(),
        input.display(),
        packs.len(),
        out.display(),
        bytes as f64 / 1e6,
        start.elapsed().as_secs_f64()
    ))
}

/// Writes every pack of `packs` from the folders under `input` into `out`,
/// on `threads` threads, after checking each folder with `whole`; keeps
/// the packs already there and whole. Returns the packs kept and the bytes
/// written.
fn pack_all(
    input: &Path,
    out: &Path,
    packs: &Packs<'_>,
    unit: PackUnit,
    whole: &(dyn Fn(&Path) -> Result<(), String> + Sync),
    threads: Option<usize>,
    progress: ProgressMode,
) -> Result<(u64, u64), GenError> {
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
            if target.is_file() && verify_of(unit, &target, &keys).is_ok() {
                kept.fetch_add(1, Ordering::Relaxed);
                bar.inc();
                return Ok(());
            }
            for key in &keys {
                whole(&scenario_dir(input, &key.group, key.split.name(), &key.folder_name()))
                    .map_err(GenError::Input)?;
            }
            let writer = PackWriter::begin_of(unit, input, keys, &target)?;
            bytes.fetch_add(writer.commit(false)?, Ordering::Relaxed);
            bar.inc();
            Ok::<(), GenError>(())
        })
    })?;
    bar.finish();
    Ok((kept.load(Ordering::Relaxed), bytes.load(Ordering::Relaxed)))
}
