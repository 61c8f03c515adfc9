//! Readers given a dataset whose files were edited by hand, or asked for
//! more than a scenario holds: a clear error naming the file and what is
//! wrong, never a panic (exit 101) or an allocation that aborts (134).

mod common;

use common::{city_spec, fresh_dir, gen_ok, npy, npz, read_json, run, run_within, toy_spec, write_spec};
use std::path::{Path, PathBuf};
use std::process::Output;

fn stderr(output: &Output) -> String {
    String::from_utf8_lossy(&output.stderr).into_owned()
}

/// Exit `code`, `says` in the message, and no panic.
fn assert_error(output: &Output, code: i32, says: &str) {
    let text = stderr(output);
    assert!(!text.contains("panicked"), "a panic: {text}");
    assert_eq!(output.status.code(), Some(code), "stderr: {text}");
    assert!(text.contains(says), "expected {says:?} in: {text}");
}

fn s(path: &Path) -> &str {
    path.to_str().unwrap()
}

/// A small city dataset of `frames` frames (4 cars, splits 1/1/1).
fn city(dir: &Path, frames: u32) -> PathBuf {
    let spec = write_spec(dir, &city_spec("edited", &[(4, 0.5)], (1, 1, 1), frames, "{}"));
    let data = dir.join("data");
    gen_ok(&spec, &data, &["--quiet", "--no-images"]);
    data
}

/// `data` copied to `to`, with `edit` applied to its train scenario's
/// scenario.json (or, with `manifest`, to manifest.json).
fn edited(data: &Path, to: &Path, manifest: bool, edit: impl Fn(&mut serde_json::Value)) -> PathBuf {
    let copy = std::process::Command::new("cp").args(["-r", s(data), s(to)]).status().unwrap();
    assert!(copy.success());
    let file = if manifest { to.join("manifest.json") } else { to.join("cars04_edges50/train/00000/scenario.json") };
    let mut value: serde_json::Value = serde_json::from_slice(&std::fs::read(&file).unwrap()).unwrap();
    edit(&mut value);
    std::fs::write(&file, serde_json::to_vec(&value).unwrap()).unwrap();
    to.to_path_buf()
}

#[test]
fn a_scenario_json_edited_out_of_range_is_named_by_every_reader() {
    let dir = fresh_dir("edited-scenario-json");
    let data = city(&dir, 20);
    let bad_edge = edited(&data, &dir.join("edge"), false, |v| v["edges"] = serde_json::json!([[0, 99]]));
    for command in ["stats", "baseline"] {
        assert_error(&run(&[command, s(&bad_edge)]), 2, "edges: pair [0, 99] names a car beyond the 4 cars");
    }
    let no_interval = edited(&data, &dir.join("interval"), false, |v| v["frame_interval"] = 0.into());
    assert_error(&run(&["baseline", s(&no_interval)]), 2, "frame_interval 0");
    // Claims a billion frames: refused before memory is set aside for them.
    let billion = edited(&data, &dir.join("billion"), false, |v| v["frames"] = 1_000_000_000u64.into());
    for command in ["stats", "baseline"] {
        assert_error(&run(&[command, s(&billion)]), 2, "frames 1000000000");
    }
    let scenario = billion.join("cars04_edges50/train/00000");
    assert_error(&run(&["preview", s(&scenario), "--out", s(&dir.join("p.gif"))]), 2, "frames 1000000000");
    // Claims the most a spec allows, far more than its poses.csv holds.
    let most = edited(&data, &dir.join("most"), false, |v| v["frames"] = 100_000.into());
    assert_error(&run(&["baseline", s(&most)]), 2, "more rows than");
    let manifest = edited(&data, &dir.join("manifest"), true, |v| v["spec"]["frames"] = 0.into());
    assert_error(&run(&["export", "nri", s(&manifest), "--out", s(&dir.join("nri"))]), 2, "the spec in it is invalid");
    assert!(!dir.join("nri").exists(), "nothing exported");
}

#[test]
fn the_baseline_refuses_one_frame_scenarios_and_clamps_lags_beyond_the_scenario() {
    let dir = fresh_dir("baseline-short");
    let short = dir.join("short");
    std::fs::create_dir_all(&short).unwrap();
    city(&short, 1);
    assert_error(&run(&["baseline", s(&short.join("data"))]), 2, "2 frames or more");

    // 20 frames of 1 s: a lag of 1e18 s (or one that overflows an integer
    // of frames) scores as a lag back to the first frame does.
    let data = city(&dir, 20);
    let json = |lag: &str| {
        let output = run(&["baseline", s(&data), "--max-lag", lag, "--json"]);
        assert!(output.status.success(), "--max-lag {lag}: {}", stderr(&output));
        let mut value: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
        // The lag asked for is reported as given.
        value.as_object_mut().unwrap().remove("lags_s");
        for row in value["groups"].as_array_mut().into_iter().flatten() {
            row.as_object_mut().unwrap().remove("max_lag_s");
        }
        value
    };
    let whole = json("20");
    assert!(whole.to_string().contains("auroc"), "{whole}");
    assert_eq!(json("1e18"), whole);
    assert_eq!(json("1e10"), whole);
}

#[test]
fn validate_checks_every_city_log_interactions_included() {
    let dir = fresh_dir("validate-interactions");
    let data = city(&dir, 20);
    let clean = run(&["validate", s(&data)]);
    assert!(clean.status.success(), "{}", String::from_utf8_lossy(&clean.stdout));
    // 3 scenarios of 7 files each (scenario, poses, pixels, lights, events,
    // interactions, effects), every one read and checked.
    assert!(String::from_utf8_lossy(&clean.stdout).contains("21 files"), "{}", String::from_utf8_lossy(&clean.stdout));
    let interactions = "cars04_edges50/train/00000/interactions.csv";
    let missing = dir.join("missing");
    assert!(std::process::Command::new("cp").args(["-r", s(&data), s(&missing)]).status().unwrap().success());
    std::fs::remove_file(missing.join(interactions)).unwrap();
    let output = run(&["validate", s(&missing)]);
    assert_eq!(output.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&output.stdout).contains("interactions.csv: missing"), "{output:?}");
    // A row taken out: the checksum and the row order say so.
    let short = dir.join("short");
    assert!(std::process::Command::new("cp").args(["-r", s(&data), s(&short)]).status().unwrap().success());
    let path = short.join(interactions);
    let text = std::fs::read_to_string(&path).unwrap();
    let mut lines: Vec<&str> = text.lines().collect();
    lines.remove(6);
    std::fs::write(&path, lines.join("\n") + "\n").unwrap();
    let report = String::from_utf8_lossy(&run(&["validate", s(&short)]).stdout).into_owned();
    assert!(report.contains("interactions.csv: checksum mismatch"), "{report}");
    assert!(report.contains("interactions.csv: row 7 is malformed or out of order"), "{report}");
}

