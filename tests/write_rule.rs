//! The one write rule, from the command line: no command writes into a
//! dataset it does not own, onto its own input, or through a symbolic link
//! out of the folder asked for; `--force` removes only what causalcity
//! wrote. Every refusal exits 2, leaves the dataset valid and the outside
//! file as it was.

mod common;

use common::{fresh_dir, gen_ok, hash_tree, npy, npz, run, toy_spec, write_spec};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Output;

fn stderr(output: &Output) -> String {
    String::from_utf8_lossy(&output.stderr).into_owned()
}

fn assert_refused(output: &Output, says: &str) {
    assert_eq!(output.status.code(), Some(2), "stderr: {}", stderr(output));
    assert!(stderr(output).contains(says), "expected {says:?} in: {}", stderr(output));
}

fn assert_valid(dir: &Path) {
    let output = run(&["validate", dir.to_str().unwrap()]);
    assert!(output.status.success(), "validate {}: {}", dir.display(), String::from_utf8_lossy(&output.stdout));
}

fn s(path: &Path) -> &str {
    path.to_str().unwrap()
}

/// A small toy dataset (one group of 4 cars, splits 2/1/1, no images).
fn toy_dataset(dir: &Path) -> PathBuf {
    let spec = write_spec(dir, &toy_spec("rule", &[(4, 0.5)], (2, 1, 1), 30));
    let data = dir.join("data");
    gen_ok(&spec, &data, &["--quiet", "--no-images"]);
    data
}

/// Edge scores for the test split of the toy dataset.
fn predictions(dir: &Path) -> PathBuf {
    let path = dir.join("pred.npz");
    let scores: Vec<f64> = (0..16).map(|i| (i % 5) as f64 / 5.0).collect();
    npz(&path, &[("cars04_edges50/test/00000", npy(&[4, 4], &scores))]);
    path
}

#[test]
fn evaluate_csv_never_lands_in_the_dataset_on_its_input_or_through_a_link() {
    let dir = fresh_dir("rule-evaluate-csv");
    let data = toy_dataset(&dir);
    let pred = predictions(&dir);
    let outside = dir.join("outside.txt");
    std::fs::write(&outside, "keep me").unwrap();
    let link = dir.join("link.csv");
    std::os::unix::fs::symlink(&outside, &link).unwrap();
    let folder = dir.join("a-folder");
    std::fs::create_dir(&folder).unwrap();
    let before = hash_tree(&data);
    let pred_bytes = std::fs::read(&pred).unwrap();
    let cases: Vec<(PathBuf, &str)> = vec![
        (data.join("manifest.json"), "inside a gen dataset"),
        (data.join("extra.csv"), "inside a gen dataset"),
        (data.join("cars04_edges50/test/00000/scores.csv"), "inside a gen dataset"),
        (pred.clone(), "the predictions file"),
        (link.clone(), "symbolic link"),
        (folder.clone(), "is a folder"),
        (outside.join("under.csv"), "is a file, so nothing can be written under it"),
    ];
    for (csv, says) in &cases {
        let output = run(&["evaluate", s(&data), s(&pred), "--history", "20", "--csv", s(csv)]);
        assert_refused(&output, says);
        assert!(output.stdout.is_empty(), "nothing is scored before the refusal");
    }
    assert_eq!(hash_tree(&data), before, "the dataset is unchanged");
    assert_eq!(std::fs::read(&pred).unwrap(), pred_bytes);
    assert_eq!(std::fs::read_to_string(&outside).unwrap(), "keep me");
    assert!(std::fs::symlink_metadata(&link).unwrap().file_type().is_symlink());
    assert_valid(&data);

    // Outside the dataset it writes, into a new folder if need be.
    let csv = dir.join("results/new/table.csv");
    let output = run(&["evaluate", s(&data), s(&pred), "--csv", s(&csv)]);
    assert!(output.status.success(), "{}", stderr(&output));
    let table = std::fs::read_to_string(&csv).unwrap();
    assert!(table.lines().count() > 1 && table.contains("cars04_edges50"), "{table}");
    // A rerun replaces its own table; a file of another kind is kept (a
    // spec given as --csv by a slip of the hand was written over), and so
    // are notes (text, but not this table).
    let header = table.lines().next().unwrap().to_string();
    std::fs::write(&csv, format!("{header}\nan earlier run's row\n")).unwrap();
    let output = run(&["evaluate", s(&data), s(&pred), "--csv", s(&csv)]);
    assert!(output.status.success(), "{}", stderr(&output));
    assert_eq!(std::fs::read_to_string(&csv).unwrap(), table, "the earlier table is replaced");
    let notes = dir.join("notes.md");
    std::fs::write(&notes, "# my notes\n").unwrap();
    for flag in ["--csv", "--per-scenario"] {
        let output = run(&["evaluate", s(&data), s(&pred), flag, s(&notes)]);
        assert_refused(&output, "already holds text other than this command's table");
    }
    assert_eq!(std::fs::read_to_string(&notes).unwrap(), "# my notes\n");
    let spec = dir.join("spec.json");
    std::fs::write(&spec, "{\"name\": \"mine\"}\n").unwrap();
    let output = run(&["evaluate", s(&data), s(&pred), "--csv", s(&spec)]);
    assert_refused(&output, "already holds JSON (such as a spec), and this command writes a CSV table");
    assert_eq!(std::fs::read_to_string(&spec).unwrap(), "{\"name\": \"mine\"}\n");
    // A FIFO (or a device node: as root, --csv /dev/full became a CSV
    // file) is not renamed over: it is refused and stays what it was.
    let (fifo, png_fifo) = (dir.join("pipe.csv"), dir.join("pipe.png"));
    for path in [&fifo, &png_fifo] {
        assert!(std::process::Command::new("mkfifo").arg(path).status().unwrap().success());
    }
    for command in [
        vec!["evaluate", s(&data), s(&pred), "--csv", s(&fifo)],
        vec!["evaluate", s(&data), s(&pred), "--per-scenario", s(&fifo)],
        vec!["heatmap", s(&data), "--out", s(&png_fifo)],
    ] {
        assert_refused(&run(&command), "is a FIFO (named pipe), not a regular file: nothing is written there");
        use std::os::unix::fs::FileTypeExt;
        for path in [&fifo, &png_fifo] {
            assert!(std::fs::symlink_metadata(path).unwrap().file_type().is_fifo(), "{command:?} replaced {path:?}");
        }
    }
    let picture = dir.join("heat.png");
    std::fs::write(&picture, "frame,score\n0,1\n").unwrap();
    assert_refused(&run(&["heatmap", s(&data), "--out", s(&picture)]), "already holds text");
    assert_eq!(std::fs::read_to_string(&picture).unwrap(), "frame,score\n0,1\n");
}

#[test]
fn a_history_that_overflows_is_refused_not_a_panic() {
    let dir = fresh_dir("rule-history");
    let data = toy_dataset(&dir);
    let path = dir.join("traj.npz");
    npz(&path, &[("cars04_edges50/test/00000/trajectory", npy(&[2, 4, 2], &[1.0; 16]))]);
    for history in [u64::MAX.to_string(), (u64::MAX - 1).to_string(), "29".to_string()] {
        let output = run(&["evaluate", s(&data), s(&path), "--history", &history]);
        assert_refused(&output, "--history at most 28");
    }
    let output = run(&["evaluate", s(&data), s(&path), "--history", "28", "--json"]);
    assert!(output.status.success(), "{}", stderr(&output));
}

