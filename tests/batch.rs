//! Batch runs that survive: kills and resumes, interrupts, sharding and
//! merging, the mixing guard, full and read-only disks, and `validate`.

mod common;
use common::*;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn small_spec(dir: &Path) -> PathBuf {
    write_spec(dir, &toy_spec("batch", &[(4, 0.5), (8, 0.5)], (4, 2, 2), 40))
}

fn gen_cmd(spec: &Path, out: &Path, extra: &[&str]) -> Command {
    let mut cmd = Command::new(bin());
    cmd.args(["gen", "--quiet", "--spec"]).arg(spec).arg("--out").arg(out).args(extra);
    cmd
}

fn validate_dir(dir: &Path) -> (i32, String) {
    let out = run(&["validate", dir.to_str().unwrap()]);
    (out.status.code().unwrap(), String::from_utf8_lossy(&out.stdout).into_owned())
}

#[test]
fn killed_runs_resume_to_identical_bytes() {
    let dir = fresh_dir("batch-kill");
    // About 1.5 s of work on two cores, so that kills land mid-run.
    let spec = write_spec(&dir, &toy_spec("kill", &[(4, 0.5), (8, 0.5)], (4, 2, 2), 120));
    let reference = dir.join("reference");
    gen_ok(&spec, &reference, &["--quiet"]);
    let expected = hash_tree(&reference);
    assert!(expected.len() > 16 * 240);

    // Kill at spread-out moments; one folder is killed three times before it completes.
    let delays_ms: [&[u64]; 5] = [&[40], &[150, 90], &[300], &[520, 260, 130], &[800]];
    let mut interrupted = 0;
    for (trial, delays) in delays_ms.iter().enumerate() {
        let out = dir.join(format!("killed-{trial}"));
        for &delay in *delays {
            let mut child = gen_cmd(&spec, &out, &[]).stdout(Stdio::null()).stderr(Stdio::null()).spawn().unwrap();
            std::thread::sleep(Duration::from_millis(delay));
            let _ = child.kill(); // SIGKILL
            child.wait().unwrap();
        }
        // Whatever state the kill left, no partial scenario looks complete.
        let (code, report) = validate_dir(&out);
        assert!(
            code != 0 || hash_tree(&out) == expected,
            "a killed run validated as complete without being so: {report}"
        );
        interrupted += (code != 0) as usize;
        gen_ok(&spec, &out, &["--quiet"]);
        assert_eq!(hash_tree(&out), expected, "trial {trial}: resumed output differs from an uninterrupted run");
    }
    assert!(interrupted >= 4, "only {interrupted} of 5 kills landed mid-run");
}

#[test]
fn ctrl_c_stops_quickly_and_says_how_to_resume() {
    let dir = fresh_dir("batch-sigint");
    let spec = write_spec(&dir, &toy_spec("sigint", &[(12, 0.5)], (60, 0, 0), 150));
    let out = dir.join("out");
    let child = gen_cmd(&spec, &out, &["-j", "2"]).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
    std::thread::sleep(Duration::from_millis(700));
    let sent = Instant::now();
    let status = Command::new("kill").args(["-INT", &child.id().to_string()]).status().unwrap();
    assert!(status.success());
    let output = child.wait_with_output().unwrap();
    let took = sent.elapsed();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(took < Duration::from_secs(2), "took {took:?} to stop");
    assert_eq!(output.status.code(), Some(130), "{stderr}");
    assert!(stderr.contains("Rerun the same command to resume"), "{stderr}");
    let (code, report) = validate_dir(&out);
    assert_eq!(code, 1, "an interrupted dataset must not validate: {report}");
    assert!(report.contains("did not finish"), "{report}");
    gen_ok(&spec, &out, &["--quiet"]);
    let (code, report) = validate_dir(&out);
    assert_eq!(code, 0, "{report}");
}

#[test]
fn ctrl_c_stops_inside_one_long_poses_only_scenario() {
    // One poses-only scenario of 100,000 frames and 80 cars: 28 s of
    // simulating and writing (958 MB). Before, Ctrl-C was looked at only
    // between scenarios, so the run finished it and exited 0; now every
    // frame of the simulation checks, and nothing half-done is kept.
    let dir = fresh_dir("batch-sigint-long");
    let spec = write_spec(&dir, &city_spec("long", &[(80, 0.5)], (1, 0, 0), 100_000, "{}"));
    let out = dir.join("out");
    let child = gen_cmd(&spec, &out, &["--no-images", "--no-effects"]).stderr(Stdio::piped()).spawn().unwrap();
    let deadline = Instant::now() + Duration::from_secs(60);
    while !out.join("manifest.json").exists() {
        assert!(Instant::now() < deadline, "the run never started");
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(300));
    assert!(Command::new("kill").args(["-INT", &child.id().to_string()]).status().unwrap().success());
    let output = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(130), "the scenario ran to its end: {stderr}");
    assert!(stderr.contains("0 of 1 scenarios are complete"), "{stderr}");
    assert!(!out.join("cars80_edges50/train/00000").exists());
    let (code, report) = validate_dir(&out);
    assert_eq!(code, 1, "{report}");
    assert!(report.contains("did not finish"), "{report}");
}

#[test]
fn a_run_larger_than_the_disk_is_refused_with_the_figures_and_nothing_written() {
    // 60 million scenarios of about 40 kB each: terabytes, more than any
    // disk this runs on has free.
    let dir = fresh_dir("batch-space");
    let spec = write_spec(&dir, &toy_spec("huge", &[(4, 0.5), (8, 0.5)], (10_000_000, 10_000_000, 10_000_000), 20));
    let out = dir.join("out");
    let output = gen_cmd(&spec, &out, &["--no-images", "--no-effects"]).output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("60000000 scenarios") && stderr.contains("free"), "{stderr}");
    assert!(stderr.contains("--force-space") && stderr.contains("--limit"), "{stderr}");
    // The figures add up: the total is the scenarios times one's size, and
    // the margin kept besides is said, not hidden in the total.
    let figure = |after: &str, unit: &str| -> f64 {
        let rest = &stderr[stderr.find(after).unwrap_or_else(|| panic!("{after:?} in {stderr}")) + after.len()..];
        rest[..rest.find(unit).unwrap()].trim().parse().unwrap()
    };
    let total_gb = figure("would write about ", "GB");
    let each_kb = figure("scenarios of about ", "kB");
    assert!((60e6 * each_kb / 1e6 - total_gb).abs() / total_gb < 0.01, "{total_gb} GB vs {each_kb} kB each: {stderr}");
    assert!(stderr.contains("it keeps 67.1 MB free besides"), "{stderr}");
    assert!(!out.exists(), "a refused run left {} behind", out.display());

    // Into a dataset that exists, the sample goes again and the rest stays.
    let small = dir.join("small");
    gen_ok(&spec, &small, &["--quiet", "--no-images", "--no-effects", "--limit", "1"]);
    let before = hash_tree(&small);
    let output = gen_cmd(&spec, &small, &["--no-images", "--no-effects", "--limit", "9000000"]).output().unwrap();
    assert_eq!(output.status.code(), Some(2), "{}", String::from_utf8_lossy(&output.stderr));
    assert_eq!(hash_tree(&small), before, "a refused run changed the dataset");
}

