//! The `gen` job: read and check the spec, plan every scenario, simulate,
//! render and write them in parallel, then write the manifest.

use super::plan::{Expansion, ScenarioKey, ScenarioPlan};
use super::progress::{Progress, ProgressMode};
use crate::map::CityMap;
use crate::output::annotations::{AnnotatedCar, AnnotationsBuilder, ANNOTATIONS_FILE};
use crate::output::logs::{write_events, write_lights};
use crate::output::manifest::{Manifest, ManifestRecord, Products, ShardEntry};
use crate::output::number::{logged_value, push_fixed};
use crate::output::png::{encode_png, PixelFormat, PngSettings};
use crate::output::poses::{write_pixels, write_poses, PIXELS_FILE, PIXEL_DECIMALS};
use crate::output::scenario::scenario_json;
use crate::output::{io_err, scenario_dir, write_atomically, ScenarioDir, WriteError, PARTIAL_PREFIX};
use crate::render::camera::{CameraKind, CameraPlan};
use crate::render::weather::SceneLook;
use crate::render::{CarSprite, FrameCanvas, Renderer, Scene};
use crate::spec::{DatasetSpec, SpecError, WorldKind};
use crate::world::city::CityWorld;
use crate::world::toy::ToyWorld;
use crate::world::{CarState, Trajectories, World};
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// What `causalcity gen` was asked to do.
#[derive(Debug, Clone)]
pub struct GenOptions {
    pub spec_path: PathBuf,
    /// Output folder; `data/<spec name>` when absent.
    pub out: Option<PathBuf>,
    /// At most this many scenarios per split and group.
    pub limit: Option<u32>,
    /// Worker threads; all cores when absent.
    pub threads: Option<usize>,
    pub images: bool,
    /// Also write NS-DR annotations.json per scenario (needs images).
    pub annotations: bool,
    pub progress: ProgressMode,
    /// Generate only this part of the dataset.
    pub shard: Option<Shard>,
    /// Replace a dataset made from another spec (removes only what causalcity wrote).
    pub force: bool,
    /// fsync every file and folder before a scenario is renamed into place.
    pub fsync: bool,
    /// Stop cleanly on SIGINT / SIGTERM (the binary sets this).
    pub handle_signals: bool,
}

/// Shard `index` of `count` (0-based): scenario i of the dataset's fixed order
/// belongs to shard i mod count, so every shard gets its share of every group
/// and split.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    pub index: u32,
    pub count: u32,
}

impl std::str::FromStr for Shard {
    type Err = String;

