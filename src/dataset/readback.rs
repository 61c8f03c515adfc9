//! A scenario folder read back from disk into the [`ScenarioArrays`] that
//! simulating it gives: every log parsed, every number as its file writes
//! it (which is exactly the in-memory value, see [`super::arrays`]), and
//! the bird's-eye frames decoded on demand from their PNGs. Errors name
//! the file, the line and the field.

use super::ScenarioSummary;
use crate::map::signals::light_label;
use crate::output::arrays::{EventRow, InteractionArrays, LightArrays, ScenarioArrays, LIGHT_COLOURS};
use crate::output::layout::{frame_digits, FrameKind};
use crate::output::logs::{
    parse_interactions, read_effects, read_interactions as read_interaction_records, InteractionRecord,
};
use crate::output::png::decode_8bit;
use crate::world::{BoundBy, EventKind};
use std::path::Path;

/// Reads the scenario folder `dir` (as `gen` or `counterfactual` wrote it):
/// `scenario.json`, `poses.csv` and, where the folder has them,
/// `lights.csv`, `interactions.csv`, `events.csv` and `effects.csv`. The
/// frames stay on disk ([`read_frames`] decodes them).
pub fn read_scenario(dir: &Path) -> Result<ScenarioArrays, String> {
    let summary = ScenarioSummary::read(dir)?;
    let json_path = dir.join("scenario.json");
    let scenario_json =
        crate::input::read_record(&json_path).map_err(|e| format!("cannot read {}: {e}", json_path.display()))?;
    let value: serde_json::Value =
        serde_json::from_slice(&scenario_json).map_err(|e| format!("{}: {e}", json_path.display()))?;
    let (frames, cars) = (summary.frames as usize, summary.cars.len());
    // A scenario.json that claims more rows than poses.csv can hold is
    // refused before any memory is set aside for them.
    let poses_path = dir.join("poses.csv");
    super::poses_fit(&poses_path, frames, cars)?;
    if let Some(car) = summary.cars.iter().enumerate().find(|(i, c)| c.id as usize != *i) {
        return Err(format!(
            "{}: cars[{}] has id {}; ids must be 0, 1, ... in order",
            json_path.display(),
            car.0,
            car.1.id
        ));
    }
    let mut a = ScenarioArrays {
        scenario_json,
        frames,
        cars,
        car_ids: summary.cars.iter().map(|c| c.id).collect(),
        car_names: summary.cars.iter().map(|c| c.name.clone()).collect(),
        t: vec![0.0; frames],
        position: vec![0.0; frames * cars * 3],
        rotation: vec![0.0; frames * cars * 3],
        pixels: vec![0.0; frames * cars * 2],
        speed: vec![0.0; frames * cars],
        in_view: vec![0; frames * cars],
        graph: vec![0; cars * cars],
        edges: summary.edges.clone(),
        lights: None,
        interactions: None,
        events: Vec::new(),
        images: None,
        batch: None,
        effects: None,
    };
    for &[leader, follower] in &summary.edges {
        if leader as usize >= cars || follower as usize >= cars {
            return Err(format!("{}: edge [{leader}, {follower}] names a car beyond {cars}", json_path.display()));
        }
        a.graph[leader as usize * cars + follower as usize] = 1;
    }
    read_poses(&poses_path, &mut a)?;
    // What the folder must hold follows from scenario.json: effects where
    // it lists causal edges, the city's logs in the city world.
    let effects = dir.join("effects.csv");
    if value.get("causal_edges").is_some() {
        let threshold = match &value["effect_threshold_m"] {
            serde_json::Value::Null => {
                return Err(format!(
                    "{}: effect_threshold_m is missing, but it lists causal_edges",
                    json_path.display()
                ))
            }
            v => v.as_f64().filter(|t| t.is_finite() && *t > 0.0).ok_or_else(|| {
                format!("{}: effect_threshold_m {v} is not allowed: metres above 0", json_path.display())
            })?,
        };
        let rows = read_effects(&effects, cars, frames, threshold)?;
        // As validate holds them: every row once, and the graphs they give.
        let report = super::effects::check_effects(rows, &value, &json_path, cars, threshold).map_err(|e| {
            if e.starts_with(&json_path.display().to_string()) {
                e
            } else {
                format!("{}: {e}", effects.display())
            }
        })?;
        a.effects = Some(report.rows);
    }
    if value["world"] == "city" {
        let read = read_light_log(dir, frames, summary.frame_interval)?;
        a.interactions = Some(read_interactions(&dir.join("interactions.csv"), frames, cars, &read.names)?);
        a.events = read_events(&dir.join("events.csv"), frames, cars, &read.names)?;
        a.lights = Some(read);
    }
    Ok(a)
}

