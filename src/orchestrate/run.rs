//! The `gen` job: read and check the spec, plan every scenario, simulate,
//! render and write them in parallel, then write the manifest.

use crate::output::claim::{claim, ClaimError, Writer};
use crate::output::manifest::{Manifest, ManifestRecord, Packing, Products, ShardEntry};
use crate::output::packs::Packs;
use crate::output::writer::{ScenarioWriteError, ScenarioWriter, WriterBuffers};
use crate::output::{io_err, scenario_dir, verify_scenario_of, write_atomically, WriteError, PARTIAL_PREFIX};
use crate::plan::{Expansion, ScenarioKey, ScenarioPlan};
use crate::progress::{Progress, ProgressMode};
use crate::spec::{DatasetSpec, SpecError};
use crate::timing::{Stage, StageSeconds, StageTimes};
use crate::world::effects::EffectReport;
use crate::world::Trajectories;
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// What `causalcity gen` was asked to do.
#[derive(Debug, Clone)]
pub struct GenOptions {
    pub spec_path: PathBuf,
    /// Output folder; `data/<spec name>` when absent.
    pub out: Option<PathBuf>,
    /// At most this many scenarios per split and group.
    pub limit: Option<u32>,
    /// Worker threads; all cores when absent.
    pub threads: Option<usize>,
    pub images: bool,
    /// Also write NS-DR annotations.json per scenario (needs images).
    pub annotations: bool,
    /// Measure and write every scenario's interventional effects
    /// (effects.csv, causal graphs in scenario.json).
    pub effects: bool,
    /// City world: how the lights' colours are logged.
    pub lights: crate::output::manifest::LightsLog,
    /// A folder per scenario, or tar packs of whole scenarios.
    pub packing: Packing,
    pub progress: ProgressMode,
    /// Generate only this part of the dataset.
    pub shard: Option<Shard>,
    /// Replace a dataset made from another spec (removes only what causalcity wrote).
    pub force: bool,
    /// Write even when the disk looks too small for the whole run.
    pub force_space: bool,
    /// fsync every file and folder before a scenario is renamed into place.
    pub fsync: bool,
    /// Stop cleanly on SIGINT / SIGTERM (the binary sets this).
    pub handle_signals: bool,
}

/// The most worker threads a run takes (`-j`): more than any machine's
/// cores, so a typo (`-j 100000`) is refused instead of starting a hundred
/// thousand threads.
pub const MAX_THREADS: usize = 1024;

/// Shard `index` of `count` (0-based): scenario i of the dataset's fixed order
/// belongs to shard i mod count, so every shard gets its share of every group
/// and split.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    pub index: u32,
    pub count: u32,
}

impl std::str::FromStr for Shard {
    type Err = String;

    fn from_str(text: &str) -> Result<Shard, String> {
        let usage = || format!("{text:?} is not a shard: use K/N with 0 <= K < N, e.g. 0/10");
        let (k, n) = text.split_once('/').ok_or_else(usage)?;
        let (index, count): (u32, u32) =
            (k.trim().parse().map_err(|_| usage())?, n.trim().parse().map_err(|_| usage())?);
        if count == 0 || index >= count {
            return Err(usage());
        }
        Ok(Shard { index, count })
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

/// What a finished run did.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Summary {
    pub out: PathBuf,
    /// Scenarios this run was asked for (its shard's share when sharded).
    pub scenarios: u64,
    pub written: u64,
    /// Already complete from an earlier run (verified against their
    /// checksums).
    pub skipped: u64,
    /// Found damaged (a file missing or changed) and written again.
    pub repaired: u64,
    pub failed: u64,
    pub frame_pairs: u64,
    pub bytes: u64,
    #[serde(serialize_with = "seconds")]
    pub elapsed: Duration,
    pub threads: usize,
    /// Peak resident memory of the process, bytes (Linux only).
    pub peak_memory: Option<u64>,
    pub shard: Option<String>,
    /// Seconds per stage, summed over threads.
    pub stage_seconds: StageSeconds,
}

impl std::fmt::Display for Summary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let secs = self.elapsed.as_secs_f64();
        write!(
            f,
            "wrote {} scenarios ({} frame pairs, {:.1} MB), skipped {} already complete, {}{} failed, to {} in {:.1} s: {:.1} scenarios/s on {} threads",
            self.written,
            self.frame_pairs,
            self.bytes as f64 / 1e6,
            self.skipped,
            if self.repaired > 0 { format!("rewrote {} damaged, ", self.repaired) } else { String::new() },
            self.failed,
            self.out.display(),
            secs,
            self.written as f64 / secs.max(1e-9),
            self.threads
        )?;
        if let Some(shard) = &self.shard {
            write!(f, ", shard {shard}")?;
        }
        if let Some(peak) = self.peak_memory {
            write!(f, ", peak memory {:.0} MB", peak as f64 / 1e6)?;
        }
        Ok(())
    }
}

fn seconds<S: serde::Serializer>(d: &Duration, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_f64(d.as_secs_f64())
}

/// Why a run failed; [`GenError::exit_code`] maps it to the process status.
#[derive(Debug, thiserror::Error)]
pub enum GenError {
    #[error("invalid spec {path}: {error}")]
    Spec { path: PathBuf, error: SpecError },
    #[error("{error}\n{done} finished scenarios are kept. Free some space or fix the folder's permissions (or choose another --out), then rerun the same command to resume.")]
    Write { error: WriteError, done: u64 },
    #[error("cannot plan scenario {scenario}: {reason}")]
    Plan { scenario: String, reason: String },
    #[error("cannot start {threads} worker threads: {reason}")]
    Threads { threads: usize, reason: String },
    #[error("{out} holds a dataset made differently:\n  {}\nUse another --out, or --force to replace it (removes only what causalcity wrote there).", differences.join("\n  "))]
    Mixed { out: PathBuf, differences: Vec<String> },
    #[error(
        "{out} is on a disk with {} free, but this run would write about {} more: {pending} scenarios \
         of about {} each (measured on one of the most cars, which was removed again), and it keeps {} free \
         besides for manifests and the file system's own bookkeeping.\n\
         Free some space, write fewer scenarios (--limit N, --no-images), or pass --force-space to write \
         anyway (the run then stops when the disk is full; rerun to resume).",
        crate::output::arrays::gigabytes(*available),
        crate::output::arrays::gigabytes(*needed),
        size_in_words(*per_scenario),
        size_in_words(SPACE_MARGIN_BYTES)
    )]
    Space { out: PathBuf, needed: u64, available: u64, per_scenario: u64, pending: u64 },
    /// A manifest in the output that is unreadable or not causalcity's:
    /// the folder given is the problem (exit 2).
    #[error("{0}")]
    Manifest(String),
    #[error("interrupted: {done} of {total} scenarios are complete in {out}. Rerun the same command to resume.")]
    Interrupted { done: u64, total: u64, out: PathBuf },
    #[error(transparent)]
    Claim(ClaimError),
    /// Arrays held in memory (Python) do not fit.
    #[error(transparent)]
    Memory(crate::output::arrays::OutOfMemory),
    /// Input that cannot be used (a folder that is no shard, a missing shard).
    #[error("{0}")]
    Input(String),
}

