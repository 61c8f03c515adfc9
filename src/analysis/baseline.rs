//! `causalcity baseline`: a non-learned causal-discovery baseline, the sanity
//! check to run before training.
//!
//! Every ordered pair of cars (a, b) of a scenario gets a *following score*:
//! for each frame t, the distance from b's position to the nearest of a's
//! positions over the last `max_lag` seconds (lags of at least one frame),
//! averaged over the frames. A follower drives where its leader drove a
//! moment before, so its score is small; unrelated cars score large. The pair
//! is called "a leads b" when the score is below a threshold, picked per
//! group as the one that maximises F1 on the train split (groups whose train
//! split has no pairs use the threshold pooled over all groups). Precision,
//! recall and F1 are reported on the test split. Positions are the logged
//! ground-plane positions in metres.

use crate::dataset::{Dataset, PoseLog, ScenarioSummary};
use crate::spec::Split;
use rayon::prelude::*;
use serde::Serialize;
use std::fmt;
use std::path::Path;

/// One group's result.
#[derive(Debug, Clone, Serialize)]
pub struct GroupBaseline {
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
}

/// The baseline over a dataset.
#[derive(Debug, Clone, Serialize)]
pub struct BaselineReport {
    pub dataset: String,
    pub world: String,
    pub max_lag_s: f64,
    pub groups: Vec<GroupBaseline>,
}

/// A scored ordered pair: (score in metres, truly linked).
type ScoredPair = (f64, bool);

/// Runs the baseline over the dataset in `dir`.
pub fn baseline(dir: &Path, max_lag_s: f64) -> Result<BaselineReport, String> {
    if !(max_lag_s > 0.0 && max_lag_s.is_finite()) {
        return Err(format!("--max-lag must be a positive number of seconds, not {max_lag_s}"));
    }
    let dataset = Dataset::open_complete(dir)?;
    let spec = dataset.spec();
    let mut per_group = Vec::new();
    for group in &spec.groups {
        let name = group.name();
        let score_split = |split: Split| -> Result<Vec<Vec<ScoredPair>>, String> {
            dataset.scenario_dirs(&name, split).par_iter().map(|d| score_scenario(d, max_lag_s)).collect()
        };
        per_group.push((group, score_split(Split::Train)?, score_split(Split::Test)?));
    }
    let pooled: Vec<ScoredPair> = per_group.iter().flat_map(|(_, train, _)| train.iter().flatten().copied()).collect();
    let pooled_threshold = best_threshold(&pooled);
    let mut groups = Vec::new();
    for (group, train, test) in per_group {
        let train_pairs: Vec<ScoredPair> = train.iter().flatten().copied().collect();
        let (threshold, from) = match best_threshold(&train_pairs) {
            Some(t) => (t, "train"),
            None => match pooled_threshold {
                Some(t) => (t, "pooled"),
                None => {
                    return Err(format!(
                        "{}: no leader-follower pairs in any train split, so there is no threshold to learn; \
                         generate train scenarios with edge_proportion > 0",
                        dir.display()
                    ))
                }
            },
        };
        let test_pairs: Vec<ScoredPair> = test.iter().flatten().copied().collect();
        let counts = Counts::at(&test_pairs, threshold);
        groups.push(GroupBaseline {
            group: group.name(),
            cars: group.cars,
            edge_proportion: group.edge_proportion,
            threshold_m: threshold,
            threshold_from: from,
            train_scenarios: train.len(),
            train_f1: Counts::at(&train_pairs, threshold).f1(),
            test_scenarios: test.len(),
            test_pairs: test_pairs.len(),
            test_true_edges: counts.true_positives + counts.false_negatives,
            test_predicted_edges: counts.true_positives + counts.false_positives,
            test_predicted_share: if test_pairs.is_empty() {
                0.0
            } else {
                (counts.true_positives + counts.false_positives) as f64 / test_pairs.len() as f64
            },
            precision: counts.precision(),
            recall: counts.recall(),
            f1: counts.f1(),
        });
    }
    Ok(BaselineReport { dataset: dir.display().to_string(), world: spec.world.name().to_string(), max_lag_s, groups })
}

/// Scores every ordered pair of the scenario in `dir`.
fn score_scenario(dir: &Path, max_lag_s: f64) -> Result<Vec<ScoredPair>, String> {
    let scenario = ScenarioSummary::read(dir)?;
    let (frames, cars) = (scenario.frames as usize, scenario.cars.len());
    let poses = PoseLog::read(dir, frames, cars)?;
    let max_lag = ((max_lag_s / scenario.frame_interval).round() as usize).max(1);
    let tracks: Vec<Vec<[f64; 2]>> =
        (0..cars).map(|c| (0..frames).map(|f| [poses.at(f, c).x, poses.at(f, c).y]).collect()).collect();
    let mut pairs = Vec::with_capacity(cars * cars.saturating_sub(1));
    for leader in 0..cars {
        for follower in 0..cars {
            if leader == follower {
                continue;
            }
            let linked = scenario.edges.iter().any(|e| e[0] as usize == leader && e[1] as usize == follower);
            pairs.push((following_score(&tracks[leader], &tracks[follower], max_lag), linked));
        }
    }
    Ok(pairs)
}

