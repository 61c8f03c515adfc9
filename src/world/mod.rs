//! Worlds turn a scenario plan into trajectories: the pose of every car at
//! every frame, in metres and radians. A world never sees pixels or files.

pub mod toy;

use crate::map::CityMap;
use crate::orchestrate::plan::ScenarioPlan;
use glam::DVec2;

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

/// The simulated scenario: `states[frame][car]`, cars in plan (id) order.
#[derive(Debug, Clone)]
pub struct Trajectories {
    pub frame_interval: f64,
    pub states: Vec<Vec<CarState>>,
}

impl Trajectories {
    pub fn frames(&self) -> usize {
        self.states.len()
    }
}

/// The dynamics of one world.
pub trait World: Sync {
    fn simulate(&self, map: &CityMap, plan: &ScenarioPlan) -> Trajectories;
}
