//! The city world, checked from its written files: lights obeyed, no
//! unexplained overlaps, kinematic limits, planned lane sequences,
//! determinism, confounders that act, and the dataset-level behaviour the
//! default design promises.

mod common;
use causalcity::geometry::OrientedBox;
use causalcity::map::{curve::wrap_angle, CityMap, LaneEnd, LegKind};
use common::*;
use glam::DVec2;
use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;
use std::sync::Mutex;

static DATASET: Mutex<Option<PathBuf>> = Mutex::new(None);

/// A city dataset with many red-light runners and mixed weather, no images.
fn dataset() -> PathBuf {
    let mut guard = DATASET.lock().unwrap();
    if let Some(p) = guard.as_ref() {
        return p.clone();
    }
    let dir = fresh_dir(&format!("city-{}", std::process::id()));
    let city = r#"{"red_light_runner_probability": 0.15,
                   "confounders": {"wetness": {"choice": [0, 1]}, "rain": {"choice": [0, 0.5]}, "hour": {"uniform": [5, 23]}}}"#;
    let spec = write_spec(&dir, &city_spec("city", &[(12, 0.5), (8, 0.8)], (40, 0, 0), 150, city));
    let out = dir.join("out");
    gen_ok(&spec, &out, &["--no-images", "--quiet"]);
    *guard = Some(out.clone());
    out
}

fn front(p: &Pose, length: f64) -> DVec2 {
    DVec2::new(p.x, p.y) + DVec2::new(p.yaw.cos(), p.yaw.sin()) * length / 2.0
}

fn footprint(p: &Pose, car: &Car, shrink: f64) -> OrientedBox {
    OrientedBox {
        centre: DVec2::new(p.x, p.y),
        heading: p.yaw,
        length: car.length_m - 2.0 * shrink,
        width: car.width_m - 2.0 * shrink,
    }
}

/// The lane a point lies on (centre within `tolerance` of the centre line,
/// heading within 30 degrees), if any.
fn lane_at(map: &CityMap, p: DVec2, yaw: f64, tolerance: f64) -> Option<usize> {
    map.lanes.iter().position(|l| {
        let (s, lat) = l.curve.local_coordinates(p);
        s >= -0.01
            && s <= l.curve.length() + 0.01
            && lat.abs() <= tolerance
            && wrap_angle(l.curve.heading_at(s) - yaw).abs() < 0.5
    })
}

