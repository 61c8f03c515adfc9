//! Scenario plans: everything about a scenario that is fixed before it is
//! simulated (cars, routes, roles, the city's lights, confounders and
//! drivers, interventions, extra cameras). Plans are plain data made by
//! [`expand`] from a spec or by the scenario-file reader; worlds simulate
//! them, writers record them. Nothing here knows pixels or files.

pub mod confounders;
pub mod expand;
pub mod interventions;

use crate::camera::CameraPlan;
use crate::map::signals::LightPlan;
use crate::map::{Action, LaneId, Route};
use crate::spec::{DriverModel, DriverParams, DrivingRules, SignalHeads, Split, WorldKind};
use confounders::{ConfounderModel, Confounders, Effects};
use interventions::Intervention;
use serde::Serialize;
use sha2::{Digest, Sha256};
use std::sync::Arc;

pub use expand::{Expansion, KeySequence};

/// A car's part in the causal graph.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    Leader,
    Follower,
    Independent,
    /// Colliders: a car a follower must give way to at its first junction
    /// (a designed edge to that follower), driving a queue of its own.
    Priority,
}

/// Where one scenario sits in the dataset.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct ScenarioKey {
    pub group: String,
    pub group_index: usize,
    pub split: Split,
    pub index: u32,
    /// Hand-written scenarios: the scenario's own name.
    pub name: Option<String>,
}

impl ScenarioKey {
    /// Its folder relative to the dataset, `<group>/<split>/<folder name>`
    /// (`cars08_edges50/train/00042`), as pack members name it too.
    pub fn relative_folder(&self) -> String {
        format!("{}/{}/{}", self.group, self.split.name(), self.folder_name())
    }

    /// Folder name of the scenario, e.g. `00042` (or a hand-written
    /// scenario's name).
    pub fn folder_name(&self) -> String {
        match &self.name {
            Some(name) => name.clone(),
            None => format!("{:05}", self.index),
        }
    }
}

/// Everything about one car that is fixed before simulation.
#[derive(Debug, Clone)]
pub struct CarPlan {
    /// 0-based, randomly permuted per scenario so the index hides the role.
    pub id: u32,
    pub name: String,
    /// A colour the scenario file gave; otherwise the renderer's palette
    /// colours the car by id.
    pub colour: Option<[u8; 3]>,
    /// Value of this car's pixels in the instance masks (id + 1).
    pub mask_id: u8,
    pub spawn: LaneId,
    pub spawn_name: String,
    /// Metres along the spawn lane where the car starts.
    pub spawn_distance: f64,
    pub actions: Vec<Action>,
    /// Metres along the current lane for merges, 0 for other actions.
    pub merge_distances: Vec<f64>,
    pub role: Role,
    pub length: f64,
    pub width: f64,
    /// Shared by a leader and its follower.
    pub route: Arc<Route>,
    /// City world, hard negatives only: the car it starts right behind,
    /// looking like its follower, though not linked to it.
    pub hard_negative_behind: Option<u32>,
    /// Followers: the id of the car it follows, taking the turns and merges
    /// its leader takes (see [`Fallback`] for when it loses it).
    pub leader: Option<u32>,
    /// Colliders' followers: the id of the car with priority it must give
    /// way to at its first junction (the world's rules make it do so).
    pub gives_way_to: Option<u32>,
    /// Followers: what the car does if its leader leaves the scene.
    pub on_leader_lost: Option<OnLeaderLost>,
}

/// What a follower does once it has lost its leader (the leader was
/// removed). While its leader is in the scene a follower drives what its
/// leader drives: a red light between them does not make it lose its leader
/// (it has seen where the leader went), and when the leader's remaining
/// actions change, so do the follower's.
#[derive(Debug, Clone)]
pub enum OnLeaderLost {
    /// It stops where it is and stays (the toy world: no agency, so a
    /// follower goes only where its leader goes).
    Stop,
    /// It drives a queue of its own (the city world: agency), carried on
    /// from the actions it has done so far.
    Drive(Fallback),
}

/// A follower's own drive queue, from the same start as its leader's.
#[derive(Debug, Clone)]
pub struct Fallback {
    pub actions: Vec<Action>,
    /// Metres along the current lane for merges, 0 for other actions.
    pub merge_distances: Vec<f64>,
}

/// A city car's driving plan, its own (a follower shares its leader's route
/// and actions, not its driving).
#[derive(Debug, Clone, PartialEq)]
pub struct CarAgency {
    /// Desired speed (m/s, after confounders) before the first action, after
    /// each action in turn, and after the last.
    pub desired_speeds: Vec<f64>,
    /// Speed the driver would like to start at, m/s; the world lowers it to
    /// what the driver sees ahead at the start.
    pub start_speed: f64,
    /// After confounders.
    pub driver: DriverParams,
    /// Forced through red and yellow lights.
    pub runs_red_lights: bool,
}