#[test]
fn preview_of_a_folder_without_a_scenario_is_bad_input() {
    let dir = fresh_dir("preview-no-scenario");
    let data = city(&dir, 20);
    let gif = dir.join("p.gif");
    assert_error(
        &run(&["preview", s(&data), "--out", s(&gif)]),
        2,
        "it is a dataset: give one of its scenario folders",
    );
    assert_error(&run(&["preview", s(&dir.join("nowhere")), "--out", s(&gif)]), 2, "holds no scenario.json");
    assert!(!gif.exists());
}

#[test]
fn a_manifest_whose_spec_was_edited_is_refused_by_every_reader() {
    // Another seed in manifest.json's spec: validate said valid, and the
    // readers took it for the spec of scenarios it did not make.
    let dir = fresh_dir("edited-manifest-spec");
    let data = city(&dir, 20);
    let reseeded = edited(&data, &dir.join("seed"), true, |v| v["spec"]["seed"] = 8.into());
    let smaller = edited(&data, &dir.join("splits"), true, |v| v["spec"]["splits"]["train"] = 0.into());
    for edited in [&reseeded, &smaller] {
        for command in ["validate", "stats", "baseline"] {
            assert_error(&run(&[command, s(edited)]), 2, "manifest.json: its spec does not hash to its spec_sha256");
        }
    }
    assert!(run(&["validate", s(&data)]).status.success(), "the dataset as gen wrote it is valid");
    // The fields gen derives from the spec, edited: validate said valid.
    let counted = edited(&data, &dir.join("counted"), true, |v| v["scenarios"] = 80_000_000_000u64.into());
    let grown = edited(&data, &dir.join("grown"), true, |v| v["groups"][0]["cars"] = 1_000_000.into());
    for (edited, says) in [(&counted, "`scenarios` is 80000000000 here, 3 by its spec"), (&grown, "`groups`")] {
        let checked = run(&["validate", s(edited)]);
        assert_eq!(checked.status.code(), Some(1), "{}", stderr(&checked));
        let report = String::from_utf8_lossy(&checked.stdout);
        assert!(report.contains(says) && report.contains("edited after gen wrote it"), "{report}");
    }
}

#[test]
fn a_sweep_whose_spec_was_edited_is_refused_and_one_from_before_the_hash_opens() {
    // sweep.json recorded no hash of its spec: a sweep edited to another
    // seed validated, and readers took it for pairs it did not make.
    let dir = fresh_dir("edited-sweep-spec");
    let spec = write_spec(&dir, &city_spec("edited-sweep", &[(4, 0.5)], (1, 1, 1), 20, "{}"));
    let sweep = dir.join("sweep");
    let made = run(&["counterfactual", "--sweep", s(&spec), "--out", s(&sweep), "--no-images", "-q"]);
    assert!(made.status.success(), "{}", stderr(&made));
    let record_path = sweep.join("sweep.json");
    let record: serde_json::Value = serde_json::from_slice(&std::fs::read(&record_path).unwrap()).unwrap();
    assert_eq!(record["spec_sha256"].as_str().map(str::len), Some(64), "the record keeps the spec's hash");
    let rewrite = |edit: &dyn Fn(&mut serde_json::Value)| {
        let mut value = record.clone();
        edit(&mut value);
        std::fs::write(&record_path, serde_json::to_vec(&value).unwrap()).unwrap();
    };
    // A pair's summary.json linked to a copy elsewhere: named, not read
    // through (it validated).
    let summary = std::fs::read_dir(sweep.join("cars04_edges50/train")).unwrap().next().unwrap().unwrap().path();
    let summary = summary.join("summary.json");
    let copy = dir.join("summary-copy.json");
    std::fs::copy(&summary, &copy).unwrap();
    std::fs::remove_file(&summary).unwrap();
    std::os::unix::fs::symlink(&copy, &summary).unwrap();
    let checked = run_within(&["validate", s(&sweep)], 30);
    assert_eq!(checked.status.code(), Some(1), "{}", stderr(&checked));
    let report = String::from_utf8_lossy(&checked.stdout);
    assert!(report.contains("summary.json: unreadable: a symbolic link, not followed"), "{report}");
    std::fs::remove_file(&summary).unwrap();
    std::fs::copy(&copy, &summary).unwrap();
    rewrite(&|v| v["spec"]["seed"] = 8.into());
    assert_error(&run(&["validate", s(&sweep)]), 2, "sweep.json: its spec does not hash to its spec_sha256");
    let packed = dir.join("packed");
    assert_error(&run(&["pack", s(&sweep), "--out", s(&packed)]), 2, "its spec does not hash");
    assert!(!packed.exists(), "a refused pack writes nothing");
    // A sweep written before the record kept the hash is read as before.
    rewrite(&|v| {
        v.as_object_mut().unwrap().remove("spec_sha256");
    });
    let checked = run(&["validate", s(&sweep)]);
    assert!(checked.status.success(), "{}", stderr(&checked));
}

