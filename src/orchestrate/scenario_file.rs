//! Hand-written scenario files: the original CausalCity format (a JSON list
//! of `{"Name", "Vehicles": [{"Id", "Spawn", "SpawnAtDistance",
//! "DriveQueue", "MergeAtDistances"}]}`) read unchanged, plus optional
//! extensions in the same file (snake_case keys):
//! - per scenario: `world`, `seed`, `frames`, `frame_interval`, `city` (the
//!   spec's city section: driver, lights and offsets, confounders),
//!   `interventions` and `cameras`;
//! - per vehicle: `desired_speeds` (m/s, one per leg: before the first action,
//!   after each), `time_headway` (s), `runs_red_lights`, `colour` (`#rrggbb`).
//!
//! Reading is two passes. The file is parsed strictly ([`crate::json`]: no
//! duplicate keys, no trailing data, no unknown keys at any depth) into raw
//! serde types that mirror the JSON; then one resolving pass turns names into
//! indices (cars, lanes, lights, intersections), checks ranges and plans every
//! route on the map. Cars with the same spawn lane, drive queue and merge
//! distances form leader-follower pairs, the one further along leading (the
//! original's definition). Every error names the file, the scenario, the car
//! and the field; nothing is simulated until the whole file is good.

use crate::camera::CameraPlan;
use crate::geometry::OrientedBox;
use crate::json::{self, JsonError, Shown};
use crate::map::signals::{light_at, light_index, light_label, Colour, ScheduleStep, Signal, APPROACHES};
use crate::map::{Action, CityMap, LanePolicy, Route};
use crate::plan::confounders::ConfounderName;
use crate::plan::interventions::{Effect, Intervention, Trigger};
use crate::plan::{stream_key, Expansion, GivenCar, PlannedTown, ScenarioKey, ScenarioPlan};
use crate::spec::{
    valid_folder_name, BirdsEyeView, CameraSpec, CarRef, CitySpec, DatasetSpec, MapSpec, Split, WorldKind,
};
use serde::Deserialize;
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
    /// What reading adapted (quirks of the original's files, spawns moved),
    /// one sentence each naming the car and field.
    pub warnings: Vec<String>,
}

/// What the command line may override.
#[derive(Debug, Clone, Copy, Default)]
pub struct FileOptions {
    pub world: Option<WorldKind>,
    /// Reject every action, merge distance and spawn that would need
    /// adapting, instead of adapting it with a warning.
    pub strict: bool,
}

/// Step by which a car that would start on top of another moves forward, metres.
const SPAWN_STEP: f64 = 0.1;

/// Seed of a scenario file that gives none.
const DEFAULT_SEED: u64 = 1;

// ---------------------------------------------------------------------------
// Raw types: the JSON as written, checked for shape only.

/// One scenario as written.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawScenario {
    #[serde(rename = "Name")]
    name: String,
    #[serde(rename = "Vehicles")]
    vehicles: Vec<RawVehicle>,
    world: Option<WorldKind>,
    seed: Option<u64>,
    frames: Option<u32>,
    frame_interval: Option<f64>,
    city: Option<CitySpec>,
    /// Read by [`raw_interventions`], which keeps the JSON paths of the
    /// intervention's fields that sit beside their `do` tag.
    interventions: Option<Vec<Value>>,
    cameras: Option<Vec<CameraSpec>>,
    /// How the bird's-eye frames are drawn (`flat` or `pinhole`).
    birds_eye: Option<BirdsEyeView>,
    /// The scenario's own map (a spec's `map` section, drawing nothing):
    /// the default city when absent.
    map: Option<MapSpec>,
    #[allow(dead_code)]
    comment: Option<String>,
}

/// One vehicle as written.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawVehicle {
    #[serde(rename = "Id")]
    id: String,
    #[serde(rename = "Spawn")]
    spawn: String,
    #[serde(rename = "SpawnAtDistance", default)]
    spawn_at_distance: f64,
    #[serde(rename = "DriveQueue", default)]
    drive_queue: Vec<String>,
    /// Numbers, or (the original generator's quirk) action names, read in
    /// the resolving pass.
    #[serde(rename = "MergeAtDistances")]
    merge_at_distances: Option<Vec<Value>>,
    desired_speeds: Option<Vec<f64>>,
    time_headway: Option<f64>,
    runs_red_lights: Option<bool>,
    colour: Option<String>,
    #[allow(dead_code)]
    comment: Option<String>,
}