impl From<WriteError> for GenError {
    fn from(error: WriteError) -> GenError {
        GenError::Write { error, done: 0 }
    }
}

impl From<GenError> for crate::error::Error {
    fn from(e: GenError) -> Self {
        use crate::error::Error;
        if let GenError::Memory(_) = e {
            return Error::Memory(e.to_string());
        }
        match e.exit_code() {
            2 => Error::Input(e.to_string()),
            130 => Error::Interrupted(e.to_string()),
            _ => Error::Failure(e.to_string()),
        }
    }
}

impl GenError {
    /// 2 for bad input, 130 when interrupted, 1 for failures while running.
    pub fn exit_code(&self) -> i32 {
        match self {
            GenError::Spec { .. }
            | GenError::Mixed { .. }
            | GenError::Input(_)
            | GenError::Space { .. }
            | GenError::Manifest(_) => 2,
            GenError::Claim(e) => e.exit_code(),
            GenError::Interrupted { .. } => 130,
            _ => 1,
        }
    }
}

/// Set by SIGINT / SIGTERM; workers stop at the next frame.
static STOP: AtomicBool = AtomicBool::new(false);
static HANDLER: std::sync::Once = std::sync::Once::new();

/// The process's stop request (SIGINT / SIGTERM where a command handles
/// them), for the other commands' loops to check.
pub(crate) fn stop_flag() -> &'static AtomicBool {
    &STOP
}

/// Asks a running `gen` to stop as SIGINT does: every worker gives up at
/// its next frame and what is complete is kept. For callers that catch the
/// interrupt themselves (Python's KeyboardInterrupt).
pub fn request_stop() {
    STOP.store(true, Ordering::SeqCst);
}

/// Forgets a stop request once the run it was meant for has ended.
pub fn clear_stop() {
    STOP.store(false, Ordering::SeqCst);
}

/// Ctrl-C (SIGINT) and SIGTERM ask the running command to stop at its next
/// frame (a second Ctrl-C quits at once); for the command line only.
pub fn install_signal_handler() {
    HANDLER.call_once(|| {
        let _ = ctrlc::set_handler(|| {
            if STOP.swap(true, Ordering::SeqCst) {
                // A second Ctrl-C: leave at once (partial folders are hidden and discarded on rerun).
                std::process::exit(130);
            }
            crate::progress::note("\nstopping: finishing no more scenarios (press Ctrl-C again to quit at once)");
        });
    });
}

/// Ctrl-C (SIGINT) and SIGTERM end `command` (one that works through no
/// frames: merge, pack, export) at once with exit 130 and a word on how to
/// finish: what it wrote lies in partial files and folders that running it
/// again discards or finishes. (It died of the signal, exit 143 for
/// SIGTERM, saying nothing.) For the command line only.
pub fn install_quit_handler(command: &'static str) {
    HANDLER.call_once(|| {
        let _ = ctrlc::set_handler(move || {
            crate::progress::note(format_args!(
                "\ninterrupted: {command} stopped; run the same command again to finish it"
            ));
            std::process::exit(130);
        });
    });
}

/// The writer of a run over `expansion`'s (first) town, camera and spec.
pub(crate) fn scenario_writer(expansion: &Expansion, products: Products, fsync: bool) -> ScenarioWriter {
    ScenarioWriter::new(expansion.map.clone(), expansion.camera, expansion.spec.leader_gap_px(), products, fsync)
}

/// One writer per town of `expansion` (a town's map and camera), in
/// [`Expansion::towns`] order; buffers of one serve them all (every town's
/// frames have the spec's image size).
pub(crate) struct TownWriters(Vec<ScenarioWriter>);

impl TownWriters {
    pub(crate) fn new(expansion: &Expansion, products: Products, fsync: bool) -> TownWriters {
        let gap = expansion.spec.leader_gap_px();
        TownWriters(
            expansion
                .towns()
                .iter()
                .map(|town| ScenarioWriter::new(town.map.clone(), town.camera, gap, products, fsync))
                .collect(),
        )
    }

    /// The writer of the town `plan` happens on.
    pub(crate) fn of(&self, plan: &ScenarioPlan) -> &ScenarioWriter {
        &self.0[plan.town_index()]
    }

    pub(crate) fn buffers(&self) -> WriterBuffers {
        self.0[0].buffers()
    }
}

/// Removes the folder `dir` (in `out`) whose scenario or pair is now in its
/// pack, if it is there: never through a link, and never when it holds
/// anything but `own`.
pub(crate) fn remove_packed(out: &Path, dir: &Path, own: &crate::output::OwnFiles) -> Result<(), GenError> {
    let refused = |why: crate::output::Refused| GenError::Input(why.to_string());
    crate::output::refuse_links_below(out, dir).map_err(refused)?;
    if std::fs::symlink_metadata(dir).is_ok_and(|m| m.is_dir()) {
        crate::output::refuse_foreign(dir, own, "its tar pack").map_err(refused)?;
        std::fs::remove_dir_all(dir).map_err(io_err(dir))?;
    }
    Ok(())
}

/// Refuses a link at any group or split folder of `spec`'s in `out`
/// (checked before anything is written or moved): scenarios, pairs and
/// packs are written below them, and never through a link. The output
/// folder's top level is its claim's to check.
pub(crate) fn refuse_linked_splits(out: &Path, spec: &DatasetSpec) -> Result<(), GenError> {
    for group in &spec.groups {
        for split in crate::spec::Split::ALL {
            let folder = out.join(group.name()).join(split.name());
            crate::output::refuse_links_below(out, &folder).map_err(|why| GenError::Input(why.to_string()))?;
        }
    }
    Ok(())
}

/// Writes a simulated scenario into `target` through `writer`, stopping
/// when the run is interrupted.
pub(crate) fn write_simulated(
    writer: &ScenarioWriter,
    plan: &ScenarioPlan,
    trajectories: &Trajectories,
    effects: Option<&EffectReport>,
    target: (&Path, PathBuf),
    buffers: &mut WriterBuffers,
    times: &StageTimes,
) -> Result<u64, GenError> {
    writer.write(plan, trajectories, effects, target, buffers, &STOP, times).map_err(|e| match e {
        ScenarioWriteError::Write(error) => GenError::Write { error, done: 0 },
        ScenarioWriteError::Interrupted => GenError::Interrupted { done: 0, total: 0, out: PathBuf::new() },
        ScenarioWriteError::Refused(why) => GenError::Input(why.to_string()),
    })
}

/// Reads, checks and expands a spec file; nothing is written.
pub fn load_spec(path: &Path) -> Result<Expansion, GenError> {
    let spec_err = |error| GenError::Spec { path: path.to_path_buf(), error };
    let spec = DatasetSpec::from_file(path).map_err(spec_err)?;
    Expansion::from_spec(spec).map_err(spec_err)
}

