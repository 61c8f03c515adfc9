//! A written dataset opened for reading: its manifest, the spec it was made
//! from, and where each of its scenarios lives. Used by every command that
//! reads datasets (stats, heatmap, exports), and a scenario folder read
//! back into arrays ([`readback`]).

pub mod effects;
pub mod pairs;
pub mod poses;
pub mod readback;

use crate::output::manifest::{ManifestRecord, Packing};
use crate::output::scenario_dir;
use crate::plan::{Expansion, KeySequence, ScenarioKey};
use crate::spec::{DatasetSpec, Split};
use std::path::{Path, PathBuf};

/// A dataset folder and what its manifest says it holds. Its scenario keys
/// are walked from the spec ([`Dataset::keys`]), never listed: opening a
/// dataset takes the same memory for ten scenarios as for ten million.
pub struct Dataset {
    pub dir: PathBuf,
    pub record: ManifestRecord,
    pub expansion: Expansion,
    /// A packed dataset's (`gen --format tar`) packs, unpacked for readers
    /// of scenario folders when they first need them; the folders go when
    /// this goes.
    pub unpacked: Option<Unpacked>,
    /// Held while this is open: `gen --force` refuses to remove the
    /// dataset meanwhile.
    _hold: crate::output::claim::ReadHold,
}

/// Each scenario's (cars, frames) by its folder relative to the dataset
/// (`group/split/name`).
pub type ScenarioSizes = std::collections::HashMap<String, (usize, usize)>;

/// Where a packed dataset's packs are unpacked (a private temporary
/// folder, removed when this is dropped) and which are there.
pub struct Unpacked {
    scratch: crate::output::packs::Scratch,
    per_tar: u32,
    /// Unpack the frames (PNG) too ([`Dataset::with_frames`]); readers of
    /// the logs leave them in the packs.
    frames: bool,
    done: std::sync::Mutex<Vec<bool>>,
}

/// The shard manifests in `dir/shards/` (`shards/K-of-N.json`), sorted: a
/// `gen --shard` job's folder before its merge.
fn shard_manifests(dir: &Path) -> Vec<String> {
    let mut found: Vec<String> = std::fs::read_dir(dir.join("shards"))
        .into_iter()
        .flatten()
        .flatten()
        .map(|entry| entry.file_name().to_string_lossy().into_owned())
        .filter(|name| name.contains("-of-") && name.ends_with(".json"))
        .map(|name| format!("shards/{name}"))
        .collect();
    found.sort();
    found
}

impl Dataset {
    /// Opens the dataset in `dir`; errors name the folder and what is wrong.
    pub fn open(dir: &Path) -> Result<Dataset, String> {
        let manifest = dir.join("manifest.json");
        let hold = crate::output::claim::hold_for_reading(dir)?;
        let record = ManifestRecord::read(&manifest)?.ok_or_else(|| match dir.join(SWEEP_RECORD).is_file() {
            true => format!(
                "{} is a counterfactual sweep (sweep.json), not a gen dataset: this command reads datasets gen \
                     wrote",
                dir.display()
            ),
            false => match shard_manifests(dir).as_slice() {
                [] => format!("no manifest.json in {}: not a causalcity dataset", dir.display()),
                shards => format!(
                    "{} holds the shards of a gen job ({}) and no manifest.json: not a dataset until they are \
                     merged. Once every shard has finished: `causalcity merge --out {}` if all of them wrote here, \
                     or `causalcity merge --out DEST FOLDER...` naming each shard's folder (merge names any shard \
                     missing or unfinished); or rerun an interrupted merge",
                    dir.display(),
                    shards.join(", "),
                    dir.display()
                ),
            },
        })?;
        let expansion = expansion_of(&record, &manifest)?;
        let unpacked = match record.packing() {
            Packing::Folders => None,
            Packing::Tar { per_tar } => Some(Unpacked {
                scratch: crate::output::packs::Scratch::new()?,
                per_tar,
                frames: false,
                done: std::sync::Mutex::new(Vec::new()),
            }),
        };
        Ok(Dataset { dir: dir.to_path_buf(), record, expansion, unpacked, _hold: hold })
    }