#[test]
fn a_spec_at_the_largest_split_sizes_starts_at_once_in_little_memory_and_stops() {
    // 10,000,000 per split (the documented maximum) in two groups: 60
    // million scenarios. Before, gen listed every key first (6 GB after
    // 10 s, then an abort) and Ctrl-C did not stop it; now keys are
    // computed from their position as the run reaches them.
    let dir = fresh_dir("batch-largest");
    let spec = write_spec(&dir, &toy_spec("largest", &[(4, 0.5), (8, 0.5)], (10_000_000, 10_000_000, 10_000_000), 20));
    let out = dir.join("out");
    let child = gen_cmd(&spec, &out, &["--no-images", "--no-effects", "-j", "2", "--force-space"])
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let first = out.join("cars04_edges50/train/00000");
    let deadline = Instant::now() + Duration::from_secs(60);
    while !first.exists() {
        assert!(Instant::now() < deadline, "no scenario was written: the run never got going");
        std::thread::sleep(Duration::from_millis(20));
    }
    let status = std::fs::read_to_string(format!("/proc/{}/status", child.id())).unwrap_or_default();
    let peak_kb: u64 = status
        .lines()
        .find(|l| l.starts_with("VmHWM:"))
        .and_then(|l| l.split_whitespace().nth(1)?.parse().ok())
        .unwrap_or(0);
    assert!(Command::new("kill").args(["-INT", &child.id().to_string()]).status().unwrap().success());
    let output = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(130), "{stderr}");
    assert!(stderr.contains("of 60000000 scenarios are complete"), "{stderr}");
    if cfg!(target_os = "linux") {
        // 60 million keys would take gigabytes; the run itself needs a few megabytes.
        assert!(peak_kb > 0 && peak_kb < 200_000, "peak memory {peak_kb} kB");
    }
}

#[test]
fn three_shards_merged_equal_one_run() {
    let dir = fresh_dir("batch-shards");
    let spec = small_spec(&dir);
    let whole = dir.join("whole");
    gen_ok(&spec, &whole, &["--quiet", "-j", "2"]);
    let expected = hash_tree(&whole);

    // Shards in folders of their own, merged into a new one.
    let mut shard_dirs = Vec::new();
    for k in 0..3 {
        let out = dir.join(format!("shard{k}"));
        let output = gen_ok(&spec, &out, &["--shard", &format!("{k}/3"), "--json", "-j", "1"]);
        let summary: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
        assert_eq!(summary["shard"], format!("{k}/3"));
        assert!(summary["written"].as_u64().unwrap() >= 5, "shards are balanced: {summary}");
        shard_dirs.push(out.to_str().unwrap().to_string());
    }
    let merged = dir.join("merged");
    let mut args = vec!["merge", "--out", merged.to_str().unwrap()];
    args.extend(shard_dirs.iter().map(String::as_str));
    // A file of the user's in a shard: said of the shard (it was told "Use
    // another --out", though the shard is an input).
    let notes = Path::new(&shard_dirs[0]).join("notes.txt");
    std::fs::write(&notes, "mine").unwrap();
    let output = run(&args);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("(a shard to merge) holds") && stderr.contains("notes.txt"), "{stderr}");
    assert!(stderr.contains("Move the rest out of it") && !stderr.contains("another --out"), "{stderr}");
    std::fs::remove_file(&notes).unwrap();
    let output = run(&args);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    assert_eq!(hash_tree(&merged), expected, "merged shards differ from one run");
    // Nothing is left of the shards (before: empty group and split folders).
    for shard in &shard_dirs {
        assert!(!Path::new(shard).exists(), "merge left {shard} behind: {:?}", hash_tree(Path::new(shard)));
    }

    // Shards written into one shared folder, merged in place.
    let shared = dir.join("shared");
    for k in [2, 0, 1] {
        gen_ok(&spec, &shared, &["--quiet", "--shard", &format!("{k}/3")]);
    }
    let premature = run(&["validate", shared.to_str().unwrap()]);
    assert_ne!(premature.status.code(), Some(0), "shards without a merge are not a dataset yet");
    // Said as shards to merge (it said "not a causalcity dataset").
    let said = String::from_utf8_lossy(&premature.stderr);
    assert!(said.contains("holds the shards of a gen job (shards/0-of-3.json, shards/1-of-3.json"), "{said}");
    assert!(said.contains(&format!("causalcity merge --out {}", shared.display())), "{said}");
    let output = run(&["merge", "--out", shared.to_str().unwrap()]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    assert_eq!(hash_tree(&shared), expected);

    // A missing shard is named.
    let partial = dir.join("partial");
    gen_ok(&spec, &partial, &["--quiet", "--shard", "0/3"]);
    let output = run(&["merge", "--out", partial.to_str().unwrap()]);
    assert_eq!(output.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&output.stderr).contains("shards 1, 2 of 3 are missing"));

    // A shard finished by a whole run: the dataset one run writes, without
    // the shard's manifest (left behind, merge took it for a job to finish,
    // and validate ignored it).
    gen_ok(&spec, &partial, &["--quiet"]);
    assert!(!partial.join("shards").exists(), "the shard manifest outlived the whole run");
    assert_eq!(hash_tree(&partial), expected);
    let (code, text) = validate_dir(&partial);
    assert_eq!(code, 0, "{text}");
}

#[test]
fn a_merge_cut_off_as_it_removes_the_shard_manifests_and_folders_is_finished_by_running_it_again() {
    // Cut off after it wrote the complete manifest, a merge left shard
    // manifests, empty group folders and a lock file; run again it was
    // refused ("holds group folders but no manifest.json", "is not a
    // folder") and they stayed.
    let dir = fresh_dir("batch-merge-cut-off");
    let spec = small_spec(&dir);
    let whole = dir.join("whole");
    gen_ok(&spec, &whole, &["--quiet", "-j", "2"]);
    let expected = hash_tree(&whole);
    let shards: Vec<PathBuf> = (0..3).map(|k| dir.join(format!("shard{k}"))).collect();
    let mut manifests = Vec::new();
    for (k, shard) in shards.iter().enumerate() {
        gen_ok(&spec, shard, &["--quiet", "--shard", &format!("{k}/3")]);
        let name = format!("{k}-of-3.json");
        manifests.push((name.clone(), std::fs::read(shard.join("shards").join(&name)).unwrap()));
    }
    let merged = dir.join("merged");
    let mut args = vec!["merge".to_string(), "--out".into(), merged.display().to_string()];
    args.extend(shards.iter().map(|s| s.display().to_string()));
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    assert!(run(&args).status.success());
    // What a cut off merge leaves, from the shard manifests' removal on:
    // shard 0 emptied but for its group and split folders and its lock,
    // shard 1 still holding its manifest, shard 2 gone, and --out one
    // copy of the shard manifests.
    let leave = |with_notes: bool| {
        std::fs::create_dir_all(shards[0].join("cars04_edges50/train")).unwrap();
        std::fs::create_dir_all(shards[0].join("cars08_edges50/test")).unwrap();
        std::fs::write(shards[0].join(".causalcity.lock"), "").unwrap();
        std::fs::create_dir_all(shards[1].join("shards")).unwrap();
        std::fs::create_dir_all(shards[1].join("cars04_edges50/val")).unwrap();
        std::fs::write(shards[1].join("shards").join(&manifests[1].0), &manifests[1].1).unwrap();
        std::fs::create_dir_all(merged.join("shards")).unwrap();
        std::fs::write(merged.join("shards").join(&manifests[2].0), &manifests[2].1).unwrap();
        if with_notes {
            std::fs::write(shards[0].join("cars04_edges50/notes.txt"), "mine").unwrap();
        }
    };
    leave(false);
    let again = run(&args);
    let stdout = String::from_utf8_lossy(&again.stdout);
    assert!(again.status.success(), "{}", String::from_utf8_lossy(&again.stderr));
    assert!(stdout.contains("merged before); finished what the merge cut off left"), "{stdout}");
    for shard in &shards {
        assert!(!shard.exists(), "{} is left: {:?}", shard.display(), hash_tree(shard));
    }
    assert_eq!(hash_tree(&merged), expected, "the finished merge differs from one run");
    // A file of the user's among the leftovers: nothing is removed.
    leave(true);
    let refused = run(&args);
    assert_eq!(refused.status.code(), Some(2), "{}", String::from_utf8_lossy(&refused.stderr));
    assert!(shards[0].join("cars04_edges50/notes.txt").exists());
    assert!(shards[1].join("shards").join(&manifests[1].0).exists());
    assert!(merged.join("shards").join(&manifests[2].0).exists());
    std::fs::remove_file(shards[0].join("cars04_edges50/notes.txt")).unwrap();
    // A shard folder a running command holds: refused before anything goes.
    let held = Command::new("flock")
        .args(["-s", shards[0].join(".causalcity.lock").to_str().unwrap(), "sleep", "30"])
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_millis(300));
    let refused = run(&args);
    let mut held = held;
    let _ = held.kill();
    let _ = held.wait();
    assert_eq!(refused.status.code(), Some(2), "{}", String::from_utf8_lossy(&refused.stderr));
    assert!(
        String::from_utf8_lossy(&refused.stderr).contains("in use"),
        "{}",
        String::from_utf8_lossy(&refused.stderr)
    );
    assert!(shards[0].join("cars04_edges50/train").is_dir() && shards[1].join("shards").join(&manifests[1].0).exists());
    // A network in a shard folder that --out's copy links to is the only
    // copy: never removed as a leftover.
    let network = shards[0].join("networks/town.net.xml");
    std::fs::create_dir_all(network.parent().unwrap()).unwrap();
    std::fs::write(&network, "<net/>").unwrap();
    std::fs::create_dir_all(merged.join("networks")).unwrap();
    std::os::unix::fs::symlink("../../shard0/networks/town.net.xml", merged.join("networks/town.net.xml")).unwrap();
    let _ = run(&args);
    assert_eq!(std::fs::read_to_string(&network).unwrap(), "<net/>");
    // An empty folder inside --out named as a shard is the dataset's own.
    let inside = merged.join("cars04_edges50/spare");
    std::fs::create_dir_all(&inside).unwrap();
    let _ = run(&["merge", "--out", merged.to_str().unwrap(), inside.to_str().unwrap()]);
    assert!(inside.is_dir(), "merge removed a folder of --out's as a shard's leftover");
}

