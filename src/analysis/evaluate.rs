//! `causalcity evaluate`: scores anyone's predictions against a dataset's
//! ground truth with the paper's metrics, so that every method is scored
//! the same way.
//!
//! The ground truth is a `gen` dataset, or a `counterfactual --sweep`
//! output, whose factual runs then stand for the scenarios. The predictions
//! file is an `.npz` (numpy's `np.savez`) holding, for each scored scenario,
//! arrays named by its folder relative to the dataset:
//!
//! - `<group>/<split>/<index>`, e.g. `cars08_edges50/test/00000`: `[cars,
//!   cars]` edge scores, `[i, j]` scoring "car i leads car j" (cause to
//!   effect, as `Scenario.graph` in Python and `edges` in scenario.json),
//!   higher meaning more likely; the diagonal is ignored;
//! - `<group>/<split>/<index>/trajectory`: `[steps, cars, 2]` predicted
//!   bird's-eye pixel positions (px, py) of frames `history ..
//!   history + steps` after observing frames `0 .. history` (the paper
//!   observes 100 frames and predicts up to 20);
//! - `<group>/<split>/<index>/frames` (city world): `[frames, cars, cars]`
//!   per-frame edge scores, `[t, i, j]` scoring "car i bound car j's speed
//!   at frame t", scored against `interactions.csv` (car j's `other_car`
//!   is i: the car ahead, a conflicting car or one it collided with);
//! - `<group>/<split>/<index>/counterfactual` (a sweep): `[steps, cars, 2]`
//!   predicted positions of the counterfactual run (after its
//!   intervention) at frames `history .. history + steps`, scored against
//!   `counterfactual/poses.csv`; a car the intervention removed is not
//!   scored once it has left the map.
//!
//! Any kind may be left out; within a group and split, every scenario of
//! the dataset must be scored once one is, so that no method is scored on a
//! subset of its choosing. Edge scores get, per graph kind, group and split:
//! F1 at a threshold chosen on the validation split (the one with the best
//! F1 over all of val's pairs), mean over scenarios with its standard error;
//! precision and recall over all pairs; AUROC and AUPRC (average precision)
//! over all pairs, needing no threshold; and the structural Hamming distance
//! (SHD: ordered pairs whose called link differs from the truth, so a
//! reversed edge counts twice), mean over scenarios. Per-frame graphs get
//! the same over every frame's pairs (graph `per-frame`), their SHD per
//! frame. Trajectories, factual and counterfactual, get the mean squared
//! error of positions normalised by the image size (x / width, y / height,
//! both 0 to 1, averaged over the two coordinates and the cars), per step
//! ahead, mean over scenarios with its standard error.

use super::metrics::{auroc, average_precision, best_threshold, Counts, ScoredPair};
use super::predictions::{read_npz, read_npz_array, NamedArray};
use crate::dataset::{Dataset, GraphKind, PoseLog, ScenarioSummary, Sweep};
use crate::error::Error;
use crate::output::claim::FileKind;
use crate::output::layout::INTERACTIONS_CSV;
use crate::output::logs::{event_frame, read_interactions};
use crate::plan::ScenarioKey;
use crate::spec::{DatasetSpec, Split, WorldKind};
use crate::world::effects::EFFECT_THRESHOLD_M;
use crate::world::CarState;
use rayon::prelude::*;
use serde::Serialize;
use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};

/// Frames observed before the predicted ones, as in the paper (NRI's encoder
/// sees 100 frames of history).
pub const DEFAULT_HISTORY_FRAMES: usize = 100;

/// Suffix of a scenario's predicted-trajectory array.
pub const TRAJECTORY_SUFFIX: &str = "/trajectory";
/// Suffix of a scenario's per-frame edge scores.
pub const PER_FRAME_SUFFIX: &str = "/frames";
/// Suffix of a sweep pair's predicted counterfactual trajectory (from the
/// intervention's frame on).
pub const COUNTERFACTUAL_SUFFIX: &str = "/counterfactual";
/// Suffix of a sweep pair's scores that each car is affected by the
/// intervention.
pub const AFFECTED_SUFFIX: &str = "/affected";
/// The row name of the affected-car scores among the edge rows.
pub const AFFECTED_GRAPH: &str = "affected";

/// The most bytes a dataset record may hold.
const MAX_DATASET_RECORD: u64 = 64 * 1024;

/// How many times the values its scenario allows an array may hold, plus
/// [`SHAPE_SLACK_VALUES`], before the reader refuses it unread.
const SHAPE_SLACK: u64 = 4;
const SHAPE_SLACK_VALUES: u64 = 4096;

/// The name reports give the per-frame graph (next to [`GraphKind::name`]).
pub const PER_FRAME_GRAPH: &str = "per-frame";

/// The array of a predictions file that records the dataset the
/// predictions were made on (UTF-8 JSON of a [`DatasetIdentity`], as
/// uint8): `save_predictions(..., dataset=...)` and the reference methods
/// write it.
pub const DATASET_RECORD: &str = "causalcity-dataset";

/// What tells datasets apart for a predictions file: the spec (its hash,
/// which covers the seed and world), and the scenarios per split scored.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
pub struct DatasetIdentity {
    pub name: String,
    pub world: String,
    pub seed: u64,
    pub spec_sha256: String,
    /// Scenarios per split over all groups (after any `--limit`).
    pub splits: BTreeMap<String, usize>,
    /// A sweep's `--kinds` of intervention, in order: with the spec they
    /// decide each pair's intervention (empty for a `gen` dataset, and in
    /// records written before sweeps gave them).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub kinds: Vec<String>,
}

impl DatasetIdentity {
    /// The identity of the `gen` dataset or `counterfactual --sweep` output
    /// in `dir`.
    pub fn of(dir: &Path) -> Result<DatasetIdentity, String> {
        Ok(Truth::open(dir)?.identity())
    }

    fn describe(&self) -> String {
        let splits: Vec<String> =
            ["train", "val", "test"].iter().map(|s| self.splits.get(*s).copied().unwrap_or(0).to_string()).collect();
        let kinds = if self.kinds.is_empty() {
            String::new()
        } else {
            format!(", a sweep of --kinds {}", self.kinds.join(","))
        };
        format!(
            "{} ({} world, seed {}, spec sha256 {}, {} train/val/test scenarios{kinds})",
            self.name,
            self.world,
            self.seed,
            crate::output::short_hash(&self.spec_sha256),
            splits.join("/")
        )
    }

    /// Whether predictions recorded as made on `self` belong to `ours`: the
    /// same in every field, a record without a sweep's kinds (written
    /// before sweeps gave them) taking any.
    fn matches(&self, ours: &DatasetIdentity) -> bool {
        let kinds = if self.kinds.is_empty() { &ours.kinds } else { &self.kinds };
        (&self.name, &self.world, self.seed, &self.spec_sha256, &self.splits, kinds)
            == (&ours.name, &ours.world, ours.seed, &ours.spec_sha256, &ours.splits, &ours.kinds)
    }
}

/// What to score and how.
#[derive(Debug, Clone)]
pub struct EvaluateOptions {
    /// Graph kinds to score edges against (the causal and direct ones need
    /// a dataset made with effects).
    pub graphs: Vec<GraphKind>,
    /// Frames observed before a predicted trajectory's first frame.
    pub history: usize,
    /// A fixed threshold on edge scores (a pair is called linked above it)
    /// instead of the one with the best F1 on val.
    pub threshold: Option<f64>,
}

impl Default for EvaluateOptions {
    fn default() -> Self {
        EvaluateOptions { graphs: vec![GraphKind::Designed], history: DEFAULT_HISTORY_FRAMES, threshold: None }
    }
}

/// Edge-discovery scores of one graph, group and split.
#[derive(Debug, Clone, Serialize)]
pub struct EdgeScores {
    /// `designed`, `causal`, `direct` ([`GraphKind::name`]) or `per-frame`.
    pub graph: &'static str,
    pub group: String,
    pub cars: u32,
    pub edge_proportion: f64,
    pub split: &'static str,
    /// The split holds something out from train (the spec's `held_out`):
    /// an out-of-distribution row. Absent (false) for in-distribution rows.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub held_out: bool,
    pub scenarios: usize,
    /// Ordered pairs scored (cars x (cars - 1) per scenario, and per frame
    /// for the per-frame graph).
    pub pairs: usize,
    pub true_edges: usize,
    /// Pairs scored above the threshold.
    pub predicted_edges: usize,
    /// A pair is called linked when its score is above this.
    pub threshold: f64,
    /// `val` (best F1 on this group's val split), `given` (--threshold),
    /// `pooled` (best F1 on every group's val pooled: this group's val
    /// holds no true link) or `default` (0.5: no val predictions, or no
    /// true link in any group's val).
    pub threshold_from: &'static str,
    /// Over all pairs; None when nothing was called (precision) or nothing
    /// was there to find (recall).
    pub precision: Option<f64>,
    pub recall: Option<f64>,
    /// Mean over scenarios of each scenario's F1 (1 for a scenario with no
    /// link that was called none, as scikit-learn's `zero_division=1`).
    pub f1: f64,
    /// Standard error of that mean (None for one scenario).
    pub f1_se: Option<f64>,
    /// Over all pairs; None without both linked and unlinked pairs.
    pub auroc: Option<f64>,
    /// Average precision over all pairs; None without a linked pair.
    pub auprc: Option<f64>,
    /// Who leads whom: the share of the linked pairs a -> b (whose reverse
    /// b -> a is not linked) scored above their reverse, ties counting
    /// half; 0.5 is chance. None for the per-frame and affected-car
    /// graphs, and without such a pair.
    pub direction: Option<f64>,
    /// Mean structural Hamming distance per scenario (per frame for the
    /// per-frame graph).
    pub shd: f64,
    pub shd_se: Option<f64>,
}

