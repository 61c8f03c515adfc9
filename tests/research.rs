//! The research-facing outputs, checked on real files: NS-DR annotations
//! (COCO RLE against the mask PNGs), V-CDN HDF5 files against the CSVs,
//! previews that decode at the documented size, and the causal-discovery
//! baseline's accuracy on toy and city datasets.

mod common;
use common::*;
use image::AnimationDecoder;
use serde_json::Value;
use std::path::Path;

fn decode_png_gray(path: &Path) -> image::GrayImage {
    image::open(path).unwrap().to_luma8()
}

/// Decodes a COCO compressed RLE into a row-major 0/1 mask.
fn decode_rle(rle: &Value) -> (u32, u32, Vec<u8>) {
    let (h, w) = (rle["size"][0].as_u64().unwrap() as u32, rle["size"][1].as_u64().unwrap() as u32);
    let runs = hotcoco::mask::rle_from_string(rle["counts"].as_str().unwrap(), h, w).unwrap();
    let column_major = hotcoco::mask::decode(&runs);
    let mut row_major = vec![0u8; (w * h) as usize];
    for x in 0..w as usize {
        for y in 0..h as usize {
            row_major[y * w as usize + x] = column_major[x * h as usize + y];
        }
    }
    (w, h, row_major)
}

#[test]
fn annotations_decode_to_the_mask_pngs_and_export_nsdr_writes_the_same_bytes() {
    let dir = fresh_dir("research-annotations");
    let spec = write_spec(&dir, &toy_spec("ann", &[(4, 0.5), (8, 0.5)], (1, 0, 1), 40));
    let data = dir.join("data");
    gen_ok(&spec, &data, &["--quiet", "--annotations"]);
    let exported = dir.join("nsdr");
    let output = run(&["export", "nsdr", data.to_str().unwrap(), "--out", exported.to_str().unwrap(), "-q"]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));

    let schema = validator("annotations.schema.json");
    let mut objects = 0;
    for scenario in scenario_dirs(&data) {
        let written = std::fs::read(scenario.join("annotations.json")).unwrap();
        let relative = scenario.strip_prefix(&data).unwrap();
        assert_eq!(written, std::fs::read(exported.join(relative).join("annotations.json")).unwrap());
        let annotations: Value = serde_json::from_slice(&written).unwrap();
        assert_valid(&schema, &annotations, &scenario.join("annotations.json"));
        let poses = read_poses(&scenario.join("poses.csv"));
        let frames = annotations["frames"].as_array().unwrap();
        assert_eq!(frames.len(), 40);
        for frame in frames.iter().step_by(3) {
            let mask = decode_png_gray(&scenario.join(frame["mask_filename"].as_str().unwrap()));
            let mut union = vec![0u8; mask.len()];
            for object in frame["objects"].as_array().unwrap() {
                let (w, h, pixels) = decode_rle(&object["mask"]);
                assert_eq!((w, h), mask.dimensions());
                let id = object["mask_id"].as_u64().unwrap() as u8;
                let expected: Vec<u8> = mask.as_raw().iter().map(|&v| (v == id) as u8).collect();
                assert_eq!(pixels, expected, "{} frame {}", scenario.display(), frame["frame_index"]);
                assert_eq!(object["area"].as_u64().unwrap(), expected.iter().map(|&v| v as u64).sum::<u64>());
                let pose = poses
                    .iter()
                    .find(|p| p.frame == frame["frame_index"].as_u64().unwrap() as u32 && p.car as u64 == object["id"])
                    .unwrap();
                assert_eq!((object["px"].as_f64().unwrap(), object["py"].as_f64().unwrap()), (pose.px, pose.py));
                for (u, p) in union.iter_mut().zip(&pixels) {
                    *u |= p;
                }
                objects += 1;
            }
            // Every car pixel belongs to an annotated object.
            let cars: Vec<u8> = mask.as_raw().iter().map(|&v| (v > 0) as u8).collect();
            assert_eq!(union, cars);
        }
    }
    assert!(objects > 50, "only {objects} objects checked");

    // validate knows annotations.json belongs to such a dataset.
    let report = run(&["validate", data.to_str().unwrap()]);
    assert!(report.status.success(), "{}", String::from_utf8_lossy(&report.stdout));
    let victim = scenario_dirs(&data)[0].join("annotations.json");
    std::fs::remove_file(&victim).unwrap();
    let report = run(&["validate", data.to_str().unwrap()]);
    assert!(!report.status.success());
    assert!(String::from_utf8_lossy(&report.stdout).contains("annotations.json"));
}

