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
use crate::output::{scenario_dir, verify_scenario_of, write_atomically};
use crate::plan::ScenarioKey;
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
    // Packed already: said before opening it, which makes a folder to
    // unpack into (a TMPDIR that could hold none was named instead).
    let what = ("dataset", "scenarios", "scenario");
    if let Ok(Some(record)) = ManifestRecord::read(&dataset.join("manifest.json")) {
        refuse_packed(dataset, record.packing(), what)?;
    }
    let opened = Dataset::open_complete(dataset).map_err(GenError::Input)?;
    let _claim = claim_out(dataset, opened.record.packing(), out, Writer::Pack, what)?;
    let spec = opened.spec();
    super::run::refuse_linked_splits(out, spec)?;
    let (products, packing) = (opened.record.products(), Packing::Tar { per_tar: per_tar.max(1) });
    let manifest_path = out.join("manifest.json");
    if let Some(existing) = ManifestRecord::read(&manifest_path).map_err(GenError::Manifest)? {
        let differences = existing.differences(spec, products, packing);
        // (Limits that leave the same scenarios are one: 12 and none over splits of at most 4.)
        if !differences.is_empty() || existing.effective_limit() != opened.record.effective_limit() {
            return Err(GenError::Input(format!(
                "{} already holds another dataset ({}): pack into an empty folder; nothing was written",
                out.display(),
                if differences.is_empty() { "limit differs".to_string() } else { differences.join("; ") }
            )));
        }
    }
    let manifest = |complete| {
        let limit = opened.record.effective_limit();
        Manifest::new(spec, &opened.expansion.camera, limit, products, packing, complete, None).to_json()
    };
    write_atomically(&manifest_path, &manifest(false))?;
    sweep_partials(out, spec)?;
    keep_networks(spec, out)?;

    let packs = Packs::new(opened.key_sequence(), per_tar);
    let seed = spec.seed;
    let whole = |dir: &Path, key: &ScenarioKey| {
        verify_scenario_of(dir, key, seed).map_err(|why| {
            format!(
                "{why}: {} is damaged or unfinished (validate says what else is); rerun its gen command, \
                 which rewrites damaged scenarios, then pack again",
                dataset.display()
            )
        })
    };
    let packed = pack_all(&opened.dir, out, &packs, PackUnit::Scenario, &whole, threads, progress)?;
    write_atomically(&manifest_path, &manifest(true))?;
    Ok(packed.describe(opened.key_sequence().len(), "scenarios", dataset, out, start))
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
    let _claim = claim_out(input, sweep.packing, out, Writer::Sweep, ("sweep", "pairs", "pair"))?;
    super::run::refuse_linked_splits(out, &sweep.expansion.spec)?;
    // The input's record, as the packed sweep's: the same fields, and how
    // it is packed. (Only a finished sweep opens.)
    let path = input.join(SWEEP_RECORD);
    let read = |path: &Path| -> Result<serde_json::Value, GenError> {
        let bytes = crate::input::read_record(path)
            .map_err(|e| GenError::Input(format!("cannot read {}: {e}", path.display())))?;
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
    let whole = |dir: &Path, _: &ScenarioKey| match complete_pair(dir) {
        Some(_) => Ok(()),
        None => Err(format!(
            "{}: the pair is missing, damaged or unfinished (validate says what else is); rerun its counterfactual \
             --sweep command, which rewrites it, then pack again",
            dir.display()
        )),
    };
    let packed = pack_all(input, out, &packs, PackUnit::Pair, &whole, threads, progress)?;
    write_atomically(&record_path, &json(true))?;
    Ok(packed.describe(sweep.key_sequence().len(), "counterfactual pairs", input, out, start))
}