/// Mean over frames of the distance from `follower` to the nearest point of
/// `leader`'s path over the previous `max_lag` frames.
pub fn following_score(leader: &[[f64; 2]], follower: &[[f64; 2]], max_lag: usize) -> f64 {
    let frames = leader.len().min(follower.len());
    if frames < 2 {
        return f64::INFINITY;
    }
    let mut total = 0.0;
    for (t, &[fx, fy]) in follower.iter().enumerate().take(frames).skip(1) {
        let nearest = (t.saturating_sub(max_lag)..t)
            .map(|s| {
                let [lx, ly] = leader[s];
                (fx - lx) * (fx - lx) + (fy - ly) * (fy - ly)
            })
            .fold(f64::INFINITY, f64::min);
        total += nearest.sqrt();
    }
    total / (frames - 1) as f64
}

#[derive(Debug, Default, Clone, Copy)]
struct Counts {
    true_positives: usize,
    false_positives: usize,
    false_negatives: usize,
}

impl Counts {
    fn at(pairs: &[ScoredPair], threshold: f64) -> Counts {
        let mut c = Counts::default();
        for &(score, linked) in pairs {
            match (score < threshold, linked) {
                (true, true) => c.true_positives += 1,
                (true, false) => c.false_positives += 1,
                (false, true) => c.false_negatives += 1,
                (false, false) => {}
            }
        }
        c
    }

    fn precision(&self) -> Option<f64> {
        let called = self.true_positives + self.false_positives;
        (called > 0).then(|| self.true_positives as f64 / called as f64)
    }

    fn recall(&self) -> Option<f64> {
        let there = self.true_positives + self.false_negatives;
        (there > 0).then(|| self.true_positives as f64 / there as f64)
    }

    fn f1(&self) -> Option<f64> {
        let denominator = 2 * self.true_positives + self.false_positives + self.false_negatives;
        (denominator > 0).then(|| 2.0 * self.true_positives as f64 / denominator as f64)
    }
}

/// The threshold that maximises F1 over `pairs` (midway between the scores
/// it separates); None without a linked pair.
fn best_threshold(pairs: &[ScoredPair]) -> Option<f64> {
    let positives = pairs.iter().filter(|p| p.1).count();
    if positives == 0 {
        return None;
    }
    let mut sorted: Vec<ScoredPair> = pairs.iter().copied().filter(|p| p.0.is_finite()).collect();
    sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
    // Calling the first k pairs linked: F1 = 2 tp / (k + positives).
    let (mut best_f1, mut best_k, mut tp) = (-1.0, 0, 0usize);
    for k in 1..=sorted.len() {
        tp += sorted[k - 1].1 as usize;
        let tied_with_next = k < sorted.len() && sorted[k].0 == sorted[k - 1].0;
        let f1 = 2.0 * tp as f64 / (k + positives) as f64;
        if !tied_with_next && f1 > best_f1 {
            (best_f1, best_k) = (f1, k);
        }
    }
    let below = sorted[best_k - 1].0;
    Some(match sorted.get(best_k) {
        Some(&(above, _)) => (below + above) / 2.0,
        None => below * 1.5 + 1e-9,
    })
}

impl fmt::Display for BaselineReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "following-score baseline on {} ({} world, lags up to {} s): threshold from train, scores on test",
            self.dataset, self.world, self.max_lag_s
        )?;
        writeln!(
            f,
            "{:<18} {:>4} {:>6} {:>11} {:>6} {:>6} {:>7} {:>9} {:>9} {:>6} {:>6}",
            "group", "cars", "edges%", "threshold m", "from", "test", "pairs", "linked", "called", "P", "R"
        )?;
        let show = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.3}"));
        for g in &self.groups {
            writeln!(
                f,
                "{:<18} {:>4} {:>6.0} {:>11.3} {:>6} {:>6} {:>7} {:>9} {:>9} {:>6} {:>6}  F1 {}",
                g.group,
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
                show(g.f1)
            )?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
    fn the_threshold_separates_a_clean_split() {
        let pairs = vec![(0.1, true), (0.2, true), (3.0, false), (4.0, false)];
        let t = best_threshold(&pairs).unwrap();
        assert!(t > 0.2 && t < 3.0);
        assert_eq!(Counts::at(&pairs, t).f1(), Some(1.0));
        assert_eq!(best_threshold(&[(1.0, false)]), None);
    }
}
