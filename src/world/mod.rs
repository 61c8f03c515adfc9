//! Worlds turn a scenario plan into trajectories: the pose of every car at
//! every frame, in metres and radians. A world never sees pixels or files.

pub mod city;
pub mod driver;
pub mod effects;
pub mod rerun;
pub mod toy;

use crate::map::signals::LightState;
use crate::map::CityMap;
use crate::plan::confounders::Confounders;
use crate::plan::{ScenarioPlan, WorldPlan};
use glam::DVec2;
use std::sync::atomic::AtomicBool;

/// A car's state at one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CarState {
    /// Centre of the car on the ground, metres.
    pub position: DVec2,
    /// Height of the car's reference point above the ground, metres.
    pub z: f64,
    pub roll: f64,
    pub pitch: f64,
    /// Heading, radians counter-clockwise from east.
    pub yaw: f64,
    /// Speed along the path, metres per second.
    pub speed: f64,
}

/// Where removed cars are parked, far off every camera, metres.
const PARKING: DVec2 = DVec2::new(10_000.0, 10_000.0);

impl CarState {
    /// A car taken off the map by an intervention: parked far off every
    /// camera (each car on its own spot), at rest.
    pub fn parked(id: u32) -> CarState {
        let position = PARKING + DVec2::new(10.0 * id as f64, 0.0);
        CarState { position, z: 0.0, roll: 0.0, pitch: 0.0, yaw: 0.0, speed: 0.0 }
    }

    /// Whether this is car `id`'s state once removed (exactly its parking
    /// spot, at rest): no camera draws it or sees it. (A position alone
    /// could be a real car's: a network may span 1,000 km.)
    pub fn is_parked(&self, id: u32) -> bool {
        *self == CarState::parked(id)
    }

    /// Whether a logged position (metres, as poses.csv rounds it) is a
    /// removed car's parking spot rather than a place on the map.
    pub fn is_parked_at(x: f64, y: f64) -> bool {
        (y - PARKING.y).abs() < 0.5 && x > PARKING.x - 0.5
    }
}

#[cfg(test)]
mod parked_tests {
    use super::*;

    #[test]
    fn only_a_removed_cars_own_parking_state_is_parked() {
        let parked = CarState::parked(3);
        assert!(parked.is_parked(3));
        assert!(!parked.is_parked(4), "another car's spot");
        // A real car driving through the parking band of a network that
        // large (SUMO networks may span 1,000 km) is on the map.
        let driving = CarState { speed: 8.0, yaw: 0.3, ..parked };
        assert!(!driving.is_parked(3));
        assert!(CarState::is_parked_at(driving.position.x, driving.position.y), "the band alone would say parked");
    }
}

/// Something that happened during a scenario, for `events.csv`.
#[derive(Debug, Clone, PartialEq)]
pub struct Event {
    /// Seconds since the start.
    pub t: f64,
    pub kind: EventKind,
    /// Car id; `None` for events of no car (a light or the weather changed).
    pub car: Option<u32>,
    /// The other car involved (collisions).
    pub other: Option<u32>,
    /// The light involved (light interventions), by index in the light plan.
    pub light: Option<usize>,
    pub detail: String,
}

/// Kinds of [`Event`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EventKind {
    Collision,
    RedLightRun,
    MergeDone,
    TurnDone,
    ActionsFinished,
    /// An intervention of the scenario fired.
    Intervention,
    /// A lane change the driver chose to reach the lane a turn needs.
    LaneChange,
    /// An action carried out otherwise than written (a merge moved).
    ActionAdapted,
    /// An action not carried out (no lane, no room, no gap).
    ActionSkipped,
}

impl EventKind {
    /// Every kind (`data-schema/events.schema.json` lists the same names).
    pub const ALL: [EventKind; 9] = [
        EventKind::Collision,
        EventKind::RedLightRun,
        EventKind::MergeDone,
        EventKind::TurnDone,
        EventKind::ActionsFinished,
        EventKind::Intervention,
        EventKind::LaneChange,
        EventKind::ActionAdapted,
        EventKind::ActionSkipped,
    ];

    pub fn name(self) -> &'static str {
        match self {
            EventKind::Collision => "collision",
            EventKind::RedLightRun => "red_light_run",
            EventKind::MergeDone => "merge_done",
            EventKind::TurnDone => "turn_done",
            EventKind::ActionsFinished => "actions_finished",
            EventKind::Intervention => "intervention",
            EventKind::LaneChange => "lane_change",
            EventKind::ActionAdapted => "action_adapted",
            EventKind::ActionSkipped => "action_skipped",
        }
    }
}

