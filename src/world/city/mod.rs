//! The city world: cars with agency. Each car follows its route (lane centre
//! lines, turn connectors, lane changes) and chooses its speed every reaction
//! time from a car-following model: free road, the car ahead on its path, stop
//! lines at red and yellow lights, cars still crossing the intersection, curve
//! speeds, and gaps it waits for before merging. Perception is noisy and the
//! acceleration is held between decisions, so collisions can happen; when they
//! do, both cars stop for a few seconds. Confounders act through the driver
//! parameters the plan hands over. Interventions (`plan/interventions.rs`)
//! fire at a time or on an event and change one car or light. Everything
//! random comes from per-car streams derived from the scenario's, so runs are
//! reproducible and an intervention on one car leaves the randomness of every
//! other car untouched (counterfactual pairs differ only where it acts).
//!
//! Layout, one concern per file:
//! - `mod.rs`: [`CityWorld`], the frame loop and one simulation step;
//! - `car.rs`: a car's state while the scenario runs, and its pose;
//! - `perception.rs`: what a driver sees (track occupancy, the leader ahead,
//!   stop lines and lights, crossing traffic, curves, lane-change gaps and
//!   the wait for them);
//! - `driving.rs`: each decision (target speed from the model) and the motion
//!   between decisions;
//! - `start.rs`: start speeds, lowered to what each driver sees at time 0;
//! - `interventions.rs`: triggers, effects and the one re-planning routine;
//! - `actuation.rs`: traffic-actuated programmes, whose phases detected
//!   cars extend;
//! - `events.rs`: red-light runs, completed actions, lane changes and
//!   adaptations of the drive queue, and collisions;
//! - `replay.rs`: effects re-runs that simulate only the cars an
//!   intervention reached, replaying the others from the factual run.
//!
//! Units: metres, seconds, metres per second.

mod actuation;
mod car;
mod driving;
mod events;
mod interventions;
mod perception;
pub mod replay;
mod start;
#[cfg(test)]
mod tests;

use super::driver::{CarFollowing, Iidm};
use super::{Event, Trajectories};
use crate::map::route::LegKind;
use crate::map::signals::{Colour, Light, LightState};
use crate::map::CityMap;
use crate::plan::confounders::{ConfounderModel, Confounders};
use crate::plan::interventions::Intervention;
use crate::plan::{CityPlan, ScenarioPlan};
use car::SimCar;
use glam::DVec2;
use std::cell::RefCell;
use std::collections::BTreeSet;
use std::sync::atomic::{AtomicBool, Ordering};

/// Longest internal time step, seconds; frames fall on step boundaries.
pub const MAX_STEP: f64 = 0.05;

/// Agency dynamics over a car-following model (the improved IDM by default).
pub struct CityWorld {
    model: Box<dyn CarFollowing>,
}

impl Default for CityWorld {
    fn default() -> Self {
        CityWorld { model: Box::new(Iidm::default()) }
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

    /// Simulates `plan`, whose city parts are `city`: one state per car and
    /// one state per light every `plan.frame_interval` seconds, in steps of
    /// at most [`MAX_STEP`] seconds.
    pub fn simulate(&self, map: &CityMap, plan: &ScenarioPlan, city: &CityPlan) -> Trajectories {
        let never = AtomicBool::new(false);
        self.simulate_until(map, plan, city, &never).expect("a simulation that is never stopped finishes")
    }

    /// [`CityWorld::simulate`], giving up (`None`) at the first frame at
    /// which `stop` is set.
    pub fn simulate_until(
        &self,
        map: &CityMap,
        plan: &ScenarioPlan,
        city: &CityPlan,
        stop: &AtomicBool,
    ) -> Option<Trajectories> {
        simulate_with(self.model.as_ref(), map, plan, city, stop)
    }
}

/// [`CityWorld::simulate_until`] with drivers that use `model`.
pub fn simulate_with(
    model: &dyn CarFollowing,
    map: &CityMap,
    plan: &ScenarioPlan,
    city: &CityPlan,
    stop: &AtomicBool,
) -> Option<Trajectories> {
    Sim::new(map, plan, city, model).run(stop)
}

impl Sim<'_> {
    /// Runs the simulation frame by frame (see [`CityWorld::simulate`]).
    fn run(&mut self, stop: &AtomicBool) -> Option<Trajectories> {
        let (plan, city) = (self.plan, self.city);
        let sim = self;
        if plan.frames == 0 {
            return Some(Trajectories {
                frame_interval: plan.frame_interval,
                states: vec![],
                lights: vec![],
                events: vec![],
                confounder_changes: vec![],
                interactions: vec![],
            });
        }
        let steps = (plan.frame_interval / MAX_STEP).ceil().max(1.0) as usize;
        let dt = plan.frame_interval / steps as f64;
        let mut states = Vec::with_capacity(plan.frames as usize);
        let mut lights = Vec::with_capacity(plan.frames as usize);
        let mut interactions = Vec::with_capacity(plan.frames as usize);
        let twins = light_twins(&city.lights.lights);
        for frame in 0..plan.frames as usize {
            if stop.load(Ordering::Relaxed) {
                return None;
            }
            if frame > 0 {
                for k in 0..steps {
                    sim.step(Sim::step_time((frame - 1) * steps + k, steps, plan.frame_interval, dt), dt);
                }
            }
            let t = frame as f64 * plan.frame_interval;
            sim.advance_actuated(t);
            // Interventions due now show in this frame's record (lights).
            sim.fire_interventions(t, dt);
            states.push(sim.cars.iter().map(SimCar::state).collect());
            interactions.push(sim.cars.iter().map(|c| c.binding).collect());
            lights.push(sim.light_states(&twins, t));
        }
        // A change shows from the first frame at or after it.
        let confounder_changes = sim
            .confounder_changes
            .iter()
            .map(|&(t, c)| (((t / plan.frame_interval) - 1e-9).ceil().max(0.0) as usize, c))
            .collect();
        Some(Trajectories {
            frame_interval: plan.frame_interval,
            states,
            lights,
            events: std::mem::take(&mut sim.events),
            confounder_changes,
            interactions,
        })
    }

