//! `lights.csv`, `events.csv` and `interactions.csv` (city world), and
//! `effects.csv` (both worlds). Columns are documented in
//! `data-schema/lights.schema.json`, `data-schema/events.schema.json`,
//! `data-schema/interactions.schema.json` and `data-schema/effects.schema.json`.

use super::number::{push_fixed, push_int};
use super::poses::PIXEL_DECIMALS;
use super::rows::{cells, Rows};
use crate::map::signals::{light_label, LightPlan};
use crate::world::effects::{EffectReport, EffectRow, InterventionKind};
use crate::world::{BoundBy, Trajectories};
use serde::Serialize;
use std::io::Write;
use std::path::Path;

pub const LIGHT_COLUMNS: [&str; 9] =
    ["frame", "t", "intersection", "approach", "signal", "colour", "since_change", "head_px", "head_py"];
pub const EVENT_COLUMNS: [&str; 7] = ["frame", "t", "kind", "car", "other_car", "light", "detail"];
pub const INTERACTION_COLUMNS: [&str; 5] = ["frame", "car", "bound_by", "other_car", "light"];
pub const EFFECT_COLUMNS: [&str; 6] = ["cause", "effect", "intervention", "max_divergence_m", "first_frame", "direct"];
/// Decimals of `max_divergence_m` (millimetres).
pub const DIVERGENCE_DECIMALS: u32 = 3;

fn round(x: f64, decimals: i32) -> f64 {
    let f = 10f64.powi(decimals);
    (x * f).round() / f
}

/// One row per frame and light, lights in plan order (with `changes_only`,
/// one per light at frame 0 and then only where a light's colour differs
/// from the frame before: `light_changes.csv`); `head_pixels` is each
/// light's signal head in the bird's-eye view (empty cells without one).
/// Lights are most of what a poses-only scenario writes, so each light's
/// constant cells are formatted once (quoted as the csv writer quotes them)
/// and each row adds only its frame, colour and time since the change.
pub fn write_lights<W: Write>(
    mut out: W,
    plan: &LightPlan,
    intersection_names: &[String],
    head_pixels: &[Option<glam::DVec2>],
    trajectories: &Trajectories,
    changes_only: bool,
) -> std::io::Result<()> {
    let mut approach = [0u8; 4];
    let mut constant = Vec::with_capacity(plan.lights.len());
    for (light, head) in plan.lights.iter().zip(head_pixels) {
        let name: &str = light.approach.encode_utf8(&mut approach);
        let mut middle = cells(&[intersection_names[light.intersection].as_str(), name, light.signal_label().as_str()]);
        middle.push(b',');
        let mut tail = Vec::new();
        if let Some(p) = head {
            push_fixed(&mut tail, p.x, PIXEL_DECIMALS);
            tail.push(b',');
            push_fixed(&mut tail, p.y, PIXEL_DECIMALS);
        } else {
            tail.push(b',');
        }
        tail.push(b'\n');
        constant.push((middle, tail));
    }
    let mut buf = cells(&LIGHT_COLUMNS);
    buf.push(b'\n');
    let mut prefix = Vec::new();
    for (frame, states) in trajectories.lights.iter().enumerate() {
        prefix.clear();
        push_int(&mut prefix, frame as u64);
        prefix.push(b',');
        push_fixed(&mut prefix, frame as f64 * trajectories.frame_interval, 6);
        prefix.push(b',');
        let before = frame.checked_sub(1).map(|f| &trajectories.lights[f]);
        for (k, (state, (middle, tail))) in states.iter().zip(&constant).enumerate() {
            if changes_only && before.is_some_and(|b| b[k].colour == state.colour) {
                continue;
            }
            buf.extend_from_slice(&prefix);
            buf.extend_from_slice(middle);
            buf.extend_from_slice(state.colour.name().as_bytes());
            buf.push(b',');
            push_fixed(&mut buf, state.since_change, 3);
            buf.push(b',');
            buf.extend_from_slice(tail);
        }
        if buf.len() >= 1 << 16 {
            out.write_all(&buf)?;
            buf.clear();
        }
    }
    out.write_all(&buf)?;
    out.flush()?;
    Ok(())
}

#[derive(Serialize)]
struct EventRow<'a> {
    frame: u64,
    t: f64,
    kind: &'a str,
    car: Option<u32>,
    other_car: Option<u32>,
    light: &'a str,
    detail: &'a str,
}

/// Every light's name (`AC/W/straight`, as scenario files name lights), in
/// plan order.
pub fn light_names(plan: &LightPlan, intersection_names: &[String]) -> Vec<String> {
    plan.lights
        .iter()
        .map(|l| light_label(&intersection_names[l.intersection], l.approach, &l.signal_label()))
        .collect()
}

/// The first frame that shows the outcome of an event at `t` seconds.
pub fn event_frame(t: f64, frame_interval: f64) -> u64 {
    (t / frame_interval - 1e-6).ceil().max(0.0) as u64
}

/// An event's time as `events.csv` gives it (seconds, 4 decimals).
pub fn event_time(t: f64) -> f64 {
    round(t, 4)
}