#[test]
fn trajectories_of_one_split_predict_the_same_steps() {
    // One train scenario predicting 3 steps beside another's 2: step 3 was
    // scored from it alone, the row counting both (helper audit).
    let dir = fresh_dir("rule-uneven-steps");
    let data = toy_dataset(&dir);
    let path = dir.join("uneven.npz");
    let (short, long) = (npy(&[2, 4, 2], &[100.0; 16]), npy(&[3, 4, 2], &[100.0; 24]));
    npz(
        &path,
        &[("cars04_edges50/train/00000/trajectory", long), ("cars04_edges50/train/00001/trajectory", short.clone())],
    );
    assert_refused(
        &run(&["evaluate", s(&data), s(&path), "--history", "20"]),
        "predicts 2 steps and \"cars04_edges50/train/00000\" 3: predict the same steps for every scenario of \
         cars04_edges50/train",
    );
    npz(
        &path,
        &[("cars04_edges50/train/00000/trajectory", short.clone()), ("cars04_edges50/train/00001/trajectory", short)],
    );
    let output = run(&["evaluate", s(&data), s(&path), "--history", "20"]);
    assert!(output.status.success(), "{}", stderr(&output));
}

#[test]
fn a_trajectory_error_that_overflows_is_named_not_reported_as_null() {
    let dir = fresh_dir("rule-overflow");
    let data = toy_dataset(&dir);
    let path = dir.join("far.npz");
    npz(&path, &[("cars04_edges50/test/00000/trajectory", npy(&[2, 4, 2], &[1e308; 16]))]);
    let output = run(&["evaluate", s(&data), s(&path), "--history", "20", "--json"]);
    assert_refused(&output, "overflows");
    assert!(stderr(&output).contains("cars04_edges50/test/00000/trajectory"), "{}", stderr(&output));
    assert!(stderr(&output).contains(&format!("{}: array", s(&path))), "names the file: {}", stderr(&output));
    // Longer than the scenario: no advice of a history it cannot have.
    let long = dir.join("long.npz");
    npz(&long, &[("cars04_edges50/test/00000/trajectory", npy(&[40, 4, 2], &[1.0; 320]))]);
    let output = run(&["evaluate", s(&data), s(&long), "--history", "20"]);
    assert_refused(&output, "predict at most 10 steps");
    assert!(!stderr(&output).contains("--history at most"), "{}", stderr(&output));
}

#[test]
fn a_link_at_the_lock_file_is_refused_never_written_through() {
    let dir = fresh_dir("rule-lock-link");
    let spec = write_spec(&dir, &toy_spec("lock", &[(4, 0.5)], (1, 1, 1), 20));
    let victim = dir.join("victim.txt");
    std::fs::write(&victim, "precious").unwrap();
    let out = dir.join("out");
    std::fs::create_dir(&out).unwrap();
    std::os::unix::fs::symlink(&victim, out.join(".causalcity.lock")).unwrap();
    let output = run(&["gen", "--quiet", "--no-images", "--spec", s(&spec), "--out", s(&out)]);
    assert_refused(&output, "is a symbolic link");
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "precious");
    assert!(!out.join("manifest.json").exists(), "nothing was written");

    // A dangling link creates nothing where it points.
    let out = dir.join("out2");
    std::fs::create_dir(&out).unwrap();
    let nowhere = dir.join("created-through-the-link");
    std::os::unix::fs::symlink(&nowhere, out.join(".causalcity.lock")).unwrap();
    let output = run(&["gen", "--quiet", "--no-images", "--spec", s(&spec), "--out", s(&out)]);
    assert_refused(&output, "is a symbolic link");
    assert!(!nowhere.exists());
}

#[test]
fn a_hard_link_a_pipe_or_a_folder_at_the_lock_file_is_refused_for_gen_merge_and_pack() {
    // O_NOFOLLOW stops a symbolic link only: a hard link at the lock's name
    // had gen, merge and pack write their holder line into the file
    // outside --out and then unlink the name; a pipe there was locked,
    // written to and removed (helper audit).
    let dir = fresh_dir("rule-lock-hard-link");
    let spec = write_spec(&dir, &toy_spec("hardlock", &[(4, 0.5)], (2, 1, 1), 20));
    let data = dir.join("data");
    gen_ok(&spec, &data, &["--quiet", "--no-images"]);
    let shards: Vec<PathBuf> = (0..2).map(|k| dir.join(format!("shard{k}"))).collect();
    for (k, shard) in shards.iter().enumerate() {
        gen_ok(&spec, shard, &["--quiet", "--no-images", "--shard", &format!("{k}/2")]);
    }
    let victim = dir.join("victim.txt");
    std::fs::write(&victim, "precious").unwrap();
    let commands: [(&str, Vec<String>); 3] = [
        (
            "gen",
            vec![
                "gen".into(),
                "--quiet".into(),
                "--no-images".into(),
                "--spec".into(),
                s(&spec).into(),
                "--out".into(),
            ],
        ),
        ("merge", vec!["merge".into(), s(&shards[0]).into(), s(&shards[1]).into(), "--out".into()]),
        ("pack", vec!["pack".into(), s(&data).into(), "--out".into()]),
    ];
    let mut refused = 0;
    for (name, args) in &commands {
        // A folder there: it exited 1, "cannot write ...: Is a directory".
        for planted in ["hard link", "pipe", "folder"] {
            let out = dir.join(format!("{name}-{}", planted.replace(' ', "-")));
            std::fs::create_dir(&out).unwrap();
            let lock = out.join(".causalcity.lock");
            match planted {
                "hard link" => std::fs::hard_link(&victim, &lock).unwrap(),
                "folder" => std::fs::create_dir(&lock).unwrap(),
                _ => assert!(std::process::Command::new("mkfifo").arg(&lock).status().unwrap().success()),
            }
            let mut args = args.clone();
            args.push(s(&out).into());
            let args: Vec<&str> = args.iter().map(String::as_str).collect();
            let says = match planted {
                "hard link" => "a hard link (",
                "folder" => "a folder where a lock file should be: remove it",
                _ => "not a regular file",
            };
            assert_refused(&run(&args), says);
            assert_eq!(std::fs::read_to_string(&victim).unwrap(), "precious", "{name}: the file outside was written");
            assert!(std::fs::symlink_metadata(&lock).is_ok(), "{name}: the planted {planted} was removed");
            assert_eq!(std::fs::read_dir(&out).unwrap().count(), 1, "{name}: something was written");
            refused += 1;
        }
    }
    assert_eq!(refused, 9);
}

#[test]
fn a_pipe_inside_a_scenario_is_named_by_merge_and_pack_never_opened() {
    // merge and pack verify each scenario against its checksums: a pipe
    // in place of poses.csv hung them (merge left a lock behind), and a
    // resumed gen hung on it past SIGTERM (helper audit). gen rewrites it as
    // a damaged scenario of its own.
    let dir = fresh_dir("rule-pipe-in-scenario");
    let spec = write_spec(&dir, &toy_spec("pipe", &[(4, 0.5)], (2, 1, 1), 20));
    let shards: Vec<PathBuf> = (0..2).map(|k| dir.join(format!("shard{k}"))).collect();
    for (k, shard) in shards.iter().enumerate() {
        gen_ok(&spec, shard, &["--quiet", "--no-images", "--shard", &format!("{k}/2")]);
    }
    let data = dir.join("data");
    gen_ok(&spec, &data, &["--quiet", "--no-images"]);
    let plant = |root: &Path| {
        let scenario = common::scenario_dirs(root).into_iter().next().expect("a scenario");
        let poses = scenario.join("poses.csv");
        std::fs::remove_file(&poses).unwrap();
        assert!(std::process::Command::new("mkfifo").arg(&poses).status().unwrap().success());
        poses
    };
    let in_shard = plant(&shards[1]);
    let merged = dir.join("merged");
    let output = common::run_within(&["merge", "--out", s(&merged), s(&shards[0]), s(&shards[1])], 60);
    assert_refused(&output, &format!("{}: not a regular file (a pipe or a device)", in_shard.display()));
    assert!(!merged.exists(), "merge wrote {}", merged.display());
    let in_data = plant(&data);
    let packed = dir.join("packed");
    let output = common::run_within(&["pack", s(&data), "--out", s(&packed)], 60);
    assert_refused(&output, &format!("{}: not a regular file", in_data.display()));
    // gen's resume reads it as damaged and writes it again: a valid shard.
    let output = common::run_within(
        &["gen", "--quiet", "--no-images", "--spec", s(&spec), "--out", s(&shards[1]), "--shard", "1/2"],
        60,
    );
    assert!(output.status.success(), "{}", stderr(&output));
    assert!(std::fs::metadata(&in_shard).unwrap().is_file());
}

