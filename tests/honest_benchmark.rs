//! The city benchmark does not give its answer away in the first frame:
//! cars start in platoons blind to their roles, followers at speeds drawn
//! like every other car's, and a rule that sees only frame 0 finds the
//! links far worse than in the toy world, while the dynamics rank them
//! well. Checked on the default
//! city spec (`configs/city.json`), as a user would run it.

mod common;

use common::*;
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// The default city dataset, 100 scenarios per split and group, poses only
/// (no effects: nothing here reads them);
/// generated once for every test here.
fn default_city() -> PathBuf {
    static DATA: Mutex<Option<PathBuf>> = Mutex::new(None);
    let mut guard = DATA.lock().unwrap();
    if let Some(path) = guard.as_ref() {
        return path.clone();
    }
    let dir = fresh_dir("honest-benchmark");
    let spec = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/city.json");
    let data = dir.join("city");
    gen_ok(&spec, &data, &["--quiet", "--no-images", "--no-effects", "--limit", "100"]);
    *guard = Some(data.clone());
    data
}

/// The carriageway a spawn lane belongs to: its road segment ("A1") and
/// direction (lanes w and x run one way, y and z the other).
fn carriageway(lane: &str) -> (String, bool) {
    let (segment, letter) = lane.split_at(lane.len() - 1);
    (segment.to_string(), matches!(letter, "w" | "x"))
}

#[test]
fn platoons_start_blind_to_roles_and_followers_drive_their_own_way() {
    let data = default_city();
    let spec: Value = serde_json::from_str(&std::fs::read_to_string("configs/city.json").unwrap()).unwrap();
    assert_eq!(spec["city"]["start"]["platoon_cars"], 4, "the default city starts cars in platoons of 4");
    let lo = spec["city"]["start"]["follower_gap_m"]["uniform"][0].as_f64().unwrap();
    // For (ahead, behind) pairs on one carriageway: [edges, other pairs] of
    // each kind, and how many of them have the car ahead first on its
    // carriageway, or another car between them.
    let (mut pairs, mut first, mut between) = ([0usize; 2], [0usize; 2], [0usize; 2]);
    let (mut followers, mut shared_speeds, mut alone) = (0, 0, 0);
    for dir in scenario_dirs(&data) {
        let scenario = read_scenario(&dir);
        let cars = &scenario.cars;
        let on = |c: &common::Car| carriageway(&c.spawn);
        // No car starts alone on its carriageway (every group here has a multiple of 4 cars).
        alone += cars.iter().filter(|c| cars.iter().filter(|o| on(o) == on(c)).count() < 2).count();
        for a in cars {
            for b in cars.iter().filter(|b| on(b) == on(a) && b.spawn_distance < a.spawn_distance) {
                let is_edge = scenario.edges.contains(&[a.id, b.id]);
                let k = if is_edge { 0 } else { 1 };
                pairs[k] += 1;
                first[k] += cars.iter().all(|o| on(o) != on(a) || o.spawn_distance <= a.spawn_distance) as usize;
                between[k] += cars.iter().any(|o| {
                    on(o) == on(a) && o.spawn_distance < a.spawn_distance && o.spawn_distance > b.spawn_distance
                }) as usize;
                // Two cars of one lane start at least the shortest follower gap apart.
                if a.spawn == b.spawn {
                    let gap = a.spawn_distance - b.spawn_distance - a.length_m;
                    assert!(gap > lo - 0.01, "{}: cars {} and {} start {gap:.3} m apart", dir.display(), a.id, b.id);
                }
            }
        }
        let car = |id: u32| cars.iter().find(|c| c.id == id).unwrap();
        for &[leader, follower] in &scenario.edges {
            followers += 1;
            let (l, f) = (car(leader), car(follower));
            assert_eq!(on(l), on(f), "{}: follower {follower} starts on another carriageway", dir.display());
            assert!(l.spawn_distance > f.spawn_distance, "{}: follower {follower} starts ahead", dir.display());
            shared_speeds += (l.desired_speeds == f.desired_speeds) as usize;
            assert_eq!(l.actions, f.actions, "a follower takes its leader's actions");
        }
    }
    assert!(followers > 500, "only {followers} followers");
    assert_eq!(alone, 0, "cars starting alone on their carriageway");
    assert_eq!(shared_speeds, 0, "followers with their leader's desired speeds");
    // Many more look-alikes than edges, and an edge is placed like any of
    // them: (with the old pairs design, the car ahead was first on its
    // carriageway for 74 % of edges and 37 % of look-alikes).
    assert!(pairs[1] > 3 * pairs[0], "{pairs:?} (edges, other pairs) one behind the other");
    let share = |n: [usize; 2], k: usize| n[k] as f64 / pairs[k] as f64;
    for (what, n) in [("first on its carriageway", first), ("with a car between", between)] {
        let (edge, other) = (share(n, 0), share(n, 1));
        assert!(
            (edge - other).abs() < 0.06,
            "{what}: {:.1} % of edges, {:.1} % of other pairs",
            100.0 * edge,
            100.0 * other
        );
    }
}