/// Edge-discovery scores of one graph and split over every group: each
/// scenario counts once (scored at its own group's threshold), so groups
/// weigh by their scenarios. Given when two or more groups are scored.
#[derive(Debug, Clone, Serialize)]
pub struct OverallScores {
    pub graph: &'static str,
    pub split: &'static str,
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub held_out: bool,
    pub groups: usize,
    pub scenarios: usize,
    pub pairs: usize,
    pub true_edges: usize,
    pub predicted_edges: usize,
    pub precision: Option<f64>,
    pub recall: Option<f64>,
    /// Mean over every scenario of its F1.
    pub f1: f64,
    pub f1_se: Option<f64>,
    /// Over every pair of every group (scores compared across groups).
    pub auroc: Option<f64>,
    pub auprc: Option<f64>,
    /// Over every linked pair of every group (see [`EdgeScores::direction`]).
    pub direction: Option<f64>,
    pub shd: f64,
    pub shd_se: Option<f64>,
}

/// Trajectory-prediction error of one group and split at each step ahead.
#[derive(Debug, Clone, Serialize)]
pub struct TrajectoryScores {
    pub group: String,
    pub cars: u32,
    pub edge_proportion: f64,
    pub split: &'static str,
    pub scenarios: usize,
    pub steps: Vec<StepError>,
}

/// The error `step` frames after the history.
#[derive(Debug, Clone, Serialize)]
pub struct StepError {
    /// 1 for the first predicted frame.
    pub step: usize,
    /// Normalised mean squared error (see the module's documentation).
    pub mse: f64,
    pub se: Option<f64>,
    /// Scenarios whose prediction reaches this step.
    pub scenarios: usize,
}

/// Everything `evaluate` measured.
#[derive(Debug, Clone, Serialize)]
pub struct EvaluationReport {
    pub dataset: String,
    pub predictions: String,
    pub world: String,
    /// (width, height) of the bird's-eye image, pixels: the normalisation.
    pub image_size: [u32; 2],
    pub history_frames: usize,
    pub edges: Vec<EdgeScores>,
    /// Every group together, per graph and split (with two or more groups).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub overall: Vec<OverallScores>,
    pub trajectories: Vec<TrajectoryScores>,
    /// Predicted counterfactual trajectories against the re-simulated ones
    /// from the intervention's frame on (a sweep only), over every car on
    /// the map.
    pub counterfactuals: Vec<TrajectoryScores>,
    /// The same over the cars the intervention moved (by more than the
    /// effect threshold), where a pair has any.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub counterfactuals_affected: Vec<TrajectoryScores>,
    /// What the reader must know before trusting a number: predictions
    /// that do not say which dataset they were made on, rows without val
    /// predictions whose threshold is a fixed 0.5.
    pub warnings: Vec<String>,
    /// One row per scored scenario and graph (`--per-scenario`); not in
    /// the JSON report, whose size it would multiply.
    #[serde(skip)]
    pub per_scenario: Vec<ScenarioScores>,
}

/// One scenario's scores against one graph, at its group's threshold
/// (`--per-scenario`): what a researcher needs to find the scenarios a
/// method gets wrong. `graph` is empty on the row of a scenario with
/// trajectories but no edge scores.
#[derive(Debug, Clone)]
pub struct ScenarioScores {
    /// The scenario's folder in the dataset, e.g. `cars08_edges50/test/00003`.
    pub scenario: String,
    pub group: String,
    pub split: &'static str,
    pub graph: &'static str,
    pub cars: usize,
    pub threshold: Option<f64>,
    /// Linked pairs (for the per-frame graph: over every frame).
    pub true_edges: usize,
    pub predicted_edges: usize,
    pub true_positives: usize,
    pub precision: Option<f64>,
    pub recall: Option<f64>,
    /// As in the group rows: 1 when nothing is linked and nothing called.
    pub f1: Option<f64>,
    pub shd: Option<f64>,
    /// None when the scenario's pairs are all linked or all unlinked.
    pub auroc: Option<f64>,
    /// As in the group rows ([`EdgeScores::direction`]): None without a
    /// linked pair whose reverse is unlinked.
    pub direction: Option<f64>,
    /// Mean over the predicted steps of the normalised squared position
    /// error, where trajectories were predicted.
    pub trajectory_mse: Option<f64>,
    pub counterfactual_mse: Option<f64>,
}

/// What an array of a predictions file predicts, told by its name's suffix.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Predicted {
    Edges,
    Trajectory,
    PerFrame,
    Counterfactual,
    Affected,
}

impl Predicted {
    const ALL: [Predicted; 5] =
        [Predicted::Edges, Predicted::Trajectory, Predicted::PerFrame, Predicted::Counterfactual, Predicted::Affected];

    fn suffix(self) -> &'static str {
        match self {
            Predicted::Edges => "",
            Predicted::Trajectory => TRAJECTORY_SUFFIX,
            Predicted::PerFrame => PER_FRAME_SUFFIX,
            Predicted::Counterfactual => COUNTERFACTUAL_SUFFIX,
            Predicted::Affected => AFFECTED_SUFFIX,
        }
    }

    fn what(self) -> &'static str {
        match self {
            Predicted::Edges => "edge scores",
            Predicted::Trajectory => "trajectories",
            Predicted::PerFrame => "per-frame edge scores",
            Predicted::Counterfactual => "counterfactual trajectories",
            Predicted::Affected => "affected-car scores",
        }
    }

    /// The scenario folder an array names and what it predicts.
    fn of(name: &str) -> (&str, Predicted) {
        Predicted::ALL[1..]
            .iter()
            .find_map(|&p| name.strip_suffix(p.suffix()).map(|folder| (folder, p)))
            .unwrap_or((name, Predicted::Edges))
    }
}

/// Where the truth is: a `gen` dataset, or a sweep's pairs.
struct Truth {
    dir: PathBuf,
    /// The folder the scenario folders are under: `dir`, or where a packed
    /// dataset's packs are unpacked while read.
    scenarios: PathBuf,
    /// A `gen` dataset (not a sweep): scored a split at a time, so that a
    /// packed one holds one split in TMPDIR.
    dataset: Option<Dataset>,
    /// A packed dataset's scenario sizes (cars, frames) by folder, read from
    /// its packs without unpacking them.
    sizes: Option<crate::dataset::ScenarioSizes>,
    spec: DatasetSpec,
    keys: Vec<ScenarioKey>,
    /// Scenario folders carry the causal and direct graphs.
    effects: bool,
    sweep: bool,
    /// A sweep's `--kinds`, in order (empty for a `gen` dataset).
    kinds: Vec<String>,
    /// A sweep, which draws each pair's intervention (its summary's is
    /// checked against it).
    drawn: Option<Sweep>,
    /// Where a packed sweep's pairs are unpacked (their logs, no frames)
    /// for as long as they are scored.
    unpacked: Option<crate::output::packs::Scratch>,
}

impl Truth {
    fn open(dir: &Path) -> Result<Truth, String> {
        if !dir.join("manifest.json").exists() {
            if let Some(sweep) = Sweep::open(dir)? {
                // Every scenario is scored against its files: evaluate holds
                // one entry per scenario whatever it does.
                let keys = sweep.key_sequence().iter().collect();
                let unpacked = unpack_sweep(&sweep)?;
                let scenarios = unpacked.as_ref().map_or_else(|| sweep.dir.clone(), |s| s.path().to_path_buf());
                return Ok(Truth {
                    dir: sweep.dir.clone(),
                    scenarios,
                    dataset: None,
                    sizes: None,
                    spec: sweep.expansion.spec.clone(),
                    keys,
                    effects: false,
                    sweep: true,
                    kinds: sweep.kinds.clone(),
                    drawn: Some(sweep),
                    unpacked,
                });
            }
        }
        let dataset = Dataset::open_complete(dir)?;
        let keys = dataset.keys().collect();
        let scenarios = dataset.folders_root_unread().to_path_buf();
        let sizes = dataset.packed_scenario_sizes()?;
        Ok(Truth {
            dir: dataset.dir.clone(),
            scenarios,
            effects: dataset.record.effects,
            spec: dataset.spec().clone(),
            dataset: Some(dataset),
            sizes,
            keys,
            sweep: false,
            kinds: Vec::new(),
            drawn: None,
            unpacked: None,
        })
    }

    fn identity(&self) -> DatasetIdentity {
        let spec = &self.spec;
        let mut splits = BTreeMap::new();
        for key in &self.keys {
            *splits.entry(key.split.name().to_string()).or_insert(0) += 1;
        }
        DatasetIdentity {
            name: spec.name.clone(),
            world: spec.world.name().to_string(),
            seed: spec.seed,
            spec_sha256: crate::output::manifest::spec_sha256(spec),
            splits,
            kinds: self.kinds.clone(),
        }
    }

    /// `message` naming a file of a packed dataset or sweep by its pack and
    /// member, not by the temporary folder it was unpacked into.
    fn name_unpacked(&self, message: String) -> String {
        match (&self.dataset, &self.unpacked) {
            (Some(dataset), _) => dataset.name_packed_paths(message),
            (None, Some(scratch)) => crate::output::packs::name_unpacked_paths(message, scratch.path(), &self.dir),
            (None, None) => message,
        }
    }

    fn require_graph(&self, graph: GraphKind) -> Result<(), String> {
        if graph != GraphKind::Designed && !self.effects {
            let why = if self.sweep {
                "a counterfactual sweep's factual runs carry the designed graph only"
            } else {
                "it was generated with gen --no-effects (regenerate it without that flag, or use the designed graph)"
            };
            return Err(format!("{} has no {} graph: {why}", self.dir.display(), graph.name()));
        }
        Ok(())
    }
}