#[test]
fn a_scenario_of_another_seed_or_place_is_refused_by_merge_pack_gen_and_validate() {
    // merge checked checksums only: another seed's scenario copied into a
    // shard (checksums intact, folder or tar) was merged, exit 0, and
    // validate called the result valid; another group's was merged too
    // (helper audit).
    let dir = fresh_dir("rule-foreign-scenario");
    let spec = write_spec(&dir, &toy_spec("foreign", &[(4, 0.5), (6, 0.5)], (2, 1, 1), 20));
    std::fs::create_dir_all(dir.join("other")).unwrap();
    let other_seed = write_spec(
        &dir.join("other"),
        &toy_spec("foreign", &[(4, 0.5), (6, 0.5)], (2, 1, 1), 20).replace("\"seed\": 11,", "\"seed\": 8,"),
    );
    assert_ne!(std::fs::read(&spec).unwrap(), std::fs::read(&other_seed).unwrap(), "the seed was not changed");
    let elsewhere = dir.join("seed8");
    gen_ok(&other_seed, &elsewhere, &["--quiet", "--no-images"]);
    let copy = |from: &Path, to: &Path| {
        std::fs::remove_dir_all(to).unwrap();
        assert!(std::process::Command::new("cp").arg("-a").arg(from).arg(to).status().unwrap().success());
    };
    let place = "cars04_edges50/val/00000";
    let mut checked = 0;
    for (case, from, says) in [
        ("seed", elsewhere.join(place), "`seed` is 8 there, 11 for this scenario"),
        ("group", PathBuf::from("cars06_edges50/train/00000"), "`group` is \"cars06_edges50\" there"),
    ] {
        let shards: Vec<PathBuf> = (0..2).map(|k| dir.join(format!("{case}-shard{k}"))).collect();
        for (k, shard) in shards.iter().enumerate() {
            gen_ok(&spec, shard, &["--quiet", "--no-images", "--shard", &format!("{k}/2")]);
        }
        let holder = shards.iter().find(|s| s.join(place).is_dir()).expect("a shard holds the scenario");
        let from =
            if from.is_absolute() { from } else { shards.iter().map(|s| s.join(&from)).find(|p| p.is_dir()).unwrap() };
        copy(&from, &holder.join(place));
        let before = hash_tree(holder);
        let merged = dir.join(format!("{case}-merged"));
        let output = run(&["merge", "--out", s(&merged), s(&shards[0]), s(&shards[1])]);
        assert_refused(&output, says);
        assert_eq!(hash_tree(holder), before, "{case}: merge moved something");
        // The whole dataset with the scenario swapped: validate and pack name it.
        let data = dir.join(format!("{case}-data"));
        gen_ok(&spec, &data, &["--quiet", "--no-images"]);
        copy(&from, &data.join(place));
        let report = run(&["validate", s(&data)]);
        assert_eq!(report.status.code(), Some(1), "{case}: {}", String::from_utf8_lossy(&report.stdout));
        assert!(
            String::from_utf8_lossy(&report.stdout).contains(&format!("`{case}` is")),
            "{case}: {}",
            String::from_utf8_lossy(&report.stdout)
        ); // fmt: skip
        assert_refused(&run(&["pack", s(&data), "--out", s(&dir.join(format!("{case}-packed")))]), says);
        // gen's resume takes it as damaged and writes the scenario again.
        gen_ok(&spec, &data, &["--quiet", "--no-images"]);
        assert_valid(&data);
        checked += 1;
    }
    // Tar shards: a pack of another seed's dataset in place of the shard's.
    let shards: Vec<PathBuf> = (0..2).map(|k| dir.join(format!("tar-shard{k}"))).collect();
    for (k, shard) in shards.iter().enumerate() {
        gen_ok(&spec, shard, &["--quiet", "--no-images", "--format", "tar", "--shard", &format!("{k}/2")]);
    }
    let elsewhere_packed = dir.join("seed8-packed");
    gen_ok(&other_seed, &elsewhere_packed, &["--quiet", "--no-images", "--format", "tar"]);
    let pack = "cars04_edges50/val/00000-00000.tar";
    let holder = shards.iter().find(|s| s.join(pack).is_file()).expect("a shard holds the pack");
    std::fs::copy(elsewhere_packed.join(pack), holder.join(pack)).unwrap();
    let output = run(&["merge", "--out", s(&dir.join("tar-merged")), s(&shards[0]), s(&shards[1])]);
    assert_refused(&output, "scenario.json: `seed` is 8 there, 11 for this scenario");
    checked += 1;
    assert_eq!(checked, 3);
}

#[test]
fn merge_moves_only_scenarios_that_hold_their_layouts_files_and_nothing_else() {
    // A user's file inside a shard's scenario was moved into --out, and
    // shard manifests edited to say "effects": false (a field outside the
    // spec's hash) were merged over scenarios holding effects.csv: exit 0,
    // then validate found unexpected files (helper audit).
    let dir = fresh_dir("rule-merge-layout");
    let spec = write_spec(&dir, &toy_spec("layout", &[(4, 0.5)], (2, 1, 1), 20));
    let shards: Vec<PathBuf> = (0..2).map(|k| dir.join(format!("shard{k}"))).collect();
    for (k, shard) in shards.iter().enumerate() {
        gen_ok(&spec, shard, &["--quiet", "--no-images", "--shard", &format!("{k}/2")]);
    }
    let scenario = common::scenario_dirs(&shards[1]).into_iter().next().expect("a scenario");
    std::fs::write(scenario.join("notes.txt"), "mine").unwrap();
    let before: Vec<_> = shards.iter().map(|s| hash_tree(s)).collect();
    let merged = dir.join("merged");
    let output = run(&["merge", "--out", s(&merged), s(&shards[0]), s(&shards[1])]);
    assert_refused(&output, "notes.txt: not a file of the scenario (not in its checksums.sha256)");
    assert_eq!(shards.iter().map(|s| hash_tree(s)).collect::<Vec<_>>(), before, "merge moved something");
    std::fs::remove_file(scenario.join("notes.txt")).unwrap();
    // An empty folder of the user's likewise (validate calls it unexpected).
    std::fs::create_dir(scenario.join("extra")).unwrap();
    let output = run(&["merge", "--out", s(&merged), s(&shards[0]), s(&shards[1])]);
    assert_refused(&output, "extra: not a folder of the scenario");
    std::fs::remove_dir(scenario.join("extra")).unwrap();
    let mut edited = 0;
    for shard in &shards {
        for manifest in std::fs::read_dir(shard.join("shards")).unwrap() {
            let path = manifest.unwrap().path();
            let text = std::fs::read_to_string(&path).unwrap();
            assert!(text.contains("\"effects\": true"), "{text}");
            std::fs::write(&path, text.replace("\"effects\": true", "\"effects\": false")).unwrap();
            edited += 1;
        }
    }
    assert_eq!(edited, 2);
    let output = run(&["merge", "--out", s(&merged), s(&shards[0]), s(&shards[1])]);
    assert_refused(&output, "lists effects.csv, which is not a file of this dataset's scenarios");
    assert!(!merged.join("manifest.json").exists());
}

