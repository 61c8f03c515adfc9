//! Hand-written scenarios (`causalcity run`), interventions and
//! counterfactual pairs (`causalcity counterfactual`), checked on the files
//! they write.

mod common;
use common::*;
use std::path::{Path, PathBuf};

#[test]
fn every_example_scenario_runs() {
    let examples = json_files("configs/examples");
    assert!(examples.len() >= 3);
    let schema = validator("scenario-file.schema.json");
    for file in examples {
        assert_valid(&schema, &read_json(&file), &file);
        let out = fresh_dir(&format!("hw-example-{}", file.file_stem().unwrap().to_string_lossy()));
        let output = run(&["run", "--scenario", file.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-images"]);
        assert!(output.status.success(), "{}: {}", file.display(), String::from_utf8_lossy(&output.stderr));
        let scenarios: Vec<serde_json::Value> =
            match serde_json::from_str(&std::fs::read_to_string(&file).unwrap()).unwrap() {
                serde_json::Value::Array(list) => list,
                one => vec![one],
            };
        for scenario in scenarios {
            let name = scenario["Name"].as_str().unwrap();
            let dir = out.join(name);
            let record = read_json(&dir.join("scenario.json"));
            assert_valid(&validator("scenario.schema.json"), &record, &dir.join("scenario.json"));
            let cars = scenario["Vehicles"].as_array().unwrap();
            assert_eq!(record["cars"].as_array().unwrap().len(), cars.len());
            for (car, vehicle) in record["cars"].as_array().unwrap().iter().zip(cars) {
                assert_eq!(car["name"], vehicle["Id"]);
                assert_eq!(car["spawn"], vehicle["Spawn"]);
            }
            let frames = scenario["frames"].as_u64().unwrap_or(150) as usize;
            assert_eq!(read_poses(&dir.join("poses.csv")).len(), frames * cars.len());
        }
    }
}

#[test]
fn pairs_are_inferred_as_in_the_original() {
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/examples/stop-the-leader.json");
    let out = fresh_dir("hw-pairs");
    let output = run(&["run", "--scenario", file.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-images"]);
    assert!(output.status.success());
    let record = read_json(&out.join("stop_the_leader/scenario.json"));
    assert_eq!(record["edges"], serde_json::json!([[0, 1]]), "Car_1 leads Car_2 on the same lane and actions");
    assert_eq!(record["cars"][2]["role"], "independent");
    assert_eq!(record["cars"][2]["colour"], "#22aaff");
    assert_eq!(record["cars"][2]["desired_speeds"], serde_json::json!([2.0, 2.0]));
}

#[test]
fn a_lane_a_town_leaves_out_is_never_offered_as_the_example_spawn_point() {
    // map.grid.missing removed D0: "D0w" was refused with 'e.g. "D0w"'
    // (helper audit).
    let dir = fresh_dir("hw-missing-lane");
    let file = dir.join("gone.json");
    std::fs::write(
        &file,
        r#"[{"Name": "S1", "map": {"grid": {"rows": 3, "columns": 3, "missing": ["D0"]}}, "Vehicles": [
            {"Id": "Car_1", "Spawn": "D0w", "SpawnAtDistance": 0, "DriveQueue": ["left"]}]}]"#,
    )
    .unwrap();
    let out = dir.join("out");
    let output = run(&["run", "--scenario", file.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-images"]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains(r#"field Spawn: "D0w" is not a spawn point of this town"#), "{stderr}");
    assert!(stderr.contains("map.grid's missing, dead_ends and lanes leave some out"), "{stderr}");
    let example = stderr.split("e.g. \"").nth(1).and_then(|rest| rest.split('"').next()).unwrap_or_default();
    assert!(!example.is_empty() && example != "D0w", "the example {example:?}: {stderr}");
    // The example is a lane of the town: a car spawns there.
    std::fs::write(&file, std::fs::read_to_string(&file).unwrap().replace("D0w", example)).unwrap();
    let output = run(&["run", "--scenario", file.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-images"]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
}

fn scenario_with(vehicles: &str) -> String {
    format!(r#"[{{"Name": "Bad_1", "frames": 10, "Vehicles": [{vehicles}]}}]"#)
}

#[test]
fn bad_scenarios_exit_2_naming_scenario_car_and_field() {
    let ok =
        r#"{"Id": "Car_1", "Spawn": "A1w", "SpawnAtDistance": 5, "DriveQueue": ["straight"], "MergeAtDistances": [0]}"#;
    let cases = [
        (r#"{"Id": "Car_2", "Spawn": "Q9q", "DriveQueue": ["straight"]}"#, "Car_2", "field Spawn", "not a spawn point"),
        (
            r#"{"Id": "Car_2", "Spawn": "B1w", "DriveQueue": ["straight", "fly"]}"#,
            "Car_2",
            "field DriveQueue[1]",
            "not an action",
        ),
        (
            r#"{"Id": "Car_2", "Spawn": "B1x", "DriveQueue": ["mergeR"], "MergeAtDistances": [500]}"#,
            "Car_2",
            "field MergeAtDistances[0]",
            "past the lane end",
        ),
        (
            r#"{"Id": "Car_2", "Spawn": "B1w", "DriveQueue": ["left"]}"#,
            "Car_2",
            "field DriveQueue[0]",
            "cannot turn left",
        ),
        (r#"{"Id": "Car_1", "Spawn": "B1w", "DriveQueue": ["straight"]}"#, "Car_1", "field Id", "duplicate car id"),
        (
            r#"{"Id": "Car_2", "Spawn": "A1w", "SpawnAtDistance": 5.5, "DriveQueue": ["straight"]}"#,
            "Car_2",
            "field SpawnAtDistance",
            "on top of Car_1",
        ),
        (r#"{"Id": "Car_2", "Spawn": "B1w", "Speed": 3}"#, "Car_2", "field Speed", "unknown field"),
    ];
    let dir = fresh_dir("hw-bad");
    for (k, (vehicle, car, field, message)) in cases.iter().enumerate() {
        let file = dir.join(format!("bad{k}.json"));
        std::fs::write(&file, scenario_with(&format!("{ok}, {vehicle}"))).unwrap();
        let out = dir.join(format!("out{k}"));
        // --strict: the wrong lane, the merge past the lane end and the car on
        // top of another would otherwise be adapted (see the next tests).
        let output = run(&["run", "--scenario", file.to_str().unwrap(), "--out", out.to_str().unwrap(), "--strict"]);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "case {k}: {stderr}");
        for part in ["scenario \"Bad_1\"", &format!("car \"{car}\""), field, message] {
            assert!(stderr.contains(part), "case {k}: {part:?} missing from {stderr}");
        }
        assert!(!out.exists(), "case {k}: nothing may be written");
    }
    // A DriveQueue of millions of actions aborted run out of memory (a route
    // is planned whole), and a frame_interval below a millisecond froze every
    // car (t was 0 at every frame of 5e-324), exit 0.
    let long =
        format!(r#"{{"Id": "Car_2", "Spawn": "B1w", "DriveQueue": [{}]}}"#, vec![r#""straight""#; 1001].join(", "));
    let frozen = format!(r#"[{{"Name": "Bad_1", "frames": 10, "frame_interval": 5e-324, "Vehicles": [{ok}]}}]"#);
    // A fraction or a huge number of frames named the type's range (0 to
    // 4294967295), not the field's.
    let frames = |n: &str| format!(r#"[{{"Name": "Bad_1", "frames": {n}, "Vehicles": [{ok}]}}]"#);
    for (case, text, parts) in [
        ("long", scenario_with(&format!("{ok}, {long}")), ["field DriveQueue", "1001 actions: at most 1000"]),
        ("frozen", frozen, ["field frame_interval", "5e-324 is not allowed: seconds, from 0.001 to 10"]),
        (
            "fraction",
            frames("20.5"),
            ["field frames", "20.5 is not a whole number: use a whole number from 1 to 100000"],
        ),
        ("huge", frames("1e12"), ["field frames", "1000000000000 is too large: use a whole number from 1 to 100000"]),
        ("negative", frames("-3"), ["field frames", "-3 is too small: use a whole number from 1 to 100000"]),
        // A frame index named the type's range too (0 to 18446744073709551615).
        (
            "at-frame",
            format!(
                r#"[{{"Name": "Bad_1", "frames": 20, "Vehicles": [{ok}],
                    "interventions": [{{"at_frame": 2.5, "do": "stop", "car": "Car_1", "seconds": 2}}]}}]"#
            ),
            [
                "field interventions[0].at_frame",
                "2.5 is not a whole number: use a frame index, a whole number from 0 to the scenario's last frame",
            ],
        ),
    ] {
        let file = dir.join(format!("{case}.json"));
        std::fs::write(&file, text).unwrap();
        let out = dir.join(format!("out-{case}"));
        let output = run(&["run", "--scenario", file.to_str().unwrap(), "--out", out.to_str().unwrap()]);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{case}: {stderr}");
        for part in ["scenario \"Bad_1\"", parts[0], parts[1]] {
            assert!(stderr.contains(part), "{case}: {part:?} missing from {stderr}");
        }
        assert!(!out.exists(), "{case}: nothing may be written");
    }
    // Interventions are checked too, with their path.
    let file = dir.join("bad-intervention.json");
    std::fs::write(
        &file,
        format!(r#"[{{"Name": "Bad_2", "Vehicles": [{ok}], "interventions": [{{"at": 1, "do": "stop", "car": "Car_9", "seconds": 2}}]}}]"#),
    )
    .unwrap();
    let output = run(&["run", "--scenario", file.to_str().unwrap(), "--out", dir.join("x").to_str().unwrap()]);
    assert_eq!(output.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(stderr.contains("interventions[0].car") && stderr.contains("\"Car_9\" is not a car"), "{stderr}");
}

fn counterfactual_of(name: &str, extra: &[&str]) -> PathBuf {
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/examples/stop-the-leader.json");
    let out = fresh_dir(name);
    let mut args = vec!["counterfactual", "--scenario", file.to_str().unwrap(), "--out", out.to_str().unwrap()];
    args.extend_from_slice(extra);
    let output = run(&args);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    out.join("stop_the_leader")
}

/// `counterfactual` of the scenario file `scenario` with the intervention
/// file `interventions` into `out`, without images.
fn counterfactual_with_file(scenario: &Path, interventions: &Path, out: &Path) -> std::process::Output {
    run(&[
        "counterfactual",
        "--scenario",
        scenario.to_str().unwrap(),
        "--intervention",
        interventions.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--no-images",
    ])
}

/// The stop-the-leader pair with `interventions` (a JSON list) for the counterfactual.
fn counterfactual_with(name: &str, interventions: &str) -> PathBuf {
    let dir = fresh_dir(&format!("{name}-file"));
    let file = dir.join("interventions.json");
    std::fs::write(&file, interventions).unwrap();
    counterfactual_of(name, &["--intervention", file.to_str().unwrap()])
}

#[test]
fn a_counterfactual_is_identical_before_the_intervention_and_moves_only_what_it_causes() {
    let pair = counterfactual_of("hw-cf", &[]);
    let (factual, counterfactual) = (pair.join("factual"), pair.join("counterfactual"));
    let summary = read_json(&pair.join("summary.json"));
    let t = summary["intervention_time_s"].as_f64().unwrap();
    assert_eq!(t, 3.0);
    let first = (t / 0.2).round() as usize; // frame 15 is the last before it acts
    for frame in 0..=first {
        let name = format!("rgb/{frame:04}.png");
        assert_eq!(
            std::fs::read(factual.join(&name)).unwrap(),
            std::fs::read(counterfactual.join(&name)).unwrap(),
            "{name}"
        );
        let name = format!("mask/{frame:04}.png");
        assert_eq!(
            std::fs::read(factual.join(&name)).unwrap(),
            std::fs::read(counterfactual.join(&name)).unwrap(),
            "{name}"
        );
    }
    let (a, b) = (read_poses(&factual.join("poses.csv")), read_poses(&counterfactual.join("poses.csv")));
    let text = |p: &Path| std::fs::read_to_string(p).unwrap();
    let lines = |p: &Path| text(p).lines().map(String::from).collect::<Vec<_>>();
    let (la, lb) = (lines(&factual.join("poses.csv")), lines(&counterfactual.join("poses.csv")));
    for (i, row) in a.iter().enumerate() {
        if row.frame as usize <= first {
            assert_eq!(la[i + 1], lb[i + 1], "poses row {} before the intervention", i + 2);
        }
    }
    // The leader stops, its follower is held up, the unrelated car is not moved at all.
    // Distance driven by the end of the stop (9 s, frame 45).
    let travelled = |poses: &[Pose], car: u32| {
        poses.iter().filter(|p| p.car == car && p.frame <= 45).map(|p| p.speed * 0.2).sum::<f64>()
    };
    assert!(travelled(&b, 0) < travelled(&a, 0) - 3.0, "the stopped leader is behind where it would have been");
    assert!(travelled(&b, 1) < travelled(&a, 1) - 3.0, "its follower is delayed too");
    assert!((travelled(&b, 2) - travelled(&a, 2)).abs() < 1e-9, "the unrelated car drives exactly as before");
    assert_eq!(summary["affected"], serde_json::json!(["Car_1", "Car_2"]));
    let rows: Vec<(u32, u32, f64)> = text(&pair.join("divergence.csv"))
        .lines()
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (f[0].parse().unwrap(), f[2].parse().unwrap(), f[3].parse().unwrap())
        })
        .collect();
    assert_eq!(rows.len(), 100 * 3);
    assert!(rows.iter().filter(|r| r.1 == 2).all(|r| r.2 == 0.0), "divergence 0 for the unrelated car");
    assert!(rows.iter().filter(|r| r.0 as usize <= first).all(|r| r.2 == 0.0));
    assert!(rows.iter().any(|r| r.1 == 1 && r.2 > 3.0));
    // summary.json's first divergent frame is the first frame whose poses.csv rows differ.
    let mut checked = 0;
    for car in summary["cars"].as_array().unwrap() {
        let id = car["id"].as_u64().unwrap() as usize;
        let differs = (0..la.len() - 1).filter(|i| i % 3 == id).find(|&i| la[i + 1] != lb[i + 1]).map(|i| i / 3);
        assert_eq!(car["first_divergent_frame"].as_u64().map(|f| f as usize), differs, "{car}");
        assert_eq!(car["affected"], differs.is_some(), "{car}");
        checked += differs.is_some() as usize;
    }
    assert_eq!(checked, 2, "two cars moved");
    // The intervention is in the counterfactual's events, not the factual's.
    assert!(text(&counterfactual.join("events.csv")).contains(",intervention,0,,,stop Car_1 for 6 s"));
    assert!(!text(&factual.join("events.csv")).contains("intervention"));
}

#[test]
fn a_no_op_intervention_gives_identical_folders() {
    let dir = fresh_dir("hw-noop-file");
    let file = dir.join("noop.json");
    std::fs::write(&file, r#"[{"at": 2.0, "do": "none"}]"#).unwrap();
    let pair = counterfactual_of("hw-noop", &["--intervention", file.to_str().unwrap()]);
    // The scenario's own stop is in both runs; the added intervention does nothing.
    assert_eq!(hash_tree(&pair.join("factual")), hash_tree(&pair.join("counterfactual")));
    assert_eq!(read_json(&pair.join("summary.json"))["affected"], serde_json::json!([]));
    // Said as what it is (the summary line had a blank where it goes).
    let scenario = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/examples/cameras.json");
    let out = fresh_dir("hw-noop-said").join("out");
    let said = counterfactual_with_file(&scenario, &file, &out);
    let stdout = String::from_utf8_lossy(&said.stdout);
    assert!(said.status.success() && stdout.contains("cameras: no intervention -> affected 0 of"), "{stdout}");
}

#[test]
fn interventions_act_as_documented() {
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/examples/interventions.json");
    let out = fresh_dir("hw-tour");
    let output = run(&["run", "--scenario", file.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-images"]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let dir = out.join("interventions_tour");
    let events: Vec<EventRow> = read_csv(&dir.join("events.csv"));
    let fired: Vec<&EventRow> = events.iter().filter(|e| e.kind == "intervention").collect();
    assert_eq!(fired.len(), 7, "{events:?}");
    assert!(fired.iter().all(|e| !e.detail.contains("not applied")), "{fired:?}");
    assert!(fired.iter().any(|e| e.car == Some(1) && e.detail.starts_with("Car_2 drives right, straight")));
    // set_light: AD/W/straight is red from 4 s for 5 s.
    let lights = light_rows(&dir);
    for l in lights.iter().filter(|l| l.intersection == "AD" && l.approach == "W" && l.signal == "straight") {
        if (4.0..9.0).contains(&l.t) {
            assert_eq!(l.colour, "red", "t = {}", l.t);
        }
    }
    // set_light_plan: from 1 s, BD/S/straight runs 20 s green, 5 s red.
    for l in lights.iter().filter(|l| l.intersection == "BD" && l.approach == "S" && l.signal == "straight") {
        let expected = if l.t < 1.0 {
            None
        } else if l.t < 20.0 || l.t >= 25.0 {
            Some("green")
        } else {
            Some("red")
        };
        if let Some(colour) = expected {
            assert_eq!(l.colour, colour, "t = {}", l.t);
        }
    }
    // run_red_light fired when that light turned red, and Car_1 then ran it.
    assert!(events.iter().any(|e| e.kind == "red_light_run" && e.car == Some(0) && e.detail.contains("forced")));
    // remove: Car_4 is off camera and still from 15 s on.
    for p in read_poses(&dir.join("poses.csv")).iter().filter(|p| p.car == 3 && p.t >= 15.0) {
        assert_eq!((p.in_view, p.speed), (0, 0.0));
    }
    // when Car_3 reaches BD it speeds up to 3 m/s.
    let reach = fired.iter().find(|e| e.detail.contains("reaches BD")).unwrap();
    let top = read_poses(&dir.join("poses.csv"))
        .iter()
        .filter(|p| p.car == 2 && p.t > reach.t)
        .map(|p| p.speed)
        .fold(0.0, f64::max);
    assert!(top > 2.5, "Car_3 reached {top} m/s after the intervention");
}

#[test]
fn a_sweep_writes_reproducible_pairs_from_a_gen_spec() {
    let dir = fresh_dir("hw-sweep");
    let spec = write_spec(&dir, &city_spec("sweep", &[(6, 0.5)], (3, 1, 0), 60, "{}"));
    let mut trees = Vec::new();
    // The sweep into `out` on `threads`, with `extra` flags.
    let sweep = |out: &Path, threads: &str, extra: &[&str]| {
        let spec = spec.to_str().unwrap();
        let mut args = vec!["counterfactual", "--sweep", spec, "--out", out.to_str().unwrap(), "--no-images", "-q"];
        args.extend_from_slice(&["-j", threads, "--kinds", "stop,remove"]);
        args.extend_from_slice(extra);
        let output = run(&args);
        assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    };
    for threads in ["1", "2"] {
        let out = dir.join(format!("out{threads}"));
        sweep(&out, threads, &[]);
        trees.push(hash_tree(&out));
        let pairs: Vec<PathBuf> = ["train/00000", "train/00001", "train/00002", "val/00000"]
            .iter()
            .map(|p| out.join("cars06_edges50").join(p))
            .collect();
        let mut with_effect = 0;
        for pair in &pairs {
            let summary = read_json(&pair.join("summary.json"));
            let label = summary["interventions"][0].as_str().unwrap();
            assert!(label.starts_with("stop ") || label.starts_with("remove "), "{label}");
            let t = summary["intervention_time_s"].as_f64().unwrap();
            let before = (t / 0.2).round() as u32;
            let factual = std::fs::read_to_string(pair.join("factual/poses.csv")).unwrap();
            let counterfactual = std::fs::read_to_string(pair.join("counterfactual/poses.csv")).unwrap();
            let rows = |text: &str| {
                text.lines()
                    .filter(|l| l.split(',').next().unwrap().parse::<u32>().is_ok_and(|f| f <= before))
                    .map(String::from)
                    .collect::<Vec<_>>()
            };
            assert_eq!(rows(&factual), rows(&counterfactual), "{}", pair.display());
            // The car acted on is in the effect set whenever anything moved.
            let acted_on = label.split_whitespace().nth(1).unwrap();
            let affected: Vec<&str> =
                summary["affected"].as_array().unwrap().iter().map(|v| v.as_str().unwrap()).collect();
            if !affected.is_empty() {
                assert!(affected.contains(&acted_on), "{label}: {affected:?}");
                with_effect += 1;
            }
        }
        assert!(with_effect >= 2, "most random stops and removals change something");
        assert!(out.join("sweep.json").exists());
        // Packed, the same pairs are in tar files whose bytes do not depend
        // on the threads either.
        let packed = dir.join(format!("packed{threads}"));
        sweep(&packed, threads, &["--format", "tar", "--scenarios-per-tar", "2"]);
        let tars = ["train/00000-00001.tar", "train/00002-00002.tar", "val/00000-00000.tar"];
        for tar in tars {
            assert!(packed.join("cars06_edges50").join(tar).is_file(), "{tar}");
        }
        trees.push(hash_tree(&packed));
    }
    assert_eq!(trees[0], trees[2], "the same pairs on 1 and 2 threads");
    assert_eq!(trees[1], trees[3], "the same packs on 1 and 2 threads");
}

#[test]
fn a_sweep_rerun_repairs_an_edited_summary_or_divergence_log_and_a_refused_one_leaves_the_record_as_it_was() {
    let dir = fresh_dir("hw-sweep-repair");
    let spec = write_spec(&dir, &city_spec("sweep-repair", &[(6, 0.5)], (2, 1, 0), 60, "{}"));
    let out = dir.join("out");
    let sweep = || {
        let args = ["counterfactual", "--sweep", spec.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-images"];
        run(&[&args[..], &["-q", "--kinds", "stop,remove"]].concat())
    };
    assert!(sweep().status.success());
    let whole = hash_tree(&out);
    // summary.json and divergence.csv carry no checksum: an edited
    // intervention (which evaluate scores, and validate passes) and a
    // damaged log were kept by every rerun, exit 0.
    let pair = out.join("cars06_edges50/train/00001");
    let summary = std::fs::read_to_string(pair.join("summary.json")).unwrap();
    let car = read_json(&pair.join("summary.json"))["intervention"]["car"].as_u64().unwrap();
    let edited = summary.replacen(&format!("\"car\": {car}"), &format!("\"car\": {}", (car + 1) % 6), 1);
    assert_ne!(edited, summary, "the edit must change the summary");
    std::fs::write(pair.join("summary.json"), edited).unwrap();
    let log = out.join("cars06_edges50/val/00000/divergence.csv");
    std::fs::write(&log, std::fs::read_to_string(&log).unwrap() + "x\n").unwrap();
    let rerun = sweep();
    assert!(rerun.status.success(), "{}", String::from_utf8_lossy(&rerun.stderr));
    assert_eq!(hash_tree(&out), whole, "the rerun did not write the edited pairs again");

    // A pair the rerun refuses (a link at its folder): exit 2, and the
    // sweep's record as it was (it was left incomplete, which evaluate
    // then refused).
    let moved = dir.join("elsewhere");
    std::fs::rename(&pair, &moved).unwrap();
    std::os::unix::fs::symlink(&moved, &pair).unwrap();
    let record = std::fs::read(out.join("sweep.json")).unwrap();
    let refused = sweep();
    assert_eq!(refused.status.code(), Some(2), "{}", String::from_utf8_lossy(&refused.stderr));
    assert!(String::from_utf8_lossy(&refused.stderr).contains("is a link"));
    assert_eq!(std::fs::read(out.join("sweep.json")).unwrap(), record, "the refused rerun rewrote sweep.json");
}

#[test]
fn validate_and_evaluate_refuse_a_sweep_pair_whose_intervention_is_not_the_one_its_key_draws() {
    // An edited intervention in summary.json (another car) passed validate
    // and evaluate scored it (exit 0); so did every pair of a sweep.json
    // whose kinds were edited. Folder and packed sweeps alike.
    let dir = fresh_dir("hw-sweep-drawn");
    let spec = write_spec(&dir, &city_spec("sweep-drawn", &[(6, 0.5)], (1, 1, 1), 60, "{}"));
    let out = dir.join("out");
    let args = ["counterfactual", "--sweep", spec.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-images"];
    assert!(run(&[&args[..], &["-q", "--kinds", "stop,remove"]].concat()).status.success());
    let pred = dir.join("affected.npz");
    let scores: Vec<f64> = (0..6).map(|c| c as f64 / 6.0).collect();
    let arrays = [
        ("cars06_edges50/val/00000/affected", npy(&[6], &scores)),
        ("cars06_edges50/test/00000/affected", npy(&[6], &scores)),
    ];
    npz(&pred, &arrays);
    let evaluate = |data: &Path| run(&["evaluate", data.to_str().unwrap(), pred.to_str().unwrap()]);
    let validate = |data: &Path| run(&["validate", data.to_str().unwrap()]);
    assert!(validate(&out).status.success());
    let scored = evaluate(&out);
    assert!(scored.status.success(), "{}", String::from_utf8_lossy(&scored.stderr));
    // A pair folder that is a link to a good copy: evaluate refuses it,
    // naming it, as validate does (it read through it, exit 0).
    let linked = dir.join("linked-pair");
    copy_tree(&out, &linked);
    let pair = linked.join("cars06_edges50/test/00000");
    std::fs::remove_dir_all(&pair).unwrap();
    std::os::unix::fs::symlink(out.join("cars06_edges50/test/00000"), &pair).unwrap();
    let refused = evaluate(&linked);
    assert_eq!(refused.status.code(), Some(2), "{}", String::from_utf8_lossy(&refused.stderr));
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert!(stderr.contains(&format!("{}: a symbolic link", pair.display())), "{stderr}");
    assert!(refused.stdout.is_empty(), "nothing is scored");

    let says = ", but this sweep (its spec, and kinds";
    let edited = dir.join("edited");
    copy_tree(&out, &edited);
    let summary_path = edited.join("cars06_edges50/test/00000/summary.json");
    let summary = std::fs::read_to_string(&summary_path).unwrap();
    // Another car, its id and name as the runs have them (a careless edit
    // of one alone is the pair's files disagreeing, which was named).
    let intervention = &read_json(&summary_path)["intervention"];
    let car = intervention["car"].as_u64().unwrap();
    let name = intervention["car_name"].as_str().unwrap().to_string();
    let other = (car + 1) % 6;
    let other_name = read_json(&summary_path)["cars"][other as usize]["name"].as_str().unwrap().to_string();
    let changed = summary.replacen(
        &format!("\"car\": {car},\n    \"car_name\": \"{name}\""),
        &format!("\"car\": {other},\n    \"car_name\": \"{other_name}\""),
        1,
    );
    assert_ne!(changed, summary, "the edit must change the summary");
    std::fs::write(&summary_path, changed).unwrap();
    let packed = dir.join("packed");
    assert!(run(&["pack", edited.to_str().unwrap(), "--out", packed.to_str().unwrap(), "-q"]).status.success());
    let mut checked = 0;
    for data in [&edited, &packed] {
        let report = validate(data);
        assert_eq!(report.status.code(), Some(1), "validate {}", data.display());
        let text = String::from_utf8_lossy(&report.stdout).into_owned();
        let named: Vec<&str> = text.lines().filter(|l| l.contains(says)).collect();
        assert_eq!(named.len(), 1, "{text}");
        assert!(named[0].contains("cars06_edges50/test/00000/summary.json"), "{text}");
        assert!(named[0].contains(&format!("stop car {car} ")) || named[0].contains(&format!("remove car {car} ")));
        let refused = evaluate(data);
        assert_eq!(refused.status.code(), Some(2), "evaluate {}", data.display());
        assert!(
            String::from_utf8_lossy(&refused.stderr).contains(says),
            "{}",
            String::from_utf8_lossy(&refused.stderr)
        );
        assert!(refused.stdout.is_empty(), "nothing is scored");
        checked += 1;
    }
    assert_eq!(checked, 2);
    // A packed sweep's rerun holds what carries no checksum to the same
    // rule: it kept the edited summary inside its pack, exit 0.
    let args = ["counterfactual", "--sweep", spec.to_str().unwrap(), "--no-images", "-q", "--kinds", "stop,remove"];
    let fresh = dir.join("fresh-packed");
    assert!(run(&[&args[..], &["--format", "tar", "--out", fresh.to_str().unwrap()]].concat()).status.success());
    assert_ne!(hash_tree(&packed), hash_tree(&fresh), "the edit is in the pack");
    let rerun = run(&[&args[..], &["--format", "tar", "--out", packed.to_str().unwrap()]].concat());
    assert!(rerun.status.success(), "{}", String::from_utf8_lossy(&rerun.stderr));
    assert!(String::from_utf8_lossy(&rerun.stderr).contains("writing the pack again"));
    assert_eq!(hash_tree(&packed), hash_tree(&fresh), "the rerun wrote the pack as a sweep writes it");
    assert!(validate(&packed).status.success());

    // A summary without the record (as sweeps made before it was kept) is
    // held to the drawn frame by when its intervention fired.
    let unrecorded = dir.join("unrecorded");
    copy_tree(&out, &unrecorded);
    let path = unrecorded.join("cars06_edges50/test/00000/summary.json");
    let mut old_style = read_json(&path);
    old_style.as_object_mut().unwrap().remove("intervention");
    std::fs::write(&path, old_style.to_string()).unwrap();
    assert!(validate(&unrecorded).status.success(), "a summary from before the record reads");
    assert!(evaluate(&unrecorded).status.success());
    old_style["intervention_time_s"] = serde_json::json!(0.1);
    std::fs::write(&path, old_style.to_string()).unwrap();
    let text = String::from_utf8_lossy(&validate(&unrecorded).stdout).into_owned();
    assert!(text.contains("records no intervention, and one that fired at 0.1 s, but this sweep"), "{text}");
    // sweep.json without kinds: nothing says which intervention each pair
    // was given (the check passed then).
    let kindless = dir.join("kindless");
    copy_tree(&edited, &kindless);
    let mut record = read_json(&kindless.join("sweep.json"));
    record.as_object_mut().unwrap().remove("kinds");
    std::fs::write(kindless.join("sweep.json"), record.to_string()).unwrap();
    for output in [validate(&kindless), evaluate(&kindless)] {
        assert_eq!(output.status.code(), Some(2));
        assert!(String::from_utf8_lossy(&output.stderr).contains("sweep.json: kinds is missing or empty"));
    }

    // The affected list and the firing time agree with the cars' flags and
    // the record (an emptied list changed the count of pairs with an
    // effect; both were kept by every rerun).
    let mut repaired = 0;
    for (name, says) in [("affected", "affected lists []"), ("intervention_time_s", "intervention_time_s 0.05")] {
        let copy = dir.join(format!("edited-{name}"));
        copy_tree(&out, &copy);
        let path = copy.join("cars06_edges50/test/00000/summary.json");
        let mut summary = read_json(&path);
        summary[name] = if name == "affected" { serde_json::json!([]) } else { serde_json::json!(0.05) };
        std::fs::write(&path, summary.to_string()).unwrap();
        let text = String::from_utf8_lossy(&validate(&copy).stdout).into_owned();
        assert!(text.contains(says), "{name}: {text}");
        assert!(run(&[&args[..], &["--out", copy.to_str().unwrap()]].concat()).status.success());
        assert_eq!(hash_tree(&copy), hash_tree(&out), "{name}: the rerun wrote the pair again");
        repaired += 1;
    }
    assert_eq!(repaired, 2);

    // sweep.json's kinds in another order draw another kind for every pair.
    let reordered = dir.join("reordered");
    copy_tree(&out, &reordered);
    let mut record = read_json(&reordered.join("sweep.json"));
    record["kinds"] = serde_json::json!(["remove", "stop"]);
    std::fs::write(reordered.join("sweep.json"), record.to_string()).unwrap();
    let report = validate(&reordered);
    assert_eq!(report.status.code(), Some(1));
    let text = String::from_utf8_lossy(&report.stdout).into_owned();
    assert_eq!(
        text.lines().filter(|l| l.contains(says) && l.contains("kinds remove, stop in sweep.json")).count(),
        3,
        "{text}"
    );
}

/// `from` copied whole to `to`.
fn copy_tree(from: &Path, to: &Path) {
    let status = std::process::Command::new("cp").args(["-r", from.to_str().unwrap(), to.to_str().unwrap()]).status();
    assert!(status.unwrap().success());
}

#[test]
fn run_and_counterfactual_log_the_lights_as_gen_does_and_a_sweep_records_how() {
    let dir = fresh_dir("hw-light-logs");
    // run: light_changes.csv by default, lights.csv with --lights frames;
    // the same lights every frame either way.
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/examples/interventions.json");
    let mut rows = Vec::new();
    for (lights, log) in [("changes", "light_changes.csv"), ("frames", "lights.csv")] {
        let out = dir.join(format!("run-{lights}"));
        let mut args = vec!["run", "--scenario", file.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-images"];
        if lights == "frames" {
            args.extend(["--lights", "frames"]);
        }
        let ran = run(&args);
        assert!(ran.status.success(), "{}", String::from_utf8_lossy(&ran.stderr));
        let scenario = out.join("interventions_tour");
        let other = if log == "lights.csv" { "light_changes.csv" } else { "lights.csv" };
        assert!(scenario.join(log).exists() && !scenario.join(other).exists(), "run --lights {lights}");
        rows.push(light_rows(&scenario).into_iter().map(|r| (r.frame, r.signal, r.colour)).collect::<Vec<_>>());
    }
    assert!(!rows[0].is_empty());
    assert_eq!(rows[0], rows[1]);

    // A sweep records its light log, validate checks the runs by it, and a
    // resume with the other log is refused.
    let spec = write_spec(&dir, &city_spec("sweep-lights", &[(4, 0.5)], (2, 0, 0), 30, "{}"));
    let sweep = |out: &Path, extra: &[&str]| {
        let mut args = vec!["counterfactual", "--sweep", spec.to_str().unwrap(), "--out", out.to_str().unwrap()];
        args.extend(["--no-images", "-q", "--kinds", "stop"]);
        args.extend_from_slice(extra);
        run(&args)
    };
    let (changes, frames) = (dir.join("sweep-changes"), dir.join("sweep-frames"));
    assert!(sweep(&changes, &[]).status.success());
    assert!(sweep(&frames, &["--lights", "frames"]).status.success());
    assert_eq!(read_json(&changes.join("sweep.json"))["lights"], "changes");
    assert_eq!(read_json(&frames.join("sweep.json"))["lights"], "frames");
    let pair = |out: &Path, run: &str| out.join("cars04_edges50/train/00000").join(run);
    for run in ["factual", "counterfactual"] {
        assert!(
            pair(&changes, run).join("light_changes.csv").exists() && !pair(&changes, run).join("lights.csv").exists()
        );
        assert!(pair(&frames, run).join("lights.csv").exists());
    }
    for out in [&changes, &frames] {
        let checked = run(&["validate", out.to_str().unwrap()]);
        assert!(checked.status.success(), "{}", String::from_utf8_lossy(&checked.stdout));
    }
    // A sweep from before the record said so logged every frame.
    let mut record = read_json(&frames.join("sweep.json"));
    record.as_object_mut().unwrap().remove("lights");
    std::fs::write(frames.join("sweep.json"), record.to_string()).unwrap();
    let checked = run(&["validate", frames.to_str().unwrap()]);
    assert!(checked.status.success(), "{}", String::from_utf8_lossy(&checked.stdout));
    let resumed = sweep(&frames, &[]);
    let stderr = String::from_utf8_lossy(&resumed.stderr);
    assert_eq!(resumed.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("lights (it was made with --lights frames)"), "{stderr}");
    // Other settings are told with both values, as given (it said "differs: kinds").
    for (extra, says) in [
        (
            &["--kinds", "remove,set-desired-speed"][..],
            "kinds (it was made with --kinds stop, this run asks for --kinds remove,set-desired-speed)",
        ),
        (&["--limit", "1"][..], "limit (it was made with no --limit, this run asks for --limit 1)"),
    ] {
        let refused = run(&[
            &["counterfactual", "--sweep", spec.to_str().unwrap(), "--out", changes.to_str().unwrap()][..],
            &["--no-images", "-q"],
            extra,
        ]
        .concat());
        let stderr = String::from_utf8_lossy(&refused.stderr);
        assert_eq!(refused.status.code(), Some(2), "{stderr}");
        assert!(stderr.contains(says), "{stderr}");
    }
    // validate reads each pair by the record: told changes, it misses light_changes.csv.
    record["lights"] = "changes".into();
    std::fs::write(frames.join("sweep.json"), record.to_string()).unwrap();
    let checked = run(&["validate", frames.to_str().unwrap()]);
    assert_eq!(checked.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&checked.stdout).contains("light_changes.csv"));
}

#[test]
fn extra_cameras_write_their_own_frames_and_the_chase_camera_keeps_its_car_centred() {
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/examples/cameras.json");
    let out = fresh_dir("hw-cameras");
    let output = run(&["run", "--scenario", file.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let dir = out.join("cameras");
    let record = read_json(&dir.join("scenario.json"));
    assert_eq!(record["cameras"].as_array().unwrap().len(), 2);

    // Chase: 256 x 256 around Car_1 (mask id 1), which stays at the centre.
    let chase = dir.join("cameras/chase_car1");
    for frame in 0..40 {
        let mask = image::open(chase.join(format!("mask/{frame:04}.png"))).unwrap().to_luma8();
        assert_eq!(mask.dimensions(), (256, 256));
        let (mut n, mut sx, mut sy) = (0.0, 0.0, 0.0);
        for (x, y, p) in mask.enumerate_pixels() {
            if p[0] == 1 {
                n += 1.0;
                sx += x as f64;
                sy += y as f64;
            }
        }
        assert!(n > 100.0, "frame {frame}: the chased car is in view");
        let (cx, cy) = (sx / n, sy / n);
        assert!((cx - 127.5).abs() <= 1.5 && (cy - 127.5).abs() <= 1.5, "frame {frame}: centroid ({cx:.2}, {cy:.2})");
        // Longer than wide on screen: it drives up the image.
        let rows = mask
            .enumerate_pixels()
            .filter(|(_, _, p)| p[0] == 1)
            .map(|(_, y, _)| y)
            .collect::<std::collections::BTreeSet<_>>()
            .len();
        let cols = mask
            .enumerate_pixels()
            .filter(|(_, _, p)| p[0] == 1)
            .map(|(x, _, _)| x)
            .collect::<std::collections::BTreeSet<_>>()
            .len();
        assert!(rows > cols, "frame {frame}: {rows} rows x {cols} columns");
    }
    // Depth: 16-bit grey, millimetres; the car is closer than the road beside it.
    let depth = image::open(chase.join("depth/0020.png")).unwrap();
    assert_eq!(depth.color(), image::ColorType::L16);
    let depth = depth.to_luma16();
    let altitude_mm = 40.0 * 256.0 / 1024.0 / 2.0 * 1000.0;
    let at_car = depth.get_pixel(128, 128)[0] as f64;
    let at_road = depth.get_pixel(128 + 20, 128)[0] as f64;
    assert!((at_car - (altitude_mm - 1500.0)).abs() < 5.0, "car roof at {at_car} mm");
    assert!(at_road > at_car + 1000.0, "road {at_road} mm, car {at_car} mm");

    // Static: its own pixel log agrees with its masks.
    let corner = dir.join("cameras/street_A1");
    let rows: Vec<Vec<String>> = std::fs::read_to_string(corner.join("poses.csv"))
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(String::from).collect())
        .collect();
    assert_eq!(rows.len(), 40 * 3);
    let mut checked = 0;
    for frame in 0..40usize {
        let mask = image::open(corner.join(format!("mask/{frame:04}.png"))).unwrap().to_luma8();
        assert_eq!(mask.dimensions(), (384, 256));
        for row in rows.iter().filter(|r| r[0] == frame.to_string()) {
            let id: u8 = row[1].parse::<u8>().unwrap() + 1;
            let (px, py): (f64, f64) = (row[2].parse().unwrap(), row[3].parse().unwrap());
            let pixels: Vec<(u32, u32)> =
                mask.enumerate_pixels().filter(|(_, _, p)| p[0] == id).map(|(x, y, _)| (x, y)).collect();
            // Wholly inside the image: the centroid is the logged position.
            if pixels.len() > 200 && pixels.iter().all(|&(x, y)| x > 0 && y > 0 && x < 383 && y < 255) {
                let n = pixels.len() as f64;
                let cx = pixels.iter().map(|p| p.0 as f64).sum::<f64>() / n;
                let cy = pixels.iter().map(|p| p.1 as f64).sum::<f64>() / n;
                assert!((cx - px).abs() < 1.5 && (cy - py).abs() < 1.5, "frame {frame} car {id}");
                checked += 1;
            }
        }
    }
    assert!(checked > 0, "at least one car crossed the corner camera");
}

/// Rows of a camera's poses.csv (frame, car, px, py, in_view, ...).
fn camera_rows(folder: &Path) -> Vec<Vec<String>> {
    let text = std::fs::read_to_string(folder.join("poses.csv")).unwrap();
    text.lines().skip(1).map(|l| l.split(',').map(String::from).collect()).collect()
}

#[test]
fn a_removed_car_is_seen_by_no_camera_and_the_cameras_following_it_stay_where_it_left() {
    let dir = fresh_dir("hw-removed-camera");
    let file = dir.join("removed.json");
    std::fs::write(
        &file,
        r#"[{"Name": "s", "seed": 5, "frames": 8,
  "Vehicles": [{"Id": "Car_1", "Spawn": "A1w", "SpawnAtDistance": 10, "DriveQueue": ["right"], "MergeAtDistances": [0]},
               {"Id": "Car_2", "Spawn": "A1w", "SpawnAtDistance": 5, "DriveQueue": ["right"], "MergeAtDistances": [0]}],
  "cameras": [{"name": "fp", "first_person": "Car_1", "width": 64, "height": 48},
              {"name": "tp", "third_person": "Car_1", "width": 64, "height": 48},
              {"name": "ch", "chase": "Car_1", "width": 64, "height": 256}],
  "interventions": [{"at_frame": 3, "do": "remove", "car": "Car_1"}]}]"#,
    )
    .unwrap();
    let out = dir.join("out");
    let output = run(&["run", "--scenario", file.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let scenario = out.join("s");
    // The bird's-eye log says from which frame Car_1 (id 0, mask 1) is gone.
    let gone: Vec<usize> = std::fs::read_to_string(scenario.join("poses.csv"))
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect::<Vec<_>>())
        .filter(|r| r[2] == "0" && r[12] == "0")
        .map(|r| r[0].parse().unwrap())
        .collect();
    assert_eq!(gone, (3..8).collect::<Vec<_>>(), "removed at frame 3");
    for camera in ["tp", "ch"] {
        let folder = scenario.join("cameras").join(camera);
        let rows = camera_rows(&folder);
        for frame in 0..8usize {
            let seen = |car: &str| rows.iter().any(|r| r[0] == frame.to_string() && r[1] == car && r[4] == "1");
            let mask = image::open(folder.join(format!("mask/{frame:04}.png"))).unwrap().to_luma8();
            let pixels = |id: u8| mask.pixels().filter(|p| p[0] == id).count();
            if frame < 3 {
                assert!(seen("0") && pixels(1) > 0, "{camera} frame {frame}: Car_1 in view before its removal");
            } else {
                assert!(!seen("0"), "{camera} frame {frame}: the removed Car_1 is logged out of view");
                assert_eq!(pixels(1), 0, "{camera} frame {frame}: no pixel of the removed Car_1");
                // The camera stayed where Car_1 left: Car_2, behind it, is still seen.
                assert!(seen("1") && pixels(2) > 0, "{camera} frame {frame}: Car_2 behind is in view");
            }
        }
    }
    let first_person = camera_rows(&scenario.join("cameras/fp"));
    assert!(
        first_person.iter().filter(|r| r[0].parse::<usize>().unwrap() >= 3).all(|r| r[1] != "0" || r[4] == "0"),
        "the removed car is not in its own first-person view"
    );

    // Without images the cameras write nothing, and both commands say so
    // (gen did; run and counterfactual were silent).
    for command in ["run", "counterfactual"] {
        let out = dir.join(format!("{command}-no-images"));
        let output =
            run(&[command, "--no-images", "--scenario", file.to_str().unwrap(), "--out", out.to_str().unwrap()]);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(output.status.success(), "{stderr}");
        assert!(
            stderr.contains("scenario \"s\": --no-images: its cameras (fp, tp, ch) write nothing"),
            "{command}: {stderr}"
        );
        let cameras = if command == "run" { out.join("s/cameras") } else { out.join("s/factual/cameras") };
        assert!(!cameras.exists(), "{command}: no cameras/ folder");
    }
}

#[test]
fn a_confounder_changed_mid_scenario_greys_the_frames_and_slows_every_car() {
    let pair =
        counterfactual_with("hw-fog", r#"[{"at": 2.0, "do": "set_confounder", "confounder": "fog", "value": 1.0}]"#);
    let summary = read_json(&pair.join("summary.json"));
    // Fog is a common cause: every car drives differently, the unrelated one too.
    assert_eq!(summary["affected"], serde_json::json!(["Car_1", "Car_2", "Car_3"]));
    let contrast = |path: PathBuf| {
        let image = image::open(path).unwrap().to_luma8();
        let n = image.len() as f64;
        let mean = image.iter().map(|&v| v as f64).sum::<f64>() / n;
        (image.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / n).sqrt()
    };
    let (factual, counterfactual) = (pair.join("factual"), pair.join("counterfactual"));
    assert_eq!(
        std::fs::read(factual.join("rgb/0009.png")).unwrap(),
        std::fs::read(counterfactual.join("rgb/0009.png")).unwrap()
    );
    let (clear, foggy) = (contrast(factual.join("rgb/0010.png")), contrast(counterfactual.join("rgb/0010.png")));
    assert!(foggy < 0.7 * clear, "fog from frame 10 greys the frame: contrast {foggy:.1} vs {clear:.1}");
    let speeds = |dir: &Path, car: u32| {
        read_poses(&dir.join("poses.csv"))
            .iter()
            .filter(|p| p.car == car && p.frame > 20)
            .map(|p| p.speed)
            .fold(0.0, f64::max)
    };
    assert!(speeds(&counterfactual, 2) < speeds(&factual, 2), "fog slows the unrelated car");
}

#[test]
fn setting_the_rain_wets_the_road_by_its_equation_unless_the_wetness_is_held() {
    let pair =
        counterfactual_with("hw-rain", r#"[{"at": 2.0, "do": "set_confounder", "confounder": "rain", "value": 0.8}]"#);
    let events = read_csv::<EventRow>(&pair.join("counterfactual/events.csv"));
    let wetted: Vec<&EventRow> = events.iter().filter(|e| e.detail.starts_with("wetness 0.000 -> ")).collect();
    assert_eq!(wetted.len(), 1, "{events:?}");
    let wetness: f64 = wetted[0].detail["wetness 0.000 -> ".len()..].split(' ').next().unwrap().parse().unwrap();
    assert!(wetness >= 0.3, "rain 0.8 leaves the road at wetness {wetness}");
    assert!(wetted[0].detail.contains("after rain was set to 0.8"));
    // The weather is no car: neither row names one (a light or the weather was car 0 before).
    let weather: Vec<&EventRow> =
        events.iter().filter(|e| e.kind == "intervention" && e.detail.contains("rain")).collect();
    assert!(weather.len() == 2 && weather.iter().all(|e| e.car.is_none() && e.light.is_none()), "{weather:?}");
    // The factual run stays dry: nothing but the intervention changed the weather.
    let factual = read_json(&pair.join("factual/scenario.json"));
    assert_eq!(factual["city"]["confounders"]["wetness"].as_f64(), Some(0.0));
    assert_eq!(factual["city"]["confounder_model"]["source"]["wetness"], "equation");

    // Held by an earlier intervention, wetness no longer follows the rain.
    let pair = counterfactual_with(
        "hw-rain-held",
        r#"[{"at": 1.0, "do": "set_confounder", "confounder": "wetness", "value": 0.1},
            {"at": 2.0, "do": "set_confounder", "confounder": "rain", "value": 0.8}]"#,
    );
    let events = read_csv::<EventRow>(&pair.join("counterfactual/events.csv"));
    assert!(events.iter().filter(|e| e.kind == "intervention").count() >= 2, "{events:?}");
    assert!(!events.iter().any(|e| e.detail.contains("by its equation")), "{events:?}");
}

#[test]
fn a_gen_spec_can_list_cameras_and_validate_checks_their_files() {
    let dir = fresh_dir("hw-gen-cameras");
    let spec = city_spec("camspec", &[(4, 0.5)], (2, 0, 0), 12, "{}").replacen(
        "\"city\": {}",
        r#""city": {}, "cameras": [{"name": "follow0", "chase": 0, "depth": true},
            {"name": "west", "static": {"centre": [-24, 0], "rotation_deg": 90}, "width": 320, "height": 200}]"#,
        1,
    );
    // Camera folders whose names differ only in case are one folder on
    // macOS and Windows: refused in a spec as in a scenario file.
    std::fs::create_dir_all(dir.join("alike")).unwrap();
    let alike = write_spec(&dir.join("alike"), &spec.replacen("\"west\"", "\"Follow0\"", 1));
    let output = run(&["gen", "--spec", alike.to_str().unwrap(), "--out", dir.join("alike-out").to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("cameras[1].name") && stderr.contains("only in case"), "{stderr}");
    assert!(!dir.join("alike-out").exists());
    let spec_path = write_spec(&dir, &spec);
    assert_valid(&validator("spec.schema.json"), &read_json(&spec_path), &spec_path);
    let out = dir.join("out");
    gen_ok(&spec_path, &out, &["--quiet"]);
    let report = run(&["validate", out.to_str().unwrap()]);
    assert!(report.status.success(), "{}", String::from_utf8_lossy(&report.stdout));
    for scenario in scenario_dirs(&out) {
        for frame in 0..12 {
            let mask = image::open(scenario.join(format!("cameras/follow0/mask/{frame:04}.png"))).unwrap().to_luma8();
            let pixels: Vec<(u32, u32)> =
                mask.enumerate_pixels().filter(|(_, _, p)| p[0] == 1).map(|(x, y, _)| (x, y)).collect();
            let n = pixels.len() as f64;
            let cx = pixels.iter().map(|p| p.0 as f64).sum::<f64>() / n;
            let cy = pixels.iter().map(|p| p.1 as f64).sum::<f64>() / n;
            assert!((cx - 127.5).abs() <= 1.5 && (cy - 127.5).abs() <= 1.5, "frame {frame}: ({cx:.2}, {cy:.2})");
        }
        assert_eq!(image::open(scenario.join("cameras/west/rgb/0011.png")).unwrap().width(), 320);
    }
    std::fs::remove_file(scenario_dirs(&out)[0].join("cameras/west/rgb/0005.png")).unwrap();
    let report = run(&["validate", out.to_str().unwrap()]);
    assert!(!report.status.success());
    assert!(String::from_utf8_lossy(&report.stdout).contains("cameras/west/rgb/0005.png"));
    // A chased car that some scenario lacks is a spec error.
    let bad = write_spec(&dir, &spec.replace("\"chase\": 0", "\"chase\": 9"));
    let output = run(&["gen", "--spec", bad.to_str().unwrap(), "--out", dir.join("bad").to_str().unwrap()]);
    assert_eq!(output.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&output.stderr).contains("cameras[0].chase"));
}

/// Runs `args` (ending in `--out DIR`), expects exit 2 with every part in
/// stderr and nothing written to DIR.
fn rejected_by(case: &str, args: &[&str], out: &Path, parts: &[&str]) {
    let output = run(args);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{case}: {stderr}");
    for part in parts {
        assert!(stderr.contains(part), "{case}: {part:?} missing from {stderr}");
    }
    assert!(!stderr.contains("panicked"), "{case}: {stderr}");
    assert!(!out.exists(), "{case}: nothing may be written");
}

const OK_CAR: &str =
    r#"{"Id": "Car_1", "Spawn": "A1w", "SpawnAtDistance": 5, "DriveQueue": ["straight"], "MergeAtDistances": [0]}"#;

#[test]
fn scenario_files_are_read_strictly() {
    let dir = fresh_dir("hw-strict");
    let one = |interventions: &str| {
        format!(r#"[{{"Name": "Strict", "frames": 10, "Vehicles": [{OK_CAR}], "interventions": [{interventions}]}}]"#)
    };
    let cases: Vec<(&str, String, Vec<&str>)> = vec![
        (
            "duplicate-vehicle-key",
            r#"[{"Name": "Strict", "Vehicles": [{"Id": "Car_1", "Spawn": "A1w", "Spawn": "B1w"}]}]"#.into(),
            vec!["scenario \"Strict\"", "car \"Car_1\"", "field Spawn", "duplicate key"],
        ),
        (
            "duplicate-scenario-key",
            format!(r#"[{{"Name": "Strict", "frames": 10, "frames": 20, "Vehicles": [{OK_CAR}]}}]"#),
            vec!["scenario \"Strict\"", "field frames", "duplicate key"],
        ),
        ("trailing-data", format!("{} xyz", one("")), vec!["trailing characters"]),
        ("second-document", format!("{0}{0}", one("")), vec!["trailing characters"]),
        (
            "unknown-key-in-when",
            one(r#"{"when": {"car": "Car_1", "reaches": "AC", "after": 2}, "do": "remove", "car": "Car_1"}"#),
            vec!["scenario \"Strict\"", "interventions[0].when", "unknown field `after`"],
        ),
        (
            "unknown-key-in-schedule-step",
            one(
                r#"{"at": 1, "do": "set_light_plan", "light": "AC/W/straight", "schedule": [{"colour": "red", "duration": 3, "x": 1}]}"#,
            ),
            vec!["scenario \"Strict\"", "interventions[0].schedule[0]", "unknown field `x`"],
        ),
        (
            "key-of-another-effect",
            one(r#"{"at": 1, "do": "stop", "car": "Car_1", "seconds": 2, "speed": 3}"#),
            vec!["interventions[0]", "unknown field `speed`", "seconds"],
        ),
        (
            "speed-beyond-the-towns",
            one(r#"{"at": 1, "do": "set_desired_speed", "car": "Car_1", "speed": 1e9}"#),
            vec!["interventions[0].speed", "1000000000 is not allowed", "at most 20"],
        ),
        (
            "after-the-last-frame",
            one(r#"{"at": 1000, "do": "stop", "car": "Car_1", "seconds": 2}"#),
            vec![
                "interventions[0].at",
                "1000 s is after the scenario's last frame (frame 9 at",
                "would change nothing",
            ],
        ),
        (
            // 0.3 s x 3 is 0.8999999999999999 in floating point: 0.9 is the
            // last frame's time as typed (accepted: interventions[0]), 0.95 is past it.
            "after-the-last-frame-by-a-fraction",
            format!(
                r#"[{{"Name": "Strict", "frames": 4, "frame_interval": 0.3, "Vehicles": [{OK_CAR}], "interventions": [{{"at": 0.9, "do": "remove", "car": "Car_1"}}, {{"at": 0.95, "do": "remove", "car": "Car_1"}}]}}]"#
            ),
            vec![
                "interventions[1].at",
                "0.95 s is after the scenario's last frame (frame 3 at 0.9 s)",
                "give 0 to 0.9 s",
            ],
        ),
        (
            "past-the-last-frame",
            one(r#"{"at_frame": 10, "do": "remove", "car": "Car_1"}"#),
            vec!["interventions[0].at_frame", "10 is not a frame of this scenario", "give 0 to 9"],
        ),
        (
            "unknown-effect",
            one(r#"{"at": 1, "do": "fly", "car": "Car_1"}"#),
            vec!["interventions[0].do", "\"fly\" is not an intervention", "set_light_plan"],
        ),
        (
            "two-triggers",
            one(r#"{"at": 1, "at_frame": 3, "do": "remove", "car": "Car_1"}"#),
            vec!["interventions[0]", "exactly one trigger"],
        ),
        (
            "unknown-light",
            one(r#"{"at": 1, "do": "set_light", "light": "AX/W/straight", "colour": "red", "seconds": 2}"#),
            vec!["interventions[0].light", "\"AX/W/straight\" is not a light", "(AC AD BC BD; N E S W; straight left)"],
        ),
        (
            "names-alike-but-for-case",
            format!(
                r#"[{{"Name": "Left", "frames": 10, "Vehicles": [{OK_CAR}]}}, {{"Name": "left", "frames": 10, "Vehicles": [{OK_CAR}]}}]"#
            ),
            vec!["scenario \"left\"", "field Name", "\"Left\"", "only in case"],
        ),
        (
            "the-same-name-twice",
            format!(r#"[{{"Name": "Twice", "Vehicles": [{OK_CAR}]}}, {{"Name": "Twice", "Vehicles": [{OK_CAR}]}}]"#),
            vec!["scenario \"Twice\"", "field Name", "names another scenario too"],
        ),
        (
            "cameras-alike-but-for-case",
            format!(
                r#"[{{"Name": "Cams", "frames": 10, "Vehicles": [{OK_CAR}], "cameras": [{{"name": "Chase", "chase": "Car_1"}}, {{"name": "chase", "chase": "Car_1"}}]}}]"#
            ),
            vec!["scenario \"Cams\"", "cameras[1].name", "\"Chase\"", "only in case"],
        ),
        (
            "vehicle-as-a-list",
            r#"[{"Name": "Strict", "Vehicles": [["Car_1", "A1w"]]}]"#.into(),
            vec!["scenario \"Strict\"", "Vehicles[0]", "invalid type: a list, expected an object"],
        ),
        (
            "distance-as-text",
            r#"[{"Name": "Strict", "Vehicles": [{"Id": "Car_1", "Spawn": "A1w", "SpawnAtDistance": "far"}]}]"#.into(),
            vec!["car \"Car_1\"", "field SpawnAtDistance", "invalid type"],
        ),
        (
            "unknown-key-in-a-distribution",
            format!(
                r#"[{{"Name": "Strict", "Vehicles": [{OK_CAR}], "city": {{"confounders": {{"rain": {{"choice": [0.5], "typo": 1}}}}}}}}]"#
            ),
            vec!["scenario \"Strict\"", "city.confounders.rain", "typo"],
        ),
    ];
    for (case, text, parts) in &cases {
        let file = dir.join(format!("{case}.json"));
        std::fs::write(&file, text).unwrap();
        let out = dir.join(format!("out-{case}"));
        let args = ["run", "--scenario", file.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-images"];
        rejected_by(case, &args, &out, parts);
    }
}

#[test]
fn intervention_files_are_read_strictly() {
    let dir = fresh_dir("hw-strict-interventions");
    let scenario = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/examples/stop-the-leader.json");
    let cases = [
        (
            "duplicate-key",
            r#"[{"at": 1, "do": "stop", "car": "Car_1", "seconds": 2, "seconds": 4}]"#,
            vec!["interventions[0].seconds", "duplicate key"],
        ),
        ("trailing-data", r#"[{"at": 1, "do": "none"}] []"#, vec!["trailing characters"]),
        (
            "unknown-key-in-when",
            r#"{"when": {"light": "AC/W/straight", "turns": "red", "car": "Car_1"}, "do": "none"}"#,
            vec!["interventions[0].when", "expected {\"car\": CAR"],
        ),
        (
            "unknown-key",
            r#"[{"at": 1, "do": "none"}, {"at": 1, "do": "remove", "car": "Car_1", "colour": "red"}]"#,
            vec!["interventions[1]", "unknown field `colour`"],
        ),
        // Not interventions at all: it said "give exactly one trigger".
        (
            "a-list-wrapped-in-an-object",
            r#"{"interventions": [{"at": 1, "do": "remove", "car": "Car_1"}]}"#,
            vec!["interventions[0]", "has no trigger and no \"do\"", "the list itself"],
        ),
        (
            "a-scenario-file",
            r#"[{"Name": "s", "Vehicles": [], "interventions": []}]"#,
            vec!["interventions[0]", "keys \"Name\", \"Vehicles\"", "given as --scenario"],
        ),
        // Times past any scenario, or shorter than any frame (1e300 s was
        // taken and printed with 300 digits).
        (
            "a-stop-of-1e300-s",
            r#"[{"at": 1, "do": "stop", "car": "Car_1", "seconds": 1e300}]"#,
            vec!["interventions[0].seconds", "1e300 is not allowed", "from 0.001 to 1000000"],
        ),
        (
            "a-phase-of-1e-300-s",
            r#"[{"at": 1, "do": "set_light_plan", "light": "AC/W/straight", "schedule": [{"colour": "red", "duration": 1e-300}]}]"#,
            vec!["interventions[0].schedule[0].duration", "1e-300 is not allowed", "from 0.001 to 1000000"],
        ),
        (
            "an-offset-of-1e308-s",
            r#"[{"at": 1, "do": "set_light_plan", "light": "AC/W/straight", "schedule": [{"colour": "red", "duration": 1}], "offset": -1e308}]"#,
            vec!["interventions[0].offset", "-1e308 is not allowed", "from -1000000 to 1000000"],
        ),
    ];
    for (case, text, parts) in &cases {
        let file = dir.join(format!("{case}.json"));
        std::fs::write(&file, text).unwrap();
        let out = dir.join(format!("out-{case}"));
        let args = [
            "counterfactual",
            "--scenario",
            scenario.to_str().unwrap(),
            "--intervention",
            file.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--no-images",
        ];
        let mut parts = parts.clone();
        let name = file.to_str().unwrap().to_string();
        parts.push(&name);
        rejected_by(case, &args, &out, &parts);
    }
}

/// Runs `file` leniently and strictly: the lenient run succeeds and each
/// adaptation in events.csv is a warning on stderr; the strict run exits 2
/// naming the scenario, a car and a field, and writes nothing. Returns the
/// scenario folder of the lenient run and its stderr.
fn run_lenient_and_strict(file: &Path, scenario: &str, out: &Path) -> (PathBuf, String) {
    let output = run(&["run", "--scenario", file.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-images"]);
    let stderr = String::from_utf8_lossy(&output.stderr).into_owned();
    assert!(output.status.success(), "{}: {stderr}", file.display());
    let dir = out.join(scenario);
    let events: Vec<EventRow> = read_csv(&dir.join("events.csv"));
    let adaptations: Vec<&EventRow> = events
        .iter()
        .filter(|e| ["action_adapted", "action_skipped", "lane_change"].contains(&e.kind.as_str()))
        .collect();
    for e in &adaptations {
        assert!(
            stderr.lines().any(|l| l.starts_with("warning: ") && l.ends_with(&e.detail)),
            "{}: no warning for {:?}:\n{stderr}",
            file.display(),
            e.detail
        );
    }
    let strict_out = out.with_extension("strict");
    let output = run(&[
        "run",
        "--scenario",
        file.to_str().unwrap(),
        "--out",
        strict_out.to_str().unwrap(),
        "--no-images",
        "--strict",
    ]);
    let strict_err = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{}: --strict: {strict_err}", file.display());
    for part in [format!("scenario \"{scenario}\""), "car \"Car_".into(), "field ".into()] {
        assert!(strict_err.contains(&part), "{}: --strict: {part:?} missing from {strict_err}", file.display());
    }
    assert!(!strict_out.exists(), "--strict wrote output");
    (dir, stderr)
}

#[test]
fn the_original_readme_example_runs_unchanged_with_its_adaptation_logged() {
    // The original release's README example, byte for byte as it gives it:
    // its mergeR cannot be done (the lane is the outer one by then).
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/examples/original-readme.json");
    let dir = fresh_dir("hw-original-readme");
    let (scenario, stderr) = run_lenient_and_strict(&file, "Scenario_1", &dir.join("out"));
    let events: Vec<EventRow> = read_csv(&scenario.join("events.csv"));
    let skipped: Vec<&EventRow> = events.iter().filter(|e| e.kind == "action_skipped").collect();
    assert_eq!(skipped.len(), 1, "{events:?}");
    assert!(skipped[0].detail.starts_with("DriveQueue[3] mergeR: lane D1w is the outer lane"), "{}", skipped[0].detail);
    assert!(stderr.contains("car \"Car_1\""));
}

#[test]
fn files_from_the_original_generator_run_with_every_adaptation_logged() {
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/original-generator");
    let files: Vec<PathBuf> = (1..=10).map(|seed| fixtures.join(format!("seed-{seed:02}.json"))).collect();
    let map = causalcity::map::CityMap::default();
    let out = fresh_dir("hw-original-generator");
    let (mut planned_adaptations, mut lane_changes, mut turns) = (0, 0, 0);
    let schema = validator("scenario-file.schema.json");
    for file in &files {
        assert_valid(&schema, &read_json(file), file);
        let stem = file.file_stem().unwrap().to_string_lossy().into_owned();
        let (dir, stderr) = run_lenient_and_strict(file, "Scenario", &out.join(&stem));
        // One warning per car for the merge names in MergeAtDistances.
        let names = stderr.lines().filter(|l| l.contains("field MergeAtDistances[0, 1, 2, 3, 4]")).count();
        assert_eq!(names, 8, "{stem}: {stderr}");
        let s = read_scenario(&dir);
        let events: Vec<EventRow> = read_csv(&dir.join("events.csv"));
        for (id, _) in s.cars.iter().enumerate() {
            let id = id as u32;
            // Everything planning adapted is in events.csv at the start, by field.
            let route = planned_route(&map, &s.cars, id, &events);
            for a in &route.adaptations {
                planned_adaptations += 1;
                let field = match a.kind {
                    causalcity::map::AdaptationKind::Adapted => "MergeAtDistances",
                    causalcity::map::AdaptationKind::Skipped => "DriveQueue",
                };
                let prefix = format!("{field}[{}] {}: ", a.action_index, a.action);
                let detail = format!("{prefix}{}", a.reason);
                // A turn given up for want of a gap is logged when the driver gives up.
                let given_up = |e: &EventRow| a.reason.contains("no gap") && e.detail.starts_with(&prefix);
                assert!(
                    events.iter().any(|e| e.car == Some(id) && (e.detail == detail || given_up(e))),
                    "{stem}: car {id}: {detail:?} not in events.csv"
                );
            }
            // Every turn is made from a lane that allows it.
            for e in events.iter().filter(|e| e.car == Some(id) && e.kind == "turn_done") {
                turns += 1;
                let (action, from) = (e.detail.split(' ').next().unwrap(), e.detail.rsplit(' ').next().unwrap());
                let letter = from.chars().last().unwrap();
                match action {
                    "left" => assert!("xy".contains(letter), "{stem}: {}", e.detail),
                    "right" => assert!("wz".contains(letter), "{stem}: {}", e.detail),
                    _ => {}
                }
            }
            lane_changes += events.iter().filter(|e| e.car == Some(id) && e.kind == "lane_change").count();
        }
    }
    assert!(
        planned_adaptations > 0 && lane_changes >= 10 && turns >= 20,
        "{planned_adaptations} {lane_changes} {turns}"
    );
}

#[test]
fn a_sweep_stopped_by_ctrl_c_says_so_validates_as_unfinished_and_resumes_to_the_same_bytes() {
    use std::process::{Command, Stdio};
    use std::time::{Duration, Instant};
    let dir = fresh_dir("hw-sweep-resume");
    // 100 pairs of 150-frame city scenarios without images: about a second.
    let spec = write_spec(&dir, &city_spec("resume", &[(8, 0.5)], (80, 10, 10), 150, "{}"));
    let sweep_args = |out: &Path| {
        vec![
            "counterfactual".to_string(),
            "--sweep".into(),
            spec.to_str().unwrap().into(),
            "--no-images".into(),
            "--quiet".into(),
            "-j".into(),
            "1".into(),
            "--out".into(),
            out.to_str().unwrap().into(),
        ]
    };
    let reference = dir.join("reference");
    let whole = run(&sweep_args(&reference).iter().map(String::as_str).collect::<Vec<_>>());
    assert!(whole.status.success(), "{}", String::from_utf8_lossy(&whole.stderr));
    let validated = run(&["validate", reference.to_str().unwrap()]);
    assert!(validated.status.success(), "{}", String::from_utf8_lossy(&validated.stdout));

    let out = dir.join("stopped");
    let child = Command::new(bin()).args(sweep_args(&out)).stderr(Stdio::piped()).spawn().unwrap();
    let deadline = Instant::now() + Duration::from_secs(60);
    // Three pairs first: one to damage, two to keep.
    while !out.join("cars08_edges50/train/00002/summary.json").exists() {
        assert!(Instant::now() < deadline, "no pair was written");
        std::thread::sleep(Duration::from_millis(10));
    }
    assert!(Command::new("kill").args(["-INT", &child.id().to_string()]).status().unwrap().success());
    let output = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(130), "{stderr}");
    assert!(stderr.contains("of 100 scenarios are complete") && stderr.contains("Rerun the same command"), "{stderr}");
    let done = scenario_dirs(&out).len();
    assert!(done < 100, "the sweep ran to its end ({done} pair folders of 100)");
    let validated = run(&["validate", out.to_str().unwrap()]);
    assert_eq!(validated.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&validated.stdout).contains("did not finish"));

    // A damaged pair is redone, complete ones are kept, and the result is
    // the uninterrupted sweep byte for byte.
    let poses = out.join("cars08_edges50/train/00000/counterfactual/poses.csv");
    std::fs::write(&poses, "damaged\n").unwrap();
    let resumed = run(&sweep_args(&out).iter().map(String::as_str).collect::<Vec<_>>());
    let said = String::from_utf8_lossy(&resumed.stdout);
    assert!(resumed.status.success(), "{}", String::from_utf8_lossy(&resumed.stderr));
    assert!(said.contains("kept from an earlier run") && !said.contains(" 0 kept"), "{said}");
    assert_eq!(hash_tree(&out), hash_tree(&reference));
    let validated = run(&["validate", out.to_str().unwrap()]);
    assert!(validated.status.success(), "{}", String::from_utf8_lossy(&validated.stdout));
}

#[test]
fn a_run_or_counterfactual_stopped_by_ctrl_c_says_how_many_scenarios_it_wrote_and_where() {
    use std::process::{Command, Stdio};
    use std::time::{Duration, Instant};
    // A short scenario and one of 100,000 frames with images (minutes):
    // stopped once the short one is written, it said "0 of 0 scenarios are
    // complete in .".
    let dir = fresh_dir("hw-run-stopped");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let example: serde_json::Value = read_json(&root.join("configs/examples/stop-the-leader.json"));
    let (mut short, mut long) = (example[0].clone(), example[0].clone());
    short["Name"] = "short".into();
    short["frames"] = 40.into();
    long["Name"] = "long".into();
    long["frames"] = 100_000.into();
    let file = dir.join("two.json");
    std::fs::write(&file, serde_json::to_string(&[short, long]).unwrap()).unwrap();
    // Each command, stopped once its short scenario (`done`, a file written
    // last) is there: exit 130, and the count and folder named.
    let mut checked = 0;
    for (command, done) in [("run", "short/scenario.json"), ("counterfactual", "short/summary.json")] {
        let out = dir.join(command);
        let args = [command, "--scenario", file.to_str().unwrap(), "--out", out.to_str().unwrap()];
        let child = Command::new(bin()).args(args).stderr(Stdio::piped()).spawn().unwrap();
        let deadline = Instant::now() + Duration::from_secs(60);
        while !out.join(done).exists() {
            assert!(Instant::now() < deadline, "{command}: the short scenario was not written");
            std::thread::sleep(Duration::from_millis(10));
        }
        assert!(Command::new("kill").args(["-INT", &child.id().to_string()]).status().unwrap().success());
        let output = child.wait_with_output().unwrap();
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(130), "{command}: {stderr}");
        let said = format!("interrupted: 1 of 2 scenarios are written in {}", out.display());
        assert!(stderr.contains(&said) && stderr.contains("it writes every scenario again"), "{command}: {stderr}");
        checked += 1;
    }
    assert_eq!(checked, 2);
}

#[test]
fn the_documented_intervention_file_runs_as_docs_show() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let file = root.join("configs/intervention-files/stop-and-slow.json");
    assert_valid(&validator("intervention-file.schema.json"), &read_json(&file), &file);
    // docs/handwritten-scenarios.md shows this file and this command's output.
    let docs = std::fs::read_to_string(root.join("docs/handwritten-scenarios.md")).unwrap();
    assert!(docs.contains(std::fs::read_to_string(&file).unwrap().trim()), "the docs show another file");
    let out = fresh_dir("hw-intervention-file").join("cf");
    let scenario = root.join("configs/examples/stop-the-leader.json");
    let output = counterfactual_with_file(&scenario, &file, &out);
    let said = String::from_utf8_lossy(&output.stdout);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    assert!(docs.contains(said.trim()), "docs show another result than {said}");
    let summary = read_json(&out.join("stop_the_leader/summary.json"));
    assert_eq!(summary["affected"], serde_json::json!(["Car_2", "Car_3"]));
}

#[test]
fn a_scenario_file_can_happen_on_a_grid_town_naming_its_lanes_as_causalcity_map_lists_them() {
    let dir = fresh_dir("hw-grid-town");
    let file = dir.join("grid.json");
    // (A null map is left out: the default city.)
    let scenario = |spawn: &str, map: serde_json::Value| {
        let mut text = serde_json::json!([{"Name": "grid_scene", "frames": 30, "map": map, "Vehicles": [
            {"Id": "Car_1", "Spawn": spawn, "SpawnAtDistance": 8, "DriveQueue": ["straight"], "MergeAtDistances": [0]},
            {"Id": "Car_2", "Spawn": "C3z", "SpawnAtDistance": 4, "DriveQueue": ["straight"], "MergeAtDistances": [0]}
        ]}]);
        if text[0]["map"].is_null() {
            text[0].as_object_mut().unwrap().remove("map");
        }
        text.to_string()
    };
    let grid = serde_json::json!({"grid": {"rows": 3, "columns": 3}});
    // E1w is a lane of the 3 x 3 town only (roads A-F); causalcity map lists it.
    let spec = dir.join("spec.json");
    std::fs::write(&spec, format!(r#"{{"name": "g", "world": "city", "seed": 1, "groups": [{{"cars": 2, "edge_proportion": 0}}], "splits": {{"train": 1, "val": 0, "test": 0}}, "map": {grid}}}"#)).unwrap();
    let listed: serde_json::Value =
        serde_json::from_slice(&run(&["map", "--spec", spec.to_str().unwrap(), "--json"]).stdout).unwrap();
    let e1w = listed["lanes"].as_array().unwrap().iter().find(|l| l["name"] == "E1w").expect("E1w listed").clone();
    std::fs::write(&file, scenario("E1w", grid.clone())).unwrap();
    let out = dir.join("out");
    let output = run(&["run", "--scenario", file.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let json = read_json(&out.join("grid_scene/scenario.json"));
    assert_eq!(json["town"], "grid-3x3");
    assert_eq!(json["map"]["grid"]["rows"], 3);
    // Car_1 starts 8 m along E1w, as the map lists the lane.
    let poses = read_poses(&out.join("grid_scene/poses.csv"));
    let first = poses.iter().find(|p| p.frame == 0 && p.car == 0).unwrap();
    let (start, end) = (&e1w["start"], &e1w["end"]);
    let (sx, sy, ex, ey) =
        (start[0].as_f64().unwrap(), start[1].as_f64().unwrap(), end[0].as_f64().unwrap(), end[1].as_f64().unwrap());
    let length = ((ex - sx).powi(2) + (ey - sy).powi(2)).sqrt();
    let along = ((first.x - sx) * (ex - sx) + (first.y - sy) * (ey - sy)) / length;
    assert!((along - 8.0).abs() < 0.5, "Car_1 starts {along:.2} m along E1w");

    // On the default city E1w does not exist; on the grid a wrong id names the grid's roads.
    for (case, text, needle) in [
        ("default city", scenario("E1w", serde_json::Value::Null), "road A-D, segment 0-2"),
        ("unknown lane", scenario("Z9w", grid.clone()), "road A-F, segment 0-3"),
        (
            "a drawn town",
            scenario("E1w", serde_json::json!({"grid": {"rows": {"uniform": [2, 3]}, "columns": 3}})),
            "one town",
        ),
    ] {
        std::fs::write(&file, text).unwrap();
        let out = dir.join(format!("bad-{}", case.replace(' ', "-")));
        let output = run(&["run", "--scenario", file.to_str().unwrap(), "--out", out.to_str().unwrap()]);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{case}: {stderr}");
        assert!(stderr.contains(needle), "{case}: {stderr}");
        assert!(!out.exists(), "{case}: nothing written");
    }
}

#[test]
fn a_counterfactual_flag_of_the_other_source_is_refused_with_exit_2_and_nothing_written() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let file = root.join("configs/examples/stop-the-leader.json");
    let spec = root.join("configs/ci-city.json");
    let (file, spec) = (file.to_str().unwrap(), spec.to_str().unwrap());
    let dir = fresh_dir("hw-other-source");
    let cases: [(&[&str], &str); 7] = [
        (&["--scenario", file, "--kinds", "stop"], "--kinds"),
        (&["--scenario", file, "--format", "tar"], "--format"),
        (&["--scenario", file, "--scenarios-per-tar", "4"], "--scenarios-per-tar"),
        (&["--scenario", file, "--limit", "1"], "--limit"),
        (&["--scenario", file, "-j", "2"], "--threads"),
        (&["--sweep", spec, "--world", "toy"], "--world"),
        (&["--sweep", spec, "--intervention", file], "--intervention"),
    ];
    for (args, flag) in cases {
        let out = dir.join(flag.trim_start_matches('-'));
        let mut command = vec!["counterfactual", "--out", out.to_str().unwrap()];
        command.extend_from_slice(args);
        let output = run(&command);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(stderr.contains(&format!("{flag} belongs to")), "{args:?}: {stderr}");
        assert!(!out.exists(), "{args:?} wrote {}", out.display());
    }
}

/// A two-car scenario on its own `rows` x `columns` grid town, Car_1 on
/// B1w (a lane of every grid), with `interventions`.
fn on_own_grid(rows: u32, columns: u32, interventions: &str) -> String {
    format!(
        r#"[{{"Name": "g", "seed": 7, "frames": 20, "map": {{"grid": {{"rows": {rows}, "columns": {columns}}}}},
        "Vehicles": [
          {{"Id": "Car_1", "Spawn": "B1w", "SpawnAtDistance": 4, "DriveQueue": ["straight"], "MergeAtDistances": [0]}},
          {{"Id": "Car_2", "Spawn": "A1w", "SpawnAtDistance": 4, "DriveQueue": ["straight"], "MergeAtDistances": [0]}}],
        "interventions": {interventions}}}]"#
    )
}

#[test]
fn an_intervention_file_names_lights_and_intersections_on_the_scenarios_own_map() {
    // The file's names were resolved on the default city: on a 1 x 1 town
    // BD's index panicked (exit 101, half a pair written); on a 3 x 3 town
    // another light (CE) was switched without a word; and AF, a light of
    // the 3 x 3 town only, was refused.
    let dir = fresh_dir("hw-own-map-interventions");
    let stop = r#"[{"at": 0.5, "do": "stop", "car": "Car_1", "seconds": 1}]"#;
    let counterfactual = |name: &str, rows: u32, interventions: &str| {
        let (file, extra) = (dir.join(format!("{name}.json")), dir.join(format!("{name}-interventions.json")));
        std::fs::write(&file, on_own_grid(rows, rows, stop)).unwrap();
        std::fs::write(&extra, interventions).unwrap();
        let out = dir.join(name);
        (counterfactual_with_file(&file, &extra, &out), out)
    };
    let set_light = |light: &str| {
        format!(r#"[{{"at": 0.5, "do": "set_light", "light": "{light}", "colour": "red", "seconds": 2}}]"#)
    };
    for (rows, light) in [(3, "BD/W/straight"), (3, "AF/W/straight")] {
        let (output, out) = counterfactual(&format!("grid{rows}-{}", &light[..2]), rows, &set_light(light));
        assert!(output.status.success(), "{light}: {}", String::from_utf8_lossy(&output.stderr));
        let events = std::fs::read_to_string(out.join("g/counterfactual/events.csv")).unwrap();
        let switched: Vec<&str> =
            events.lines().filter(|l| l.contains(",intervention,") && l.contains("red for 2 s")).collect();
        assert_eq!(switched.len(), 1, "{events}");
        assert!(switched[0].contains(&format!(",{light},")), "{light} asked, switched: {}", switched[0]);
    }
    let (output, out) = counterfactual("grid1", 1, &set_light("BD/W/straight"));
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("\"BD/W/straight\" is not a light"), "{stderr}");
    assert!(!out.exists(), "nothing written");
    // An intersection it lacks is told with the ones it has.
    let (output, _) = counterfactual(
        "grid1-reach",
        1,
        r#"[{"when": {"car": "Car_1", "reaches": "BD"}, "do": "stop", "car": "Car_2", "seconds": 1}]"#,
    );
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("\"BD\" is not an intersection of this map: AB"), "{stderr}");
}

#[test]
fn a_car_moved_off_another_at_the_start_leads_it_when_it_now_stands_ahead() {
    // Two cars written on one spot of one lane with one drive queue: the
    // second starts 2.3 m further on. The pair was taken as written (Car_1
    // leading), while the poses and interactions had Car_2 ahead and Car_1
    // bound by it.
    let dir = fresh_dir("hw-moved-spawn");
    let file = dir.join("pair.json");
    let car = |id: &str| {
        format!(
            r#"{{"Id": "{id}", "Spawn": "B1w", "SpawnAtDistance": 3, "DriveQueue": ["straight"], "MergeAtDistances": [0]}}"#
        )
    };
    std::fs::write(
        &file,
        format!(r#"[{{"Name": "p", "seed": 7, "frames": 30, "Vehicles": [{}, {}]}}]"#, car("Car_1"), car("Car_2")),
    )
    .unwrap();
    let out = dir.join("out");
    let output = run(&["run", "--scenario", file.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-images"]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    assert!(stderr.contains("starting at 5.3 m"), "{stderr}");
    let record = read_json(&out.join("p/scenario.json"));
    assert_eq!(record["edges"], serde_json::json!([[1, 0]]), "Car_2, moved ahead, leads");
    assert_eq!(record["cars"][1]["role"], "leader");
    // The follower is the one the interactions bind by the other car.
    let interactions = std::fs::read_to_string(out.join("p/interactions.csv")).unwrap();
    let bound: Vec<&str> = interactions.lines().filter(|l| l.split(',').nth(2) == Some("car")).collect();
    assert!(!bound.is_empty(), "{interactions}");
    for row in bound {
        let fields: Vec<&str> = row.split(',').collect();
        assert_eq!((fields[1], fields[3]), ("0", "1"), "only Car_1 follows, bound by Car_2: {row}");
    }
}

#[test]
fn counterfactual_tells_what_it_adapted_and_what_never_fired_and_refuses_an_empty_file() {
    let dir = fresh_dir("hw-cf-warnings");
    let write = |name: &str, text: String| {
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        path
    };
    let scenario = |queue: &str, merge: &str, interventions: &str| {
        format!(
            r#"[{{"Name": "b", "seed": 7, "frames": 20, "Vehicles": [
              {{"Id": "Car_1", "Spawn": "B1w", "SpawnAtDistance": 14, "DriveQueue": [{queue}], "MergeAtDistances": [{merge}]}},
              {{"Id": "Car_2", "Spawn": "C2y", "SpawnAtDistance": 4, "DriveQueue": ["straight"], "MergeAtDistances": [0]}}],
              "interventions": {interventions}}}]"#
        )
    };
    let stop = r#"[{"at": 0.5, "do": "stop", "car": "Car_1", "seconds": 2}]"#;
    let counterfactual = |file: &Path, out: &str, extra: &[&str]| {
        let out = dir.join(out);
        let mut args =
            vec!["counterfactual", "--scenario", file.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-images"];
        args.extend_from_slice(extra);
        (run(&args), out)
    };
    // A left turn it cannot take from B1w, and a merge name read as 0: run
    // warned of both, counterfactual said nothing.
    let adapted = write("adapted.json", scenario(r#""left""#, r#""mergeL""#, stop));
    let (output, _) = counterfactual(&adapted, "adapted", &[]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    assert!(stderr.contains(r#"warning: scenario "b", car "Car_1", field MergeAtDistances[0]"#), "{stderr}");
    assert!(stderr.contains(r#"car "Car_1", at 0.0 s, skipped: DriveQueue[0] left"#), "{stderr}");
    let (output, out) = counterfactual(&adapted, "adapted-strict", &["--strict"]);
    assert_eq!(output.status.code(), Some(2), "{}", String::from_utf8_lossy(&output.stderr));
    assert!(!out.exists());
    // An intervention whose car never reaches the intersection.
    let never = r#"[{"when": {"car": "Car_2", "reaches": "AD"}, "do": "stop", "car": "Car_1", "seconds": 2}]"#;
    let never = write("never.json", scenario(r#""straight""#, "0", never));
    let (output, out) = counterfactual(&never, "never", &[]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    assert!(stderr.contains("reaches AD)\" never fired in the scenario's 3.8 s"), "{stderr}");
    assert_eq!(read_json(&out.join("b/summary.json"))["intervention_time_s"], serde_json::Value::Null);
    // One that fires: no such warning.
    let fires = write("fires.json", scenario(r#""straight""#, "0", stop));
    let (output, _) = counterfactual(&fires, "fires", &[]);
    assert!(output.status.success());
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!stderr.contains("never fired") && !stderr.contains("last frame"), "{stderr}");
    // One that fires at the last frame (3.8 s, frame 19), by time or by
    // frame: told that no frame shows its effect, and none does.
    for (name, trigger) in [("last-at", r#""at": 3.8"#), ("last-frame", r#""at_frame": 19"#)] {
        let last = format!(r#"[{{{trigger}, "do": "stop", "car": "Car_1", "seconds": 2}}]"#);
        let file = write(&format!("{name}.json"), scenario(r#""straight""#, "0", &last));
        let (output, out) = counterfactual(&file, name, &[]);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(output.status.success(), "{stderr}");
        assert!(stderr.contains("fired at 3.8 s, the scenario's last frame: no frame after it shows"), "{stderr}");
        let summary = read_json(&out.join("b/summary.json"));
        let fired = summary["intervention_time_s"].as_f64().unwrap();
        assert!((fired - 3.8).abs() < 1e-9, "{summary}");
        assert_eq!(summary["affected"], serde_json::json!([]), "{summary}");
    }
    // `run` tells its own interventions alike (it said nothing, though the
    // docs say it warns of one at the last frame).
    let ran = |file: &Path, out: &str| {
        let out = dir.join(out);
        run(&["run", "--scenario", file.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-images"])
    };
    let mut told = 0;
    for (name, says) in [
        ("last-at", "fired at 3.8 s, the scenario's last frame: no frame after it shows"),
        ("last-frame", "fired at 3.8 s, the scenario's last frame: no frame after it shows"),
        ("never", "reaches AD)\" never fired in the scenario's 3.8 s: it changed nothing"),
    ] {
        let output = ran(&dir.join(format!("{name}.json")), &format!("run-{name}"));
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(output.status.success(), "{name}: {stderr}");
        assert!(stderr.contains(says), "{name}: {stderr}");
        told += 1;
    }
    assert_eq!(told, 3);
    let output = ran(&fires, "run-fires");
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success() && !stderr.contains("never fired") && !stderr.contains("last frame"), "{stderr}");
    // Two interventions of one label, one of which never fires: told once
    // (the one that fired stood for both), by run and by counterfactual,
    // whose counterfactual run then is not the factual one.
    let fire_and_never = r#"[{"at": 0.5, "do": "stop", "car": "Car_1", "seconds": 2, "label": "X"},
        {"when": {"car": "Car_2", "reaches": "AD"}, "do": "stop", "car": "Car_1", "seconds": 2, "label": "X"}]"#;
    let twice = write("twice.json", scenario(r#""straight""#, "0", fire_and_never));
    let output = ran(&twice, "run-twice");
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    assert_eq!(stderr.matches("\"X\" never fired in the scenario's 3.8 s: it changed nothing").count(), 1, "{stderr}");
    let added = write("added.json", fire_and_never.to_string());
    let (output, _) = counterfactual(&fires, "added-twice", &["--intervention", added.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    assert_eq!(stderr.matches("\"X\" never fired").count(), 1, "{stderr}");
    assert!(stderr.contains("it changed nothing in the counterfactual run"), "{stderr}");
    assert!(!stderr.contains("the counterfactual run is the factual one"), "{stderr}");
    // An empty intervention file: the counterfactual would be the factual run.
    let empty = write("empty.json", "[]".into());
    let (output, out) = counterfactual(&fires, "empty", &["--intervention", empty.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("empty.json, field interventions: the list is empty"), "{stderr}");
    assert!(!out.exists());
}

#[test]
fn run_and_counterfactual_never_write_over_an_input_lying_in_their_output() {
    let dir = fresh_dir("hw-own-input");
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/examples/stop-the-leader.json");
    let out = dir.join("out");
    let args = |scenario: &Path| {
        ["run", "--scenario", scenario.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-images"]
            .map(String::from)
    };
    let first = run(&args(&file).iter().map(String::as_str).collect::<Vec<_>>());
    assert!(first.status.success(), "{}", String::from_utf8_lossy(&first.stderr));
    // The scenario file kept under a name the run writes, in its folder.
    let inside = out.join("stop_the_leader/events.csv");
    std::fs::copy(&file, &inside).unwrap();
    let before = hash_tree(&out);
    let output = run(&args(&inside).iter().map(String::as_str).collect::<Vec<_>>());
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("never writes onto its own input"), "{stderr}");
    assert_eq!(hash_tree(&out), before, "the input and the folder are as they were");

    // An intervention file kept as a pair's summary.json.
    let pairs = dir.join("pairs");
    let interventions = dir.join("stop.json");
    std::fs::write(&interventions, r#"[{"at": 1, "do": "stop", "car": "Car_1", "seconds": 1}]"#).unwrap();
    let counterfactual = |extra: &Path| counterfactual_with_file(&file, extra, &pairs);
    assert!(counterfactual(&interventions).status.success());
    let inside = pairs.join("stop_the_leader/summary.json");
    std::fs::copy(&interventions, &inside).unwrap();
    let before = hash_tree(&pairs);
    let output = counterfactual(&inside);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("where the intervention file"), "{stderr}");
    assert_eq!(hash_tree(&pairs), before);
}
