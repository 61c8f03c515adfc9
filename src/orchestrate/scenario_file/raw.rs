//! The raw types of a scenario file: the JSON as written, checked for shape
//! only (the resolving pass in `mod.rs` gives it meaning).

use crate::json::{self, JsonError};
use crate::map::signals::{Colour, ScheduleStep};
use crate::spec::{BirdsEyeView, CameraSpec, CitySpec, MapSpec, WorldKind};
use serde::Deserialize;
use serde_json::{Map, Value};

/// One scenario as written.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawScenario {
    #[serde(rename = "Name")]
    pub(super) name: String,
    #[serde(rename = "Vehicles")]
    pub(super) vehicles: Vec<RawVehicle>,
    pub(super) world: Option<WorldKind>,
    pub(super) seed: Option<u64>,
    pub(super) frames: Option<u32>,
    pub(super) frame_interval: Option<f64>,
    pub(super) city: Option<CitySpec>,
    /// Read by [`raw_interventions`], which keeps the JSON paths of the
    /// intervention's fields that sit beside their `do` tag.
    pub(super) interventions: Option<Vec<Value>>,
    pub(super) cameras: Option<Vec<CameraSpec>>,
    /// How the bird's-eye frames are drawn (`flat` or `pinhole`).
    pub(super) birds_eye: Option<BirdsEyeView>,
    /// The scenario's own map (a spec's `map` section, drawing nothing):
    /// the default city when absent.
    pub(super) map: Option<MapSpec>,
    #[allow(dead_code)]
    pub(super) comment: Option<String>,
}

/// One vehicle as written.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawVehicle {
    #[serde(rename = "Id")]
    pub(super) id: String,
    #[serde(rename = "Spawn")]
    pub(super) spawn: String,
    #[serde(rename = "SpawnAtDistance", default)]
    pub(super) spawn_at_distance: f64,
    #[serde(rename = "DriveQueue", default)]
    pub(super) drive_queue: Vec<String>,
    /// Numbers, or (the original generator's quirk) action names, read in
    /// the resolving pass.
    #[serde(rename = "MergeAtDistances")]
    pub(super) merge_at_distances: Option<Vec<Value>>,
    pub(super) desired_speeds: Option<Vec<f64>>,
    pub(super) time_headway: Option<f64>,
    pub(super) runs_red_lights: Option<bool>,
    pub(super) colour: Option<String>,
    #[allow(dead_code)]
    pub(super) comment: Option<String>,
}

/// One intervention as written: a trigger, an effect tagged by `do`, and an
/// optional label, all keys of one object.
#[derive(Debug)]
pub(super) struct RawIntervention {
    pub(super) trigger: RawTrigger,
    pub(super) effect: RawEffect,
    pub(super) label: Option<String>,
}

/// When an intervention fires: exactly one of these keys.
#[derive(Debug, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub(super) enum RawTrigger {
    /// Seconds from the start.
    At(f64),
    AtFrame(u64),
    When(RawWhen),
}

/// An event: `{"car", "reaches"}` or `{"light", "turns"}`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawWhen {
    pub(super) car: Option<String>,
    pub(super) reaches: Option<String>,
    pub(super) light: Option<String>,
    pub(super) turns: Option<Colour>,
}

/// What an intervention does, tagged by its `do` key.
#[derive(Debug, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub(super) enum RawEffect {
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
pub(super) struct RawCommon {
    pub(super) label: Option<String>,
    #[allow(dead_code)]
    pub(super) comment: Option<String>,
}

const TRIGGER_KEYS: [&str; 3] = ["at", "at_frame", "when"];
const COMMON_KEYS: [&str; 2] = ["label", "comment"];

/// Reads one intervention object (at JSON path `path`).
pub(super) fn raw_intervention(value: Value, path: &str) -> Result<RawIntervention, JsonError> {
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
    // Neither a trigger nor "do": not an intervention at all (a scenario,
    // or a list wrapped in an object), which "give exactly one trigger"
    // did not say.
    if trigger.is_empty() && !effect.contains_key("do") {
        let short = |k: &str| {
            if k.chars().count() > 40 {
                format!("{}...", k.chars().take(40).collect::<String>())
            } else {
                k.to_string()
            }
        };
        let keys: Vec<String> = effect.keys().take(8).map(|k| format!("{:?}", short(k))).collect();
        let more = if effect.len() > keys.len() { ", ..." } else { "" };
        let hint = if effect.contains_key("Vehicles") || effect.contains_key("Name") {
            "; it looks like a scenario (it has Name or Vehicles), which is given as --scenario"
        } else if effect.contains_key("interventions") {
            "; an intervention file is the list itself ([{\"at\": 6.0, \"do\": ...}, ...]), not an object \
             holding one"
        } else {
            ""
        };
        return Err(fail(
            "",
            &format!(
                "this object (keys {}{more}) has no trigger and no \"do\": it is not an intervention such as \
                 {{\"at\": 6.0, \"do\": \"stop\", \"car\": \"Car_1\", \"seconds\": 4}}{hint}",
                if keys.is_empty() { "none".to_string() } else { keys.join(", ") }
            ),
        ));
    }
    if trigger.len() != 1 {
        return Err(fail(
            "",
            "give exactly one trigger: \"at\" (seconds), \"at_frame\" (frame index) or \"when\" (an event)",
        ));
    }
    let trigger: RawTrigger = json::from_value(Value::Object(trigger)).map_err(|mut e| {
        // A frame index's range is the scenario's frames, not the type's
        // (0 to 18446744073709551615 was named for 2.5); checked once read.
        if e.path == "at_frame" {
            for said in ["use a whole number from 0 to 18446744073709551615", "use a whole number, 0 or more"] {
                e.message =
                    e.message.replace(said, "use a frame index, a whole number from 0 to the scenario's last frame");
            }
        }
        e.under(path)
    })?;
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
pub(super) fn raw_interventions(list: Vec<Value>, path: &str) -> Result<Vec<RawIntervention>, JsonError> {
    list.into_iter().enumerate().map(|(i, item)| raw_intervention(item, &format!("{path}[{i}]"))).collect()
}