/// What bound a city car's speed choice: the constraint that gave the
/// lowest target speed at its latest decision.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BoundBy {
    /// Nothing but its own desired speed.
    Free,
    /// The car ahead on its path.
    Car,
    /// A stop line at a red or yellow light.
    Light,
    /// A car still crossing the intersection on a conflicting movement.
    Conflict,
    /// Waiting for a lane-change gap.
    Merge,
    /// A curve ahead.
    Curve,
    /// Standing after a collision.
    Collision,
    /// Held by an intervention (stopped, or removed).
    Intervention,
    /// Giving way, at a junction without lights, to a car with the right
    /// of way.
    GiveWay,
    /// Stopping at an all-way stop's line.
    StopLine,
}

impl BoundBy {
    pub fn name(self) -> &'static str {
        match self {
            BoundBy::Free => "free",
            BoundBy::Car => "car",
            BoundBy::Light => "light",
            BoundBy::Conflict => "conflict",
            BoundBy::Merge => "merge",
            BoundBy::Curve => "curve",
            BoundBy::Collision => "collision",
            BoundBy::Intervention => "intervention",
            BoundBy::GiveWay => "give_way",
            BoundBy::StopLine => "stop_line",
        }
    }

    /// Every kind, in the order of `data-schema/interactions.schema.json`.
    pub const ALL: [BoundBy; 10] = [
        BoundBy::Free,
        BoundBy::Car,
        BoundBy::Light,
        BoundBy::Conflict,
        BoundBy::Merge,
        BoundBy::Curve,
        BoundBy::Collision,
        BoundBy::Intervention,
        BoundBy::GiveWay,
        BoundBy::StopLine,
    ];

    /// The kind `interactions.csv` spells `name`.
    pub fn from_name(name: &str) -> Option<BoundBy> {
        BoundBy::ALL.into_iter().find(|b| b.name() == name)
    }
}

/// One car's binding constraint at one frame, with the other car or the
/// light it names (light index in the scenario's light plan).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Interaction {
    pub bound_by: BoundBy,
    pub other_car: Option<u32>,
    pub light: Option<usize>,
}

impl Interaction {
    pub const FREE: Interaction = Interaction { bound_by: BoundBy::Free, other_car: None, light: None };
}

/// The simulated scenario: `states[frame][car]`, cars in plan (id) order.
#[derive(Debug, Clone)]
pub struct Trajectories {
    pub frame_interval: f64,
    pub states: Vec<Vec<CarState>>,
    /// `lights[frame][light]`, in the order of the scenario's light plan; empty without lights.
    pub lights: Vec<Vec<LightState>>,
    /// In time order.
    pub events: Vec<Event>,
    /// Confounder changes made by interventions: (first frame, new values),
    /// in order; empty when the scenario's confounders hold throughout.
    pub confounder_changes: Vec<(usize, Confounders)>,
    /// City world: `interactions[frame][car]`, what bound each car's speed
    /// choice at its latest decision; empty for the toy world.
    pub interactions: Vec<Vec<Interaction>>,
}

/// Deceleration above which a driver is on the brake, m/s^2: below it a car
/// slows by rolling resistance, drag and engine braking alone, about 0.2-0.5
/// m/s^2 for a car in gear at city speeds; the lower end, as the default city
/// is slowed.
pub const BRAKE_LIGHT_DECELERATION: f64 = 0.2;
/// Speed under which a car counts as standing (and holds its brake), m/s.
pub const HOLDING_SPEED: f64 = 0.05;

impl Trajectories {
    pub fn frames(&self) -> usize {
        self.states.len()
    }

    /// Whether `car`'s brake lights are on at `frame`: it slowed by more than
    /// [`BRAKE_LIGHT_DECELERATION`] since the frame before, or it stands.
    pub fn braking(&self, frame: usize, car: usize) -> bool {
        let now = self.states[frame][car].speed;
        let slowed =
            frame > 0 && self.states[frame - 1][car].speed - now > BRAKE_LIGHT_DECELERATION * self.frame_interval;
        slowed || now < HOLDING_SPEED
    }
}

/// Simulates a plan in its world: the toy world's constant speed, or the
/// city world with the plan's car-following model.
pub fn simulate(map: &CityMap, plan: &ScenarioPlan) -> Trajectories {
    let never = AtomicBool::new(false);
    simulate_until(map, plan, &never).expect("a simulation that is never stopped finishes")
}

/// [`simulate`], giving up (`None`) at the first frame at which `stop` is
/// set: a long scenario (100,000 frames of 80 cars take seconds) must not
/// hold up an interrupted run.
pub fn simulate_until(map: &CityMap, plan: &ScenarioPlan, stop: &AtomicBool) -> Option<Trajectories> {
    match &plan.world {
        WorldPlan::Toy { step_m } => toy::simulate(map, plan, *step_m, stop),
        WorldPlan::City(city) => city::simulate_with(driver::model_by_name(city.driver_model), map, plan, city, stop),
    }
}

/// Name of a world's behaviour model, for scenario.json.
pub fn model_name(world: &WorldPlan) -> &'static str {
    match world {
        WorldPlan::Toy { .. } => toy::MODEL_NAME,
        WorldPlan::City(city) => driver::model_by_name(city.driver_model).name(),
    }
}