/// Where a run's manifest lives: `manifest.json`, or `shards/K-of-N.json`.
pub fn manifest_path(out: &Path, shard: Option<Shard>) -> PathBuf {
    match shard {
        None => out.join("manifest.json"),
        Some(s) => out.join("shards").join(format!("{}-of-{}.json", s.index, s.count)),
    }
}

/// Every manifest in `out`: the dataset's and the shards'.
fn existing_manifests(out: &Path) -> Result<Vec<(PathBuf, ManifestRecord)>, GenError> {
    let mut paths = vec![out.join("manifest.json")];
    if let Ok(entries) = std::fs::read_dir(out.join("shards")) {
        let mut shard_paths: Vec<PathBuf> = entries.filter_map(|e| e.ok().map(|e| e.path())).collect();
        shard_paths.sort();
        paths.extend(shard_paths.into_iter().filter(|p| p.extension().is_some_and(|e| e == "json")));
    }
    let mut found = Vec::new();
    for path in paths {
        if let Some(record) = ManifestRecord::read(&path).map_err(GenError::Manifest)? {
            found.push((path, record));
        }
    }
    Ok(found)
}

/// Keeps a copy of every SUMO network `spec` names in `out/networks/`, by
/// file name, so that readers rebuild the same maps from the output alone.
/// Never through a link; a copy with other bytes is replaced (the spec as
/// run pins each network's SHA-256).
pub(crate) fn keep_networks(spec: &DatasetSpec, out: &Path) -> Result<(), GenError> {
    let networks = spec.networks();
    if networks.is_empty() {
        return Ok(());
    }
    let folder = out.join(crate::spec::NETWORKS_FOLDER);
    if std::fs::symlink_metadata(&folder).is_ok_and(|m| !m.is_dir()) {
        return Err(GenError::Input(format!(
            "{}: a link or a file where the output keeps its networks; nothing is written through it. Remove it",
            folder.display()
        )));
    }
    if let Err(e) = std::fs::create_dir(&folder) {
        if e.kind() != std::io::ErrorKind::AlreadyExists {
            return Err(io_err(&folder)(e).into());
        }
    }
    for (name, network) in networks {
        let path = folder.join(&name);
        // A link there is replaced by the file, never read or written through.
        if !crate::output::holds_bytes(&path, &network.bytes) {
            // A temporary name of this process's own: shards started
            // together write the same bytes side by side.
            let temp = folder.join(format!(".{name}.{}.partial", std::process::id()));
            std::fs::write(&temp, &network.bytes).and_then(|()| std::fs::rename(&temp, &path)).map_err(|e| {
                let _ = std::fs::remove_file(&temp);
                GenError::from(io_err(&path)(e))
            })?;
        }
    }
    Ok(())
}

/// Removes what causalcity wrote into `out` according to `record`: the
/// manifests and the group folders it lists, nothing else.
fn remove_dataset(out: &Path, records: &[(PathBuf, ManifestRecord)]) -> Result<(), GenError> {
    let group_name = |n: &str| {
        n.starts_with("cars") && n.contains("_edges") && n.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
    };
    // Never under a reader: a dataset open for reading (a command, or the
    // Python package) makes --force refuse, and none opens it from here
    // until the removal is done.
    let _readers_excluded = crate::output::claim::exclude_readers(out).map_err(GenError::Claim)?;
    // Everything is looked at before anything is removed: a user's file
    // anywhere in the old dataset's folders makes --force refuse, whole.
    let mut foreign = Vec::new();
    for (_, record) in records {
        for g in record.groups.iter().filter(|g| group_name(&g.name)) {
            foreign_in_group(&out.join(&g.name), &mut foreign).map_err(|e| GenError::Write { error: e, done: 0 })?;
        }
    }
    if !foreign.is_empty() {
        foreign.sort();
        let shown: Vec<String> = foreign.iter().take(5).map(|p| format!("  {}", p.display())).collect();
        let more = foreign.len().saturating_sub(shown.len());
        return Err(GenError::Input(format!(
            "--force removes only what causalcity wrote, and {} also holds {} path(s) it did not write:\n{}{}\n\
             Nothing was removed. Move them out of the dataset's folders, then rerun with --force.",
            out.display(),
            foreign.len(),
            shown.join("\n"),
            if more > 0 { format!("\n  ... and {more} more") } else { String::new() }
        )));
    }
    // Each group folder leaves the dataset by one rename, then the
    // manifests go, then the moved folders are deleted: a run killed in
    // between leaves the old manifests (a dataset missing whole groups,
    // which --force removes and a resume rewrites) or none, never a
    // scenario folder with some of its files deleted, which no rerun
    // could tell from a user's.
    finish_removal(out)?;
    let removing = out.join(crate::output::layout::REMOVING_DIR);
    for (_, record) in records {
        for g in record.groups.iter().filter(|g| group_name(&g.name)) {
            let dir = out.join(&g.name);
            if std::fs::symlink_metadata(&dir).is_ok_and(|m| m.is_dir()) {
                move_aside(&removing, &dir, Path::new(&g.name))?;
            }
        }
    }
    // The networks the old specs named, aside too: once the manifests are
    // gone, nothing else would say they were the old dataset's.
    let networks = out.join(crate::spec::NETWORKS_FOLDER);
    // Never through a link: a linked networks/ is left alone.
    let real_folder = std::fs::symlink_metadata(&networks).is_ok_and(|m| m.is_dir());
    for (_, record) in records.iter().filter(|_| real_folder) {
        let sections =
            [&record.spec["map"], &record.spec["held_out"]["val"]["map"], &record.spec["held_out"]["test"]["map"]];
        for sumo in sections.iter().filter_map(|m| m["sumo"].as_str()) {
            let name = crate::spec::network_file_name(sumo);
            let path = networks.join(name);
            if std::fs::symlink_metadata(&path).is_ok_and(|m| !m.is_dir()) {
                move_aside(&removing, &path, &Path::new(crate::spec::NETWORKS_FOLDER).join(name))?;
            }
        }
    }
    for (path, _) in records {
        std::fs::remove_file(path).map_err(io_err(path))?;
    }
    remove_dir_if_empty(&networks)?;
    remove_dir_if_empty(&out.join("shards"))?;
    finish_removal(out)
}

/// Moves `from` by one rename to `removing/name` (the folder made if
/// missing).
fn move_aside(removing: &Path, from: &Path, name: &Path) -> Result<(), GenError> {
    let to = removing.join(name);
    let parent = to.parent().unwrap_or(removing);
    std::fs::create_dir_all(parent).map_err(io_err(parent))?;
    std::fs::rename(from, &to).map_err(io_err(from))?;
    Ok(())
}

