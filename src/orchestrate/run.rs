//! The `gen` job: read and check the spec, plan every scenario, simulate,
//! render and write them in parallel, then write the manifest.

use super::plan::{Expansion, ScenarioKey, ScenarioPlan};
use super::progress::{Progress, ProgressMode};
use crate::map::CityMap;
use crate::output::logs::{write_events, write_lights};
use crate::output::manifest::Manifest;
use crate::output::png::{encode_png, PixelFormat, PngSettings};
use crate::output::poses::write_poses;
use crate::output::scenario::scenario_json;
use crate::output::{io_err, scenario_dir, write_atomically, ScenarioDir, WriteError};
use crate::render::weather::SceneLook;
use crate::render::{CarSprite, FrameCanvas, Renderer};
use crate::spec::{DatasetSpec, SpecError, WorldKind};
use crate::world::city::CityWorld;
use crate::world::toy::ToyWorld;
use crate::world::{Trajectories, World};
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
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
    pub progress: ProgressMode,
}

/// What a finished run did.
#[derive(Debug, Clone)]
pub struct Summary {
    pub out: PathBuf,
    pub scenarios: u64,
    pub frame_pairs: u64,
    pub bytes: u64,
    pub elapsed: Duration,
    pub threads: usize,
    /// Peak resident memory of the process, bytes (Linux only).
    pub peak_memory: Option<u64>,
}

/// Why a run failed; [`GenError::exit_code`] maps it to the process status.
#[derive(Debug, thiserror::Error)]
pub enum GenError {
    #[error("invalid spec {path}: {error}")]
    Spec { path: PathBuf, error: SpecError },
    #[error("{0}\nhint: check that the output folder is writable and the disk has room, or choose another with --out")]
    Write(#[from] WriteError),
    #[error("cannot plan scenario {scenario}: {reason}")]
    Plan { scenario: String, reason: String },
    #[error("cannot start {threads} worker threads: {reason}")]
    Threads { threads: usize, reason: String },
}

impl GenError {
    /// 2 for bad input, 1 for failures while running.
    pub fn exit_code(&self) -> i32 {
        match self {
            GenError::Spec { .. } => 2,
            _ => 1,
        }
    }
}

/// Everything shared by the workers of one run.
struct Job {
    expansion: Expansion,
    map: Arc<CityMap>,
    world: Box<dyn World>,
    renderer: Option<Renderer>,
    out: PathBuf,
    png: PngSettings,
    intersection_names: Vec<String>,
}

/// Reads, checks and expands a spec file; nothing is written.
pub fn load_spec(path: &Path) -> Result<Expansion, GenError> {
    let spec_err = |error| GenError::Spec { path: path.to_path_buf(), error };
    let spec = DatasetSpec::from_file(path).map_err(spec_err)?;
    Expansion::new(spec, Arc::new(CityMap::default())).map_err(spec_err)
}

/// Runs `causalcity gen`.
pub fn generate(options: &GenOptions) -> Result<Summary, GenError> {
    let start = Instant::now();
    let expansion = load_spec(&options.spec_path)?;
    let out = options.out.clone().unwrap_or_else(|| Path::new("data").join(&expansion.spec.name));
    std::fs::create_dir_all(&out).map_err(io_err(&out))?;

    let threads = options
        .threads
        .filter(|&t| t > 0)
        .unwrap_or_else(|| std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1));
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| GenError::Threads { threads, reason: e.to_string() })?;

    let map = expansion.map.clone();
    let renderer = options.images.then(|| Renderer::new(&map, expansion.camera));
    let world: Box<dyn World> = match expansion.spec.world {
        WorldKind::Toy => Box::new(ToyWorld),
        WorldKind::City => Box::new(CityWorld::default()),
    };
    let intersection_names = map.intersections.iter().map(|i| i.name.clone()).collect();
    let job =
        Job { map, world, renderer, out: out.clone(), png: PngSettings::default(), expansion, intersection_names };
    let keys = job.expansion.keys(options.limit);
    let progress = Progress::new(keys.len() as u64, options.progress);
    let bytes = AtomicU64::new(0);
    let result = pool.install(|| {
        keys.par_iter().try_for_each_init(
            || job.renderer.as_ref().map(Renderer::canvas),
            |canvas, key| {
                let written = write_scenario(&job, key, canvas.as_mut())?;
                bytes.fetch_add(written, Ordering::Relaxed);
                progress.inc();
                Ok::<(), GenError>(())
            },
        )
    });
    progress.finish();
    result?;

    let spec = &job.expansion.spec;
    let manifest = Manifest::new(spec, &job.expansion.camera, options.limit, options.images).to_json();
    write_atomically(&out.join("manifest.json"), &manifest)?;
    let scenarios = keys.len() as u64;
    Ok(Summary {
        out,
        scenarios,
        frame_pairs: if options.images { scenarios * spec.frames as u64 } else { 0 },
        bytes: bytes.load(Ordering::Relaxed) + manifest.len() as u64,
        elapsed: start.elapsed(),
        threads,
        peak_memory: peak_memory_bytes(),
    })
}

