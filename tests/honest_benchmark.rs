//! The city benchmark does not give its answer away in the first frame:
//! followers start at drawn gaps and speeds like every other car, hard
//! negatives look like followers at the start and part ways later, and a
//! rule that sees only frame 0 finds the links far worse than in the toy
//! world, while the dynamics still rank them well. Checked on the default
//! city spec (`configs/city.json`), as a user would run it.

mod common;

use common::*;
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// The default city dataset, 100 scenarios per split and group, poses only;
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
    gen_ok(&spec, &data, &["--quiet", "--no-images", "--limit", "100"]);
    *guard = Some(data.clone());
    data
}

/// Frame-0 poses by car id.
fn first_frame(dir: &Path) -> BTreeMap<u32, Pose> {
    read_poses(&dir.join("poses.csv")).into_iter().filter(|p| p.frame == 0).map(|p| (p.car, p)).collect()
}

/// Bumper gap (metres) from `behind` to `ahead` when both are in one lane
/// facing the same way with `ahead` in front, else None.
fn gap_in_lane(ahead: &Pose, behind: &Pose, length: f64) -> Option<f64> {
    let (dx, dy) = (ahead.x - behind.x, ahead.y - behind.y);
    let (c, s) = (behind.yaw.cos(), behind.yaw.sin());
    let (along, across) = (dx * c + dy * s, -dx * s + dy * c);
    let turn = (ahead.yaw - behind.yaw).sin().abs();
    (along > 0.0 && across.abs() < 0.5 && turn < 0.05).then_some(along - length)
}

#[test]
fn followers_and_hard_negatives_start_at_drawn_gaps_with_their_own_driving() {
    let data = default_city();
    let spec: Value = serde_json::from_str(&std::fs::read_to_string("configs/city.json").unwrap()).unwrap();
    let gaps = &spec["city"]["start"]["follower_gap_m"]["uniform"];
    let (lo, hi) = (gaps[0].as_f64().unwrap(), gaps[1].as_f64().unwrap());
    let (mut followers, mut hard_negatives, mut shared_speeds, mut cars) = (0, 0, 0, 0);
    let mut follower_gaps = Vec::new();
    for dir in scenario_dirs(&data) {
        let scenario = read_scenario(&dir);
        let poses = first_frame(&dir);
        let car = |id: u32| scenario.cars.iter().find(|c| c.id == id).unwrap();
        cars += scenario.cars.len();
        for &[leader, follower] in &scenario.edges {
            followers += 1;
            let gap = gap_in_lane(&poses[&leader], &poses[&follower], car(leader).length_m)
                .unwrap_or_else(|| panic!("{}: follower {follower} is not behind leader {leader}", dir.display()));
            // Millimetre placement and lateral wander aside, the drawn gap.
            assert!(gap > lo - 0.01 && gap < hi + 0.01, "{}: follower gap {gap:.3} m", dir.display());
            follower_gaps.push(gap);
            shared_speeds += (car(leader).desired_speeds == car(follower).desired_speeds) as usize;
            assert_eq!(car(leader).actions, car(follower).actions, "a pair shares its actions");
        }
        for c in scenario.cars.iter().filter(|c| c.hard_negative_behind.is_some()) {
            hard_negatives += 1;
            let ahead = car(c.hard_negative_behind.unwrap());
            assert!(!scenario.edges.contains(&[ahead.id, c.id]), "a hard negative is no follower");
            assert_ne!(c.actions[0], ahead.actions[0], "{}: car {} keeps with car {}", dir.display(), c.id, ahead.id);
            let gap = gap_in_lane(&poses[&ahead.id], &poses[&c.id], ahead.length_m)
                .unwrap_or_else(|| panic!("{}: hard negative {} is not behind car {}", dir.display(), c.id, ahead.id));
            assert!(gap > lo - 0.01 && gap < hi + 0.01, "{}: hard negative gap {gap:.3} m", dir.display());
        }
    }
    assert!(followers > 500, "only {followers} followers");
    // Gaps spread over the drawn range, not one exact value.
    follower_gaps.sort_by(f64::total_cmp);
    let (q10, q90) = (follower_gaps[follower_gaps.len() / 10], follower_gaps[follower_gaps.len() * 9 / 10]);
    assert!(q90 - q10 > 0.5 * (hi - lo), "follower gaps from {q10:.2} to {q90:.2} m");
    assert_eq!(shared_speeds, 0, "followers with their leader's desired speeds");
    // Hard negatives are on by default: about as many as followers.
    assert!(hard_negatives * 2 > followers, "{hard_negatives} hard negatives for {followers} followers in {cars} cars");
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
