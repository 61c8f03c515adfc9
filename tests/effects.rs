//! The interventional ground truth as a user meets it: `gen` writes
//! effects.csv and the causal graphs into every scenario, `validate` checks
//! them against each other, `stats` reports how many designed edges an
//! effect backs, and `--no-effects` leaves them out. Everything is read back
//! from the files written.

mod common;

use common::*;
use serde_json::Value;
use std::collections::BTreeSet;
use std::path::Path;

/// effects.csv's rows of one scenario: (cause, effect, intervention,
/// max_divergence_m, first_frame, direct).
type Row = (u32, u32, String, f64, Option<u32>, u8);

fn effect_rows(dir: &Path) -> Vec<Row> {
    let mut reader = csv::Reader::from_path(dir.join("effects.csv")).unwrap();
    reader.deserialize().map(|r| r.unwrap()).collect()
}

fn pairs(scenario: &Value, field: &str) -> BTreeSet<(u32, u32)> {
    scenario[field]
        .as_array()
        .unwrap_or_else(|| panic!("scenario.json has no {field}"))
        .iter()
        .map(|e| (e[0].as_u64().unwrap() as u32, e[1].as_u64().unwrap() as u32))
        .collect()
}

#[test]
fn toy_effects_are_exactly_the_designed_edges_and_a_leaderless_follower_stops() {
    let dir = fresh_dir("effects-toy");
    let spec = write_spec(&dir, &toy_spec("effects-toy", &[(4, 0.5), (8, 0.8), (12, 0.5)], (3, 1, 1), 60));
    let out = dir.join("out");
    gen_ok(&spec, &out, &["--quiet", "--no-images"]);
    let mut designed = 0;
    for d in scenario_dirs(&out) {
        let scenario = read_json(&d.join("scenario.json"));
        let edges = pairs(&scenario, "edges");
        designed += edges.len();
        // Toy cars pass through each other: only a follower reacts, and only to its leader.
        assert_eq!(pairs(&scenario, "causal_edges"), edges, "{}", d.display());
        assert_eq!(pairs(&scenario, "direct_edges"), edges, "{}", d.display());
        assert!(scenario["edges_without_effect"].as_array().unwrap().is_empty());
        let rows = effect_rows(&d);
        let cars = scenario["cars"].as_array().unwrap().len();
        assert_eq!(rows.len(), 2 * cars * (cars - 1), "every car twice, against every other car");
        for &(leader, follower) in &edges {
            let follower_car = &scenario["cars"][follower as usize];
            assert_eq!(follower_car["follows"], leader);
            assert_eq!(follower_car["on_leader_lost"], "stop");
            // Without its leader the follower stands: 0.156 m a frame, past 0.5 m by frame 4.
            let removed = rows.iter().find(|r| (r.0, r.1, r.2.as_str()) == (leader, follower, "remove")).unwrap();
            assert_eq!(removed.4, Some(4), "{removed:?}");
            assert_eq!(removed.5, 1);
        }
    }
    assert!(designed >= 30, "only {designed} designed edges checked");
    let report = run(&["validate", out.to_str().unwrap()]);
    assert_eq!(report.status.code(), Some(0), "{}", String::from_utf8_lossy(&report.stdout));
}