/// One intervention as written: a trigger, an effect tagged by `do`, and an
/// optional label, all keys of one object.
#[derive(Debug)]
pub struct RawIntervention {
    trigger: RawTrigger,
    effect: RawEffect,
    label: Option<String>,
}

/// When an intervention fires: exactly one of these keys.
#[derive(Debug, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
enum RawTrigger {
    /// Seconds from the start.
    At(f64),
    AtFrame(u64),
    When(RawWhen),
}

/// An event: `{"car", "reaches"}` or `{"light", "turns"}`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawWhen {
    car: Option<String>,
    reaches: Option<String>,
    light: Option<String>,
    turns: Option<Colour>,
}

/// What an intervention does, tagged by its `do` key.
#[derive(Debug, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
enum RawEffect {
    Stop { car: String, seconds: f64 },
    RunRedLight { car: String },
    SetDesiredSpeed { car: String, speed: f64 },
    Remove { car: String },
    ReplaceActions { car: String, actions: Vec<String>, merge_distances: Option<Vec<f64>> },
    SetLight { light: String, colour: Colour, seconds: f64 },
    SetLightPlan { light: String, schedule: Vec<ScheduleStep>, offset: Option<f64> },
    SetConfounder { confounder: String, value: f64 },
    None {},
}

/// Keys of an intervention that are not its effect's.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCommon {
    label: Option<String>,
    #[allow(dead_code)]
    comment: Option<String>,
}

const TRIGGER_KEYS: [&str; 3] = ["at", "at_frame", "when"];
const COMMON_KEYS: [&str; 2] = ["label", "comment"];

/// Reads one intervention object (at JSON path `path`).
fn raw_intervention(value: Value, path: &str) -> Result<RawIntervention, JsonError> {
    let fail = |sub: &str, message: &str| JsonError { path: sub.into(), message: message.into() }.under(path);
    let Value::Object(object) = value else {
        return Err(fail(
            "",
            "an intervention is an object such as {\"at\": 6.0, \"do\": \"stop\", \"car\": \"Car_1\", \"seconds\": 4}",
        ));
    };
    let (mut trigger, mut common, mut effect) = (Map::new(), Map::new(), Map::new());
    for (key, v) in object {
        if TRIGGER_KEYS.contains(&key.as_str()) {
            trigger.insert(key, v);
        } else if COMMON_KEYS.contains(&key.as_str()) {
            common.insert(key, v);
        } else {
            effect.insert(key, v);
        }
    }
    if trigger.len() != 1 {
        return Err(fail(
            "",
            "give exactly one trigger: \"at\" (seconds), \"at_frame\" (frame index) or \"when\" (an event)",
        ));
    }
    let trigger: RawTrigger = json::from_value(Value::Object(trigger)).map_err(|e| e.under(path))?;
    let RawCommon { label, .. } = json::from_value(Value::Object(common)).map_err(|e| e.under(path))?;
    const DO: &str = "stop, run_red_light, set_desired_speed, remove, replace_actions, set_light, set_light_plan, set_confounder or none";
    let tag = match effect.remove("do") {
        Some(Value::String(tag)) => tag,
        Some(other) => return Err(fail("do", &format!("{other} is not an intervention: {DO}"))),
        None => return Err(fail("do", &format!("missing: what the intervention does, one of {DO}"))),
    };
    // `{"do": TAG, fields...}` read as serde's externally tagged `{TAG: {fields}}`.
    let tagged = Value::Object(Map::from_iter([(tag.clone(), Value::Object(effect))]));
    let effect: RawEffect = json::from_value_untagged_path(tagged).map_err(|e| {
        if e.path.is_empty() && e.message.starts_with("unknown variant") {
            JsonError { path: "do".into(), message: format!("{tag:?} is not an intervention: {DO}") }.under(path)
        } else {
            e.under(path)
        }
    })?;
    Ok(RawIntervention { trigger, effect, label })
}

/// Reads a list of interventions (at JSON path `path`).
fn raw_interventions(list: Vec<Value>, path: &str) -> Result<Vec<RawIntervention>, JsonError> {
    list.into_iter().enumerate().map(|(i, item)| raw_intervention(item, &format!("{path}[{i}]"))).collect()
}

// ---------------------------------------------------------------------------
// Loading: parse everything, then resolve.

/// An error about a whole file (no scenario or car), at JSON path `field`.
fn file_error(path: &Path, field: String, message: String) -> ScenarioFileError {
    ScenarioFileError { file: path.to_path_buf(), scenario: None, car: None, field, message }
}

