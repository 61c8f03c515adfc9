//! `causalcity validate`: checks a dataset folder against what `data-schema/`
//! documents and against its own checksums, in parallel, reading every file
//! once: files present, frame counts and sizes, CSV columns and row counts,
//! ids consistent across scenario.json, the CSV logs and the masks, and the
//! SHA-256 of every file. Reports every problem with its path.

use crate::dataset::Dataset;
use crate::output::layout::{
    FrameKind, ScenarioLayout, EFFECTS_CSV, EVENTS_CSV, INTERACTIONS_CSV, LIGHTS_CSV, LIGHT_CHANGES_CSV, POSES_CSV,
    SCENARIO_JSON,
};
use crate::output::logs::{parse_effects, EVENT_COLUMNS, INTERACTION_COLUMNS, LIGHT_COLUMNS};
use crate::output::manifest::Packing;
use crate::output::packs::{split_pair, PackUnit, Packs, PAIR_FILES, PAIR_RUNS};
use crate::output::poses::{parse_pixels, PIXELS_FILE, POSE_COLUMNS};
use crate::output::{hex, scenario_dir, CHECKSUMS, PARTIAL_PREFIX};
use crate::plan::ScenarioKey;
use crate::spec::{DatasetSpec, Split};
use rayon::prelude::*;
use serde::Serialize;
use sha2::{Digest, Sha256};
use std::collections::{BTreeMap, BTreeSet};
use std::fmt;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// One thing wrong, and where.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Problem {
    pub path: PathBuf,
    pub message: String,
}

/// The outcome of a validation.
#[derive(Debug, Clone, Serialize)]
pub struct ValidationReport {
    pub dir: PathBuf,
    pub scenarios_expected: usize,
    pub scenarios_checked: usize,
    pub files_checked: u64,
    pub bytes_read: u64,
    pub seconds: f64,
    pub problems: Vec<Problem>,
    /// What each split draws, when a split holds something out (`held_out`)
    /// or the towns are drawn per scenario: towns and graph shape, and what
    /// train and test share.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub design: Option<SplitDesign>,
}

/// The towns and graph shape of each split (train, val, test) and what
/// test shares with train.
#[derive(Debug, Clone, Serialize)]
pub struct SplitDesign {
    pub splits: Vec<SplitDraws>,
    /// Towns both train and test draw.
    pub shared_towns: Vec<String>,
    /// Whether train and test plan the same graph shape.
    pub shared_graph: bool,
    /// Whether train and test have the same cars per scenario in every group.
    pub shared_cars: bool,
    /// Whether train and test draw confounders from the same ranges (city world).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub shared_confounders: Option<bool>,
}

/// What one split draws.
#[derive(Debug, Clone, Serialize)]
pub struct SplitDraws {
    pub split: &'static str,
    pub towns: Vec<String>,
    /// `pairs`, `chains of 3`, `forks of 4`.
    pub graph: String,
    /// Cars per scenario in each group, in spec order.
    pub cars: Vec<u32>,
    /// The sections it holds out from train (`map`, `graph`, `cars`, `confounders`).
    pub held_out: Vec<&'static str>,
}

impl SplitDesign {
    /// The design of `expansion`'s dataset; `None` for a dataset of one
    /// town and one graph shape.
    pub fn of(expansion: &crate::plan::expand::Expansion) -> Option<SplitDesign> {
        let spec = &expansion.spec;
        if spec.held_out.is_empty() && expansion.all_town_names().len() < 2 {
            return None;
        }
        let graph = |split: Split| {
            let g = spec.graph_of(split);
            match g.shape {
                crate::spec::GraphShape::Pairs => "pairs".to_string(),
                shape => format!("{} of {}", shape.name(), g.unit_cars()),
            }
        };
        let splits: Vec<SplitDraws> = Split::ALL
            .into_iter()
            .map(|split| {
                let held_out = spec.held_out.of(split).map(|h| h.sections()).unwrap_or_default();
                SplitDraws {
                    split: split.name(),
                    towns: expansion.town_names(split).into_iter().map(String::from).collect(),
                    graph: graph(split),
                    cars: spec.groups_of(split).iter().map(|g| g.cars).collect(),
                    held_out,
                }
            })
            .collect();
        let shared_towns = splits[0].towns.iter().filter(|t| splits[2].towns.contains(t)).cloned().collect();
        let shared_graph = splits[0].graph == splits[2].graph;
        let shared_cars = splits[0].cars == splits[2].cars;
        let shared_confounders = (spec.world == crate::spec::WorldKind::City)
            .then(|| spec.confounders_of(Split::Train) == spec.confounders_of(Split::Test));
        Some(SplitDesign { splits, shared_towns, shared_graph, shared_cars, shared_confounders })
    }
}

impl fmt::Display for SplitDesign {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for s in &self.splits {
            let held =
                if s.held_out.is_empty() { String::new() } else { format!(" (held out: {})", s.held_out.join(", ")) };
            let cars: Vec<String> = s.cars.iter().map(u32::to_string).collect();
            writeln!(
                f,
                "{:<5} towns {}; graph {}; cars {}{held}",
                s.split,
                s.towns.join(" "),
                s.graph,
                cars.join(" ")
            )?;
        }
        let towns = if self.shared_towns.is_empty() { "no town".to_string() } else { self.shared_towns.join(" ") };
        let graph = if self.shared_graph { "the graph shape" } else { "no graph shape" };
        let cars = if self.shared_cars { "the car counts" } else { "not the car counts" };
        let confounders = match self.shared_confounders {
            Some(true) => "; the confounder ranges",
            Some(false) => "; not the confounder ranges",
            None => "",
        };
        writeln!(f, "train and test share: {towns}; {graph}; {cars}{confounders}")
    }
}

impl fmt::Display for ValidationReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for p in &self.problems {
            writeln!(f, "{}: {}", p.path.display(), p.message)?;
        }
        if let Some(design) = &self.design {
            write!(f, "{design}")?;
        }
        writeln!(
            f,
            "{}: {} of {} scenarios checked, {} files, {:.1} MB in {:.1} s: {}",
            self.dir.display(),
            self.scenarios_checked,
            self.scenarios_expected,
            self.files_checked,
            self.bytes_read as f64 / 1e6,
            self.seconds,
            match self.problems.len() {
                0 => "valid".to_string(),
                1 => "1 problem".to_string(),
                n => format!("{n} problems"),
            }
        )
    }
}

/// What every scenario of the dataset must look like.
struct Expected<'a> {
    spec: &'a DatasetSpec,
    layout: ScenarioLayout,
    /// Rows per frame of lights.csv (city world) of a dataset of one town.
    lights_per_frame: usize,
    /// Per split of [`Split::ALL`]: every town it draws, with its lights.csv
    /// rows per frame (a scenario of a many-town dataset names its town).
    towns: [Vec<(crate::spec::MapSpec, usize)>; 3],
}

