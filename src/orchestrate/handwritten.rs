//! `causalcity run` and `causalcity counterfactual`: hand-written scenario
//! files simulated and written as scenario folders (the same files as `gen`
//! writes), and factual / counterfactual pairs with the ground-truth effect
//! of an intervention.
//!
//! A counterfactual pair shares the plan, the initial state and every random
//! stream (each car draws from its own), so everything before the
//! intervention fires is byte-identical and afterwards only what the
//! intervention causes differs. `divergence.csv` gives, per frame and car,
//! the distance between a car's factual and counterfactual positions;
//! `summary.json` lists the cars it moved at all (the effect set).

use super::run::{
    keep_networks, load_spec, refuse_linked_splits, remove_packed, scenario_writer, stop_flag, write_simulated,
    GenError, TownWriters,
};
use super::scenario_file::{load, load_interventions, FileOptions, LoadedScenario, ScenarioFileError};
use crate::dataset::SWEEP_RECORD;
use crate::map::CityMap;
use crate::output::claim::{claim, Writer};
use crate::output::manifest::{LightsLog, Packing, Products};
use crate::output::number::push_fixed;
use crate::output::packs::{PackUnit, PackWriter, Packs};
use crate::output::poses::logged_pose;
use crate::output::writer::ScenarioWriter;
use crate::output::{scenario_dir, write_atomically, WriteError};
use crate::plan::interventions::{Intervention, SweepDraw};
use crate::plan::ScenarioPlan;
use crate::plan::{Expansion, ScenarioKey};
use crate::progress::{Progress, ProgressMode};
use crate::spec::WorldKind;
use crate::timing::StageTimes;
use crate::world::{EventKind, Trajectories};
use rayon::prelude::*;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;

/// Why `run` or `counterfactual` failed.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error("{0}")]
    Input(ScenarioFileError),
    #[error("{0}")]
    Usage(String),
    #[error(transparent)]
    Write(#[from] GenError),
    /// Stopped (Ctrl-C) with `done` of the file's `total` scenarios
    /// written in `out`. `run` and `counterfactual --scenario` write every
    /// scenario again when rerun, so the message says so (gen's says
    /// "resume").
    #[error(
        "interrupted: {done} of {total} scenarios are written in {out}; rerun the same command to write them \
         all (it writes every scenario again)"
    )]
    Interrupted { done: u64, total: u64, out: PathBuf },
}

impl From<RunError> for crate::error::Error {
    fn from(e: RunError) -> Self {
        match e {
            RunError::Write(e) => e.into(),
            RunError::Interrupted { .. } => crate::error::Error::Interrupted(e.to_string()),
            RunError::Input(_) | RunError::Usage(_) => crate::error::Error::Input(e.to_string()),
        }
    }
}

impl RunError {
    /// 2 for bad input, otherwise as `gen`.
    pub fn exit_code(&self) -> i32 {
        match self {
            RunError::Input(_) | RunError::Usage(_) => 2,
            RunError::Interrupted { .. } => 130,
            RunError::Write(e) => e.exit_code(),
        }
    }
}

/// What `run` / `counterfactual` were asked to do.
#[derive(Debug, Clone)]
pub struct RunOptions {
    pub scenario_file: PathBuf,
    /// Default: `data/<file stem>`.
    pub out: Option<PathBuf>,
    pub world: Option<WorldKind>,
    pub images: bool,
    pub annotations: bool,
    /// City world: lights.csv or light_changes.csv.
    pub lights: LightsLog,
    /// Reject what would need adapting (see [`FileOptions::strict`]).
    pub strict: bool,
}

impl RunOptions {
    /// `--out`, or `data/<file stem>` when the stem can name a folder
    /// (never `..` or an absolute path), else `data/scenarios`.
    pub fn out(&self) -> PathBuf {
        self.out.clone().unwrap_or_else(|| {
            let stem = self.scenario_file.file_stem().map(|s| s.to_string_lossy().into_owned());
            let stem = stem.filter(|s| crate::spec::valid_folder_name(s));
            Path::new("data").join(stem.unwrap_or_else(|| "scenarios".into()))
        })
    }

    fn products(&self) -> Products {
        // Effects are a dataset's (gen's) ground truth.
        Products {
            images: self.images,
            annotations: self.annotations && self.images,
            effects: false,
            lights: self.lights,
        }
    }
}

/// One written scenario folder.
#[derive(Debug, Clone, Serialize)]
pub struct Written {
    pub scenario: String,
    pub path: PathBuf,
    pub bytes: u64,
    /// What was read leniently or adapted while planning and driving, one
    /// sentence each naming the scenario, car and field (events.csv has the
    /// adaptations too).
    pub warnings: Vec<String>,
}

/// The warnings of scenario `s`: what reading adapted (and cameras that
/// `--no-images` leaves without pictures), then every action the
/// simulation adapted or skipped, in time order.
fn warnings(s: &LoadedScenario, trajectories: &Trajectories, images: bool) -> Vec<String> {
    let read = s.warnings.iter().map(|w| format!("scenario {:?}, {w}", s.name));
    let mut warnings: Vec<String> =
        read.chain(camera_warning(s, images)).chain(driven_warnings(&s.name, &s.plan, trajectories, "")).collect();
    // Each of its interventions that never fired, or fired at the last
    // frame, as a counterfactual pair tells its added ones (`run` said
    // nothing, though the docs say it warns of the last frame).
    let firings = |label: &str| firings_of(trajectories, label);
    warnings.extend(intervention_warnings(&s.name, &s.plan, &s.plan.interventions, firings, "it changed nothing"));
    warnings
}