/// Deletes what a `gen --force` moved aside to remove
/// ([`crate::output::layout::REMOVING_DIR`]), if anything: group folders
/// and a `networks/` folder of network files, all checked to be
/// causalcity's before they were moved. Anything else there (a link, a
/// file, a folder of another name) is refused, never deleted: it is not
/// what a removal left.
pub(crate) fn finish_removal(out: &Path) -> Result<(), GenError> {
    let removing = out.join(crate::output::layout::REMOVING_DIR);
    let refuse = |what: &Path| {
        GenError::Input(format!(
            "{}: not what an interrupted gen --force leaves in {} (group folders and networks/ only); nothing \
             was deleted. Move it out",
            what.display(),
            removing.display()
        ))
    };
    match std::fs::symlink_metadata(&removing) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(io_err(&removing)(e).into()),
        Ok(m) if !m.is_dir() => return Err(refuse(&removing)),
        Ok(_) => {}
    }
    for entry in std::fs::read_dir(&removing).map_err(io_err(&removing))? {
        let entry = entry.map_err(io_err(&removing))?;
        let (name, path) = (entry.file_name().to_string_lossy().into_owned(), entry.path());
        let is_dir = std::fs::symlink_metadata(&path).is_ok_and(|m| m.is_dir());
        let ours = is_dir
            && (crate::output::claim::is_group_folder(&name)
                || (name == crate::spec::NETWORKS_FOLDER
                    && std::fs::read_dir(&path)
                        .map_err(io_err(&path))?
                        .flatten()
                        .all(|f| f.file_type().is_ok_and(|t| !t.is_dir()))));
        if !ours {
            return Err(refuse(&path));
        }
    }
    Ok(std::fs::remove_dir_all(&removing).map_err(io_err(&removing))?)
}

/// Refuses a `--force` removal of `out` when a SUMO network the new spec
/// reads lies inside it (its `networks/` copy of an earlier run): the
/// removal would delete the run's own input and write it again.
fn refuse_removing_inputs(out: &Path, spec: &DatasetSpec) -> Result<(), GenError> {
    let Ok(out_real) = std::fs::canonicalize(out) else { return Ok(()) };
    for (_, network) in spec.networks() {
        let Ok(path) = std::fs::canonicalize(&network.path) else { continue };
        if path.starts_with(&out_real) {
            return Err(GenError::Input(format!(
                "{}: the spec's map.sumo network lies inside {}, which --force removes: gen would delete its own \
                 input. Nothing was removed. Copy the network out of the dataset and name the copy in the spec",
                network.path.display(),
                out.display()
            )));
        }
    }
    Ok(())
}

/// Removes `dir` if it is a real, empty folder; a link, a file, a folder
/// with anything in it or no folder at all is left as it is.
fn remove_dir_if_empty(dir: &Path) -> Result<(), WriteError> {
    if std::fs::symlink_metadata(dir).is_ok_and(|m| m.is_dir())
        && std::fs::read_dir(dir).is_ok_and(|mut d| d.next().is_none())
    {
        std::fs::remove_dir(dir).map_err(io_err(dir))?;
    }
    Ok(())
}

/// Once a whole (unsharded) run has completed `out`, removes the manifests
/// of `gen --shard` runs of the same dataset found there when it started:
/// their scenarios are now the dataset's, listed by its manifest, as after
/// a merge (left behind, they were offered to `merge` as a job to finish).
/// Shards run under a shared lock, which the whole run's excludes.
fn remove_finished_shards(out: &Path, existing: &[(PathBuf, ManifestRecord)]) -> Result<(), GenError> {
    for (path, _) in existing.iter().filter(|(_, record)| record.shard.is_some()) {
        match std::fs::remove_file(path) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(io_err(path)(e).into()),
            _ => {}
        }
    }
    Ok(remove_dir_if_empty(&out.join("shards"))?)
}

/// Collects into `foreign` every path under a group folder that no run
/// wrote: anything but split folders of scenario folders (each file listed
/// in its checksums, or the listing itself) and hidden leftovers of
/// interrupted scenarios.
fn foreign_in_group(group: &Path, foreign: &mut Vec<PathBuf>) -> Result<(), WriteError> {
    let entries = |dir: &Path| -> Result<Vec<(PathBuf, bool)>, WriteError> {
        let listing = match std::fs::read_dir(dir) {
            Ok(listing) => listing,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
            Err(e) => return Err(io_err(dir)(e)),
        };
        listing
            .map(|e| {
                let e = e.map_err(io_err(dir))?;
                Ok((e.path(), e.file_type().is_ok_and(|t| t.is_dir())))
            })
            .collect()
    };
    for (split_dir, is_dir) in entries(group)? {
        let is_split = crate::spec::Split::ALL.iter().any(|s| split_dir.file_name() == Some(s.name().as_ref()));
        if !(is_dir && is_split) {
            foreign.push(split_dir);
            continue;
        }
        for (scenario, is_dir) in entries(&split_dir)? {
            let name = scenario.file_name().unwrap_or_default().to_string_lossy().into_owned();
            let listing = scenario.join(crate::output::CHECKSUMS);
            if is_dir && name.starts_with(PARTIAL_PREFIX) {
                continue;
            }
            // Packs (`--format tar`), and the leftover of one being written.
            let pack_name = name.strip_suffix(".partial").unwrap_or(&name);
            if !is_dir && crate::output::packs::parse_file_name(pack_name).is_some() {
                continue;
            }
            if !(is_dir && name.chars().all(|c| c.is_ascii_digit()) && listing.is_file()) {
                foreign.push(scenario);
                continue;
            }
            let listed: std::collections::HashSet<PathBuf> = std::fs::read_to_string(&listing)
                .map_err(io_err(&listing))?
                .lines()
                .filter_map(|line| line.split_once("  ").map(|(_, name)| scenario.join(name)))
                .chain([listing.clone()])
                .collect();
            let mut stack = vec![scenario];
            while let Some(dir) = stack.pop() {
                for (path, is_dir) in entries(&dir)? {
                    if is_dir {
                        stack.push(path);
                    } else if !listed.contains(&path) {
                        foreign.push(path);
                    }
                }
            }
        }
    }
    Ok(())
}

/// Finished scenarios of `spec` already in `out` (folders with their
/// checksums, and those packs hold by their names), counted from the
/// folders, not from the keys: what a failed run tells the user it keeps.
fn finished_on_disk(out: &Path, spec: &DatasetSpec) -> u64 {
    let mut finished = 0;
    for g in &spec.groups {
        for split in crate::spec::Split::ALL {
            let Ok(entries) = std::fs::read_dir(out.join(g.name()).join(split.name())) else { continue };
            let entries: Vec<_> =
                entries.flatten().filter(|e| !e.file_name().to_string_lossy().starts_with('.')).collect();
            let packs: Vec<(u32, u32)> = entries
                .iter()
                .filter_map(|e| crate::output::packs::parse_file_name(&e.file_name().to_string_lossy()))
                .collect();
            finished += packs.iter().map(|(first, last)| u64::from(last - first) + 1).sum::<u64>();
            // A finished folder, unless a run killed after packing it left it beside its pack.
            let packed =
                |name: &str| name.parse::<u32>().is_ok_and(|i| packs.iter().any(|(f, l)| (*f..=*l).contains(&i)));
            finished += entries
                .iter()
                .filter(|e| {
                    !packed(&e.file_name().to_string_lossy()) && e.path().join(crate::output::CHECKSUMS).is_file()
                })
                .count() as u64;
        }
    }
    finished
}