impl<'a> Expected<'a> {
    fn new(spec: &'a DatasetSpec, layout: ScenarioLayout) -> Expected<'a> {
        let lights = |map: &crate::spec::MapSpec| map.city_map().map_or(0, |m| m.light_count());
        let towns =
            Split::ALL.map(|split| spec.map_of(split).towns().into_iter().map(|t| (t.clone(), lights(&t))).collect());
        Expected { spec, layout, lights_per_frame: lights(&spec.map), towns }
    }
}

/// Checks the dataset in `dir`. Errors only when `dir` is not a dataset.
pub fn validate(dir: &Path, threads: Option<usize>) -> Result<ValidationReport, String> {
    let start = Instant::now();
    if let Some(holder) = crate::output::claim::writer_at_work(dir) {
        return Err(format!(
            "{} is being written now ({holder}): validate it once that has finished (its half-written scenarios \
             are not damage)",
            dir.display()
        ));
    }
    let manifest_path = dir.join("manifest.json");
    if !manifest_path.exists() {
        if let Some((sweep, complete)) = crate::dataset::Sweep::open_even_unfinished(dir)? {
            return validate_sweep(&sweep, complete, threads, start);
        }
    }
    let dataset = Dataset::open(dir)?;
    // Validation keeps every car's fingerprint to find twins across
    // splits, so it holds one entry per scenario whatever it does.
    let keys: Vec<ScenarioKey> = dataset.keys().collect();
    let (record, keys) = (&dataset.record, &keys);
    let spec = dataset.spec();
    let expected = Expected::new(spec, ScenarioLayout::of_spec(spec, record.products()));

    let mut problems = derived_fields_edited(&manifest_path, &dataset);
    if !record.complete {
        problems.push(Problem {
            path: manifest_path.clone(),
            message: "the run that wrote this dataset did not finish: rerun its gen command to complete it".into(),
        });
    }
    let packs = match record.packing() {
        Packing::Folders => None,
        Packing::Tar { per_tar } => Some(Packs::new(dataset.key_sequence(), per_tar)),
    };
    problems.extend(unexpected_entries(dir, keys, spec, packs.as_ref()));

    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads.unwrap_or(0)).build().map_err(|e| e.to_string())?;
    let results: Vec<ScenarioCheck> = match &packs {
        None => pool.install(|| keys.par_iter().map(|key| check_scenario(dir, key, &expected)).collect()),
        Some(packs) => {
            let checked: Vec<Vec<ScenarioCheck>> = pool.install(|| {
                (0..packs.len())
                    .into_par_iter()
                    .map(|n| check_pack(dir, packs, n, PackUnit::Scenario, &expected, None))
                    .collect()
            });
            checked.into_iter().flatten().collect()
        }
    };
    let (mut files, mut bytes) = (0, 0);
    // A scenario is checked when it has files to check: a missing one
    // (an interrupted run's) is a problem, not a scenario checked.
    let checked = results.iter().filter(|r| r.1 > 0).count();
    let mut prints = Vec::with_capacity(keys.len());
    let mut named_links = BTreeSet::new();
    for (p, f, b, cars) in results {
        problems.extend(p.into_iter().filter(|p| once(&mut named_links, p)));
        files += f;
        bytes += b;
        prints.push(cars);
    }
    problems.extend(split_twins(dir, keys, &prints));
    Ok(ValidationReport {
        dir: dir.to_path_buf(),
        scenarios_expected: keys.len(),
        scenarios_checked: checked,
        files_checked: files,
        bytes_read: bytes,
        seconds: start.elapsed().as_secs_f64(),
        problems,
        design: SplitDesign::of(&dataset.expansion),
    })
}