/// Plans, simulates and writes one scenario; returns the bytes written.
fn write_scenario(job: &Job, key: &ScenarioKey, canvas: Option<&mut FrameCanvas>) -> Result<u64, GenError> {
    let plan = job.expansion.plan(key).map_err(|reason| GenError::Plan {
        scenario: format!("{}/{}/{}", key.group, key.split.name(), key.folder_name()),
        reason,
    })?;
    let trajectories = job.world.simulate(&job.map, &plan);
    let camera = &job.expansion.camera;
    let target = scenario_dir(&job.out, &key.group, key.split.name(), &key.folder_name());
    let dir = ScenarioDir::begin(target, plan.frames, canvas.is_some())?;
    let record =
        scenario_json(&plan, camera, job.expansion.spec.leader_gap_px, &job.intersection_names, job.world.model_name());
    let mut bytes = dir.write_file("scenario.json", &record)?;
    let ids: Vec<u32> = plan.cars.iter().map(|c| c.id).collect();
    bytes += dir.write_with("poses.csv", |w| write_poses(w, &ids, &trajectories, camera))?;
    if let Some(city) = &plan.city {
        bytes +=
            dir.write_with("lights.csv", |w| write_lights(w, &city.lights, &job.intersection_names, &trajectories))?;
        bytes += dir.write_with("events.csv", |w| write_events(w, &trajectories))?;
    }
    if let (Some(renderer), Some(canvas)) = (&job.renderer, canvas) {
        bytes += write_frames(job, renderer, canvas, &dir, &plan, &trajectories)?;
    }
    dir.commit()?;
    Ok(bytes)
}

fn write_frames(
    job: &Job,
    renderer: &Renderer,
    canvas: &mut FrameCanvas,
    dir: &ScenarioDir,
    plan: &ScenarioPlan,
    trajectories: &Trajectories,
) -> Result<u64, GenError> {
    let (w, h) = (renderer.camera.width, renderer.camera.height);
    let look = match &plan.city {
        Some(city) => {
            let c = &city.confounders;
            let seed = u64::from_le_bytes(city.sim_stream[..8].try_into().expect("8 bytes"));
            SceneLook { daylight: c.daylight(), wetness: c.wetness, fog: c.fog, rain: c.rain, snow: c.snow, seed }
        }
        None => SceneLook::clear(),
    };
    let scene = renderer.scene(look);
    let mut bytes = 0;
    let mut sprites = Vec::with_capacity(plan.cars.len());
    for (frame, states) in trajectories.states.iter().enumerate() {
        sprites.clear();
        sprites.extend(plan.cars.iter().zip(states).map(|(car, s)| CarSprite {
            position: s.position,
            yaw: s.yaw,
            length: car.length,
            width: car.width,
            colour: car.colour,
            mask_id: car.mask_id,
        }));
        let frame = frame as u32;
        renderer.render(canvas, &scene, &sprites, frame);
        bytes += dir.write_with(&dir.frame_name("rgb", frame), |out| {
            encode_png(out, w, h, PixelFormat::Rgb8, &canvas.rgb, job.png).map_err(png_to_io)
        })?;
        bytes += dir.write_with(&dir.frame_name("mask", frame), |out| {
            encode_png(out, w, h, PixelFormat::Gray8, &canvas.mask, job.png).map_err(png_to_io)
        })?;
    }
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
