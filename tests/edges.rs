//! The last input and integrity edges: what validate, merge, run, stats,
//! preview, baseline and gen do with damaged datasets, refused merges,
//! hostile file names, closed pipes and out-of-range flags. Every test runs
//! the real binary and looks at exit codes, messages and files on disk.

mod common;

use common::*;
use std::path::Path;
use std::process::{Command, Stdio};

fn text(output: &std::process::Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&output.stdout), String::from_utf8_lossy(&output.stderr))
}

/// A small toy dataset without images in `dir/out`.
fn small_dataset(dir: &Path, splits: (u32, u32, u32)) -> std::path::PathBuf {
    let spec = write_spec(dir, &toy_spec("edges", &[(4, 0.5)], splits, 20));
    let out = dir.join("out");
    gen_ok(&spec, &out, &["--quiet", "--no-images"]);
    out
}

#[test]
fn validate_names_stray_and_unknown_entries_at_every_level() {
    let dir = fresh_dir("edges-validate");
    let out = small_dataset(&dir, (2, 0, 0));
    let clean = run(&["validate", out.to_str().unwrap()]);
    assert!(clean.status.success(), "a fresh dataset validates: {}", text(&clean));

    let scenario = out.join("cars04_edges50/train/00000");
    let strays =
        [out.join("notes.txt"), out.join("cars04_edges50/README"), out.join("cars99_edges10"), scenario.join("extra")];
    std::fs::write(&strays[0], "stray").unwrap();
    std::fs::write(&strays[1], "stray").unwrap();
    std::fs::create_dir_all(&strays[2]).unwrap();
    std::fs::create_dir_all(&strays[3]).unwrap();
    let output = run(&["validate", out.to_str().unwrap()]);
    assert_eq!(output.status.code(), Some(1), "damage fails validation: {}", text(&output));
    let report = text(&output);
    for stray in &strays {
        assert!(report.contains(stray.to_str().unwrap()), "{} is not named in:\n{report}", stray.display());
    }
    assert!(report.contains("unexpected folder"), "{report}");
}

#[test]
fn a_refused_merge_moves_nothing() {
    let dir = fresh_dir("edges-merge");
    let spec = write_spec(&dir, &toy_spec("merge", &[(4, 0.5)], (4, 0, 0), 20));
    let shards: Vec<_> = (0..2).map(|k| dir.join(format!("shard{k}"))).collect();
    for (k, shard) in shards.iter().enumerate() {
        gen_ok(&spec, shard, &["--quiet", "--no-images", "--shard", &format!("{k}/2")]);
    }
    // Shard 1 loses a scenario: the merge must be refused before anything moves.
    std::fs::remove_dir_all(shards[1].join("cars04_edges50/train/00001")).unwrap();
    let before: Vec<_> = shards.iter().map(|s| hash_tree(s)).collect();
    let merged = dir.join("merged");
    let output =
        run(&["merge", "--out", merged.to_str().unwrap(), shards[0].to_str().unwrap(), shards[1].to_str().unwrap()]);
    assert_ne!(output.status.code(), Some(0), "a merge with a missing scenario is refused");
    assert!(text(&output).contains("cars04_edges50/train/00001"), "names the missing scenario: {}", text(&output));
    for (shard, hashes) in shards.iter().zip(&before) {
        assert_eq!(&hash_tree(shard), hashes, "{} changed although the merge was refused", shard.display());
    }
    assert!(!merged.exists(), "a refused merge created its --out");
}

#[test]
fn run_without_out_stays_inside_data() {
    let dir = fresh_dir("edges-run-out");
    let example = std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/examples/original.json")).unwrap();
    // "...json" has the stem "..": the default folder must not become data/..
    std::fs::write(dir.join("...json"), example).unwrap();
    let output =
        Command::new(bin()).args(["run", "--no-images", "--scenario", "./...json"]).current_dir(&dir).output().unwrap();
    assert!(output.status.success(), "{}", text(&output));
    let mut written: Vec<String> =
        std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    written.sort();
    assert_eq!(written, ["...json", "data"], "run wrote outside data/");
    let inside: Vec<_> = std::fs::read_dir(dir.join("data")).unwrap().map(|e| e.unwrap().path()).collect();
    assert_eq!(inside.len(), 1, "{inside:?}");
    assert!(inside[0]
        .join(read_json(&dir.join("...json"))[0]["Name"].as_str().unwrap())
        .join("scenario.json")
        .is_file());
}

