//! What the simulation records in `events.csv`: stop lines crossed on red,
//! route legs completed (merges, turns, lane changes a driver chose for a
//! turn, the end of the drive queue), actions planning adapted or skipped,
//! and collisions, after which both cars stand still for a few seconds.

use super::Sim;
use crate::geometry::OrientedBox;
use crate::map::signals::Colour;
use crate::map::{Action, AdaptationKind, LegKind};
use crate::world::{Event, EventKind};
use glam::DVec2;
use rand::RngExt;

/// Gap at which two cars that collided count as apart again, metres.
pub(super) const CONTACT_RELEASE: f64 = 0.3;

/// How far (metres) from a car's near point (`radius` its bound,
/// [`super::car::SimCar::near_point`]) another car's point may be and still
/// count as a candidate pair: half the pair's bound (the car's half
/// diagonal `reach`, half of [`CONTACT_RELEASE`]), with room for round-off.
/// Two cars are candidates when their points are closer than the sum.
pub(super) fn extent(reach: f64, radius: f64) -> f64 {
    radius + reach + CONTACT_RELEASE / 2.0 + 1e-6
}

/// Whether two cars at near points `a` and `b` with extents `ea` and `eb`
/// ([`extent`]) are a candidate pair (squared: a pair at the limit is, by
/// the extents' slack, too far apart to touch either way).
pub(super) fn may_touch(a: DVec2, ea: f64, b: DVec2, eb: f64) -> bool {
    a.distance_squared(b) < (ea + eb) * (ea + eb)
}

