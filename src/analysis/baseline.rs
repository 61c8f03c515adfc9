//! `causalcity baseline`: a non-learned causal-discovery baseline, the sanity
//! check to run before training.
//!
//! Every ordered pair of cars (a, b) of a scenario gets a *following score*:
//! for each frame t, the distance from b's position to the nearest of a's
//! positions over the last `max_lag` seconds (lags of at least one frame),
//! averaged over the frames. Unless `--max-lag` gives it, `max_lag` is the
//! one of [`LAG_GRID_S`] (up to the scenario's length) with the best AUROC
//! on each group's train split. A follower drives where its leader drove a
//! moment before, so its score is small; unrelated cars score large. The pair
//! is called "a leads b" when the score is below a threshold, picked per
//! group as the one that maximises F1 on the train split (groups whose train
//! split has no pairs use the threshold pooled over all groups). Precision,
//! recall and F1 are reported on the test split. Positions are the logged
//! ground-plane positions in metres.
//!
//! F1 at a threshold depends on the share of true links (with 10 % of pairs
//! linked, calling every pair linked already gives F1 0.18; with 40 %, 0.57),
//! so every row also has the threshold-free AUROC (the chance that a true
//! link scores below a non-link; 0.5 is guessing) and average precision.
//!
//! Next to each group's dynamics row stands a `frame0` row: the best rule
//! that sees only the first frame, the leak a dataset has. It scores a pair
//! (a, b) by how far a stands ahead of b along b's heading when both are in
//! one lane and face the same way (infinite otherwise), and learns its
//! threshold on train like the dynamics score. A benchmark whose frame0 row
//! does as well as its dynamics row gives its answer away before anything
//! moves.
//!
//! Either graph of a dataset can be the truth: the designed leader-follower
//! edges (default), or the causal or direct graph measured by intervention
//! (`effects.csv`), a (cause, effect) pair counting as (leader, follower).

use super::metrics::{auroc, average_precision, best_threshold, Counts, ScoredPair};
use crate::dataset::{Dataset, GraphKind, Pose, PoseLog, ScenarioSummary};
use crate::error::Error;
use crate::spec::Split;
use rayon::prelude::*;
use serde::Serialize;
use std::fmt;
use std::path::Path;

/// One group's result for one method.
#[derive(Debug, Clone, Serialize)]
pub struct GroupBaseline {
    /// `dynamics` (the following score) or `frame0` (the first frame only).
    pub method: &'static str,
    /// Dynamics: the longest lag of the following score, seconds.
    pub max_lag_s: Option<f64>,
    /// Dynamics: "train" when picked by train AUROC, "given" by --max-lag.
    pub lag_from: Option<&'static str>,
    pub group: String,
    pub cars: u32,
    pub edge_proportion: f64,
    /// Score below which a pair is called linked (metres).
    pub threshold_m: f64,
    /// "train" when picked on this group's train split, "pooled" when taken
    /// from all groups' train splits.
    pub threshold_from: &'static str,
    pub train_scenarios: usize,
    pub train_f1: Option<f64>,
    pub test_scenarios: usize,
    /// Ordered pairs scored on test.
    pub test_pairs: usize,
    pub test_true_edges: usize,
    pub test_predicted_edges: usize,
    /// Share of test pairs called linked.
    pub test_predicted_share: f64,
    /// None when nothing was predicted (precision) or nothing was there to
    /// find (recall); F1 is None when both are.
    pub precision: Option<f64>,
    pub recall: Option<f64>,
    pub f1: Option<f64>,
    /// Threshold-free, on test: the chance that a linked pair scores below
    /// an unlinked one (ties count half); None without both kinds of pair.
    pub auroc: Option<f64>,
    /// Threshold-free, on test: precision averaged over the recall steps.
    pub average_precision: Option<f64>,
}

