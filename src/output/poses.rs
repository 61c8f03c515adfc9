//! `poses.csv`: one row per frame and car, sorted by frame then car id.
//! Columns are documented in `data-schema/poses.columns.json`.

use super::number::logged_value;
use super::rows::Rows;
use crate::camera::Camera;
use crate::world::Trajectories;
use std::io::Write;

/// The column names, in order.
pub const POSE_COLUMNS: [&str; 13] =
    ["frame", "t", "car", "x", "y", "z", "roll", "pitch", "yaw", "px", "py", "speed", "in_view"];

/// Largest magnitude of a position (metres) or pixel that readers take from
/// a pose log or `pixels.npy`: far beyond any map or bird's-eye camera
/// causalcity writes (a removed car is parked 10 km off the map, 128,000 px
/// in the default view), and far below where sums of them overflow (a
/// speed of 1e308 made `stats`' mean speed infinite).
pub const MAX_POSE_MAGNITUDE: f64 = 1e9;

/// Decimals of px and py in the log.
pub const PIXEL_DECIMALS: u32 = 3;

/// The binary copy of poses.csv's px, py: float32 [frames, cars, 2], cars in
/// id order, the logged values exactly (loaders and exports read it without
/// parsing text).
pub const PIXELS_FILE: &str = "pixels.npy";

/// Writes `pixels.npy` for `trajectories`: npyz writes the header, the
/// float32 values follow as little-endian bytes in one piece (npyz's own
/// element writer costs about 300 instructions a value).
pub fn write_pixels<W: Write>(mut out: W, trajectories: &Trajectories, camera: &Camera) -> std::io::Result<()> {
    use npyz::WriterBuilder;
    let cars = trajectories.states.first().map_or(0, Vec::len);
    let shape = [trajectories.states.len() as u64, cars as u64, 2];
    npyz::WriteOptions::<f32>::new().default_dtype().shape(&shape).writer(&mut out).write_header_only()?;
    let mut data = Vec::with_capacity(trajectories.states.len() * cars * 8);
    for states in &trajectories.states {
        for state in states {
            let pixel = camera.to_pixel(state.position);
            data.extend_from_slice(&(logged_value(pixel.x, PIXEL_DECIMALS) as f32).to_le_bytes());
            data.extend_from_slice(&(logged_value(pixel.y, PIXEL_DECIMALS) as f32).to_le_bytes());
        }
    }
    out.write_all(&data)?;
    out.flush()
}

/// Reads a `pixels.npy` of `frames` x `cars`: row-major (px, py) pairs.
pub fn read_pixels(path: &std::path::Path, frames: usize, cars: usize) -> Result<Vec<f32>, String> {
    let bytes = crate::input::read_data(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    parse_pixels(&bytes, path, frames, cars)
}

/// [`read_pixels`] of the file's bytes (errors name `path`).
pub fn parse_pixels(bytes: &[u8], path: &std::path::Path, frames: usize, cars: usize) -> Result<Vec<f32>, String> {
    let fail = |e: &dyn std::fmt::Display| format!("{}: {e}", path.display());
    let npy = npyz::NpyFile::new(bytes).map_err(|e| fail(&e))?;
    let expected = [frames as u64, cars as u64, 2];
    if npy.shape() != expected || npy.dtype().descr() != "'<f4'" {
        return Err(fail(&format!(
            "shape {:?} dtype {}, expected {expected:?} float32",
            npy.shape(),
            npy.dtype().descr()
        )));
    }
    let values = npy.into_vec::<f32>().map_err(|e| fail(&e))?;
    // The limit poses.csv's px, py are read with: an export reads only
    // this file.
    if let Some(i) = values.iter().position(|v| !v.is_finite() || v.abs() as f64 > MAX_POSE_MAGNITUDE) {
        let at = [i / (2 * cars.max(1)), i / 2 % cars.max(1), i % 2];
        return Err(fail(&format!("holds {} at {at:?}: every pixel must be a finite number within +-1e9", values[i])));
    }
    Ok(values)
}

/// Writes the pose log of `trajectories` for cars with the given ids.
pub fn write_poses<W: Write>(
    out: W,
    car_ids: &[u32],
    trajectories: &Trajectories,
    camera: &Camera,
) -> std::io::Result<()> {
    let mut rows = Rows::new(out, &POSE_COLUMNS)?;
    for (frame, states) in trajectories.states.iter().enumerate() {
        let t = frame as f64 * trajectories.frame_interval;
        for (state, &car) in states.iter().zip(car_ids) {
            let pixel = camera.to_pixel(state.position);
            rows.int(frame as u64)
                .fixed(t, 6)
                .int(car as u64)
                .fixed(state.position.x, 4)
                .fixed(state.position.y, 4)
                .fixed(state.z, 4)
                .fixed(state.roll, 6)
                .fixed(state.pitch, 6)
                .fixed(state.yaw, 6)
                .fixed(pixel.x, PIXEL_DECIMALS)
                .fixed(pixel.y, PIXEL_DECIMALS)
                .fixed(state.speed, 4)
                .int(camera.contains_pixel(pixel) as u64);
            rows.end()?;
        }
    }
    rows.finish()?;
    Ok(())
}

/// A car state as poses.csv writes it (x, y, z, roll, pitch, yaw, speed,
/// each rounded to its column's decimals): two states whose logged poses
/// are equal write the same row.
pub fn logged_pose(state: &crate::world::CarState) -> [f64; 7] {
    [
        logged_value(state.position.x, 4),
        logged_value(state.position.y, 4),
        logged_value(state.z, 4),
        logged_value(state.roll, 6),
        logged_value(state.pitch, 6),
        logged_value(state.yaw, 6),
        logged_value(state.speed, 4),
    ]
}
