//! Routes: the path a car takes through the map, built from a spawn lane and
//! a queue of high-level actions exactly as the original scenario files state
//! them (`left`, `right`, `straight` at the next intersection; `mergeL`,
//! `mergeR` at a distance along the current lane). Once the actions are used
//! up the route goes straight on (and round the off-camera loops) for as long
//! as it is asked to, so no car ever runs out of road.
//!
//! Planning is the driver's strategic layer (the lanes its actions need, as
//! SUMO's strategic lane changes or highway-env's route planning): under
//! [`LanePolicy::Adapt`] a turn that the current lane does not allow gets a
//! lane change into the lane that does, as early as it fits (on the lane
//! before, when the car reaches this one straight on or round a loop); an
//! action that cannot be done as written is adapted (a merge moved to the
//! nearest feasible point) or skipped, and each such change is recorded in
//! [`Route::adaptations`]. [`LanePolicy::Strict`] rejects the first action
//! that would need it. Whether the gap for a lane change is there is the
//! tactical layer's business (the world's, while it runs).

use super::curve::Curve;
use super::{CityMap, ConnectorId, LaneEnd, LaneId, LanePosition, Turn};
use crate::json::Shown;
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
    /// The lesser of two left turns at a junction of five arms or more
    /// ([`Turn::SlightLeft`]).
    #[serde(rename = "slight_left")]
    SlightLeft,
    /// The lesser of two right turns at a junction of five arms or more
    /// ([`Turn::SlightRight`]).
    #[serde(rename = "slight_right")]
    SlightRight,
}

impl Action {
    pub const ALL: [Action; 7] = [
        Action::Left,
        Action::Right,
        Action::Straight,
        Action::MergeL,
        Action::MergeR,
        Action::SlightLeft,
        Action::SlightRight,
    ];

    /// The name used in scenario files.
    pub fn name(self) -> &'static str {
        match self {
            Action::Left => "left",
            Action::Right => "right",
            Action::Straight => "straight",
            Action::MergeL => "mergeL",
            Action::MergeR => "mergeR",
            Action::SlightLeft => "slight_left",
            Action::SlightRight => "slight_right",
        }
    }

    /// The action a scenario file names `name`.
    pub fn from_name(name: &str) -> Option<Action> {
        Action::ALL.into_iter().find(|a| a.name() == name)
    }

    /// The action that makes `turn` at a junction (straight on for a
    /// U-turn loop, which no action asks for).
    pub fn making(turn: Turn) -> Action {
        match turn {
            Turn::Left => Action::Left,
            Turn::Right => Action::Right,
            Turn::SlightLeft => Action::SlightLeft,
            Turn::SlightRight => Action::SlightRight,
            Turn::Straight | Turn::UTurn => Action::Straight,
        }
    }

    pub fn is_merge(self) -> bool {
        matches!(self, Action::MergeL | Action::MergeR)
    }

    /// The movement a turn action makes at a junction; none for a merge.
    pub fn turn(self) -> Option<Turn> {
        match self {
            Action::Left => Some(Turn::Left),
            Action::Right => Some(Turn::Right),
            Action::Straight => Some(Turn::Straight),
            Action::SlightLeft => Some(Turn::SlightLeft),
            Action::SlightRight => Some(Turn::SlightRight),
            Action::MergeL | Action::MergeR => None,
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

/// How planning treats an action that cannot be driven as written.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub enum LanePolicy {
    /// Reject it: the scenario author asked for exactly these legs.
    Strict,
    /// Change lanes for turns, move merges to where they fit, skip what
    /// cannot be done at all; actions at `given_up` (indices into the queue)
    /// are skipped because the driver gave up waiting for a gap.
    #[default]
    Adapt,
    /// As `Adapt`, with these queue indices given up.
    AdaptGivingUp(Vec<usize>),
}

/// Lane changes planned for a turn start at least this far after where the
/// car enters the lane, metres, so the driver can check the gap first.
pub const STRATEGIC_CHANGE_LEAD: f64 = 1.0;
/// ... and this far ahead of a car that starts the scenario at rest on the
/// lane, which checks the gap before it moves, metres.
pub const SPAWN_CHANGE_LEAD: f64 = 0.1;

/// Whether an adapted action is still carried out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AdaptationKind {
    /// Carried out somewhere else than written (a merge moved).
    Adapted,
    /// Not carried out (the car drives straight on instead of a turn).
    Skipped,
}

