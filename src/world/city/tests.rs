//! The city simulation driven on tiny hand-made plans of the default map, in
//! the spirit of highway-env's `test_stop_before_obstacle`: a car stops
//! behind a standing car, a queue discharges at green, a merge waits for its
//! gap. Distances in metres, times in seconds, speeds in m/s.

use super::CityWorld;
use crate::map::signals::{Colour, LightPlan, ScheduleStep, Signal};
use crate::map::{Action, CityMap, LaneEnd, LaneId, LanePolicy, Route, Turn};
use crate::plan::confounders::ConfounderModel;
use crate::plan::interventions::{Effect, Intervention, Trigger};
use crate::plan::{CarAgency, CarPlan, CityPlan, Role, ScenarioKey, ScenarioPlan, WorldPlan};
use crate::spec::{DriverParams, Split};
use crate::world::{EventKind, Trajectories};
use rand::SeedableRng;
use std::sync::Arc;

const LENGTH: f64 = 4.0;
const WIDTH: f64 = 1.8;
const FRAME: f64 = 0.2;

/// One car of a test plan: centre `at` metres along lane `lane`, driving
/// `actions` (merges at `merges` metres along their lane) at `desired` m/s.
#[derive(Clone)]
struct Given {
    lane: &'static str,
    at: f64,
    actions: Vec<Action>,
    merges: Vec<f64>,
    desired: f64,
    /// The start speed the plan wishes for, m/s.
    start: f64,
}

fn straight(lane: &'static str, at: f64, desired: f64) -> Given {
    Given { lane, at, actions: vec![], merges: vec![], desired, start: 0.0 }
}

fn lane(map: &CityMap, name: &str) -> LaneId {
    map.lane_by_name(name).unwrap_or_else(|| panic!("no lane {name}"))
}

/// Drivers without perception noise or wander, so distances are exact.
fn driver() -> DriverParams {
    DriverParams { perception_noise: 0.0, lateral_wander: 0.0, ..DriverParams::default() }
}

/// A city plan of `cars` (ids in order) lasting `seconds`, with `lights`.
fn plan(
    map: &CityMap,
    cars: &[Given],
    lights: LightPlan,
    interventions: Vec<Intervention>,
    seconds: f64,
) -> ScenarioPlan {
    let planned = cars
        .iter()
        .enumerate()
        .map(|(i, g)| {
            let spawn = lane(map, g.lane);
            let reach = g.at + (g.desired * seconds * 1.5).max(200.0);
            let route = Route::plan(map, spawn, g.at, &g.actions, &g.merges, reach, &LanePolicy::Adapt)
                .expect("drivable test route");
            CarPlan {
                id: i as u32,
                name: format!("Car_{}", i + 1),
                colour: None,
                mask_id: i as u8 + 1,
                spawn,
                spawn_name: g.lane.to_string(),
                spawn_distance: g.at,
                actions: g.actions.clone(),
                merge_distances: g.merges.clone(),
                role: Role::Independent,
                length: LENGTH,
                width: WIDTH,
                route: Arc::new(route),
                hard_negative_behind: None,
                gives_way_to: None,
                leader: None,
                on_leader_lost: None,
            }
        })
        .collect();
    let agency = cars
        .iter()
        .map(|g| CarAgency {
            desired_speeds: vec![g.desired; g.actions.len() + 1],
            start_speed: g.start,
            driver: driver(),
            runs_red_lights: false,
        })
        .collect();
    let mut clear_noon = rand_chacha::ChaCha8Rng::seed_from_u64(0);
    let (confounders, confounder_model) =
        ConfounderModel::draw(&crate::spec::ConfounderSpec::default(), &mut clear_noon);
    let city = CityPlan {
        confounders,
        confounder_model,
        effects: confounders.effects(),
        lights,
        base_driver: driver(),
        driver_model: crate::spec::DriverModel::Iidm,
        sim_stream: [7; 32],
        agency,
        signal_heads: crate::spec::SignalHeads::Visible,
        rules: crate::spec::DrivingRules::Original,
    };
    ScenarioPlan {
        key: ScenarioKey { group: "test".into(), group_index: 0, split: Split::Test, index: 0, name: None },
        world: WorldPlan::City(city),
        seed: 0,
        stream_key: String::new(),
        frames: (seconds / FRAME) as u32 + 1,
        frame_interval: FRAME,
        cars: planned,
        edges: vec![],
        interventions,
        cameras: vec![],
        town: None,
        birds_eye: crate::spec::BirdsEyeView::Flat,
    }
}

fn simulate(map: &CityMap, plan: &ScenarioPlan) -> Trajectories {
    CityWorld::default().simulate(map, plan, plan.world.city().expect("city plan"))
}

/// The default light plan with the lights governing the end of `lanes`
/// (straight and left) running `schedule` from time 0.
fn lights_with(map: &CityMap, lanes: &[&str], schedule: &[(Colour, f64)]) -> LightPlan {
    let mut lights = LightPlan::cycle(map.signalised(), 1.0, &[]);
    for name in lanes {
        let LaneEnd::Intersection { intersection, approach } = map.lanes[lane(map, name)].end else {
            panic!("{name} does not end at an intersection")
        };
        for signal in [Signal::Straight, Signal::Left] {
            let index = lights.index(intersection, approach, signal, 0).expect("a signalised junction");
            let light = &mut lights.lights[index];
            light.offset = 0.0;
            light.schedule = schedule.iter().map(|&(colour, duration)| ScheduleStep { colour, duration }).collect();
        }
    }
    lights
}

/// Metres along lane `name` and sideways from its centre line of car `car` at `frame`.
fn on_lane(map: &CityMap, traj: &Trajectories, name: &str, frame: usize, car: usize) -> (f64, f64) {
    map.lanes[lane(map, name)].curve.local_coordinates(traj.states[frame][car].position)
}

#[test]
fn a_car_stops_behind_a_standing_car_without_touching_it() {
    let map = CityMap::default();
    // A1w is 36 m long: the standing car's back is 16 m ahead of the other's front.
    let cars = [straight("A1w", 25.0, 0.0), straight("A1w", 5.0, 3.0)];
    let traj = simulate(&map, &plan(&map, &cars, LightPlan::cycle(map.signalised(), 1.0, &[]), vec![], 30.0));
    let min_gap = driver().min_gap;
    let gaps: Vec<f64> =
        traj.states.iter().map(|frame| frame[0].position.distance(frame[1].position) - LENGTH).collect();
    let closest = gaps.iter().copied().fold(f64::INFINITY, f64::min);
    let last = &traj.states[traj.frames() - 1];
    assert!(gaps[0] > 15.9, "the cars start 16 m apart, not {:.2}", gaps[0]);
    assert!(closest > 0.5 * min_gap, "came within {closest:.3} m of the standing car");
    assert!(
        (gaps[gaps.len() - 1] - min_gap).abs() < 0.3,
        "rests {:.3} m behind it, min gap {min_gap}",
        gaps[gaps.len() - 1]
    );
    assert!(last[1].speed < 0.05, "still moving at {:.3} m/s", last[1].speed);
    assert!(last[0].position.distance(traj.states[0][0].position) < 1e-9, "the standing car moved");
    let peak = traj.states.iter().map(|f| f[1].speed).fold(0.0, f64::max);
    assert!(peak > 1.5, "the car never got going (peak {peak:.2} m/s)");
    assert!(traj.events.iter().all(|e| e.kind != EventKind::Collision), "{:?}", traj.events);
}