#[test]
fn another_spec_is_refused_unless_forced() {
    let dir = fresh_dir("batch-mixing");
    let spec = small_spec(&dir);
    let out = dir.join("out");
    gen_ok(&spec, &out, &["--quiet", "--no-images"]);
    let other = dir.join("other.json");
    std::fs::write(&other, std::fs::read_to_string(&spec).unwrap().replace("\"seed\": 11", "\"seed\": 12")).unwrap();
    let before = hash_tree(&out);
    let output = gen_cmd(&other, &out, &["--no-images"]).output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("spec.seed: 11 there, 12 now") && stderr.contains("--force"), "{stderr}");
    assert_eq!(hash_tree(&out), before, "a refused run must not touch the folder");
    // Images on or off is part of what a dataset is.
    let output = gen_cmd(&spec, &out, &[]).output().unwrap();
    assert_eq!(output.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&output.stderr).contains("images"));

    let output =
        run(&["gen", "--spec", other.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-images", "--force"]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    // The removal is said and timed (before: silent, up to a minute).
    assert!(stderr.contains("--force: removing the dataset") && stderr.contains("removed it in"), "{stderr}");
    let manifest = read_json(&out.join("manifest.json"));
    assert_eq!(manifest["spec"]["seed"], 12);
    let reference = dir.join("reference");
    gen_ok(&other, &reference, &["--quiet", "--no-images"]);
    assert_eq!(hash_tree(&out), hash_tree(&reference));

    // A file causalcity did not write: no run goes on beside it, forced or
    // not, and it stays.
    std::fs::write(out.join("NOTES.txt"), "mine").unwrap();
    let before = hash_tree(&out);
    for flags in [&["--no-images"][..], &["--no-images", "--force"]] {
        let output = gen_cmd(&spec, &out, flags).output().unwrap();
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{flags:?}: {stderr}");
        assert!(stderr.contains("NOTES.txt"), "{stderr}");
        assert_eq!(hash_tree(&out), before, "{flags:?} touched the folder");
    }
}

/// A spec with images (removing its dataset takes a while) and the same
/// spec with another seed, which `gen --force` replaces it with.
fn spec_and_reseeded(dir: &Path, name: &str) -> (PathBuf, PathBuf) {
    let spec = write_spec(dir, &toy_spec(name, &[(4, 0.5), (8, 0.5)], (6, 3, 3), 60));
    let other = dir.join("other.json");
    std::fs::write(&other, std::fs::read_to_string(&spec).unwrap().replace("\"seed\": 11", "\"seed\": 12")).unwrap();
    (spec, other)
}

/// Waits (at most 30 s) until `path` is gone: a removal has begun.
fn wait_until_gone(path: &Path) {
    let started = Instant::now();
    while path.exists() && started.elapsed() < Duration::from_secs(30) {
        std::thread::sleep(Duration::from_micros(200));
    }
}

#[test]
fn a_force_killed_while_removing_leaves_a_folder_any_rerun_repairs() {
    // gen --force deleted the old scenario folders one file at a time,
    // checksums first: killed part way, it left folders "not written by
    // causalcity" under a manifest still saying complete, and every rerun,
    // forced or not, was refused for good.
    let dir = fresh_dir("batch-force-kill");
    let (spec, other) = spec_and_reseeded(&dir, "forcekill");
    let (reference, other_reference) = (dir.join("reference"), dir.join("other-reference"));
    gen_ok(&spec, &reference, &["--quiet"]);
    gen_ok(&other, &other_reference, &["--quiet"]);
    let expected = [hash_tree(&reference), hash_tree(&other_reference)];
    // A file the removal takes away early, in either order it may go.
    let first_scenario = |out: &Path| out.join("cars04_edges50/train/00000/checksums.sha256");
    for (trial, rerun) in [(0, &spec), (1, &other)] {
        let out = dir.join(format!("killed-{trial}"));
        gen_ok(&spec, &out, &["--quiet"]);
        let mut child =
            gen_cmd(&other, &out, &["--force", "-j", "1"]).stdout(Stdio::null()).stderr(Stdio::null()).spawn().unwrap();
        // Killed as soon as the removal has begun.
        wait_until_gone(&first_scenario(&out));
        let _ = child.kill(); // SIGKILL
        child.wait().unwrap();
        assert!(!first_scenario(&out).exists(), "trial {trial}: the removal never began");
        // Rerun with the old spec (a resume) or the new one (forced again):
        // either completes the folder it asks for, byte for byte.
        let force: &[&str] = if trial == 0 { &["--quiet"] } else { &["--quiet", "--force"] };
        gen_ok(rerun, &out, force);
        assert_eq!(hash_tree(&out), expected[trial], "trial {trial}: the rerun differs from an uninterrupted run");
        let (code, report) = validate_dir(&out);
        assert_eq!(code, 0, "trial {trial}: {report}");
    }
    // A damaged scenario is replaced whole (the old copy moved aside, then
    // deleted), leaving nothing behind.
    let out = dir.join("killed-1");
    let scenario = first_scenario(&out).parent().unwrap().to_path_buf();
    std::fs::remove_file(scenario.join("poses.csv")).unwrap();
    let output = gen_cmd(&other, &out, &[]).output().unwrap();
    assert!(String::from_utf8_lossy(&output.stderr).contains("writing it again"), "{output:?}");
    assert_eq!(hash_tree(&out), expected[1]);
}

#[test]
fn only_what_a_cut_off_removal_left_is_deleted_never_a_users_folder_of_that_name() {
    // A folder of the user's named .causalcity-removing was deleted by
    // any plain gen (review): only group folders and networks/ that a
    // removal moved there are.
    let dir = fresh_dir("batch-removing-name");
    let spec = small_spec(&dir);
    let out = dir.join("out");
    gen_ok(&spec, &out, &["--quiet", "--no-images"]);
    let removing = out.join(".causalcity-removing");
    std::fs::create_dir_all(removing.join("cars04_edges50/train/00000")).unwrap();
    std::fs::write(removing.join("cars04_edges50/train/00000/poses.csv"), "old").unwrap();
    let (code, report) = validate_dir(&out);
    assert_eq!(code, 1, "{report}");
    assert!(report.contains("leftover of an interrupted gen --force"), "{report}");
    // What a removal leaves goes with the next run.
    gen_ok(&spec, &out, &["--quiet", "--no-images"]);
    assert!(!removing.exists(), "the leftover of a cut-off removal stayed");
    // Anything else there is the user's: refused, kept.
    std::fs::create_dir_all(&removing).unwrap();
    std::fs::write(removing.join("notes.txt"), "precious").unwrap();
    let output = gen_cmd(&spec, &out, &["--no-images"]).output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("notes.txt: not what an interrupted gen --force leaves"), "{stderr}");
    assert_eq!(std::fs::read_to_string(removing.join("notes.txt")).unwrap(), "precious");
}