#[test]
fn no_car_enters_an_intersection_against_red_unless_forced() {
    let out = dataset();
    let map = CityMap::default();
    let setback = map.layout.stop_line_setback;
    let (mut crossings, mut forced_runs) = (0, 0);
    for d in scenario_dirs(&out) {
        let s = read_scenario(&d);
        let by_car = poses_by_car(&read_poses(&d.join("poses.csv")));
        let lights: BTreeMap<(u32, String, String, String), String> =
            light_rows(&d).into_iter().map(|l| ((l.frame, l.intersection, l.approach, l.signal), l.colour)).collect();
        let events: Vec<EventRow> = read_csv(&d.join("events.csv"));
        for (car_id, track) in &by_car {
            let car = &s.cars[*car_id as usize];
            // The movement the car makes after each lane, from its plan.
            let route = planned_route(&map, &s.cars, *car_id, &events);
            let legs: Vec<LegKind> = route.kinds().collect();
            let signal_after = |lane: usize| -> Option<&'static str> {
                legs.windows(2).find_map(|w| match (w[0], w[1]) {
                    (LegKind::Lane(l), LegKind::Connector(c)) if l == lane => {
                        Some(if map.connectors[c].turn == causalcity::map::Turn::Left { "left" } else { "straight" })
                    }
                    _ => None,
                })
            };
            for f in 1..track.len() {
                let (a, b) = (&track[f - 1], &track[f]);
                let (fa, fb) = (front(a, car.length_m), front(b, car.length_m));
                for lane in &map.lanes {
                    let LaneEnd::Intersection { intersection, approach } = lane.end else { continue };
                    let len = lane.curve.length();
                    let (sa, lat_a) = lane.curve.local_coordinates(fa);
                    let (sb, _) = lane.curve.local_coordinates(fb);
                    let line = len - setback;
                    if !(sa < line && sb >= line && lat_a.abs() < 1.5) {
                        continue;
                    }
                    if wrap_angle(lane.curve.heading_at(len) - a.yaw).abs() > 0.5 {
                        continue;
                    }
                    crossings += 1;
                    let lane_id = map.lane_by_name(&lane.name).unwrap();
                    let signal = signal_after(lane_id).unwrap_or_else(|| {
                        panic!(
                            "{}: car {car_id} crossed the stop line of {} at frame {}, not on its planned route {:?}",
                            d.display(),
                            lane.name,
                            b.frame,
                            route.kinds().collect::<Vec<_>>()
                        )
                    });
                    let name = &map.intersections[intersection].name;
                    let colour = &lights[&(a.frame, name.clone(), approach.to_string(), signal.to_string())];
                    if colour == "red" {
                        assert!(
                            car.runs_red_lights,
                            "{}: car {car_id} entered {name} from {approach} via {} ({sa:.3} -> {sb:.3}, line {line:.3}) on red at frame {} without being forced",
                            d.display(),
                            lane.name,
                            b.frame
                        );
                        let logged = events.iter().any(|e| {
                            e.kind == "red_light_run" && e.car == Some(*car_id) && e.frame.abs_diff(b.frame) <= 1
                        });
                        assert!(
                            logged,
                            "{}: red-light run of car {car_id} at frame {} not in events.csv",
                            d.display(),
                            b.frame
                        );
                        forced_runs += 1;
                    }
                }
            }
        }
        for e in events.iter().filter(|e| e.kind == "red_light_run") {
            assert!(
                s.cars[e.car.expect("a red-light run names its car") as usize].runs_red_lights
                    && e.detail.ends_with("(forced)"),
                "{e:?}"
            );
        }
    }
    assert!(crossings > 100, "only {crossings} stop-line crossings seen");
    assert!(forced_runs > 0, "the sample should contain forced red-light runs");
}

#[test]
fn cars_overlap_only_after_a_logged_collision() {
    let out = dataset();
    let mut collisions = 0;
    for d in scenario_dirs(&out) {
        let s = read_scenario(&d);
        let poses = read_poses(&d.join("poses.csv"));
        let events: Vec<EventRow> = read_csv(&d.join("events.csv"));
        let mut logged: BTreeMap<(u32, u32), u32> = BTreeMap::new();
        for e in events.iter().filter(|e| e.kind == "collision") {
            let other = e.other_car.expect("a collision names the other car");
            let car = e.car.expect("a collision names its car");
            logged.entry((car.min(other), car.max(other))).or_insert(e.frame);
            collisions += 1;
        }
        let mut frame_poses: BTreeMap<u32, Vec<&Pose>> = BTreeMap::new();
        for p in &poses {
            frame_poses.entry(p.frame).or_default().push(p);
        }
        for (frame, ps) in frame_poses {
            for i in 0..ps.len() {
                for j in i + 1..ps.len() {
                    let (a, b) = (ps[i], ps[j]);
                    let boxes =
                        (footprint(a, &s.cars[a.car as usize], 0.005), footprint(b, &s.cars[b.car as usize], 0.005));
                    if boxes.0.overlaps(&boxes.1) {
                        let key = (a.car.min(b.car), a.car.max(b.car));
                        let at = logged.get(&key);
                        assert!(
                            at.is_some_and(|&f| f <= frame),
                            "{}: cars {} and {} overlap at frame {frame} with no collision logged before",
                            d.display(),
                            a.car,
                            b.car
                        );
                    }
                }
            }
        }
    }
    eprintln!("collisions in the sample: {collisions}");
}

