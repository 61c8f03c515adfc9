//! The city map: continuity, spawn points, and which actions each spawn lane
//! allows, on the default city and on grids of other sizes.

use causalcity::map::{
    Action, AdaptationKind, CityMap, LaneEnd, LanePolicy, LanePosition, LegKind, MapLayout, Route, Turn,
};
use causalcity::spec::{GridSpec, MapSpec};

fn heading_diff(a: f64, b: f64) -> f64 {
    causalcity::map::curve::wrap_angle(a - b).abs()
}

/// A grid town as a spec's `map.grid` asks for it: `rows` east-west and
/// `columns` north-south roads, 30 m apart, each running 20 m beyond its
/// last crossing.
fn grid(rows: usize, columns: usize) -> MapLayout {
    let grid = GridSpec {
        rows: rows.into(),
        columns: columns.into(),
        block_m: 30.0,
        outer_m: 20.0,
        missing: Vec::new(),
        lanes: 2,
        control: Default::default(),
        dead_ends: Default::default(),
    };
    MapSpec { grid: Some(grid), ..MapSpec::default() }.layout()
}

/// The default city and grids of 1 x 1, 1 x 3, 3 x 2 and 4 x 4 junctions.
fn every_map() -> Vec<(String, CityMap)> {
    let mut maps = vec![("default".to_string(), CityMap::default())];
    for (rows, columns) in [(1, 1), (1, 3), (3, 2), (4, 4)] {
        maps.push((format!("{rows} x {columns} grid"), CityMap::new(grid(rows, columns))));
    }
    maps.push((
        "3 x 3 grid, one lane each way".into(),
        CityMap::new(MapLayout { lanes_per_direction: 1, ..grid(3, 3) }),
    ));
    maps.push(("2 x 3 grid, three lanes each way".into(), three_lane_town(2, 3, vec![])));
    maps
}

#[test]
fn every_connector_joins_its_lanes_continuously() {
    for (label, map) in every_map() {
        assert!(!map.connectors.is_empty(), "{label}");
        connectors_join(&map);
    }
}

fn connectors_join(map: &CityMap) {
    for c in &map.connectors {
        let from = &map.lanes[c.from].curve;
        let to = &map.lanes[c.to].curve;
        let gap_in = from.end().distance(c.curve.start());
        let gap_out = c.curve.end().distance(to.start());
        assert!(
            gap_in < 0.01 && gap_out < 0.01,
            "{:?} {} -> {}: gaps {gap_in} {gap_out}",
            c.turn,
            map.lanes[c.from].name,
            map.lanes[c.to].name
        );
        assert!(heading_diff(from.heading_at(from.length()), c.curve.heading_at(0.0)) < 1e-6);
        assert!(heading_diff(c.curve.heading_at(c.curve.length()), to.heading_at(0.0)) < 1e-6);
    }
}

#[test]
fn every_lane_has_a_way_on() {
    for (label, map) in every_map() {
        for (id, lane) in map.lanes.iter().enumerate() {
            match lane.end {
                LaneEnd::Loop(c) => assert_eq!(map.connectors[c].from, id),
                LaneEnd::Intersection { .. } => {
                    assert!(map.exit(id, Turn::Straight).is_some(), "{label}: {} has no straight exit", lane.name)
                }
            }
            assert!(map.connectors.iter().any(|c| c.to == id), "{label}: nothing leads into {}", lane.name);
        }
    }
}