#[test]
fn force_removes_only_what_causalcity_wrote_and_refuses_whole_otherwise() {
    let dir = fresh_dir("rule-force");
    let data = toy_dataset(&dir);
    let other = write_spec(&dir, &toy_spec("other", &[(4, 0.5)], (1, 1, 1), 20));
    let mine = [
        data.join("cars04_edges50/README.txt"),
        data.join("cars04_edges50/train/00000/notes.txt"),
        data.join("cars04_edges50/train/myanalysis/plot.txt"),
    ];
    for path in &mine {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(path, "the user's").unwrap();
    }
    let before = hash_tree(&data);
    let output = run(&["gen", "--quiet", "--no-images", "--force", "--spec", s(&other), "--out", s(&data)]);
    assert_refused(&output, "--force removes only what causalcity wrote");
    for path in &mine[..2] {
        assert!(stderr(&output).contains(s(path)), "names {}: {}", path.display(), stderr(&output));
    }
    assert!(stderr(&output).contains("myanalysis"), "{}", stderr(&output));
    assert_eq!(hash_tree(&data), before, "nothing was removed");

    // Once the user's files are out, --force replaces the dataset.
    for path in &mine {
        std::fs::remove_file(path).unwrap();
    }
    std::fs::remove_dir(data.join("cars04_edges50/train/myanalysis")).unwrap();
    let output = run(&["gen", "--quiet", "--no-images", "--force", "--spec", s(&other), "--out", s(&data)]);
    assert!(output.status.success(), "{}", stderr(&output));
    assert_valid(&data);
    let manifest = std::fs::read_to_string(data.join("manifest.json")).unwrap();
    assert!(manifest.contains("\"other\""), "{manifest}");
}

#[test]
fn a_link_into_a_dataset_does_not_get_an_export_or_a_picture_inside_it() {
    let dir = fresh_dir("rule-link-inside");
    let data = toy_dataset(&dir);
    let link = dir.join("L");
    std::os::unix::fs::symlink(data.join("cars04_edges50"), &link).unwrap();
    let before = hash_tree(&data);
    let scenario = data.join("cars04_edges50/test/00000");
    let attempts: Vec<Vec<String>> = vec![
        vec!["export".into(), "nri".into(), s(&data).into(), "--out".into(), s(&link.join("exp")).into()],
        vec!["heatmap".into(), s(&data).into(), "--out".into(), s(&link.join("heat.png")).into()],
        vec!["heatmap".into(), s(&data).into(), "--out".into(), s(&data.join("heat.png")).into()],
        vec!["preview".into(), s(&scenario).into(), "--out".into(), s(&scenario.join("p.png")).into()],
    ];
    for args in &attempts {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        assert_refused(&run(&args), "inside a gen dataset");
    }
    assert_eq!(hash_tree(&data), before);
    assert_valid(&data);
}

#[test]
fn a_picture_a_table_or_a_dataset_never_lands_in_an_export_which_export_then_still_updates() {
    let dir = fresh_dir("rule-into-export");
    let data = toy_dataset(&dir);
    let export = dir.join("nri");
    let exported = run(&["export", "nri", s(&data), "--out", s(&export), "--quiet"]);
    assert!(exported.status.success(), "{}", stderr(&exported));
    let spec = write_spec(&dir, &toy_spec("inner", &[(4, 0.5)], (1, 1, 1), 10));
    let before = hash_tree(&export);
    let pred = predictions(&dir);
    let attempts: Vec<Vec<String>> = vec![
        vec!["heatmap".into(), s(&data).into(), "--out".into(), s(&export.join("heat.png")).into()],
        vec!["heatmap".into(), s(&data).into(), "--out".into(), s(&export.join("cars04_edges50/h.png")).into()],
        vec!["evaluate".into(), s(&data).into(), s(&pred).into(), "--csv".into(), s(&export.join("s.csv")).into()],
        vec!["gen".into(), "--spec".into(), s(&spec).into(), "--out".into(), s(&export.join("d")).into()],
    ];
    for args in &attempts {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        assert_refused(&run(&args), &format!("is inside an export ({})", export.display()));
    }
    // Nothing written, and the export is still export's own to update.
    assert_eq!(hash_tree(&export), before);
    let again = run(&["export", "nri", s(&data), "--out", s(&export), "--quiet"]);
    assert!(again.status.success(), "{}", stderr(&again));
    // Folders of that shape that export did not write are no export: a
    // folder of datasets named after their groups, a user's notes in split
    // folders, a user's own arrays per group. A picture goes into each.
    let datasets = dir.join("by-group");
    gen_ok(&spec, &datasets.join("cars04_edges50"), &["--quiet", "--no-images"]);
    let notes = dir.join("notes/cars08_edges50/train");
    std::fs::create_dir_all(&notes).unwrap();
    std::fs::write(notes.join("notes.txt"), "mine").unwrap();
    let arrays = dir.join("arrays/cars08_edges50");
    std::fs::create_dir_all(&arrays).unwrap();
    std::fs::write(arrays.join("scores.npy"), npy(&[2], &[0.5, 1.0])).unwrap();
    let mut drawn_into = 0;
    for picture in [datasets.join("heat.png"), notes.join("heat.png"), arrays.join("heat.png")] {
        let drawn = run(&["heatmap", s(&data), "--out", s(&picture)]);
        assert!(drawn.status.success() && picture.is_file(), "{}: {}", picture.display(), stderr(&drawn));
        drawn_into += 1;
    }
    assert_eq!(drawn_into, 3);
}

#[test]
fn an_export_cut_off_midway_is_still_an_export_nothing_lands_in_it_and_the_rerun_finishes_it() {
    // A cut-off export (its lock left, arrays still staged as .partial,
    // NS-DR scenario folders without their annotations yet) took a picture
    // (exit 0), and the rerun that would finish the export then refused the
    // folder: "holds files it did not write".
    let dir = fresh_dir("rule-into-cut-export");
    let spec = write_spec(&dir, &toy_spec("cut", &[(4, 0.5)], (2, 1, 1), 8));
    let data = dir.join("data");
    gen_ok(&spec, &data, &["--quiet"]);
    let (nri, nsdr) = (dir.join("nri"), dir.join("nsdr"));
    for (kind, out) in [("nri", &nri), ("nsdr", &nsdr)] {
        let output = run(&["export", kind, s(&data), "--out", s(out), "--quiet"]);
        assert!(output.status.success(), "{}", stderr(&output));
    }
    let finished: Vec<_> = [&nri, &nsdr].iter().map(|out| hash_tree(out)).collect();
    // Cut off: the lock file a killed export leaves, an array not yet
    // moved into place; NS-DR writes a scenario's folder, its annotations
    // (staged, then renamed), then links its frames: a scenario folder
    // still empty, one with its annotations staged, a split folder just made.
    std::fs::write(nri.join(".causalcity.lock"), "pid 1 on host: export nri").unwrap();
    let array = nri.join("cars04_edges50/loc_train.npy");
    std::fs::rename(&array, array.with_extension("npy.partial")).unwrap();
    std::fs::write(nsdr.join(".causalcity.lock"), "pid 1 on host: export nsdr").unwrap();
    let mut scenarios: Vec<PathBuf> =
        std::fs::read_dir(nsdr.join("cars04_edges50/train")).unwrap().map(|e| e.unwrap().path()).collect();
    scenarios.sort();
    assert!(scenarios.len() >= 2, "{scenarios:?}");
    std::fs::remove_dir_all(&scenarios[0]).unwrap();
    std::fs::create_dir(&scenarios[0]).unwrap();
    for link in ["rgb", "mask"] {
        std::fs::remove_file(scenarios[1].join(link)).unwrap();
    }
    let half = scenarios[1].join("annotations.json");
    std::fs::rename(&half, half.with_extension("json.partial")).unwrap();
    std::fs::remove_dir_all(nsdr.join("cars04_edges50/val")).unwrap();
    std::fs::create_dir(nsdr.join("cars04_edges50/val")).unwrap();
    let cut: Vec<_> = [&nri, &nsdr].iter().map(|out| hash_tree(out)).collect();
    let mut refused = 0;
    for out in [&nri, &nsdr] {
        for picture in [out.join("heat.png"), out.join("cars04_edges50/heat.png")] {
            let drawn = run(&["heatmap", s(&data), "--out", s(&picture)]);
            assert_refused(&drawn, &format!("is inside an export ({})", out.display()));
            refused += 1;
        }
    }
    assert_eq!(refused, 4);
    let now: Vec<_> = [&nri, &nsdr].iter().map(|out| hash_tree(out)).collect();
    assert_eq!(now, cut, "nothing written into the cut-off exports");
    // The same export run again finishes each, as one whole run wrote it.
    for (kind, out) in [("nri", &nri), ("nsdr", &nsdr)] {
        let output = run(&["export", kind, s(&data), "--out", s(out), "--quiet"]);
        assert!(output.status.success(), "{}", stderr(&output));
    }
    let again: Vec<_> = [&nri, &nsdr].iter().map(|out| hash_tree(out)).collect();
    assert_eq!(again, finished);
    // Without a lock, a folder of that shape holding frames but no
    // annotations (a user's copies) is no export: a picture goes in.
    let copies = dir.join("copies/cars04_edges50/train/00000/rgb");
    std::fs::create_dir_all(&copies).unwrap();
    let picture = dir.join("copies/heat.png");
    let drawn = run(&["heatmap", s(&data), "--out", s(&picture)]);
    assert!(drawn.status.success() && picture.is_file(), "{}", stderr(&drawn));
}

