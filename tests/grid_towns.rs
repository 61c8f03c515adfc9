//! Grid towns (`map.grid`): a spec asks for rows x columns junctions, and
//! the city world drives, renders, logs its lights and validates on it.

mod common;
use common::*;
use std::collections::BTreeSet;

/// Whether most of the 7 x 7 pixels around (px, py) are road surface (the
/// renderer's asphalt, [66, 68, 72], give or take a tint).
fn is_road(image: &image::RgbImage, px: f64, py: f64) -> bool {
    let (cx, cy) = (px.round() as i64, py.round() as i64);
    let mut road = 0;
    for dx in -3..=3 {
        for dy in -3..=3 {
            let p = image.get_pixel((cx + dx) as u32, (cy + dy) as u32);
            road += p.0.iter().zip([66i32, 68, 72]).all(|(&c, a)| (c as i32 - a).abs() <= 8) as u32;
        }
    }
    road > 25
}

/// A scenario's first bird's-eye frame, and where a point (x, y) m lies in
/// it (pixels), from the camera its scenario.json records.
fn first_frame(scenario: &std::path::Path) -> (image::RgbImage, impl Fn(f64, f64) -> (f64, f64)) {
    let camera = read_json(&scenario.join("scenario.json"))["camera"].clone();
    let image = image::open(scenario.join("rgb/0000.png")).unwrap().to_rgb8();
    let (width, height) = (image.width() as f64, image.height() as f64);
    let pixel = move |x: f64, y: f64| {
        let ppm = camera["pixels_per_metre"].as_f64().unwrap();
        (
            (width - 1.0) / 2.0 + (x - camera["centre_x"].as_f64().unwrap()) * ppm,
            (height - 1.0) / 2.0 - (y - camera["centre_y"].as_f64().unwrap()) * ppm,
        )
    };
    (image, pixel)
}

