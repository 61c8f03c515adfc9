//! One rule for a counterfactual pair's folder, held by every reader of a
//! sweep (`evaluate`, `validate` and the Python package): both runs are the
//! pair's own scenario (its group, split and index) and of one size,
//! `summary.json` names the pair and its cars as the runs do, its affected
//! list is the cars it flags (those that diverged), the intervention lies
//! within the run, names its car and fired when it says, and every car's
//! `max_divergence_m` is the largest of its rows in `divergence.csv`, which
//! holds no divergence before the intervention's frame (the runs are
//! identical until then). An edited, swapped or linked file was scored as
//! written.
//!
//! `summary.json` and `divergence.csv` carry no checksum, so both are also
//! held to the runs' `poses.csv` (which do): a car's first divergent frame
//! is the first whose rows differ, and each distance is the one between the
//! two runs' logged positions. Both files edited alike (a car made affected,
//! or moved further, in each) passed every other check.

use crate::output::pair_summary::PairSummary;
use std::path::Path;

/// Slack between `max_divergence_m` (full precision) and `divergence.csv`'s
/// distances (written to 0.1 mm), metres.
const DIVERGENCE_SLACK_M: f64 = 1e-4;

/// Slack between a `divergence.csv` distance (to 0.1 mm, from the runs'
/// full-precision positions) and the distance between the positions the
/// runs' `poses.csv` log (each coordinate to 0.1 mm): at most 0.05 mm for
/// the written distance and 0.14 mm for the logged positions, metres.
const POSES_SLACK_M: f64 = 2.5e-4;

/// The `poses.csv` columns whose logged values decide whether a car's rows
/// differ between the runs (`output::poses::logged_pose`); x and y first.
const POSE_COLUMNS: [&str; 7] = ["x", "y", "z", "roll", "pitch", "yaw", "speed"];

/// Checks the pair folder `pair`, read as `(group, split, index)` of its
/// sweep, and returns its summary. Errors name the file and what differs.
pub fn check_pair(pair: &Path, key: (&str, &str, u64)) -> Result<PairSummary, String> {
    let read = |name: &str| {
        let path = pair.join(name);
        // A regular file only (a pipe hung the reader), JSON records of a
        // record's size.
        let read = if name.ends_with(".json") { crate::input::read_record } else { crate::input::read_data };
        read(&path).map_err(|e| format!("{}: cannot read it: {e}", path.display()))
    };
    check_pair_files(&read, pair, key)
}

/// [`check_pair`] of a packed pair, its files as its pack holds them
/// (`members`), named as within `pair` (`<pack>: <group>/<split>/<index>`).
pub fn check_packed_pair(
    members: &crate::output::packs::PairMembers,
    pair: &Path,
    key: (&str, &str, u64),
) -> Result<PairSummary, String> {
    use crate::output::packs::PAIR_RUNS;
    let read = |name: &str| {
        let (held, file) = match name.split_once('/') {
            Some((run, file)) => (PAIR_RUNS.iter().position(|r| *r == run).map(|r| &members.runs[r]), file),
            None => (Some(&members.pair), name),
        };
        let missing = || format!("{}: missing", pair.join(name).display());
        held.and_then(|m| m.get(file)).cloned().ok_or_else(missing)
    };
    check_pair_files(&read, pair, key)
}