/// A change planning made to one action of the drive queue.
#[derive(Debug, Clone, PartialEq)]
pub struct Adaptation {
    /// Index in the drive queue the route was planned for.
    pub action_index: usize,
    pub action: Action,
    pub kind: AdaptationKind,
    pub reason: String,
}

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
#[derive(Debug, Clone, PartialEq)]
pub struct RouteLeg {
    pub kind: LegKind,
    pub curve: Curve,
    /// Arc length on `curve` where this leg begins.
    pub curve_start: f64,
    pub length: f64,
    /// Arc length along the route where this leg begins.
    pub route_start: f64,
    /// Index in the drive queue of the action this leg carries out (merges
    /// and turns at intersections, or the straight move replacing a skipped
    /// turn); `None` for lanes, loops and default moves.
    pub action: Option<usize>,
    /// A lane change the driver planned itself: the index of the turn it
    /// prepares.
    pub prepares: Option<usize>,
}

impl RouteLeg {
    /// Position and heading at route arc length `s` (clamped to this leg),
    /// `lateral` metres left of the centre line.
    fn pose(&self, s: f64, lateral: f64) -> (DVec2, f64) {
        let on_curve = self.curve_start + (s - self.route_start).clamp(0.0, self.length);
        self.curve.pose(on_curve, lateral)
    }
}

/// A car's path from the start of its spawn lane, parameterised by arc length.
#[derive(Debug, Clone)]
pub struct Route {
    pub legs: Vec<RouteLeg>,
    pub length: f64,
    /// What planning changed about the drive queue, in queue order (always
    /// empty under [`LanePolicy::Strict`]).
    pub adaptations: Vec<Adaptation>,
}

