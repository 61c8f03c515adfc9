//! Helpers shared by the integration tests: they run the real binary and read
//! what it wrote (JSON, CSV, PNG) from disk.
#![allow(dead_code)]

use serde::Deserialize;
use serde_json::Value;
use sha2::{Digest, Sha256};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::Mutex;

pub fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_causalcity")
}

/// A fresh folder under cargo's per-test-target temporary directory.
pub fn fresh_dir(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

pub fn run(args: &[&str]) -> Output {
    Command::new(bin()).args(args).output().expect("run causalcity")
}

/// Runs causalcity like [`run`], but kills it and fails the test if it
/// has not finished within `seconds` (for inputs that once made it hang).
pub fn run_within(args: &[&str], seconds: u64) -> Output {
    use std::process::Stdio;
    let child =
        Command::new(bin()).args(args).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().expect("run causalcity");
    let pid = child.id();
    let (done, finished) = std::sync::mpsc::channel();
    std::thread::spawn(move || done.send(child.wait_with_output()));
    match finished.recv_timeout(std::time::Duration::from_secs(seconds)) {
        Ok(output) => output.expect("read causalcity's output"),
        Err(_) => {
            let _ = Command::new("kill").args(["-9", &pid.to_string()]).status();
            panic!("causalcity {args:?} did not finish within {seconds} s");
        }
    }
}

/// Runs `causalcity gen` and asserts it succeeded.
pub fn gen_ok(spec: &Path, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec!["gen", "--spec", spec.to_str().unwrap(), "--out", out.to_str().unwrap()];
    args.extend_from_slice(extra);
    let output = run(&args);
    assert!(
        output.status.success(),
        "gen failed: {}\n{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    output
}

/// The `.json` files of a folder of the repository, sorted.
pub fn json_files(dir: &str) -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join(dir);
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .collect();
    files.sort();
    files
}

/// A toy spec with the given groups `(cars, proportion)` and splits.
pub fn toy_spec(name: &str, groups: &[(u32, f64)], splits: (u32, u32, u32), frames: u32) -> String {
    let groups: Vec<String> =
        groups.iter().map(|(c, p)| format!(r#"{{"cars": {c}, "edge_proportion": {p}}}"#)).collect();
    format!(
        r#"{{"name": "{name}", "world": "toy", "seed": 11, "frames": {frames},
            "groups": [{}], "splits": {{"train": {}, "val": {}, "test": {}}}}}"#,
        groups.join(", "),
        splits.0,
        splits.1,
        splits.2
    )
}

pub fn write_spec(dir: &Path, text: &str) -> PathBuf {
    let path = dir.join("spec.json");
    std::fs::write(&path, text).unwrap();
    path
}

/// One row of poses.csv.
#[derive(Debug, Clone, Deserialize)]
pub struct Pose {
    pub frame: u32,
    pub t: f64,
    pub car: u32,
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub roll: f64,
    pub pitch: f64,
    pub yaw: f64,
    pub px: f64,
    pub py: f64,
    pub speed: f64,
    pub in_view: u8,
}

pub fn read_poses(path: &Path) -> Vec<Pose> {
    let mut reader = csv::Reader::from_path(path).unwrap();
    reader.deserialize().map(|r| r.unwrap()).collect()
}

/// Poses indexed `[car][frame]`.
pub fn poses_by_car(poses: &[Pose]) -> BTreeMap<u32, Vec<Pose>> {
    let mut by_car: BTreeMap<u32, Vec<Pose>> = BTreeMap::new();
    for p in poses {
        by_car.entry(p.car).or_default().push(p.clone());
    }
    by_car
}

/// Of a scenario's designed edges (`meta`'s `edges`, poses `by_car`):
/// (pairs, pairs whose follower keeps within 4.5 m of where its leader has
/// driven so far in at least 80 % of frames), issue 36's measure.
pub fn designed_pairs_following(meta: &Value, by_car: &BTreeMap<u32, Vec<Pose>>) -> (usize, usize) {
    let (mut pairs, mut following) = (0, 0);
    for edge in meta["edges"].as_array().unwrap() {
        let (leader, follower) =
            (&by_car[&(edge[0].as_u64().unwrap() as u32)], &by_car[&(edge[1].as_u64().unwrap() as u32)]);
        let near = follower
            .iter()
            .enumerate()
            .filter(|(t, f)| leader[..=*t].iter().any(|l| (l.x - f.x).hypot(l.y - f.y) <= 4.5));
        pairs += 1;
        following += usize::from(near.count() * 10 >= follower.len() * 8);
    }
    (pairs, following)
}

pub fn read_json(path: &Path) -> Value {
    serde_json::from_slice(&std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))).unwrap()
}