    /// The folder the scenario folders at `positions` are under: the
    /// dataset's own, or for a packed dataset, the temporary folder that
    /// the packs holding them are unpacked into (each once, in parallel).
    /// Errors name a missing or damaged pack.
    fn folders_root(&self, positions: std::ops::Range<usize>) -> Result<&Path, String> {
        let Some(unpacked) = &self.unpacked else { return Ok(self.folders_root_unread()) };
        if positions.is_empty() {
            return Ok(self.folders_root_unread());
        }
        let packs = crate::output::packs::Packs::new(self.key_sequence(), unpacked.per_tar);
        let wanted: Vec<usize> = {
            let mut done = unpacked.done.lock().map_err(|_| "a reader thread failed".to_string())?;
            if done.is_empty() {
                done.resize(packs.len(), false);
            }
            packs.numbers_of(positions.clone()).filter(|&n| !done[n]).collect()
        };
        use rayon::prelude::*;
        let root = self.folders_root_unread();
        wanted.into_par_iter().try_for_each(|n| {
            let path = packs.path(&self.dir, &packs.pack(n));
            if !path.is_file() {
                return Err(format!("{}: missing pack (validate says what else is missing)", path.display()));
            }
            let frames = unpacked.frames;
            let keys = packs.keys(&packs.pack(n));
            crate::output::packs::unpack(&path, &keys, root, &|name| frames || !name.ends_with(".png"))?;
            // Marked once whole: what failed is tried again, not taken as there.
            unpacked.done.lock().map_err(|_| "a reader thread failed".to_string())?[n] = true;
            Ok(())
        })?;
        Ok(root)
    }

    /// The folder the scenario folders are under while they are read: the
    /// dataset's own, or the temporary folder a packed dataset's packs are
    /// unpacked into (nothing is unpacked by asking).
    pub fn folders_root_unread(&self) -> &Path {
        match &self.unpacked {
            None => &self.dir,
            Some(unpacked) => unpacked.scratch.path(),
        }
    }

    /// Each scenario's (cars, frames) from its scenario.json, by its folder
    /// relative to the dataset (`group/split/name`): for a packed dataset,
    /// read from the packs in memory (a header scan per pack, nothing
    /// unpacked); `None` for a folder dataset, whose files are read where
    /// they are. Errors name the pack and member.
    pub fn packed_scenario_sizes(&self) -> Result<Option<ScenarioSizes>, String> {
        let Some(unpacked) = &self.unpacked else { return Ok(None) };
        use rayon::prelude::*;
        let packs = crate::output::packs::Packs::new(self.key_sequence(), unpacked.per_tar);
        let found: Vec<Vec<(String, (usize, usize))>> = (0..packs.len())
            .into_par_iter()
            .map(|n| {
                let path = packs.path(&self.dir, &packs.pack(n));
                if !path.is_file() {
                    return Err(format!("{}: missing pack (validate says what else is missing)", path.display()));
                }
                let mut sizes = Vec::new();
                let wanted =
                    |name: &str| crate::output::packs::split_member(name).is_some_and(|(_, f)| f == "scenario.json");
                crate::output::packs::read_members_where(&path, &wanted, |name, bytes| {
                    // Named as validate names a member: `<pack>: <member>`.
                    let label = PathBuf::from(format!("{}: {name}", path.display()));
                    let summary = ScenarioSummary::parse(&bytes, &label, GraphKind::Designed)?;
                    let (folder, _) = crate::output::packs::split_member(name).expect("wanted names have a folder");
                    sizes.push((folder.to_string(), (summary.cars.len(), summary.frames as usize)));
                    Ok(())
                })?;
                // Every scenario the pack's name promises has its summary.
                let found: std::collections::BTreeSet<&str> = sizes.iter().map(|(f, _)| f.as_str()).collect();
                if let Some(key) =
                    packs.keys(&packs.pack(n)).iter().find(|k| !found.contains(k.relative_folder().as_str()))
                {
                    return Err(format!(
                        "{}: {}/scenario.json is not in it: the pack is damaged (validate says more)",
                        path.display(),
                        key.relative_folder()
                    ));
                }
                Ok(sizes)
            })
            .collect::<Result<_, String>>()?;
        Ok(Some(found.into_iter().flatten().collect()))
    }

