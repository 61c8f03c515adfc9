//! Datasets on a real road network imported from SUMO (`map.sumo`): gen
//! drives, draws and measures effects on it, keeps the network with the
//! dataset so that every reader rebuilds the same map, and refuses what
//! it cannot use with exit 2 and nothing written.

mod common;
use common::*;
use std::path::{Path, PathBuf};

fn berlin() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/sumo/berlin-small.net.xml")
}

/// A folder with a copy of the network and a spec naming it beside it.
fn spec_beside_network(name: &str, map: &str, splits: (u32, u32, u32)) -> (PathBuf, PathBuf) {
    let dir = fresh_dir(name);
    std::fs::copy(berlin(), dir.join("berlin-small.net.xml")).unwrap();
    let text = format!(
        r#"{{"name": "{name}", "world": "city", "seed": 3, "frames": 120, "frame_interval": 0.5,
            "groups": [{{"cars": 8, "edge_proportion": 0.5}}, {{"cars": 12, "edge_proportion": 0.5}}],
            "splits": {{"train": {}, "val": {}, "test": {}}}, "actions_per_car": 4, "map": {map}}}"#,
        splits.0, splits.1, splits.2
    );
    let spec = write_spec(&dir, &text);
    (dir, spec)
}

/// The SUMO lane ids of the network file.
fn lane_ids() -> std::collections::BTreeSet<String> {
    let text = std::fs::read_to_string(berlin()).unwrap();
    text.split("<lane id=\"").skip(1).map(|rest| rest[..rest.find('"').unwrap()].to_string()).collect()
}