#[test]
fn a_grid_of_any_size_has_every_junction_segment_and_turn_and_routes_drive_through_it() {
    let mut spawns = 0;
    for (rows, columns) in [(1, 1), (1, 3), (3, 2), (4, 4)] {
        let map = CityMap::new(grid(rows, columns));
        let label = format!("{rows} x {columns}");
        assert_eq!(map.intersections.len(), rows * columns, "{label}");
        // Each road has one segment more than the roads it crosses, 4 lanes each.
        assert_eq!(map.lanes.len(), 4 * (rows * (columns + 1) + columns * (rows + 1)), "{label}");
        for k in 0..map.intersections.len() {
            let arriving = map
                .lanes
                .iter()
                .filter(|l| matches!(l.end, LaneEnd::Intersection { intersection, .. } if intersection == k))
                .count();
            assert_eq!(arriving, 8, "{label}: junction {k} takes two lanes from each of four sides");
        }
        for (id, lane) in map.lanes.iter().enumerate() {
            if let LaneEnd::Intersection { .. } = lane.end {
                let turn = if lane.position == LanePosition::Outer { Turn::Right } else { Turn::Left };
                let mut expected = vec![Turn::Straight, turn];
                expected.sort_by_key(|t| *t != Turn::Left);
                assert_eq!(map.allowed_turns(id), expected, "{label}: {}", lane.name);
            }
        }
        // From every spawn point a route turning at every junction it meets
        // plans, and its legs join up.
        for spawn in map.spawn_points() {
            let actions = [Action::Left, Action::Straight, Action::Right, Action::Straight, Action::Left];
            let route = Route::plan(&map, spawn, 0.0, &actions, &[0.0; 5], 1000.0, &LanePolicy::Adapt)
                .unwrap_or_else(|e| panic!("{label}: from {}: {e}", map.lanes[spawn].name));
            assert!(route.length >= 1000.0);
            for w in route.legs.windows(2) {
                let end = w[0].curve.position(w[0].curve_start + w[0].length, 0.0);
                assert!(end.distance(w[1].curve.position(w[1].curve_start, 0.0)) < 0.01, "{label}");
            }
            spawns += 1;
        }
    }
    assert_eq!(spawns, 16 + 40 + 68 + 160);
}

#[test]
fn all_48_spawn_points_exist_with_the_original_names() {
    let map = CityMap::default();
    let mut names = Vec::new();
    for road in ['A', 'B', 'C', 'D'] {
        for segment in 0..3 {
            for lane in ['w', 'x', 'y', 'z'] {
                let name = format!("{road}{segment}{lane}");
                assert!(map.lane_by_name(&name).is_some(), "missing spawn point {name}");
                names.push(name);
            }
        }
    }
    assert_eq!(map.spawn_points().len(), 48);
    // Lanes of one direction are parallel and one lane width apart.
    for road in ['A', 'B', 'C', 'D'] {
        for segment in 0..3 {
            for (a, b) in [('w', 'x'), ('z', 'y')] {
                let la = &map.lanes[map.lane_by_name(&format!("{road}{segment}{a}")).unwrap()].curve;
                let lb = &map.lanes[map.lane_by_name(&format!("{road}{segment}{b}")).unwrap()].curve;
                let (_, lateral) = la.local_coordinates(lb.lane_center_at(1.0));
                assert!((lateral - map.layout.lane_width).abs() < 1e-9, "{road}{segment}{b} is not left of {a}");
            }
        }
    }
}

#[test]
fn every_action_from_every_spawn_lane_is_valid_or_rejected_with_a_reason() {
    let map = CityMap::default();
    for lane in map.spawn_points() {
        let name = map.lanes[lane].name.clone();
        let letter = map.lanes[lane].letter;
        let outer = letter == 'w' || letter == 'z';
        for action in Action::ALL {
            let merge_at = if action.is_merge() { 1.0 } else { 0.0 };
            let result = Route::plan(&map, lane, 0.0, &[action], &[merge_at], 100.0, &LanePolicy::Strict);
            let expected_ok = match action {
                Action::Straight => true,
                Action::Right | Action::MergeL => outer,
                Action::Left | Action::MergeR => !outer,
                // A grid town has no junction of five arms.
                Action::SlightLeft | Action::SlightRight => false,
            };
            match result {
                Ok(route) => {
                    assert!(expected_ok, "{name}: {action} should be rejected");
                    assert!(route.length >= 100.0);
                    if action.is_merge() {
                        assert!(route.kinds().any(|k| matches!(k, LegKind::LaneChange { .. })));
                    }
                }
                Err(e) => {
                    assert!(!expected_ok, "{name}: {action} rejected: {e}");
                    assert_eq!(e.action_index, 0);
                    // The lane named is where the turn is tried: the spawn lane, or the
                    // lane of the same road segment after the off-camera loop.
                    assert!(e.reason.contains(&name[..2]), "reason should name the lane: {e}");
                }
            }
        }
        // A merge past the lane end is rejected and says how far it may go.
        let merge = if outer { Action::MergeL } else { Action::MergeR };
        let err = Route::plan(&map, lane, 0.0, &[merge], &[500.0], 10.0, &LanePolicy::Strict).unwrap_err();
        assert!(err.reason.contains("past the lane end"), "{err}");
    }
}