/// Every scenario folder of a dataset: `root/<group>/<split>/<NNNNN>`.
pub fn scenario_dirs(root: &Path) -> Vec<PathBuf> {
    let mut dirs = Vec::new();
    for group in sorted_entries(root) {
        // Group folders only (not `networks/`, `shards/` or `logs/`).
        if !group.is_dir() || !group.file_name().is_some_and(|n| n.to_string_lossy().starts_with("cars")) {
            continue;
        }
        for split in sorted_entries(&group) {
            for scenario in sorted_entries(&split) {
                dirs.push(scenario);
            }
        }
    }
    dirs
}

pub fn sorted_entries(dir: &Path) -> Vec<PathBuf> {
    let mut entries: Vec<PathBuf> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().path()).collect();
    entries.sort();
    entries
}

/// SHA-256 of every file under `root`, by relative path.
pub fn hash_tree(root: &Path) -> BTreeMap<String, String> {
    let mut hashes = BTreeMap::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for path in sorted_entries(&dir) {
            if path.is_dir() {
                stack.push(path);
            } else {
                let digest = Sha256::digest(std::fs::read(&path).unwrap());
                let rel = path.strip_prefix(root).unwrap().to_string_lossy().into_owned();
                let hex: String = digest.iter().map(|b| format!("{b:02x}")).collect();
                hashes.insert(rel, hex);
            }
        }
    }
    hashes
}

/// Whether any file lies under `root`, read while another process may still be
/// writing there: an entry renamed or removed between listing and looking (a
/// temporary file made whole) counts as not there, never as an error.
pub fn holds_a_file_while_written(root: &Path) -> bool {
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&dir) else { continue };
        for entry in entries.flatten() {
            match entry.file_type() {
                Ok(kind) if kind.is_dir() => stack.push(entry.path()),
                Ok(_) => return true,
                Err(_) => {}
            }
        }
    }
    false
}

static SHARED: Mutex<Option<PathBuf>> = Mutex::new(None);

/// A small toy dataset with images (two groups, 2/1/1 scenarios, 150 frames),
/// generated once per test binary.
pub fn shared_image_dataset() -> PathBuf {
    let mut guard = SHARED.lock().unwrap();
    if let Some(p) = guard.as_ref() {
        return p.clone();
    }
    let dir = fresh_dir(&format!("shared-{}", std::process::id()));
    let spec = write_spec(&dir, &toy_spec("shared", &[(4, 0.5), (12, 0.5)], (2, 1, 1), 150));
    let out = dir.join("out");
    gen_ok(&spec, &out, &["--quiet"]);
    *guard = Some(out.clone());
    out
}

/// Cars of a scenario.json, with the fields tests use.
#[derive(Debug, Clone, Deserialize)]
pub struct Car {
    pub id: u32,
    pub mask_id: u8,
    pub colour: String,
    pub spawn: String,
    pub spawn_distance: f64,
    pub actions: Vec<String>,
    pub merge_distances: Vec<f64>,
    pub role: String,
    pub length_m: f64,
    pub width_m: f64,
    /// City only.
    #[serde(default)]
    pub desired_speeds: Vec<f64>,
    pub driver: Option<Driver>,
    #[serde(default)]
    pub runs_red_lights: bool,
    /// City hard negatives: the car it starts right behind.
    #[serde(default)]
    pub hard_negative_behind: Option<u32>,
}

#[derive(Debug, Clone, Deserialize)]
pub struct Scenario {
    pub frames: u32,
    pub frame_interval: f64,
    pub camera: Camera,
    pub cars: Vec<Car>,
    pub edges: Vec<[u32; 2]>,
    pub toy: Option<Toy>,
    /// City only: confounders, effects, lights.
    pub city: Option<serde_json::Value>,
}

