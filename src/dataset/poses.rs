//! One rule for reading `poses.csv` back, shared by every reader (`stats`,
//! `baseline`, `heatmap`, the exports, `validate` and the Python package):
//! the header as `gen` writes it, each (frame, car) once and every one
//! present, and each value within `data-schema/poses.schema.json` (finite;
//! `t` and `speed` 0 or more; `yaw` within +-pi; `in_view` 0 or 1; one `t`
//! per frame). Errors name the file, the line, the column and the value.

use crate::output::poses::{MAX_POSE_MAGNITUDE, POSE_COLUMNS};
use std::path::Path;

/// Largest |yaw| in the log: pi as its 6 decimals write it (3.141593).
const MAX_YAW: f64 = std::f64::consts::PI + 5e-7;

/// One row of `poses.csv`, checked.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseRow {
    pub frame: usize,
    /// Seconds from the start.
    pub t: f64,
    pub car: usize,
    /// x, y, z, metres.
    pub position: [f64; 3],
    /// roll, pitch, yaw, radians.
    pub rotation: [f64; 3],
    /// px, py in the bird's-eye frame.
    pub pixel: [f64; 2],
    /// Metres per second.
    pub speed: f64,
    pub in_view: bool,
}

/// Reads every row of the pose log `reader` (from the file `path`) of a
/// scenario of `frames` x `cars`, handing each to `each` in file order.
pub fn read_pose_rows<R: std::io::Read>(
    reader: R,
    path: &Path,
    frames: usize,
    cars: usize,
    mut each: impl FnMut(&PoseRow),
) -> Result<(), String> {
    let mut reader = csv::Reader::from_reader(reader);
    let header = reader.byte_headers().map_err(|e| format!("{}: {e}", path.display()))?;
    if header.iter().ne(POSE_COLUMNS.iter().map(|c| c.as_bytes())) {
        let found: Vec<String> = header.iter().map(|c| String::from_utf8_lossy(c).into_owned()).collect();
        return Err(format!("{}: columns {found:?}, expected {POSE_COLUMNS:?}", path.display()));
    }
    let mut filled = vec![false; frames * cars];
    let mut times: Vec<Option<f64>> = vec![None; frames];
    let mut record = csv::ByteRecord::new();
    let mut line = 1usize;
    while reader.read_byte_record(&mut record).map_err(|e| format!("{}: {e}", path.display()))? {
        line += 1;
        let row = parse_row(&record, path, line)?;
        let at = |what: String| format!("{} line {line}: {what}", path.display());
        if row.frame >= frames || row.car >= cars {
            return Err(at(format!(
                "frame {}, car {} is outside the scenario's {frames} frames x {cars} cars (its scenario.json)",
                row.frame, row.car
            )));
        }
        let slot = &mut filled[row.frame * cars + row.car];
        if std::mem::replace(slot, true) {
            return Err(at(format!("frame {}, car {} is given twice", row.frame, row.car)));
        }
        match times[row.frame] {
            Some(t) if t != row.t => {
                return Err(at(format!("t {} differs from frame {}'s t {t} in an earlier row", row.t, row.frame)))
            }
            Some(_) => {}
            None => times[row.frame] = Some(row.t),
        }
        each(&row);
    }
    if let Some(missing) = filled.iter().position(|f| !f) {
        return Err(format!(
            "{}: no pose for frame {} car {} ({frames} frames x {cars} cars expected)",
            path.display(),
            missing / cars,
            missing % cars
        ));
    }
    Ok(())
}

/// One record's values, each checked against the schema.
fn parse_row(record: &csv::ByteRecord, path: &Path, line: usize) -> Result<PoseRow, String> {
    let text = |k: usize| record.get(k).map(String::from_utf8_lossy).unwrap_or_default();
    let bad = |k: usize, allowed: &str| {
        format!("{} line {line}: {} {:?} is not allowed: {allowed}", path.display(), POSE_COLUMNS[k], text(k))
    };
    if record.len() != POSE_COLUMNS.len() {
        return Err(format!(
            "{} line {line}: {} fields, expected {} ({})",
            path.display(),
            record.len(),
            POSE_COLUMNS.len(),
            POSE_COLUMNS.join(",")
        ));
    }
    let whole = |k: usize| text(k).parse::<usize>().map_err(|_| bad(k, "a whole number, 0 or more"));
    let number = |k: usize, allowed: &str, ok: &dyn Fn(f64) -> bool| {
        text(k).parse::<f64>().ok().filter(|v| v.is_finite() && ok(*v)).ok_or_else(|| bad(k, allowed))
    };
    let within = |v: f64| v.abs() <= MAX_POSE_MAGNITUDE;
    let place = "a finite number within +-1e9";
    let angle = "radians from -3.141593 to 3.141593";
    Ok(PoseRow {
        frame: whole(0)?,
        t: number(1, "seconds, 0 or more (at most 1e9)", &|v| (0.0..=MAX_POSE_MAGNITUDE).contains(&v))?,
        car: whole(2)?,
        position: [number(3, place, &within)?, number(4, place, &within)?, number(5, place, &within)?],
        rotation: [
            number(6, angle, &|v| v.abs() <= MAX_YAW)?,
            number(7, angle, &|v| v.abs() <= MAX_YAW)?,
            number(8, angle, &|v| v.abs() <= MAX_YAW)?,
        ],
        pixel: [number(9, place, &within)?, number(10, place, &within)?],
        speed: number(11, "metres per second, 0 or more (at most 1e9)", &|v| (0.0..=MAX_POSE_MAGNITUDE).contains(&v))?,
        in_view: match &*text(12) {
            "1" => true,
            "0" => false,
            _ => return Err(bad(12, "0 or 1")),
        },
    })
}
