//! Perspective cameras: the pinhole model's predictions against what the
//! renderer draws (walls leaning outwards, roofs off their footprints, cars
//! shrinking with distance, occlusion, depth along rays), and the camera
//! kinds from scenario files and specs through `run`, `gen` and `validate`.

mod common;

use causalcity::camera::Pinhole;
use causalcity::map::CityMap;
use causalcity::render::background::{blocks, Block, BUILDING_HEIGHT_M};
use causalcity::render::perspective::{empty_frame, PerspectiveFrame, PerspectiveRenderer, World3d};
use causalcity::render::weather::SceneLook;
use causalcity::render::CarSprite;
use causalcity::render::CAR_HEIGHT_M;
use common::{fresh_dir, gen_ok, run, write_spec};
use glam::{DVec2, DVec3};

fn render(world: &World3d, camera: &Pinhole, cars: &[CarSprite], hidden: Option<u8>) -> PerspectiveFrame {
    let mut frame = empty_frame(camera);
    PerspectiveRenderer::new().render(world, camera, &SceneLook::clear(), &[], cars, hidden, &mut frame);
    frame
}

fn car(x: f64, y: f64, mask_id: u8) -> CarSprite {
    CarSprite {
        position: DVec2::new(x, y),
        yaw: 0.0,
        length: 4.5,
        width: 1.8,
        colour: [200, 30, 30],
        mask_id,
        braking: false,
    }
}

/// The distance from the camera along pixel (x, y)'s ray to the plane z = h.
fn distance_to_plane(camera: &Pinhole, x: usize, y: usize, h: f64) -> f64 {
    let ray = camera.ray(x as f64, y as f64);
    let t = (h - camera.position[2]) / ray.z;
    ray.length() * t
}

fn at(frame: &PerspectiveFrame, x: usize, y: usize) -> (f64, u8) {
    let i = y * frame.width as usize + x;
    (frame.distance[i] as f64, frame.mask[i])
}

#[test]
fn pinhole_birds_eye_leans_walls_outwards_and_puts_roofs_where_the_model_predicts() {
    let map = CityMap::default();
    let world = World3d::new(&map);
    let camera = Pinhole::original_birds_eye(1024, 640);
    let (c, f) = (camera.centre_px(), camera.focal_px());
    // The building east of the centre on the row through y = 0.
    let [x0, ..] = blocks(&map, DVec2::splat(-200.0), DVec2::splat(200.0))
        .into_iter()
        .find_map(|b| match b {
            Block::Building { footprint: [x0, y0, x1, y1], .. } if x0 > 0.0 && y0 < -1.0 && y1 > 1.0 && x1 > x0 => {
                Some([x0, y0, x1, y1])
            }
            _ => None,
        })
        .expect("a building east of the centre");
    let frame = render(&world, &camera, &[], None);
    let row = c.y.round() as usize;
    // Its inner edge on the ground, and its roof's inner edge: 40 m and 28 m below the lens.
    let foot = c.x + f * x0 / 40.0;
    let roof = c.x + f * x0 / (40.0 - BUILDING_HEIGHT_M);
    assert!(roof - foot > 100.0, "the roof is {:.0} px out from its footprint", roof - foot);
    let ground_before = at(&frame, foot as usize - 3, row).0;
    assert!((ground_before / distance_to_plane(&camera, foot as usize - 3, row, 0.0) - 1.0).abs() < 0.01);
    // Between footprint and roof edge: the wall facing the centre, nearer than the ground, farther than the roof.
    for x in [foot as usize + 3, ((foot + roof) / 2.0) as usize, roof as usize - 3] {
        let (d, _) = at(&frame, x, row);
        let (ground, roof_plane) =
            (distance_to_plane(&camera, x, row, 0.0), distance_to_plane(&camera, x, row, BUILDING_HEIGHT_M));
        assert!(
            d < ground * 0.999 && d > roof_plane * 1.001,
            "x {x}: {d:.2} m, ground {ground:.2}, roof {roof_plane:.2}"
        );
    }
    // From the roof's edge outwards: the roof, 28 m below the lens along the ray.
    let x = roof as usize + 3;
    let (d, _) = at(&frame, x, row);
    assert!((d / distance_to_plane(&camera, x, row, BUILDING_HEIGHT_M) - 1.0).abs() < 0.01);

    // A car's roof centre lies off its ground point by what the model predicts.
    let ground_point = DVec2::new(-20.0, 8.0);
    let frame = render(&world, &camera, &[car(ground_point.x, ground_point.y, 9)], None);
    // The cabin's roof centre: 10 % of the length behind the centre, CAR_HEIGHT_M up.
    let roof_point = ground_point + DVec2::new(-0.45, 0.0);
    let predicted = |p: DVec2, z: f64| DVec2::new(c.x + f * p.x / (40.0 - z), c.y - f * p.y / (40.0 - z));
    let (roof_px, ground_px) = (predicted(roof_point, CAR_HEIGHT_M), predicted(ground_point, 0.0));
    let from_camera = camera.to_pixel(DVec3::new(roof_point.x, roof_point.y, CAR_HEIGHT_M)).unwrap();
    assert!((from_camera - roof_px).length() < 1e-6);
    assert!((roof_px - ground_px).length() > 6.0, "offset {:.1} px", (roof_px - ground_px).length());
    let (x, y) = (roof_px.x.round() as usize, roof_px.y.round() as usize);
    let (d, mask) = at(&frame, x, y);
    assert_eq!(mask, 9, "the roof centre's pixel shows the car");
    assert!((d / distance_to_plane(&camera, x, y, CAR_HEIGHT_M) - 1.0).abs() < 0.01, "the roof, not the ground");
}