#[test]
fn an_export_never_writes_through_a_link_planted_in_its_folder() {
    // export nri wrote through a link at its staged loc_train.npy.partial
    // (the file it pointed to, outside --out, became an array), and export
    // nsdr through a linked split folder (helper audit).
    let dir = fresh_dir("rule-export-links");
    let spec = write_spec(&dir, &toy_spec("links", &[(4, 0.5)], (2, 1, 1), 8));
    let data = dir.join("data");
    gen_ok(&spec, &data, &["--quiet"]);
    let victim = dir.join("victim.txt");
    std::fs::write(&victim, "keep me").unwrap();
    let elsewhere = dir.join("elsewhere");
    std::fs::create_dir(&elsewhere).unwrap();
    let nri = dir.join("nri");
    std::fs::create_dir_all(nri.join("cars04_edges50")).unwrap();
    std::os::unix::fs::symlink(&victim, nri.join("cars04_edges50/loc_train.npy.partial")).unwrap();
    let nsdr = dir.join("nsdr");
    std::fs::create_dir_all(nsdr.join("cars04_edges50")).unwrap();
    std::os::unix::fs::symlink(&elsewhere, nsdr.join("cars04_edges50/train")).unwrap();
    for (kind, out) in [("nri", &nri), ("nsdr", &nsdr)] {
        assert_refused(&run(&["export", kind, s(&data), "--out", s(out), "--quiet"]), "is a symbolic link");
    }
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "keep me");
    assert_eq!(std::fs::read_dir(&elsewhere).unwrap().count(), 0, "nothing written outside --out");
    // Without the links, both export.
    std::fs::remove_file(nri.join("cars04_edges50/loc_train.npy.partial")).unwrap();
    std::fs::remove_file(nsdr.join("cars04_edges50/train")).unwrap();
    for (kind, out) in [("nri", &nri), ("nsdr", &nsdr)] {
        let output = run(&["export", kind, s(&data), "--out", s(out), "--quiet"]);
        assert!(output.status.success(), "{}", stderr(&output));
    }
}

#[test]
fn an_export_refuses_a_folder_holding_the_users_subfolders() {
    let dir = fresh_dir("rule-export-foreign");
    let data = toy_dataset(&dir);
    let out = dir.join("export");
    std::fs::create_dir_all(out.join("mine")).unwrap();
    std::fs::write(out.join("mine/loc_train.npy"), "the user's").unwrap();
    let output = run(&["export", "nri", s(&data), "--out", s(&out)]);
    assert_refused(&output, "\"mine\"");
    assert_eq!(std::fs::read_to_string(out.join("mine/loc_train.npy")).unwrap(), "the user's");
    assert_eq!(std::fs::read_dir(&out).unwrap().count(), 1, "nothing was added");
}

#[test]
fn merge_names_a_shard_folder_given_twice() {
    let dir = fresh_dir("rule-merge-twice");
    let spec = write_spec(&dir, &toy_spec("twice", &[(4, 0.5)], (2, 1, 1), 20));
    let shard = dir.join("a0");
    gen_ok(&spec, &shard, &["--quiet", "--no-images", "--shard", "0/2"]);
    let before = hash_tree(&shard);
    let output = run(&["merge", "--out", s(&dir.join("m")), s(&shard), s(&shard)]);
    assert_refused(&output, "is given twice");
    assert!(!stderr(&output).contains("another causalcity process"), "{}", stderr(&output));
    assert_eq!(hash_tree(&shard), before);
}

#[test]
fn a_limit_at_or_above_every_split_is_the_same_dataset() {
    let dir = fresh_dir("rule-limit");
    let spec = write_spec(&dir, &toy_spec("limits", &[(4, 0.5)], (2, 1, 1), 20));
    let data = dir.join("data");
    gen_ok(&spec, &data, &["--quiet", "--no-images", "--limit", "5"]);
    let before = hash_tree(&data);
    for limit in [["--limit", "3"], ["--limit", "2"]] {
        let output = gen_ok(&spec, &data, &["--no-images", "--json", limit[0], limit[1]]);
        let summary: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
        assert_eq!((summary["written"].as_u64(), summary["skipped"].as_u64()), (Some(0), Some(4)), "{summary}");
    }
    // A limit that leaves fewer scenarios in a split is still refused.
    let output = run(&["gen", "--quiet", "--no-images", "--limit", "1", "--spec", s(&spec), "--out", s(&data)]);
    assert_refused(&output, "others would stay behind");
    let after = hash_tree(&data);
    let scenarios = |tree: &std::collections::BTreeMap<String, String>| {
        tree.iter()
            .filter(|(k, _)| !k.ends_with("manifest.json"))
            .map(|(k, v)| (k.clone(), v.clone()))
            .collect::<Vec<_>>()
    };
    assert_eq!(scenarios(&after), scenarios(&before));
    assert_valid(&data);
}

#[test]
fn stats_and_baseline_exit_2_where_there_is_no_finished_dataset_as_evaluate_does() {
    let dir = fresh_dir("rule-exit-codes");
    let missing = dir.join("nonexistent");
    for command in ["stats", "baseline", "evaluate"] {
        let mut args = vec![command, s(&missing)];
        if command == "evaluate" {
            args.push("pred.npz");
        }
        let output = run(&args);
        assert_refused(&output, "manifest.json");
    }
}

#[test]
fn a_file_size_limit_ends_in_a_failure_not_a_panic() {
    let dir = fresh_dir("rule-ulimit");
    let spec = write_spec(&dir, &toy_spec("ulimit", &[(4, 0.5)], (1, 1, 1), 20));
    let out = dir.join("out");
    let script = format!(
        "ulimit -f 0; exec '{}' gen --quiet --no-images --spec '{}' --out '{}'",
        common::bin(),
        s(&spec),
        s(&out)
    );
    let output = std::process::Command::new("sh").arg("-c").arg(&script).output().unwrap();
    assert_eq!(output.status.code(), Some(1), "{}", stderr(&output));
    assert!(stderr(&output).contains("File too large"), "{}", stderr(&output));
    // Its stderr a file too (which the limit also stops): still exit 1.
    let log = dir.join("err.txt");
    let script = format!("{script} 2>'{}'", s(&log));
    let output = std::process::Command::new("sh").arg("-c").arg(&script).output().unwrap();
    assert_eq!(output.status.code(), Some(1));
}

