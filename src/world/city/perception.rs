//! What a driver sees: which cars occupy which track, the nearest car ahead
//! on its path, where it must stop (lights, traffic still crossing), how fast
//! the curves ahead allow, and whether the gap for a merge is free. All
//! distances are metres along the car's route or a track.

use super::Sim;
use crate::map::control::JunctionControl;
use crate::map::curve::Curve;
use crate::map::route::last_change_start;
use crate::map::signals::{Colour, LightState};
use crate::map::{LegKind, RouteLeg};
use crate::spec::DrivingRules;
use std::sync::Arc;

/// How long a driver waits at the last point of its lane for a lane-change
/// gap before it gives the action up, seconds.
pub(super) const LANE_CHANGE_PATIENCE: f64 = 20.0;
/// Room a waiting lane changer leaves, beyond its own min gap, between the
/// point of its lane change and the point it asks the car behind in the
/// other lane to stop short of (cooperative lane changes), metres: covers
/// that car's perception error in stopping.
const CLAIM_MARGIN: f64 = 0.5;
/// How far ahead along its route a driver looks, metres: no perception
/// reads a route leg that starts farther ahead (an effects re-run relies on
/// it, `replay.rs`).
pub(super) const LOOKAHEAD: f64 = 30.0;
/// A car on a sibling movement (same lane, other turn) counts as ahead of
/// cars behind it until it is this far into its turn, metres.
const SIBLING_CLEARANCE: f64 = 3.0;

/// A driver at a junction without lights counts as waiting at its line
/// when its front is this close to it, metres (a stop brings it within
/// [`crate::world::driver::STOP_LINE_MARGIN`] plus a little)...
const HALT_REACH: f64 = 1.5;
/// ...and it is this slow, m/s.
const HALT_SPEED: f64 = 0.2;
/// Seconds a driver giving way leaves, beyond the time it needs to clear
/// the junction box, before a car with priority reaches its line.
const GIVE_WAY_MARGIN_S: f64 = 1.0;
/// How far beyond its braking distance before the line a driver who must
/// give way starts to look for traffic with precedence, metres.
const GIVE_WAY_LOOK_M: f64 = 6.0;

/// Why a driver must stop before an intersection.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Stop {
    /// Its light (index in the plan) shows red, or yellow it can stop for.
    Light(usize),
    /// This car is still crossing the box on a conflicting movement.
    Crossing(usize),
    /// This car has the right of way: it will reach its line too soon, or
    /// waits at an all-way stop's line with precedence.
    GiveWay(usize),
    /// An all-way stop's line, which every car stops at.
    AllWayLine,
}

/// What a decision does to the movement a driver is committed to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Commit {
    /// Leaves it as it is.
    Keep,
    /// Commits to this connector (it claims the box from now on).
    To(usize),
    /// Gives the claim up (a waiting driver outranked at a line without lights).
    Withdraw,
}

/// Where one car is in the occupancy: up to three (track, metres along it).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(super) struct Places {
    entries: [(usize, f64); 3],
    len: usize,
}

impl Places {
    fn push(&mut self, entry: (usize, f64)) {
        self.entries[self.len] = entry;
        self.len += 1;
    }

    pub(super) fn iter(&self) -> std::slice::Iter<'_, (usize, f64)> {
        self.entries[..self.len].iter()
    }
}

/// A candidate car ahead: (distance along the route to its centre, car).
type Candidate = (f64, usize);

/// The nearest of `candidates`; the first one on a tie.
fn nearest(candidates: impl Iterator<Item = Candidate>) -> Option<Candidate> {
    let mut best = None;
    candidates.for_each(|candidate| closer(&mut best, candidate));
    best
}

/// Keeps `candidate` in `best` when it is nearer (the first one on a tie).
/// The hot searches call it from plain loops, which cost less than
/// flattened iterators over one or two tracks.
fn closer(best: &mut Option<Candidate>, (d, j): Candidate) {
    if best.is_none_or(|(b, _)| d < b) {
        *best = Some((d, j));
    }
}

