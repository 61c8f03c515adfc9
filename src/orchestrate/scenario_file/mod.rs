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
//!
//! One concern per file: `raw.rs` (the JSON's shape), `vehicles.rs` (cars,
//! their routes and the pairs they form), `interventions.rs`; this file
//! loads a file and resolves each scenario.

mod interventions;
mod raw;
mod vehicles;

pub use interventions::{load_interventions, load_interventions_text};

use crate::camera::CameraPlan;
use crate::geometry::OrientedBox;
use crate::json::{self, JsonError, Shown, ShownText};
use crate::map::{CityMap, LanePolicy, Route};
use crate::plan::{stream_key, Expansion, GivenCar, PlannedTown, ScenarioKey, ScenarioPlan};
use crate::spec::{
    folder_name_clash, valid_folder_name, CameraSpec, CarRef, DatasetSpec, Split, WorldKind, MAX_FRAMES,
    MAX_FRAME_INTERVAL_S, MIN_FRAME_INTERVAL_S,
};
use interventions::{car_index, resolve_interventions};
use raw::{raw_interventions, RawIntervention, RawScenario};
use serde_json::Value;
use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use vehicles::{infer_pairs, resolve_vehicle};

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
            write!(f, ": scenario {}", ShownText(s))?;
        }
        if let Some(c) = &self.car {
            write!(f, ", car {}", ShownText(c))?;
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
    let text = crate::input::read_record_text(path).map_err(|e| unreadable(path, e))?;
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
        if let Some(message) = folder_name_clash(&scenario.name, loaded.iter().map(|l| l.name.as_str()), "scenario") {
            return Err(ScenarioFileError {
                file: path.to_path_buf(),
                scenario: Some(scenario.name.clone()),
                car: None,
                field: "Name".into(),
                message,
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
        // A scenario's frames take the spec's range (the type's was named).
        let message = match e.path.as_str() {
            "frames" => crate::spec::field_range_said(&e.path, e.message),
            _ => e.message,
        };
        self.err(None, e.path, message)
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
                "{} is not allowed: use 1 to 64 characters from A-Z a-z 0-9 - _ . (it names the output folder)",
                ShownText(&name)
            ),
        ));
    }
    let world = options.world.or(raw.world).unwrap_or(WorldKind::City);
    let seed = raw.seed.unwrap_or(DEFAULT_SEED);
    let frames = raw.frames.unwrap_or_else(DatasetSpec::default_frames);
    if !(1..=MAX_FRAMES).contains(&frames) {
        return Err(here.err(None, "frames", format!("{frames} is not allowed: 1 to {MAX_FRAMES}")));
    }
    if let Some(t) = raw.frame_interval {
        // As a spec's: below a millisecond frames repeat (t was 0 at every
        // frame of 5e-324 and the cars never moved).
        if !(MIN_FRAME_INTERVAL_S..=MAX_FRAME_INTERVAL_S).contains(&t) {
            return Err(here.err(
                None,
                "frame_interval",
                format!("{} is not allowed: seconds, from {MIN_FRAME_INTERVAL_S} to {MAX_FRAME_INTERVAL_S}", Shown(t)),
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
            let mut section = section.clone();
            if let Some(sumo) = section.sumo.clone() {
                // A real network, beside the scenario file.
                let folder = here.file.parent().unwrap_or(Path::new("."));
                let network =
                    crate::spec::ImportedNetwork::read(&folder.join(&sumo), section.lane_change_m, "map.sumo")
                        .map_err(|e| here.err(None, e.field, e.message))?;
                section.network = crate::spec::LoadedNetwork(Some(Arc::new(network)));
            }
            spec.map = section.clone();
            own_map = section.city_map().map_err(|e| here.err(None, e.field, e.message))?;
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
    // The leader-follower pairs as the cars start: a car moved forward off
    // another leads it if it now stands ahead (as the poses show it).
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
        camera.check_input(&field).map_err(|e| here.err(None, e.field, e.message))?;
        let plan = camera
            .plan(&field, |car| match car {
                CarRef::Name(name) => car_index(names, name),
                CarRef::Id(id) => car_index(names, &id.to_string()),
            })
            .map_err(|e| here.err(None, e.field, e.message))?;
        if let Some(why) = folder_name_clash(&plan.name, plans.iter().map(|p| p.name.as_str()), "camera") {
            return Err(here.err(None, format!("{field}.name"), why));
        }
        plans.push(plan);
    }
    Ok(plans)
}