    /// Every light's state at time `t` (seconds), a light with a twin
    /// ([`light_twins`]) copying the twin's when neither an intervention nor
    /// a detector can set them apart.
    fn light_states(&self, twins: &[usize], t: f64) -> Vec<LightState> {
        let planned = self.light_overrides.is_empty() && self.light_plans.is_empty() && self.actuation.is_empty();
        let mut states: Vec<LightState> = Vec::with_capacity(twins.len());
        for (l, &twin) in twins.iter().enumerate() {
            let state = if planned && twin < l { states[twin] } else { self.light_state(l, t) };
            states.push(state);
        }
        states
    }
}

/// For each light, the first light with the same offset and schedule (the
/// light itself when none comes before it): such lights show the same
/// states. Towns whose junctions share a clock have many (a 2 x 2 town
/// with equal offsets: 8 of 32), and the per-frame record looked every
/// light up, 14 % of a plain simulation's instructions.
fn light_twins(lights: &[Light]) -> Vec<usize> {
    (0..lights.len())
        .map(|l| {
            let same = |m: &usize| lights[*m].offset == lights[l].offset && lights[*m].schedule == lights[l].schedule;
            (0..l).find(same).unwrap_or(l)
        })
        .collect()
}

/// A running simulation: the cars, what interventions changed so far (lights,
/// confounders), who occupies which track, and the events logged.
struct Sim<'a> {
    map: &'a CityMap,
    plan: &'a ScenarioPlan,
    city: &'a CityPlan,
    model: &'a dyn CarFollowing,
    /// In plan (id) order.
    cars: Vec<SimCar<'a>>,
    events: Vec<Event>,
    /// Interventions still waiting for their trigger.
    pending: Vec<&'a Intervention>,
    /// Lights forced by interventions: (light, colour, from, until), seconds.
    light_overrides: Vec<(usize, Colour, f64, f64)>,
    /// Lights given a new plan by interventions: (light, plan, from), seconds.
    light_plans: Vec<(usize, Light, f64)>,
    /// The programmes whose phases detected cars extend.
    actuation: actuation::Actuation<'a>,
    /// The confounders now, and the changes interventions made (time, values).
    confounders: Confounders,
    confounder_changes: Vec<(f64, Confounders)>,
    /// The confounders' model now (interventions hold what they set).
    confounder_model: ConfounderModel,
    /// Per track (lane or connector): (car, arc length on the track, metres).
    occupancy: Vec<Vec<(usize, f64)>>,
    /// The tracks of `occupancy` that hold a car (each once), so filling it
    /// again clears only those: a big town has thousands of tracks.
    occupied: Vec<usize>,
    /// Pairs of cars (i < j) in contact since a collision.
    contacts: BTreeSet<(usize, usize)>,
    /// Time of the last frame, seconds: re-planned routes must last until then.
    horizon: f64,
    /// While set, the tracks each decision reads, each with the position
    /// along it from which on what it finds there can matter (see
    /// `perception::occupants_from`).
    reads: Option<RefCell<Vec<(usize, f64)>>>,
    /// A factual run for effects re-runs records here (`replay.rs`).
    tape: Option<Box<replay::Tape<'a>>>,
    /// A re-run's cars replayed from the tape rather than simulated.
    frozen: Vec<bool>,
    /// The cars not `frozen`, in car order (a re-run's steps walk these,
    /// not every car).
    live: Vec<usize>,
    /// While a re-run brings a replayed car up to date: its leader's
    /// changes reach its followers through their own snapshots instead.
    quiet_followers: bool,
    /// A re-run's cause whose drive queue the intervention replaced, replayed
    /// until the part of its route it reads changes (`replay.rs`).
    deferred: Option<Box<replay::Deferred<'a>>>,
    /// Buffers the collision checks reuse from step to step (no allocation
    /// per step): near points, candidate pairs, the sweep's extents and the
    /// footprints computed.
    scratch_points: Vec<Option<(DVec2, f64)>>,
    scratch_pairs: Vec<(usize, usize)>,
    scratch_extents: Vec<(usize, DVec2, f64)>,
    scratch_boxes: Vec<Option<crate::geometry::OrientedBox>>,
}