/// A file that cannot be read.
fn unreadable(path: &Path, e: std::io::Error) -> ScenarioFileError {
    file_error(path, String::new(), format!("cannot read the file: {e}"))
}

/// Reads and checks every scenario of `path`.
pub fn load(path: &Path, options: FileOptions, map: &Arc<CityMap>) -> Result<Vec<LoadedScenario>, ScenarioFileError> {
    let text = std::fs::read_to_string(path).map_err(|e| unreadable(path, e))?;
    load_text(path, &text, options, map)
}

/// Reads and checks every scenario of `text`, a file's contents; errors name
/// `path` (a file, or a label such as `<dict>` for text made in memory).
pub fn load_text(
    path: &Path,
    text: &str,
    options: FileOptions,
    map: &Arc<CityMap>,
) -> Result<Vec<LoadedScenario>, ScenarioFileError> {
    let fail = |field: &str, message: String| file_error(path, field.into(), message);
    // A dataset spec given where a scenario file belongs: say so, rather
    // than list the scenario fields it lacks.
    if let Ok(Value::Object(top)) = serde_json::from_str::<Value>(text) {
        if top.contains_key("groups") && top.contains_key("splits") {
            return Err(fail(
                "",
                format!(
                    "this is a dataset spec (it has groups and splits), not a scenario file: generate it with \
                     `causalcity gen --spec {}`; run and counterfactual take scenario files \
                     (see configs/examples/ and docs/handwritten-scenarios.md)",
                    path.display()
                ),
            ));
        }
    }
    let json = json::parse(text).map_err(|e| parse_error(path, text, e))?;
    let entries = match json {
        Value::Array(list) => list,
        Value::Object(_) => vec![json],
        _ => return Err(fail("", "expected a list of scenarios (or one scenario object)".into())),
    };
    if entries.is_empty() {
        return Err(fail("", "the list of scenarios is empty".into()));
    }
    let mut loaded: Vec<LoadedScenario> = Vec::new();
    for (index, entry) in entries.into_iter().enumerate() {
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

/// A file that is not strict JSON (say, a duplicate key): the error names
/// the scenario and car as well as it can, from a lenient reading.
fn parse_error(file: &Path, text: &str, e: JsonError) -> ScenarioFileError {
    let lenient: Option<Value> = serde_json::from_str(text).ok();
    let (index, entry, rest) = match (&lenient, e.path.strip_prefix('[')) {
        (Some(Value::Array(list)), Some(rest)) => {
            let (k, rest) = rest.split_once(']').unwrap_or(("", rest));
            let k = k.parse::<usize>().ok();
            (k, k.and_then(|k| list.get(k)), rest.strip_prefix('.').unwrap_or(rest).to_string())
        }
        (Some(one @ Value::Object(_)), None) => (Some(0), Some(one), e.path.clone()),
        _ => (None, None, e.path.clone()),
    };
    match (index, entry) {
        (Some(index), Some(entry)) => {
            let label = match entry.get("Name").and_then(Value::as_str) {
                Some(n) if valid_folder_name(n) => n.to_string(),
                _ => format!("#{}", index + 1),
            };
            Here { file, scenario: label }.parse_err(entry, JsonError { path: rest, message: e.message })
        }
        _ => {
            ScenarioFileError { file: file.to_path_buf(), scenario: None, car: None, field: e.path, message: e.message }
        }
    }
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

    /// A parse error inside the scenario `entry`: one under `Vehicles[k]`
    /// names the car by its Id when it has one, and the field inside it.
    fn parse_err(&self, entry: &Value, e: JsonError) -> ScenarioFileError {
        if let Some(rest) = e.path.strip_prefix("Vehicles[") {
            if let Some((k, field)) = rest.split_once(']') {
                let id = k.parse::<usize>().ok().and_then(|k| entry["Vehicles"][k]["Id"].as_str());
                if let Some(id) = id.filter(|id| !id.is_empty()) {
                    let field = field.strip_prefix('.').unwrap_or(field);
                    let field = if field.is_empty() { format!("Vehicles[{k}]") } else { field.to_string() };
                    return self.err(Some(id), field, e.message);
                }
            }
        }
        self.err(None, e.path, e.message)
    }
}

fn load_one(
    file: &Path,
    index: usize,
    entry: Value,
    options: FileOptions,
    map: &Arc<CityMap>,
) -> Result<LoadedScenario, ScenarioFileError> {
    // Errors name the scenario by its Name as soon as it has a usable one.
    let label = match entry.get("Name").and_then(Value::as_str) {
        Some(n) if valid_folder_name(n) => n.to_string(),
        _ => format!("#{}", index + 1),
    };
    let here = Here { file, scenario: label };
    if !entry.is_object() {
        return Err(here.err(None, "", "a scenario must be an object with Name and Vehicles"));
    }
    let raw: RawScenario = json::from_value(entry.clone()).map_err(|e| here.parse_err(&entry, e))?;
    let interventions = match raw.interventions.clone() {
        None => None,
        Some(list) => Some(raw_interventions(list, "interventions").map_err(|e| here.parse_err(&entry, e))?),
    };
    resolve(&here, index, raw, interventions, options, map)
}

/// The resolving pass over one parsed scenario.
fn resolve(
    here: &Here<'_>,
    index: usize,
    raw: RawScenario,
    interventions: Option<Vec<RawIntervention>>,
    options: FileOptions,
    map: &Arc<CityMap>,
) -> Result<LoadedScenario, ScenarioFileError> {
    let name = raw.name.clone();
    if !valid_folder_name(&name) {
        return Err(here.err(
            None,
            "Name",
            format!(
                "{name:?} is not allowed: use 1 to 64 characters from A-Z a-z 0-9 - _ . (it names the output folder)"
            ),
        ));
    }
    let world = options.world.or(raw.world).unwrap_or(WorldKind::City);
    let seed = raw.seed.unwrap_or(DEFAULT_SEED);
    let frames = raw.frames.unwrap_or_else(DatasetSpec::default_frames);
    if !(1..=100_000).contains(&frames) {
        return Err(here.err(None, "frames", format!("{frames} is not allowed: 1 to 100000")));
    }
    if let Some(t) = raw.frame_interval {
        if !(t > 0.0 && t <= 10.0) {
            return Err(here.err(
                None,
                "frame_interval",
                format!("{} is not allowed: seconds, above 0 and at most 10", Shown(t)),
            ));
        }
    }
    let city = match (raw.city, world) {
        (None, _) => None,
        (Some(_), WorldKind::Toy) => {
            return Err(here.err(None, "city", "applies to the city world only: remove it or run with --world city"))
        }
        (Some(city), WorldKind::City) => {
            city.validate().map_err(|e| here.err(None, e.field, e.message))?;
            Some(city)
        }
    };
    let mut spec = DatasetSpec::for_given_cars(name.clone(), world, seed, frames, raw.frame_interval, city);
    spec.birds_eye = raw.birds_eye.unwrap_or_default();
    // A map of its own: checked as a spec's, one town, its lanes named as
    // `causalcity map` lists them.
    let own_map;
    let raw_map = raw.map.clone();
    let map = match &raw.map {
        None => map,
        Some(section) => {
            section.validate().map_err(|e| here.err(None, e.field, e.message))?;
            if section.towns().len() > 1 {
                return Err(here.err(
                    None,
                    "map.grid",
                    "a scenario happens on one town: give rows and columns as numbers, not distributions",
                ));
            }
            spec.map = section.clone();
            own_map = Arc::new(CityMap::new(section.layout()));
            &own_map
        }
    };
    let expansion = Expansion::new(spec, map.clone()).map_err(|e| here.err(None, e.field, e.message))?;

    if raw.vehicles.is_empty() {
        return Err(here.err(None, "Vehicles", "the list is empty: a scenario needs at least one car"));
    }
    if raw.vehicles.len() > 255 {
        return Err(here.err(
            None,
            "Vehicles",
            format!("{} cars: at most 255 (mask ids are 8-bit)", raw.vehicles.len()),
        ));
    }
    let travel = expansion.max_travel();
    let mut cars: Vec<GivenCar> = Vec::new();
    let mut warnings = Vec::new();
    for (k, vehicle) in raw.vehicles.iter().enumerate() {
        let car = resolve_vehicle(here, k, vehicle, map, world, travel, &cars, options.strict, &mut warnings)?;
        cars.push(car);
    }
    // The leader-follower pairs are the file's as written.
    let pairs = infer_pairs(&cars);
    // Nobody may start on top of anybody else: strictly an error, else the
    // later car moves forward along its lane to the first free place.
    let footprint = |c: &GivenCar, s: f64| {
        let lane = &map.lanes[c.spawn].curve;
        let (centre, heading) = (lane.lane_center_at(s), lane.heading_at(s));
        OrientedBox { centre, heading, length: expansion.spec.car_length_m, width: expansion.spec.car_width_m }
    };
    let mut boxes: Vec<OrientedBox> = Vec::new();
    for j in 0..cars.len() {
        let given = cars[j].spawn_distance;
        let lane_end = map.lanes[cars[j].spawn].curve.length() - expansion.spec.car_length_m / 2.0;
        let mut s = given;
        let blocker = loop {
            let here_box = footprint(&cars[j], s);
            match boxes.iter().position(|b| b.overlaps(&here_box)) {
                None => break None,
                Some(i) if options.strict || s + SPAWN_STEP > lane_end => break Some(i),
                Some(_) => s += SPAWN_STEP,
            }
        };
        if let Some(i) = blocker {
            let why = if options.strict { "move one of them" } else { "and no free place is left on its lane" };
            return Err(here.err(
                Some(&cars[j].name),
                "SpawnAtDistance",
                format!("starts on top of {}: {why} (a car is {} m long)", cars[i].name, expansion.spec.car_length_m),
            ));
        }
        if s != given {
            let s = (s * 10.0).round() / 10.0;
            warnings.push(format!(
                "car {:?}, field SpawnAtDistance: {given} m would start on top of another car: starting at {s} m",
                cars[j].name
            ));
            let car = &mut cars[j];
            car.spawn_distance = s;
            let route =
                Route::plan(map, car.spawn, s, &car.actions, &car.merge_distances, s + travel, &LanePolicy::Adapt)
                    .map_err(|e| here.err(Some(&car.name), "DriveQueue", e.to_string()))?;
            car.route = Arc::new(route);
        }
        boxes.push(footprint(&cars[j], cars[j].spawn_distance));
    }
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
    // A map of its own is recorded, so that the scenario can be rebuilt.
    if let Some(section) = &raw_map {
        plan.town = Some(PlannedTown { index: 0, name: section.town_name(), map: section.clone() });
    }
    plan.interventions = match interventions {
        None => Vec::new(),
        Some(_) if world == WorldKind::Toy => {
            return Err(here.err(
                None,
                "interventions",
                "need the city world (the toy world has no agency): run with --world city",
            ))
        }
        Some(list) => resolve_interventions(here, &list, "interventions", &names, map, &expansion)?,
    };
    plan.cameras = match &raw.cameras {
        None => Vec::new(),
        Some(specs) => resolve_cameras(here, specs, &names)?,
    };
    Ok(LoadedScenario { name, expansion, plan, warnings })
}

/// Extra cameras: as in a spec, with the chased car named by its Id.
fn resolve_cameras(
    here: &Here<'_>,
    specs: &[CameraSpec],
    names: &[String],
) -> Result<Vec<CameraPlan>, ScenarioFileError> {
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

/// Actions by name; `field(i)` is the JSON path of entry `i`.
fn resolve_actions(names: &[String], field: impl Fn(usize) -> String) -> Result<Vec<Action>, (String, String)> {
    names
        .iter()
        .enumerate()
        .map(|(i, a)| {
            Action::from_name(a).ok_or_else(|| (field(i), format!("{a:?} is not an action: use {}", action_names())))
        })
        .collect()
}

/// One vehicle resolved; under `strict` nothing is adapted, otherwise
/// each quirk read leniently adds a sentence to `warnings`.
#[allow(clippy::too_many_arguments)]
fn resolve_vehicle(
    here: &Here<'_>,
    k: usize,
    vehicle: &RawVehicle,
    map: &CityMap,
    world: WorldKind,
    travel: f64,
    earlier: &[GivenCar],
    strict: bool,
    warnings: &mut Vec<String>,
) -> Result<GivenCar, ScenarioFileError> {
    let id = vehicle.id.clone();
    if id.is_empty() {
        return Err(here.err(
            None,
            format!("Vehicles[{k}].Id"),
            "is empty: every vehicle needs an Id such as \"Car_1\"",
        ));
    }
    let car = Some(id.as_str());
    if earlier.iter().any(|c| c.name == id) {
        return Err(here.err(car, "Id", "duplicate car id: every vehicle of a scenario needs its own"));
    }
    let spawn_name = vehicle.spawn.as_str();
    let spawn = map.lane_by_name(spawn_name).ok_or_else(|| {
        let layout = &map.layout;
        let mut roads: Vec<char> =
            layout.east_west_roads.iter().chain(&layout.north_south_roads).map(|(name, _)| *name).collect();
        roads.sort_unstable();
        let segments = layout.east_west_roads.len().max(layout.north_south_roads.len());
        let (first, last) = (roads.first().copied().unwrap_or('A'), roads.last().copied().unwrap_or('A'));
        here.err(
            car,
            "Spawn",
            format!(
                "{spawn_name:?} is not a spawn point: road {first}-{last}, segment 0-{segments}, lane w-z, e.g. \"{}0w\" (causalcity map lists them)",
                layout.north_south_roads.first().map_or('C', |r| r.0)
            ),
        )
    })?;
    let lane_length = map.lanes[spawn].curve.length();
    let spawn_distance = vehicle.spawn_at_distance;
    if !(0.0..lane_length).contains(&spawn_distance) {
        return Err(here.err(
            car,
            "SpawnAtDistance",
            format!(
                "{} is not allowed: metres along lane {spawn_name}, from 0 to below {lane_length:.2}",
                Shown(spawn_distance)
            ),
        ));
    }
    let actions = resolve_actions(&vehicle.drive_queue, |i| format!("DriveQueue[{i}]"))
        .map_err(|(field, message)| here.err(car, field, message))?;
    let merge_distances: Vec<f64> = match &vehicle.merge_at_distances {
        None => vec![0.0; actions.len()],
        Some(list) => {
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
            let mut distances = Vec::with_capacity(list.len());
            let mut names_read = Vec::new();
            for (i, entry) in list.iter().enumerate() {
                let field = format!("MergeAtDistances[{i}]");
                match entry {
                    Value::Number(n) => match n.as_f64().filter(|d| d.is_finite() && *d >= 0.0) {
                        Some(d) => distances.push(d),
                        None => {
                            return Err(here.err(
                                car,
                                field,
                                format!("{n} is not allowed: metres along the lane, 0 or more"),
                            ))
                        }
                    },
                    // The original generator writes action names here.
                    Value::String(_) if !strict => {
                        names_read.push(i);
                        distances.push(0.0);
                    }
                    other => {
                        return Err(here.err(
                            car,
                            field,
                            format!("{other} is not allowed: metres along the lane, 0 or more"),
                        ))
                    }
                }
            }
            if !names_read.is_empty() {
                let texts: Vec<String> = names_read.iter().map(|&i| list[i].to_string()).collect();
                warnings.push(format!(
                    "car {id:?}, field MergeAtDistances{names_read:?}: {} {} not distances (the original generator writes merge names there): read as no distance given (0)",
                    texts.join(", "),
                    if texts.len() == 1 { "is" } else { "are" }
                ));
            }
            distances
        }
    };
    let policy = if strict { LanePolicy::Strict } else { LanePolicy::Adapt };
    let route = Route::plan(map, spawn, spawn_distance, &actions, &merge_distances, spawn_distance + travel, &policy)
        .map_err(|e| {
        let field = if e.action.is_merge() && e.reason.contains("merge distance") {
            format!("MergeAtDistances[{}]", e.action_index)
        } else {
            format!("DriveQueue[{}]", e.action_index)
        };
        here.err(car, field, format!("{}: {}", e.action, e.reason))
    })?;

    if world == WorldKind::Toy {
        let given = [
            ("desired_speeds", vehicle.desired_speeds.is_some()),
            ("time_headway", vehicle.time_headway.is_some()),
            ("runs_red_lights", vehicle.runs_red_lights.is_some()),
        ];
        if let Some((field, _)) = given.iter().find(|(_, given)| *given) {
            return Err(here.err(car, *field, "applies to the city world only (toy cars have no agency)"));
        }
    }
    let desired_speeds = match &vehicle.desired_speeds {
        None => None,
        Some(list) if list.len() == actions.len() + 1 => {
            if let Some((i, v)) = list.iter().enumerate().find(|(_, v)| !(**v > 0.0 && **v <= 20.0)) {
                return Err(here.err(
                    car,
                    format!("desired_speeds[{i}]"),
                    format!("{} is not allowed: m/s, above 0 and at most 20", Shown(*v)),
                ));
            }
            Some(list.clone())
        }
        Some(_) => {
            return Err(here.err(
                car,
                "desired_speeds",
                format!("expected {} speeds (m/s): one before the first action and one after each", actions.len() + 1),
            ))
        }
    };
    if let Some(h) = vehicle.time_headway {
        if !(h > 0.0 && h <= 10.0) {
            return Err(here.err(
                car,
                "time_headway",
                format!("{} is not allowed: seconds, above 0 and at most 10", Shown(h)),
            ));
        }
    }
    let colour = match &vehicle.colour {
        None => None,
        Some(text) => Some(crate::render::palette::parse_hex_colour(text).ok_or_else(|| {
            here.err(car, "colour", format!("{text:?} is not allowed: \"#rrggbb\", e.g. \"#ff8800\""))
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
        time_headway: vehicle.time_headway,
        runs_red_lights: vehicle.runs_red_lights,
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
    light_label(&map.intersections[intersection].name, approach, signal.name())
}

/// The index of the light called `text` (`AC/W/straight`), or a message.
fn light_by_name(map: &CityMap, text: &str) -> Result<usize, String> {
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
                (Some(k), Some(a), Some(s)) => Some(light_index(k, a, s)),
                _ => None,
            }
        }
        _ => None,
    };
    found.ok_or_else(|| {
        format!("{text:?} is not a light: INTERSECTION/APPROACH/SIGNAL, e.g. \"AC/W/straight\" (AC AD BC BD; N E S W; straight left)")
    })
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

/// Resolves parsed interventions (a list at JSON path `field`).
fn resolve_interventions(
    here: &Here<'_>,
    list: &[RawIntervention],
    field: &str,
    names: &[String],
    map: &CityMap,
    expansion: &Expansion,
) -> Result<Vec<Intervention>, ScenarioFileError> {
    let mut out = Vec::new();
    for (i, raw) in list.iter().enumerate() {
        let at = format!("{field}[{i}]");
        let resolved = resolve_intervention(raw, names, map, expansion).map_err(|(sub, message)| {
            here.err(None, if sub.is_empty() { at.clone() } else { format!("{at}.{sub}") }, message)
        })?;
        out.extend(resolved);
    }
    Ok(out)
}

/// One intervention; `None` for `"do": "none"` (does nothing, leaves no
/// trace). Errors are (field inside the intervention, message).
fn resolve_intervention(
    raw: &RawIntervention,
    names: &[String],
    map: &CityMap,
    expansion: &Expansion,
) -> Result<Option<Intervention>, (String, String)> {
    let car_named = |field: &str, name: &str| car_index(names, name).map_err(|e| (field.to_string(), e));
    let light_named = |field: &str, name: &str| light_by_name(map, name).map_err(|e| (field.to_string(), e));
    let positive = |field: &str, v: f64, what: &str| {
        if v.is_finite() && v > 0.0 {
            Ok(v)
        } else {
            Err((field.to_string(), format!("{} is not allowed: {what}, above 0", Shown(v))))
        }
    };
    let (trigger, when_text) = match &raw.trigger {
        RawTrigger::At(t) => {
            if !(t.is_finite() && *t >= 0.0) {
                return Err(("at".into(), format!("{} is not allowed: seconds from the start, 0 or more", Shown(*t))));
            }
            (Trigger::At(*t), format!("at {t} s"))
        }
        RawTrigger::AtFrame(f) => (Trigger::At(*f as f64 * expansion.spec.frame_interval()), format!("at frame {f}")),
        RawTrigger::When(RawWhen { car: Some(car), reaches: Some(name), light: None, turns: None }) => {
            let car = car_named("when.car", car)?;
            let intersection = map.intersections.iter().position(|x| x.name == *name).ok_or_else(|| {
                ("when.reaches".to_string(), format!("{name:?} is not an intersection: AC, AD, BC or BD"))
            })?;
            (Trigger::CarReaches { car, intersection }, format!("when {} reaches {name}", names[car]))
        }
        RawTrigger::When(RawWhen { car: None, reaches: None, light: Some(text), turns: Some(colour) }) => {
            let light = light_named("when.light", text)?;
            (Trigger::LightTurns { light, colour: *colour }, format!("when {text} turns {}", colour.name()))
        }
        RawTrigger::When(_) => return Err((
            "when".into(),
            "expected {\"car\": CAR, \"reaches\": INTERSECTION} or {\"light\": \"AC/W/straight\", \"turns\": COLOUR}"
                .into(),
        )),
    };
    let effect = match &raw.effect {
        RawEffect::None {} => return Ok(None),
        RawEffect::Stop { car, seconds } => Effect::Stop {
            car: car_named("car", car)?,
            seconds: positive("seconds", *seconds, "seconds to stay stopped")?,
        },
        RawEffect::RunRedLight { car } => Effect::RunRedLights { car: car_named("car", car)? },
        RawEffect::SetDesiredSpeed { car, speed } => {
            Effect::SetDesiredSpeed { car: car_named("car", car)?, speed: positive("speed", *speed, "m/s")? }
        }
        RawEffect::Remove { car } => Effect::Remove { car: car_named("car", car)? },
        RawEffect::SetLight { light, colour, seconds } => Effect::SetLight {
            light: light_named("light", light)?,
            colour: *colour,
            seconds: positive("seconds", *seconds, "seconds the colour is held")?,
        },
        RawEffect::ReplaceActions { car, actions, merge_distances } => {
            let car = car_named("car", car)?;
            let actions = resolve_actions(actions, |k| format!("actions[{k}]"))?;
            let merge_distances = match merge_distances {
                None => vec![0.0; actions.len()],
                Some(d) if d.len() == actions.len() => {
                    if let Some((k, v)) = d.iter().enumerate().find(|(_, v)| !(v.is_finite() && **v >= 0.0)) {
                        return Err((
                            format!("merge_distances[{k}]"),
                            format!("{} is not allowed: metres along the lane, 0 or more", Shown(*v)),
                        ));
                    }
                    d.clone()
                }
                Some(_) => {
                    return Err((
                        "merge_distances".into(),
                        format!("expected {} numbers, one per action", actions.len()),
                    ))
                }
            };
            Effect::ReplaceActions { car, actions, merge_distances }
        }
        RawEffect::SetLightPlan { light, schedule, offset } => {
            let light = light_named("light", light)?;
            if schedule.is_empty() {
                return Err(("schedule".into(), "expected [{\"colour\": \"green\", \"duration\": 10}, ...]".into()));
            }
            for (k, step) in schedule.iter().enumerate() {
                positive(&format!("schedule[{k}].duration"), step.duration, "seconds")?;
            }
            let offset = offset.unwrap_or(0.0);
            if !offset.is_finite() {
                return Err(("offset".into(), format!("{offset} is not a number of seconds")));
            }
            Effect::SetLightPlan { light, offset, schedule: schedule.clone() }
        }
        RawEffect::SetConfounder { confounder: name, value } => {
            let (confounder, _) = ConfounderName::ALL.into_iter().find(|(_, n)| n == name).ok_or_else(|| {
                ("confounder".to_string(), format!("{name:?} is not a confounder: rain, fog, snow, wetness or hour"))
            })?;
            let limit = if confounder == ConfounderName::Hour { 24.0 } else { 1.0 };
            if !(0.0..=limit).contains(value) {
                return Err(("value".into(), format!("{} is not allowed: 0 to {limit}", Shown(*value))));
            }
            Effect::SetConfounder { confounder, value: *value }
        }
    };
    let label = match &raw.label {
        Some(label) => label.clone(),
        None => format!("{} ({when_text})", effect.describe(|c| names[c].clone(), |l| light_name(map, l))),
    };
    Ok(Some(Intervention { trigger, effect, label }))
}

/// Reads an intervention file (a list of interventions, as in a scenario's
/// `interventions`, or one intervention object) once, and checks it against
/// each of `scenarios`: one list of interventions per scenario.
pub fn load_interventions(
    path: &Path,
    scenarios: &[LoadedScenario],
    map: &CityMap,
) -> Result<Vec<Vec<Intervention>>, ScenarioFileError> {
    let text = std::fs::read_to_string(path).map_err(|e| unreadable(path, e))?;
    load_interventions_text(path, &text, scenarios, map)
}

/// [`load_interventions`] of `text`, a file's contents; errors name `path`.
pub fn load_interventions_text(
    path: &Path,
    text: &str,
    scenarios: &[LoadedScenario],
    map: &CityMap,
) -> Result<Vec<Vec<Intervention>>, ScenarioFileError> {
    let file_error = |field: String, message: String| file_error(path, field, message);
    // Paths as in a scenario's `interventions`, whether the file is a list or one object.
    let json = json::parse(text).map_err(|e| {
        let field =
            if e.path.is_empty() || e.path.starts_with('[') { e.path.clone() } else { format!("[0].{}", e.path) };
        let field = if field.is_empty() { field } else { format!("interventions{field}") };
        file_error(field, e.message)
    })?;
    let list = match json {
        Value::Array(list) => raw_interventions(list, "interventions"),
        one => raw_intervention(one, "interventions[0]").map(|one| vec![one]),
    }
    .map_err(|e| file_error(e.path, e.message))?;
    scenarios
        .iter()
        .map(|scenario| {
            let here = Here { file: path, scenario: scenario.name.clone() };
            if scenario.plan.world.kind() != WorldKind::City {
                return Err(here.err(None, "", "interventions need the city world (the toy world has no agency)"));
            }
            let names: Vec<String> = scenario.plan.cars.iter().map(|c| c.name.clone()).collect();
            resolve_interventions(&here, &list, "interventions", &names, map, &scenario.expansion)
        })
        .collect()
}