    fn from_str(text: &str) -> Result<Shard, String> {
        let usage = || format!("{text:?} is not a shard: use K/N with 0 <= K < N, e.g. 0/10");
        let (k, n) = text.split_once('/').ok_or_else(usage)?;
        let (index, count): (u32, u32) =
            (k.trim().parse().map_err(|_| usage())?, n.trim().parse().map_err(|_| usage())?);
        if count == 0 || index >= count {
            return Err(usage());
        }
        Ok(Shard { index, count })
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

/// What a finished run did.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Summary {
    pub out: PathBuf,
    /// Scenarios this run was asked for (its shard's share when sharded).
    pub scenarios: u64,
    pub written: u64,
    /// Already complete from an earlier run.
    pub skipped: u64,
    pub failed: u64,
    pub frame_pairs: u64,
    pub bytes: u64,
    #[serde(serialize_with = "seconds")]
    pub elapsed: Duration,
    pub threads: usize,
    /// Peak resident memory of the process, bytes (Linux only).
    pub peak_memory: Option<u64>,
    pub shard: Option<String>,
}

fn seconds<S: serde::Serializer>(d: &Duration, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_f64(d.as_secs_f64())
}

/// Why a run failed; [`GenError::exit_code`] maps it to the process status.
#[derive(Debug, thiserror::Error)]
pub enum GenError {
    #[error("invalid spec {path}: {error}")]
    Spec { path: PathBuf, error: SpecError },
    #[error("{error}\n{done} finished scenarios are kept. Free some space or fix the folder's permissions (or choose another --out), then rerun the same command to resume.")]
    Write { error: WriteError, done: u64 },
    #[error("cannot plan scenario {scenario}: {reason}")]
    Plan { scenario: String, reason: String },
    #[error("cannot start {threads} worker threads: {reason}")]
    Threads { threads: usize, reason: String },
    #[error("{out} holds a dataset made differently:\n  {}\nUse another --out, or --force to replace it (removes only what causalcity wrote there).", differences.join("\n  "))]
    Mixed { out: PathBuf, differences: Vec<String> },
    #[error("{0}")]
    Manifest(String),
    #[error("interrupted: {done} of {total} scenarios are complete in {out}. Rerun the same command to resume.")]
    Interrupted { done: u64, total: u64, out: PathBuf },
}

impl From<WriteError> for GenError {
    fn from(error: WriteError) -> GenError {
        GenError::Write { error, done: 0 }
    }
}

impl GenError {
    /// 2 for bad input, 130 when interrupted, 1 for failures while running.
    pub fn exit_code(&self) -> i32 {
        match self {
            GenError::Spec { .. } | GenError::Mixed { .. } => 2,
            GenError::Interrupted { .. } => 130,
            _ => 1,
        }
    }
}

/// Set by SIGINT / SIGTERM; workers stop at the next frame.
static STOP: AtomicBool = AtomicBool::new(false);
static HANDLER: std::sync::Once = std::sync::Once::new();

fn install_signal_handler() {
    HANDLER.call_once(|| {
        let _ = ctrlc::set_handler(|| {
            if STOP.swap(true, Ordering::SeqCst) {
                // A second Ctrl-C: leave at once (partial folders are hidden and discarded on rerun).
                std::process::exit(130);
            }
            eprintln!("\nstopping: finishing no more scenarios (press Ctrl-C again to quit at once)");
        });
    });
}

/// Everything shared by the workers of one run: the world that simulates
/// and the writers of a scenario folder.
pub(crate) struct Job<'e> {
    pub expansion: &'e Expansion,
    pub world: Box<dyn World>,
    pub renderer: Option<Renderer>,
    pub out: PathBuf,
    pub intersection_names: Vec<String>,
    pub fsync: bool,
    pub annotations: bool,
}