    /// The keys of the scenarios the dataset holds, in its order.
    pub fn key_sequence(&self) -> KeySequence<'_> {
        self.expansion.key_sequence(self.record.limit)
    }

    /// [`Dataset::key_sequence`]'s keys, each made when it is reached.
    pub fn keys(&self) -> impl ExactSizeIterator<Item = ScenarioKey> + '_ {
        (0..self.key_sequence().len()).map(move |i| self.key_sequence().key(i))
    }

    /// For readers of the frames: a packed dataset's PNGs are unpacked too
    /// (without this, only the logs and JSON are, and a scenario folder
    /// read from packs has no `rgb/`, `mask/` or camera frames).
    pub fn with_frames(mut self) -> Dataset {
        if let Some(unpacked) = &mut self.unpacked {
            unpacked.frames = true;
        }
        self
    }

    /// Opens a dataset whose run has finished.
    pub fn open_complete(dir: &Path) -> Result<Dataset, String> {
        let dataset = Dataset::open(dir)?;
        if !dataset.record.complete {
            return Err(format!("{} is not complete: finish it with its gen command first", dir.display()));
        }
        dataset.refuse_linked_folders()?;
        Ok(dataset)
    }

    pub fn spec(&self) -> &DatasetSpec {
        &self.expansion.spec
    }

    /// Checks that every scenario carries `graph` (the causal and direct
    /// graphs need effects, which `gen --no-effects` leaves out).
    pub fn require_graph(&self, graph: GraphKind) -> Result<(), String> {
        if graph != GraphKind::Designed && !self.record.effects {
            return Err(format!(
                "{} has no {} graph: it was generated with gen --no-effects (regenerate it without that flag, \
                 or use the designed graph)",
                self.dir.display(),
                graph.name()
            ));
        }
        Ok(())
    }

    /// Calls `read` with the scenario folders of `group`'s `split` (in index
    /// order), then [`Dataset::release`]s them: a reader that goes through a
    /// packed dataset this way holds one split's folders in `TMPDIR` at a
    /// time, never the dataset's.
    pub fn with_split<R>(
        &self,
        group: &str,
        split: Split,
        read: impl FnOnce(&[PathBuf]) -> Result<R, String>,
    ) -> Result<R, String> {
        let dirs = self.scenario_dirs(group, split)?;
        let result = read(&dirs).map_err(|e| self.name_packed_paths(e));
        self.release(group, split)?;
        result
    }

    /// `message` with each path into the temporary folder that a packed
    /// dataset's scenarios are unpacked into told as where the file is
    /// ([`crate::output::packs::name_unpacked_paths`]). Unchanged for a
    /// folder dataset.
    pub fn name_packed_paths(&self, message: String) -> String {
        match &self.unpacked {
            Some(unpacked) => crate::output::packs::name_unpacked_paths(message, unpacked.scratch.path(), &self.dir),
            None => message,
        }
    }

    /// Calls `each(folder, relative)` for every scenario of the dataset, in
    /// parallel within a split, a group's split at a time as
    /// [`Dataset::with_split`] reads one: `relative` is the scenario's folder
    /// relative to the dataset (`<group>/<split>/<scenario>`), which exports
    /// mirror. A failure to read the dataset itself (a packed split's packs
    /// unpacked) is told to `unreadable` before it is returned, so that the
    /// caller can tell it from a failure of `each`.
    pub fn each_scenario_in_turn(
        &self,
        unreadable: impl Fn(&str),
        each: impl Fn(&Path, &Path) -> Result<(), String> + Sync,
    ) -> Result<(), String> {
        use rayon::prelude::*;
        for group in self.spec().groups.iter().map(|g| g.name()) {
            for split in Split::ALL {
                let under = Path::new(&group).join(split.name());
                let dirs = self.scenario_dirs(&group, split).inspect_err(|e| unreadable(e))?;
                let result = dirs
                    .par_iter()
                    .try_for_each(|dir| each(dir, &under.join(dir.file_name().expect("scenario folders have names"))))
                    .map_err(|e| self.name_packed_paths(e));
                self.release(&group, split)?;
                result?;
            }
        }
        Ok(())
    }

    /// A reader is done with `group`'s `split`: a packed dataset's folders
    /// unpacked for it are removed (read again, they are unpacked again), so
    /// that a reader going through the dataset a split at a time holds one
    /// split in `TMPDIR`, not the dataset. Nothing for a folder dataset.
    pub fn release(&self, group: &str, split: Split) -> Result<(), String> {
        let Some(unpacked) = &self.unpacked else { return Ok(()) };
        let Some(index) = self.spec().groups.iter().position(|g| g.name() == group) else { return Ok(()) };
        let positions = self.key_sequence().positions_of(index, split);
        if positions.is_empty() {
            return Ok(());
        }
        let packs = crate::output::packs::Packs::new(self.key_sequence(), unpacked.per_tar);
        let mut done = unpacked.done.lock().map_err(|_| "a reader thread failed".to_string())?;
        let folder = unpacked.scratch.path().join(group).join(split.name());
        if folder.exists() {
            std::fs::remove_dir_all(&folder).map_err(|e| format!("cannot remove {}: {e}", folder.display()))?;
        }
        for n in packs.numbers_of(positions) {
            if let Some(d) = done.get_mut(n) {
                *d = false;
            }
        }
        Ok(())
    }

    /// Scenario folders of one group and split, in index order. A packed
    /// dataset's packs that hold them are unpacked first (into a temporary
    /// folder, each once).
    pub fn scenario_dirs(&self, group: &str, split: Split) -> Result<Vec<PathBuf>, String> {
        let Some(index) = self.spec().groups.iter().position(|g| g.name() == group) else { return Ok(Vec::new()) };
        let sequence = self.key_sequence();
        let positions = sequence.positions_of(index, split);
        let root = self.folders_root(positions.clone())?;
        Ok(positions
            .map(|p| sequence.key(p))
            .map(|k| scenario_dir(root, &k.group, split.name(), &k.folder_name()))
            .collect())
    }

    /// Refuses a folder dataset with a linked group, split or scenario
    /// folder ([`crate::output::linked_below`]): its readers read a
    /// dataset's scenarios from its own folders, never through a link, as
    /// `validate` names one and `gen` writes through none (`evaluate`,
    /// `stats` and `export` read through them before, exit 0). One `lstat`
    /// per folder, the keys walked as `gen` walks them.
    pub fn refuse_linked_folders(&self) -> Result<(), String> {
        if self.unpacked.is_some() {
            return Ok(());
        }
        let sequence = self.key_sequence();
        let mut above = std::collections::BTreeSet::new();
        for p in 0..sequence.len() {
            let key = sequence.key(p);
            let split = self.dir.join(&key.group).join(key.split.name());
            // (each group and split folder once)
            let link = match above.insert(split.clone()) {
                true => crate::output::linked_below(&self.dir, &split.join(key.folder_name())),
                false => crate::output::linked_below(&split, &split.join(key.folder_name())),
            };
            if let Some(link) = link {
                return Err(crate::output::linked_folder_error(&link));
            }
        }
        Ok(())
    }
}