impl Sim<'_> {
    /// Logs every stop line car `i` crossed on red while its front moved
    /// from `front_before` to `front_after` (route metres), at time `now`.
    pub(super) fn log_red_light_runs(&mut self, i: usize, front_before: f64, front_after: f64, now: f64) {
        let setback = self.map.layout.stop_line_setback;
        let car = &self.cars[i];
        let mut runs = Vec::new();
        for leg in &car.route.legs[car.leg..] {
            let line = leg.route_start - setback;
            if line > front_after {
                break;
            }
            let LegKind::Connector(c) = leg.kind else { continue };
            if front_before < line && front_after >= line {
                runs.extend(self.red_light_run(i, c, now));
            }
        }
        self.events.extend(runs);
    }

    /// The event for car `i` entering connector `c` at time `now`, if that is
    /// an intersection movement whose light shows red.
    fn red_light_run(&self, i: usize, c: usize, now: f64) -> Option<Event> {
        let intersection = self.map.connectors[c].intersection?;
        let light = self.light_for(c)?;
        if self.light_state(light, now).colour != Colour::Red {
            return None;
        }
        let car = &self.cars[i];
        let forced = if car.runs_red_lights { "forced" } else { "not forced" };
        let light_index = light;
        let light = &self.city.lights.lights[light];
        Some(Event {
            t: now,
            kind: EventKind::RedLightRun,
            car: Some(car.plan.id),
            other: None,
            light: Some(light_index),
            detail: format!(
                "{} {} {} ({forced})",
                self.map.intersections[intersection].name,
                light.approach,
                light.signal_label()
            ),
        })
    }

    /// Moves car `i` past every route leg its centre has left (never past
    /// the last), logging the actions those legs completed at time `now`.
    pub(super) fn complete_legs(&mut self, i: usize, now: f64) {
        loop {
            let car = &self.cars[i];
            if car.leg + 1 >= car.route.legs.len() {
                return;
            }
            let leg = &car.route.legs[car.leg];
            if car.s < leg.route_start + leg.length {
                return;
            }
            let (kind, action, prepares) = (leg.kind, leg.action, leg.prepares);
            if let Some(relative) = action {
                self.action_done(i, kind, relative, now);
            }
            if let (Some(relative), LegKind::LaneChange { from, to, .. }) = (prepares, kind) {
                let car = &self.cars[i];
                let index = car.action_base + relative;
                let detail = format!(
                    "{} -> {} for DriveQueue[{index}] {}",
                    self.map.lanes[from].name, self.map.lanes[to].name, car.actions[index]
                );
                let id = car.plan.id;
                self.events.push(Event {
                    t: now,
                    kind: EventKind::LaneChange,
                    car: Some(id),
                    other: None,
                    light: None,
                    detail,
                });
            }
            let car = &mut self.cars[i];
            if matches!(kind, LegKind::Connector(c) if car.committed == Some(c)) {
                car.committed = None;
            }
            car.leg += 1;
        }
    }

    /// Logs the drive-queue action (route action `relative`) that car `i`
    /// completed on a leg of `kind` (nothing for a skipped turn, whose
    /// straight move is no action), and the end of the queue if no action
    /// after it is left to do.
    fn action_done(&mut self, i: usize, kind: LegKind, relative: usize, now: f64) {
        let car = &self.cars[i];
        let id = car.plan.id;
        let index = car.action_base + relative;
        if !car.route.skips(relative) {
            if let Some((kind, detail)) = self.action_event(kind, car.actions[index]) {
                self.events.push(Event { t: now, kind, car: Some(id), other: None, light: None, detail });
            }
        }
        let car = &mut self.cars[i];
        car.actions_done = index + 1;
        let rest_skipped = (relative + 1..car.actions.len() - car.action_base).all(|k| car.route.skips(k));
        if rest_skipped {
            let detail = format!("{} actions", car.actions.len());
            self.events.push(Event {
                t: now,
                kind: EventKind::ActionsFinished,
                car: Some(id),
                other: None,
                light: None,
                detail,
            });
        }
    }

    /// Kind and detail of the event for `action` done on a leg of `kind`:
    /// a merge (lanes from and to) or a turn (at which intersection).
    fn action_event(&self, kind: LegKind, action: Action) -> Option<(EventKind, String)> {
        match kind {
            LegKind::LaneChange { from, to, .. } => {
                Some((EventKind::MergeDone, format!("{} -> {}", self.map.lanes[from].name, self.map.lanes[to].name)))
            }
            LegKind::Connector(c) => {
                let connector = &self.map.connectors[c];
                let at = connector.intersection.map(|k| self.map.intersections[k].name.as_str()).unwrap_or("");
                Some((EventKind::TurnDone, format!("{action} at {at} from {}", self.map.lanes[connector.from].name)))
            }
            LegKind::Lane(_) => None,
        }
    }

    /// Logs, at time `t`, each adaptation of car `i`'s route not logged yet:
    /// `action_adapted` or `action_skipped`, the detail naming the field.
    pub(super) fn log_adaptations(&mut self, i: usize, t: f64) {
        let car = &self.cars[i];
        let mut new = Vec::new();
        for a in &car.route.adaptations {
            let index = car.action_base + a.action_index;
            if car.logged_adaptations.contains(&index) {
                continue;
            }
            let (kind, field) = match a.kind {
                AdaptationKind::Adapted => (EventKind::ActionAdapted, "MergeAtDistances"),
                AdaptationKind::Skipped => (EventKind::ActionSkipped, "DriveQueue"),
            };
            let detail = format!("{field}[{index}] {}: {}", a.action, a.reason);
            new.push((index, Event { t, kind, car: Some(car.plan.id), other: None, light: None, detail }));
        }
        for (index, event) in new {
            self.cars[i].logged_adaptations.push(index);
            self.events.push(event);
        }
    }

    /// Finds pairs of cars whose footprints newly overlap at time `now`
    /// (seconds): logs each collision and holds both cars still. Pairs
    /// clearly apart by [`super::car::SimCar::near_point`] are settled without their
    /// footprints (the same outcome: not near); a footprint is computed
    /// once, when a pair first needs it.
    pub(super) fn detect_collisions(&mut self, now: f64) {
        let mut points = std::mem::take(&mut self.scratch_points);
        points.clear();
        points.extend(self.cars.iter_mut().map(|car| (!car.removed).then(|| car.near_point())));
        if let Some(tape) = &mut self.tape {
            tape.note_extents(
                points.iter().zip(&self.cars).map(|(p, car)| p.map(|(point, r)| (point, extent(car.reach, r)))),
            );
        }
        let mut candidates = std::mem::take(&mut self.scratch_pairs);
        let mut extents = std::mem::take(&mut self.scratch_extents);
        self.candidate_pairs(&points, &mut extents, &mut candidates);
        #[cfg(debug_assertions)]
        self.check_candidates(&candidates);
        self.settle_pairs(&candidates, now, |sim, x| sim.cars[x].footprint(), |_, _, _| {});
        (self.scratch_points, self.scratch_pairs, self.scratch_extents) = (points, candidates, extents);
    }

    /// Settles the candidate pairs (sorted; every other pair is clearly
    /// apart) at time `now`: contacts of pairs no longer candidates end ("not
    /// near"), and each pair that newly touches collides, `before_collide`
    /// called first. `footprint` gives a car's rectangle, asked at most once
    /// per car.
    ///
    /// Most steps there is nothing to settle (no pair near, no contact):
    /// that is told here, before any call (every step of every effects
    /// re-run comes here).
    #[inline(always)]
    pub(super) fn settle_pairs(
        &mut self,
        candidates: &[(usize, usize)],
        now: f64,
        footprint: impl Fn(&Self, usize) -> OrientedBox,
        before_collide: impl FnMut(&mut Self, usize, usize),
    ) {
        if !candidates.is_empty() || !self.contacts.is_empty() {
            self.settle_candidates(candidates, now, footprint, before_collide);
        }
    }

    /// [`Sim::settle_pairs`] where there is something to settle.
    fn settle_candidates(
        &mut self,
        candidates: &[(usize, usize)],
        now: f64,
        footprint: impl Fn(&Self, usize) -> OrientedBox,
        mut before_collide: impl FnMut(&mut Self, usize, usize),
    ) {
        if !self.contacts.is_empty() {
            self.contacts.retain(|pair| candidates.binary_search(pair).is_ok());
        }
        if candidates.is_empty() {
            return;
        }
        let mut boxes = std::mem::take(&mut self.scratch_boxes);
        boxes.clear();
        boxes.resize(self.cars.len(), None);
        for &(i, j) in candidates {
            let reach = self.cars[i].reach + self.cars[j].reach;
            let bi = *boxes[i].get_or_insert_with(|| footprint(self, i));
            let bj = *boxes[j].get_or_insert_with(|| footprint(self, j));
            if self.new_contact(i, j, reach, &bi, &bj) {
                before_collide(self, i, j);
                self.collide(i, j, now);
            }
        }
        self.scratch_boxes = boxes;
    }

    /// Pairs `(i, j)`, `i < j`, of cars whose centres may be near enough to
    /// touch, into `pairs`, given for each car on the map a point and a
    /// radius its centre is within (`None`: off the map), in order: a sweep
    /// along x over each car's reach, so the cost grows with the cars, not
    /// their pairs. `extents` is the sweep's buffer, kept from step to step
    /// for its order.
    pub(super) fn candidate_pairs(
        &self,
        points: &[Option<(DVec2, f64)>],
        extents: &mut Vec<(usize, DVec2, f64)>,
        pairs: &mut Vec<(usize, usize)>,
    ) {
        // Per car: its point and how far from it another car's point may be
        // and still count (half the pair's bound, with room for round-off).
        let extent = |i: usize, (point, radius): (DVec2, f64)| (i, point, extent(self.cars[i].reach, radius));
        // Kept in the order the last step's sort left when the same cars
        // are on the map (they move little in a step), so the sort finds it
        // nearly sorted; the pairs found do not depend on the order.
        let same_cars =
            extents.len() == points.iter().flatten().count() && extents.iter().all(|e| points[e.0].is_some());
        if same_cars {
            for e in extents.iter_mut() {
                *e = extent(e.0, points[e.0].expect("checked above"));
            }
        } else {
            extents.clear();
            extents.extend(points.iter().enumerate().filter_map(|(i, p)| p.map(|p| extent(i, p))));
        }
        extents.sort_by(|a, b| (a.1.x - a.2).total_cmp(&(b.1.x - b.2)));
        pairs.clear();
        for (k, &(i, pi, ei)) in extents.iter().enumerate() {
            for &(j, pj, ej) in &extents[k + 1..] {
                if pj.x - ej >= pi.x + ei {
                    break;
                }
                if may_touch(pi, ei, pj, ej) {
                    pairs.push((i.min(j), i.max(j)));
                }
            }
        }
        pairs.sort_unstable();
    }

    /// Debug builds (every test): no pair left out of `candidates` is near
    /// by its exact footprints.
    #[cfg(debug_assertions)]
    fn check_candidates(&self, candidates: &[(usize, usize)]) {
        let n = self.cars.len();
        for (i, j) in (0..n).flat_map(|i| (i + 1..n).map(move |j| (i, j))) {
            if self.cars[i].removed || self.cars[j].removed || candidates.contains(&(i, j)) {
                continue;
            }
            let d = self.cars[i].pose().0.distance(self.cars[j].pose().0);
            let reach = self.cars[i].reach + self.cars[j].reach;
            assert!(d >= reach + CONTACT_RELEASE, "cars {i} and {j} are {d} m apart, but not a candidate pair");
        }
    }

    /// Whether cars `i < j` (footprints `a` and `b`, `reach` the sum of
    /// their half diagonals) have just touched. A contact ends only once the
    /// cars are clearly apart ([`CONTACT_RELEASE`]), so sideways wander does
    /// not log one crash many times.
    fn new_contact(&mut self, i: usize, j: usize, reach: f64, a: &OrientedBox, b: &OrientedBox) -> bool {
        let near = a.centre.distance(b.centre) < reach + CONTACT_RELEASE;
        if self.contacts.contains(&(i, j)) {
            if !near || !a.inflated(CONTACT_RELEASE).overlaps(b) {
                self.contacts.remove(&(i, j));
            }
            return false;
        }
        if !near || !a.overlaps(b) {
            return false;
        }
        self.contacts.insert((i, j));
        true
    }

    /// Logs the collision of cars `i` and `j` at time `now` and stops both
    /// for 2 to 5 seconds each (drawn from each car's own stream).
    fn collide(&mut self, i: usize, j: usize, now: f64) {
        if let Some(tape) = &mut self.tape {
            tape.collided = true;
        }
        let (a, b) = (&self.cars[i], &self.cars[j]);
        self.events.push(Event {
            t: now,
            kind: EventKind::Collision,
            car: Some(a.plan.id),
            other: Some(b.plan.id),
            light: None,
            detail: format!("speeds {:.2} and {:.2} m/s", a.v, b.v),
        });
        let ids = [self.cars[i].plan.id, self.cars[j].plan.id];
        for (k, other) in [(i, ids[1]), (j, ids[0])] {
            let car = &mut self.cars[k];
            car.collided_with = Some(other);
            let stop = car.rng.random_range(2.0..5.0);
            car.v = 0.0;
            car.accel = 0.0;
            car.hold_until = now + stop;
        }
    }
}