/// Removes hidden leftovers of interrupted scenarios (and packs) in the
/// spec's folders.
pub(crate) fn sweep_partials(out: &Path, spec: &DatasetSpec) -> Result<(), GenError> {
    for g in &spec.groups {
        for split in crate::spec::Split::ALL {
            let dir = out.join(g.name()).join(split.name());
            let Ok(entries) = std::fs::read_dir(&dir) else { continue };
            for e in entries.flatten() {
                let name = e.file_name().to_string_lossy().into_owned();
                if name.starts_with(PARTIAL_PREFIX) {
                    std::fs::remove_dir_all(e.path()).map_err(io_err(&e.path()))?;
                } else if name
                    .strip_suffix(".partial")
                    .is_some_and(|pack| crate::output::packs::parse_file_name(pack).is_some())
                {
                    std::fs::remove_file(e.path()).map_err(io_err(&e.path()))?;
                }
            }
        }
    }
    Ok(())
}

/// Positions in the dataset's fixed order of the scenarios of `shard` (all
/// when `None`) among `total`: every `count`-th from `index` on, as
/// numbers, never as a list (memory independent of the split sizes).
#[derive(Debug, Clone, Copy)]
struct ShardPositions {
    first: usize,
    step: usize,
    len: usize,
}

impl ShardPositions {
    fn new(total: usize, shard: Option<Shard>) -> ShardPositions {
        let (first, step) = shard.map_or((0, 1), |s| (s.index as usize, s.count as usize));
        ShardPositions { first, step, len: total.saturating_sub(first).div_ceil(step) }
    }

    /// The dataset position of this shard's `i`-th scenario.
    fn position(&self, i: usize) -> usize {
        self.first + i * self.step
    }

    /// Every position of the shard, in order.
    fn iter(self) -> impl Iterator<Item = usize> {
        (0..self.len).map(move |i| self.position(i))
    }
}

/// Runs `causalcity gen`: resumes an interrupted run of the same spec, refuses
/// to mix specs unless forced.
pub fn generate(options: &GenOptions) -> Result<Summary, GenError> {
    let start = Instant::now();
    let expansion = load_spec(&options.spec_path)?;
    generate_expansion(&expansion, options, start)
}

/// [`generate`] of a spec already read and expanded (`options.spec_path` is
/// not read again); `start` is when the run began, for its summary.
pub fn generate_expansion(expansion: &Expansion, options: &GenOptions, start: Instant) -> Result<Summary, GenError> {
    let kept = || {
        let out = options.out.clone().unwrap_or_else(|| Path::new("data").join(&expansion.spec.name));
        finished_on_disk(&out, &expansion.spec)
    };
    match generate_into(expansion, options, start) {
        // Say what is really kept: every finished scenario in the folder,
        // not only those this run reached (a read-only folder said 0 with 7 there).
        Err(GenError::Write { error, .. }) => Err(GenError::Write { error, done: kept() }),
        Err(GenError::Claim(ClaimError::Io { path, source })) => {
            Err(GenError::Write { error: WriteError { path, source }, done: kept() })
        }
        other => other,
    }
}

/// What sets the dataset `options` would write apart from the `existing`
/// manifests in its folder (theirs and their shards'): one difference per
/// line, none when they are one dataset (the shards of one folder split it
/// the same way).
fn differences_from(
    existing: &[(PathBuf, ManifestRecord)],
    expansion: &Expansion,
    options: &GenOptions,
    products: Products,
) -> Vec<String> {
    let mut differences: Vec<String> = existing
        .iter()
        .flat_map(|(_, record)| record.differences(&expansion.spec, products, options.packing))
        .collect::<std::collections::BTreeSet<_>>()
        .into_iter()
        .collect();
    // A different --limit: a larger one (or none) extends the dataset, whose
    // first scenarios are the same keys; a smaller one would leave scenarios
    // the new manifest does not list, and shards of one job share theirs.
    let shown = |limit: Option<u32>| limit.map_or("no --limit".to_string(), |n| format!("--limit {n}"));
    // What a limit means is the scenarios per split it leaves: a limit at
    // or above every split's size is the same dataset as no limit.
    let per_split = |limit: Option<u32>| {
        crate::spec::Split::ALL.map(|split| {
            let size = expansion.spec.splits.count(split);
            limit.map_or(size, |l| l.min(size))
        })
    };
    for (path, record) in existing {
        let (theirs, ours) = (per_split(record.limit), per_split(options.limit));
        let shrinks = ours.iter().zip(&theirs).any(|(o, t)| o < t);
        // A pack is named by the scenarios it holds, so more of them would
        // make other packs and leave the old ones behind.
        let packed = options.packing != Packing::Folders || record.packing() != Packing::Folders;
        if theirs != ours && (shrinks || packed || options.shard.is_some() || record.shard.is_some()) {
            differences.push(format!(
                "limit: {} was written with {}, this run asks for {}{}",
                path.display(),
                shown(record.limit),
                shown(options.limit),
                if shrinks {
                    " (fewer scenarios: the others would stay behind, unlisted)"
                } else if packed {
                    " (a packed dataset keeps its --limit: its packs are named by the scenarios they hold)"
                } else {
                    ""
                }
            ));
        }
    }
    if let Some(ours) = options.shard {
        for (path, record) in existing {
            if let Some(theirs) = record.shard.filter(|theirs| theirs.count != ours.count) {
                differences.push(format!(
                    "shards: {} splits the dataset into {} shards, this run into {}",
                    path.display(),
                    theirs.count,
                    ours.count
                ));
            }
        }
    }
    differences
}

