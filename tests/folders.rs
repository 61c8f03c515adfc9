//! One writer per folder, and only into folders a command would have
//! written itself: concurrent `gen` runs never mix, a damaged scenario is
//! rewritten on rerun and refused by `merge`, and every command refuses a
//! foreign `--out` with exit 2, leaving it as it was.

mod common;

use common::{bin, city_spec, fresh_dir, gen_ok, hash_tree, run, toy_spec, write_spec};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

fn stderr(output: &std::process::Output) -> String {
    String::from_utf8_lossy(&output.stderr).into_owned()
}

fn assert_valid(dir: &Path) {
    let output = run(&["validate", dir.to_str().unwrap()]);
    assert!(
        output.status.success(),
        "validate {}: {}{}",
        dir.display(),
        String::from_utf8_lossy(&output.stdout),
        stderr(&output)
    );
}

/// A city spec with images that takes about a second to generate, so that
/// two runs started a few hundred milliseconds apart overlap.
fn slow_spec(dir: &Path) -> std::path::PathBuf {
    write_spec(dir, &city_spec("busy", &[(8, 0.5), (4, 0.5)], (6, 1, 1), 100, "{}"))
}

/// Start offsets in milliseconds, drawn from a seeded stream (the same on
/// every run of the test).
fn offsets(n: usize) -> Vec<u64> {
    let mut state: u64 = 0x9e37_79b9_7f4a_7c15;
    (0..n)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state % 400
        })
        .collect()
}

#[test]
fn two_gen_runs_on_one_folder_never_mix() {
    let dir = fresh_dir("folders-two-gen");
    let spec = slow_spec(&dir);
    let reference = dir.join("reference");
    gen_ok(&spec, &reference, &["--quiet"]);
    let expected = hash_tree(&reference);
    let mut refused = 0;
    for (trial, offset) in offsets(5).into_iter().enumerate() {
        let out = dir.join(format!("trial{trial}"));
        let args = ["gen", "--quiet", "--spec", spec.to_str().unwrap(), "--out", out.to_str().unwrap()];
        let first = Command::new(bin()).args(args).stderr(Stdio::piped()).spawn().unwrap();
        std::thread::sleep(Duration::from_millis(offset));
        let second = Command::new(bin()).args(args).output().unwrap();
        let first = first.wait_with_output().unwrap();
        for (who, output) in [("first", &first), ("second", &second)] {
            let code = output.status.code();
            assert!(
                code == Some(0) || code == Some(2),
                "trial {trial}: the {who} run exited {code:?}: {}",
                stderr(output)
            );
            if code == Some(2) {
                let message = stderr(output);
                assert!(
                    message.contains("is in use by another causalcity process") && message.contains("pid "),
                    "{message}"
                );
                refused += 1;
            }
        }
        assert!(first.status.success() || second.status.success(), "trial {trial}: neither run finished");
        assert_valid(&out);
        assert_eq!(hash_tree(&out), expected, "trial {trial} (second run {offset} ms later) differs from one run");
    }
    // The runs overlapped: the lock, not luck, kept them apart.
    assert!(refused >= 3, "only {refused} of 5 overlapping second runs were refused");
}

#[test]
fn duplicated_shards_are_refused_while_the_shards_of_one_job_share_a_folder() {
    let dir = fresh_dir("folders-shards");
    let spec = slow_spec(&dir);
    let reference = dir.join("reference");
    gen_ok(&spec, &reference, &["--quiet"]);
    let out = dir.join("shared");
    let start = |shard: &str| {
        Command::new(bin())
            .args([
                "gen",
                "--quiet",
                "--spec",
                spec.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
                "--shard",
                shard,
            ])
            .stderr(Stdio::piped())
            .spawn()
            .unwrap()
    };
    let (zero, one) = (start("0/2"), start("1/2"));
    std::thread::sleep(Duration::from_millis(150));
    let duplicate = start("0/2").wait_with_output().unwrap();
    let (zero, one) = (zero.wait_with_output().unwrap(), one.wait_with_output().unwrap());
    assert!(zero.status.success() && one.status.success(), "{}{}", stderr(&zero), stderr(&one));
    assert_eq!(duplicate.status.code(), Some(2), "a duplicated shard ran beside its twin: {}", stderr(&duplicate));
    assert!(stderr(&duplicate).contains("--shard 0/2"), "{}", stderr(&duplicate));
    let merged = run(&["merge", "--out", out.to_str().unwrap()]);
    assert!(merged.status.success(), "{}", stderr(&merged));
    assert_valid(&out);
    assert_eq!(hash_tree(&out), hash_tree(&reference), "shards in one folder, merged, differ from one run");
}

