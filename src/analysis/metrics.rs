//! Ranking metrics of scored pairs, shared by `baseline` and `evaluate`.
//! A pair is (score, truly linked) where a *lower* score means "more likely
//! linked" (the baseline's distances); `evaluate` negates predicted scores,
//! whose convention is the opposite. Each metric is defined as scikit-learn
//! defines it, so that numbers agree with `roc_auc_score`,
//! `average_precision_score` and `f1_score`.

/// A scored ordered pair: (score, truly linked); lower scores are called first.
pub type ScoredPair = (f64, bool);

/// Pairs sorted by score, grouped into runs of equal scores:
/// (linked, unlinked) counts per run, lowest score first.
fn tied_runs(pairs: &[ScoredPair]) -> Vec<(usize, usize)> {
    let mut sorted: Vec<ScoredPair> = pairs.to_vec();
    sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut runs: Vec<(usize, usize)> = Vec::new();
    let mut last = None;
    for (score, linked) in sorted {
        if last != Some(score) {
            runs.push((0, 0));
            last = Some(score);
        }
        let run = runs.last_mut().expect("a run was pushed");
        if linked {
            run.0 += 1;
        } else {
            run.1 += 1;
        }
    }
    runs
}

/// The chance that a linked pair scores below an unlinked one, ties half
/// (the Mann-Whitney form of the area under the ROC curve).
pub fn auroc(pairs: &[ScoredPair]) -> Option<f64> {
    let positives = pairs.iter().filter(|p| p.1).count();
    let negatives = pairs.len() - positives;
    if positives == 0 || negatives == 0 {
        return None;
    }
    let (mut wins, mut negatives_above) = (0.0, negatives as f64);
    for (linked, unlinked) in tied_runs(pairs) {
        negatives_above -= unlinked as f64;
        wins += linked as f64 * (negatives_above + unlinked as f64 / 2.0);
    }
    Some(wins / (positives * negatives) as f64)
}

/// Average precision: precision at each distinct threshold, weighted by the
/// recall it adds (as scikit-learn computes it).
pub fn average_precision(pairs: &[ScoredPair]) -> Option<f64> {
    let positives = pairs.iter().filter(|p| p.1).count();
    if positives == 0 {
        return None;
    }
    // Each run's linked pairs times its precision, summed, then divided by
    // the linked pairs once: each term is at most its linked count (a
    // precision is at most 1), so the sum is at most their (exact) total and
    // the mean at most 1. Dividing each term first summed fractions whose
    // round-off took a perfect ranking to 1.0000000000000004, above the
    // metric's range (a `paper` run then refused its own unit record).
    let (mut tp, mut called, mut weighted) = (0usize, 0usize, 0.0);
    for (linked, unlinked) in tied_runs(pairs) {
        tp += linked;
        called += linked + unlinked;
        weighted += linked as f64 * (tp as f64 / called as f64);
    }
    Some(weighted / positives as f64)
}

#[derive(Debug, Default, Clone, Copy)]
pub struct Counts {
    pub true_positives: usize,
    pub false_positives: usize,
    pub false_negatives: usize,
}

