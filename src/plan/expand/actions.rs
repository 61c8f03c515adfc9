//! The drive queues drawn for a car: the original generator's, or only
//! what each lane allows.

use crate::map::{Action, CityMap, LaneEnd, LaneId};
use rand::RngExt;
use rand_chacha::ChaCha8Rng;

/// Chance that a lane-valid drawn action is a merge, where one fits.
const MERGE_SHARE: f64 = 0.25;

/// A random drive queue drawn as the original's `scenarioGenerator.py`
/// draws it, whatever lane the car will be in: each action `left`, `right`
/// or `straight` with equal chance (and, at a junction of five arms or
/// more, `slight_left` and `slight_right` where the road has them). (The
/// original writes merge names only into `MergeAtDistances`, where its
/// engine never carried them out, so no merges are drawn.) Drivers plan
/// the lane changes their turns need.
///
/// On a town with T-junctions, a movement that no lane of the road has at
/// the junction the action applies to is drawn again among those it has
/// (on a full grid every junction has every movement, so nothing is drawn
/// again and the queue is the original's draw).
pub(super) fn original_actions(
    rng: &mut ChaCha8Rng,
    map: &CityMap,
    spawn: LaneId,
    count: u32,
) -> (Vec<Action>, Vec<f64>) {
    const DRAWN: [Action; 3] = [Action::Left, Action::Right, Action::Straight];
    let mut lane = spawn;
    let mut queue = Vec::with_capacity(count as usize);
    for _ in 0..count {
        let Some(approach) = past_loop(map, lane) else { break };
        let exit = |a: Action| a.turn().and_then(|turn| road_exit(map, approach, turn));
        // At a junction of five arms or more, the slight turns too.
        let slight = [Action::SlightLeft, Action::SlightRight].into_iter().filter(|&a| exit(a).is_some());
        let drawn: Vec<Action> = DRAWN.into_iter().chain(slight).collect();
        let mut action = drawn[rng.random_range(0..drawn.len())];
        if exit(action).is_none() {
            let possible: Vec<Action> = drawn.into_iter().filter(|&a| exit(a).is_some()).collect();
            if !possible.is_empty() {
                action = possible[rng.random_range(0..possible.len())];
            }
        }
        if let Some(connector) = exit(action) {
            lane = map.connectors[connector].to;
        }
        queue.push(action);
    }
    let merges = vec![0.0; queue.len()];
    (queue, merges)
}

/// The lane a car on `lane` next reaches a junction with a choice on:
/// `lane` itself, or the one its off-camera loop leads to (on an imported
/// network, after any loops and junctions where its road only goes on);
/// `None` on a road that never reaches a choice.
fn past_loop(map: &CityMap, lane: LaneId) -> Option<LaneId> {
    let mut lane = lane;
    for _ in 0..=map.lanes.len() {
        let next = match map.lanes[lane].end {
            LaneEnd::Loop(c) => c,
            LaneEnd::Intersection { .. } if map.has_choice(lane) => return Some(lane),
            LaneEnd::Intersection { .. } => map.exit(lane, map.default_turn(lane))?,
        };
        lane = map.connectors[next].to;
    }
    None
}

/// The connector making `turn` at the end of `lane` or of a lane beside it
/// (the same road, the same direction): the movement a driver on that road
/// can make, changing lanes first if it must.
fn road_exit(map: &CityMap, lane: LaneId, turn: crate::map::Turn) -> Option<usize> {
    map.exit(lane, turn).or_else(|| map.lane_towards(lane, turn).and_then(|l| road_exit(map, l, turn)))
}

/// A valid random drive queue from `lane`, where the first car on the route
/// starts `entry` metres along it. Merges are drawn only where they fit.
pub(super) fn random_actions(
    rng: &mut ChaCha8Rng,
    map: &CityMap,
    spawn: LaneId,
    entry: f64,
    count: u32,
) -> (Vec<Action>, Vec<f64>) {
    let mut lane = spawn;
    let mut earliest = entry;
    let run = map.layout.lane_change_length;
    let mut actions = Vec::new();
    let mut merges = Vec::new();
    for _ in 0..count {
        let len = map.lanes[lane].curve.length();
        // Merge distances on a 0.1 m grid that fits before the lane ends.
        // At least 1 m after the car, so a car can check the gap before it starts.
        let lo = ((earliest + 1.0) * 10.0).ceil() / 10.0;
        let hi = ((len - run) * 10.0).floor() / 10.0;
        let merge_side = map
            .adjacent_lane(lane, true)
            .map(|l| (Action::MergeL, l))
            .or_else(|| map.adjacent_lane(lane, false).map(|l| (Action::MergeR, l)));
        if let (Some((action, target)), true) = (merge_side, lo <= hi) {
            if rng.random_bool(MERGE_SHARE) {
                let at = ((rng.random_range(lo..=hi) * 10.0).round() / 10.0).clamp(lo, hi);
                actions.push(action);
                merges.push(at);
                lane = target;
                earliest = at + run;
                continue;
            }
        }
        // A turn applies at the next intersection with a choice, after any
        // off-camera loop.
        let Some(approach) = past_loop(map, lane) else { break };
        let turns = map.allowed_turns(approach);
        if turns.is_empty() {
            break;
        }
        let turn = turns[rng.random_range(0..turns.len())];
        let action = Action::making(turn);
        actions.push(action);
        merges.push(0.0);
        let connector = map.exit(approach, turn).expect("allowed turn has a connector");
        lane = map.connectors[connector].to;
        earliest = 0.0;
    }
    (actions, merges)
}
