//! Rendering, checked on the decoded PNGs: sizes, the ids in the masks,
//! pixel-exact car footprints and mask centroids against the logged pixels.

mod common;
use common::*;
use std::collections::BTreeSet;

/// Pixel-space footprint of a car: centre, unit axes and half extents.
struct Footprint {
    centre: (f64, f64),
    forward: (f64, f64),
    half: (f64, f64),
}

impl Footprint {
    fn new(p: &Pose, car: &Car, ppm: f64) -> Footprint {
        // Image y points down, so the heading flips sign.
        Footprint {
            centre: (p.px, p.py),
            forward: (p.yaw.cos(), -p.yaw.sin()),
            half: (car.length_m * ppm / 2.0, car.width_m * ppm / 2.0),
        }
    }

    /// Signed distance-ish margin of a point inside the box (positive inside).
    fn inside_margin(&self, x: f64, y: f64) -> f64 {
        let (dx, dy) = (x - self.centre.0, y - self.centre.1);
        let along = dx * self.forward.0 + dy * self.forward.1;
        let across = -dx * self.forward.1 + dy * self.forward.0;
        (self.half.0 - along.abs()).min(self.half.1 - across.abs())
    }

    fn radius(&self) -> f64 {
        (self.half.0.powi(2) + self.half.1.powi(2)).sqrt()
    }

    fn within_image(&self, w: f64, h: f64) -> bool {
        let r = self.radius() + 1.0;
        self.centre.0 - r >= 0.0
            && self.centre.1 - r >= 0.0
            && self.centre.0 + r <= w - 1.0
            && self.centre.1 + r <= h - 1.0
    }

    fn outside_image(&self, w: f64, h: f64) -> bool {
        let r = self.radius() + 1.0;
        self.centre.0 + r < 0.0 || self.centre.1 + r < 0.0 || self.centre.0 - r > w || self.centre.1 - r > h
    }

    fn may_touch(&self, other: &Footprint) -> bool {
        let d = ((self.centre.0 - other.centre.0).powi(2) + (self.centre.1 - other.centre.1).powi(2)).sqrt();
        d < self.radius() + other.radius() + 2.0
    }
}

fn hex(colour: &str) -> [u8; 3] {
    let v = u32::from_str_radix(&colour[1..], 16).unwrap();
    [(v >> 16) as u8, (v >> 8) as u8, v as u8]
}