#[test]
fn a_queue_at_red_discharges_in_order_once_green() {
    let map = CityMap::default();
    let green_at = 5.0;
    let lights = lights_with(&map, &["A1w"], &[(Colour::Red, green_at), (Colour::Green, 100.0)]);
    let setback = map.layout.stop_line_setback;
    let line = map.lanes[lane(&map, "A1w")].curve.length() - setback;
    // Three cars at rest, 1 m apart, the first with its front 0.2 m before the line.
    let spacing = LENGTH + 1.0;
    let cars: Vec<Given> =
        (0..3).map(|k| straight("A1w", line - 0.2 - LENGTH / 2.0 - k as f64 * spacing, 2.0)).collect();
    let traj = simulate(&map, &plan(&map, &cars, lights, vec![], 25.0));
    let t = |frame: usize| frame as f64 * FRAME;
    let mut starts = Vec::new();
    let mut crossings = Vec::new();
    for car in 0..cars.len() {
        let start = (0..traj.frames()).find(|&f| traj.states[f][car].speed > 0.5).map(t);
        let crossed = (0..traj.frames()).find(|&f| on_lane(&map, &traj, "A1w", f, car).0 + LENGTH / 2.0 > line + 0.5);
        starts.push(start.unwrap_or_else(|| panic!("car {car} never moved off")));
        crossings.push(t(crossed.unwrap_or_else(|| panic!("car {car} never crossed the stop line"))));
    }
    assert_eq!(starts.len(), 3);
    assert!(starts[0] >= green_at, "the first car left at {:.1} s, before green at {green_at} s", starts[0]);
    for k in 1..starts.len() {
        assert!(
            starts[k] > starts[k - 1],
            "car {k} moved off at {:.1} s, before the car ahead ({:.1} s)",
            starts[k],
            starts[k - 1]
        );
        assert!(crossings[k] > crossings[k - 1], "car {k} crossed before the car ahead: {crossings:?}");
    }
    // At 2 m/s with 1.2 m/s^2, three cars 5 m apart clear the line well within 15 s.
    assert!(crossings[2] - green_at < 15.0, "queue cleared {:.1} s after green", crossings[2] - green_at);
    assert!(crossings[0] - green_at < 3.0, "the first car took {:.1} s to cross", crossings[0] - green_at);
    assert!(traj.events.iter().all(|e| e.kind != EventKind::Collision && e.kind != EventKind::RedLightRun));
}

#[test]
fn a_merge_waits_until_the_car_beside_has_gone() {
    let map = wide_blocks();
    let lights = lights_with(&map, &["A1x"], &[(Colour::Green, 100.0)]);
    // The merge starts at the last possible place (A1w is 36 m, a merge takes
    // 8 m), so it cannot be moved along: the car must wait for the gap.
    let merge_at = 28.0;
    let merging = Given {
        lane: "A1w",
        at: 15.0,
        actions: vec![Action::MergeL],
        merges: vec![merge_at],
        desired: 2.0,
        start: 0.0,
    };
    // Beside the merge start, a little behind it: not ahead on the merging path.
    let blocker = straight("A1x", 27.0, 0.0);
    let free_at = 14.0;
    let go = Intervention {
        trigger: Trigger::At(free_at),
        effect: Effect::SetDesiredSpeed { car: 1, speed: 3.0 },
        label: "blocker drives off".into(),
    };
    let traj = simulate(&map, &plan(&map, &[merging, blocker], lights, vec![go], 30.0));
    let merged = traj
        .events
        .iter()
        .find(|e| e.kind == EventKind::MergeDone && e.car == Some(0))
        .unwrap_or_else(|| panic!("the merge never happened: {:?}", traj.events));
    assert!(merged.t > free_at, "merged at {:.2} s while the target lane was blocked until {free_at} s", merged.t);
    assert!(merged.t < free_at + 15.0, "merged only at {:.2} s", merged.t);
    // While blocked it stays in its own lane, waiting short of the merge start.
    let blocked: Vec<usize> = (0..traj.frames()).filter(|&f| f as f64 * FRAME <= free_at).collect();
    assert!(blocked.len() > 30);
    for &f in &blocked {
        let (along, sideways) = on_lane(&map, &traj, "A1w", f, 0);
        assert!(sideways.abs() < 0.3, "{:.2} m off its lane centre at {:.1} s", sideways, f as f64 * FRAME);
        assert!(
            along < merge_at + 0.5,
            "{along:.2} m along its lane at {:.1} s, past the merge start",
            f as f64 * FRAME
        );
    }
    let waiting = traj.states[blocked[blocked.len() - 1]][0].speed;
    assert!(waiting < 0.05, "still rolling at {waiting:.2} m/s when the gap opened");
    // When the merge is done the car is on the target lane's centre line.
    let done = ((merged.t / FRAME) - 1e-9).ceil() as usize;
    let (_, sideways) = on_lane(&map, &traj, "A1x", done, 0);
    assert!(sideways.abs() < 0.3, "{sideways:.2} m off the target lane when the merge was done");
    assert!(traj.events.iter().all(|e| e.kind != EventKind::Collision), "{:?}", traj.events);
}

/// A map whose blocks are 48 m wide, so that A1w is 36 m long, with 8 m
/// lane changes.
fn wide_blocks() -> CityMap {
    CityMap::new(crate::map::MapLayout {
        north_south_roads: vec![('C', -24.0), ('D', 24.0)],
        extent_x: 52.0,
        lane_change_length: 8.0,
        ..Default::default()
    })
}

/// A car on A1w (36 m, see [`wide_blocks`]) told to turn left at AD, which needs the inner lane A1x, and
/// a car standing on A1x beside the last point where the change still ends
/// before the stop line; lights on A1x green throughout.
fn wrong_lane_for_a_left_turn(interventions: Vec<Intervention>, seconds: f64) -> Trajectories {
    let map = wide_blocks();
    let lights = lights_with(&map, &["A1x"], &[(Colour::Green, 1000.0)]);
    // Every start from 1 m ahead of the car to the last one overlaps the blocker.
    let turning =
        Given { lane: "A1w", at: 14.0, actions: vec![Action::Left], merges: vec![0.0], desired: 2.0, start: 0.0 };
    let blocker = straight("A1x", 26.0, 0.0);
    simulate(&map, &plan(&map, &[turning, blocker], lights, interventions, seconds))
}