#[test]
fn city_effects_back_the_designed_edges_and_validate_checks_them() {
    let dir = fresh_dir("effects-city");
    let spec = write_spec(&dir, &std::fs::read_to_string("configs/city.json").unwrap());
    let out = dir.join("out");
    gen_ok(&spec, &out, &["--quiet", "--no-images", "--limit", "6"]);
    let (mut designed, mut backed, mut causal, mut undesigned) = (0, 0, 0, 0);
    for d in scenario_dirs(&out) {
        let scenario = read_json(&d.join("scenario.json"));
        assert_eq!(scenario["effect_threshold_m"], 0.5);
        let (edges, causal_edges, direct) =
            (pairs(&scenario, "edges"), pairs(&scenario, "causal_edges"), pairs(&scenario, "direct_edges"));
        assert!(direct.is_subset(&causal_edges));
        designed += edges.len();
        backed += edges.intersection(&causal_edges).count();
        causal += causal_edges.len();
        undesigned += causal_edges.difference(&edges).count();
        // The graphs are what the rows say.
        let rows = effect_rows(&d);
        let from_rows: BTreeSet<(u32, u32)> = rows.iter().filter(|r| r.4.is_some()).map(|r| (r.0, r.1)).collect();
        assert_eq!(from_rows, causal_edges);
        for r in &rows {
            assert_eq!(r.4.is_some(), r.3 > 0.5, "{r:?}");
        }
        for &(leader, follower) in &edges {
            let lost = &scenario["cars"][follower as usize]["on_leader_lost"]["drive"]["actions"];
            assert_eq!(lost.as_array().map(Vec::len), Some(5), "a city follower drives a queue of its own");
            assert_eq!(scenario["cars"][follower as usize]["follows"], leader);
        }
    }
    assert!(designed >= 60, "only {designed} designed edges");
    let share = backed as f64 / designed as f64;
    assert!(share >= 0.9, "{backed} of {designed} designed edges backed by an effect");

    // stats reports the same counts.
    let stats = run(&["stats", out.to_str().unwrap(), "--json"]);
    assert!(stats.status.success(), "{}", String::from_utf8_lossy(&stats.stderr));
    let stats: Value = serde_json::from_slice(&stats.stdout).unwrap();
    let sum = |field: &str| -> u64 {
        stats["rows"].as_array().unwrap().iter().map(|r| r["causal"][field].as_u64().unwrap()).sum()
    };
    assert_eq!(sum("designed_edges") as usize, designed);
    assert_eq!(sum("designed_with_effect") as usize, backed);
    assert_eq!(sum("causal_edges") as usize, causal);
    assert_eq!(sum("causal_not_designed") as usize, undesigned);
    let table = run(&["stats", out.to_str().unwrap()]);
    assert!(String::from_utf8_lossy(&table.stdout).contains("backed"));

    // The causal graph exports as NRI edges (receiver, sender) and scores in baseline.
    let nri = dir.join("nri");
    let export = run(&[
        "export",
        "nri",
        out.to_str().unwrap(),
        "--out",
        nri.to_str().unwrap(),
        "--graph",
        "causal",
        "--directed",
    ]);
    assert!(export.status.success(), "{}", String::from_utf8_lossy(&export.stderr));
    let file = std::fs::File::open(nri.join("cars08_edges80/edges_test.npy")).unwrap();
    let npy = npyz::NpyFile::new(std::io::BufReader::new(file)).unwrap();
    let shape = npy.shape().to_vec();
    let edges: Vec<i64> = npy.into_vec().unwrap();
    let (scenarios, cars) = (shape[0] as usize, shape[1] as usize);
    let mut exported = BTreeSet::new();
    for s in 0..scenarios {
        for (i, j) in (0..cars).flat_map(|i| (0..cars).map(move |j| (i, j))).filter(|&(i, j)| i != j) {
            if edges[(s * cars + i) * cars + j] == 1 {
                exported.insert((s, j as u32, i as u32));
            }
        }
    }
    let mut expected = BTreeSet::new();
    for (s, d) in sorted_entries(&out.join("cars08_edges80/test")).iter().enumerate() {
        expected
            .extend(pairs(&read_json(&d.join("scenario.json")), "causal_edges").into_iter().map(|(a, b)| (s, a, b)));
    }
    assert!(!expected.is_empty());
    assert_eq!(exported, expected);
    let scored = run(&["baseline", out.to_str().unwrap(), "--graph", "direct", "--json"]);
    assert!(scored.status.success(), "{}", String::from_utf8_lossy(&scored.stderr));
    let scored: Value = serde_json::from_slice(&scored.stdout).unwrap();
    assert_eq!(scored["graph"], "direct");

    // validate passes, then catches a graph that disagrees with the rows.
    let report = run(&["validate", out.to_str().unwrap()]);
    assert_eq!(report.status.code(), Some(0), "{}", String::from_utf8_lossy(&report.stdout));
    let victim = scenario_dirs(&out).into_iter().next().unwrap();
    let path = victim.join("scenario.json");
    let mut scenario = read_json(&path);
    scenario["causal_edges"] = serde_json::json!([]);
    let bytes = serde_json::to_vec_pretty(&scenario).unwrap();
    std::fs::write(&path, &bytes).unwrap();
    // Keep the checksum listing right, so that only the effects check can object.
    let listing = std::fs::read_to_string(victim.join("checksums.sha256")).unwrap();
    let digest: String = <sha2::Sha256 as sha2::Digest>::digest(&bytes).iter().map(|b| format!("{b:02x}")).collect();
    let fixed: String = listing
        .lines()
        .map(|l| if l.ends_with("  scenario.json") { format!("{digest}  scenario.json\n") } else { format!("{l}\n") })
        .collect();
    std::fs::write(victim.join("checksums.sha256"), fixed).unwrap();
    let report = run(&["validate", out.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&report.stdout).to_string() + &String::from_utf8_lossy(&report.stderr);
    assert_eq!(report.status.code(), Some(1), "{text}");
    assert!(text.contains("causal_edges"), "{text}");
}

#[test]
fn no_effects_leaves_them_out_and_a_rerun_with_them_is_refused() {
    let dir = fresh_dir("effects-off");
    let spec = write_spec(&dir, &toy_spec("effects-off", &[(4, 0.5)], (2, 1, 1), 20));
    let out = dir.join("out");
    gen_ok(&spec, &out, &["--quiet", "--no-images", "--no-effects"]);
    let dirs = scenario_dirs(&out);
    assert_eq!(dirs.len(), 4);
    for d in &dirs {
        assert!(!d.join("effects.csv").exists());
        let scenario = read_json(&d.join("scenario.json"));
        assert!(scenario.get("causal_edges").is_none() && scenario.get("effect_threshold_m").is_none());
        assert_eq!(pairs(&scenario, "edges").len(), 1, "the designed graph is still there");
    }
    assert_eq!(read_json(&out.join("manifest.json"))["effects"], false);
    let report = run(&["validate", out.to_str().unwrap()]);
    assert_eq!(report.status.code(), Some(0), "{}", String::from_utf8_lossy(&report.stdout));
    // The same folder with effects is another dataset.
    let again =
        run(&["gen", "--quiet", "--no-images", "--spec", spec.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    let message = String::from_utf8_lossy(&again.stderr);
    assert_eq!(again.status.code(), Some(2), "{message}");
    assert!(message.contains("--no-effects"), "{message}");
    // Readers asked for a measured graph say the dataset has none, and write nothing.
    let nri = dir.join("nri");
    for args in [
        vec!["export", "nri", out.to_str().unwrap(), "--out", nri.to_str().unwrap(), "--graph", "causal"],
        vec!["baseline", out.to_str().unwrap(), "--graph", "direct"],
    ] {
        let refused = run(&args);
        let message = String::from_utf8_lossy(&refused.stderr);
        assert_eq!(refused.status.code(), Some(2), "{args:?}: {message}");
        assert!(message.contains("--no-effects"), "{message}");
    }
    assert!(!nri.exists());
}

/// Splits own their start points, so no val or test car can have an
/// identical trajectory in train; validate checks it, and says so when a
/// train scenario is copied into test.
#[test]
fn splits_share_no_start_and_validate_finds_a_trajectory_twin() {
    use causalcity::map::CityMap;
    use causalcity::plan::expand::split_owning_start;
    let dir = fresh_dir("effects-splits");
    let spec = write_spec(&dir, &toy_spec("splits", &[(4, 0.5), (12, 0.5)], (6, 3, 3), 20));
    let out = dir.join("out");
    gen_ok(&spec, &out, &["--quiet", "--no-images", "--no-effects"]);
    let map = CityMap::default();
    let mut cars = 0;
    for d in scenario_dirs(&out) {
        let scenario = read_json(&d.join("scenario.json"));
        let split = ["train", "val", "test"].iter().position(|s| scenario["split"] == *s).unwrap();
        for car in scenario["cars"].as_array().unwrap() {
            let lane = map.lane_by_name(car["spawn"].as_str().unwrap()).unwrap();
            assert_eq!(split_owning_start(lane, car["spawn_distance"].as_f64().unwrap()), split, "{car}");
            cars += 1;
        }
    }
    assert_eq!(cars, 12 * 4 + 12 * 12);
    let report = run(&["validate", out.to_str().unwrap()]);
    assert_eq!(report.status.code(), Some(0), "{}", String::from_utf8_lossy(&report.stdout));
    // A train scenario's poses copied into a test scenario: its cars now have twins in train.
    let train = out.join("cars04_edges50/train/00002");
    let test = out.join("cars04_edges50/test/00001");
    std::fs::copy(train.join("poses.csv"), test.join("poses.csv")).unwrap();
    let report = run(&["validate", out.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&report.stdout).to_string() + &String::from_utf8_lossy(&report.stderr);
    assert_eq!(report.status.code(), Some(1), "{text}");
    let twins = text.lines().filter(|l| l.contains("cars04_edges50/train/00002: the splits overlap")).count();
    assert_eq!(twins, 4, "{text}");
}