impl<'e> Job<'e> {
    /// A job over `expansion`'s world writing into `out`.
    pub fn new(expansion: &'e Expansion, out: PathBuf, products: Products, fsync: bool) -> Job<'e> {
        let world: Box<dyn World> = match expansion.spec.world {
            WorldKind::Toy => Box::new(ToyWorld),
            WorldKind::City => Box::new(CityWorld::default()),
        };
        Job {
            world,
            renderer: products.images.then(|| Renderer::new(&expansion.map, expansion.camera)),
            out,
            expansion,
            intersection_names: expansion.map.intersections.iter().map(|i| i.name.clone()).collect(),
            fsync,
            annotations: products.annotations && products.images,
        }
    }
}

/// Reads, checks and expands a spec file; nothing is written.
pub fn load_spec(path: &Path) -> Result<Expansion, GenError> {
    let spec_err = |error| GenError::Spec { path: path.to_path_buf(), error };
    let spec = DatasetSpec::from_file(path).map_err(spec_err)?;
    Expansion::new(spec, Arc::new(CityMap::default())).map_err(spec_err)
}

/// Where a run's manifest lives: `manifest.json`, or `shards/K-of-N.json`.
pub fn manifest_path(out: &Path, shard: Option<Shard>) -> PathBuf {
    match shard {
        None => out.join("manifest.json"),
        Some(s) => out.join("shards").join(format!("{}-of-{}.json", s.index, s.count)),
    }
}

/// Every manifest in `out`: the dataset's and the shards'.
fn existing_manifests(out: &Path) -> Result<Vec<(PathBuf, ManifestRecord)>, GenError> {
    let mut paths = vec![out.join("manifest.json")];
    if let Ok(entries) = std::fs::read_dir(out.join("shards")) {
        let mut shard_paths: Vec<PathBuf> = entries.filter_map(|e| e.ok().map(|e| e.path())).collect();
        shard_paths.sort();
        paths.extend(shard_paths.into_iter().filter(|p| p.extension().is_some_and(|e| e == "json")));
    }
    let mut found = Vec::new();
    for path in paths {
        if let Some(record) = ManifestRecord::read(&path).map_err(GenError::Manifest)? {
            found.push((path, record));
        }
    }
    Ok(found)
}

/// Removes what causalcity wrote into `out` according to `record`: the
/// manifests and the group folders it lists, nothing else.
fn remove_dataset(out: &Path, records: &[(PathBuf, ManifestRecord)]) -> Result<(), GenError> {
    let group_name = |n: &str| {
        n.starts_with("cars") && n.contains("_edges") && n.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
    };
    for (path, record) in records {
        for g in &record.groups {
            let dir = out.join(&g.name);
            if group_name(&g.name) && dir.exists() {
                std::fs::remove_dir_all(&dir).map_err(io_err(&dir))?;
            }
        }
        std::fs::remove_file(path).map_err(io_err(path))?;
    }
    let shards = out.join("shards");
    if shards.exists() && std::fs::read_dir(&shards).map(|mut d| d.next().is_none()).unwrap_or(false) {
        std::fs::remove_dir(&shards).map_err(io_err(&shards))?;
    }
    Ok(())
}

/// Removes hidden leftovers of interrupted scenarios in the spec's folders.
fn sweep_partials(out: &Path, spec: &DatasetSpec) -> Result<(), GenError> {
    for g in &spec.groups {
        for split in crate::spec::Split::ALL {
            let dir = out.join(g.name()).join(split.name());
            let Ok(entries) = std::fs::read_dir(&dir) else { continue };
            for e in entries.flatten() {
                if e.file_name().to_string_lossy().starts_with(PARTIAL_PREFIX) {
                    std::fs::remove_dir_all(e.path()).map_err(io_err(&e.path()))?;
                }
            }
        }
    }
    Ok(())
}

/// The scenarios of `shard` (all when `None`), in the dataset's fixed order.
pub fn shard_keys(keys: Vec<ScenarioKey>, shard: Option<Shard>) -> Vec<ScenarioKey> {
    match shard {
        None => keys,
        Some(s) => {
            keys.into_iter().enumerate().filter(|(i, _)| *i as u32 % s.count == s.index).map(|(_, k)| k).collect()
        }
    }
}

/// Runs `causalcity gen`: resumes an interrupted run of the same spec, refuses
/// to mix specs unless forced.
pub fn generate(options: &GenOptions) -> Result<Summary, GenError> {
    let start = Instant::now();
    let expansion = load_spec(&options.spec_path)?;
    let products = Products { images: options.images, annotations: options.annotations && options.images };
    let out = options.out.clone().unwrap_or_else(|| Path::new("data").join(&expansion.spec.name));
    std::fs::create_dir_all(&out).map_err(io_err(&out))?;

    // One dataset per folder: same spec, tool version and image setting.
    let existing = existing_manifests(&out)?;
    let differences: Vec<String> = existing
        .iter()
        .flat_map(|(_, record)| record.differences(&expansion.spec, products))
        .collect::<std::collections::BTreeSet<_>>()
        .into_iter()
        .collect();
    if !differences.is_empty() {
        if !options.force {
            return Err(GenError::Mixed { out, differences });
        }
        remove_dataset(&out, &existing)?;
    }
    if options.shard.is_none() {
        sweep_partials(&out, &expansion.spec)?;
    }

    let threads = options
        .threads
        .filter(|&t| t > 0)
        .unwrap_or_else(|| std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1));
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| GenError::Threads { threads, reason: e.to_string() })?;
    if options.handle_signals {
        install_signal_handler();
    }
    STOP.store(false, Ordering::SeqCst);

    let keys = shard_keys(expansion.keys(options.limit), options.shard);
    let shard_entry =
        options.shard.map(|s| ShardEntry { index: s.index, count: s.count, scenarios: keys.len() as u64 });
    let manifest_file = manifest_path(&out, options.shard);
    if let Some(parent) = manifest_file.parent() {
        std::fs::create_dir_all(parent).map_err(io_err(parent))?;
    }
    let manifest = |complete| {
        Manifest::new(&expansion.spec, &expansion.camera, options.limit, products, complete, shard_entry).to_json()
    };
    write_atomically(&manifest_file, &manifest(false))?;

    let job = Job::new(&expansion, out.clone(), products, options.fsync);
    let progress = Progress::new(keys.len() as u64, options.progress);
    let bytes = AtomicU64::new(0);
    let written = AtomicU64::new(0);
    let skipped = AtomicU64::new(0);
    let result = pool.install(|| {
        keys.par_iter().try_for_each_init(
            || job.renderer.as_ref().map(Renderer::canvas),
            |canvas, key| {
                if STOP.load(Ordering::Relaxed) {
                    return Err(GenError::Interrupted { done: 0, total: 0, out: PathBuf::new() });
                }
                if scenario_dir(&job.out, &key.group, key.split.name(), &key.folder_name()).exists() {
                    skipped.fetch_add(1, Ordering::Relaxed);
                } else {
                    bytes.fetch_add(write_scenario(&job, key, canvas.as_mut())?, Ordering::Relaxed);
                    written.fetch_add(1, Ordering::Relaxed);
                }
                progress.inc();
                Ok(())
            },
        )
    });
    progress.finish();
    let done = written.load(Ordering::Relaxed) + skipped.load(Ordering::Relaxed);
    match result {
        Err(GenError::Interrupted { .. }) => {
            return Err(GenError::Interrupted { done, total: keys.len() as u64, out });
        }
        Err(GenError::Write { error, .. }) => return Err(GenError::Write { error, done }),
        Err(e) => return Err(e),
        Ok(()) => {}
    }
    let final_manifest = manifest(true);
    write_atomically(&manifest_file, &final_manifest)?;
    let written = written.load(Ordering::Relaxed);
    Ok(Summary {
        out,
        scenarios: keys.len() as u64,
        written,
        skipped: skipped.load(Ordering::Relaxed),
        failed: 0,
        frame_pairs: if options.images { written * expansion.spec.frames as u64 } else { 0 },
        bytes: bytes.load(Ordering::Relaxed) + final_manifest.len() as u64,
        elapsed: start.elapsed(),
        threads,
        peak_memory: peak_memory_bytes(),
        shard: options.shard.map(|s| s.to_string()),
    })
}