#[test]
fn a_car_changes_into_the_turn_lane_once_the_gap_comes_and_turns_from_it() {
    let free_at = 16.0;
    let go = Intervention {
        trigger: Trigger::At(free_at),
        effect: Effect::SetDesiredSpeed { car: 1, speed: 3.0 },
        label: "blocker drives off".into(),
    };
    let traj = wrong_lane_for_a_left_turn(vec![go], 60.0);
    let of_car = |kind: EventKind| traj.events.iter().filter(move |e| e.car == Some(0) && e.kind == kind);
    let change: Vec<_> = of_car(EventKind::LaneChange).collect();
    assert_eq!(change.len(), 1, "{:?}", traj.events);
    assert_eq!(change[0].detail, "A1w -> A1x for DriveQueue[0] left");
    assert!(change[0].t > free_at, "changed lanes at {:.1} s, while A1x was blocked until {free_at} s", change[0].t);
    let turn: Vec<_> = of_car(EventKind::TurnDone).collect();
    assert_eq!(turn.len(), 1, "{:?}", traj.events);
    assert_eq!(turn[0].detail, "left at AD from A1x");
    assert!(turn[0].t > change[0].t);
    assert_eq!(of_car(EventKind::ActionSkipped).count(), 0);
    // It waited in its own lane, at rest, before the stop line.
    let map = wide_blocks();
    let line = map.lanes[lane(&map, "A1w")].curve.length() - map.layout.stop_line_setback;
    let waiting = ((free_at - 1.0) / FRAME) as usize;
    let (along, sideways) = on_lane(&map, &traj, "A1w", waiting, 0);
    assert!(sideways.abs() < 0.3, "{sideways:.2} m off A1w while waiting");
    assert!(
        along + LENGTH / 2.0 < line,
        "front {:.2} m along, past the stop line at {line:.2} m",
        along + LENGTH / 2.0
    );
    assert!(traj.states[waiting][0].speed < 0.05, "still rolling at {:.2} m/s", traj.states[waiting][0].speed);
    assert!(traj.events.iter().all(|e| e.kind != EventKind::Collision), "{:?}", traj.events);
}

#[test]
fn a_driver_gives_up_the_turn_when_no_gap_comes_and_goes_straight_on() {
    let traj = wrong_lane_for_a_left_turn(vec![], 60.0);
    let skipped: Vec<_> =
        traj.events.iter().filter(|e| e.car == Some(0) && e.kind == EventKind::ActionSkipped).collect();
    assert_eq!(skipped.len(), 1, "{:?}", traj.events);
    assert!(
        skipped[0].detail.starts_with("DriveQueue[0] left: no gap to change from A1w into A1x"),
        "{}",
        skipped[0].detail
    );
    // It waited the whole patience at the last point, and not much longer.
    let t = skipped[0].t;
    assert!(
        t > super::perception::LANE_CHANGE_PATIENCE && t < super::perception::LANE_CHANGE_PATIENCE + 15.0,
        "gave up at {t:.1} s"
    );
    assert!(traj
        .events
        .iter()
        .all(|e| e.car != Some(0) || (e.kind != EventKind::LaneChange && e.kind != EventKind::TurnDone)));
    // Then straight on through AD into A2w.
    let map = wide_blocks();
    let a2w = map.lanes[lane(&map, "A2w")].curve.length();
    let on_a2w = (0..traj.frames()).filter(|&f| {
        let (along, sideways) = on_lane(&map, &traj, "A2w", f, 0);
        sideways.abs() < 0.3 && (1.0..a2w - 1.0).contains(&along)
    });
    assert!(on_a2w.count() > 5, "never drove along A2w after giving up");
}

#[test]
fn a_follower_drives_straight_on_where_its_leader_gave_up_the_turn() {
    // The leader of `wrong_lane_for_a_left_turn` gives up its left turn;
    // its follower waits on the turn lane A1x behind the blocker, which
    // drives off once the leader has given up.
    let map = wide_blocks();
    let lights = lights_with(&map, &["A1x"], &[(Colour::Green, 1000.0)]);
    let leader =
        Given { lane: "A1w", at: 14.0, actions: vec![Action::Left], merges: vec![0.0], desired: 2.0, start: 0.0 };
    let blocker = straight("A1x", 26.0, 0.0);
    let follower = Given { lane: "A1x", at: 14.0, ..leader.clone() };
    let go = Intervention {
        trigger: Trigger::At(super::perception::LANE_CHANGE_PATIENCE + 20.0),
        effect: Effect::SetDesiredSpeed { car: 1, speed: 3.0 },
        label: "blocker drives off".into(),
    };
    let mut plan = plan(&map, &[leader, blocker, follower], lights, vec![go], 90.0);
    plan.cars[0].role = Role::Leader;
    plan.cars[2].role = Role::Follower;
    plan.cars[2].leader = Some(0);
    plan.edges = vec![(0, 2)];
    let traj = simulate(&map, &plan);
    let gave_up = traj.events.iter().find(|e| e.car == Some(0) && e.kind == EventKind::ActionSkipped);
    assert!(gave_up.is_some_and(|e| e.t < super::perception::LANE_CHANGE_PATIENCE + 20.0), "{:?}", traj.events);
    // From A1x a left turn was open to it; it went straight on into A2x as its leader did.
    let turns: Vec<_> = traj.events.iter().filter(|e| e.car == Some(2) && e.kind == EventKind::TurnDone).collect();
    assert!(turns.iter().all(|e| !e.detail.starts_with("left")), "{turns:?}");
    let a2x = map.lanes[lane(&map, "A2x")].curve.length();
    let on_a2x = (0..traj.frames()).filter(|&f| {
        let (along, sideways) = on_lane(&map, &traj, "A2x", f, 2);
        sideways.abs() < 0.3 && (1.0..a2x - 1.0).contains(&along)
    });
    assert!(on_a2x.count() > 5, "the follower never drove along A2x: {:?}", traj.events);
}

/// Largest deceleration of car `car` between consecutive frames, m/s^2.
fn hardest_braking(traj: &Trajectories, car: usize) -> f64 {
    traj.states.windows(2).map(|w| (w[0][car].speed - w[1][car].speed) / FRAME).fold(0.0, f64::max)
}

#[test]
fn a_car_starting_right_behind_another_starts_no_faster_than_its_gap_allows() {
    let map = wide_blocks();
    let lights = lights_with(&map, &["A1w"], &[(Colour::Green, 1000.0)]);
    let p = driver();
    // 3 m apart bumper to bumper on A1w (36 m, see [`wide_blocks`]): the car
    // ahead starts at the speed whose desired gap s0 + v T is those 3 m,
    // the car behind wishes to start faster.
    let gap = 3.0;
    let equilibrium = (gap - p.min_gap) / p.time_headway;
    let ahead = Given { start: equilibrium, ..straight("A1w", 12.0, 3.0) };
    let behind = Given { start: 3.0, ..straight("A1w", 12.0 - LENGTH - gap, 3.0) };
    let traj = simulate(&map, &plan(&map, &[ahead, behind], lights, vec![], 6.0));
    let start: Vec<f64> = traj.states[0].iter().map(|c| c.speed).collect();
    // Free road: the wish stands.
    assert!((start[0] - equilibrium).abs() < 1e-9, "the car ahead started at {:.3} m/s", start[0]);
    // Behind: no faster than the gap allows at the speed of the car ahead.
    assert!(
        start[1] > equilibrium - 0.05 && start[1] <= equilibrium + 1e-9,
        "the car behind started at {:.3} m/s, its gap allows {equilibrium:.3}",
        start[1]
    );
    // Content at the start: it never stands, never brakes hard.
    assert!(traj.states.iter().all(|f| f[1].speed > 0.5), "the car behind stalled");
    assert!(hardest_braking(&traj, 1) < 0.3, "the car behind braked at {:.2} m/s^2", hardest_braking(&traj, 1));
}