/// Whether the intervention pair `key`'s summary records is the one a sweep
/// of `expansion`'s spec and `kinds` (sweep.json's names, in order) draws
/// for it ([`crate::plan::interventions::SweepDraw`]); returns the drawn
/// one. An edited summary (another car, kind or frame) was read as the
/// pair's truth by `validate`, `evaluate` and the Python package, and so
/// was every pair of a sweep.json whose kinds were edited. A summary from
/// before the record was kept (it has none) must have fired the
/// intervention on the drawn frame.
pub fn check_drawn(
    expansion: &Expansion,
    kinds: &[String],
    key: &ScenarioKey,
    summary: &crate::output::pair_summary::PairSummary,
) -> Result<crate::output::pair_summary::InterventionRecord, String> {
    use crate::plan::interventions::{SweepDraw, SweepKind};
    let drawn_from = kinds
        .iter()
        .map(|k| SweepKind::from_name(k).ok_or_else(|| format!("{k:?} is not a kind of intervention a sweep draws")))
        .collect::<Result<Vec<_>, _>>()?;
    if drawn_from.is_empty() {
        return Err(format!("{SWEEP_RECORD} names no kinds, so nothing says which intervention a pair was given"));
    }
    let plan = expansion.plan(key)?;
    let drawn = crate::output::pair_summary::InterventionRecord::of_draw(&plan, &SweepDraw::of(&plan, &drawn_from));
    let recorded = match (&summary.intervention, summary.intervention_time_s) {
        (Some(recorded), _) if *recorded == drawn => return Ok(drawn),
        (Some(recorded), _) => recorded.describe(),
        (None, Some(t)) if drawn.fired_at(t, plan.frame_interval) => return Ok(drawn),
        (None, Some(t)) => format!("no intervention, and one that fired at {t} s"),
        (None, None) => "no intervention, and none that fired".to_string(),
    };
    Err(format!(
        "records {recorded}, but this sweep (its spec, and kinds {} in {SWEEP_RECORD}) draws {} for this pair: the \
         summary, or sweep.json's kinds, changed after the sweep wrote them",
        kinds.join(", "),
        drawn.describe()
    ))
}

/// The expansion of the spec a manifest (at `path`) records, refused when
/// the spec no longer hashes to the manifest's `spec_sha256`: an edited
/// spec would describe scenarios other than the ones on disk (another
/// seed simulates others; smaller splits hide some).
pub fn expansion_of(record: &ManifestRecord, path: &Path) -> Result<Expansion, String> {
    let expansion = expansion_from(record.spec.clone(), path)?;
    check_spec_hash(&expansion, &record.spec_sha256, path, "gen wrote the dataset", "scenarios")?;
    Ok(expansion)
}

/// Refuses a record (at `path`) whose spec no longer hashes to the
/// `spec_sha256` it recorded: edited after `who` (its writer), so that it
/// describes other `what` than the ones on disk.
fn check_spec_hash(expansion: &Expansion, recorded: &str, path: &Path, who: &str, what: &str) -> Result<(), String> {
    let hashed = crate::output::manifest::spec_sha256(&expansion.spec);
    if hashed == recorded {
        return Ok(());
    }
    Err(format!(
        "{}: its spec does not hash to its spec_sha256 ({} recorded, {} now): it was edited after {who}, so it no \
         longer describes the {what} on disk; restore it (or regenerate)",
        path.display(),
        crate::output::short_hash(recorded),
        crate::output::short_hash(&hashed)
    ))
}

