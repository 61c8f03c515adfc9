//! The lights are a confounder a vision method can see, or not: signal heads
//! show their logged colour at their logged pixel in every frame (bird's-eye
//! view and extra cameras) when visible, nowhere when hidden, and never enter
//! the masks; cars show brake lights while they slow down or stand.

mod common;

use common::*;
use std::path::{Path, PathBuf};

/// What a lamp colour a pixel shows, by hue (robust to night and fog veils);
/// `None` for anything else (pavement, housing, asphalt).
fn lamp(rgb: &[u8]) -> Option<&'static str> {
    let (r, g, b) = (rgb[0] as i32, rgb[1] as i32, rgb[2] as i32);
    if r > g + 80 && r > b + 80 {
        Some("red")
    } else if r > 120 && g > 100 && b < r.min(g) - 60 {
        Some("yellow")
    } else if g > r + 60 && g > b + 40 {
        Some("green")
    } else {
        None
    }
}

const FRAMES: u32 = 30;

/// A city dataset of 8-car scenarios at noon, dusk and night, with and
/// without fog (no rain or snow, whose streaks would cross the lamps), and
/// an extra camera over the same ground turned half a turn.
fn generate(dir: &Path, heads: &str) -> PathBuf {
    let city = format!(
        r#"{{"signal_heads": "{heads}", "confounders": {{"hour": {{"choice": [12, 19, 23]}}, "fog": {{"choice": [0, 0.5]}}}}}}"#
    );
    let spec = city_spec(&format!("heads-{heads}"), &[(8, 0.5)], (3, 0, 0), FRAMES, &city).replacen(
        "\"city\":",
        r#""cameras": [{"name": "turned", "static": {"centre": [0, 0], "rotation_deg": 180}}], "city":"#,
        1,
    );
    let spec = write_spec(dir, &spec);
    let out = dir.join(heads);
    gen_ok(&spec, &out, &["--quiet"]);
    out
}

fn rgb(path: PathBuf) -> image::RgbImage {
    image::open(path).unwrap().to_rgb8()
}

#[test]
fn signal_heads_show_their_logged_colour_when_visible_and_never_in_the_masks() {
    let dir = fresh_dir("signal-heads");
    let (visible, hidden) = (generate(&dir, "visible"), generate(&dir, "hidden"));
    let (mut shown, mut turned_shown, mut looked_hidden) = (0, 0, 0);
    let mut colours = std::collections::BTreeSet::new();
    for scenario in scenario_dirs(&visible) {
        let twin = hidden.join(scenario.strip_prefix(&visible).unwrap());
        let scenario_json = read_json(&scenario.join("scenario.json"));
        assert_eq!(scenario_json["city"]["signal_heads"], "visible");
        let ppm = scenario_json["camera"]["pixels_per_metre"].as_f64().unwrap();
        let rows = light_rows(&scenario);
        // Every light has a head in the bird's-eye view.
        let head = |r: &LightRow| (r.head_px.unwrap(), r.head_py.unwrap());
        assert_eq!(rows.len() as u32, 32 * FRAMES);
        for frame in 0..FRAMES {
            let name = format!("{frame:04}.png");
            let (image, hidden_image) = (rgb(scenario.join("rgb").join(&name)), rgb(twin.join("rgb").join(&name)));
            let turned = rgb(scenario.join("cameras/turned/rgb").join(&name));
            let (w, h) = image.dimensions();
            let mask = std::fs::read(scenario.join("mask").join(&name)).unwrap();
            // Masks never show the heads: the same bytes with or without them.
            assert_eq!(mask, std::fs::read(twin.join("mask").join(&name)).unwrap(), "{name}");
            let heads: Vec<&LightRow> = rows.iter().filter(|r| r.frame == frame).collect();
            for row in &heads {
                let (x, y) = head(row);
                let (x, y) = (x.round(), y.round());
                if x < 1.0 || y < 1.0 || x > (w - 2) as f64 || y > (h - 2) as f64 {
                    continue;
                }
                let (x, y) = (x as u32, y as u32);
                assert_eq!(lamp(&image.get_pixel(x, y).0), Some(row.colour.as_str()), "{name} {row:?}");
                assert_eq!(lamp(&hidden_image.get_pixel(x, y).0), None, "hidden run shows a lamp: {name} {row:?}");
                // The turned camera sees the same head at the opposite pixel.
                assert_eq!(lamp(&turned.get_pixel(w - 1 - x, h - 1 - y).0), Some(row.colour.as_str()), "turned {name}");
                colours.insert(row.colour.clone());
                (shown, turned_shown, looked_hidden) = (shown + 1, turned_shown + 1, looked_hidden + 1);
            }
            // The two runs differ only around the heads (same cars, brake lights and weather).
            let reach = 0.5 * 0.9 * std::f64::consts::SQRT_2 * ppm + 2.0;
            for (x, y, p) in image.enumerate_pixels() {
                if p != hidden_image.get_pixel(x, y) {
                    let near = heads.iter().any(|r| (head(r).0 - x as f64).hypot(head(r).1 - y as f64) <= reach);
                    assert!(near, "{name}: pixel ({x}, {y}) changed away from every head");
                }
            }
        }
    }
    assert!(shown > 1000 && turned_shown == shown && looked_hidden == shown, "{shown} head-frames checked");
    assert_eq!(colours.len(), 3, "only {colours:?} seen");
}

#[test]
fn cars_show_brake_lights_while_they_slow_down_or_stand() {
    let dir = fresh_dir("brake-lights");
    let out = generate(&dir, "hidden");
    let (mut on, mut off) = (0, 0);
    for scenario in scenario_dirs(&out) {
        let s = read_scenario(&scenario);
        let ppm = s.camera.pixels_per_metre;
        let tracks = poses_by_car(&read_poses(&scenario.join("poses.csv")));
        for car in &s.cars {
            // A red car's body would pass for a brake light.
            let body = u32::from_str_radix(&car.colour[1..], 16).unwrap().to_be_bytes();
            if lamp(&body[1..]).is_some() {
                continue;
            }
            let track = &tracks[&car.id];
            for pair in track.windows(2) {
                let (before, now) = (&pair[0], &pair[1]);
                let slowing = before.speed - now.speed;
                let expect = if slowing > 1.5 * 0.2 * s.frame_interval || now.speed < 0.03 {
                    true
                } else if slowing <= 0.0 && now.speed > 0.1 {
                    false
                } else {
                    continue; // near the threshold
                };
                // The centre of the left brake light: 6 % of the length in
                // from the rear, 62.5 % of the half width to the left.
                let (c, si) = (now.yaw.cos(), now.yaw.sin());
                let (back, left) = (-(0.5 - 0.06) * car.length_m, 0.625 * 0.5 * car.width_m);
                let (dx, dy) = (back * c - left * si, back * si + left * c);
                let (x, y) = ((now.px + dx * ppm).round(), (now.py - dy * ppm).round());
                if now.in_view == 0 || x < 0.0 || y < 0.0 || x >= 1023.0 || y >= 639.0 {
                    continue;
                }
                let image = rgb(scenario.join("rgb").join(format!("{:04}.png", now.frame)));
                let lit = lamp(&image.get_pixel(x as u32, y as u32).0) == Some("red");
                assert_eq!(lit, expect, "car {} frame {}: speed {} -> {}", car.id, now.frame, before.speed, now.speed);
                if expect {
                    on += 1;
                } else {
                    off += 1;
                }
            }
        }
    }
    assert!(on > 50 && off > 50, "{on} frames with brake lights checked, {off} without");
}