/// [`check_pair`] of a pair's files as `read` gives them by their name in
/// the pair (`summary.json`, `factual/scenario.json`, ...: a packed pair's
/// members); errors name them under the folder `pair`.
pub fn check_pair_files(
    read: &dyn Fn(&str) -> Result<Vec<u8>, String>,
    pair: &Path,
    (group, split, index): (&str, &str, u64),
) -> Result<PairSummary, String> {
    let read_json = |name: &str| -> Result<serde_json::Value, String> {
        serde_json::from_slice(&read(name)?).map_err(|e| format!("{}: not JSON: {e}", pair.join(name).display()))
    };
    let mut runs = Vec::new();
    for run in ["factual", "counterfactual"] {
        let path = pair.join(run).join("scenario.json");
        let record = read_json(&format!("{run}/scenario.json"))?;
        let found = (record["group"].as_str(), record["split"].as_str(), record["index"].as_u64());
        if found != (Some(group), Some(split), Some(index)) {
            return Err(format!(
                "{}: it is a run of {}/{} index {}, not of {group}/{split} index {index} where it was read: a linked, \
                 copied or renamed run",
                path.display(),
                record["group"],
                record["split"],
                record["index"]
            ));
        }
        runs.push((path, record));
    }
    let size = |record: &serde_json::Value| {
        let names: Vec<String> = record["cars"]
            .as_array()
            .map(|cars| cars.iter().map(|c| c["name"].as_str().unwrap_or_default().to_string()).collect())
            .unwrap_or_default();
        (record["frames"].as_u64().unwrap_or(0) as usize, names)
    };
    let ((frames, names), (cf_frames, cf_names)) = (size(&runs[0].1), size(&runs[1].1));
    if (frames, names.len()) != (cf_frames, cf_names.len()) {
        return Err(format!(
            "{}: {cf_frames} frames of {} cars, and the factual run has {frames} frames of {} cars: a run of \
             another pair",
            runs[1].0.display(),
            cf_names.len(),
            names.len()
        ));
    }
    let path = pair.join("summary.json");
    let summary: PairSummary = serde_json::from_slice(&read("summary.json")?)
        .map_err(|e| format!("{}: not a counterfactual pair's summary: {e}", path.display()))?;
    let bad = |what: String| Err(format!("{}: {what}", path.display()));
    // The pair's folder name (a packed pair is read from a temporary folder).
    let folder = format!("{index:05}");
    if summary.scenario != folder {
        return bad(format!(
            "scenario {:?}, but it was read as pair {folder:?}: another pair's summary",
            summary.scenario
        ));
    }
    if summary.cars.len() != names.len() {
        return bad(format!("names {} cars, and its runs have {}", summary.cars.len(), names.len()));
    }
    for (i, car) in summary.cars.iter().enumerate() {
        if car.id as usize != i || car.name != names[i] {
            return bad(format!(
                "cars[{i}] is car {} {:?}, and the runs' car {i} is {:?}: cars in id order, as the runs name them",
                car.id, car.name, names[i]
            ));
        }
        if !(car.max_divergence_m.is_finite() && car.max_divergence_m >= 0.0) {
            return bad(format!("cars[{i}].max_divergence_m {} is not a distance, 0 or more", car.max_divergence_m));
        }
    }
    // The cars it says were affected are those it flags, in car order, and
    // a car is flagged when it diverged at some frame (an edited list, or
    // flag, changed the sweep's count of pairs with an effect).
    for (i, car) in summary.cars.iter().enumerate() {
        if car.affected != car.first_divergent_frame.is_some() {
            return bad(format!(
                "cars[{i}] is flagged affected {} with first_divergent_frame {:?}: a car is affected when it \
                 diverged",
                car.affected, car.first_divergent_frame
            ));
        }
    }
    let flagged: Vec<&str> = summary.cars.iter().filter(|c| c.affected).map(|c| c.name.as_str()).collect();
    if !summary.affected.iter().map(String::as_str).eq(flagged.iter().copied()) {
        return bad(format!(
            "affected lists {:?}, and the cars it flags affected are {flagged:?}: the same cars, in car order",
            summary.affected
        ));
    }
    if let Some(record) = &summary.intervention {
        let interval = runs[0].1["frame_interval"].as_f64().unwrap_or(0.0);
        if let Some(t) = summary.intervention_time_s.filter(|&t| !record.fired_at(t, interval)) {
            return bad(format!(
                "intervention_time_s {t}, and its intervention fires at {} s (frame {}): the same moment",
                record.at_s, record.frame
            ));
        }
        let car = record.car as usize;
        if car >= names.len() || record.frame as usize >= frames {
            return bad(format!(
                "intervention on car {} at frame {}, and its runs have {} cars and {frames} frames",
                record.car,
                record.frame,
                names.len()
            ));
        }
        if record.car_name != names[car] {
            return bad(format!(
                "intervention car {car} is named {:?}, and the runs' car {car} is {:?}",
                record.car_name, names[car]
            ));
        }
    }
    let first = summary.intervention.as_ref().map(|r| r.frame as usize);
    // What the runs' poses say (checksummed, unlike the two files below).
    let cars = names.len();
    let factual = read_poses(&read("factual/poses.csv")?, &pair.join("factual/poses.csv"), frames, cars)?;
    let counterfactual =
        read_poses(&read("counterfactual/poses.csv")?, &pair.join("counterfactual/poses.csv"), frames, cars)?;
    // A summary without the intervention record is from before summaries
    // recorded it, when a car's first divergent frame compared
    // full-precision states: it may come before the rows differ, or with
    // none differing (a difference below the logged precision), never
    // after. (Its distances, from which evaluate takes the affected truth,
    // hold as today's.)
    let dated = summary.intervention.is_none();
    for (i, car) in summary.cars.iter().enumerate() {
        let differs = (0..frames).find(|&f| factual[f * cars + i] != counterfactual[f * cars + i]);
        let agrees = match (car.first_divergent_frame, differs) {
            (Some(said), Some(found)) => said == found || (dated && said < found),
            (Some(_), None) => dated,
            (None, found) => found.is_none(),
        };
        if !agrees {
            return bad(format!(
                "cars[{i}].first_divergent_frame is {}, and the runs' poses.csv first differ for car {i} at {}: \
                 the summary is another pair's or edited",
                frame_or_none(car.first_divergent_frame),
                frame_or_none(differs)
            ));
        }
    }
    let apart: Vec<f64> = factual
        .iter()
        .zip(&counterfactual)
        .map(|(a, b)| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt())
        .collect();
    check_divergence(&read("divergence.csv")?, &pair.join("divergence.csv"), &summary, frames, first, &apart)?;
    Ok(summary)
}