/// The first scenario folder of a dataset, in sorted order.
fn first_scenario(root: &Path) -> std::path::PathBuf {
    let groups = common::sorted_entries(root);
    let group = groups.iter().find(|g| g.file_name().unwrap().to_string_lossy().starts_with("cars")).expect("a group");
    let split = common::sorted_entries(group).into_iter().next().expect("a split");
    common::sorted_entries(&split).into_iter().next().expect("a scenario")
}

#[test]
fn a_damaged_scenario_is_rewritten_on_rerun_and_refused_by_merge() {
    let dir = fresh_dir("folders-damaged");
    let spec = write_spec(&dir, &toy_spec("damaged", &[(4, 0.5)], (2, 1, 1), 20));
    let out = dir.join("data");
    gen_ok(&spec, &out, &["--quiet"]);
    let expected = hash_tree(&out);
    let scenarios = common::scenario_dirs(&out);
    std::fs::remove_file(scenarios[0].join("rgb").join("0005.png")).unwrap();
    let poses = scenarios[1].join("poses.csv");
    let mut bytes = std::fs::read(&poses).unwrap();
    let last = bytes.len() - 2;
    bytes[last] = if bytes[last] == b'0' { b'1' } else { b'0' };
    std::fs::write(&poses, bytes).unwrap();
    let rerun = gen_ok(&spec, &out, &["--quiet"]);
    let message = stderr(&rerun);
    assert_eq!(message.matches("is damaged").count(), 2, "{message}");
    assert!(String::from_utf8_lossy(&rerun.stdout).contains("rewrote 2 damaged"));
    assert_eq!(hash_tree(&out), expected, "the rerun did not restore the damaged scenarios");

    // Shards in folders of their own; one holds a damaged scenario.
    let shards: Vec<_> = (0..2).map(|k| dir.join(format!("shard{k}"))).collect();
    for (k, shard) in shards.iter().enumerate() {
        gen_ok(&spec, shard, &["--quiet", "--shard", &format!("{k}/2")]);
    }
    let victim = first_scenario(&shards[1]).join("poses.csv");
    std::fs::write(&victim, "frame,t,car\n").unwrap();
    let before = [hash_tree(&shards[0]), hash_tree(&shards[1])];
    let merged = dir.join("merged");
    let output =
        run(&["merge", "--out", merged.to_str().unwrap(), shards[0].to_str().unwrap(), shards[1].to_str().unwrap()]);
    assert_eq!(output.status.code(), Some(2), "{}", stderr(&output));
    assert!(stderr(&output).contains("damaged") && stderr(&output).contains("poses.csv"), "{}", stderr(&output));
    assert!(!merged.exists(), "a refused merge created its --out");
    assert_eq!([hash_tree(&shards[0]), hash_tree(&shards[1])], before, "a refused merge moved something");
}