#[test]
fn pipes_devices_and_linked_folders_are_refused_by_name_never_read_without_end() {
    // A spec, manifest or scenario.json that was a pipe hung the command;
    // one linked to /dev/zero read until memory ran out. A linked scenario
    // folder validated, though gen refuses to write through it.
    let dir = fresh_dir("edited-pipes");
    let data = city(&dir, 20);
    let fifo = dir.join("pipe.json");
    assert!(std::process::Command::new("mkfifo").arg(&fifo).status().unwrap().success());
    for args in [vec!["map", "--spec", s(&fifo)], vec!["gen", "--spec", s(&fifo), "--out", s(&dir.join("never"))]] {
        assert_error(&run_within(&args, 30), 2, "pipe.json: not a regular file (a pipe or a device)");
    }
    assert!(!dir.join("never").exists());
    let piped = dir.join("piped");
    std::fs::create_dir(&piped).unwrap();
    std::os::unix::fs::symlink(&fifo, piped.join("manifest.json")).unwrap();
    for command in ["validate", "stats"] {
        assert_error(&run_within(&[command, s(&piped)], 30), 2, "manifest.json: not a regular file");
    }
    // A scenario.json linked to the pipe: named, never read.
    let linked_file = edited(&data, &dir.join("linked-file"), false, |_| {});
    let json = linked_file.join("cars04_edges50/train/00000/scenario.json");
    std::fs::remove_file(&json).unwrap();
    std::os::unix::fs::symlink(&fifo, &json).unwrap();
    let checked = run_within(&["validate", s(&linked_file)], 30);
    assert_eq!(checked.status.code(), Some(1), "{}", stderr(&checked));
    assert!(String::from_utf8_lossy(&checked.stdout).contains("scenario.json: a symbolic link"));
    assert_error(&run_within(&["stats", s(&linked_file)], 30), 2, "scenario.json: not a regular file");
    // A pipe at the lock file: validate asks whether a command is writing
    // the folder without opening it (it hung).
    let locked = dir.join("piped-lock");
    assert!(std::process::Command::new("cp").args(["-r", s(&data), s(&locked)]).status().unwrap().success());
    assert!(std::process::Command::new("mkfifo").arg(locked.join(".causalcity.lock")).status().unwrap().success());
    let checked = run_within(&["validate", s(&locked)], 30);
    assert!(!stderr(&checked).contains("is being written now"), "{}", stderr(&checked));
    // A scenario folder that is a link to a good copy: named by validate.
    let linked_folder = dir.join("linked-folder");
    assert!(std::process::Command::new("cp").args(["-r", s(&data), s(&linked_folder)]).status().unwrap().success());
    let folder = linked_folder.join("cars04_edges50/test/00000");
    std::fs::remove_dir_all(&folder).unwrap();
    std::os::unix::fs::symlink(data.join("cars04_edges50/test/00000"), &folder).unwrap();
    let checked = run(&["validate", s(&linked_folder)]);
    assert_eq!(checked.status.code(), Some(1), "a linked scenario folder is not valid: {}", stderr(&checked));
    let report = String::from_utf8_lossy(&checked.stdout);
    assert!(report.contains("cars04_edges50/test/00000: a symbolic link"), "{report}");
    assert!(stderr(&checked).contains("1 problem found"), "{}", stderr(&checked));
    // A linked group folder: named once, not once per scenario in it.
    let linked_group = dir.join("linked-group");
    assert!(std::process::Command::new("cp").args(["-r", s(&data), s(&linked_group)]).status().unwrap().success());
    std::fs::remove_dir_all(linked_group.join("cars04_edges50")).unwrap();
    std::os::unix::fs::symlink(data.join("cars04_edges50"), linked_group.join("cars04_edges50")).unwrap();
    let checked = run(&["validate", s(&linked_group)]);
    assert!(stderr(&checked).contains("1 problem found"), "{}", stderr(&checked));
    assert!(String::from_utf8_lossy(&checked.stdout).contains("linked-group/cars04_edges50: a symbolic link"));
}

#[test]
fn gen_into_a_folder_whose_manifest_is_not_causalcitys_is_bad_input() {
    // Exit 1 (a failure while running) before; the folder given is the
    // problem, as validate and stats say with exit 2.
    let dir = fresh_dir("edited-foreign-manifest");
    let spec = write_spec(&dir, &city_spec("foreign", &[(4, 0.5)], (1, 1, 1), 10, "{}"));
    let out = dir.join("out");
    std::fs::create_dir(&out).unwrap();
    std::fs::write(out.join("manifest.json"), "{\"name\": \"my web app\"}").unwrap();
    for force in [false, true] {
        let mut args = vec!["gen", "--spec", s(&spec), "--out", s(&out), "--quiet"];
        if force {
            args.push("--force");
        }
        assert_error(&run(&args), 2, "manifest.json is not a causalcity manifest");
        assert_eq!(std::fs::read_to_string(out.join("manifest.json")).unwrap(), "{\"name\": \"my web app\"}");
    }
}