impl Sim<'_> {
    /// Records, per track, every car on it and how far along it is. Cars past
    /// their stop line, or committed to go, also claim the connector ahead.
    pub(super) fn fill_occupancy(&mut self) {
        self.clear_occupancy();
        for i in 0..self.cars.len() {
            if self.cars[i].removed {
                continue;
            }
            let places = self.places(i);
            if let Some(tape) = &mut self.tape {
                tape.note_places(i, &places);
            }
            for &(track, pos) in places.iter() {
                self.occupy(track, i, pos);
            }
        }
    }

    /// Empties the occupancy (only the tracks that held a car).
    pub(super) fn clear_occupancy(&mut self) {
        for &track in &self.occupied {
            self.occupancy[track].clear();
        }
        self.occupied.clear();
    }

    /// Where car `i` is in the occupancy: (track, metres along it) for the
    /// connector it claims, then its leg's track (both lanes mid-merge).
    pub(super) fn places(&self, i: usize) -> Places {
        let mut places = Places::default();
        if let Some(claim) = self.claimed_connector(i) {
            places.push(claim);
        }
        let car = &self.cars[i];
        let leg = &car.route.legs[car.leg];
        let along = car.s - leg.route_start;
        if let Some(claim) = self.merge_claim(i) {
            places.push(claim);
        }
        match leg.kind {
            LegKind::Lane(lane) => places.push((lane, leg.curve_start + along)),
            LegKind::Connector(c) => places.push((self.map.connector_track(c), along)),
            LegKind::LaneChange { from, to, at } => {
                // Mid-merge a car occupies both lanes.
                let lane_s = at + along * self.map.layout.lane_change_length / leg.length;
                places.push((from, lane_s));
                places.push((to, lane_s));
            }
        }
        places
    }

    /// Whether the spec asks for the cooperative driving rules (`city.rules`).
    fn cooperative(&self) -> bool {
        self.city.rules == DrivingRules::Cooperative
    }

    /// The point a car waiting to change lanes (cooperative lane changes)
    /// asks the car behind in the lane it wants to stop short of: (that
    /// lane, metres along it), while it still waits on its lane for that
    /// change. A car mid-change stands in both lanes and claims nothing.
    fn merge_claim(&self, i: usize) -> Option<(usize, f64)> {
        let car = &self.cars[i];
        let (track, pos) = car.merge_claim?;
        let waits = match (car.route.legs[car.leg].kind, car.route.legs.get(car.leg + 1).map(|l| l.kind)) {
            (LegKind::Lane(lane), Some(LegKind::LaneChange { from, to, .. })) => lane == from && to == track,
            _ => false,
        };
        waits.then_some((track, pos))
    }

    /// The cars on `track` and how far along each is (metres), in car
    /// order: the one way perception reads the occupancy, so that a run
    /// recording what decisions depend on notes every track read.
    fn occupants(&self, track: usize) -> &[(usize, f64)] {
        self.occupants_from(track, f64::NEG_INFINITY)
    }

    /// [`Sim::occupants`] for a reader that looks only at the cars at `from`
    /// metres along `track` or beyond: a car before `from`, or anything
    /// about it, cannot change what it finds. A recording notes the bound,
    /// so that an effects re-run tries the decision again only when a car
    /// it changed stands (or stood) within it (`replay.rs`).
    fn occupants_from(&self, track: usize, from: f64) -> &[(usize, f64)] {
        if let Some(reads) = &self.reads {
            reads.borrow_mut().push((track, from));
        }
        &self.occupancy[track]
    }

    /// Records car `i` on `track`, `pos` metres along it.
    pub(super) fn occupy(&mut self, track: usize, i: usize, pos: f64) {
        if self.occupancy[track].is_empty() {
            self.occupied.push(track);
        }
        self.occupancy[track].push((i, pos));
    }

    /// A car past its stop line, or committed to go, already claims the
    /// intersection movement it is about to make: (its track, a negative
    /// position on it, metres).
    fn claimed_connector(&self, i: usize) -> Option<(usize, f64)> {
        let car = &self.cars[i];
        let leg = &car.route.legs[car.leg];
        let next = car.route.legs.get(car.leg + 1)?;
        let setback = self.map.layout.stop_line_setback;
        let claim = |c: usize, start: f64| (self.map.connector_track(c), -(start - car.front()).max(0.0) - 1.0);
        match (leg.kind, next.kind) {
            (LegKind::Lane(_), LegKind::Connector(c)) => {
                let to_box = next.route_start - car.front();
                let claims =
                    self.map.connectors[c].intersection.is_some() && (to_box < setback || car.committed == Some(c));
                claims.then(|| claim(c, next.route_start))
            }
            // At a junction without lights a driver committed to its
            // movement claims it even while it finishes a lane change
            // before the line.
            _ => {
                let c = car.committed?;
                let ahead = car.route.legs[car.leg + 1..].iter().take(2).find(|l| l.kind == LegKind::Connector(c))?;
                let unsignalised = self.map.control_of(c).is_some_and(|k| k != JunctionControl::Signals);
                unsignalised.then(|| claim(c, ahead.route_start))
            }
        }
    }

    /// The nearest car ahead on car `i`'s path whose centre is within
    /// [`LOOKAHEAD`] of its own along the route: (bumper gap in metres, its
    /// speed in m/s, the car).
    pub(super) fn leader_ahead(&self, i: usize) -> Option<(f64, f64, usize)> {
        let car = &self.cars[i];
        let on_path = car.route.legs[car.leg..]
            .iter()
            .take_while(|leg| leg.route_start - car.s <= LOOKAHEAD)
            .find_map(|leg| self.nearest_on_leg(i, leg));
        let beside = if self.cooperative() { self.leader_beside(i) } else { None };
        let (d, j) = nearest(on_path.into_iter().chain(beside)).filter(|&(d, _)| d <= LOOKAHEAD)?;
        let other = &self.cars[j];
        Some((d - (car.plan.length + other.plan.length) / 2.0, other.v, j))
    }

    /// Car `i`'s own leader when it drives ahead on a lane beside car `i`'s
    /// (cooperative rules): a follower does not pass its leader, so it
    /// keeps behind it as behind a car in its own lane.
    fn leader_beside(&self, i: usize) -> Option<Candidate> {
        let car = &self.cars[i];
        let leader = car.leader?;
        let leg = &car.route.legs[car.leg];
        let LegKind::Lane(lane) = leg.kind else { return None };
        let own = leg.curve_start + (car.s - leg.route_start);
        // A leader changing, or asking to change, into this car's lane is
        // seen there, where this car stops for it or drives on past.
        if self.occupants(lane).iter().any(|&(j, _)| j == leader) {
            return None;
        }
        [true, false].into_iter().filter_map(|left| self.map.adjacent_lane(lane, left)).find_map(|beside| {
            let &(_, pos) = self.occupants(beside).iter().find(|&&(j, _)| j == leader)?;
            (pos > own).then_some((pos - own, leader))
        })
    }

    /// The nearest other car ahead of car `i` on `leg` of its route: on the
    /// leg's tracks, or (at an intersection) still turning away on a sibling
    /// movement from the same lane.
    fn nearest_on_leg(&self, i: usize, leg: &RouteLeg) -> Option<Candidate> {
        let sibling = match leg.kind {
            LegKind::Connector(c) => {
                let a = self.nearest_on_siblings(i, leg, c);
                let b = self.nearest_on_merging(i, leg, c);
                nearest(a.into_iter().chain(b))
            }
            _ => None,
        };
        let on_track = self.nearest_on_tracks(i, leg);
        match (sibling, on_track) {
            (Some(a), Some(b)) => Some(if b.0 < a.0 { b } else { a }),
            (a, b) => a.or(b),
        }
    }

    /// Cars that left the same lane on another movement than connector `c`
    /// (a right turn beside my straight): in front until they have turned away.
    fn nearest_on_siblings(&self, i: usize, leg: &RouteLeg, c: usize) -> Option<Candidate> {
        let car = &self.cars[i];
        let from = self.map.connectors[c].from;
        // A car still before the box only claims its movement; it is not in
        // front. Junctions with lights keep the original rule, under which it
        // is, unless the spec asks for the cooperative rules: it can leave two
        // cars waiting on each other for good (docs/city.md#driving-rules).
        let claims_count = self.map.control_of(c) == Some(JunctionControl::Signals) && !self.cooperative();
        // On an imported network movements may run together well into the
        // junction before they part: in front until its back is past that.
        let mut best: Option<Candidate> = None;
        for sibling in self.map.exits_from(from).filter(|&o| o != c) {
            let shared = self.map.shared_start(c, sibling);
            for &(j, pos) in self.occupants(self.map.connector_track(sibling)) {
                let clearance = if shared > 0.0 { shared + self.cars[j].plan.length } else { SIBLING_CLEARANCE };
                let d = leg.route_start + pos.max(0.0) - car.s;
                if j != i && pos < clearance && d > 0.0 && (pos >= 0.0 || claims_count) {
                    closer(&mut best, (d, j));
                }
            }
        }
        best
    }

    /// Cars on movements that run into one path with connector `c` before
    /// it ends (imported networks): ahead when nearer that end than car `i`
    /// will be there, measured back from the end.
    fn nearest_on_merging(&self, i: usize, leg: &RouteLeg, c: usize) -> Option<Candidate> {
        let car = &self.cars[i];
        let end = leg.route_start + leg.length;
        let occupants = self.map.merging(c).iter().flat_map(|&m| {
            let length = self.map.connectors[m].curve.length();
            self.occupants(self.map.connector_track(m)).iter().map(move |&(j, pos)| (j, pos, length))
        });
        nearest(
            occupants
                .filter(|&(j, pos, _)| j != i && pos >= 0.0)
                .map(|(j, pos, length)| (end - (length - pos) - car.s, j))
                .filter(|&(d, _)| d > 0.0),
        )
    }

    /// Cars ahead of car `i` on the tracks `leg` runs on (both lanes of a merge).
    fn nearest_on_tracks(&self, i: usize, leg: &RouteLeg) -> Option<Candidate> {
        let car = &self.cars[i];
        let run = self.map.layout.lane_change_length;
        // Which tracks this leg runs on, and the track arc length at its start and end.
        let (tracks, start, end): ([Option<usize>; 2], f64, f64) = match leg.kind {
            LegKind::Lane(l) => ([Some(l), None], leg.curve_start, leg.curve_start + leg.length),
            LegKind::Connector(c) => ([Some(self.map.connector_track(c)), None], 0.0, leg.length),
            LegKind::LaneChange { from, to, at } => ([Some(from), Some(to)], at, at + run),
        };
        // Only cars ahead count: at `pos`, `d` below is `pos - behind` up to
        // round-off (about 1e-13 m here), so a car a micrometre or more
        // behind that is never one.
        let behind = start + (car.s - leg.route_start);
        let from = (start - 0.01).max(behind - 1e-6);
        let mut best: Option<Candidate> = None;
        for track in tracks.into_iter().flatten() {
            for &(j, pos) in self.occupants_from(track, from) {
                if j != i && pos >= start - 0.01 && pos <= end + 0.01 {
                    let d = leg.route_start + (pos - start) - car.s;
                    if d > 0.0 {
                        closer(&mut best, (d, j));
                    }
                }
            }
        }
        best
    }

    /// Distance from car `i`'s front to where it must stop for a light or for
    /// cars crossing the intersection, if it must (metres), and why. Records
    /// the connector the car commits to once it is too close to stop
    /// comfortably.
    pub(super) fn stop_ahead(&mut self, i: usize, t: f64) -> Option<(f64, Stop)> {
        let (stop, commit) = self.stop_seen(i, t);
        match commit {
            Commit::Keep => {}
            Commit::To(c) => self.cars[i].committed = Some(c),
            Commit::Withdraw => self.cars[i].committed = None,
        }
        stop
    }

    /// What [`Sim::stop_ahead`] finds, without recording anything: the stop,
    /// and the connector the car would commit to.
    pub(super) fn stop_seen(&self, i: usize, t: f64) -> (Option<(f64, Stop)>, Commit) {
        let car = &self.cars[i];
        let front = car.front();
        let p = &car.driver;
        let braking = car.v * car.v / (2.0 * p.comfortable_deceleration);
        let setback = self.map.layout.stop_line_setback;
        let mut commit = Commit::Keep;
        for leg in &car.route.legs[car.leg..] {
            if leg.route_start - car.s > LOOKAHEAD {
                break;
            }
            let LegKind::Connector(c) = leg.kind else { continue };
            let dist = leg.route_start - setback - front;
            // Cooperative rules: between its line and the box a car still
            // stops for one crossing its path, or claiming a crossing
            // movement that goes first, where it can stop comfortably. Two
            // cars that set off together on one green (opposite left turns
            // on one-lane roads) would otherwise meet in the box.
            if dist < -0.05 && self.cooperative() {
                let to_box = dist + setback;
                if to_box > 0.0 && braking <= to_box {
                    if let Some(j) = self.crossing_before(i, c) {
                        return (Some((to_box, Stop::Crossing(j))), commit);
                    }
                }
            }
            // Past the stop line, or forced through its lights: nothing stops
            // the car here. (A red-light runner keeps the rules of junctions
            // without lights.)
            if dist < -0.05 || (car.runs_red_lights && self.map.control_of(c) == Some(JunctionControl::Signals)) {
                continue;
            }
            // Once committed (moving, too close to stop comfortably) the light
            // no longer matters, but cars still crossing the box always do. A
            // car that has come to rest before its line is committed no more.
            let committed = car.committed == Some(c) && car.v > 0.1;
            let halted = car.v < HALT_SPEED && dist < HALT_REACH;
            let rule = match self.light_for(c) {
                Some(light) if !committed && self.stops_for(light, t, braking, dist) => Some(Stop::Light(light)),
                // A left turn on a permissive green gives way to oncoming
                // traffic, until it is moving too close to stop.
                Some(_) if self.map.permissive_left(c) && !committed => self.give_way(i, c, dist, braking, halted),
                Some(_) => None,
                // A driver cleared to go at a line without lights goes.
                None if self.map.gives_way(c) && car.committed != Some(c) => self.give_way(i, c, dist, braking, halted),
                None if self.map.connectors[c].intersection.is_some() => None,
                None => continue,
            };
            // One that committed and then came to rest before its line gives
            // its claim up while it gives way, so oncoming cars do not stop for it.
            if let Some(stop @ Stop::GiveWay(_)) = rule {
                if halted && car.committed == Some(c) && self.map.permissive_left(c) {
                    return (Some((dist.max(0.0), stop)), Commit::Withdraw);
                }
            }
            let crossing = if dist < braking + 2.0 { self.conflict_occupant(c) } else { None };
            let why = rule.or(crossing.map(|(j, _)| Stop::Crossing(j)));
            if let Some(why) = why {
                // At a line without lights, a driver at rest that has claimed
                // the box but must wait for a car claiming a movement with
                // precedence gives its claim up: otherwise each could wait
                // for the other for good.
                let outranked =
                    crossing.is_some_and(|(_, other)| self.map.right_of_way(other) < self.map.right_of_way(c));
                if rule.is_none() && outranked && halted && car.committed == Some(c) && self.map.gives_way(c) {
                    return (Some((dist.max(0.0), why)), Commit::Withdraw);
                }
                return (Some((dist.max(0.0), why)), commit);
            }
            // Waiting at a line without lights and clear to go: claim the box.
            if halted && self.map.gives_way(c) {
                commit = Commit::To(c);
            }
            if car.v > 0.1 && dist < braking {
                commit = Commit::To(c);
            }
        }
        (None, commit)
    }

    /// Whether light `light` at time `t` tells a driver `dist` metres before
    /// its line, who needs `braking` metres to stop comfortably, to stop:
    /// always at red, at yellow only if it can.
    fn stops_for(&self, light: usize, t: f64, braking: f64, dist: f64) -> bool {
        match self.light_state(light, t).colour {
            Colour::Red => true,
            Colour::Yellow => braking <= dist,
            Colour::Green => false,
        }
    }

    /// The light (index in the plan) that governs entering `connector`
    /// ([`CityMap::light_of`]).
    pub(super) fn light_for(&self, connector: usize) -> Option<usize> {
        self.map.light_of(connector)
    }

    /// Light `index` at time `t` (seconds): its plan, unless an intervention
    /// forces it or gave it a new plan.
    pub(super) fn light_state(&self, index: usize, t: f64) -> LightState {
        let forced =
            self.light_overrides.iter().rev().find(|&&(l, _, from, until)| l == index && t >= from && t < until);
        if let Some(&(_, colour, from, _)) = forced {
            return LightState { colour, since_change: t - from };
        }
        match self.light_plans.iter().rev().find(|(l, _, from)| *l == index && t >= *from) {
            Some((_, light, _)) => light.state_at(t),
            None => match self.actuation.state(index, t) {
                Some(state) => state,
                None => self.city.lights.lights[index].state_at(t),
            },
        }
    }

    /// Whom car `i`, `dist` metres before the line of `connector` at a
    /// junction without lights (`halted` there or not), must stop for: at an
    /// all-way stop the line itself until it has halted there, then a car
    /// waiting at the line of a movement with precedence that crosses its
    /// path; at a priority or right-before-left junction, or turning left on
    /// a permissive green, a car on a movement with precedence
    /// ([`CityMap::goes_before`]) that will reach its line before this car
    /// could clear the box.
    fn give_way(&self, i: usize, connector: usize, dist: f64, braking: f64, halted: bool) -> Option<Stop> {
        let all_way = self.map.control_of(connector) == Some(JunctionControl::AllWayStop);
        if all_way && !halted {
            return Some(Stop::AllWayLine);
        }
        // A driver looks for traffic with precedence once it could still
        // stop for it comfortably with a little room to spare, not before.
        if dist > braking + GIVE_WAY_LOOK_M {
            return None;
        }
        let car = &self.cars[i];
        let x = &self.map.intersections[self.map.connectors[connector].intersection?];
        // Time this car needs to cross the box from where it is, seconds.
        let clear = car.driver.reaction_time
            + (dist + 2.0 * x.half_size + car.plan.length) / car.desired().max(0.1)
            + GIVE_WAY_MARGIN_S;
        let setback = self.map.layout.stop_line_setback;
        let mut first: Option<(f64, usize)> = None;
        for &other in self.map.conflicts(connector) {
            if !self.map.goes_before(other, connector) {
                continue;
            }
            let lane = self.map.connectors[other].from;
            let line = self.map.lanes[lane].curve.length() - setback;
            for &(j, pos) in self.occupants(lane) {
                if j == i {
                    continue;
                }
                let theirs = &self.cars[j];
                let to_line = line - pos - theirs.plan.length / 2.0;
                if to_line < -0.05 {
                    continue; // past its line: it claims its movement
                }
                let arrives = if all_way {
                    (to_line < HALT_REACH && theirs.v < HALT_SPEED).then_some(0.0)
                } else {
                    let eta = if theirs.v > 0.05 { to_line / theirs.v } else { f64::INFINITY };
                    (eta < clear).then_some(eta)
                };
                if let Some(eta) = arrives {
                    if first.is_none_or(|(e, _)| eta < e) {
                        first = Some((eta, j));
                    }
                }
            }
        }
        first.map(|(_, j)| Stop::GiveWay(j))
    }

    /// A car other than `i` in the box on a movement crossing `connector`,
    /// or claiming one that goes first by [`CityMap::right_of_way`]'s fixed
    /// order: the first found.
    fn crossing_before(&self, i: usize, connector: usize) -> Option<usize> {
        let mine = self.map.right_of_way(connector);
        self.map.conflicts(connector).iter().find_map(|&other| {
            let first = self.map.right_of_way(other) < mine;
            let track = self.map.connector_track(other);
            self.occupants(track).iter().find(|&&(j, pos)| j != i && (pos >= 0.0 || first)).map(|&(j, _)| j)
        })
    }

    /// A car on (or claiming) a connector crossing `connector`, if any: the
    /// first found, and the connector it is on.
    fn conflict_occupant(&self, connector: usize) -> Option<(usize, usize)> {
        self.map
            .conflicts(connector)
            .iter()
            .find_map(|&other| self.occupants(self.map.connector_track(other)).first().map(|&(j, _)| (j, other)))
    }

    /// Highest speed (m/s) that still lets car `i` slow to the curve speed of
    /// every curve within [`LOOKAHEAD`] at its comfortable deceleration.
    pub(super) fn curve_limit(&self, i: usize) -> f64 {
        let car = &self.cars[i];
        let p = &car.driver;
        let mut limit = f64::INFINITY;
        for leg in &car.route.legs[car.leg..] {
            let d = (leg.route_start - car.s).max(0.0);
            if d > LOOKAHEAD {
                break;
            }
            if let Curve::Arc(arc) = &leg.curve {
                let curve_speed = (p.curve_acceleration * arc.radius).sqrt();
                limit = limit.min((curve_speed * curve_speed + 2.0 * p.comfortable_deceleration * d).sqrt());
            }
        }
        limit
    }

    /// For a lane change about to start (a merge, or one the driver planned
    /// for a turn): `None` when car `i` may go on (the gap is fine, or the
    /// change was moved further along the lane), else the distance to the
    /// change's start where it has to wait, metres. A car that has waited
    /// [`LANE_CHANGE_PATIENCE`] at the last feasible point gives the action up.
    pub(super) fn merge_wait(&mut self, i: usize, t: f64) -> Option<f64> {
        // A claim lasts one decision: made again below while the car waits.
        self.cars[i].merge_claim = None;
        let car = &self.cars[i];
        let next = car.leg + 1;
        let upcoming = match (car.route.legs.get(car.leg), car.route.legs.get(next)) {
            (Some(current), Some(change)) => match change.kind {
                LegKind::LaneChange { from, to, at } if current.kind == LegKind::Lane(from) => {
                    Some((change, from, to, at))
                }
                _ => None,
            },
            _ => None,
        };
        let Some((change, from, to, at)) = upcoming else {
            self.cars[i].waiting_since = None;
            return None;
        };
        let (d, for_turn) = (change.route_start - car.s, change.prepares.is_some());
        let (v, rt) = (car.v, car.driver.reaction_time);
        if self.merge_gap_ok(i, to, at) {
            self.cars[i].waiting_since = None;
            return None;
        }
        // Looked at only within a reaction time (plus half a second) and 1.5 m.
        let near = d <= v * (rt + 0.5) + 1.5;
        if near {
            // Moved on by the distance covered in a reaction time (at least 1 m),
            // onto the 0.1 m grid of merge distances, while the lane is long enough.
            let later = ((at + (v * rt + 0.5).max(1.0)) * 10.0).ceil() / 10.0;
            let last = last_change_start(self.map, from, for_turn);
            if later <= last + 1e-6 && Arc::make_mut(&mut self.cars[i].route).move_lane_change(self.map, next, later) {
                self.cars[i].anchor = None;
                return None;
            }
        }
        // Held up by the change: waiting at its start, or at rest before it
        // (behind a car already in the lane it wants).
        let cooperative = self.cooperative();
        if near || v < 0.1 {
            // A cooperative driver's patience runs only while the lane it
            // wants moves: a queue standing in the way (at a red light) will
            // move on and leave the gap.
            if cooperative && self.queue_in_the_way(i, from, to, at) {
                self.cars[i].waiting_since = Some(t);
            }
            let since = *self.cars[i].waiting_since.get_or_insert(t);
            if t - since >= LANE_CHANGE_PATIENCE {
                self.give_up_lane_change(i, t);
                return None;
            }
        } else {
            self.cars[i].waiting_since = None;
        }
        self.cars[i].merge_claim = if near && cooperative { self.claim_for(i, to, at) } else { None };
        near.then_some(d.max(0.0))
    }

    /// Where car `i`, waiting to change into lane `to` at `at` metres along
    /// it, asks the car behind there to stop: short of `at` by its own min
    /// gap and [`CLAIM_MARGIN`], so that car stops where
    /// [`Sim::merge_gap_ok`] finds the gap behind free. `None` when the
    /// nearest car behind that point could not stop short of it, with its
    /// min gap, at its comfortable deceleration: it is let by, and the car
    /// after it is asked.
    fn claim_for(&self, i: usize, to: usize, at: f64) -> Option<(usize, f64)> {
        let car = &self.cars[i];
        let point = at - car.driver.min_gap - CLAIM_MARGIN;
        let behind = nearest(
            self.occupants(to).iter().filter(|&&(j, pos)| j != i && pos <= point).map(|&(j, pos)| (point - pos, j)),
        );
        let stops = behind.is_none_or(|(d, j)| {
            let other = &self.cars[j];
            let gap = d - (car.plan.length + other.plan.length) / 2.0;
            let braking = other.v * other.v / (2.0 * other.driver.comfortable_deceleration);
            gap >= other.driver.min_gap + braking
        });
        stops.then_some((to, point))
    }

    /// Whether what keeps car `i` out of lane `to` at `at`, coming from lane
    /// `from`, is a queue standing there: every car in the way of the change
    /// is at rest, and none is itself a lane changer (in, or asking for, a
    /// lane beside `to` as well: two cars that want each other's lanes, or
    /// one lane from both sides, would wait for good), nor its own follower.
    fn queue_in_the_way(&self, i: usize, from: usize, to: usize, at: f64) -> bool {
        // A car also in (or claiming) `from`, or the lane on `to`'s other side.
        let beside = [self.map.adjacent_lane(to, true), self.map.adjacent_lane(to, false), Some(from)];
        let swapping =
            |j: usize| beside.iter().flatten().any(|&lane| self.occupants(lane).iter().any(|&(k, _)| k == j));
        let mut in_the_way =
            self.occupants(to).iter().filter(|&&(j, pos)| j != i && !self.clear_of(i, j, pos, at)).peekable();
        // Its own follower waits for it, not for the queue.
        let follower = |j: usize| self.cars[j].leader == Some(i);
        in_the_way.peek().is_some() && in_the_way.all(|&(j, _)| self.cars[j].v < 0.1 && !swapping(j) && !follower(j))
    }

    /// Whether car `j`, `pos` metres along the lane car `i` wants, is clear
    /// of a change into it over `[at, at + run]`: by half both lengths plus
    /// the min gap, a car behind also by a second of its own speed.
    fn clear_of(&self, i: usize, j: usize, pos: f64, at: f64) -> bool {
        let (car, other) = (&self.cars[i], &self.cars[j]);
        let run = self.map.layout.lane_change_length;
        let lengths = (car.plan.length + other.plan.length) / 2.0 + car.driver.min_gap;
        pos <= at - lengths - other.v * 1.0 || pos >= at + run + lengths
    }

    /// Whether lane `to` has room for car `i` changing into it over
    /// `[at, at + run]` metres along it: every car on it is clear by half
    /// both lengths plus the min gap, a car behind also by a second of its
    /// own speed, and (MOBIL's safety criterion, Kesting, Treiber and Helbing
    /// 2007) the new follower would not have to brake harder than its
    /// comfortable deceleration.
    fn merge_gap_ok(&self, i: usize, to: usize, at: f64) -> bool {
        let car = &self.cars[i];
        let clear = self.occupants(to).iter().all(|&(j, pos)| j == i || self.clear_of(i, j, pos, at));
        let new_follower =
            nearest(self.occupants(to).iter().filter(|&&(j, pos)| j != i && pos < at).map(|&(j, pos)| (at - pos, j)));
        clear
            && new_follower.is_none_or(|(d, j)| {
                let other = &self.cars[j];
                let gap = d - (car.plan.length + other.plan.length) / 2.0;
                let braking = self.model.follow_acceleration(&other.driver, other.v, other.desired(), gap, car.v);
                braking >= -other.driver.comfortable_deceleration
            })
    }
}