/// The expansion of a spec recorded (as JSON) in the file at `path`.
fn expansion_from(spec: serde_json::Value, path: &Path) -> Result<Expansion, String> {
    let mut spec: DatasetSpec =
        serde_json::from_value(spec).map_err(|e| format!("{}: the spec in it is unreadable: {e}", path.display()))?;
    // The dataset's root: the manifest's folder, or the one above `shards/`.
    let folder = path.parent().unwrap_or(Path::new("."));
    // (A shard's manifest is shards/K-of-N.json; manifest.json and
    // sweep.json sit at the root, whatever the root is called.)
    let at_root = path.file_name().is_some_and(|n| n == "manifest.json" || n == "sweep.json");
    let in_shards = !at_root && folder.file_name().is_some_and(|n| n == "shards");
    let root = if in_shards { folder.parent().unwrap_or(folder) } else { folder };
    spec.read_networks_in_dataset(root)
        .map_err(|e| format!("{}: the network its spec names is missing or unreadable: {e}", path.display()))?;
    // A hand-edited record is checked as a spec file is (frames, sizes, ...).
    // (Limits added since an earlier version wrote it are not applied.)
    spec.validate_recorded().map_err(|e| format!("{}: the spec in it is invalid: {e}", path.display()))?;
    Expansion::from_written_spec(spec).map_err(|e| format!("{}: the spec in it is invalid: {e}", path.display()))
}

/// One car as a scenario.json names it.
#[derive(Debug, Clone, serde::Deserialize)]
pub struct ScenarioCar {
    pub id: u32,
    pub name: String,
    pub mask_id: u8,
    /// "#rrggbb"
    #[serde(default)]
    pub colour: String,
}

/// A list of car pairs `[[a, b], ...]` of a scenario.json (`edges`,
/// `causal_edges`, ...); `None` when the field is missing or malformed.
pub fn edge_pairs(scenario: &serde_json::Value, field: &str) -> Option<Vec<(u32, u32)>> {
    let pair = |e: &serde_json::Value| Some((u32::try_from(e[0].as_u64()?).ok()?, u32::try_from(e[1].as_u64()?).ok()?));
    scenario[field].as_array()?.iter().map(pair).collect()
}

/// Which causal graph of a scenario a reader scores or exports.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum GraphKind {
    /// The design: leader-follower pairs (`edges`).
    #[default]
    Designed,
    /// Total effects under intervention (`causal_edges`).
    Causal,
    /// Direct effects under intervention (`direct_edges`).
    Direct,
}

impl GraphKind {
    pub const ALL: [GraphKind; 3] = [GraphKind::Designed, GraphKind::Causal, GraphKind::Direct];

    pub fn name(self) -> &'static str {
        match self {
            GraphKind::Designed => "designed",
            GraphKind::Causal => "causal",
            GraphKind::Direct => "direct",
        }
    }

    /// The scenario.json field holding it.
    pub fn field(self) -> &'static str {
        match self {
            GraphKind::Designed => "edges",
            GraphKind::Causal => "causal_edges",
            GraphKind::Direct => "direct_edges",
        }
    }
}

/// What readers need from a scenario.json.
#[derive(Debug, Clone, serde::Deserialize)]
pub struct ScenarioSummary {
    pub name: String,
    pub frames: u32,
    pub frame_interval: f64,
    pub cars: Vec<ScenarioCar>,
    /// (leader, follower) car ids.
    pub edges: Vec<[u32; 2]>,
    /// (cause, effect) car ids, where effects were measured.
    #[serde(default)]
    pub causal_edges: Option<Vec<[u32; 2]>>,
    #[serde(default)]
    pub direct_edges: Option<Vec<[u32; 2]>>,
    /// The graph asked for by [`ScenarioSummary::read_graph`] (the designed
    /// one by default), (cause, effect) car ids.
    #[serde(skip)]
    pub graph: Vec<[u32; 2]>,
    /// Which scenario of its dataset it is (`gen`'s scenarios say; a
    /// handwritten run's need not).
    #[serde(default)]
    pub group: Option<String>,
    #[serde(default)]
    pub split: Option<String>,
    #[serde(default)]
    pub index: Option<u64>,
}

