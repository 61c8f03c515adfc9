//! `causalcity evaluate`: scores anyone's predictions against a dataset's
//! ground truth with the paper's metrics, so that every method is scored
//! the same way.
//!
//! The predictions file is an `.npz` (numpy's `np.savez`) holding, for each
//! scored scenario, arrays named by its folder relative to the dataset:
//!
//! - `<group>/<split>/<index>`, e.g. `cars08_edges50/test/00000`: `[cars,
//!   cars]` edge scores, `[i, j]` scoring "car i leads car j" (cause to
//!   effect, as `Scenario.graph` in Python and `edges` in scenario.json),
//!   higher meaning more likely; the diagonal is ignored;
//! - `<group>/<split>/<index>/trajectory`: `[steps, cars, 2]` predicted
//!   bird's-eye pixel positions (px, py) of frames `history ..
//!   history + steps` after observing frames `0 .. history` (the paper
//!   observes 100 frames and predicts up to 20).
//!
//! Either kind may be left out; within a group and split, every scenario of
//! the dataset must be scored once one is, so that no method is scored on a
//! subset of its choosing. Edge scores get, per graph kind, group and split:
//! F1 at a threshold chosen on the validation split (the one with the best
//! F1 over all of val's pairs), mean over scenarios with its standard error;
//! precision and recall over all pairs; AUROC and AUPRC (average precision)
//! over all pairs, needing no threshold; and the structural Hamming distance
//! (SHD: ordered pairs whose called link differs from the truth, so a
//! reversed edge counts twice), mean over scenarios. Trajectories get the
//! mean squared error of positions normalised by the image size (x / width,
//! y / height, both 0 to 1, averaged over the two coordinates and the cars),
//! per step ahead, mean over scenarios with its standard error.

use super::metrics::{auroc, average_precision, best_threshold, Counts, ScoredPair};
use super::predictions::{read_npz, NamedArray};
use crate::dataset::{Dataset, GraphKind, PoseLog, ScenarioSummary};
use crate::error::Error;
use crate::spec::Split;
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

/// Edge-discovery scores of one graph kind, group and split.
#[derive(Debug, Clone, Serialize)]
pub struct EdgeScores {
    pub graph: GraphKind,
    pub group: String,
    pub cars: u32,
    pub edge_proportion: f64,
    pub split: &'static str,
    pub scenarios: usize,
    /// Ordered pairs scored (cars x (cars - 1) per scenario).
    pub pairs: usize,
    pub true_edges: usize,
    /// Pairs scored above the threshold.
    pub predicted_edges: usize,
    /// A pair is called linked when its score is above this.
    pub threshold: f64,
    /// `val` (best F1 on this group's val split), `given` (--threshold) or
    /// `default` (0.5: no val predictions with a link to tune on).
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
    /// Mean structural Hamming distance per scenario.
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
    pub trajectories: Vec<TrajectoryScores>,
}

/// One scored scenario's predictions, checked against its files.
struct ScenarioPredictions {
    group: String,
    split: Split,
    dir: PathBuf,
    edges: Option<Vec<f64>>,
    trajectory: Option<(usize, Vec<f64>)>,
}

/// What one scenario contributes: per graph, its scored pairs (negated
/// scores, so that lower is more likely, as [`super::metrics`] ranks); and
/// its trajectory error per step.
struct ScenarioResult {
    pairs: Vec<Vec<ScoredPair>>,
    step_errors: Vec<f64>,
}

/// Scores the predictions file `predictions` against the dataset in
/// `dataset`. Everything wrong with the predictions (an array naming no
/// scenario, a wrong shape, a NaN, a partly scored split, nothing to score)
/// is an [`Error::Input`] naming the file and array; nothing is scored then.
pub fn evaluate(dataset: &Path, predictions: &Path, options: &EvaluateOptions) -> Result<EvaluationReport, Error> {
    if let Some(t) = options.threshold.filter(|t| !t.is_finite()) {
        return Err(Error::Input(format!("--threshold must be a finite number, not {t}")));
    }
    if options.graphs.is_empty() {
        return Err(Error::input("give at least one graph kind to score against"));
    }
    let opened = Dataset::open_complete(dataset).map_err(Error::Input)?;
    for &graph in &options.graphs {
        opened.require_graph(graph).map_err(Error::Input)?;
    }
    let arrays = read_npz(predictions).map_err(Error::Input)?;
    let scored = match_scenarios(&opened, predictions, arrays, options)?;
    let results: Vec<ScenarioResult> = scored
        .par_iter()
        .map(|s| score_scenario(s, &opened, options))
        .collect::<Result<_, String>>()
        .map_err(Error::Input)?;
    Ok(summarise(&opened, dataset, predictions, options, &scored, &results))
}