/// A packed sweep's pairs without their frames, unpacked into a folder of
/// evaluate's own (`None` for a sweep of pair folders). Errors name the
/// pack.
fn unpack_sweep(sweep: &Sweep) -> Result<Option<crate::output::packs::Scratch>, String> {
    let Some(packs) = sweep.packs() else { return Ok(None) };
    let scratch = crate::output::packs::Scratch::new()?;
    for number in 0..packs.len() {
        let path = packs.path(&sweep.dir, &packs.pack(number));
        if !path.is_file() {
            return Err(format!(
                "{}: missing pack: rerun the counterfactual --sweep command to write it",
                path.display()
            ));
        }
        let keys = packs.keys(&packs.pack(number));
        crate::output::packs::unpack(&path, &keys, scratch.path(), &|name| !name.ends_with(".png"))?;
    }
    Ok(Some(scratch))
}

/// One scored scenario's predictions, checked against its files.
struct ScenarioPredictions {
    key: ScenarioKey,
    group: String,
    split: Split,
    /// The scenario's folder (a sweep pair's factual run).
    dir: PathBuf,
    /// A sweep pair's counterfactual run.
    counterfactual_dir: Option<PathBuf>,
    /// (cars, frames), once read for an array of this scenario.
    size: Option<(usize, usize)>,
    /// A sweep pair's intervention and its effects, once read.
    pair: Option<PairTruth>,
    /// Indexed by [`Predicted`] (in `Predicted::ALL` order).
    arrays: [Option<NamedArray>; 5],
}

/// What a sweep pair's summary.json says the task is scored against.
#[derive(Debug, Clone)]
struct PairTruth {
    /// The first frame that can show the intervention: a predicted
    /// counterfactual starts there.
    frame: usize,
    /// The intervened car (not scored among the affected).
    car: usize,
    /// Per car: its counterfactual moved more than [`EFFECT_THRESHOLD_M`]
    /// from its factual run at some frame (as effects.csv decides).
    affected: Vec<bool>,
}

impl PairTruth {
    /// Reads the summary.json of the pair around `factual_dir`, whose runs
    /// have `cars` cars and `frames` frames: pair `key` of `sweep`, whose
    /// intervention it must record.
    fn read(
        factual_dir: &Path,
        (key, sweep): (&ScenarioKey, Option<&Sweep>),
        frame_interval: f64,
        (cars, frames): (usize, usize),
    ) -> Result<PairTruth, String> {
        let pair = factual_dir.parent().unwrap_or(factual_dir);
        let path = pair.join("summary.json");
        let index = pair.file_name().and_then(|n| n.to_str()).and_then(|n| n.parse::<u64>().ok()).unwrap_or(u64::MAX);
        // The pair's own runs and files, agreeing (an edited or swapped
        // summary.json was scored as written).
        let summary = crate::dataset::pairs::check_pair(pair, (&key.group, key.split.name(), index))?;
        let drawn = match sweep {
            Some(sweep) => Some(sweep.check_drawn(key, &summary).map_err(|e| format!("{}: {e}", path.display()))?),
            None => None,
        };
        // (A summary from before the record: the drawn one, which fired then.)
        let (frame, car) = match summary.intervention.as_ref().or(drawn.as_ref()) {
            Some(record) => (record.frame as usize, record.car as usize),
            None => {
                let t = summary.intervention_time_s.ok_or_else(|| {
                    format!(
                        "{}: the intervention never fired, so there is no counterfactual to predict",
                        path.display()
                    )
                })?;
                // Sweeps from before summary.json named the car: the one
                // that diverged first.
                let first = summary.cars.iter().filter_map(|c| c.first_divergent_frame.map(|f| (f, c.id))).min();
                (event_frame(t, frame_interval) as usize, first.map_or(0, |(_, id)| id as usize))
            }
        };
        let affected: Vec<bool> = summary.cars.iter().map(|c| c.max_divergence_m > EFFECT_THRESHOLD_M).collect();
        if affected.len() != cars || car >= cars || frame >= frames {
            return Err(format!(
                "{}: names {} cars, car {car} and frame {frame}, but its runs have {cars} cars and {frames} frames",
                path.display(),
                affected.len()
            ));
        }
        Ok(PairTruth { frame, car, affected })
    }
}

impl ScenarioPredictions {
    /// (cars, frames) from its scenario.json, read once. A dataset file
    /// that cannot be read is kept in `failure` (the dataset's damage, bad
    /// input once told); the returned message only stops the reader.
    fn size(&mut self, failure: &mut Option<Error>) -> Result<(usize, usize), String> {
        if let Some(size) = self.size {
            return Ok(size);
        }
        // Checked first: an edited scenario.json would size the arrays.
        let read = crate::output::verify_files(&self.dir, &[crate::output::layout::SCENARIO_JSON])
            .and_then(|()| ScenarioSummary::read(&self.dir));
        match read {
            Ok(summary) => Ok(*self.size.insert((summary.cars.len(), summary.frames as usize))),
            Err(e) => {
                *failure = Some(Error::Failure(e.clone()));
                Err(e)
            }
        }
    }

    fn get(&self, what: Predicted) -> Option<&NamedArray> {
        self.arrays[what as usize].as_ref()
    }

    /// The pair's truth (a sweep only), read once; failures as in [`Self::size`].
    fn pair(&mut self, failure: &mut Option<Error>, sweep: Option<&Sweep>) -> Result<&PairTruth, String> {
        if self.pair.is_none() {
            let read = ScenarioSummary::read(&self.dir).and_then(|s| {
                let size = (s.cars.len(), s.frames as usize);
                PairTruth::read(&self.dir, (&self.key, sweep), s.frame_interval, size)
            });
            match read {
                Ok(pair) => self.pair = Some(pair),
                Err(e) => {
                    *failure = Some(Error::Failure(e.clone()));
                    return Err(e);
                }
            }
        }
        self.pair.as_ref().ok_or_else(|| "no pair".to_string())
    }
}

/// What one scenario contributes: per graph, its scored pairs (negated
/// scores, so that lower is more likely, as [`super::metrics`] ranks); the
/// pairs of every frame with the frame count; and its trajectory errors
/// per step.
struct ScenarioResult {
    pairs: Vec<Vec<ScoredPair>>,
    /// Per graph of `pairs`: the linked pairs scored above their unlinked
    /// reverse (ties count half) and how many such pairs there are.
    directions: Vec<Direction>,
    frame_pairs: Option<(Vec<ScoredPair>, usize)>,
    step_errors: Vec<f64>,
    counterfactual_errors: Vec<f64>,
    /// The same over the affected cars only (empty when none is affected).
    counterfactual_affected_errors: Vec<f64>,
    /// A sweep pair's cars but the intervened one: (negated score, affected).
    affected_pairs: Option<Vec<ScoredPair>>,
}

/// Scores the predictions file `predictions` against the dataset (or
/// counterfactual sweep) in `dataset`. Everything wrong with the
/// predictions (an array naming no scenario, a wrong shape, a NaN, a partly
/// scored split, nothing to score) is an [`Error::Input`] naming the file
/// and array; nothing is scored then.
pub fn evaluate(dataset: &Path, predictions: &Path, options: &EvaluateOptions) -> Result<EvaluationReport, Error> {
    if let Some(t) = options.threshold.filter(|t| !t.is_finite()) {
        return Err(Error::Input(format!("--threshold must be a finite number, not {t}")));
    }
    if options.graphs.is_empty() {
        return Err(Error::input("give at least one graph kind to score against"));
    }
    let truth = Truth::open(dataset).map_err(Error::opening)?;
    for &graph in &options.graphs {
        truth.require_graph(graph).map_err(Error::Input)?;
    }
    // A packed dataset's files are named by pack and member, not by where
    // they were unpacked.
    let named = |e: Error| match e {
        Error::Input(m) => Error::Input(truth.name_unpacked(m)),
        // (match_scenarios fails only on the dataset's own files.)
        // (told apart before the unpack folder's name is replaced: it is
        // what tells a write of evaluate's own)
        Error::Failure(m) if Error::is_own_write(&m) => Error::Failure(truth.name_unpacked(m)),
        Error::Failure(m) => Error::damaged(&truth.dir, truth.name_unpacked(m)),
        other => other,
    };
    let ours = truth.identity();
    let mismatch = |theirs: &DatasetIdentity| {
        Error::Input(format!(
            "{}: these predictions were made on {}, and {} is {}: score them against the dataset they were made on",
            predictions.display(),
            theirs.describe(),
            dataset.display(),
            ours.describe()
        ))
    };
    // The record first: predictions made on another dataset are told so,
    // not by the first array that names no scenario here.
    let record = read_npz_array(predictions, DATASET_RECORD, MAX_DATASET_RECORD).ok().flatten();
    if let Some(theirs) = record.and_then(|array| dataset_record(&array)) {
        if !theirs.matches(&ours) {
            return Err(mismatch(&theirs));
        }
    }
    let (scored, record) = match_scenarios(&truth, predictions, options).map_err(named)?;
    let mut warnings = Vec::new();
    match record {
        Some(theirs) if !theirs.matches(&ours) => return Err(mismatch(&theirs)),
        Some(_) => {}
        None => warnings.push(format!(
            "{} does not say which dataset it was made on (no {DATASET_RECORD:?} array), so nothing checks that it \
             belongs to {}: save it with causalcity.save_predictions(..., dataset=...)",
            predictions.display(),
            dataset.display()
        )),
    }
    let results = score_in_turn(&truth, &scored, options).map_err(|e| match e {
        // What a prediction array got wrong, named with its file.
        Error::Input(message) if message.starts_with("array ") => {
            Error::Input(format!("{}: {message}", predictions.display()))
        }
        e => e,
    })?;
    let mut report = summarise(&truth, dataset, predictions, options, &scored, &results);
    report.warnings.splice(0..0, warnings);
    Ok(report)
}

/// The dataset record `array` holds (UTF-8 JSON as uint8), if it is one.
fn dataset_record(array: &NamedArray) -> Option<DatasetIdentity> {
    let bytes: Option<Vec<u8>> =
        array.values.iter().map(|&v| (v.fract() == 0.0 && (0.0..=255.0).contains(&v)).then_some(v as u8)).collect();
    bytes.and_then(|b| serde_json::from_slice::<DatasetIdentity>(&b).ok())
}