#[test]
fn frames_and_masks_decode_and_match_the_pose_log() {
    let out = shared_image_dataset();
    let mut centroids_checked = 0;
    for d in scenario_dirs(&out) {
        let s = read_scenario(&d);
        let (w, h) = (s.camera.width, s.camera.height);
        assert_eq!((w, h), (1024, 640));
        let ppm = s.camera.pixels_per_metre;
        let poses = read_poses(&d.join("poses.csv"));
        let mask_ids: BTreeSet<u8> = s.cars.iter().map(|c| c.mask_id).collect();
        assert_eq!(sorted_entries(&d.join("rgb")).len(), s.frames as usize);
        assert_eq!(sorted_entries(&d.join("mask")).len(), s.frames as usize);
        for frame in (0..s.frames).step_by(10) {
            let rgb = image::open(d.join(format!("rgb/{frame:04}.png"))).unwrap();
            assert!(matches!(rgb, image::DynamicImage::ImageRgb8(_)), "RGB frames are 8-bit RGB");
            let rgb = rgb.into_rgb8();
            let mask = image::open(d.join(format!("mask/{frame:04}.png"))).unwrap();
            assert!(matches!(mask, image::DynamicImage::ImageLuma8(_)), "masks are 8-bit grey");
            let mask = mask.into_luma8();
            assert_eq!(rgb.dimensions(), (w, h));
            assert_eq!(mask.dimensions(), (w, h));

            let present: BTreeSet<u8> = mask.pixels().map(|p| p.0[0]).filter(|&v| v != 0).collect();
            assert!(present.is_subset(&mask_ids), "unknown ids {present:?} in {}", d.display());
            let frame_poses: Vec<&Pose> = poses.iter().filter(|p| p.frame == frame).collect();
            let prints: Vec<Footprint> =
                frame_poses.iter().map(|p| Footprint::new(p, &s.cars[p.car as usize], ppm)).collect();
            for (i, p) in frame_poses.iter().enumerate() {
                let car = &s.cars[p.car as usize];
                let fp = &prints[i];
                if fp.outside_image(w as f64, h as f64) {
                    assert!(!present.contains(&car.mask_id), "car {} is off camera but in the mask", car.id);
                    continue;
                }
                let alone = prints.iter().enumerate().all(|(j, o)| j == i || !fp.may_touch(o));
                if !alone || !fp.within_image(w as f64, h as f64) {
                    continue;
                }
                assert!(present.contains(&car.mask_id), "car {} is on camera but not in the mask", car.id);
                // Pixel-exact footprint: pixel centres clearly inside carry the id,
                // pixels clearly outside do not (no anti-aliasing). "Clearly" is
                // 0.05 px: the rasterizer snaps edges to 1/64 px.
                let r = fp.radius().ceil() as i64 + 2;
                let (mut n, mut sx, mut sy) = (0.0, 0.0, 0.0);
                for y in (p.py.round() as i64 - r)..=(p.py.round() as i64 + r) {
                    for x in (p.px.round() as i64 - r)..=(p.px.round() as i64 + r) {
                        let v = mask.get_pixel(x as u32, y as u32).0[0];
                        let margin = fp.inside_margin(x as f64, y as f64);
                        if margin > 0.05 {
                            assert_eq!(
                                v, car.mask_id,
                                "pixel ({x},{y}) inside car {} (margin {margin}, pose {p:?}) is {v}",
                                car.id
                            );
                        } else if margin < -0.05 {
                            assert_ne!(v, car.mask_id, "pixel ({x},{y}) outside car {} carries its id", car.id);
                        }
                        if v == car.mask_id {
                            n += 1.0;
                            sx += x as f64;
                            sy += y as f64;
                        }
                    }
                }
                let (cx, cy) = (sx / n, sy / n);
                assert!(
                    ((cx - p.px).powi(2) + (cy - p.py).powi(2)).sqrt() <= 1.5,
                    "mask centroid ({cx:.2}, {cy:.2}) vs logged ({}, {})",
                    p.px,
                    p.py
                );
                let expected_area = car.length_m * car.width_m * ppm * ppm;
                assert!((n - expected_area).abs() < expected_area * 0.15, "area {n} vs {expected_area}");
                // The body colour shows at the car's centre in the RGB frame.
                let centre = rgb.get_pixel(p.px.round() as u32, p.py.round() as u32).0;
                assert_eq!(centre, hex(&car.colour), "car {} colour at its centre", car.id);
                centroids_checked += 1;
            }
        }
    }
    assert!(centroids_checked > 50, "only {centroids_checked} cars checked");
}

#[test]
fn the_background_is_the_same_in_every_frame_where_no_car_is() {
    let out = shared_image_dataset();
    let d = &scenario_dirs(&out)[0];
    let a = image::open(d.join("rgb/0000.png")).unwrap().into_rgb8();
    let b = image::open(d.join("rgb/0149.png")).unwrap().into_rgb8();
    let ma = image::open(d.join("mask/0000.png")).unwrap().into_luma8();
    let mb = image::open(d.join("mask/0149.png")).unwrap().into_luma8();
    let mut compared = 0;
    for (x, y, pa) in a.enumerate_pixels() {
        // Away from cars in either frame (2 px margin for anti-aliased edges).
        let near_car = (-2i64..=2).any(|dy| {
            (-2i64..=2).any(|dx| {
                let (xx, yy) = ((x as i64 + dx).clamp(0, 1023) as u32, (y as i64 + dy).clamp(0, 639) as u32);
                ma.get_pixel(xx, yy).0[0] != 0 || mb.get_pixel(xx, yy).0[0] != 0
            })
        });
        if !near_car {
            assert_eq!(pa, b.get_pixel(x, y), "background differs at ({x},{y})");
            compared += 1;
        }
    }
    assert!(compared > 600_000);
}