/// The scenario key a `scenario.json`'s path names, when it lies where a
/// dataset keeps one: `<group>/<split>/<index>/scenario.json`, the group
/// as every spec names them (`cars08_edges50`; a pack member's label
/// `<pack>: <member>` counts from the member's name). `None` elsewhere (a
/// pair's runs, a handwritten run's folder).
fn place_of(path: &Path) -> Option<(String, String, u64)> {
    let text = path.to_string_lossy();
    let mut parts = text.rsplit('/');
    let (file, index, split, group) = (parts.next()?, parts.next()?, parts.next()?, parts.next()?);
    let group = group.rsplit(": ").next()?;
    let is_group = crate::output::claim::is_group_folder(group);
    let is_split = crate::spec::Split::ALL.iter().any(|s| s.name() == split);
    let index = index.bytes().all(|b| b.is_ascii_digit()).then(|| index.parse::<u64>().ok()).flatten()?;
    (file == "scenario.json" && is_group && is_split).then(|| (group.to_string(), split.to_string(), index))
}

impl ScenarioSummary {
    /// Reads `dir/scenario.json`; errors name the file.
    pub fn read(dir: &Path) -> Result<ScenarioSummary, String> {
        ScenarioSummary::read_graph(dir, GraphKind::Designed)
    }