#[test]
fn routes_are_continuous_and_never_run_out() {
    let map = CityMap::default();
    let queues: [&[Action]; 4] = [
        &[],
        &[Action::Straight, Action::Straight, Action::Straight, Action::Straight, Action::Straight],
        &[Action::MergeL, Action::Left, Action::MergeR, Action::Right, Action::Straight],
        &[Action::Right, Action::Right, Action::Right, Action::Right, Action::Right],
    ];
    for lane in map.spawn_points() {
        for queue in queues {
            let merges: Vec<f64> = queue.iter().map(|a| if a.is_merge() { 2.0 } else { 0.0 }).collect();
            let Ok(route) = Route::plan(&map, lane, 0.0, queue, &merges, 3000.0, &LanePolicy::Adapt) else {
                continue;
            };
            assert!(route.length >= 3000.0);
            // Sample the whole route: no jumps, no heading flips.
            let mut prev = route.pose_at(0.0, 0.0);
            let step = 0.05;
            let mut s = step;
            while s <= route.length {
                let here = route.pose_at(s, 0.0);
                let moved = here.0.distance(prev.0);
                assert!(
                    moved <= step * 1.0001 && moved > step * 0.9,
                    "jump of {moved} m at s={s} on {}",
                    map.lanes[lane].name
                );
                assert!(heading_diff(here.1, prev.1) < 0.1, "heading flip at s={s}");
                prev = here;
                s += step;
            }
        }
    }
}

/// Plans `actions` from the start of `lane` (merges at `merges`) adaptively.
fn adaptive(map: &CityMap, lane: &str, entry: f64, actions: &[Action], merges: &[f64]) -> Route {
    let spawn = map.lane_by_name(lane).unwrap();
    Route::plan(map, spawn, entry, actions, merges, 300.0, &LanePolicy::Adapt).expect("adaptive planning never fails")
}

#[test]
fn a_turn_from_the_wrong_lane_gets_a_lane_change_before_the_stop_line() {
    let map = CityMap::default();
    let setback = map.layout.stop_line_setback;
    for (lane, action, target) in
        [("A1w", Action::Left, "A1x"), ("A1x", Action::Right, "A1w"), ("C1z", Action::Left, "C1y")]
    {
        let route = adaptive(&map, lane, 0.0, &[action], &[0.0]);
        assert!(route.adaptations.is_empty(), "{lane} {action}: {:?}", route.adaptations);
        let legs: Vec<_> = route.legs.iter().collect();
        let k = legs.iter().position(|l| matches!(l.kind, LegKind::LaneChange { .. })).expect("a lane change");
        let LegKind::LaneChange { from, to, at } = legs[k].kind else { unreachable!() };
        assert_eq!(map.lanes[from].name, lane);
        assert_eq!(map.lanes[to].name, target);
        assert_eq!(legs[k].prepares, Some(0), "the change prepares the turn");
        assert_eq!(legs[k].action, None, "the change is no action of the queue");
        assert!(at >= 1.0 - 1e-9, "starts {at} m along, before the car could look");
        assert!(
            at + map.layout.lane_change_length <= map.lanes[from].curve.length() - setback + 1e-9,
            "the change must end before the stop line"
        );
        // Then the turn itself, from the target lane, carried out as action 0.
        let turn = legs[k + 1..].iter().find(|l| matches!(l.kind, LegKind::Connector(_))).unwrap();
        let LegKind::Connector(c) = turn.kind else { unreachable!() };
        assert_eq!(map.connectors[c].from, to);
        let expected = if action == Action::Left { Turn::Left } else { Turn::Right };
        assert_eq!(map.connectors[c].turn, expected);
        assert_eq!(turn.action, Some(0));
        // Strict planning rejects the same queue, naming the lane.
        let spawn = map.lane_by_name(lane).unwrap();
        let err = Route::plan(&map, spawn, 0.0, &[action], &[0.0], 300.0, &LanePolicy::Strict).unwrap_err();
        assert!(err.reason.contains("cannot turn") && err.reason.contains(lane), "{err}");
    }
}