/// City-world parts of a scenario.
#[derive(Debug, Clone)]
pub struct CityPlan {
    pub confounders: Confounders,
    /// The confounders' exogenous draws and which equations set them.
    pub confounder_model: ConfounderModel,
    pub effects: Effects,
    pub lights: LightPlan,
    /// Base driver parameters before confounders.
    pub base_driver: DriverParams,
    /// The drivers' car-following model.
    pub driver_model: DriverModel,
    /// Key of the simulation's own random stream (driver noise, collision stops).
    pub sim_stream: [u8; 32],
    /// How each car drives, in id order.
    pub agency: Vec<CarAgency>,
    /// Whether frames draw the signal heads.
    pub signal_heads: SignalHeads,
    /// The original's driving rules, or the cooperative ones.
    pub rules: DrivingRules,
}

/// The world a scenario runs in, with what only that world needs.
// One plan per scenario in flight, never stored in bulk: boxing buys nothing.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone)]
pub enum WorldPlan {
    /// No agency: every car covers `step_m` metres per frame.
    Toy { step_m: f64 },
    /// Agency: lights, confounders and each car's driving.
    City(CityPlan),
}

impl WorldPlan {
    pub fn kind(&self) -> WorldKind {
        match self {
            WorldPlan::Toy { .. } => WorldKind::Toy,
            WorldPlan::City(_) => WorldKind::City,
        }
    }

    /// The city parts, for a city scenario.
    pub fn city(&self) -> Option<&CityPlan> {
        match self {
            WorldPlan::City(city) => Some(city),
            WorldPlan::Toy { .. } => None,
        }
    }
}

/// One scenario, ready to simulate.
#[derive(Debug, Clone)]
pub struct ScenarioPlan {
    pub key: ScenarioKey,
    pub world: WorldPlan,
    pub seed: u64,
    /// Hex of the 32-byte key of the scenario's random stream.
    pub stream_key: String,
    pub frames: u32,
    pub frame_interval: f64,
    /// Cars in id order.
    pub cars: Vec<CarPlan>,
    /// (leader id, follower id) pairs.
    pub edges: Vec<(u32, u32)>,
    /// City world only: interventions applied while simulating (none for
    /// `gen`; hand-written scenarios and counterfactuals name them).
    pub interventions: Vec<Intervention>,
    /// Extra cameras (hand-written scenarios; none for `gen`).
    pub cameras: Vec<CameraPlan>,
    /// How the bird's-eye frames are drawn.
    pub birds_eye: crate::spec::BirdsEyeView,
    /// The town it happens on, when the dataset has several (`None`: the
    /// dataset's only town).
    pub town: Option<PlannedTown>,
}

impl ScenarioPlan {
    /// Its town's place in [`expand::Expansion::towns`] (0: the only one).
    pub fn town_index(&self) -> usize {
        self.town.as_ref().map_or(0, |t| t.index)
    }
}

/// The town a scenario of a many-town dataset happens on.
#[derive(Debug, Clone, PartialEq)]
pub struct PlannedTown {
    /// Its place in [`expand::Expansion::towns`].
    pub index: usize,
    /// Its name ([`crate::spec::MapSpec::town_name`]).
    pub name: String,
    /// Its map section, with nothing left to draw: enough to rebuild it.
    pub map: crate::spec::MapSpec,
}

/// A car of a hand-written scenario: where it starts, what it does, and
/// optional driving overrides (city world).
#[derive(Debug, Clone)]
pub struct GivenCar {
    pub name: String,
    pub spawn: LaneId,
    pub spawn_distance: f64,
    pub actions: Vec<Action>,
    pub merge_distances: Vec<f64>,
    pub route: Arc<Route>,
    /// Desired speed per leg (m/s), used as given.
    pub desired_speeds: Option<Vec<f64>>,
    pub time_headway: Option<f64>,
    pub runs_red_lights: Option<bool>,
    pub colour: Option<[u8; 3]>,
}

/// The 32-byte key of a scenario's random stream.
pub fn stream_key(seed: u64, group: &str, split: Split, index: u32) -> [u8; 32] {
    let mut h = Sha256::new();
    h.update(b"causalcity/scenario/v1\0");
    h.update(seed.to_le_bytes());
    h.update(group.as_bytes());
    h.update([0u8]);
    h.update(split.name().as_bytes());
    h.update([0u8]);
    h.update(index.to_le_bytes());
    h.finalize().into()
}