/// Pairs every array with its scenario and checks names, shapes, values and
/// coverage.
/// Also returns the file's record of the dataset it was made on, if any.
fn match_scenarios(
    truth: &Truth,
    file: &Path,
    options: &EvaluateOptions,
) -> Result<(Vec<ScenarioPredictions>, Option<DatasetIdentity>), Error> {
    let bad = |message: String| Error::Input(format!("{}: {message}", file.display()));
    let mut by_folder: BTreeMap<String, ScenarioPredictions> = BTreeMap::new();
    let mut order: Vec<String> = Vec::new();
    for key in &truth.keys {
        let folder = key.relative_folder();
        let pair = truth.scenarios.join(&key.group).join(key.split.name()).join(key.folder_name());
        let (dir, counterfactual_dir) =
            if truth.sweep { (pair.join("factual"), Some(pair.join("counterfactual"))) } else { (pair, None) };
        let size = truth.sizes.as_ref().and_then(|sizes| sizes.get(&folder).copied());
        order.push(folder.clone());
        by_folder.insert(
            folder,
            ScenarioPredictions {
                key: key.clone(),
                group: key.group.clone(),
                split: key.split,
                dir,
                counterfactual_dir,
                size,
                pair: None,
                arrays: Default::default(),
            },
        );
    }
    let example = order.first().cloned().unwrap_or_else(|| "<group>/<split>/<index>".to_string());
    let unknown = |name: &str| {
        format!(
            "array {name:?} names no scenario of {}: name arrays by scenario folder, e.g. {example} (edge scores), \
             {example}{TRAJECTORY_SUFFIX} (a predicted trajectory), {example}{PER_FRAME_SUFFIX} (per-frame edge \
             scores), or for a sweep {example}{COUNTERFACTUAL_SUFFIX} (a counterfactual trajectory) and \
             {example}{AFFECTED_SUFFIX} (affected-car scores)",
            truth.dir.display()
        )
    };
    // Each array may hold no more values than its scenario's cars and
    // frames allow: the reader is capped by that, whatever the file
    // declares. The cap leaves room (x4, plus 4,096 values) so that a shape
    // that is merely wrong is read and told its right shape below.
    let mut failure = None;
    let arrays = read_npz(file, |name| {
        if name == DATASET_RECORD {
            return Ok(MAX_DATASET_RECORD);
        }
        let (folder, what) = Predicted::of(name);
        let scenario = by_folder.get_mut(folder).ok_or_else(|| unknown(name))?;
        let (cars, frames) = scenario.size(&mut failure)?;
        let (cars, frames) = (cars as u64, frames as u64);
        let expected = match what {
            Predicted::Edges => cars * cars,
            Predicted::PerFrame => frames * cars * cars,
            Predicted::Trajectory | Predicted::Counterfactual => frames * cars * 2,
            Predicted::Affected => cars,
        };
        Ok(expected.saturating_mul(SHAPE_SLACK).saturating_add(SHAPE_SLACK_VALUES))
    });
    if let Some(failure) = failure {
        return Err(failure);
    }
    let mut arrays = arrays.map_err(Error::Input)?;
    let record = match arrays.iter().position(|a| a.name == DATASET_RECORD) {
        None => None,
        Some(at) => {
            let array = arrays.remove(at);
            Some(dataset_record(&array).ok_or_else(|| {
                bad(format!(
                    "array {DATASET_RECORD:?} is not the dataset record save_predictions writes (UTF-8 JSON as uint8)"
                ))
            })?)
        }
    };
    if arrays.is_empty() {
        return Err(bad("holds no arrays: save one [cars, cars] array of edge scores per scenario, named by its \
                        folder (e.g. cars08_edges50/test/00000)"
            .to_string()));
    }
    let world = truth.spec.world;
    for array in arrays {
        let (folder, what) = Predicted::of(&array.name);
        let Some(scenario) = by_folder.get_mut(folder) else {
            return Err(bad(unknown(&array.name)));
        };
        if what == Predicted::PerFrame && world != WorldKind::City {
            return Err(bad(format!(
                "array {:?}: per-frame graphs come from interactions.csv, which only the city world writes; this \
                 dataset is {}-world",
                array.name,
                world.name()
            )));
        }
        if matches!(what, Predicted::Counterfactual | Predicted::Affected) && !truth.sweep {
            return Err(bad(format!(
                "array {:?}: {} are scored against a counterfactual --sweep output, and {} is a gen dataset",
                array.name,
                what.what(),
                truth.dir.display()
            )));
        }
        let (cars, frames) = scenario.size.expect("read for the reader's cap");
        let shape = &array.shape;
        match what {
            Predicted::Affected if shape.as_slice() != [cars] => {
                return Err(bad(format!(
                    "array {:?} has shape {shape:?}; affected-car scores of this pair are [{cars}] (a score per car \
                     that the intervention moves it)",
                    array.name
                )));
            }
            Predicted::Counterfactual => {
                let fits = shape.len() == 3 && shape[1] == cars && shape[2] == 2 && shape[0] >= 1;
                if !fits {
                    return Err(bad(format!(
                        "array {:?} has shape {shape:?}; a predicted counterfactual of this pair is [steps, {cars}, \
                         2] (steps >= 1; px, py in bird's-eye pixels from the intervention's frame on)",
                        array.name
                    )));
                }
                let mut failure = None;
                let start = scenario
                    .pair(&mut failure, truth.drawn.as_ref())
                    .map_err(|e| failure.unwrap_or(Error::Failure(e)))?
                    .frame;
                if start.saturating_add(shape[0]) > frames {
                    return Err(bad(format!(
                        "array {:?} predicts {} steps from the intervention's frame {start}, but the pair has \
                         {frames} frames: predict at most {}",
                        array.name,
                        shape[0],
                        frames.saturating_sub(start)
                    )));
                }
            }
            Predicted::Trajectory => {
                let fits = shape.len() == 3 && shape[1] == cars && shape[2] == 2 && shape[0] >= 1;
                if !fits {
                    return Err(bad(format!(
                        "array {:?} has shape {shape:?}; a predicted trajectory of this scenario is [steps, {cars}, \
                         2] (steps >= 1; px, py in bird's-eye pixels)",
                        array.name
                    )));
                }
                if options.history.checked_add(shape[0]).is_none_or(|end| end > frames) {
                    // A shorter history helps only while one frame of it is left.
                    let history = frames.saturating_sub(shape[0]);
                    let or_history =
                        if history >= 1 { format!(", or give --history at most {history}") } else { String::new() };
                    return Err(bad(format!(
                        "array {:?} predicts {} steps after {} frames of history, but the scenario has {frames} \
                         frames: predict at most {} steps{or_history}",
                        array.name,
                        shape[0],
                        options.history,
                        frames.saturating_sub(options.history),
                    )));
                }
            }
            Predicted::PerFrame if shape.as_slice() != [frames, cars, cars] => {
                return Err(bad(format!(
                    "array {:?} has shape {shape:?}; per-frame edge scores of this scenario are [{frames}, {cars}, \
                     {cars}] ([t, i, j]: car i bound car j's speed at frame t)",
                    array.name
                )));
            }
            Predicted::Edges if shape.as_slice() != [cars, cars] => {
                return Err(bad(format!(
                    "array {:?} has shape {shape:?}; edge scores of this scenario are [{cars}, {cars}] ([i, j]: car \
                     i leads car j)",
                    array.name
                )));
            }
            Predicted::Edges | Predicted::PerFrame | Predicted::Affected => {}
        }
        // The scores that are ignored (a graph's diagonal, the intervened
        // car's own affected score) may be anything, NaN included.
        let intervened = match what {
            Predicted::Affected => {
                let mut failure = None;
                Some(
                    scenario
                        .pair(&mut failure, truth.drawn.as_ref())
                        .map_err(|e| failure.unwrap_or(Error::Failure(e)))?
                        .car,
                )
            }
            _ => None,
        };
        let graph_like = matches!(what, Predicted::Edges | Predicted::PerFrame);
        let off_diagonal = |i: usize| !graph_like || (i % (cars * cars)) / cars != i % cars;
        let scored = |i: usize| off_diagonal(i) && intervened != Some(i);
        if let Some(i) = (0..array.values.len()).find(|&i| scored(i) && !array.values[i].is_finite()) {
            let mut index = Vec::new();
            let mut rest = i;
            for &n in shape.iter().rev() {
                index.push(rest % n);
                rest /= n;
            }
            index.reverse();
            return Err(bad(format!(
                "array {:?} holds {} at {index:?}: every score must be a finite number",
                array.name, array.values[i]
            )));
        }
        scenario.arrays[what as usize] = Some(array);
    }
    // Coverage: a group and split scored in part is an error.
    for what in Predicted::ALL {
        let mut splits: BTreeMap<(String, &'static str), (usize, Vec<&str>)> = BTreeMap::new();
        for folder in &order {
            let s = &by_folder[folder];
            let entry = splits.entry((s.group.clone(), s.split.name())).or_default();
            if s.get(what).is_some() {
                entry.0 += 1;
            } else {
                entry.1.push(folder);
            }
        }
        // A trajectory's steps ahead are the same for every scenario of a
        // split: the error at a step is a mean over the split's scenarios
        // (with one scenario predicting further, its steps were scored from
        // it alone).
        if what == Predicted::Trajectory {
            let mut steps_of: BTreeMap<(String, &'static str), (usize, &str)> = BTreeMap::new();
            for folder in &order {
                let s = &by_folder[folder];
                let Some(array) = s.get(what) else { continue };
                let steps = array.shape[0];
                let (first, named) = *steps_of.entry((s.group.clone(), s.split.name())).or_insert((steps, folder));
                if steps != first {
                    return Err(bad(format!(
                        "array {:?} predicts {steps} steps and {named:?} {first}: predict the same steps for every \
                         scenario of {}/{}",
                        array.name,
                        s.group,
                        s.split.name()
                    )));
                }
            }
        }
        // A counterfactual's steps likewise, but for a pair whose run ends
        // sooner: it predicts up to its last frame (a pair cut short was
        // left out of the later steps' means, or one predicting further
        // was scored alone there).
        if what == Predicted::Counterfactual {
            let mut longest: BTreeMap<(String, &'static str), (usize, &str)> = BTreeMap::new();
            for folder in &order {
                let s = &by_folder[folder];
                let Some(array) = s.get(what) else { continue };
                let entry = longest.entry((s.group.clone(), s.split.name())).or_insert((0, folder));
                if array.shape[0] > entry.0 {
                    *entry = (array.shape[0], folder);
                }
            }
            for folder in &order {
                let s = &by_folder[folder];
                let (Some(array), Some(pair), Some((_, frames))) = (s.get(what), s.pair.as_ref(), s.size) else {
                    continue;
                };
                let (horizon, named) = longest[&(s.group.clone(), s.split.name())];
                let expected = horizon.min(frames.saturating_sub(pair.frame));
                if array.shape[0] != expected {
                    return Err(bad(format!(
                        "array {:?} predicts {} steps from the intervention's frame {} of {frames}, and {named:?} \
                         {horizon}: predict the same steps for every pair of {}/{} ({expected} for this one; fewer \
                         only where a pair's run ends)",
                        array.name,
                        array.shape[0],
                        pair.frame,
                        s.group,
                        s.split.name()
                    )));
                }
            }
        }
        for ((group, split), (present, missing)) in splits {
            if present > 0 && !missing.is_empty() {
                return Err(bad(format!(
                    "has {} for {present} of the {} scenarios of {group}/{split}; missing {} (first {:?}): score \
                     every scenario of a split, or none",
                    what.what(),
                    present + missing.len(),
                    missing.len(),
                    missing[0]
                )));
            }
        }
    }
    let scored = order
        .into_iter()
        .filter_map(|folder| by_folder.remove(&folder))
        .filter(|s| s.arrays.iter().any(Option::is_some))
        .collect();
    Ok((scored, record))
}

/// Scores every scenario, a group's split at a time (the run of `scored`
/// that shares one), each split's folders there only while it is scored:
/// a packed dataset holds one split in TMPDIR.
fn score_in_turn(
    truth: &Truth,
    scored: &[ScenarioPredictions],
    options: &EvaluateOptions,
) -> Result<Vec<ScenarioResult>, Error> {
    let score = |run: &[ScenarioPredictions]| -> Result<Vec<ScenarioResult>, Error> {
        // Nothing is scored against a file that changed after it was written.
        // Nor through a linked folder below a sweep (validate names one; a
        // `gen` dataset's were refused as it was opened, by
        // `Dataset::open_complete`).
        if let Some(link) = run.iter().filter(|_| truth.sweep).find_map(|s| linked_truth(s, &truth.scenarios)) {
            return Err(Error::Input(crate::output::linked_folder_error(&link)));
        }
        run.par_iter().try_for_each(verify_truth).map_err(|e| Error::damaged(&truth.dir, truth.name_unpacked(e)))?;
        let scores: Result<Vec<ScenarioResult>, String> =
            run.par_iter().map(|s| score_scenario(s, truth, options)).collect();
        scores.map_err(|e| Error::Input(truth.name_unpacked(e)))
    };
    let Some(dataset) = &truth.dataset else { return score(scored) };
    let mut results = Vec::with_capacity(scored.len());
    for run in scored.chunk_by(|a, b| a.group == b.group && a.split == b.split) {
        let (group, split) = (&run[0].group, run[0].split);
        // Unpacked here (the folders' paths are the run's own); a failure to
        // unpack is the dataset's, a bad score the input's.
        dataset.scenario_dirs(group, split).map_err(|e| Error::reading(&truth.dir, e))?;
        let scores = score(run);
        dataset.release(group, split).map_err(Error::Failure)?;
        results.extend(scores?);
    }
    Ok(results)
}

/// Checks every file of scenario `s` that [`score_scenario`] reads against
/// its folder's checksums: its `scenario.json` (the graphs), and the
/// `interactions.csv` and `poses.csv` its predictions are scored against
/// (a counterfactual's in the pair's counterfactual run). An edited graph
/// was scored as written, exit 0 (AUROC 0.364 became 1.000); `validate`
/// alone named it.
fn verify_truth(s: &ScenarioPredictions) -> Result<(), String> {
    let mut files = vec![crate::output::layout::SCENARIO_JSON];
    if s.get(Predicted::PerFrame).is_some() {
        files.push(INTERACTIONS_CSV);
    }
    if s.get(Predicted::Trajectory).is_some() {
        files.push(crate::output::layout::POSES_CSV);
    }
    crate::output::verify_files(&s.dir, &files)?;
    if let (Some(dir), Some(_)) = (&s.counterfactual_dir, s.get(Predicted::Counterfactual)) {
        let files = [crate::output::layout::SCENARIO_JSON, crate::output::layout::POSES_CSV];
        crate::output::verify_files(dir, &files)?;
    }
    Ok(())
}

/// The first linked folder below the dataset's `root` on the way to scenario
/// `s`'s folders (a pair's runs included), if any.
fn linked_truth(s: &ScenarioPredictions, root: &Path) -> Option<PathBuf> {
    [Some(&s.dir), s.counterfactual_dir.as_ref()]
        .into_iter()
        .flatten()
        .find_map(|dir| crate::output::linked_below(root, dir))
}

/// Reads one scenario's truth and scores its predictions.
fn score_scenario(s: &ScenarioPredictions, truth: &Truth, options: &EvaluateOptions) -> Result<ScenarioResult, String> {
    let summary = ScenarioSummary::read(&s.dir)?;
    let (frames, cars) = (summary.frames as usize, summary.cars.len());
    let off_diagonal = |i: &usize| i / cars != i % cars;
    let (mut pairs, mut directions) = (Vec::new(), Vec::new());
    if let Some(scores) = s.get(Predicted::Edges) {
        for &graph in &options.graphs {
            let graph = if graph == GraphKind::Designed {
                summary.clone()
            } else {
                ScenarioSummary::read_graph(&s.dir, graph)?
            };
            let mut linked = vec![false; cars * cars];
            for [a, b] in &graph.graph {
                linked[*a as usize * cars + *b as usize] = true;
            }
            pairs.push((0..cars * cars).filter(off_diagonal).map(|i| (-scores.values[i], linked[i])).collect());
            directions.push(direction_of(&scores.values, &linked, cars));
        }
    }
    let frame_pairs = match s.get(Predicted::PerFrame) {
        None => None,
        Some(scores) => {
            let records = read_interactions(&s.dir.join(INTERACTIONS_CSV), frames, cars)?;
            let mut scored = Vec::with_capacity(frames * cars * cars.saturating_sub(1));
            for t in 0..frames {
                let at = t * cars * cars;
                for i in (0..cars * cars).filter(off_diagonal) {
                    let (cause, effect) = (i / cars, i % cars);
                    let linked = records[t * cars + effect].other_car == Some(cause);
                    scored.push((-scores.values[at + i], linked));
                }
            }
            Some((scored, frames))
        }
    };
    let image = &truth.spec.image;
    let size = (image.width as f64, image.height as f64);
    let mut step_errors = Vec::new();
    if let Some(predicted) = s.get(Predicted::Trajectory) {
        let poses = PoseLog::read(&s.dir, frames, cars)?;
        step_errors = trajectory_errors(predicted, &poses, options.history, size, None)?;
    }
    let (mut counterfactual_errors, mut counterfactual_affected_errors) = (Vec::new(), Vec::new());
    let mut affected_pairs = None;
    if let (Some(pair), Some(dir)) = (&s.pair, &s.counterfactual_dir) {
        if let Some(predicted) = s.get(Predicted::Counterfactual) {
            let poses = PoseLog::read(dir, frames, cars)?;
            counterfactual_errors = trajectory_errors(predicted, &poses, pair.frame, size, None)?;
            counterfactual_affected_errors =
                trajectory_errors(predicted, &poses, pair.frame, size, Some(&pair.affected))?;
        }
        if let Some(scores) = s.get(Predicted::Affected) {
            let others = (0..cars).filter(|&c| c != pair.car);
            affected_pairs = Some(others.map(|c| (-scores.values[c], pair.affected[c])).collect());
        }
    }
    Ok(ScenarioResult {
        pairs,
        directions,
        frame_pairs,
        step_errors,
        counterfactual_errors,
        counterfactual_affected_errors,
        affected_pairs,
    })
}

/// A scenario's linked pairs a -> b whose reverse is not linked, counted
/// against their reverse's score: (pairs scored above it, plus half of
/// those tied with it; such pairs). `scores` and `linked` are row-major
/// [cars x cars], row the cause.
fn direction_of(scores: &[f64], linked: &[bool], cars: usize) -> Direction {
    let mut direction = Direction::default();
    for (a, b) in (0..cars).flat_map(|a| (0..cars).map(move |b| (a, b))).filter(|(a, b)| a != b) {
        let (forward, reverse) = (a * cars + b, b * cars + a);
        if linked[forward] && !linked[reverse] {
            direction.pairs += 1;
            direction.right += match scores[forward].partial_cmp(&scores[reverse]) {
                Some(std::cmp::Ordering::Greater) => 1.0,
                Some(std::cmp::Ordering::Equal) => 0.5,
                _ => 0.0,
            };
        }
    }
    direction
}

/// Linked pairs scored above their unlinked reverse (ties count half) out
/// of how many such pairs: summed over scenarios, then divided.
#[derive(Debug, Clone, Copy, Default)]
struct Direction {
    right: f64,
    pairs: usize,
}

impl Direction {
    fn add(&mut self, other: Direction) {
        self.right += other.right;
        self.pairs += other.pairs;
    }

    fn share(&self) -> Option<f64> {
        (self.pairs > 0).then(|| self.right / self.pairs as f64)
    }
}

/// A threshold in the table's 9 columns: 4 decimals, or in exponent form
/// where those would show nothing or overflow the column (a threshold of
/// -1e-9 printed `-0.0000`, one near 1e300 all its digits).
fn shown_threshold(t: f64) -> String {
    const COLUMN: usize = 9;
    if t == 0.0 {
        return "0.0000".to_string();
    }
    let fixed = format!("{t:.4}");
    if t.abs() >= 1e-3 && fixed.len() <= COLUMN {
        return fixed;
    }
    [format!("{t:.2e}"), format!("{t:.1e}")]
        .into_iter()
        .find(|s| s.len() <= COLUMN)
        .unwrap_or_else(|| format!("{t:.0e}"))
}

/// The normalised squared error of a predicted `[steps, cars, 2]`
/// trajectory against `poses` at each step after `history`, over the cars
/// on the map (a removed car is parked off it and not scored). A step at
/// which no counted car is on the map has no error (NaN, skipped by the
/// means); with none at any step the scenario is not scored (empty): the
/// removed intervened car alone among the affected cars scored a perfect
/// 0 whatever was predicted. A position so far off that its error
/// overflows is refused, naming the array: an infinite error would read as
/// "not scored" in the JSON report.
fn trajectory_errors(
    predicted: &NamedArray,
    poses: &PoseLog,
    history: usize,
    (w, h): (f64, f64),
    only: Option<&[bool]>,
) -> Result<Vec<f64>, String> {
    let (steps, cars) = (predicted.shape[0], predicted.shape[1]);
    let counted = |car: usize| only.is_none_or(|only| only[car]);
    if !(0..cars).any(counted) {
        return Ok(Vec::new());
    }
    let errors: Vec<Option<f64>> = (0..steps)
        .map(|step| {
            let (mut total, mut scored) = (0.0, 0usize);
            for car in (0..cars).filter(|&c| counted(c)) {
                let truth = poses.at(history + step, car);
                if CarState::is_parked_at(truth.x, truth.y) {
                    continue;
                }
                let at = (step * cars + car) * 2;
                let (dx, dy) = ((predicted.values[at] - truth.px) / w, (predicted.values[at + 1] - truth.py) / h);
                total += (dx * dx + dy * dy) / 2.0;
                scored += 1;
            }
            // Every counted car off the map: nothing was left to predict.
            (scored > 0).then(|| total / scored as f64)
        })
        .collect();
    let Some(last) = errors.iter().rposition(Option::is_some) else { return Ok(Vec::new()) };
    let errors: Vec<f64> = errors[..=last].iter().map(|e| e.unwrap_or(f64::NAN)).collect();
    match errors.iter().position(|e| e.is_infinite()) {
        None => Ok(errors),
        Some(step) => {
            let worst = predicted.values[step * cars * 2..(step + 1) * cars * 2].iter().fold(0.0f64, |worst, v| {
                if v.abs() > worst.abs() {
                    *v
                } else {
                    worst
                }
            });
            Err(format!(
                "array {:?}: its squared error at step {} overflows (it predicts a position of {worst:e} pixels): \
                 predict positions of the image's scale",
                predicted.name,
                step + 1
            ))
        }
    }
}

/// Mean and standard error (None for fewer than two values).
fn mean_se(values: &[f64]) -> (f64, Option<f64>) {
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let se = (values.len() > 1).then(|| {
        let var = values.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / (n - 1.0);
        (var / n).sqrt()
    });
    (mean, se)
}

/// The threshold for one graph and group: given, else the best F1 on val's
/// pairs, else (val scored but holding no true link, where F1 picks
/// nothing) the best F1 on every group's val pooled, as `baseline` does,
/// else 0.5. A group without a link in val took 0.5 and was told it had no
/// val predictions.
fn threshold_for(
    options: &EvaluateOptions,
    val_pairs: &[ScoredPair],
    pooled_val: &[ScoredPair],
) -> (f64, &'static str) {
    if let Some(t) = options.threshold {
        return (t, "given");
    }
    // The metrics rank negated scores: negate back.
    if let Some(t) = best_threshold(val_pairs) {
        return (-t, "val");
    }
    match best_threshold(pooled_val) {
        Some(t) if !val_pairs.is_empty() => (-t, "pooled"),
        _ => (0.5, "default"),
    }
}

/// A scenario's scored pairs of one graph and how many graphs they span
/// (1, or the frames of a per-frame graph), for SHD per graph.
/// With its direction counts ([`Direction`]; none counted for the
/// per-frame and affected-car graphs).
type GraphPairs<'a> = (&'a [ScoredPair], usize, Direction);

/// One split's scores over every group: every pair, each scenario's F1
/// and SHD, the counts at each group's threshold, the groups scored and
/// the direction counts.
type Pooled = (Vec<ScoredPair>, Vec<f64>, Vec<f64>, Counts, usize, Direction);

/// Edge rows of one graph for every group and split that has its scores.
fn edge_rows<'a>(
    graph: &'static str,
    truth: &Truth,
    options: &EvaluateOptions,
    scored: &[ScenarioPredictions],
    results: &'a [ScenarioResult],
    pairs_of: impl Fn(&'a ScenarioResult) -> Option<GraphPairs<'a>>,
) -> (Vec<EdgeScores>, Vec<OverallScores>) {
    let mut rows = Vec::new();
    let mut pooled: [Pooled; 3] = Default::default();
    let pooled_val: Vec<ScoredPair> = scored
        .iter()
        .zip(results)
        .filter(|(s, _)| s.split == Split::Val)
        .filter_map(|(_, r)| pairs_of(r))
        .flat_map(|(p, _, _)| p.iter().copied())
        .collect();
    for group in &truth.spec.groups {
        let name = group.name();
        let in_split = |split: Split| -> Vec<GraphPairs<'a>> {
            scored
                .iter()
                .zip(results)
                .filter(|(s, _)| s.group == name && s.split == split)
                .filter_map(|(_, r)| pairs_of(r))
                .collect()
        };
        let val: Vec<ScoredPair> = in_split(Split::Val).iter().flat_map(|(p, _, _)| p.iter().copied()).collect();
        let (threshold, threshold_from) = threshold_for(options, &val, &pooled_val);
        for split in Split::ALL {
            let scenarios = in_split(split);
            if scenarios.is_empty() {
                continue;
            }
            let all: Vec<ScoredPair> = scenarios.iter().flat_map(|(p, _, _)| p.iter().copied()).collect();
            let per_scenario: Vec<(Counts, usize)> =
                scenarios.iter().map(|(p, graphs, _)| (Counts::at(p, -threshold), *graphs)).collect();
            let mut direction = Direction::default();
            for (_, _, d) in &scenarios {
                direction.add(*d);
            }
            let f1s: Vec<f64> = per_scenario.iter().map(|(c, _)| c.f1().unwrap_or(1.0)).collect();
            let shds: Vec<f64> = per_scenario
                .iter()
                .map(|(c, graphs)| (c.false_positives + c.false_negatives) as f64 / *graphs as f64)
                .collect();
            let counts = Counts::at(&all, -threshold);
            let pool = &mut pooled[split.index()];
            pool.0.extend_from_slice(&all);
            pool.1.extend_from_slice(&f1s);
            pool.2.extend_from_slice(&shds);
            pool.3.true_positives += counts.true_positives;
            pool.3.false_positives += counts.false_positives;
            pool.3.false_negatives += counts.false_negatives;
            pool.4 += 1;
            pool.5.add(direction);
            let (f1, f1_se) = mean_se(&f1s);
            let (shd, shd_se) = mean_se(&shds);
            rows.push(EdgeScores {
                graph,
                group: name.clone(),
                cars: truth.spec.group_of(split, group).cars,
                edge_proportion: group.edge_proportion,
                split: split.name(),
                held_out: truth.spec.held_out.of(split).is_some(),
                scenarios: scenarios.len(),
                pairs: all.len(),
                true_edges: counts.true_positives + counts.false_negatives,
                predicted_edges: counts.true_positives + counts.false_positives,
                threshold,
                threshold_from,
                precision: counts.precision(),
                recall: counts.recall(),
                f1,
                f1_se,
                auroc: auroc(&all),
                auprc: average_precision(&all),
                direction: direction.share(),
                shd,
                shd_se,
            });
        }
    }
    let mut overall = Vec::new();
    for (split, (all, f1s, shds, counts, groups, direction)) in Split::ALL.into_iter().zip(pooled) {
        if groups < 2 {
            continue;
        }
        let (f1, f1_se) = mean_se(&f1s);
        let (shd, shd_se) = mean_se(&shds);
        overall.push(OverallScores {
            graph,
            split: split.name(),
            held_out: truth.spec.held_out.of(split).is_some(),
            groups,
            scenarios: f1s.len(),
            pairs: all.len(),
            true_edges: counts.true_positives + counts.false_negatives,
            predicted_edges: counts.true_positives + counts.false_positives,
            precision: counts.precision(),
            recall: counts.recall(),
            f1,
            f1_se,
            auroc: auroc(&all),
            auprc: average_precision(&all),
            direction: direction.share(),
            shd,
            shd_se,
        });
    }
    (rows, overall)
}

/// Error rows per group and split from each scenario's per-step errors.
fn trajectory_rows(
    truth: &Truth,
    scored: &[ScenarioPredictions],
    results: &[ScenarioResult],
    errors_of: impl Fn(&ScenarioResult) -> &[f64],
) -> Vec<TrajectoryScores> {
    let mut rows = Vec::new();
    for group in &truth.spec.groups {
        let name = group.name();
        for split in Split::ALL {
            let errors: Vec<&[f64]> = scored
                .iter()
                .zip(results)
                .filter(|(s, r)| s.group == name && s.split == split && !errors_of(r).is_empty())
                .map(|(_, r)| errors_of(r))
                .collect();
            let longest = errors.iter().map(|e| e.len()).max().unwrap_or(0);
            let steps = (0..longest)
                .map(|k| {
                    // (NaN: no car to score at that step.)
                    let at_step: Vec<f64> =
                        errors.iter().filter_map(|e| e.get(k).copied().filter(|v| !v.is_nan())).collect();
                    let (mse, se) = mean_se(&at_step);
                    StepError { step: k + 1, mse, se, scenarios: at_step.len() }
                })
                .filter(|step| step.scenarios > 0)
                .collect::<Vec<_>>();
            if !steps.is_empty() {
                rows.push(TrajectoryScores {
                    group: name.clone(),
                    cars: truth.spec.group_of(split, group).cars,
                    edge_proportion: group.edge_proportion,
                    split: split.name(),
                    scenarios: errors.len(),
                    steps,
                });
            }
        }
    }
    rows
}

fn summarise(
    truth: &Truth,
    dataset: &Path,
    predictions: &Path,
    options: &EvaluateOptions,
    scored: &[ScenarioPredictions],
    results: &[ScenarioResult],
) -> EvaluationReport {
    let spec = &truth.spec;
    let (mut edges, mut overall, mut per_scenario) = (Vec::new(), Vec::new(), Vec::new());
    for (g, &graph) in options.graphs.iter().enumerate() {
        let (rows, all) = edge_rows(graph.name(), truth, options, scored, results, |r| graph_pairs(r, g));
        per_scenario
            .extend(scenario_rows(graph.name(), &truth.scenarios, &rows, scored, results, |r| graph_pairs(r, g)));
        edges.extend(rows);
        overall.extend(all);
    }
    let (rows, all) = edge_rows(PER_FRAME_GRAPH, truth, options, scored, results, frame_pairs);
    per_scenario.extend(scenario_rows(PER_FRAME_GRAPH, &truth.scenarios, &rows, scored, results, frame_pairs));
    edges.extend(rows);
    overall.extend(all);
    let (rows, all) = edge_rows(AFFECTED_GRAPH, truth, options, scored, results, affected_pairs);
    per_scenario.extend(scenario_rows(AFFECTED_GRAPH, &truth.scenarios, &rows, scored, results, affected_pairs));
    edges.extend(rows);
    overall.extend(all);
    // Scenarios with trajectories and no edge scores still get a row.
    let trajectory_only = scored
        .iter()
        .zip(results)
        .filter(|(_, r)| r.pairs.is_empty() && r.frame_pairs.is_none() && r.affected_pairs.is_none());
    let trajectory_only =
        trajectory_only.filter(|(_, r)| !r.step_errors.is_empty() || !r.counterfactual_errors.is_empty());
    per_scenario.extend(trajectory_only.map(|(s, r)| scenario_base(&truth.scenarios, s, r)));
    per_scenario.sort_by(|a, b| (a.scenario.as_str(), a.graph).cmp(&(b.scenario.as_str(), b.graph)));
    // Rows by where their threshold came from, and whether val was scored.
    let rows_from = |from: &str, val_scored: bool| -> Vec<String> {
        let val_rows: std::collections::BTreeSet<(&str, &str)> =
            edges.iter().filter(|e| e.split == Split::Val.name()).map(|e| (e.group.as_str(), e.graph)).collect();
        edges
            .iter()
            .filter(|e| e.threshold_from == from && val_rows.contains(&(e.group.as_str(), e.graph)) == val_scored)
            .map(|e| format!("{} {}", e.group, e.graph))
            .collect::<std::collections::BTreeSet<_>>()
            .into_iter()
            .collect()
    };
    let mut warnings = Vec::new();
    let untuned = rows_from("default", false);
    if !untuned.is_empty() {
        warnings.push(format!(
            "NO VAL PREDICTIONS for {}: their F1, precision, recall and SHD use a fixed threshold of 0.5, which \
             means something only for probabilities. Read AUROC and AUPRC (threshold-free), save val predictions \
             (the threshold is then the best F1 on val), or give --threshold",
            untuned.join(", ")
        ));
    }
    let unlinked = rows_from("default", true);
    if !unlinked.is_empty() {
        warnings.push(format!(
            "NO TRUE LINK IN VAL for {}, nor in any group's val: no F1 on val picks a threshold, so their F1, \
             precision, recall and SHD use a fixed threshold of 0.5, which means something only for probabilities. \
             Read AUROC and AUPRC (threshold-free), or give --threshold",
            unlinked.join(", ")
        ));
    }
    let pooled = rows_from("pooled", true);
    if !pooled.is_empty() {
        warnings.push(format!(
            "no true link in val for {}: their threshold is the best F1 on every group's val pooled (threshold \
             \"pooled\")",
            pooled.join(", ")
        ));
    }
    EvaluationReport {
        warnings,
        dataset: dataset.display().to_string(),
        predictions: predictions.display().to_string(),
        world: spec.world.name().to_string(),
        image_size: [spec.image.width, spec.image.height],
        history_frames: options.history,
        edges,
        overall,
        trajectories: trajectory_rows(truth, scored, results, |r| &r.step_errors),
        counterfactuals: trajectory_rows(truth, scored, results, |r| &r.counterfactual_errors),
        counterfactuals_affected: trajectory_rows(truth, scored, results, |r| &r.counterfactual_affected_errors),
        per_scenario,
    }
}

/// A scenario's scored pairs of graph `g` (one graph counted).
fn graph_pairs(r: &ScenarioResult, g: usize) -> Option<GraphPairs<'_>> {
    r.pairs.get(g).map(|p| (p.as_slice(), 1, r.directions[g]))
}