/// A failure of writing the pack at `target`: one about a file beside it
/// (the pack, its `.partial`) or a folder above it is writing (exit 1);
/// any other is reading a scenario of the input (checked whole a moment
/// before), the input changing under pack, the user's to resolve (exit 2,
/// "cannot read"). It said "cannot write" of a file of the input that a
/// `gen --force` had removed, with advice to free space.
fn read_or_write(error: crate::output::WriteError, target: &Path) -> GenError {
    let writing = error.path.parent() == target.parent() || target.starts_with(&error.path);
    if !writing {
        GenError::Input(format!(
            "cannot read {}: {}: the dataset changed while pack read it (another run writing or removing it?); \
             rerun pack once nothing else uses it (the packs written so far are kept)",
            error.path.display(),
            error.source
        ))
    } else {
        GenError::Write { error, done: 0 }
    }
}

/// What [`pack_all`] did.
struct Packed {
    packs: usize,
    kept: u64,
    bytes: u64,
}

impl Packed {
    /// In words, for `count` `what` ("scenarios") of `input` packed into
    /// `out` since `start`.
    fn describe(&self, count: usize, what: &str, input: &Path, out: &Path, start: Instant) -> String {
        format!(
            "packed {count} {what} of {} into {} tar files in {} ({:.1} MB written, {} packs already there kept) in \
             {:.1} s",
            input.display(),
            self.packs,
            out.display(),
            self.bytes as f64 / 1e6,
            self.kept,
            start.elapsed().as_secs_f64()
        )
    }
}

/// Refuses an `input` (a `what`: "dataset" or "sweep", of `units` in
/// `unit` folders) that is packed already, or `out` that is `input`; then
/// claims `out` for `writer`.
fn claim_out(
    input: &Path,
    packing: Packing,
    out: &Path,
    writer: Writer,
    (what, units, unit): (&str, &str, &str),
) -> Result<crate::output::claim::Claim, GenError> {
    refuse_packed(input, packing, (what, units, unit))?;
    if resolve(out) == resolve(input) {
        return Err(GenError::Input(format!(
            "--out {} is the {what} itself: pack writes a new {what} and leaves its input as it is; nothing was written",
            out.display()
        )));
    }
    claim(out, writer, &format!("pack {}", input.display())).map_err(GenError::Claim)
}

/// Refuses an `input` (a `what` of `unit` folders) that is packed already.
fn refuse_packed(input: &Path, packing: Packing, (what, units, unit): (&str, &str, &str)) -> Result<(), GenError> {
    match packing {
        Packing::Tar { per_tar } => Err(GenError::Input(format!(
            "{} is packed already ({per_tar} {units} per tar): pack reads a {what} of {unit} folders",
            input.display()
        ))),
        Packing::Folders => Ok(()),
    }
}

/// Writes every pack of `packs` from the folders under `input` into `out`,
/// on `threads` threads, after checking each folder with `whole`; keeps
/// the packs already there and whole.
fn pack_all(
    input: &Path,
    out: &Path,
    packs: &Packs<'_>,
    unit: PackUnit,
    whole: &(dyn Fn(&Path, &ScenarioKey) -> Result<(), String> + Sync),
    threads: Option<usize>,
    progress: ProgressMode,
) -> Result<Packed, GenError> {
    let threads =
        threads.filter(|&t| t > 0).unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| GenError::Threads { threads, reason: e.to_string() })?;
    // Counted in tar files: "6/6 scenarios" was shown for 14 scenarios.
    let bar = Progress::counting(packs.len() as u64, progress, "tar files");
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
                whole(&scenario_dir(input, &key.group, key.split.name(), &key.folder_name()), key)
                    .map_err(GenError::Input)?;
            }
            let writer = PackWriter::begin_of(unit, input, keys, &target).map_err(|e| read_or_write(e, &target))?;
            bytes.fetch_add(writer.commit(false).map_err(|e| read_or_write(e, &target))?, Ordering::Relaxed);
            bar.inc();
            Ok::<(), GenError>(())
        })
    })?;
    bar.finish();
    Ok(Packed { packs: packs.len(), kept: kept.load(Ordering::Relaxed), bytes: bytes.load(Ordering::Relaxed) })
}