#[test]
fn impossible_actions_are_adapted_or_skipped_never_silently() {
    let map = CityMap::default();
    let run = map.layout.lane_change_length;
    // mergeR from the outer lane: there is nothing to the right.
    let r = adaptive(&map, "D1w", 0.0, &[Action::MergeR, Action::Straight], &[2.0, 0.0]);
    assert_eq!(r.adaptations.len(), 1);
    assert_eq!(r.adaptations[0].kind, AdaptationKind::Skipped);
    assert!(r.adaptations[0].reason.contains("no lane to its right"), "{}", r.adaptations[0].reason);
    assert!(!r.kinds().any(|k| matches!(k, LegKind::LaneChange { .. })));
    assert!(r.skips(0) && !r.skips(1));
    // A merge distance past the lane end moves to the last feasible point.
    let len = map.lanes[map.lane_by_name("D1w").unwrap()].curve.length();
    let r = adaptive(&map, "D1w", 0.0, &[Action::MergeL], &[50.0]);
    assert_eq!(r.adaptations.len(), 1);
    assert_eq!(r.adaptations[0].kind, AdaptationKind::Adapted);
    let at = r.legs.iter().find_map(|l| match l.kind {
        LegKind::LaneChange { at, .. } => Some(at),
        _ => None,
    });
    assert!((at.unwrap() - (len - run)).abs() < 0.1 + 1e-9, "moved to {at:?}, lane {len} m");
    // A merge behind the car moves up to the car.
    let r = adaptive(&map, "A1w", 10.0, &[Action::MergeL], &[2.0]);
    assert_eq!(r.adaptations[0].kind, AdaptationKind::Adapted);
    assert!(r.adaptations[0].reason.contains("behind the car"));
    let at = r.legs.iter().find_map(|l| match l.kind {
        LegKind::LaneChange { at, .. } => Some(at),
        _ => None,
    });
    assert_eq!(at, Some(10.0));
    // A turn whose lane change has no room (the car starts near the stop
    // line, and came from no lane before) is skipped: straight on instead.
    let lane = map.lane_by_name("C1z").unwrap();
    let near_line = map.lanes[lane].curve.length() - map.layout.stop_line_setback - 1.0;
    let r = adaptive(&map, "C1z", near_line, &[Action::Left, Action::Right], &[0.0, 0.0]);
    assert_eq!(r.adaptations.len(), 1, "{:?}", r.adaptations);
    assert_eq!((r.adaptations[0].action_index, r.adaptations[0].kind), (0, AdaptationKind::Skipped));
    assert!(r.adaptations[0].reason.contains("no room"), "{}", r.adaptations[0].reason);
    let first_turn = r.legs.iter().find_map(|l| match l.kind {
        LegKind::Connector(c) if map.connectors[c].intersection.is_some() => Some((c, l.action)),
        _ => None,
    });
    let (c, action) = first_turn.unwrap();
    assert_eq!((map.connectors[c].turn, action), (Turn::Straight, Some(0)), "straight on, in place of action 0");
    // Strict planning rejects each of these.
    for (lane, entry, actions, merges) in [
        ("D1w", 0.0, vec![Action::MergeR], vec![2.0]),
        ("D1w", 0.0, vec![Action::MergeL], vec![50.0]),
        ("A1w", 10.0, vec![Action::MergeL], vec![2.0]),
    ] {
        let spawn = map.lane_by_name(lane).unwrap();
        assert!(Route::plan(&map, spawn, entry, &actions, &merges, 300.0, &LanePolicy::Strict).is_err());
    }
}

#[test]
fn a_turn_lane_change_with_no_room_moves_to_the_lane_before() {
    // East-west roads 20 m apart: the middle segments of C and D are 8 m,
    // too short for a lane change before their stop lines.
    let layout = MapLayout { east_west_roads: vec![('B', -10.0), ('A', 10.0)], ..MapLayout::default() };
    let map = CityMap::new(layout);
    let c1w = map.lane_by_name("C1w").unwrap();
    assert!(map.lanes[c1w].curve.length() < map.layout.lane_change_length + map.layout.stop_line_setback);
    let direct = adaptive(&map, "C1w", 0.0, &[Action::Left], &[0.0]);
    assert!(direct.skips(0), "no room on C1w itself: {:?}", direct.adaptations);
    // From C0w straight on through BC, then left at AC: the change into the
    // inner lane happens on C0w, before the straight move.
    let r = adaptive(&map, "C0w", 0.0, &[Action::Straight, Action::Left], &[0.0, 0.0]);
    assert!(r.adaptations.is_empty(), "{:?}", r.adaptations);
    let names: Vec<String> = r
        .kinds()
        .take(6)
        .map(|k| match k {
            LegKind::Lane(l) => map.lanes[l].name.clone(),
            LegKind::LaneChange { from, to, .. } => format!("{}->{}", map.lanes[from].name, map.lanes[to].name),
            LegKind::Connector(c) => format!("{:?}", map.connectors[c].turn),
        })
        .collect();
    assert_eq!(names, ["C0w", "C0w->C0x", "C0x", "Straight", "C1x", "Left"]);
    let change = r.legs.iter().find(|l| matches!(l.kind, LegKind::LaneChange { .. })).unwrap();
    assert_eq!((change.prepares, change.action), (Some(1), None));
    let left = r.legs.iter().find(|l| l.action == Some(1)).unwrap();
    assert!(matches!(left.kind, LegKind::Connector(c) if map.connectors[c].turn == Turn::Left));
}