#[test]
fn speeds_accelerations_and_positions_stay_physical() {
    let out = dataset();
    let map = CityMap::default();
    for d in scenario_dirs(&out) {
        let s = read_scenario(&d);
        let events: Vec<EventRow> = read_csv(&d.join("events.csv"));
        let crashed: BTreeSet<(u32, u32)> = events
            .iter()
            .filter(|e| e.kind == "collision")
            .flat_map(|e| [(e.car.unwrap(), e.frame), (e.other_car.unwrap(), e.frame)])
            .collect();
        let dt = s.frame_interval;
        for (car_id, track) in poses_by_car(&read_poses(&d.join("poses.csv"))) {
            let car = &s.cars[car_id as usize];
            let top = car.desired_speeds.iter().copied().fold(0.0, f64::max);
            for (f, p) in track.iter().enumerate() {
                assert!(
                    p.speed >= 0.0 && p.speed <= top * 1.02 + 0.01,
                    "{}: car {car_id} speed {}",
                    d.display(),
                    p.speed
                );
                // On a lane, a connector or between two lanes while merging.
                let pos = DVec2::new(p.x, p.y);
                let on_lane = map.lanes.iter().any(|l| {
                    let (s, lat) = l.curve.local_coordinates(pos);
                    s >= -0.5 && s <= l.curve.length() + 0.5 && lat.abs() <= map.layout.lane_width / 2.0 + 0.01
                });
                let on_connector = map.connectors.iter().any(|c| {
                    let (s, lat) = c.curve.local_coordinates(pos);
                    s >= -0.5 && s <= c.curve.length() + 0.5 && lat.abs() <= map.layout.lane_width / 2.0
                });
                assert!(on_lane || on_connector, "{}: car {car_id} off the road at {pos:?}", d.display());
                if f == 0 {
                    continue;
                }
                let prev = &track[f - 1];
                let accel = (p.speed - prev.speed) / dt;
                let collided = crashed.contains(&(car_id, p.frame));
                assert!(
                    accel <= car.driver.as_ref().unwrap().max_acceleration + 1e-3,
                    "{}: car {car_id} accelerates {accel}",
                    d.display()
                );
                assert!(
                    collided || accel >= -car.driver.as_ref().unwrap().max_deceleration - 1e-3,
                    "{}: car {car_id} brakes {accel} beyond its limit {} at frame {}",
                    d.display(),
                    car.driver.as_ref().unwrap().max_deceleration,
                    p.frame
                );
                let moved = DVec2::new(p.x - prev.x, p.y - prev.y);
                let heading = DVec2::new(prev.yaw.cos(), prev.yaw.sin());
                assert!(
                    moved.dot(heading) >= -0.01,
                    "{}: car {car_id} moves backwards at frame {}",
                    d.display(),
                    p.frame
                );
            }
        }
    }
}

#[test]
fn lane_sequences_follow_the_action_lists() {
    let out = dataset();
    let map = CityMap::default();
    let mut merges_seen = 0;
    for d in scenario_dirs(&out).into_iter().take(25) {
        let s = read_scenario(&d);
        let events: Vec<EventRow> = read_csv(&d.join("events.csv"));
        for (car_id, track) in poses_by_car(&read_poses(&d.join("poses.csv"))) {
            let route = planned_route(&map, &s.cars, car_id, &events);
            let mut planned: Vec<usize> = Vec::new();
            for kind in route.kinds() {
                let lane = match kind {
                    LegKind::Lane(l) => l,
                    LegKind::LaneChange { to, .. } => to,
                    LegKind::Connector(_) => continue,
                };
                if planned.last() != Some(&lane) {
                    planned.push(lane);
                }
            }
            let mut seen: Vec<usize> = Vec::new();
            for p in &track {
                if let Some(lane) = lane_at(&map, DVec2::new(p.x, p.y), p.yaw, 0.6) {
                    if seen.last() != Some(&lane) {
                        seen.push(lane);
                    }
                }
            }
            let names = |v: &[usize]| v.iter().map(|&l| map.lanes[l].name.clone()).collect::<Vec<_>>();
            assert!(
                planned.starts_with(&seen),
                "{}: car {car_id} drove {:?}, planned {:?}",
                d.display(),
                names(&seen),
                names(&planned)
            );
            merges_seen += seen
                .windows(2)
                .filter(|w| {
                    map.lanes[w[0]].road == map.lanes[w[1]].road && map.lanes[w[0]].segment == map.lanes[w[1]].segment
                })
                .count();
        }
    }
    assert!(merges_seen > 5, "only {merges_seen} merges observed");
}

