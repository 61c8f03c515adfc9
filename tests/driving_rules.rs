//! `city.rules`: the original's driving rules (the default, so existing
//! specs keep their bytes) or the cooperative ones, under which drivers let
//! a waiting lane changer in, wait out a queue standing in the way, and a
//! follower keeps behind its leader on the lane beside. Measured as a user
//! would: gen on a 4 x 4 town with lights, then poses.csv and events.csv.

mod common;
use common::*;
use std::path::Path;

/// The 4 x 4 town with lights of `configs/ood-towns.json`'s test split:
/// 8 cars, platoon starts, 150 frames of a second.
fn town_spec(name: &str, rules: Option<&str>) -> String {
    let rules = rules.map(|r| format!(r#", "rules": "{r}""#)).unwrap_or_default();
    format!(
        r#"{{"name": "{name}", "world": "city", "seed": 36, "frames": 150, "frame_interval": 1.0,
            "groups": [{{"cars": 8, "edge_proportion": 0.5}}], "splits": {{"train": 60, "val": 0, "test": 0}},
            "actions_per_car": 5, "map": {{"grid": {{"rows": 4, "columns": 4}}}},
            "city": {{"start": {{"follower_gap_m": {{"uniform": [1.0, 12.0]}}, "platoon_cars": 4}},
                      "lights": {{"cycle_scale": 0.5, "phase": "random_per_intersection"}}{rules}}}}}"#
    )
}

/// What a dataset's drivers did: (designed pairs, pairs whose follower kept
/// within 4.5 m of its leader's path so far in at least 80 % of frames,
/// cars that stood still for the last 60 s, lane changes given up).
fn driving(out: &Path) -> (usize, usize, usize, usize) {
    let (mut pairs, mut following, mut standing, mut given_up) = (0, 0, 0, 0);
    for scenario in scenario_dirs(out) {
        let meta = read_json(&scenario.join("scenario.json"));
        let by_car = poses_by_car(&read_poses(&scenario.join("poses.csv")));
        let (p, f) = designed_pairs_following(&meta, &by_car);
        (pairs, following) = (pairs + p, following + f);
        for poses in by_car.values() {
            let (last, before) = (&poses[poses.len() - 1], &poses[poses.len() - 61]);
            standing += usize::from((last.x - before.x).hypot(last.y - before.y) < 0.1);
        }
        let events = std::fs::read_to_string(scenario.join("events.csv")).unwrap();
        given_up += events.lines().filter(|l| l.contains(",action_skipped,") && l.contains("no gap")).count();
    }
    (pairs, following, standing, given_up)
}

#[test]
fn cooperative_drivers_let_lane_changers_in_and_followers_follow_on_a_town_with_lights() {
    let dir = fresh_dir("rules-town");
    let (original, cooperative) = (dir.join("original"), dir.join("cooperative"));
    gen_ok(&write_spec(&dir, &town_spec("rules-original", None)), &original, &["--no-images"]);
    let spec = dir.join("cooperative.json");
    std::fs::write(&spec, town_spec("rules-cooperative", Some("cooperative"))).unwrap();
    gen_ok(&spec, &cooperative, &["--no-images"]);

    let (pairs, following_before, standing_before, given_up_before) = driving(&original);
    let (pairs_after, following, standing, given_up) = driving(&cooperative);
    assert!(pairs >= 100 && pairs_after == pairs, "{pairs} and {pairs_after} designed pairs");
    // The original's rules: turns given up beside queues, followers lost.
    assert!(given_up_before >= 20, "only {given_up_before} lane changes given up under the original rules");
    assert!(following_before * 100 < pairs * 80, "{following_before} of {pairs} follow under the original rules");
    // Cooperative: issue 36's bar of 85 %, half the turns given up or fewer
    // (two cars that want each other's lanes still give up), fewer cars stuck.
    assert!(following * 100 >= pairs * 85, "{following} of {pairs} designed followers follow");
    assert!(given_up * 2 <= given_up_before, "{given_up} lane changes given up, {given_up_before} before");
    assert!(standing < standing_before, "{standing} cars stand for the last 60 s, {standing_before} before");

    // scenario.json and the manifest's spec say which rules ran; the
    // original's are the default and written nowhere.
    let first = |root: &Path| read_json(&scenario_dirs(root)[0].join("scenario.json"));
    assert_eq!(first(&cooperative)["city"]["rules"], "cooperative");
    assert!(first(&original)["city"].get("rules").is_none());
    let manifest = std::fs::read_to_string(original.join("manifest.json")).unwrap();
    assert!(!manifest.contains("\"rules\""));
    assert!(std::fs::read_to_string(cooperative.join("manifest.json")).unwrap().contains("\"rules\": \"cooperative\""));
}

/// Collision events in every scenario's events.csv under `out`.
fn collisions(out: &Path) -> usize {
    scenario_dirs(out)
        .iter()
        .map(|s| {
            std::fs::read_to_string(s.join("events.csv")).unwrap().lines().filter(|l| l.contains(",collision,")).count()
        })
        .sum()
}

#[test]
fn cooperative_drivers_do_not_meet_in_the_box_on_one_lane_roads() {
    // configs/ood-network.json's held-out town: one-lane roads, where
    // opposite left turns cross and set off together on their shared arrow.
    let town = r#"{"grid": {"rows": 4, "columns": 4, "lanes": 1, "missing": ["E0", "H4", "B2", "C3"]}}"#;
    let dir = fresh_dir("rules-one-lane");
    let (mut before, mut after) = (0, 0);
    for (rules, count) in [(None, &mut before), (Some("cooperative"), &mut after)] {
        let name = format!("one-lane-{}", rules.unwrap_or("original"));
        let text = town_spec(&name, rules)
            .replace(r#"{"grid": {"rows": 4, "columns": 4}}"#, town)
            .replace(r#"[{"cars": 8, "edge_proportion": 0.5}]"#, r#"[{"cars": 12, "edge_proportion": 0.5}]"#);
        assert!(text.contains("\"lanes\": 1") && text.contains("\"cars\": 12"), "{text}");
        let spec = dir.join(format!("{name}.json"));
        std::fs::write(&spec, text).unwrap();
        let out = dir.join(&name);
        gen_ok(&spec, &out, &["--no-images", "--no-effects"]);
        *count = collisions(&out);
    }
    assert!(before >= 3, "only {before} collisions under the original rules: the test no longer provokes them");
    assert_eq!(after, 0, "{after} collisions under the cooperative rules ({before} under the original)");
}

#[test]
fn an_unknown_rule_is_refused_naming_the_field_and_what_is_allowed() {
    let dir = fresh_dir("rules-bad");
    let spec = write_spec(&dir, &town_spec("rules-bad", Some("polite")));
    let out = dir.join("out");
    let output = run(&["gen", "--spec", spec.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("polite") && stderr.contains("original") && stderr.contains("cooperative"), "{stderr}");
    assert!(!out.exists(), "a refused spec wrote {}", out.display());
}