#[test]
fn a_sweep_made_without_images_is_not_kept_by_a_run_with_images() {
    let dir = fresh_dir("rule-sweep-images");
    let spec = write_spec(&dir, &common::city_spec("sw", &[(4, 0.5)], (1, 1, 1), 30, "{}"));
    let out = dir.join("sweep");
    let args = ["counterfactual", "--sweep", s(&spec), "--out", s(&out), "--quiet", "--kinds", "stop"];
    let first = run(&[&args[..], &["--no-images"]].concat());
    assert!(first.status.success(), "{}", stderr(&first));
    let before = hash_tree(&out);
    assert_refused(&run(&args), "it was made with --no-images");
    assert_eq!(hash_tree(&out), before);
    let again = run(&[&args[..], &["--no-images", "--json"]].concat());
    assert!(again.status.success(), "{}", stderr(&again));
    let summary: serde_json::Value = serde_json::from_slice(&again.stdout).unwrap();
    assert_eq!(summary["kept"], 3, "{summary}");
}

#[test]
fn rewriting_a_damaged_scenario_never_removes_the_users_files_in_it() {
    let dir = fresh_dir("rule-damaged-user-file");
    let data = toy_dataset(&dir);
    let spec = dir.join("spec.json");
    let scenario = data.join("cars04_edges50/train/00000");
    let notes = scenario.join("notes.txt");
    std::fs::write(&notes, "the user's").unwrap();
    let mut poses = std::fs::OpenOptions::new().append(true).open(scenario.join("poses.csv")).unwrap();
    poses.write_all(b"damage\n").unwrap();
    drop(poses);
    // (The run stops there, its manifest saying the dataset is unfinished.)
    let group = data.join("cars04_edges50");
    let before = hash_tree(&group);
    let output = run(&["gen", "--quiet", "--no-images", "--spec", s(&spec), "--out", s(&data)]);
    assert_refused(&output, "are not files causalcity wrote there");
    assert!(stderr(&output).contains(s(&notes)), "names the file: {}", stderr(&output));
    assert_eq!(hash_tree(&group), before, "nothing was replaced");

    // Without the user's file, the damaged scenario is written again.
    std::fs::remove_file(&notes).unwrap();
    let output = run(&["gen", "--quiet", "--no-images", "--spec", s(&spec), "--out", s(&data)]);
    assert!(output.status.success(), "{}", stderr(&output));
    assert_valid(&data);
}

#[test]
fn a_linked_split_folder_is_never_written_through_by_gen_merge_or_pack() {
    let dir = fresh_dir("rule-linked-split");
    let data = toy_dataset(&dir);
    let spec = dir.join("spec.json");
    // Another dataset's val folder, linked in place of this one's.
    let other = dir.join("other");
    let other_specs = dir.join("other-spec");
    std::fs::create_dir_all(&other_specs).unwrap();
    let other_spec = write_spec(&other_specs, &toy_spec("other", &[(4, 0.5)], (1, 1, 1), 30));
    gen_ok(&other_spec, &other, &["--quiet", "--no-images"]);
    let other_before = hash_tree(&other);
    let val = data.join("cars04_edges50/val");
    std::fs::remove_dir_all(&val).unwrap();
    std::os::unix::fs::symlink(other.join("cars04_edges50/val"), &val).unwrap();
    let output = run(&["gen", "--quiet", "--no-images", "--spec", s(&spec), "--out", s(&data)]);
    assert_refused(&output, "never writes through a link");
    assert!(stderr(&output).contains(s(&val)), "names the link: {}", stderr(&output));

    // merge into a shard folder whose split is a link.
    let (a, b) = (dir.join("shard0"), dir.join("shard1"));
    gen_ok(&spec, &a, &["--quiet", "--no-images", "--shard", "0/2"]);
    gen_ok(&spec, &b, &["--quiet", "--no-images", "--shard", "1/2"]);
    let linked = a.join("cars04_edges50/test");
    let _ = std::fs::remove_dir_all(&linked);
    std::os::unix::fs::symlink(other.join("cars04_edges50/test"), &linked).unwrap();
    assert_refused(&run(&["merge", "--out", s(&a), s(&b)]), "never writes through a link");

    // pack resuming into a folder whose split is a link.
    std::fs::remove_file(&val).unwrap();
    let output = run(&["gen", "--quiet", "--no-images", "--spec", s(&spec), "--out", s(&data)]);
    assert!(output.status.success(), "{}", stderr(&output));
    let packed = dir.join("packed");
    assert!(run(&["pack", "--quiet", "--out", s(&packed), s(&data)]).status.success());
    let train = packed.join("cars04_edges50/train");
    std::fs::remove_dir_all(&train).unwrap();
    std::os::unix::fs::symlink(other.join("cars04_edges50/train"), &train).unwrap();
    assert_refused(&run(&["pack", "--quiet", "--out", s(&packed), s(&data)]), "never writes through a link");
    assert_eq!(hash_tree(&other), other_before, "the other dataset is as it was");
}

#[test]
fn run_and_counterfactual_never_replace_a_folder_holding_the_users_files() {
    let dir = fresh_dir("rule-run-folder");
    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/examples/stop-the-leader.json");
    let text = std::fs::read_to_string(&example).unwrap();
    let name = common::read_json(&example)[0]["Name"].as_str().unwrap().to_string();
    // The scenario file kept inside the folder its scenario would be written to.
    let out = dir.join("out");
    let folder = out.join(&name);
    std::fs::create_dir_all(&folder).unwrap();
    let input = folder.join("scenario-file.json");
    std::fs::write(&input, &text).unwrap();
    let output = run(&["run", "--no-images", "--scenario", s(&input), "--out", s(&out)]);
    assert_refused(&output, "never writes onto its own input");
    assert_eq!(std::fs::read_to_string(&input).unwrap(), text, "its input is untouched");

    // A rerun into its own output replaces its own folder; a user's file
    // inside a counterfactual's factual/ stops the rerun.
    let cf = dir.join("cf");
    let args = ["counterfactual", "--no-images", "--scenario", s(&example), "--out", s(&cf)];
    assert!(run(&args).status.success());
    assert!(run(&args).status.success(), "a rerun replaces what it wrote");
    let notes = cf.join(&name).join("factual/notes.txt");
    std::fs::write(&notes, "the user's").unwrap();
    let before = hash_tree(&cf);
    assert_refused(&run(&args), "are not files causalcity wrote there");
    assert_eq!(hash_tree(&cf), before, "nothing was replaced");
    // `run` into the counterfactual's folder would replace the pair.
    let output = run(&["run", "--no-images", "--scenario", s(&example), "--out", s(&cf)]);
    assert_refused(&output, "holds a counterfactual pair");
    assert_eq!(hash_tree(&cf), before, "nothing was replaced");

    // A user's file at the top of the pair folder stops the rerun too (it
    // was written around, exit 0).
    std::fs::remove_file(&notes).unwrap();
    let top = cf.join(&name).join("notes.txt");
    std::fs::write(&top, "the user's").unwrap();
    let before = hash_tree(&cf);
    let output = run(&args);
    assert_refused(&output, "are not files causalcity wrote there");
    assert!(String::from_utf8_lossy(&output.stderr).contains("notes.txt"), "the file is named");
    assert_eq!(hash_tree(&cf), before, "nothing was replaced");

    // `counterfactual` into a `run` folder would mix the two (it wrote its
    // pair beside run's files, exit 0, and run then refused the folder).
    let ran = dir.join("ran");
    assert!(run(&["run", "--no-images", "--scenario", s(&example), "--out", s(&ran)]).status.success());
    let before = hash_tree(&ran);
    let output = run(&["counterfactual", "--no-images", "--scenario", s(&example), "--out", s(&ran)]);
    assert_refused(&output, "holds a scenario of `causalcity run`");
    assert_eq!(hash_tree(&ran), before, "run's folder is as it was");
}

