//! Hand-written scenario files: the original CausalCity format (a JSON list
//! of `{"Name", "Vehicles": [{"Id", "Spawn", "SpawnAtDistance",
//! "DriveQueue", "MergeAtDistances"}]}`) read unchanged, plus optional
//! extensions in the same file (snake_case keys):
//! - per scenario: `world`, `seed`, `frames`, `frame_interval`, `city` (the
//!   spec's city section: driver, lights and offsets, confounders) and
//!   `interventions`;
//! - per vehicle: `desired_speeds` (m/s, one per leg: before the first action,
//!   after each), `time_headway` (s), `runs_red_lights`, `colour` (`#rrggbb`).
//!
//! Cars with the same spawn lane, drive queue and merge distances form
//! leader-follower pairs, the one further along leading (the original's
//! definition). Every error names the file, the scenario, the car and the
//! field; nothing is simulated until the whole file is good.

use crate::camera::CameraPlan;
use crate::geometry::OrientedBox;
use crate::map::signals::{light_at, light_index, Colour, ScheduleStep, Signal, APPROACHES};
use crate::map::{Action, CityMap, Route};
use crate::plan::interventions::{ConfounderName, Effect, Intervention, Trigger};
use crate::plan::{stream_key, Expansion, GivenCar, ScenarioKey, ScenarioPlan};
use crate::spec::{valid_folder_name, CameraSpec, CarRef, CitySpec, DatasetSpec, ImageSize, Split, Splits, WorldKind};
use serde_json::{Map, Value};
use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// A scenario file that cannot be run, and exactly where.
#[derive(Debug, Clone, PartialEq)]
pub struct ScenarioFileError {
    pub file: PathBuf,
    /// The scenario's Name (or its position when it has none).
    pub scenario: Option<String>,
    pub car: Option<String>,
    /// JSON path inside the scenario or vehicle, e.g. `DriveQueue[3]`.
    pub field: String,
    pub message: String,
}

impl fmt::Display for ScenarioFileError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file.display())?;
        if let Some(s) = &self.scenario {
            write!(f, ": scenario {s:?}")?;
        }
        if let Some(c) = &self.car {
            write!(f, ", car {c:?}")?;
        }
        if !self.field.is_empty() {
            write!(f, ", field {}", self.field)?;
        }
        write!(f, ": {}", self.message)
    }
}

/// One scenario of a file, ready to simulate.
pub struct LoadedScenario {
    pub name: String,
    pub expansion: Expansion,
    pub plan: ScenarioPlan,
}

/// What the command line may override.
#[derive(Debug, Clone, Copy, Default)]
pub struct FileOptions {
    pub world: Option<WorldKind>,
}

const SCENARIO_KEYS: [&str; 10] =
    ["Name", "Vehicles", "world", "seed", "frames", "frame_interval", "city", "interventions", "cameras", "comment"];
const VEHICLE_KEYS: [&str; 10] = [
    "comment",
    "Id",
    "Spawn",
    "SpawnAtDistance",
    "DriveQueue",
    "MergeAtDistances",
    "desired_speeds",
    "time_headway",
    "runs_red_lights",
    "colour",
];

/// Reads and checks every scenario of `path`.
pub fn load(path: &Path, options: FileOptions, map: &Arc<CityMap>) -> Result<Vec<LoadedScenario>, ScenarioFileError> {
    let fail = |field: &str, message: String| ScenarioFileError {
        file: path.to_path_buf(),
        scenario: None,
        car: None,
        field: field.into(),
        message,
    };
    let text = std::fs::read_to_string(path).map_err(|e| fail("", format!("cannot read the file: {e}")))?;
    let json: Value = serde_json::from_str(&text).map_err(|e| fail("", format!("not valid JSON: {e}")))?;
    let entries = match json {
        Value::Array(list) => list,
        Value::Object(_) => vec![json],
        _ => return Err(fail("", "expected a list of scenarios (or one scenario object)".into())),
    };
    if entries.is_empty() {
        return Err(fail("", "the list of scenarios is empty".into()));
    }
    let mut loaded: Vec<LoadedScenario> = Vec::new();
    for (index, entry) in entries.iter().enumerate() {
        let scenario = load_one(path, index, entry, options, map)?;
        if loaded.iter().any(|l| l.name == scenario.name) {
            return Err(ScenarioFileError {
                file: path.to_path_buf(),
                scenario: Some(scenario.name.clone()),
                car: None,
                field: "Name".into(),
                message:
                    "another scenario of the file has this name: names must be unique (they name the output folders)"
                        .into(),
            });
        }
        loaded.push(scenario);
    }
    Ok(loaded)
}

