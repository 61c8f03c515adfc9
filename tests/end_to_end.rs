//! The built binary on a tiny spec: the whole output layout, checked against
//! the documents in data-schema/.

mod common;
use common::*;
use serde_json::Value;
use sha2::Digest;
use std::collections::BTreeMap;
use std::path::Path;

#[test]
fn the_layout_matches_data_schema() {
    let dir = fresh_dir("e2e-layout");
    let spec = write_spec(&dir, &toy_spec("e2e", &[(4, 0.5), (8, 0.2)], (2, 1, 1), 24));
    let out = dir.join("out");
    let output = gen_ok(&spec, &out, &[]);
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(stdout.contains("wrote 8 scenarios (192 frame pairs"), "summary: {stdout}");
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(stderr.contains("progress: 8/8 scenarios"), "plain progress lines when not a terminal: {stderr}");

    // Top level: the manifest and one folder per group, nothing else.
    let top: Vec<String> =
        sorted_entries(&out).iter().map(|p| p.file_name().unwrap().to_string_lossy().into_owned()).collect();
    assert_eq!(top, ["cars04_edges50", "cars08_edges20", "manifest.json"]);
    let manifest = read_json(&out.join("manifest.json"));
    assert_valid(&validator("manifest.schema.json"), &manifest, &out.join("manifest.json"));
    assert_valid(&validator("spec.schema.json"), &manifest["spec"], Path::new("manifest.spec"));
    assert_valid(&validator("spec.schema.json"), &read_json(&spec), &spec);
    let digits = manifest["frame_file_digits"].as_u64().unwrap() as usize;

    let scenario_schema = validator("scenario.schema.json");
    let table = read_json(&schema_dir().join("poses.schema.json"));
    let columns: Vec<&str> = table["fields"].as_array().unwrap().iter().map(|f| f["name"].as_str().unwrap()).collect();
    let dirs = scenario_dirs(&out);
    assert_eq!(dirs.len(), 8);
    for d in &dirs {
        let names: Vec<String> =
            sorted_entries(d).iter().map(|p| p.file_name().unwrap().to_string_lossy().into_owned()).collect();
        assert_eq!(
            names,
            ["checksums.sha256", "effects.csv", "mask", "pixels.npy", "poses.csv", "rgb", "scenario.json"],
            "{}",
            d.display()
        );
        // sha256sum -c format, covering every other file.
        let listing = std::fs::read_to_string(d.join("checksums.sha256")).unwrap();
        let frames_here = sorted_entries(&d.join("rgb")).len();
        assert_eq!(listing.lines().count(), 4 + 2 * frames_here);
        for line in listing.lines() {
            let (hash, name) = line.split_once("  ").unwrap();
            let digest = sha2::Sha256::digest(std::fs::read(d.join(name)).unwrap());
            let hex: String = digest.iter().map(|b| format!("{b:02x}")).collect();
            assert_eq!(hash, hex, "{name}");
        }
        let scenario = read_json(&d.join("scenario.json"));
        assert_valid(&scenario_schema, &scenario, &d.join("scenario.json"));
        let frames = scenario["frames"].as_u64().unwrap() as usize;
        let cars = scenario["cars"].as_array().unwrap().len();

        let mut reader = csv::Reader::from_path(d.join("poses.csv")).unwrap();
        let header: Vec<String> = reader.headers().unwrap().iter().map(String::from).collect();
        assert_eq!(header, columns, "poses.csv columns");
        let rows: Vec<csv::StringRecord> = reader.records().map(|r| r.unwrap()).collect();
        assert_eq!(rows.len(), frames * cars);
        for (i, row) in rows.iter().enumerate() {
            let (frame, car): (usize, usize) = (row[0].parse().unwrap(), row[2].parse().unwrap());
            assert_eq!((frame, car), (i / cars, i % cars), "rows sorted by frame then car");
            for (value, field) in row.iter().zip(table["fields"].as_array().unwrap()) {
                match field["type"].as_str().unwrap() {
                    "integer" => assert!(value.parse::<i64>().is_ok(), "{value} is not an integer"),
                    _ => assert!(value.parse::<f64>().map(f64::is_finite).unwrap_or(false), "{value} is not a number"),
                }
            }
            assert!(&row[12] == "0" || &row[12] == "1");
        }
        for kind in ["rgb", "mask"] {
            let files: Vec<String> = sorted_entries(&d.join(kind))
                .iter()
                .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
                .collect();
            let expected: Vec<String> = (0..frames).map(|f| format!("{f:0digits$}.png")).collect();
            assert_eq!(files, expected, "{}/{kind}", d.display());
        }
    }
    // No temporary folders are left behind.
    for group in ["cars04_edges50", "cars08_edges20"] {
        for split in ["train", "val", "test"] {
            for e in sorted_entries(&out.join(group).join(split)) {
                assert!(!e.file_name().unwrap().to_string_lossy().starts_with('.'), "leftover {}", e.display());
            }
        }
    }
}

