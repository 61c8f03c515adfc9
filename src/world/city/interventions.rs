//! Interventions while the scenario runs: when each trigger holds, what each
//! effect changes, and the one routine that re-plans a car's route from where
//! it stands (replaced actions, lane changes given up).

use super::car::PendingQueue;
use super::Sim;
use crate::map::signals::Light;
use crate::map::{Action, LanePolicy, LegKind, Route, RouteError};
use crate::plan::confounders::ConfounderName;
use crate::plan::interventions::{Effect, Trigger};
use crate::plan::OnLeaderLost;
use crate::world::{BoundBy, Event, EventKind, Interaction};
use std::sync::Arc;

/// A re-planned route must reach this many times the car's fastest planned
/// desired speed times the time left, so it outlasts the scenario even if
/// the car drives faster than planned.
const ROUTE_SPEED_MARGIN: f64 = 1.5;
/// Speed a re-planned route allows for at least, m/s (cars with slower
/// planned desired speeds still get a route this long).
const ROUTE_MIN_SPEED: f64 = 1.0;
/// Metres added to a re-planned route beyond that.
const ROUTE_SLACK: f64 = 20.0;

impl Sim<'_> {
    /// Fires the interventions whose trigger holds at time `t` (the start of
    /// a step of length `dt`, seconds), logging each.
    #[inline]
    pub(super) fn fire_interventions(&mut self, t: f64, dt: f64) {
        // Most steps of most runs (every effects re-run after its start)
        // have none left.
        if self.pending.is_empty() {
            return;
        }
        let mut k = 0;
        while k < self.pending.len() {
            let intervention = self.pending[k];
            if !self.triggered(&intervention.trigger, t, dt) {
                k += 1;
                continue;
            }
            self.pending.remove(k);
            let car_id = |car: usize| self.cars[car].plan.id;
            self.events.push(Event {
                t,
                kind: EventKind::Intervention,
                car: intervention.effect.car().map(car_id),
                other: None,
                light: intervention.effect.light(),
                detail: intervention.label.clone(),
            });
            self.apply(intervention.effect.clone(), t);
        }
    }

    /// Whether `trigger` holds at time `t`, the start of a step of `dt` seconds.
    fn triggered(&self, trigger: &Trigger, t: f64, dt: f64) -> bool {
        match *trigger {
            Trigger::At(time) => t + 1e-9 >= time,
            Trigger::LightTurns { light, colour } => {
                self.light_state(light, t).colour == colour && self.light_state(light, t - dt).colour != colour
            }
            Trigger::CarReaches { car, intersection } => {
                let car = &self.cars[car];
                if car.removed {
                    return false;
                }
                let setback = self.map.layout.stop_line_setback;
                car.route.legs[car.leg..]
                    .iter()
                    .find_map(|leg| match leg.kind {
                        LegKind::Connector(c) => self.map.connectors[c].intersection.map(|k| (k, leg)),
                        _ => None,
                    })
                    .is_some_and(|(k, leg)| k == intersection && car.front() >= leg.route_start - setback)
            }
        }
    }

    /// Carries out `effect` at time `t` (seconds).
    fn apply(&mut self, effect: Effect, t: f64) {
        match effect {
            Effect::Stop { car, seconds } => {
                let car = &mut self.cars[car];
                car.stopped_until = t + seconds;
                car.next_decision = t;
            }
            Effect::RunRedLights { car } => self.cars[car].runs_red_lights = true,
            Effect::SetDesiredSpeed { car, speed } => {
                let car = &mut self.cars[car];
                car.desired_override = Some(speed);
                car.next_decision = t;
            }
            Effect::Remove { car: removed } => {
                let car = &mut self.cars[removed];
                car.removed = true;
                car.binding = Interaction { bound_by: BoundBy::Intervention, other_car: None, light: None };
                // Its followers have lost it: each drives its own queue from
                // the actions it has done.
                for follower in self.followers_of(removed) {
                    let car = &mut self.cars[follower];
                    match &car.plan.on_leader_lost {
                        Some(OnLeaderLost::Drive(fallback)) => {
                            let done = car.actions_done;
                            let own = (car.actions.get(done..), car.merges.get(done..));
                            let lost = (fallback.actions.get(done..), fallback.merge_distances.get(done..));
                            // A queue like the one it drives changes nothing (scenario files' followers).
                            if own != lost {
                                car.pending_actions =
                                    Some(PendingQueue::slice(&fallback.actions, &fallback.merge_distances, done));
                            }
                        }
                        Some(OnLeaderLost::Stop) => {
                            car.stopped_until = f64::INFINITY;
                            car.next_decision = t;
                        }
                        None => {}
                    }
                }
            }
            Effect::SetLight { light, colour, seconds } => {
                self.light_overrides.push((light, colour, t, t + seconds));
                // Drivers see the change at their next decision.
            }
            Effect::SetLightPlan { light, offset, schedule } => {
                let new = Light { offset, schedule, ..self.city.lights.lights[light].clone() };
                self.light_plans.push((light, new, t));
            }
            Effect::ReplaceActions { car, actions, merge_distances } => {
                self.cars[car].pending_actions = Some(PendingQueue { actions, merges: merge_distances, from: None });
            }
            Effect::SetConfounder { confounder, value } => self.set_confounder(confounder, value, t),
        }
    }

    /// Sets a confounder at time `t` (a do-intervention: the variables still
    /// set by their equations follow, each change logged as an intervention
    /// event): every driver's parameters and desired speed change by the
    /// ratio (or difference) of the new effects to the old.
    fn set_confounder(&mut self, confounder: ConfounderName, value: f64, t: f64) {
        let before = self.confounders;
        let new = self.confounder_model.intervene(before, confounder, value);
        for (name, was, now) in [("fog", before.fog, new.fog), ("wetness", before.wetness, new.wetness)] {
            if was != now && name != confounder.name() {
                self.events.push(Event {
                    t,
                    kind: EventKind::Intervention,
                    car: None,
                    other: None,
                    light: None,
                    detail: format!(
                        "{name} {was:.3} -> {now:.3} by its equation, after {} was set to {value}",
                        confounder.name()
                    ),
                });
            }
        }
        let (old, effects) = (before.effects(), new.effects());
        for car in &mut self.cars {
            let d = &mut car.driver;
            d.time_headway *= effects.time_headway_factor / old.time_headway_factor;
            d.max_deceleration *= effects.grip_factor / old.grip_factor;
            d.comfortable_deceleration = (d.comfortable_deceleration * effects.comfortable_braking_factor
                / old.comfortable_braking_factor)
                .min(d.max_deceleration);
            d.perception_noise += effects.perception_noise_added - old.perception_noise_added;
            d.reaction_time += effects.reaction_time_added - old.reaction_time_added;
            d.lateral_wander += effects.lateral_wander_added - old.lateral_wander_added;
            car.speed_factor *= effects.desired_speed_factor / old.desired_speed_factor;
        }
        self.confounders = new;
        self.confounder_changes.push((t, new));
    }

    /// Replaces car `i`'s remaining actions once it is on a lane (not
    /// mid-turn or mid-merge); if they cannot be driven from there the car
    /// keeps its own and an event says so.
    pub(super) fn replace_actions(&mut self, i: usize, t: f64) {
        let Some(pending) = &self.cars[i].pending_actions else { return };
        let (actions, merges) = pending.remaining(self.cars[i].actions_done);
        let Some((lane_s, planned)) = self.replan(i, t, actions, merges, &LanePolicy::Adapt) else { return };
        let (actions, merges) = (actions.to_vec(), merges.to_vec());
        let car = &mut self.cars[i];
        car.pending_actions = None;
        match planned {
            Ok(route) => {
                let done = car.actions_done;
                let own = Arc::make_mut(&mut car.actions);
                own.truncate(done);
                own.extend(actions);
                let own = Arc::make_mut(&mut car.merges);
                own.truncate(done);
                own.extend(merges);
                car.follow_route(route, lane_s, done);
                car.committed = None;
                car.given_up.retain(|&k| k < done);
                car.logged_adaptations.retain(|&k| k < done);
                car.waiting_since = None;
                self.log_adaptations(i, t);
                self.show_followers(i);
            }
            Err(e) => {
                let id = car.plan.id;
                self.events.push(Event {
                    t,
                    kind: EventKind::Intervention,
                    car: Some(id),
                    other: None,
                    light: None,
                    detail: format!("replacing the actions not applied: {e}; the car keeps its own"),
                });
            }
        }
    }

    /// The cars that follow car `i` and are still in the scene.
    pub(super) fn followers_of(&self, i: usize) -> Vec<usize> {
        (0..self.cars.len()).filter(|&j| self.cars[j].leader == Some(i) && !self.cars[j].removed).collect()
    }

    /// Car `i`'s remaining actions changed: its followers see it (turn
    /// signals, the lane it takes) and take the same actions from the ones
    /// they have done, re-planning once they are on a lane. A turn the
    /// leader gave up is one it drives straight through, so they do too.
    pub(super) fn show_followers(&mut self, i: usize) {
        if self.cars[i].removed || self.quiet_followers {
            return;
        }
        let leader = &self.cars[i];
        let mut seen = leader.actions.to_vec();
        for &k in &leader.given_up {
            if let Some(action) = seen.get_mut(k).filter(|a| !a.is_merge()) {
                *action = Action::Straight;
            }
        }
        let merges = Arc::clone(&leader.merges);
        let followers = self.followers_of(i);
        if followers.is_empty() {
            return;
        }
        if let Some(tape) = &mut self.tape {
            tape.note_shown(i, &seen, &merges);
        }
        for follower in followers {
            // A re-run simulates a simulated leader's followers too (`replay.rs`).
            debug_assert!(!self.frozen[follower], "a replayed follower of simulated car {i}");
            self.show_queue(follower, &seen, &merges);
        }
    }

    /// Follower `follower` sees its leader's drive queue `seen` (merges at
    /// `merges`): it takes the actions from the ones it has done.
    pub(super) fn show_queue(&mut self, follower: usize, seen: &[Action], merges: &[f64]) {
        let done = self.cars[follower].actions_done;
        self.cars[follower].pending_actions = Some(PendingQueue::slice(seen, merges, done));
        if let Some(tape) = &mut self.tape {
            tape.touch(follower);
        }
    }

    /// Car `i` gives up the lane change just ahead of it (no gap came in
    /// [`super::perception::LANE_CHANGE_PATIENCE`]): the merge, or the turn
    /// the change prepared, is skipped and the route re-planned from here.
    pub(super) fn give_up_lane_change(&mut self, i: usize, t: f64) {
        let car = &self.cars[i];
        let Some(change) = car.route.legs.get(car.leg + 1) else { return };
        let LegKind::LaneChange { from, to, .. } = change.kind else { return };
        let Some(relative) = change.action.or(change.prepares) else { return };
        let index = car.action_base + relative;
        let mut given_up = car.given_up.clone();
        given_up.push(index);
        let policy = LanePolicy::AdaptGivingUp(given_up.iter().filter_map(|&k| k.checked_sub(index)).collect());
        let Some((lane_s, Ok(route))) = self.replan(i, t, &car.actions[index..], &car.merges[index..], &policy) else {
            return;
        };
        let (from, to) = (&self.map.lanes[from].name, &self.map.lanes[to].name);
        let turn_given_up = change.prepares.is_some();
        let instead = if turn_given_up { ": going straight on instead" } else { "" };
        let detail = format!(
            "DriveQueue[{index}] {}: no gap to change from {from} into {to} came in {} s{instead}",
            car.actions[index],
            super::perception::LANE_CHANGE_PATIENCE
        );
        let id = car.plan.id;
        self.events.push(Event { t, kind: EventKind::ActionSkipped, car: Some(id), other: None, light: None, detail });
        let car = &mut self.cars[i];
        car.given_up = given_up;
        car.logged_adaptations.push(index);
        car.waiting_since = None;
        car.follow_route(route, lane_s, index);
        self.log_adaptations(i, t);
        // Its followers see it drive straight on.
        if turn_given_up {
            self.show_followers(i);
        }
    }

    /// The one re-planning routine: a route for car `i` from where it stands
    /// on its current lane (`lane_s` metres along it, returned first) that
    /// carries out `actions` (merges at `merges` metres along their lanes)
    /// and lasts until the scenario's last frame. `None` when the car is not
    /// on a lane (mid-turn or mid-merge).
    fn replan(
        &self,
        i: usize,
        t: f64,
        actions: &[Action],
        merges: &[f64],
        policy: &LanePolicy,
    ) -> Option<(f64, Result<Route, RouteError>)> {
        let car = &self.cars[i];
        let current = &car.route.legs[car.leg];
        let LegKind::Lane(lane) = current.kind else { return None };
        let max_speed = car.agency.desired_speeds.iter().copied().fold(ROUTE_MIN_SPEED, f64::max);
        let lane_s = current.curve_start + (car.s - current.route_start);
        let min_length = lane_s + max_speed * ROUTE_SPEED_MARGIN * (self.horizon - t).max(0.0) + ROUTE_SLACK;
        Some((lane_s, Route::plan(self.map, lane, lane_s, actions, merges, min_length, policy)))
    }
}