#[test]
fn same_spec_same_bytes_for_any_thread_count() {
    let dir = fresh_dir("city-determinism");
    let city = r#"{"confounders": {"rain": 0.6, "wetness": 0.8, "hour": 21}}"#;
    let spec = write_spec(&dir, &city_spec("det", &[(8, 0.5)], (2, 1, 1), 30, city));
    let a = dir.join("j1");
    let b = dir.join("j2");
    gen_ok(&spec, &a, &["--quiet", "-j", "1"]);
    gen_ok(&spec, &b, &["--quiet", "-j", "2"]);
    let (ha, hb) = (hash_tree(&a), hash_tree(&b));
    assert!(ha.keys().any(|k| k.ends_with("light_changes.csv")) && ha.keys().any(|k| k.contains("rgb/")));
    assert_eq!(ha, hb);
}

fn speed_and_collisions(dir: &std::path::Path) -> (f64, usize) {
    let (mut sum, mut n, mut crashes) = (0.0, 0, 0);
    for d in scenario_dirs(dir) {
        for p in read_poses(&d.join("poses.csv")) {
            sum += p.speed;
            n += 1;
        }
        let events: Vec<EventRow> = read_csv(&d.join("events.csv"));
        crashes += events.iter().any(|e| e.kind == "collision") as usize;
    }
    (sum / n as f64, crashes)
}