/// Pairs every array with its scenario and checks names, shapes, values and
/// coverage.
fn match_scenarios(
    opened: &Dataset,
    file: &Path,
    arrays: Vec<NamedArray>,
    options: &EvaluateOptions,
) -> Result<Vec<ScenarioPredictions>, Error> {
    let bad = |message: String| Error::Input(format!("{}: {message}", file.display()));
    let mut by_folder: BTreeMap<String, ScenarioPredictions> = BTreeMap::new();
    let mut order: Vec<String> = Vec::new();
    for key in &opened.keys {
        let folder = format!("{}/{}/{}", key.group, key.split.name(), key.folder_name());
        let dir = opened.dir.join(&key.group).join(key.split.name()).join(key.folder_name());
        order.push(folder.clone());
        by_folder.insert(
            folder,
            ScenarioPredictions { group: key.group.clone(), split: key.split, dir, edges: None, trajectory: None },
        );
    }
    if arrays.is_empty() {
        return Err(bad("holds no arrays: save one [cars, cars] array of edge scores per scenario, named by its \
                        folder (e.g. cars08_edges50/test/00000)"
            .to_string()));
    }
    for array in arrays {
        let (folder, is_trajectory) = match array.name.strip_suffix(TRAJECTORY_SUFFIX) {
            Some(folder) => (folder.to_string(), true),
            None => (array.name.clone(), false),
        };
        let example = order.first().map(String::as_str).unwrap_or("<group>/<split>/<index>");
        let Some(scenario) = by_folder.get_mut(&folder) else {
            return Err(bad(format!(
                "array {:?} names no scenario of {}: name arrays by scenario folder, e.g. {example} (edge scores) or \
                 {example}{TRAJECTORY_SUFFIX} (a predicted trajectory)",
                array.name,
                opened.dir.display()
            )));
        };
        let summary = ScenarioSummary::read(&scenario.dir).map_err(Error::Failure)?;
        let (cars, frames) = (summary.cars.len(), summary.frames as usize);
        let shape = &array.shape;
        if is_trajectory {
            let fits = shape.len() == 3 && shape[1] == cars && shape[2] == 2 && shape[0] >= 1;
            if !fits {
                return Err(bad(format!(
                    "array {:?} has shape {shape:?}; a predicted trajectory of this scenario is [steps, {cars}, 2] \
                     (steps >= 1; px, py in bird's-eye pixels)",
                    array.name
                )));
            }
            if options.history + shape[0] > frames {
                return Err(bad(format!(
                    "array {:?} predicts {} steps after {} frames of history, but the scenario has {frames} frames: \
                     predict at most {} steps, or give --history at most {}",
                    array.name,
                    shape[0],
                    options.history,
                    frames.saturating_sub(options.history),
                    frames.saturating_sub(shape[0])
                )));
            }
        } else if shape.as_slice() != [cars, cars] {
            return Err(bad(format!(
                "array {:?} has shape {shape:?}; edge scores of this scenario are [{cars}, {cars}] ([i, j]: car i \
                 leads car j)",
                array.name
            )));
        }
        let off_diagonal = |i: usize| is_trajectory || i / cars != i % cars;
        if let Some(i) = (0..array.values.len()).find(|&i| off_diagonal(i) && !array.values[i].is_finite()) {
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
        if is_trajectory {
            scenario.trajectory = Some((shape[0], array.values));
        } else {
            scenario.edges = Some(array.values);
        }
    }
    // Coverage: a group and split scored in part is an error.
    for (kind, has) in [
        ("edge scores", (|s: &ScenarioPredictions| s.edges.is_some()) as fn(&ScenarioPredictions) -> bool),
        ("trajectories", |s: &ScenarioPredictions| s.trajectory.is_some()),
    ] {
        let mut splits: BTreeMap<(String, &'static str), (usize, Vec<&str>)> = BTreeMap::new();
        for folder in &order {
            let s = &by_folder[folder];
            let entry = splits.entry((s.group.clone(), s.split.name())).or_default();
            if has(s) {
                entry.0 += 1;
            } else {
                entry.1.push(folder);
            }
        }
        for ((group, split), (present, missing)) in splits {
            if present > 0 && !missing.is_empty() {
                return Err(bad(format!(
                    "has {kind} for {present} of the {} scenarios of {group}/{split}; missing {} (first {:?}): score \
                     every scenario of a split, or none",
                    present + missing.len(),
                    missing.len(),
                    missing[0]
                )));
            }
        }
    }
    Ok(order
        .into_iter()
        .filter_map(|folder| by_folder.remove(&folder))
        .filter(|s| s.edges.is_some() || s.trajectory.is_some())
        .collect())
}

/// Reads one scenario's truth and scores its predictions.
fn score_scenario(
    s: &ScenarioPredictions,
    opened: &Dataset,
    options: &EvaluateOptions,
) -> Result<ScenarioResult, String> {
    let mut pairs = Vec::new();
    if let Some(scores) = &s.edges {
        for &graph in &options.graphs {
            let summary = ScenarioSummary::read_graph(&s.dir, graph)?;
            let cars = summary.cars.len();
            let mut linked = vec![false; cars * cars];
            for [a, b] in &summary.graph {
                linked[*a as usize * cars + *b as usize] = true;
            }
            let scored = (0..cars * cars).filter(|i| i / cars != i % cars).map(|i| (-scores[i], linked[i])).collect();
            pairs.push(scored);
        }
    }
    let mut step_errors = Vec::new();
    if let Some((steps, predicted)) = &s.trajectory {
        let summary = ScenarioSummary::read(&s.dir)?;
        let (frames, cars) = (summary.frames as usize, summary.cars.len());
        let poses = PoseLog::read(&s.dir, frames, cars)?;
        let image = &opened.spec().image;
        let (w, h) = (image.width as f64, image.height as f64);
        for step in 0..*steps {
            let frame = options.history + step;
            let mut total = 0.0;
            for car in 0..cars {
                let truth = poses.at(frame, car);
                let at = (step * cars + car) * 2;
                let (dx, dy) = ((predicted[at] - truth.px) / w, (predicted[at + 1] - truth.py) / h);
                total += (dx * dx + dy * dy) / 2.0;
            }
            step_errors.push(total / cars as f64);
        }
    }
    Ok(ScenarioResult { pairs, step_errors })
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
/// pairs, else 0.5.
fn threshold_for(options: &EvaluateOptions, val_pairs: &[ScoredPair]) -> (f64, &'static str) {
    if let Some(t) = options.threshold {
        return (t, "given");
    }
    match best_threshold(val_pairs) {
        // The metrics rank negated scores: negate back.
        Some(t) => (-t, "val"),
        None => (0.5, "default"),
    }
}

fn summarise(
    opened: &Dataset,
    dataset: &Path,
    predictions: &Path,
    options: &EvaluateOptions,
    scored: &[ScenarioPredictions],
    results: &[ScenarioResult],
) -> EvaluationReport {
    let spec = opened.spec();
    let mut edges = Vec::new();
    let mut trajectories = Vec::new();
    for (g, &graph) in options.graphs.iter().enumerate() {
        for group in &spec.groups {
            let name = group.name();
            let in_split = |split: Split| -> Vec<&ScenarioResult> {
                scored
                    .iter()
                    .zip(results)
                    .filter(|(s, r)| s.group == name && s.split == split && !r.pairs.is_empty())
                    .map(|(_, r)| r)
                    .collect()
            };
            let val: Vec<ScoredPair> = in_split(Split::Val).iter().flat_map(|r| r.pairs[g].iter().copied()).collect();
            let (threshold, threshold_from) = threshold_for(options, &val);
            for split in Split::ALL {
                let rows = in_split(split);
                if rows.is_empty() {
                    continue;
                }
                let all: Vec<ScoredPair> = rows.iter().flat_map(|r| r.pairs[g].iter().copied()).collect();
                let per_scenario: Vec<Counts> = rows.iter().map(|r| Counts::at(&r.pairs[g], -threshold)).collect();
                let f1s: Vec<f64> = per_scenario.iter().map(|c| c.f1().unwrap_or(1.0)).collect();
                let shds: Vec<f64> =
                    per_scenario.iter().map(|c| (c.false_positives + c.false_negatives) as f64).collect();
                let counts = Counts::at(&all, -threshold);
                let (f1, f1_se) = mean_se(&f1s);
                let (shd, shd_se) = mean_se(&shds);
                edges.push(EdgeScores {
                    graph,
                    group: name.clone(),
                    cars: group.cars,
                    edge_proportion: group.edge_proportion,
                    split: split.name(),
                    scenarios: rows.len(),
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
                    shd,
                    shd_se,
                });
            }
        }
    }
    for group in &spec.groups {
        let name = group.name();
        for split in Split::ALL {
            let rows: Vec<&ScenarioResult> = scored
                .iter()
                .zip(results)
                .filter(|(s, r)| s.group == name && s.split == split && !r.step_errors.is_empty())
                .map(|(_, r)| r)
                .collect();
            let longest = rows.iter().map(|r| r.step_errors.len()).max().unwrap_or(0);
            let steps = (0..longest)
                .map(|k| {
                    let at_step: Vec<f64> = rows.iter().filter_map(|r| r.step_errors.get(k).copied()).collect();
                    let (mse, se) = mean_se(&at_step);
                    StepError { step: k + 1, mse, se, scenarios: at_step.len() }
                })
                .collect::<Vec<_>>();
            if !steps.is_empty() {
                trajectories.push(TrajectoryScores {
                    group: name.clone(),
                    cars: group.cars,
                    edge_proportion: group.edge_proportion,
                    split: split.name(),
                    scenarios: rows.len(),
                    steps,
                });
            }
        }
    }
    EvaluationReport {
        dataset: dataset.display().to_string(),
        predictions: predictions.display().to_string(),
        world: spec.world.name().to_string(),
        image_size: [spec.image.width, spec.image.height],
        history_frames: options.history,
        edges,
        trajectories,
    }
}

/// A number for a table or CSV cell ("" / "-" for none).
fn cell(value: Option<f64>, none: &str) -> String {
    value.map_or(none.to_string(), |v| format!("{v:.6}"))
}

impl EvaluationReport {
    /// The report as a long CSV table, one measured value per row: `group,
    /// cars, edge_proportion, split, graph, metric, step, value, se,
    /// scenarios` (graph empty for trajectory errors, step empty for edge
    /// metrics, se empty where there is none).
    pub fn to_csv(&self) -> String {
        let mut out = String::from("group,cars,edge_proportion,split,graph,metric,step,value,se,scenarios\n");
        for e in &self.edges {
            let metrics: [(&str, Option<f64>, Option<f64>); 7] = [
                ("f1", Some(e.f1), e.f1_se),
                ("precision", e.precision, None),
                ("recall", e.recall, None),
                ("auroc", e.auroc, None),
                ("auprc", e.auprc, None),
                ("shd", Some(e.shd), e.shd_se),
                ("threshold", Some(e.threshold), None),
            ];
            for (metric, value, se) in metrics {
                out += &format!(
                    "{},{},{},{},{},{metric},,{},{},{}\n",
                    e.group,
                    e.cars,
                    e.edge_proportion,
                    e.split,
                    e.graph.name(),
                    cell(value, ""),
                    cell(se, ""),
                    e.scenarios
                );
            }
        }
        for t in &self.trajectories {
            for s in &t.steps {
                out += &format!(
                    "{},{},{},{},,trajectory_mse,{},{},{},{}\n",
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
        let pm = |v: f64, se: Option<f64>| format!("{v:.3}±{}", se.map_or("-".to_string(), |s| format!("{s:.3}")));
        writeln!(f, "predictions {} on {} ({} world)", self.predictions, self.dataset, self.world)?;
        if !self.edges.is_empty() {
            writeln!(
                f,
                "{:<9} {:<16} {:<5} {:>5} {:>7} {:>6} {:>6} {:>9} {:<7} {:>6} {:>6} {:>12} {:>6} {:>6} {:>12}",
                "graph",
                "group",
                "split",
                "scen",
                "pairs",
                "linked",
                "called",
                "threshold",
                "from",
                "P",
                "R",
                "F1±se",
                "AUROC",
                "AUPRC",
                "SHD±se"
            )?;
            for e in &self.edges {
                writeln!(
                    f,
                    "{:<9} {:<16} {:<5} {:>5} {:>7} {:>6} {:>6} {:>9.4} {:<7} {:>6} {:>6} {:>12} {:>6} {:>6} {:>12}",
                    e.graph.name(),
                    e.group,
                    e.split,
                    e.scenarios,
                    e.pairs,
                    e.true_edges,
                    e.predicted_edges,
                    e.threshold,
                    e.threshold_from,
                    show(e.precision),
                    show(e.recall),
                    pm(e.f1, e.f1_se),
                    show(e.auroc),
                    show(e.auprc),
                    pm(e.shd, e.shd_se)
                )?;
            }
            writeln!(
                f,
                "edges: a pair is called linked when its score is above the threshold (from: val = best F1 on the val \
                 split, given, or default 0.5); F1 and SHD are means over scenarios, P, R, AUROC and AUPRC over all \
                 pairs"
            )?;
        }
        if !self.trajectories.is_empty() {
            let shown = [1usize, 5, 10, 20];
            write!(f, "{:<16} {:<5} {:>5} {:>6}", "group", "split", "scen", "steps")?;
            for step in &shown {
                write!(f, " {:>15}", format!("MSE@{step}"))?;
            }
            writeln!(f)?;
            for t in &self.trajectories {
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
                "trajectories: mean squared error of bird's-eye positions normalised by the image size ({} x {} px) \
                 at steps ahead of frame {}, mean over scenarios ± standard error",
                self.image_size[0], self.image_size[1], self.history_frames
            )?;
        }
        Ok(())
    }
}