#[test]
fn a_car_starting_before_a_red_light_starts_slow_enough_to_stop_comfortably() {
    let map = wide_blocks();
    let lights = lights_with(&map, &["A1w"], &[(Colour::Red, 1000.0)]);
    let p = driver();
    let line = map.lanes[lane(&map, "A1w")].curve.length() - map.layout.stop_line_setback;
    // Front 6 m before the line, wishing 5 m/s: it could not stop from there.
    let car = Given { start: 5.0, ..straight("A1w", line - 6.0 - LENGTH / 2.0, 5.0) };
    let traj = simulate(&map, &plan(&map, &[car], lights, vec![], 12.0));
    let start = traj.states[0][0].speed;
    assert!(start > 0.5 && start < 5.0, "started at {start:.3} m/s");
    assert!(start * start / (2.0 * p.comfortable_deceleration) < 6.0, "cannot stop in 6 m from {start:.3} m/s");
    let last = traj.frames() - 1;
    let front = on_lane(&map, &traj, "A1w", last, 0).0 + LENGTH / 2.0;
    assert!(traj.states[last][0].speed < 0.05 && front <= line, "front at {front:.2}, line at {line:.2}");
    let braking = hardest_braking(&traj, 0);
    assert!(braking <= p.comfortable_deceleration * 1.5, "braked at {braking:.2} m/s^2");
    assert!(traj.events.iter().all(|e| e.kind != EventKind::RedLightRun), "{:?}", traj.events);
}

/// A leader 8 m ahead of its follower on A1w (16 m long), both planned straight on at
/// AD (lights green), the follower falling back on a right turn, driven for
/// 20 s with `interventions`.
fn follow_scene(map: &CityMap, interventions: Vec<Intervention>) -> Trajectories {
    let cars = [
        Given { lane: "A1w", at: 12.0, actions: vec![Action::Straight], merges: vec![0.0], desired: 2.5, start: 1.0 },
        Given { lane: "A1w", at: 4.0, actions: vec![Action::Straight], merges: vec![0.0], desired: 2.5, start: 1.0 },
    ];
    let lights = lights_with(map, &["A1w"], &[(Colour::Green, 100.0)]);
    let mut plan = plan(map, &cars, lights, interventions, 20.0);
    let follower = &mut plan.cars[1];
    follower.role = Role::Follower;
    follower.leader = Some(0);
    follower.on_leader_lost = Some(crate::plan::OnLeaderLost::Drive(crate::plan::Fallback {
        actions: vec![Action::Right],
        merge_distances: vec![0.0],
    }));
    plan.cars[0].role = Role::Leader;
    plan.edges = vec![(0, 1)];
    simulate(map, &plan)
}

/// Whether car `car` drives along the lane that `turn` from A1w leads to
/// at some frame.
fn passes_after(map: &CityMap, traj: &Trajectories, car: usize, turn: crate::map::Turn) -> bool {
    let exit = map.exit(lane(map, "A1w"), turn).expect("A1w has the turn");
    let to = &map.lanes[map.connectors[exit].to];
    traj.states.iter().any(|frame| {
        let (s, lateral) = to.curve.local_coordinates(frame[car].position);
        s > 1.0 && s < to.curve.length() - 1.0 && lateral.abs() < 0.3
    })
}

#[test]
fn a_follower_takes_the_turn_its_leader_takes_and_its_own_once_the_leader_is_gone() {
    use crate::map::Turn;
    let map = CityMap::default();
    // As planned: both straight on.
    let factual = follow_scene(&map, vec![]);
    assert!(passes_after(&map, &factual, 0, Turn::Straight) && passes_after(&map, &factual, 1, Turn::Straight));
    // The leader told to turn right: the follower sees it and turns right too.
    let turn = Intervention {
        trigger: Trigger::At(0.0),
        effect: Effect::ReplaceActions { car: 0, actions: vec![Action::Right], merge_distances: vec![0.0] },
        label: "leader turns right".into(),
    };
    let turned = follow_scene(&map, vec![turn]);
    assert!(passes_after(&map, &turned, 0, Turn::Right), "the leader did not turn right");
    assert!(passes_after(&map, &turned, 1, Turn::Right), "the follower did not take its leader's turn");
    // The leader removed: the follower drives its own queue (a right turn here).
    let remove =
        Intervention { trigger: Trigger::At(0.0), effect: Effect::Remove { car: 0 }, label: "remove leader".into() };
    let lost = follow_scene(&map, vec![remove]);
    assert!(passes_after(&map, &lost, 1, Turn::Right), "the follower did not fall back on its own queue");
}

/// The default map with junction AC run by `control` instead of lights.
fn map_with_ac(control: crate::map::control::JunctionControl) -> CityMap {
    CityMap::new(crate::map::MapLayout { junction_controls: vec![("AC".into(), control)], ..Default::default() })
}

/// The first frame at which car `car`'s centre has entered AC's box
/// (centre (-14, 14), 6 m either way).
fn enters_ac_box(traj: &Trajectories, car: usize) -> Option<usize> {
    traj.states.iter().position(|f| {
        let p = f[car].position;
        (p.x + 14.0).abs() < 6.0 && (p.y - 14.0).abs() < 6.0
    })
}

#[test]
fn at_a_priority_junction_the_side_road_gives_way_to_the_through_road() {
    use crate::map::control::JunctionControl;
    use crate::world::BoundBy;
    let map = map_with_ac(JunctionControl::Priority);
    // Car 0 on road A from the west (the through road), car 1 on road C
    // from the north, nearer its line: it would enter first without rules.
    let cars = [Given { start: 3.0, ..straight("A0w", 4.0, 3.0) }, Given { start: 3.0, ..straight("C2z", 6.0, 3.0) }];
    let traj = simulate(&map, &plan(&map, &cars, LightPlan::cycle(map.signalised(), 1.0, &[]), vec![], 30.0));
    let (major, minor) =
        (enters_ac_box(&traj, 0).expect("car 0 crosses"), enters_ac_box(&traj, 1).expect("car 1 crosses"));
    assert!(major < minor, "the through car entered at frame {major}, the side-road car at {minor}");
    let gave_way = traj.interactions.iter().filter(|f| f[1].bound_by == BoundBy::GiveWay && f[1].other_car == Some(0));
    assert!(gave_way.count() > 0, "car 1 never gave way to car 0");
    assert!(traj.interactions.iter().all(|f| f[0].bound_by != BoundBy::GiveWay), "the through car gave way");
    assert!(traj.events.iter().all(|e| e.kind != EventKind::Collision), "{:?}", traj.events);
    // Alone, the side-road car would have gone first.
    let alone = simulate(&map, &plan(&map, &cars[1..], LightPlan::cycle(map.signalised(), 1.0, &[]), vec![], 30.0));
    assert!(enters_ac_box(&alone, 0).expect("crosses alone") < major, "the test does not force a conflict");
}

