//! A scenario file's interventions (and intervention files): triggers and
//! effects resolved by car and light names.

use super::raw::{raw_intervention, raw_interventions, RawEffect, RawIntervention, RawTrigger, RawWhen};
use super::vehicles::resolve_actions;
use super::{file_error, unreadable, Here, LoadedScenario, ScenarioFileError};
use crate::json::{self, Shown};
use crate::map::CityMap;
use crate::plan::confounders::ConfounderName;
use crate::plan::interventions::{Effect, Intervention, Trigger};
use crate::plan::Expansion;
use crate::spec::WorldKind;
use serde_json::Value;
use std::path::Path;

/// The index of the car called `name`, or a message listing the cars.
pub(super) fn car_index(names: &[String], name: &str) -> Result<usize, String> {
    names
        .iter()
        .position(|n| n == name)
        .ok_or_else(|| format!("{name:?} is not a car of this scenario: one of {}", names.join(", ")))
}

/// Resolves parsed interventions (a list at JSON path `field`).
pub(super) fn resolve_interventions(
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
    let light_named = |field: &str, name: &str| map.light_by_name(name).map_err(|e| (field.to_string(), e));
    let positive = |field: &str, v: f64, what: &str| {
        if v.is_finite() && v > 0.0 {
            Ok(v)
        } else {
            Err((field.to_string(), format!("{} is not allowed: {what}, above 0", Shown(v))))
        }
    };
    // A time held or a phase's length: from a millisecond (the shortest
    // frame interval) to the longest scenario (a hold that long lasts to
    // the end of any; 1e300 s was taken and printed with 300 digits).
    let (shortest, longest) = (crate::spec::MIN_FRAME_INTERVAL_S, crate::spec::MAX_SCENARIO_S);
    let duration = |field: &str, v: f64, what: &str| {
        if v.is_finite() && (shortest..=longest).contains(&v) {
            Ok(v)
        } else {
            Err((
                field.to_string(),
                format!(
                    "{} is not allowed: {what}, from {shortest} to {longest} (the longest scenario a spec \
                     allows)",
                    Shown(v)
                ),
            ))
        }
    };
    // An intervention after the last frame changes nothing a file records:
    // refused, so that a counterfactual is never silently the factual run.
    let (frames, interval) = (expansion.spec.frames, expansion.spec.frame_interval());
    // The last frame's time as a user types it (0.9, not 0.8999999999999999);
    // a trigger fires within 1e-9 s of its time, as the simulation has it.
    let last_s = ((frames.saturating_sub(1)) as f64 * interval * 1e9).round() / 1e9;
    let (trigger, when_text) = match &raw.trigger {
        RawTrigger::At(t) => {
            if !(t.is_finite() && *t >= 0.0) {
                return Err(("at".into(), format!("{} is not allowed: seconds from the start, 0 or more", Shown(*t))));
            }
            if *t > last_s + 1e-9 {
                return Err((
                    "at".into(),
                    format!(
                        "{} s is after the scenario's last frame (frame {} at {} s): it would change nothing; give 0 \
                         to {} s",
                        Shown(*t),
                        frames.saturating_sub(1),
                        Shown(last_s),
                        Shown(last_s)
                    ),
                ));
            }
            (Trigger::At(*t), format!("at {t} s"))
        }
        RawTrigger::AtFrame(f) => {
            if *f >= u64::from(frames) {
                return Err((
                    "at_frame".into(),
                    format!(
                        "{f} is not a frame of this scenario: it would change nothing; give 0 to {}",
                        frames.saturating_sub(1)
                    ),
                ));
            }
            (Trigger::At(*f as f64 * interval), format!("at frame {f}"))
        }
        RawTrigger::When(RawWhen { car: Some(car), reaches: Some(name), light: None, turns: None }) => {
            let car = car_named("when.car", car)?;
            let intersection = map.intersections.iter().position(|x| x.name == *name).ok_or_else(|| {
                let known: Vec<&str> = map.intersections.iter().map(|x| x.name.as_str()).collect();
                (
                    "when.reaches".to_string(),
                    format!("{name:?} is not an intersection of this map: {}", known.join(", ")),
                )
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
            seconds: duration("seconds", *seconds, "seconds to stay stopped")?,
        },
        RawEffect::RunRedLight { car } => Effect::RunRedLights { car: car_named("car", car)? },
        RawEffect::SetDesiredSpeed { car, speed } => {
            let max = crate::spec::MAX_DESIRED_SPEED_M_S;
            if *speed > max {
                return Err((
                    "speed".into(),
                    format!("{} is not allowed: m/s, above 0 and at most {max}", Shown(*speed)),
                ));
            }
            Effect::SetDesiredSpeed { car: car_named("car", car)?, speed: positive("speed", *speed, "m/s")? }
        }
        RawEffect::Remove { car } => Effect::Remove { car: car_named("car", car)? },
        RawEffect::SetLight { light, colour, seconds } => Effect::SetLight {
            light: light_named("light", light)?,
            colour: *colour,
            seconds: duration("seconds", *seconds, "seconds the colour is held")?,
        },
        RawEffect::ReplaceActions { car, actions, merge_distances } => {
            let car = car_named("car", car)?;
            let actions = resolve_actions(actions, "actions", |k| format!("actions[{k}]"))?;
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
                duration(&format!("schedule[{k}].duration"), step.duration, "seconds")?;
            }
            let offset = offset.unwrap_or(0.0);
            if !(offset.is_finite() && offset.abs() <= longest) {
                return Err((
                    "offset".into(),
                    format!("{} is not allowed: seconds, from -{longest} to {longest}", Shown(offset)),
                ));
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
        None => format!("{} ({when_text})", effect.describe(|c| names[c].clone(), |l| map.light_name(l))),
    };
    Ok(Some(Intervention { trigger, effect, label }))
}

/// Reads an intervention file (a list of interventions, as in a scenario's
/// `interventions`, or one intervention object) once, and checks it against
/// each of `scenarios`, its names resolved on that scenario's map: one list
/// of interventions per scenario.
pub fn load_interventions(
    path: &Path,
    scenarios: &[LoadedScenario],
) -> Result<Vec<Vec<Intervention>>, ScenarioFileError> {
    let text = crate::input::read_record_text(path).map_err(|e| unreadable(path, e))?;
    load_interventions_text(path, &text, scenarios)
}

/// [`load_interventions`] of `text`, a file's contents; errors name `path`.
pub fn load_interventions_text(
    path: &Path,
    text: &str,
    scenarios: &[LoadedScenario],
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
    if list.is_empty() {
        return Err(file_error(
            "interventions".into(),
            "the list is empty: the counterfactual would be the factual run; give at least one intervention \
             (or {\"do\": \"none\"} to check a pipeline on identical runs)"
                .into(),
        ));
    }
    scenarios
        .iter()
        .map(|scenario| {
            let here = Here { file: path, scenario: scenario.name.clone() };
            if scenario.plan.world.kind() != WorldKind::City {
                return Err(here.err(None, "", "interventions need the city world (the toy world has no agency)"));
            }
            let names: Vec<String> = scenario.plan.cars.iter().map(|c| c.name.clone()).collect();
            // The scenario's own map where it has one: lights and
            // intersections are named on the map it drives.
            let map = &scenario.expansion.map;
            resolve_interventions(&here, &list, "interventions", &names, map, &scenario.expansion)
        })
        .collect()
}