/// A sweep pair's affected-car scores (one "graph" of cars).
fn affected_pairs(r: &ScenarioResult) -> Option<GraphPairs<'_>> {
    r.affected_pairs.as_ref().map(|p| (p.as_slice(), 1, Direction::default()))
}

/// A scenario's scored pairs of every frame, with the frames counted as graphs.
fn frame_pairs(r: &ScenarioResult) -> Option<GraphPairs<'_>> {
    r.frame_pairs.as_ref().map(|(p, frames)| (p.as_slice(), *frames, Direction::default()))
}

/// A scenario's row with its name, group, split and trajectory errors
/// filled in and no edge scores.
/// `scenarios`: the folder the scenario folders are under ([`Truth::scenarios`]).
fn scenario_base(scenarios: &Path, s: &ScenarioPredictions, r: &ScenarioResult) -> ScenarioScores {
    let mean = |errors: &[f64]| {
        let scored: Vec<f64> = errors.iter().copied().filter(|e| !e.is_nan()).collect();
        (!scored.is_empty()).then(|| scored.iter().sum::<f64>() / scored.len() as f64)
    };
    let name = s.dir.strip_prefix(scenarios).unwrap_or(&s.dir);
    // A sweep pair's factual run sits one folder below the pair.
    let name = if s.counterfactual_dir.is_some() { name.parent().unwrap_or(name) } else { name };
    ScenarioScores {
        scenario: name.to_string_lossy().replace('\\', "/"),
        group: s.group.clone(),
        split: s.split.name(),
        graph: "",
        cars: s.size.map_or(0, |(cars, _)| cars),
        threshold: None,
        true_edges: 0,
        predicted_edges: 0,
        true_positives: 0,
        precision: None,
        recall: None,
        f1: None,
        shd: None,
        auroc: None,
        direction: None,
        trajectory_mse: mean(&r.step_errors),
        counterfactual_mse: mean(&r.counterfactual_errors),
    }
}

