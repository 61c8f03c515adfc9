//! Graph shapes beyond pairs (`graph`): a spec asks for chains or forks,
//! `gen` writes them as designed edges, and effects.csv backs them as it
//! backs pairs. Everything is read back from the files written.

mod common;
use common::*;
use serde_json::Value;
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

type Edges = BTreeSet<(u32, u32)>;

fn edges(scenario: &Value, field: &str) -> Edges {
    scenario[field]
        .as_array()
        .unwrap_or_else(|| panic!("scenario.json has no {field}"))
        .iter()
        .map(|e| (e[0].as_u64().unwrap() as u32, e[1].as_u64().unwrap() as u32))
        .collect()
}

/// effects.csv rows keyed by (cause, effect, intervention): (first_frame, direct).
fn effect_rows(dir: &Path) -> BTreeMap<(u32, u32, String), (Option<u32>, u8)> {
    let mut reader = csv::Reader::from_path(dir.join("effects.csv")).unwrap();
    reader
        .deserialize::<(u32, u32, String, f64, Option<u32>, u8)>()
        .map(|r| {
            let r = r.unwrap();
            ((r.0, r.1, r.2), (r.4, r.5))
        })
        .collect()
}

fn with_graph(spec: &str, graph: Value) -> String {
    let mut spec: Value = serde_json::from_str(spec).unwrap();
    spec["graph"] = graph;
    spec.to_string()
}

/// Each car's leaders and followers among `designed`.
fn degrees(designed: &Edges) -> (BTreeMap<u32, usize>, BTreeMap<u32, usize>) {
    let (mut leaders, mut followers) = (BTreeMap::new(), BTreeMap::new());
    for &(a, b) in designed {
        *followers.entry(a).or_default() += 1;
        *leaders.entry(b).or_default() += 1;
    }
    (leaders, followers)
}

#[test]
fn toy_chains_pass_an_intervention_down_the_line_and_forks_do_not_pass_it_sideways() {
    let dir = fresh_dir("graph-shapes-toy");
    let base = toy_spec("shapes", &[(8, 0.5), (12, 0.8)], (3, 1, 1), 60);
    for (shape, cars) in [("chains", 3), ("forks", 3), ("chains", 4)] {
        let spec = write_spec(&dir, &with_graph(&base, serde_json::json!({"shape": shape, "cars": cars})));
        let out = dir.join(format!("{shape}{cars}"));
        gen_ok(&spec, &out, &["--quiet", "--no-images"]);
        let (mut scenarios, mut designed_total, mut transitive, mut siblings) = (0, 0, 0, 0);
        for d in scenario_dirs(&out) {
            let scenario = read_json(&d.join("scenario.json"));
            let designed = edges(&scenario, "edges");
            let group = d.parent().unwrap().parent().unwrap().file_name().unwrap().to_str().unwrap().to_string();
            let wanted = if group == "cars08_edges50" { 2 } else { 5 };
            assert_eq!(designed.len(), wanted, "{}", d.display());
            designed_total += designed.len();
            scenarios += 1;
            // Toy cars pass through each other: each follower reacts to its own leader only.
            assert_eq!(edges(&scenario, "direct_edges"), designed, "{}", d.display());
            for &(leader, follower) in &designed {
                assert_eq!(scenario["cars"][follower as usize]["follows"], leader, "{}", d.display());
            }
            let (leaders, followers) = degrees(&designed);
            assert!(leaders.values().all(|&n| n == 1), "a car follows one car at most: {designed:?}");
            let rows = effect_rows(&d);
            let causal = edges(&scenario, "causal_edges");
            if shape == "chains" {
                assert!(followers.values().all(|&n| n == 1), "a chain's car leads one car: {designed:?}");
                // A -> B -> C: without A, B stops, so C stops too (an effect, not a direct one).
                for &(a, b) in &designed {
                    for &(_, c) in designed.iter().filter(|e| e.0 == b) {
                        assert!(causal.contains(&(a, c)), "{}: {a} -> {b} -> {c}", d.display());
                        let (first, direct) = rows[&(a, c, "remove".to_string())];
                        assert!(first.is_some() && direct == 0, "{}: {a} -> {c}: {first:?} {direct}", d.display());
                        transitive += 1;
                    }
                }
            } else {
                assert!(followers.values().any(|&n| n == 2), "a fork's leader leads two cars: {designed:?}");
                assert!(designed.iter().all(|(a, _)| !leaders.contains_key(a)), "a fork's leader follows no one");
                // A -> B, A -> C: without B, C still follows A.
                for &(a, b) in &designed {
                    for &(_, c) in designed.iter().filter(|e| e.0 == a && e.1 != b) {
                        assert!(!causal.contains(&(b, c)), "{}: {b} moved its sibling {c}", d.display());
                        assert_eq!(rows[&(b, c, "remove".to_string())].0, None);
                        siblings += 1;
                    }
                }
            }
        }
        assert_eq!(scenarios, 10, "{shape}");
        assert_eq!(designed_total, 5 * 2 + 5 * 5, "{shape}");
        if shape == "chains" {
            assert!(transitive >= 10, "{shape}{cars}: only {transitive} chains of three checked");
        } else {
            assert!(siblings >= 10, "{shape}{cars}: only {siblings} sibling pairs checked");
        }
        let report = run(&["validate", out.to_str().unwrap()]);
        assert_eq!(report.status.code(), Some(0), "{}", String::from_utf8_lossy(&report.stdout));
    }
}