/// When the interventions labelled `label` fired in a run, in time order
/// (each fires once).
fn firings_of(run: &Trajectories, label: &str) -> Vec<f64> {
    run.events.iter().filter(|e| e.kind == EventKind::Intervention && e.detail == label).map(|e| e.t).collect()
}

/// A warning for each of `interventions` (of `plan`) that never fired in
/// the run, saying `never_means`, and each that fired at the scenario's last
/// frame, which no frame after it shows. `firings` tells when the ones of a
/// label fired: interventions that share a label are told by how many of
/// them fired (one that fired stood for all of them: review).
fn intervention_warnings(
    scenario: &str,
    plan: &ScenarioPlan,
    interventions: &[crate::plan::interventions::Intervention],
    firings: impl Fn(&str) -> Vec<f64>,
    never_means: &str,
) -> Vec<String> {
    let end = plan.frames.saturating_sub(1) as f64 * plan.frame_interval;
    let mut warnings = Vec::new();
    let mut told = std::collections::BTreeSet::new();
    for intervention in interventions {
        let label = intervention.label.as_str();
        if !told.insert(label) {
            continue;
        }
        let times = firings(label);
        let never = interventions.iter().filter(|i| i.label == label).count().saturating_sub(times.len());
        for _ in 0..never {
            warnings.push(format!(
                "scenario {scenario:?}: the intervention \"{label}\" never fired in the scenario's {end:.1} s: {never_means}"
            ));
        }
        // Fired at the last frame: no later frame can show what it did.
        for t in times.into_iter().filter(|&t| t > end - plan.frame_interval / 2.0) {
            warnings.push(format!(
                "scenario {scenario:?}: the intervention \"{label}\" fired at {t:.1} s, the scenario's last frame: no \
                 frame after it shows what it does to the cars (give the scenario more frames or fire it earlier)"
            ));
        }
    }
    warnings
}

/// The scenario's cameras that `--no-images` leaves without pictures, as
/// `gen` tells a spec's.
fn camera_warning(s: &LoadedScenario, images: bool) -> Option<String> {
    let names = s.plan.cameras.iter().map(|c| c.name.as_str());
    super::cameras_without_images(images, "its", names).map(|w| format!("scenario {:?}: {w}", s.name))
}

/// Every action the simulation of `plan` adapted or skipped, in time order,
/// one sentence each naming the scenario (and `run`, e.g. `the
/// counterfactual run, `, when there are two) and the car.
fn driven_warnings(scenario: &str, plan: &ScenarioPlan, trajectories: &Trajectories, run: &str) -> Vec<String> {
    trajectories
        .events
        .iter()
        // A lane change is always the driver's own, for a turn written from
        // a lane that does not allow it: an adaptation like the others.
        .filter(|e| matches!(e.kind, EventKind::ActionAdapted | EventKind::ActionSkipped | EventKind::LaneChange))
        .map(|e| {
            let car = plan.cars.iter().find(|c| Some(c.id) == e.car).map_or("?", |c| c.name.as_str());
            let what = match e.kind {
                EventKind::ActionSkipped => "skipped",
                EventKind::LaneChange => "changed lanes for a turn its lane does not allow",
                _ => "adapted",
            };
            format!("scenario {scenario:?}, {run}car {car:?}, at {:.1} s, {what}: {}", e.t, e.detail)
        })
        .collect()
}

/// The warnings of a counterfactual pair: what its factual run adapted,
/// what only its counterfactual run adapted, and each added intervention
/// that never fired (a car that never reaches the intersection, a light
/// that never turns that colour): its counterfactual is then the factual
/// run.
fn pair_warnings(
    scenario: &str,
    (factual, counterfactual): (&ScenarioPlan, &ScenarioPlan),
    pair: &SimulatedPair,
) -> Vec<String> {
    let mut warnings = driven_warnings(scenario, factual, &pair.factual, "");
    // The same adaptation in both runs (before the intervention) is told once.
    let as_counterfactual = |plan, run| driven_warnings(scenario, plan, run, "the counterfactual run, ");
    let in_factual = as_counterfactual(factual, &pair.factual);
    let in_counterfactual = as_counterfactual(counterfactual, &pair.counterfactual);
    warnings.extend(in_counterfactual.into_iter().filter(|w| !in_factual.contains(w)));
    // When the added interventions fired: the counterfactual run's firings
    // of their label beyond those of the factual run (which has them too
    // when it was the scenario's own).
    let firings = |label: &str| {
        let factual = firings_of(&pair.factual, label).len();
        firings_of(&pair.counterfactual, label).into_iter().skip(factual).collect()
    };
    let added = &counterfactual.interventions[factual.interventions.len()..];
    // (with others added, the runs may still differ)
    let never_means = match added.len() {
        1 => "the counterfactual run is the factual one",
        _ => "it changed nothing in the counterfactual run",
    };
    warnings.extend(intervention_warnings(scenario, counterfactual, added, firings, never_means));
    warnings
}

