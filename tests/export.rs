//! `export nri`: shapes, dtypes and values of the .npy files against the CSVs
//! and scenario.json, for both layouts and directed / undirected edges.

mod common;
use common::*;
use std::path::Path;

fn load<T: npyz::Deserialize>(path: &Path) -> (Vec<u64>, Vec<T>, String) {
    let npy = npyz::NpyFile::new(std::io::BufReader::new(std::fs::File::open(path).unwrap())).unwrap();
    let shape = npy.shape().to_vec();
    let dtype = npy.dtype().descr();
    (shape, npy.into_vec::<T>().unwrap(), dtype)
}

#[test]
fn nri_exports_match_the_pose_logs_in_both_layouts() {
    let dir = fresh_dir("export-nri");
    let spec = write_spec(&dir, &toy_spec("nri", &[(4, 0.5), (8, 0.8)], (3, 2, 1), 20));
    let data = dir.join("data");
    gen_ok(&spec, &data, &["--quiet", "--no-images"]);
    for (layout, directed, suffix) in [("causalcity", false, ""), ("nri", false, "_nri"), ("causalcity", true, "_dir")]
    {
        let out = dir.join(format!("out{suffix}"));
        let mut args =
            vec!["export", "nri", data.to_str().unwrap(), "--out", out.to_str().unwrap(), "--layout", layout];
        if directed {
            args.push("--directed");
        }
        if !suffix.is_empty() {
            args.extend(["--suffix", suffix]);
        }
        let output = run(&args);
        assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
        for (group, cars) in [("cars04_edges50", 4usize), ("cars08_edges80", 8)] {
            for (split, nri_split, count) in [("train", "train", 3usize), ("val", "valid", 2), ("test", "test", 1)] {
                let file = |kind: &str| out.join(group).join(format!("{kind}_{nri_split}{suffix}.npy"));
                let (loc_shape, loc, loc_dtype) = load::<f32>(&file("loc"));
                let (vel_shape, vel, _) = load::<f32>(&file("vel"));
                let (edge_shape, edges, edge_dtype) = load::<i64>(&file("edges"));
                assert_eq!(loc_dtype, "'<f4'");
                assert_eq!(edge_dtype, "'<i8'");
                let expected = if layout == "nri" {
                    vec![count as u64, 20, 2, cars as u64]
                } else {
                    vec![count as u64, 20, cars as u64, 2]
                };
                assert_eq!(loc_shape, expected);
                assert_eq!(vel_shape, expected);
                assert_eq!(edge_shape, vec![count as u64, cars as u64, cars as u64]);
                let at = |s: usize, f: usize, c: usize, axis: usize| {
                    if layout == "nri" {
                        ((s * 20 + f) * 2 + axis) * cars + c
                    } else {
                        ((s * 20 + f) * cars + c) * 2 + axis
                    }
                };
                for s in 0..count {
                    let scenario_dir = data.join(group).join(split).join(format!("{s:05}"));
                    for p in read_poses(&scenario_dir.join("poses.csv")) {
                        let (f, c) = (p.frame as usize, p.car as usize);
                        assert_eq!(loc[at(s, f, c, 0)], p.px as f32);
                        assert_eq!(loc[at(s, f, c, 1)], p.py as f32);
                        if f > 0 {
                            let back = at(s, f - 1, c, 0);
                            assert_eq!(vel[at(s, f, c, 0)], loc[at(s, f, c, 0)] - loc[back]);
                        }
                    }
                    let scenario = read_scenario(&scenario_dir);
                    let mut expected_edges = vec![0i64; cars * cars];
                    if layout == "causalcity" {
                        for i in 0..cars {
                            expected_edges[i * cars + i] = 1;
                        }
                    }
                    for [leader, follower] in &scenario.edges {
                        let (l, f) = (*leader as usize, *follower as usize);
                        expected_edges[f * cars + l] = 1;
                        if !directed {
                            expected_edges[l * cars + f] = 1;
                        }
                    }
                    assert_eq!(
                        &edges[s * cars * cars..(s + 1) * cars * cars],
                        &expected_edges[..],
                        "{group} {split} {s}"
                    );
                }
            }
        }
    }
    // An unfinished or foreign folder is refused with a clear message.
    let output = run(&["export", "nri", dir.to_str().unwrap(), "--out", dir.join("x").to_str().unwrap()]);
    assert_eq!(output.status.code(), Some(2), "a folder that is no dataset is bad input");
    assert!(String::from_utf8_lossy(&output.stderr).contains("no manifest.json"));
}