    /// Reads `dir/scenario.json` with `graph` in [`ScenarioSummary::graph`];
    /// errors name the file (and the field, when the graph is missing).
    pub fn read_graph(dir: &Path, graph: GraphKind) -> Result<ScenarioSummary, String> {
        let path = dir.join("scenario.json");
        let bytes = crate::input::read_record(&path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
        ScenarioSummary::parse(&bytes, &path, graph)
    }

    /// [`ScenarioSummary::read_graph`] of a scenario.json's bytes; errors
    /// name `path`, where they came from.
    pub fn parse(bytes: &[u8], path: &Path, graph: GraphKind) -> Result<ScenarioSummary, String> {
        let mut summary: ScenarioSummary =
            serde_json::from_slice(bytes).map_err(|e| format!("{}: not a causalcity scenario: {e}", path.display()))?;
        summary.graph = match graph {
            GraphKind::Designed => Some(summary.edges.clone()),
            GraphKind::Causal => summary.causal_edges.clone(),
            GraphKind::Direct => summary.direct_edges.clone(),
        }
        .ok_or_else(|| format!("{}: no `{}` (it was written without effects)", path.display(), graph.field()))?;
        // What a spec allows, so that readers' tables stay the size of a
        // real scenario however the file was edited.
        if !(1..=crate::spec::MAX_FRAMES).contains(&summary.frames) {
            return Err(format!(
                "{}: frames {} is not a scenario's: use 1 to {}",
                path.display(),
                summary.frames,
                crate::spec::MAX_FRAMES
            ));
        }
        let interval = summary.frame_interval;
        if !(interval.is_finite() && interval > 0.0 && interval <= crate::spec::MAX_FRAME_INTERVAL_S) {
            return Err(format!(
                "{}: frame_interval {interval} is not a scenario's: seconds above 0 and at most {}",
                path.display(),
                crate::spec::MAX_FRAME_INTERVAL_S
            ));
        }
        if summary.cars.len() > crate::spec::MAX_CARS as usize {
            return Err(format!(
                "{}: {} cars is more than a scenario has (at most {})",
                path.display(),
                summary.cars.len(),
                crate::spec::MAX_CARS
            ));
        }
        // A scenario is read only where its dataset keeps it: one moved or
        // copied into another's folder was read as that one (its graph
        // scored against the other's predictions, exported under its name).
        if let Some((group, split, index)) = place_of(path) {
            let here = [
                ("group", summary.group.as_ref().is_none_or(|g| *g == group), format!("{:?}", summary.group)),
                ("split", summary.split.as_ref().is_none_or(|s| *s == split), format!("{:?}", summary.split)),
                ("index", summary.index.is_none_or(|i| i == index), format!("{:?}", summary.index)),
            ];
            if let Some((field, _, value)) = here.iter().find(|(_, ok, _)| !ok) {
                let value = value.trim_start_matches("Some(").trim_end_matches(')');
                return Err(format!(
                    "{}: `{field}` is {value}, but it lies at {group}/{split}/{index:05}: a scenario moved or copied \
                     from elsewhere (causalcity validate says what else is)",
                    path.display()
                ));
            }
        }
        let cars = summary.cars.len() as u32;
        if let Some((i, car)) = summary.cars.iter().enumerate().find(|(i, c)| c.id != *i as u32) {
            return Err(format!("{}: cars[{i}] has id {}: car ids must be 0..{cars} in order", path.display(), car.id));
        }
        // Every graph the file holds, whichever is read: a self-loop or a
        // pair given twice changed stats' gaps and edge counts silently.
        let graphs = [("edges", Some(&summary.edges)), ("causal_edges", summary.causal_edges.as_ref())];
        for (field, pairs) in graphs.into_iter().chain([("direct_edges", summary.direct_edges.as_ref())]) {
            let mut seen = std::collections::HashSet::new();
            for &[a, b] in pairs.into_iter().flatten() {
                let why = match () {
                    _ if a >= cars || b >= cars => format!("names a car beyond the {cars} cars (ids 0..{cars})"),
                    _ if a == b => "links a car to itself".to_string(),
                    _ if !seen.insert((a, b)) => "is given twice".to_string(),
                    _ => continue,
                };
                return Err(format!("{}: {field}: pair [{a}, {b}] {why}", path.display()));
            }
        }
        Ok(summary)
    }
}

/// Fewest bytes a row of poses.csv takes.
const MIN_POSE_ROW_BYTES: u64 = 26;

/// Refuses a pose log at `path` too short to hold `frames` x `cars` rows
/// (a scenario.json edited to claim more), before any memory is set aside
/// for them.
pub(crate) fn poses_fit(path: &Path, frames: usize, cars: usize) -> Result<(), String> {
    // A pipe or a folder is named as what it is, never opened.
    let bytes = crate::input::regular_file(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?.len();
    if (frames as u64).saturating_mul(cars as u64).saturating_mul(MIN_POSE_ROW_BYTES) > bytes {
        return Err(format!(
            "{frames} frames x {cars} cars (its scenario.json) are more rows than {} ({bytes} bytes) can hold",
            path.display()
        ));
    }
    Ok(())
}

/// One row of poses.csv (the columns readers use).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Pose {
    /// Metres on the ground plane.
    pub x: f64,
    pub y: f64,
    /// Pixel position in the bird's-eye frame.
    pub px: f64,
    pub py: f64,
    /// Heading, radians counter-clockwise from east.
    pub yaw: f64,
    /// Metres per second.
    pub speed: f64,
    pub in_view: bool,
}

/// A scenario's pose log as a [frame][car] table.
#[derive(Debug, Clone)]
pub struct PoseLog {
    pub frames: usize,
    pub cars: usize,
    poses: Vec<Pose>,
}

impl PoseLog {
    /// Reads `dir/poses.csv`, which must hold exactly `frames` x `cars` rows.
    pub fn read(dir: &Path, frames: usize, cars: usize) -> Result<PoseLog, String> {
        let path = dir.join("poses.csv");
        poses_fit(&path, frames, cars)?;
        let file = std::fs::File::open(&path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
        let mut poses = vec![Pose::default(); frames * cars];
        poses::read_pose_rows(std::io::BufReader::new(file), &path, frames, cars, |row| {
            let ([x, y, _], [px, py]) = (row.position, row.pixel);
            let (yaw, speed, in_view) = (row.rotation[2], row.speed, row.in_view);
            poses[row.frame * cars + row.car] = Pose { x, y, px, py, yaw, speed, in_view };
        })?;
        Ok(PoseLog { frames, cars, poses })
    }

    pub fn at(&self, frame: usize, car: usize) -> &Pose {
        &self.poses[frame * self.cars + car]
    }

    /// The poses of one frame, in car-id order.
    pub fn frame(&self, frame: usize) -> &[Pose] {
        &self.poses[frame * self.cars..(frame + 1) * self.cars]
    }
}

/// The record of a `counterfactual --sweep` (`sweep.json`): written with
/// `"complete": false` when it starts, and `true` when it has finished.
pub const SWEEP_RECORD: &str = "sweep.json";

/// A finished `counterfactual --sweep` output opened for reading: the spec
/// it expanded and its pairs, `<group>/<split>/<index>/{factual,
/// counterfactual}/`, one per scenario key.
pub struct Sweep {
    pub dir: PathBuf,
    pub expansion: Expansion,
    /// `--limit` of the sweep's run: its keys are walked from the spec.
    pub limit: Option<u32>,
    /// How its runs log the lights (`--lights`; sweeps from before the
    /// record said so logged every frame).
    pub lights: crate::output::manifest::LightsLog,
    /// Pair folders, or pairs packed into tar files (`--format tar`).
    pub packing: crate::output::manifest::Packing,
    /// Its `--kinds` of intervention, in the order given (which, with the
    /// spec, decides each pair's intervention).
    pub kinds: Vec<String>,
}

impl Sweep {
    /// Opens the sweep in `dir`; `Ok(None)` when `dir` has no sweep.json.
    /// Errors name the file and what is wrong.
    pub fn open(dir: &Path) -> Result<Option<Sweep>, String> {
        match Sweep::open_even_unfinished(dir)? {
            Some((_, false)) => Err(format!(
                "{} is not complete: finish it with its counterfactual --sweep command first",
                dir.display()
            )),
            other => Ok(other.map(|(sweep, _)| sweep)),
        }
    }