/// Checks a `counterfactual --sweep` output: sweep.json finished, and every
/// pair there (in its folder, or in its pack) with its summary, its
/// divergence log and both runs checked as `gen`'s scenarios are (files,
/// columns, checksums).
fn validate_sweep(
    sweep: &crate::dataset::Sweep,
    complete: bool,
    threads: Option<usize>,
    start: Instant,
) -> Result<ValidationReport, String> {
    let dir = &sweep.dir;
    let spec = &sweep.expansion.spec;
    let mut problems = Vec::new();
    if !complete {
        problems.push(Problem {
            path: dir.join(crate::dataset::SWEEP_RECORD),
            message: "the sweep that wrote this folder did not finish: rerun its counterfactual --sweep command to \
                      complete it"
                .into(),
        });
    }
    let pair_of = |k: &ScenarioKey| scenario_dir(dir, &k.group, k.split.name(), &k.folder_name());
    let keys: Vec<ScenarioKey> = sweep.key_sequence().iter().collect();
    let packs = sweep.packs();
    // Images or not, as the runs were written (sweep.json does not say).
    let rgb = crate::output::layout::FrameKind::Rgb.folder();
    let images = match &packs {
        None => {
            keys.iter().map(|k| pair_of(k).join("factual")).find(|f| f.is_dir()).is_some_and(|f| f.join(rgb).is_dir())
        }
        Some(packs) => packed_pairs_have_images(dir, packs, rgb),
    };
    let products =
        crate::output::manifest::Products { images, annotations: false, effects: false, lights: sweep.lights };
    let expected = Expected::new(spec, ScenarioLayout::of_spec(spec, products));
    let check_pair = |key: &ScenarioKey| -> ScenarioCheck {
        let pair = pair_of(key);
        if !pair.is_dir() {
            let message = "missing counterfactual pair: rerun the counterfactual --sweep command to write it".into();
            return (vec![Problem { path: pair, message }], 0, 0, Vec::new());
        }
        let mut problems = Vec::new();
        // The pair folder's own entries (each run is checked below).
        let (mut found_files, mut found_folders) = (Vec::new(), Vec::new());
        for e in std::fs::read_dir(&pair).into_iter().flatten().flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            if e.path().is_dir() {
                found_folders.push(name)
            } else {
                found_files.push(name)
            }
        }
        for extra in found_files.iter().filter(|n| !PAIR_FILES.contains(&n.as_str())) {
            problems.push(Problem { path: pair.join(extra), message: "unexpected file".into() });
        }
        for extra in found_folders.iter().filter(|n| !matches!(n.as_str(), "factual" | "counterfactual")) {
            let message = if extra.starts_with(PARTIAL_PREFIX) {
                "left by an interrupted sweep: rerun its command (it redoes this pair)"
            } else {
                "unexpected folder"
            };
            problems.push(Problem { path: pair.join(extra), message: message.into() });
        }
        for name in PAIR_FILES {
            if !found_files.iter().any(|f| f == name) {
                problems.push(Problem { path: pair.join(name), message: "missing".into() });
            }
        }
        // (Never through a link, nor from a pipe.)
        match ScenarioFiles::Folder.read(&pair, "summary.json") {
            Ok(text) => {
                if let Err(e) = serde_json::from_slice::<crate::output::pair_summary::PairSummary>(&text) {
                    let message = format!("not a pair summary: {e}");
                    problems.push(Problem { path: pair.join("summary.json"), message });
                }
            }
            Err(e) if found_files.iter().any(|f| f == "summary.json") => {
                problems.push(Problem { path: pair.join("summary.json"), message: format!("unreadable: {e}") });
            }
            Err(_) => {} // missing, said above
        }
        let (mut files, mut bytes) = (0, 0);
        for run in ["factual", "counterfactual"] {
            let key = ScenarioKey { name: Some(format!("{}/{run}", key.folder_name())), ..key.clone() };
            let (p, f, b, _) = check_scenario(dir, &key, &expected);
            problems.extend(p);
            files += f;
            bytes += b;
        }
        // Whole files that read: then whether they are this pair's and agree,
        // as evaluate and the Python package hold them.
        if problems.is_empty() {
            if let Err(message) =
                crate::dataset::pairs::check_pair(&pair, (&key.group, key.split.name(), key.index.into()))
            {
                let shown = format!("{}/", pair.display());
                let message = message.strip_prefix(&shown).map(str::to_string).unwrap_or(message);
                problems.push(Problem { path: pair.clone(), message });
            } else if let Ok(text) = ScenarioFiles::Folder.read(&pair, "summary.json") {
                if let Err(message) = drawn_as_recorded(sweep, key, &text) {
                    problems.push(Problem { path: pair.join("summary.json"), message });
                }
            }
        }
        (problems, files, bytes, Vec::new())
    };
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads.unwrap_or(0)).build().map_err(|e| e.to_string())?;
    let results: Vec<ScenarioCheck> = match &packs {
        None => pool.install(|| keys.par_iter().map(check_pair).collect()),
        Some(packs) => pool
            .install(|| {
                (0..packs.len())
                    .into_par_iter()
                    .map(|n| check_pack(dir, packs, n, PackUnit::Pair, &expected, Some(sweep)))
                    .collect::<Vec<_>>()
            })
            .into_iter()
            .flatten()
            .collect(),
    };
    let (mut files, mut bytes) = (0, 0);
    let checked = results.iter().filter(|r| r.1 > 0).count();
    let mut named_links = BTreeSet::new();
    for (p, f, b, _) in results {
        problems.extend(p.into_iter().filter(|p| once(&mut named_links, p)));
        files += f;
        bytes += b;
    }
    Ok(ValidationReport {
        dir: dir.clone(),
        scenarios_expected: keys.len(),
        scenarios_checked: checked,
        files_checked: files,
        bytes_read: bytes,
        seconds: start.elapsed().as_secs_f64(),
        problems,
        design: None,
    })
}

/// [`crate::dataset::Sweep::check_drawn`] of pair `key`'s `summary.json` (`text`).
fn drawn_as_recorded(sweep: &crate::dataset::Sweep, key: &ScenarioKey, text: &[u8]) -> Result<(), String> {
    let summary: crate::output::pair_summary::PairSummary =
        serde_json::from_slice(text).map_err(|e| format!("not a pair summary: {e}"))?;
    sweep.check_drawn(key, &summary).map(|_| ()).map_err(|e| {
        format!("{e}. Rerun the counterfactual --sweep command (with sweep.json as it was written) to write it again")
    })
}

/// Whether the first pack of a packed sweep holds frames (false when it is
/// missing or unreadable: its check says so).
fn packed_pairs_have_images(dir: &Path, packs: &Packs<'_>, rgb: &str) -> bool {
    let Some(first) = (!packs.is_empty()).then(|| packs.path(dir, &packs.pack(0))) else { return false };
    let found = std::cell::Cell::new(false);
    let frames = format!("/factual/{rgb}/");
    let _ = crate::output::packs::read_members_where(
        &first,
        &|name| {
            found.set(found.get() || name.contains(&frames));
            false
        },
        |_, _| Ok(()),
    );
    found.get()
}

/// Leftovers of interrupted runs, and files and folders the manifest does
/// not know: at the root (beside manifest.json and the group folders), in a
/// group folder (beside its splits) and in a split folder.
fn unexpected_entries(dir: &Path, keys: &[ScenarioKey], spec: &DatasetSpec, packs: Option<&Packs<'_>>) -> Vec<Problem> {
    let known: BTreeSet<PathBuf> = match packs {
        None => keys.iter().map(|k| scenario_dir(dir, &k.group, k.split.name(), &k.folder_name())).collect(),
        Some(packs) => (0..packs.len()).map(|n| packs.path(dir, &packs.pack(n))).collect(),
    };
    let splits: BTreeSet<PathBuf> = known.iter().filter_map(|p| p.parent().map(Path::to_path_buf)).collect();
    let groups: BTreeSet<PathBuf> = spec.groups.iter().map(|g| dir.join(g.name())).collect();
    let mut problems = Vec::new();
    // The root: manifest.json, the group folders, an empty or shard-manifest
    // `shards/`, and the jobs' `logs/`.
    let mut allowed: BTreeSet<PathBuf> = groups.clone();
    allowed.insert(dir.join("manifest.json"));
    allowed.insert(dir.join("shards"));
    allowed.insert(dir.join(crate::output::layout::JOB_LOGS_DIR));
    let networks = spec.networks();
    let root_message = if networks.is_empty() {
        "not part of this dataset: the dataset root holds manifest.json, the group folders of its spec and logs/ only"
    } else {
        "not part of this dataset: the dataset root holds manifest.json, the group folders of its spec, networks/ and logs/ only"
    };
    let mut parents: Vec<(PathBuf, &str)> = vec![(dir.to_path_buf(), root_message)];
    // The SUMO networks the spec names, kept by file name (their bytes
    // were checked against the spec's map.sumo_sha256 when the dataset
    // was opened: its maps were read from them).
    if !networks.is_empty() {
        let folder = dir.join(crate::spec::NETWORKS_FOLDER);
        allowed.insert(folder.clone());
        allowed.extend(networks.iter().map(|(name, _)| folder.join(name)));
        parents.push((folder, "not part of this dataset: networks/ holds the SUMO networks its spec names only"));
    }
    for group in &groups {
        allowed.extend(Split::ALL.iter().map(|s| group.join(s.name())).filter(|p| splits.contains(p)));
        parents
            .push((group.clone(), "not part of this dataset: a group folder holds the split folders of its spec only"));
    }
    for (parent, message) in parents {
        let Ok(entries) = std::fs::read_dir(&parent) else { continue };
        for e in entries.flatten() {
            let lock = parent == dir && crate::output::claim::is_lock_file(&e.file_name().to_string_lossy());
            if !allowed.contains(&e.path()) && !lock {
                let removing = parent == dir && e.file_name() == crate::output::layout::REMOVING_DIR;
                let message = if removing {
                    "leftover of an interrupted gen --force (the old dataset moved aside to be deleted): rerun gen \
                     or merge to finish deleting it"
                } else {
                    message
                };
                problems.push(Problem { path: e.path(), message: message.into() });
            }
        }
    }
    // A whole dataset's manifest lists every scenario: a shard manifest
    // beside it was left by a shard run after the job was merged (merge
    // would take it for a job to finish).
    let shards = dir.join("shards");
    if std::fs::symlink_metadata(&shards).is_ok_and(|m| m.is_dir()) {
        for e in std::fs::read_dir(&shards).into_iter().flatten().flatten() {
            problems.push(Problem {
                path: e.path(),
                message: "a shard's manifest beside the whole dataset's (a shard run after its job was merged): \
                          remove it (a whole gen of the spec removes it)"
                    .into(),
            });
        }
    }
    for split in splits {
        let Ok(entries) = std::fs::read_dir(&split) else { continue };
        for e in entries.flatten() {
            let path = e.path();
            if known.contains(&path) {
                continue;
            }
            let name = e.file_name().to_string_lossy().into_owned();
            let message = if name.starts_with(PARTIAL_PREFIX) {
                "leftover of an interrupted scenario: rerun gen to finish it"
            } else if packs.is_some() && name.ends_with(".tar.partial") {
                "leftover of an interrupted pack: rerun gen to finish it"
            } else if packs.is_some() && name.bytes().all(|b| b.is_ascii_digit()) {
                "a scenario not packed yet: rerun gen to pack it"
            } else {
                "not part of this dataset (the manifest does not list it)"
            };
            problems.push(Problem { path, message: message.into() });
        }
    }
    problems
}