/// Share of `ids` (by scenario folder) that never reach 0.1 m/s in the first second.
fn standing_share(cars: &[(PathBuf, u32)], speeds: &BTreeMap<(PathBuf, u32), f64>) -> f64 {
    let standing = cars.iter().filter(|k| speeds[*k] < 0.1).count();
    standing as f64 / cars.len() as f64
}

#[test]
fn followers_do_not_stand_still_at_the_start_more_than_other_cars() {
    let data = default_city();
    let mut fastest = BTreeMap::new();
    let (mut followers, mut others) = (Vec::new(), Vec::new());
    for dir in scenario_dirs(&data) {
        let scenario = read_scenario(&dir);
        for p in read_poses(&dir.join("poses.csv")).into_iter().filter(|p| p.t <= 1.0 + 1e-9) {
            let v = fastest.entry((dir.clone(), p.car)).or_insert(0.0f64);
            *v = v.max(p.speed);
        }
        for c in &scenario.cars {
            let is_follower = scenario.edges.iter().any(|e| e[1] == c.id);
            if is_follower { &mut followers } else { &mut others }.push((dir.clone(), c.id));
        }
    }
    assert!(followers.len() > 500 && others.len() > 1000);
    let (f, o) = (standing_share(&followers, &fastest), standing_share(&others, &fastest));
    // Before leak-free starts: 100 % of followers against 1.5 % of other
    // cars; now under 1 % of either.
    assert!((f - o).abs() <= 0.10, "followers standing {:.1} %, other cars {:.1} %", 100.0 * f, 100.0 * o);
    assert!(f < 0.05, "followers standing {:.1} %", 100.0 * f);
}

