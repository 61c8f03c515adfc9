//! The city world: cars with agency. Each car follows its route (lane centre
//! lines, turn connectors, lane changes) and chooses its speed every reaction
//! time from a car-following model: free road, the car ahead on its path, stop
//! lines at red and yellow lights, cars still crossing the intersection, curve
//! speeds, and gaps it waits for before merging. Perception is noisy and the
//! acceleration is held between decisions, so collisions can happen; when they
//! do, both cars stop for a few seconds. Confounders act through the driver
//! parameters the plan hands over. Interventions (`interventions.rs`) fire
//! at a time or on an event and change one car or light. Everything random
//! comes from per-car streams derived from the scenario's, so runs are
//! reproducible and an intervention on one car leaves the randomness of every
//! other car untouched (counterfactual pairs differ only where it acts).

use super::driver::{CarFollowing, Idm};
use super::{CarState, Event, EventKind, Trajectories};
use crate::geometry::OrientedBox;
use crate::map::curve::Curve;
use crate::map::signals::{Colour, Light, LightState, Signal};
use crate::map::{Action, CityMap, LaneEnd, LegKind, Route, Turn};
use crate::plan::confounders::Confounders;
use crate::plan::interventions::{Effect, Intervention, Trigger};
use crate::plan::{CarAgency, CarPlan, CityPlan, ScenarioPlan};
use crate::spec::DriverParams;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::BTreeSet;

/// Longest internal time step, seconds; frames fall on step boundaries.
pub const MAX_STEP: f64 = 0.05;
/// How far ahead along its route a driver looks, metres.
const LOOKAHEAD: f64 = 30.0;
/// Largest sideways wander from the lane centre, metres.
const MAX_WANDER: f64 = 0.4;
/// A car on a sibling movement (same lane, other turn) counts as ahead of
/// cars behind it until it is this far into its turn, metres.
const SIBLING_CLEARANCE: f64 = 3.0;
/// Gap at which two cars that collided count as apart again, metres.
const CONTACT_RELEASE: f64 = 0.3;
/// Correlation time of the sideways wander, seconds.
const WANDER_TIME: f64 = 3.0;

/// Agency dynamics over a car-following model (IDM by default).
pub struct CityWorld {
    model: Box<dyn CarFollowing>,
}

impl Default for CityWorld {
    fn default() -> Self {
        CityWorld { model: Box::new(Idm::default()) }
    }
}

impl CityWorld {
    /// A city world whose drivers use `model`.
    pub fn with_model(model: Box<dyn CarFollowing>) -> CityWorld {
        CityWorld { model }
    }
}

impl CityWorld {
    /// Name of the drivers' car-following model, for scenario.json.
    pub fn model_name(&self) -> &'static str {
        self.model.name()
    }

    /// Simulates `plan`, whose city parts are `city`.
    pub fn simulate(&self, map: &CityMap, plan: &ScenarioPlan, city: &CityPlan) -> Trajectories {
        let mut sim = Sim::new(map, plan, city, self.model.as_ref());
        if plan.frames == 0 {
            return Trajectories {
                frame_interval: plan.frame_interval,
                states: vec![],
                lights: vec![],
                events: vec![],
                confounder_changes: vec![],
            };
        }
        let steps = (plan.frame_interval / MAX_STEP).ceil().max(1.0) as usize;
        let dt = plan.frame_interval / steps as f64;
        let mut states = Vec::with_capacity(plan.frames as usize);
        let mut lights = Vec::with_capacity(plan.frames as usize);
        for frame in 0..plan.frames as usize {
            if frame > 0 {
                for k in 0..steps {
                    let t = (frame - 1) as f64 * plan.frame_interval + k as f64 * dt;
                    sim.step(t, dt);
                }
            }
            let t = frame as f64 * plan.frame_interval;
            // Interventions due now show in this frame's record (lights).
            sim.fire_interventions(t, dt);
            states.push(sim.cars.iter().map(SimCar::state).collect());
            lights.push((0..city.lights.lights.len()).map(|l| sim.light_state(l, t)).collect());
        }
        // A change shows from the first frame at or after it.
        let confounder_changes = sim
            .confounder_changes
            .iter()
            .map(|&(t, c)| (((t / plan.frame_interval) - 1e-9).ceil().max(0.0) as usize, c))
            .collect();
        Trajectories { frame_interval: plan.frame_interval, states, lights, events: sim.events, confounder_changes }
    }
}