#[test]
fn a_killed_shards_lock_file_goes_when_a_plain_run_finishes_the_job() {
    // It stayed: the finished dataset held an extra file, no longer the
    // bytes of an uninterrupted run.
    let dir = fresh_dir("batch-shard-lock");
    let spec = write_spec(&dir, &toy_spec("shardlock", &[(4, 0.5), (8, 0.5)], (6, 3, 3), 60));
    let reference = dir.join("reference");
    gen_ok(&spec, &reference, &["--quiet", "--no-images"]);
    let out = dir.join("out");
    let lock = out.join(".causalcity-shard-1-of-2.lock");
    let mut child = gen_cmd(&spec, &out, &["--shard", "1/2", "--no-images", "-j", "1"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let started = Instant::now();
    while !lock.exists() && started.elapsed() < Duration::from_secs(30) {
        std::thread::sleep(Duration::from_micros(200));
    }
    let _ = child.kill(); // SIGKILL
    child.wait().unwrap();
    assert!(lock.exists(), "the killed shard left no lock file to test with");
    gen_ok(&spec, &out, &["--quiet", "--no-images"]);
    assert!(!lock.exists(), "the killed shard's lock file outlived the run that finished the job");
    assert!(hash_tree(&out) == hash_tree(&reference), "the finished dataset is not an uninterrupted run's bytes");
    let (code, report) = validate_dir(&out);
    assert_eq!(code, 0, "{report}");
}

#[test]
fn a_sigterm_while_force_removes_finishes_the_removal_and_stops_with_the_resume_hint() {
    // SIGTERM during the removal ended gen at once (exit 143, no word),
    // leaving its lock file and half a removal.
    let dir = fresh_dir("batch-force-term");
    let (spec, other) = spec_and_reseeded(&dir, "forceterm");
    let out = dir.join("out");
    gen_ok(&spec, &out, &["--quiet"]);
    let child =
        gen_cmd(&other, &out, &["--force", "-j", "1"]).stdout(Stdio::null()).stderr(Stdio::piped()).spawn().unwrap();
    wait_until_gone(&out.join("cars04_edges50/train/00000/checksums.sha256"));
    let status = Command::new("kill").args(["-TERM", &child.id().to_string()]).status().unwrap();
    assert!(status.success());
    let output = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(130), "{stderr}");
    assert!(stderr.contains("Rerun the same command to resume"), "{stderr}");
    let names: Vec<String> =
        std::fs::read_dir(&out).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    assert!(!names.iter().any(|n| n.ends_with(".lock") || n.starts_with(".causalcity")), "{names:?}");
    let manifest = read_json(&out.join("manifest.json"));
    assert_eq!(manifest["spec"]["seed"], 12, "the old dataset's manifest outlived the removal");
    gen_ok(&other, &out, &["--quiet"]);
    let (code, report) = validate_dir(&out);
    assert_eq!(code, 0, "{report}");
}

/// A small tmpfs mounted for a test, unmounted when dropped.
struct Tmpfs(PathBuf);

impl Tmpfs {
    fn mount(dir: &Path, size: &str) -> Option<Tmpfs> {
        std::fs::create_dir_all(dir).unwrap();
        let ok = Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={size}"), "tmpfs"])
            .arg(dir)
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success());
        ok.then(|| Tmpfs(dir.to_path_buf()))
    }

    fn remount(&self, options: &str) {
        let status = Command::new("mount").args(["-o", &format!("remount,{options}")]).arg(&self.0).status().unwrap();
        assert!(status.success());
    }
}

impl Drop for Tmpfs {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg(&self.0).status();
    }
}

#[test]
fn a_full_or_read_only_disk_stops_cleanly_and_a_rerun_completes() {
    let dir = fresh_dir("batch-disk");
    let spec = small_spec(&dir);
    let mount = dir.join("disk");
    let Some(disk) = Tmpfs::mount(&mount, "3m") else {
        // No permission to mount here: use a per-file size limit instead (a real EFBIG from the OS).
        let out = dir.join("limited");
        let script = format!(
            "trap '' XFSZ; ulimit -f 16; exec {} gen --quiet --spec {} --out {}",
            bin(),
            spec.display(),
            out.display()
        );
        let output = Command::new("sh").args(["-c", &script]).output().unwrap();
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(1), "{stderr}");
        assert!(stderr.contains("cannot write") && stderr.contains("too large"), "{stderr}");
        gen_ok(&spec, &out, &["--quiet"]);
        assert_eq!(validate_dir(&out).0, 0);
        eprintln!("tmpfs not available: tested the write-failure path with ulimit -f");
        return;
    };
    let out = mount.join("out");
    // The space check sees that the dataset does not fit: exit 2, nothing written.
    let output = gen_cmd(&spec, &out, &["-j", "1"]).output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("free") && stderr.contains("--force-space"), "{stderr}");
    assert!(!out.exists(), "a refused run left {} behind", out.display());
    // Told to write anyway, it stops when the disk is full.
    let output = gen_cmd(&spec, &out, &["-j", "1", "--force-space"]).output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("No space left on device") && stderr.contains(out.to_str().unwrap()), "{stderr}");
    assert!(stderr.contains("rerun the same command to resume"), "{stderr}");
    assert!(!stderr.contains("panicked"));
    // Finished scenarios are intact: every folder present passes its checksums.
    let (_, report) = validate_dir(&out);
    assert!(!report.contains("checksum mismatch") && !report.contains("unexpected file"), "{report}");
    let finished = scenario_dirs(&out).len();
    assert!(finished > 0, "some scenarios fit on the disk");

    // Read-only: a clear message too.
    disk.remount("ro");
    let output = gen_cmd(&spec, &out, &["--force-space"]).output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_ne!(output.status.code(), Some(0));
    assert!(stderr.contains("Read-only file system"), "{stderr}");
    assert_eq!(scenario_dirs(&out).len(), finished, "finished scenarios survive");
    // It counts what is on disk (before: "0 finished scenarios are kept").
    assert!(stderr.contains(&format!("\n{finished} finished scenarios are kept")), "{stderr}");

    // Room again: the same command completes the dataset.
    disk.remount("rw,size=200m");
    gen_ok(&spec, &out, &["--quiet"]);
    let (code, report) = validate_dir(&out);
    assert_eq!(code, 0, "{report}");
    let reference = dir.join("reference");
    gen_ok(&spec, &reference, &["--quiet"]);
    assert_eq!(hash_tree(&out), hash_tree(&reference));
}