#[test]
fn right_before_left_the_car_from_the_right_goes_first_even_from_the_side_road() {
    use crate::map::control::JunctionControl;
    use crate::world::BoundBy;
    // Car 0 comes along road A from the east, nearer its line; car 1 down
    // road C from the north, on car 0's right. A priority junction lets
    // car 0 (on A, the through road) go first; right before left, car 1.
    let cars = [Given { start: 3.0, ..straight("A1z", 6.0, 3.0) }, Given { start: 3.0, ..straight("C2z", 4.0, 3.0) }];
    let entries = |control| {
        let map = map_with_ac(control);
        let traj = simulate(&map, &plan(&map, &cars, LightPlan::cycle(map.signalised(), 1.0, &[]), vec![], 30.0));
        assert!(traj.events.iter().all(|e| e.kind != EventKind::Collision), "{:?}", traj.events);
        let entered =
            (enters_ac_box(&traj, 0).expect("car 0 crosses"), enters_ac_box(&traj, 1).expect("car 1 crosses"));
        (entered, traj)
    };
    let ((from_east, from_north), traj) = entries(JunctionControl::RightBeforeLeft);
    assert!(from_north < from_east, "from the north entered at frame {from_north}, from the east at {from_east}");
    let gave_way = traj.interactions.iter().filter(|f| f[0].bound_by == BoundBy::GiveWay && f[0].other_car == Some(1));
    assert!(gave_way.count() > 0, "car 0 never gave way to car 1");
    assert!(traj.interactions.iter().all(|f| f[1].bound_by != BoundBy::GiveWay), "the car from the right gave way");
    // The same cars at a priority junction: the through road goes first.
    let ((from_east, from_north), _) = entries(JunctionControl::Priority);
    assert!(
        from_east < from_north,
        "priority: from the east entered at frame {from_east}, from the north at {from_north}"
    );
}

#[test]
fn right_before_left_four_cars_arriving_together_all_cross_without_collision() {
    use crate::map::control::JunctionControl;
    // Each has another on its right: the rule alone would leave all four waiting.
    let map = map_with_ac(JunctionControl::RightBeforeLeft);
    let cars = [
        Given { start: 3.0, ..straight("A0w", 4.0, 3.0) },
        Given { start: 3.0, ..straight("A1z", 4.0, 3.0) },
        Given { start: 3.0, ..straight("C2z", 4.0, 3.0) },
        Given { start: 3.0, ..straight("C1w", 4.0, 3.0) },
    ];
    let traj = simulate(&map, &plan(&map, &cars, LightPlan::cycle(map.signalised(), 1.0, &[]), vec![], 60.0));
    assert!(traj.events.iter().all(|e| e.kind != EventKind::Collision), "{:?}", traj.events);
    for car in 0..4 {
        assert!(enters_ac_box(&traj, car).is_some(), "car {car} never crossed");
    }
}

#[test]
fn at_an_all_way_stop_a_lone_car_halts_at_its_line_then_crosses() {
    use crate::map::control::JunctionControl;
    use crate::world::BoundBy;
    let map = map_with_ac(JunctionControl::AllWayStop);
    let cars = [Given { start: 3.0, ..straight("A0w", 2.0, 3.0) }];
    let traj = simulate(&map, &plan(&map, &cars, LightPlan::cycle(map.signalised(), 1.0, &[]), vec![], 30.0));
    // A0w is 16 m long; its stop line stands 3.6 m before its end.
    let line = 16.0 - map.layout.stop_line_setback;
    let halted = (0..traj.frames()).find(|&f| {
        let (s, _) = on_lane(&map, &traj, "A0w", f, 0);
        let front = s + LENGTH / 2.0;
        traj.states[f][0].speed < 0.2 && front > line - 1.5 && front <= line
    });
    let halted = halted.expect("the car never came to rest at its line");
    let entered = enters_ac_box(&traj, 0).expect("the car never crossed");
    assert!(halted < entered, "halted at frame {halted}, entered the box at {entered}");
    assert!(traj.interactions.iter().any(|f| f[0].bound_by == BoundBy::StopLine));
    // At a junction with lights on green it would not have stopped.
    let map = CityMap::default();
    let lights = lights_with(&map, &["A0w"], &[(Colour::Green, 100.0)]);
    let traj = simulate(&map, &plan(&map, &cars, lights, vec![], 30.0));
    assert!(traj.states.iter().all(|f| f[0].speed > 1.0 || f[0].position.x > -8.0), "stopped on green");
}

#[test]
fn at_an_all_way_stop_two_cars_waiting_go_one_after_the_other_in_order_of_precedence() {
    use crate::map::control::JunctionControl;
    use crate::map::Turn;
    use crate::world::BoundBy;
    let map = map_with_ac(JunctionControl::AllWayStop);
    let cars = [Given { start: 3.0, ..straight("A0w", 4.0, 3.0) }, Given { start: 3.0, ..straight("C2z", 4.0, 3.0) }];
    let traj = simulate(&map, &plan(&map, &cars, LightPlan::cycle(map.signalised(), 1.0, &[]), vec![], 40.0));
    let first_entered: Vec<usize> = (0..2).map(|c| enters_ac_box(&traj, c).expect("both cross")).collect();
    let key = |name: &str| map.right_of_way(map.exit(lane(&map, name), Turn::Straight).expect("straight on"));
    let (first, second) = if key("A0w") < key("C2z") { (0, 1) } else { (1, 0) };
    assert!(first_entered[first] < first_entered[second], "entered at frames {first_entered:?}");
    assert!(
        traj.interactions.iter().any(|f| matches!(f[second].bound_by, BoundBy::GiveWay | BoundBy::Conflict)),
        "car {second} never waited for car {first}"
    );
    assert!(traj.events.iter().all(|e| e.kind != EventKind::Collision), "{:?}", traj.events);
}

/// The small real network the SUMO import tests use (OpenStreetMap, ODbL).
fn berlin() -> CityMap {
    imported(include_str!("../../../tests/data/sumo/berlin-small.net.xml"))
}

/// The map of a SUMO network's text, lane changes over 6 m.
fn imported(text: &str) -> CityMap {
    let net = crate::map::sumo::SumoNetwork::from_xml(text).expect("the test network reads");
    CityMap::from_sumo(&net, 6.0).expect("the test network drives").0
}

#[test]
fn a_left_turn_on_a_permissive_green_gives_way_to_oncoming_traffic() {
    use crate::map::Turn;
    use crate::world::BoundBy;
    let map = berlin();
    // An approach whose programme has no protected left phase, and the
    // oncoming straight movement that goes before its left turn.
    let (left, oncoming) = (0..map.connectors.len())
        .filter(|&c| map.permissive_left(c) && map.connectors[c].turn == Turn::Left)
        .find_map(|c| {
            let o = map
                .conflicts(c)
                .iter()
                .copied()
                .find(|&o| map.connectors[o].turn == Turn::Straight && map.goes_before(o, c))?;
            Some((c, o))
        })
        .expect("Berlin has a left turn on a permissive green with oncoming traffic");
    let name =
        |c: usize| -> &'static str { Box::leak(map.lanes[map.connectors[c].from].name.clone().into_boxed_str()) };
    let (turner, through) = (name(left), name(oncoming));
    let length = |n: &str| map.lanes[lane(&map, n)].curve.length();
    // Both 12 m before their line, on green for as long as the test runs.
    let at = |n: &str| length(n) - map.layout.stop_line_setback - 12.0;
    let cars = [
        Given { lane: turner, at: at(turner), actions: vec![Action::Left], merges: vec![], desired: 6.0, start: 6.0 },
        Given {
            lane: through,
            at: at(through),
            actions: vec![Action::Straight],
            merges: vec![],
            desired: 6.0,
            start: 6.0,
        },
    ];
    let lights = lights_with(&map, &[turner, through], &[(Colour::Green, 100.0)]);
    let traj = simulate(&map, &plan(&map, &cars, lights, vec![], 20.0));
    assert!(traj.events.iter().all(|e| e.kind != EventKind::Collision), "{:?}", traj.events);
    let gave_way = traj.interactions.iter().any(|f| f[0].bound_by == BoundBy::GiveWay && f[0].other_car == Some(1));
    assert!(gave_way, "the left turn never gave way to the oncoming car");
    assert!(traj.interactions.iter().all(|f| f[1].bound_by != BoundBy::GiveWay), "the oncoming car gave way");
}