/// The baseline over a dataset.
#[derive(Debug, Clone, Serialize)]
pub struct BaselineReport {
    pub dataset: String,
    pub world: String,
    /// The lags the dynamics score tried, seconds (one when given).
    pub lags_s: Vec<f64>,
    /// The graph scored against: designed, causal or direct.
    pub graph: GraphKind,
    /// The dynamics baseline, per group.
    pub groups: Vec<GroupBaseline>,
    /// The best first-frame rule, per group: the leak.
    pub frame0: Vec<GroupBaseline>,
}

/// Both scores of every ordered pair of a scenario (the dynamics score at
/// each lag tried).
struct ScenarioScores {
    dynamics: Vec<Vec<ScoredPair>>,
    frame0: Vec<ScoredPair>,
}

/// Widest lateral offset at which two cars count as in one lane, metres
/// (half the default 3 m lane).
const SAME_LANE_M: f64 = 1.5;
/// Largest heading difference at which two cars face the same way, radians.
const SAME_HEADING_RAD: f64 = 0.5;

/// Longest lags the dynamics score tries when none is given, seconds: the
/// one with the best AUROC on each group's train split is used (a follower
/// at walking pace trails its leader by many seconds, more behind a light).
pub const LAG_GRID_S: [f64; 6] = [2.0, 4.0, 8.0, 15.0, 30.0, 60.0];

/// Runs the baseline over the dataset in `dir`, with lags up to `max_lag_s`
/// seconds, or (`None`) the lag of [`LAG_GRID_S`] that ranks train best.
/// Bad input (a lag that is no positive number, a graph the dataset does not
/// have), and unreadable files (a damaged dataset), are an [`Error::Input`].
pub fn baseline(dir: &Path, max_lag_s: Option<f64>, graph: GraphKind) -> Result<BaselineReport, Error> {
    if let Some(lag) = max_lag_s.filter(|l| !(*l > 0.0 && l.is_finite())) {
        return Err(Error::Input(format!("--max-lag must be a positive number of seconds, not {lag}")));
    }
    let dataset = Dataset::open_complete(dir).map_err(Error::opening)?;
    dataset.require_graph(graph).map_err(Error::Input)?;
    if dataset.spec().frames < 2 {
        return Err(Error::Input(format!(
            "{}: its scenarios have {} frame, and following needs a path: the baseline scores scenarios of 2 frames \
             or more",
            dir.display(),
            dataset.spec().frames
        )));
    }
    // A threshold learnt on train, scored on test: both must have scenarios
    // (without test it scored nothing, exit 0; without train it blamed the
    // edge proportion).
    for (split, role) in [(Split::Train, "learns its threshold on"), (Split::Test, "scores")] {
        if !dataset.keys().any(|k| k.split == split) {
            return Err(Error::Input(format!(
                "{}: it has no {} scenarios, and the baseline {role} its {} scenarios: generate a dataset whose \
                 splits.{} is 1 or more",
                dir.display(),
                split.name(),
                split.name(),
                split.name()
            )));
        }
    }
    let duration = dataset.spec().frames as f64 * dataset.spec().frame_interval();
    let lags: Vec<f64> = match max_lag_s {
        Some(lag) => vec![lag],
        // Lags beyond the scenario add nothing: the grid up to the first that covers it.
        None => {
            let covering = LAG_GRID_S.iter().position(|&l| l >= duration).unwrap_or(LAG_GRID_S.len() - 1);
            LAG_GRID_S[..=covering].to_vec()
        }
    };
    score(dir, &dataset, &lags, graph)
}