#[test]
fn dynamic_edges_are_the_per_frame_interactions() {
    let dir = fresh_dir("export-nri-dynamic");
    let spec = write_spec(&dir, &city_spec("dyn", &[(8, 0.5)], (2, 1, 1), 120, "{}"));
    let data = dir.join("data");
    gen_ok(&spec, &data, &["--quiet", "--no-images"]);
    let mut bonds = 0;
    for (layout, directed) in [("causalcity", false), ("nri", true)] {
        let out = dir.join(format!("out-{layout}"));
        let mut args = vec!["export", "nri", data.to_str().unwrap(), "--out", out.to_str().unwrap()];
        args.extend(["--layout", layout, "--dynamic"]);
        if directed {
            args.push("--directed");
        }
        let output = run(&args);
        assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
        for (split, nri_split, count) in [("train", "train", 2usize), ("val", "valid", 1), ("test", "test", 1)] {
            let (shape, graph, dtype) =
                load::<u8>(&out.join("cars08_edges50").join(format!("dynamic_edges_{nri_split}.npy")));
            assert_eq!(dtype, "'|u1'");
            assert_eq!(shape, vec![count as u64, 120, 8, 8]);
            for s in 0..count {
                let scenario_dir = data.join("cars08_edges50").join(split).join(format!("{s:05}"));
                let mut expected = vec![0u8; 120 * 64];
                for frame in 0..120 {
                    for car in 0..8 {
                        expected[frame * 64 + car * 9] = (layout == "causalcity") as u8;
                    }
                }
                for row in read_csv::<InteractionRow>(&scenario_dir.join("interactions.csv")) {
                    let (t, i) = (row.frame as usize, row.car as usize);
                    let named = ["car", "conflict", "collision", "give_way"].contains(&row.bound_by.as_str());
                    assert_eq!(named, row.other_car.is_some(), "{row:?}");
                    if let Some(j) = row.other_car {
                        let j = j as usize;
                        expected[t * 64 + i * 8 + j] = 1;
                        if !directed {
                            expected[t * 64 + j * 8 + i] = 1;
                        }
                        bonds += 1;
                    }
                }
                assert_eq!(&graph[s * 120 * 64..(s + 1) * 120 * 64], &expected[..], "{layout} {split} {s}");
            }
        }
    }
    // Eight cars in traffic for 120 frames: some car binds another somewhere.
    assert!(bonds > 0, "no interaction named another car");

    // A toy dataset has no interactions: refused before anything is written.
    let toy = write_spec(&dir, &toy_spec("toy", &[(4, 0.5)], (1, 1, 1), 10));
    gen_ok(&toy, &dir.join("toy"), &["--quiet", "--no-images"]);
    let out = dir.join("out-toy");
    let output =
        run(&["export", "nri", dir.join("toy").to_str().unwrap(), "--out", out.to_str().unwrap(), "--dynamic"]);
    assert_eq!(output.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&output.stderr).contains("--dynamic needs a city-world dataset"));
    assert!(!out.exists());
}

#[test]
fn export_nri_quiet_writes_the_same_files_and_prints_nothing() {
    let dir = fresh_dir("export-nri-quiet");
    let spec = write_spec(&dir, &toy_spec("nriq", &[(4, 0.5)], (2, 1, 1), 12));
    let data = dir.join("data");
    gen_ok(&spec, &data, &["--quiet", "--no-images"]);
    let loud = dir.join("loud");
    let quiet = dir.join("quiet");
    let said = run(&["export", "nri", data.to_str().unwrap(), "--out", loud.to_str().unwrap()]);
    assert!(said.status.success() && !said.stdout.is_empty(), "{}", String::from_utf8_lossy(&said.stderr));
    for flag in ["-q", "--quiet"] {
        let _ = std::fs::remove_dir_all(&quiet);
        let output = run(&["export", "nri", data.to_str().unwrap(), "--out", quiet.to_str().unwrap(), flag]);
        assert!(output.status.success(), "{flag}: {}", String::from_utf8_lossy(&output.stderr));
        assert!(output.stdout.is_empty(), "{flag} printed {}", String::from_utf8_lossy(&output.stdout));
        assert_eq!(hash_tree(&quiet), hash_tree(&loud), "{flag} wrote other files");
    }
}

#[test]
fn run_given_a_dataset_spec_says_to_use_gen() {
    let dir = fresh_dir("export-run-dataset-spec");
    let spec = write_spec(&dir, &toy_spec("notascenario", &[(4, 0.5)], (2, 1, 1), 12));
    for command in ["run", "counterfactual"] {
        let out = dir.join(command);
        let output = run(&[command, "--scenario", spec.to_str().unwrap(), "--out", out.to_str().unwrap()]);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{command}: {stderr}");
        assert!(stderr.contains("dataset spec") && stderr.contains("causalcity gen --spec"), "{command}: {stderr}");
        assert!(!out.exists(), "{command} wrote {}", out.display());
    }
}