impl Route {
    /// Plans the route that starts at the beginning of `spawn`, carries out
    /// `actions` (with `merge_distances[i]` metres along the current lane for
    /// merges) under `policy`, and is at least `min_length` long. `entry` is
    /// how far along the spawn lane the car starts: a merge on the spawn lane
    /// must not lie behind it.
    pub fn plan(
        map: &CityMap,
        spawn: LaneId,
        entry: f64,
        actions: &[Action],
        merge_distances: &[f64],
        min_length: f64,
        policy: &LanePolicy,
    ) -> Result<Route, RouteError> {
        let mut route = Route { legs: Vec::new(), length: 0.0, adaptations: Vec::new() };
        let strict = *policy == LanePolicy::Strict;
        let given_up = |i: usize| matches!(policy, LanePolicy::AdaptGivingUp(list) if list.contains(&i));
        let mut lane = spawn;
        let mut lane_entry = 0.0;
        let mut earliest = entry;
        let mut next = 0;
        let change_run = map.layout.lane_change_length;
        // The planner's state where the lane before the current one began to
        // be driven to its end, when the current lane was reached from it
        // straight on (or round a loop): a turn's lane change is planned
        // there when it fits, as a driver changes lanes early.
        let mut previous: Option<Snapshot> = None;
        // A lane change that look-back decided on: (lane, into, queue index served).
        let mut forced: Option<(LaneId, LaneId, usize)> = None;
        // The queue action look-back last went back for: on an imported
        // network once per action, as the lane beside the one before need not
        // lead to the lane that turns.
        let mut looked_back: Option<usize> = None;
        // Loops and junctions without a choice passed in a row while an
        // action waits.
        let mut loops_in_a_row = 0;
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
                    let asked = merge_distances.get(next).copied().unwrap_or(0.0);
                    let placement = if given_up(next) {
                        Err("the driver gave up waiting for a gap".to_string())
                    } else {
                        place_merge(map, lane, action, asked, earliest)
                    };
                    let (target, at) = match placement {
                        Ok((target, at, None)) => (target, at),
                        Ok((_, _, Some((problem, _)))) | Err(problem) if strict => return Err(error(problem)),
                        Ok((target, at, Some((problem, instead)))) => {
                            route.adapt(next, action, AdaptationKind::Adapted, format!("{problem}; {instead}"));
                            (target, at)
                        }
                        Err(reason) => {
                            route.adapt(next, action, AdaptationKind::Skipped, reason);
                            next += 1;
                            continue;
                        }
                    };
                    route.push_lane_change(map, lane, target, lane_entry, at, Some(next), None);
                    previous = None;
                    lane = target;
                    lane_entry = at + change_run;
                    earliest = lane_entry;
                    next += 1;
                }
                _ => {
                    if let Some((from, target, serves)) = forced.take().filter(|f| f.0 == lane) {
                        let at = grid_up(earliest + STRATEGIC_CHANGE_LEAD);
                        route.push_lane_change(map, lane, target, lane_entry, at, None, Some(serves));
                        lane = target;
                        lane_entry = at + change_run;
                        earliest = lane_entry;
                        debug_assert_ne!(from, lane);
                        continue;
                    }
                    // With no action left a car goes straight on, or where a
                    // T-junction has no straight on, takes its lane's turn.
                    let turn = head.and_then(Action::turn).unwrap_or_else(|| map.default_turn(lane));
                    let at_intersection = matches!(map.lanes[lane].end, LaneEnd::Intersection { .. })
                        && (head.is_none() || map.has_choice(lane));
                    if let Some(action) = head.filter(|_| !at_intersection) {
                        // A lane that loops back, or meets a junction with no choice,
                        // while the lane beside it turns (imported networks: a
                        // turnaround lane): change into it. On a road that never
                        // reaches a choice, give up.
                        if map.lane_towards(lane, turn).is_some() {
                            if let Ok((target, at)) =
                                plan_turn_lane(map, lane, turn, earliest + STRATEGIC_CHANGE_LEAD, given_up(next))
                            {
                                route.push_lane_change(map, lane, target, lane_entry, at, None, Some(next));
                                lane = target;
                                lane_entry = at + change_run;
                                earliest = lane_entry;
                                continue;
                            }
                        }
                        loops_in_a_row += 1;
                        if loops_in_a_row > map.lanes.len() {
                            let reason =
                                "no junction with a choice ahead: the road only goes on or loops back".to_string();
                            if strict {
                                return Err(error(reason));
                            }
                            route.adapt(next, action, AdaptationKind::Skipped, reason);
                            next += 1;
                            loops_in_a_row = 0;
                            continue;
                        }
                    } else {
                        loops_in_a_row = 0;
                    }
                    let mut carried_out = at_intersection && head.is_some();
                    if at_intersection && map.exit(lane, turn).is_none() {
                        let action = head.expect("with no action, the turn is one the lane has");
                        if strict {
                            return Err(error(wrong_lane(map, lane, action)));
                        }
                        // As early as it fits: on the lane before, if the car came
                        // straight on (or round a loop) from it, else on this one.
                        let to_left = turn.bears_left();
                        // (At a T-junction's stem no lane may go straight on.)
                        let beside_turns = map.lane_towards(lane, turn).is_some();
                        // (Grid towns go back once per lane change a turn needs.)
                        let again = map.is_imported() && looked_back == Some(next);
                        let back = previous
                            .take()
                            .filter(|p| beside_turns && !given_up(next) && !again && p.has_room(map, to_left));
                        if let Some(p) = back {
                            looked_back = Some(next);
                            let before = map.adjacent_lane(p.lane, to_left).expect("room means a lane beside");
                            forced = Some((p.lane, before, next));
                            (lane, lane_entry, earliest, next) = (p.lane, p.lane_entry, p.earliest, p.next);
                            route.legs.truncate(p.legs);
                            route.length = p.length;
                            route.adaptations.truncate(p.adaptations);
                            continue;
                        }
                        let on_spawn = route.legs.iter().all(|l| l.kind == LegKind::Lane(spawn));
                        let lead = if on_spawn && entry > 0.0 { SPAWN_CHANGE_LEAD } else { STRATEGIC_CHANGE_LEAD };
                        match plan_turn_lane(map, lane, turn, earliest + lead, given_up(next)) {
                            Ok((target, at)) => {
                                route.push_lane_change(map, lane, target, lane_entry, at, None, Some(next));
                                lane = target;
                                lane_entry = at + change_run;
                                earliest = lane_entry;
                                continue;
                            }
                            Err(reason) => {
                                route.adapt(next, action, AdaptationKind::Skipped, reason);
                                carried_out = true;
                            }
                        }
                    }
                    let snapshot = Snapshot {
                        lane,
                        lane_entry,
                        earliest,
                        next,
                        legs: route.legs.len(),
                        length: route.length,
                        adaptations: route.adaptations.len(),
                    };
                    route.push(LegKind::Lane(lane), curve.clone(), lane_entry, lane_len - lane_entry, None);
                    let connector = match map.lanes[lane].end {
                        LaneEnd::Loop(c) => c,
                        LaneEnd::Intersection { .. } => map
                            .exit(lane, turn)
                            .or_else(|| map.exit(lane, map.default_turn(lane)))
                            .expect("a lane's own turn"),
                    };
                    let c = &map.connectors[connector];
                    previous = matches!(c.turn, Turn::Straight | Turn::UTurn).then_some(snapshot);
                    let action = carried_out.then_some(next);
                    route.push(LegKind::Connector(connector), c.curve.clone(), 0.0, c.curve.length(), action);
                    lane = c.to;
                    lane_entry = 0.0;
                    earliest = 0.0;
                    if carried_out {
                        next += 1;
                    }
                }
            }
        }
    }

    /// Records an adaptation of queue action `index`.
    fn adapt(&mut self, index: usize, action: Action, kind: AdaptationKind, reason: String) {
        self.adaptations.push(Adaptation { action_index: index, action, kind, reason });
    }

    /// Whether queue action `index` was skipped.
    pub fn skips(&self, index: usize) -> bool {
        self.adaptations.iter().any(|a| a.action_index == index && a.kind == AdaptationKind::Skipped)
    }

    /// Pushes `lane` from `lane_entry` to `at` metres, then a lane change from
    /// there into `target`, carrying out queue action `action` (a merge) or
    /// preparing `prepares` (a turn).
    #[allow(clippy::too_many_arguments)]
    fn push_lane_change(
        &mut self,
        map: &CityMap,
        lane: LaneId,
        target: LaneId,
        lane_entry: f64,
        at: f64,
        action: Option<usize>,
        prepares: Option<usize>,
    ) {
        let curve = &map.lanes[lane].curve;
        self.push(LegKind::Lane(lane), curve.clone(), lane_entry, at - lane_entry, None);
        let change = lane_change_curve(map, lane, target, at);
        let len = change.length();
        self.push(LegKind::LaneChange { from: lane, to: target, at }, change, 0.0, len, action);
        if let Some(leg) = self.legs.last_mut() {
            leg.prepares = prepares;
        }
    }

    fn push(&mut self, kind: LegKind, curve: Curve, curve_start: f64, length: f64, action: Option<usize>) {
        if length <= 0.0 {
            return;
        }
        self.legs.push(RouteLeg { kind, curve, curve_start, length, route_start: self.length, action, prepares: None });
        self.length += length;
    }

    /// Moves the lane change of leg `k` to start `at` metres along its lane,
    /// keeping every later leg where it is on the route (the lane before the
    /// change grows by what the lane after it loses). False, and nothing
    /// changed, when `k` is no lane change between two stretches of lane
    /// long enough for the move.
    pub fn move_lane_change(&mut self, map: &CityMap, k: usize, at: f64) -> bool {
        let Some(&RouteLeg { kind: LegKind::LaneChange { from, to, at: old }, .. }) = self.legs.get(k) else {
            return false;
        };
        let delta = at - old;
        let (Some(before), Some(after)) = (self.legs.get(k.wrapping_sub(1)), self.legs.get(k + 1)) else {
            return false;
        };
        if before.kind != LegKind::Lane(from)
            || after.kind != LegKind::Lane(to)
            || before.length + delta <= 0.0
            || after.length - delta <= 0.0
        {
            return false;
        }
        self.legs[k - 1].length += delta;
        let change = &mut self.legs[k];
        change.kind = LegKind::LaneChange { from, to, at };
        change.curve = lane_change_curve(map, from, to, at);
        change.route_start += delta;
        let after = &mut self.legs[k + 1];
        after.curve_start += delta;
        after.route_start += delta;
        after.length -= delta;
        true
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
        self.leg_at(s).pose(s, lateral)
    }

    /// [`Route::pose_at`] for a caller that knows which leg `s` is probably
    /// on (a car's current leg): the same pose, without the search when
    /// `hint` is that leg.
    pub fn pose_at_near(&self, hint: usize, s: f64, lateral: f64) -> (DVec2, f64) {
        let end = |k: usize| self.legs[k].route_start + self.legs[k].length;
        let last = self.legs.len() - 1;
        // The leg `leg_index_at` finds: the first whose end is past `s`, or the last.
        let found = hint <= last && (hint == 0 || end(hint - 1) <= s) && (hint == last || end(hint) > s);
        debug_assert!(!found || hint == self.leg_index_at(s), "leg {hint} is not where s = {s} is");
        if found {
            self.legs[hint].pose(s, lateral)
        } else {
            self.pose_at(s, lateral)
        }
    }

    /// The lanes, lane changes and connectors of the route in order.
    pub fn kinds(&self) -> impl Iterator<Item = LegKind> + '_ {
        self.legs.iter().map(|l| l.kind)
    }
}