#[test]
fn stats_columns_stopped_and_lights_measure_different_things() {
    let dir = fresh_dir("edges-stats");
    let spec = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/ci-city.json")).unwrap();
    let spec_path = write_spec(&dir, &spec.replace("\"ci-city\"", "\"stats\""));
    let out = dir.join("out");
    gen_ok(&spec_path, &out, &["--quiet", "--no-images"]);
    let output = run(&["stats", "--json", out.to_str().unwrap()]);
    assert!(output.status.success(), "{}", text(&output));
    let stats: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    let rows = stats["rows"].as_array().unwrap();
    assert!(!rows.is_empty());
    let mut differ = 0;
    for row in rows {
        let (stopped, lights) = (row["stopped_share"].as_f64().unwrap(), row["light_stop_share"].as_f64().unwrap());
        assert!(lights <= stopped, "cars stopped at a light are cars that stopped: {row}");
        differ += (lights < stopped) as usize;
    }
    assert!(differ > 0, "stopped and lights are identical in all {} rows", rows.len());
}

#[test]
fn a_closed_pipe_ends_quietly() {
    let dir = fresh_dir("edges-pipe");
    let out = small_dataset(&dir, (2, 1, 1));
    let mut child = Command::new(bin())
        .args(["stats", out.to_str().unwrap()])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Close the reading end before the table is printed (as `| head -0` would).
    drop(child.stdout.take());
    let output = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_eq!(output.status.code(), Some(0), "{stderr}");
}

#[test]
fn out_of_range_flags_exit_2_naming_the_flag() {
    let dir = fresh_dir("edges-flags");
    let out = small_dataset(&dir, (1, 0, 0));
    let scenario = out.join("cars04_edges50/train/00000");
    let spec = dir.join("spec.json");
    let cases: [(&[&str], &str); 9] = [
        (&["preview", scenario.to_str().unwrap(), "--out", "x.gif", "--scale", "0"], "--scale"),
        (&["preview", scenario.to_str().unwrap(), "--out", "x.gif", "--fps", "0"], "--fps"),
        (&["preview", scenario.to_str().unwrap(), "--out", "x.gif", "--fps", "200"], "--fps"),
        // Beyond what a GIF's delay in whole hundredths of a second gives
        // (it was clamped to 0.5-50 without a word).
        (&["preview", scenario.to_str().unwrap(), "--out", "x.gif", "--fps", "75"], "from 0.5 to 50"),
        (&["preview", scenario.to_str().unwrap(), "--out", "x.gif", "--fps", "0.1"], "from 0.5 to 50"),
        (&["preview", scenario.to_str().unwrap(), "--out", "x.bmp"], "--out"),
        (&["baseline", out.to_str().unwrap(), "--max-lag", "NaN"], "--max-lag"),
        (&["gen", "--spec", spec.to_str().unwrap(), "--limit", "-1"], "--limit"),
        (&["gen", "--spec", spec.to_str().unwrap(), "--shard", "3/2"], "--shard"),
    ];
    for (args, flag) in cases {
        let output = run(args);
        assert_eq!(output.status.code(), Some(2), "{args:?}: {}", text(&output));
        assert!(
            String::from_utf8_lossy(&output.stderr).contains(flag),
            "{args:?} does not name {flag}: {}",
            text(&output)
        );
    }
    assert!(!dir.join("x.gif").exists() && !Path::new("x.gif").exists(), "a refused preview wrote a file");
}

#[test]
fn gen_json_reports_seconds_per_stage() {
    let dir = fresh_dir("edges-stages");
    let spec = write_spec(&dir, &toy_spec("stages", &[(4, 0.5)], (2, 0, 0), 10));
    let output = gen_ok(&spec, &dir.join("out"), &["--quiet", "--json"]);
    let summary: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    let stages = &summary["stage_seconds"];
    let elapsed = summary["elapsed"].as_f64().unwrap();
    for stage in ["plan", "simulate", "render", "encode", "write", "checksum"] {
        let s = stages[stage].as_f64().unwrap_or_else(|| panic!("no {stage} in {stages}"));
        assert!(s >= 0.0, "{stage}: {s}");
    }
    // With images on one thread, drawing and encoding take real time, and
    // the stages never add up to more than the run (one thread).
    for stage in ["render", "encode", "write"] {
        assert!(stages[stage].as_f64().unwrap() > 0.0, "{stage} took no time: {stages}");
    }
    let total: f64 =
        ["plan", "simulate", "render", "encode", "write", "checksum"].iter().map(|s| stages[s].as_f64().unwrap()).sum();
    let threads = summary["threads"].as_f64().unwrap();
    assert!(total <= elapsed * threads + 1e-3, "stages {total} s exceed {threads} threads x {elapsed} s");
}