#[test]
fn stats_and_heatmap_read_poses_and_events_as_every_reader_does() {
    // An emptied poses.csv gave speeds of 0, a NaN speed printed NaN, and a
    // header-less events.csv counted no events: exit 0 each time.
    let dir = fresh_dir("edited-stats-logs");
    let data = city(&dir, 20);
    let copy = |name: &str, file: &str, edit: &dyn Fn(String) -> String| {
        let to = dir.join(name);
        assert!(std::process::Command::new("cp").args(["-r", s(&data), s(&to)]).status().unwrap().success());
        let path = to.join("cars04_edges50/train/00000").join(file);
        std::fs::write(&path, edit(std::fs::read_to_string(&path).unwrap())).unwrap();
        to
    };
    let emptied = copy("emptied", "poses.csv", &|_| String::new());
    let nan = copy("nan", "poses.csv", &|text| {
        let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
        let mut fields: Vec<&str> = lines[1].split(',').collect();
        fields[11] = "NaN";
        lines[1] = fields.join(",");
        lines.join("\n") + "\n"
    });
    let no_header = copy("no-header", "events.csv", &|_| String::new());
    let heat = dir.join("heat.png");
    for (copy, says) in
        [(&emptied, "poses.csv (0 bytes) can hold"), (&nan, r#"poses.csv line 2: speed "NaN" is not allowed"#)]
    {
        assert_error(&run(&["stats", s(copy)]), 2, says);
        assert_error(&run(&["heatmap", s(copy), "--out", s(&heat)]), 2, says);
        assert!(!heat.exists(), "no picture of a damaged dataset");
    }
    assert_error(&run(&["stats", s(&no_header)]), 2, "events.csv: columns [], expected frame,t,kind");
    assert!(run(&["stats", s(&data)]).status.success());
}

#[test]
fn a_dataset_written_within_an_earlier_versions_limits_still_reads() {
    // Limits added since (the lowest cycle_scale and schedule step, a zoom
    // on a perspective camera, the lowest frame_interval) hold new specs
    // only: every reader refused a dataset written before them ("the spec
    // in it is invalid").
    let dir = fresh_dir("edited-earlier-limits");
    let spec = write_spec(&dir, &city_spec("earlier", &[(4, 0.5)], (2, 0, 1), 20, "{}"));
    let out = dir.join("data");
    gen_ok(&spec, &out, &["--quiet", "--no-images"]);
    let path = out.join("manifest.json");
    let mut manifest = read_json(&path);
    manifest["spec"]["city"]["lights"]["cycle_scale"] = 0.005.into();
    // As that version recorded it: the hash of the spec it ran.
    let recorded: causalcity::spec::DatasetSpec = serde_json::from_value(manifest["spec"].clone()).unwrap();
    manifest["spec_sha256"] = causalcity::output::manifest::spec_sha256(&recorded).into();
    std::fs::write(&path, serde_json::to_string_pretty(&manifest).unwrap()).unwrap();
    let stats = run(&["stats", out.to_str().unwrap()]);
    assert!(stats.status.success(), "{}", String::from_utf8_lossy(&stats.stderr));
    assert!(String::from_utf8_lossy(&stats.stdout).contains("cars04_edges50"));
    // Given as input, the same spec is held to them.
    let given = std::fs::read_to_string(&spec)
        .unwrap()
        .replace(r#""city": {}"#, r#""city": {"lights": {"cycle_scale": 0.005}}"#);
    assert!(given.contains("0.005"));
    let output =
        run(&["gen", "--spec", write_spec(&dir, &given).to_str().unwrap(), "--out", dir.join("new").to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("city.lights.cycle_scale") && stderr.contains("from 0.01 to 10"), "{stderr}");
}

/// `data` copied to `to` with `edit` applied to the text of its train
/// scenario's `file`, and the scenario's checksum of it updated (as a
/// careful editor would), so that only the values speak.
fn edited_file(data: &Path, to: &Path, file: &str, edit: impl Fn(String) -> String) -> PathBuf {
    use sha2::Digest;
    assert!(std::process::Command::new("cp").args(["-r", s(data), s(to)]).status().unwrap().success());
    let scenario = to.join("cars04_edges50/train/00000");
    let text = edit(std::fs::read_to_string(scenario.join(file)).unwrap());
    std::fs::write(scenario.join(file), &text).unwrap();
    let digest: String = sha2::Sha256::digest(text.as_bytes()).iter().map(|b| format!("{b:02x}")).collect();
    let sums = scenario.join("checksums.sha256");
    let lines: Vec<String> = std::fs::read_to_string(&sums)
        .unwrap()
        .lines()
        .map(|l| if l.ends_with(&format!("  {file}")) { format!("{digest}  {file}") } else { l.to_string() })
        .collect();
    std::fs::write(&sums, lines.join("\n") + "\n").unwrap();
    to.to_path_buf()
}

/// poses.csv with field `column` of data row `row` (0-based) set to `value`.
fn pose_set(text: String, row: usize, column: usize, value: &str) -> String {
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    let mut fields: Vec<String> = lines[row + 1].split(',').map(str::to_string).collect();
    fields[column] = value.to_string();
    lines[row + 1] = fields.join(",");
    lines.join("\n") + "\n"
}

#[test]
fn pose_values_outside_the_schema_and_malformed_graphs_are_named_by_every_reader() {
    // Each was read as written, exit 0: a NaN or 1e308 speed (stats' mean
    // speed became inf), a negative speed, a yaw of 100 rad, a t that
    // differs between the cars of a frame (validate said valid too); a
    // self-loop or a repeated pair in any graph of scenario.json (stats'
    // gaps and edge counts changed).
    let dir = fresh_dir("edited-pose-values");
    let data = city(&dir, 20);
    let cases: Vec<(&str, usize, usize, &str, &str)> = vec![
        ("nan-speed", 5, 11, "nan", r#"line 7: speed "nan" is not allowed: metres per second, 0 or more"#),
        ("huge-speed", 5, 11, "1e308", r#"speed "1e308" is not allowed"#),
        ("negative-speed", 2, 11, "-5", r#"speed "-5" is not allowed"#),
        ("yaw", 3, 8, "100", r#"line 5: yaw "100" is not allowed: radians from -3.141593 to 3.141593"#),
        ("infinite-x", 1, 3, "inf", r#"x "inf" is not allowed: a finite number within +-1e9"#),
        ("t", 5, 1, "7.25", "line 7: t 7.25 differs from frame 1's t"),
    ];
    let mut checked = 0;
    for (name, row, column, value, says) in &cases {
        let bad = edited_file(&data, &dir.join(name), "poses.csv", |t| pose_set(t, *row, *column, value));
        for command in ["stats", "baseline"] {
            assert_error(&run(&[command, s(&bad)]), 2, says);
        }
        let report = run(&["validate", s(&bad)]);
        assert_eq!(report.status.code(), Some(1), "validate {name}");
        let text = String::from_utf8_lossy(&report.stdout);
        assert!(text.contains("poses.csv: ") && text.contains(says), "{text}");
        checked += 1;
    }
    assert_eq!(checked, cases.len());
    // A pipe where poses.csv should be is named as one (it was "more rows
    // than poses.csv (0 bytes) can hold").
    let piped = dir.join("piped");
    assert!(std::process::Command::new("cp").args(["-r", s(&data), s(&piped)]).status().unwrap().success());
    let poses = piped.join("cars04_edges50/train/00000/poses.csv");
    std::fs::remove_file(&poses).unwrap();
    assert!(std::process::Command::new("mkfifo").arg(&poses).status().unwrap().success());
    assert_error(&run_within(&["stats", s(&piped)], 60), 2, "not a regular file (a pipe or a device)");

    for (name, field, pairs, says) in [
        ("self-loop", "edges", serde_json::json!([[2, 2]]), "edges: pair [2, 2] links a car to itself"),
        ("twice", "edges", serde_json::json!([[1, 2], [1, 2]]), "edges: pair [1, 2] is given twice"),
        ("beyond", "causal_edges", serde_json::json!([[0, 50]]), "causal_edges: pair [0, 50] names a car beyond"),
    ] {
        let bad = edited(&data, &dir.join(name), false, |v| v[field] = pairs.clone());
        assert_error(&run(&["stats", s(&bad)]), 2, says);
    }
}

#[test]
fn export_nri_refuses_non_finite_pixels_and_a_manifest_claiming_more_than_memory() {
    // NRI's export reads pixels.npy alone: a NaN or an infinity there was
    // exported into loc_train.npy, exit 0.
    let dir = fresh_dir("edited-pixels");
    let data = city(&dir, 20);
    for (name, value, says) in
        [("nan", f32::NAN, "holds NaN at [0, 1, 0]"), ("inf", f32::INFINITY, "holds inf at [0, 1, 0]")]
    {
        let copy = dir.join(name);
        assert!(std::process::Command::new("cp").args(["-r", s(&data), s(&copy)]).status().unwrap().success());
        let path = copy.join("cars04_edges50/train/00000/pixels.npy");
        let mut bytes = std::fs::read(&path).unwrap();
        let start = 10 + u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
        // frame 0, car 1, px
        bytes[start + 8..start + 12].copy_from_slice(&value.to_le_bytes());
        std::fs::write(&path, bytes).unwrap();
        let out = dir.join(format!("{name}-nri"));
        assert_error(&run(&["export", "nri", s(&copy), "--out", s(&out), "--quiet"]), 2, says);
        assert!(!out.join("cars04_edges50/loc_train.npy").exists(), "nothing exported");
    }
    // A manifest edited (its hash recomputed) to claim 88-car scenarios of
    // 100,000 frames, 20,000 of them: the export aborted (exit 134)
    // setting aside 1.4 TB before a scenario was read.
    let claimed = dir.join("claimed");
    assert!(std::process::Command::new("cp").args(["-r", s(&data), s(&claimed)]).status().unwrap().success());
    let path = claimed.join("manifest.json");
    let mut manifest = read_json(&path);
    manifest["spec"]["frames"] = 100_000.into();
    manifest["spec"]["groups"][0]["cars"] = 88.into();
    manifest["spec"]["splits"] = serde_json::json!({"train": 20000, "val": 1, "test": 1});
    manifest["limit"] = serde_json::Value::Null;
    let spec: causalcity::spec::DatasetSpec = serde_json::from_value(manifest["spec"].clone()).unwrap();
    let spec = causalcity::plan::Expansion::from_spec(spec).unwrap().spec;
    manifest["spec_sha256"] = causalcity::output::manifest::spec_sha256(&spec).into();
    std::fs::write(&path, manifest.to_string()).unwrap();
    let output = run(&["export", "nri", s(&claimed), "--out", s(&dir.join("claimed-nri")), "--quiet"]);
    let text = stderr(&output);
    assert!(!text.contains("panicked") && !text.contains("memory allocation"), "{text}");
    assert!(matches!(output.status.code(), Some(1 | 2)), "exit {:?}: {text}", output.status.code());
}

#[test]
fn a_counterfactual_pair_whose_files_disagree_is_named_by_validate() {
    // Each was scored by evaluate as written and validated: a car's
    // max_divergence_m edited, the intervention moved to another car or a
    // later frame, a divergence.csv of another pair.
    let dir = fresh_dir("edited-pairs");
    let spec = write_spec(&dir, &city_spec("edited-pairs", &[(4, 0.5)], (1, 1, 1), 20, "{}"));
    let sweep = dir.join("sweep");
    let made =
        run(&["counterfactual", "--sweep", s(&spec), "--out", s(&sweep), "--no-images", "-q", "--kinds", "stop"]);
    assert!(made.status.success(), "{}", stderr(&made));
    let checked = run(&["validate", s(&sweep)]);
    assert!(checked.status.success(), "{}", String::from_utf8_lossy(&checked.stdout));
    let pair = "cars04_edges50/test/00000";
    let summary: serde_json::Value = read_json(&sweep.join(pair).join("summary.json"));
    let car = summary["intervention"]["car"].as_u64().unwrap() as usize;
    let frame = summary["intervention"]["frame"].as_u64().unwrap();
    let moved = summary["cars"].as_array().unwrap().iter().position(|c| c["max_divergence_m"].as_f64() > Some(0.01));
    let moved = moved.expect("the stopped car's pair moves some car");
    type Edit = Box<dyn Fn(&mut serde_json::Value)>;
    let edits: Vec<(&str, Edit, String)> = vec![
        (
            "divergence",
            Box::new(move |v| v["cars"][moved]["max_divergence_m"] = 3.0.into()),
            format!("car {moved}'s largest divergence is"),
        ),
        (
            "car",
            Box::new(move |v| v["intervention"]["car"] = ((car + 1) % 4).into()),
            format!("intervention car {} is named", (car + 1) % 4),
        ),
        (
            "frame",
            Box::new(|v| v["intervention"]["frame"] = 19.into()),
            "before the intervention's frame 19".to_string(),
        ),
        ("order", Box::new(|v| v["cars"].as_array_mut().unwrap().reverse()), "cars[0] is car 3".to_string()),
    ];
    assert!(frame < 19, "the intervention fires before the last frame");
    let mut checked = 0;
    for (name, edit, says) in &edits {
        let copy = dir.join(name);
        assert!(std::process::Command::new("cp").args(["-r", s(&sweep), s(&copy)]).status().unwrap().success());
        let path = copy.join(pair).join("summary.json");
        let mut value = read_json(&path);
        edit(&mut value);
        std::fs::write(&path, serde_json::to_vec_pretty(&value).unwrap()).unwrap();
        let output = run(&["validate", s(&copy)]);
        let text = String::from_utf8_lossy(&output.stdout);
        assert_eq!(output.status.code(), Some(1), "{name}: {text}");
        assert!(text.contains(says.as_str()), "{name}: expected {says:?} in {text}");
        checked += 1;
    }
    assert_eq!(checked, edits.len());
    // summary.json and divergence.csv edited alike (neither has a checksum):
    // a still car made affected, and the moved car moved 2 m further at the
    // last frame. Both passed: the runs' poses.csv (checksummed) now decide.
    let still = summary["cars"].as_array().unwrap().iter().position(|c| c["max_divergence_m"].as_f64() == Some(0.0));
    let still = still.expect("a car the stop did not move");
    let text = std::fs::read_to_string(sweep.join(pair).join("divergence.csv")).unwrap();
    let last = 1 + 19 * 4 + moved; // the header, then a row per frame and car
    let further = text.lines().nth(last).unwrap().split(',').nth(3).unwrap().parse::<f64>().unwrap() + 2.0;
    type Forgery = Box<dyn Fn(&mut serde_json::Value, &mut Vec<String>)>;
    let forgeries: Vec<(&str, Forgery, String)> = vec![
        (
            "made-affected",
            Box::new(move |v, _| {
                v["cars"][still]["affected"] = true.into();
                v["cars"][still]["first_divergent_frame"] = 19.into();
                let flagged = v["cars"].as_array().unwrap().iter().filter(|c| c["affected"] == true);
                v["affected"] = flagged.map(|c| c["name"].clone()).collect();
            }),
            format!("cars[{still}].first_divergent_frame is frame 19, and the runs' poses.csv first differ for car {still} at no frame"),
        ),
        (
            "moved-further",
            Box::new(move |v, rows| {
                v["cars"][moved]["max_divergence_m"] = further.into();
                let mut row: Vec<String> = rows[last].split(',').map(String::from).collect();
                row[3] = format!("{further:.4}");
                rows[last] = row.join(",");
            }),
            format!("line {}: car {moved} is {further:.4} m from its factual position at frame 19, and the runs' poses.csv put it", last + 1),
        ),
    ];
    let mut forged = 0;
    for (name, forge, says) in &forgeries {
        let copy = dir.join(name);
        assert!(std::process::Command::new("cp").args(["-r", s(&sweep), s(&copy)]).status().unwrap().success());
        let path = copy.join(pair).join("summary.json");
        let mut value = read_json(&path);
        let mut rows: Vec<String> = text.lines().map(String::from).collect();
        forge(&mut value, &mut rows);
        std::fs::write(&path, serde_json::to_vec_pretty(&value).unwrap()).unwrap();
        std::fs::write(copy.join(pair).join("divergence.csv"), rows.join("\n") + "\n").unwrap();
        let output = run(&["validate", s(&copy)]);
        let printed = String::from_utf8_lossy(&output.stdout);
        assert_eq!(output.status.code(), Some(1), "{name}: {printed}");
        assert!(printed.contains(says.as_str()), "{name}: expected {says:?} in {printed}");
        forged += 1;
    }
    assert_eq!(forged, forgeries.len());
    // A summary from before the intervention record still reads: then a
    // first divergent frame could come a frame before the rows differ.
    let dated = dir.join("dated");
    assert!(std::process::Command::new("cp").args(["-r", s(&sweep), s(&dated)]).status().unwrap().success());
    let path = dated.join(pair).join("summary.json");
    let mut value = read_json(&path);
    value.as_object_mut().unwrap().remove("intervention");
    let first = value["cars"][moved]["first_divergent_frame"].as_u64().unwrap();
    value["cars"][moved]["first_divergent_frame"] = (first - 1).into();
    std::fs::write(&path, serde_json::to_vec_pretty(&value).unwrap()).unwrap();
    let output = run(&["validate", s(&dated)]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stdout));
    // Never after the rows differ, record or not.
    value["cars"][moved]["first_divergent_frame"] = (first + 1).into();
    std::fs::write(&path, serde_json::to_vec_pretty(&value).unwrap()).unwrap();
    let output = run(&["validate", s(&dated)]);
    let printed = String::from_utf8_lossy(&output.stdout);
    assert_eq!(output.status.code(), Some(1), "{printed}");
    let says =
        format!("cars[{moved}].first_divergent_frame is frame {}, and the runs' poses.csv first differ", first + 1);
    assert!(printed.contains(&says), "expected {says:?} in {printed}");
    // The same rule for a packed sweep's pairs (validate parsed the summary only).
    let packed = dir.join("packed");
    let args = ["--no-images", "-q", "--kinds", "stop", "--format", "tar", "--scenarios-per-tar", "4"];
    let made = run(&[&["counterfactual", "--sweep", s(&spec), "--out", s(&packed)][..], &args[..]].concat());
    assert!(made.status.success(), "{}", stderr(&made));
    let tar = packed.join("cars04_edges50/test/00000-00000.tar");
    let mut bytes = std::fs::read(&tar).unwrap();
    let (from, to) = (&b"\"max_divergence_m\": 0.0,"[..], &b"\"max_divergence_m\": 5.0,"[..]);
    let at = bytes.windows(from.len()).position(|w| w == from).expect("a car that did not move");
    bytes[at..at + from.len()].copy_from_slice(to);
    std::fs::write(&tar, bytes).unwrap();
    let output = run(&["validate", s(&packed)]);
    let text = String::from_utf8_lossy(&output.stdout);
    assert_eq!(output.status.code(), Some(1), "{text}");
    assert!(text.contains("largest divergence is 0 m, and summary.json's max_divergence_m 5"), "{text}");
    // sweep.json's limit edited to 0: "0 of 0 scenarios checked: valid".
    let none = dir.join("limit-0");
    assert!(std::process::Command::new("cp").args(["-r", s(&sweep), s(&none)]).status().unwrap().success());
    let mut record = read_json(&none.join("sweep.json"));
    record["limit"] = 0.into();
    std::fs::write(none.join("sweep.json"), record.to_string()).unwrap();
    assert_error(&run(&["validate", s(&none)]), 2, "sweep.json: limit 0 is not allowed");
    // Its kinds edited to one no sweep draws, or one named twice: validated
    // (the kind names lived above the readers).
    for (kinds, says) in [
        (serde_json::json!(["nuke"]), "kinds[0] \"nuke\" is not a kind of intervention a sweep draws: use stop"),
        (serde_json::json!(["stop", "stop"]), "kinds[1] \"stop\" is named twice"),
    ] {
        let edited = dir.join(format!("kinds-{}", kinds.as_array().unwrap().len()));
        assert!(std::process::Command::new("cp").args(["-r", s(&sweep), s(&edited)]).status().unwrap().success());
        let mut record = read_json(&edited.join("sweep.json"));
        assert!(record["kinds"].is_array(), "{record}");
        record["kinds"] = kinds;
        std::fs::write(edited.join("sweep.json"), record.to_string()).unwrap();
        assert_error(&run(&["validate", s(&edited)]), 2, says);
    }
}

#[test]
fn a_scenario_moved_into_another_scenarios_folder_is_named_by_every_reader() {
    // Two scenario folders swapped (their checksums intact): export nri
    // wrote one group's arrays under the other's name, and stats, baseline
    // and heatmap read them as written, exit 0 (helper audit).
    let dir = fresh_dir("edited-swapped");
    let data = city(&dir, 20);
    let (a, b) = (data.join("cars04_edges50/train/00000"), data.join("cars04_edges50/val/00000"));
    let swap = dir.join("swap");
    std::fs::rename(&a, &swap).unwrap();
    std::fs::rename(&b, &a).unwrap();
    std::fs::rename(&swap, &b).unwrap();
    let says =
        "cars04_edges50/train/00000/scenario.json: `split` is \"val\", but it lies at cars04_edges50/train/00000";
    let out = dir.join("nri");
    for args in [
        vec!["export", "nri", s(&data), "--out", s(&out), "-q"],
        vec!["stats", s(&data)],
        vec!["baseline", s(&data)],
        vec!["heatmap", s(&data), "--out", s(&dir.join("h.png"))],
    ] {
        let output = run(&args);
        // A damaged dataset is bad input (readers exited 1), with the way to every problem.
        assert_eq!(output.status.code(), Some(2), "{args:?}: {}", stderr(&output));
        assert!(stderr(&output).contains(says), "{args:?}: {}", stderr(&output));
        assert!(stderr(&output).contains("is damaged: `causalcity validate"), "{args:?}: {}", stderr(&output));
    }
    assert!(!dir.join("h.png").exists());
    let report = run(&["validate", s(&data)]);
    assert_eq!(report.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&report.stdout).contains("`split` is \"val\" here"));
}

#[test]
fn a_pipe_in_place_of_a_frame_is_named_by_export_nsdr_and_preview() {
    // export nsdr and preview opened a frame PNG whatever it was: a pipe
    // there hung them (preview left its .partial behind). Run with a time
    // limit, so that a regression fails rather than hangs.
    let dir = fresh_dir("edited-frame-pipe");
    let text = city_spec("framepipe", &[(4, 0.5)], (1, 0, 1), 6, "{}").replacen(
        "\"world\"",
        "\"image\": {\"width\": 128, \"height\": 80}, \"world\"",
        1,
    );
    let spec = write_spec(&dir, &text);
    let data = dir.join("data");
    gen_ok(&spec, &data, &["--quiet"]);
    let scenario = data.join("cars04_edges50/train/00000");
    let mut checked = 0;
    for frame in ["mask/0000.png", "rgb/0000.png"] {
        let copy = dir.join(frame.replace('/', "-"));
        assert!(std::process::Command::new("cp").args(["-r", s(&data), s(&copy)]).status().unwrap().success());
        let planted = copy.join("cars04_edges50/train/00000").join(frame);
        std::fs::remove_file(&planted).unwrap();
        assert!(std::process::Command::new("mkfifo").arg(&planted).status().unwrap().success());
        let says = format!("{}: not a regular file (a pipe or a device)", planted.display());
        let gif = dir.join(format!("{}.gif", frame.replace('/', "-")));
        let scenario_copy = copy.join("cars04_edges50/train/00000");
        let output = run_within(&["preview", s(&scenario_copy), "--out", s(&gif), "--masks"], 60);
        assert!(!output.status.success() && stderr(&output).contains(&says), "preview: {}", stderr(&output));
        assert!(!gif.exists() && !dir.join(format!("{}.partial", gif.display())).exists());
        if frame.starts_with("mask") {
            let out = dir.join("nsdr");
            let output = run_within(&["export", "nsdr", s(&copy), "--out", s(&out), "-q"], 60);
            assert!(!output.status.success() && stderr(&output).contains(&says), "nsdr: {}", stderr(&output));
        }
        checked += 1;
    }
    assert_eq!(checked, 2);
    assert!(scenario.join("rgb/0000.png").is_file());
}

#[test]
fn evaluate_scores_nothing_against_a_file_that_changed_after_it_was_written() {
    // An edited graph in scenario.json was scored as written, exit 0
    // (AUROC 0.364 became 1.000): only validate named it.
    let dir = fresh_dir("edited-evaluate-checksums");
    let spec = write_spec(&dir, &toy_spec("scored", &[(4, 0.5)], (1, 1, 2), 30));
    let data = dir.join("data");
    gen_ok(&spec, &data, &["--quiet", "--no-images"]);
    let pred = dir.join("pred.npz");
    let mut arrays = Vec::new();
    for folder in ["val/00000", "test/00000", "test/00001"] {
        let edges: Vec<f64> = (0..16).map(|i| (i % 7) as f64 / 7.0).collect();
        arrays.push((format!("cars04_edges50/{folder}"), npy(&[4, 4], &edges)));
        let path: Vec<f64> = (0..10 * 4 * 2).map(|i| 300.0 + i as f64).collect();
        arrays.push((format!("cars04_edges50/{folder}/trajectory"), npy(&[10, 4, 2], &path)));
    }
    let named: Vec<(&str, Vec<u8>)> = arrays.iter().map(|(n, b)| (n.as_str(), b.clone())).collect();
    npz(&pred, &named);
    let scored = run(&["evaluate", s(&data), s(&pred), "--history", "20"]);
    assert!(scored.status.success(), "{}", stderr(&scored));
    let table = String::from_utf8_lossy(&scored.stdout).into_owned();
    assert!(table.contains("cars04_edges50") && table.contains("test"), "{table}");

    let scenario = "cars04_edges50/test/00001";
    type Edit = Box<dyn Fn(String) -> String>;
    let cases: Vec<(&str, &str, Edit)> = vec![
        // Another graph, valid JSON and pairs: what a hand edit looks like.
        ("graph", "scenario.json", Box::new(|t: String| t.replacen("\"edges\": [", "\"edges\": [[0, 3], ", 1))),
        // One pose moved by a metre: the trajectory error's truth.
        (
            "pose",
            "poses.csv",
            Box::new(|t: String| {
                let x: f64 = t.lines().nth(1).unwrap().split(',').nth(3).unwrap().parse().unwrap();
                pose_set(t, 0, 3, &format!("{}", x + 1.0))
            }),
        ),
    ];
    let mut checked = 0;
    for (name, file, edit) in &cases {
        let copy = dir.join(name);
        assert!(std::process::Command::new("cp").args(["-r", s(&data), s(&copy)]).status().unwrap().success());
        let path = copy.join(scenario).join(file);
        let text = std::fs::read_to_string(&path).unwrap();
        let changed = edit(text.clone());
        assert_ne!(changed, text, "{name}: the edit changed nothing");
        std::fs::write(&path, changed).unwrap();
        let output = run(&["evaluate", s(&copy), s(&pred), "--history", "20"]);
        assert_error(&output, 2, &format!("{scenario}/{file}: its checksum does not match checksums.sha256"));
        assert_error(&output, 2, &format!("causalcity validate {}", copy.display()));
        assert!(output.stdout.is_empty(), "{name}: nothing is scored: {}", String::from_utf8_lossy(&output.stdout));
        // The same dataset repaired by rerunning gen scores as before.
        gen_ok(&spec, &copy, &["--quiet", "--no-images"]);
        let again = run(&["evaluate", s(&copy), s(&pred), "--history", "20"]);
        assert!(again.status.success(), "{name}: {}", stderr(&again));
        assert_eq!(String::from_utf8_lossy(&again.stdout).replace(s(&copy), s(&data)), table, "{name}");
        checked += 1;
    }
    assert_eq!(checked, cases.len());
}

#[test]
fn readers_refuse_a_linked_scenario_split_or_group_folder_as_validate_names_it() {
    // evaluate, stats, export and baseline read through a linked folder
    // (exit 0) while validate named it: a dataset's scenarios are read from
    // its own folders. A link to a good copy, so that nothing else differs.
    let dir = fresh_dir("edited-linked-readers");
    let spec = write_spec(&dir, &toy_spec("linked", &[(4, 0.5)], (1, 1, 2), 30));
    let data = dir.join("data");
    gen_ok(&spec, &data, &["--quiet", "--no-images"]);
    let pred = dir.join("pred.npz");
    let edges: Vec<f64> = (0..16).map(|i| (i % 7) as f64 / 7.0).collect();
    let arrays: Vec<(String, Vec<u8>)> = ["val/00000", "test/00000", "test/00001"]
        .iter()
        .map(|folder| (format!("cars04_edges50/{folder}"), npy(&[4, 4], &edges)))
        .collect();
    npz(&pred, &arrays.iter().map(|(n, b)| (n.as_str(), b.clone())).collect::<Vec<_>>());
    let readers = |data: &Path, out: &Path| -> Vec<(&'static str, Output)> {
        vec![
            ("evaluate", run(&["evaluate", s(data), s(&pred)])),
            ("stats", run(&["stats", s(data)])),
            ("baseline", run(&["baseline", s(data)])),
            ("export", run(&["export", "nri", s(data), "--out", s(out), "--quiet"])),
        ]
    };
    // As written, every reader reads it.
    for (name, output) in readers(&data, &dir.join("nri")) {
        assert!(output.status.success(), "{name}: {}", stderr(&output));
    }
    let mut refused = 0;
    for (level, linked) in
        [("scenario", "cars04_edges50/test/00001"), ("split", "cars04_edges50/test"), ("group", "cars04_edges50")]
    {
        let copy = dir.join(format!("linked-{level}"));
        assert!(std::process::Command::new("cp").args(["-r", s(&data), s(&copy)]).status().unwrap().success());
        std::fs::remove_dir_all(copy.join(linked)).unwrap();
        std::os::unix::fs::symlink(data.join(linked), copy.join(linked)).unwrap();
        let checked = run(&["validate", s(&copy)]);
        assert_eq!(checked.status.code(), Some(1), "{level}: {}", String::from_utf8_lossy(&checked.stdout));
        let out = dir.join(format!("nri-{level}"));
        for (name, output) in readers(&copy, &out) {
            let says = format!("{}: a symbolic link (to {})", copy.join(linked).display(), data.join(linked).display());
            assert_error(&output, 2, &says);
            assert!(stderr(&output).contains("never through a link"), "{name}: {}", stderr(&output));
            refused += 1;
        }
        assert!(!out.exists(), "{level}: export wrote {}", out.display());
    }
    assert_eq!(refused, 12);
}
