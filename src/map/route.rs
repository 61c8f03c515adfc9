//! Routes: the path a car takes through the map, built from a spawn lane and
//! a queue of high-level actions exactly as the original scenario files state
//! them (`left`, `right`, `straight` at the next intersection; `mergeL`,
//! `mergeR` at a distance along the current lane). Once the actions are used
//! up the route goes straight on (and round the off-camera loops) for as long
//! as it is asked to, so no car ever runs out of road.

use super::curve::Curve;
use super::{CityMap, ConnectorId, LaneEnd, LaneId, LanePosition, Turn};
use glam::DVec2;
use serde::{Deserialize, Serialize};
use std::fmt;

/// A high-level action from a car's drive queue.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Action {
    #[serde(rename = "left")]
    Left,
    #[serde(rename = "right")]
    Right,
    #[serde(rename = "straight")]
    Straight,
    #[serde(rename = "mergeL")]
    MergeL,
    #[serde(rename = "mergeR")]
    MergeR,
}

impl Action {
    pub const ALL: [Action; 5] = [Action::Left, Action::Right, Action::Straight, Action::MergeL, Action::MergeR];

    /// The name used in scenario files.
    pub fn name(self) -> &'static str {
        match self {
            Action::Left => "left",
            Action::Right => "right",
            Action::Straight => "straight",
            Action::MergeL => "mergeL",
            Action::MergeR => "mergeR",
        }
    }

    /// The action a scenario file names `name`.
    pub fn from_name(name: &str) -> Option<Action> {
        Action::ALL.into_iter().find(|a| a.name() == name)
    }

    pub fn is_merge(self) -> bool {
        matches!(self, Action::MergeL | Action::MergeR)
    }

    fn turn(self) -> Option<Turn> {
        match self {
            Action::Left => Some(Turn::Left),
            Action::Right => Some(Turn::Right),
            Action::Straight => Some(Turn::Straight),
            _ => None,
        }
    }
}

impl fmt::Display for Action {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Why an action cannot be carried out from where the car is.
#[derive(Debug, Clone, PartialEq)]
pub struct RouteError {
    /// Index of the offending action in the drive queue.
    pub action_index: usize,
    pub action: Action,
    pub reason: String,
}

impl fmt::Display for RouteError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "action {} ({}): {}", self.action_index, self.action, self.reason)
    }
}

impl std::error::Error for RouteError {}

/// What a stretch of a route runs along.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LegKind {
    Lane(LaneId),
    Connector(ConnectorId),
    /// A merge that starts `at` metres along `from` and ends on `to`.
    LaneChange {
        from: LaneId,
        to: LaneId,
        at: f64,
    },
}

/// One stretch of a route: part of a curve.
#[derive(Debug, Clone)]
pub struct RouteLeg {
    pub kind: LegKind,
    pub curve: Curve,
    /// Arc length on `curve` where this leg begins.
    pub curve_start: f64,
    pub length: f64,
    /// Arc length along the route where this leg begins.
    pub route_start: f64,
    /// Index in the drive queue of the action this leg carries out (merges
    /// and turns at intersections); `None` for lanes, loops and default moves.
    pub action: Option<usize>,
}

/// A car's path from the start of its spawn lane, parameterised by arc length.
#[derive(Debug, Clone)]
pub struct Route {
    pub legs: Vec<RouteLeg>,
    pub length: f64,
}