#[test]
fn cars_drive_on_and_on_through_an_imported_sumo_network() {
    let map = berlin();
    let turns = [Action::Left, Action::Right, Action::Straight, Action::Right, Action::Left];
    // A car on every lane long enough, each with its own queue of turns.
    let mut cars = Vec::new();
    for (k, id) in map.spawn_points().into_iter().enumerate() {
        if map.lanes[id].curve.length() < 20.0 {
            continue;
        }
        let name: &'static str = Box::leak(map.lanes[id].name.clone().into_boxed_str());
        let actions: Vec<Action> = (0..4).map(|a| turns[(k + a) % turns.len()]).collect();
        cars.push(Given { lane: name, at: 6.0, actions, merges: vec![], desired: 8.0, start: 0.0 });
    }
    assert!(cars.len() >= 30, "only {} cars placed", cars.len());
    let seconds = 180.0;
    let traj = simulate(&map, &plan(&map, &cars, LightPlan::cycle(map.signalised(), 1.0, &[]), vec![], seconds));
    let collisions: Vec<_> = traj.events.iter().filter(|e| e.kind == EventKind::Collision).collect();
    assert!(collisions.is_empty(), "{collisions:?}");
    let last = traj.frames() - 1;
    for (car, given) in cars.iter().enumerate() {
        let driven: f64 =
            (1..=last).map(|f| traj.states[f][car].position.distance(traj.states[f - 1][car].position)).sum();
        // The longest time at rest, seconds: a red light or a queue, never for good.
        let mut longest = 0;
        let mut run = 0;
        for f in 0..=last {
            run = if traj.states[f][car].speed < 0.1 { run + 1 } else { 0 };
            longest = longest.max(run);
        }
        let rest = longest as f64 * FRAME;
        assert!(driven > 300.0, "car {car} from {} drove {driven:.0} m in {seconds} s", given.lane);
        assert!(rest < 90.0, "car {car} from {} stood still for {rest:.0} s", given.lane);
    }
}

#[test]
fn on_an_imported_network_a_car_keeps_behind_one_that_shares_its_path_into_the_junction_before_turning_away() {
    // From 143308587#0_1 the straight and the right turn run together for
    // some 20 m through the large joined junction before they part.
    let map = berlin();
    let from = lane(&map, "143308587#0_1");
    let (right, straight) = (map.exit(from, Turn::Right).unwrap(), map.exit(from, Turn::Straight).unwrap());
    let shared = map.shared_start(straight, right);
    assert!(shared > 10.0 && shared < 40.0, "{shared}");
    let line = map.lanes[from].curve.length() - map.layout.stop_line_setback;
    // A slow car turning right just before the line, a fast one going straight 15 m behind.
    let cars = [
        Given {
            lane: "143308587#0_1",
            at: line - 3.0,
            actions: vec![Action::Right],
            merges: vec![],
            desired: 1.0,
            start: 1.0,
        },
        Given {
            lane: "143308587#0_1",
            at: line - 18.0,
            actions: vec![Action::Straight],
            merges: vec![],
            desired: 6.0,
            start: 6.0,
        },
    ];
    let traj = simulate(&map, &plan(&map, &cars, LightPlan::cycle(map.signalised(), 1.0, &[]), vec![], 60.0));
    assert!(traj.events.iter().all(|e| e.kind != EventKind::Collision), "{:?}", traj.events);
    let closest = traj.states.iter().map(|f| f[0].position.distance(f[1].position)).fold(f64::INFINITY, f64::min);
    assert!(closest > LENGTH, "the cars came within {closest:.2} m centre to centre");
    // And the fast car did get past the junction once the slow one turned away.
    let last = &traj.states[traj.frames() - 1];
    let moved = last[1].position.distance(traj.states[0][1].position);
    assert!(
        moved > 100.0,
        "moved {moved:.1} m; speeds {:?}",
        traj.states.iter().step_by(25).map(|f| (f[0].speed, f[1].speed)).collect::<Vec<_>>()
    );
}

/// A 3 x 3 grid of one-lane roads whose junctions all run SUMO's
/// traffic-actuated programme (netgenerate; no map data).
fn actuated_grid() -> CityMap {
    imported(include_str!("../../../tests/data/sumo/grid3-actuated.net.xml"))
}

#[test]
fn a_car_passing_an_actuated_phases_detector_holds_its_green_and_its_absence_ends_it() {
    let map = actuated_grid();
    // Junction B1's first phase gives the road from the south (B0B1) green
    // for 5 to 50 s; a detector 2 s at 13.89 m/s (27.8 m) before its line.
    let programme = map.actuated.iter().find(|p| p.id == "B1").expect("B1 runs an actuated programme");
    let approach = lane(&map, "B0B1_0");
    let (shortest, longest) = programme.phases[0].bounds.expect("its first phase extends");
    assert_eq!((shortest, longest), (5.0, 50.0));
    let &(_, detector) =
        programme.phases[0].detectors.iter().find(|d| d.0 == approach).expect("a detector on the approach");
    let line = map.lanes[approach].curve.length() - map.layout.stop_line_setback;
    assert!((line - detector - 2.0 * 13.89).abs() < 0.01, "detector {detector:.1} m, line {line:.1} m");
    let LaneEnd::Intersection { intersection, approach: side } = map.lanes[approach].end else {
        panic!("B0B1 ends at B1")
    };
    // A car at 12 m/s whose centre passes the detector 4.5 s in (over it
    // for a third of a second), or the same car on a road far from B1.
    let on_approach = Given { start: 12.0, ..straight("B0B1_0", detector - 54.0, 12.0) };
    let elsewhere = Given { start: 12.0, ..straight("A0A1_0", 10.0, 12.0) };
    let green_for = |car: &Given, actuated: bool| -> (f64, Trajectories) {
        let lights = map.light_plan(1.0, &[], actuated);
        let light = lights.index(intersection, side, Signal::Straight, 0).expect("B1 has lights");
        let traj = simulate(&map, &plan(&map, std::slice::from_ref(car), lights, vec![], 20.0));
        let green = traj.lights.iter().take_while(|frame| frame[light].colour == Colour::Green).count();
        (green as f64 * FRAME, traj)
    };
    // Nobody over the detector: the phase ends at its shortest.
    let (alone, _) = green_for(&elsewhere, true);
    assert!((alone - shortest).abs() <= FRAME + 1e-9, "green for {alone:.1} s with no car near");
    // The car holds it until 3 s (max-gap) after it left the detector, and
    // drives through on that green.
    let (held, traj) = green_for(&on_approach, true);
    assert!((7.0..=8.6).contains(&held), "green for {held:.1} s with a car passing at 4.5 s");
    let crossed = traj.states.iter().position(|f| map.lanes[approach].curve.local_coordinates(f[0].position).0 > line);
    let crossed = crossed.expect("the car reached its line");
    let at = crossed as f64 * FRAME;
    assert!(at < held, "the car crossed at {at:.1} s, after its green ended at {held:.1} s");
    let slowest = traj.states[..crossed].iter().map(|f| f[0].speed).fold(f64::INFINITY, f64::min);
    assert!(slowest > 10.0, "the car slowed to {slowest:.1} m/s before its line");
    // Run as fixed, the phase lasts its written 42 s whatever drives.
    let (fixed, _) = green_for(&on_approach, false);
    assert!(fixed >= 20.0 - 1e-9, "a fixed programme's green ended after {fixed:.1} s");
}