/// Checks the pack `number` of a packed dataset (`unit` scenarios) or
/// sweep (pairs): that it holds its folders whole and nothing else, then
/// each as a folder's, from its members read into memory a folder at a
/// time: a scenario as `gen`'s, a pair by its own files, a summary that
/// reads, and each run as a scenario. Problems name the pack, and the file
/// inside it.
fn check_pack(
    dir: &Path,
    packs: &Packs<'_>,
    number: usize,
    unit: PackUnit,
    expected: &Expected<'_>,
    sweep: Option<&crate::dataset::Sweep>,
) -> Vec<ScenarioCheck> {
    let pack = packs.pack(number);
    let keys = packs.keys(&pack);
    let path = packs.path(dir, &pack);
    let rerun = match unit {
        PackUnit::Scenario => "rerun gen",
        PackUnit::Pair => "rerun the counterfactual --sweep command",
    };
    let mut checks: Vec<ScenarioCheck> = keys.iter().map(|_| (Vec::new(), 0, 0, Vec::new())).collect();
    let problem = |message: String| {
        let prefix = format!("{}: ", path.display());
        let message = message.strip_prefix(&prefix).map(str::to_string).unwrap_or(message);
        Problem { path: path.clone(), message }
    };
    if !path.is_file() {
        checks[0].0.push(problem(format!("missing pack: {rerun} to write it")));
        return checks;
    }
    let folder_of = ScenarioKey::relative_folder;
    // A scenario's files (`members`, of the folder `folder` in the pack)
    // as `gen`'s, into `check`.
    let scenario =
        |check: &mut ScenarioCheck, folder: &Path, members: &BTreeMap<String, Vec<u8>>, key: &ScenarioKey| {
            let (found, files, bytes, prints) =
                check_scenario_files(folder, &ScenarioFiles::Members(members), key, expected);
            check.0.extend(found.into_iter().map(|p| problem(format!("{}: {}", p.path.display(), p.message))));
            check.1 += files;
            check.2 += bytes;
            check.3.extend(prints);
        };
    // One pass: the pack's membership, and each folder as it is read.
    let read = crate::output::packs::read_scenarios(&path, &keys, |i, members| {
        let folder = PathBuf::from(folder_of(&keys[i]));
        let check = &mut checks[i];
        match unit {
            PackUnit::Scenario => scenario(check, &folder, &members, &keys[i]),
            PackUnit::Pair => {
                let members = split_pair(members);
                for name in PAIR_FILES.iter().filter(|name| !members.pair.contains_key(**name)) {
                    check.0.push(problem(format!("{}: missing", folder.join(name).display())));
                }
                for extra in members.pair.keys().filter(|name| !PAIR_FILES.contains(&name.as_str())) {
                    check.0.push(problem(format!("{}: unexpected file", folder.join(extra).display())));
                }
                if let Some(text) = members.pair.get("summary.json") {
                    if let Err(e) = serde_json::from_slice::<crate::output::pair_summary::PairSummary>(text) {
                        let summary = folder.join("summary.json");
                        check.0.push(problem(format!("{}: not a pair summary: {e}", summary.display())));
                    }
                }
                for (run, run_members) in PAIR_RUNS.into_iter().zip(&members.runs) {
                    let key = ScenarioKey { name: Some(format!("{}/{run}", keys[i].folder_name())), ..keys[i].clone() };
                    scenario(check, &folder.join(run), run_members, &key);
                }
                // Whole files that read: then whether they are this pair's
                // and agree, as for a pair folder.
                if check.0.is_empty() {
                    let key = (keys[i].group.as_str(), keys[i].split.name(), keys[i].index.into());
                    if let Err(message) = crate::dataset::pairs::check_packed_pair(&members, &folder, key) {
                        check.0.push(problem(message));
                    } else if let (Some(sweep), Some(text)) = (sweep, members.pair.get("summary.json")) {
                        if let Err(message) = drawn_as_recorded(sweep, &keys[i], text) {
                            check.0.push(problem(format!("{}: {message}", folder.join("summary.json").display())));
                        }
                    }
                }
                // A pair's runs are not a dataset's scenarios: no twins are sought.
                check.3.clear();
            }
        }
        Ok(())
    });
    match read {
        Ok(read) => {
            for (i, _) in read.found.iter().enumerate().filter(|(_, f)| !**f) {
                let message = format!("{} is not in it: {rerun} to write the pack again", folder_of(&keys[i]));
                checks[i].0.push(problem(message));
            }
            // Readers pass over folder entries, but `tar -xf` makes an empty
            // one a folder the layout does not have: named under its
            // scenario where it lies in one.
            for folder in read.empty_folders {
                let owner = keys.iter().position(|k| {
                    let own = folder_of(k);
                    folder == own || folder.strip_prefix(&own).is_some_and(|rest| rest.starts_with('/'))
                });
                let message = format!(
                    "{folder}/: a folder with no file in the pack; unpacked (tar -xf) it is an empty folder that \
                     the folder layout does not have: {rerun} to write the pack again"
                );
                checks[owner.unwrap_or(0)].0.push(problem(message));
            }
        }
        Err(why) => checks[0].0.push(problem(why)),
    }
    checks
}

