//! The city's scale and view: cars stay on camera in the default datasets,
//! lights differ between scenarios, the default city's drivers keep
//! realistic time gaps, and stats prints what these need.

mod common;
use common::*;
use std::path::{Path, PathBuf};

/// The shipped spec `configs/NAME.json` with at most `limit` scenarios per split.
fn default_dataset(name: &str, limit: u32, out: &Path) {
    let spec = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("configs/{name}.json"));
    gen_ok(&spec, out, &["--quiet", "--no-images", "--limit", &limit.to_string()]);
}

/// Share of car-frames with in_view 1, counted from every poses.csv.
fn in_view_share(root: &Path) -> f64 {
    let (mut seen, mut all) = (0usize, 0usize);
    for d in scenario_dirs(root) {
        for p in read_poses(&d.join("poses.csv")) {
            all += 1;
            seen += p.in_view as usize;
        }
    }
    seen as f64 / all as f64
}

fn stats_json(dir: &Path) -> serde_json::Value {
    let output = run(&["stats", dir.to_str().unwrap(), "--json"]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    serde_json::from_slice(&output.stdout).unwrap()
}

#[test]
fn most_car_frames_of_the_default_datasets_are_on_camera() {
    let dir = fresh_dir("scale-in-view");
    for world in ["toy", "city"] {
        let out: PathBuf = dir.join(world);
        default_dataset(world, 10, &out);
        let share = in_view_share(&out);
        assert!(share >= 0.85, "{world}: {:.1} % of car-frames in view", 100.0 * share);
        // stats prints the same share (weighted by car-frames over its rows).
        let stats = stats_json(&out);
        let rows = stats["rows"].as_array().unwrap();
        let frames: f64 = rows.iter().map(|r| r["cars"].as_f64().unwrap()).sum();
        let weighted: f64 =
            rows.iter().map(|r| r["cars"].as_f64().unwrap() * r["in_view_share"].as_f64().unwrap()).sum();
        assert!((weighted / frames - share).abs() < 1e-9, "{world}: stats says {}", weighted / frames);
    }
}