/// A 3 x 3 grid without D0 (south of CD), B2 (between BE and BF) and E3
/// (north of AE): four T-junctions.
fn t_junction_town() -> CityMap {
    CityMap::new(MapLayout { missing_segments: vec![('D', 0), ('B', 2), ('E', 3)], ..grid(3, 3) })
}

#[test]
fn a_town_without_some_segments_has_t_junctions_whose_every_lane_leads_on() {
    let map = t_junction_town();
    assert_eq!(map.network_problem(), None);
    connectors_join(&map);
    // 6 roads of 4 segments of 4 lanes, less 3 segments.
    assert_eq!(map.lanes.len(), 96 - 3 * 4);
    assert!(map.lanes.iter().all(|l| !["D0", "B2", "E3"].contains(&&l.name[..2])));
    let name = |k: usize| map.intersections[k].name.as_str();
    let mut tees = Vec::new();
    for k in 0..map.intersections.len() {
        let sides = map.approaches(k);
        if sides.len() == 3 {
            tees.push(name(k));
        } else {
            assert_eq!(sides.len(), 4, "{}", name(k));
        }
    }
    tees.sort_unstable();
    assert_eq!(tees, ["AE", "BE", "BF", "CD"]);
    for (id, lane) in map.lanes.iter().enumerate() {
        // Every lane leads on, and something leads into it.
        assert!(map.exits_from(id).next().is_some(), "{} leads nowhere", lane.name);
        assert!(map.connectors.iter().any(|c| c.to == id), "nothing leads into {}", lane.name);
    }
    // The stem of CD (D1 southbound): no straight on; the outer lane turns right, the inner left.
    let lane = |n: &str| map.lane_by_name(n).unwrap();
    assert_eq!(map.allowed_turns(lane("D1z")), vec![Turn::Right]);
    assert_eq!(map.allowed_turns(lane("D1y")), vec![Turn::Left]);
    assert_eq!(map.default_turn(lane("D1z")), Turn::Right);
    // The bar of AE from the west: the inner lane's left (into E3) is gone.
    assert_eq!(map.allowed_turns(lane("A1x")), vec![Turn::Straight]);
    assert_eq!(map.allowed_turns(lane("A1w")), vec![Turn::Straight, Turn::Right]);
}

#[test]
fn routes_through_t_junctions_never_run_out_and_say_what_they_could_not_do() {
    let map = t_junction_town();
    let queues: [&[Action]; 4] = [
        &[],
        &[Action::Straight, Action::Straight, Action::Straight, Action::Straight, Action::Straight],
        &[Action::Left, Action::Straight, Action::Right, Action::Straight, Action::Left],
        &[Action::Right, Action::Right, Action::Right, Action::Right, Action::Right],
    ];
    let mut planned = 0;
    for spawn in map.spawn_points() {
        for queue in queues {
            let route = Route::plan(&map, spawn, 0.0, queue, &vec![0.0; queue.len()], 1500.0, &LanePolicy::Adapt)
                .unwrap_or_else(|e| panic!("from {}: {e}", map.lanes[spawn].name));
            assert!(route.length >= 1500.0);
            for w in route.legs.windows(2) {
                let end = w[0].curve.position(w[0].curve_start + w[0].length, 0.0);
                assert!(end.distance(w[1].curve.position(w[1].curve_start, 0.0)) < 0.01);
            }
            planned += 1;
        }
    }
    assert_eq!(planned, 84 * 4);
    // Straight on from the stem cannot be done: adapted with a reason, or refused when strict.
    let stem = map.lane_by_name("D1z").unwrap();
    let route = Route::plan(&map, stem, 0.0, &[Action::Straight], &[0.0], 200.0, &LanePolicy::Adapt).unwrap();
    assert!(route.adaptations.iter().any(|a| a.kind == AdaptationKind::Skipped), "{:?}", route.adaptations);
    assert!(Route::plan(&map, stem, 0.0, &[Action::Straight], &[0.0], 200.0, &LanePolicy::Strict).is_err());
}