/// The manifest's fields that gen derives from its spec (scenario and
/// frame counts, each group's cars and split sizes) that no longer agree
/// with it: edited by hand, they mislead readers of the manifest alone
/// (the spec's own edits are refused by its `spec_sha256`).
fn derived_fields_edited(path: &Path, dataset: &Dataset) -> Vec<Problem> {
    let record = &dataset.record;
    let manifest = crate::output::manifest::Manifest::new(
        dataset.spec(),
        &dataset.expansion.camera,
        record.limit,
        record.products(),
        record.packing(),
        record.complete,
        None,
    );
    let derived = serde_json::to_value(&manifest).expect("a manifest serialises");
    let written = [
        ("scenarios", &record.scenarios),
        ("frames_per_scenario", &record.frames_per_scenario),
        ("frame_file_digits", &record.frame_file_digits),
    ];
    let mut fields: Vec<String> = written
        .into_iter()
        .filter(|(field, value)| **value != derived[field])
        .map(|(field, value)| format!("`{field}` is {value} here, {} by its spec", derived[field]))
        .collect();
    let written_groups: Vec<serde_json::Value> =
        record.groups.iter().map(|g| serde_json::json!([g.name, g.cars, g.splits])).collect();
    let derived_groups: Vec<serde_json::Value> = derived["groups"]
        .as_array()
        .into_iter()
        .flatten()
        .map(|g| serde_json::json!([g["name"], g["cars"], g["splits"]]))
        .collect();
    if written_groups != derived_groups {
        fields.push("`groups` (names, cars or split sizes) differ from its spec's".to_string());
    }
    fields
        .into_iter()
        .map(|field| Problem {
            path: path.to_path_buf(),
            message: format!("{field}: edited after gen wrote it; restore it (or regenerate)"),
        })
        .collect()
}

/// How validate names a linked group, split or scenario folder.
const LINKED_FOLDER: &str = "a symbolic link: a dataset holds its own folders";

/// False for a linked folder `named` holds already: each of its scenarios
/// finds a linked group or split folder, which is named once.
fn once(named: &mut BTreeSet<PathBuf>, problem: &Problem) -> bool {
    !problem.message.starts_with(LINKED_FOLDER) || named.insert(problem.path.clone())
}

/// Checks one scenario; returns its problems, files and bytes read.
/// One scenario's findings: problems, files and bytes read, and each car's
/// trajectory fingerprint (from poses.csv).
type ScenarioCheck = (Vec<Problem>, u64, u64, Vec<Fingerprint>);

/// SHA-256 (first 16 bytes) of a car's logged x, y at every frame: equal
/// for two cars exactly when their trajectories are identical as logged.
type Fingerprint = [u8; 16];

/// Where a scenario's files are read from.
enum ScenarioFiles<'a> {
    /// Its folder (the `dir` checks are given).
    Folder,
    /// A pack's members, by name within the scenario, held in memory.
    Members(&'a BTreeMap<String, Vec<u8>>),
}

impl ScenarioFiles<'_> {
    fn read(&self, dir: &Path, name: &str) -> std::io::Result<Vec<u8>> {
        match self {
            // Never through a link (named as one), nor from a pipe or a device.
            ScenarioFiles::Folder => match std::fs::symlink_metadata(dir.join(name)) {
                Ok(m) if m.is_symlink() => {
                    Err(std::io::Error::new(std::io::ErrorKind::InvalidInput, "a symbolic link, not followed"))
                }
                _ => crate::input::read_data(&dir.join(name)),
            },
            ScenarioFiles::Members(members) => members
                .get(name)
                .cloned()
                .ok_or_else(|| std::io::Error::new(std::io::ErrorKind::NotFound, "not in the pack")),
        }
    }

    /// Every file, folder and link there, relative to the scenario.
    fn entries(&self, dir: &Path) -> Entries {
        match self {
            ScenarioFiles::Folder => list_entries(dir),
            ScenarioFiles::Members(members) => {
                let folders: BTreeSet<String> = members
                    .keys()
                    .flat_map(|name| name.match_indices('/').map(|(i, _)| name[..i].to_string()).collect::<Vec<_>>())
                    .collect();
                Entries {
                    files: members.keys().cloned().collect(),
                    folders: folders.into_iter().collect(),
                    links: Vec::new(),
                }
            }
        }
    }
}

fn check_scenario(root: &Path, key: &ScenarioKey, expected: &Expected<'_>) -> ScenarioCheck {
    let dir = scenario_dir(root, &key.group, key.split.name(), &key.folder_name());
    // A dataset holds its own folders: a linked one is not checked through
    // (gen refuses to write through it).
    // (Every folder from the root down: group, split, a sweep's pair, the
    // scenario or run.)
    if let Some(folder) = crate::output::linked_below(root, &dir) {
        let message = format!(
            "{LINKED_FOLDER}, never links (replace it with the folder it points to, or rerun gen into a new folder)"
        );
        return (vec![Problem { path: folder, message }], 0, 0, Vec::new());
    }
    if !dir.is_dir() {
        let message = "missing scenario folder: rerun gen to write it".to_string();
        return (vec![Problem { path: dir, message }], 0, 0, Vec::new());
    }
    check_scenario_files(&dir, &ScenarioFiles::Folder, key, expected)
}