/// A first-person camera on the east-west road A, looking east along it.
fn driver_camera(map: &CityMap) -> (Pinhole, f64) {
    let road_y = map.layout.east_west_roads[1].1 - map.layout.lane_width / 2.0;
    let camera = Pinhole {
        width: 640,
        height: 400,
        position: [-30.0, road_y, 1.2],
        yaw_rad: 0.0,
        pitch_rad: 0.0,
        roll_rad: 0.0,
        horizontal_fov_deg: 90.0,
    };
    (camera, road_y)
}

fn mask_rows(frame: &PerspectiveFrame, id: u8) -> usize {
    let w = frame.width as usize;
    frame.mask.chunks_exact(w).filter(|row| row.contains(&id)).count()
}

#[test]
fn a_car_ahead_shrinks_with_its_distance_and_hidden_cars_have_no_mask() {
    let map = CityMap::default();
    let world = World3d::new(&map);
    let (camera, road_y) = driver_camera(&map);
    let f = camera.focal_px();
    let mut heights = Vec::new();
    for ahead in [8.0, 12.0, 16.0, 24.0] {
        let frame = render(&world, &camera, &[car(-30.0 + ahead, road_y, 3)], None);
        let rows = mask_rows(&frame, 3) as f64;
        // The logged depth: the nearest of the car's pixels, along the camera's axis.
        let nearest_axis = (0..frame.mask.len())
            .filter(|&i| frame.mask[i] == 3)
            .map(|i| {
                let (x, y) = (i % frame.width as usize, i / frame.width as usize);
                frame.distance[i] as f64 / camera.ray(x as f64, y as f64).length()
            })
            .fold(f64::INFINITY, f64::min);
        assert!((nearest_axis - (ahead - 2.25)).abs() < 0.05, "the back of the car is {nearest_axis:.2} m ahead");
        // From the ground to its top: CAR_HEIGHT_M at about that distance (the
        // cabin's top sits 0.7 m farther), f * h / z pixels tall.
        let expected = f * CAR_HEIGHT_M / nearest_axis;
        assert!((rows - expected).abs() <= 2.5, "{ahead} m: {rows} rows, expected {expected:.1}");
        heights.push((rows, nearest_axis));
    }
    // Inverse proportion: height x distance stays the same.
    let products: Vec<f64> = heights.iter().map(|(h, z)| h * z).collect();
    let spread = products.iter().cloned().fold(f64::MIN, f64::max) / products.iter().cloned().fold(f64::MAX, f64::min);
    assert!(spread < 1.1, "height x distance {products:?}");

    // A car right behind a nearer car of the same size has no mask pixels.
    let frame = render(&world, &camera, &[car(-22.0, road_y, 3), car(-10.0, road_y, 4)], None);
    assert!(frame.visible_pixels(3) > 1000);
    assert_eq!(frame.visible_pixels(4), 0);
    let alone = render(&world, &camera, &[car(-10.0, road_y, 4)], None);
    assert!(alone.visible_pixels(4) > 500, "visible when alone");
    // The camera's own car is not drawn.
    let own = render(&world, &camera, &[car(-30.0, road_y, 5)], Some(5));
    assert_eq!(own.visible_pixels(5), 0);

    // A car behind a building: it projects into the image, but shows nowhere.
    let birds_eye = Pinhole::original_birds_eye(1024, 640);
    let low = Pinhole { position: [0.0, 0.0, 6.0], pitch_rad: 0.0, yaw_rad: 0.0, ..birds_eye };
    let behind_building = car(40.0, 0.0, 6);
    let frame = render(&world, &low, &[behind_building], None);
    let centre = low.to_pixel(DVec3::new(40.0, 0.0, 0.75)).expect("in front of the camera");
    assert!(low.contains_pixel(centre));
    assert_eq!(frame.visible_pixels(6), 0, "hidden behind the building east of the centre");
}