#[test]
fn no_images_writes_poses_and_ground_truth_only() {
    let dir = fresh_dir("e2e-no-images");
    let spec = write_spec(&dir, &toy_spec("noimg", &[(4, 0.5)], (1, 1, 1), 10));
    let out = dir.join("out");
    gen_ok(&spec, &out, &["--no-images", "--quiet"]);
    let manifest = read_json(&out.join("manifest.json"));
    assert_eq!(manifest["images"], false);
    for d in scenario_dirs(&out) {
        let names: Vec<String> =
            sorted_entries(&d).iter().map(|p| p.file_name().unwrap().to_string_lossy().into_owned()).collect();
        assert_eq!(names, ["checksums.sha256", "effects.csv", "pixels.npy", "poses.csv", "scenario.json"]);
    }
}

#[test]
fn shipped_configs_are_valid_specs() {
    let v = validator("spec.schema.json");
    for entry in sorted_entries(&Path::new(env!("CARGO_MANIFEST_DIR")).join("configs")) {
        if entry.extension().is_some_and(|e| e == "json") {
            assert_valid(&v, &read_json(&entry), &entry);
        }
    }
    // The shipped toy spec carries the paper's design.
    let toy = read_json(&Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/toy.json"));
    assert_eq!(toy["splits"], serde_json::json!({"train": 4000, "val": 500, "test": 500}));
    assert_eq!(toy["frames"], 150);
    let groups: Vec<(u64, f64)> = toy["groups"]
        .as_array()
        .unwrap()
        .iter()
        .map(|g| (g["cars"].as_u64().unwrap(), g["edge_proportion"].as_f64().unwrap()))
        .collect();
    assert_eq!(groups, [(4, 0.5), (8, 0.2), (8, 0.5), (8, 0.8), (12, 0.5)]);
}

#[test]
fn the_city_layout_matches_data_schema_and_validates() {
    let dir = fresh_dir("e2e-city");
    let city = r#"{"confounders": {"rain": {"choice": [0, 1]}, "hour": {"uniform": [0, 24]}}}"#;
    let spec = write_spec(&dir, &city_spec("e2e-city", &[(8, 0.5)], (2, 1, 1), 20, city));
    let out = dir.join("out");
    gen_ok(&spec, &out, &["--quiet"]);
    assert_valid(&validator("manifest.schema.json"), &read_json(&out.join("manifest.json")), &out);
    let scenario_schema = validator("scenario.schema.json");
    let columns = |name: &str| -> Vec<String> {
        read_json(&schema_dir().join(name))["fields"]
            .as_array()
            .unwrap()
            .iter()
            .map(|f| f["name"].as_str().unwrap().to_string())
            .collect()
    };
    for d in scenario_dirs(&out) {
        let scenario = read_json(&d.join("scenario.json"));
        assert_valid(&scenario_schema, &scenario, &d.join("scenario.json"));
        assert!(scenario["city"]["effects"]["desired_speed_factor"].is_number());
        let cars = scenario["cars"].as_array().unwrap().len();
        for (file, schema, rows_per_frame) in [
            // gen's default light log: each light at frame 0, then its changes.
            ("light_changes.csv", "light_changes.schema.json", None),
            ("events.csv", "events.schema.json", None),
            ("interactions.csv", "interactions.schema.json", Some(20 * cars)),
            // Every car removed and its next action changed, each compared with every other car.
            ("effects.csv", "effects.schema.json", Some(2 * cars * (cars - 1))),
        ] {
            let mut reader = csv::Reader::from_path(d.join(file)).unwrap();
            let header: Vec<String> = reader.headers().unwrap().iter().map(String::from).collect();
            assert_eq!(header, columns(schema), "{file} columns");
            let rows = reader.records().count();
            if let Some(n) = rows_per_frame {
                assert_eq!(rows, n, "{file} rows");
            }
        }
        assert!(!d.join("lights.csv").exists(), "gen wrote lights.csv without --lights frames");
        assert_eq!(light_rows(&d).len(), 20 * 32, "every light at every frame");
    }
    let output = run(&["validate", out.to_str().unwrap(), "--json"]);
    let report: Value = serde_json::from_slice(&output.stdout).unwrap();
    assert_eq!(output.status.code(), Some(0), "{report}");
    assert_eq!(report["scenarios_checked"], 4);
    assert_eq!(report["problems"].as_array().unwrap().len(), 0);
}

/// Each light's (colour, since_change) per frame, from a scenario's light
/// log: lights.csv as it is, light_changes.csv carried forward frame by
/// frame to `frames`. Keyed by intersection/approach/signal; with the
/// head's pixel.
fn light_frames(dir: &Path, interval: f64, frames: usize) -> BTreeMap<String, (Vec<(String, f64)>, String)> {
    let changes = dir.join("light_changes.csv");
    let file = if changes.exists() { changes } else { dir.join("lights.csv") };
    let mut lights: BTreeMap<String, (Vec<(String, f64)>, String)> = BTreeMap::new();
    for row in csv::Reader::from_path(&file).unwrap().records() {
        let row = row.unwrap();
        let frame: usize = row[0].parse().unwrap();
        let entry = lights.entry(format!("{}/{}/{}", &row[2], &row[3], &row[4])).or_default();
        entry.1 = format!("{},{}", &row[7], &row[8]);
        while entry.0.len() < frame {
            let (colour, since) = entry.0.last().cloned().expect("every light has a row at frame 0");
            entry.0.push((colour, since + interval));
        }
        entry.0.push((row[5].to_string(), row[6].parse().unwrap()));
    }
    for (rows, _) in lights.values_mut() {
        while rows.len() < frames {
            let (colour, since) = rows.last().cloned().expect("every light has a row at frame 0");
            rows.push((colour, since + interval));
        }
    }
    lights
}

#[test]
fn lights_logged_as_changes_carry_every_frame_of_lights_csv_in_a_fraction_of_the_bytes() {
    let dir = fresh_dir("e2e-light-changes");
    let spec = write_spec(&dir, &city_spec("e2e-light-changes", &[(8, 0.5)], (2, 1, 1), 300, "{}"));
    let (frames_out, changes_out) = (dir.join("frames"), dir.join("changes"));
    gen_ok(&spec, &frames_out, &["--quiet", "--no-images", "--lights", "frames"]);
    gen_ok(&spec, &changes_out, &["--quiet", "--no-images"]);
    assert_eq!(read_json(&changes_out.join("manifest.json"))["lights"], "changes", "the default, recorded");
    // No field means frames, as in manifests written before --lights existed.
    assert!(read_json(&frames_out.join("manifest.json")).get("lights").is_none());
    let interval = read_json(&frames_out.join("manifest.json"))["spec"]["frame_interval"].as_f64().unwrap();
    let (mut full_bytes, mut change_bytes, mut checked) = (0, 0, 0);
    for (a, b) in scenario_dirs(&frames_out).into_iter().zip(scenario_dirs(&changes_out)) {
        assert!(!b.join("lights.csv").exists() && !a.join("light_changes.csv").exists());
        let schema = read_json(&schema_dir().join("light_changes.schema.json"));
        let columns: Vec<&str> =
            schema["fields"].as_array().unwrap().iter().map(|f| f["name"].as_str().unwrap()).collect();
        let mut reader = csv::Reader::from_path(b.join("light_changes.csv")).unwrap();
        assert!(reader.headers().unwrap().iter().eq(columns.iter().copied()), "light_changes.csv columns");
        // Every other file the same bytes.
        for file in ["scenario.json", "poses.csv", "events.csv", "interactions.csv", "effects.csv"] {
            assert_eq!(std::fs::read(a.join(file)).unwrap(), std::fs::read(b.join(file)).unwrap(), "{file}");
        }
        let (full, compact) = (light_frames(&a, interval, 300), light_frames(&b, interval, 300));
        assert_eq!(full.len(), 32);
        assert_eq!(full.keys().collect::<Vec<_>>(), compact.keys().collect::<Vec<_>>());
        for (name, (rows, head)) in &full {
            let (carried, compact_head) = &compact[name];
            assert_eq!(head, compact_head, "{name}");
            assert_eq!(rows.len(), 300);
            for (f, ((c1, s1), (c2, s2))) in rows.iter().zip(carried).enumerate() {
                assert_eq!(c1, c2, "{name} frame {f}");
                assert!((s1 - s2).abs() < 1.5e-3, "{name} frame {f}: since_change {s1} against {s2}");
                checked += 1;
            }
        }
        // The tests' light_rows (the library's reader for light_changes.csv)
        // gives lights.csv's rows as serde reads them.
        let (read, expanded) = (light_rows(&a), light_rows(&b));
        assert_eq!(read.len(), 300 * 32);
        assert_eq!(read.len(), expanded.len());
        for (r, e) in read.iter().zip(&expanded) {
            let same = (r.frame, &r.intersection, &r.approach, &r.signal, &r.colour, r.head_px, r.head_py)
                == (e.frame, &e.intersection, &e.approach, &e.signal, &e.colour, e.head_px, e.head_py);
            assert!(same && (r.since_change - e.since_change).abs() < 1e-9 && (r.t - e.t).abs() < 1e-6, "{r:?} {e:?}");
        }
        full_bytes += std::fs::metadata(a.join("lights.csv")).unwrap().len();
        change_bytes += std::fs::metadata(b.join("light_changes.csv")).unwrap().len();
    }
    assert_eq!(checked, 4 * 32 * 300);
    assert!(change_bytes * 20 < full_bytes, "light_changes.csv {change_bytes} bytes against lights.csv {full_bytes}");
    // validate and stats read it, and say the same of both.
    let checked = run(&["validate", changes_out.to_str().unwrap()]);
    assert!(checked.status.success(), "{}", String::from_utf8_lossy(&checked.stdout));
    let stats = |out: &Path| run(&["stats", out.to_str().unwrap(), "--json"]).stdout;
    let (a, b): (Value, Value) =
        (serde_json::from_slice(&stats(&frames_out)).unwrap(), serde_json::from_slice(&stats(&changes_out)).unwrap());
    assert_eq!(a["rows"], b["rows"]);
    // A resumed run must log the lights as the dataset does.
    let mixed = run(&[
        "gen",
        "--spec",
        spec.to_str().unwrap(),
        "--out",
        changes_out.to_str().unwrap(),
        "--no-images",
        "--lights",
        "frames",
    ]);
    let stderr = String::from_utf8_lossy(&mixed.stderr);
    assert_eq!(mixed.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("lights: changes there, frames now (--lights)"), "{stderr}");
}

#[test]
fn the_progress_rate_counts_the_first_scenario_from_the_start() {
    // One scenario of 3,000 city frames (gen writes it first, as the free
    // space check's sample): its progress line said thousands of scenarios
    // a second (counted from after it) where the summary said 0.2.
    let dir = fresh_dir("e2e-progress-rate");
    let spec = write_spec(&dir, &city_spec("rate", &[(8, 0.5)], (1, 0, 0), 3000, "{}"));
    let output = gen_ok(&spec, &dir.join("out"), &["--no-images"]);
    let (stdout, stderr) = (String::from_utf8_lossy(&output.stdout), String::from_utf8_lossy(&output.stderr));
    let number_before = |text: &str, marker: &str| -> f64 {
        let end = text.find(marker).unwrap_or_else(|| panic!("no {marker:?} in {text}"));
        let start = text[..end].rfind(' ').unwrap() + 1;
        text[start..end].parse().unwrap()
    };
    let progress = number_before(&stderr, "/s, ETA");
    let summary = number_before(&stdout, " scenarios/s");
    assert!(stderr.contains("progress: 1/1 scenarios"), "{stderr}");
    assert!(progress <= 2.0 * summary + 0.1, "progress {progress}/s, summary {summary} scenarios/s: {stderr}{stdout}");
}