#[test]
fn every_command_refuses_a_folder_it_did_not_write() {
    let dir = fresh_dir("folders-foreign");
    let toy_spec_path = write_spec(&dir, &toy_spec("owner", &[(4, 0.5)], (1, 1, 1), 20));
    let toy = dir.join("toy");
    gen_ok(&toy_spec_path, &toy, &["--quiet"]);
    let city_dir = dir.join("cityspec");
    std::fs::create_dir_all(&city_dir).unwrap();
    let city_spec_path = write_spec(&city_dir, &city_spec("neighbour", &[(4, 0.5)], (1, 1, 1), 20, "{}"));
    let sweep = dir.join("sweep");
    let output = run(&[
        "counterfactual",
        "--sweep",
        city_spec_path.to_str().unwrap(),
        "--out",
        sweep.to_str().unwrap(),
        "--quiet",
        "--no-images",
    ]);
    assert!(output.status.success(), "{}", stderr(&output));
    let orphans = dir.join("orphans");
    std::fs::create_dir_all(&orphans).unwrap();
    common::scenario_dirs(&toy).iter().take(1).for_each(|s| {
        let rel = s.strip_prefix(&toy).unwrap();
        std::fs::create_dir_all(orphans.join(rel)).unwrap();
        std::fs::write(orphans.join(rel).join("scenario.json"), "{}").unwrap();
    });
    let stray = dir.join("stray");
    std::fs::create_dir_all(&stray).unwrap();
    std::fs::write(stray.join("notes.txt"), "mine").unwrap();
    // Shards of the city spec, to be merged into the toy dataset.
    let city_shards: Vec<PathBuf> = (0..2).map(|k| dir.join(format!("city-shard{k}"))).collect();
    for (k, shard) in city_shards.iter().enumerate() {
        let shard_flag = format!("{k}/2");
        let args = ["gen", "--spec", city_spec_path.to_str().unwrap(), "--out", shard.to_str().unwrap()];
        let output = run(&[&args[..], &["--quiet", "--no-images", "--shard", &shard_flag]].concat());
        assert!(output.status.success(), "{}", stderr(&output));
    }

    let p = |path: &Path| path.to_str().unwrap().to_string();
    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/examples/stop-the-leader.json");
    let cases: Vec<(Vec<String>, &Path, &str)> = vec![
        (
            vec!["gen".into(), "--spec".into(), p(&toy_spec_path), "--out".into(), p(&sweep)],
            &sweep,
            "counterfactual sweep",
        ),
        (
            vec!["gen".into(), "--spec".into(), p(&toy_spec_path), "--out".into(), p(&orphans)],
            &orphans,
            "no manifest.json",
        ),
        (vec!["gen".into(), "--spec".into(), p(&toy_spec_path), "--out".into(), p(&stray)], &stray, "notes.txt"),
        (
            vec!["counterfactual".into(), "--sweep".into(), p(&toy_spec_path), "--out".into(), p(&sweep)],
            &sweep,
            "city-world",
        ),
        (
            vec![
                "counterfactual".into(),
                "--sweep".into(),
                p(&city_spec_path),
                "--out".into(),
                p(&toy),
                "--no-images".into(),
            ],
            &toy,
            "gen dataset",
        ),
        (vec!["export".into(), "nri".into(), p(&toy), "--out".into(), p(&toy)], &toy, "gen dataset"),
        (
            vec!["export".into(), "nri".into(), p(&toy), "--out".into(), p(&toy.join("nri"))],
            &toy,
            "inside a gen dataset",
        ),
        (vec!["export".into(), "nsdr".into(), p(&toy), "--out".into(), p(&sweep)], &sweep, "counterfactual sweep"),
        (vec!["export".into(), "nri".into(), p(&toy), "--out".into(), p(&stray)], &stray, "notes.txt"),
        (
            vec![
                "export".into(),
                "nri".into(),
                p(&toy),
                "--out".into(),
                p(&dir.join("nri")),
                "--suffix".into(),
                "/../../escaped".into(),
            ],
            &dir,
            "--suffix",
        ),
        (vec!["run".into(), "--scenario".into(), p(&example), "--out".into(), p(&toy)], &toy, "gen dataset"),
        (
            vec!["counterfactual".into(), "--scenario".into(), p(&example), "--out".into(), p(&sweep)],
            &sweep,
            "counterfactual sweep",
        ),
        (vec!["merge".into(), "--out".into(), p(&dir.join("merged")), p(&toy)], &toy, "no shard manifest"),
        (vec!["pack".into(), p(&toy), "--out".into(), p(&toy.join("packed"))], &toy, "inside a gen dataset"),
        (vec!["pack".into(), p(&toy), "--out".into(), p(&sweep)], &sweep, "counterfactual sweep"),
        (
            vec!["merge".into(), "--out".into(), p(&toy), p(&city_shards[0]), p(&city_shards[1])],
            &toy,
            "already holds another dataset",
        ),
    ];
    let mut checked = 0;
    for (args, folder, says) in &cases {
        let before = hash_tree(folder);
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let output = run(&args);
        let message = stderr(&output);
        assert_eq!(output.status.code(), Some(2), "{args:?} exited {:?}: {message}", output.status.code());
        assert!(message.contains(says), "{args:?} should say {says:?}: {message}");
        assert_eq!(hash_tree(folder), before, "{args:?} changed {}", folder.display());
        checked += 1;
    }
    assert_eq!(checked, cases.len());
    for never in ["nri", "escaped.npy", "merged"] {
        assert!(!dir.join(never).exists(), "a refused command left {never}");
    }
    assert_valid(&toy);
}