/// One car while the scenario runs.
struct SimCar<'p> {
    plan: &'p CarPlan,
    agency: &'p CarAgency,
    /// The car's own copy: merges it defers re-plan it.
    route: Route,
    /// Drive-queue index of the route's first action.
    action_base: usize,
    merges: Vec<f64>,
    /// Route arc length of the car's centre.
    s: f64,
    v: f64,
    accel: f64,
    leg: usize,
    next_decision: f64,
    hold_until: f64,
    actions_done: usize,
    /// Intersection connector the car has decided to drive through.
    committed: Option<usize>,
    wander: f64,
    /// Where the wander is heading, drawn at each decision.
    wander_target: f64,
    /// Standard-normal state of the perception error.
    noise: f64,
    /// Half the footprint's diagonal: beyond twice this, two cars cannot touch.
    reach: f64,
    /// This car's own random stream (decisions, collision stops).
    rng: ChaCha8Rng,
    /// Forced through red lights (by the plan or an intervention).
    runs_red_lights: bool,
    /// Intervention: hold still until this time.
    stopped_until: f64,
    /// Intervention: desired speed replaced.
    desired_override: Option<f64>,
    /// Intervention: taken off the map.
    removed: bool,
    /// The drive queue: the plan's, until an intervention replaces the rest.
    actions: Vec<Action>,
    /// Intervention: actions waiting to replace the rest once on a lane.
    pending_actions: Option<(Vec<Action>, Vec<f64>)>,
    /// The driver's parameters now (the plan's, until a confounder changes).
    driver: DriverParams,
    /// Multiplies the planned desired speeds (a confounder change).
    speed_factor: f64,
}

/// Where removed cars are parked, far off every camera, metres.
const PARKING: glam::DVec2 = glam::DVec2::new(10_000.0, 10_000.0);

impl SimCar<'_> {
    fn front(&self) -> f64 {
        self.s + self.plan.length / 2.0
    }

    fn desired(&self) -> f64 {
        if let Some(speed) = self.desired_override {
            return speed;
        }
        let speeds = &self.agency.desired_speeds;
        self.speed_factor * speeds.get(self.actions_done.min(speeds.len().saturating_sub(1))).copied().unwrap_or(1.0)
    }

    fn pose(&self) -> (glam::DVec2, f64) {
        self.route.pose_at(self.s, self.wander)
    }

    fn footprint(&self) -> OrientedBox {
        let (centre, heading) = self.pose();
        OrientedBox { centre, heading, length: self.plan.length, width: self.plan.width }
    }

    fn state(&self) -> CarState {
        if self.removed {
            let position = PARKING + glam::DVec2::new(10.0 * self.plan.id as f64, 0.0);
            return CarState { position, z: 0.0, roll: 0.0, pitch: 0.0, yaw: 0.0, speed: 0.0 };
        }
        let (position, yaw) = self.pose();
        CarState { position, z: 0.0, roll: 0.0, pitch: 0.0, yaw, speed: self.v }
    }
}

struct Sim<'a> {
    map: &'a CityMap,
    city: &'a CityPlan,
    model: &'a dyn CarFollowing,
    cars: Vec<SimCar<'a>>,
    events: Vec<Event>,
    /// Interventions still waiting for their trigger.
    pending: Vec<&'a Intervention>,
    /// Lights forced by interventions: (light, colour, from, until).
    light_overrides: Vec<(usize, Colour, f64, f64)>,
    /// Lights given a new plan by interventions: (light, plan, from).
    light_plans: Vec<(usize, Light, f64)>,
    /// The confounders now, and the changes interventions made (time, values).
    confounders: Confounders,
    confounder_changes: Vec<(f64, Confounders)>,
    /// Per track (lane or connector): (car, arc length on the track).
    occupancy: Vec<Vec<(usize, f64)>>,
    contacts: BTreeSet<(usize, usize)>,
    horizon: f64,
}