fn frame_or_none(frame: Option<usize>) -> String {
    frame.map_or_else(|| "no frame".to_string(), |f| format!("frame {f}"))
}

/// A run's `poses.csv`: each row's logged pose ([`POSE_COLUMNS`]), a row
/// per frame and car in order, `frames` x `cars` rows.
fn read_poses(data: &[u8], path: &Path, frames: usize, cars: usize) -> Result<Vec<[f64; 7]>, String> {
    let mut reader = csv::Reader::from_reader(data);
    let header = reader.headers().map_err(|e| format!("{}: {e}", path.display()))?.clone();
    let column = |name: &str| header.iter().position(|h| h == name);
    let wanted: Vec<Option<usize>> = ["frame", "car"].iter().chain(&POSE_COLUMNS).map(|name| column(name)).collect();
    let Some(wanted) = wanted.into_iter().collect::<Option<Vec<usize>>>() else {
        return Err(format!(
            "{}: line 1: expected a header with frame, car, {}",
            path.display(),
            POSE_COLUMNS.join(", ")
        ));
    };
    let mut poses = Vec::with_capacity(frames * cars);
    for (n, row) in reader.records().enumerate() {
        let row = row.map_err(|e| format!("{}: {e}", path.display()))?;
        if n == frames * cars {
            return Err(format!("{}: more than {frames} frames x {cars} cars rows", path.display()));
        }
        let (frame, car) = (n / cars.max(1), n % cars.max(1));
        let value = |k: usize| row.get(wanted[k]).and_then(|v| v.parse::<f64>().ok()).filter(|v| v.is_finite());
        let pose: Option<Vec<f64>> = (2..wanted.len()).map(value).collect();
        let place = (value(0), value(1)) == (Some(frame as f64), Some(car as f64));
        match pose.filter(|_| place) {
            Some(pose) => poses.push(std::array::from_fn(|k| pose[k])),
            None => {
                return Err(format!(
                    "{}: line {}: {:?}: expected frame {frame}, car {car} and a pose of numbers",
                    path.display(),
                    n + 2,
                    row.iter().collect::<Vec<_>>().join(",")
                ))
            }
        }
    }
    if poses.len() != frames * cars {
        return Err(format!("{}: {} rows, expected {frames} frames x {cars} cars", path.display(), poses.len()));
    }
    Ok(poses)
}