/// Builds errors for one scenario.
struct Here<'a> {
    file: &'a Path,
    scenario: String,
}

impl Here<'_> {
    fn err(&self, car: Option<&str>, field: impl Into<String>, message: impl Into<String>) -> ScenarioFileError {
        ScenarioFileError {
            file: self.file.to_path_buf(),
            scenario: Some(self.scenario.clone()),
            car: car.map(String::from),
            field: field.into(),
            message: message.into(),
        }
    }
}

fn unknown_keys(object: &Map<String, Value>, allowed: &[&str]) -> Option<String> {
    object.keys().find(|k| !allowed.contains(&k.as_str())).cloned()
}

fn load_one(
    file: &Path,
    index: usize,
    entry: &Value,
    options: FileOptions,
    map: &Arc<CityMap>,
) -> Result<LoadedScenario, ScenarioFileError> {
    let mut here = Here { file, scenario: format!("#{}", index + 1) };
    let Some(object) = entry.as_object() else {
        return Err(here.err(None, "", "a scenario must be an object with Name and Vehicles"));
    };
    let name = match object.get("Name") {
        Some(Value::String(n)) if valid_folder_name(n) => n.clone(),
        Some(Value::String(n)) => {
            return Err(here.err(
                None,
                "Name",
                format!(
                    "{n:?} is not allowed: use 1 to 64 characters from A-Z a-z 0-9 - _ . (it names the output folder)"
                ),
            ))
        }
        _ => return Err(here.err(None, "Name", "missing: every scenario needs a Name string")),
    };
    here.scenario = name.clone();
    if let Some(key) = unknown_keys(object, &SCENARIO_KEYS) {
        return Err(here.err(None, key, format!("unknown field: a scenario has {}", SCENARIO_KEYS.join(", "))));
    }
    let world = match (options.world, object.get("world")) {
        (Some(w), _) => w,
        (None, None) => WorldKind::City,
        (None, Some(v)) => serde_json::from_value(v.clone())
            .map_err(|_| here.err(None, "world", format!("{v} is not allowed: \"city\" or \"toy\"")))?,
    };
    let seed = match object.get("seed") {
        None => 1,
        Some(v) => v
            .as_u64()
            .ok_or_else(|| here.err(None, "seed", format!("{v} is not allowed: a whole number from 0 to 2^64-1")))?,
    };
    let frames = match object.get("frames") {
        None => 150,
        Some(v) => {
            v.as_u64()
                .filter(|&f| (1..=100_000).contains(&f))
                .ok_or_else(|| here.err(None, "frames", format!("{v} is not allowed: 1 to 100000")))? as u32
        }
    };
    let frame_interval = match object.get("frame_interval") {
        None => None,
        Some(v) => Some(v.as_f64().filter(|&t| t > 0.0 && t <= 10.0).ok_or_else(|| {
            here.err(None, "frame_interval", format!("{v} is not allowed: seconds, above 0 and at most 10"))
        })?),
    };
    let city: Option<CitySpec> = match (object.get("city"), world) {
        (None, _) => None,
        (Some(_), WorldKind::Toy) => {
            return Err(here.err(None, "city", "applies to the city world only: remove it or run with --world city"))
        }
        (Some(v), WorldKind::City) => {
            let city: CitySpec = serde_path_to_error::deserialize(v.clone()).map_err(|e| {
                let path = e.path().to_string();
                let field = if path == "." { "city".to_string() } else { format!("city.{path}") };
                here.err(None, field, e.into_inner().to_string())
            })?;
            city.validate().map_err(|e| here.err(None, e.field, e.message))?;
            Some(city)
        }
    };
    let spec = DatasetSpec {
        name: name.clone(),
        world,
        seed,
        frames,
        frame_interval,
        image: ImageSize::default(),
        groups: Vec::new(),
        splits: Splits { train: 1, val: 0, test: 0 },
        actions_per_car: 0,
        toy_speed_px_per_frame: 2.0,
        leader_gap_px: 30.0,
        car_length_m: 2.2,
        car_width_m: 1.1,
        city,
        cameras: Vec::new(),
    };
    let expansion = Expansion::new(spec, map.clone()).map_err(|e| here.err(None, e.field, e.message))?;

    let vehicles = match object.get("Vehicles") {
        Some(Value::Array(list)) if !list.is_empty() => list,
        Some(Value::Array(_)) => {
            return Err(here.err(None, "Vehicles", "the list is empty: a scenario needs at least one car"))
        }
        _ => return Err(here.err(None, "Vehicles", "missing: a list of cars")),
    };
    if vehicles.len() > 255 {
        return Err(here.err(None, "Vehicles", format!("{} cars: at most 255 (mask ids are 8-bit)", vehicles.len())));
    }
    let travel = expansion.max_travel();
    let mut cars: Vec<GivenCar> = Vec::new();
    for (k, vehicle) in vehicles.iter().enumerate() {
        cars.push(load_vehicle(&here, k, vehicle, map, world, travel, &cars)?);
    }
    // Nobody may start on top of anybody else.
    let boxes: Vec<OrientedBox> = cars
        .iter()
        .map(|c| {
            let (centre, heading) = c.route.pose_at(c.spawn_distance, 0.0);
            OrientedBox { centre, heading, length: expansion.spec.car_length_m, width: expansion.spec.car_width_m }
        })
        .collect();
    for j in 0..cars.len() {
        for i in 0..j {
            if boxes[i].overlaps(&boxes[j]) {
                return Err(here.err(
                    Some(&cars[j].name),
                    "SpawnAtDistance",
                    format!(
                        "starts on top of {}: move one of them (a car is {} m long)",
                        cars[i].name, expansion.spec.car_length_m
                    ),
                ));
            }
        }
    }
    let pairs = infer_pairs(&cars);
    let names: Vec<String> = cars.iter().map(|c| c.name.clone()).collect();
    let key = ScenarioKey {
        group: "scenarios".into(),
        group_index: 0,
        split: Split::Train,
        index: index as u32,
        name: Some(name.clone()),
    };
    let stream = stream_key(seed, &format!("scenario-file/{name}"), Split::Train, 0);
    let mut plan = expansion.plan_given(&key, stream, &cars, &pairs);
    plan.interventions = match object.get("interventions") {
        None => Vec::new(),
        Some(_) if world == WorldKind::Toy => {
            return Err(here.err(
                None,
                "interventions",
                "need the city world (the toy world has no agency): run with --world city",
            ))
        }
        Some(v) => parse_interventions(&here, v, "interventions", &names, map, &expansion)?,
    };
    plan.cameras = match object.get("cameras") {
        None => Vec::new(),
        Some(v) => parse_cameras(&here, v, &names)?,
    };
    Ok(LoadedScenario { name, expansion, plan })
}