/// The lane change from `lane` into the parallel lane `target` that starts
/// `at` metres along `lane`.
fn lane_change_curve(map: &CityMap, lane: LaneId, target: LaneId, at: f64) -> Curve {
    let curve = &map.lanes[lane].curve;
    if !matches!(curve, Curve::Line(_)) {
        // Along a bent lane (imported networks): follow it sideways onto the target.
        let run = map.layout.lane_change_length;
        let end = map.lanes[target].curve.position(at + run, 0.0);
        let shift = curve.local_coordinates(end).1;
        return Curve::lane_change_along(curve, at, run, shift, end);
    }
    let heading = curve.heading_at(at);
    let to_left = map.adjacent_lane(lane, true) == Some(target);
    let shift = if to_left { 1.0 } else { -1.0 } * map.layout.lane_width;
    Curve::lane_change(
        curve.lane_center_at(at),
        DVec2::new(heading.cos(), heading.sin()),
        map.layout.lane_change_length,
        shift,
    )
}

/// Rounds up onto the 0.1 m grid merge distances use.
fn grid_up(x: f64) -> f64 {
    (x * 10.0 - 1e-6).ceil() / 10.0
}

/// Rounds down onto the 0.1 m grid merge distances use.
fn grid_down(x: f64) -> f64 {
    (x * 10.0 + 1e-6).floor() / 10.0
}