fn open_csv(path: &Path) -> Result<csv::Reader<std::fs::File>, String> {
    // A regular file only: a pipe hung the reader.
    crate::input::regular_file(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    csv::Reader::from_path(path).map_err(|e| format!("cannot read {}: {e}", path.display()))
}

/// A parsed field or an error naming the file, line, column and value.
fn field<T: std::str::FromStr>(
    path: &Path,
    line: usize,
    row: &csv::StringRecord,
    columns: &[&str],
    k: usize,
) -> Result<T, String> {
    let text = row.get(k).unwrap_or("");
    text.parse::<T>()
        .map_err(|_| format!("{} line {line}: {} {text:?} is not a valid value", path.display(), columns[k]))
}

/// [`field`] of a duration: finite seconds, 0 or more.
fn seconds(path: &Path, line: usize, row: &csv::StringRecord, columns: &[&str], k: usize) -> Result<f64, String> {
    let value: f64 = field(path, line, row, columns, k)?;
    if !(value.is_finite() && value >= 0.0) {
        return Err(format!(
            "{} line {line}: {} {value} is not allowed: seconds, 0 or more",
            path.display(),
            columns[k]
        ));
    }
    Ok(value)
}

/// [`field`] of a pixel coordinate: finite (empty: none, NaN).
fn pixel(path: &Path, line: usize, row: &csv::StringRecord, columns: &[&str], k: usize) -> Result<f64, String> {
    if row.get(k) == Some("") {
        return Ok(f64::NAN);
    }
    let value: f64 = field(path, line, row, columns, k)?;
    if !value.is_finite() {
        return Err(format!(
            "{} line {line}: {} {value} is not allowed: a finite pixel, or empty",
            path.display(),
            columns[k]
        ));
    }
    Ok(value)
}

fn check_header<R: std::io::Read>(path: &Path, reader: &mut csv::Reader<R>, columns: &[&str]) -> Result<(), String> {
    let header = reader.headers().map_err(|e| format!("{}: {e}", path.display()))?;
    if header.iter().ne(columns.iter().copied()) {
        return Err(format!(
            "{}: columns {:?}, expected {columns:?}",
            path.display(),
            header.iter().collect::<Vec<_>>()
        ));
    }
    Ok(())
}

fn read_poses(path: &Path, a: &mut ScenarioArrays) -> Result<(), String> {
    let (frames, cars) = (a.frames, a.cars);
    let file = std::fs::File::open(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    super::poses::read_pose_rows(std::io::BufReader::new(file), path, frames, cars, |row| {
        let at = row.frame * cars + row.car;
        a.t[row.frame] = row.t;
        a.position[at * 3..at * 3 + 3].copy_from_slice(&row.position);
        a.rotation[at * 3..at * 3 + 3].copy_from_slice(&row.rotation);
        a.pixels[at * 2..at * 2 + 2].copy_from_slice(&row.pixel);
        a.speed[at] = row.speed;
        a.in_view[at] = row.in_view as u8;
    })
}

const LIGHT_COLUMNS: [&str; 9] =
    ["frame", "t", "intersection", "approach", "signal", "colour", "since_change", "head_px", "head_py"];

/// The lights of the scenario folder `dir` as arrays, from
/// `light_changes.csv` (gen's default) or, where the folder has that
/// instead (`--lights frames`), `lights.csv`.
pub fn read_light_log(dir: &Path, frames: usize, frame_interval: f64) -> Result<LightArrays, String> {
    let changes = dir.join(crate::output::layout::LIGHT_CHANGES_CSV);
    let every_frame = dir.join(crate::output::layout::LIGHTS_CSV);
    match (changes.exists(), every_frame.exists()) {
        (true, _) => read_light_changes(&changes, frames, frame_interval),
        (false, true) => read_lights(&every_frame, frames),
        (false, false) => Err(format!(
            "cannot read {} (nor {}): No such file; a city scenario logs its lights in one of them",
            changes.display(),
            crate::output::layout::LIGHTS_CSV
        )),
    }
}

/// `light_changes.csv`: every light at frame 0 (which lists them in plan
/// order), then a row where a light's colour differs from the frame
/// before, frames ascending and lights in plan order within a frame. Each
/// frame between holds the colour, its time since the change growing by
/// the frame interval (as lights.csv writes it, to the millisecond).
fn read_light_changes(path: &Path, frames: usize, frame_interval: f64) -> Result<LightArrays, String> {
    parse_light_changes(open_csv(path)?, path, frames, frame_interval)
}

/// [`read_light_changes`] of `light_changes.csv`'s bytes, read from
/// `reader` (errors name `path`).
pub fn parse_light_changes<R: std::io::Read>(
    mut reader: csv::Reader<R>,
    path: &Path,
    frames: usize,
    frame_interval: f64,
) -> Result<LightArrays, String> {
    check_header(path, &mut reader, &LIGHT_COLUMNS)?;
    let mut names: Vec<String> = Vec::new();
    let mut heads: Vec<f64> = Vec::new();
    // Per light: its colour and time since the change at its last row, and that row's frame.
    let mut current: Vec<(u8, f64, usize)> = Vec::new();
    let (mut colour, mut since_change) = (Vec::new(), Vec::new());
    let mut filled = 0usize; // frames written to the arrays
    let mut last: Option<(usize, usize)> = None; // (frame, light) of the row before
    let fill_to =
        |to: usize, current: &[(u8, f64, usize)], colour: &mut Vec<u8>, since: &mut Vec<f64>, filled: &mut usize| {
            while *filled < to {
                for &(c, s, at) in current {
                    colour.push(c);
                    let grown = s + (*filled - at) as f64 * frame_interval;
                    since.push((grown * 1000.0).round() / 1000.0);
                }
                *filled += 1;
            }
        };
    for (n, row) in reader.records().enumerate() {
        let line = n + 2;
        let row = row.map_err(|e| format!("{}: {e}", path.display()))?;
        let frame: usize = field(path, line, &row, &LIGHT_COLUMNS, 0)?;
        let name = light_label(&row[2], &row[3], &row[4]);
        let c = LIGHT_COLOURS.iter().position(|c| c.name() == &row[5]).ok_or_else(|| {
            format!("{} line {line}: colour {:?} is not one of green, yellow, red", path.display(), &row[5])
        })? as u8;
        let since = seconds(path, line, &row, &LIGHT_COLUMNS, 6)?;
        if frame == 0 {
            if names.contains(&name) || last.is_some_and(|(f, _)| f > 0) {
                return Err(format!("{} line {line}: light {name} at frame 0 is out of order", path.display()));
            }
            for k in [7, 8] {
                heads.push(pixel(path, line, &row, &LIGHT_COLUMNS, k)?);
            }
            names.push(name);
            current.push((c, since, 0));
            last = Some((0, names.len() - 1));
            continue;
        }
        let light = names
            .iter()
            .position(|x| *x == name)
            .ok_or_else(|| format!("{} line {line}: light {name} is not one of frame 0's", path.display()))?;
        if frame >= frames || last.is_some_and(|(f, l)| (frame, light) <= (f, l)) {
            return Err(format!(
                "{} line {line}: light {name} at frame {frame} is out of order (frames ascending below {frames}, lights in frame 0's order)",
                path.display()
            ));
        }
        if current[light].0 == c {
            return Err(format!(
                "{} line {line}: light {name} at frame {frame} shows {} as before: not a change",
                path.display(),
                &row[5]
            ));
        }
        fill_to(frame, &current, &mut colour, &mut since_change, &mut filled);
        current[light] = (c, since, frame);
        last = Some((frame, light));
    }
    fill_to(frames, &current, &mut colour, &mut since_change, &mut filled);
    Ok(LightArrays { names, colour, since_change, head_pixels: heads })
}

fn read_lights(path: &Path, frames: usize) -> Result<LightArrays, String> {
    parse_lights(open_csv(path)?, path, frames)
}

/// `lights.csv` (`--lights frames`): every light, frame by frame, in frame
/// 0's order, read from `reader` (errors name `path`).
pub fn parse_lights<R: std::io::Read>(
    mut reader: csv::Reader<R>,
    path: &Path,
    frames: usize,
) -> Result<LightArrays, String> {
    check_header(path, &mut reader, &LIGHT_COLUMNS)?;
    let mut lights =
        LightArrays { names: Vec::new(), colour: Vec::new(), since_change: Vec::new(), head_pixels: Vec::new() };
    let mut rows = 0usize;
    for (n, row) in reader.records().enumerate() {
        let line = n + 2;
        let row = row.map_err(|e| format!("{}: {e}", path.display()))?;
        let frame: usize = field(path, line, &row, &LIGHT_COLUMNS, 0)?;
        let name = light_label(&row[2], &row[3], &row[4]);
        if frame == 0 {
            lights.names.push(name.clone());
            for k in [7, 8] {
                lights.head_pixels.push(pixel(path, line, &row, &LIGHT_COLUMNS, k)?);
            }
        }
        let count = lights.names.len().max(1);
        if frame != rows / count || lights.names.get(rows % count) != Some(&name) {
            return Err(format!(
                "{} line {line}: light {name} at frame {frame} is out of order (one row per frame and light, lights in frame 0's order)",
                path.display()
            ));
        }
        let colour = LIGHT_COLOURS.iter().position(|c| c.name() == &row[5]).ok_or_else(|| {
            format!("{} line {line}: colour {:?} is not one of green, yellow, red", path.display(), &row[5])
        })?;
        lights.colour.push(colour as u8);
        lights.since_change.push(seconds(path, line, &row, &LIGHT_COLUMNS, 6)?);
        rows += 1;
    }
    if rows != frames * lights.names.len() {
        return Err(format!(
            "{}: {rows} rows, expected {frames} frames x {} lights",
            path.display(),
            lights.names.len()
        ));
    }
    Ok(lights)
}

/// The index of light `name` among `names` (-1 for none); `place` says
/// where it was read, for the error. With no names (a light log that could
/// not be read, which is reported on its own) any name is taken, as 0.
fn light_index(place: &dyn Fn() -> String, names: Option<&[String]>, name: &str) -> Result<i16, String> {
    match (name, names) {
        ("", _) => Ok(-1),
        (_, None) => Ok(0),
        (_, Some(names)) => names
            .iter()
            .position(|n| n == name)
            .map(|i| i as i16)
            .ok_or_else(|| format!("{}: light {name:?} is not one of the light log's lights", place())),
    }
}

fn read_interactions(path: &Path, frames: usize, cars: usize, lights: &[String]) -> Result<InteractionArrays, String> {
    interaction_arrays(&read_interaction_records(path, frames, cars)?, path, cars, Some(lights))
}

/// `interactions.csv` read from `reader` (errors name `path`), its lights
/// among `lights` (the light log's, where it could be read): the rule
/// `validate` holds the file to, as the readers do.
pub fn parse_interaction_arrays<R: std::io::Read>(
    reader: csv::Reader<R>,
    path: &Path,
    frames: usize,
    cars: usize,
    lights: Option<&[String]>,
) -> Result<InteractionArrays, String> {
    interaction_arrays(&parse_interactions(reader, path, frames, cars)?, path, cars, lights)
}

fn interaction_arrays(
    records: &[InteractionRecord],
    path: &Path,
    cars: usize,
    lights: Option<&[String]>,
) -> Result<InteractionArrays, String> {
    let mut out = InteractionArrays { bound_by: Vec::new(), other_car: Vec::new(), light: Vec::new() };
    for (at, r) in records.iter().enumerate() {
        out.bound_by.push(BoundBy::ALL.iter().position(|&b| b == r.bound_by).unwrap_or(0) as u8);
        out.other_car.push(r.other_car.map_or(-1, |c| c as i16));
        let place = || format!("{} (frame {}, car {})", path.display(), at / cars, at % cars);
        out.light.push(light_index(&place, lights, r.light.as_deref().unwrap_or(""))?);
    }
    Ok(out)
}

const EVENT_COLUMNS: [&str; 7] = ["frame", "t", "kind", "car", "other_car", "light", "detail"];

fn read_events(path: &Path, frames: usize, cars: usize, lights: &[String]) -> Result<Vec<EventRow>, String> {
    parse_events(open_csv(path)?, path, frames, cars, Some(lights))
}

/// `events.csv` read from `reader` (errors name `path`): each row's frame
/// within the scenario, a known kind, `t` in seconds (0 or more), its cars
/// among the scenario's (the car empty only for an intervention on no car:
/// a light or the weather) and its light among `lights` (the light log's,
/// where it could be read).
pub fn parse_events<R: std::io::Read>(
    mut reader: csv::Reader<R>,
    path: &Path,
    frames: usize,
    cars: usize,
    lights: Option<&[String]>,
) -> Result<Vec<EventRow>, String> {
    check_header(path, &mut reader, &EVENT_COLUMNS)?;
    let mut events = Vec::new();
    for (n, row) in reader.records().enumerate() {
        let line = n + 2;
        let row = row.map_err(|e| format!("{}: {e}", path.display()))?;
        let frame: u64 = field(path, line, &row, &EVENT_COLUMNS, 0)?;
        if frame as usize >= frames {
            return Err(format!(
                "{} line {line}: frame {frame} is beyond the scenario's {frames} frames",
                path.display()
            ));
        }
        let kind = EventKind::ALL.iter().find(|k| k.name() == &row[2]).ok_or_else(|| {
            format!("{} line {line}: kind {:?} is not an event kind of events.schema.json", path.display(), &row[2])
        })?;
        let car = |k: usize| -> Result<Option<u32>, String> {
            match &row[k] {
                "" => Ok(None),
                _ => {
                    let id: u32 = field(path, line, &row, &EVENT_COLUMNS, k)?;
                    if id as usize >= cars {
                        return Err(format!(
                            "{} line {line}: {} {id} is not a car below {cars}",
                            path.display(),
                            EVENT_COLUMNS[k]
                        ));
                    }
                    Ok(Some(id))
                }
            }
        };
        light_index(&|| format!("{} line {line}", path.display()), lights, &row[5])?;
        let t: f64 = field(path, line, &row, &EVENT_COLUMNS, 1)?;
        if !(t.is_finite() && t >= 0.0) {
            return Err(format!("{} line {line}: t {t} is not allowed: seconds, 0 or more", path.display()));
        }
        let (car, other_car) = (car(3)?, car(4)?);
        if car.is_none() && *kind != EventKind::Intervention {
            return Err(format!(
                "{} line {line}: a {} event names no car (only an intervention may have none)",
                path.display(),
                kind.name()
            ));
        }
        if car.is_some() && car == other_car {
            return Err(format!("{} line {line}: other_car is the car itself ({})", path.display(), &row[3]));
        }
        events.push(EventRow {
            frame,
            t,
            kind: kind.name(),
            car,
            other_car,
            light: (!row[5].is_empty()).then(|| row[5].to_string()),
            detail: row[6].to_string(),
        });
    }
    Ok(events)
}

/// Decodes frames `start..end` of the scenario folder `dir` (`frames`
/// frames of `width` x `height`) from `rgb/NNNN.png` or `mask/NNNN.png`:
/// `[n, height, width, 3]` or `[n, height, width]` bytes, as
/// [`ScenarioArrays::images`] holds them.
pub fn read_frames(
    dir: &Path,
    kind: FrameKind,
    frames: u32,
    (start, end): (u32, u32),
    (width, height): (u32, u32),
) -> Result<Vec<u8>, String> {
    let colour = match kind {
        FrameKind::Rgb => png::ColorType::Rgb,
        FrameKind::Mask => png::ColorType::Grayscale,
        FrameKind::Depth => return Err("depth frames are read by the camera that wrote them, not here".into()),
    };
    if end > frames {
        return Err(format!("{}: frames {start}..{end} asked for, the scenario has {frames}", dir.display()));
    }
    let digits = frame_digits(frames);
    let mut out = Vec::new();
    for frame in start..end {
        let path = dir.join(kind.folder()).join(format!("{frame:0digits$}.png"));
        // A regular file only: a pipe hung the reader, a link to /dev/zero filled memory.
        let data = crate::input::read_data(&path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
        out.extend(decode_8bit(&data, width, height, colour).map_err(|e| format!("{}: {e}", path.display()))?);
    }
    Ok(out)
}