/// Extra cameras: as in a spec, with the chased car named by its Id.
fn parse_cameras(here: &Here<'_>, value: &Value, names: &[String]) -> Result<Vec<CameraPlan>, ScenarioFileError> {
    let specs: Vec<CameraSpec> = serde_path_to_error::deserialize(value.clone()).map_err(|e| {
        let path = e.path().to_string();
        let field =
            if path == "." { "cameras".to_string() } else { format!("cameras{}", path.trim_start_matches('.')) };
        here.err(None, field, e.into_inner().to_string())
    })?;
    let mut plans: Vec<CameraPlan> = Vec::new();
    for (i, camera) in specs.iter().enumerate() {
        let field = format!("cameras[{i}]");
        let plan = camera
            .plan(&field, |car| match car {
                CarRef::Name(name) => car_index(names, name),
                CarRef::Id(id) => car_index(names, &id.to_string()),
            })
            .map_err(|e| here.err(None, e.field, e.message))?;
        if plans.iter().any(|p| p.name == plan.name) {
            return Err(here.err(None, format!("{field}.name"), format!("{:?} names another camera too", plan.name)));
        }
        plans.push(plan);
    }
    Ok(plans)
}

fn load_vehicle(
    here: &Here<'_>,
    k: usize,
    vehicle: &Value,
    map: &CityMap,
    world: WorldKind,
    travel: f64,
    earlier: &[GivenCar],
) -> Result<GivenCar, ScenarioFileError> {
    let position = format!("Vehicles[{k}]");
    let Some(object) = vehicle.as_object() else {
        return Err(here.err(None, position, "a vehicle must be an object with Id, Spawn and DriveQueue"));
    };
    let id = match object.get("Id") {
        Some(Value::String(id)) if !id.is_empty() => id.clone(),
        _ => {
            return Err(here.err(
                None,
                format!("{position}.Id"),
                "missing: every vehicle needs an Id string such as \"Car_1\"",
            ))
        }
    };
    let car = Some(id.as_str());
    if earlier.iter().any(|c| c.name == id) {
        return Err(here.err(car, "Id", "duplicate car id: every vehicle of a scenario needs its own"));
    }
    if let Some(key) = unknown_keys(object, &VEHICLE_KEYS) {
        return Err(here.err(car, key, format!("unknown field: a vehicle has {}", VEHICLE_KEYS.join(", "))));
    }
    let spawn_name = object.get("Spawn").and_then(Value::as_str).unwrap_or_default();
    let spawn = map.lane_by_name(spawn_name).ok_or_else(|| {
        here.err(
            car,
            "Spawn",
            format!("{spawn_name:?} is not a spawn point: road A-D, segment 0-2, lane w-z, e.g. \"C0w\""),
        )
    })?;
    let lane_length = map.lanes[spawn].curve.length();
    let spawn_distance = match object.get("SpawnAtDistance") {
        None => 0.0,
        Some(v) => v.as_f64().filter(|d| (0.0..lane_length).contains(d)).ok_or_else(|| {
            here.err(
                car,
                "SpawnAtDistance",
                format!("{v} is not allowed: metres along lane {spawn_name}, from 0 to below {lane_length:.2}"),
            )
        })?,
    };
    let queue = match object.get("DriveQueue") {
        None => Vec::new(),
        Some(Value::Array(list)) => list.clone(),
        Some(v) => return Err(here.err(car, "DriveQueue", format!("{v} is not a list of actions"))),
    };
    let actions: Vec<Action> = queue
        .iter()
        .enumerate()
        .map(|(i, a)| {
            a.as_str().and_then(Action::from_name).ok_or_else(|| {
                here.err(car, format!("DriveQueue[{i}]"), format!("{a} is not an action: use {}", action_names()))
            })
        })
        .collect::<Result<_, _>>()?;
    let merge_distances: Vec<f64> = match object.get("MergeAtDistances") {
        None => vec![0.0; actions.len()],
        Some(Value::Array(list)) => {
            if list.len() != actions.len() {
                return Err(here.err(
                    car,
                    "MergeAtDistances",
                    format!(
                        "{} entries for {} actions: give one per DriveQueue entry (0 for turns)",
                        list.len(),
                        actions.len()
                    ),
                ));
            }
            list.iter()
                .enumerate()
                .map(|(i, d)| {
                    d.as_f64().filter(|d| d.is_finite() && *d >= 0.0).ok_or_else(|| {
                        here.err(
                            car,
                            format!("MergeAtDistances[{i}]"),
                            format!("{d} is not allowed: metres along the lane, 0 or more"),
                        )
                    })
                })
                .collect::<Result<_, _>>()?
        }
        Some(v) => return Err(here.err(car, "MergeAtDistances", format!("{v} is not a list of numbers"))),
    };
    let route =
        Route::plan(map, spawn, spawn_distance, &actions, &merge_distances, spawn_distance + travel).map_err(|e| {
            let field = if e.action.is_merge() && e.reason.contains("merge distance") {
                format!("MergeAtDistances[{}]", e.action_index)
            } else {
                format!("DriveQueue[{}]", e.action_index)
            };
            here.err(car, field, format!("{}: {}", e.action, e.reason))
        })?;

    let city_only = |field: &str| -> Result<(), ScenarioFileError> {
        if world == WorldKind::Toy && object.contains_key(field) {
            return Err(here.err(car, field, "applies to the city world only (toy cars have no agency)"));
        }
        Ok(())
    };
    for field in ["desired_speeds", "time_headway", "runs_red_lights"] {
        city_only(field)?;
    }
    let desired_speeds = match object.get("desired_speeds") {
        None => None,
        Some(Value::Array(list)) if list.len() == actions.len() + 1 => Some(
            list.iter()
                .enumerate()
                .map(|(i, v)| {
                    v.as_f64().filter(|v| *v > 0.0 && *v <= 20.0).ok_or_else(|| {
                        here.err(
                            car,
                            format!("desired_speeds[{i}]"),
                            format!("{v} is not allowed: m/s, above 0 and at most 20"),
                        )
                    })
                })
                .collect::<Result<Vec<f64>, _>>()?,
        ),
        Some(_) => {
            return Err(here.err(
                car,
                "desired_speeds",
                format!("expected {} speeds (m/s): one before the first action and one after each", actions.len() + 1),
            ))
        }
    };
    let time_headway = match object.get("time_headway") {
        None => None,
        Some(v) => Some(v.as_f64().filter(|h| *h > 0.0 && *h <= 10.0).ok_or_else(|| {
            here.err(car, "time_headway", format!("{v} is not allowed: seconds, above 0 and at most 10"))
        })?),
    };
    let runs_red_lights = match object.get("runs_red_lights") {
        None => None,
        Some(v) => {
            Some(v.as_bool().ok_or_else(|| here.err(car, "runs_red_lights", format!("{v} is not true or false")))?)
        }
    };
    let colour =
        match object.get("colour") {
            None => None,
            Some(v) => Some(v.as_str().and_then(crate::render::palette::parse_hex_colour).ok_or_else(|| {
                here.err(car, "colour", format!("{v} is not allowed: \"#rrggbb\", e.g. \"#ff8800\""))
            })?),
        };
    Ok(GivenCar {
        name: id,
        spawn,
        spawn_distance,
        actions,
        merge_distances,
        route: Arc::new(route),
        desired_speeds,
        time_headway,
        runs_red_lights,
        colour,
    })
}

