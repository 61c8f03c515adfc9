//! Colliders (`graph.shape: "colliders"`): a follower that must also give
//! way to a third car. The planner only places that car where the world's
//! rules will make the follower give way to it: on a movement that crosses
//! the follower's at its first junction and goes before it, timed to reach
//! its line about when the follower reaches its own. Whether it did is
//! measured, as for every designed edge, by the effects.

use super::planner::{draw_desired_speeds, round_mm, PlacedCar, Planner, SPAWN_CLEARANCE};
use super::spawn::{split_owning_start, OWNED_START_SEARCH_MM};
use crate::geometry::OrientedBox;
use crate::map::control::JunctionControl;
use crate::map::{Action, ConnectorId, LaneId, LegKind, Turn};
use crate::plan::Role;
use crate::spec::CitySpec;
use rand::RngExt;
use rand_chacha::ChaCha8Rng;
use std::sync::Arc;

/// How much earlier than "as the leader, and as the follower, would leave
/// the box" the car with priority is timed to reach its line, seconds. A
/// driver who gives way looks a few seconds before its line for a car with
/// priority that would arrive before it could clear the box, and the car
/// with priority, often a junction further away, is estimated least well.
/// Tuned on 3 x 3 priority towns (60 scenarios, free starts): the car with
/// priority holds the follower up in 87 % of colliders at 2 s, 48 % at 0 s
/// and 50 % at -2 s; directly (not through its leader, held up too) in 15,
/// 17 and 12 %.
pub(super) const PRIORITY_LEAD_S: f64 = 2.0;

/// At an all-way stop, when the car with priority reaches its line,
/// seconds relative to the follower's estimated arrival at its own: just
/// before, so that it halts first and goes first.
pub(super) const ALL_WAY_LEAD_S: (f64, f64) = (-2.0, 0.0);

/// The shortest arrival window worth a try, seconds.
const MIN_WINDOW_S: f64 = 0.5;

/// Tries at the car with priority for one leader-follower pair (another
/// crossing movement or arrival time each).
const PRIORITY_TRIES: usize = 40;

impl Planner {
    /// Whether this town has a junction where a driver must give way to a
    /// crossing movement: without lights, or a left turn on a permissive
    /// green.
    pub fn has_give_way_junctions(&self) -> bool {
        (0..self.map.connectors.len()).any(|c| self.gives_way_at(c))
    }

    fn gives_way_at(&self, connector: ConnectorId) -> bool {
        self.map.connectors[connector].intersection.is_some()
            && (self.map.gives_way(connector) || self.map.permissive_left(connector))
    }

