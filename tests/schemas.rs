//! The schemas in data-schema/ agree with the parsers: every JSON input of
//! the tool (specs, scenario files, intervention files) is checked against
//! both its schema and the real parser (the library functions `gen`, `run`
//! and `counterfactual` call); good documents pass both, bad ones fail both.
//! Duplicate keys and trailing data are invisible to JSON Schema, so for those
//! only the parser is checked.

mod common;
use causalcity::map::CityMap;
use causalcity::orchestrate::scenario_file::{load, load_interventions, FileOptions};
use causalcity::spec::DatasetSpec;
use common::*;
use serde_json::{json, Value};
use std::path::Path;
use std::sync::Arc;

fn schema_errors(schema: &jsonschema::Validator, doc: &Value) -> Vec<String> {
    schema.iter_errors(doc).map(|e| format!("{e} at {}", e.instance_path())).collect()
}

// ---------------------------------------------------------------------------
// Specs

fn spec_parser(text: &str) -> Result<(), String> {
    DatasetSpec::from_json(text).map(|_| ()).map_err(|e| e.to_string())
}

fn city_base() -> Value {
    json!({
        "name": "agree", "world": "city", "seed": 3, "frames": 10,
        "groups": [{"cars": 4, "edge_proportion": 0.5}],
        "splits": {"train": 1, "val": 0, "test": 0},
        "city": {
            "driver": {"time_headway": 1.2},
            "lights": {"cycle_scale": 0.5, "offsets": [0, 1, 2, 3],
                "overrides": [{"intersection": "AC", "approach": "W", "signal": "straight",
                               "schedule": [{"colour": "green", "duration": 5}]}]},
            "confounders": {"rain": {"uniform": [0, 0.2]}, "fog": {"choice": [0, 0.5]}, "hour": 18}
        },
        "cameras": [{"name": "top", "static": {"centre": [0, 0]}}]
    })
}

fn edited(base: &Value, edit: impl FnOnce(&mut Value)) -> Value {
    let mut v = base.clone();
    edit(&mut v);
    v
}