fn spec_with_map(name: &str, map: serde_json::Value) -> String {
    let mut spec: serde_json::Value =
        serde_json::from_str(&city_spec(name, &[(8, 0.5)], (2, 1, 1), 40, r#"{"confounders": {}}"#)).unwrap();
    spec["map"] = map;
    spec.to_string()
}

/// Writes `spec` into `dir/sub`, runs gen on it and checks that it is
/// refused with exit 2, a message holding `needle`, and nothing written.
fn assert_refused(dir: &std::path::Path, sub: &str, spec: &str, needle: &str) {
    let dir = dir.join(sub);
    std::fs::create_dir_all(&dir).unwrap();
    let spec = write_spec(&dir, spec);
    let refused = run(&["gen", "--spec", spec.to_str().unwrap(), "--out", dir.join("out").to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert_eq!(refused.status.code(), Some(2), "{sub}: {stderr}");
    assert!(stderr.contains(needle), "{sub}: {stderr}");
    assert!(!dir.join("out").exists(), "{sub}: wrote output");
}

#[test]
fn a_three_by_three_grid_town_generates_with_images_and_effects_and_validates() {
    let dir = fresh_dir("grid-town-3x3");
    let grid = write_spec(&dir, &spec_with_map("grid", serde_json::json!({"grid": {"rows": 3, "columns": 3}})));
    let out = dir.join("grid");
    gen_ok(&grid, &out, &[]);
    let validated = run(&["validate", out.to_str().unwrap()]);
    assert!(validated.status.success(), "{}", String::from_utf8_lossy(&validated.stderr));

    let scenarios = scenario_dirs(&out);
    assert_eq!(scenarios.len(), 4);
    let mut spawn_roads = BTreeSet::new();
    for scenario in &scenarios {
        // Every light of all nine junctions, every frame.
        let rows = light_rows(scenario);
        assert_eq!(rows.len(), 40 * 9 * 8, "{}", scenario.display());
        let junctions: BTreeSet<&str> = rows.iter().map(|r| r.intersection.as_str()).collect();
        let expected = ["AD", "AE", "AF", "BD", "BE", "BF", "CD", "CE", "CF"];
        assert_eq!(junctions.into_iter().collect::<Vec<_>>(), expected, "{}", scenario.display());
        let json = read_json(&scenario.join("scenario.json"));
        for car in json["cars"].as_array().unwrap() {
            spawn_roads.insert(car["spawn"].as_str().unwrap().chars().next().unwrap());
        }
        // effects.csv holds the interventional truth here too.
        assert!(std::fs::metadata(scenario.join("effects.csv")).unwrap().len() > 0);
    }
    // Cars start on the new roads too, not only on the default city's A-D.
    assert!(spawn_roads.iter().any(|&r| r > 'D'), "spawn roads {spawn_roads:?}");

    // The bird's-eye camera frames the whole town: every junction's centre
    // is in view and drawn as road (in the default city, (+-28, +-28) m lie
    // off its roads).
    let json = read_json(&scenarios[0].join("scenario.json"));
    let camera = &json["camera"];
    let ppm = camera["pixels_per_metre"].as_f64().unwrap();
    let image = image::open(scenarios[0].join("rgb/0000.png")).unwrap().to_rgb8();
    let mut seen = 0;
    for x in [-28.0, 0.0, 28.0] {
        for y in [-28.0, 0.0, 28.0] {
            let px = (image.width() as f64 - 1.0) / 2.0 + (x - camera["centre_x"].as_f64().unwrap()) * ppm;
            let py = (image.height() as f64 - 1.0) / 2.0 - (y - camera["centre_y"].as_f64().unwrap()) * ppm;
            assert!(px > 3.0 && py > 3.0 && px < image.width() as f64 - 4.0 && py < image.height() as f64 - 4.0);
            assert!(is_road(&image, px, py), "junction at ({x}, {y}) m, pixel ({px:.0}, {py:.0}), is not road");
            seen += 1;
        }
    }
    assert_eq!(seen, 9);
    assert!(camera["altitude_m"].as_f64().unwrap() > 40.0, "the camera rose to frame the bigger town");
    // The same check tells towns apart: in the default city (28, 0) m is a block, not a junction.
    let default = write_spec(&dir, &spec_with_map("default", serde_json::json!({})));
    let default_out = dir.join("default");
    gen_ok(&default, &default_out, &["--limit", "1"]);
    let first = &scenario_dirs(&default_out)[0];
    let ppm = read_json(&first.join("scenario.json"))["camera"]["pixels_per_metre"].as_f64().unwrap();
    let city = image::open(first.join("rgb/0000.png")).unwrap().to_rgb8();
    let centre = ((city.width() as f64 - 1.0) / 2.0, (city.height() as f64 - 1.0) / 2.0);
    assert!(is_road(&city, centre.0 + 14.0 * ppm, centre.1 - 14.0 * ppm), "the default city's junction AD");
    assert!(!is_road(&city, centre.0 + 28.0 * ppm, centre.1), "(28, 0) m in the default city");
}

#[test]
fn causalcity_map_lists_every_lane_id_and_draws_them() {
    let dir = fresh_dir("grid-town-map");
    let spec = write_spec(&dir, &spec_with_map("grid", serde_json::json!({"grid": {"rows": 3, "columns": 3}})));
    let picture = dir.join("map.png");
    let output = run(&["map", "--spec", spec.to_str().unwrap(), "--out", picture.to_str().unwrap(), "--json"]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let listed: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    assert_eq!(listed["junctions"].as_array().unwrap().len(), 9);
    let lanes = listed["lanes"].as_array().unwrap();
    // 6 roads of 4 segments of 4 lanes; names unique, as scenario files use them.
    assert_eq!(lanes.len(), 96);
    let names: BTreeSet<&str> = lanes.iter().map(|l| l["name"].as_str().unwrap()).collect();
    assert_eq!(names.len(), 96);
    assert!(names.contains("A0w") && names.contains("F3z"), "{names:?}");
    let a1w = lanes.iter().find(|l| l["name"] == "A1w").unwrap();
    assert_eq!(a1w["ends_at"], "AE from W");
    assert_eq!(a1w["turns"], serde_json::json!(["straight", "right"]));

    // The picture: the spec's image size, with yellow lane labels over the roads.
    let image = image::open(&picture).unwrap().to_rgb8();
    assert_eq!(image.dimensions(), (1024, 640));
    let labels = image.pixels().filter(|p| p.0 == [250, 235, 120]).count();
    assert!(labels > 96 * 20, "label boxes cover {labels} pixels");

    // Bad input: exit 2, nothing written. (A spec named .png, so that only
    // the write rule stands between the picture and its own input.)
    let png_spec = dir.join("spec-named.png");
    std::fs::copy(&spec, &png_spec).unwrap();
    let (spec, png_spec) = (spec.to_str().unwrap(), png_spec.to_str().unwrap());
    for (case, args, needle) in [
        ("not a png", vec!["map", "--spec", spec, "--out", "x.gif"], "ending in .png"),
        ("onto its spec", vec!["map", "--spec", png_spec, "--out", png_spec], "the spec it draws"),
        ("no such spec", vec!["map", "--spec", "/nonexistent/spec.json"], "/nonexistent/spec.json"),
    ] {
        let before = std::fs::read(png_spec).unwrap();
        let output = run(&args);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{case}: {stderr}");
        assert!(stderr.contains(needle), "{case}: {stderr}");
        assert_eq!(std::fs::read(png_spec).unwrap(), before, "{case}: the spec is untouched");
    }
    assert!(!std::path::Path::new("x.gif").exists());
}

/// Every file under `root` (relative path, bytes), sorted.
fn tree(root: &std::path::Path) -> Vec<(String, Vec<u8>)> {
    let mut files = Vec::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
            } else {
                let name = path.strip_prefix(root).unwrap().display().to_string();
                if name != "manifest.json" && !name.starts_with(".causalcity") {
                    files.push((name, std::fs::read(&path).unwrap()));
                }
            }
        }
    }
    files.sort();
    files
}

#[test]
fn a_spec_draws_each_scenarios_town_and_records_it_so_it_can_be_rebuilt() {
    let dir = fresh_dir("grid-town-drawn");
    let mut spec: serde_json::Value =
        serde_json::from_str(&city_spec("towns", &[(6, 0.5)], (10, 2, 2), 20, r#"{"confounders": {}}"#)).unwrap();
    spec["map"] = serde_json::json!({"grid": {"rows": {"uniform": [1, 3]}, "columns": {"choice": [2, 4]}}});
    let spec = write_spec(&dir, &spec.to_string());
    let out = dir.join("towns");
    gen_ok(&spec, &out, &["--threads", "2"]);
    let validated = run(&["validate", out.to_str().unwrap()]);
    assert!(validated.status.success(), "{}", String::from_utf8_lossy(&validated.stdout));

    let mut towns = BTreeSet::new();
    let mut checked = 0;
    for scenario in scenario_dirs(&out) {
        let json = read_json(&scenario.join("scenario.json"));
        let town = json["town"].as_str().unwrap().to_string();
        let (rows, columns) =
            (json["map"]["grid"]["rows"].as_u64().unwrap(), json["map"]["grid"]["columns"].as_u64().unwrap());
        assert_eq!(town, format!("grid-{rows}x{columns}"));
        assert!((1..=3).contains(&rows) && [2, 4].contains(&columns), "{town}");
        towns.insert(town.clone());
        // Every light of the town's junctions, every frame.
        let lights = light_rows(&scenario).len();
        assert_eq!(lights as u64, 20 * rows * columns * 8, "{}", scenario.display());

        // The recorded map rebuilds the town: as a spec's map, `causalcity map` lists its junctions.
        let rebuilt = dir.join("rebuilt.json");
        std::fs::write(&rebuilt, rebuilt_text(&spec, &json["map"])).unwrap();
        let listed = run(&["map", "--spec", rebuilt.to_str().unwrap(), "--json"]);
        assert!(listed.status.success(), "{}", String::from_utf8_lossy(&listed.stderr));
        let listed: serde_json::Value = serde_json::from_slice(&listed.stdout).unwrap();
        assert_eq!(listed["junctions"].as_array().unwrap().len() as u64, rows * columns);
        assert_eq!(listed["town"], town.as_str());

        // The frame frames this town: every junction centre is road.
        let camera = &json["camera"];
        let ppm = camera["pixels_per_metre"].as_f64().unwrap();
        let image = image::open(scenario.join("rgb/0000.png")).unwrap().to_rgb8();
        for centre in listed["junction_centres"].as_array().unwrap() {
            let (x, y) = (centre[0].as_f64().unwrap(), centre[1].as_f64().unwrap());
            let px = (image.width() as f64 - 1.0) / 2.0 + (x - camera["centre_x"].as_f64().unwrap()) * ppm;
            let py = (image.height() as f64 - 1.0) / 2.0 - (y - camera["centre_y"].as_f64().unwrap()) * ppm;
            assert!(is_road(&image, px, py), "{town}: junction at ({x}, {y}) m is not road in {}", scenario.display());
            checked += 1;
        }
    }
    assert!(towns.len() >= 4, "only towns {towns:?} drawn in 14 scenarios");
    assert!(checked >= 14 * 2, "only {checked} junctions checked");

    // The draw is the seed's: the same bytes on one thread.
    let again = dir.join("again");
    gen_ok(&spec, &again, &["--threads", "1"]);
    assert!(tree(&out) == tree(&again), "a rerun on one thread wrote different bytes");

    // The listing names every town; a heat map, which draws one, refuses.
    let listed = run(&["map", "--spec", spec.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&listed.stdout);
    assert!(text.contains("of the 6 the spec draws") && text.contains("grid-3x4"), "{text}");
    let unknown = run(&["map", "--spec", spec.to_str().unwrap(), "--town", "grid-9x9"]);
    assert_eq!(unknown.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&unknown.stderr).contains("use one of grid-1x2"));
    let heat = run(&["heatmap", out.to_str().unwrap(), "--out", dir.join("heat.png").to_str().unwrap()]);
    assert_eq!(heat.status.code(), Some(2), "{}", String::from_utf8_lossy(&heat.stderr));
    assert!(String::from_utf8_lossy(&heat.stderr).contains("towns"));
    assert!(!dir.join("heat.png").exists());
    let stats = run(&["stats", out.to_str().unwrap()]);
    assert!(stats.status.success(), "{}", String::from_utf8_lossy(&stats.stderr));
}

/// The spec at `spec` with `map` as its map section.
fn rebuilt_text(spec: &std::path::Path, map: &serde_json::Value) -> String {
    let mut value: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(spec).unwrap()).unwrap();
    value["map"] = map.clone();
    value.to_string()
}

#[test]
fn a_split_can_hold_out_towns_and_graph_shapes_and_validate_says_what_train_and_test_share() {
    let dir = fresh_dir("grid-town-held-out");
    let mut spec: serde_json::Value =
        serde_json::from_str(&city_spec("ood", &[(8, 0.5)], (6, 2, 3), 20, r#"{"confounders": {}}"#)).unwrap();
    spec["map"] = serde_json::json!({"grid": {"rows": {"choice": [2, 3]}, "columns": 2}});
    spec["held_out"] =
        serde_json::json!({"test": {"map": {"grid": {"rows": 4, "columns": 3}}, "graph": {"shape": "chains"}}});
    let spec_path = write_spec(&dir, &spec.to_string());
    let out = dir.join("ood");
    gen_ok(&spec_path, &out, &["--no-images"]);

    let mut seen: std::collections::BTreeMap<String, BTreeSet<String>> = Default::default();
    let mut chains = 0;
    for scenario in scenario_dirs(&out) {
        let json = read_json(&scenario.join("scenario.json"));
        let split = json["split"].as_str().unwrap().to_string();
        seen.entry(split.clone()).or_default().insert(json["town"].as_str().unwrap().to_string());
        let edges: Vec<(u64, u64)> = json["edges"]
            .as_array()
            .unwrap()
            .iter()
            .map(|e| (e[0].as_u64().unwrap(), e[1].as_u64().unwrap()))
            .collect();
        let linked = edges.iter().filter(|(a, _)| edges.iter().any(|(_, b)| b == a)).count();
        if split == "test" {
            assert_eq!(linked, 1, "a test scenario's 2 edges form a chain: {edges:?}");
            chains += 1;
        } else {
            assert_eq!(linked, 0, "train and val keep disjoint pairs: {edges:?}");
        }
    }
    assert_eq!(chains, 3);
    assert_eq!(seen["test"], BTreeSet::from(["grid-4x3".to_string()]));
    for split in ["train", "val"] {
        assert!(seen[split].iter().all(|t| t == "grid-2x2" || t == "grid-3x2"), "{split}: {:?}", seen[split]);
    }
    assert!(seen["train"].len() == 2, "train drew {:?}", seen["train"]);

    // validate checks every scenario against its split's towns and says what train and test share.
    let report = run(&["validate", out.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&report.stdout);
    assert!(report.status.success(), "{text}");
    assert!(text.contains("test  towns grid-4x3; graph chains of 3; cars 8 (held out: map, graph)"), "{text}");
    assert!(
        text.contains("train and test share: no town; no graph shape; the car counts; the confounder ranges"),
        "{text}"
    );
    let json: serde_json::Value =
        serde_json::from_slice(&run(&["validate", out.to_str().unwrap(), "--json"]).stdout).unwrap();
    assert_eq!(json["design"]["shared_towns"], serde_json::json!([]));
    assert_eq!(json["design"]["splits"][2]["held_out"], serde_json::json!(["map", "graph"]));

    // A test scenario moved into train is caught: its town is not one train draws.
    let test = out.join("cars08_edges50/test/00000/scenario.json");
    let train = out.join("cars08_edges50/train/00000/scenario.json");
    let (test_json, mut train_json) = (read_json(&test), read_json(&train));
    train_json["map"] = test_json["map"].clone();
    let bytes = serde_json::to_vec_pretty(&train_json).unwrap();
    std::fs::write(&train, &bytes).unwrap();
    let report = run(&["validate", out.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&report.stdout);
    assert_eq!(report.status.code(), Some(1), "{text}");
    assert!(text.contains("is not a town the spec draws for train"), "{text}");
}

#[test]
fn a_split_can_hold_out_confounder_ranges_drawing_the_same_numbers_through_them() {
    let dir = fresh_dir("held-out-confounders");
    for sub in ["a", "b", "c"] {
        std::fs::create_dir_all(dir.join(sub)).unwrap();
    }
    let city = r#"{"confounders": {"hour": {"uniform": [8, 16]}, "rain": 0.0}}"#;
    let twin: serde_json::Value = serde_json::from_str(&city_spec("twin", &[(6, 0.5)], (3, 2, 4), 12, city)).unwrap();
    let mut held = twin.clone();
    held["held_out"] = serde_json::json!({"test": {"confounders": {"hour": {"uniform": [20, 24]}, "rain": 1.0}}});
    let (twin_out, held_out) = (dir.join("twin"), dir.join("held"));
    gen_ok(&write_spec(&dir.join("a"), &twin.to_string()), &twin_out, &["--no-images", "--no-effects"]);
    gen_ok(&write_spec(&dir.join("b"), &held.to_string()), &held_out, &["--no-images", "--no-effects"]);
    let mut tested = 0;
    for scenario in scenario_dirs(&twin_out) {
        let rel = scenario.strip_prefix(&twin_out).unwrap();
        let (a, b) = (read_json(&scenario.join("scenario.json")), read_json(&held_out.join(rel).join("scenario.json")));
        if a["split"] != "test" {
            // Train and val are those of the spec without held_out, byte for byte.
            for file in ["scenario.json", "poses.csv", "light_changes.csv"] {
                assert_eq!(
                    std::fs::read(scenario.join(file)).unwrap(),
                    std::fs::read(held_out.join(rel).join(file)).unwrap()
                );
            }
            continue;
        }
        let (ca, cb) = (&a["city"]["confounders"], &b["city"]["confounders"]);
        let (hour_a, hour_b) = (ca["hour"].as_f64().unwrap(), cb["hour"].as_f64().unwrap());
        assert!((8.0..=16.0).contains(&hour_a) && (20.0..=24.0).contains(&hour_b), "{hour_a} {hour_b}");
        // The same exogenous number read through the held-out range.
        assert!(((hour_a - 8.0) / 8.0 - (hour_b - 20.0) / 4.0).abs() < 1e-9, "{hour_a} {hour_b}");
        assert_eq!((ca["rain"].as_f64(), cb["rain"].as_f64()), (Some(0.0), Some(1.0)));
        assert_eq!(a["city"]["confounder_model"]["exogenous"], b["city"]["confounder_model"]["exogenous"]);
        tested += 1;
    }
    assert_eq!(tested, 4);
    let report = run(&["validate", held_out.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&report.stdout);
    assert!(report.status.success(), "{text}");
    assert!(text.contains("(held out: confounders)") && text.contains("not the confounder ranges"), "{text}");
    // Out of range, or in the toy world: refused, naming the field.
    let mut bad = twin.clone();
    bad["held_out"] = serde_json::json!({"test": {"confounders": {"hour": 25.0}}});
    let refused = run(&[
        "gen",
        "--spec",
        write_spec(&dir.join("c"), &bad.to_string()).to_str().unwrap(),
        "--out",
        dir.join("c/out").to_str().unwrap(),
    ]);
    assert_eq!(refused.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&refused.stderr).contains("held_out.test.confounders.hour"), "{:?}", refused);
    assert!(!dir.join("c/out").exists());
}

#[test]
fn perspective_cameras_and_masks_work_on_drawn_towns() {
    let dir = fresh_dir("grid-town-cameras");
    let mut spec: serde_json::Value =
        serde_json::from_str(&city_spec("cams", &[(6, 0.5)], (4, 0, 0), 16, r#"{"confounders": {}}"#)).unwrap();
    spec["map"] = serde_json::json!({"grid": {"rows": {"choice": [2, 4]}, "columns": 3}});
    spec["birds_eye"] = "pinhole".into();
    spec["cameras"] = serde_json::json!([
        {"name": "chase0", "third_person": 0, "width": 160, "height": 100, "depth": true},
        {"name": "driver1", "first_person": 1, "width": 160, "height": 100}
    ]);
    let spec = write_spec(&dir, &spec.to_string());
    let out = dir.join("cams");
    gen_ok(&spec, &out, &[]);
    let validated = run(&["validate", out.to_str().unwrap()]);
    assert!(validated.status.success(), "{}", String::from_utf8_lossy(&validated.stdout));
    let mut towns = BTreeSet::new();
    for scenario in scenario_dirs(&out) {
        towns.insert(read_json(&scenario.join("scenario.json"))["town"].as_str().unwrap().to_string());
        // The chased car fills part of the third-person view: its mask id (id + 1 = 1) is there.
        let mask = image::open(scenario.join("cameras/chase0/mask/0008.png")).unwrap().to_luma8();
        assert!(
            mask.pixels().filter(|p| p.0[0] == 1).count() > 50,
            "{}: car 0 not seen from behind",
            scenario.display()
        );
        // The bird's-eye masks name every car seen, each with its own id.
        let birds_eye = image::open(scenario.join("mask/0008.png")).unwrap().to_luma8();
        let ids: BTreeSet<u8> = birds_eye.pixels().map(|p| p.0[0]).filter(|&v| v > 0).collect();
        assert!(ids.len() >= 3 && ids.iter().all(|&v| v <= 6), "{}: mask ids {ids:?}", scenario.display());
        assert!(scenario.join("cameras/chase0/depth/0008.png").exists());
    }
    assert_eq!(towns.len(), 2, "both towns drawn in 4 scenarios: {towns:?}");
}

#[test]
fn the_birds_eye_camera_frames_the_whole_network_or_an_area_the_spec_gives() {
    let dir = fresh_dir("grid-town-camera-area");
    for (name, area) in
        [("network", serde_json::json!("network")), ("area", serde_json::json!({"x": [-20, 20], "y": [-10, 10]}))]
    {
        let mut spec: serde_json::Value =
            serde_json::from_str(&city_spec(name, &[(4, 0.5)], (1, 0, 0), 4, r#"{"confounders": {}}"#)).unwrap();
        spec["map"] = serde_json::json!({"grid": {"rows": 2, "columns": 3}, "camera_area": area});
        let spec_path = dir.join(format!("{name}.json"));
        std::fs::write(&spec_path, spec.to_string()).unwrap();
        let out = dir.join(name);
        gen_ok(&spec_path, &out, &[]);
        let scenario = &scenario_dirs(&out)[0];
        let camera = read_json(&scenario.join("scenario.json"))["camera"].clone();
        let ppm = camera["pixels_per_metre"].as_f64().unwrap();
        let (cx, cy) = (camera["centre_x"].as_f64().unwrap(), camera["centre_y"].as_f64().unwrap());
        let to_pixel = |x: f64, y: f64| (511.5 + (x - cx) * ppm, 319.5 - (y - cy) * ppm);
        if name == "network" {
            // Every lane, out to the U-turn loops, is in the picture, and the view is no larger than
            // the network needs: along one axis the lanes span most of the image.
            let listed = run(&["map", "--spec", spec_path.to_str().unwrap(), "--json"]);
            let listed: serde_json::Value = serde_json::from_slice(&listed.stdout).unwrap();
            let (mut xs, mut ys) = (Vec::new(), Vec::new());
            for lane in listed["lanes"].as_array().unwrap() {
                for end in ["start", "end"] {
                    let (px, py) = to_pixel(lane[end][0].as_f64().unwrap(), lane[end][1].as_f64().unwrap());
                    assert!(
                        (0.0..1024.0).contains(&px) && (0.0..640.0).contains(&py),
                        "{} {end} at ({px}, {py})",
                        lane["name"]
                    );
                    xs.push(px);
                    ys.push(py);
                }
            }
            let span =
                |v: &[f64]| v.iter().fold(f64::MIN, |a, &b| a.max(b)) - v.iter().fold(f64::MAX, |a, &b| a.min(b));
            assert_eq!(xs.len(), 2 * 68, "2 x 4 + 3 x 3 segments of 4 lanes, both ends");
            assert!(
                span(&xs) > 0.7 * 1024.0 || span(&ys) > 0.7 * 640.0,
                "lanes span {:.0} x {:.0} px",
                span(&xs),
                span(&ys)
            );
        } else {
            // 40 m x 20 m at 1024 x 640: 40 m across, centred on the area.
            assert_eq!((cx, cy), (0.0, 0.0));
            assert!((ppm - 1024.0 / 40.0).abs() < 0.05, "{ppm} px per metre");
        }
        let validated = run(&["validate", out.to_str().unwrap()]);
        assert!(validated.status.success(), "{}", String::from_utf8_lossy(&validated.stdout));
    }
}

#[test]
fn a_split_can_hold_out_the_car_count_keeping_train_and_val_and_every_reader_agrees() {
    let dir = fresh_dir("held-out-cars");
    for sub in ["a", "b", "c", "d"] {
        std::fs::create_dir_all(dir.join(sub)).unwrap();
    }
    let twin: serde_json::Value =
        serde_json::from_str(&city_spec("twin", &[(6, 0.5), (8, 0.8)], (3, 2, 2), 12, r#"{"confounders": {}}"#))
            .unwrap();
    let mut held = twin.clone();
    held["held_out"] = serde_json::json!({"test": {"cars": 10}});
    let (twin_out, held_out) = (dir.join("twin"), dir.join("held"));
    gen_ok(&write_spec(&dir.join("a"), &twin.to_string()), &twin_out, &["--no-images"]);
    gen_ok(&write_spec(&dir.join("b"), &held.to_string()), &held_out, &["--no-images"]);

    // Train and val are the twin's byte for byte; test scenarios have 10
    // cars and each group's edge proportion of them (0.5: 3 edges; 0.8: 4).
    let mut tested = 0;
    for scenario in scenario_dirs(&twin_out) {
        let rel = scenario.strip_prefix(&twin_out).unwrap();
        let json = read_json(&held_out.join(rel).join("scenario.json"));
        if json["split"] != "test" {
            for file in ["scenario.json", "poses.csv", "light_changes.csv", "effects.csv"] {
                assert_eq!(
                    std::fs::read(scenario.join(file)).unwrap(),
                    std::fs::read(held_out.join(rel).join(file)).unwrap(),
                    "{rel:?} {file}"
                );
            }
            continue;
        }
        assert_eq!(json["cars"].as_array().unwrap().len(), 10, "{rel:?}");
        let edges = json["edges"].as_array().unwrap().len();
        let want = if rel.starts_with("cars06_edges50") { 3 } else { 4 };
        assert_eq!(edges, want, "{rel:?}");
        let poses = read_poses(&held_out.join(rel).join("poses.csv"));
        assert_eq!(poses_by_car(&poses).len(), 10);
        // Effects back the test scenarios too: a row per ordered pair of cars.
        let effects = std::fs::read_to_string(held_out.join(rel).join("effects.csv")).unwrap();
        assert!(effects.lines().count() > 90, "{rel:?}: {} rows", effects.lines().count());
        tested += 1;
    }
    assert_eq!(tested, 4);

    // The manifest records the split's own count; validate checks it and says what is shared.
    let manifest = read_json(&held_out.join("manifest.json"));
    assert_eq!(manifest["groups"][0]["held_out"], serde_json::json!({"test": {"cars": 10, "edges": 3}}));
    assert_eq!(manifest["groups"][1]["cars"], 8);
    assert_valid(&validator("manifest.schema.json"), &manifest, &held_out.join("manifest.json"));
    let report = run(&["validate", held_out.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&report.stdout);
    assert!(report.status.success(), "{text}");
    assert!(text.contains("train towns default; graph pairs; cars 6 8\n"), "{text}");
    assert!(text.contains("test  towns default; graph pairs; cars 10 10 (held out: cars)"), "{text}");
    assert!(text.contains("train and test share: default; the graph shape; not the car counts"), "{text}");

    // export nri gives test its own car count.
    let export = dir.join("nri");
    let exported = run(&["export", "nri", held_out.to_str().unwrap(), "--out", export.to_str().unwrap()]);
    assert!(exported.status.success(), "{}", String::from_utf8_lossy(&exported.stderr));
    let header = |name: &str| {
        let bytes = std::fs::read(export.join("cars06_edges50").join(name)).unwrap();
        String::from_utf8_lossy(&bytes[..128]).to_string()
    };
    assert!(header("loc_train.npy").contains("(3, 12, 6, 2, )"), "{}", header("loc_train.npy"));
    assert!(header("loc_test.npy").contains("(2, 12, 10, 2, )"), "{}", header("loc_test.npy"));

    // A test scenario with a train-sized car list is caught.
    let test = held_out.join("cars06_edges50/test/00000/scenario.json");
    let mut json = read_json(&test);
    json["cars"].as_array_mut().unwrap().truncate(6);
    std::fs::write(&test, serde_json::to_vec_pretty(&json).unwrap()).unwrap();
    let report = run(&["validate", held_out.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&report.stdout);
    assert_eq!(report.status.code(), Some(1), "{text}");
    assert!(text.contains("6 cars, the spec asks for 10 in test"), "{text}");

    // Refused with exit 2, naming the field, nothing written: no cars, or
    // more than the map holds, or too few for the group's edges.
    for (sub, value, field) in [
        ("c", serde_json::json!({"test": {"cars": 0}}), "held_out.test.cars"),
        ("d", serde_json::json!({"val": {"cars": 200}}), "held_out.val.cars"),
    ] {
        let mut bad = twin.clone();
        bad["held_out"] = value;
        let out = dir.join(sub).join("out");
        let refused = run(&[
            "gen",
            "--spec",
            write_spec(&dir.join(sub), &bad.to_string()).to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]);
        let stderr = String::from_utf8_lossy(&refused.stderr);
        assert_eq!(refused.status.code(), Some(2), "{stderr}");
        assert!(stderr.contains(field), "{stderr}");
        assert!(!out.exists());
    }
}

#[test]
fn a_town_with_t_junctions_generates_draws_and_validates_and_no_car_drives_a_missing_road() {
    let dir = fresh_dir("grid-town-tees");
    let map = serde_json::json!({"grid": {"rows": 3, "columns": 3, "missing": ["D0", "B2", "E3"]}});
    let spec = write_spec(&dir, &spec_with_map("tees", map.clone()));
    let out = dir.join("tees");
    gen_ok(&spec, &out, &[]);
    let report = run(&["validate", out.to_str().unwrap()]);
    assert!(report.status.success(), "{}", String::from_utf8_lossy(&report.stdout));

    let scenarios = scenario_dirs(&out);
    assert_eq!(scenarios.len(), 4);
    let (image, pixel) = first_frame(&scenarios[0]);
    // Road B runs from D to E (B1) but not on to F (B2); every junction box
    // is road. (Along the inner lane, clear of markings; a car may hide one point.)
    let road_along = |x: f64| {
        [-4.0, 0.0, 4.0].iter().filter(|&&dx| is_road(&image, pixel(x + dx, 1.5).0, pixel(x + dx, 1.5).1)).count()
    };
    assert!(road_along(-14.0) >= 2, "B1");
    assert_eq!(road_along(14.0), 0, "B2 is left out");
    for (x, y) in [(-28.0, -28.0), (0.0, 0.0), (28.0, 0.0), (0.0, 28.0)] {
        let (px, py) = pixel(x, y);
        assert!(is_road(&image, px, py), "the T-junction at ({x}, {y}) m");
    }
    // No car ever stands on B2's ground (x 6..22 m, |y| < 6 m), in any frame of any scenario.
    let mut poses = 0;
    for scenario in &scenarios {
        for pose in read_poses(&scenario.join("poses.csv")) {
            assert!(!(pose.x > 6.0 && pose.x < 22.0 && pose.y.abs() < 6.0), "{pose:?} in {}", scenario.display());
            poses += 1;
        }
        assert!(std::fs::metadata(scenario.join("effects.csv")).unwrap().len() > 0);
    }
    assert_eq!(poses, 4 * 40 * 8);
    // The manifest's spec records the town, missing segments included, so that it can be rebuilt.
    let manifest = read_json(&out.join("manifest.json"));
    assert_eq!(manifest["spec"]["map"]["grid"]["missing"], serde_json::json!(["D0", "B2", "E3"]));

    // Refused with exit 2, naming the field, nothing written.
    for (sub, missing, needle) in [
        ("unknown", serde_json::json!(["Z9"]), "map.grid.missing[0]`: \"Z9\" is not a road segment"),
        ("twice", serde_json::json!(["B2", "B2"]), "\"B2\" is named twice"),
        ("corner", serde_json::json!(["C0", "D0"]), "junction CD would keep 2 roads"),
    ] {
        let mut bad = map.clone();
        bad["grid"]["missing"] = missing;
        assert_refused(&dir, sub, &spec_with_map("bad", bad), needle);
    }
}

#[test]
fn a_town_of_one_lane_roads_generates_draws_and_validates() {
    let dir = fresh_dir("grid-town-one-lane");
    let map = serde_json::json!({"grid": {"rows": 3, "columns": 3, "lanes": 1, "missing": ["B2"]}});
    let spec = write_spec(&dir, &spec_with_map("one", map.clone()));
    let out = dir.join("one");
    gen_ok(&spec, &out, &[]);
    let report = run(&["validate", out.to_str().unwrap()]);
    assert!(report.status.success(), "{}", String::from_utf8_lossy(&report.stdout));
    let scenarios = scenario_dirs(&out);
    let (image, pixel) = first_frame(&scenarios[0]);
    // Road B is 6 m wide: road 1.5 m off its centre line, none 4.5 m off
    // (where a two-lane road's outer lanes run). A car may hide one point.
    let road_at =
        |y: f64| [-18.0, -14.0, -10.0].iter().filter(|&&x| is_road(&image, pixel(x, y).0, pixel(x, y).1)).count();
    assert!(road_at(1.5) >= 2 && road_at(-1.5) >= 2);
    assert_eq!(road_at(5.0) + road_at(-5.0), 0);
    // Every car keeps to a lane: within 1.5 m of a road's centre line
    // (y or x a multiple of 28 m) or on a junction's curves or loops.
    let mut poses = 0;
    for scenario in &scenarios {
        for p in read_poses(&scenario.join("poses.csv")) {
            let off = |v: f64| (v - (v / 28.0).round() * 28.0).abs();
            assert!(off(p.x).min(off(p.y)) < 3.0 + 1e-6 || p.x.abs() > 40.0 || p.y.abs() > 40.0, "{p:?}");
            poses += 1;
        }
    }
    assert_eq!(poses, 4 * 40 * 8);
    // 1 to 3 lanes each way: 4 is refused naming the field, nothing written.
    let mut bad = map.clone();
    bad["grid"]["lanes"] = serde_json::json!(4);
    assert_refused(&dir, "bad", &spec_with_map("bad", bad), "map.grid.lanes`: 4 is not allowed");
}

#[test]
fn a_town_of_three_lane_roads_generates_draws_and_validates() {
    let dir = fresh_dir("grid-town-three-lanes");
    let map = serde_json::json!({"grid": {"rows": 2, "columns": 2, "lanes": 3, "block_m": 44, "outer_m": 34, "missing": ["C0"]}});
    let spec = write_spec(&dir, &spec_with_map("three", map));
    let out = dir.join("three");
    gen_ok(&spec, &out, &[]);
    let report = run(&["validate", out.to_str().unwrap()]);
    assert!(report.status.success(), "{}", String::from_utf8_lossy(&report.stdout));
    let scenarios = scenario_dirs(&out);
    let (image, pixel) = first_frame(&scenarios[0]);
    // Road B (y = -22 m) is 18 m wide: road 7.5 m off its centre line, none 10.5 m off.
    let road_at = |y: f64| [-4.0, 0.0, 4.0].iter().filter(|&&x| is_road(&image, pixel(x, y).0, pixel(x, y).1)).count();
    assert!(road_at(-22.0 + 7.5) >= 2 && road_at(-22.0 - 7.5) >= 2);
    assert_eq!(road_at(-22.0 + 10.5) + road_at(-22.0 - 10.5), 0);
    // Cars start on middle lanes too, and every scenario is backed by effects.
    let mut middle = 0;
    for scenario in &scenarios {
        let json = read_json(&scenario.join("scenario.json"));
        middle += json["cars"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|c| c["spawn"].as_str().unwrap().ends_with(['m', 'n']))
            .count();
        assert!(std::fs::metadata(scenario.join("effects.csv")).unwrap().len() > 0);
    }
    assert!(middle > 0, "no car started on a middle lane");
}

#[test]
fn a_town_with_priority_junctions_and_all_way_stops_generates_draws_and_validates() {
    let dir = fresh_dir("grid-town-control");
    let control = serde_json::json!({"AC": "priority", "AD": "all_way_stop", "BC": "all_way_stop"});
    let map = serde_json::json!({"grid": {"rows": 2, "columns": 2, "control": control}});
    let spec = write_spec(&dir, &spec_with_map("control", map.clone()));
    let out = dir.join("control");
    gen_ok(&spec, &out, &[]);
    let report = run(&["validate", out.to_str().unwrap()]);
    assert!(report.status.success(), "{}", String::from_utf8_lossy(&report.stdout));
    let manifest = read_json(&out.join("manifest.json"));
    assert_eq!(manifest["spec"]["map"]["grid"]["control"], control, "recorded so that it can be rebuilt");

    let scenarios = scenario_dirs(&out);
    assert_eq!(scenarios.len(), 4);
    let mut kinds = BTreeSet::new();
    for scenario in &scenarios {
        // Only BD has lights: 8 of them, every frame.
        let lights = light_rows(scenario);
        let junctions: BTreeSet<&str> = lights.iter().map(|l| l.intersection.as_str()).collect();
        assert_eq!(junctions, BTreeSet::from(["BD"]), "{}", scenario.display());
        assert_eq!(lights.len(), 40 * 8);
        for row in read_csv::<InteractionRow>(&scenario.join("interactions.csv")) {
            if row.bound_by == "give_way" {
                assert!(row.other_car.is_some_and(|j| j != row.car), "{row:?}");
            }
            kinds.insert(row.bound_by);
        }
        assert!(std::fs::metadata(scenario.join("effects.csv")).unwrap().len() > 0);
    }
    assert!(kinds.contains("stop_line") && kinds.contains("give_way"), "{kinds:?}");

    // Stop signs stand at AD (14, 14) and BC (-14, -14), none at BD (14, -14),
    // which shows its signal heads instead.
    let (image, pixel) = first_frame(&scenarios[0]);
    let signs_near = |x: f64, y: f64| {
        let (px, py) = pixel(x, y);
        let reach = 12.0 * (pixel(1.0, 0.0).0 - pixel(0.0, 0.0).0);
        image
            .enumerate_pixels()
            .filter(|(ix, iy, p)| {
                (*ix as f64 - px).abs() < reach && (*iy as f64 - py).abs() < reach && p.0 == [196, 32, 36]
            })
            .count()
    };
    assert!(signs_near(14.0, 14.0) > 0 && signs_near(-14.0, -14.0) > 0, "no stop signs drawn");
    assert_eq!(signs_near(14.0, -14.0), 0, "a stop sign at a junction with lights");

    // Refused with exit 2, naming the field, nothing written.
    let overridden = r#"{"confounders": {}, "lights": {"overrides": [{"intersection": "AD", "approach": "N", "signal": "straight", "schedule": [{"colour": "green", "duration": 5}]}]}}"#;
    for (sub, control, city, needle) in [
        // Every control a junction takes is named (right_before_left was not).
        (
            "kind",
            serde_json::json!("roundabout"),
            None,
            "\"roundabout\" is not allowed: use \"signals\", \"priority\", \"all_way_stop\", \"right_before_left\", or",
        ),
        ("junction", serde_json::json!({"XY": "priority"}), None, "map.grid.control.XY`: \"XY\" is not a junction"),
        (
            "override",
            control.clone(),
            Some(overridden),
            "city.lights.overrides[0].intersection`: \"AD\" has no traffic lights",
        ),
    ] {
        let mut bad = map.clone();
        bad["grid"]["control"] = control;
        let mut text: serde_json::Value = serde_json::from_str(&spec_with_map("bad", bad)).unwrap();
        if let Some(city) = city {
            text["city"] = serde_json::from_str(city).unwrap();
        }
        assert_refused(&dir, sub, &text.to_string(), needle);
    }
}

#[test]
fn the_shipped_ood_control_spec_tests_on_a_town_without_lights_after_training_with_them() {
    let dir = fresh_dir("ood-control");
    let shipped = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/ood-control.json");
    let mut spec: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(shipped).unwrap()).unwrap();
    spec["splits"] = serde_json::json!({"train": 2, "val": 1, "test": 2});
    spec["frames"] = serde_json::json!(30);
    let spec = write_spec(&dir, &spec.to_string());
    let out = dir.join("ood");
    gen_ok(&spec, &out, &["--no-images"]);
    let mut splits = BTreeSet::new();
    for scenario in scenario_dirs(&out) {
        let split = scenario.parent().unwrap().file_name().unwrap().to_str().unwrap().to_string();
        let rows = light_rows(&scenario).len();
        let town = read_json(&scenario.join("scenario.json"))["town"].as_str().unwrap_or("").to_string();
        if split == "test" {
            assert_eq!(rows, 0, "{}: lights in the held-out town", scenario.display());
            assert!(town.contains("priority") && town.contains("all_way_stop"), "{town}");
        } else {
            assert!(rows > 0, "{}: no lights in a training town", scenario.display());
        }
        splits.insert(split);
    }
    assert_eq!(splits.len(), 3);
    let report = run(&["validate", out.to_str().unwrap()]);
    assert!(report.status.success(), "{}", String::from_utf8_lossy(&report.stdout));
}

#[test]
fn a_town_with_dead_ends_generates_draws_and_validates_and_cars_turn_back_before_the_cut() {
    let dir = fresh_dir("grid-town-dead-ends");
    // 40 m blocks: B2 (x 6..34 m at y 0) stays joined to BE and turns back
    // 8 m short of BF; D1 (x -40) stays joined to CD, short of BD.
    let map =
        serde_json::json!({"grid": {"rows": 3, "columns": 3, "block_m": 40, "dead_ends": {"B2": "BE", "D1": "CD"}}});
    let spec = write_spec(&dir, &spec_with_map("dead", map.clone()));
    let out = dir.join("dead");
    gen_ok(&spec, &out, &[]);
    let report = run(&["validate", out.to_str().unwrap()]);
    assert!(report.status.success(), "{}", String::from_utf8_lossy(&report.stdout));
    let manifest = read_json(&out.join("manifest.json"));
    assert_eq!(manifest["spec"]["map"]["grid"]["dead_ends"], map["grid"]["dead_ends"]);

    let scenarios = scenario_dirs(&out);
    let (image, pixel) = first_frame(&scenarios[0]);
    // Road B is road up to its loop and ground in the gap before BF's box.
    let (px, py) = pixel(20.0, 1.5);
    assert!(is_road(&image, px, py), "B2 before its loop");
    let (px, py) = pixel(31.5, 4.5);
    assert!(!is_road(&image, px, py), "the gap between the loop and BF");
    // No car is ever in the gap, and every pose stays on the network.
    let mut poses = 0;
    for scenario in &scenarios {
        for p in read_poses(&scenario.join("poses.csv")) {
            assert!(!(p.x > 31.0 && p.x < 34.0 && p.y.abs() < 6.0), "{p:?} in {}", scenario.display());
            assert!(!(p.y > -14.0 + 0.5 && p.y < -6.0 && (p.x + 40.0).abs() < 6.0), "{p:?} past D1's loop");
            poses += 1;
        }
        assert!(std::fs::metadata(scenario.join("effects.csv")).unwrap().len() > 0);
    }
    assert_eq!(poses, 4 * 40 * 8);

    // Refused with exit 2, naming the field, nothing written.
    for (sub, dead_ends, needle) in [
        (
            "outer",
            serde_json::json!({"B0": "BD"}),
            "map.grid.dead_ends.B0`: \"B0\" is not a road segment between two junctions",
        ),
        ("junction", serde_json::json!({"B2": "AE"}), "\"AE\" is not a junction at an end of B2: give BE or BF"),
        (
            "short",
            serde_json::json!({"B2": "BE"}),
            "leaves 8.00 m of road before BE once its loop (8.0 m) is taken off",
        ),
    ] {
        let mut bad = map.clone();
        bad["grid"]["dead_ends"] = dead_ends;
        if sub == "short" {
            bad["grid"]["block_m"] = serde_json::json!(28);
        }
        assert_refused(&dir, sub, &spec_with_map("bad", bad), needle);
    }
}

#[test]
fn at_junctions_without_lights_no_two_drivers_wait_for_each_other_for_good() {
    // The settings under which two drivers each claiming the box once
    // waited for each other for the rest of the scenario (scenario 3 here).
    let dir = fresh_dir("grid-town-no-deadlock");
    let spec = r#"{"name": "p", "world": "city", "seed": 36, "frames": 150, "frame_interval": 1.0,
        "image": {"width": 640, "height": 640}, "groups": [{"cars": 8, "edge_proportion": 0.5}], "splits": {"train": 8, "val": 0, "test": 0},
        "actions_per_car": 5, "map": {"grid": {"rows": 3, "columns": 3, "control": "priority"}},
        "city": {"start": {"follower_gap_m": {"uniform": [1.0, 12.0]}, "platoon_cars": 4, "speed_fraction": {"uniform": [0.5, 1.0]}},
                 "desired_speed": 1.8, "desired_speed_spread": 0.25, "red_light_runner_probability": 0.02,
                 "lights": {"cycle_scale": 0.5, "phase": "random_per_intersection"}}}"#;
    let spec = write_spec(&dir, spec);
    let out = dir.join("p");
    gen_ok(&spec, &out, &["--no-images", "--no-effects"]);
    let mut checked = 0;
    for scenario in scenario_dirs(&out) {
        let rows = read_csv::<InteractionRow>(&scenario.join("interactions.csv"));
        let cars = rows.iter().map(|r| r.car).max().unwrap() as usize + 1;
        let frames = rows.len() / cars;
        // Consecutive frames each pair of cars spends bound by each other.
        let mut together = vec![0usize; cars * cars];
        for frame in 0..frames {
            let at = &rows[frame * cars..(frame + 1) * cars];
            for (i, row) in at.iter().enumerate() {
                let mutual = row.other_car.is_some_and(|j| at[j as usize].other_car == Some(i as u32));
                for j in 0..cars {
                    let k = i * cars + j;
                    together[k] = if mutual && row.other_car == Some(j as u32) { together[k] + 1 } else { 0 };
                    assert!(
                        together[k] < 30,
                        "{}: cars {i} and {j} wait for each other from frame {}",
                        scenario.display(),
                        frame + 1 - together[k]
                    );
                }
            }
        }
        let events = std::fs::read_to_string(scenario.join("events.csv")).unwrap();
        assert!(!events.contains(",collision,"), "{}: {events}", scenario.display());
        checked += 1;
    }
    assert_eq!(checked, 8);
}
