//! The toy world: no agency. Every car moves the same fixed distance per frame
//! along its route; there are no lights and cars pass through each other. A
//! follower drives its leader's route (the turns and merges its leader
//! takes), so its pose at frame t is its leader's pose at frame t - gap /
//! step; if its leader is removed it stops (it has no agency to go anywhere
//! of its own), as its plan's `on_leader_lost` says.
//!
//! Interventions act from the start (time 0), as the interventional re-runs
//! of [`super::effects`] use them: `Remove` takes a car off the map and
//! `ReplaceActions` re-plans its route from its start. Other effects need
//! agency and change nothing here (scenario files refuse toy interventions).

use super::rerun::RerunFrames;
use super::{CarState, Trajectories};
use crate::map::{Action, CityMap, LanePolicy, Route};
use crate::plan::interventions::Effect;
use crate::plan::{CarPlan, OnLeaderLost, ScenarioPlan};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// Name of the toy world's behaviour model, for scenario.json.
pub const MODEL_NAME: &str = "constant-speed";

/// What a toy car drives once the interventions are applied.
enum Drive {
    Route(Arc<Route>),
    /// Standing at its start (a follower that lost its leader).
    Stopped,
    Removed,
}

/// Every car of `plan` moves `step` metres per frame along its route;
/// `None` once `stop` is set (checked every frame).
pub fn simulate(map: &CityMap, plan: &ScenarioPlan, step: f64, stop: &AtomicBool) -> Option<Trajectories> {
    let speed = step / plan.frame_interval;
    let drives = drives(map, plan);
    let states = (0..plan.frames)
        .map(|frame| {
            if stop.load(Ordering::Relaxed) {
                return None;
            }
            Some(plan.cars.iter().zip(&drives).map(|(car, drive)| state(car, drive, frame, step, speed)).collect())
        })
        .collect::<Option<_>>()?;
    Some(Trajectories {
        frame_interval: plan.frame_interval,
        states,
        lights: Vec::new(),
        events: Vec::new(),
        confounder_changes: Vec::new(),
        interactions: Vec::new(),
    })
}

/// An effects re-run of `changed` (`plan` with interventions added) that
/// simulates only the cars whose drive the interventions changed (the
/// intervened car, and the followers whose chain of leaders reaches it);
/// every other car's frames are `factual`'s, which must be `plan`'s
/// simulation. The same frames as [`simulate`] on `changed`, bit for bit: a
/// toy car's pose depends on its drive alone. `None` once `stop` is set.
pub fn rerun<'r>(
    map: &CityMap,
    plan: &ScenarioPlan,
    changed: &ScenarioPlan,
    factual: &'r Trajectories,
    step: f64,
    stop: &AtomicBool,
) -> Option<RerunFrames<'r>> {
    let speed = step / changed.frame_interval;
    let before = drives(map, plan);
    let after = drives(map, changed);
    let reached: Vec<usize> = (0..changed.cars.len()).filter(|&i| !same_drive(&before[i], &after[i])).collect();
    let mut run = RerunFrames::new(factual, changed.cars.len());
    for frame in 0..factual.states.len() {
        if stop.load(Ordering::Relaxed) {
            return None;
        }
        for &i in &reached {
            run.push(i, frame, state(&changed.cars[i], &after[i], frame as u32, step, speed), None);
        }
    }
    Some(run)
}

/// Whether two drives move a car alike at every frame: the same route (one
/// shared route, not merely an equal one), or both standing or removed.
fn same_drive(a: &Drive, b: &Drive) -> bool {
    match (a, b) {
        (Drive::Route(a), Drive::Route(b)) => Arc::ptr_eq(a, b),
        (Drive::Stopped, Drive::Stopped) | (Drive::Removed, Drive::Removed) => true,
        _ => false,
    }
}

/// Car `car`'s state at `frame` on `drive`, moving `step` metres per frame
/// at `speed` (m/s).
fn state(car: &CarPlan, drive: &Drive, frame: u32, step: f64, speed: f64) -> CarState {
    match drive {
        Drive::Removed => CarState::parked(car.id),
        Drive::Stopped => {
            let (position, yaw) = car.route.pose_at(car.spawn_distance, 0.0);
            CarState { position, z: 0.0, roll: 0.0, pitch: 0.0, yaw, speed: 0.0 }
        }
        Drive::Route(route) => {
            let s = car.spawn_distance + step * frame as f64;
            let (position, yaw) = route.pose_at(s, 0.0);
            CarState { position, z: 0.0, roll: 0.0, pitch: 0.0, yaw, speed }
        }
    }
}

/// Each car's route (in id order) after the plan's interventions: its own,
/// re-planned where its actions were replaced; a follower's is its leader's
/// (unless its own actions were replaced), or its fallback's once the leader
/// is removed.
fn drives(map: &CityMap, plan: &ScenarioPlan) -> Vec<Drive> {
    let mut own: Vec<Drive> = plan.cars.iter().map(|c| Drive::Route(c.route.clone())).collect();
    let mut replaced = vec![false; plan.cars.len()];
    for intervention in &plan.interventions {
        match &intervention.effect {
            Effect::Remove { car } => own[*car] = Drive::Removed,
            Effect::ReplaceActions { car, actions, merge_distances } => {
                // Actions that cannot be driven leave the car on its own route.
                let planned = route_from_start(map, &plan.cars[*car], actions, merge_distances);
                if let (Some(route), Drive::Route(_)) = (planned, &own[*car]) {
                    own[*car] = Drive::Route(route);
                    replaced[*car] = true;
                }
            }
            _ => {}
        }
    }
    (0..plan.cars.len())
        .map(|i| {
            if matches!(own[i], Drive::Removed) {
                return Drive::Removed;
            }
            // Along the chain of leaders; no plan has a cycle, but a chain
            // longer than the cars would be one, and ends there.
            let mut current = i;
            for _ in 0..plan.cars.len() {
                let c = &plan.cars[current];
                let Some(leader) = c.leader.map(|l| l as usize).filter(|_| !replaced[current]) else { break };
                match (&own[leader], &c.on_leader_lost) {
                    (Drive::Removed, Some(OnLeaderLost::Drive(f))) => {
                        // A queue that cannot be driven leaves it on its leader's route.
                        match route_from_start(map, c, &f.actions, &f.merge_distances) {
                            Some(route) => return Drive::Route(route),
                            None => break,
                        }
                    }
                    (Drive::Removed, Some(OnLeaderLost::Stop)) => return Drive::Stopped,
                    (Drive::Removed, None) => break,
                    (Drive::Route(_) | Drive::Stopped, _) => current = leader,
                }
            }
            match &own[current] {
                Drive::Route(route) => Drive::Route(route.clone()),
                Drive::Stopped => Drive::Stopped,
                Drive::Removed => Drive::Removed,
            }
        })
        .collect()
}

/// The route of `actions` from `car`'s start, as long as its own; `None`
/// when they cannot be driven.
fn route_from_start(map: &CityMap, car: &CarPlan, actions: &[Action], merges: &[f64]) -> Option<Arc<Route>> {
    let length = car.route.length;
    Route::plan(map, car.spawn, car.spawn_distance, actions, merges, length, &LanePolicy::Adapt).ok().map(Arc::new)
}
