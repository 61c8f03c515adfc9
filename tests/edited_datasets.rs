//! Readers given a dataset whose files were edited by hand, or asked for
//! more than a scenario holds: a clear error naming the file and what is
//! wrong, never a panic (exit 101) or an allocation that aborts (134).

mod common;

use common::{city_spec, fresh_dir, gen_ok, read_json, run, run_within, write_spec};
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
        assert_error(&run(&[command, s(&bad_edge)]), 1, "edges must name them");
    }
    let no_interval = edited(&data, &dir.join("interval"), false, |v| v["frame_interval"] = 0.into());
    assert_error(&run(&["baseline", s(&no_interval)]), 1, "frame_interval 0");
    // Claims a billion frames: refused before memory is set aside for them.
    let billion = edited(&data, &dir.join("billion"), false, |v| v["frames"] = 1_000_000_000u64.into());
    for command in ["stats", "baseline"] {
        assert_error(&run(&[command, s(&billion)]), 1, "frames 1000000000");
    }
    let scenario = billion.join("cars04_edges50/train/00000");
    assert_error(&run(&["preview", s(&scenario), "--out", s(&dir.join("p.gif"))]), 1, "frames 1000000000");
    // Claims the most a spec allows, far more than its poses.csv holds.
    let most = edited(&data, &dir.join("most"), false, |v| v["frames"] = 100_000.into());
    assert_error(&run(&["baseline", s(&most)]), 1, "more rows than");
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
    assert_error(&run_within(&["stats", s(&linked_file)], 30), 1, "scenario.json: not a regular file");
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
    for (copy, says) in [(&emptied, "poses.csv (0 bytes) can hold"), (&nan, "poses.csv: row 2 is not a pose")] {
        assert_error(&run(&["stats", s(copy)]), 1, says);
        assert_error(&run(&["heatmap", s(copy), "--out", s(&heat)]), 1, says);
        assert!(!heat.exists(), "no picture of a damaged dataset");
    }
    assert_error(&run(&["stats", s(&no_header)]), 1, "events.csv: columns [], expected frame,t,kind");
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