fn baseline_rows(data: &Path) -> (Vec<Value>, Vec<Value>) {
    let output = run(&["baseline", data.to_str().unwrap(), "--json"]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let report: Value = serde_json::from_slice(&output.stdout).unwrap();
    (report["groups"].as_array().unwrap().clone(), report["frame0"].as_array().unwrap().clone())
}

#[test]
fn the_first_frame_no_longer_finds_the_links_and_the_dynamics_still_rank_them() {
    let data = default_city();
    let (dynamics, frame0) = baseline_rows(&data);
    assert_eq!(frame0.len(), 5, "one frame0 row per group");
    for (d, z) in dynamics.iter().zip(&frame0) {
        let group = z["group"].as_str().unwrap();
        assert_eq!(d["group"], z["group"]);
        let f1 = z["f1"].as_f64().unwrap();
        // Before leak-free starts: 0.998-1.000 on every group. The rule
        // finds every pair that starts in one lane; on the default layout's
        // 16 m lanes between intersections it still reached 0.59 with 8
        // cars and 3 pairs; with the preset's 36 m east-west blocks
        // 0.20-0.47, here and on 200 test scenarios.
        assert!(f1 <= 0.5, "{group}: frame0 F1 {f1:.3}");
        // 0.87-0.94 here, 0.85-0.93 on 200 test scenarios, with lags up
        // to 8 s; with the lag learned on train (30 s), 0.94-0.96.
        let auroc = d["auroc"].as_f64().unwrap();
        assert!(auroc >= 0.8, "{group}: dynamics AUROC {auroc:.3}");
        // Issue 23: watching the scene ranks the pairs better than the
        // first frame does (0.89-0.95 here).
        let leak = z["auroc"].as_f64().unwrap();
        assert!(auroc > leak, "{group}: dynamics AUROC {auroc:.3}, frame0 {leak:.3}");
        assert_eq!(d["lag_from"], "train", "{group}");
    }
}

#[test]
fn the_weather_follows_its_equations_and_a_value_the_spec_gives_overrides_them() {
    let data = default_city();
    let (mut rainy, mut dry, mut fog_early, mut early, mut fog_late, mut late) = (0, 0, 0, 0, 0, 0);
    let dirs = scenario_dirs(&data);
    assert!(dirs.len() >= 500, "{} scenarios", dirs.len());
    for d in &dirs {
        let city = &read_json(&d.join("scenario.json"))["city"];
        let value = |name: &str| city["confounders"][name].as_f64().unwrap();
        let (rain, snow, wetness, fog, hour) =
            (value("rain"), value("snow"), value("wetness"), value("fog"), value("hour"));
        assert_eq!(city["confounder_model"]["source"]["wetness"], "equation");
        assert_eq!(city["confounder_model"]["source"]["fog"], "equation");
        if rain >= 0.5 {
            assert!(wetness >= 0.3, "{}: rain {rain}, wetness {wetness}", d.display());
            rainy += 1;
        }
        // A dry day is dry; rain or snow always leaves water.
        assert_eq!(wetness > 0.0, rain > 0.0 || snow > 0.0, "{}", d.display());
        dry += (rain == 0.0 && snow == 0.0) as usize;
        if hour < 8.0 {
            (early, fog_early) = (early + 1, fog_early + (fog > 0.0) as usize);
        } else if hour >= 11.0 {
            (late, fog_late) = (late + 1, fog_late + (fog > 0.0) as usize);
        }
    }
    assert!(rainy > 100 && dry > 100, "{rainy} rainy, {dry} dry scenarios");
    // Fog comes in the early hours (before 08:00: 5-8 h in this spec), not later than 11:00.
    assert!(early > 50 && fog_early as f64 > 0.3 * early as f64, "{fog_early} of {early} early scenarios foggy");
    assert_eq!(fog_late, 0, "fog after 11:00 in {fog_late} of {late} scenarios");

    // Fixing wetness and fog in the spec (a do-intervention) overrides their equations.
    let dir = fresh_dir("weather-do");
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/city.json")).unwrap();
    let mut spec: Value = serde_json::from_str(&text).unwrap();
    spec["city"]["confounders"]["wetness"] = 0.0.into();
    spec["city"]["confounders"]["fog"] = 0.5.into();
    spec["city"]["confounders"]["hour"] = 15.into();
    spec["city"]["confounders"]["rain"] = 0.8.into();
    let spec = write_spec(&dir, &spec.to_string());
    gen_ok(&spec, &dir.join("data"), &["--quiet", "--no-images", "--limit", "2"]);
    let dirs = scenario_dirs(&dir.join("data"));
    assert!(!dirs.is_empty());
    for d in dirs {
        let city = &read_json(&d.join("scenario.json"))["city"];
        assert_eq!(
            (city["confounders"]["wetness"].as_f64(), city["confounders"]["fog"].as_f64()),
            (Some(0.0), Some(0.5))
        );
        assert_eq!(city["confounder_model"]["source"]["wetness"], "spec");
        assert_eq!(city["confounder_model"]["source"]["fog"], "spec");
    }
}