/// Per-scenario rows of one graph, each at its group's threshold (from the
/// group rows `rows`).
fn scenario_rows<'a>(
    graph: &'static str,
    dataset: &Path,
    rows: &[EdgeScores],
    scored: &[ScenarioPredictions],
    results: &'a [ScenarioResult],
    pairs_of: impl Fn(&'a ScenarioResult) -> Option<GraphPairs<'a>>,
) -> Vec<ScenarioScores> {
    let mut out = Vec::new();
    for (s, r) in scored.iter().zip(results) {
        let (Some((pairs, graphs, direction)), Some(row)) = (pairs_of(r), rows.iter().find(|e| e.group == s.group))
        else {
            continue;
        };
        let counts = Counts::at(pairs, -row.threshold);
        out.push(ScenarioScores {
            graph,
            threshold: Some(row.threshold),
            true_edges: counts.true_positives + counts.false_negatives,
            predicted_edges: counts.true_positives + counts.false_positives,
            true_positives: counts.true_positives,
            precision: counts.precision(),
            recall: counts.recall(),
            f1: Some(counts.f1().unwrap_or(1.0)),
            shd: Some((counts.false_positives + counts.false_negatives) as f64 / graphs as f64),
            auroc: auroc(pairs),
            direction: direction.share(),
            ..scenario_base(dataset, s, r)
        });
    }
    out
}