/// Plans, simulates and writes one scenario; returns the bytes written.
fn write_scenario(job: &Job<'_>, key: &ScenarioKey, canvas: Option<&mut FrameCanvas>) -> Result<u64, GenError> {
    let plan = job.expansion.plan(key).map_err(|reason| GenError::Plan {
        scenario: format!("{}/{}/{}", key.group, key.split.name(), key.folder_name()),
        reason,
    })?;
    let trajectories = job.world.simulate(&job.expansion.map, &plan);
    let target = scenario_dir(&job.out, &key.group, key.split.name(), &key.folder_name());
    write_planned(job, &plan, &trajectories, target, canvas)
}

/// Writes a simulated scenario into the folder `target` (atomically);
/// returns the bytes written.
pub(crate) fn write_planned(
    job: &Job<'_>,
    plan: &ScenarioPlan,
    trajectories: &Trajectories,
    target: PathBuf,
    canvas: Option<&mut FrameCanvas>,
) -> Result<u64, GenError> {
    let camera = &job.expansion.camera;
    let mut dir = ScenarioDir::begin(target, plan.frames, canvas.is_some(), job.fsync)?;
    let record =
        scenario_json(plan, camera, job.expansion.spec.leader_gap_px, &job.intersection_names, job.world.model_name());
    let mut bytes = dir.write_file("scenario.json", &record)?;
    let ids: Vec<u32> = plan.cars.iter().map(|c| c.id).collect();
    bytes += dir.write_with("poses.csv", |w| write_poses(w, &ids, trajectories, camera))?;
    bytes += dir.write_with(PIXELS_FILE, |w| write_pixels(w, trajectories, camera))?;
    if let Some(city) = &plan.city {
        bytes +=
            dir.write_with("lights.csv", |w| write_lights(w, &city.lights, &job.intersection_names, trajectories))?;
        bytes += dir.write_with("events.csv", |w| write_events(w, trajectories))?;
    }
    if let (Some(renderer), Some(canvas)) = (&job.renderer, canvas) {
        bytes += write_frames(renderer, canvas, &mut dir, plan, trajectories, job.annotations)?;
        for camera_plan in &plan.cameras {
            bytes += write_camera(&job.expansion.map, &mut dir, plan, trajectories, camera_plan)?;
        }
    }
    bytes += dir.commit()?;
    Ok(bytes)
}