/// The scenarios of the file, each on its own map or the default one.
fn load_file(options: &RunOptions) -> Result<Vec<LoadedScenario>, RunError> {
    let map = Arc::new(CityMap::default());
    load(&options.scenario_file, FileOptions { world: options.world, strict: options.strict }, &map)
        .map_err(RunError::Input)
}

/// Simulates and writes every scenario of the file into `<out>/<Name>/`.
pub fn run_file(options: &RunOptions) -> Result<Vec<Written>, RunError> {
    let scenarios = load_file(options)?;
    let out = options.out();
    refuse_inputs_below(&out, &scenarios, &[("the scenario file", options.scenario_file.as_path())])?;
    let describe = format!("run {}", options.scenario_file.display());
    let _claim = claim(&out, Writer::Scenarios, &describe).map_err(GenError::Claim)?;
    refuse_unowned(
        &out,
        &scenarios,
        &crate::output::OwnFiles::SCENARIO,
        "a new scenario folder",
        ("factual", "a counterfactual pair (`causalcity counterfactual`)"),
    )?;
    let results: Vec<Result<Written, RunError>> = scenarios
        .par_iter()
        .map(|s| {
            let writer = scenario_writer(&s.expansion, options.products(), false);
            let trajectories = crate::world::simulate_until(&s.expansion.map, &s.plan, stop_flag())
                .ok_or(GenError::Interrupted { done: 0, total: 0, out: PathBuf::new() })?;
            let path = out.join(&s.name);
            let times = StageTimes::default();
            let bytes = write_simulated(
                &writer,
                &s.plan,
                &trajectories,
                None,
                (&out, path.clone()),
                &mut writer.buffers(),
                &times,
            )?;
            let warnings = warnings(s, &trajectories, options.images);
            Ok(Written { scenario: s.name.clone(), path, bytes, warnings })
        })
        .collect();
    gathered(results, out)
}

/// Each scenario's result, or (stopped part way) how many were written and
/// where: it said "0 of 0 scenarios are complete in .".
fn gathered<T>(results: Vec<Result<T, RunError>>, out: PathBuf) -> Result<Vec<T>, RunError> {
    if results.iter().any(|r| matches!(r, Err(RunError::Write(GenError::Interrupted { .. })))) {
        let done = results.iter().filter(|r| r.is_ok()).count() as u64;
        return Err(RunError::Interrupted { done, total: results.len() as u64, out });
    }
    results.into_iter().collect()
}

impl std::fmt::Display for Written {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "wrote {} ({:.1} MB)", self.path.display(), self.bytes as f64 / 1e6)
    }
}

pub use crate::output::pair_summary::{CarDivergence, InterventionRecord, PairSummary};

/// Writes `<out>/<Name>/factual/`, `counterfactual/`, `divergence.csv` and
/// `summary.json` for every scenario of the file. The counterfactual adds
/// the interventions of `intervention_file` to the scenario; without one,
/// the scenario's own interventions make the counterfactual and the factual
/// runs without them.
pub fn counterfactual(options: &RunOptions, intervention_file: Option<&Path>) -> Result<Vec<WrittenPair>, RunError> {
    let scenarios = load_file(options)?;
    let extras = match intervention_file {
        Some(file) => Some(load_interventions(file, &scenarios).map_err(RunError::Input)?),
        None => None,
    };
    let pairs = pair_plans(&options.scenario_file, &scenarios, extras)?;
    let out = options.out();
    let mut inputs = vec![("the scenario file", options.scenario_file.as_path())];
    inputs.extend(intervention_file.map(|file| ("the intervention file", file)));
    refuse_inputs_below(&out, &scenarios, &inputs)?;
    let describe = format!("counterfactual {}", options.scenario_file.display());
    let _claim = claim(&out, Writer::Scenarios, &describe).map_err(GenError::Claim)?;
    refuse_unowned(
        &out,
        &scenarios,
        &PAIR_OWN,
        "a new pair folder",
        ("checksums.sha256", "a scenario of `causalcity run`"),
    )?;
    let results: Vec<Result<WrittenPair, RunError>> = pairs
        .par_iter()
        .map(|(s, factual, counterfactual)| {
            let writer = scenario_writer(&s.expansion, options.products(), false);
            let (summary, driven) = write_pair(
                &s.expansion,
                &writer,
                &s.name,
                (factual, counterfactual),
                None,
                (&out, &out.join(&s.name)),
            )?;
            let read = s.warnings.iter().map(|w| format!("scenario {:?}, {w}", s.name));
            let warnings = read.chain(camera_warning(s, options.images)).chain(driven).collect();
            Ok(WrittenPair { summary, warnings })
        })
        .collect();
    gathered(results, out)
}

/// One pair `counterfactual` wrote: its summary.json, and what reading and
/// driving adapted or what never fired, one sentence each.
pub struct WrittenPair {
    pub summary: PairSummary,
    pub warnings: Vec<String>,
}