#[test]
fn a_disk_that_is_full_from_the_start_leaves_nothing_behind() {
    // Every write fails (a per-file size limit of 0 bytes: a real EFBIG
    // from the OS). Before, manifest.json.partial was left in --out.
    let dir = fresh_dir("batch-full-at-start");
    let spec = small_spec(&dir);
    let out = dir.join("out");
    let script =
        format!("trap '' XFSZ; ulimit -f 0; exec {} gen --spec {} --out {}", bin(), spec.display(), out.display());
    let output = Command::new("sh").args(["-c", &script]).output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("cannot write") && stderr.contains("0 finished scenarios are kept"), "{stderr}");
    let left: Vec<_> =
        std::fs::read_dir(&out).map(|d| d.flatten().map(|e| e.file_name()).collect()).unwrap_or_default();
    assert!(left.is_empty(), "left behind in {}: {left:?}", out.display());
    gen_ok(&spec, &out, &["--quiet"]);
    assert_eq!(validate_dir(&out).0, 0);
}

#[test]
fn validate_catches_each_kind_of_damage() {
    let dir = fresh_dir("batch-validate");
    let spec = write_spec(&dir, &toy_spec("damage", &[(4, 0.5)], (2, 0, 0), 12));
    let clean = dir.join("clean");
    gen_ok(&spec, &clean, &["--quiet"]);
    assert_eq!(validate_dir(&clean).0, 0);
    // The cluster examples' job logs may sit beside the dataset; any other folder may not.
    std::fs::create_dir(clean.join("logs")).unwrap();
    std::fs::write(clean.join("logs/gen-7_0.log"), "progress: 1/3 scenarios\n").unwrap();
    assert_eq!(validate_dir(&clean).0, 0);
    std::fs::create_dir(clean.join("notes")).unwrap();
    let (code, report) = validate_dir(&clean);
    assert!(code != 0 && report.contains("notes: not part of this dataset"), "{report}");
    std::fs::remove_dir(clean.join("notes")).unwrap();
    let scenario = "cars04_edges50/train/00001";

    type Damage = fn(&Path);
    let damages: [(&str, Damage, &str); 6] = [
        ("deleted-frame", |d| std::fs::remove_file(d.join("rgb/0007.png")).unwrap(), "rgb/0007.png: missing"),
        (
            "truncated-png",
            |d| {
                let p = d.join("rgb/0003.png");
                let bytes = std::fs::read(&p).unwrap();
                std::fs::write(&p, &bytes[..bytes.len() / 2]).unwrap();
            },
            "rgb/0003.png: checksum mismatch",
        ),
        (
            "missing-csv-row",
            |d| {
                let p = d.join("poses.csv");
                let text = std::fs::read_to_string(&p).unwrap();
                let mut lines: Vec<&str> = text.lines().collect();
                lines.remove(10);
                std::fs::write(&p, lines.join("\n") + "\n").unwrap();
            },
            "poses.csv: row 11 is malformed or out of order",
        ),
        (
            "flipped-byte",
            |d| {
                let p = d.join("mask/0005.png");
                let mut bytes = std::fs::read(&p).unwrap();
                let k = bytes.len() - 20;
                bytes[k] ^= 0x01;
                std::fs::write(&p, bytes).unwrap();
            },
            "mask/0005.png: checksum mismatch",
        ),
        (
            "extra-car-id",
            |d| {
                let p = d.join("mask/0002.png");
                let mut mask = image::open(&p).unwrap().into_luma8();
                mask.put_pixel(3, 3, image::Luma([9]));
                mask.save(&p).unwrap();
            },
            "mask/0002.png: ids [9] belong to no car",
        ),
        (
            "leftover",
            |d| std::fs::create_dir_all(d.parent().unwrap().join(".partial-00007")).unwrap(),
            ".partial-00007: leftover",
        ),
    ];
    for (name, damage, needle) in damages {
        let copy = dir.join(name);
        let status = Command::new("cp").arg("-r").arg(&clean).arg(&copy).status().unwrap();
        assert!(status.success());
        damage(&copy.join(scenario));
        let (code, report) = validate_dir(&copy);
        assert_eq!(code, 1, "{name}: validate should fail: {report}");
        assert!(report.contains(needle), "{name}: report should contain {needle:?}:\n{report}");
        assert!(report.contains(&copy.join(scenario).display().to_string()) || name == "leftover", "{report}");
    }
    let not_a_dataset = run(&["validate", dir.to_str().unwrap()]);
    assert_eq!(not_a_dataset.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&not_a_dataset.stderr).contains("no manifest.json"));
}