/// Checks one scenario whose files `files` gives; problems name them
/// under `dir`.
fn check_scenario_files(
    dir: &Path,
    files: &ScenarioFiles<'_>,
    key: &ScenarioKey,
    expected: &Expected<'_>,
) -> ScenarioCheck {
    let dir = dir.to_path_buf();
    let mut problems = Vec::new();
    let mut problem = |path: &Path, message: String| problems.push(Problem { path: path.to_path_buf(), message });
    let spec = expected.spec;
    let layout = &expected.layout;
    let frames = spec.frames as usize;
    let city = layout.city;

    // The files and folders there should be.
    let names = layout.files();
    let wanted: BTreeSet<&str> = names.iter().map(String::as_str).collect();
    let folders = layout.folders();
    let wanted_folders: BTreeSet<&str> = folders.iter().map(String::as_str).collect();
    let found = files.entries(&dir);
    for extra in found.files.iter().filter(|n| !wanted.contains(n.as_str())) {
        problem(&dir.join(extra), "unexpected file".into());
    }
    for extra in found.folders.iter().filter(|n| !wanted_folders.contains(n.as_str())) {
        problem(&dir.join(extra), "unexpected folder".into());
    }
    for link in &found.links {
        problem(
            &dir.join(link),
            "a symbolic link: a dataset holds its own files, never links (rerun gen, which writes the scenario again)"
                .into(),
        );
    }

    // The checksum listing.
    let text = files.read(&dir, CHECKSUMS).and_then(|bytes| {
        String::from_utf8(bytes).map_err(|_| std::io::Error::new(std::io::ErrorKind::InvalidData, "not text"))
    });
    let listing: BTreeMap<String, String> = match text {
        Ok(text) => {
            text.lines().filter_map(|l| l.split_once("  ").map(|(h, n)| (n.to_string(), h.to_string()))).collect()
        }
        Err(e) => {
            problem(&dir.join(CHECKSUMS), format!("cannot read: {e}"));
            BTreeMap::new()
        }
    };

    let source = files;
    let (mut files, mut bytes) = (0u64, 0u64);
    let mut read = |name: &str, problems: &mut Vec<Problem>| -> Option<Vec<u8>> {
        let path = dir.join(name);
        let data = match source.read(&dir, name) {
            Ok(d) => d,
            Err(e) => {
                problems.push(Problem { path, message: format!("missing or unreadable: {e}") });
                return None;
            }
        };
        files += 1;
        bytes += data.len() as u64;
        match listing.get(name) {
            Some(h) if *h == hex(&Sha256::digest(&data)) => {}
            Some(_) => problems.push(Problem {
                path: path.clone(),
                message: "checksum mismatch: the file changed after it was written".into(),
            }),
            None => problems.push(Problem { path: path.clone(), message: format!("not listed in {CHECKSUMS}") }),
        }
        Some(data)
    };

    // scenario.json: identity, frames and cars.
    let mut mask_ids: BTreeSet<u8> = BTreeSet::new();
    let mut cars = 0usize;
    let mut record = serde_json::Value::Null;
    let mut lights_per_frame = expected.lights_per_frame;
    if let Some(data) = read(SCENARIO_JSON, &mut problems) {
        let path = dir.join(SCENARIO_JSON);
        match serde_json::from_slice::<serde_json::Value>(&data) {
            Ok(v) => {
                record = v.clone();
                let checks = [
                    (v["format"] == crate::output::scenario::SCENARIO_FORMAT, "format"),
                    (v["group"] == key.group.as_str(), "group"),
                    (v["split"] == key.split.name(), "split"),
                    (v["index"] == key.index, "index"),
                    (v["seed"] == spec.seed, "seed"),
                    (v["frames"] == spec.frames, "frames"),
                    (v["world"] == spec.world.name(), "world"),
                ];
                for (ok, field) in checks {
                    if !ok {
                        problems
                            .push(Problem { path: path.clone(), message: format!("`{field}` is {} here", v[field]) });
                    }
                }
                // A dataset of several towns: the scenario's is one the spec draws.
                if let Some(town) = v.get("map") {
                    let parsed = serde_json::from_value::<crate::spec::MapSpec>(town.clone()).ok();
                    let known = parsed.and_then(|t| expected.towns[key.split.index()].iter().find(|(k, _)| *k == t));
                    match known {
                        Some((_, lights)) => lights_per_frame = *lights,
                        None => problems.push(Problem {
                            path: path.clone(),
                            message: format!("`map` {town} is not a town the spec draws for {}", key.split.name()),
                        }),
                    }
                }
                let list = v["cars"].as_array().cloned().unwrap_or_default();
                cars = list.len();
                for (i, car) in list.iter().enumerate() {
                    if car["id"] != i || car["mask_id"] != i + 1 {
                        problems.push(Problem {
                            path: path.clone(),
                            message: format!("car {i} has id {} and mask_id {}", car["id"], car["mask_id"]),
                        });
                    }
                    mask_ids.insert((i + 1) as u8);
                }
                let group = spec.groups.iter().find(|g| g.name() == key.group);
                if let Some(g) = group.map(|g| spec.group_of(key.split, g)) {
                    if cars != g.cars as usize {
                        problems.push(Problem {
                            path: path.clone(),
                            message: format!("{cars} cars, the spec asks for {} in {}", g.cars, key.split.name()),
                        });
                    }
                }
            }
            Err(e) => problems.push(Problem { path, message: format!("not valid JSON: {e}") }),
        }
    }

    // CSV logs: columns, row counts, ids.
    let mut fingerprints_here = Vec::new();
    if let Some(data) = read(POSES_CSV, &mut problems) {
        fingerprints_here = fingerprints(&data, frames, cars);
        let before = problems.len();
        check_csv(&dir.join(POSES_CSV), &data, &POSE_COLUMNS, frames * cars, &mut problems, |row, i| {
            let (frame, car) = (row.get(0)?.parse::<usize>().ok()?, row.get(2)?.parse::<usize>().ok()?);
            let ok = cars > 0 && frame == i / cars && car == i % cars;
            ok.then_some(()).ok_or(()).ok()
        });
        // In order and complete: then every value as the readers take it.
        if problems.len() == before {
            let path = dir.join(POSES_CSV);
            if let Err(message) = crate::dataset::poses::read_pose_rows(&data[..], &path, frames, cars, |_| {}) {
                problems.push(Problem { message: without_path(message, &path), path });
            }
        }
        if let Some(pixels) = read(PIXELS_FILE, &mut problems) {
            if let Err(message) = check_pixels(&dir, &pixels, &data, frames, cars) {
                let path = dir.join(PIXELS_FILE);
                problems.push(Problem { message: without_path(message, &path), path });
            }
        }
    }
    // The light log's lights, where it could be read: the events' and
    // interactions' lights are among them.
    let mut light_names: Option<Vec<String>> = None;
    if city && expected.layout.lights == crate::output::manifest::LightsLog::Changes {
        // Every light at frame 0, then changes in order (as the Python
        // package reads it).
        if let Some(data) = read(LIGHT_CHANGES_CSV, &mut problems) {
            let path = dir.join(LIGHT_CHANGES_CSV);
            let reader = csv::Reader::from_reader(&data[..]);
            match crate::dataset::readback::parse_light_changes(reader, &path, frames, spec.frame_interval()) {
                Ok(read) if read.names.len() == lights_per_frame => light_names = Some(read.names),
                Ok(read) => problems.push(Problem {
                    path,
                    message: format!("{} lights at frame 0, expected {lights_per_frame}", read.names.len()),
                }),
                Err(message) => problems.push(Problem { message: without_path(message, &path), path }),
            }
        }
    } else if city {
        if let Some(data) = read(LIGHTS_CSV, &mut problems) {
            // Every light of every intersection, every frame.
            let lights = lights_per_frame;
            let path = dir.join(LIGHTS_CSV);
            let before = problems.len();
            check_csv(&path, &data, &LIGHT_COLUMNS, frames * lights, &mut problems, |row, i| {
                (row.get(0)?.parse::<usize>().ok()? == i / lights).then_some(())
            });
            // In order: then every value as the readers take it.
            if problems.len() == before {
                match crate::dataset::readback::parse_lights(csv::Reader::from_reader(&data[..]), &path, frames) {
                    Ok(read) => light_names = Some(read.names),
                    Err(message) => problems.push(Problem { message: without_path(message, &path), path }),
                }
            }
        }
    }
    if city {
        if let Some(data) = read(EVENTS_CSV, &mut problems) {
            let path = dir.join(EVENTS_CSV);
            let mut reader = csv::Reader::from_reader(&data[..]);
            let header_ok = reader.headers().map(|h| h.iter().eq(EVENT_COLUMNS.iter().copied())).unwrap_or(false);
            if !header_ok {
                problems.push(Problem {
                    path: path.clone(),
                    message: format!("columns should be {}", EVENT_COLUMNS.join(",")),
                });
            }
            // `car` names a car of the scenario, or is empty for an
            // intervention on no car (a light, the weather).
            let before = problems.len();
            for (i, row) in reader.records().enumerate() {
                let ok = row.as_ref().ok().is_some_and(|r| match r.get(3) {
                    Some("") => r.get(2) == Some("intervention"),
                    Some(c) => c.parse::<usize>().is_ok_and(|c| c < cars),
                    None => false,
                });
                if !ok {
                    problems.push(Problem {
                        path: path.clone(),
                        message: format!("row {} names no car of this scenario", i + 2),
                    });
                    break;
                }
            }
            // Then every value as the readers take it.
            if problems.len() == before {
                let reader = csv::Reader::from_reader(&data[..]);
                let names = light_names.as_deref();
                if let Err(message) = crate::dataset::readback::parse_events(reader, &path, frames, cars, names) {
                    problems.push(Problem { message: without_path(message, &path), path });
                }
            }
        }
    }

    if city {
        if let Some(data) = read(INTERACTIONS_CSV, &mut problems) {
            // One row per car and frame: frame by frame, cars in id order.
            let path = dir.join(INTERACTIONS_CSV);
            let before = problems.len();
            check_csv(&path, &data, &INTERACTION_COLUMNS, frames * cars, &mut problems, |row, i| {
                let (frame, car) = (row.get(0)?.parse::<usize>().ok()?, row.get(1)?.parse::<usize>().ok()?);
                (cars > 0 && frame == i / cars && car == i % cars).then_some(())
            });
            // In order: then every value as the readers take it.
            if problems.len() == before {
                let reader = csv::Reader::from_reader(&data[..]);
                let names = light_names.as_deref();
                let read = crate::dataset::readback::parse_interaction_arrays(reader, &path, frames, cars, names);
                if let Err(message) = read {
                    problems.push(Problem { message: without_path(message, &path), path });
                }
            }
        }
    }

    if layout.effects {
        if let Some(data) = read(EFFECTS_CSV, &mut problems) {
            if let Err(message) = check_effects(&dir, &data, &record, cars, frames) {
                problems.push(Problem { path: dir.join(EFFECTS_CSV), message });
            }
        }
    }

    if layout.annotations {
        let name = crate::output::annotations::ANNOTATIONS_FILE;
        if let Some(data) = read(name, &mut problems) {
            let frames_listed = serde_json::from_slice::<serde_json::Value>(&data)
                .ok()
                .and_then(|v| v["frames"].as_array().map(Vec::len));
            if frames_listed != Some(frames) {
                problems.push(Problem {
                    path: dir.join(name),
                    message: format!("expected NS-DR annotations of {frames} frames"),
                });
            }
        }
    }

    // Frames: RGB by header (their bytes are covered by the checksums), masks
    // decoded so that every id is checked.
    if layout.images {
        let (w, h) = (spec.image.width, spec.image.height);
        for f in 0..frames {
            let rgb = layout.frame_name(FrameKind::Rgb, f as u32);
            if let Some(data) = read(&rgb, &mut problems) {
                match png_header(&data) {
                    Some((pw, ph, 8, 2)) if (pw, ph) == (w, h) => {}
                    Some((pw, ph, depth, colour)) => problems.push(Problem {
                        path: dir.join(&rgb),
                        message: format!("{pw}x{ph}, depth {depth}, colour type {colour}; expected {w}x{h} 8-bit RGB"),
                    }),
                    None => problems.push(Problem { path: dir.join(&rgb), message: "not a PNG".into() }),
                }
            }
            let mask = layout.frame_name(FrameKind::Mask, f as u32);
            if let Some(data) = read(&mask, &mut problems) {
                if let Err(message) = check_mask(&data, w, h, &mask_ids) {
                    problems.push(Problem { path: dir.join(&mask), message });
                }
            }
        }
        // Extra cameras: present and as written (checksums).
        for name in names.iter().filter(|n| n.starts_with(crate::output::layout::CAMERAS)) {
            read(name, &mut problems);
        }
    }
    (problems, files, bytes, fingerprints_here)
}