/// Refuses, before anything is written, a scenario folder this command
/// would replace (`<out>/<Name>/`) that lies behind a link or holds what it
/// did not write there (`own`): a user's note, or the other command's
/// output (a `run` folder given to `counterfactual` was mixed with the pair
/// written around it). The writers check each folder again as they write.
/// `other` is the mark of the other command's folder and what it is (the
/// `checksums.sha256` at the top of a scenario folder `run` wrote, the
/// `factual/` of a pair).
fn refuse_unowned(
    out: &Path,
    scenarios: &[LoadedScenario],
    own: &crate::output::OwnFiles,
    what: &str,
    (mark, other): (&str, &str),
) -> Result<(), RunError> {
    let refused = |why: crate::output::Refused| RunError::from(GenError::Input(why.to_string()));
    for s in scenarios {
        let folder = out.join(&s.name);
        crate::output::refuse_links_below(out, &folder).map_err(refused)?;
        if std::fs::symlink_metadata(&folder).is_ok_and(|m| m.is_dir()) {
            if std::fs::symlink_metadata(folder.join(mark)).is_ok() {
                return Err(GenError::Input(format!(
                    "{} holds {other} (it has {mark}), which {what} would replace or be mixed with: each \
                     command writes its own --out. Nothing was written; give another --out (or move that \
                     folder away), then rerun.",
                    folder.display()
                ))
                .into());
            }
            crate::output::refuse_foreign(&folder, own, what).map_err(refused)?;
        }
    }
    Ok(())
}

/// Refuses an input file that lies in a scenario folder this command
/// writes (`<out>/<Name>/`): written over, the run would destroy what it
/// reads.
fn refuse_inputs_below(out: &Path, scenarios: &[LoadedScenario], inputs: &[(&str, &Path)]) -> Result<(), RunError> {
    for s in scenarios {
        let folder = out.join(&s.name);
        crate::output::claim::refuse_inputs_inside(&folder, inputs).map_err(GenError::Claim)?;
    }
    Ok(())
}

/// Each scenario of `file` with its factual and counterfactual plans. The
/// counterfactual adds the scenario's `extras`; without extras, the
/// scenario's own interventions make the counterfactual and the factual
/// runs without them.
pub fn pair_plans<'s>(
    file: &Path,
    scenarios: &'s [LoadedScenario],
    extras: Option<Vec<Vec<Intervention>>>,
) -> Result<Vec<(&'s LoadedScenario, ScenarioPlan, ScenarioPlan)>, RunError> {
    let mut pairs = Vec::new();
    for (k, s) in scenarios.iter().enumerate() {
        let (factual, counterfactual) = match &extras {
            Some(extras) => {
                let mut cf = s.plan.clone();
                cf.interventions.extend(extras[k].iter().cloned());
                (s.plan.clone(), cf)
            }
            None if s.plan.interventions.is_empty() => {
                return Err(RunError::Usage(format!(
                    "{}: scenario {:?} has no interventions: name them in its \"interventions\" or pass --intervention FILE",
                    file.display(),
                    s.name
                )));
            }
            None => {
                let mut f = s.plan.clone();
                f.interventions.clear();
                (f, s.plan.clone())
            }
        };
        pairs.push((s, factual, counterfactual));
    }
    Ok(pairs)
}

/// A simulated factual / counterfactual pair and what the intervention did.
pub struct SimulatedPair {
    pub factual: Trajectories,
    pub counterfactual: Trajectories,
    /// divergence.csv's text.
    pub divergence_csv: Vec<u8>,
    /// Metres between each car's factual and counterfactual positions,
    /// `[frames, cars]`, as divergence.csv gives them.
    pub divergence_m: Vec<f64>,
    pub summary: PairSummary,
}

/// Simulates both plans of a pair (in parallel) and measures their
/// divergence; `None` once `stop` is set (checked every frame).
pub fn simulate_pair(
    expansion: &Expansion,
    name: &str,
    factual: &ScenarioPlan,
    counterfactual: &ScenarioPlan,
    stop: &AtomicBool,
) -> Option<SimulatedPair> {
    let town = expansion.town_of(factual);
    let map = &town.map;
    let (a, b) = rayon::join(
        || crate::world::simulate_until(map, factual, stop),
        || crate::world::simulate_until(map, counterfactual, stop),
    );
    let (a, b) = (a?, b?);
    let names: Vec<(u32, String)> = factual.cars.iter().map(|c| (c.id, c.name.clone())).collect();
    let labels: Vec<String> =
        counterfactual.interventions[factual.interventions.len()..].iter().map(|i| i.label.clone()).collect();
    let (divergence_csv, divergence_m, summary) =
        divergence(name, &names, &labels, &a, &b, town.camera.pixels_per_metre);
    Some(SimulatedPair { factual: a, counterfactual: b, divergence_csv, divergence_m, summary })
}

/// What causalcity writes in a pair folder: its two scenario folders (each
/// with its own checksum listing), the divergence and the summary, and
/// the leftovers of an interrupted write of them.
const PAIR_OWN: crate::output::OwnFiles<'static> = crate::output::OwnFiles {
    listed: &["factual", "counterfactual"],
    names: &[
        "divergence.csv",
        "summary.json",
        "divergence.csv.partial",
        "summary.json.partial",
        ".partial-factual",
        ".partial-counterfactual",
    ],
};