/// A number for a table or CSV cell ("" / "-" for none): six decimals, or
/// seven significant digits in exponent form below 0.001 (normalised
/// trajectory errors are about 1e-5, which six decimals would cut to one
/// or two digits).
fn cell(value: Option<f64>, none: &str) -> String {
    value.map_or(none.to_string(), |v| if v != 0.0 && v.abs() < 1e-3 { format!("{v:.6e}") } else { format!("{v:.6}") })
}

/// The header of `evaluate --csv` (one row per value).
pub const TABLE_CSV_HEADER: &str = "group,cars,edge_proportion,split,graph,metric,step,value,se,scenarios";

/// The header of `evaluate --per-scenario` (one row per scenario and graph).
pub const PER_SCENARIO_CSV_HEADER: &str = "scenario,group,split,graph,cars,threshold,true_edges,predicted_edges,\
                                           true_positives,precision,recall,f1,shd,auroc,trajectory_mse,\
                                           counterfactual_mse,direction";

/// The headers `--per-scenario` wrote before: a table of one of them is
/// replaced as this command's own (columns are only ever added at the end).
const PER_SCENARIO_CSV_HEADERS_BEFORE: &[&str] = &["scenario,group,split,graph,cars,threshold,true_edges,\
                                                   predicted_edges,true_positives,precision,recall,f1,shd,auroc,\
                                                   trajectory_mse,counterfactual_mse"];