#[test]
fn the_slurm_array_example_builds_the_same_dataset() {
    let dir = fresh_dir("batch-slurm");
    let spec = small_spec(&dir);
    let whole = dir.join("whole");
    gen_ok(&spec, &whole, &["--quiet"]);
    // `causalcity` on PATH, as on a cluster.
    let bin_dir = dir.join("bin");
    std::fs::create_dir_all(&bin_dir).unwrap();
    std::os::unix::fs::symlink(bin(), bin_dir.join("causalcity")).unwrap();
    let path = format!("{}:{}", bin_dir.display(), std::env::var("PATH").unwrap_or_default());
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/slurm/gen.sbatch");
    let shared = dir.join("shared");
    for task in 0..3 {
        let output = Command::new("bash")
            .arg(&script)
            .arg(&spec)
            .arg(&shared)
            .env("PATH", &path)
            .env("SLURM_ARRAY_TASK_ID", task.to_string())
            .env("SLURM_ARRAY_TASK_COUNT", "3")
            .env("SLURM_CPUS_PER_TASK", "1")
            .output()
            .unwrap();
        assert!(output.status.success(), "task {task}: {}", String::from_utf8_lossy(&output.stderr));
    }
    let output = run(&["merge", "--out", shared.to_str().unwrap()]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    assert_eq!(hash_tree(&shared), hash_tree(&whole));
}

/// Replaces `file` in scenario folder `dir` with `text` and re-signs it in
/// checksums.sha256, so that only validate's own reading can catch it.
fn replace_signed(dir: &Path, file: &str, text: &str) {
    use sha2::Digest;
    std::fs::write(dir.join(file), text).unwrap();
    let sums = std::fs::read_to_string(dir.join("checksums.sha256")).unwrap();
    let digest: String = sha2::Sha256::digest(text.as_bytes()).iter().map(|b| format!("{b:02x}")).collect();
    let signed: Vec<String> = sums
        .lines()
        .map(|l| match l.ends_with(&format!("  {file}")) {
            true => format!("{digest}  {file}"),
            false => l.to_string(),
        })
        .collect();
    assert!(signed.iter().any(|l| l.starts_with(&digest)), "{file} is not in checksums.sha256");
    std::fs::write(dir.join("checksums.sha256"), signed.join("\n") + "\n").unwrap();
}

#[test]
fn validate_reads_a_city_scenarios_logs_in_either_light_layout() {
    let dir = fresh_dir("batch-validate-city");
    let spec = write_spec(&dir, &city_spec("damage-city", &[(4, 0.5)], (2, 0, 0), 40, "{}"));
    let scenario = "cars04_edges50/train/00001";
    for lights in ["changes", "frames"] {
        let clean = dir.join(format!("clean-{lights}"));
        gen_ok(&spec, &clean, &["--quiet", "--no-images", "--lights", lights]);
        let (code, report) = validate_dir(&clean);
        assert_eq!(code, 0, "{report}");
        let log = if lights == "changes" { "light_changes.csv" } else { "lights.csv" };
        assert!(clean.join(scenario).join(log).exists());
        type Damage = fn(&Path, &str);
        let damages: [(&str, Damage, &str); 2] = [
            (
                "event-of-no-car",
                |d, _| {
                    let header = "frame,t,kind,car,other_car,light,detail\n";
                    replace_signed(d, "events.csv", &format!("{header}3,1.5,collision,9,0,,\n"));
                },
                "events.csv: row 2 names no car of this scenario",
            ),
            (
                "light-rows-out-of-order",
                |d, log| {
                    let text = std::fs::read_to_string(d.join(log)).unwrap();
                    let mut lines: Vec<&str> = text.lines().collect();
                    let last = lines.len() - 1;
                    lines.swap(1, last);
                    replace_signed(d, log, &(lines.join("\n") + "\n"));
                },
                "",
            ),
        ];
        for (name, damage, needle) in damages {
            let copy = dir.join(format!("{name}-{lights}"));
            assert!(Command::new("cp").arg("-r").arg(&clean).arg(&copy).status().unwrap().success());
            damage(&copy.join(scenario), log);
            let (code, report) = validate_dir(&copy);
            assert_eq!(code, 1, "{name} ({lights}): validate should fail: {report}");
            let needle = if needle.is_empty() { log } else { needle };
            assert!(report.contains(needle), "{name} ({lights}): report should contain {needle:?}:\n{report}");
            assert!(!report.contains("checksum mismatch"), "{report}");
        }
    }
}

#[test]
fn validate_holds_the_city_logs_to_the_values_the_readers_take() {
    // validate checked the events', interactions' and lights.csv's order and
    // cars only: a NaN time, an unknown light, a free car bound by another
    // or a negative time since a light changed validated, and every reader
    // (stats, evaluate, the Python package) then refused the dataset.
    let dir = fresh_dir("batch-validate-log-values");
    let spec = write_spec(&dir, &city_spec("log-values", &[(4, 0.5)], (1, 0, 0), 40, "{}"));
    let scenario = "cars04_edges50/train/00000";
    let events_header = "frame,t,kind,car,other_car,light,detail\n";
    let edit_line = |d: &Path, file: &str, line: usize, from: &str, to: &str| {
        let text = std::fs::read_to_string(d.join(file)).unwrap();
        let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
        assert!(lines[line - 1].contains(from), "{file} line {line}: {}", lines[line - 1]);
        lines[line - 1] = lines[line - 1].replacen(from, to, 1);
        replace_signed(d, file, &(lines.join("\n") + "\n"));
    };
    let mut checked = 0;
    for lights in ["changes", "frames"] {
        let clean = dir.join(format!("clean-{lights}"));
        gen_ok(&spec, &clean, &["--quiet", "--no-images", "--lights", lights]);
        let (code, report) = validate_dir(&clean);
        assert_eq!(code, 0, "{report}");
        type Damage<'a> = (&'a str, Box<dyn Fn(&Path) + 'a>, &'a str);
        let mut damages: Vec<Damage> = vec![
            (
                "event-at-nan-seconds",
                Box::new(|d| replace_signed(d, "events.csv", &format!("{events_header}3,NaN,turn_done,0,,,x\n"))),
                "events.csv: line 2: t NaN is not allowed",
            ),
            (
                "event-at-an-unknown-light",
                Box::new(|d| {
                    replace_signed(d, "events.csv", &format!("{events_header}3,3.0,turn_done,0,,ZZ/N/left,x\n"))
                }),
                "is not one of the light log's lights",
            ),
            (
                "free-car-bound-by-another",
                Box::new(|d| edit_line(d, "interactions.csv", 2, "0,0,free,,", "0,0,free,1,")),
                "interactions.csv: line 2: bound_by free names an other_car",
            ),
            (
                "car-bound-by-itself",
                Box::new(|d| edit_line(d, "interactions.csv", 2, "0,0,free,,", "0,0,car,0,")),
                "car 0 is bound by itself",
            ),
        ];
        if lights == "frames" {
            damages.push((
                "light-changed-minus-a-second-ago",
                Box::new(|d| {
                    let text = std::fs::read_to_string(d.join("lights.csv")).unwrap();
                    let line: Vec<&str> = text.lines().nth(1).unwrap().split(',').collect();
                    let since = line[6];
                    edit_line(d, "lights.csv", 2, &format!(",{since},"), ",-1.0,");
                }),
                "lights.csv: line 2: since_change -1 is not allowed",
            ));
        }
        for (name, damage, needle) in &damages {
            let copy = dir.join(format!("{name}-{lights}"));
            assert!(Command::new("cp").arg("-r").arg(&clean).arg(&copy).status().unwrap().success());
            damage(&copy.join(scenario));
            let (code, report) = validate_dir(&copy);
            assert_eq!(code, 1, "{name} ({lights}): validate should fail: {report}");
            assert!(report.contains(needle), "{name} ({lights}): report should contain {needle:?}:\n{report}");
            assert!(!report.contains("checksum mismatch"), "{report}");
            checked += 1;
        }
    }
    assert_eq!(checked, 9);
}

#[test]
fn validate_while_gen_writes_says_so_not_that_the_dataset_is_damaged() {
    // validate of a folder gen was writing reported "did not finish: rerun
    // its gen command", leftovers and missing scenarios (helper audit).
    let dir = fresh_dir("batch-validate-busy");
    let spec = write_spec(&dir, &toy_spec("busy", &[(8, 0.5)], (20000, 0, 0), 100));
    let out = dir.join("out");
    let mut gen =
        gen_cmd(&spec, &out, &["-j", "1", "--no-images"]).stdout(Stdio::null()).stderr(Stdio::null()).spawn().unwrap();
    let deadline = Instant::now() + Duration::from_secs(60);
    while !out.join("cars08_edges50").exists() && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(20));
    }
    let checked = run(&["validate", out.to_str().unwrap()]);
    let still_running = gen.try_wait().unwrap().is_none();
    let _ = gen.kill();
    let _ = gen.wait();
    assert!(still_running, "gen finished before validate ran: the test checked nothing");
    let text = String::from_utf8_lossy(&checked.stderr);
    assert_eq!(checked.status.code(), Some(2), "{text}");
    assert!(text.contains("is being written now") && text.contains("gen"), "{text}");
    assert!(checked.stdout.is_empty(), "no problems listed: {}", String::from_utf8_lossy(&checked.stdout));
}