#[test]
fn a_file_of_several_scenarios_writes_none_when_one_folder_is_refused() {
    let dir = fresh_dir("rule-run-several");
    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/examples/stop-the-leader.json");
    let mut scenarios: Vec<serde_json::Value> = serde_json::from_slice(&std::fs::read(&example).unwrap()).unwrap();
    let mut second = scenarios[0].clone();
    second["Name"] = serde_json::json!("second_one");
    scenarios.push(second);
    let file = dir.join("two.json");
    std::fs::write(&file, serde_json::to_vec_pretty(&scenarios).unwrap()).unwrap();
    for command in ["run", "counterfactual"] {
        let out = dir.join(command);
        std::fs::create_dir_all(out.join("second_one")).unwrap();
        std::fs::write(out.join("second_one/notes.txt"), "the user's").unwrap();
        let before = hash_tree(&out);
        let output = run(&[command, "--no-images", "--scenario", s(&file), "--out", s(&out)]);
        assert_refused(&output, "notes.txt");
        assert_eq!(hash_tree(&out), before, "{command}: the first scenario was not written either");
    }
}

#[test]
fn an_out_that_is_a_file_or_lies_under_one_is_bad_input() {
    let dir = fresh_dir("rule-out-file");
    let spec = write_spec(&dir, &toy_spec("rule", &[(4, 0.5)], (1, 1, 1), 20));
    let file = dir.join("notes.txt");
    std::fs::write(&file, "the user's").unwrap();
    let dangling = dir.join("dangling");
    std::os::unix::fs::symlink(dir.join("nowhere"), &dangling).unwrap();
    for (out, says) in [
        (file.clone(), "is a file, not a folder"),
        (file.join("sub"), "which is not a folder"),
        (dangling.clone(), "is a symbolic link"),
    ] {
        let scenario = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/examples/stop-the-leader.json");
        let commands = [
            vec!["gen", "--quiet", "--no-images", "--spec", s(&spec)],
            vec!["run", "--no-images", "--scenario", s(&scenario)],
        ];
        for command in commands {
            let mut args = command.clone();
            args.extend(["--out", s(&out)]);
            let output = run(&args);
            assert_refused(&output, says);
        }
    }
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "the user's");
    assert!(!dir.join("nowhere").exists());
}

#[test]
fn only_what_a_checksum_listing_names_counts_as_causalcitys() {
    let dir = fresh_dir("rule-own-files");
    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/examples/stop-the-leader.json");
    let name = common::read_json(&example)[0]["Name"].as_str().unwrap().to_string();
    // A user's file of the name causalcity writes, in a folder causalcity
    // never finished (no listing): the user's, not to be overwritten.
    let out = dir.join("out");
    std::fs::create_dir_all(out.join(&name)).unwrap();
    let mine = out.join(&name).join("scenario.json");
    std::fs::copy(&example, &mine).unwrap();
    assert_refused(&run(&["run", "--no-images", "--scenario", s(&mine), "--out", s(&out)]), "scenario.json");
    assert_eq!(std::fs::read(&mine).unwrap(), std::fs::read(&example).unwrap());

    // In a damaged scenario: a file named like a leftover, and a folder
    // with a checksum listing of its own, are the user's too.
    let data = toy_dataset(&dir);
    let spec = dir.join("spec.json");
    let scenario = data.join("cars04_edges50/train/00000");
    std::fs::remove_file(scenario.join("poses.csv")).unwrap();
    std::fs::write(scenario.join("draft.partial"), "the user's").unwrap();
    std::fs::create_dir(scenario.join("backup")).unwrap();
    std::fs::write(scenario.join("backup/notes.txt"), "the user's").unwrap();
    let sum = "8a4fc2b8a4b1e0cb7d3c85f5d1b1a5cfa45d3a1a0e2f13e9c3b1dbce5e1b1f1d  notes.txt\n";
    std::fs::write(scenario.join("backup/checksums.sha256"), sum).unwrap();
    let output = run(&["gen", "--quiet", "--no-images", "--spec", s(&spec), "--out", s(&data)]);
    assert_refused(&output, "draft.partial");
    assert!(stderr(&output).contains("backup/notes.txt"), "{}", stderr(&output));
    assert!(scenario.join("draft.partial").exists() && scenario.join("backup/notes.txt").exists());
}

#[test]
fn merge_never_moves_scenarios_through_a_link_in_a_shard() {
    let dir = fresh_dir("rule-merge-shard-link");
    let spec = write_spec(&dir, &toy_spec("rule", &[(4, 0.5)], (2, 1, 1), 20));
    let (a, b) = (dir.join("shard0"), dir.join("shard1"));
    gen_ok(&spec, &a, &["--quiet", "--no-images", "--shard", "0/2"]);
    gen_ok(&spec, &b, &["--quiet", "--no-images", "--shard", "1/2"]);
    // One of b's splits lives elsewhere, linked in.
    let elsewhere = dir.join("elsewhere");
    let split = std::fs::read_dir(b.join("cars04_edges50")).unwrap().flatten().next().unwrap().path();
    std::fs::rename(&split, &elsewhere).unwrap();
    std::os::unix::fs::symlink(&elsewhere, &split).unwrap();
    let before = hash_tree(&elsewhere);
    assert_refused(&run(&["merge", "--out", s(&a), s(&b)]), "never writes through a link");
    assert_eq!(hash_tree(&elsewhere), before, "nothing moved out of it");
}

#[test]
fn merge_never_takes_a_link_at_a_scenario_folder_as_the_scenario() {
    let dir = fresh_dir("rule-merge-scenario-link");
    let spec = write_spec(&dir, &toy_spec("rule", &[(4, 0.5)], (2, 1, 1), 20));
    let (a, b) = (dir.join("shard0"), dir.join("shard1"));
    gen_ok(&spec, &a, &["--quiet", "--no-images", "--shard", "0/2"]);
    gen_ok(&spec, &b, &["--quiet", "--no-images", "--shard", "1/2"]);
    let scenarios = |shard: &Path| -> Vec<PathBuf> {
        let mut found = Vec::new();
        for split in std::fs::read_dir(shard.join("cars04_edges50")).unwrap().flatten() {
            found.extend(std::fs::read_dir(split.path()).unwrap().flatten().map(|e| e.path()));
        }
        found.sort();
        found
    };
    let (in_a, in_b) = (scenarios(&a), scenarios(&b));
    assert!(!in_a.is_empty() && !in_b.is_empty(), "both shards hold scenarios");
    // In --out, b's first scenario as a link to a copy of it elsewhere: not
    // the scenario in place (merge kept the link and dropped b's copy).
    let copy = dir.join("copy");
    let place = a.join(in_b[0].strip_prefix(&b).unwrap());
    std::fs::create_dir_all(place.parent().unwrap()).unwrap();
    assert!(std::process::Command::new("cp").args(["-r", s(&in_b[0]), s(&copy)]).status().unwrap().success());
    std::os::unix::fs::symlink(&copy, &place).unwrap();
    let (before_a, before_b) = (hash_tree(&a), hash_tree(&b));
    let output = run(&["merge", "--out", s(&a), s(&b)]);
    assert_refused(&output, "never writes through a link");
    assert!(stderr(&output).contains(s(&place)), "names the link: {}", stderr(&output));
    assert_eq!((hash_tree(&a), hash_tree(&b)), (before_a, before_b), "nothing moved");
    assert!(in_b[0].is_dir(), "b's scenario is still there");

    // In a shard, a scenario folder as a link: never moved into --out.
    std::fs::remove_file(&place).unwrap();
    let moved = dir.join("moved");
    std::fs::rename(&in_b[0], &moved).unwrap();
    std::os::unix::fs::symlink(&moved, &in_b[0]).unwrap();
    let output = run(&["merge", "--out", s(&a), s(&b)]);
    assert_refused(&output, "never writes through a link");
    assert!(stderr(&output).contains(s(&in_b[0])), "names the link: {}", stderr(&output));
    assert!(!place.exists() && std::fs::symlink_metadata(&place).is_err(), "no link landed in --out");
}