/// One row per event; `frame` is the first frame that shows its outcome.
/// `car` is empty for events of no car (a light or the weather changed),
/// `light` names the light of light interventions and red-light runs.
pub fn write_events<W: Write>(
    out: W,
    plan: &LightPlan,
    intersection_names: &[String],
    trajectories: &Trajectories,
) -> csv::Result<()> {
    // The header is written by hand so that a scenario without events still has one.
    let mut w = csv::WriterBuilder::new().has_headers(false).from_writer(out);
    w.write_record(EVENT_COLUMNS)?;
    let light_names = light_names(plan, intersection_names);
    for e in &trajectories.events {
        w.serialize(EventRow {
            frame: event_frame(e.t, trajectories.frame_interval),
            t: event_time(e.t),
            kind: e.kind.name(),
            car: e.car,
            other_car: e.other,
            light: e.light.map_or("", |l| light_names[l].as_str()),
            detail: &e.detail,
        })?;
    }
    w.flush()?;
    Ok(())
}

/// One row per frame and car (cars in id order): what bound the car's speed
/// choice at its latest decision, and the other car or the light
/// (`AC/W/straight`, as scenario files name lights) it names.
pub fn write_interactions<W: Write>(
    out: W,
    plan: &LightPlan,
    intersection_names: &[String],
    trajectories: &Trajectories,
) -> std::io::Result<()> {
    let mut rows = Rows::new(out, &INTERACTION_COLUMNS)?;
    let light_names = light_names(plan, intersection_names);
    for (frame, cars) in trajectories.interactions.iter().enumerate() {
        for (car, interaction) in cars.iter().enumerate() {
            rows.int(frame as u64).int(car as u64).text(interaction.bound_by.name());
            match interaction.other_car {
                Some(other) => rows.int(other as u64),
                None => rows.text(""),
            };
            rows.text(interaction.light.map_or("", |l| light_names[l].as_str()));
            rows.end()?;
        }
    }
    rows.finish()?;
    Ok(())
}

/// One `interactions.csv` row as read back: what bound the car, and the
/// other car or the light (`AC/W/straight`) it names.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct InteractionRecord {
    pub bound_by: BoundBy,
    pub other_car: Option<usize>,
    pub light: Option<String>,
}