#[test]
fn city_chains_and_forks_are_backed_by_effects_with_and_without_platoons() {
    let dir = fresh_dir("graph-shapes-city");
    let platoons = std::fs::read_to_string("configs/city.json").unwrap();
    let free = city_spec("free", &[(8, 0.5), (12, 0.5)], (10, 1, 1), 150, r#"{"confounders": {}}"#);
    for (name, base, shape, limit) in [
        ("platoon-chains", &platoons, "chains", "3"),
        ("free-forks", &free, "forks", "10"),
        ("free-chains", &free, "chains", "10"),
    ] {
        let spec = write_spec(&dir, &with_graph(base, serde_json::json!({"shape": shape})));
        let out = dir.join(name);
        gen_ok(&spec, &out, &["--quiet", "--no-images", "--limit", limit]);
        let (mut designed_total, mut backed, mut joined) = (0, 0, 0);
        for d in scenario_dirs(&out) {
            let scenario = read_json(&d.join("scenario.json"));
            let designed = edges(&scenario, "edges");
            let (leaders, followers) = degrees(&designed);
            joined += match shape {
                "chains" => designed.iter().filter(|(a, _)| leaders.contains_key(a)).count(),
                _ => followers.values().filter(|&&n| n >= 2).count(),
            };
            designed_total += designed.len();
            backed += designed.intersection(&edges(&scenario, "direct_edges")).count();
            for &(leader, follower) in &designed {
                let car = &scenario["cars"][follower as usize];
                assert_eq!(car["follows"], leader, "{}", d.display());
                assert_eq!(car["role"], "follower");
                // A follower drives its leader's queue (a chain's: the same one down the line).
                assert_eq!(car["actions"], scenario["cars"][leader as usize]["actions"], "{}", d.display());
            }
        }
        assert!(joined >= 5, "{name}: only {joined} chain links or forks");
        // Measured over 200 edges of the free spec: pairs 98 %, chains 100 %,
        // forks 99.5 % (in 60 frames 86-88 %: a car far back in a queue may
        // not reach its leader's next turn in time to show the effect).
        let share = backed as f64 / designed_total as f64;
        assert!(
            designed_total >= 40 && share >= 0.9,
            "{name}: {backed} of {designed_total} designed edges have a direct effect"
        );
        let report = run(&["validate", out.to_str().unwrap()]);
        assert_eq!(report.status.code(), Some(0), "{name}: {}", String::from_utf8_lossy(&report.stdout));
    }
}

/// A collider's designed edges read back from scenario.json: (leader,
/// follower, car with priority), each checked for the roles and fields
/// that say so.
fn colliders_of(scenario: &Value, dir: &Path) -> Vec<(u32, u32, u32)> {
    let designed = edges(scenario, "edges");
    let cars = scenario["cars"].as_array().unwrap();
    let mut found = Vec::new();
    for car in cars {
        let Some(priority) = car["gives_way_to"].as_u64() else { continue };
        let (follower, priority) = (car["id"].as_u64().unwrap() as u32, priority as u32);
        let leader = car["follows"].as_u64().unwrap_or_else(|| panic!("{}: a collider follows", dir.display())) as u32;
        assert_eq!(car["role"], "follower", "{}", dir.display());
        assert_eq!(cars[priority as usize]["role"], "priority", "{}", dir.display());
        assert!(
            cars[priority as usize].get("follows").is_none(),
            "{}: the car with priority drives its own queue",
            dir.display()
        );
        assert!(
            designed.contains(&(leader, follower)) && designed.contains(&(priority, follower)),
            "{}",
            dir.display()
        );
        found.push((leader, follower, priority));
    }
    // Every designed edge is a collider's, or the one pair left over.
    assert!(designed.len() <= 2 * found.len() + 1, "{}: {designed:?}", dir.display());
    found
}

#[test]
fn city_colliders_give_way_to_the_car_with_priority_and_are_backed_by_effects() {
    let dir = fresh_dir("graph-shapes-colliders");
    let colliders = serde_json::json!({"shape": "colliders"});
    // (name, town, platoon cars, least share of colliders whose follower the
    // car with priority moves, least share where it does so directly).
    // Measured on 60-80 scenarios: all-way stops 97-100 % / 72-88 %,
    // priority junctions 80-87 % / 15-23 %, where the leader, held up
    // too, often holds the follower up first.
    for (name, control, platoon, causal, direct) in
        [("all-way-stop", "all_way_stop", 0, 0.85, 0.6), ("priority-platoons", "priority", 4, 0.6, 0.03)]
    {
        let city = format!(r#"{{"start": {{"platoon_cars": {platoon}}}, "rules": "cooperative"}}"#);
        let mut spec: Value = serde_json::from_str(&city_spec(name, &[(8, 0.5)], (40, 1, 0), 60, &city)).unwrap();
        spec["frame_interval"] = serde_json::json!(1.0);
        spec["graph"] = colliders.clone();
        spec["map"] = serde_json::json!({"grid": {"rows": 3, "columns": 3, "control": control}});
        let spec = write_spec(&dir, &spec.to_string());
        let out = dir.join(name);
        gen_ok(&spec, &out, &["--quiet", "--no-images"]);
        let (mut checked, mut moved, mut direct_hits) = (0, 0, 0);
        let schema = validator("scenario.schema.json");
        for d in scenario_dirs(&out) {
            let scenario = read_json(&d.join("scenario.json"));
            assert_valid(&schema, &scenario, &d.join("scenario.json"));
            let (causal_edges, direct_edges) = (edges(&scenario, "causal_edges"), edges(&scenario, "direct_edges"));
            let found = colliders_of(&scenario, &d);
            // 8 cars at 50 %: two edges, one collider.
            assert_eq!(found.len(), 1, "{}", d.display());
            for (leader, follower, priority) in found {
                checked += 1;
                assert!(direct_edges.contains(&(leader, follower)), "{}: the follower follows", d.display());
                moved += usize::from(causal_edges.contains(&(priority, follower)));
                direct_hits += usize::from(direct_edges.contains(&(priority, follower)));
            }
        }
        assert_eq!(checked, 41, "{name}");
        let (moved, direct_hits) = (moved as f64 / checked as f64, direct_hits as f64 / checked as f64);
        eprintln!("{name}: {checked} colliders, moved {:.0} %, directly {:.0} %", 100.0 * moved, 100.0 * direct_hits);
        assert!(moved >= causal, "{name}: the car with priority moves {:.0} % of its followers", 100.0 * moved);
        assert!(direct_hits >= direct, "{name}: directly {:.0} %", 100.0 * direct_hits);
        let report = run(&["validate", out.to_str().unwrap()]);
        assert_eq!(report.status.code(), Some(0), "{name}: {}", String::from_utf8_lossy(&report.stdout));
    }
    // Cars without drawn actions: the car with priority gets the one or two
    // it needs to cross the follower's path.
    let mut spec: Value = serde_json::from_str(&city_spec("no-actions", &[(8, 0.5)], (5, 0, 0), 20, "{}")).unwrap();
    spec["graph"] = colliders;
    spec["actions_per_car"] = serde_json::json!(0);
    spec["map"] = serde_json::json!({"grid": {"rows": 3, "columns": 3, "control": "priority"}});
    let out = dir.join("no-actions");
    gen_ok(&write_spec(&dir, &spec.to_string()), &out, &["--quiet", "--no-images"]);
    let found: usize =
        scenario_dirs(&out).iter().map(|d| colliders_of(&read_json(&d.join("scenario.json")), d).len()).sum();
    assert_eq!(found, 5);
}