fn generate_into(expansion: &Expansion, options: &GenOptions, start: Instant) -> Result<Summary, GenError> {
    let names = expansion.spec.cameras.iter().map(|c| c.name.as_str());
    if let Some(warning) = super::cameras_without_images(options.images, "the spec's", names) {
        crate::progress::note(format_args!("warning: {warning}"));
    }
    if let Some(why) = expansion.spec.cars_below_a_pixel().filter(|_| options.images) {
        crate::progress::note(format_args!("warning: {why}"));
    }
    let products = Products {
        images: options.images,
        annotations: options.annotations && options.images,
        effects: options.effects,
        lights: options.lights,
    };
    let out = options.out.clone().unwrap_or_else(|| Path::new("data").join(&expansion.spec.name));
    // One writer per folder (the shards of one job together), and only into
    // a folder that holds nothing but a dataset.
    let shard = options.shard.map(|s| (s.index, s.count));
    let describe = match options.shard {
        Some(s) => format!("gen {} --shard {s}", options.spec_path.display()),
        None => format!("gen {}", options.spec_path.display()),
    };
    let mut claim = claim(&out, Writer::Gen { shard }, &describe).map_err(GenError::Claim)?;
    refuse_linked_splits(&out, &expansion.spec)?;

    // One dataset per folder: same spec, tool version and image setting;
    // the shards of one folder split it the same way.
    let existing = existing_manifests(&out)?;
    let differences = differences_from(&existing, expansion, options, products);
    // Ctrl-C or a SIGTERM while --force removes lets the removal finish,
    // then stops the run (exit 130); before, SIGTERM ended it at once
    // (exit 143), leaving its lock file.
    STOP.store(false, Ordering::SeqCst);
    if options.handle_signals {
        install_signal_handler();
    }
    // What a removal cut off left (moved aside whole) goes first, while
    // no other run writes here (a shard takes the folder alone only then:
    // shards started together would find it taken).
    if std::fs::symlink_metadata(out.join(crate::output::layout::REMOVING_DIR)).is_ok() {
        claim.alone(|| finish_removal(&out)).map_err(GenError::Claim)?.transpose()?;
    }
    let mut removal = std::time::Duration::ZERO;
    if !differences.is_empty() {
        if !options.force {
            return Err(GenError::Mixed { out, differences });
        }
        refuse_removing_inputs(&out, &expansion.spec)?;
        // Said, timed and kept out of the run's rate: removing a large
        // dataset can take a minute.
        let quiet = options.progress == ProgressMode::Quiet;
        if !quiet {
            crate::progress::note(format_args!(
                "--force: removing the dataset made differently in {} ...",
                out.display()
            ));
        }
        let removing = Instant::now();
        // A shard shares the folder with the job's other shards: it removes
        // the old dataset only while none is writing there (one did remove
        // a running shard's scenarios, which then failed).
        claim.alone(|| remove_dataset(&out, &existing)).map_err(GenError::Claim)?.ok_or_else(|| {
            GenError::Input(format!(
                "{}: --force would remove the dataset there while another run (a shard of this job) is writing \
                 in it: nothing was removed; rerun once the others have stopped",
                out.display()
            ))
        })??;
        removal = removing.elapsed();
        if !quiet {
            crate::progress::note(format_args!("removed it in {:.1} s", removal.as_secs_f64()));
        }
    }
    if options.shard.is_none() {
        sweep_partials(&out, &expansion.spec)?;
    }

    let threads = options
        .threads
        .filter(|&t| t > 0)
        .unwrap_or_else(|| std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1));
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| GenError::Threads { threads, reason: e.to_string() })?;

    let sequence = expansion.key_sequence(options.limit);
    let positions = ShardPositions::new(sequence.len(), options.shard);
    // Packed: a shard run writes whole packs, every `count`-th from `index` on.
    let packs = match options.packing {
        Packing::Folders => None,
        Packing::Tar { per_tar } => Some(Packs::new(sequence, per_tar)),
    };
    // More shards than scenarios (or packs) to share: the rest would hold
    // none, and their merge would wait for manifests nobody needs.
    if let Some(shard) = options.shard {
        let (units, what) = packs.map_or((sequence.len(), "scenarios"), |p| (p.len(), "tar files"));
        if shard.count as usize > units {
            let idle = match shard.count - 1 {
                last if last as usize == units => format!("shard {units} would hold none"),
                last => format!("shards {units} to {last} would hold none"),
            };
            return Err(GenError::Input(format!(
                "--shard {}/{}: this run has {units} {what} to share out, so {idle}: use at most {units} shards",
                shard.index, shard.count,
            )));
        }
    }
    let pack_numbers = ShardPositions::new(packs.map_or(0, |p| p.len()), options.shard);
    let my_packs = || pack_numbers.iter();
    let total = match &packs {
        None => positions.len as u64,
        Some(packs) => my_packs().map(|n| u64::from(packs.pack(n).count)).sum(),
    };
    // A shard retried after its job was merged: the folder holds the whole
    // dataset, complete, and the shard's manifest would make it a job to
    // finish again (merge then asked for the other shards).
    // (Not once --force has removed it.)
    let merged = differences.is_empty() && existing.iter().any(|(_, r)| r.shard.is_none() && r.complete);
    if let Some(shard) = options.shard.filter(|_| merged) {
        crate::progress::note(format_args!(
            "{} holds the whole dataset, complete (this job's shards were merged): shard {shard} has nothing to do",
            out.display()
        ));
        return Ok(Summary {
            out,
            scenarios: total,
            written: 0,
            skipped: 0,
            repaired: 0,
            failed: 0,
            frame_pairs: 0,
            bytes: 0,
            elapsed: start.elapsed(),
            threads,
            peak_memory: peak_memory_bytes(),
            shard: Some(shard.to_string()),
            stage_seconds: StageTimes::default().seconds(),
        });
    }
    let shard_entry = options.shard.map(|s| ShardEntry { index: s.index, count: s.count, scenarios: total });
    let manifest_file = manifest_path(&out, options.shard);
    let made_manifest_folder = manifest_file.parent().filter(|p| !p.exists()).map(Path::to_path_buf);
    if let Some(parent) = manifest_file.parent() {
        std::fs::create_dir_all(parent).map_err(io_err(parent))?;
    }
    // A limit at or above every split's size is the same dataset as no
    // limit, and is written as none: a rerun of a finished dataset with
    // such a limit rewrote its manifest with it (no longer the bytes of a
    // run without), and later runs were told it "was written with" it.
    let splits = &expansion.spec.splits;
    let written_limit = options.limit.filter(|&l| crate::spec::Split::ALL.iter().any(|&split| splits.count(split) > l));
    let manifest = |complete| {
        Manifest::new(
            &expansion.spec,
            &expansion.camera,
            written_limit,
            products,
            options.packing,
            complete,
            shard_entry,
        )
        .to_json()
    };
    // The manifest goes first, so that whatever follows (the space check's
    // sample included) lands in a folder that says which dataset it is.
    let previous_manifest = std::fs::read(&manifest_file).ok();
    write_atomically(&manifest_file, &manifest(false))?;
    // Nothing written: the manifest as it was (or none).
    let undo_manifest = |previous: Option<Vec<u8>>| -> Result<(), GenError> {
        match previous {
            Some(bytes) => write_atomically(&manifest_file, &bytes)?,
            None => {
                let _ = std::fs::remove_file(&manifest_file);
                if let Some(folder) = &made_manifest_folder {
                    let _ = std::fs::remove_dir(folder);
                }
            }
        }
        Ok(())
    };
    // Shards share the folder's lock, so shards of two datasets started
    // together could both have found no other manifest above, and both
    // written (one in three tries). Each looks again now that its own is
    // there: of two, the one that wrote later sees the other's and leaves
    // (both may, if each looks after both wrote: a rerun then goes on).
    if options.shard.is_some() {
        let others: Vec<_> = existing_manifests(&out)?.into_iter().filter(|(path, _)| *path != manifest_file).collect();
        let differences = differences_from(&others, expansion, options, products);
        if !differences.is_empty() {
            undo_manifest(previous_manifest)?;
            return Err(GenError::Input(format!(
                "{}: a `gen --shard` run of another dataset began writing here at the same moment:\n  {}\nNothing \
                 was written by this run: rerun it once the other has finished (it then says what to do), or use \
                 another --out",
                out.display(),
                differences.join("\n  ")
            )));
        }
    }

    let writer = TownWriters::new(expansion, products, options.fsync);
    let times = StageTimes::default();
    // Progress counts from here: the space check's sample is its first
    // scenario (counted from after it, one scenario of 5 s went at 9,007/s).
    let writing_from = Instant::now();
    let sample = if options.force_space {
        None
    } else {
        let target_of = |position: usize| {
            let key = sequence.key(position);
            scenario_dir(&out, &key.group, key.split.name(), &key.folder_name())
        };
        // Already written: its folder, or (packed) the pack holding it.
        let present = |position: usize| {
            target_of(position).exists() || packs.is_some_and(|p| p.path(&out, &p.of_position(position)).exists())
        };
        let checked = match &packs {
            None => check_space(expansion, &writer, &out, &sequence, positions.iter(), &present, &times),
            Some(p) => {
                let candidates = my_packs().flat_map(|n| p.pack(n).positions);
                check_space(expansion, &writer, &out, &sequence, candidates, &present, &times)
            }
        };
        match checked {
            Ok(sample) => sample,
            Err(GenError::Interrupted { .. }) => return Err(GenError::Interrupted { done: 0, total, out }),
            Err(refused @ GenError::Space { .. }) => {
                undo_manifest(previous_manifest)?;
                return Err(refused);
            }
            Err(e) => return Err(e),
        }
    };

    // The SUMO networks the spec names, kept beside the manifest so that
    // every reader rebuilds the same map from the dataset alone.
    keep_networks(&expansion.spec, &out)?;

    let progress = Progress::since(writing_from, total, options.progress);
    let bytes = AtomicU64::new(sample.filter(|_| packs.is_none()).map_or(0, |(_, b)| b));
    let written = AtomicU64::new(sample.is_some() as u64);
    let skipped = AtomicU64::new(0);
    let repaired = AtomicU64::new(0);
    // Plans, simulates and writes the scenario at `position` into its folder,
    // unless it is there already, whole.
    let one = |buffers: &mut WriterBuffers, position: usize| -> Result<(), GenError> {
        if STOP.load(Ordering::Relaxed) {
            return Err(GenError::Interrupted { done: 0, total: 0, out: PathBuf::new() });
        }
        if sample.is_some_and(|(first, _)| first == position) {
            progress.inc(); // written (and counted) by the space check
            return Ok(());
        }
        let key = &sequence.key(position);
        let target = scenario_dir(&out, &key.group, key.split.name(), &key.folder_name());
        // Never kept, read or written through a link.
        crate::output::refuse_links_below(&out, &target).map_err(|why| GenError::Input(why.to_string()))?;
        let intact = target.exists()
            && verify_scenario_of(&target, key, expansion.spec.seed)
                .map_err(|why| {
                    crate::progress::note(format_args!(
                        "warning: {} is damaged ({why}): writing it again",
                        target.display()
                    ));
                    repaired.fetch_add(1, Ordering::Relaxed);
                })
                .is_ok();
        if intact {
            skipped.fetch_add(1, Ordering::Relaxed);
            progress.skip();
        } else {
            let written_bytes = write_scenario(expansion, &writer, key, (&out, target), buffers, &times)?;
            if packs.is_none() {
                bytes.fetch_add(written_bytes, Ordering::Relaxed);
            }
            written.fetch_add(1, Ordering::Relaxed);
            progress.inc();
        }
        Ok(())
    };
    let result = pool.install(|| match &packs {
        None => (0..positions.len)
            .into_par_iter()
            .map(|i| positions.position(i))
            .try_for_each_init(|| writer.buffers(), |buffers, position| one(buffers, position)),
        Some(packs) => (0..pack_numbers.len).into_par_iter().try_for_each(|i| {
            let pack = packs.pack(pack_numbers.position(i));
            let path = packs.path(&out, &pack);
            let keys = packs.keys(&pack);
            let folder = |key: &ScenarioKey| scenario_dir(&out, &key.group, key.split.name(), &key.folder_name());
            if path.exists() {
                match crate::output::packs::verify_scenarios_of(&path, &keys, expansion.spec.seed) {
                    Ok(()) => {
                        // Folders a run killed after packing them left behind.
                        for key in &keys {
                            remove_packed(&out, &folder(key), &crate::output::OwnFiles::SCENARIO)?;
                        }
                        skipped.fetch_add(u64::from(pack.count), Ordering::Relaxed);
                        (0..pack.count).for_each(|_| progress.skip());
                        return Ok(());
                    }
                    Err(why) => {
                        crate::progress::note(format_args!("warning: {why}: writing the pack again"));
                        repaired.fetch_add(u64::from(pack.count), Ordering::Relaxed);
                    }
                }
            }
            // Scenarios are appended to the pack as they finish, in order.
            let packing = crate::output::packs::PackWriter::begin(&out, keys.clone(), &path)?;
            pack.positions.clone().into_par_iter().try_for_each_init(
                || writer.buffers(),
                |buffers, position| {
                    one(buffers, position)?;
                    packing.finished(position - pack.positions.start).map_err(GenError::from)
                },
            )?;
            if STOP.load(Ordering::Relaxed) {
                return Err(GenError::Interrupted { done: 0, total: 0, out: PathBuf::new() });
            }
            let size = packing.commit(options.fsync)?;
            bytes.fetch_add(size, Ordering::Relaxed);
            keys.par_iter()
                .try_for_each(|key| remove_packed(&out, &folder(key), &crate::output::OwnFiles::SCENARIO))?;
            Ok(())
        }),
    });
    progress.finish();
    let done = written.load(Ordering::Relaxed) + skipped.load(Ordering::Relaxed);
    match result {
        Err(GenError::Interrupted { .. }) => {
            return Err(GenError::Interrupted { done, total, out });
        }
        Err(GenError::Write { error, .. }) => return Err(GenError::Write { error, done }),
        Err(e) => return Err(e),
        Ok(()) => {}
    }
    let final_manifest = manifest(true);
    write_atomically(&manifest_file, &final_manifest)?;
    if options.shard.is_none() {
        remove_finished_shards(&out, &existing)?;
    }
    let written = written.load(Ordering::Relaxed);
    Ok(Summary {
        out,
        scenarios: total,
        written,
        skipped: skipped.load(Ordering::Relaxed),
        repaired: repaired.load(Ordering::Relaxed),
        failed: 0,
        frame_pairs: if options.images { written * expansion.spec.frames as u64 } else { 0 },
        bytes: bytes.load(Ordering::Relaxed) + final_manifest.len() as u64,
        elapsed: start.elapsed().saturating_sub(removal),
        threads,
        peak_memory: peak_memory_bytes(),
        shard: options.shard.map(|s| s.to_string()),
        stage_seconds: times.seconds(),
    })
}

