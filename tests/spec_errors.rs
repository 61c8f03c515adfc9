//! Bad input: every class of spec error exits 2, names the field and writes nothing.

mod common;
use common::*;

fn base() -> serde_json::Value {
    serde_json::from_str(&toy_spec("bad", &[(8, 0.5)], (2, 1, 1), 10)).unwrap()
}

/// Runs gen on `text`, expects exit 2 with `needle` in stderr and no output folder.
fn rejected(case: &str, text: &str, needles: &[&str]) {
    let dir = fresh_dir(&format!("spec-errors-{case}"));
    let spec = write_spec(&dir, text);
    let out = dir.join("out");
    let output = run(&["gen", "--spec", spec.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(2), "{case}: expected exit 2, stderr: {stderr}");
    for needle in needles {
        assert!(stderr.contains(needle), "{case}: stderr should mention {needle:?}: {stderr}");
    }
    assert!(!stderr.contains("panicked"), "{case}: {stderr}");
    assert!(!out.exists(), "{case}: output was written for a bad spec");
}

fn with(edit: impl FnOnce(&mut serde_json::Value)) -> String {
    let mut v = base();
    edit(&mut v);
    v.to_string()
}

#[test]
fn null_where_a_value_must_stand_is_told_in_plain_words() {
    // "invalid type: null, expected a whole number"
    let text = with(|v| v["frames"] = serde_json::Value::Null);
    rejected(
        "null-frames",
        &text,
        &["field `frames`", "null is not a value here: give a value, or leave the field out"],
    );
    let text = city_with(r#"{"start": {"platoon_cars": null}}"#);
    rejected("null-nested", &text, &["city.start.platoon_cars", "null is not a value here"]);
}

#[test]
fn malformed_json() {
    rejected("malformed", r#"{"name": "x", "world": "toy",,}"#, &["invalid spec", "line 1"]);
    rejected("empty", "", &["invalid spec"]);
}

#[test]
fn unknown_field_is_named_with_the_allowed_ones() {
    rejected("unknown", &with(|v| v["colour_mode"] = 1.into()), &["colour_mode", "expected one of", "frames"]);
    rejected(
        "unknown-nested",
        &with(|v| v["groups"][0]["edges"] = 2.into()),
        &["groups[0]", "edges", "edge_proportion"],
    );
}

#[test]
fn wrong_type_names_the_field() {
    rejected("type-frames", &with(|v| v["frames"] = "many".into()), &["frames", "invalid type"]);
    rejected("type-world", &with(|v| v["world"] = "mars".into()), &["world", "toy", "city"]);
    rejected(
        "type-proportion",
        &with(|v| v["groups"][0]["edge_proportion"] = "half".into()),
        &["groups[0].edge_proportion"],
    );
}

#[test]
fn zero_counts_are_rejected_with_the_allowed_range() {
    rejected(
        "zero-cars",
        &with(|v| v["groups"][0]["cars"] = 0.into()),
        &["groups[0].cars", "0 is not allowed", "1 to 255"],
    );
    rejected("zero-frames", &with(|v| v["frames"] = 0.into()), &["`frames`", "0 is not allowed"]);
    rejected(
        "zero-splits",
        &with(|v| v["splits"] = serde_json::json!({"train": 0, "val": 0, "test": 0})),
        &["splits", "at least one"],
    );
    rejected("no-groups", &with(|v| v["groups"] = serde_json::json!([])), &["groups", "empty"]);
}

#[test]
fn negative_counts_are_rejected() {
    rejected("negative-train", &with(|v| v["splits"]["train"] = (-5).into()), &["splits.train", "-5"]);
    rejected("negative-seed", &with(|v| v["seed"] = (-1).into()), &["seed", "-1"]);
    rejected(
        "negative-speed",
        &with(|v| v["toy_speed_px_per_frame"] = (-2.0).into()),
        &["toy_speed_px_per_frame", "above 0"],
    );
}

#[test]
fn proportion_outside_zero_one() {
    rejected(
        "proportion-high",
        &with(|v| v["groups"][0]["edge_proportion"] = 1.5.into()),
        &["groups[0].edge_proportion", "1.5", "from 0 to 1"],
    );
    rejected(
        "proportion-low",
        &with(|v| v["groups"][0]["edge_proportion"] = (-0.1).into()),
        &["groups[0].edge_proportion", "-0.1"],
    );
}

#[test]
fn impossible_groups() {
    // 3 cars at 100 % would need 2 pairs = 4 cars.
    rejected(
        "too-many-edges",
        &with(|v| v["groups"][0] = serde_json::json!({"cars": 3, "edge_proportion": 1.0})),
        &["groups[0].edge_proportion", "need 4 cars"],
    );
    // A letterbox camera leaves too little visible road for 200 cars.
    rejected(
        "too-many-cars",
        &with(|v| {
            v["groups"][0] = serde_json::json!({"cars": 200, "edge_proportion": 0.5});
            v["image"] = serde_json::json!({"width": 1024, "height": 64});
        }),
        &["groups[0].cars", "do not fit", "at most"],
    );
    rejected(
        "duplicate-group",
        &with(|v| {
            v["groups"] = serde_json::json!([{"cars": 4, "edge_proportion": 0.5}, {"cars": 4, "edge_proportion": 0.5}])
        }),
        &["groups[1]", "cars04_edges50"],
    );
    rejected("gap-shorter-than-car", &with(|v| v["leader_gap_px"] = 10.into()), &["leader_gap_px", "overlap"]);
}

#[test]
fn image_size_out_of_range() {
    rejected(
        "image-small",
        &with(|v| v["image"] = serde_json::json!({"width": 10, "height": 640})),
        &["image.width", "10", "32 to 8192"],
    );
    rejected(
        "image-big",
        &with(|v| v["image"] = serde_json::json!({"width": 1024, "height": 100000})),
        &["image.height", "100000"],
    );
}

#[test]
fn hostile_names_cannot_escape_the_output_folder() {
    rejected("name-dotdot", &with(|v| v["name"] = "../escape".into()), &["`name`", "not allowed"]);
    rejected("name-slash", &with(|v| v["name"] = "/etc".into()), &["`name`"]);
}

#[test]
fn missing_spec_file_is_named() {
    let output = run(&["gen", "--spec", "/nonexistent/spec.json"]);
    assert_eq!(output.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&output.stderr).contains("/nonexistent/spec.json"));
}

#[test]
fn bad_flags_exit_2() {
    let output = run(&["gen", "--spec", "configs/ci-toy.json", "--limit", "0"]);
    assert_eq!(output.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&output.stderr).contains("--limit"));
}

#[test]
fn unwritable_output_folder_gets_a_clear_message() {
    let dir = fresh_dir("spec-errors-unwritable");
    let spec = write_spec(&dir, &base().to_string());
    // A path below a regular file can never be created, even by root.
    let blocker = dir.join("a-file");
    std::fs::write(&blocker, b"not a folder").unwrap();
    let out = blocker.join("out");
    let output = run(&["gen", "--spec", spec.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    // The path given is wrong, not the disk: bad input.
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains(out.to_str().unwrap()) && stderr.contains("not a folder"), "{stderr}");
    assert!(!stderr.contains("Free some space"), "should not blame the disk: {stderr}");
    assert!(!stderr.contains("panicked"));
}

#[test]
fn trailing_data_after_the_spec_is_rejected() {
    let text = base().to_string();
    rejected("trailing-garbage", &format!("{text} xyz"), &["invalid spec", "trailing characters"]);
    rejected("two-specs", &format!("{text}\n{text}"), &["invalid spec", "trailing characters"]);
}

fn city_with(city: &str) -> String {
    city_spec("bad", &[(4, 0.5)], (1, 0, 0), 10, city)
}

fn city_with_graph(city: &str, graph: serde_json::Value) -> String {
    let mut spec: serde_json::Value = serde_json::from_str(&city_with(city)).unwrap();
    spec["graph"] = graph;
    spec.to_string()
}

#[test]
fn unknown_or_conflicting_keys_in_a_distribution_are_named() {
    rejected(
        "dist-typo",
        &city_with(r#"{"confounders": {"rain": {"uniform": [0, 0.2], "choice": [0.9], "typo": 1}}}"#),
        &["city.confounders.rain", "typo", "uniform", "choice"],
    );
    rejected(
        "dist-both",
        &city_with(r#"{"confounders": {"rain": {"uniform": [0, 0.2], "choice": [0.9]}}}"#),
        &["city.confounders.rain", "exactly one", "uniform", "choice"],
    );
    rejected("dist-empty", &city_with(r#"{"confounders": {"fog": {}}}"#), &["city.confounders.fog", "exactly one"]);
    rejected(
        "dist-list",
        &city_with(r#"{"confounders": {"snow": [0, 1]}}"#),
        &["city.confounders.snow", "invalid type: a list"],
    );
}

#[test]
fn lists_in_place_of_objects_are_rejected() {
    rejected(
        "image-list",
        &with(|v| v["image"] = serde_json::json!([1024, 640])),
        &["`image`", "invalid type: a list, expected an object"],
    );
    rejected(
        "splits-list",
        &with(|v| v["splits"] = serde_json::json!([1, 0, 0])),
        &["`splits`", "invalid type: a list, expected an object"],
    );
    rejected(
        "group-list",
        &with(|v| v["groups"][0] = serde_json::json!([8, 0.5])),
        &["`groups[0]`", "expected an object"],
    );
}

#[test]
fn duplicate_keys_are_named() {
    // serde_json writes compact text: `{"frames":10,...}`.
    let text = base().to_string();
    assert!(text.contains(r#""seed":11"#) && text.contains(r#""train":2"#));
    rejected("dup-top", &text.replace(r#""seed":11"#, r#""seed":11,"seed":12"#), &["`seed`", "duplicate key"]);
    rejected(
        "dup-nested",
        &text.replace(r#""train":2"#, r#""train":2,"train":3"#),
        &["`splits.train`", "duplicate key"],
    );
    let city = city_with(r#"{"confounders": {"rain": {"uniform": [0, 0.2], "uniform": [0, 0.5]}}}"#);
    rejected("dup-distribution", &city, &["city.confounders.rain.uniform", "duplicate key"]);
}

#[test]
fn a_partial_driver_takes_the_defaults_for_the_rest() {
    let dir = fresh_dir("spec-partial-driver");
    let spec =
        write_spec(&dir, &city_spec("partial", &[(4, 0.5)], (1, 0, 0), 5, r#"{"driver": {"time_headway": 1.7}}"#));
    let out = dir.join("out");
    gen_ok(&spec, &out, &["--no-images"]);
    let driver = &read_json(&out.join("manifest.json"))["spec"]["city"]["driver"];
    // DriverParams::default() for every field not given.
    let expected = serde_json::json!({
        "time_headway": 1.7, "min_gap": 0.8, "max_acceleration": 1.2, "comfortable_deceleration": 1.5,
        "max_deceleration": 6.0, "reaction_time": 0.3, "perception_noise": 0.04, "lateral_wander": 0.03,
        "curve_acceleration": 1.2
    });
    assert_eq!(driver, &expected);
}

#[test]
fn a_map_too_small_for_a_lane_change_before_the_stop_line_is_named() {
    // Roads 20 m apart leave 8 m between the 12 m wide roads: too short for a lane change before the stop line.
    rejected(
        "map-central",
        &with(|v| v["map"] = serde_json::json!({"north_south_roads": [-10, 10]})),
        &["map.north_south_roads", "8.00 m", "between roads C and D", "at least 13.6 m"],
    );
    rejected(
        "map-extent",
        &with(|v| v["map"] = serde_json::json!({"extent_y": 30})),
        &["map.extent_y", "leave 10.00 m", "north-south roads from -map.extent_y to road B"],
    );
    rejected("map-lane", &with(|v| v["map"] = serde_json::json!({"lane_width": 0})), &["map.lane_width", "above 0"]);
    rejected(
        "map-camera",
        &with(|v| v["map"] = serde_json::json!({"camera_altitude_m": 20})),
        &["map.camera_altitude_m", "20 m shows less than every intersection", "use at least"],
    );
}

#[test]
fn a_grid_town_is_checked_for_its_size_and_room_to_change_lanes() {
    let grid = |g: serde_json::Value| with(|v| v["map"] = serde_json::json!({ "grid": g }));
    rejected(
        "grid-rows-0",
        &grid(serde_json::json!({"rows": 0, "columns": 2})),
        &["map.grid.rows", "0 is not allowed", "1 to 8"],
    );
    rejected(
        "grid-columns-9",
        &grid(serde_json::json!({"rows": 2, "columns": 9})),
        &["map.grid.columns", "9", "1 to 8"],
    );
    rejected("grid-missing", &grid(serde_json::json!({"rows": 2})), &["map.grid", "columns"]);
    rejected(
        "grid-drawn-range",
        &grid(serde_json::json!({"rows": {"uniform": [3, 2]}, "columns": 2})),
        &["map.grid.rows", "[3, 2] has low above high"],
    );
    rejected(
        "grid-drawn-9",
        &grid(serde_json::json!({"rows": 2, "columns": {"choice": [2, 9]}})),
        &["map.grid.columns", "9 is not allowed", "1 to 8"],
    );
    // A range is judged by its ends: listing [1, 2^64 - 1] took all memory.
    rejected(
        "grid-drawn-huge",
        &grid(serde_json::json!({"rows": {"uniform": [1, u64::MAX]}, "columns": 2})),
        &["map.grid.rows", "uniform range [1, 18446744073709551615] is not allowed", "1 to 8"],
    );
    rejected(
        "grid-drawn-empty",
        &grid(serde_json::json!({"rows": {"choice": []}, "columns": 2})),
        &["map.grid.rows", "empty"],
    );
    rejected(
        "grid-drawn-half",
        &grid(serde_json::json!({"rows": 2.5, "columns": 2})),
        &["map.grid.rows", "a whole number", "uniform"],
    );
    // A town that a draw can reach but that breaks a rule is named.
    rejected(
        "grid-drawn-town",
        &with(|v| {
            v["map"] =
                serde_json::json!({"grid": {"rows": {"uniform": [1, 4]}, "columns": 1}, "camera_altitude_m": 45});
        }),
        &["map.camera_altitude_m", "in the grid-3x1 town: 45 m shows less than every intersection"],
    );
    rejected(
        "grid-unknown",
        &grid(serde_json::json!({"rows": 2, "columns": 2, "lane_count": 3})),
        &["lane_count", "block_m", "lanes"],
    );
    rejected(
        "grid-lanes",
        &grid(serde_json::json!({"rows": 2, "columns": 2, "lanes": 4})),
        &["map.grid.lanes", "4 is not allowed", "1 to 3"],
    );
    // Roads in descending order were told as a negative road length.
    rejected(
        "roads-descending",
        &with(|v| v["map"] = serde_json::json!({"east_west_roads": [30, -30]})),
        &["map.east_west_roads", "[30.0, -30.0] is not allowed", "road B's centre line first", "[-30, 30]"],
    );
    // Beyond a byte it was told "0 to 255", which allowed none of them.
    rejected(
        "grid-lanes-1000",
        &grid(serde_json::json!({"rows": 2, "columns": 2, "lanes": 1000})),
        &["map.grid.lanes", "1000 is not allowed", "1 to 3"],
    );
    // 20 m blocks leave 8 m between the 12 m wide roads: too short for a lane change.
    rejected(
        "grid-block",
        &grid(serde_json::json!({"rows": 2, "columns": 3, "block_m": 20})),
        &["map.grid.block_m", "leaves 8.00 m", "between neighbouring roads", "at least 13.6 m"],
    );
    rejected(
        "grid-outer",
        &grid(serde_json::json!({"rows": 1, "columns": 1, "outer_m": 10})),
        &["map.grid.outer_m", "leaves 4.00 m", "beyond the outermost roads"],
    );
    rejected(
        "grid-altitude",
        &with(|v| v["map"] = serde_json::json!({"grid": {"rows": 3, "columns": 3}, "camera_altitude_m": -5})),
        &["map.camera_altitude_m", "-5 is not allowed", "above 0"],
    );
    rejected(
        "camera-area-name",
        &with(|v| v["map"] = serde_json::json!({"camera_area": "everything"})),
        &["map.camera_area", "\"everything\" is not allowed", "network"],
    );
    // An imported network's coordinates run to its size: 20 km is a place,
    // 150 km none that a camera frames.
    rejected(
        "camera-area-too-far",
        &with(|v| v["map"] = serde_json::json!({"camera_area": {"x": [0, 150000], "y": [0, 10]}})),
        &["map.camera_area", "x = [0, 150000] is not allowed", "within +-100000 m"],
    );
    rejected(
        "camera-area-reversed",
        &with(|v| v["map"] = serde_json::json!({"camera_area": {"x": [5, -5], "y": [0, 10]}})),
        &["map.camera_area", "x = [5, -5] is not allowed", "the lower first"],
    );
    rejected(
        "grid-and-roads",
        &with(|v| v["map"] = serde_json::json!({"grid": {"rows": 3, "columns": 3}, "east_west_roads": [-20, 20]})),
        &["map.grid", "places its own roads", "map.east_west_roads"],
    );
}

#[test]
fn a_graph_shape_is_checked_for_its_size_and_the_cars_it_needs() {
    let graph = |g: serde_json::Value| with(|v| v["graph"] = g);
    rejected(
        "graph-shape",
        &graph(serde_json::json!({"shape": "rings"})),
        &["graph.shape", "rings", "pairs", "chains", "forks", "colliders"],
    );
    rejected(
        "graph-cars-7",
        &graph(serde_json::json!({"shape": "chains", "cars": 7})),
        &["graph.cars", "7 is not allowed", "2 to 6"],
    );
    rejected(
        "graph-pairs-of-3",
        &graph(serde_json::json!({"shape": "pairs", "cars": 3})),
        &["graph.cars", "3 is not allowed", "a pair has 2 cars"],
    );
    // Chains and forks take fewer cars per edge than pairs, but one car still has no one to follow.
    rejected(
        "graph-too-few-cars",
        &with(|v| {
            v["graph"] = serde_json::json!({"shape": "forks", "cars": 4});
            v["groups"] = serde_json::json!([{"cars": 1, "edge_proportion": 1.0}]);
        }),
        &["groups[0].edge_proportion", "1 edges in forks of 4 cars", "which need 2 cars"],
    );
    rejected(
        "graph-platoon",
        &city_with_graph(r#"{"start": {"platoon_cars": 2}}"#, serde_json::json!({"shape": "chains"})),
        &["graph.cars", "3 is not allowed with city.start.platoon_cars = 2", "one chain start in one platoon"],
    );
    // Colliders need a driver who gives way: not in the toy world, not
    // where every junction has lights with protected turns.
    rejected(
        "colliders-toy",
        &graph(serde_json::json!({"shape": "colliders"})),
        &["graph.shape", "\"colliders\" needs \"world\": \"city\"", "pairs, chains or forks"],
    );
    rejected(
        "colliders-lights",
        &city_spec("bad", &[(8, 0.5)], (1, 0, 0), 10, "{}").replacen('{', r#"{"graph": {"shape": "colliders"}, "#, 1),
        &[
            "graph.shape",
            "junctions where a driver gives way",
            "\"priority\", \"all_way_stop\" or \"right_before_left\"",
        ],
    );
    rejected(
        "colliders-cars",
        &city_with_graph("{}", serde_json::json!({"shape": "colliders", "cars": 4})),
        &["graph.cars", "4 is not allowed with graph.shape \"colliders\"", "a collider has 3 cars"],
    );
}

#[test]
fn a_held_out_split_is_checked_and_named_as_the_spec_names_it() {
    rejected(
        "held-out-train",
        &with(|v| v["held_out"] = serde_json::json!({"train": {"graph": {"shape": "chains"}}})),
        &["held_out", "train", "val", "test"],
    );
    rejected(
        "held-out-graph",
        &with(|v| v["held_out"] = serde_json::json!({"test": {"graph": {"shape": "chains", "cars": 9}}})),
        &["held_out.test.graph.cars", "9 is not allowed"],
    );
    rejected(
        "held-out-map",
        &with(|v| v["held_out"] = serde_json::json!({"val": {"map": {"grid": {"rows": 9, "columns": 2}}}})),
        &["held_out.val.map.grid.rows", "9 is not allowed"],
    );
    rejected(
        "held-out-cars",
        &with(|v| {
            v["groups"] = serde_json::json!([{"cars": 1, "edge_proportion": 1.0}]);
            v["graph"] = serde_json::json!({"shape": "chains"});
        }),
        &["groups[0].edge_proportion", "which need 2 cars"],
    );
    rejected(
        "held-out-altitude",
        &with(|v| {
            v["held_out"] =
                serde_json::json!({"test": {"map": {"grid": {"rows": 4, "columns": 1}, "camera_altitude_m": 45}}});
        }),
        &["held_out.test.map.camera_altitude_m", "in the grid-4x1 town test holds out"],
    );
}

#[test]
fn city_starts_are_checked_against_the_driver() {
    rejected(
        "gap-below-min-gap",
        &city_with(r#"{"driver": {"min_gap": 2.0}, "start": {"follower_gap_m": {"uniform": [1.0, 8.0]}}}"#),
        &["city.start.follower_gap_m", "1 is not allowed", "min_gap = 2"],
    );
    rejected(
        "hard-negative-share",
        &city_with(r#"{"start": {"hard_negative_share": 1.5}}"#),
        &["city.start.hard_negative_share", "1.5", "0 to 1"],
    );
    rejected(
        "speed-fraction",
        &city_with(r#"{"start": {"speed_fraction": {"choice": [0.5, 2]}}}"#),
        &["city.start.speed_fraction", "2 is not allowed"],
    );
    rejected(
        "platoon-of-one",
        &city_with(r#"{"start": {"platoon_cars": 1}}"#),
        &["city.start.platoon_cars", "1 is not allowed", "2 to 16"],
    );
    rejected(
        "platoons-and-hard-negatives",
        &city_with(r#"{"start": {"platoon_cars": 4, "hard_negative_share": 0.5}}"#),
        &["city.start.hard_negative_share", "platoon_cars = 4", "remove hard_negative_share"],
    );
    // 3 pairs cannot be drawn from two platoons of 3 cars.
    rejected(
        "odd-platoons",
        &city_spec("bad", &[(6, 1.0)], (1, 0, 0), 10, r#"{"start": {"platoon_cars": 3}}"#),
        &["groups[0]", "3 leader-follower pairs do not fit in platoons of 3", "even city.start.platoon_cars"],
    );
    let toy_gap_in_the_city =
        city_with("{}").replacen(r#""world": "city","#, r#""world": "city", "leader_gap_px": 30,"#, 1);
    rejected("leader-gap-in-city", &toy_gap_in_the_city, &["leader_gap_px", "toy", "city.start.follower_gap_m"]);
}

#[test]
fn numbers_are_echoed_as_written_and_every_value_names_what_is_allowed() {
    // Before: 2^64 came back as `1.8446744073709552e+19`, 1e308 as 309
    // digits, -1 for a camera's car as "did not match any variant of
    // untagged enum CarRef", and a 32x32 toy image was blamed on
    // leader_gap_px, which the spec did not set.
    let seed = with(|v| v["seed"] = 12345.into()).replace("12345", "18446744073709551616");
    rejected("seed-2-64", &seed, &["field `seed`", "above 18446744073709551615 is too large", "whole number from 0"]);
    let frames = with(|v| v["frames"] = 12345.into()).replace("12345", "2.5");
    // The field's own range, not its type's ("from 0 to 4294967295" for
    // frames, "0 or more" for a negative one).
    rejected(
        "frames-fraction",
        &frames,
        &["field `frames`", "2.5 is not a whole number: use a whole number from 1 to 100000"],
    );
    let cars = with(|v| v["groups"][0]["cars"] = 12345.into()).replace("12345", "2.5");
    rejected(
        "cars-fraction",
        &cars,
        &["field `groups[0].cars`", "2.5 is not a whole number: use a whole number from 1 to 255"],
    );
    let train = with(|v| v["splits"]["train"] = 4_294_967_296u64.into());
    rejected("splits-u32", &train, &["field `splits.train`", "is too large: use a whole number from 0 to 10000000"]);
    // Platoons that cannot be placed name the gap within them too: a gap
    // of 1 cm was blamed on the cars and the platoon size alone.
    rejected(
        "platoon-gap-tiny",
        &city_with(
            r#"{"start": {"follower_gap_m": {"uniform": [0.01, 0.01]}, "platoon_cars": 4}, "driver": {"min_gap": 0.01}}"#,
        ),
        &["groups[0]", "could not place 4 cars in platoons of 4", "wider gaps within them (city.start.follower_gap_m)"],
    );
    // Light timings past any sense: at a cycle_scale of 1e-300 every light
    // changed at every frame, exit 0.
    rejected(
        "cycle-scale-tiny",
        &city_with(r#"{"lights": {"cycle_scale": 1e-300}}"#),
        &["city.lights.cycle_scale", "1e-300 is not allowed", "from 0.01 to 10"],
    );
    let schedule = r#"{"lights": {"overrides": [{"intersection": "AC", "approach": "W", "signal": "straight",
        "offset": 0, "schedule": [{"colour": "green", "duration": 5}, {"colour": "red", "duration": 1e-300}]}]}}"#;
    rejected(
        "schedule-tiny",
        &city_with(schedule),
        &["city.lights.overrides[0].schedule[1].duration", "1e-300 is not allowed", "from 0.04 to 1000000"],
    );
    // A phase longer than any scenario (1e300 s was taken and written so
    // to light_changes.csv), and one light given two schedules (the second
    // silently won).
    rejected(
        "schedule-endless",
        &city_with(&schedule.replace("1e-300", "1e300")),
        &["city.lights.overrides[0].schedule[1].duration", "1e300 is not allowed", "(the longest scenario)"],
    );
    let twice = r#"{"lights": {"overrides": [
        {"intersection": "AC", "approach": "W", "signal": "straight", "schedule": [{"colour": "green", "duration": 5}]},
        {"intersection": "AD", "approach": "W", "signal": "straight", "schedule": [{"colour": "red", "duration": 5}]},
        {"intersection": "AC", "approach": "W", "signal": "straight", "schedule": [{"colour": "red", "duration": 5}]}]}}"#;
    rejected(
        "override-twice",
        &city_with(twice),
        &["field `city.lights.overrides[2]`", "AC W straight is given twice (also overrides[0])"],
    );
    // A long name is shown by its start and length: 100 MB of it was echoed whole.
    let long = with(|v| v["name"] = "a".repeat(100_000).into());
    rejected("name-long", &long, &["field `name`", "\"aaaa", "... (100000 characters) is not allowed"]);
    let dir = fresh_dir("spec-errors-name-long-size");
    let said =
        run(&["gen", "--spec", write_spec(&dir, &long).to_str().unwrap(), "--out", dir.join("o").to_str().unwrap()]);
    assert!(said.stderr.len() < 1_000, "{} bytes of error", said.stderr.len());
    // Below 0 names the field's range, not the type's.
    let frames = with(|v| v["frames"] = (-5).into());
    rejected("frames-negative", &frames, &["field `frames`", "-5 is too small: use a whole number from 1 to 100000"]);
    let frames = with(|v| v["frames"] = 12345.into()).replace("12345", "1000000000000.0");
    rejected("frames-1e12", &frames, &["field `frames`", " 1000000000000 is too large"]);
    // The largest value a field holds, written as a float, is not "too large".
    let frames = with(|v| v["frames"] = 12345.into()).replace("12345", "4294967295.0");
    rejected("frames-max-as-float", &frames, &["field `frames`", "4294967295 is written as a decimal"]);
    // A value of the wrong kind is told in a JSON file's words, not Rust's
    // ("expected u32", "expected f64" before).
    let frames = with(|v| v["frames"] = "ten".into());
    rejected("frames-text", &frames, &["field `frames`", "string \"ten\", expected a whole number"]);
    let interval = with(|v| v["frame_interval"] = "x".into());
    rejected("interval-text", &interval, &["field `frame_interval`", "string \"x\", expected a number"]);
    // 1e-300 s was taken, and stats printed speeds of 300 digits.
    let interval = with(|v| v["frame_interval"] = 1e-300.into());
    rejected("interval-tiny", &interval, &["field `frame_interval`", "1e-300 is not allowed", "from 0.001 to 10"]);
    let proportion = with(|v| v["groups"][0]["edge_proportion"] = 0.25.into()).replace("0.25", "1e308");
    rejected("proportion-1e308", &proportion, &["groups[0].edge_proportion", "1e308 is not allowed"]);
    rejected(
        "first-person-negative",
        &with(|v| v["cameras"] = serde_json::json!([{"name": "driver", "first_person": -1}])),
        &["cameras[0].first_person", "-1 is not a car: its id (a whole number from 0) or its name"],
    );
    // A zoom on a perspective camera was taken and did nothing.
    for (case, camera, kind) in [
        ("zoom-first-person", serde_json::json!({"name": "driver", "first_person": 0, "zoom": 3}), "first_person"),
        ("zoom-pinhole", serde_json::json!({"name": "high", "pinhole": {}, "zoom": 2}), "pinhole"),
    ] {
        rejected(
            case,
            &with(|v| v["cameras"] = serde_json::json!([camera])),
            &["cameras[0].zoom", &format!("does nothing for a {kind} camera"), "leave it out"],
        );
    }
    rejected(
        "pinhole-below-ground",
        &with(|v| v["cameras"] = serde_json::json!([{"name": "low", "pinhole": {"position": [0, 0, -5]}}])),
        &["cameras[0].pinhole.position[2]", "-5 is not allowed", "above the ground"],
    );
    // Far beyond any map, as map.camera_area is bounded: the frames were
    // blank and poses.csv held inf.
    rejected(
        "camera-far-away",
        &with(|v| v["cameras"] = serde_json::json!([{"name": "far", "static": {"centre": [0, 1e30]}}])),
        &["cameras[0].static.centre[1]", "1e30 is not allowed", "within +-100000"],
    );
    rejected(
        "pinhole-far-up",
        &with(|v| v["cameras"] = serde_json::json!([{"name": "up", "pinhole": {"position": [0, 0, 1e308]}}])),
        &["cameras[0].pinhole.position[2]", "1e308 is not allowed"],
    );
    rejected(
        "tiny-toy-image",
        &with(|v| v["image"] = serde_json::json!({"width": 32, "height": 32})),
        &["field `image`", "a 32x32 image shows 0.40 px per metre", "Use a larger image"],
    );
}

#[test]
fn actuated_lights_need_an_imported_network() {
    // A grid town's lights run the fixed cycle: nothing to actuate.
    rejected(
        "actuated-grid",
        &city_with(r#"{"lights": {"actuated": true}}"#),
        &["city.lights.actuated", "no split drives a SUMO network", "map.sumo"],
    );
    rejected("actuated-type", &city_with(r#"{"lights": {"actuated": "yes"}}"#), &["city.lights.actuated", "boolean"]);
}

#[test]
fn platoons_packed_too_tightly_are_refused_before_anything_is_written_never_midway() {
    // 100 cars in platoons of 4 with gaps of 1-12 m on a small town: the
    // first scenario planned, and one scenario in 4 then failed midway
    // through the dataset (exit 1, two scenarios left behind). Now each
    // seed's dataset is either refused up front or written whole.
    let (mut refused, mut written) = (0, 0);
    for seed in 1..=8 {
        let mut spec: serde_json::Value = serde_json::from_str(&city_spec(
            "tight",
            &[(100, 0.5)],
            (20, 5, 5),
            2,
            r#"{"start": {"follower_gap_m": {"uniform": [1, 12]}, "platoon_cars": 4}}"#,
        ))
        .unwrap();
        spec["seed"] = seed.into();
        spec["map"] = serde_json::json!({"north_south_roads": [-24, 24], "extent_x": 44, "camera_altitude_m": 48});
        let dir = fresh_dir(&format!("spec-errors-tight-{seed}"));
        let path = write_spec(&dir, &spec.to_string());
        let out = dir.join("out");
        let args =
            ["gen", "--spec", path.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-images", "--no-effects"];
        let result = run(&args);
        let stderr = String::from_utf8_lossy(&result.stderr);
        match result.status.code() {
            Some(2) => {
                assert!(stderr.contains("could not place 100 cars in platoons of 4"), "seed {seed}: {stderr}");
                assert!(!out.exists(), "seed {seed}: refused, yet wrote {out:?}");
                refused += 1;
            }
            Some(0) => {
                let manifest: serde_json::Value =
                    serde_json::from_str(&std::fs::read_to_string(out.join("manifest.json")).unwrap()).unwrap();
                assert_eq!((&manifest["scenarios"], &manifest["complete"]), (&30.into(), &true.into()), "seed {seed}");
                written += 1;
            }
            code => panic!("seed {seed}: exit {code:?} midway: {stderr}"),
        }
    }
    // Both outcomes happen at this density: the test checks each.
    assert!(refused > 0 && written > 0, "refused {refused}, written {written}");
}
