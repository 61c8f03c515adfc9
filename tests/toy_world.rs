//! Toy-world invariants, read back from the written poses.csv.

mod common;
use common::*;

#[test]
fn every_car_moves_exactly_the_toy_speed_every_frame() {
    let out = shared_image_dataset();
    for d in scenario_dirs(&out) {
        let s = read_scenario(&d);
        let ppm = s.camera.pixels_per_metre;
        let speed_px = s.toy.as_ref().unwrap().speed_px_per_frame;
        assert_eq!(speed_px, 2.0);
        let poses = read_poses(&d.join("poses.csv"));
        assert_eq!(poses.len(), (s.frames as usize) * s.cars.len());
        for (car, track) in poses_by_car(&poses) {
            assert_eq!(track.len(), s.frames as usize);
            for w in track.windows(2) {
                let step = ((w[1].px - w[0].px).powi(2) + (w[1].py - w[0].py).powi(2)).sqrt();
                // Chords on the tightest (1.5 m) turns are 0.001 px shorter than the arc.
                assert!((step - 2.0).abs() < 0.01, "{} car {car} frame {}: moved {step} px", d.display(), w[1].frame);
                let logged = w[1].speed * s.frame_interval * ppm;
                assert!((logged - 2.0).abs() < 1e-3, "speed column says {logged} px/frame");
                assert!((w[1].t - w[1].frame as f64 * s.frame_interval).abs() < 1e-9);
            }
        }
    }
}

#[test]
fn followers_trail_their_leaders_by_exactly_the_gap() {
    let out = shared_image_dataset();
    let mut pairs_checked = 0;
    for d in scenario_dirs(&out) {
        let s = read_scenario(&d);
        let toy = s.toy.as_ref().unwrap();
        assert_eq!(toy.leader_gap_px, 30.0);
        let lag = (toy.leader_gap_px / toy.speed_px_per_frame).round() as usize;
        assert_eq!(lag, 15);
        let by_car = poses_by_car(&read_poses(&d.join("poses.csv")));
        for [l, f] in &s.edges {
            let (leader, follower) = (&by_car[l], &by_car[f]);
            // At the start both are on the straight spawn lane, 30 px apart.
            let d0 = ((leader[0].px - follower[0].px).powi(2) + (leader[0].py - follower[0].py).powi(2)).sqrt();
            assert!((d0 - 30.0).abs() < 0.005, "start gap {d0} px");
            for t in lag..leader.len() {
                let (a, b) = (&follower[t], &leader[t - lag]);
                assert!(
                    (a.px - b.px).abs() < 0.002 && (a.py - b.py).abs() < 0.002,
                    "frame {t}: follower {a:?} leader {b:?}"
                );
                assert!((a.x - b.x).abs() < 2e-4 && (a.y - b.y).abs() < 2e-4);
                assert!(causalcity::map::curve::wrap_angle(a.yaw - b.yaw).abs() < 1e-5);
                // Distance along the path = the leader's travel over the lag.
                let along: f64 = (t - lag..t)
                    .map(|k| {
                        ((leader[k + 1].px - leader[k].px).powi(2) + (leader[k + 1].py - leader[k].py).powi(2)).sqrt()
                    })
                    .sum();
                assert!((along - 30.0).abs() < 0.05, "path gap {along} px at frame {t}");
            }
            pairs_checked += 1;
        }
    }
    assert!(pairs_checked >= 8, "checked {pairs_checked} pairs");
}

#[test]
fn poses_are_physical_and_in_range() {
    let out = shared_image_dataset();
    for d in scenario_dirs(&out) {
        for p in read_poses(&d.join("poses.csv")) {
            assert_eq!((p.z, p.roll, p.pitch), (0.0, 0.0, 0.0));
            assert!(p.yaw.abs() <= std::f64::consts::PI + 1e-6);
            // The map spans about +-60 m; nothing flies off.
            assert!(p.x.abs() < 70.0 && p.y.abs() < 70.0, "{p:?}");
            let on_image = p.px >= -0.5 && p.px < 1023.5 && p.py >= -0.5 && p.py < 639.5;
            assert_eq!(p.in_view == 1, on_image, "{p:?}");
        }
    }
}

/// The toy's follower follows: with its leader's next action changed, it
/// still trails the leader by exactly the gap along the leader's new path
/// (and leaves its old one); with its leader removed it stands still.
#[test]
fn a_toy_follower_follows_its_leader_under_interventions() {
    use causalcity::plan::Expansion;
    use causalcity::world::effects::{intervened, InterventionKind};
    let spec = causalcity::spec::DatasetSpec::from_json(&toy_spec("follows", &[(8, 0.5)], (16, 2, 2), 150)).unwrap();
    let expansion = Expansion::from_spec(spec).unwrap();
    let map = &expansion.map;
    let lag = 15;
    let (mut diverted, mut pairs) = (0, 0);
    for key in expansion.keys(None) {
        let plan = expansion.plan(&key).unwrap();
        let factual = causalcity::world::simulate(map, &plan);
        for &(leader, follower) in &plan.edges {
            let (l, f) = (leader as usize, follower as usize);
            pairs += 1;
            let changed = intervened(map, &plan, l, InterventionKind::NextAction).expect("toy cars have actions");
            let rerun = causalcity::world::simulate(map, &changed);
            for t in lag..rerun.frames() {
                let gap = rerun.states[t][f].position.distance(rerun.states[t - lag][l].position);
                assert!(gap < 1e-6, "{key:?}: follower {f} is {gap} m off its leader's path at frame {t}");
            }
            let moved =
                (0..rerun.frames()).any(|t| rerun.states[t][f].position.distance(factual.states[t][f].position) > 0.5);
            diverted += moved as usize;
            let removed =
                causalcity::world::simulate(map, &intervened(map, &plan, l, InterventionKind::Remove).unwrap());
            let start = factual.states[0][f].position;
            assert!(removed.states.iter().all(|frame| frame[f].position == start && frame[f].speed == 0.0));
        }
    }
    assert!(pairs >= 30, "{pairs} pairs");
    // Most leaders reach their next turn in time for the follower to take it too.
    assert!(diverted * 2 > pairs, "only {diverted} of {pairs} followers took the changed turn");
}