/// `bytes` as MB below a gigabyte, else as GB (a scenario's size in messages).
fn size_in_words(bytes: u64) -> String {
    if bytes < 1_000_000 {
        format!("{:.1} kB", bytes as f64 / 1e3)
    } else if bytes < 1_000_000_000 {
        format!("{:.1} MB", bytes as f64 / 1e6)
    } else {
        crate::output::arrays::gigabytes(bytes)
    }
}

/// Up to this many scenarios, the space check counts exactly which are
/// still missing; above it, it assumes all are (stat-ing millions of folders
/// would delay the start).
const SPACE_CHECK_EXACT_UP_TO: usize = 200_000;

/// Room for the manifests and the file system's own bookkeeping, beyond
/// the scenarios' bytes.
const SPACE_MARGIN_BYTES: u64 = 64 << 20;

/// Where the scenarios of the most cars are among the run's positions:
/// their groups' splits (a held-out split has its own count), sorted.
struct MostCars(Vec<std::ops::Range<usize>>);

impl MostCars {
    fn of(expansion: &Expansion, sequence: &crate::plan::KeySequence<'_>) -> MostCars {
        let spec = &expansion.spec;
        let classes: Vec<(std::ops::Range<usize>, u32)> = (0..sequence.groups())
            .filter_map(|g| spec.groups.get(g).map(|group| (g, group)))
            .flat_map(|(g, group)| {
                crate::spec::Split::ALL.map(|split| (sequence.positions_of(g, split), spec.group_of(split, group).cars))
            })
            .filter(|(positions, _)| !positions.is_empty())
            .collect();
        let most = classes.iter().map(|(_, cars)| *cars).max().unwrap_or(0);
        let mut ranges: Vec<_> =
            classes.into_iter().filter(|(_, cars)| *cars == most).map(|(positions, _)| positions).collect();
        ranges.sort_by_key(|r| r.start);
        MostCars(ranges)
    }