/// A standard normal draw (Box-Muller).
fn normal(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = rng.random::<f64>().max(1e-12);
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

impl<'a> Sim<'a> {
    fn new(map: &'a CityMap, plan: &'a ScenarioPlan, city: &'a CityPlan, model: &'a dyn CarFollowing) -> Sim<'a> {
        let cars = plan
            .cars
            .iter()
            .zip(&city.agency)
            .map(|(c, agency)| {
                let mut rng = ChaCha8Rng::from_seed(city.sim_stream);
                rng.set_stream(c.id as u64 + 1);
                let route: Route = (*c.route).clone();
                let leg = route.leg_index_at(c.spawn_distance);
                SimCar {
                    plan: c,
                    agency,
                    route,
                    action_base: 0,
                    merges: c.merge_distances.clone(),
                    s: c.spawn_distance,
                    v: 0.0,
                    accel: 0.0,
                    leg,
                    // Drivers do not all decide in lockstep.
                    next_decision: rng.random_range(0.0..agency.driver.reaction_time),
                    hold_until: f64::NEG_INFINITY,
                    actions_done: 0,
                    committed: None,
                    wander: 0.0,
                    wander_target: 0.0,
                    noise: normal(&mut rng),
                    reach: c.length.hypot(c.width) / 2.0,
                    rng,
                    runs_red_lights: agency.runs_red_lights,
                    stopped_until: f64::NEG_INFINITY,
                    desired_override: None,
                    removed: false,
                    actions: c.actions.clone(),
                    pending_actions: None,
                    driver: agency.driver,
                    speed_factor: 1.0,
                }
            })
            .collect();
        Sim {
            map,
            city,
            model,
            cars,
            events: Vec::new(),
            pending: plan.interventions.iter().collect(),
            light_overrides: Vec::new(),
            light_plans: Vec::new(),
            confounders: city.confounders,
            confounder_changes: Vec::new(),
            occupancy: vec![Vec::new(); map.track_count()],
            contacts: BTreeSet::new(),
            horizon: plan.frames.saturating_sub(1) as f64 * plan.frame_interval,
        }
    }

    fn step(&mut self, t: f64, dt: f64) {
        self.fire_interventions(t, dt);
        for i in 0..self.cars.len() {
            if self.cars[i].pending_actions.is_some() {
                self.replace_actions(i, t);
            }
        }
        self.fill_occupancy();
        for i in 0..self.cars.len() {
            if self.cars[i].removed {
                continue;
            }
            if t + 1e-9 >= self.cars[i].next_decision {
                self.decide(i, t, dt);
                self.cars[i].next_decision = t + self.cars[i].driver.reaction_time;
            }
        }
        for i in 0..self.cars.len() {
            if !self.cars[i].removed {
                self.advance(i, t, dt);
            }
        }
        self.detect_collisions(t + dt);
    }

    /// Fires the interventions whose trigger holds at time `t` (the start of
    /// a step of length `dt`), logging each.
    fn fire_interventions(&mut self, t: f64, dt: f64) {
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
                car: intervention.effect.car().map_or(0, car_id),
                other: None,
                detail: intervention.label.clone(),
            });
            match intervention.effect.clone() {
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
                Effect::Remove { car } => self.cars[car].removed = true,
                Effect::SetLight { light, colour, seconds } => {
                    self.light_overrides.push((light, colour, t, t + seconds));
                    // Drivers see the change at their next decision.
                }
                Effect::SetLightPlan { light, offset, schedule } => {
                    let new = Light { offset, schedule, ..self.city.lights.lights[light].clone() };
                    self.light_plans.push((light, new, t));
                }
                Effect::ReplaceActions { car, actions, merge_distances } => {
                    self.cars[car].pending_actions = Some((actions, merge_distances));
                }
                Effect::SetConfounder { confounder, value } => {
                    let (old, new) = (self.confounders.effects(), confounder.set(self.confounders, value));
                    let effects = new.effects();
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
            }
        }
    }

    /// Replaces car `i`'s remaining actions once it is on a lane.
    fn replace_actions(&mut self, i: usize, t: f64) {
        let max_speed = self.cars[i].agency.desired_speeds.iter().copied().fold(1.0, f64::max);
        let horizon = self.horizon;
        let car = &mut self.cars[i];
        let current = &car.route.legs[car.leg];
        let LegKind::Lane(lane) = current.kind else { return };
        let Some((actions, merges)) = car.pending_actions.take() else { return };
        let lane_s = current.curve_start + (car.s - current.route_start);
        let min_length = lane_s + max_speed * 1.5 * (horizon - t).max(0.0) + 20.0;
        match Route::plan(self.map, lane, lane_s, &actions, &merges, min_length) {
            Ok(route) => {
                let done = car.actions_done;
                car.actions.truncate(done);
                car.actions.extend(actions);
                car.merges.truncate(done);
                car.merges.extend(merges);
                car.route = route;
                car.s = lane_s;
                car.leg = car.route.leg_index_at(lane_s);
                car.action_base = done;
                car.committed = None;
            }
            Err(e) => {
                let id = car.plan.id;
                self.events.push(Event {
                    t,
                    kind: EventKind::Intervention,
                    car: id,
                    other: None,
                    detail: format!("replacing the actions not applied: {e}; the car keeps its own"),
                });
            }
        }
    }

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

    fn fill_occupancy(&mut self) {
        for track in &mut self.occupancy {
            track.clear();
        }
        let setback = self.map.layout.stop_line_setback;
        for (i, car) in self.cars.iter().enumerate().filter(|(_, c)| !c.removed) {
            let leg = &car.route.legs[car.leg];
            let along = car.s - leg.route_start;
            // A car past its stop line, or committed to go, already claims the
            // movement it is about to make (at a negative position on it).
            if let (LegKind::Lane(_), Some(next)) = (leg.kind, car.route.legs.get(car.leg + 1)) {
                if let LegKind::Connector(c) = next.kind {
                    let to_box = next.route_start - car.front();
                    if self.map.connectors[c].intersection.is_some() && (to_box < setback || car.committed == Some(c)) {
                        self.occupancy[self.map.connector_track(c)].push((i, -to_box.max(0.0) - 1.0));
                    }
                }
            }
            match leg.kind {
                LegKind::Lane(lane) => self.occupancy[lane].push((i, leg.curve_start + along)),
                LegKind::Connector(c) => self.occupancy[self.map.connector_track(c)].push((i, along)),
                LegKind::LaneChange { from, to, at } => {
                    // Mid-merge a car occupies both lanes.
                    let lane_s = at + along * self.map.layout.lane_change_length / leg.length;
                    self.occupancy[from].push((i, lane_s));
                    self.occupancy[to].push((i, lane_s));
                }
            }
        }
    }

    /// The nearest car ahead on car `i`'s path: (bumper gap, its speed).
    fn leader_ahead(&self, i: usize) -> Option<(f64, f64)> {
        let car = &self.cars[i];
        let run = self.map.layout.lane_change_length;
        for leg in &car.route.legs[car.leg..] {
            if leg.route_start - car.s > LOOKAHEAD {
                break;
            }
            // Which tracks this leg runs on, and the track arc length at its start.
            let (tracks, start, end): ([Option<usize>; 2], f64, f64) = match leg.kind {
                LegKind::Lane(l) => ([Some(l), None], leg.curve_start, leg.curve_start + leg.length),
                LegKind::Connector(c) => ([Some(self.map.connector_track(c)), None], 0.0, leg.length),
                LegKind::LaneChange { from, to, at } => ([Some(from), Some(to)], at, at + run),
            };
            let mut best: Option<(f64, usize)> = None;
            // Cars that left the same lane on another movement (a right turn
            // beside my straight) are still in front until they have turned away.
            if let LegKind::Connector(c) = leg.kind {
                let from = self.map.connectors[c].from;
                for sibling in self.map.exits_from(from).filter(|&o| o != c) {
                    for &(j, pos) in &self.occupancy[self.map.connector_track(sibling)] {
                        let d = leg.route_start + pos.max(0.0) - car.s;
                        if j != i && pos < SIBLING_CLEARANCE && d > 0.0 && best.is_none_or(|(b, _)| d < b) {
                            best = Some((d, j));
                        }
                    }
                }
            }
            for track in tracks.into_iter().flatten() {
                for &(j, pos) in &self.occupancy[track] {
                    if j == i || pos < start - 0.01 || pos > end + 0.01 {
                        continue;
                    }
                    let d = leg.route_start + (pos - start) - car.s;
                    if d > 0.0 && best.is_none_or(|(b, _)| d < b) {
                        best = Some((d, j));
                    }
                }
            }
            if let Some((d, j)) = best {
                let other = &self.cars[j];
                return Some((d - (car.plan.length + other.plan.length) / 2.0, other.v));
            }
        }
        None
    }

    /// Distance from car `i`'s front to where it must stop for a light or for
    /// cars crossing the intersection, if it must.
    fn stop_ahead(&mut self, i: usize, t: f64) -> Option<f64> {
        let car = &self.cars[i];
        let front = car.front();
        let p = &car.driver;
        let braking = car.v * car.v / (2.0 * p.comfortable_deceleration);
        let setback = self.map.layout.stop_line_setback;
        let mut commit = None;
        let mut stop = None;
        for leg in &car.route.legs[car.leg..] {
            if leg.route_start - car.s > LOOKAHEAD {
                break;
            }
            let LegKind::Connector(c) = leg.kind else { continue };
            let dist = leg.route_start - setback - front;
            // Past the stop line, or forced through: nothing stops the car here.
            if dist < -0.05 || car.runs_red_lights {
                continue;
            }
            let Some(light) = self.light_for(c) else { continue };
            // Once committed (moving, too close to stop comfortably) the light
            // no longer matters, but cars still crossing the box always do. A
            // car that has come to rest before its line is committed no more.
            let committed = car.committed == Some(c) && car.v > 0.1;
            let must_stop = !committed
                && match self.light_state(light, t).colour {
                    Colour::Red => true,
                    Colour::Yellow => braking <= dist,
                    Colour::Green => false,
                };
            let crossing = dist < braking + 2.0 && self.conflict_occupied(c);
            if must_stop || crossing {
                stop = Some(dist.max(0.0));
                break;
            }
            if car.v > 0.1 && dist < braking {
                commit = Some(c);
            }
        }
        if commit.is_some() {
            self.cars[i].committed = commit;
        }
        stop
    }

    /// The light (index in the plan) that governs entering `connector`: its
    /// approach's Left signal for left turns, its Straight signal otherwise.
    fn light_for(&self, connector: usize) -> Option<usize> {
        let c = &self.map.connectors[connector];
        let intersection = c.intersection?;
        let LaneEnd::Intersection { approach, .. } = self.map.lanes[c.from].end else { return None };
        let signal = if c.turn == Turn::Left { Signal::Left } else { Signal::Straight };
        Some(self.city.lights.index(intersection, approach, signal))
    }

    /// Light `index` at time `t`: its plan, unless an intervention forces it.
    fn light_state(&self, index: usize, t: f64) -> LightState {
        let forced =
            self.light_overrides.iter().rev().find(|&&(l, _, from, until)| l == index && t >= from && t < until);
        if let Some(&(_, colour, from, _)) = forced {
            return LightState { colour, since_change: t - from };
        }
        match self.light_plans.iter().rev().find(|(l, _, from)| *l == index && t >= *from) {
            Some((_, light, _)) => light.state_at(t),
            None => self.city.lights.lights[index].state_at(t),
        }
    }

    fn conflict_occupied(&self, connector: usize) -> bool {
        self.map.conflicts(connector).iter().any(|&other| !self.occupancy[self.map.connector_track(other)].is_empty())
    }

    /// Highest speed that still lets car `i` slow to the curve speed of every curve ahead.
    fn curve_limit(&self, i: usize) -> f64 {
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

    /// For a merge about to start: `None` when car `i` may go on (the gap is
    /// fine, or the merge was moved further along the lane), else the distance
    /// to the merge start where it has to wait.
    fn merge_wait(&mut self, i: usize, t: f64) -> Option<f64> {
        let car = &self.cars[i];
        let next = car.leg + 1;
        let (Some(current), Some(change)) = (car.route.legs.get(car.leg), car.route.legs.get(next)) else {
            return None;
        };
        let LegKind::LaneChange { from, to, at } = change.kind else { return None };
        if current.kind != LegKind::Lane(from) {
            return None;
        }
        let d = change.route_start - car.s;
        let rt = car.driver.reaction_time;
        if d > car.v * (rt + 0.5) + 1.5 || self.merge_gap_ok(i, to, at) {
            return None;
        }
        let run = self.map.layout.lane_change_length;
        let later = ((at + (car.v * rt + 0.5).max(1.0)) * 10.0).ceil() / 10.0;
        if later + run <= self.map.lanes[from].curve.length() - 1e-6 {
            self.defer_merge(i, change.action, later, t);
            return None;
        }
        Some(d.max(0.0))
    }

    /// Whether the target lane has room for car `i` merging over `[at, at + run]`.
    fn merge_gap_ok(&self, i: usize, to: usize, at: f64) -> bool {
        let car = &self.cars[i];
        let run = self.map.layout.lane_change_length;
        self.occupancy[to].iter().all(|&(j, pos)| {
            if j == i {
                return true;
            }
            let other = &self.cars[j];
            let lengths = (car.plan.length + other.plan.length) / 2.0 + car.driver.min_gap;
            pos <= at - lengths - other.v * 1.0 || pos >= at + run + lengths
        })
    }

    /// Moves the merge of car `i` (route action `relative`) to `later` metres along its lane.
    fn defer_merge(&mut self, i: usize, relative: Option<usize>, later: f64, t: f64) {
        let max_speed = self.cars[i].agency.desired_speeds.iter().copied().fold(1.0, f64::max);
        let car = &mut self.cars[i];
        let Some(relative) = relative else { return };
        let index = car.action_base + relative;
        let current = &car.route.legs[car.leg];
        let LegKind::Lane(lane) = current.kind else { return };
        let lane_s = current.curve_start + (car.s - current.route_start);
        let mut merges = car.merges.clone();
        merges[index] = later;
        let min_length = lane_s + max_speed * 1.5 * (self.horizon - t).max(0.0) + 20.0;
        if let Ok(route) = Route::plan(self.map, lane, lane_s, &car.actions[index..], &merges[index..], min_length) {
            car.merges = merges;
            car.route = route;
            car.s = lane_s;
            car.leg = car.route.leg_index_at(lane_s);
            car.action_base = index;
        }
    }

    fn decide(&mut self, i: usize, t: f64, dt: f64) {
        if t < self.cars[i].hold_until {
            self.cars[i].accel = 0.0;
            return;
        }
        let model = self.model;
        let (p, v, desired) = {
            let car = &self.cars[i];
            (car.driver, car.v, car.desired())
        };
        let mut target = model.free_speed(&p, v, desired, dt);
        if let Some((gap, leader_speed)) = self.leader_ahead(i) {
            let perceived = gap * (p.perception_noise * self.cars[i].noise).exp();
            target = target.min(model.follow_speed(&p, v, desired, perceived, leader_speed, dt));
        }
        if let Some(distance) = self.stop_ahead(i, t) {
            target = target.min(model.stop_speed(&p, v, desired, distance, dt));
        }
        target = target.min(self.curve_limit(i));
        if let Some(distance) = self.merge_wait(i, t) {
            target = target.min(model.stop_speed(&p, v, desired, distance, dt));
        }
        if t < self.cars[i].stopped_until {
            target = 0.0;
        }
        let rho = (-p.reaction_time / 2.0).exp();
        let car = &mut self.cars[i];
        let draw = normal(&mut car.rng);
        let wander_draw = normal(&mut car.rng);
        car.accel = ((target - v) / dt).clamp(-p.max_deceleration, p.max_acceleration);
        car.noise = rho * car.noise + (1.0 - rho * rho).sqrt() * draw;
        // Sideways wander: an Ornstein-Uhlenbeck target per decision, approached smoothly.
        let wander_rho = (-p.reaction_time / WANDER_TIME).exp();
        car.wander_target = (wander_rho * car.wander_target
            + p.lateral_wander * (1.0 - wander_rho * wander_rho).sqrt() * wander_draw)
            .clamp(-MAX_WANDER, MAX_WANDER);
    }

    fn advance(&mut self, i: usize, t: f64, dt: f64) {
        let now = t + dt;
        let car = &mut self.cars[i];
        let glide = (dt / car.driver.reaction_time).min(1.0);
        car.wander += (car.wander_target - car.wander) * glide;
        if now <= car.hold_until {
            car.v = 0.0;
            return;
        }
        let front_before = car.front();
        let mut v_new = (car.v + car.accel * dt).max(0.0);
        if car.accel > 0.0 {
            // Speeding up towards the desired speed never overshoots it.
            v_new = v_new.min(car.desired().max(car.v));
        }
        car.s += (car.v + v_new) / 2.0 * dt;
        car.v = v_new;
        if car.v == 0.0 && car.accel < 0.0 {
            car.accel = 0.0;
        }
        let front_after = car.front();
        let id = car.plan.id;
        let mut events = Vec::new();

        // Crossing a stop line on red.
        let setback = self.map.layout.stop_line_setback;
        let car = &self.cars[i];
        for leg in &car.route.legs[car.leg..] {
            if leg.route_start - setback > front_after {
                break;
            }
            let LegKind::Connector(c) = leg.kind else { continue };
            let connector = &self.map.connectors[c];
            let Some(intersection) = connector.intersection else { continue };
            let line = leg.route_start - setback;
            if front_before < line && front_after >= line {
                let Some(light) = self.light_for(c) else { continue };
                if self.light_state(light, now).colour == Colour::Red {
                    let forced = if car.runs_red_lights { "forced" } else { "not forced" };
                    let light = &self.city.lights.lights[light];
                    events.push(Event {
                        t: now,
                        kind: EventKind::RedLightRun,
                        car: id,
                        other: None,
                        detail: format!(
                            "{} {} {} ({forced})",
                            self.map.intersections[intersection].name,
                            light.approach,
                            light.signal.name()
                        ),
                    });
                }
            }
        }
        let car = &mut self.cars[i];

        // Legs completed: actions done.
        while car.leg + 1 < car.route.legs.len() {
            let leg = &car.route.legs[car.leg];
            if car.s < leg.route_start + leg.length {
                break;
            }
            if let Some(relative) = leg.action {
                let index = car.action_base + relative;
                let detail = match leg.kind {
                    LegKind::LaneChange { from, to, .. } => Some((
                        EventKind::MergeDone,
                        format!("{} -> {}", self.map.lanes[from].name, self.map.lanes[to].name),
                    )),
                    LegKind::Connector(c) => {
                        let connector = &self.map.connectors[c];
                        let at = connector.intersection.map(|k| self.map.intersections[k].name.as_str()).unwrap_or("");
                        Some((EventKind::TurnDone, format!("{} at {at}", car.actions[index])))
                    }
                    LegKind::Lane(_) => None,
                };
                if let Some((kind, detail)) = detail {
                    events.push(Event { t: now, kind, car: id, other: None, detail });
                }
                car.actions_done = index + 1;
                if index + 1 == car.actions.len() {
                    events.push(Event {
                        t: now,
                        kind: EventKind::ActionsFinished,
                        car: id,
                        other: None,
                        detail: format!("{} actions", car.actions.len()),
                    });
                }
            }
            if let LegKind::Connector(c) = leg.kind {
                if car.committed == Some(c) {
                    car.committed = None;
                }
            }
            car.leg += 1;
        }
        self.events.extend(events);
    }

    fn detect_collisions(&mut self, now: f64) {
        let boxes: Vec<OrientedBox> = self.cars.iter().map(SimCar::footprint).collect();
        for i in 0..boxes.len() {
            for j in i + 1..boxes.len() {
                if self.cars[i].removed || self.cars[j].removed {
                    continue;
                }
                let reach = self.cars[i].reach + self.cars[j].reach;
                let near = boxes[i].centre.distance(boxes[j].centre) < reach + CONTACT_RELEASE;
                if self.contacts.contains(&(i, j)) {
                    // A contact ends only once the cars are clearly apart, so
                    // sideways wander does not log one crash many times.
                    if !near || !boxes[i].inflated(CONTACT_RELEASE).overlaps(&boxes[j]) {
                        self.contacts.remove(&(i, j));
                    }
                    continue;
                }
                if !near || !boxes[i].overlaps(&boxes[j]) {
                    continue;
                }
                self.contacts.insert((i, j));
                let (a, b) = (&self.cars[i], &self.cars[j]);
                self.events.push(Event {
                    t: now,
                    kind: EventKind::Collision,
                    car: a.plan.id,
                    other: Some(b.plan.id),
                    detail: format!("speeds {:.2} and {:.2} m/s", a.v, b.v),
                });
                for k in [i, j] {
                    let car = &mut self.cars[k];
                    let stop = car.rng.random_range(2.0..5.0);
                    car.v = 0.0;
                    car.accel = 0.0;
                    car.hold_until = now + stop;
                }
            }
        }
    }
}