/// [`baseline`] of an opened dataset, the dynamics score at each of `lags`.
/// A scenario it cannot read is the dataset's damage ([`Error::damaged`]).
fn score(dir: &Path, dataset: &Dataset, lags: &[f64], graph: GraphKind) -> Result<BaselineReport, Error> {
    let spec = dataset.spec();
    let mut per_group = Vec::new();
    for group in &spec.groups {
        let name = group.name();
        let score_split = |split: Split| -> Result<Vec<ScenarioScores>, Error> {
            dataset
                .with_split(&name, split, |dirs| dirs.par_iter().map(|d| score_scenario(d, lags, graph)).collect())
                .map_err(|e| Error::reading(dir, e))
        };
        per_group.push((group, score_split(Split::Train)?, score_split(Split::Test)?));
    }
    // The dynamics score's lag per group: the best train AUROC (the first on a tie).
    let pairs_at = |scores: &[ScenarioScores], lag: Option<usize>| -> Vec<ScoredPair> {
        match lag {
            Some(k) => scores.iter().flat_map(|s| &s.dynamics[k]).copied().collect(),
            None => scores.iter().flat_map(|s| &s.frame0).copied().collect(),
        }
    };
    let chosen: Vec<usize> = per_group
        .iter()
        .map(|(_, train, _)| {
            let ranks: Vec<f64> = (0..lags.len()).map(|k| auroc(&pairs_at(train, Some(k))).unwrap_or(0.0)).collect();
            (0..lags.len()).fold(0, |best, k| if ranks[k] > ranks[best] { k } else { best })
        })
        .collect();
    let mut methods = [Vec::new(), Vec::new()];
    for (m, frame0) in [false, true].into_iter().enumerate() {
        let lag_of = |g: usize| (!frame0).then(|| chosen[g]);
        let pooled: Vec<ScoredPair> =
            per_group.iter().enumerate().flat_map(|(g, (_, train, _))| pairs_at(train, lag_of(g))).collect();
        let pooled_threshold = best_threshold(&pooled);
        for (g, (group, train, test)) in per_group.iter().enumerate() {
            let (train_pairs, test_pairs) = (pairs_at(train, lag_of(g)), pairs_at(test, lag_of(g)));
            let (threshold, from) = match (best_threshold(&train_pairs), pooled_threshold) {
                (Some(t), _) => (t, "train"),
                (None, Some(t)) => (t, "pooled"),
                (None, None) => {
                    return Err(Error::Input(format!(
                        "{}: no leader-follower pairs in any train split, so there is no threshold to learn; \
                         generate train scenarios with edge_proportion > 0",
                        dir.display()
                    )))
                }
            };
            let counts = Counts::at(&test_pairs, threshold);
            let called = counts.true_positives + counts.false_positives;
            methods[m].push(GroupBaseline {
                method: if frame0 { "frame0" } else { "dynamics" },
                max_lag_s: lag_of(g).map(|k| lags[k]),
                lag_from: lag_of(g).map(|_| if lags.len() > 1 { "train" } else { "given" }),
                group: group.name(),
                // The rows score the test split, which may hold the car count out.
                cars: spec.group_of(Split::Test, group).cars,
                edge_proportion: group.edge_proportion,
                threshold_m: threshold,
                threshold_from: from,
                train_scenarios: train.len(),
                train_f1: Counts::at(&train_pairs, threshold).f1(),
                test_scenarios: test.len(),
                test_pairs: test_pairs.len(),
                test_true_edges: counts.true_positives + counts.false_negatives,
                test_predicted_edges: called,
                test_predicted_share: if test_pairs.is_empty() { 0.0 } else { called as f64 / test_pairs.len() as f64 },
                precision: counts.precision(),
                recall: counts.recall(),
                f1: counts.f1(),
                auroc: auroc(&test_pairs),
                average_precision: average_precision(&test_pairs),
            });
        }
    }
    let [groups, frame0] = methods;
    Ok(BaselineReport {
        dataset: dir.display().to_string(),
        world: spec.world.name().to_string(),
        lags_s: lags.to_vec(),
        graph,
        groups,
        frame0,
    })
}