#[test]
fn an_nri_export_never_leaves_an_earlier_exports_files_beside_its_own() {
    // Exporting a dataset without val and test scenarios into the folder of
    // an earlier export kept that export's valid and test arrays: an NRI
    // loader read train from one dataset, valid and test from another.
    let dir = fresh_dir("export-earlier");
    let full = dir.join("full");
    gen_ok(&write_spec(&dir, &toy_spec("full", &[(4, 0.5)], (2, 1, 1), 10)), &full, &["--no-images", "-q"]);
    let train_only = dir.join("train-only");
    gen_ok(&write_spec(&dir, &toy_spec("train", &[(4, 0.5)], (2, 0, 0), 10)), &train_only, &["--no-images", "-q"]);
    let out = dir.join("nri");
    let first = run(&["export", "nri", full.to_str().unwrap(), "--out", out.to_str().unwrap(), "-q"]);
    assert!(first.status.success(), "{}", String::from_utf8_lossy(&first.stderr));
    let before = hash_tree(&out);
    let mixed = run(&["export", "nri", train_only.to_str().unwrap(), "--out", out.to_str().unwrap(), "-q"]);
    let stderr = String::from_utf8_lossy(&mixed.stderr);
    assert_eq!(mixed.status.code(), Some(2), "{stderr}");
    // It names the first stray in name order: one of the earlier export's
    // test or valid arrays.
    assert!(stderr.contains("cars04_edges50/edges_test.npy is not a file this export writes"), "{stderr}");
    assert_eq!(hash_tree(&out), before, "nothing written");
    // The same export again replaces its own files.
    let again = run(&["export", "nri", full.to_str().unwrap(), "--out", out.to_str().unwrap(), "-q"]);
    assert!(again.status.success(), "{}", String::from_utf8_lossy(&again.stderr));
    assert_eq!(hash_tree(&out), before);
}

#[test]
fn an_nsdr_export_never_leaves_an_earlier_exports_scenarios_beside_its_own() {
    // An export of fewer scenarios over an earlier one kept the earlier
    // export's extra scenario folders, their annotations pointing into the
    // other dataset.
    let dir = fresh_dir("export-nsdr-earlier");
    let spec = |name: &str, splits| {
        city_spec(name, &[(4, 0.5)], splits, 5, "{}").replacen(
            "\"frames\"",
            "\"image\": {\"width\": 128, \"height\": 80}, \"frames\"",
            1,
        )
    };
    let (more, fewer) = (dir.join("more"), dir.join("fewer"));
    gen_ok(&write_spec(&dir, &spec("more", (2, 1, 1))), &more, &["--no-effects", "-q"]);
    gen_ok(&write_spec(&dir, &spec("fewer", (1, 0, 0))), &fewer, &["--no-effects", "-q"]);
    let out = dir.join("nsdr");
    let first = run(&["export", "nsdr", more.to_str().unwrap(), "--out", out.to_str().unwrap(), "-q"]);
    assert!(first.status.success(), "{}", String::from_utf8_lossy(&first.stderr));
    // Scenario 00000 is one the second export would write over.
    let annotations = out.join("cars04_edges50/train/00000/annotations.json");
    let before = std::fs::read(&annotations).unwrap();
    let mixed = run(&["export", "nsdr", fewer.to_str().unwrap(), "--out", out.to_str().unwrap(), "-q"]);
    let stderr = String::from_utf8_lossy(&mixed.stderr);
    assert_eq!(mixed.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("is not a scenario this export writes"), "{stderr}");
    assert_eq!(std::fs::read(&annotations).unwrap(), before, "nothing written");
    // The same export again replaces its own scenarios.
    let again = run(&["export", "nsdr", more.to_str().unwrap(), "--out", out.to_str().unwrap(), "-q"]);
    assert!(again.status.success(), "{}", String::from_utf8_lossy(&again.stderr));
    assert_eq!(std::fs::read(&annotations).unwrap(), before);
}