/// Why a merge moved: what is wrong with the distance asked, and where the
/// merge goes instead.
type Moved = (String, String);

/// Where a merge asked for `asked` metres along `lane` can start, for a car
/// `earliest` metres along it: (target lane, start, and if it moved: what
/// is wrong with the distance asked, and where the merge goes instead), or
/// why it cannot be done on this lane at all.
fn place_merge(
    map: &CityMap,
    lane: LaneId,
    action: Action,
    asked: f64,
    earliest: f64,
) -> Result<(LaneId, f64, Option<Moved>), String> {
    let to_left = action == Action::MergeL;
    let name = &map.lanes[lane].name;
    let Some(target) = map.adjacent_lane(lane, to_left) else {
        let side = if to_left { "left" } else { "right" };
        let kind = match map.lanes[lane].position {
            LanePosition::Outer => "outer",
            LanePosition::Inner => "inner",
            LanePosition::Single => "only",
            LanePosition::Middle => "middle",
        };
        return Err(format!("lane {name} is the {kind} lane of its direction: there is no lane to its {side}"));
    };
    let run = map.layout.lane_change_length;
    let lane_len = map.lanes[lane].curve.length();
    let (first, last) = (grid_up(earliest), grid_down(lane_len - run));
    if !asked.is_finite() || asked < earliest - 1e-9 {
        let moved = format!(
            "merge distance {} m lies behind the car, which is {earliest:.2} m along lane {name}",
            Shown(asked)
        );
        return if first <= last {
            Ok((target, first, Some((moved, format!("merging from {first:.1} m")))))
        } else {
            Err(format!("{moved}, and the lane has no room for a merge after it"))
        };
    }
    if asked + run > lane_len + 1e-9 {
        let moved = format!(
            "merge distance {} m is past the lane end: lane {name} is {lane_len:.2} m long and a merge needs {run} m, so use at most {:.2}",
            Shown(asked),
            lane_len - run
        );
        return if first <= last {
            let at = last.max(first);
            Ok((target, at, Some((moved, format!("merging at {at:.1} m, the last feasible point")))))
        } else {
            Err(format!("{moved}, and the car is already past that"))
        };
    }
    Ok((target, asked, None))
}