    fn holds(&self, position: usize) -> bool {
        let at = self.0.partition_point(|r| r.end <= position);
        self.0.get(at).is_some_and(|r| r.contains(&position))
    }
}

/// Whether the disk can hold this run: writes the first missing scenario
/// of the most cars (the run keeps it: returns its position and bytes),
/// measures it, and
/// when that many bytes for every missing scenario would not fit, removes
/// it again (and the folders made for it) and refuses with the figures.
fn check_space(
    expansion: &Expansion,
    writer: &TownWriters,
    out: &Path,
    sequence: &crate::plan::KeySequence<'_>,
    candidates: impl Iterator<Item = usize>,
    present: &dyn Fn(usize) -> bool,
    times: &StageTimes,
) -> Result<Option<(usize, u64)>, GenError> {
    let Some(available) = crate::output::free_disk_bytes(out) else {
        return Ok(None);
    };
    let target_of = |position: usize| {
        let key = sequence.key(position);
        scenario_dir(out, &key.group, key.split.name(), &key.folder_name())
    };
    // Scenarios of more cars write more: the one measured is the first
    // missing one of the most cars, so that the estimate errs high, not
    // low (the first scenario, of the spec's first group, was taken for
    // every group's: a 1-car one for a job of 88-car ones, 40x low).
    let most_cars = MostCars::of(expansion, sequence);
    let (first, pending) = {
        let mut candidates = candidates.into_iter().peekable();
        let mut seen = 0usize;
        let Some(first_missing) = candidates.by_ref().inspect(|_| seen += 1).find(|&p| !present(p)) else {
            return Ok(None);
        };
        let mut sample = most_cars.holds(first_missing).then_some(first_missing);
        // Up to a point, count exactly which are still missing; above it,
        // assume all are (stat-ing millions of folders would delay the start).
        let mut rest = 0u64;
        let mut counted = 0usize;
        for p in candidates {
            counted += 1;
            let exact = seen + counted <= SPACE_CHECK_EXACT_UP_TO;
            let wanted = sample.is_none() && most_cars.holds(p);
            // Past the exact count a scenario is taken as missing, unless it
            // is looked at as the sample.
            let missing = !(exact || wanted) || !present(p);
            if wanted && missing {
                sample = Some(p);
            }
            rest += u64::from(missing || !exact);
        }
        (sample.unwrap_or(first_missing), 1 + rest)
    };
    let target = target_of(first);
    // Folders this check creates, to remove if it refuses.
    let made: Vec<PathBuf> =
        target.ancestors().skip(1).take_while(|a| *a != out && !a.exists()).map(Path::to_path_buf).collect();
    let key = sequence.key(first);
    let bytes = write_scenario(expansion, writer, &key, (out, target.clone()), &mut writer.buffers(), times)?;
    let needed = bytes.saturating_mul(pending - 1).saturating_add(SPACE_MARGIN_BYTES);
    let left = crate::output::free_disk_bytes(out).unwrap_or(available);
    if needed <= left {
        return Ok(Some((first, bytes)));
    }
    let _ = std::fs::remove_dir_all(&target);
    for folder in made {
        let _ = std::fs::remove_dir(folder); // only when empty
    }
    // What the message adds up: pending x per scenario, besides the margin.
    let needed = bytes.saturating_mul(pending);
    Err(GenError::Space { out: out.to_path_buf(), needed, available, per_scenario: bytes, pending })
}

/// Plans, simulates and writes one scenario; returns the bytes written.
fn write_scenario(
    expansion: &Expansion,
    writers: &TownWriters,
    key: &ScenarioKey,
    target: (&Path, PathBuf),
    buffers: &mut WriterBuffers,
    times: &StageTimes,
) -> Result<u64, GenError> {
    let plan = times.time(Stage::Plan, || expansion.plan(key)).map_err(|reason| GenError::Plan {
        scenario: format!("{}/{}/{}", key.group, key.split.name(), key.folder_name()),
        reason,
    })?;
    let interrupted = || GenError::Interrupted { done: 0, total: 0, out: PathBuf::new() };
    let map = &expansion.town_of(&plan).map;
    let writer = writers.of(&plan);
    let (run, effects) =
        simulate_with_effects(map, &plan, writer.products().effects, &STOP, times).ok_or_else(interrupted)?;
    write_simulated(writer, &plan, &run, effects.as_ref(), target, buffers, times)
}

/// Simulates `plan` (the simulate stage) and, when `effects`, measures its
/// interventional effects (the effects stage). The factual run is recorded
/// for the effects' re-runs as it is simulated, so the simulate stage
/// includes the recording. `None` when `stop` was set.
pub(crate) fn simulate_with_effects(
    map: &crate::map::CityMap,
    plan: &ScenarioPlan,
    effects: bool,
    stop: &AtomicBool,
    times: &StageTimes,
) -> Option<(Trajectories, Option<EffectReport>)> {
    use crate::world::effects::{measure_recorded, simulate_recorded, FactualRun};
    if !effects {
        return Some((times.time(Stage::Simulate, || crate::world::simulate_until(map, plan, stop))?, None));
    }
    let run: FactualRun = times.time(Stage::Simulate, || simulate_recorded(map, plan, stop))?;
    let report = times.time(Stage::Effects, || measure_recorded(map, plan, &run, stop))?;
    Some((run.into_trajectories(), Some(report)))
}

/// Peak resident set size of this process (VmHWM), where the OS reports it.
pub fn peak_memory_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}