/// Simulates a factual / counterfactual pair (the counterfactual's extra
/// interventions come after the factual's) and writes it into `folder`
/// inside the output folder `root`.
fn write_pair(
    expansion: &Expansion,
    writer: &ScenarioWriter,
    name: &str,
    (factual, counterfactual): (&ScenarioPlan, &ScenarioPlan),
    record: Option<InterventionRecord>,
    (root, folder): (&Path, &Path),
) -> Result<(PairSummary, Vec<String>), GenError> {
    let refused = |why: crate::output::Refused| GenError::Input(why.to_string());
    crate::output::refuse_links_below(root, folder).map_err(refused)?;
    let mut pair = simulate_pair(expansion, name, factual, counterfactual, stop_flag())
        .ok_or(GenError::Interrupted { done: 0, total: 0, out: PathBuf::new() })?;
    pair.summary.intervention = record;
    let (mut buffers, times) = (writer.buffers(), StageTimes::default());
    write_simulated(writer, factual, &pair.factual, None, (root, folder.join("factual")), &mut buffers, &times)?;
    write_simulated(
        writer,
        counterfactual,
        &pair.counterfactual,
        None,
        (root, folder.join("counterfactual")),
        &mut buffers,
        &times,
    )?;
    write_atomically(&folder.join("divergence.csv"), &pair.divergence_csv)?;
    let mut json = serde_json::to_vec_pretty(&pair.summary).expect("summary serialises");
    json.push(b'\n');
    write_atomically(&folder.join("summary.json"), &json)?;
    let warnings = pair_warnings(name, (factual, counterfactual), &pair);
    Ok((pair.summary, warnings))
}

pub use crate::plan::interventions::SweepKind;

/// What `counterfactual --sweep` was asked to do.
#[derive(Debug, Clone)]
pub struct SweepOptions {
    pub spec_path: PathBuf,
    /// Default: `data/<spec name>-counterfactual`.
    pub out: Option<PathBuf>,
    pub limit: Option<u32>,
    pub kinds: Vec<SweepKind>,
    pub products: Products,
    /// Pair folders, or whole pairs packed into tar files (as `gen --format
    /// tar` packs scenarios).
    pub packing: Packing,
    pub threads: Option<usize>,
    pub progress: ProgressMode,
}

/// What a sweep wrote.
#[derive(Debug, Clone, Serialize)]
pub struct SweepSummary {
    pub out: PathBuf,
    pub pairs: usize,
    /// Of `pairs`, those already complete from an earlier run (kept, not redone).
    pub kept: usize,
    /// Pairs whose intervention moved at least one car.
    pub pairs_with_effect: usize,
    /// Mean size of the effect set over the pairs.
    pub mean_affected_cars: f64,
}

impl std::fmt::Display for SweepSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} counterfactual pairs in {} ({} written now, {} kept from an earlier run): {} with an effect, \
             {:.2} cars affected on average",
            self.pairs,
            self.out.display(),
            self.pairs - self.kept,
            self.kept,
            self.pairs_with_effect,
            self.mean_affected_cars
        )
    }
}