#[test]
fn depth_is_the_distance_along_each_ray_on_empty_road() {
    let map = CityMap::default();
    let world = World3d::new(&map);
    let (driver, _) = driver_camera(&map);
    let layout = &map.layout;
    // The middle of a road, away from the kerbs (poles, walls).
    let on_road = |p: DVec3| {
        layout.east_west_roads.iter().any(|&(_, y)| (p.y - y).abs() < layout.lane_width)
            || layout.north_south_roads.iter().any(|&(_, x)| (p.x - x).abs() < layout.lane_width)
    };
    for camera in [Pinhole::original_birds_eye(1024, 640), driver] {
        let frame = render(&world, &camera, &[], None);
        let mut depth = Vec::new();
        frame.depth_mm(&mut depth);
        let (w, h) = (camera.width as usize, camera.height as usize);
        let (mut road, mut right) = (0, 0);
        for y in (0..h).step_by(5) {
            for x in (0..w).step_by(5) {
                let ray = camera.ray(x as f64, y as f64);
                if ray.z >= 0.0 {
                    continue;
                }
                let expected = distance_to_plane(&camera, x, y, 0.0);
                let hit = camera.position() + ray * (-camera.position[2] / ray.z);
                if !on_road(hit) || expected > 60.0 {
                    continue;
                }
                road += 1;
                let decoded = depth[y * w + x] as f64 / 1000.0;
                right += ((decoded / expected - 1.0).abs() < 0.01) as usize;
            }
        }
        assert!(road > 500, "only {road} road pixels");
        // Every road pixel but the few a pole's head or a wall covers.
        assert!(right as f64 >= 0.98 * road as f64, "{right} of {road} road pixels within 1 %");
    }
}