impl Route {
    /// Plans the route that starts at the beginning of `spawn`, carries out
    /// `actions` (with `merge_distances[i]` metres along the current lane for
    /// merges) and is at least `min_length` long. `entry` is how far along the
    /// spawn lane the car starts: a merge on the spawn lane must not lie
    /// behind it.
    pub fn plan(
        map: &CityMap,
        spawn: LaneId,
        entry: f64,
        actions: &[Action],
        merge_distances: &[f64],
        min_length: f64,
    ) -> Result<Route, RouteError> {
        let mut route = Route { legs: Vec::new(), length: 0.0 };
        let mut lane = spawn;
        let mut lane_entry = 0.0;
        let mut earliest = entry;
        let mut next = 0;
        let change_run = map.layout.lane_change_length;
        loop {
            if next >= actions.len() && route.length >= min_length {
                return Ok(route);
            }
            let curve = &map.lanes[lane].curve;
            let lane_len = curve.length();
            let head = actions.get(next).copied();
            let error = |reason: String| RouteError { action_index: next, action: head.unwrap(), reason };
            match head {
                Some(action) if action.is_merge() => {
                    let to_left = action == Action::MergeL;
                    let name = &map.lanes[lane].name;
                    let Some(target) = map.adjacent_lane(lane, to_left) else {
                        let side = if to_left { "left" } else { "right" };
                        let kind = match map.lanes[lane].position {
                            LanePosition::Outer => "outer",
                            LanePosition::Inner => "inner",
                        };
                        return Err(error(format!(
                            "lane {name} is the {kind} lane of its direction: there is no lane to its {side}"
                        )));
                    };
                    let at = merge_distances.get(next).copied().unwrap_or(0.0);
                    if !at.is_finite() || at < earliest - 1e-9 {
                        return Err(error(format!(
                            "merge distance {at} m lies behind the car, which is {earliest:.2} m along lane {name}"
                        )));
                    }
                    if at + change_run > lane_len + 1e-9 {
                        return Err(error(format!(
                            "merge distance {at} m is past the lane end: lane {name} is {lane_len:.2} m long and a merge needs {change_run} m, so use at most {:.2}",
                            lane_len - change_run
                        )));
                    }
                    route.push(LegKind::Lane(lane), curve.clone(), lane_entry, at - lane_entry, None);
                    let heading = curve.heading_at(at);
                    let shift = if to_left { 1.0 } else { -1.0 } * map.layout.lane_width;
                    let change = Curve::lane_change(
                        curve.lane_center_at(at),
                        DVec2::new(heading.cos(), heading.sin()),
                        change_run,
                        shift,
                    );
                    let len = change.length();
                    route.push(LegKind::LaneChange { from: lane, to: target, at }, change, 0.0, len, Some(next));
                    lane = target;
                    lane_entry = at + change_run;
                    earliest = lane_entry;
                    next += 1;
                }
                _ => {
                    route.push(LegKind::Lane(lane), curve.clone(), lane_entry, lane_len - lane_entry, None);
                    let (connector, consumed) = match map.lanes[lane].end {
                        LaneEnd::Loop(c) => (c, false),
                        LaneEnd::Intersection { .. } => {
                            let turn = head.and_then(Action::turn).unwrap_or(Turn::Straight);
                            match map.exit(lane, turn) {
                                Some(c) => (c, head.is_some()),
                                None => {
                                    let name = &map.lanes[lane].name;
                                    let allowed = match map.lanes[lane].position {
                                        LanePosition::Outer => "the outer lanes (w, z) go straight or turn right",
                                        LanePosition::Inner => "the inner lanes (x, y) go straight or turn left",
                                    };
                                    return Err(error(format!(
                                        "cannot turn {} from lane {name}: {allowed}; merge first",
                                        head.unwrap()
                                    )));
                                }
                            }
                        }
                    };
                    let c = &map.connectors[connector];
                    let action = consumed.then_some(next);
                    route.push(LegKind::Connector(connector), c.curve.clone(), 0.0, c.curve.length(), action);
                    lane = c.to;
                    lane_entry = 0.0;
                    earliest = 0.0;
                    if consumed {
                        next += 1;
                    }
                }
            }
        }
    }

    fn push(&mut self, kind: LegKind, curve: Curve, curve_start: f64, length: f64, action: Option<usize>) {
        if length <= 0.0 {
            return;
        }
        self.legs.push(RouteLeg { kind, curve, curve_start, length, route_start: self.length, action });
        self.length += length;
    }

    /// The leg containing route arc length `s` (clamped to the route).
    pub fn leg_at(&self, s: f64) -> &RouteLeg {
        &self.legs[self.leg_index_at(s)]
    }

    /// Index of the leg containing route arc length `s` (clamped to the route).
    pub fn leg_index_at(&self, s: f64) -> usize {
        self.legs.partition_point(|l| l.route_start + l.length <= s).min(self.legs.len() - 1)
    }

    /// Position and heading at route arc length `s`, `lateral` metres left of
    /// the centre line.
    pub fn pose_at(&self, s: f64, lateral: f64) -> (DVec2, f64) {
        let leg = self.leg_at(s);
        let on_curve = leg.curve_start + (s - leg.route_start).clamp(0.0, leg.length);
        (leg.curve.position(on_curve, lateral), leg.curve.heading_at(on_curve))
    }

    /// The lanes, lane changes and connectors of the route in order.
    pub fn kinds(&self) -> impl Iterator<Item = LegKind> + '_ {
        self.legs.iter().map(|l| l.kind)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn route_runs_on_forever_after_the_actions() {
        let map = CityMap::default();
        let spawn = map.lane_by_name("A1w").unwrap();
        let route = Route::plan(&map, spawn, 0.0, &[], &[], 2000.0).unwrap();
        assert!(route.length >= 2000.0);
        // Consecutive legs join up.
        for w in route.legs.windows(2) {
            let (a, b) = (&w[0], &w[1]);
            let end = a.curve.position(a.curve_start + a.length, 0.0);
            let start = b.curve.position(b.curve_start, 0.0);
            assert!(end.distance(start) < 0.01, "{:?} -> {:?}", a.kind, b.kind);
        }
    }
}