fn write_frames(
    renderer: &Renderer,
    canvas: &mut FrameCanvas,
    dir: &mut ScenarioDir,
    plan: &ScenarioPlan,
    trajectories: &Trajectories,
    annotations: bool,
) -> Result<u64, GenError> {
    let (w, h) = (renderer.camera.width, renderer.camera.height);
    let scenario_name = plan.key.folder_name();
    let annotated_cars: Vec<AnnotatedCar> =
        plan.cars.iter().map(|c| AnnotatedCar { id: c.id, name: c.name.clone(), mask_id: c.mask_id }).collect();
    let mut builder = annotations.then(|| AnnotationsBuilder::new(&scenario_name, w, h, &annotated_cars));
    let mut pixels = Vec::with_capacity(plan.cars.len());
    let mut scene = renderer.scene(scene_look(plan, trajectories, 0));
    let mut bytes = 0;
    let mut sprites = Vec::with_capacity(plan.cars.len());
    for (frame, states) in trajectories.states.iter().enumerate() {
        if STOP.load(Ordering::Relaxed) {
            return Err(GenError::Interrupted { done: 0, total: 0, out: PathBuf::new() });
        }
        if frame > 0 && trajectories.confounder_changes.iter().any(|(from, _)| *from == frame) {
            scene = renderer.scene(scene_look(plan, trajectories, frame));
        }
        fill_sprites(&mut sprites, plan, states);
        let frame = frame as u32;
        renderer.render(canvas, &scene, &sprites, frame);
        let (rgb_name, mask_name) = (dir.frame_name("rgb", frame), dir.frame_name("mask", frame));
        bytes += write_rgb_and_mask(dir, &rgb_name, &mask_name, canvas, (w, h))?;
        if let Some(builder) = builder.as_mut() {
            pixels.clear();
            pixels.extend(states.iter().map(|s| {
                let p = renderer.camera.to_pixel(s.position);
                [logged_value(p.x, PIXEL_DECIMALS), logged_value(p.y, PIXEL_DECIMALS)]
            }));
            builder.add_frame(frame, rgb_name, mask_name, &canvas.mask, &pixels);
        }
    }
    if let Some(builder) = builder {
        bytes += dir.write_file(ANNOTATIONS_FILE, &builder.to_json())?;
    }
    Ok(bytes)
}

/// Encodes a rendered frame's RGB image and instance mask into the scenario
/// folder; returns the bytes written.
fn write_rgb_and_mask(
    dir: &mut ScenarioDir,
    rgb_name: &str,
    mask_name: &str,
    canvas: &FrameCanvas,
    (w, h): (u32, u32),
) -> Result<u64, WriteError> {
    let rgb = dir.write_with(rgb_name, |out| {
        encode_png(out, w, h, PixelFormat::Rgb8, &canvas.rgb, PngSettings::rgb()).map_err(png_to_io)
    })?;
    let mask = dir.write_with(mask_name, |out| {
        encode_png(out, w, h, PixelFormat::Gray8, &canvas.mask, PngSettings::mask()).map_err(png_to_io)
    })?;
    Ok(rgb + mask)
}

/// The cars of one frame as the renderer draws them.
fn fill_sprites(sprites: &mut Vec<CarSprite>, plan: &ScenarioPlan, states: &[CarState]) {
    sprites.clear();
    sprites.extend(plan.cars.iter().zip(states).map(|(car, s)| CarSprite {
        position: s.position,
        yaw: s.yaw,
        length: car.length,
        width: car.width,
        colour: car.colour,
        mask_id: car.mask_id,
    }));
}

/// How a scenario looks at `frame`: light, water, fog, rain and snow (as
/// planned, or as an intervention changed them).
fn scene_look(plan: &ScenarioPlan, trajectories: &Trajectories, frame: usize) -> SceneLook {
    match &plan.city {
        Some(city) => {
            let changed = trajectories.confounder_changes.iter().rev().find(|(from, _)| *from <= frame);
            let c = changed.map_or(&city.confounders, |(_, c)| c);
            let seed = u64::from_le_bytes(city.sim_stream[..8].try_into().expect("8 bytes"));
            SceneLook { daylight: c.daylight(), wetness: c.wetness, fog: c.fog, rain: c.rain, snow: c.snow, seed }
        }
        None => SceneLook::clear(),
    }
}