#[test]
fn annotations_need_images_and_a_dataset_keeps_its_setting() {
    let dir = fresh_dir("research-annotations-flags");
    let spec = write_spec(&dir, &toy_spec("flags", &[(4, 0.5)], (1, 0, 0), 10));
    let data = dir.join("data");
    let both = run(&[
        "gen",
        "--spec",
        spec.to_str().unwrap(),
        "--out",
        data.to_str().unwrap(),
        "--no-images",
        "--annotations",
    ]);
    assert_eq!(both.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&both.stderr).contains("--no-images"));
    gen_ok(&spec, &data, &["--quiet"]);
    let again = run(&["gen", "--spec", spec.to_str().unwrap(), "--out", data.to_str().unwrap(), "--annotations"]);
    assert_eq!(again.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&again.stderr).contains("annotations: false there, true now"));
}

#[test]
fn a_gif_of_a_slow_scenario_plays_in_at_most_15_seconds_and_a_fast_one_in_real_time() {
    let dir = fresh_dir("research-preview-speed");
    // The paper's city: one frame a second, 150 frames (75 shown at --every 2).
    let mut spec: serde_json::Value =
        serde_json::from_str(&city_spec("slow", &[(4, 0.5)], (1, 0, 0), 150, r#"{"confounders": {}}"#)).unwrap();
    spec["frame_interval"] = 1.0.into();
    spec["image"] = serde_json::json!({"width": 160, "height": 100});
    let spec = write_spec(&dir, &spec.to_string());
    let data = dir.join("slow");
    gen_ok(&spec, &data, &["--quiet", "--no-effects"]);
    let scenario = &scenario_dirs(&data)[0];
    let play = |args: &[&str], name: &str| -> (usize, f64, String) {
        let gif = dir.join(name);
        let mut all = vec!["preview", scenario.to_str().unwrap(), "--out", gif.to_str().unwrap()];
        all.extend_from_slice(args);
        let output = run(&all);
        assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
        let file = std::io::BufReader::new(std::fs::File::open(&gif).unwrap());
        let frames = image::codecs::gif::GifDecoder::new(file).unwrap().into_frames().collect_frames().unwrap();
        let seconds: f64 = frames
            .iter()
            .map(|f| {
                let (n, d) = f.delay().numer_denom_ms();
                n as f64 / d as f64 / 1000.0
            })
            .sum();
        (frames.len(), seconds, String::from_utf8_lossy(&output.stdout).to_string())
    };
    let (frames, seconds, said) = play(&[], "default.gif");
    assert_eq!(frames, 75);
    assert!((14.0..=15.0).contains(&seconds), "plays {seconds} s (real time would be 150 s)");
    assert!(said.contains("10.0x real time"), "{said}");
    // --fps still gives exactly what it asks for.
    let (_, seconds, _) = play(&["--fps", "1"], "slow.gif");
    assert!((seconds - 75.0).abs() < 1e-6, "{seconds}");
    // A scenario that plays in 15 s or less at its real speed keeps it: the toy's 0.1 s
    // frames, 150 of them, every 2nd shown, 0.2 s apart.
    let toy = scenario_dirs(&shared_image_dataset())[0].clone();
    let gif = dir.join("toy.gif");
    let output = run(&["preview", toy.to_str().unwrap(), "--out", gif.to_str().unwrap()]);
    assert!(String::from_utf8_lossy(&output.stdout).contains("5.0 frames/s, 1.0x real time"), "{output:?}");
}

#[test]
fn preview_writes_a_downscaled_gif_and_a_contact_sheet() {
    let data = shared_image_dataset();
    let scenario = scenario_dirs(&data).into_iter().find(|d| d.to_string_lossy().contains("cars12")).unwrap();
    let dir = fresh_dir("research-preview");
    let gif = dir.join("s.gif");
    let output = run(&[
        "preview",
        scenario.to_str().unwrap(),
        "--out",
        gif.to_str().unwrap(),
        "--masks",
        "--trails",
        "--arrows",
        "--every",
        "5",
    ]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let decoder =
        image::codecs::gif::GifDecoder::new(std::io::BufReader::new(std::fs::File::open(&gif).unwrap())).unwrap();
    let frames = decoder.into_frames().collect_frames().unwrap();
    assert_eq!(frames.len(), 30, "150 frames, every 5th");
    // Default scale 0.4 of 1024x640.
    assert_eq!(frames[0].buffer().dimensions(), (410, 256));
    assert!(std::fs::metadata(&gif).unwrap().len() < 2_000_000, "small enough to share");
    // The animation moves: first and last frames differ.
    assert_ne!(frames[0].buffer().as_raw(), frames[29].buffer().as_raw());

    let sheet = dir.join("s.png");
    let output = run(&[
        "preview",
        scenario.to_str().unwrap(),
        "--out",
        sheet.to_str().unwrap(),
        "--sheet-frames",
        "6",
        "--columns",
        "3",
        "--scale",
        "0.25",
    ]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let image = image::open(&sheet).unwrap();
    // 3 x 2 tiles of 256x160 with 4 px gaps.
    assert_eq!((image.width(), image.height()), (3 * 256 + 4 * 4, 2 * 160 + 3 * 4));
    // Every tile carries its frame number and time as a light label on a
    // dark box in its top-left corner; different frames, different labels.
    let rgb = image.to_rgb8();
    let label = |tile: u32| -> Vec<[u8; 3]> {
        let (x0, y0) = (4 + (tile % 3) * (256 + 4), 4 + (tile / 3) * (160 + 4));
        (y0..y0 + 10).flat_map(|y| (x0..x0 + 120).map(move |x| (x, y))).map(|(x, y)| rgb.get_pixel(x, y).0).collect()
    };
    let labels: Vec<Vec<[u8; 3]>> = (0..6).map(label).collect();
    for (i, l) in labels.iter().enumerate() {
        let text = l.iter().filter(|p| **p == [245, 245, 245]).count();
        let boxed = l.iter().filter(|p| **p == [20, 20, 20]).count();
        assert!(text > 40 && boxed > 200, "tile {i}: {text} text and {boxed} box pixels");
    }
    assert!(labels.windows(2).all(|w| w[0] != w[1]), "tiles of different frames share a label");

    let bad = run(&["preview", scenario.to_str().unwrap(), "--out", dir.join("s.jpg").to_str().unwrap()]);
    assert_eq!(bad.status.code(), Some(2), "an output format preview cannot write is bad input");
    assert!(String::from_utf8_lossy(&bad.stderr).contains(".gif"));
    assert!(!dir.join("s.jpg").exists());
}

fn baseline_json(data: &Path) -> Value {
    let output = run(&["baseline", data.to_str().unwrap(), "--json"]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    serde_json::from_slice(&output.stdout).unwrap()
}

fn group<'a>(report: &'a Value, name: &str) -> &'a Value {
    report["groups"].as_array().unwrap().iter().find(|g| g["group"] == name).unwrap()
}

#[test]
fn the_baseline_finds_toy_links_calls_few_without_links_and_finds_the_city_harder() {
    let dir = fresh_dir("research-baseline");
    let groups = [(8, 0.5), (8, 0.0)];
    let toy = dir.join("toy");
    gen_ok(&write_spec(&dir, &toy_spec("bl-toy", &groups, (40, 0, 40), 150)), &toy, &["--quiet", "--no-images"]);
    let report = baseline_json(&toy);
    let linked = group(&report, "cars08_edges50");
    assert!(linked["f1"].as_f64().unwrap() >= 0.95, "toy F1 {}", linked["f1"]);
    assert_eq!(linked["test_true_edges"], 80);
    let unlinked = group(&report, "cars08_edges00");
    assert_eq!(unlinked["threshold_from"], "pooled");
    assert!(unlinked["test_predicted_share"].as_f64().unwrap() <= 0.05, "{unlinked}");

    let city = dir.join("city");
    let city_spec = city_spec("bl-city", &groups, (40, 0, 40), 150, "{}");
    gen_ok(&write_spec(&dir, &city_spec), &city, &["--quiet", "--no-images"]);
    let report = baseline_json(&city);
    let city_f1 = group(&report, "cars08_edges50")["f1"].as_f64().unwrap();
    assert!(city_f1 < linked["f1"].as_f64().unwrap() - 0.03, "city F1 {city_f1} should be clearly below the toy's");
    assert!(group(&report, "cars08_edges00")["test_predicted_share"].as_f64().unwrap() <= 0.05);

    // Threshold-free figures beside F1: the city's dynamics still rank
    // true links first far better than guessing.
    let city_linked = group(&report, "cars08_edges50");
    let auroc = city_linked["auroc"].as_f64().unwrap();
    let ap = city_linked["average_precision"].as_f64().unwrap();
    assert!(auroc > 0.9 && auroc <= 1.0, "city AUROC {auroc}");
    assert!(ap > 0.5 && ap <= 1.0, "city AP {ap}");
    assert!(group(&report, "cars08_edges00")["auroc"].is_null(), "no AUROC without links");

    // The frame-0 row: one per group, learned on train like the dynamics.
    // The toy world starts every follower exactly leader_gap_px behind its
    // leader (the paper's rule), so the first frame alone finds its links.
    let toy_report = baseline_json(&toy);
    let frame0: Vec<&Value> = toy_report["frame0"].as_array().unwrap().iter().collect();
    assert_eq!(frame0.len(), 2);
    let toy_frame0 = frame0.iter().find(|g| g["group"] == "cars08_edges50").unwrap();
    assert_eq!(toy_frame0["method"], "frame0");
    assert!(toy_frame0["f1"].as_f64().unwrap() >= 0.95, "toy frame0 {toy_frame0}");

    let table = run(&["baseline", toy.to_str().unwrap()]);
    let table = String::from_utf8_lossy(&table.stdout);
    assert!(table.contains("cars08_edges50") && table.contains("AUROC") && table.contains("frame0"), "{table}");
}

#[test]
fn the_baseline_needs_links_somewhere_in_train() {
    let dir = fresh_dir("research-baseline-empty");
    let data = dir.join("data");
    gen_ok(&write_spec(&dir, &toy_spec("empty", &[(4, 0.0)], (2, 0, 1), 30)), &data, &["--quiet", "--no-images"]);
    let output = run(&["baseline", data.to_str().unwrap()]);
    // Bad input, and not a damaged dataset.
    assert_eq!(output.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&output.stderr).contains("no leader-follower pairs"));
    assert!(!String::from_utf8_lossy(&output.stderr).contains("is damaged"));
}

#[cfg(feature = "hdf5")]
#[test]
fn vcdn_files_match_the_pose_logs() {
    let dir = fresh_dir("research-vcdn");
    let data = dir.join("data");
    gen_ok(
        &write_spec(&dir, &toy_spec("vcdn", &[(4, 0.5), (8, 0.8)], (2, 1, 1), 20)),
        &data,
        &["--quiet", "--no-images"],
    );
    let out = dir.join("vcdn");
    let output = run(&["export", "vcdn", data.to_str().unwrap(), "--out", out.to_str().unwrap(), "-q"]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    for scenario in scenario_dirs(&data) {
        let relative = scenario.strip_prefix(&data).unwrap();
        let file = hdf5::File::open(
            out.join(relative.parent().unwrap())
                .join(format!("{}.h5", relative.file_name().unwrap().to_string_lossy())),
        )
        .unwrap();
        let record = read_json(&scenario.join("scenario.json"));
        let n = record["cars"].as_array().unwrap().len();
        let states = file.dataset("states").unwrap();
        assert_eq!(states.shape(), vec![20, n, 4]);
        assert_eq!(file.dataset("attrs").unwrap().shape(), vec![20, n, 1]);
        assert_eq!(file.dataset("actions").unwrap().shape(), vec![20, n, 2]);
        assert_eq!(file.dataset("rels").unwrap().shape(), vec![20, n * (n - 1) / 2, 2]);
        let values: Vec<f32> = states.read_raw().unwrap();
        for p in read_poses(&scenario.join("poses.csv")) {
            let at = (p.frame as usize * n + p.car as usize) * 4;
            assert!((values[at] as f64 - p.px).abs() < 1e-3 && (values[at + 1] as f64 - p.py).abs() < 1e-3);
        }
        let rels: Vec<f32> = file.dataset("rels").unwrap().read_raw().unwrap();
        let links = rels.iter().take(n * (n - 1)).step_by(2).filter(|&&v| v == 1.0).count();
        assert_eq!(links, record["edges"].as_array().unwrap().len());
    }
}

#[cfg(not(feature = "hdf5"))]
#[test]
fn vcdn_export_explains_how_to_get_hdf5() {
    let data = shared_image_dataset();
    let out = fresh_dir("research-vcdn-missing");
    let output = run(&["export", "vcdn", data.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert_eq!(output.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&output.stderr).contains("--features hdf5"));
}

#[test]
fn preview_shows_an_extra_cameras_frames() {
    let dir = fresh_dir("research-preview-camera");
    let example = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/examples/cameras.json");
    let out = dir.join("run");
    let output = run(&["run", "--scenario", example.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let cameras: Vec<_> = std::fs::read_dir(out.join("cameras/cameras")).unwrap().flatten().map(|e| e.path()).collect();
    assert!(!cameras.is_empty(), "the example has extra cameras");
    for camera in cameras {
        let first = image::open(camera.join("rgb/0000.png")).unwrap();
        let gif = dir.join(format!("{}.gif", camera.file_name().unwrap().to_string_lossy()));
        let output = run(&["preview", camera.to_str().unwrap(), "--out", gif.to_str().unwrap(), "--scale", "1"]);
        assert!(output.status.success(), "{}: {}", camera.display(), String::from_utf8_lossy(&output.stderr));
        let decoder =
            image::codecs::gif::GifDecoder::new(std::io::BufReader::new(std::fs::File::open(&gif).unwrap())).unwrap();
        let frames = decoder.into_frames().collect_frames().unwrap();
        // The camera's own frames at its own size, not the bird's-eye view's.
        assert_eq!(frames[0].buffer().dimensions(), (first.width(), first.height()), "{}", camera.display());
        assert!(frames.len() > 1);
    }
}