fn mean_luma(img: &image::RgbImage) -> f64 {
    img.pixels().map(|p| 0.299 * p.0[0] as f64 + 0.587 * p.0[1] as f64 + 0.114 * p.0[2] as f64).sum::<f64>()
        / (img.width() * img.height()) as f64
}

fn luma_spread(img: &image::RgbImage) -> f64 {
    let m = mean_luma(img);
    (img.pixels()
        .map(|p| (0.299 * p.0[0] as f64 + 0.587 * p.0[1] as f64 + 0.114 * p.0[2] as f64 - m).powi(2))
        .sum::<f64>()
        / (img.width() * img.height()) as f64)
        .sqrt()
}

#[test]
fn weather_changes_the_frames_but_never_the_masks() {
    let dir = fresh_dir("rendering-weather");
    let looks = [
        ("day", r#"{"hour": 12}"#),
        ("night", r#"{"hour": 23}"#),
        ("fog", r#"{"hour": 12, "fog": 1.0}"#),
        ("rain", r#"{"hour": 12, "rain": 1.0}"#),
        ("snow", r#"{"hour": 12, "snow": 1.0}"#),
    ];
    let mut frames = std::collections::BTreeMap::new();
    for (name, confounders) in looks {
        let city = format!(r#"{{"confounders": {confounders}, "red_light_runner_probability": 0}}"#);
        let spec = dir.join(format!("{name}.json"));
        std::fs::write(&spec, city_spec(name, &[(8, 0.5)], (1, 0, 0), 12, &city)).unwrap();
        let out = dir.join(name);
        gen_ok(&spec, &out, &["--quiet"]);
        let d = &scenario_dirs(&out)[0];
        let s = read_scenario(d);
        let ids: BTreeSet<u8> = s.cars.iter().map(|c| (c.id + 1) as u8).collect();
        for f in [0, 11] {
            let mask = image::open(d.join(format!("mask/{f:04}.png"))).unwrap().into_luma8();
            let values: BTreeSet<u8> = mask.pixels().map(|p| p.0[0]).filter(|&v| v != 0).collect();
            assert!(values.is_subset(&ids), "{name}: weather leaked into the mask: {values:?}");
        }
        let first = image::open(d.join("rgb/0000.png")).unwrap().into_rgb8();
        let last = image::open(d.join("rgb/0011.png")).unwrap().into_rgb8();
        // Frame 0 has every car at rest at its spawn, the same in every look.
        let mask0 = std::fs::read(d.join("mask/0000.png")).unwrap();
        frames.insert(name, (first, last, mask0));
    }
    let (day, night, fog) = (&frames["day"].0, &frames["night"].0, &frames["fog"].0);
    assert!(mean_luma(night) < 0.6 * mean_luma(day), "night should be much darker");
    assert!(luma_spread(fog) < 0.7 * luma_spread(day), "fog should wash out contrast");
    for name in ["night", "fog", "rain", "snow"] {
        assert_eq!(frames[name].2, frames["day"].2, "{name}: frame-0 mask differs from the clear day's");
    }
    // Precipitation moves: away from cars, rain and snow frames change over time.
    for name in ["rain", "snow"] {
        let (a, b, _) = &frames[name];
        let changed = a.pixels().zip(b.pixels()).filter(|(p, q)| p != q).count();
        let still = frames["day"].0.pixels().zip(frames["day"].1.pixels()).filter(|(p, q)| p != q).count();
        assert!(changed > still + 2000, "{name}: only {changed} pixels changed (clear day: {still})");
    }
}

/// Headlight beams lie on the road: at night, a car right behind another
/// lights the road between them but never a pixel of the car in front, and
/// with the dirty-rectangle pipeline a frame is the same as one drawn from
/// scratch.
#[test]
fn beams_light_the_road_never_the_car_in_front() {
    use causalcity::camera::Camera;
    use causalcity::map::CityMap;
    use causalcity::render::weather::SceneLook;
    use causalcity::render::{CarSprite, Renderer};
    use glam::DVec2;

    let map = CityMap::default();
    let renderer = Renderer::new(&map, Camera::birds_eye(1024, 640));
    let night = renderer.scene(SceneLook { daylight: 0.0, ..SceneLook::clear() });
    let car = |x: f64, id: u8| CarSprite {
        position: DVec2::new(x, 2.0),
        yaw: 0.0,
        length: 2.2,
        width: 1.1,
        colour: [200, 40, 40],
        mask_id: id,
        braking: false,
    };
    // Heading east; the rear car's front is 1 m behind the front car's back,
    // so its 3.5 m beams reach under the front car.
    let (front, rear) = (car(4.0, 1), car(0.8, 2));
    let mut alone = renderer.canvas();
    renderer.render(&mut alone, &night, &[front], &[], 0);
    let mut queued = renderer.canvas();
    renderer.render(&mut queued, &night, &[front, rear], &[], 0);
    // Inside the car, away from its anti-aliased outline (whose pixels
    // blend the road beneath, lit or not).
    let inside = |i: usize| {
        let (x, y) = ((i % 1024) as i64, (i / 1024) as i64);
        (-1..=1).all(|dy| (-1..=1).all(|dx| queued.mask[((y + dy) * 1024 + x + dx) as usize] == 1))
    };
    let mut front_pixels = 0;
    let mut lit = Vec::new();
    for (i, &id) in queued.mask.iter().enumerate() {
        if id == 1 && inside(i) {
            front_pixels += 1;
            if queued.rgb[i * 3..i * 3 + 3] != alone.rgb[i * 3..i * 3 + 3] {
                lit.push((i % 1024, i / 1024, &queued.rgb[i * 3..i * 3 + 3], &alone.rgb[i * 3..i * 3 + 3]));
            }
        }
    }
    assert!(
        lit.is_empty(),
        "{} of {front_pixels} pixels of the front car are lit: {:?}",
        lit.len(),
        &lit[..lit.len().min(8)]
    );
    assert!(front_pixels > 200, "only {front_pixels} inner pixels of the front car");
    // The road between the cars is lit in the queue and dark without the rear car.
    let gap = renderer.camera.to_pixel(DVec2::new(2.45, 2.0 + 0.3 * 1.1)); // on the left beam
    let i = gap.y.round() as usize * 1024 + gap.x.round() as usize;
    let luma = |c: &causalcity::render::FrameCanvas| c.rgb[i * 3..i * 3 + 3].iter().map(|&v| v as u32).sum::<u32>();
    assert!(luma(&queued) > luma(&alone) + 30, "the beam does not light the road between the cars");

    // Drawing the queue again over the lone car's frame (only its rectangle
    // restored) gives the frame drawn from scratch, byte for byte.
    renderer.render(&mut alone, &night, &[front, rear], &[], 1);
    let mut fresh = renderer.canvas();
    renderer.render(&mut fresh, &night, &[front, rear], &[], 1);
    assert!(alone.rgb == fresh.rgb && alone.mask == fresh.mask, "incremental frame differs from a fresh one");
}

#[test]
fn rain_snow_and_signal_heads_drawn_one_after_another_equal_frames_drawn_from_scratch() {
    use causalcity::camera::Camera;
    use causalcity::map::signals::Colour;
    use causalcity::map::CityMap;
    use causalcity::render::weather::SceneLook;
    use causalcity::render::{CarSprite, HeadSprite, Renderer};
    use glam::DVec2;

    // Only what the previous frame drew is restored: streaks and flakes of
    // one frame must be gone in the next, wherever they fell. One canvas
    // runs through every scene, as a worker's does through its scenarios:
    // clear scenes share one background, the others each have their own.
    let map = CityMap::default();
    let renderer = Renderer::new(&map, Camera::birds_eye(512, 320));
    let car = |x: f64, id: u8| CarSprite {
        position: DVec2::new(x, 2.0),
        yaw: 0.3,
        length: 4.5,
        width: 1.8,
        colour: [40, 90, 200],
        mask_id: id,
        braking: id.is_multiple_of(2),
    };
    let mut running = renderer.canvas();
    let mut checked = 0;
    for (i, look) in [
        SceneLook { rain: 1.0, wetness: 0.8, seed: 11, ..SceneLook::clear() },
        SceneLook { snow: 0.7, daylight: 0.2, seed: 12, ..SceneLook::clear() },
        SceneLook::clear(),
        SceneLook { seed: 99, ..SceneLook::clear() },
        SceneLook { rain: 0.4, snow: 0.4, fog: 0.3, seed: 13, ..SceneLook::clear() },
        SceneLook { daylight: 0.0, seed: 14, ..SceneLook::clear() },
    ]
    .into_iter()
    .enumerate()
    {
        let scene = renderer.scene(look);
        for frame in 0..6u32 {
            // No car in frame 4.
            let cars: Vec<_> = if frame == 4 {
                vec![]
            } else {
                vec![car(-10.0 + 3.0 * frame as f64, 1), car(8.0 - 2.0 * frame as f64, 2)]
            };
            // Signal heads under the cars' paths and one apart: none in
            // frame 0, red until frame 3, then green, and none again in
            // frame 5. In every other scene a fourth head overlaps the first,
            // so that its change redraws every head; otherwise only the two
            // that changed are redrawn.
            let colour = if frame < 3 { Colour::Red } else { Colour::Green };
            let mut heads = match frame {
                0 | 5 => vec![],
                _ => vec![
                    HeadSprite { position: DVec2::new(-4.0, 2.5), colour },
                    HeadSprite { position: DVec2::new(5.0, 1.5), colour: Colour::Yellow },
                    HeadSprite { position: DVec2::new(20.0, -9.0), colour },
                ],
            };
            if i % 2 == 1 && !heads.is_empty() {
                heads.push(HeadSprite { position: DVec2::new(-3.5, 2.7), colour: Colour::Yellow });
            }
            renderer.render(&mut running, &scene, &cars, &heads, frame);
            let mut fresh = renderer.canvas();
            renderer.render(&mut fresh, &scene, &cars, &heads, frame);
            assert!(running.rgb == fresh.rgb, "frame {frame} of {look:?}: RGB differs from one drawn from scratch");
            assert!(running.mask == fresh.mask, "frame {frame} of {look:?}: mask differs");
            checked += 1;
        }
    }
    assert_eq!(checked, 36);
}

#[test]
fn a_city_image_too_small_to_show_a_car_is_warned_of() {
    // 32 x 32 of the junctions: 0.4 px per metre, a car 0.39 of a pixel.
    // Its masks are empty, and gen said nothing before.
    let dir = fresh_dir("rendering-tiny-city");
    let tiny = city_spec("tiny", &[(4, 0.5)], (1, 0, 0), 5, "{}").replacen(
        "\"frames\"",
        "\"image\": {\"width\": 32, \"height\": 32}, \"frames\"",
        1,
    );
    let spec = write_spec(&dir, &tiny);
    let out = dir.join("out");
    let made = gen_ok(&spec, &out, &["--no-effects", "-q"]);
    let stderr = String::from_utf8_lossy(&made.stderr);
    assert!(stderr.contains("warning: a 32x32 image") && stderr.contains("covers 0.39 of a pixel"), "{stderr}");
    // Fewer mask pixels than car frames in view: most cars are missing.
    let scenario = &scenario_dirs(&out)[0];
    let in_view = read_poses(&scenario.join("poses.csv")).iter().filter(|p| p.in_view == 1).count();
    let mut shown = 0;
    for entry in std::fs::read_dir(scenario.join("mask")).unwrap() {
        let mask = image::open(entry.unwrap().path()).unwrap().to_luma8();
        shown += mask.pixels().filter(|p| p.0[0] != 0).count();
    }
    assert!(in_view >= 10 && shown < in_view, "{shown} mask pixels for {in_view} car frames in view");
    // 128 x 80 shows them (2.6 px per metre): no warning.
    let fine = write_spec(&dir, &tiny.replace("\"width\": 32, \"height\": 32", "\"width\": 128, \"height\": 80"));
    let made = gen_ok(&fine, &dir.join("fine"), &["--no-effects", "-q"]);
    assert!(!String::from_utf8_lossy(&made.stderr).contains("warning"), "{}", String::from_utf8_lossy(&made.stderr));
}