/// Scores every ordered pair of the scenario in `dir`, both ways.
fn score_scenario(dir: &Path, lags_s: &[f64], graph: GraphKind) -> Result<ScenarioScores, String> {
    let scenario = ScenarioSummary::read_graph(dir, graph)?;
    let (frames, cars) = (scenario.frames as usize, scenario.cars.len());
    let poses = PoseLog::read(dir, frames, cars)?;
    let lags: Vec<usize> = lags_s.iter().map(|s| ((s / scenario.frame_interval).round() as usize).max(1)).collect();
    let tracks: Vec<Vec<[f64; 2]>> =
        (0..cars).map(|c| (0..frames).map(|f| [poses.at(f, c).x, poses.at(f, c).y]).collect()).collect();
    let mut scores = ScenarioScores { dynamics: vec![Vec::new(); lags.len()], frame0: Vec::new() };
    for leader in 0..cars {
        for follower in 0..cars {
            if leader == follower {
                continue;
            }
            let linked = scenario.graph.iter().any(|e| e[0] as usize == leader && e[1] as usize == follower);
            for (k, score) in following_scores(&tracks[leader], &tracks[follower], &lags).into_iter().enumerate() {
                scores.dynamics[k].push((score, linked));
            }
            scores.frame0.push((frame0_score(poses.at(0, leader), poses.at(0, follower)), linked));
        }
    }
    Ok(scores)
}