#[test]
fn a_forced_shard_never_removes_a_dataset_other_shards_are_writing() {
    // `gen --shard 2/3 --force` of another seed removed the scenarios and
    // manifest of a shard still running (which then failed, saying its
    // finished scenarios were kept), exit 0.
    let dir = fresh_dir("batch-forced-shard");
    let spec = small_spec(&dir);
    let out = dir.join("out");
    gen_ok(&spec, &out, &["--quiet", "--no-images", "--shard", "0/3"]);
    let other = dir.join("other.json");
    std::fs::write(&other, std::fs::read_to_string(&spec).unwrap().replace("\"seed\": 11", "\"seed\": 12")).unwrap();
    let before = hash_tree(&out);
    // Shard 1 of the job at work: it holds the folder's lock shared.
    let running = std::fs::File::open(out.join(".causalcity.lock")).or_else(|_| {
        std::fs::OpenOptions::new().create(true).truncate(false).write(true).open(out.join(".causalcity.lock"))
    });
    let running = running.unwrap();
    running.lock_shared().unwrap();
    let forced =
        |extra: &[&str]| gen_cmd(&other, &out, &[&["--no-images", "--shard", "2/3", "--force"], extra].concat());
    let output = forced(&[]).output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("while another run") && stderr.contains("nothing was removed"), "{stderr}");
    let mut after = hash_tree(&out);
    after.remove(".causalcity.lock");
    let mut expected = before.clone();
    expected.remove(".causalcity.lock");
    assert_eq!(after, expected, "the running job's dataset is untouched");
    // Once the others have stopped, the forced shard replaces it.
    drop(running);
    let output = forced(&[]).output().unwrap();
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    assert_eq!(read_json(&out.join("shards/2-of-3.json"))["spec"]["seed"], 12);
    assert!(!out.join("shards/0-of-3.json").exists(), "the old job's shard is gone with its dataset");
}

#[test]
fn merge_takes_equivalent_limits_and_never_shrinks_a_whole_dataset() {
    // Splits of 4/2/2: a limit of 4 or more is no limit.
    let dir = fresh_dir("batch-merge-limits");
    let spec = small_spec(&dir);
    let whole = dir.join("whole");
    gen_ok(&spec, &whole, &["--quiet", "--no-images"]);
    let expected = hash_tree(&whole);
    // gen lets shards of equivalent limits into one folder; merge refused them.
    let shared = dir.join("shared");
    for (k, limit) in [(0, &["--limit", "100"][..]), (1, &[][..]), (2, &["--limit", "4"][..])] {
        gen_ok(&spec, &shared, &[&["--quiet", "--no-images", "--shard", &format!("{k}/3")], limit].concat());
    }
    let output = run(&["merge", "--out", shared.to_str().unwrap()]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let (code, text) = validate_dir(&shared);
    assert_eq!(code, 0, "{text}");
    let scenarios = |tree: &std::collections::BTreeMap<String, String>| {
        tree.iter().filter(|(k, _)| k.contains('/')).map(|(k, v)| (k.clone(), v.clone())).collect::<Vec<_>>()
    };
    assert_eq!(scenarios(&hash_tree(&shared)), scenarios(&expected), "the scenarios one run writes");
    // Shards of --limit 1 merged into the whole dataset rewrote its manifest
    // with limit 1, leaving most of it unlisted (validate failed), exit 0.
    let mut shards = Vec::new();
    for k in 0..3 {
        let out = dir.join(format!("limited{k}"));
        gen_ok(&spec, &out, &["--quiet", "--no-images", "--limit", "1", "--shard", &format!("{k}/3")]);
        shards.push(out.to_str().unwrap().to_string());
    }
    let mut args = vec!["merge", "--out", whole.to_str().unwrap()];
    args.extend(shards.iter().map(String::as_str));
    let output = run(&args);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("--limit: none there, 1 in the shards") && stderr.contains("nothing was moved"),
        "{stderr}"
    );
    assert_eq!(hash_tree(&whole), expected, "the whole dataset is untouched");
    assert!(shards.iter().all(|s| Path::new(s).join("shards").exists()), "the shards are where they were");
}

#[test]
fn a_shard_retried_after_its_merge_writes_nothing_and_validate_names_a_shard_manifest_left_beside() {
    // A retried shard wrote its manifest back into the merged dataset, which
    // validate called valid and merge then took for a job missing shards.
    let dir = fresh_dir("batch-retried-shard");
    let spec = small_spec(&dir);
    let shared = dir.join("shared");
    for k in 0..3 {
        gen_ok(&spec, &shared, &["--quiet", "--no-images", "--shard", &format!("{k}/3")]);
    }
    assert!(run(&["merge", "--out", shared.to_str().unwrap()]).status.success());
    let merged = hash_tree(&shared);
    // The merge task retried (the k8s example's `merge --out D`): done, exit 0.
    let again = run(&["merge", "--out", shared.to_str().unwrap()]);
    let said = String::from_utf8_lossy(&again.stdout).into_owned() + &String::from_utf8_lossy(&again.stderr);
    assert!(again.status.success() && said.contains("nothing to merge"), "{said}");
    assert_eq!(hash_tree(&shared), merged);
    let output = gen_cmd(&spec, &shared, &["--no-images", "--shard", "1/3"]).output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success() && stderr.contains("shard 1/3 has nothing to do"), "{stderr}");
    assert_eq!(hash_tree(&shared), merged, "the merged dataset is as it was");
    assert_eq!(validate_dir(&shared).0, 0);
    // One left there all the same (copied, or by an older version) is named.
    std::fs::create_dir_all(shared.join("shards")).unwrap();
    std::fs::write(shared.join("shards/0-of-3.json"), "{}").unwrap();
    let out = run(&["validate", shared.to_str().unwrap()]);
    let said = String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{said}");
    assert!(said.contains("shards/0-of-3.json: a shard's manifest beside the whole dataset's"), "{said}");
}

#[test]
fn the_space_check_measures_a_scenario_of_the_most_cars() {
    // It measured the first scenario, of the spec's first group: a job of
    // 4- and 12-car scenarios was estimated at the 4-car size (a 1-car and
    // 88-car spec, 40x low), and a run the disk could not hold started.
    let dir = fresh_dir("batch-space-most-cars");
    let spec = write_spec(&dir, &toy_spec("mixed", &[(4, 0.5), (12, 0.5)], (10_000_000, 0, 0), 20));
    let output = gen_cmd(&spec, &dir.join("out"), &["--no-images", "--no-effects"]).output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    let rest = &stderr[stderr.find("scenarios of about ").expect("the size per scenario") + 19..];
    let each_kb: f64 = rest[..rest.find("kB").expect("in kB")].trim().parse().unwrap();
    // The two kinds of scenario, as a small run of the same spec writes them.
    let small = dir.join("small");
    gen_ok(&spec, &small, &["--quiet", "--no-images", "--no-effects", "--limit", "1"]);
    let kb = |group: &str| -> f64 {
        let folder = small.join(group).join("train/00000");
        let files: Vec<_> = std::fs::read_dir(&folder).unwrap().map(|e| e.unwrap().metadata().unwrap().len()).collect();
        assert!(!files.is_empty(), "{}", folder.display());
        files.iter().sum::<u64>() as f64 / 1e3
    };
    let (four, twelve) = (kb("cars04_edges50"), kb("cars12_edges50"));
    assert!(twelve > 1.5 * four, "12 cars write more: {twelve} kB against {four} kB");
    assert!(
        (each_kb - twelve).abs() / twelve < 0.1,
        "measured {each_kb} kB, a 12-car scenario is {twelve} kB: {stderr}"
    );
}