/// A 2 x 2 grid of two-lane roads (netgenerate; no map data) whose
/// junction B1 has a right-turn arrow: the right turn from the south goes
/// on the straight phase and again with the protected left from the west.
fn arrow_grid() -> CityMap {
    imported(include_str!("../../../tests/data/sumo/grid2-arrows.net.xml"))
}

#[test]
fn a_right_turn_arrow_lets_the_right_turn_go_while_straight_on_waits() {
    let map = arrow_grid();
    let b1 = map.intersections.iter().position(|x| x.name == "B1").expect("junction B1");
    // B1's programme: from the south straight and right green 0-36 s,
    // yellow to 39; the arrow (right turn, and the west's left) 39-45,
    // yellow to 48; red to the end of the cycle at 87. Start at 33 s: in
    // scenario time green to 3 s, yellow to 6, the arrow green 6-12 and
    // yellow to 15, straight on red from 6 to 54.
    let mut offsets = vec![0.0; map.intersections.len()];
    offsets[b1] = 33.0;
    let lights = map.light_plan(1.0, &offsets, false);
    let straight_light = lights.index(b1, 'S', Signal::Straight, 0).expect("B1/S/straight");
    let arrow = lights.index(b1, 'S', Signal::Straight, 1).expect("B1/S/straight-2, the arrow");
    assert_eq!(map.light_name(arrow), "B1/S/straight-2");
    assert_eq!(map.light_by_name("B1/S/straight-2"), Ok(arrow));
    let approach = lane(&map, "B0B1_0");
    let line = map.lanes[approach].curve.length() - map.layout.stop_line_setback;
    // Two runs of one car 70 m before the line at 6 m/s, which sees its
    // light from 30 m (about 6.7 s in): turning right, and straight on.
    let right = Given { actions: vec![Action::Right], start: 6.0, ..straight("B0B1_0", line - 70.0, 6.0) };
    let ahead = Given { start: 6.0, ..straight("B0B1_0", line - 70.0, 6.0) };
    let crossing = |car: &Given| -> (Option<f64>, Trajectories) {
        let traj = simulate(&map, &plan(&map, std::slice::from_ref(car), lights.clone(), vec![], 60.0));
        let crossed = traj.states.iter().position(|f| {
            let (s, r) = map.lanes[approach].curve.local_coordinates(f[0].position);
            s > line || r.abs() > 3.0
        });
        (crossed.map(|k| k as f64 * FRAME), traj)
    };
    let (turned, traj) = crossing(&right);
    let at = |t: f64| &traj.lights[(t / FRAME).round() as usize];
    assert_eq!((at(1.0)[straight_light].colour, at(1.0)[arrow].colour), (Colour::Green, Colour::Green));
    assert_eq!((at(4.0)[straight_light].colour, at(4.0)[arrow].colour), (Colour::Yellow, Colour::Yellow));
    assert_eq!((at(8.0)[straight_light].colour, at(8.0)[arrow].colour), (Colour::Red, Colour::Green));
    assert_eq!((at(13.0)[straight_light].colour, at(13.0)[arrow].colour), (Colour::Red, Colour::Yellow));
    let turned = turned.expect("the right turn reached its line");
    assert!((6.0..15.0).contains(&turned), "the right turn crossed at {turned:.1} s, not on the arrow (6-15 s)");
    assert_eq!(at(turned)[straight_light].colour, Colour::Red, "it went while straight on was red");
    let (went, _) = crossing(&ahead);
    let went = went.expect("the straight car crossed once its green came back");
    assert!(went >= 54.0, "the straight car crossed at {went:.1} s, before its green at 54 s");
}

#[test]
fn at_a_junction_of_five_arms_a_side_street_from_the_priority_roads_side_waits_for_it() {
    use crate::world::BoundBy;
    // Five arms; the priority road runs north-south, and side street nwC
    // joins from the north too, 30 degrees off it. Both cars go straight on
    // into Cs; the side street's car is nearer its line.
    let map = imported(include_str!("../../../tests/data/sumo/star5-priority.net.xml"));
    let before_line =
        |name: &str, metres: f64| map.lanes[lane(&map, name)].curve.length() - map.layout.stop_line_setback - metres;
    let car = |name: &'static str, metres: f64| Given {
        lane: name,
        at: before_line(name, metres),
        actions: vec![Action::Straight],
        merges: vec![],
        desired: 6.0,
        start: 6.0,
    };
    let cars = [car("nC_0", 16.0), car("nwC_0", 8.0)];
    let centre = map.intersections[0].centre;
    let enters = |traj: &Trajectories, car: usize| {
        traj.states.iter().position(|f| f[car].position.distance(centre) < 6.0).expect("the car crosses")
    };
    let no_lights = || LightPlan::cycle(map.signalised(), 1.0, &[]);
    let traj = simulate(&map, &plan(&map, &cars, no_lights(), vec![], 30.0));
    assert!(traj.events.iter().all(|e| e.kind != EventKind::Collision), "{:?}", traj.events);
    let (main, side) = (enters(&traj, 0), enters(&traj, 1));
    assert!(main < side, "the priority road's car entered at frame {main}, the side street's at {side}");
    let gave_way = traj.interactions.iter().any(|f| f[1].bound_by == BoundBy::GiveWay && f[1].other_car == Some(0));
    assert!(gave_way, "the side street's car never gave way");
    assert!(traj.interactions.iter().all(|f| f[0].bound_by != BoundBy::GiveWay), "the priority road's car gave way");
    // Alone, the side street's car would have entered first, and sooner.
    let alone = simulate(&map, &plan(&map, &cars[1..], no_lights(), vec![], 30.0));
    assert!(enters(&alone, 0) < main && enters(&alone, 0) < side, "the test does not force a conflict");
}