#[test]
fn a_network_left_with_a_two_road_junction_or_in_two_parts_is_named_as_such() {
    // Without B0 and C0, junction BC keeps only B1 and C1.
    let corner = CityMap::new(MapLayout { missing_segments: vec![('B', 0), ('C', 0)], ..grid(2, 2) });
    let problem = corner.network_problem().expect("a two-road junction");
    assert!(problem.contains("junction BC would keep 2 roads"), "{problem}");
    // One road crossing two: without A1 between them the town is two towns.
    let split = CityMap::new(MapLayout { missing_segments: vec![('A', 1)], ..grid(1, 2) });
    let problem = split.network_problem().expect("two parts");
    assert!(problem.contains("falls apart"), "{problem}");
    // The full grids are whole.
    for (label, map) in every_map() {
        assert_eq!(map.network_problem(), None, "{label}");
    }
}

#[test]
fn one_lane_roads_turn_every_way_from_their_one_lane_and_routes_drive_through_them() {
    for missing in [vec![], vec![('D', 0), ('B', 2), ('E', 3)]] {
        let tees = !missing.is_empty();
        let map = CityMap::new(MapLayout { lanes_per_direction: 1, missing_segments: missing, ..grid(3, 3) });
        assert_eq!(map.network_problem(), None);
        connectors_join(&map);
        assert_eq!(map.lanes.len(), if tees { 48 - 6 } else { 48 }, "2 lanes per segment");
        assert!(map.lanes.iter().all(|l| (l.letter == 'w' || l.letter == 'z') && l.position == LanePosition::Single));
        // A road 6 m wide: its lanes' centres 1.5 m either side of the centre line.
        let lane = |n: &str| map.lane_by_name(n).unwrap();
        assert!((map.lanes[lane("B1w")].curve.start().y - -1.5).abs() < 1e-9);
        assert!((map.lanes[lane("B1z")].curve.start().y - 1.5).abs() < 1e-9);
        for (id, l) in map.lanes.iter().enumerate() {
            assert!(map.adjacent_lane(id, true).is_none() && map.adjacent_lane(id, false).is_none());
            if let LaneEnd::Intersection { .. } = l.end {
                if !tees {
                    assert_eq!(map.allowed_turns(id), vec![Turn::Left, Turn::Straight, Turn::Right], "{}", l.name);
                }
                assert!(!map.allowed_turns(id).is_empty(), "{}", l.name);
            }
        }
        let queues: [&[Action]; 3] = [
            &[],
            &[Action::Left, Action::Straight, Action::Right, Action::Left, Action::Left],
            &[Action::Right, Action::Right, Action::Straight, Action::Right, Action::Right],
        ];
        for spawn in map.spawn_points() {
            for queue in queues {
                let route = Route::plan(&map, spawn, 0.0, queue, &vec![0.0; queue.len()], 1500.0, &LanePolicy::Adapt)
                    .unwrap_or_else(|e| panic!("from {}: {e}", map.lanes[spawn].name));
                assert!(route.length >= 1500.0);
                // No lane changes on a one-lane road; every turn is done (on the full grid).
                assert!(!route.kinds().any(|k| matches!(k, LegKind::LaneChange { .. })));
                if !tees {
                    assert!(route.adaptations.is_empty(), "{:?}", route.adaptations);
                }
            }
            // A merge has no lane to go to: refused with the reason.
            let err = Route::plan(&map, spawn, 0.0, &[Action::MergeL], &[2.0], 100.0, &LanePolicy::Strict).unwrap_err();
            assert!(err.reason.contains("only lane of its direction"), "{err}");
        }
    }
}

/// A grid of three-lane roads 44 m apart (room for two lane changes before a turn).
fn three_lane_town(rows: usize, columns: usize, missing: Vec<(char, u8)>) -> CityMap {
    let spec = GridSpec {
        rows: rows.into(),
        columns: columns.into(),
        block_m: 44.0,
        outer_m: 34.0,
        missing: Vec::new(),
        lanes: 3,
        control: Default::default(),
        dead_ends: Default::default(),
    };
    let layout = MapSpec { grid: Some(spec), ..MapSpec::default() }.layout();
    CityMap::new(MapLayout { missing_segments: missing, ..layout })
}

