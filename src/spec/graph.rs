//! The shape of each scenario's designed leader-follower graph (`graph`):
//! disjoint pairs (the paper's, the default), chains, forks or colliders.

use super::SpecError;
use serde::{Deserialize, Serialize};

/// How a scenario's designed edges are joined.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum GraphShape {
    /// Disjoint leader-follower pairs: each car in one edge at most.
    #[default]
    Pairs,
    /// Queues in which every car but the first follows the car right ahead
    /// of it: A -> B -> C.
    Chains,
    /// One leader with several followers queued behind it, each following
    /// the leader: A -> B, A -> C.
    Forks,
    /// A follower that must also give way to a third car: A -> C, B -> C.
    /// A leads C; B is placed on a movement that crosses C's at C's first
    /// junction and goes before it, timed to reach the junction about when
    /// C does. City towns with junctions where a driver gives way only.
    Colliders,
}

impl GraphShape {
    pub fn name(self) -> &'static str {
        match self {
            GraphShape::Pairs => "pairs",
            GraphShape::Chains => "chains",
            GraphShape::Forks => "forks",
            GraphShape::Colliders => "colliders",
        }
    }
}

/// Cars in one collider: the leader, its follower and the car with priority.
pub const COLLIDER_CARS: u32 = 3;

/// Most cars in one chain or fork (its leader included).
pub const MAX_GRAPH_UNIT_CARS: u32 = 6;

/// The designed graph's shape: `{"shape": "chains", "cars": 3}`. Every
/// shape has the group's `round(edge_proportion x cars / 2)` edges; the
/// shape says how they are joined.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GraphSpec {
    #[serde(default)]
    pub shape: GraphShape,
    /// Cars in one chain or fork, its leader included (3 when absent);
    /// pairs have 2 and leave it out.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cars: Option<u32>,
}

impl GraphSpec {
    pub fn is_pairs(&self) -> bool {
        self.shape == GraphShape::Pairs
    }

    /// Cars in one full chain, fork or collider, its leader included.
    pub fn unit_cars(&self) -> u32 {
        match self.shape {
            GraphShape::Pairs => 2,
            GraphShape::Colliders => COLLIDER_CARS,
            _ => self.cars.unwrap_or(3),
        }
    }

    /// Cars of one full unit that start queued in one lane: all of a chain
    /// or fork, a collider's leader and follower (its third car comes from
    /// the crossing road).
    pub fn queued_cars(&self) -> u32 {
        match self.shape {
            GraphShape::Colliders => 2,
            _ => self.unit_cars(),
        }
    }

    /// The cars of each connected part (leader first, then its followers)
    /// that together hold `edges` edges: full chains or forks while edges
    /// remain, then one smaller part with the rest (a pair at least).
    pub fn units(&self, edges: u32) -> Vec<u32> {
        let per_unit = self.unit_cars() - 1;
        let mut units = vec![self.unit_cars(); (edges / per_unit) as usize];
        if !edges.is_multiple_of(per_unit) {
            units.push(edges % per_unit + 1);
        }
        units
    }

    /// Cars that `edges` edges of this shape take.
    pub fn cars_needed(&self, edges: u32) -> u32 {
        self.units(edges).iter().sum()
    }

    pub(super) fn validate(&self) -> Result<(), SpecError> {
        match (self.shape, self.cars) {
            (GraphShape::Pairs, Some(cars)) if cars != 2 => Err(SpecError::new(
                "graph.cars",
                format!("{cars} is not allowed with graph.shape \"pairs\": a pair has 2 cars; use \"chains\" or \"forks\" for more"),
            )),
            (GraphShape::Colliders, Some(cars)) if cars != COLLIDER_CARS => Err(SpecError::new(
                "graph.cars",
                format!("{cars} is not allowed with graph.shape \"colliders\": a collider has {COLLIDER_CARS} cars (a leader, its follower and the car the follower gives way to); leave graph.cars out"),
            )),
            (_, Some(cars)) if !(2..=MAX_GRAPH_UNIT_CARS).contains(&cars) => Err(SpecError::new(
                "graph.cars",
                format!(
                    "{cars} is not allowed: cars in one chain or fork, its leader included, 2 to {MAX_GRAPH_UNIT_CARS}"
                ),
            )),
            _ => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn units_hold_exactly_the_edges_asked_for() {
        let chains = GraphSpec { shape: GraphShape::Chains, cars: Some(3) };
        assert_eq!(chains.units(2), vec![3]);
        assert_eq!(chains.units(3), vec![3, 2]);
        assert_eq!(chains.cars_needed(3), 5);
        let forks = GraphSpec { shape: GraphShape::Forks, cars: Some(4) };
        assert_eq!(forks.units(5), vec![4, 3]);
        assert_eq!(GraphSpec::default().units(3), vec![2, 2, 2]);
        for spec in [chains, forks, GraphSpec::default()] {
            for edges in 0..12 {
                let units = spec.units(edges);
                assert_eq!(units.iter().map(|n| n - 1).sum::<u32>(), edges, "{spec:?}");
                assert!(units.iter().all(|&n| n >= 2 && n <= spec.unit_cars()));
            }
        }
    }
}