#[test]
fn a_dataset_on_a_real_network_is_driven_measured_kept_whole_and_valid() {
    let (dir, spec) = spec_beside_network("sumo-gen", r#"{"sumo": "berlin-small.net.xml"}"#, (4, 2, 2));
    let out = dir.join("out");
    gen_ok(&spec, &out, &["--no-images"]);
    // The network travels with the dataset, byte for byte.
    let kept = out.join("networks/berlin-small.net.xml");
    assert_eq!(std::fs::read(&kept).unwrap(), std::fs::read(berlin()).unwrap());

    let lanes = lane_ids();
    let scenarios = scenario_dirs(&out);
    assert_eq!(scenarios.len(), 16);
    let (mut pairs, mut following) = (0, 0);
    for scenario in &scenarios {
        let meta = read_json(&scenario.join("scenario.json"));
        // Cars spawn on the network's own lanes, by SUMO id.
        for car in meta["cars"].as_array().unwrap() {
            let spawn = car["spawn"].as_str().unwrap();
            assert!(lanes.contains(spawn), "{}: spawn {spawn} is no lane of the network", scenario.display());
        }
        let by_car = poses_by_car(&read_poses(&scenario.join("poses.csv")));
        for poses in by_car.values() {
            // On the network (netconvert's convBoundary: x 863-1396, y 134-512 m) and driving.
            assert!(poses.iter().all(|p| (850.0..1410.0).contains(&p.x) && (120.0..530.0).contains(&p.y)));
            let moved: f64 = poses.windows(2).map(|w| (w[1].x - w[0].x).hypot(w[1].y - w[0].y)).sum();
            assert!(moved > 20.0, "{}: a car drove only {moved:.1} m in 60 s", scenario.display());
        }
        // A follower keeps near where its leader drove.
        let (p, f) = designed_pairs_following(&meta, &by_car);
        (pairs, following) = (pairs + p, following + f);
        // Interventional ground truth, as on the grid towns.
        assert!(scenario.join("effects.csv").is_file());
        assert!(meta["causal_edges"].is_array());
    }
    assert!(pairs >= 30, "only {pairs} designed pairs");
    assert!(following * 10 >= pairs * 9, "{following} of {pairs} designed followers follow");

    // validate reads the network from the dataset: it passes after the
    // spec's copy is gone and the dataset has moved.
    std::fs::remove_file(dir.join("berlin-small.net.xml")).unwrap();
    let moved = dir.join("moved");
    std::fs::rename(&out, &moved).unwrap();
    let checked = run(&["validate", moved.to_str().unwrap()]);
    assert!(checked.status.success(), "{}", String::from_utf8_lossy(&checked.stderr));
    // ... and sees a network that is not the one the dataset was made on.
    std::fs::write(moved.join("networks/stray.net.xml"), "<net/>").unwrap();
    let stray = run(&["validate", moved.to_str().unwrap()]);
    assert_eq!(stray.status.code(), Some(1), "{}", String::from_utf8_lossy(&stray.stdout));
    assert!(String::from_utf8_lossy(&stray.stdout).contains("networks/stray.net.xml"));
}

#[test]
fn frames_of_a_real_network_show_its_roads_and_the_cars_on_them() {
    let area = r#"{"sumo": "berlin-small.net.xml", "camera_area": {"x": [990, 1110], "y": [395, 530]}}"#;
    let (dir, spec) = spec_beside_network("sumo-frames", area, (1, 0, 0));
    let out = dir.join("out");
    gen_ok(&spec, &out, &["--limit", "1"]);
    let scenario = &scenario_dirs(&out)[0];
    let frame = image::open(scenario.join("rgb/0020.png")).unwrap().to_rgb8();
    let share = |rgb: [u8; 3]| frame.pixels().filter(|p| p.0 == rgb).count() as f64 / frame.len() as f64 * 3.0;
    // Asphalt along the lanes and over the junctions, bare ground elsewhere (no grid town's blocks).
    let (asphalt, ground) = (share([66, 68, 72]), share([200, 198, 190]));
    assert!(asphalt > 0.05 && ground > 0.3, "asphalt {asphalt:.3}, ground {ground:.3}");
    assert!(frame.pixels().all(|p| p.0 != [122, 168, 98]), "a grid town's park on a real network");
    // Every car in view is in its mask.
    let mask = image::open(scenario.join("mask/0020.png")).unwrap().to_luma8();
    let poses = read_poses(&scenario.join("poses.csv"));
    let in_view: Vec<&Pose> = poses.iter().filter(|p| p.frame == 20 && p.in_view == 1).collect();
    assert!(!in_view.is_empty(), "no car in view");
    let meta = read_json(&scenario.join("scenario.json"));
    for pose in in_view {
        let id = meta["cars"][pose.car as usize]["mask_id"].as_u64().unwrap() as u8;
        let covered = mask.pixels().filter(|p| p.0[0] == id).count();
        assert!(covered > 10, "car {} covers {covered} mask pixels", pose.car);
    }
}

#[test]
fn what_a_real_network_spec_cannot_use_is_refused_with_nothing_written() {
    let cases = [
        (r#"{"sumo": "nowhere.net.xml"}"#, "map.sumo", "nowhere.net.xml"),
        (r#"{"sumo": "berlin-small.net.xml", "grid": {"rows": 2, "columns": 2}}"#, "map.grid", "brings its own roads"),
        (r#"{"sumo": "berlin-small.net.xml", "lane_width": 3.5}"#, "map.lane_width", "leave map.lane_width out"),
        (r#"{"sumo": "berlin-small.png"}"#, "map.sumo", "a SUMO network file"),
        (r#"{"sumo": "not-a-net.xml"}"#, "map.sumo", "not-a-net.xml: its root element is <html>, not <net>"),
        // Measured against the network, not the default four-road city
        // (helper audit: "47.2 m x 47.2 m" for any network).
        (
            r#"{"sumo": "berlin-small.net.xml", "camera_altitude_m": 20}"#,
            "map.camera_altitude_m",
            "20 m shows less than the whole network (",
        ),
    ];
    let mut checked = 0;
    for (k, (map, field, needle)) in cases.into_iter().enumerate() {
        let (dir, spec) = spec_beside_network(&format!("sumo-refused-{k}"), map, (1, 0, 0));
        std::fs::write(dir.join("not-a-net.xml"), "<html><body>hello</body></html>").unwrap();
        let out = dir.join("out");
        let result = run(&["gen", "--spec", spec.to_str().unwrap(), "--out", out.to_str().unwrap()]);
        let stderr = String::from_utf8_lossy(&result.stderr);
        assert_eq!(result.status.code(), Some(2), "{map}: {stderr}");
        assert!(stderr.contains(field) && stderr.contains(needle), "{map}: {stderr}");
        assert!(!out.exists(), "{map}: something was written");
        checked += 1;
    }
    assert_eq!(checked, 6);
}

#[test]
fn the_shipped_ood_real_network_spec_trains_on_grid_towns_and_tests_on_the_imported_network() {
    let dir = fresh_dir("ood-real-network");
    let configs = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs");
    let mut spec: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(configs.join("ood-real-network.json")).unwrap()).unwrap();
    spec["splits"] = serde_json::json!({"train": 2, "val": 1, "test": 2});
    spec["frames"] = serde_json::json!(30);
    // The shipped spec names the network relative to configs/; the copy, by its absolute path.
    let sumo = spec["held_out"]["test"]["map"]["sumo"].as_str().unwrap().to_string();
    let network = configs.join(&sumo).canonicalize().unwrap();
    assert_eq!(network, berlin().canonicalize().unwrap());
    spec["held_out"]["test"]["map"]["sumo"] = serde_json::json!(network.to_str().unwrap());
    let out = dir.join("ood");
    gen_ok(&write_spec(&dir, &spec.to_string()), &out, &["--no-images"]);
    let lanes = lane_ids();
    let mut splits = std::collections::BTreeSet::new();
    for scenario in scenario_dirs(&out) {
        let split = scenario.parent().unwrap().file_name().unwrap().to_str().unwrap().to_string();
        let meta = read_json(&scenario.join("scenario.json"));
        let spawn = meta["cars"][0]["spawn"].as_str().unwrap().to_string();
        // Test happens on the network, train and val on grid towns.
        assert_eq!(split == "test", lanes.contains(&spawn), "{}: spawn {spawn}", scenario.display());
        assert_eq!(
            split == "test",
            meta["town"] == "sumo-berlin-small",
            "{}: town {}",
            scenario.display(),
            meta["town"]
        );
        splits.insert(split);
    }
    assert_eq!(splits.len(), 3);
    assert!(out.join("networks/berlin-small.net.xml").is_file());
    let report = run(&["validate", out.to_str().unwrap()]);
    assert!(report.status.success(), "{}", String::from_utf8_lossy(&report.stdout));
}

#[test]
fn a_hand_written_scenario_drives_on_a_network_beside_it_by_sumo_lane_ids() {
    let dir = fresh_dir("sumo-handwritten");
    std::fs::copy(berlin(), dir.join("berlin-small.net.xml")).unwrap();
    let scenario = |spawn: &str| {
        format!(
            r#"[{{"Name": "Berlin_1", "map": {{"sumo": "berlin-small.net.xml"}}, "Vehicles": [
                {{"Id": "Car_1", "Spawn": "318210363#0_1", "SpawnAtDistance": 5, "DriveQueue": ["right", "straight"], "MergeAtDistances": [0, 0]}},
                {{"Id": "Car_2", "Spawn": "{spawn}", "SpawnAtDistance": 20, "DriveQueue": ["straight"], "MergeAtDistances": [0]}}]}}]"#
        )
    };
    let file = dir.join("berlin.json");
    std::fs::write(&file, scenario("318210363#0_2")).unwrap();
    let out = dir.join("out");
    let ran = run(&["run", "--scenario", file.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(ran.status.success(), "{}", String::from_utf8_lossy(&ran.stderr));
    let meta = read_json(&out.join("Berlin_1/scenario.json"));
    let spawns: Vec<&str> = meta["cars"].as_array().unwrap().iter().map(|c| c["spawn"].as_str().unwrap()).collect();
    assert_eq!(spawns, ["318210363#0_1", "318210363#0_2"]);
    let by_car = poses_by_car(&read_poses(&out.join("Berlin_1/poses.csv")));
    for poses in by_car.values() {
        let (first, last) = (&poses[0], &poses[poses.len() - 1]);
        assert!((last.x - first.x).hypot(last.y - first.y) > 30.0, "a car stayed where it started");
    }
    // A lane the network does not have is named, with an example of one it has.
    std::fs::write(&file, scenario("nope")).unwrap();
    let refused = run(&["run", "--scenario", file.to_str().unwrap(), "--out", dir.join("out2").to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert_eq!(refused.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("\"nope\" is not a lane of the network") && stderr.contains("Spawn"), "{stderr}");
    assert!(!dir.join("out2").exists());
}

#[test]
fn a_real_network_dataset_resumes_merges_sweeps_and_refuses_a_changed_network() {
    let (dir, spec) = spec_beside_network("sumo-lifecycle", r#"{"sumo": "berlin-small.net.xml"}"#, (2, 1, 1));
    let out = dir.join("out");
    // A first run of one scenario per split, then the rest: the second run resumes.
    gen_ok(&spec, &out, &["--no-images", "--limit", "1"]);
    let resumed = gen_ok(&spec, &out, &["--no-images"]);
    let said = format!("{}{}", String::from_utf8_lossy(&resumed.stdout), String::from_utf8_lossy(&resumed.stderr));
    assert!(said.contains("skipped 6 already complete"), "{said}");
    assert_eq!(scenario_dirs(&out).len(), 8);
    // The manifest pins the network's bytes.
    let manifest = read_json(&out.join("manifest.json"));
    let pinned = manifest["spec"]["map"]["sumo_sha256"].as_str().unwrap().to_string();
    assert_eq!(pinned.len(), 64);
    // A changed network is another dataset: refused, nothing touched.
    let network = dir.join("berlin-small.net.xml");
    let original = std::fs::read(&network).unwrap();
    std::fs::write(&network, [&original[..], b"<!-- edited -->\n"].concat()).unwrap();
    let before = hash_tree(&out);
    let changed = run(&["gen", "--spec", spec.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-images"]);
    assert_eq!(changed.status.code(), Some(2), "{}", String::from_utf8_lossy(&changed.stderr));
    assert!(String::from_utf8_lossy(&changed.stderr).contains("sumo_sha256"));
    assert_eq!(hash_tree(&out), before, "a refused run changed the dataset");
    // --force replaces it, network copy included.
    gen_ok(&spec, &out, &["--no-images", "--force"]);
    assert_ne!(read_json(&out.join("manifest.json"))["spec"]["map"]["sumo_sha256"].as_str().unwrap(), pinned);
    assert_eq!(std::fs::read(out.join("networks/berlin-small.net.xml")).unwrap().len(), original.len() + 16);
    std::fs::write(&network, &original).unwrap();
    // A dataset whose copy of the network was edited no longer opens.
    let copy = out.join("networks/berlin-small.net.xml");
    std::fs::write(&copy, &original).unwrap();
    let tampered = run(&["validate", out.to_str().unwrap()]);
    assert!(!tampered.status.success());
    assert!(
        String::from_utf8_lossy(&tampered.stderr).contains("SHA-256"),
        "{}",
        String::from_utf8_lossy(&tampered.stderr)
    );

    // Shards in folders of their own merge into one dataset that keeps the network.
    let (s0, s1, merged) = (dir.join("s0"), dir.join("s1"), dir.join("merged"));
    gen_ok(&spec, &s0, &["--no-images", "--shard", "0/2"]);
    gen_ok(&spec, &s1, &["--no-images", "--shard", "1/2"]);
    let m = run(&["merge", "--out", merged.to_str().unwrap(), s0.to_str().unwrap(), s1.to_str().unwrap()]);
    assert!(m.status.success(), "{}", String::from_utf8_lossy(&m.stderr));
    assert_eq!(std::fs::read(merged.join("networks/berlin-small.net.xml")).unwrap(), original);
    let checked = run(&["validate", merged.to_str().unwrap()]);
    assert!(checked.status.success(), "{}", String::from_utf8_lossy(&checked.stdout));
    // Merged into one shard's own folder, named as a source too: the
    // network kept there is not taken for a shard's leftover copy.
    let (s2, s3) = (dir.join("s2"), dir.join("s3"));
    gen_ok(&spec, &s2, &["--no-images", "--shard", "0/2"]);
    gen_ok(&spec, &s3, &["--no-images", "--shard", "1/2"]);
    let m = run(&["merge", "--out", s2.to_str().unwrap(), s2.to_str().unwrap(), s3.to_str().unwrap()]);
    assert!(m.status.success(), "{}", String::from_utf8_lossy(&m.stderr));
    assert_eq!(std::fs::read(s2.join("networks/berlin-small.net.xml")).unwrap(), original);
    let checked = run(&["validate", s2.to_str().unwrap()]);
    assert!(checked.status.success(), "{}", String::from_utf8_lossy(&checked.stdout));

    // A shard's copy of the network that is a link is never read through:
    // merge takes another shard's copy, and a link in --out is replaced by
    // the file. A shard whose copy is gone merges from the other's.
    let (s4, s5, s6, merged2) = (dir.join("s4"), dir.join("s5"), dir.join("s6"), dir.join("merged2"));
    gen_ok(&spec, &s4, &["--no-images", "--shard", "0/2"]);
    gen_ok(&spec, &s5, &["--no-images", "--shard", "1/2"]);
    let elsewhere = dir.join("elsewhere.net.xml");
    std::fs::write(&elsewhere, b"not a network").unwrap();
    std::fs::remove_file(s4.join("networks/berlin-small.net.xml")).unwrap();
    std::os::unix::fs::symlink(&elsewhere, s4.join("networks/berlin-small.net.xml")).unwrap();
    let m = run(&["merge", "--out", merged2.to_str().unwrap(), s4.to_str().unwrap(), s5.to_str().unwrap()]);
    assert!(m.status.success(), "{}", String::from_utf8_lossy(&m.stderr));
    assert_eq!(std::fs::read(merged2.join("networks/berlin-small.net.xml")).unwrap(), original);
    assert_eq!(std::fs::read(&elsewhere).unwrap(), b"not a network", "the link's target untouched");
    // Every shard's copy a link: refused, nothing moved.
    let s7 = dir.join("s7");
    gen_ok(&spec, &s6, &["--no-images", "--shard", "0/2"]);
    gen_ok(&spec, &s7, &["--no-images", "--shard", "1/2"]);
    for shard in [&s6, &s7] {
        std::fs::remove_file(shard.join("networks/berlin-small.net.xml")).unwrap();
        std::os::unix::fs::symlink(&elsewhere, shard.join("networks/berlin-small.net.xml")).unwrap();
    }
    let before = (hash_tree(&s6), hash_tree(&s7));
    let merged3 = dir.join("merged3");
    let linked = run(&["merge", "--out", merged3.to_str().unwrap(), s6.to_str().unwrap(), s7.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&linked.stderr);
    assert_eq!(linked.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("networks/berlin-small.net.xml is a link"), "{stderr}");
    assert_eq!((hash_tree(&s6), hash_tree(&s7)), before, "nothing moved");
    // gen resuming into a folder whose copy is a link puts the file in its place.
    let resumed = dir.join("resumed");
    gen_ok(&spec, &resumed, &["--no-images", "--limit", "1"]);
    std::fs::remove_file(resumed.join("networks/berlin-small.net.xml")).unwrap();
    std::os::unix::fs::symlink(&elsewhere, resumed.join("networks/berlin-small.net.xml")).unwrap();
    gen_ok(&spec, &resumed, &["--no-images"]);
    let kept = resumed.join("networks/berlin-small.net.xml");
    assert!(std::fs::symlink_metadata(&kept).unwrap().is_file(), "the link replaced by the file");
    assert_eq!(std::fs::read(&kept).unwrap(), original);
    assert_eq!(std::fs::read(&elsewhere).unwrap(), b"not a network");

    // A counterfactual sweep keeps it too, and validates.
    let sweep = dir.join("sweep");
    let swept = run(&[
        "counterfactual",
        "--sweep",
        spec.to_str().unwrap(),
        "--out",
        sweep.to_str().unwrap(),
        "--limit",
        "1",
        "--no-images",
    ]);
    assert!(swept.status.success(), "{}", String::from_utf8_lossy(&swept.stderr));
    assert!(sweep.join("networks/berlin-small.net.xml").is_file());
    let checked = run(&["validate", sweep.to_str().unwrap()]);
    assert!(checked.status.success(), "{}", String::from_utf8_lossy(&checked.stdout));
}

#[test]
fn a_generated_spider_web_of_right_before_left_junctions_drives_without_collisions() {
    // Junctions of up to 7 arms, several from one compass side, all driven as all-way stops.
    let dir = fresh_dir("sumo-spider");
    let network = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/sumo/spider7.net.xml");
    std::fs::copy(&network, dir.join("spider7.net.xml")).unwrap();
    let text = r#"{"name": "spider", "world": "city", "seed": 5, "frames": 120, "frame_interval": 0.5,
        "groups": [{"cars": 12, "edge_proportion": 0.5}], "splits": {"train": 12, "val": 0, "test": 0},
        "actions_per_car": 4, "map": {"sumo": "spider7.net.xml"}}"#;
    let spec = write_spec(&dir, text);
    let out = dir.join("out");
    gen_ok(&spec, &out, &["--no-images"]);
    let mut scenarios = 0;
    for scenario in scenario_dirs(&out) {
        let events = std::fs::read_to_string(scenario.join("events.csv")).unwrap();
        assert!(!events.contains(",collision,"), "{}: {events}", scenario.display());
        let by_car = poses_by_car(&read_poses(&scenario.join("poses.csv")));
        for poses in by_car.values() {
            let moved: f64 = poses.windows(2).map(|w| (w[1].x - w[0].x).hypot(w[1].y - w[0].y)).sum();
            assert!(moved > 20.0, "{}: a car drove only {moved:.1} m in 60 s", scenario.display());
        }
        scenarios += 1;
    }
    assert_eq!(scenarios, 12);
    // The all-way rule binds cars: some wait at a stop line.
    let lines: usize = scenario_dirs(&out)
        .iter()
        .map(|s| std::fs::read_to_string(s.join("interactions.csv")).unwrap().matches(",stop_line,").count())
        .sum();
    assert!(lines > 0, "no car ever waited at a stop line");
}

#[test]
fn a_chase_camera_sees_the_real_networks_roads() {
    let dir = fresh_dir("sumo-chase");
    std::fs::copy(berlin(), dir.join("berlin-small.net.xml")).unwrap();
    let text = r#"{"name": "chase", "world": "city", "seed": 3, "frames": 20, "frame_interval": 0.5,
        "image": {"width": 320, "height": 200},
        "groups": [{"cars": 4, "edge_proportion": 0.5}], "splits": {"train": 1, "val": 0, "test": 0},
        "map": {"sumo": "berlin-small.net.xml"}, "cameras": [{"name": "chase", "third_person": 0}]}"#;
    let spec = write_spec(&dir, text);
    let out = dir.join("out");
    gen_ok(&spec, &out, &[]);
    let scenario = &scenario_dirs(&out)[0];
    let frame = image::open(scenario.join("cameras/chase/rgb/0010.png")).unwrap().to_rgb8();
    // Below the horizon: the road under the car, dark asphalt, not bare ground only.
    let lower = frame.height() / 2..frame.height();
    let dark = lower
        .flat_map(|y| (0..frame.width()).map(move |x| (x, y)))
        .filter(|&(x, y)| frame.get_pixel(x, y).0.iter().all(|&c| c < 110))
        .count();
    assert!(dark > (frame.width() * frame.height() / 20) as usize, "only {dark} dark pixels below the horizon");
    let report = run(&["validate", out.to_str().unwrap()]);
    assert!(report.status.success(), "{}", String::from_utf8_lossy(&report.stdout));
}

#[test]
fn gen_writes_no_network_through_a_linked_networks_folder() {
    let (dir, spec) = spec_beside_network("sumo-linked", r#"{"sumo": "berlin-small.net.xml"}"#, (1, 0, 0));
    let out = dir.join("out");
    gen_ok(&spec, &out, &["--no-images", "--limit", "1"]);
    // networks/ replaced by a link to a folder outside the dataset.
    let elsewhere = dir.join("elsewhere");
    std::fs::create_dir_all(&elsewhere).unwrap();
    std::fs::remove_dir_all(out.join("networks")).unwrap();
    std::os::unix::fs::symlink(&elsewhere, out.join("networks")).unwrap();
    let before = hash_tree(&out);
    let refused = run(&["gen", "--spec", spec.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-images"]);
    assert_eq!(refused.status.code(), Some(2), "{}", String::from_utf8_lossy(&refused.stderr));
    assert!(
        String::from_utf8_lossy(&refused.stderr).contains("networks"),
        "{}",
        String::from_utf8_lossy(&refused.stderr)
    );
    assert_eq!(std::fs::read_dir(&elsewhere).unwrap().count(), 0, "a file was written through the link");
    assert_eq!(hash_tree(&out), before);
    // --force leaves the linked folder's target alone too.
    std::fs::write(elsewhere.join("keep.txt"), "mine").unwrap();
    let _ = run(&["gen", "--spec", spec.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-images", "--force"]);
    assert_eq!(std::fs::read_to_string(elsewhere.join("keep.txt")).unwrap(), "mine");
    assert!(!elsewhere.join("berlin-small.net.xml").exists());
}

/// Green runs of the scenario's lights (seconds, at `frame_interval`), each
/// light's first and last run left out (cut by the scenario's start and end).
fn inner_green_runs(scenario: &Path, frame_interval: f64) -> Vec<f64> {
    let colours = lights_by_name(scenario);
    let mut runs = Vec::new();
    for (sequence, _) in colours.values() {
        let mut lengths: Vec<(String, usize)> = Vec::new();
        for colour in sequence {
            match lengths.last_mut() {
                Some((c, n)) if c == colour => *n += 1,
                _ => lengths.push((colour.clone(), 1)),
            }
        }
        let inner = lengths.len().saturating_sub(1);
        runs.extend(
            lengths[..inner].iter().skip(1).filter(|(c, _)| c == "green").map(|(_, n)| *n as f64 * frame_interval),
        );
    }
    runs
}

#[test]
fn actuated_lights_answer_to_traffic_within_their_bounds_and_their_effects_are_measured() {
    // Every junction of the grid runs SUMO's actuated programme: green
    // phases of 5-50 s (2.5-25 s at cycle_scale 0.5), written as 42 s (21 s).
    let dir = fresh_dir("sumo-actuated");
    let network = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/sumo/grid3-actuated.net.xml");
    std::fs::copy(&network, dir.join("grid3-actuated.net.xml")).unwrap();
    let spec = |actuated: bool| {
        let text = format!(
            r#"{{"name": "actuated-{actuated}", "world": "city", "seed": 5, "frames": 150, "frame_interval": 0.5,
                "groups": [{{"cars": 12, "edge_proportion": 0.5}}], "splits": {{"train": 6, "val": 1, "test": 1}},
                "actions_per_car": 4, "map": {{"sumo": "grid3-actuated.net.xml"}},
                "city": {{"start": {{"platoon_cars": 4}}, "lights": {{"cycle_scale": 0.5, "actuated": {actuated}}}}}}}"#
        );
        std::fs::write(dir.join(format!("actuated-{actuated}.json")), text).unwrap();
        dir.join(format!("actuated-{actuated}.json"))
    };
    let (actuated, fixed) = (dir.join("actuated"), dir.join("fixed"));
    gen_ok(&spec(true), &actuated, &["--no-images"]);
    gen_ok(&spec(false), &fixed, &["--no-images"]);

    let schema = validator("scenario.schema.json");
    let (mut runs, mut causal_actuated, mut causal_fixed) = (Vec::new(), 0, 0);
    for scenario in scenario_dirs(&actuated) {
        let meta = read_json(&scenario.join("scenario.json"));
        assert_valid(&schema, &meta, &scenario);
        let lights = meta["city"]["lights"].as_array().unwrap();
        assert!(!lights.is_empty() && lights.iter().all(|l| l["actuated"] == true), "{}", scenario.display());
        runs.extend(inner_green_runs(&scenario, 0.5));
        causal_actuated += meta["causal_edges"].as_array().unwrap().len();
    }
    assert!(runs.len() >= 100, "only {} green runs", runs.len());
    // Within the phase's bounds (to a frame), and set by the traffic: some
    // end at the shortest, some held longer, in many lengths.
    let outside: Vec<f64> = runs.iter().copied().filter(|r| !(2.0..=25.5).contains(r)).collect();
    assert!(outside.is_empty(), "greens of {outside:?} s");
    // Twelve cars in nine junctions leave most phases without traffic
    // (measured: 4,736 of 4,856 green runs at the shortest, 92 held 5-14.5 s).
    let at_shortest = runs.iter().filter(|&&r| r <= 3.0).count();
    let held = runs.iter().filter(|&&r| r >= 5.0).count();
    assert!(at_shortest * 2 >= runs.len() && held >= 30, "{at_shortest} short, {held} held of {}", runs.len());
    let lengths: std::collections::BTreeSet<u64> = runs.iter().map(|r| (r * 2.0).round() as u64).collect();
    assert!(lengths.len() >= 8, "green lengths (half seconds) {lengths:?}");
    // Run as fixed programmes, every green lasts its written 21 s.
    for scenario in scenario_dirs(&fixed) {
        let fixed_runs = inner_green_runs(&scenario, 0.5);
        let off: Vec<f64> = fixed_runs.iter().copied().filter(|r| (r - 21.0).abs() > 0.5).collect();
        assert!(!fixed_runs.is_empty() && off.is_empty(), "{}: greens of {off:?} s", scenario.display());
        causal_fixed += read_json(&scenario.join("scenario.json"))["causal_edges"].as_array().unwrap().len();
    }
    // A car over a detector changes when others get their green: the
    // effects see it as causes that reach further.
    assert!(causal_actuated * 10 > causal_fixed * 13, "causal edges {causal_actuated} actuated, {causal_fixed} fixed");

    let checked = run(&["validate", actuated.to_str().unwrap()]);
    assert!(checked.status.success(), "{}", String::from_utf8_lossy(&checked.stdout));
    // The same bytes on one thread.
    let one = dir.join("one-thread");
    gen_ok(&spec(true), &one, &["--no-images", "-j", "1"]);
    assert_eq!(hash_tree(&one), hash_tree(&actuated));
}

#[test]
fn actuated_phases_that_may_end_at_once_last_a_step_and_the_run_ends() {
    // grid3-actuated with every phase's shortest length 0 (greens and
    // yellows alike): without traffic a phase may end as soon as it began,
    // and gen went round the phases for ever at the first gap. A phase now
    // lasts at least a step, as in SUMO.
    let dir = fresh_dir("sumo-actuated-zero");
    let network =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/sumo/grid3-actuated.net.xml"))
            .unwrap();
    let zero: Vec<String> = network
        .lines()
        .map(|line| match line.contains("duration=\"3\"") {
            true => line.replace("\"/>", "\" minDur=\"0\" maxDur=\"6\"/>"),
            false => line.replace("minDur=\"5\"", "minDur=\"0\""),
        })
        .collect();
    assert_eq!(zero.iter().filter(|l| l.contains("minDur=\"0\"")).count(), 36, "every phase");
    std::fs::write(dir.join("zero.net.xml"), zero.join("\n")).unwrap();
    let spec = write_spec(
        &dir,
        r#"{"name": "actuated-zero", "world": "city", "seed": 5, "frames": 60, "frame_interval": 0.5,
            "groups": [{"cars": 4, "edge_proportion": 0.5}], "splits": {"train": 1, "val": 1, "test": 1},
            "map": {"sumo": "zero.net.xml"}, "city": {"lights": {"cycle_scale": 0.5, "actuated": true}}}"#,
    );
    let out = dir.join("out");
    let ran =
        run_within(&["gen", "--spec", spec.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-images"], 120);
    assert!(ran.status.success(), "{}", String::from_utf8_lossy(&ran.stderr));
    let checked = run(&["validate", out.to_str().unwrap()]);
    assert!(checked.status.success(), "{}", String::from_utf8_lossy(&checked.stdout));
    // Greens shorter than the written shortest (2.5 s at cycle_scale 0.5)
    // show once the first gap has passed: phases of a step.
    let runs: Vec<f64> = scenario_dirs(&out).iter().flat_map(|s| inner_green_runs(s, 0.5)).collect();
    assert!(runs.iter().any(|&r| r < 2.5), "greens of {runs:?} s");
}

/// Each light's colour per frame, by (intersection, approach, signal), and
/// its signal head (bird's-eye pixels), from the scenario's light log.
type LightsCsv = std::collections::BTreeMap<(String, String, String), (Vec<String>, (Option<f64>, Option<f64>))>;

fn lights_by_name(scenario: &Path) -> LightsCsv {
    let mut lights = LightsCsv::new();
    for row in light_rows(scenario) {
        let entry = lights.entry((row.intersection, row.approach, row.signal)).or_default();
        entry.0.push(row.colour);
        entry.1 = (row.head_px, row.head_py);
    }
    lights
}

#[test]
fn a_right_turn_arrow_is_a_light_of_its_own_in_every_file_and_interventions_name_it() {
    // tests/data/sumo/grid2-arrows.net.xml: junction B1's right turn from
    // the south has an arrow, green with the west's protected left while
    // straight on from the south is red (README there).
    let dir = fresh_dir("sumo-arrows");
    let network = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/sumo/grid2-arrows.net.xml");
    std::fs::copy(&network, dir.join("grid2-arrows.net.xml")).unwrap();
    let described = run(&["map", "--net", network.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&described.stdout);
    assert!(text.contains("1 light of its own") && text.contains("B1/S/straight-2: B0B1_0 right"), "{text}");
    let spec = write_spec(
        &dir,
        r#"{"name": "arrows", "world": "city", "seed": 4, "frames": 200, "frame_interval": 0.5,
            "groups": [{"cars": 8, "edge_proportion": 0.5}], "splits": {"train": 2, "val": 1, "test": 1},
            "actions_per_car": 4, "map": {"sumo": "grid2-arrows.net.xml"}, "city": {"lights": {"cycle_scale": 1.0}}}"#,
    );
    let out = dir.join("out");
    gen_ok(&spec, &out, &["--no-images"]);
    let schema = validator("scenario.schema.json");
    let key = |signal: &str| ("B1".to_string(), "S".to_string(), signal.to_string());
    let mut arrow_frames = 0;
    for scenario in scenario_dirs(&out) {
        let meta = read_json(&scenario.join("scenario.json"));
        assert_valid(&schema, &meta, &scenario);
        let listed: Vec<String> = meta["city"]["lights"]
            .as_array()
            .unwrap()
            .iter()
            .map(|l| {
                format!(
                    "{}/{}/{}",
                    l["intersection"].as_str().unwrap(),
                    l["approach"].as_str().unwrap(),
                    l["signal"].as_str().unwrap()
                )
            })
            .collect();
        assert_eq!(listed.len(), 4 * 8 + 1);
        assert_eq!(
            listed.last().map(String::as_str),
            Some("B1/S/straight-2"),
            "the variant follows the cycle's lights"
        );
        let lights = lights_by_name(&scenario);
        assert_eq!(lights.len(), 33, "{:?}", lights.keys());
        let (straight, straight_head) = &lights[&key("straight")];
        let (arrow, arrow_head) = &lights[&key("straight-2")];
        assert_eq!(arrow.len(), 200);
        assert_ne!(straight_head, arrow_head, "each light has a head of its own");
        // 100 s hold a whole 87 s cycle: the arrow shows green alone for
        // 6 s (12 frames, to a frame) each time the window holds it whole,
        // and never red while straight on from the south is green.
        let alone: Vec<bool> = straight.iter().zip(arrow).map(|(s, a)| s == "red" && a == "green").collect();
        let mut runs: Vec<(usize, usize)> = Vec::new();
        for (k, &on) in alone.iter().enumerate() {
            match runs.last_mut() {
                Some((start, len)) if on && *start + *len == k => *len += 1,
                _ if on => runs.push((k, 1)),
                _ => {}
            }
        }
        let whole: Vec<usize> =
            runs.iter().filter(|&&(start, len)| start > 0 && start + len < alone.len()).map(|r| r.1).collect();
        assert!(!whole.is_empty() && whole.iter().all(|n| (11..=13).contains(n)), "{}: {runs:?}", scenario.display());
        assert!(straight.iter().zip(arrow).all(|(s, a)| !(s == "green" && a == "red")));
        arrow_frames += whole.len();
    }
    assert!(arrow_frames >= 4);
    let checked = run(&["validate", out.to_str().unwrap()]);
    assert!(checked.status.success(), "{}", String::from_utf8_lossy(&checked.stdout));

    // A hand-written scenario names it: held red for 50 s, straight on's
    // light keeps its programme.
    let file = dir.join("hold.json");
    std::fs::write(
        &file,
        r#"[{"Name": "Hold", "map": {"sumo": "grid2-arrows.net.xml"}, "frames": 100,
             "city": {"lights": {"phase": "fixed"}},
             "Vehicles": [{"Id": "Car_1", "Spawn": "B0B1_0", "SpawnAtDistance": 20, "DriveQueue": ["right"], "MergeAtDistances": [0]}],
             "interventions": [{"at": 0.0, "do": "set_light", "light": "B1/S/straight-2", "colour": "red", "seconds": 50}]}]"#,
    )
    .unwrap();
    let held = dir.join("held");
    let ran = run(&["run", "--scenario", file.to_str().unwrap(), "--out", held.to_str().unwrap()]);
    assert!(ran.status.success(), "{}", String::from_utf8_lossy(&ran.stderr));
    let lights = lights_by_name(&held.join("Hold"));
    assert!(lights[&key("straight-2")].0.iter().all(|c| c == "red"));
    assert!(lights[&key("straight")].0.iter().any(|c| c == "green"));
    // One it does not have is refused, naming the ones it has.
    let text = std::fs::read_to_string(&file).unwrap().replace("straight-2", "straight-3");
    std::fs::write(&file, text).unwrap();
    let refused = run(&["run", "--scenario", file.to_str().unwrap(), "--out", dir.join("held2").to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert_eq!(refused.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("B1/S/straight-3") && stderr.contains("straight, straight-2"), "{stderr}");
    assert!(!dir.join("held2").exists());
}

#[test]
fn datasets_on_a_junction_of_five_arms_generate_with_frames_and_effects_and_validate() {
    for (network, own_light) in [("star5-priority.net.xml", None), ("star5-lights.net.xml", Some("C/N/straight-2"))] {
        let dir = fresh_dir(&format!("sumo-{network}"));
        let source = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/sumo").join(network);
        std::fs::copy(&source, dir.join(network)).unwrap();
        let spec = write_spec(
            &dir,
            &format!(
                r#"{{"name": "star5", "world": "city", "seed": 5, "frames": 80, "frame_interval": 0.5,
                    "image": {{"width": 256, "height": 160}},
                    "groups": [{{"cars": 6, "edge_proportion": 0.5}}], "splits": {{"train": 2, "val": 1, "test": 1}},
                    "actions_per_car": 4, "map": {{"sumo": "{network}"}}}}"#
            ),
        );
        let out = dir.join("out");
        gen_ok(&spec, &out, &[]);
        let scenarios = scenario_dirs(&out);
        assert_eq!(scenarios.len(), 4, "{network}");
        let schema = validator("scenario.schema.json");
        let mut slight = 0;
        for scenario in &scenarios {
            assert!(scenario.join("rgb/0079.png").is_file() && scenario.join("mask/0079.png").is_file());
            let effects = std::fs::read_to_string(scenario.join("effects.csv")).unwrap();
            assert!(effects.lines().count() > 6, "{}: {} effects rows", scenario.display(), effects.lines().count());
            let meta = read_json(&scenario.join("scenario.json"));
            assert_valid(&schema, &meta, scenario);
            // Drive queues use the lesser of two rights or lefts too.
            slight += meta["cars"]
                .as_array()
                .unwrap()
                .iter()
                .flat_map(|car| car["actions"].as_array().unwrap())
                .filter(|a| *a == "slight_left" || *a == "slight_right")
                .count();
            let lights: Vec<String> = meta["city"]["lights"]
                .as_array()
                .unwrap()
                .iter()
                .map(|l| format!("{}/{}/{}", l["intersection"], l["approach"], l["signal"]).replace('"', ""))
                .collect();
            // With lights, the side street from the north runs on a light of
            // its own; the priority junction has none.
            match own_light {
                Some(name) => assert!(lights.iter().any(|l| l == name), "{lights:?}"),
                None => assert!(lights.is_empty(), "{lights:?}"),
            }
        }
        assert!(slight > 0, "{network}: no car was given a slight turn");
        let report = run(&["validate", out.to_str().unwrap()]);
        assert!(report.status.success(), "{network}: {}", String::from_utf8_lossy(&report.stdout));
    }
}