#[test]
fn three_lane_roads_keep_their_middle_lane_straight_and_turns_take_two_lane_changes() {
    for missing in [vec![], vec![('C', 0), ('A', 1)]] {
        let tees = !missing.is_empty();
        let map = three_lane_town(2, 3, missing);
        assert_eq!(map.network_problem(), None);
        connectors_join(&map);
        let lane = |n: &str| map.lane_by_name(n).unwrap();
        // Kerb to kerb: w m x | y n z, 3 m apart (B, the southern road, at y = -22 m).
        let ys: Vec<f64> = ["B1w", "B1m", "B1x", "B1y", "B1n", "B1z"]
            .iter()
            .map(|n| map.lanes[lane(n)].curve.start().y + 22.0)
            .collect();
        for (y, want) in ys.iter().zip([-7.5, -4.5, -1.5, 1.5, 4.5, 7.5]) {
            assert!((y - want).abs() < 1e-9, "{ys:?}");
        }
        assert_eq!(map.adjacent_lane(lane("B1w"), true), Some(lane("B1m")));
        assert_eq!(map.adjacent_lane(lane("B1m"), true), Some(lane("B1x")));
        assert_eq!(map.adjacent_lane(lane("B1z"), true), Some(lane("B1n")));
        if tees {
            // Without C0, C1's lanes arriving at BC from the north are a T's stem;
            // without A1, so are A0's at AC. Their middle lanes turn either way.
            assert_eq!(map.allowed_turns(lane("C1n")), vec![Turn::Left, Turn::Right]);
            assert_eq!(map.allowed_turns(lane("A0m")), vec![Turn::Left, Turn::Right]);
            assert_eq!(map.allowed_turns(lane("C1z")), vec![Turn::Right]);
        } else {
            assert_eq!(map.allowed_turns(lane("B1m")), vec![Turn::Straight]);
            assert_eq!(map.allowed_turns(lane("B1w")), vec![Turn::Straight, Turn::Right]);
            assert_eq!(map.allowed_turns(lane("B1x")), vec![Turn::Left, Turn::Straight]);
            // Left from the kerb lane: two lane changes (w to m to x), then the turn.
            let route =
                Route::plan(&map, lane("B1w"), 0.0, &[Action::Left], &[0.0], 300.0, &LanePolicy::Adapt).unwrap();
            let changes = route.kinds().filter(|k| matches!(k, LegKind::LaneChange { .. })).count();
            assert_eq!(changes, 2, "{:?}", route.adaptations);
            assert!(route.adaptations.is_empty(), "{:?}", route.adaptations);
        }
        for spawn in map.spawn_points() {
            for queue in [&[][..], &[Action::Left, Action::Right, Action::Left, Action::Straight][..]] {
                let route = Route::plan(&map, spawn, 0.0, queue, &vec![0.0; queue.len()], 1500.0, &LanePolicy::Adapt)
                    .unwrap_or_else(|e| panic!("from {}: {e}", map.lanes[spawn].name));
                assert!(route.length >= 1500.0);
            }
        }
    }
}

#[test]
fn on_t_junction_towns_no_planned_action_is_one_the_road_cannot_do() {
    use causalcity::plan::Expansion;
    let mut cars = 0;
    for lanes in [1, 2, 3] {
        let grid = if lanes == 3 {
            r#""block_m": 44, "outer_m": 34, "lanes": 3"#.to_string()
        } else {
            format!(r#""lanes": {lanes}"#)
        };
        let text = format!(
            r#"{{"name": "tees", "world": "city", "seed": 9, "frames": 150,
                "groups": [{{"cars": 8, "edge_proportion": 0.5}}, {{"cars": 12, "edge_proportion": 0.5}}],
                "splits": {{"train": 60, "val": 0, "test": 0}},
                "map": {{"grid": {{"rows": 3, "columns": 3, "missing": ["D0", "B2", "E3"], {grid}}}}},
                "city": {{"start": {{"platoon_cars": 4}}}}}}"#
        );
        let expansion = Expansion::from_spec(causalcity::spec::DatasetSpec::from_json(&text).unwrap()).unwrap();
        for key in expansion.keys(None) {
            let plan = expansion.plan(&key).unwrap();
            for car in &plan.cars {
                // Drawn again where the junction lacks the movement, or planned
                // as the movement the car makes: never skipped before it starts.
                let skipped: Vec<_> =
                    car.route.adaptations.iter().filter(|a| a.kind == AdaptationKind::Skipped).collect();
                assert!(skipped.is_empty(), "{lanes} lanes, {}: {skipped:?}", car.name);
                cars += 1;
            }
        }
    }
    assert_eq!(cars, 3 * 60 * 20);
}