/// Every action's name, for messages.
fn action_names() -> String {
    Action::ALL.iter().map(|a| a.name()).collect::<Vec<_>>().join(", ")
}

/// A light as scenario files name it, e.g. `AC/W/straight`.
pub fn light_name(map: &CityMap, index: usize) -> String {
    let (intersection, approach, signal) = light_at(index);
    format!("{}/{approach}/{}", map.intersections[intersection].name, signal.name())
}

/// The index of the car called `name`, or a message listing the cars.
fn car_index(names: &[String], name: &str) -> Result<usize, String> {
    names
        .iter()
        .position(|n| n == name)
        .ok_or_else(|| format!("{name:?} is not a car of this scenario: one of {}", names.join(", ")))
}

/// Leader-follower pairs: cars sharing spawn lane, actions and merge
/// distances, each leading the next one behind it.
fn infer_pairs(cars: &[GivenCar]) -> Vec<(usize, usize)> {
    let mut pairs = Vec::new();
    let mut seen = vec![false; cars.len()];
    for i in 0..cars.len() {
        if seen[i] {
            continue;
        }
        let mut group: Vec<usize> = (i..cars.len())
            .filter(|&j| {
                cars[j].spawn == cars[i].spawn
                    && cars[j].actions == cars[i].actions
                    && cars[j].merge_distances == cars[i].merge_distances
            })
            .collect();
        for &j in &group {
            seen[j] = true;
        }
        group.sort_by(|&a, &b| cars[b].spawn_distance.total_cmp(&cars[a].spawn_distance));
        pairs.extend(group.windows(2).map(|w| (w[0], w[1])));
    }
    pairs.sort_unstable();
    pairs
}