/// divergence.csv: a row per frame and car in order, each distance 0 or
/// more, none before `first` (the intervention's frame), each the distance
/// between the runs' logged positions (`apart`, in the same order), and each
/// car's largest the summary's `max_divergence_m`.
fn check_divergence(
    data: &[u8],
    path: &Path,
    summary: &PairSummary,
    frames: usize,
    first: Option<usize>,
    apart: &[f64],
) -> Result<(), String> {
    let mut reader = csv::Reader::from_reader(data);
    let header = reader.headers().map_err(|e| format!("{}: {e}", path.display()))?;
    let columns = ["frame", "t", "car", "distance_m", "distance_px"];
    if header.iter().ne(columns) {
        return Err(format!("{}: line 1: expected the header {:?}", path.display(), columns.join(",")));
    }
    let cars = summary.cars.len();
    let mut largest = vec![0.0f64; cars];
    let mut rows = 0usize;
    for (n, row) in reader.records().enumerate() {
        let line = n + 2;
        let row = row.map_err(|e| format!("{}: {e}", path.display()))?;
        let (frame, car) = (n / cars.max(1), n % cars.max(1));
        let whole = |k: usize| row.get(k).and_then(|v| v.parse::<usize>().ok());
        let distance = row.get(3).and_then(|v| v.parse::<f64>().ok()).filter(|d| d.is_finite() && *d >= 0.0);
        let Some(distance) = distance.filter(|_| whole(0) == Some(frame) && whole(2) == Some(car) && n < frames * cars)
        else {
            return Err(format!(
                "{}: line {line}: {:?}: expected frame {frame}, car {car} and a distance in metres, 0 or more",
                path.display(),
                row.iter().collect::<Vec<_>>().join(",")
            ));
        };
        if first.is_some_and(|f| frame < f) && distance > 0.0 {
            return Err(format!(
                "{}: line {line}: car {car} diverges at frame {frame}, before the intervention's frame {}: the runs \
                 are identical until it (another pair's file, or an edited frame)",
                path.display(),
                first.unwrap_or(0)
            ));
        }
        if apart.get(n).is_some_and(|&logged| (distance - logged).abs() > POSES_SLACK_M) {
            return Err(format!(
                "{}: line {line}: car {car} is {distance} m from its factual position at frame {frame}, and the \
                 runs' poses.csv put it {:.4} m apart: the file is another pair's or edited",
                path.display(),
                apart[n]
            ));
        }
        largest[car] = largest[car].max(distance);
        rows += 1;
    }
    if rows != frames * cars {
        return Err(format!("{}: {rows} rows, expected {frames} frames x {cars} cars", path.display()));
    }
    for (car, (&found, summarised)) in largest.iter().zip(&summary.cars).enumerate() {
        let summarised = summarised.max_divergence_m;
        if (found - summarised).abs() > DIVERGENCE_SLACK_M + 1e-9 * summarised {
            return Err(format!(
                "{}: car {car}'s largest divergence is {found} m, and summary.json's max_divergence_m {summarised}: \
                 one of them is another pair's or edited",
                path.display()
            ));
        }
    }
    Ok(())
}