/// Each car's [`Fingerprint`] from poses.csv (rows by frame, then car; `x`
/// and `y` are its fourth and fifth columns); empty unless it holds exactly
/// `frames` x `cars` rows (the row check reports that).
fn fingerprints(poses_csv: &[u8], frames: usize, cars: usize) -> Vec<Fingerprint> {
    if cars == 0 {
        return Vec::new();
    }
    let mut hashers = vec![Sha256::new(); cars];
    let mut reader = csv::Reader::from_reader(poses_csv);
    let mut rows = 0;
    for row in reader.records() {
        let Ok(row) = row else { return Vec::new() };
        let (Some(x), Some(y)) = (row.get(3), row.get(4)) else { return Vec::new() };
        let h = &mut hashers[rows % cars];
        h.update(x.as_bytes());
        h.update(b",");
        h.update(y.as_bytes());
        h.update(b";");
        rows += 1;
    }
    if rows != frames * cars {
        return Vec::new();
    }
    hashers.into_iter().map(|h| h.finalize()[..16].try_into().expect("16 of 32 bytes")).collect()
}

/// Cars whose trajectory has an identical twin in another split (the splits
/// must not overlap): one problem per car, naming the twin it meets first
/// in the dataset's order (train before val before test within a group).
fn split_twins(root: &Path, keys: &[ScenarioKey], prints: &[Vec<Fingerprint>]) -> Vec<Problem> {
    let folder = ScenarioKey::relative_folder;
    // Every split's first car with each fingerprint.
    let mut first: std::collections::HashMap<(Fingerprint, Split), (usize, usize)> = std::collections::HashMap::new();
    for (k, (key, cars)) in keys.iter().zip(prints).enumerate() {
        for (car, print) in cars.iter().enumerate() {
            first.entry((*print, key.split)).or_insert((k, car));
        }
    }
    let mut problems = Vec::new();
    for (key, cars) in keys.iter().zip(prints) {
        for (car, print) in cars.iter().enumerate() {
            // Each pair of splits once: a car is reported against the splits before its own.
            let earlier = Split::ALL.iter().take_while(|&&s| s != key.split);
            if let Some(&(k, twin)) = earlier.filter_map(|&s| first.get(&(*print, s))).next() {
                problems.push(Problem {
                    path: scenario_dir(root, &key.group, key.split.name(), &key.folder_name()).join(POSES_CSV),
                    message: format!(
                        "car {car}'s trajectory is identical to car {twin}'s in {}: the splits overlap",
                        folder(&keys[k])
                    ),
                });
            }
        }
    }
    problems
}