/// Parses interventions (a list) at JSON path `field`.
fn parse_interventions(
    here: &Here<'_>,
    value: &Value,
    field: &str,
    names: &[String],
    map: &CityMap,
    expansion: &Expansion,
) -> Result<Vec<Intervention>, ScenarioFileError> {
    let Some(list) = value.as_array() else {
        return Err(here.err(None, field, "expected a list of interventions"));
    };
    let mut out = Vec::new();
    for (i, item) in list.iter().enumerate() {
        if let Some(intervention) = parse_intervention(here, item, &format!("{field}[{i}]"), names, map, expansion)? {
            out.push(intervention);
        }
    }
    Ok(out)
}

const INTERVENTION_KEYS: [&str; 17] = [
    "confounder",
    "value",
    "at",
    "at_frame",
    "when",
    "do",
    "car",
    "seconds",
    "speed",
    "light",
    "colour",
    "actions",
    "merge_distances",
    "schedule",
    "offset",
    "comment",
    "label",
];

/// One intervention; `None` for `"do": "none"` (does nothing, leaves no trace).
fn parse_intervention(
    here: &Here<'_>,
    item: &Value,
    field: &str,
    names: &[String],
    map: &CityMap,
    expansion: &Expansion,
) -> Result<Option<Intervention>, ScenarioFileError> {
    let err = |sub: &str, message: String| here.err(None, format!("{field}{sub}"), message);
    let Some(object) = item.as_object() else {
        return Err(err(
            "",
            "an intervention is an object such as {\"at\": 6.0, \"do\": \"stop\", \"car\": \"Car_1\", \"seconds\": 4}"
                .into(),
        ));
    };
    if let Some(key) = unknown_keys(object, &INTERVENTION_KEYS) {
        return Err(err(
            &format!(".{key}"),
            format!("unknown field: an intervention has {}", INTERVENTION_KEYS.join(", ")),
        ));
    }
    let car_named = |sub: &str, v: Option<&Value>| -> Result<usize, ScenarioFileError> {
        car_index(names, v.and_then(Value::as_str).unwrap_or_default()).map_err(|e| err(sub, e))
    };
    let light_named = |sub: &str, v: Option<&Value>| -> Result<usize, ScenarioFileError> {
        let text = v.and_then(Value::as_str).unwrap_or_default();
        let parts: Vec<&str> = text.split('/').collect();
        let found = match parts.as_slice() {
            [intersection, approach, signal] => {
                let k = map.intersections.iter().position(|x| x.name == *intersection);
                let a = approach.chars().next().filter(|c| approach.len() == 1 && APPROACHES.contains(c));
                let s = match *signal {
                    "straight" => Some(Signal::Straight),
                    "left" => Some(Signal::Left),
                    _ => None,
                };
                match (k, a, s) {
                    (Some(k), Some(a), Some(s)) => Some((k, a, s)),
                    _ => None,
                }
            }
            _ => None,
        };
        let (k, a, s) = found.ok_or_else(|| {
            err(sub, format!("{text:?} is not a light: INTERSECTION/APPROACH/SIGNAL, e.g. \"AC/W/straight\" (AC AD BC BD; N E S W; straight left)"))
        })?;
        Ok(light_index(k, a, s))
    };
    let colour_named = |sub: &str, v: Option<&Value>| -> Result<Colour, ScenarioFileError> {
        match v.and_then(Value::as_str) {
            Some("red") => Ok(Colour::Red),
            Some("yellow") => Ok(Colour::Yellow),
            Some("green") => Ok(Colour::Green),
            _ => Err(err(sub, format!("{} is not a colour: red, yellow or green", v.cloned().unwrap_or(Value::Null)))),
        }
    };
    let positive = |sub: &str, v: Option<&Value>, what: &str| -> Result<f64, ScenarioFileError> {
        v.and_then(Value::as_f64)
            .filter(|x| x.is_finite() && *x > 0.0)
            .ok_or_else(|| err(sub, format!("{} is not allowed: {what}, above 0", v.cloned().unwrap_or(Value::Null))))
    };
    let interval = expansion.spec.frame_interval();
    let (trigger, when_text) = match (object.get("at"), object.get("at_frame"), object.get("when")) {
        (Some(at), None, None) => {
            let t = at
                .as_f64()
                .filter(|t| t.is_finite() && *t >= 0.0)
                .ok_or_else(|| err(".at", format!("{at} is not allowed: seconds from the start, 0 or more")))?;
            (Trigger::At(t), format!("at {t} s"))
        }
        (None, Some(frame), None) => {
            let f = frame.as_u64().ok_or_else(|| err(".at_frame", format!("{frame} is not a frame index")))?;
            (Trigger::At(f as f64 * interval), format!("at frame {f}"))
        }
        (None, None, Some(Value::Object(when))) => {
            if when.contains_key("reaches") {
                let car = car_named(".when.car", when.get("car"))?;
                let name = when.get("reaches").and_then(Value::as_str).unwrap_or_default();
                let intersection = map.intersections.iter().position(|x| x.name == name).ok_or_else(|| {
                    err(".when.reaches", format!("{name:?} is not an intersection: AC, AD, BC or BD"))
                })?;
                (Trigger::CarReaches { car, intersection }, format!("when {} reaches {name}", names[car]))
            } else if when.contains_key("turns") {
                let light = light_named(".when.light", when.get("light"))?;
                let colour = colour_named(".when.turns", when.get("turns"))?;
                let text = when.get("light").and_then(Value::as_str).unwrap_or_default();
                (Trigger::LightTurns { light, colour }, format!("when {text} turns {}", colour.name()))
            } else {
                return Err(err(
                    ".when",
                    "expected {\"car\": CAR, \"reaches\": INTERSECTION} or {\"light\": \"AC/W/straight\", \"turns\": COLOUR}".into(),
                ));
            }
        }
        _ => {
            return Err(err(
                "",
                "give exactly one trigger: \"at\" (seconds), \"at_frame\" (frame index) or \"when\" (an event)".into(),
            ))
        }
    };
    let action = object.get("do").and_then(Value::as_str).unwrap_or_default();
    let effect = match action {
        "none" => return Ok(None),
        "stop" => {
            let car = car_named(".car", object.get("car"))?;
            let seconds = positive(".seconds", object.get("seconds"), "seconds to stay stopped")?;
            Effect::Stop { car, seconds }
        }
        "run_red_light" => {
            Effect::RunRedLights { car: car_named(".car", object.get("car"))? }
        }
        "set_desired_speed" => {
            let car = car_named(".car", object.get("car"))?;
            let speed = positive(".speed", object.get("speed"), "m/s")?;
            Effect::SetDesiredSpeed { car, speed }
        }
        "remove" => {
            Effect::Remove { car: car_named(".car", object.get("car"))? }
        }
        "set_light" => {
            let light = light_named(".light", object.get("light"))?;
            let colour = colour_named(".colour", object.get("colour"))?;
            let seconds = positive(".seconds", object.get("seconds"), "seconds the colour is held")?;
            Effect::SetLight { light, colour, seconds }
        }
        "replace_actions" => {
            let car = car_named(".car", object.get("car"))?;
            let list = object
                .get("actions")
                .and_then(Value::as_array)
                .ok_or_else(|| err(".actions", "expected the new drive queue, e.g. [\"left\", \"straight\"]".into()))?;
            let actions: Vec<Action> = list
                .iter()
                .enumerate()
                .map(|(k, a)| {
                    a.as_str().and_then(Action::from_name).ok_or_else(|| {
                        err(&format!(".actions[{k}]"), format!("{a} is not an action: {}", action_names()))
                    })
                })
                .collect::<Result<_, _>>()?;
            let merge_distances: Vec<f64> = match object.get("merge_distances") {
                None => vec![0.0; actions.len()],
                Some(Value::Array(d)) if d.len() == actions.len() => d
                    .iter()
                    .enumerate()
                    .map(|(k, v)| {
                        v.as_f64().filter(|x| x.is_finite() && *x >= 0.0).ok_or_else(|| {
                            err(&format!(".merge_distances[{k}]"), format!("{v} is not allowed: metres along the lane, 0 or more"))
                        })
                    })
                    .collect::<Result<_, _>>()?,
                Some(_) => return Err(err(".merge_distances", format!("expected {} numbers, one per action", actions.len()))),
            };
            Effect::ReplaceActions { car, actions, merge_distances }
        }
        "set_light_plan" => {
            let light = light_named(".light", object.get("light"))?;
            let steps = object
                .get("schedule")
                .and_then(Value::as_array)
                .filter(|l| !l.is_empty())
                .ok_or_else(|| err(".schedule", "expected [{\"colour\": \"green\", \"duration\": 10}, ...]".into()))?;
            let schedule: Vec<ScheduleStep> = steps
                .iter()
                .enumerate()
                .map(|(k, step)| {
                    let colour = colour_named(&format!(".schedule[{k}].colour"), step.get("colour"))?;
                    let duration = positive(&format!(".schedule[{k}].duration"), step.get("duration"), "seconds")?;
                    Ok(ScheduleStep { colour, duration })
                })
                .collect::<Result<_, ScenarioFileError>>()?;
            let offset = match object.get("offset") {
                None => 0.0,
                Some(v) => {
                    v.as_f64().filter(|x| x.is_finite()).ok_or_else(|| err(".offset", format!("{v} is not a number of seconds")))?
                }
            };
            Effect::SetLightPlan { light, offset, schedule }
        }
        "set_confounder" => {
            let name = object.get("confounder").and_then(Value::as_str).unwrap_or_default();
            let (confounder, _) = ConfounderName::ALL.into_iter().find(|(_, n)| *n == name).ok_or_else(|| {
                err(".confounder", format!("{name:?} is not a confounder: rain, fog, snow, wetness or hour"))
            })?;
            let limit = if confounder == ConfounderName::Hour { 24.0 } else { 1.0 };
            let value = object.get("value").and_then(Value::as_f64).filter(|v| (0.0..=limit).contains(v)).ok_or_else(|| {
                err(".value", format!("{} is not allowed: 0 to {limit}", object.get("value").cloned().unwrap_or(Value::Null)))
            })?;
            Effect::SetConfounder { confounder, value }
        }
        other => {
            return Err(err(
                ".do",
                format!(
                    "{other:?} is not an intervention: stop, run_red_light, set_desired_speed, remove, replace_actions, set_light, set_light_plan, set_confounder or none"
                ),
            ))
        }
    };
    let label = match object.get("label").and_then(Value::as_str) {
        Some(label) => label.to_string(),
        None => format!("{} ({when_text})", effect.describe(|c| names[c].clone(), |l| light_name(map, l))),
    };
    Ok(Some(Intervention { trigger, effect, label }))
}