    /// The car `cars[follower]` (following `cars[leader]`) must give way to
    /// at its first junction, placed clear of `boxes` and of every car in
    /// `cars`: on a movement that crosses the follower's there and goes
    /// before it, starting on its approach or on a lane before it that it
    /// leaves with the right of way, its first actions those movements, at
    /// the distance that brings it to its line in the window where the
    /// follower, not its leader, must give way (both estimated at their
    /// first desired speeds). `None` where the follower's first junction is
    /// one it has the right of way at, or no start fits.
    pub(super) fn place_priority_car(
        &self,
        rng: &mut ChaCha8Rng,
        city: &CitySpec,
        split: usize,
        (leader, follower): (usize, usize),
        cars: &[PlacedCar],
        boxes: &[OrientedBox],
    ) -> Option<PlacedCar> {
        let f = &cars[follower];
        let half = self.spec.car_length_m / 2.0;
        let setback = self.map.layout.stop_line_setback;
        // The follower's first movement through a junction, reached along
        // its lanes alone: a lane change or a loop on the way would make its
        // arrival too hard to foresee.
        let first = f.route.legs.iter().position(|leg| matches!(leg.kind, LegKind::Connector(_)))?;
        let LegKind::Connector(connector) = f.route.legs[first].kind else { return None };
        self.map.connectors[connector].intersection?;
        if f.route.legs[..first].iter().any(|leg| !matches!(leg.kind, LegKind::Lane(_))) {
            return None;
        }
        let junction_start = f.route.legs[first].route_start;
        if !self.gives_way_at(connector) {
            return None;
        }
        let to_line = junction_start - setback - (f.distance + half);
        let speed = f.desired_speeds[0].min(cars[leader].desired_speeds[0]);
        if to_line <= 0.0 || speed <= 0.0 {
            return None;
        }
        // When the car with priority should reach its line, seconds from
        // the start: at an all-way stop just before the follower halts at
        // its own (it then goes first); elsewhere once the leader has
        // crossed, and while the follower is still in its way.
        // (In a platoon the leader may start on the lane beside: its own
        // first junction's line.)
        let l = &cars[leader];
        let leader_junction = l.route.legs.iter().find(|leg| matches!(leg.kind, LegKind::Connector(_)));
        let leader_to_line = leader_junction.map_or(0.0, |leg| leg.route_start) - setback - (l.distance + half);
        let x = &self.map.intersections[self.map.connectors[connector].intersection?];
        let cross = (2.0 * x.half_size + self.spec.car_length_m) / speed - PRIORITY_LEAD_S;
        let window = if self.map.control_of(connector) == Some(JunctionControl::AllWayStop) {
            (to_line / speed + ALL_WAY_LEAD_S.0, to_line / speed + ALL_WAY_LEAD_S.1)
        } else {
            (leader_to_line.max(0.0) / speed + cross, to_line / speed + cross)
        };
        if window.1 - window.0 < MIN_WINDOW_S {
            return None;
        }
        let crossing: Vec<ConnectorId> = self
            .map
            .conflicts(connector)
            .iter()
            .copied()
            .filter(|&y| self.map.goes_before(y, connector) && self.map.connectors[y].turn != Turn::UTurn)
            .collect();
        if crossing.is_empty() {
            return None;
        }
        for _ in 0..PRIORITY_TRIES {
            let y = crossing[rng.random_range(0..crossing.len())];
            let approach = self.map.connectors[y].from;
            // Its start: on the approach, or on a lane before it from which
            // it has the right of way into the approach (further away).
            let mut starts: Vec<(Option<ConnectorId>, LaneId)> = vec![(None, approach)];
            starts.extend(self.map.connectors.iter().enumerate().filter_map(|(k, c)| {
                let free = c.to == approach
                    && c.turn != Turn::UTurn
                    && self.map.control_of(k).is_some_and(|j| j != JunctionControl::Signals)
                    && !self.gives_way_at(k);
                free.then_some((Some(k), c.from))
            }));
            let (before, lane) = starts[rng.random_range(0..starts.len())];
            let Some(span) = self.spans.iter().find(|s| s.lane == lane).copied() else { continue };
            let desired_speeds = draw_desired_speeds(rng, Some(city), self.spec.actions_per_car as usize);
            let arrives = window.0 + rng.random_range(0.0..=1.0) * (window.1 - window.0);
            // Its front reaches its line after the stretch to the approach
            // at its first desired speed (when it starts before it) and the
            // approach at the next.
            let to_line = self.map.lanes[approach].curve.length() - setback - half;
            let drawn = match before {
                None => to_line - desired_speeds[0] * arrives,
                Some(k) => {
                    // (One speed only where the spec draws no actions.)
                    let next = desired_speeds.get(1).copied().unwrap_or(desired_speeds[0]);
                    let to_approach = (arrives - to_line / next) * desired_speeds[0];
                    self.map.lanes[lane].curve.length() + self.map.connectors[k].curve.length() - to_approach
                }
            };
            let drawn = round_mm(drawn);
            let Some(s) = (0..OWNED_START_SEARCH_MM)
                .map(|mm| round_mm(drawn + mm as f64 / 1000.0))
                .find(|&s| split_owning_start(lane, s) == split)
            else {
                continue;
            };
            if s < span.lo || s > span.hi || !self.start_is_free(lane, s, cars, boxes) {
                continue;
            }
            let (mut actions, mut merges) = self.draw_actions(rng, city.action_drawing, lane, s);
            let movements: Vec<ConnectorId> = before.into_iter().chain([y]).collect();
            for (k, &m) in movements.iter().enumerate() {
                let action = Action::making(self.map.connectors[m].turn);
                if actions.len() <= k {
                    actions.push(action);
                    merges.push(0.0);
                } else {
                    actions[k] = action;
                    merges[k] = 0.0;
                }
            }
            let Ok(route) = self.plan_feasible_route(lane, s, &mut actions, &merges, self.max_travel()) else {
                continue;
            };
            // It drives its lanes and those movements, nothing else, to its line.
            let taken: Vec<LegKind> = route.legs.iter().take(2 * movements.len()).map(|leg| leg.kind).collect();
            let simple = taken.len() == 2 * movements.len()
                && taken.iter().enumerate().all(|(k, kind)| match (k % 2, kind) {
                    (0, LegKind::Lane(_)) => true,
                    (1, LegKind::Connector(c)) => *c == movements[k / 2],
                    _ => false,
                });
            if !simple {
                continue;
            }
            let mut desired_speeds = desired_speeds;
            desired_speeds.resize(actions.len() + 1, *desired_speeds.last().unwrap_or(&0.0));
            return Some(PlacedCar {
                role: Role::Priority,
                spawn: lane,
                distance: s,
                actions,
                merges,
                route: Arc::new(route),
                desired_speeds,
                behind: None,
                leader: None,
                gives_way_to: None,
                on_leader_lost: None,
            });
        }
        None
    }

    /// Whether a car may start `s` metres along `lane`: clear of `boxes`,
    /// and no closer to a car of `cars` in its lane than the shortest
    /// follower gap.
    fn start_is_free(&self, lane: LaneId, s: f64, cars: &[PlacedCar], boxes: &[OrientedBox]) -> bool {
        let b = self.car_box(lane, s).inflated(SPAWN_CLEARANCE / 2.0);
        boxes.iter().all(|p| !b.overlaps(&p.inflated(SPAWN_CLEARANCE / 2.0)))
            && cars.iter().filter(|c| c.spawn == lane).all(|c| (c.distance - s).abs() >= self.shortest_spacing_m - 1e-6)
    }
}