/// Counterfactual pairs at scale: for every scenario of a `gen` spec, one
/// random intervention of the given kinds (drawn from the scenario's own
/// stream, so the sweep is reproducible), written as
/// `<out>/<group>/<split>/<index>/` pairs, in parallel, or packed into
/// `<out>/<group>/<split>/<first>-<last>.tar` with those pairs' files
/// inside.
pub fn sweep(options: &SweepOptions) -> Result<SweepSummary, RunError> {
    let expansion = load_spec(&options.spec_path)?;
    if expansion.spec.world != WorldKind::City {
        return Err(RunError::Usage(format!(
            "{}: --sweep needs a city-world spec (toy cars have no agency to intervene on)",
            options.spec_path.display()
        )));
    }
    if options.kinds.is_empty() {
        return Err(RunError::Usage("--kinds: give at least one kind".into()));
    }
    // The kinds, in order, decide each pair's intervention and are recorded
    // as the sweep's: one named twice would record a sweep no other
    // spelling of it matches.
    if let Some(twice) = options.kinds.iter().enumerate().find_map(|(i, k)| options.kinds[..i].contains(k).then_some(k))
    {
        let name = serde_json::to_value(twice).ok().and_then(|v| v.as_str().map(|s| s.replace('_', "-")));
        return Err(RunError::Usage(format!(
            "--kinds: {} is given twice: name each kind once",
            name.unwrap_or_default()
        )));
    }
    let out = options
        .out
        .clone()
        .unwrap_or_else(|| Path::new("data").join(format!("{}-counterfactual", expansion.spec.name)));
    let threads = options.threads.unwrap_or_else(|| std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1));
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| RunError::Write(GenError::Threads { threads, reason: e.to_string() }))?;
    let describe = format!("counterfactual --sweep {}", options.spec_path.display());
    let _claim = claim(&out, Writer::Sweep, &describe).map_err(GenError::Claim)?;
    refuse_linked_splits(&out, &expansion.spec)?;
    let record = |pairs: Option<usize>| {
        let mut record = serde_json::json!({
            "format": "causalcity-counterfactual-sweep/1",
            "version": env!("CARGO_PKG_VERSION"),
            "spec": expansion.spec,
            "spec_sha256": crate::output::manifest::spec_sha256(&expansion.spec),
            "limit": options.limit,
            "kinds": options.kinds,
            "images": options.products.images,
            "lights": options.products.lights.name(),
            "complete": pairs.is_some(),
            "pairs": pairs,
        });
        // Only a packed sweep says so: a folder sweep's record is as before.
        if let Some(per_tar) = options.packing.scenarios_per_tar() {
            record["scenarios_per_tar"] = per_tar.into();
        }
        let mut json = serde_json::to_vec_pretty(&record).expect("sweep record serialises");
        json.push(b'\n');
        json
    };
    // One sweep per folder: the same spec, limit and kinds, or a new folder.
    let record_path = out.join(SWEEP_RECORD);
    if let Ok(old) = std::fs::read(&record_path) {
        let mut old: serde_json::Value = serde_json::from_slice(&old).unwrap_or_default();
        let new: serde_json::Value = serde_json::from_slice(&record(None)).expect("our own JSON");
        // Sweeps from before the record had `images` say it with their pairs.
        if old["images"].is_null() {
            if let Some(images) = pairs_have_images(&out) {
                old["images"] = images.into();
            }
        }
        // Sweeps from before the record had `lights` logged every frame.
        if old["lights"].is_null() {
            old["lights"] = LightsLog::Frames.name().into();
        }
        let differences: Vec<String> = ["version", "spec", "limit", "kinds", "images", "lights", "scenarios_per_tar"]
            .into_iter()
            .filter(|field| old[field] != new[field] && !(*field == "images" && old[field].is_null()))
            .map(|field| match field {
                "lights" => format!("lights (it was made with --lights {})", old[field].as_str().unwrap_or("?")),
                "scenarios_per_tar" => match old[field].as_u64() {
                    Some(n) => format!("format (it was made with --format tar --scenarios-per-tar {n})"),
                    None => "format (it was made with --format folders)".to_string(),
                },
                "images" if new[field] == true => "images (it was made with --no-images)".to_string(),
                "images" => {
                    "images (it was made with images; add nothing, or use another --out for --no-images)".to_string()
                }
                // The old and the new value, as given on the command line.
                "kinds" => {
                    let kinds = |v: &serde_json::Value| {
                        let names = v.as_array().into_iter().flatten().filter_map(|k| k.as_str());
                        names.map(|k| k.replace('_', "-")).collect::<Vec<_>>().join(",")
                    };
                    let made = match kinds(&old[field]) {
                        none if none.is_empty() => "its record names none".to_string(),
                        some => format!("it was made with --kinds {some}"),
                    };
                    format!("kinds ({made}, this run asks for --kinds {})", kinds(&new[field]))
                }
                "limit" => {
                    let limit =
                        |v: &serde_json::Value| v.as_u64().map_or("no --limit".to_string(), |n| format!("--limit {n}"));
                    format!("limit (it was made with {}, this run asks for {})", limit(&old[field]), limit(&new[field]))
                }
                "version" => format!(
                    "version (it was made by causalcity {}, this is {})",
                    old[field].as_str().unwrap_or("?"),
                    env!("CARGO_PKG_VERSION")
                ),
                "spec" => "spec (it was made from another spec, or this one was edited since)".to_string(),
                _ => field.to_string(),
            })
            .collect();
        if !differences.is_empty() {
            return Err(RunError::Usage(format!(
                "{} holds a sweep made differently (differs: {}): use another --out",
                out.display(),
                differences.join(", ")
            )));
        }
    }
    let keys = expansion.keys(options.limit);
    let folder_of = |key: &ScenarioKey| scenario_dir(&out, &key.group, key.split.name(), &key.folder_name());
    // A pair is never kept, read or written through a link: refused
    // before anything is written (a refused rerun of a complete sweep left
    // it incomplete, which evaluate then refused).
    for key in &keys {
        crate::output::refuse_links_below(&out, &folder_of(key)).map_err(|why| GenError::Input(why.to_string()))?;
    }
    write_atomically(&record_path, &record(None)).map_err(GenError::from)?;
    keep_networks(&expansion.spec, &out)?;
    let writers = TownWriters::new(&expansion, options.products, false);
    let bar = Progress::new(keys.len() as u64, options.progress);
    let kept = AtomicUsize::new(0);
    // The pair of `key`, simulated and written into its folder, unless a
    // complete one is there (a rerun keeps every complete pair).
    let one = |key: &ScenarioKey| -> Result<PairSummary, GenError> {
        if stop_flag().load(Ordering::Relaxed) {
            return Err(GenError::Interrupted { done: 0, total: 0, out: PathBuf::new() });
        }
        let folder = folder_of(key);
        let refused = |why: crate::output::Refused| GenError::Input(why.to_string());
        // Never kept, read or written through a link.
        crate::output::refuse_links_below(&out, &folder).map_err(refused)?;
        let plan = expansion.plan(key).map_err(|reason| GenError::Plan {
            scenario: format!("{}/{}/{}", key.group, key.split.name(), key.folder_name()),
            reason,
        })?;
        let draw = SweepDraw::of(&plan, &options.kinds);
        let record = InterventionRecord::of_draw(&plan, &draw);
        let intervention = draw.intervention;
        // Kept only as this sweep writes it: its summary.json and
        // divergence.csv carry no checksum, so they are held to the
        // readers' rule and to the intervention the pair's key draws (an
        // edited summary or divergence log was kept by every rerun).
        if let Some(summary) =
            complete_pair(&folder).filter(|s| s.intervention.as_ref() == Some(&record)).filter(|_| {
                crate::dataset::pairs::check_pair(&folder, (&key.group, key.split.name(), key.index.into())).is_ok()
            })
        {
            kept.fetch_add(1, Ordering::Relaxed);
            bar.inc();
            return Ok(summary);
        }
        let mut counterfactual = plan.clone();
        counterfactual.interventions.push(intervention);
        let pair = (&plan, &counterfactual);
        // An incomplete pair is written again from scratch: removed first,
        // unless it holds what no run wrote.
        if std::fs::symlink_metadata(&folder).is_ok_and(|m| m.is_dir()) {
            crate::output::refuse_foreign(&folder, &PAIR_OWN, "a new pair folder").map_err(refused)?;
            std::fs::remove_dir_all(&folder)
                .map_err(|source| GenError::from(WriteError { path: folder.clone(), source }))?;
        }
        // A sweep's interventions fire at a time (the summary says whether
        // one changed anything); its scenarios are a spec's, read unchanged.
        let (summary, _) =
            write_pair(&expansion, writers.of(&plan), &key.folder_name(), pair, Some(record), (&out, &folder))?;
        bar.inc();
        Ok(summary)
    };
    let sequence = expansion.key_sequence(options.limit);
    let packs = match options.packing {
        Packing::Folders => None,
        Packing::Tar { per_tar } => Some(Packs::new(sequence, per_tar)),
    };
    let result = pool.install(|| match &packs {
        None => keys.par_iter().map(one).collect::<Result<Vec<_>, GenError>>(),
        // As `gen --format tar`: pairs are appended to their pack as they
        // finish, in order; the pack is renamed into place whole, and its
        // pair folders removed.
        Some(packs) => (0..packs.len())
            .into_par_iter()
            .map(|number| {
                let pack = packs.pack(number);
                let (path, pack_keys) = (packs.path(&out, &pack), packs.keys(&pack));
                if path.exists() {
                    // Its runs by their checksums, then what carries none
                    // (summary.json, divergence.csv) by the readers' rule
                    // and the draw, as a folder sweep's pairs.
                    let verified = crate::output::packs::verify_of(PackUnit::Pair, &path, &pack_keys)
                        .and_then(|()| packed_pairs_as_drawn(&path, &pack_keys, &expansion, &options.kinds));
                    match verified {
                        Ok(()) => {
                            let summaries = packed_summaries(&path)?;
                            for key in &pack_keys {
                                remove_packed(&out, &folder_of(key), &PAIR_OWN)?;
                            }
                            kept.fetch_add(summaries.len(), Ordering::Relaxed);
                            (0..summaries.len()).for_each(|_| bar.inc());
                            return Ok(summaries);
                        }
                        Err(why) => crate::progress::note(format_args!("warning: {why}: writing the pack again")),
                    }
                }
                let packing = PackWriter::begin_of(PackUnit::Pair, &out, pack_keys.clone(), &path)?;
                let summaries = pack_keys
                    .par_iter()
                    .enumerate()
                    .map(|(i, key)| {
                        let summary = one(key)?;
                        packing.finished(i)?;
                        Ok(summary)
                    })
                    .collect::<Result<Vec<_>, GenError>>()?;
                if stop_flag().load(Ordering::Relaxed) {
                    return Err(GenError::Interrupted { done: 0, total: 0, out: PathBuf::new() });
                }
                packing.commit(false)?;
                pack_keys.par_iter().try_for_each(|key| remove_packed(&out, &folder_of(key), &PAIR_OWN))?;
                Ok(summaries)
            })
            .collect::<Result<Vec<_>, GenError>>()
            .map(|packed| packed.into_iter().flatten().collect()),
    });
    bar.finish();
    let summaries = match result {
        Ok(summaries) => summaries,
        Err(GenError::Interrupted { .. }) => {
            let in_folders = keys.iter().filter(|key| folder_of(key).join("summary.json").exists()).count();
            let in_packs: usize = packs.as_ref().map_or(0, |p| {
                (0..p.len())
                    .map(|n| p.pack(n))
                    .filter(|pack| p.path(&out, pack).is_file())
                    .map(|pack| pack.count as usize)
                    .sum()
            });
            let done = (in_folders + in_packs) as u64;
            return Err(RunError::Write(GenError::Interrupted { done, total: keys.len() as u64, out }));
        }
        Err(e) => return Err(RunError::Write(e)),
    };
    write_atomically(&record_path, &record(Some(summaries.len()))).map_err(GenError::from)?;
    let affected: usize = summaries.iter().map(|s| s.affected.len()).sum();
    Ok(SweepSummary {
        out,
        pairs: summaries.len(),
        kept: kept.load(Ordering::Relaxed),
        pairs_with_effect: summaries.iter().filter(|s| !s.affected.is_empty()).count(),
        mean_affected_cars: affected as f64 / summaries.len().max(1) as f64,
    })
}