/// Reads an intervention file (a list of interventions, as in a scenario's
/// `interventions`) once, and checks it against each of `scenarios`: one
/// list of interventions per scenario.
pub fn load_interventions(
    path: &Path,
    scenarios: &[LoadedScenario],
    map: &CityMap,
) -> Result<Vec<Vec<Intervention>>, ScenarioFileError> {
    let file_error = |message: String| ScenarioFileError {
        file: path.to_path_buf(),
        scenario: None,
        car: None,
        field: String::new(),
        message,
    };
    let text = std::fs::read_to_string(path).map_err(|e| file_error(format!("cannot read the file: {e}")))?;
    let json: Value = serde_json::from_str(&text).map_err(|e| file_error(format!("not valid JSON: {e}")))?;
    let list = if json.is_array() { json } else { Value::Array(vec![json]) };
    scenarios
        .iter()
        .map(|scenario| {
            let here = Here { file: path, scenario: scenario.name.clone() };
            if scenario.plan.world.kind() != WorldKind::City {
                return Err(here.err(None, "", "interventions need the city world (the toy world has no agency)"));
            }
            let names: Vec<String> = scenario.plan.cars.iter().map(|c| c.name.clone()).collect();
            parse_interventions(&here, &list, "interventions", &names, map, &scenario.expansion)
        })
        .collect()
}