    /// The sweep in `dir` and whether its run finished (`validate` reports
    /// an unfinished one rather than refusing it).
    pub fn open_even_unfinished(dir: &Path) -> Result<Option<(Sweep, bool)>, String> {
        let path = dir.join(SWEEP_RECORD);
        let bytes = match crate::input::read_record(&path) {
            Ok(bytes) => bytes,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(format!("cannot read {}: {e}", path.display())),
        };
        #[derive(serde::Deserialize)]
        struct Record {
            format: String,
            spec: serde_json::Value,
            limit: Option<u32>,
            /// Written false when a sweep starts, true when it has finished.
            #[serde(default = "finished")]
            complete: bool,
            #[serde(default)]
            lights: crate::output::manifest::LightsLog,
            #[serde(default)]
            scenarios_per_tar: Option<u32>,
            /// The spec's hash (sweeps from before it was recorded lack it).
            #[serde(default)]
            spec_sha256: Option<String>,
            #[serde(default)]
            kinds: Vec<String>,
        }
        fn finished() -> bool {
            true
        }
        let record: Record = serde_json::from_slice(&bytes)
            .map_err(|e| format!("{}: not a counterfactual sweep's record: {e}", path.display()))?;
        if !record.format.starts_with("causalcity-counterfactual-sweep/") {
            return Err(format!(
                "{}: format {:?} is not causalcity-counterfactual-sweep/1",
                path.display(),
                record.format
            ));
        }
        if record.limit == Some(0) {
            // (validate said "0 of 0 scenarios checked: valid".)
            return Err(format!("{}: limit 0 is not allowed: a number above 0, or absent", path.display()));
        }
        // The kinds, with the spec, decide each pair's intervention: none
        // (every sweep records its --kinds), one not a sweep's, or one
        // named twice, is no sweep's record.
        if record.kinds.is_empty() {
            return Err(format!(
                "{}: kinds is missing or empty: every sweep records the --kinds it drew its interventions from, so \
                 this record was edited (rerun its counterfactual --sweep command into a new --out)",
                path.display()
            ));
        }
        for (i, kind) in record.kinds.iter().enumerate() {
            if crate::plan::interventions::SweepKind::from_name(kind).is_none() {
                let allowed: Vec<&str> = crate::plan::interventions::SweepKind::ALL.iter().map(|k| k.name()).collect();
                return Err(format!(
                    "{}: kinds[{i}] {kind:?} is not a kind of intervention a sweep draws: use {}",
                    path.display(),
                    allowed.join(", ")
                ));
            }
            if record.kinds[..i].contains(kind) {
                return Err(format!("{}: kinds[{i}] {kind:?} is named twice: each kind once", path.display()));
            }
        }
        let expansion = expansion_from(record.spec, &path)?;
        if let Some(recorded) = &record.spec_sha256 {
            check_spec_hash(&expansion, recorded, &path, "the sweep was run", "pairs")?;
        }
        let packing = match record.scenarios_per_tar {
            None => crate::output::manifest::Packing::Folders,
            Some(0) => {
                return Err(format!("{}: scenarios_per_tar 0 is not allowed: use a number above 0", path.display()))
            }
            Some(per_tar) => crate::output::manifest::Packing::Tar { per_tar },
        };
        let sweep = Sweep {
            dir: dir.to_path_buf(),
            expansion,
            limit: record.limit,
            lights: record.lights,
            packing,
            kinds: record.kinds,
        };
        Ok(Some((sweep, record.complete)))
    }

    /// [`check_drawn`] of pair `key` of this sweep.
    pub fn check_drawn(
        &self,
        key: &ScenarioKey,
        summary: &crate::output::pair_summary::PairSummary,
    ) -> Result<crate::output::pair_summary::InterventionRecord, String> {
        check_drawn(&self.expansion, &self.kinds, key, summary)
    }

    /// The keys of the sweep's pairs, in order.
    pub fn key_sequence(&self) -> KeySequence<'_> {
        self.expansion.key_sequence(self.limit)
    }

    /// A packed sweep's packs (`None` for pair folders).
    pub fn packs(&self) -> Option<crate::output::packs::Packs<'_>> {
        match self.packing {
            crate::output::manifest::Packing::Folders => None,
            crate::output::manifest::Packing::Tar { per_tar } => {
                Some(crate::output::packs::Packs::new(self.key_sequence(), per_tar))
            }
        }
    }
}