#[derive(Debug, Clone, Deserialize)]
pub struct Camera {
    pub width: u32,
    pub height: u32,
    pub pixels_per_metre: f64,
}

#[derive(Debug, Clone, Deserialize)]
pub struct Toy {
    pub speed_px_per_frame: f64,
    pub leader_gap_px: f64,
    pub leader_gap_m: f64,
}

pub fn read_scenario(dir: &Path) -> Scenario {
    serde_json::from_value(read_json(&dir.join("scenario.json"))).unwrap()
}

/// One row of lights.csv: a light at a frame.
#[derive(Debug, Clone, Deserialize)]
pub struct LightRow {
    pub frame: u32,
    pub t: f64,
    pub intersection: String,
    pub approach: String,
    pub signal: String,
    pub colour: String,
    pub since_change: f64,
    /// The signal head's bird's-eye pixel; none where the camera has none.
    pub head_px: Option<f64>,
    pub head_py: Option<f64>,
}

/// Every light at every frame of the city scenario in `dir`, in
/// lights.csv's order (frames, then lights in plan order): lights.csv as
/// written (`--lights frames`), or the default
/// light_changes.csv expanded by the library's reader, which
/// `end_to_end.rs` checks against lights.csv light-frame by light-frame.
pub fn light_rows(dir: &Path) -> Vec<LightRow> {
    let frames_file = dir.join("lights.csv");
    if frames_file.exists() {
        return read_csv(&frames_file);
    }
    assert!(dir.join("light_changes.csv").exists(), "{}: neither lights.csv nor light_changes.csv", dir.display());
    let meta = read_json(&dir.join("scenario.json"));
    let (frames, interval) = (meta["frames"].as_u64().unwrap() as usize, meta["frame_interval"].as_f64().unwrap());
    let lights = causalcity::dataset::readback::read_light_log(dir, frames, interval).unwrap();
    let count = lights.names.len();
    let mut rows = Vec::with_capacity(frames * count);
    for frame in 0..frames {
        for (k, name) in lights.names.iter().enumerate() {
            let mut parts = name.rsplitn(3, '/');
            let (signal, approach, intersection) =
                (parts.next().unwrap(), parts.next().unwrap(), parts.next().unwrap());
            let head = |i: usize| Some(lights.head_pixels[2 * k + i]).filter(|p| !p.is_nan());
            rows.push(LightRow {
                frame: frame as u32,
                t: frame as f64 * interval,
                intersection: intersection.to_string(),
                approach: approach.to_string(),
                signal: signal.to_string(),
                colour: causalcity::output::arrays::LIGHT_COLOURS[lights.colour[frame * count + k] as usize]
                    .name()
                    .to_string(),
                since_change: lights.since_change[frame * count + k],
                head_px: head(0),
                head_py: head(1),
            });
        }
    }
    rows
}

/// One row of events.csv.
#[derive(Debug, Clone, Deserialize)]
pub struct EventRow {
    pub frame: u32,
    pub t: f64,
    pub kind: String,
    /// Empty for an intervention on no car (a light, the weather).
    pub car: Option<u32>,
    pub other_car: Option<u32>,
    /// The light of light interventions and red-light runs.
    pub light: Option<String>,
    pub detail: String,
}

pub fn read_csv<T: serde::de::DeserializeOwned>(path: &Path) -> Vec<T> {
    let mut reader = csv::Reader::from_path(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    reader.deserialize().map(|r| r.unwrap()).collect()
}

/// The driver limits a city car's scenario.json records.
#[derive(Debug, Clone, Deserialize)]
pub struct Driver {
    pub max_acceleration: f64,
    pub max_deceleration: f64,
}

/// Writes a city spec whose `city` section is `city` (JSON text).
pub fn city_spec(name: &str, groups: &[(u32, f64)], splits: (u32, u32, u32), frames: u32, city: &str) -> String {
    let groups: Vec<String> =
        groups.iter().map(|(c, p)| format!(r#"{{"cars": {c}, "edge_proportion": {p}}}"#)).collect();
    format!(
        r#"{{"name": "{name}", "world": "city", "seed": 21, "frames": {frames},
            "groups": [{}], "splits": {{"train": {}, "val": {}, "test": {}}}, "city": {city}}}"#,
        groups.join(", "),
        splits.0,
        splits.1,
        splits.2
    )
}

/// Resolves `$ref`s between the files of data-schema/.
pub struct SchemaFolder(PathBuf);

impl jsonschema::Retrieve for SchemaFolder {
    fn retrieve(&self, uri: &jsonschema::Uri<String>) -> Result<Value, Box<dyn std::error::Error + Send + Sync>> {
        let name = uri.as_str().rsplit('/').next().unwrap_or_default();
        let text = std::fs::read_to_string(self.0.join(name))?;
        Ok(serde_json::from_str(&text)?)
    }
}

pub fn schema_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("data-schema")
}