#[test]
fn wet_roads_slow_traffic_and_do_not_make_it_safer() {
    let dir = fresh_dir("city-wetness");
    let mut results = Vec::new();
    for wetness in [0, 1] {
        let city = format!(r#"{{"confounders": {{"wetness": {wetness}}}}}"#);
        let spec = dir.join(format!("wet{wetness}.json"));
        std::fs::write(&spec, city_spec(&format!("wet{wetness}"), &[(12, 0.5)], (150, 0, 0), 150, &city)).unwrap();
        let out = dir.join(format!("wet{wetness}"));
        gen_ok(&spec, &out, &["--quiet", "--no-images"]);
        results.push(speed_and_collisions(&out));
    }
    let (dry, wet) = (results[0], results[1]);
    eprintln!("dry: {:.3} m/s, {} collision scenarios; wet: {:.3} m/s, {}", dry.0, dry.1, wet.0, wet.1);
    assert!(wet.0 < dry.0 * 0.97, "wet roads should slow traffic: {} vs {}", wet.0, dry.0);
    assert!(wet.1 >= dry.1, "wet roads should not have fewer collisions: {} vs {}", wet.1, dry.1);
}

/// Runs of consecutive `true`s, longest.
fn longest_run(flags: impl Iterator<Item = bool>) -> usize {
    let (mut run, mut best) = (0, 0);
    for f in flags {
        run = if f { run + 1 } else { 0 };
        best = best.max(run);
    }
    best
}

#[test]
fn the_default_city_design_shows_agency_and_confounding() {
    let dir = fresh_dir("city-default");
    let out = dir.join("out");
    let spec = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/city.json");
    gen_ok(&spec, &out, &["--quiet", "--no-images", "--limit", "12"]);
    let (mut speed, mut n, mut seen) = (0.0, 0, 0);
    let (mut cars, mut stopped) = (0, 0);
    let mut driven = Vec::new();
    let mut cvs = Vec::new();
    let (mut dry, mut dry_crashes) = (0, 0);
    for d in scenario_dirs(&out) {
        let s = read_scenario(&d);
        assert_eq!((s.frames, s.frame_interval), (150, 1.0), "{}", d.display());
        let still_frames = (5.0 / s.frame_interval).ceil() as usize;
        let by_car = poses_by_car(&read_poses(&d.join("poses.csv")));
        for track in by_car.values() {
            speed += track.iter().map(|p| p.speed).sum::<f64>();
            n += track.len();
            seen += track.iter().filter(|p| p.in_view == 1).count();
            driven.push(
                track.windows(2).map(|w| ((w[1].x - w[0].x).powi(2) + (w[1].y - w[0].y).powi(2)).sqrt()).sum::<f64>(),
            );
            cars += 1;
            // Standing (under 0.1 m/s) for 5 s or more.
            stopped += (longest_run(track.iter().map(|p| p.speed < 0.1)) >= still_frames) as usize;
        }
        for [l, f] in &s.edges {
            let gaps: Vec<f64> = by_car[l]
                .iter()
                .zip(&by_car[f])
                .map(|(a, b)| ((a.x - b.x).powi(2) + (a.y - b.y).powi(2)).sqrt())
                .collect();
            let mean = gaps.iter().sum::<f64>() / gaps.len() as f64;
            let sd = (gaps.iter().map(|g| (g - mean).powi(2)).sum::<f64>() / gaps.len() as f64).sqrt();
            cvs.push(sd / mean);
        }
        let mut changes: BTreeMap<(String, String, String), (String, usize)> = BTreeMap::new();
        for l in light_rows(&d) {
            let entry = changes.entry((l.intersection, l.approach, l.signal)).or_insert((l.colour.clone(), 0));
            if entry.0 != l.colour {
                entry.0 = l.colour;
                entry.1 += 1;
            }
        }
        assert!(changes.values().all(|(_, c)| *c >= 2), "{}: a light changed fewer than twice", d.display());
        if s.city.as_ref().unwrap()["confounders"]["wetness"].as_f64().unwrap() == 0.0 {
            dry += 1;
            dry_crashes += read_csv::<EventRow>(&d.join("events.csv")).iter().any(|e| e.kind == "collision") as usize;
        }
    }
    let mean_speed = speed / n as f64;
    let on_camera = seen as f64 / n as f64;
    driven.sort_by(f64::total_cmp);
    let median_driven = driven[driven.len() / 2];
    cvs.sort_by(f64::total_cmp);
    let median_cv = cvs[cvs.len() / 2];
    let stop_share = stopped as f64 / cars as f64;
    eprintln!(
        "mean {mean_speed:.2} m/s, median {median_driven:.0} m driven, {on_camera:.3} of car-frames on camera, {stop_share:.2} of cars stop, median gap CV {median_cv:.2}, dry collisions {dry_crashes}/{dry}"
    );
    // Issue 23: 150 frames at 1 Hz as the paper samples, so cars pass
    // intersections and choose turns within the scene (the roads C and D
    // are 48 m apart; at 0.2 s frames the median car drove 25 m), and stay
    // on camera (>= 85 % of car-frames; 91-92 % on 200 scenarios per split).
    assert!(median_driven >= 96.0, "the median car drives {median_driven:.0} m in the scene");
    assert!(on_camera >= 0.85, "{:.1} % of car-frames on camera", 100.0 * on_camera);
    assert!((0.5..=1.8).contains(&mean_speed), "mean speed {mean_speed:.2} m/s");
    assert!(stop_share >= 0.25, "only {stop_share} of cars stop");
    assert!(median_cv >= 0.2, "leader-follower gaps barely vary: median CV {median_cv}");
    assert!((dry_crashes as f64) < 0.05 * dry as f64, "{dry_crashes} of {dry} dry scenarios have collisions");
}

#[test]
fn in_the_default_city_drivers_change_lanes_for_their_turns_and_turn_from_the_right_lane() {
    let dir = fresh_dir("city-default-lanes");
    let spec = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/city.json");
    gen_ok(&spec, &dir, &["--no-images", "--quiet", "--limit", "4"]);
    let (mut cars, mut changers, mut turns) = (0usize, 0usize, 0usize);
    for d in scenario_dirs(&dir) {
        let s = read_scenario(&d);
        cars += s.cars.len();
        let events: Vec<EventRow> = read_csv(&d.join("events.csv"));
        let changed: BTreeSet<u32> = events.iter().filter(|e| e.kind == "lane_change").filter_map(|e| e.car).collect();
        changers += changed.len();
        for e in events.iter().filter(|e| e.kind == "turn_done") {
            // "left at AD from A1x": the lane the car turned from allows the turn.
            let words: Vec<&str> = e.detail.split(' ').collect();
            let letter = words.last().and_then(|lane| lane.chars().last()).unwrap();
            let allowed = match words[0] {
                "left" => "xy",
                "right" => "wz",
                _ => "wxyz",
            };
            assert!(allowed.contains(letter), "{}: car {:?}: {}", d.display(), e.car, e.detail);
            turns += 1;
        }
    }
    assert!(turns > 100, "only {turns} turns");
    let share = changers as f64 / cars as f64;
    assert!(share >= 0.20, "{changers} of {cars} cars ({:.1} %) changed lanes for a turn", 100.0 * share);
}

/// How far ahead along its route a driver looks, metres (the city world's
/// look-ahead).
const LOOKAHEAD_M: f64 = 30.0;

#[test]
fn interactions_name_a_car_ahead_on_the_path_within_the_look_ahead() {
    let out = dataset();
    let (mut checked, mut kinds) = (0, BTreeSet::new());
    for d in scenario_dirs(&out).into_iter().take(20) {
        let s = read_scenario(&d);
        let by_car = poses_by_car(&read_poses(&d.join("poses.csv")));
        let rows: Vec<InteractionRow> = read_csv(&d.join("interactions.csv"));
        assert_eq!(rows.len(), s.frames as usize * s.cars.len(), "{}: one row per frame and car", d.display());
        for (k, row) in rows.iter().enumerate() {
            // Sorted by frame, then car.
            assert_eq!((row.frame as usize, row.car as usize), (k / s.cars.len(), k % s.cars.len()));
            kinds.insert(row.bound_by.clone());
            match row.bound_by.as_str() {
                "car" | "conflict" | "collision" | "give_way" => {
                    assert!(row.other_car.is_some() && row.light.is_none(), "{row:?}")
                }
                "light" => assert!(row.light.is_some() && row.other_car.is_none(), "{row:?}"),
                _ => assert!(row.light.is_none() && row.other_car.is_none(), "{row:?}"),
            }
            if row.bound_by != "car" {
                continue;
            }
            // The car named lies ahead on this car's own path (where its
            // later poses pass, lane changes included), its centre within the
            // look-ahead (plus the sideways wander of both).
            let (me, other) = (&by_car[&row.car], &by_car[&row.other_car.unwrap()]);
            let f = row.frame as usize;
            let target = DVec2::new(other[f].x, other[f].y);
            let mut along = 0.0;
            let mut found = None;
            for g in f..me.len() {
                if g > f {
                    along += DVec2::new(me[g].x - me[g - 1].x, me[g].y - me[g - 1].y).length();
                }
                if along > LOOKAHEAD_M + 1.0 {
                    break;
                }
                if DVec2::new(me[g].x, me[g].y).distance(target) < 3.5 {
                    found = Some(along);
                    break;
                }
            }
            let remaining = along;
            match found {
                Some(_) => checked += 1,
                // The scenario ended before this car got there: cannot tell.
                None if remaining <= LOOKAHEAD_M + 1.0 => {}
                None => panic!(
                    "{}: frame {f}: car {} bound by car {} which is not ahead on its path",
                    d.display(),
                    row.car,
                    row.other_car.unwrap()
                ),
            }
        }
    }
    assert!(checked > 500, "only {checked} car bindings checked");
    for kind in ["free", "car", "light"] {
        assert!(kinds.contains(kind), "no {kind} rows: {kinds:?}");
    }
}