#[test]
fn a_contact_sheet_too_large_to_hold_is_refused_before_it_is_drawn() {
    // Twelve 4096 x 2048 frames side by side at full scale: 49,200 x 2,056
    // pixels (a sheet of ten 8192 px frames panicked for want of memory).
    let dir = fresh_dir("edges-sheet");
    let spec = toy_spec("sheet", &[(4, 0.5)], (1, 0, 0), 12).replacen(
        "\"frames\"",
        "\"image\": {\"width\": 4096, \"height\": 2048}, \"leader_gap_px\": 200, \"frames\"",
        1,
    );
    let spec = write_spec(&dir, &spec);
    let out = dir.join("out");
    gen_ok(&spec, &out, &["--quiet", "--no-effects"]);
    let scenario = out.join("cars04_edges50/train/00000");
    let sheet = dir.join("sheet.png");
    let refused = run(&[
        "preview",
        scenario.to_str().unwrap(),
        "--out",
        sheet.to_str().unwrap(),
        "--scale",
        "1",
        "--sheet-frames",
        "12",
        "--columns",
        "12",
    ]);
    assert_eq!(refused.status.code(), Some(2), "{}", text(&refused));
    assert!(text(&refused).contains("would be 49204x2056 pixels"), "{}", text(&refused));
    assert!(!sheet.exists() && !dir.join("sheet.png.partial").exists());
    // Fewer columns at a smaller scale fit.
    let fits = run(&["preview", scenario.to_str().unwrap(), "--out", sheet.to_str().unwrap(), "--sheet-frames", "12"]);
    assert_eq!(fits.status.code(), Some(0), "{}", text(&fits));
    assert!(sheet.exists());
}

#[test]
fn empty_selections_one_frame_exports_and_missing_scenarios_are_told_as_they_are() {
    let dir = fresh_dir("edges-degenerate");
    // A heat map of a split without scenarios: exit 2, no picture (it drew
    // an empty map and said "0 scenarios", exit 0).
    let no_test = dir.join("no-test");
    gen_ok(&write_spec(&dir, &toy_spec("nt", &[(4, 0.5)], (2, 0, 0), 10)), &no_test, &["--no-images", "-q"]);
    let picture = dir.join("h.png");
    let refused = run(&["heatmap", no_test.to_str().unwrap(), "--out", picture.to_str().unwrap(), "--split", "test"]);
    assert_eq!(refused.status.code(), Some(2), "{}", text(&refused));
    assert!(text(&refused).contains("no scenarios in split test"), "{}", text(&refused));
    assert!(!picture.exists());
    // The baseline without test scenarios scored nothing, exit 0.
    let refused = run(&["baseline", no_test.to_str().unwrap()]);
    assert_eq!(refused.status.code(), Some(2), "{}", text(&refused));
    assert!(
        text(&refused).contains("it has no test scenarios, and the baseline scores its test"),
        "{}",
        text(&refused)
    );
    // NRI arrays of 1-frame scenarios: every velocity was 0 without a word.
    let one = dir.join("one-frame");
    gen_ok(&write_spec(&dir, &toy_spec("one", &[(4, 0.5)], (2, 1, 1), 1)), &one, &["--no-images", "-q"]);
    let nri = dir.join("nri");
    let refused = run(&["export", "nri", one.to_str().unwrap(), "--out", nri.to_str().unwrap()]);
    assert_eq!(refused.status.code(), Some(2), "{}", text(&refused));
    assert!(text(&refused).contains("2 frames or more"), "{}", text(&refused));
    assert!(!nri.exists());
    // validate counts the scenarios it checked, not those it expected.
    std::fs::remove_dir_all(no_test.join("cars04_edges50/train/00001")).unwrap();
    let checked = run(&["validate", no_test.to_str().unwrap()]);
    assert_eq!(checked.status.code(), Some(1), "{}", text(&checked));
    assert!(text(&checked).contains("1 of 2 scenarios checked"), "{}", text(&checked));
}