#[test]
fn an_nri_export_that_fails_part_way_leaves_an_earlier_export_as_it_was() {
    // A scenario of the test split gone from the dataset: the export failed
    // there, with this dataset's train and valid arrays already written
    // over the earlier export's, beside its test arrays.
    let dir = fresh_dir("export-fails-part-way");
    let earlier = dir.join("earlier");
    gen_ok(&write_spec(&dir, &toy_spec("earlier", &[(4, 0.5)], (2, 1, 1), 10)), &earlier, &["--no-images", "-q"]);
    let damaged = dir.join("damaged");
    gen_ok(&write_spec(&dir, &toy_spec("damaged", &[(4, 0.5)], (2, 1, 1), 12)), &damaged, &["--no-images", "-q"]);
    let out = dir.join("nri");
    let first = run(&["export", "nri", earlier.to_str().unwrap(), "--out", out.to_str().unwrap(), "-q"]);
    assert!(first.status.success(), "{}", String::from_utf8_lossy(&first.stderr));
    let before = hash_tree(&out);
    assert_eq!(before.len(), 9, "{before:?}");
    std::fs::remove_dir_all(damaged.join("cars04_edges50/test/00000")).unwrap();
    let failed = run(&["export", "nri", damaged.to_str().unwrap(), "--out", out.to_str().unwrap(), "-q"]);
    let stderr = String::from_utf8_lossy(&failed.stderr);
    // A damaged dataset is bad input (it exited 1), told how to find every problem.
    assert_eq!(failed.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("test/00000"), "{stderr}");
    assert!(stderr.contains("is damaged: `causalcity validate"), "{stderr}");
    assert_eq!(hash_tree(&out), before, "the earlier export whole, and nothing staged left behind");
    // The earlier dataset exports again over it, as before.
    let again = run(&["export", "nri", earlier.to_str().unwrap(), "--out", out.to_str().unwrap(), "-q"]);
    assert!(again.status.success(), "{}", String::from_utf8_lossy(&again.stderr));
    assert_eq!(hash_tree(&out), before);
}

#[test]
fn a_failed_export_leaves_its_out_as_it_found_it() {
    // A damaged file in the dataset's last group (nri) or split (nsdr): the
    // export failed there and left its folders (nri: every group's, empty;
    // nsdr: the scenarios before, annotations and links) in --out.
    let dir = fresh_dir("export-failed-leaves-nothing");
    let toy = dir.join("toy");
    gen_ok(&write_spec(&dir, &toy_spec("toy", &[(4, 0.5), (5, 0.5)], (2, 1, 1), 10)), &toy, &["--no-images", "-q"]);
    std::fs::write(toy.join("cars05_edges50/test/00000/pixels.npy"), b"not an array").unwrap();
    let city_dir = dir.join("city-spec");
    std::fs::create_dir_all(&city_dir).unwrap();
    let spec = city_spec("city", &[(4, 0.5)], (2, 1, 1), 5, "{}").replacen(
        "\"frames\"",
        "\"image\": {\"width\": 128, \"height\": 80}, \"frames\"",
        1,
    );
    let city = dir.join("city");
    gen_ok(&write_spec(&city_dir, &spec), &city, &["--no-effects", "-q"]);
    std::fs::write(city.join("cars04_edges50/test/00000/mask/0003.png"), b"not a png").unwrap();
    let mut checked = 0;
    for (kind, data, damaged) in [("nri", &toy, "pixels.npy"), ("nsdr", &city, "0003.png")] {
        // A new --out (in a new folder), and an empty one the user made.
        for made in [false, true] {
            let out = match made {
                false => dir.join(format!("{kind}-new/out")),
                true => dir.join(format!("{kind}-made")),
            };
            if made {
                std::fs::create_dir_all(&out).unwrap();
            }
            let failed = run(&["export", kind, data.to_str().unwrap(), "--out", out.to_str().unwrap(), "-q"]);
            let stderr = String::from_utf8_lossy(&failed.stderr);
            assert_eq!(failed.status.code(), Some(2), "{kind}: {stderr}");
            assert!(stderr.contains(damaged), "{kind}: {stderr}");
            assert!(stderr.contains("is damaged: `causalcity validate"), "{kind}: {stderr}");
            match made {
                false => assert!(!out.parent().unwrap().exists(), "{kind}: {:?}", hash_tree(&out)),
                true => assert_eq!(std::fs::read_dir(&out).unwrap().count(), 0, "{kind}: {:?}", hash_tree(&out)),
            }
            checked += 1;
        }
    }
    assert_eq!(checked, 4);
}

#[test]
fn an_nri_export_of_a_dataset_without_val_says_it_writes_no_val_files() {
    // It wrote train and test and nothing about val, which NRI's loaders
    // read (helper audit).
    let dir = fresh_dir("export-no-val");
    let spec = write_spec(&dir, &toy_spec("noval", &[(4, 0.5)], (2, 0, 1), 20));
    let data = dir.join("data");
    gen_ok(&spec, &data, &["--quiet", "--no-images"]);
    let out = dir.join("nri");
    let output = run(&["export", "nri", data.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let said = String::from_utf8_lossy(&output.stdout);
    assert!(said.contains("valid 0 scenarios (the dataset's val split is empty): no *_valid.npy written"), "{said}");
    assert!(out.join("cars04_edges50/loc_train.npy").is_file() && !out.join("cars04_edges50/loc_valid.npy").exists());
}