/// How far `leader` stands ahead of `follower` along the follower's heading
/// in the first frame, metres, when both are in one lane facing the same
/// way; infinite otherwise.
pub fn frame0_score(leader: &Pose, follower: &Pose) -> f64 {
    let (dx, dy) = (leader.x - follower.x, leader.y - follower.y);
    let (c, s) = (follower.yaw.cos(), follower.yaw.sin());
    let (ahead, lateral) = (dx * c + dy * s, (-dx * s + dy * c).abs());
    let turn =
        (leader.yaw - follower.yaw + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI;
    if ahead > 0.0 && lateral <= SAME_LANE_M && turn.abs() <= SAME_HEADING_RAD {
        ahead
    } else {
        f64::INFINITY
    }
}

/// Mean over frames of the distance from `follower` to the nearest point of
/// `leader`'s path over the previous `max_lag` frames.
pub fn following_score(leader: &[[f64; 2]], follower: &[[f64; 2]], max_lag: usize) -> f64 {
    following_scores(leader, follower, &[max_lag])[0]
}

/// [`following_score`] at each of `max_lags` (frames), in one pass: the
/// nearest leader position over the last k frames is a running minimum as
/// k grows.
pub fn following_scores(leader: &[[f64; 2]], follower: &[[f64; 2]], max_lags: &[usize]) -> Vec<f64> {
    let frames = leader.len().min(follower.len());
    if frames < 2 {
        return vec![f64::INFINITY; max_lags.len()];
    }
    // A lag beyond the scenario's start reaches the same positions as one
    // back to it (frame `t` looks at most `frames - 1` back).
    let max_lags: Vec<usize> = max_lags.iter().map(|&lag| lag.clamp(1, frames - 1)).collect();
    let longest = max_lags.iter().copied().max().unwrap_or(1);
    let mut totals = vec![0.0; max_lags.len()];
    let mut nearest_within = vec![f64::INFINITY; longest + 1];
    for (t, &[fx, fy]) in follower.iter().enumerate().take(frames).skip(1) {
        // nearest_within[k]: the least squared distance to the leader's last k positions.
        let mut nearest = f64::INFINITY;
        for (k, within) in nearest_within.iter_mut().enumerate().skip(1) {
            if let Some(s) = t.checked_sub(k) {
                let [lx, ly] = leader[s];
                nearest = nearest.min((fx - lx) * (fx - lx) + (fy - ly) * (fy - ly));
            }
            *within = nearest;
        }
        for (total, &lag) in totals.iter_mut().zip(&max_lags) {
            *total += nearest_within[lag].sqrt();
        }
    }
    totals.into_iter().map(|total| total / (frames - 1) as f64).collect()
}

/// [`following_scores`] of every ordered pair of many scenarios at once (on
/// every core): `xy` holds `[scenarios, frames, cars]` positions (metres,
/// C order); the result is `[scenarios, lags, cars, cars]`, `[s, l, a, b]`
/// scoring "a leads b" at `max_lags[l]` (the diagonal 0).
pub fn pair_following_scores(
    xy: &[[f64; 2]],
    (scenarios, frames, cars): (usize, usize, usize),
    max_lags: &[usize],
) -> Vec<f64> {
    let block = max_lags.len() * cars * cars;
    let mut out = vec![0.0f64; scenarios * block];
    if block == 0 || frames == 0 {
        return out;
    }
    out.par_chunks_mut(block).zip(xy.par_chunks(frames * cars)).for_each(|(scores, scenario)| {
        let paths: Vec<Vec<[f64; 2]>> =
            (0..cars).map(|c| (0..frames).map(|t| scenario[t * cars + c]).collect()).collect();
        for a in 0..cars {
            for b in (0..cars).filter(|&b| b != a) {
                for (l, score) in following_scores(&paths[a], &paths[b], max_lags).into_iter().enumerate() {
                    scores[(l * cars + a) * cars + b] = score;
                }
            }
        }
    });
    out
}

impl fmt::Display for BaselineReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "following-score baseline (dynamics) and the best first-frame rule (frame0) on {} ({} world, lags tried: {:?} s) against the {} graph: lag and threshold from train, scores on test",
            self.dataset, self.world, self.lags_s, self.graph.name()
        )?;
        writeln!(
            f,
            "{:<18} {:<8} {:>4} {:>6} {:>11} {:>6} {:>6} {:>7} {:>7} {:>7} {:>6} {:>6} {:>6} {:>6} {:>6}",
            "group",
            "method",
            "cars",
            "edges%",
            "threshold m",
            "from",
            "test",
            "pairs",
            "linked",
            "called",
            "P",
            "R",
            "F1",
            "AUROC",
            "AP"
        )?;
        let show = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.3}"));
        for (d, z) in self.groups.iter().zip(&self.frame0) {
            for g in [d, z] {
                writeln!(
                    f,
                    "{:<18} {:<8} {:>4} {:>6.0} {:>11.3} {:>6} {:>6} {:>7} {:>7} {:>7} {:>6} {:>6} {:>6} {:>6} {:>6}",
                    g.group,
                    g.method,
                    g.cars,
                    g.edge_proportion * 100.0,
                    g.threshold_m,
                    g.threshold_from,
                    g.test_scenarios,
                    g.test_pairs,
                    g.test_true_edges,
                    g.test_predicted_edges,
                    show(g.precision),
                    show(g.recall),
                    show(g.f1),
                    show(g.auroc),
                    show(g.average_precision)
                )?;
            }
        }
        writeln!(
            f,
            "F1 rises with the share of linked pairs whatever the method; AUROC (0.5 = guessing) and AP do not need a threshold. \
             A frame0 row as good as its dynamics row means the answer is visible before anything moves."
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scores_at_many_lags_in_one_pass_equal_each_lag_alone() {
        // A leader that wanders and a follower that lags it by 7 frames, offset.
        let leader: Vec<[f64; 2]> = (0..60).map(|t| [t as f64 * 0.7, (t as f64 * 0.3).sin() * 4.0]).collect();
        let follower: Vec<[f64; 2]> =
            (0..60usize).map(|t| leader[t.saturating_sub(7)]).map(|[x, y]| [x + 0.2, y - 0.1]).collect();
        let brute = |lag: usize| {
            let mut total = 0.0;
            for (t, [fx, fy]) in follower.iter().enumerate().skip(1) {
                let nearest = (t.saturating_sub(lag)..t)
                    .map(|s| ((fx - leader[s][0]).powi(2) + (fy - leader[s][1]).powi(2)).sqrt())
                    .fold(f64::INFINITY, f64::min);
                total += nearest;
            }
            total / 59.0
        };
        let lags = [1, 3, 7, 8, 20, 100];
        let scores = following_scores(&leader, &follower, &lags);
        for (score, lag) in scores.iter().zip(lags) {
            assert!((score - brute(lag)).abs() < 1e-12, "lag {lag}: {score} vs {}", brute(lag));
        }
        // Longer lags never score worse, and reaching the follower's lag helps.
        assert!(scores.windows(2).all(|w| w[1] <= w[0] + 1e-12));
        assert!(scores[2] < 0.5 * scores[1], "{scores:?}");
    }

    #[test]
    fn many_scenarios_at_once_score_each_pair_as_one_pair_alone() {
        // Two scenarios of three cars over 30 frames, car-major per frame.
        let (scenarios, frames, cars) = (2, 30, 3);
        let at = |s: usize, t: usize, c: usize| [t as f64 * (1.0 + c as f64) + s as f64, (t * c) as f64 * 0.1];
        let xy: Vec<[f64; 2]> =
            (0..scenarios).flat_map(|s| (0..frames).flat_map(move |t| (0..cars).map(move |c| at(s, t, c)))).collect();
        let lags = [2, 9];
        let all = pair_following_scores(&xy, (scenarios, frames, cars), &lags);
        assert_eq!(all.len(), scenarios * lags.len() * cars * cars);
        let mut checked = 0;
        for s in 0..scenarios {
            let path = |c: usize| (0..frames).map(|t| at(s, t, c)).collect::<Vec<_>>();
            for (a, b) in (0..cars).flat_map(|a| (0..cars).map(move |b| (a, b))) {
                let alone = following_scores(&path(a), &path(b), &lags);
                for (l, score) in alone.iter().enumerate() {
                    let got = all[((s * lags.len() + l) * cars + a) * cars + b];
                    assert_eq!(got, if a == b { 0.0 } else { *score }, "s {s} lag {l} ({a}, {b})");
                    checked += 1;
                }
            }
        }
        assert_eq!(checked, scenarios * lags.len() * cars * cars);
    }

    #[test]
    fn a_follower_on_its_leaders_path_scores_zero_and_the_reverse_does_not() {
        let leader: Vec<[f64; 2]> = (0..50).map(|t| [t as f64, 0.0]).collect();
        let follower: Vec<[f64; 2]> = (0..50).map(|t| [t as f64 - 5.0, 0.0]).collect();
        // Only the first frames, before the leader has been where the
        // follower is, add to the score: (4 + 3 + 2 + 1) / 49.
        assert!((following_score(&leader, &follower, 10) - 10.0 / 49.0).abs() < 1e-9);
        assert!(following_score(&follower, &leader, 10) > 5.0);
    }

    #[test]
    fn frame0_scores_a_car_right_behind_in_its_lane() {
        let at = |x: f64, y: f64, yaw: f64| Pose { x, y, yaw, ..Pose::default() };
        // Heading east; the leader 6 m ahead, 0.5 m to the side.
        assert!((frame0_score(&at(6.0, 0.5, 0.0), &at(0.0, 0.0, 0.0)) - 6.0).abs() < 1e-12);
        // Behind, beside in the next lane, or facing the other way: never a link.
        assert_eq!(frame0_score(&at(-6.0, 0.0, 0.0), &at(0.0, 0.0, 0.0)), f64::INFINITY);
        assert_eq!(frame0_score(&at(6.0, 3.0, 0.0), &at(0.0, 0.0, 0.0)), f64::INFINITY);
        assert_eq!(frame0_score(&at(6.0, 0.0, 3.1), &at(0.0, 0.0, 0.0)), f64::INFINITY);
        // Headings either side of east are close (wrap-around).
        assert!(frame0_score(&at(6.0, 0.0, -0.2), &at(0.0, 0.0, 6.2)).is_finite());
    }
}