#[test]
fn perspective_cameras_work_from_scenario_files_and_specs() {
    let dir = fresh_dir("perspective");
    let scenario = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/examples/perspective.json");
    let out = dir.join("run");
    let result = run(&["run", "--scenario", scenario.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(result.status.success(), "{}", String::from_utf8_lossy(&result.stderr));
    let cameras = out.join("perspective/cameras");
    for name in ["pinhole_birds_eye", "behind_car1", "driver_car2"] {
        let poses = std::fs::read_to_string(cameras.join(name).join("poses.csv")).unwrap();
        let mut lines = poses.lines();
        assert_eq!(lines.next(), Some("frame,car,px,py,in_view,visible_px"));
        // Frame 20's visible pixel counts are the mask PNG's.
        let mask = image::open(cameras.join(name).join("mask/0020.png")).unwrap().to_luma8();
        let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).filter(|r: &Vec<&str>| r[0] == "20").collect();
        assert_eq!(rows.len(), 3);
        let mut seen = 0;
        for row in rows {
            let id: u8 = row[1].parse().unwrap();
            let counted = mask.pixels().filter(|p| p.0[0] == id + 1).count();
            assert_eq!(row[5].parse::<usize>().unwrap(), counted, "{name}, car {id}");
            seen += counted;
        }
        assert!(seen > 0, "{name} shows some car at frame 20");
        let depth = image::open(cameras.join(name).join("depth/0020.png")).unwrap();
        assert!(matches!(depth, image::DynamicImage::ImageLuma16(_)), "{name}: 16-bit depth");
    }

    // From a spec through gen and validate, byte-identical on 1 and 2 threads.
    let spec = r#"{ "name": "persp", "world": "city", "seed": 3, "frames": 6,
        "groups": [{ "cars": 4, "edge_proportion": 0.5 }], "splits": { "train": 2, "val": 0, "test": 0 },
        "cameras": [ {"name": "top", "pinhole": {"position": [0, 0, 40]}, "width": 256, "height": 160, "depth": true},
                     {"name": "driver", "first_person": 0, "width": 160, "height": 100} ] }"#;
    let spec = write_spec(&dir, spec);
    let (one, two) = (dir.join("one"), dir.join("two"));
    gen_ok(&spec, &one, &["--quiet", "-j", "1"]);
    gen_ok(&spec, &two, &["--quiet", "-j", "2"]);
    assert_eq!(common::hash_tree(&one), common::hash_tree(&two));
    let checked = run(&["validate", one.to_str().unwrap()]);
    assert!(checked.status.success(), "{}", String::from_utf8_lossy(&checked.stdout));
    assert!(one.join("cars04_edges50/train/00000/cameras/driver/poses.csv").exists());

    // The dataset's own bird's-eye view as the original's pinhole: the same
    // poses (ground points land on the same pixels), other pictures.
    let flat = r#"{ "name": "view", "world": "city", "seed": 3, "frames": 4, "image": {"width": 256, "height": 160},
        "groups": [{ "cars": 4, "edge_proportion": 0.5 }], "splits": { "train": 1, "val": 0, "test": 0 } }"#;
    let pinhole = flat.replace(r#""frames": 4,"#, r#""frames": 4, "birds_eye": "pinhole","#);
    let (flat_out, pinhole_out) = (dir.join("flat"), dir.join("pinhole"));
    for sub in ["f", "p"] {
        std::fs::create_dir_all(dir.join(sub)).unwrap();
    }
    gen_ok(&write_spec(&dir.join("f"), flat), &flat_out, &["--quiet"]);
    gen_ok(&write_spec(&dir.join("p"), &pinhole), &pinhole_out, &["--quiet"]);
    let scenario = "cars04_edges50/train/00000";
    let read = |root: &std::path::Path, file: &str| std::fs::read(root.join(scenario).join(file)).unwrap();
    assert_eq!(read(&flat_out, "poses.csv"), read(&pinhole_out, "poses.csv"));
    assert_ne!(read(&flat_out, "rgb/0000.png"), read(&pinhole_out, "rgb/0000.png"));
    assert!(run(&["validate", pinhole_out.to_str().unwrap()]).status.success());

    // counterfactual: the perspective cameras of both runs, identical before
    // the intervention, Car_2's view changed after its leader stopped.
    let intervention = dir.join("stop.json");
    std::fs::write(&intervention, r#"{"at": 2.0, "do": "stop", "car": "Car_1", "seconds": 4}"#).unwrap();
    let pair = dir.join("pair");
    let result = run(&[
        "counterfactual",
        "--scenario",
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/examples/perspective.json").to_str().unwrap(),
        "--intervention",
        intervention.to_str().unwrap(),
        "--out",
        pair.to_str().unwrap(),
    ]);
    assert!(result.status.success(), "{}", String::from_utf8_lossy(&result.stderr));
    let view = |run: &str, frame: &str| {
        std::fs::read(pair.join("perspective").join(run).join("cameras/driver_car2/rgb").join(frame)).unwrap()
    };
    assert_eq!(view("factual", "0005.png"), view("counterfactual", "0005.png"));
    assert_ne!(view("factual", "0039.png"), view("counterfactual", "0039.png"));
}

#[test]
fn weather_shades_perspective_views_and_leaves_masks_alone() {
    use causalcity::render::perspective::draw_precipitation;
    let map = CityMap::default();
    let world = World3d::new(&map);
    let (camera, road_y) = driver_camera(&map);
    let cars = [car(-20.0, road_y, 3)];
    let draw = |look: SceneLook| {
        let mut frame = empty_frame(&camera);
        PerspectiveRenderer::new().render(&world, &camera, &look, &[], &cars, None, &mut frame);
        draw_precipitation(&look, 7, &mut frame);
        frame
    };
    let clear = draw(SceneLook::clear());
    let night = draw(SceneLook { daylight: 0.0, ..SceneLook::clear() });
    let rain = draw(SceneLook { rain: 1.0, ..SceneLook::clear() });
    let brightness = |f: &PerspectiveFrame| f.rgb.iter().map(|&v| v as u64).sum::<u64>();
    assert!(brightness(&night) * 10 < brightness(&clear) * 7, "night is darker");
    let streaked = clear.rgb.chunks_exact(3).zip(rain.rgb.chunks_exact(3)).filter(|(a, b)| a != b).count();
    assert!(streaked > 200, "rain streaks over {streaked} pixels");
    assert_eq!(clear.mask, rain.mask);
    assert_eq!(clear.mask, night.mask);
}

#[test]
fn a_pinhole_camera_over_a_large_town_draws_it_in_bounded_memory() {
    // A 10 km town: its ground texture at 10 px/m asked for 40 GB and gen
    // aborted. It is drawn coarser now, with roads still on it.
    let dir = fresh_dir("perspective-large-town");
    let spec = r#"{ "name": "large", "world": "city", "seed": 1, "frames": 3,
        "groups": [{ "cars": 2, "edge_proportion": 1.0 }], "splits": { "train": 1, "val": 0, "test": 0 },
        "map": {"extent_x": 5000, "extent_y": 5000},
        "cameras": [{"name": "p", "pinhole": {}, "width": 64, "height": 64}] }"#;
    let spec = write_spec(&dir, spec);
    let out = dir.join("out");
    let made = gen_ok(&spec, &out, &["--json", "--no-effects", "-j", "1"]);
    let summary: serde_json::Value = serde_json::from_slice(&made.stdout).unwrap();
    let peak = summary["peak_memory"].as_f64().expect("peak memory");
    assert!(peak < 2e9, "peak memory {peak} bytes");
    let frame = image::open(out.join("cars02_edges100/train/00000/cameras/p/rgb/0000.png")).unwrap().to_rgb8();
    assert_eq!(frame.dimensions(), (64, 64));
    let colours: std::collections::BTreeSet<[u8; 3]> = frame.pixels().map(|p| p.0).collect();
    assert!(colours.len() > 3, "a frame of {} colours", colours.len());
}