#[test]
fn cars_on_every_arm_of_a_five_arm_junction_cross_it_for_minutes_without_collision() {
    let turns = [
        Action::Left,
        Action::SlightRight,
        Action::Straight,
        Action::Right,
        Action::SlightLeft,
        Action::Left,
        Action::Right,
    ];
    for text in [
        include_str!("../../../tests/data/sumo/star5-priority.net.xml"),
        include_str!("../../../tests/data/sumo/star5-lights.net.xml"),
    ] {
        let map = imported(text);
        // Two cars on every lane, each with its own queue of turns, slight
        // ones included (skipped, as any turn a road lacks, where it has none).
        let mut cars = Vec::new();
        for (k, id) in map.spawn_points().into_iter().enumerate() {
            let name: &'static str = Box::leak(map.lanes[id].name.clone().into_boxed_str());
            for (j, at) in [20.0, 60.0].into_iter().enumerate() {
                let actions: Vec<Action> = (0..6).map(|a| turns[(k + 2 * j + a) % turns.len()]).collect();
                cars.push(Given { lane: name, at, actions, merges: vec![], desired: 8.0, start: 0.0 });
            }
        }
        assert_eq!(cars.len(), 20);
        let seconds = 240.0;
        let lights = map.light_plan(1.0, &vec![0.0; map.intersections.len()], false);
        let mut scenario = plan(&map, &cars, lights, vec![], seconds);
        // The rules the towns' specs use: under the original's, two cars of
        // one lane on different movements can wait on each other for good
        // at lights (docs/city.md#driving-rules).
        let WorldPlan::City(city) = &mut scenario.world else { unreachable!() };
        city.rules = crate::spec::DrivingRules::Cooperative;
        let traj = simulate(&map, &scenario);
        let collisions: Vec<_> = traj.events.iter().filter(|e| e.kind == EventKind::Collision).collect();
        assert!(collisions.is_empty(), "{collisions:?}");
        // Every car crosses the junction again and again.
        let centre = map.intersections[0].centre;
        for car in 0..cars.len() {
            let inside: Vec<bool> = traj.states.iter().map(|f| f[car].position.distance(centre) < 8.0).collect();
            let entries = inside.windows(2).filter(|w| !w[0] && w[1]).count();
            assert!(entries >= 2, "car {car} from {} entered the junction {entries} times", cars[car].lane);
        }
    }
}

#[test]
fn at_a_junction_of_five_arms_right_and_slight_right_lead_into_different_streets() {
    let map = imported(include_str!("../../../tests/data/sumo/star5-priority.net.xml"));
    let ends_on = |action: Action| {
        let car = Given { lane: "nC_0", at: 60.0, actions: vec![action], merges: vec![], desired: 8.0, start: 8.0 };
        let traj = simulate(&map, &plan(&map, &[car], LightPlan::cycle(map.signalised(), 1.0, &[]), vec![], 25.0));
        // The lane whose centre line the car is nearest at the end.
        let at = traj.states[traj.frames() - 1][0].position;
        let nearest = (0..map.lanes.len()).min_by(|&a, &b| {
            let d = |l: usize| {
                let c = &map.lanes[l].curve;
                (0..=40)
                    .map(|k| c.position(c.length() * k as f64 / 40.0, 0.0).distance(at))
                    .fold(f64::INFINITY, f64::min)
            };
            d(a).total_cmp(&d(b))
        });
        map.lanes[nearest.unwrap()].name.clone()
    };
    assert_eq!(ends_on(Action::Right), "Cnw_0");
    assert_eq!(ends_on(Action::SlightRight), "Csw_0");
    assert_eq!(ends_on(Action::Straight), "Cs_0");
    assert_eq!(ends_on(Action::Left), "Ce_0");
}

#[test]
fn every_light_records_its_own_schedule_where_lights_share_one_and_where_an_intervention_sets_one_apart() {
    let map = CityMap::default();
    // The default cycle at every junction from time 0: lights share
    // schedules across junctions; A1w's two lights get one of their own.
    let lights = lights_with(&map, &["A1w"], &[(Colour::Red, 3.0), (Colour::Green, 4.0)]);
    let twins = super::light_twins(&lights.lights);
    let shared: Vec<usize> = (0..twins.len()).filter(|&l| twins[l] != l).collect();
    assert!(!shared.is_empty(), "no two lights share a schedule: the test checks nothing of the sharing");
    // One light that shares its schedule is forced red for 2 s from t = 1.
    let forced = shared[0];
    let (from, seconds) = (1.0, 2.0);
    let set = Intervention {
        trigger: Trigger::At(from),
        effect: Effect::SetLight { light: forced, colour: Colour::Red, seconds },
        label: "forced red".into(),
    };
    let traj = simulate(&map, &plan(&map, &[straight("A1w", 20.0, 2.0)], lights.clone(), vec![set], 6.0));
    let mut apart = 0;
    for (frame, states) in traj.lights.iter().enumerate() {
        let t = frame as f64 * FRAME;
        assert_eq!(states.len(), lights.lights.len());
        for (l, state) in states.iter().enumerate() {
            let expected = if l == forced && t >= from && t < from + seconds {
                crate::map::signals::LightState { colour: Colour::Red, since_change: t - from }
            } else {
                lights.lights[l].state_at(t)
            };
            assert_eq!(*state, expected, "light {l} at {t:.1} s");
        }
        apart += (states[forced] != states[twins[forced]]) as usize;
    }
    assert!(apart > 0, "the forced light never showed otherwise than its twin: the override went unchecked");
}

#[test]
fn an_effects_rerun_never_tries_again_the_decisions_of_cars_driving_ahead_of_the_one_removed() {
    use super::replay::Recording;
    use crate::world::effects::{intervened, InterventionKind};
    // Blocks 96 m wide: A1w long enough that no car reaches its end.
    let map = CityMap::new(crate::map::MapLayout {
        north_south_roads: vec![('C', -48.0), ('D', 48.0)],
        extent_x: 100.0,
        ..Default::default()
    });
    let length = map.lanes[lane(&map, "A1w")].curve.length();
    assert!(length > 45.0, "A1w is {length} m: too short for four cars and 4 s");
    // Green throughout; car 3 drives last, behind the other three.
    let lights = lights_with(&map, &["A1w"], &[(Colour::Green, 100.0)]);
    let cars: Vec<Given> = [27.0, 19.0, 11.0, 3.0].iter().map(|&at| straight("A1w", at, 2.0)).collect();
    let factual_plan = plan(&map, &cars, lights, vec![], 4.0);
    let never = std::sync::atomic::AtomicBool::new(false);
    let city = factual_plan.world.city().expect("city plan");
    let recording = Recording::record(&map, &factual_plan, city, &never).expect("never stopped");
    assert!(recording.replayable());
    let changed = intervened(&map, &factual_plan, 3, InterventionKind::Remove).expect("a removal");
    let (rerun, replayed) = recording.rerun(&changed, 3, &never).expect("never stopped");
    // The three cars ahead read their lane, on which the removed car
    // stood, at every decision, but only ahead of themselves.
    assert!(replayed.car_steps > 0, "nothing was replayed: {replayed:?}");
    assert_eq!(replayed.tries, 0, "decisions of cars ahead were tried again: {replayed:?}");
    let full = simulate(&map, &changed);
    assert_eq!(rerun.states, full.states, "the replayed re-run differs from the full one");
    assert_eq!(rerun.interactions, full.interactions);
}