#[test]
fn a_link_to_a_file_inside_a_scenario_is_never_kept_as_its_file() {
    let dir = fresh_dir("rule-file-link");
    let data = toy_dataset(&dir);
    let scenario = data.join("cars04_edges50/train/00000");
    // poses.csv lives elsewhere, linked in: the same bytes, so checksums pass.
    let elsewhere = dir.join("elsewhere-poses.csv");
    std::fs::rename(scenario.join("poses.csv"), &elsewhere).unwrap();
    std::os::unix::fs::symlink(&elsewhere, scenario.join("poses.csv")).unwrap();
    let before = std::fs::read(&elsewhere).unwrap();
    let report = run(&["validate", s(&data)]);
    let said = String::from_utf8_lossy(&report.stdout).into_owned() + &stderr(&report);
    assert_eq!(report.status.code(), Some(1), "{said}");
    assert!(said.contains(&format!("{}: a symbolic link", s(&scenario.join("poses.csv")))), "{said}");
    // gen writes the scenario again, with a file of its own; the other file stays.
    let spec = dir.join("spec.json");
    let output = run(&["gen", "--quiet", "--no-images", "--spec", s(&spec), "--out", s(&data)]);
    assert!(output.status.success(), "{}", stderr(&output));
    let meta = std::fs::symlink_metadata(scenario.join("poses.csv")).unwrap();
    assert!(meta.is_file() && !meta.file_type().is_symlink());
    assert_eq!(std::fs::read(&elsewhere).unwrap(), before);
    assert_valid(&data);

    // merge does not move a scenario holding a link.
    let (a, b) = (dir.join("shard0"), dir.join("shard1"));
    gen_ok(&spec, &a, &["--quiet", "--no-images", "--shard", "0/2"]);
    gen_ok(&spec, &b, &["--quiet", "--no-images", "--shard", "1/2"]);
    let split = b.join("cars04_edges50/train");
    let linked = std::fs::read_dir(&split).unwrap().flatten().next().expect("b holds a train scenario").path();
    let moved = dir.join("moved-poses.csv");
    std::fs::rename(linked.join("poses.csv"), &moved).unwrap();
    std::os::unix::fs::symlink(&moved, linked.join("poses.csv")).unwrap();
    let (before_a, before_b) = (hash_tree(&a), hash_tree(&b));
    let output = run(&["merge", "--out", s(&a), s(&b)]);
    assert_refused(&output, "a symbolic link");
    assert_eq!((hash_tree(&a), hash_tree(&b)), (before_a, before_b), "nothing moved");
}

#[test]
fn nothing_is_written_into_a_dataset_still_being_written_in_shards() {
    // A gen --shard folder has no manifest.json until its merge: a heatmap
    // or an export written there went in, and the next shard and the
    // merge then refused the folder for holding it.
    let dir = fresh_dir("write-rule-shards");
    let source = toy_dataset(&dir);
    let spec = write_spec(&dir, &toy_spec("sharded", &[(4, 0.5)], (2, 1, 1), 10));
    let sharded = dir.join("sharded");
    gen_ok(&spec, &sharded, &["--no-images", "--shard", "0/2", "-q"]);
    for (args, written) in [
        (vec!["heatmap", s(&source), "--out", s(&sharded.join("h.png"))], sharded.join("h.png")),
        (vec!["heatmap", s(&source), "--out", s(&sharded.join("shards/h.png"))], sharded.join("shards/h.png")),
        (vec!["export", "nri", s(&source), "--out", s(&sharded.join("nri"))], sharded.join("nri")),
    ] {
        assert_refused(&run(&args), "written in shards");
        assert!(!written.exists(), "{}", written.display());
    }
    gen_ok(&spec, &sharded, &["--no-images", "--shard", "1/2", "-q"]);
    let merged = run(&["merge", "--out", s(&sharded)]);
    assert!(merged.status.success(), "{}", stderr(&merged));
    assert_valid(&sharded);
}

#[test]
fn gen_force_never_removes_the_network_its_spec_reads() {
    // A spec naming the dataset's own copy of its network (networks/):
    // --force deleted that file, its own input, and wrote it again
    // (helper audit).
    let dir = fresh_dir("rule-force-own-network");
    let network = dir.join("grid2.net.xml");
    std::fs::copy(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/sumo/grid2-arrows.net.xml"), &network)
        .unwrap();
    let spec_text = |seed: u32, sumo: &str| {
        format!(
            r#"{{"name": "ownnet", "world": "city", "seed": {seed}, "frames": 10, "frame_interval": 1.0,
               "image": {{"width": 128, "height": 96}}, "groups": [{{"cars": 4, "edge_proportion": 0.5}}],
               "splits": {{"train": 1, "val": 1, "test": 1}}, "actions_per_car": 3, "map": {{"sumo": "{sumo}"}}}}"#
        )
    };
    let first = dir.join("first.json");
    std::fs::write(&first, spec_text(2, "grid2.net.xml")).unwrap();
    let data = dir.join("data");
    gen_ok(&first, &data, &["--quiet", "--no-images"]);
    let kept = data.join("networks/grid2.net.xml");
    let inode = std::os::unix::fs::MetadataExt::ino(&std::fs::metadata(&kept).unwrap());
    let before = hash_tree(&data);
    let again = dir.join("again.json");
    std::fs::write(&again, spec_text(3, "data/networks/grid2.net.xml")).unwrap();
    let output = run(&["gen", "--quiet", "--no-images", "--force", "--spec", s(&again), "--out", s(&data)]);
    assert_refused(&output, "the spec's map.sumo network lies inside");
    assert!(stderr(&output).contains("Nothing was removed"), "{}", stderr(&output));
    assert_eq!(hash_tree(&data), before, "the dataset was touched");
    assert_eq!(
        std::os::unix::fs::MetadataExt::ino(&std::fs::metadata(&kept).unwrap()),
        inode,
        "the network was rewritten"
    );
}

#[test]
fn gen_force_never_removes_a_dataset_open_for_reading_and_no_reader_opens_one_being_removed() {
    // Readers took no lock: gen --force removed a dataset under a running
    // export, pack or training loop, which then failed part way.
    let dir = fresh_dir("rule-force-reader");
    let data = toy_dataset(&dir);
    let before = hash_tree(&data);
    let other = dir.join("other.json");
    std::fs::write(&other, toy_spec("rule", &[(4, 0.5)], (2, 1, 1), 20)).unwrap();
    let force = || run(&["gen", "--quiet", "--no-images", "--force", "--spec", s(&other), "--out", s(&data)]);
    // The dataset every reading command opens, held as they hold it.
    let reader = causalcity::dataset::Dataset::open(&data).unwrap();
    // A plain gen rerun replaces the manifest whole: the hold is on the
    // folder, so it holds on (on the manifest, it held the file replaced).
    let spec = dir.join("spec.json");
    gen_ok(&spec, &data, &["--quiet", "--no-images"]);
    let output = force();
    assert_refused(&output, "is open for reading");
    assert!(stderr(&output).contains("Nothing was removed"), "{}", stderr(&output));
    assert_eq!(hash_tree(&data), before, "the dataset was touched");
    // Readers share: a second one reads on.
    let stats = run(&["stats", s(&data)]);
    assert!(stats.status.success(), "{}", stderr(&stats));
    drop(reader);
    let output = force();
    assert!(output.status.success(), "{}", stderr(&output));
    assert_valid(&data);
    assert_ne!(hash_tree(&data), before, "--force wrote nothing new once the reader closed");
    // While gen --force removes a dataset it holds the folder alone, as
    // here: a reader refuses to open it rather than read it half gone.
    let removing = causalcity::output::claim::exclude_readers(&data).unwrap();
    assert!(removing.is_some(), "the folder was not held");
    for command in ["stats", "validate"] {
        let output = run(&[command, s(&data)]);
        assert_refused(&output, "is being removed by gen --force");
    }
    drop(removing);
    assert_valid(&data);
}
