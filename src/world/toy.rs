//! The toy world: no agency. Every car moves the same fixed distance per frame
//! along its route; there are no lights and cars pass through each other, so a
//! follower's pose at frame t is its leader's pose at frame t - gap / step.

use super::{CarState, Trajectories};
use crate::plan::ScenarioPlan;

/// Name of the toy world's behaviour model, for scenario.json.
pub const MODEL_NAME: &str = "constant-speed";

/// Every car of `plan` moves `step` metres per frame along its route.
pub fn simulate(plan: &ScenarioPlan, step: f64) -> Trajectories {
    let speed = step / plan.frame_interval;
    let states = (0..plan.frames)
        .map(|frame| {
            plan.cars
                .iter()
                .map(|car| {
                    let s = car.spawn_distance + step * frame as f64;
                    let (position, yaw) = car.route.pose_at(s, 0.0);
                    CarState { position, z: 0.0, roll: 0.0, pitch: 0.0, yaw, speed }
                })
                .collect()
        })
        .collect();
    Trajectories {
        frame_interval: plan.frame_interval,
        states,
        lights: Vec::new(),
        events: Vec::new(),
        confounder_changes: Vec::new(),
        interactions: Vec::new(),
    }
}
