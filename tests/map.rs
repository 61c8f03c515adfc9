//! The city map: continuity, spawn points, and which actions each spawn lane allows.

use causalcity::map::{Action, CityMap, LaneEnd, LegKind, Route, Turn};

fn heading_diff(a: f64, b: f64) -> f64 {
    causalcity::map::curve::wrap_angle(a - b).abs()
}

#[test]
fn every_connector_joins_its_lanes_continuously() {
    let map = CityMap::default();
    assert!(!map.connectors.is_empty());
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
    let map = CityMap::default();
    for (id, lane) in map.lanes.iter().enumerate() {
        match lane.end {
            LaneEnd::Loop(c) => assert_eq!(map.connectors[c].from, id),
            LaneEnd::Intersection { .. } => {
                assert!(map.exit(id, Turn::Straight).is_some(), "{} has no straight exit", lane.name)
            }
        }
        assert!(map.connectors.iter().any(|c| c.to == id), "nothing leads into {}", lane.name);
    }
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
            let result = Route::plan(&map, lane, 0.0, &[action], &[merge_at], 100.0);
            let expected_ok = match action {
                Action::Straight => true,
                Action::Right | Action::MergeL => outer,
                Action::Left | Action::MergeR => !outer,
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
        let err = Route::plan(&map, lane, 0.0, &[merge], &[500.0], 10.0).unwrap_err();
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
            let Ok(route) = Route::plan(&map, lane, 0.0, queue, &merges, 3000.0) else {
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