/// Writes one extra camera's frames under `cameras/<name>/`: rgb/, mask/,
/// depth/ (16-bit, millimetres) when asked, and poses.csv (frame, car, px,
/// py, in_view) in this camera's pixels.
fn write_camera(
    map: &crate::map::CityMap,
    dir: &mut ScenarioDir,
    plan: &ScenarioPlan,
    trajectories: &Trajectories,
    camera_plan: &CameraPlan,
) -> Result<u64, GenError> {
    let base = format!("cameras/{}", camera_plan.name);
    for sub in ["rgb", "mask", "depth"] {
        if sub != "depth" || camera_plan.depth {
            dir.create_folder(&format!("{base}/{sub}"))?;
        }
    }
    let chased = |states: &[CarState]| match camera_plan.kind {
        CameraKind::Chase { car } => states.get(car).map(|s| (s.position, s.yaw)),
        CameraKind::Static { .. } => None,
    };
    let (w, h) = (camera_plan.width, camera_plan.height);
    // A static camera draws its background once; a chase camera every frame.
    let mut fixed: Option<(Renderer, Scene)> = None;
    let mut canvas: Option<FrameCanvas> = None;
    let (mut depth, mut depth_png) = (Vec::new(), Vec::new());
    let mut poses = b"frame,car,px,py,in_view\n".to_vec();
    let mut bytes = 0;
    let mut sprites = Vec::with_capacity(plan.cars.len());
    for (frame, states) in trajectories.states.iter().enumerate() {
        if STOP.load(Ordering::Relaxed) {
            return Err(GenError::Interrupted { done: 0, total: 0, out: PathBuf::new() });
        }
        let camera = camera_plan.camera_at(chased(states));
        let look = scene_look(plan, trajectories, frame);
        if trajectories.confounder_changes.iter().any(|(from, _)| *from == frame) {
            fixed = None;
        }
        let owned;
        let (renderer, scene) = match camera_plan.kind {
            CameraKind::Static { .. } => {
                let (r, s) = fixed.get_or_insert_with(|| {
                    let r = Renderer::new(map, camera);
                    let s = r.scene(look);
                    (r, s)
                });
                (&*r, &*s)
            }
            CameraKind::Chase { .. } => {
                let r = Renderer::new(map, camera);
                let s = r.scene(look);
                owned = (r, s);
                (&owned.0, &owned.1)
            }
        };
        let canvas = canvas.get_or_insert_with(|| renderer.canvas());
        fill_sprites(&mut sprites, plan, states);
        let frame = frame as u32;
        renderer.render(canvas, scene, &sprites, frame);
        let [rgb_name, mask_name, depth_name] =
            ["rgb", "mask", "depth"].map(|kind| format!("{base}/{}", dir.frame_name(kind, frame)));
        bytes += write_rgb_and_mask(dir, &rgb_name, &mask_name, canvas, (w, h))?;
        if camera_plan.depth {
            renderer.depth_mm(&canvas.mask, &mut depth);
            depth_png.clear();
            depth_png.extend(depth.iter().flat_map(|d| d.to_be_bytes()));
            bytes += dir.write_with(&depth_name, |out| {
                encode_png(out, w, h, PixelFormat::Gray16, &depth_png, PngSettings::mask()).map_err(png_to_io)
            })?;
        }
        for (car, state) in plan.cars.iter().zip(states) {
            let pixel = camera.to_pixel(state.position);
            poses.extend_from_slice(format!("{frame},{},", car.id).as_bytes());
            push_fixed(&mut poses, pixel.x, PIXEL_DECIMALS);
            poses.push(b',');
            push_fixed(&mut poses, pixel.y, PIXEL_DECIMALS);
            poses.extend_from_slice(format!(",{}\n", camera.contains_pixel(pixel) as u8).as_bytes());
        }
    }
    bytes += dir.write_file(&format!("{base}/poses.csv"), &poses)?;
    Ok(bytes)
}

fn png_to_io(e: png::EncodingError) -> std::io::Error {
    match e {
        png::EncodingError::IoError(e) => e,
        other => std::io::Error::other(other),
    }
}

/// Peak resident set size of this process (VmHWM), where the OS reports it.
pub fn peak_memory_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}