/// Whether every pair in the pack at `path` (of the pairs `keys`) passes
/// the readers' rule (`dataset::pairs`) and records the intervention its
/// key draws from `kinds`: `summary.json` and `divergence.csv` carry no
/// checksum, so a rerun kept an edited or damaged one inside a pack.
fn packed_pairs_as_drawn(
    path: &Path,
    keys: &[ScenarioKey],
    expansion: &Expansion,
    kinds: &[crate::plan::interventions::SweepKind],
) -> Result<(), String> {
    let names: Vec<String> = kinds.iter().map(|k| k.name().to_string()).collect();
    crate::output::packs::read_scenarios(path, keys, |i, members| {
        let key = &keys[i];
        let folder = PathBuf::from(format!("{}: {}", path.display(), key.relative_folder()));
        let members = crate::output::packs::split_pair(members);
        let summary = crate::dataset::pairs::check_packed_pair(
            &members,
            &folder,
            (&key.group, key.split.name(), key.index.into()),
        )?;
        // Its record, as a folder sweep's kept pair must have it.
        let drawn = crate::dataset::check_drawn(expansion, &names, key, &summary)
            .map_err(|e| format!("{}: {e}", folder.join("summary.json").display()))?;
        if summary.intervention == Some(drawn) {
            Ok(())
        } else {
            Err(format!("{}: no intervention record", folder.join("summary.json").display()))
        }
    })
    .map(|_| ())
}