#[test]
fn spec_schema_and_parser_agree() {
    let schema = validator("spec.schema.json");
    let mut good: Vec<(String, Value)> =
        json_files("configs").into_iter().map(|f| (f.display().to_string(), read_json(&f))).collect();
    let base = city_base();
    good.push(("city base".into(), base.clone()));
    good.push(("empty driver".into(), edited(&base, |v| v["city"]["driver"] = json!({}))));
    good.push(("no city".into(), edited(&base, |v| v.as_object_mut().unwrap().remove("city").map(|_| ()).unwrap())));
    good.push(("fixed rain".into(), edited(&base, |v| v["city"]["confounders"]["rain"] = json!(0.3))));
    good.push((
        "lights per intersection".into(),
        edited(&base, |v| v["city"]["lights"]["phase"] = json!("random_per_intersection")),
    ));
    good.push(("fixed lights".into(), edited(&base, |v| v["city"]["lights"]["phase"] = json!("fixed"))));
    good.push((
        "a bigger map".into(),
        edited(&base, |v| {
            v["map"] = json!({"lane_width": 3.5, "east_west_roads": [-30, 30], "north_south_roads": [-40, 45],
                              "extent_x": 80, "extent_y": 60, "camera_altitude_m": 80})
        }),
    ));
    good.push(("chains of 4".into(), edited(&base, |v| v["graph"] = json!({"shape": "chains", "cars": 4}))));
    good.push(("forks".into(), edited(&base, |v| v["graph"] = json!({"shape": "forks"}))));
    good.push(("colliders".into(), edited(&base, |v| v["graph"] = json!({"shape": "colliders"}))));
    good.push((
        "held-out test".into(),
        edited(&base, |v| {
            v["held_out"] = json!({"test": {"map": {"grid": {"rows": 4, "columns": 4}}, "graph": {"shape": "forks"}}})
        }),
    ));
    good.push((
        "held-out confounders".into(),
        edited(&base, |v| {
            v["held_out"] = json!({"test": {"confounders": {"hour": {"uniform": [20, 24]}, "rain": 1.0}}})
        }),
    ));
    good.push((
        "held-out cars".into(),
        edited(&base, |v| v["held_out"] = json!({"val": {"cars": 6}, "test": {"cars": 12}})),
    ));
    good.push((
        "T-junctions".into(),
        edited(&base, |v| v["map"] = json!({"grid": {"rows": 3, "columns": 3, "missing": ["D0", "B2"], "lanes": 1}})),
    ));
    good.push((
        "three lanes".into(),
        edited(&base, |v| {
            v["map"] = json!({"grid": {"rows": 2, "columns": 2, "lanes": 3, "block_m": 40, "outer_m": 30}})
        }),
    ));
    good.push((
        "junctions without lights".into(),
        edited(&base, |v| {
            v["map"] = json!({"grid": {"rows": 2, "columns": 2, "control": "priority"}});
            v["city"]["lights"].as_object_mut().unwrap().remove("overrides");
        }),
    ));
    good.push((
        "some junctions without lights".into(),
        edited(&base, |v| {
            v["map"] = json!({"grid": {"rows": 2, "columns": 2, "control": {"AD": "all_way_stop", "BD": "signals"}}})
        }),
    ));
    good.push((
        "dead ends".into(),
        edited(&base, |v| {
            v["map"] = json!({"grid": {"rows": 3, "columns": 3, "block_m": 40, "dead_ends": {"B2": "BE"}}})
        }),
    ));
    good.push(("network camera".into(), edited(&base, |v| v["map"] = json!({"camera_area": "network"}))));
    good.push((
        "camera area".into(),
        edited(&base, |v| v["map"] = json!({"camera_area": {"x": [-30, 30], "y": [-20, 20]}})),
    ));
    good.push(("cooperative rules".into(), edited(&base, |v| v["city"]["rules"] = json!("cooperative"))));
    // A big imported network's coordinates run to tens of kilometres.
    good.push((
        "camera area far out".into(),
        edited(&base, |v| v["map"] = json!({"camera_area": {"x": [21000, 21600], "y": [14000, 14400]}})),
    ));
    good.push((
        "drawn towns".into(),
        edited(&base, |v| v["map"] = json!({"grid": {"rows": {"uniform": [2, 3]}, "columns": {"choice": [2, 4]}}})),
    ));
    for (what, doc) in &good {
        let errors = schema_errors(&schema, doc);
        assert!(errors.is_empty(), "{what}: schema rejects a good spec: {errors:?}");
        spec_parser(&doc.to_string()).unwrap_or_else(|e| panic!("{what}: parser rejects a good spec: {e}"));
    }

    let bad: Vec<(&str, Value)> = vec![
        ("unknown top-level key", edited(&base, |v| v["colour_mode"] = json!(1))),
        ("unknown key in a group", edited(&base, |v| v["groups"][0]["edges"] = json!(2))),
        ("unknown driving rules", edited(&base, |v| v["city"]["rules"] = json!("polite"))),
        ("unknown key in splits", edited(&base, |v| v["splits"]["dev"] = json!(1))),
        ("unknown key in city", edited(&base, |v| v["city"]["speed"] = json!(1))),
        ("unknown key in driver", edited(&base, |v| v["city"]["driver"]["patience"] = json!(1))),
        ("unknown key in lights", edited(&base, |v| v["city"]["lights"]["colour_order"] = json!(1))),
        ("unknown light phase", edited(&base, |v| v["city"]["lights"]["phase"] = json!("sometimes"))),
        ("unknown key in map", edited(&base, |v| v["map"] = json!({"blocks": 3}))),
        ("unknown graph shape", edited(&base, |v| v["graph"] = json!({"shape": "rings"}))),
        ("camera area everything", edited(&base, |v| v["map"] = json!({"camera_area": "everything"}))),
        ("camera area without y", edited(&base, |v| v["map"] = json!({"camera_area": {"x": [-30, 30]}}))),
        ("held-out train", edited(&base, |v| v["held_out"] = json!({"train": {"graph": {"shape": "chains"}}}))),
        ("held-out cars of 0", edited(&base, |v| v["held_out"] = json!({"test": {"cars": 0}}))),
        ("held-out cars of 2.5", edited(&base, |v| v["held_out"] = json!({"val": {"cars": 2.5}}))),
        (
            "held-out unknown confounder",
            edited(&base, |v| v["held_out"] = json!({"test": {"confounders": {"hail": 1.0}}})),
        ),
        (
            "missing segment not a name",
            edited(&base, |v| v["map"] = json!({"grid": {"rows": 2, "columns": 2, "missing": ["c0"]}})),
        ),
        (
            "missing segment twice",
            edited(&base, |v| v["map"] = json!({"grid": {"rows": 3, "columns": 3, "missing": ["B2", "B2"]}})),
        ),
        (
            "unknown junction control",
            edited(&base, |v| v["map"] = json!({"grid": {"rows": 2, "columns": 2, "control": "roundabout"}})),
        ),
        (
            "unknown control of one junction",
            edited(&base, |v| v["map"] = json!({"grid": {"rows": 2, "columns": 2, "control": {"AC": "stop"}}})),
        ),
        (
            "dead end kept by a list",
            edited(&base, |v| {
                v["map"] = json!({"grid": {"rows": 3, "columns": 3, "block_m": 40, "dead_ends": {"B2": ["BE"]}}})
            }),
        ),
        ("grid rows of 2.5", edited(&base, |v| v["map"] = json!({"grid": {"rows": 2.5, "columns": 2}}))),
        (
            "grid rows drawn twice",
            edited(&base, |v| v["map"] = json!({"grid": {"rows": {"uniform": [2, 3], "choice": [2]}, "columns": 2}})),
        ),
        (
            "grid columns up to 9",
            edited(&base, |v| v["map"] = json!({"grid": {"rows": 2, "columns": {"uniform": [2, 9]}}})),
        ),
        ("unknown key in graph", edited(&base, |v| v["graph"] = json!({"shape": "chains", "length": 3}))),
        ("a chain of 7", edited(&base, |v| v["graph"] = json!({"shape": "chains", "cars": 7}))),
        ("map roads as an object", edited(&base, |v| v["map"] = json!({"east_west_roads": {"A": 14, "B": -14}}))),
        ("three map roads", edited(&base, |v| v["map"] = json!({"north_south_roads": [-30, 0, 30]}))),
        ("map lane width 0", edited(&base, |v| v["map"] = json!({"lane_width": 0}))),
        ("camera altitude 0", edited(&base, |v| v["map"] = json!({"camera_altitude_m": 0}))),
        ("unknown key in an override", edited(&base, |v| v["city"]["lights"]["overrides"][0]["x"] = json!(1))),
        (
            "unknown key in a schedule step",
            edited(&base, |v| v["city"]["lights"]["overrides"][0]["schedule"][0]["x"] = json!(1)),
        ),
        ("unknown key in confounders", edited(&base, |v| v["city"]["confounders"]["smog"] = json!(0.1))),
        (
            "unknown key in a distribution",
            edited(&base, |v| v["city"]["confounders"]["rain"] = json!({"uniform": [0, 0.2], "typo": 1})),
        ),
        (
            "two forms in a distribution",
            edited(&base, |v| v["city"]["confounders"]["rain"] = json!({"uniform": [0, 0.2], "choice": [0.9]})),
        ),
        ("empty distribution", edited(&base, |v| v["city"]["confounders"]["rain"] = json!({}))),
        ("distribution as a list", edited(&base, |v| v["city"]["confounders"]["rain"] = json!([0, 0.2]))),
        ("uniform of three", edited(&base, |v| v["city"]["confounders"]["rain"] = json!({"uniform": [0, 0.1, 0.2]}))),
        ("unknown key in a camera", edited(&base, |v| v["cameras"][0]["fov"] = json!(90))),
        ("unknown key in a static view", edited(&base, |v| v["cameras"][0]["static"]["z"] = json!(9))),
        ("image as a list", edited(&base, |v| v["image"] = json!([1024, 640]))),
        ("splits as a list", edited(&base, |v| v["splits"] = json!([1, 0, 0]))),
        ("group as a list", edited(&base, |v| v["groups"][0] = json!([4, 0.5]))),
        ("driver as a list", edited(&base, |v| v["city"]["driver"] = json!([1.2, 0.8]))),
        ("frames as text", edited(&base, |v| v["frames"] = json!("many"))),
        ("negative seed", edited(&base, |v| v["seed"] = json!(-1))),
        ("unknown world", edited(&base, |v| v["world"] = json!("mars"))),
        ("driver field as text", edited(&base, |v| v["city"]["driver"]["min_gap"] = json!("wide"))),
        ("three offsets", edited(&base, |v| v["city"]["lights"]["offsets"] = json!([0, 1, 2]))),
        ("an offset of 1e300 s", edited(&base, |v| v["city"]["lights"]["offsets"] = json!([0, 1, 2, 1e300]))),
        (
            "an override's offset of 1e300 s",
            edited(&base, |v| v["city"]["lights"]["overrides"][0]["offset"] = json!(1e300)),
        ),
        ("missing splits", edited(&base, |v| v.as_object_mut().unwrap().remove("splits").map(|_| ()).unwrap())),
        ("no frames", edited(&base, |v| v["frames"] = json!(0))),
        ("tiny image", edited(&base, |v| v["image"] = json!({"width": 10, "height": 640}))),
        ("tiny camera", edited(&base, |v| v["cameras"][0]["width"] = json!(10))),
        ("huge camera", edited(&base, |v| v["cameras"][0]["height"] = json!(9000))),
        ("unknown intersection", edited(&base, |v| v["city"]["lights"]["overrides"][0]["intersection"] = json!("XY"))),
    ];
    for (what, doc) in &bad {
        assert!(!schema_errors(&schema, doc).is_empty(), "{what}: schema accepts a bad spec");
        assert!(spec_parser(&doc.to_string()).is_err(), "{what}: parser accepts a bad spec");
    }

    // Invisible to JSON Schema: the parser alone.
    let text = base.to_string();
    let inner = &text[1..];
    for (what, text) in [
        ("trailing garbage", format!("{text} xyz")),
        ("two specs", format!("{text}\n{text}")),
        ("duplicate top-level key", format!("{{\"seed\": 4, {inner}")),
        ("duplicate key in a distribution", text.replace(r#""hour":18"#, r#""hour":18,"hour":6"#)),
        ("duplicate key in a group", text.replace(r#""cars":4"#, r#""cars":4,"cars":5"#)),
    ] {
        assert_ne!(text, base.to_string(), "{what}: the edit must change the text");
        let e = spec_parser(&text).expect_err(what);
        assert!(e.contains("duplicate") || e.contains("trailing"), "{what}: {e}");
    }
}

// ---------------------------------------------------------------------------
// Scenario files and intervention files

fn map() -> Arc<CityMap> {
    Arc::new(CityMap::default())
}

fn scenario_parser(dir: &Path, name: &str, text: &str) -> Result<(), String> {
    let file = dir.join(format!("{name}.json"));
    std::fs::write(&file, text).unwrap();
    load(&file, FileOptions::default(), &map()).map(|_| ()).map_err(|e| e.to_string())
}

fn scenario_base() -> Value {
    json!([{
        "Name": "agree", "frames": 30, "seed": 2,
        "Vehicles": [
            {"Id": "Car_1", "Spawn": "A1w", "SpawnAtDistance": 5, "DriveQueue": ["straight"], "MergeAtDistances": [0],
             "desired_speeds": [2, 2], "time_headway": 1.5, "runs_red_lights": false, "colour": "#ff8800"},
            {"Id": "Car_2", "Spawn": "B1w", "DriveQueue": ["straight"]}
        ],
        "city": {"driver": {"min_gap": 1.0}, "confounders": {"rain": {"choice": [0, 0.5]}}},
        "interventions": interventions_base(),
        "cameras": [{"name": "chase1", "chase": "Car_1"}]
    }])
}

fn interventions_base() -> Value {
    json!([
        {"at": 1, "do": "stop", "car": "Car_1", "seconds": 2, "label": "brake"},
        {"at_frame": 3, "do": "set_desired_speed", "car": "Car_2", "speed": 3},
        {"when": {"car": "Car_1", "reaches": "AC"}, "do": "run_red_light", "car": "Car_1"},
        {"when": {"light": "AC/W/straight", "turns": "red"}, "do": "set_light", "light": "AC/W/straight",
         "colour": "green", "seconds": 3},
        {"at": 0.5, "do": "set_light_plan", "light": "BD/N/left", "offset": 2,
         "schedule": [{"colour": "red", "duration": 4}, {"colour": "green", "duration": 4}]},
        {"at": 1.5, "do": "replace_actions", "car": "Car_2", "actions": ["straight"], "merge_distances": [0]},
        {"at": 2, "do": "set_confounder", "confounder": "hour", "value": 20, "comment": "dusk"},
        {"at": 3, "do": "remove", "car": "Car_2"},
        {"at": 4, "do": "none"}
    ])
}

#[test]
fn scenario_file_schema_and_parser_agree() {
    let schema = validator("scenario-file.schema.json");
    let dir = fresh_dir("schemas-scenario");
    let mut good: Vec<(String, Value)> =
        json_files("configs/examples").into_iter().map(|f| (f.display().to_string(), read_json(&f))).collect();
    let base = scenario_base();
    good.push(("base".into(), base.clone()));
    good.push(("one object".into(), base[0].clone()));
    good.push(("toy world".into(), json!({"Name": "t", "world": "toy", "Vehicles": [{"Id": "a", "Spawn": "C0w"}]})));
    good.push((
        "a grid town".into(),
        json!({"Name": "g", "map": {"grid": {"rows": 3, "columns": 3}}, "Vehicles": [{"Id": "a", "Spawn": "E1w"}]}),
    ));
    // An imported network names its lanes by SUMO's ids (the network beside the file).
    let net = "grid2-arrows.net.xml";
    std::fs::copy(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/sumo").join(net), dir.join(net)).unwrap();
    good.push((
        "a SUMO network".into(),
        json!({"Name": "n", "map": {"sumo": net}, "Vehicles": [{"Id": "a", "Spawn": "B0B1_0", "DriveQueue": ["right"]}]}),
    ));
    for (k, (what, doc)) in good.iter().enumerate() {
        let errors = schema_errors(&schema, doc);
        assert!(errors.is_empty(), "{what}: schema rejects a good scenario file: {errors:?}");
        scenario_parser(&dir, &format!("good{k}"), &doc.to_string())
            .unwrap_or_else(|e| panic!("{what}: parser rejects a good scenario file: {e}"));
    }

    let s = |edit: fn(&mut Value)| edited(&base, |v| edit(&mut v[0]));
    let bad: Vec<(&str, Value)> = vec![
        ("unknown scenario key", s(|v| v["Frames"] = json!(10))),
        ("unknown vehicle key", s(|v| v["Vehicles"][1]["Speed"] = json!(3))),
        ("unknown intervention key", s(|v| v["interventions"][0]["force"] = json!(3))),
        ("unknown key in when", s(|v| v["interventions"][2]["when"]["after"] = json!(1))),
        ("unknown key in a schedule step", s(|v| v["interventions"][4]["schedule"][0]["x"] = json!(1))),
        ("a key of another effect", s(|v| v["interventions"][0]["speed"] = json!(3))),
        ("extra key on none", s(|v| v["interventions"][8]["car"] = json!("Car_1"))),
        ("unknown key in city", s(|v| v["city"]["driver"]["patience"] = json!(1))),
        ("unknown key in a distribution", s(|v| v["city"]["confounders"]["rain"]["typo"] = json!(1))),
        ("unknown key in a camera", s(|v| v["cameras"][0]["fov"] = json!(1))),
        ("vehicles as an object", s(|v| v["Vehicles"] = json!({"Id": "Car_1", "Spawn": "A1w"}))),
        ("vehicle as a list", s(|v| v["Vehicles"][1] = json!(["Car_2", "B1w"]))),
        ("distance as text", s(|v| v["Vehicles"][0]["SpawnAtDistance"] = json!("far"))),
        ("drive queue as text", s(|v| v["Vehicles"][1]["DriveQueue"] = json!("straight"))),
        ("unknown action", s(|v| v["Vehicles"][1]["DriveQueue"] = json!(["fly"]))),
        ("bad spawn", s(|v| v["Vehicles"][1]["Spawn"] = json!("Q9q"))),
        ("a SUMO lane id in the default city", s(|v| v["Vehicles"][1]["Spawn"] = json!("B0B1_0"))),
        ("a map that draws", s(|v| v["map"] = json!({"grid": {"rows": {"uniform": [2, 3]}, "columns": 2, "x": 1}}))),
        ("missing Id", s(|v| v["Vehicles"][1].as_object_mut().unwrap().remove("Id").map(|_| ()).unwrap())),
        ("bad colour", s(|v| v["Vehicles"][0]["colour"] = json!("orange"))),
        ("no frames", s(|v| v["frames"] = json!(0))),
        ("unknown world", s(|v| v["world"] = json!("mars"))),
        ("two triggers", s(|v| v["interventions"][0]["at_frame"] = json!(2))),
        ("no trigger", s(|v| v["interventions"][0].as_object_mut().unwrap().remove("at").map(|_| ()).unwrap())),
        ("unknown effect", s(|v| v["interventions"][0]["do"] = json!("fly"))),
        ("missing do", s(|v| v["interventions"][0].as_object_mut().unwrap().remove("do").map(|_| ()).unwrap())),
        (
            "missing seconds",
            s(|v| v["interventions"][0].as_object_mut().unwrap().remove("seconds").map(|_| ()).unwrap()),
        ),
        ("missing colour", s(|v| v["interventions"][3].as_object_mut().unwrap().remove("colour").map(|_| ()).unwrap())),
        ("mixed when", s(|v| v["interventions"][2]["when"]["turns"] = json!("red"))),
        ("unknown light colour", s(|v| v["interventions"][3]["colour"] = json!("blue"))),
        ("unknown light", s(|v| v["interventions"][3]["light"] = json!("AC/Q/straight"))),
        ("unknown confounder", s(|v| v["interventions"][6]["confounder"] = json!("smog"))),
        (
            "rain above 1",
            s(|v| {
                v["interventions"][6]["confounder"] = json!("rain");
                v["interventions"][6]["value"] = json!(2);
            }),
        ),
        ("negative time", s(|v| v["interventions"][0]["at"] = json!(-1))),
        ("zero seconds", s(|v| v["interventions"][0]["seconds"] = json!(0))),
        ("empty schedule", s(|v| v["interventions"][4]["schedule"] = json!([]))),
        ("schedule step as a list", s(|v| v["interventions"][4]["schedule"][0] = json!(["red", 4]))),
        ("when as a list", s(|v| v["interventions"][2]["when"] = json!(["Car_1", "AC"]))),
        ("intervention as a list", s(|v| v["interventions"][0] = json!([1, "stop"]))),
        ("empty file list", json!([])),
    ];
    for (k, (what, doc)) in bad.iter().enumerate() {
        assert!(!schema_errors(&schema, doc).is_empty(), "{what}: schema accepts a bad scenario file");
        assert!(
            scenario_parser(&dir, &format!("bad{k}"), &doc.to_string()).is_err(),
            "{what}: parser accepts a bad scenario file"
        );
    }

    let text = base.to_string();
    for (k, (what, bad_text)) in [
        ("trailing garbage", format!("{text} xyz")),
        ("duplicate scenario key", text.replace(r#""frames":30"#, r#""frames":30,"frames":20"#)),
        ("duplicate vehicle key", text.replace(r#""Spawn":"B1w""#, r#""Spawn":"B1w","Spawn":"C1w""#)),
        ("duplicate key in when", text.replace(r#""reaches":"AC""#, r#""reaches":"AC","reaches":"BD""#)),
    ]
    .into_iter()
    .enumerate()
    {
        assert_ne!(bad_text, text, "{what}: the edit must change the text");
        let e = scenario_parser(&dir, &format!("dup{k}"), &bad_text).expect_err(what);
        assert!(e.contains("duplicate") || e.contains("trailing"), "{what}: {e}");
    }
}

#[test]
fn intervention_file_schema_and_parser_agree() {
    let schema = validator("intervention-file.schema.json");
    let dir = fresh_dir("schemas-interventions");
    let scenario = dir.join("scenario.json");
    let mut base_scenario = scenario_base();
    base_scenario[0].as_object_mut().unwrap().remove("interventions");
    std::fs::write(&scenario, base_scenario.to_string()).unwrap();
    let map = map();
    let scenarios = load(&scenario, FileOptions::default(), &map).unwrap();
    let parser = |name: &str, text: &str| -> Result<(), String> {
        let file = dir.join(format!("{name}.json"));
        std::fs::write(&file, text).unwrap();
        load_interventions(&file, &scenarios).map(|_| ()).map_err(|e| e.to_string())
    };
    let base = interventions_base();
    let good = [base.clone(), base[0].clone()];
    for (k, doc) in good.iter().enumerate() {
        let errors = schema_errors(&schema, doc);
        assert!(errors.is_empty(), "good {k}: schema rejects {doc}: {errors:?}");
        parser(&format!("good{k}"), &doc.to_string()).unwrap_or_else(|e| panic!("good {k}: parser rejects {doc}: {e}"));
    }
    let bad: Vec<(&str, Value)> = vec![
        ("unknown key", edited(&base, |v| v[0]["force"] = json!(1))),
        ("unknown key in when", edited(&base, |v| v[2]["when"]["after"] = json!(1))),
        ("unknown key in a schedule step", edited(&base, |v| v[4]["schedule"][1]["x"] = json!(1))),
        ("a key of another effect", edited(&base, |v| v[1]["seconds"] = json!(1))),
        ("two triggers", edited(&base, |v| v[0]["when"] = json!({"car": "Car_1", "reaches": "AC"}))),
        ("unknown effect", edited(&base, |v| v[0]["do"] = json!("fly"))),
        ("speed as text", edited(&base, |v| v[1]["speed"] = json!("fast"))),
        ("a scenario instead", scenario_base()),
        ("a number", json!(3)),
        // Its counterfactual would be the factual run.
        ("an empty list", json!([])),
    ];
    for (k, (what, doc)) in bad.iter().enumerate() {
        assert!(!schema_errors(&schema, doc).is_empty(), "{what}: schema accepts a bad intervention file");
        assert!(
            parser(&format!("bad{k}"), &doc.to_string()).is_err(),
            "{what}: parser accepts a bad intervention file"
        );
    }
    let text = base.to_string();
    for (k, (what, bad_text)) in [
        ("trailing data", format!("{text}]")),
        ("duplicate key", text.replace(r#""seconds":2"#, r#""seconds":2,"seconds":3"#)),
    ]
    .into_iter()
    .enumerate()
    {
        assert_ne!(bad_text, text, "{what}");
        let e = parser(&format!("dup{k}"), &bad_text).expect_err(what);
        assert!(e.contains("duplicate") || e.contains("trailing") || e.contains("not valid JSON"), "{what}: {e}");
    }
}

#[test]
fn the_spec_a_manifest_records_reads_back_as_a_spec() {
    // A camera without width and height is written with both null; the
    // Python package reads the manifest's spec back through the spec parser
    // (a null refused there made such datasets unreadable).
    let dir = fresh_dir("schemas-manifest-spec");
    let mut spec: Value = serde_json::from_str(&toy_spec("manifest-spec", &[(4, 0.5)], (1, 0, 0), 5)).unwrap();
    spec["cameras"] = serde_json::json!([{"name": "top", "static": {"centre": [0, 0]}}]);
    let out = dir.join("out");
    let path = write_spec(&dir, &spec.to_string());
    gen_ok(&path, &out, &["--quiet"]);
    let manifest = read_json(&out.join("manifest.json"));
    assert!(manifest["spec"]["cameras"][0]["width"].is_null(), "{}", manifest["spec"]);
    spec_parser(&manifest["spec"].to_string()).unwrap_or_else(|e| panic!("{e}: {}", manifest["spec"]));
}