#[test]
fn without_images_a_specs_cameras_are_said_to_write_nothing() {
    // They were dropped without a word while scenario.json listed them.
    let dir = fresh_dir("perspective-no-images");
    let spec = r#"{ "name": "noimg", "world": "city", "seed": 1, "frames": 3,
        "groups": [{ "cars": 2, "edge_proportion": 1.0 }], "splits": { "train": 1, "val": 0, "test": 0 },
        "cameras": [{"name": "top", "pinhole": {}, "width": 64, "height": 64},
                    {"name": "street", "static": {"centre": [0, 0]}, "width": 64, "height": 64}] }"#;
    let spec = write_spec(&dir, spec);
    let out = dir.join("out");
    let made = gen_ok(&spec, &out, &["--no-images", "--no-effects", "-q"]);
    let stderr = String::from_utf8_lossy(&made.stderr);
    assert!(stderr.contains("warning: --no-images: the spec's cameras (top, street) write nothing"), "{stderr}");
    assert!(!out.join("cars02_edges100/train/00000/cameras").exists());
    // With images, no such warning.
    let with = dir.join("with");
    let made = gen_ok(&spec, &with, &["--no-effects", "-q"]);
    assert!(!String::from_utf8_lossy(&made.stderr).contains("warning"));
    assert!(with.join("cars02_edges100/train/00000/cameras/street/poses.csv").exists());
}