pub fn validator(name: &str) -> jsonschema::Validator {
    let schema = read_json(&schema_dir().join(name));
    jsonschema::options().with_retriever(SchemaFolder(schema_dir())).build(&schema).unwrap()
}

pub fn assert_valid(v: &jsonschema::Validator, instance: &Value, what: &Path) {
    let errors: Vec<String> = v.iter_errors(instance).map(|e| format!("{} at {}", e, e.instance_path())).collect();
    assert!(errors.is_empty(), "{} does not match its schema:\n{}", what.display(), errors.join("\n"));
}

/// The route a car's spawn and actions describe, with the lane changes its
/// driver plans for turns and the actions it gave up on (events.csv's
/// `action_skipped` rows for a gap that never came). Lane changes may happen
/// later in the simulation than planned, which changes neither the car's
/// lanes nor its turns. A pair shares the route planned from its leader's
/// start.
pub fn planned_route(
    map: &causalcity::map::CityMap,
    cars: &[Car],
    car_id: u32,
    events: &[EventRow],
) -> causalcity::map::Route {
    let car = &cars[car_id as usize];
    let actions: Vec<causalcity::map::Action> =
        car.actions.iter().map(|a| serde_json::from_value(a.as_str().into()).unwrap()).collect();
    let spawn = map.lane_by_name(&car.spawn).unwrap();
    let entry = cars
        .iter()
        .filter(|c| c.spawn == car.spawn && c.actions == car.actions && c.merge_distances == car.merge_distances)
        .map(|c| c.spawn_distance)
        .fold(car.spawn_distance, f64::max);
    let given_up: Vec<usize> = events
        .iter()
        .filter(|e| e.car == Some(car_id) && e.kind == "action_skipped" && e.detail.contains("no gap"))
        .map(|e| e.detail["DriveQueue[".len()..e.detail.find(']').unwrap()].parse().unwrap())
        .collect();
    let policy = causalcity::map::LanePolicy::AdaptGivingUp(given_up);
    causalcity::map::Route::plan(map, spawn, entry, &actions, &car.merge_distances, 500.0, &policy).unwrap()
}

/// One row of interactions.csv.
#[derive(Debug, Clone, Deserialize)]
pub struct InteractionRow {
    pub frame: u32,
    pub car: u32,
    pub bound_by: String,
    pub other_car: Option<u32>,
    pub light: Option<String>,
}

/// One `.npy` of float64 values in C order, as numpy writes it.
pub fn npy(shape: &[usize], values: &[f64]) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let tuple = if dims.len() == 1 { format!("({},)", dims[0]) } else { format!("({})", dims.join(", ")) };
    let mut header = format!("{{'descr': '<f8', 'fortran_order': False, 'shape': {tuple}, }}");
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
    bytes.extend_from_slice(header.as_bytes());
    for v in values {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    bytes
}

/// An `.npz` of the given arrays (stored, as `np.savez` writes).
pub fn npz(path: &Path, arrays: &[(&str, Vec<u8>)]) {
    use std::io::Write;
    let mut zip = zip::ZipWriter::new(std::fs::File::create(path).unwrap());
    let options = zip::write::SimpleFileOptions::default().compression_method(zip::CompressionMethod::Stored);
    for (name, bytes) in arrays {
        zip.start_file(format!("{name}.npy"), options).unwrap();
        zip.write_all(bytes).unwrap();
    }
    zip.finish().unwrap();
}