/// Reads a scenario's `interactions.csv` of `frames` x `cars`: one record per
/// frame and car, at `frame * cars + car`. Every row must be there once,
/// with a known `bound_by` and an `other_car` below `cars`.
pub fn read_interactions(path: &Path, frames: usize, cars: usize) -> Result<Vec<InteractionRecord>, String> {
    // A regular file only: a pipe hung the reader.
    crate::input::regular_file(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    let reader = csv::Reader::from_path(path).map_err(|e| format!("{}: {e}", path.display()))?;
    parse_interactions(reader, path, frames, cars)
}

/// [`read_interactions`] of `interactions.csv`'s bytes, read from `reader`
/// (errors name `path`): the rule `validate` holds a dataset's files to.
pub fn parse_interactions<R: std::io::Read>(
    mut reader: csv::Reader<R>,
    path: &Path,
    frames: usize,
    cars: usize,
) -> Result<Vec<InteractionRecord>, String> {
    let fail = |what: String| format!("{}: {what}", path.display());
    // The columns as written: a renamed or reordered column is not read
    // as another one.
    let header = reader.headers().map_err(|e| fail(e.to_string()))?;
    if header.iter().ne(INTERACTION_COLUMNS) {
        return Err(fail(format!("columns {:?}, expected {INTERACTION_COLUMNS:?}", header.iter().collect::<Vec<_>>())));
    }
    let mut records: Vec<Option<InteractionRecord>> = vec![None; frames * cars];
    for (line, row) in reader.records().enumerate() {
        let row = row.map_err(|e| fail(e.to_string()))?;
        let line = line + 2;
        let index =
            |column: usize, limit: usize| row.get(column).and_then(|v| v.parse::<usize>().ok()).filter(|&v| v < limit);
        let (Some(frame), Some(car)) = (index(0, frames), index(1, cars)) else {
            return Err(fail(format!("line {line}: frame or car outside {frames} frames x {cars} cars")));
        };
        let bound_by = row.get(2).and_then(BoundBy::from_name).ok_or_else(|| {
            fail(format!("line {line}: bound_by {:?} is not one of the kinds in interactions.schema.json", row.get(2)))
        })?;
        let other_car = match row.get(3) {
            None | Some("") => None,
            Some(_) => Some(index(3, cars).ok_or_else(|| fail(format!("line {line}: other_car is not a car id")))?),
        };
        let light = row.get(4).filter(|l| !l.is_empty()).map(str::to_string);
        if other_car == Some(car) {
            return Err(fail(format!("line {line}: car {car} is bound by itself (other_car {car})")));
        }
        if bound_by == BoundBy::Free && (other_car.is_some() || light.is_some()) {
            return Err(fail(format!(
                "line {line}: bound_by free names an other_car or a light: a free car has neither"
            )));
        }
        let slot = &mut records[frame * cars + car];
        if slot.is_some() {
            return Err(fail(format!("line {line}: a second row for frame {frame}, car {car}")));
        }
        *slot = Some(InteractionRecord { bound_by, other_car, light });
    }
    let missing = records.iter().filter(|r| r.is_none()).count();
    if missing > 0 {
        return Err(fail(format!("{missing} of {} frame-car rows are missing", frames * cars)));
    }
    Ok(records.into_iter().flatten().collect())
}

/// One row per cause, intervention and other car, in the report's order:
/// how far the other car moved from its factual trajectory, the first frame
/// beyond the report's threshold (empty when none) and whether the effect is
/// direct (`1`) or not (`0`).
pub fn write_effects<W: Write>(out: W, report: &EffectReport) -> std::io::Result<()> {
    let mut rows = Rows::new(out, &EFFECT_COLUMNS)?;
    for row in &report.rows {
        rows.int(row.cause as u64).int(row.effect as u64).text(row.intervention.name());
        rows.fixed(row.max_divergence_m, DIVERGENCE_DECIMALS);
        match row.first_frame {
            Some(frame) => rows.int(frame as u64),
            None => rows.text(""),
        };
        rows.text(if row.direct { "1" } else { "0" });
        rows.end()?;
    }
    rows.finish()?;
    Ok(())
}

/// Reads a scenario's `effects.csv` of `cars` cars and `frames` frames,
/// checking every field: ids below `cars` and distinct, a known
/// intervention, a divergence of at least 0, a first frame below `frames`
/// exactly when the divergence exceeds `threshold_m`, and `direct` only
/// with an effect. Rows come back in file order.
pub fn read_effects(path: &Path, cars: usize, frames: usize, threshold_m: f64) -> Result<Vec<EffectRow>, String> {
    let data = crate::input::read_data(path).map_err(|e| format!("{}: {e}", path.display()))?;
    parse_effects(path, &data, cars, frames, threshold_m)
}

/// [`read_effects`] of the file's bytes (`path` names it in messages).
pub fn parse_effects(
    path: &Path,
    data: &[u8],
    cars: usize,
    frames: usize,
    threshold_m: f64,
) -> Result<Vec<EffectRow>, String> {
    let fail = |what: String| format!("{}: {what}", path.display());
    let mut reader = csv::Reader::from_reader(data);
    let header = reader.headers().map_err(|e| fail(e.to_string()))?;
    if header.iter().ne(EFFECT_COLUMNS) {
        return Err(fail(format!("columns {:?}, expected {EFFECT_COLUMNS:?}", header.iter().collect::<Vec<_>>())));
    }
    let mut rows = Vec::new();
    for (line, record) in reader.records().enumerate() {
        let record = record.map_err(|e| fail(e.to_string()))?;
        let line = line + 2;
        let field = |k: usize| record.get(k).unwrap_or("");
        let car = |k: usize| {
            field(k).parse::<u32>().ok().filter(|&c| (c as usize) < cars).ok_or_else(|| {
                fail(format!("line {line}: {} {:?} is not a car id below {cars}", EFFECT_COLUMNS[k], field(k)))
            })
        };
        let (cause, effect) = (car(0)?, car(1)?);
        if cause == effect {
            return Err(fail(format!("line {line}: car {cause} is its own effect")));
        }
        let intervention = InterventionKind::from_name(field(2)).ok_or_else(|| {
            fail(format!("line {line}: intervention {:?} is not one of remove, next_action", field(2)))
        })?;
        let max_divergence_m =
            field(3).parse::<f64>().ok().filter(|d| d.is_finite() && *d >= 0.0).ok_or_else(|| {
                fail(format!("line {line}: max_divergence_m {:?} is not a distance of 0 or more", field(3)))
            })?;
        let first_frame = match field(4) {
            "" => None,
            text => Some(
                text.parse::<u32>()
                    .ok()
                    .filter(|&f| (f as usize) < frames)
                    .ok_or_else(|| fail(format!("line {line}: first_frame {text:?} is not a frame below {frames}")))?,
            ),
        };
        // The divergence is rounded to millimetres: compare with that slack.
        let exceeds = max_divergence_m > threshold_m + 0.0005;
        let within = max_divergence_m <= threshold_m - 0.0005;
        if (first_frame.is_none() && exceeds) || (first_frame.is_some() && within) {
            return Err(fail(format!(
                "line {line}: first_frame {:?} disagrees with max_divergence_m {max_divergence_m} and the threshold {threshold_m} m",
                field(4)
            )));
        }
        let direct = match field(5) {
            "1" => true,
            "0" => false,
            other => return Err(fail(format!("line {line}: direct {other:?} is not 0 or 1"))),
        };
        if direct && first_frame.is_none() {
            return Err(fail(format!("line {line}: direct is 1 but there is no effect")));
        }
        rows.push(EffectRow { cause, effect, intervention, max_divergence_m, first_frame, direct });
    }
    Ok(rows)
}