#[test]
fn shards_of_two_datasets_started_together_never_both_write_one_folder() {
    // Shards share the folder's lock: shard 0/2 of one seed and shard 1/2 of
    // another, started at the same moment, both found the folder empty and
    // both wrote into it, exit 0 (one try in three), leaving two datasets
    // mixed for merge to refuse.
    let dir = fresh_dir("batch-shard-race");
    let spec = small_spec(&dir);
    let other = dir.join("other.json");
    std::fs::write(&other, std::fs::read_to_string(&spec).unwrap().replace("\"seed\": 11", "\"seed\": 12")).unwrap();
    let out = dir.join("out");
    let mut one_won = 0;
    // (40 tries: the code before this test let both write in 1 to 3 of 12)
    for _ in 0..40 {
        let _ = std::fs::remove_dir_all(&out);
        let start = |spec: &Path, shard: &str| {
            gen_cmd(spec, &out, &["--no-images", "-j", "1", "--shard", shard])
                .stdout(Stdio::null())
                .stderr(Stdio::piped())
                .spawn()
                .unwrap()
        };
        let (a, b) = (start(&spec, "0/2"), start(&other, "1/2"));
        let (a, b) = (a.wait_with_output().unwrap(), b.wait_with_output().unwrap());
        assert!(!(a.status.success() && b.status.success()), "both shards wrote into {}", out.display());
        for refused in [&a, &b].into_iter().filter(|o| !o.status.success()) {
            let stderr = String::from_utf8_lossy(&refused.stderr);
            assert_eq!(refused.status.code(), Some(2), "{stderr}");
            let raced = stderr.contains("a `gen --shard` run of another dataset began writing here at the same moment");
            assert!(
                (raced || stderr.contains("holds a dataset made differently")) && stderr.contains("seed"),
                "{stderr}"
            );
        }
        // What is left is one dataset's: every manifest there of one seed.
        let seeds: std::collections::BTreeSet<u64> = std::fs::read_dir(out.join("shards"))
            .into_iter()
            .flatten()
            .flatten()
            .map(|e| read_json(&e.path())["spec"]["seed"].as_u64().unwrap())
            .collect();
        assert!(seeds.len() <= 1, "manifests of seeds {seeds:?} in one folder");
        if a.status.success() != b.status.success() {
            one_won += 1;
            assert_eq!(seeds.len(), 1, "the shard that went on left no manifest");
        }
    }
    assert!(one_won > 0, "in no try did one shard go on: the race was not run");
}

#[test]
fn a_limit_at_or_above_every_split_writes_the_dataset_of_no_limit() {
    // A rerun of a finished dataset with --limit 12 (every split at most 4)
    // rewrote its manifest with "limit": 12, no longer the bytes of a run
    // without, and a later --limit was told it "was written with --limit 12".
    let dir = fresh_dir("batch-limit-all");
    let spec = small_spec(&dir);
    let (plain, limited) = (dir.join("plain"), dir.join("limited"));
    gen_ok(&spec, &plain, &["--no-images"]);
    let expected = hash_tree(&plain);
    gen_ok(&spec, &limited, &["--no-images", "--limit", "4"]);
    assert_eq!(hash_tree(&limited), expected, "--limit 4 of splits of 4, 2 and 2");
    gen_ok(&spec, &plain, &["--no-images", "--limit", "12"]);
    assert_eq!(hash_tree(&plain), expected, "a rerun with --limit 12 changed the dataset");
    assert!(read_json(&plain.join("manifest.json"))["limit"].is_null());
    let output = gen_cmd(&spec, &plain, &["--no-images", "--limit", "1"]).output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("was written with no --limit, this run asks for --limit 1"), "{stderr}");
    // A refusal names the limit as given (a packed dataset keeps its own).
    let packed = dir.join("packed");
    gen_ok(&spec, &packed, &["--no-images", "--format", "tar", "--limit", "1"]);
    let output = gen_cmd(&spec, &packed, &["--no-images", "--format", "tar", "--limit", "12"]).output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("was written with --limit 1, this run asks for --limit 12"), "{stderr}");
}

#[test]
fn a_packed_merge_counts_what_it_moved_as_tar_files() {
    // "100 scenarios (40 moved, ...)": the 40 were tar files.
    let dir = fresh_dir("batch-merge-tar");
    let spec = small_spec(&dir);
    let mut args = vec!["merge".to_string(), "--out".into(), dir.join("merged").display().to_string()];
    for k in 0..2 {
        let out = dir.join(format!("s{k}"));
        gen_ok(
            &spec,
            &out,
            &["--no-images", "--format", "tar", "--scenarios-per-tar", "2", "--shard", &format!("{k}/2")],
        );
        args.push(out.display().to_string());
    }
    let output = run(&args.iter().map(String::as_str).collect::<Vec<_>>());
    let said = format!("{}{}", String::from_utf8_lossy(&output.stdout), String::from_utf8_lossy(&output.stderr));
    assert!(output.status.success(), "{said}");
    let packs = glob_count(&dir.join("merged"), ".tar");
    assert!(said.contains(&format!("16 scenarios ({packs} tar files moved, 0 duplicate tar files dropped)")), "{said}");
    assert!(packs == 8, "2 groups' splits of 4, 2 and 2 in packs of 2: {packs}");
}

/// How many files under `root` have names ending in `suffix`.
fn glob_count(root: &Path, suffix: &str) -> usize {
    hash_tree(root).keys().filter(|name| name.ends_with(suffix)).count()
}

#[test]
fn pack_and_export_stopped_by_sigterm_or_ctrl_c_say_how_to_finish_and_a_rerun_does() {
    // They died of the signal (exit 143 for SIGTERM), saying nothing.
    let dir = fresh_dir("batch-pack-term");
    let spec = write_spec(&dir, &toy_spec("packterm", &[(4, 0.5), (8, 0.5)], (4, 2, 2), 150));
    let data = dir.join("data");
    gen_ok(&spec, &data, &["--quiet"]);
    let (packed, nri) = (dir.join("packed"), dir.join("nri"));
    let jobs: [(&str, Vec<String>, &Path, &str); 2] = [
        (
            "-TERM",
            ["pack", "--out", packed.to_str().unwrap(), data.to_str().unwrap(), "--scenarios-per-tar", "1", "-j", "1"]
                .map(String::from)
                .to_vec(),
            &packed,
            "pack",
        ),
        (
            "-INT",
            ["export", "nri", data.to_str().unwrap(), "--out", nri.to_str().unwrap()].map(String::from).to_vec(),
            &nri,
            "export",
        ),
    ];
    for (signal, args, out, command) in jobs {
        // An export of this dataset takes about 10 ms: one that finished
        // before the signal reached it (exit 0, seen on a busy CI machine)
        // is run again, until one is stopped midway.
        let mut tries = 0;
        let output = loop {
            tries += 1;
            let _ = std::fs::remove_dir_all(out);
            let child = Command::new(bin()).args(&args).stdout(Stdio::null()).stderr(Stdio::piped()).spawn().unwrap();
            // Held still once it has begun writing, then signalled: it cannot
            // finish in between.
            let started = Instant::now();
            while !holds_a_file_while_written(out) {
                assert!(started.elapsed() < Duration::from_secs(60), "{command} wrote nothing");
                std::thread::sleep(Duration::from_millis(1));
            }
            let pid = child.id().to_string();
            for s in ["-STOP", signal, "-CONT"] {
                assert!(Command::new("kill").args([s, &pid]).status().unwrap().success());
            }
            let output = child.wait_with_output().unwrap();
            if output.status.code() != Some(0) || tries == 20 {
                break output;
            }
        };
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(130), "{command}: {stderr}");
        assert!(
            stderr.contains(&format!("interrupted: {command} stopped; run the same command again to finish it")),
            "{stderr}"
        );
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let rerun = run(&args);
        assert!(rerun.status.success(), "{command}: {}", String::from_utf8_lossy(&rerun.stderr));
        let finished = hash_tree(out);
        std::fs::remove_dir_all(out).unwrap();
        assert!(run(&args).status.success());
        assert_eq!(finished, hash_tree(out), "{command}: the finished rerun differs from one whole run");
    }
}