/// effects.csv parses (every field checked) and agrees with scenario.json
/// ([`crate::dataset::effects::check_effects`]).
fn check_effects(
    dir: &Path,
    data: &[u8],
    record: &serde_json::Value,
    cars: usize,
    frames: usize,
) -> Result<(), String> {
    let json = dir.join(SCENARIO_JSON);
    let threshold = record["effect_threshold_m"]
        .as_f64()
        .ok_or_else(|| format!("{} has no effect_threshold_m to check effects.csv against", json.display()))?;
    let rows = parse_effects(&dir.join(EFFECTS_CSV), data, cars, frames, threshold)?;
    crate::dataset::effects::check_effects(rows, record, &json, cars, threshold).map(|_| ())
}

/// A reader's `message` without the `path: ` it begins with (a problem is
/// printed after its path).
fn without_path(message: String, path: &Path) -> String {
    let shown = path.display().to_string();
    match (message.strip_prefix(&format!("{shown}: ")), message.strip_prefix(&format!("{shown} "))) {
        (Some(rest), _) => rest.to_string(),
        (None, Some(rest)) if rest.starts_with("line ") => rest.to_string(), // "<path> line 6: ..."
        _ => message,
    }
}

/// pixels.npy holds poses.csv's px, py as float32, frame by frame.
fn check_pixels(dir: &Path, pixels: &[u8], poses_csv: &[u8], frames: usize, cars: usize) -> Result<(), String> {
    let pixels = parse_pixels(pixels, &dir.join(PIXELS_FILE), frames, cars)?;
    let mut reader = csv::Reader::from_reader(poses_csv);
    for (i, row) in reader.records().enumerate() {
        let logged = row.ok().and_then(|r| Some([r.get(9)?.parse::<f64>().ok()?, r.get(10)?.parse::<f64>().ok()?]));
        match (logged, pixels.get(2 * i..2 * i + 2)) {
            (Some([px, py]), Some(&[x, y])) if px as f32 == x && py as f32 == y => {}
            _ => return Err(format!("differs from poses.csv's px, py at row {}", i + 2)),
        }
    }
    Ok(())
}

fn check_csv(
    path: &Path,
    data: &[u8],
    columns: &[&str],
    rows: usize,
    problems: &mut Vec<Problem>,
    row_ok: impl Fn(&csv::StringRecord, usize) -> Option<()>,
) {
    let mut reader = csv::Reader::from_reader(data);
    let header_ok = reader.headers().map(|h| h.iter().eq(columns.iter().copied())).unwrap_or(false);
    if !header_ok {
        problems
            .push(Problem { path: path.to_path_buf(), message: format!("columns should be {}", columns.join(",")) });
        return;
    }
    let mut n = 0;
    for (i, row) in reader.records().enumerate() {
        let good = row.as_ref().ok().and_then(|r| (r.len() == columns.len()).then_some(r)).and_then(|r| row_ok(r, i));
        if good.is_none() {
            problems.push(Problem {
                path: path.to_path_buf(),
                message: format!("row {} is malformed or out of order", i + 2),
            });
            return;
        }
        n += 1;
    }
    if n != rows {
        problems.push(Problem { path: path.to_path_buf(), message: format!("{n} rows, expected {rows}") });
    }
}

/// (width, height, bit depth, colour type) from a PNG's IHDR.
fn png_header(data: &[u8]) -> Option<(u32, u32, u8, u8)> {
    if data.len() < 29 || &data[..8] != b"\x89PNG\r\n\x1a\n" || &data[12..16] != b"IHDR" {
        return None;
    }
    let w = u32::from_be_bytes(data[16..20].try_into().ok()?);
    let h = u32::from_be_bytes(data[20..24].try_into().ok()?);
    Some((w, h, data[24], data[25]))
}

fn check_mask(data: &[u8], w: u32, h: u32, ids: &BTreeSet<u8>) -> Result<(), String> {
    let buf = crate::output::png::decode_gray8(data, w, h)?;
    let mut seen = [false; 256];
    for &v in &buf {
        seen[v as usize] = true;
    }
    let stray: Vec<u8> = (1..=255u8).filter(|&v| seen[v as usize] && !ids.contains(&v)).collect();
    if !stray.is_empty() {
        return Err(format!("ids {stray:?} belong to no car of scenario.json"));
    }
    Ok(())
}

/// Relative paths of every file, folder and symbolic link under `dir`.
fn list_entries(dir: &Path) -> Entries {
    let mut found = Entries::default();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&d) else { continue };
        for e in entries.flatten() {
            let path = e.path();
            let Ok(rel) = path.strip_prefix(dir) else { continue };
            let rel = rel.to_string_lossy().into_owned();
            // A link is never followed: not into a folder, not to a file.
            match e.file_type() {
                Ok(kind) if kind.is_symlink() => found.links.push(rel),
                Ok(kind) if kind.is_dir() => {
                    stack.push(path);
                    found.folders.push(rel);
                }
                _ => found.files.push(rel),
            }
        }
    }
    found
}

/// What a scenario folder holds, each path relative to it.
#[derive(Default)]
struct Entries {
    files: Vec<String>,
    folders: Vec<String>,
    /// Symbolic links (to files or folders), never followed.
    links: Vec<String>,
}