#[test]
fn junctions_without_lights_have_no_lights_and_rank_their_movements() {
    use causalcity::map::control::{Axis, JunctionControl};
    use causalcity::map::signals::{Signal, LIGHTS_PER_INTERSECTION};
    let full = CityMap::new(grid(3, 3));
    // AD without lights, and BE a priority T-junction (road B's segment 1,
    // west of E, left out: the bar is road E, north-south).
    let layout = MapLayout {
        junction_controls: vec![("AD".into(), JunctionControl::AllWayStop), ("BE".into(), JunctionControl::Priority)],
        missing_segments: vec![('B', 1)],
        ..grid(3, 3)
    };
    let map = CityMap::new(layout);
    assert_eq!(map.light_count(), full.light_count() - 2 * LIGHTS_PER_INTERSECTION);
    let k = |name: &str| map.intersections.iter().position(|x| x.name == name).unwrap();
    assert_eq!(map.intersections[k("AD")].control, JunctionControl::AllWayStop);
    assert_eq!(map.intersections[k("BE")].major, Axis::NorthSouth, "a T's bar is its priority road");
    assert_eq!(map.intersections[k("AE")].control, JunctionControl::Signals);
    assert!(map.light_index(k("AD"), 'N', Signal::Straight).is_none());
    assert!(map.light_by_name("AD/N/straight").unwrap_err().contains("has no traffic lights"));
    // Every light's name leads back to it, and the lights of the junctions
    // that have them keep their order.
    let mut checked = 0;
    for index in 0..map.light_count() {
        assert_eq!(map.light_by_name(&map.light_name(index)), Ok(index));
        checked += 1;
    }
    assert_eq!(checked, 7 * LIGHTS_PER_INTERSECTION);
    // At the priority junction the bar's straight movements come before the
    // stem's turns, and nobody on the bar going straight gives way.
    let mut ranked = 0;
    for (c, connector) in map.connectors.iter().enumerate().filter(|(_, x)| x.intersection == Some(k("BE"))) {
        let major = Axis::NorthSouth.holds(map.approach_of(c).unwrap());
        assert_eq!(map.gives_way(c), !(major && connector.turn != Turn::Left), "{connector:?}");
        for &other in map.conflicts(c) {
            let other_major = Axis::NorthSouth.holds(map.approach_of(other).unwrap());
            if major && !other_major {
                assert!(map.right_of_way(c) < map.right_of_way(other));
                ranked += 1;
            }
        }
    }
    assert!(ranked > 0, "no conflict between the bar and the stem");
    // Every movement of an all-way stop gives way.
    assert!(map
        .connectors
        .iter()
        .enumerate()
        .filter(|(_, x)| x.intersection == Some(k("AD")))
        .all(|(c, _)| map.gives_way(c)));
}

#[test]
fn a_dead_end_turns_back_in_a_loop_short_of_the_junction_it_leaves() {
    // 3 x 3, 40 m blocks: B2 stays joined to BE and ends before BF.
    let spec = GridSpec {
        rows: 3.into(),
        columns: 3.into(),
        block_m: 40.0,
        outer_m: 22.0,
        missing: Vec::new(),
        lanes: 2,
        control: Default::default(),
        dead_ends: [("B2".to_string(), "BE".to_string())].into(),
    };
    let map = CityMap::new(MapSpec { grid: Some(spec), ..MapSpec::default() }.layout());
    assert_eq!(map.network_problem(), None);
    let k = |name: &str| map.intersections.iter().position(|x| x.name == name).unwrap();
    assert_eq!(map.approaches(k("BF")).len(), 3, "BF loses its west arm");
    assert_eq!(map.approaches(k("BE")).len(), 4, "BE keeps all four");
    // Eastbound B2 lanes turn back in a loop onto the westbound ones, which run to BE.
    let mut looped = 0;
    for letter in ['w', 'x'] {
        let lane = map.lane_by_name(&format!("B2{letter}")).unwrap();
        let LaneEnd::Loop(c) = map.lanes[lane].end else { panic!("B2{letter} does not end in a loop") };
        let back = &map.lanes[map.connectors[c].to];
        assert_eq!(back.name[..2], *"B2");
        assert!(matches!(back.end, LaneEnd::Intersection { intersection, approach: 'E' } if intersection == k("BE")));
        // The loop turns back before BF's box (x = 40 - 6) and its pavement.
        let reach = map.connectors[c].curve.position(map.connectors[c].curve.length() / 2.0, 0.0).x;
        assert!(reach < 40.0 - 6.0 - 2.0 + 1e-9, "the loop reaches x = {reach}");
        looped += 1;
    }
    assert_eq!(looped, 2);
    // No movement at BF leads into B2.
    for (c, connector) in map.connectors.iter().enumerate() {
        if connector.intersection == Some(k("BF")) {
            assert_ne!(&map.lanes[connector.to].name[..2], "B2", "connector {c} enters the dead end from BF");
        }
    }
}