impl<'a> Sim<'a> {
    /// Every car of `plan` at its spawn point at its start speed, nothing fired yet.
    fn new(map: &'a CityMap, plan: &'a ScenarioPlan, city: &'a CityPlan, model: &'a dyn CarFollowing) -> Sim<'a> {
        let cars =
            plan.cars.iter().zip(&city.agency).map(|(c, agency)| SimCar::new(c, agency, city.sim_stream)).collect();
        let mut sim = Sim::with_cars(map, plan, city, model, cars);
        // What planning adapted shows at the start.
        for i in 0..sim.cars.len() {
            sim.log_adaptations(i, 0.0);
        }
        sim.settle_start_speeds();
        sim
    }

    /// `plan` with its cars as `cars`, nothing fired yet, no one in the
    /// occupancy: [`Sim::new`] before the cars' start is settled.
    fn with_cars(
        map: &'a CityMap,
        plan: &'a ScenarioPlan,
        city: &'a CityPlan,
        model: &'a dyn CarFollowing,
        cars: Vec<SimCar<'a>>,
    ) -> Sim<'a> {
        Sim {
            map,
            plan,
            city,
            model,
            cars,
            events: Vec::new(),
            pending: plan.interventions.iter().collect(),
            light_overrides: Vec::new(),
            light_plans: Vec::new(),
            actuation: actuation::Actuation::new(
                &city.lights.actuated,
                city.lights.lights.len(),
                map.lanes.len(),
                |l| city.lights.lights[l].state_at(0.0),
            ),
            confounders: city.confounders,
            confounder_changes: Vec::new(),
            confounder_model: city.confounder_model,
            occupancy: vec![Vec::new(); map.track_count()],
            occupied: Vec::new(),
            contacts: BTreeSet::new(),
            horizon: plan.frames.saturating_sub(1) as f64 * plan.frame_interval,
            reads: None,
            tape: None,
            frozen: vec![false; plan.cars.len()],
            live: (0..plan.cars.len()).collect(),
            quiet_followers: false,
            deferred: None,
            scratch_points: Vec::new(),
            scratch_pairs: Vec::new(),
            scratch_extents: Vec::new(),
            scratch_boxes: Vec::new(),
        }
    }

    /// One step from `t` to `t + dt` seconds: interventions, re-plans, who is
    /// where, the decisions due, motion, then collisions.
    fn step(&mut self, t: f64, dt: f64) {
        self.advance_actuated(t);
        self.fire_interventions(t, dt);
        for i in 0..self.cars.len() {
            if self.cars[i].pending_actions.is_some() {
                self.replace_actions(i, t);
            }
        }
        // Only decisions read the occupancy: a step in which no driver
        // decides needs none (a factual run taped for effects notes it
        // every step).
        let deciding = self.cars.iter().any(|c| !c.removed && t + 1e-9 >= c.next_decision);
        if deciding || self.tape.is_some() {
            self.fill_occupancy();
        }
        self.note_fill();
        for i in 0..self.cars.len() {
            if self.cars[i].removed {
                continue;
            }
            if t + 1e-9 >= self.cars[i].next_decision {
                if let Some(reads) = &self.reads {
                    reads.borrow_mut().clear();
                }
                self.decide(i, t, dt);
                self.cars[i].next_decision = t + self.cars[i].driver.reaction_time;
                self.note_decision(i);
            }
        }
        for i in 0..self.cars.len() {
            if !self.cars[i].removed {
                self.advance(i, t, dt);
            }
        }
        self.detect_collisions(t + dt);
        self.note_step_end();
    }

    /// Brings the actuated programmes to time `t`, the cars where they are now.
    /// A car changing lanes is on both.
    fn advance_actuated(&mut self, t: f64) {
        if self.actuation.is_empty() {
            return;
        }
        let cars = self.cars.iter().filter(|c| !c.removed).flat_map(|c| {
            let leg = &c.route.legs[c.leg];
            let along = c.s - leg.route_start;
            let length = c.plan.length;
            match leg.kind {
                LegKind::Lane(lane) => [Some((lane, leg.curve_start + along, length)), None],
                LegKind::LaneChange { from, to, at } => {
                    [Some((from, at + along, length)), Some((to, at + along, length))]
                }
                LegKind::Connector(_) => [None, None],
            }
            .into_iter()
            .flatten()
        });
        self.actuation.advance(t, cars);
    }

    /// The time at which global step `k` starts (steps of `dt` seconds,
    /// `steps` per frame), as the frame loop computes it.
    fn step_time(k: usize, steps: usize, frame_interval: f64, dt: f64) -> f64 {
        (k / steps) as f64 * frame_interval + (k % steps) as f64 * dt
    }
}