/// The summaries of the pairs in the pack at `path` (whole: verified).
fn packed_summaries(path: &Path) -> Result<Vec<PairSummary>, GenError> {
    let mut summaries = Vec::new();
    let summary =
        |name: &str| crate::output::packs::split_member(name).is_some_and(|(_, within)| within == "summary.json");
    crate::output::packs::read_members_where(path, &summary, |name, bytes| {
        let summary = serde_json::from_slice(&bytes).map_err(|e| format!("{}: {name}: {e}", path.display()))?;
        summaries.push(summary);
        Ok(())
    })
    .map_err(GenError::Input)?;
    Ok(summaries)
}

/// Whether the first finished pair found in the sweep at `out` has frames
/// (None when there is none).
fn pairs_have_images(out: &Path) -> Option<bool> {
    let folders = |dir: &Path| -> Vec<PathBuf> {
        let mut found: Vec<PathBuf> =
            std::fs::read_dir(dir).into_iter().flatten().flatten().map(|e| e.path()).filter(|p| p.is_dir()).collect();
        found.sort();
        found
    };
    folders(out).iter().flat_map(|group| folders(group)).flat_map(|split| folders(&split)).find_map(|pair| {
        let factual = pair.join("factual");
        factual.join(crate::output::CHECKSUMS).is_file().then(|| factual.join("rgb").is_dir())
    })
}

/// The summary of the pair in `folder` when the pair is complete: its
/// summary.json (written last) reads, and both runs pass their checksums.
pub fn complete_pair(folder: &Path) -> Option<PairSummary> {
    let summary = std::fs::read(folder.join("summary.json")).ok()?;
    let summary: PairSummary = serde_json::from_slice(&summary).ok()?;
    for run in ["factual", "counterfactual"] {
        crate::output::verify_scenario(&folder.join(run)).ok()?;
    }
    Some(summary)
}

/// divergence.csv (`frame,t,car,distance_m,distance_px`), its distances in
/// metres (`[frames, cars]`) and the summary.
fn divergence(
    scenario: &str,
    cars: &[(u32, String)],
    labels: &[String],
    factual: &Trajectories,
    counterfactual: &Trajectories,
    pixels_per_metre: f64,
) -> (Vec<u8>, Vec<f64>, PairSummary) {
    let mut csv = b"frame,t,car,distance_m,distance_px\n".to_vec();
    let mut distances = Vec::with_capacity(factual.frames() * cars.len());
    let mut per_car: Vec<CarDivergence> = cars
        .iter()
        .map(|(id, name)| CarDivergence {
            id: *id,
            name: name.clone(),
            affected: false,
            max_divergence_m: 0.0,
            first_divergent_frame: None,
        })
        .collect();
    for (frame, (a, b)) in factual.states.iter().zip(&counterfactual.states).enumerate() {
        for ((x, y), car) in a.iter().zip(b).zip(per_car.iter_mut()) {
            let distance = x.position.distance(y.position);
            // As the files show it: the first frame whose poses.csv rows differ.
            if logged_pose(x) != logged_pose(y) {
                car.affected = true;
                car.first_divergent_frame.get_or_insert(frame);
            }
            car.max_divergence_m = car.max_divergence_m.max(distance);
            csv.extend_from_slice(format!("{frame},").as_bytes());
            push_fixed(&mut csv, frame as f64 * factual.frame_interval, 6);
            csv.extend_from_slice(format!(",{},", car.id).as_bytes());
            push_fixed(&mut csv, distance, 4);
            distances.push(crate::output::number::logged_value(distance, 4));
            csv.push(b',');
            push_fixed(&mut csv, distance * pixels_per_metre, 3);
            csv.push(b'\n');
        }
    }
    let intervention_time_s = counterfactual
        .events
        .iter()
        .filter(|e| e.kind == EventKind::Intervention)
        .map(|e| e.t)
        .find(|t| !factual.events.iter().any(|f| f.kind == EventKind::Intervention && f.t == *t));
    let summary = PairSummary {
        scenario: scenario.to_string(),
        interventions: labels.to_vec(),
        intervention: None,
        intervention_time_s,
        affected: per_car.iter().filter(|c| c.affected).map(|c| c.name.clone()).collect(),
        cars: per_car,
    };
    (csv, distances, summary)
}