/// What `--csv` writes, for the write rule ([`claim_file`](crate::output::claim::claim_file)).
pub const TABLE_CSV: FileKind = FileKind::Table(TABLE_CSV_HEADER, &[]);

/// What `--per-scenario` writes: it replaces its own table, as this
/// version or an earlier one wrote it.
pub const PER_SCENARIO_CSV: FileKind = FileKind::Table(PER_SCENARIO_CSV_HEADER, PER_SCENARIO_CSV_HEADERS_BEFORE);

impl EvaluationReport {
    /// The per-scenario rows as a CSV table (`--per-scenario`), one row per
    /// scenario and graph, in folder order; empty cells where a value does
    /// not apply.
    pub fn per_scenario_csv(&self) -> String {
        let mut out = format!("{PER_SCENARIO_CSV_HEADER}\n");
        for r in &self.per_scenario {
            out += &format!(
                "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n",
                r.scenario,
                r.group,
                r.split,
                r.graph,
                r.cars,
                cell(r.threshold, ""),
                r.true_edges,
                r.predicted_edges,
                r.true_positives,
                cell(r.precision, ""),
                cell(r.recall, ""),
                cell(r.f1, ""),
                cell(r.shd, ""),
                cell(r.auroc, ""),
                cell(r.trajectory_mse, ""),
                cell(r.counterfactual_mse, ""),
                cell(r.direction, ""),
            );
        }
        out
    }

    /// The report as a long CSV table, one measured value per row: `group,
    /// cars, edge_proportion, split, graph, metric, step, value, se,
    /// scenarios` (graph empty for trajectory errors, `trajectory_mse` and
    /// `counterfactual_mse`; step empty for edge metrics; se empty where
    /// there is none).
    pub fn to_csv(&self) -> String {
        let mut out = format!("{TABLE_CSV_HEADER}\n");
        for e in &self.edges {
            let metrics: [(&str, Option<f64>, Option<f64>); 8] = [
                ("f1", Some(e.f1), e.f1_se),
                ("precision", e.precision, None),
                ("recall", e.recall, None),
                ("auroc", e.auroc, None),
                ("auprc", e.auprc, None),
                ("direction", e.direction, None),
                ("shd", Some(e.shd), e.shd_se),
                ("threshold", Some(e.threshold), None),
            ];
            // (a graph without direction counts writes no direction row)
            for (metric, value, se) in metrics.into_iter().filter(|(m, v, _)| *m != "direction" || v.is_some()) {
                out += &format!(
                    "{},{},{},{},{},{metric},,{},{},{}\n",
                    e.group,
                    e.cars,
                    e.edge_proportion,
                    e.split,
                    e.graph,
                    cell(value, ""),
                    cell(se, ""),
                    e.scenarios
                );
            }
        }
        let trajectories = self.trajectories.iter().map(|t| ("trajectory_mse", t));
        let counterfactuals = self.counterfactuals.iter().map(|t| ("counterfactual_mse", t));
        let affected = self.counterfactuals_affected.iter().map(|t| ("counterfactual_mse_affected", t));
        for (metric, t) in trajectories.chain(counterfactuals).chain(affected) {
            for s in &t.steps {
                out += &format!(
                    "{},{},{},{},,{metric},{},{},{},{}\n",
                    t.group,
                    t.cars,
                    t.edge_proportion,
                    t.split,
                    s.step,
                    cell(Some(s.mse), ""),
                    cell(s.se, ""),
                    s.scenarios
                );
            }
        }
        out
    }
}

impl fmt::Display for EvaluationReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let show = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.3}"));
        let percent = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{:.0}%", 100.0 * v));
        let pm = |v: f64, se: Option<f64>| format!("{v:.3}±{}", se.map_or("-".to_string(), |s| format!("{s:.3}")));
        for warning in &self.warnings {
            writeln!(f, "warning: {warning}")?;
        }
        writeln!(f, "predictions {} on {} ({} world)", self.predictions, self.dataset, self.world)?;
        if !self.edges.is_empty() {
            writeln!(
                f,
                "{:<9} {:<16} {:<5} {:>5} {:>7} {:>6} {:>6} {:>6} {:>5} {:>6} {:>9} {:<7} {:>6} {:>6} {:>12} {:>12}",
                "graph",
                "group",
                "split",
                "scen",
                "pairs",
                "linked",
                "AUROC",
                "AUPRC",
                "dir",
                "called",
                "threshold",
                "from",
                "P",
                "R",
                "F1±se",
                "SHD±se"
            )?;
            for e in &self.edges {
                writeln!(
                    f,
                    "{:<9} {:<16} {:<5} {:>5} {:>7} {:>6} {:>6} {:>6} {:>5} {:>6} {:>9} {:<7} {:>6} {:>6} {:>12} {:>12}",
                    e.graph,
                    e.group,
                    if e.held_out { format!("{}*", e.split) } else { e.split.to_string() },
                    e.scenarios,
                    e.pairs,
                    e.true_edges,
                    show(e.auroc),
                    show(e.auprc),
                    percent(e.direction),
                    e.predicted_edges,
                    shown_threshold(e.threshold),
                    e.threshold_from,
                    show(e.precision),
                    show(e.recall),
                    pm(e.f1, e.f1_se),
                    pm(e.shd, e.shd_se)
                )?;
            }
            for o in &self.overall {
                let split = if o.held_out { format!("{}*", o.split) } else { o.split.to_string() };
                writeln!(
                    f,
                    "{:<9} {:<16} {:<5} {:>5} {:>7} {:>6} {:>6} {:>6} {:>5} {:>6} {:>9} {:<7} {:>6} {:>6} {:>12} {:>12}",
                    o.graph,
                    format!("all {} groups", o.groups),
                    split,
                    o.scenarios,
                    o.pairs,
                    o.true_edges,
                    show(o.auroc),
                    show(o.auprc),
                    percent(o.direction),
                    o.predicted_edges,
                    "-",
                    "group",
                    show(o.precision),
                    show(o.recall),
                    pm(o.f1, o.f1_se),
                    pm(o.shd, o.shd_se)
                )?;
            }
            writeln!(
                f,
                "edges: AUROC and AUPRC over all pairs need no threshold, nor dir (who leads: the linked pairs \
                 a -> b, b -> a unlinked, scored above b -> a, ties half; 50% is chance); a pair is called linked when its score is \
                 above the threshold (from: val = best F1 on the val split, pooled = best F1 on every group's val \
                 where this group's holds no link, given, or default 0.5, see any warning above); F1 and SHD are means over scenarios, P and R over all pairs; per-frame: every frame's pairs \
                 against interactions.csv, SHD per frame"
            )?;
            if !self.overall.is_empty() {
                writeln!(
                    f,
                    "all N groups: every scenario of every group counts once, each called at its own group's \
                     threshold; AUROC and AUPRC over every pair of every group"
                )?;
            }
            if self.edges.iter().any(|e| e.held_out) {
                writeln!(
                    f,
                    "* held out from train (the spec's held_out): out-of-distribution rows, beside the in-distribution \
                     ones of the other splits; the threshold is tuned on val, so compare AUROC when val is the \
                     in-distribution row"
                )?;
            }
        }
        let factual_steps = format!("steps ahead of frame {}", self.history_frames);
        let from_intervention = "steps from the intervention's frame (step 1), every car on the map (a removed car \
                                 not once it has left)";
        let affected_only = "steps from the intervention's frame, the cars it moved only (pairs without one not \
                             counted)";
        for (rows, title, steps) in [
            (&self.trajectories, "trajectories", factual_steps.as_str()),
            (&self.counterfactuals, "counterfactual trajectories", from_intervention),
            (&self.counterfactuals_affected, "counterfactual trajectories of the affected cars", affected_only),
        ] {
            if rows.is_empty() {
                continue;
            }
            let shown = [1usize, 5, 10, 20];
            write!(f, "{:<16} {:<5} {:>5} {:>6}", "group", "split", "scen", "steps")?;
            for step in &shown {
                write!(f, " {:>15}", format!("MSE@{step}"))?;
            }
            writeln!(f)?;
            for t in rows {
                write!(f, "{:<16} {:<5} {:>5} {:>6}", t.group, t.split, t.scenarios, t.steps.len())?;
                for step in &shown {
                    let value = t.steps.get(step - 1).map_or("-".to_string(), |s| {
                        format!("{:.2e}±{}", s.mse, s.se.map_or("-".to_string(), |e| format!("{e:.1e}")))
                    });
                    write!(f, " {value:>15}")?;
                }
                writeln!(f)?;
            }
            writeln!(
                f,
                "{title}: mean squared error of bird's-eye positions normalised by the image size ({} x {} px) at \
                 {steps}, mean over scenarios ± standard error",
                self.image_size[0], self.image_size[1]
            )?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::shown_threshold;

    #[test]
    fn a_threshold_fills_its_column_and_never_reads_as_a_negative_zero() {
        for (t, shown) in [
            (0.5, "0.5000"),
            (-0.0, "0.0000"),
            (-1e-9, "-1.00e-9"),
            (1e300, "1.00e300"),
            (-12.5, "-12.5000"),
            (-1234.5678, "-1.23e3"),
            (-9999.99999, "-1.00e4"),
            (-1e-300, "-1.0e-300"),
            (f64::MIN, "-1.80e308"),
        ] {
            assert_eq!(shown_threshold(t), shown);
            assert!(shown.len() <= 9, "{shown} overflows the column");
        }
    }
}