impl Counts {
    pub fn at(pairs: &[ScoredPair], threshold: f64) -> Counts {
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

    pub fn precision(&self) -> Option<f64> {
        let called = self.true_positives + self.false_positives;
        (called > 0).then(|| self.true_positives as f64 / called as f64)
    }

    pub fn recall(&self) -> Option<f64> {
        let there = self.true_positives + self.false_negatives;
        (there > 0).then(|| self.true_positives as f64 / there as f64)
    }

    pub fn f1(&self) -> Option<f64> {
        let denominator = 2 * self.true_positives + self.false_positives + self.false_negatives;
        (denominator > 0).then(|| 2.0 * self.true_positives as f64 / denominator as f64)
    }
}

/// The threshold that maximises F1 over `pairs` (midway between the scores
/// it separates); None without a linked pair.
pub fn best_threshold(pairs: &[ScoredPair]) -> Option<f64> {
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
    // No finite score (a scenario too short to score): nothing to separate.
    let below = sorted.get(best_k.checked_sub(1)?)?.0;
    Some(match sorted.get(best_k) {
        // By halves where the sum overflows (scores near the float's ends).
        Some(&(above, _)) => match (below + above) / 2.0 {
            mid if mid.is_infinite() => below / 2.0 + above / 2.0,
            mid if mid > below => mid,
            // Neighbouring floats: the upper one (a score is linked below it).
            _ => above,
        },
        // Every pair linked: above the highest score by half its size (by
        // 1e-9 near 0), whatever its sign.
        None => below + (below.abs() * 0.5).max(1e-9),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_threshold_separates_a_clean_split() {
        let pairs = vec![(0.1, true), (0.2, true), (3.0, false), (4.0, false)];
        let t = best_threshold(&pairs).unwrap();
        assert!(t > 0.2 && t < 3.0);
        assert_eq!(Counts::at(&pairs, t).f1(), Some(1.0));
        assert_eq!(best_threshold(&[(1.0, false)]), None);
    }

    #[test]
    fn calling_every_pair_linked_puts_the_threshold_above_every_score_of_either_sign() {
        // Negated scores of one value, every pair linked: the threshold was
        // 1.5 x the score, below it for a negative score, so none was called.
        for score in [-1.0, -1e-12, 0.0, 2.0, -1e300, 1e300] {
            let pairs = [(score, true), (score, true)];
            let t = best_threshold(&pairs).unwrap();
            assert_eq!(Counts::at(&pairs, t).true_positives, 2, "score {score}: threshold {t}");
        }
        // Midway between the two scores it separates, without overflow.
        let wide = [(-1e308, true), (1e308, false)];
        let t = best_threshold(&wide).unwrap();
        assert!(t.is_finite() && Counts::at(&wide, t).f1() == Some(1.0), "{t}");
    }

    #[test]
    fn a_perfect_ranking_has_an_average_precision_of_exactly_one() {
        // Linked pairs at scores of their own, then the unlinked: a sum of
        // 1/n per pair misses 1 by round-off either way (0.99999999999998
        // at 1,750; 1.0000000000000004 on one toy split, above the range).
        for linked in [3, 7, 10, 1750, 4000] {
            let mut pairs: Vec<ScoredPair> = (0..linked).map(|k| (k as f64, true)).collect();
            pairs.extend((0..linked).map(|k| ((linked + k) as f64, false)));
            assert_eq!(average_precision(&pairs), Some(1.0), "{linked} linked pairs");
        }
    }

    #[test]
    fn auroc_and_average_precision_match_their_definitions() {
        // Perfectly separated, reversed, and with a tie.
        let clean = [(0.1, true), (0.2, true), (3.0, false), (4.0, false)];
        assert_eq!(auroc(&clean), Some(1.0));
        assert_eq!(average_precision(&clean), Some(1.0));
        let reversed = [(5.0, true), (0.2, false), (0.3, false)];
        assert_eq!(auroc(&reversed), Some(0.0));
        assert!((average_precision(&reversed).unwrap() - 1.0 / 3.0).abs() < 1e-12);
        let tied = [(1.0, true), (1.0, false), (2.0, false), (0.5, true)];
        // Pairs (pos, neg): 0.5 beats both, 1.0 ties one and beats one: (2 + 1.5) / 4.
        assert!((auroc(&tied).unwrap() - 3.5 / 4.0).abs() < 1e-12);
        // Thresholds 0.5 (P 1, R 1/2) and 1.0 (P 2/3, R 1): 0.5 x 1 + 0.5 x 2/3.
        assert!((average_precision(&tied).unwrap() - (0.5 + 1.0 / 3.0)).abs() < 1e-12);
        assert_eq!(auroc(&[(1.0, true)]), None);
        // Infinite scores (frame0's "not in one lane") tie at the end.
        assert_eq!(auroc(&[(f64::INFINITY, true), (f64::INFINITY, false)]), Some(0.5));
    }
}
