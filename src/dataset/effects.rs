//! effects.csv against the scenario.json beside it: the rule `validate` and
//! the Python package's reader both hold a scenario's interventional truth
//! to (a repeated or missing row, or a graph its rows do not give, was read
//! by the package as written).

use super::edge_pairs;
use crate::world::effects::{EffectReport, EffectRow, InterventionKind};
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// Checks effects.csv's `rows` (each already parsed and checked) against
/// the scenario.json `record` at `json`: one row per cause, other car and
/// intervention (every car removed; its next action changed where it has
/// one), and scenario.json's graphs the ones its rows give. Errors about the
/// rows name no file (the caller names effects.csv); about a graph, `json`.
pub fn check_effects(
    rows: Vec<EffectRow>,
    record: &serde_json::Value,
    json: &Path,
    cars: usize,
    threshold: f64,
) -> Result<EffectReport, String> {
    let mut seen = BTreeSet::new();
    let mut per_cause: BTreeMap<(u32, InterventionKind), usize> = BTreeMap::new();
    for r in &rows {
        if !seen.insert((r.cause, r.intervention, r.effect)) {
            return Err(format!("two rows for cause {}, effect {}, {}", r.cause, r.effect, r.intervention.name()));
        }
        *per_cause.entry((r.cause, r.intervention)).or_default() += 1;
    }
    for (&(cause, kind), &n) in &per_cause {
        if n + 1 != cars {
            return Err(format!("cause {cause}, {}: {n} rows, expected one per other car ({})", kind.name(), cars - 1));
        }
    }
    // Every car removed; every car with actions given another next action.
    let with_actions = |car: usize| record["cars"][car]["actions"].as_array().is_some_and(|a| !a.is_empty());
    for (kind, causes) in [
        (InterventionKind::Remove, cars),
        (InterventionKind::NextAction, (0..cars).filter(|&c| with_actions(c)).count()),
    ] {
        let rows = seen.iter().filter(|&&(_, k, _)| k == kind).count();
        if rows != causes * cars.saturating_sub(1) {
            return Err(format!(
                "{rows} {} rows, expected {} ({causes} cars intervened on, each against every other car)",
                kind.name(),
                causes * cars.saturating_sub(1)
            ));
        }
    }
    let report = EffectReport { threshold_m: threshold, rows };
    let designed = edge_pairs(record, "edges").unwrap_or_default();
    for (field, expected) in [
        ("causal_edges", report.causal_edges()),
        ("direct_edges", report.direct_edges()),
        ("edges_without_effect", report.edges_without_effect(&designed)),
    ] {
        match edge_pairs(record, field) {
            Some(found) if found == expected => {}
            Some(found) => {
                return Err(format!("{} `{field}` is {found:?}; effects.csv's rows give {expected:?}", json.display()))
            }
            None => return Err(format!("{} has no list of pairs `{field}`", json.display())),
        }
    }
    Ok(report)
}
