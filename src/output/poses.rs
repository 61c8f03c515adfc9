//! `poses.csv`: one row per frame and car, sorted by frame then car id.
//! Columns are documented in `data-schema/poses.columns.json`.

use crate::render::camera::Camera;
use crate::world::Trajectories;
use serde::Serialize;
use std::io::Write;

/// The column names, in order.
pub const POSE_COLUMNS: [&str; 13] =
    ["frame", "t", "car", "x", "y", "z", "roll", "pitch", "yaw", "px", "py", "speed", "in_view"];

#[derive(Serialize)]
struct PoseRow {
    frame: u32,
    t: f64,
    car: u32,
    x: f64,
    y: f64,
    z: f64,
    roll: f64,
    pitch: f64,
    yaw: f64,
    px: f64,
    py: f64,
    speed: f64,
    in_view: u8,
}

fn round(x: f64, decimals: i32) -> f64 {
    let f = 10f64.powi(decimals);
    let r = (x * f).round() / f;
    // Avoid "-0.0" in the file.
    if r == 0.0 {
        0.0
    } else {
        r
    }
}

/// Writes the pose log of `trajectories` for cars with the given ids.
pub fn write_poses<W: Write>(out: W, car_ids: &[u32], trajectories: &Trajectories, camera: &Camera) -> csv::Result<()> {
    let mut writer = csv::WriterBuilder::new().has_headers(true).from_writer(out);
    for (frame, states) in trajectories.states.iter().enumerate() {
        let t = round(frame as f64 * trajectories.frame_interval, 6);
        for (state, &car) in states.iter().zip(car_ids) {
            let pixel = camera.to_pixel(state.position);
            writer.serialize(PoseRow {
                frame: frame as u32,
                t,
                car,
                x: round(state.position.x, 4),
                y: round(state.position.y, 4),
                z: round(state.z, 4),
                roll: round(state.roll, 6),
                pitch: round(state.pitch, 6),
                yaw: round(state.yaw, 6),
                px: round(pixel.x, 3),
                py: round(pixel.y, 3),
                speed: round(state.speed, 4),
                in_view: camera.contains_pixel(pixel) as u8,
            })?;
        }
    }
    writer.flush()?;
    Ok(())
}