/// Why `action` cannot be driven from `lane` as it stands.
fn wrong_lane(map: &CityMap, lane: LaneId, action: Action) -> String {
    let name = &map.lanes[lane].name;
    let turn = action.turn().unwrap_or(Turn::Straight);
    if map.lane_towards(lane, turn).is_none() {
        return format!("cannot go {action} from lane {name}: no lane of its road goes that way at the junction ahead");
    }
    let allowed = match map.lanes[lane].position {
        LanePosition::Outer => "the outer lanes (w, z) go straight or turn right",
        LanePosition::Inner => "the inner lanes (x, y) go straight or turn left",
        LanePosition::Single => "its road has one lane each way",
        LanePosition::Middle => "the middle lanes (m, n) go straight",
    };
    format!("cannot turn {action} from lane {name}: {allowed}; merge first")
}

/// Where the planner stood when it began to drive `lane` to its end.
#[derive(Debug, Clone, Copy)]
struct Snapshot {
    lane: LaneId,
    lane_entry: f64,
    earliest: f64,
    next: usize,
    /// Route legs, length and adaptations before the lane's last leg.
    legs: usize,
    length: f64,
    adaptations: usize,
}

impl Snapshot {
    /// Whether a lane change to the left (or right) fits on the lane from
    /// where the car was, before the lane ends.
    fn has_room(&self, map: &CityMap, to_left: bool) -> bool {
        map.adjacent_lane(self.lane, to_left).is_some()
            && grid_up(self.earliest + STRATEGIC_CHANGE_LEAD) <= grid_down(last_change_start(map, self.lane, true))
    }
}

/// The furthest along `lane` a lane change may start, metres: a change the
/// driver planned for a turn (`for_turn`) must end before a stop line, a
/// merge only before the lane ends.
pub fn last_change_start(map: &CityMap, lane: LaneId, for_turn: bool) -> f64 {
    let l = &map.lanes[lane];
    let line = match l.end {
        LaneEnd::Intersection { .. } if for_turn => map.layout.stop_line_setback,
        _ => 0.0,
    };
    l.curve.length() - line - map.layout.lane_change_length
}

/// The lane change a driver plans to reach the lane allowing `turn` at the
/// end of `lane`: (target lane, start), starting as early as it can, at
/// `first` metres along the lane, and ending before the stop line; or why
/// there is none (no room, or the driver gave up).
fn plan_turn_lane(
    map: &CityMap,
    lane: LaneId,
    turn: Turn,
    first: f64,
    given_up: bool,
) -> Result<(LaneId, f64), String> {
    let name = &map.lanes[lane].name;
    let Some(target) = map.lane_towards(lane, turn) else {
        let road = &name[..name.len() - 1];
        return Err(format!("no lane of {road} goes {} at the junction ahead", turn_name(turn)));
    };
    let target_name = &map.lanes[target].name;
    if given_up {
        return Err(format!("no gap came to change from {name} into {target_name}: going straight on instead"));
    }
    let run = map.layout.lane_change_length;
    let end = map.lanes[lane].curve.length() - map.layout.stop_line_setback;
    let (first, last) = (grid_up(first), grid_down(last_change_start(map, lane, true)));
    if first > last {
        return Err(format!(
            "lane {name} leaves no room to change into {target_name} before the stop line (the change needs {run} m from {first:.1} m, the line is at {end:.2} m): going straight on instead"
        ));
    }
    Ok((target, first))
}

/// How an error names a movement: `left`, `right`, `straight on`.
fn turn_name(turn: Turn) -> &'static str {
    match turn {
        Turn::Left => "left",
        Turn::Right => "right",
        Turn::Straight => "straight on",
        Turn::UTurn => "round",
        Turn::SlightLeft => "slightly left",
        Turn::SlightRight => "slightly right",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn route_runs_on_forever_after_the_actions() {
        let map = CityMap::default();
        let spawn = map.lane_by_name("A1w").unwrap();
        let route = Route::plan(&map, spawn, 0.0, &[], &[], 2000.0, &LanePolicy::Strict).unwrap();
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