#[test]
fn a_smaller_limit_into_an_existing_dataset_is_refused_and_a_larger_one_extends_it() {
    let dir = fresh_dir("folders-limit");
    let spec = write_spec(&dir, &toy_spec("limits", &[(4, 0.5)], (4, 1, 1), 10));
    let out = dir.join("out");
    gen_ok(&spec, &out, &["--quiet", "--no-images", "--limit", "2"]);
    let before = hash_tree(&out);
    let args = |limit: &'static str| {
        vec![
            "gen",
            "--quiet",
            "--no-images",
            "--spec",
            spec.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--limit",
            limit,
        ]
    };
    let smaller = run(&args("1"));
    assert_eq!(smaller.status.code(), Some(2), "{}", stderr(&smaller));
    assert!(stderr(&smaller).contains("--limit 2") && stderr(&smaller).contains("--limit 1"), "{}", stderr(&smaller));
    assert_eq!(hash_tree(&out), before, "a refused --limit changed the dataset");
    assert_valid(&out);

    // A larger limit keeps the first two scenarios per split and adds the rest.
    let larger = run(&args("3"));
    assert!(larger.status.success(), "{}", stderr(&larger));
    let after = hash_tree(&out);
    let kept = before.iter().filter(|(path, _)| path.contains("/00000/") || path.contains("/00001/")).count();
    assert!(kept > 0);
    for (path, hash) in before.iter().filter(|(path, _)| path.contains("/00000/") || path.contains("/00001/")) {
        assert_eq!(after.get(path), Some(hash), "{path} changed when the dataset was extended");
    }
    assert!(after.keys().any(|p| p.contains("train/00002/")), "no third train scenario");
    assert_valid(&out);
    let manifest = common::read_json(&out.join("manifest.json"));
    assert_eq!(manifest["limit"], 3);

    // No limit at all extends it to the whole spec; then any limit is smaller.
    let whole =
        run(&["gen", "--quiet", "--no-images", "--spec", spec.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(whole.status.success(), "{}", stderr(&whole));
    assert!(hash_tree(&out).keys().any(|p| p.contains("train/00003/")));
    assert_valid(&out);
    let refused = run(&args("3"));
    assert_eq!(refused.status.code(), Some(2), "{}", stderr(&refused));
    assert!(stderr(&refused).contains("no --limit"), "{}", stderr(&refused));
}

#[test]
fn a_merge_cut_off_part_way_is_finished_by_the_same_command() {
    // Killed while moving scenarios, merge left them in --out with no
    // manifest: a rerun refused --out as foreign, and the shard folders had
    // lost the scenarios moved. Merges are killed once they have moved
    // some scenarios (watched as they go: a kill timed by the clock missed
    // the moves on a busy machine).
    let dir = fresh_dir("folders-merge-cut-off");
    let spec = write_spec(&dir, &toy_spec("cut", &[(3, 0.5), (4, 0.5)], (400, 50, 50), 2));
    let reference = dir.join("reference");
    gen_ok(&spec, &reference, &["--quiet", "--no-images", "--no-effects"]);
    let (s0, s1, out) = (dir.join("s0"), dir.join("s1"), dir.join("out"));
    let shards = || {
        for folder in [&s0, &s1, &out] {
            let _ = std::fs::remove_dir_all(folder);
        }
        gen_ok(&spec, &s0, &["--quiet", "--no-images", "--no-effects", "--shard", "0/2"]);
        gen_ok(&spec, &s1, &["--quiet", "--no-images", "--no-effects", "--shard", "1/2"]);
    };
    let args = ["merge", "--out", out.to_str().unwrap(), s0.to_str().unwrap(), s1.to_str().unwrap()];
    shards();
    let whole = Command::new(bin()).args(args).output().unwrap();
    assert!(whole.status.success(), "{}", stderr(&whole));
    assert_eq!(hash_tree(&out), hash_tree(&reference));
    // Run again once it finished (a retried cluster task): said as it is,
    // and done, exit 0 (exit 2 was a failure to a retrying scheduler).
    let again = run(&args);
    let said = String::from_utf8_lossy(&again.stdout).into_owned() + &stderr(&again);
    assert!(again.status.success(), "{said}");
    assert!(said.contains("nothing to merge") && said.contains("(merged before)"), "{said}");
    assert_eq!(hash_tree(&out), hash_tree(&reference));
    // With one shard folder still there and empty, the other gone: what a
    // merge cut off as it removed the emptied folders leaves, finished
    // (it was refused, and the folder stayed for good).
    std::fs::create_dir_all(&s0).unwrap();
    let partly = run(&args);
    let said = String::from_utf8_lossy(&partly.stdout).into_owned() + &stderr(&partly);
    assert!(partly.status.success(), "{said}");
    assert!(said.contains("finished what the merge cut off left") && said.contains("emptied shard folder"), "{said}");
    assert!(!s0.exists());
    assert_eq!(hash_tree(&out), hash_tree(&reference));
    // One holding something else: refused, said why.
    std::fs::create_dir_all(&s0).unwrap();
    std::fs::write(s0.join("notes.txt"), "mine").unwrap();
    let partly = run(&args);
    assert_eq!(partly.status.code(), Some(2), "{}", stderr(&partly));
    assert!(stderr(&partly).contains("already holds a complete dataset: merged before?"), "{}", stderr(&partly));
    assert!(s0.join("notes.txt").exists());
    let moved_train = || out.join("cars03_edges50/train").read_dir().map_or(0, |d| d.count());
    let mut cut_off = Vec::new();
    for after in [1, 150, 1, 300, 1, 150] {
        shards();
        let mut merge = Command::new(bin()).args(args).stdout(Stdio::null()).stderr(Stdio::null()).spawn().unwrap();
        while moved_train() < after && merge.try_wait().unwrap().is_none() {
            std::thread::yield_now();
        }
        let _ = merge.kill();
        let _ = merge.wait();
        let moved = moved_train();
        if moved == 0 || out.join("manifest.json").exists() {
            continue; // it finished before the kill
        }
        let rerun = run(&args);
        assert!(rerun.status.success(), "killed after {moved} scenarios moved: {}", stderr(&rerun));
        assert_valid(&out);
        assert_eq!(hash_tree(&out), hash_tree(&reference), "killed after {moved} scenarios moved");
        assert!(!s0.exists() && !s1.exists(), "the shard folders are emptied and removed");
        cut_off.push(moved);
        if cut_off.len() == 2 {
            break;
        }
    }
    assert!(!cut_off.is_empty(), "no kill landed while scenarios moved: the test checked nothing");
}

#[test]
fn shards_of_another_dataset_are_named_by_what_differs_and_a_shard_count_fits_the_scenarios() {
    let dir = fresh_dir("folders-merge-differs");
    let spec = write_spec(&dir, &toy_spec("differs", &[(3, 0.5)], (3, 1, 1), 5));
    let other = dir.join("other.json");
    std::fs::write(&other, std::fs::read_to_string(&spec).unwrap().replace(r#""seed": 11"#, r#""seed": 12"#)).unwrap();
    let (s0, s1) = (dir.join("s0"), dir.join("s1"));
    gen_ok(&spec, &s0, &["--quiet", "--no-images", "--shard", "0/2"]);
    gen_ok(&other, &s1, &["--quiet", "--no-images", "--shard", "1/2", "--no-effects"]);
    let (b0, b1) = (hash_tree(&s0), hash_tree(&s1));
    let out = dir.join("out");
    let mixed = run(&["merge", "--out", out.to_str().unwrap(), s0.to_str().unwrap(), s1.to_str().unwrap()]);
    assert_eq!(mixed.status.code(), Some(2), "{}", stderr(&mixed));
    // It said every field that might differ; now it names the ones that do.
    assert!(stderr(&mixed).contains("effects (--no-effects): false here, true in the first"), "{}", stderr(&mixed));
    assert!(stderr(&mixed).contains("spec.seed: 12 here, 11 in the first"), "{}", stderr(&mixed));
    assert_eq!((hash_tree(&s0), hash_tree(&s1)), (b0, b1), "nothing moved");
    // 5 scenarios shared by 2^32 - 1 shards: all but 5 would hold none, and
    // their merge listed every missing one (gigabytes).
    let many = dir.join("many");
    let refused =
        run(&["gen", "--spec", spec.to_str().unwrap(), "--out", many.to_str().unwrap(), "--shard", "0/4294967295"]);
    assert_eq!(refused.status.code(), Some(2), "{}", stderr(&refused));
    assert!(stderr(&refused).contains("this run has 5 scenarios to share out"), "{}", stderr(&refused));
    assert!(!many.exists(), "nothing written");
    gen_ok(&spec, &many, &["--quiet", "--no-images", "--shard", "0/5"]);
    let merged = run(&["merge", "--out", many.to_str().unwrap()]);
    assert_eq!(merged.status.code(), Some(2));
    assert!(stderr(&merged).contains("shards 1, 2, 3, 4 of 5 are missing"), "{}", stderr(&merged));
    // A shard manifest numbered past its count (hand-edited): named, where
    // the missing count underflowed.
    let manifest = many.join("shards/0-of-5.json");
    let text = std::fs::read_to_string(&manifest).unwrap().replace(r#""index": 0"#, r#""index": 7"#);
    std::fs::write(&manifest, text).unwrap();
    let merged = run(&["merge", "--out", many.to_str().unwrap()]);
    assert_eq!(merged.status.code(), Some(2), "{}", stderr(&merged));
    assert!(
        stderr(&merged).contains("shard index 7 is not allowed: a shard of 5 is numbered 0 to 4"),
        "{}",
        stderr(&merged)
    );
}

#[test]
fn a_shard_named_through_a_link_is_merged_and_removed_and_a_retried_merge_says_merged_before() {
    // A shard folder given as a link (data/s0 -> /scratch/s0) was merged,
    // but its emptied folder stayed behind the link, and the merge retried
    // (a cluster task run again) found the link and exited 2.
    let dir = fresh_dir("folders-merge-link");
    let spec = write_spec(&dir, &toy_spec("linked", &[(3, 0.5)], (6, 2, 2), 2));
    let reference = dir.join("reference");
    gen_ok(&spec, &reference, &["--quiet", "--no-images", "--no-effects"]);
    let (s0, s1, link, out) = (dir.join("s0"), dir.join("s1"), dir.join("l0"), dir.join("out"));
    gen_ok(&spec, &s0, &["--quiet", "--no-images", "--no-effects", "--shard", "0/2"]);
    gen_ok(&spec, &s1, &["--quiet", "--no-images", "--no-effects", "--shard", "1/2"]);
    std::os::unix::fs::symlink(&s0, &link).unwrap();
    // Named `l0/`, as a shell completes a link to a folder.
    let slashed = format!("{}/", link.display());
    let args = ["merge", "--out", out.to_str().unwrap(), &slashed, s1.to_str().unwrap()];
    let merged = run(&args);
    assert!(merged.status.success(), "{}", stderr(&merged));
    assert_eq!(hash_tree(&out), hash_tree(&reference));
    for gone in [&s0, &s1, &link] {
        assert!(std::fs::symlink_metadata(gone).is_err(), "{} is left after the merge", gone.display());
    }
    let again = run(&args);
    let said = String::from_utf8_lossy(&again.stdout).into_owned() + &stderr(&again);
    assert!(again.status.success() && said.contains("(merged before)"), "{said}");
    // A merge cut off as it removed the emptied folders, the linked one
    // left: finished by the same command (named without the slash too).
    std::fs::create_dir(&s0).unwrap();
    std::os::unix::fs::symlink(&s0, &link).unwrap();
    let args = ["merge", "--out", out.to_str().unwrap(), link.to_str().unwrap(), s1.to_str().unwrap()];
    let finished = run(&args);
    let said = String::from_utf8_lossy(&finished.stdout).into_owned() + &stderr(&finished);
    assert!(finished.status.success() && said.contains("finished what the merge cut off left"), "{said}");
    assert!(std::fs::symlink_metadata(&s0).is_err() && std::fs::symlink_metadata(&link).is_err(), "{said}");
    assert_eq!(hash_tree(&out), hash_tree(&reference));
}
