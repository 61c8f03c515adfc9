//! One scenario as typed arrays in memory instead of files: the values the
//! files hold, exactly (every number rounded as its log writes it, the
//! frames' pixels as their PNGs decode), for loaders that never touch the
//! disk (the Python package). Row-major; shapes are in each field's doc.

use super::footage::{signal_heads, Footage};
use super::logs::{event_frame, event_time, light_names, DIVERGENCE_DECIMALS};
use super::number::logged_value;
use super::poses::PIXEL_DECIMALS;
use super::scenario::scenario_json;
use crate::camera::Camera;
use crate::map::signals::Colour;
use crate::map::CityMap;
use crate::plan::ScenarioPlan;
use crate::render::perspective::World3d;
use crate::render::{FrameCanvas, Renderer};
use crate::spec::BirdsEyeView;
use crate::timing::StageTimes;
use crate::world::effects::{EffectReport, EffectRow};
use crate::world::{BoundBy, Trajectories};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

/// Light colours in the order of [`LightArrays::colour`]'s codes.
pub const LIGHT_COLOURS: [Colour; 3] = [Colour::Green, Colour::Yellow, Colour::Red];

/// A scenario's poses, graph, logs and (when asked) frames, in memory.
#[derive(Debug, Clone)]
pub struct ScenarioArrays {
    /// `scenario.json`, byte for byte.
    pub scenario_json: Vec<u8>,
    pub frames: usize,
    pub cars: usize,
    /// Car ids (0-based, the order of every car axis) and names.
    pub car_ids: Vec<u32>,
    pub car_names: Vec<String>,
    /// Seconds since the start, `[frames]` (poses.csv `t`).
    pub t: Vec<f64>,
    /// Metres, `[frames, cars, 3]`: x, y, z (poses.csv).
    pub position: Vec<f64>,
    /// Radians, `[frames, cars, 3]`: roll, pitch, yaw (poses.csv).
    pub rotation: Vec<f64>,
    /// Bird's-eye pixels, `[frames, cars, 2]`: px, py (poses.csv; pixels.npy
    /// holds the same values as float32).
    pub pixels: Vec<f64>,
    /// Metres per second, `[frames, cars]`.
    pub speed: Vec<f64>,
    /// 1 when the car's centre is in the bird's-eye image, `[frames, cars]`.
    pub in_view: Vec<u8>,
    /// `[cars, cars]`: `graph[i * cars + j] = 1` when car i leads car j.
    pub graph: Vec<u8>,
    /// (leader, follower) ids, as scenario.json's `edges`.
    pub edges: Vec<[u32; 2]>,
    /// City world: the lights (lights.csv).
    pub lights: Option<LightArrays>,
    /// City world: what bound each car (interactions.csv).
    pub interactions: Option<InteractionArrays>,
    /// events.csv's rows, in order (empty in the toy world).
    pub events: Vec<EventRow>,
    /// With images: the bird's-eye frames.
    pub images: Option<FrameArrays>,
    /// Frames drawn into a batch ([`BatchFrames`]) instead of `images`: the
    /// whole batch's, on the batch's last scenario (in reading order).
    pub batch: Option<FrameArrays>,
    /// Where measured: effects.csv's rows, in order, divergences rounded as
    /// the file writes them.
    pub effects: Option<Vec<EffectRow>>,
}

/// lights.csv as arrays: `L` lights in plan order.
#[derive(Debug, Clone)]
pub struct LightArrays {
    /// `AC/W/straight`, as scenario files and events.csv name lights.
    pub names: Vec<String>,
    /// `[frames, L]`: index into [`LIGHT_COLOURS`].
    pub colour: Vec<u8>,
    /// Seconds since the colour changed, `[frames, L]`.
    pub since_change: Vec<f64>,
    /// Signal head in bird's-eye pixels, `[L, 2]`; NaN without a head.
    pub head_pixels: Vec<f64>,
}

/// interactions.csv as arrays, `[frames, cars]` each.
#[derive(Debug, Clone)]
pub struct InteractionArrays {
    /// Index into [`BoundBy::ALL`].
    pub bound_by: Vec<u8>,
    /// The car that bound it, -1 for none.
    pub other_car: Vec<i16>,
    /// The light that bound it (index into [`LightArrays::names`]), -1 for none.
    pub light: Vec<i16>,
}

/// One events.csv row.
#[derive(Debug, Clone, PartialEq)]
pub struct EventRow {
    pub frame: u64,
    pub t: f64,
    pub kind: &'static str,
    pub car: Option<u32>,
    pub other_car: Option<u32>,
    /// Light name, as events.csv writes it.
    pub light: Option<String>,
    pub detail: String,
}

/// The bird's-eye frames as their PNGs decode.
#[derive(Debug, Clone)]
pub struct FrameArrays {
    pub width: u32,
    pub height: u32,
    /// `[frames, height, width, 3]`.
    pub rgb: Vec<u8>,
    /// `[frames, height, width]`: 0 for no car, else the car's id + 1.
    pub mask: Vec<u8>,
}

/// A scenario's frames do not fit in memory (Python raises `MemoryError`).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "not enough memory for the frames of scenario {scenario}: {} are needed ({frames} frames of {width} x {height}, RGB and mask){}. Use fewer frames or a smaller image, or write the frames to disk with the command line",
    gigabytes(*bytes),
    available.map(|a| format!(", {} available", gigabytes(a))).unwrap_or_default()
)]
pub struct OutOfMemory {
    pub scenario: String,
    pub bytes: u64,
    pub frames: usize,
    pub width: u32,
    pub height: u32,
    /// Memory the OS says is available, where it says.
    pub available: Option<u64>,
}

/// Bytes as gigabytes for messages, e.g. `1.57 GB`.
pub fn gigabytes(bytes: u64) -> String {
    format!("{:.2} GB", bytes as f64 / 1e9)
}

/// Memory the OS can give this process now without swapping (Linux's
/// MemAvailable); `None` where it does not say.
pub fn available_memory_bytes() -> Option<u64> {
    let info = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = info.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Bytes of one scenario's frames in memory: RGB and mask.
pub fn frame_bytes(frames: usize, camera: &Camera) -> u64 {
    frames as u64 * camera.width as u64 * camera.height as u64 * 4
}

/// Arrays of a simulated scenario, seen by `camera`; with a renderer (whose
/// camera must be `camera`), the frames too, or with `into` the frames go
/// into that slot of a batch's buffers instead. Frames that do not fit in
/// memory are an error, never an abort.
#[allow(clippy::too_many_arguments)] // the map, the camera and the scenario's parts, each once
pub fn scenario_arrays(
    map: &CityMap,
    camera: &Camera,
    leader_gap_px: f64,
    plan: &ScenarioPlan,
    trajectories: &Trajectories,
    effects: Option<EffectReport>,
    renderer: Option<(&Renderer, &mut FrameCanvas)>,
    into: Option<(&BatchFrames, usize)>,
) -> Result<ScenarioArrays, OutOfMemory> {
    let (frames, cars) = (trajectories.frames(), plan.cars.len());
    let intersection_names: Vec<String> = map.intersections.iter().map(|i| i.name.clone()).collect();
    let model = crate::world::model_name(&plan.world);
    let scenario_json = scenario_json(plan, camera, leader_gap_px, &intersection_names, model, effects.as_ref());
    let mut a = ScenarioArrays {
        scenario_json,
        frames,
        cars,
        car_ids: plan.cars.iter().map(|c| c.id).collect(),
        car_names: plan.cars.iter().map(|c| c.name.clone()).collect(),
        t: (0..frames).map(|f| logged_value(f as f64 * trajectories.frame_interval, 6)).collect(),
        position: Vec::with_capacity(frames * cars * 3),
        rotation: Vec::with_capacity(frames * cars * 3),
        pixels: Vec::with_capacity(frames * cars * 2),
        speed: Vec::with_capacity(frames * cars),
        in_view: Vec::with_capacity(frames * cars),
        graph: vec![0; cars * cars],
        edges: plan.edges.iter().map(|&(l, f)| [l, f]).collect(),
        lights: None,
        interactions: None,
        events: Vec::new(),
        images: None,
        batch: None,
        effects: effects.map(|report| {
            let round = |row: EffectRow| EffectRow {
                max_divergence_m: logged_value(row.max_divergence_m, DIVERGENCE_DECIMALS),
                ..row
            };
            report.rows.into_iter().map(round).collect()
        }),
    };
    for states in &trajectories.states {
        for s in states {
            let pixel = camera.to_pixel(s.position);
            a.position.extend([logged_value(s.position.x, 4), logged_value(s.position.y, 4), logged_value(s.z, 4)]);
            a.rotation.extend([s.roll, s.pitch, s.yaw].map(|r| logged_value(r, 6)));
            a.pixels.extend([logged_value(pixel.x, PIXEL_DECIMALS), logged_value(pixel.y, PIXEL_DECIMALS)]);
            a.speed.push(logged_value(s.speed, 4));
            a.in_view.push(camera.contains_pixel(pixel) as u8);
        }
    }
    for &(leader, follower) in &plan.edges {
        a.graph[leader as usize * cars + follower as usize] = 1;
    }
    let heads = signal_heads(map, plan);
    if let Some(city) = plan.world.city() {
        let names = light_names(&city.lights, &intersection_names);
        a.lights = Some(LightArrays {
            colour: trajectories
                .lights
                .iter()
                .flatten()
                .map(|s| LIGHT_COLOURS.iter().position(|&c| c == s.colour).unwrap_or(0) as u8)
                .collect(),
            since_change: trajectories.lights.iter().flatten().map(|s| logged_value(s.since_change, 3)).collect(),
            head_pixels: heads
                .iter()
                .flat_map(|h| match h {
                    Some(p) => {
                        let p = camera.to_pixel(*p);
                        [logged_value(p.x, PIXEL_DECIMALS), logged_value(p.y, PIXEL_DECIMALS)]
                    }
                    None => [f64::NAN; 2],
                })
                .collect(),
            names: names.clone(),
        });
        let interactions = trajectories.interactions.iter().flatten();
        a.interactions = Some(InteractionArrays {
            bound_by: interactions
                .clone()
                .map(|i| BoundBy::ALL.iter().position(|&b| b == i.bound_by).unwrap_or(0) as u8)
                .collect(),
            other_car: interactions.clone().map(|i| i.other_car.map_or(-1, |c| c as i16)).collect(),
            light: interactions.map(|i| i.light.map_or(-1, |l| l as i16)).collect(),
        });
        a.events = trajectories
            .events
            .iter()
            .map(|e| EventRow {
                frame: event_frame(e.t, trajectories.frame_interval),
                t: event_time(e.t),
                kind: e.kind.name(),
                car: e.car,
                other_car: e.other,
                light: e.light.map(|l| names[l].clone()),
                detail: e.detail.clone(),
            })
            .collect();
    }
    if let Some((renderer, canvas)) = renderer {
        let (width, height) = (renderer.camera.width, renderer.camera.height);
        let pixels = width as usize * height as usize;
        let out_of_memory = || OutOfMemory {
            scenario: plan.key.folder_name(),
            bytes: frame_bytes(frames, &renderer.camera),
            frames,
            width,
            height,
            available: available_memory_bytes(),
        };
        let footage = Footage::new(plan, trajectories, &heads);
        let world = (plan.birds_eye == BirdsEyeView::Pinhole).then(|| World3d::new(map));
        if let Some((batch, slot)) = into {
            let times = StageTimes::default();
            let _ = footage.birds_eye(renderer, canvas, world.as_ref(), &times, |frame, rgb, mask| {
                batch.write(slot, frame as usize, rgb, mask);
                Ok::<(), std::convert::Infallible>(())
            });
            return Ok(a);
        }
        let rgb = frame_buffer(frames * pixels * 3).ok_or_else(out_of_memory)?;
        let mask = frame_buffer(frames * pixels).ok_or_else(out_of_memory)?;
        let mut images = FrameArrays { width, height, rgb, mask };
        let _ = footage.birds_eye(renderer, canvas, world.as_ref(), &StageTimes::default(), |_, rgb, mask| {
            images.rgb.extend_from_slice(rgb);
            images.mask.extend_from_slice(mask);
            Ok::<(), std::convert::Infallible>(())
        });
        a.images = Some(images);
    }
    Ok(a)
}

/// The frames of a batch of scenarios of one camera in two buffers
/// (`[scenarios, frames, height, width, 3]` and `[..., height, width]`):
/// each scenario's frames are copied into its slot as they are drawn, by
/// whichever thread draws it, so the batch needs no copy of its own (the
/// copy cost a third of the rate of a Python loader with images).
pub struct BatchFrames {
    pub scenarios: usize,
    pub frames: usize,
    pub width: u32,
    pub height: u32,
    rgb: Mutex<Vec<u8>>,
    mask: Mutex<Vec<u8>>,
}

impl BatchFrames {
    /// Room for `scenarios` scenarios of `frames` frames of `camera` (from
    /// the spare frame buffers when there are some); `None` when the
    /// memory cannot be had.
    pub fn new(scenarios: usize, frames: usize, camera: &Camera) -> Option<BatchFrames> {
        let pixels = scenarios * frames * camera.width as usize * camera.height as usize;
        let rgb = Mutex::new(batch_frame_buffer(pixels.checked_mul(3)?)?);
        let mask = Mutex::new(batch_frame_buffer(pixels)?);
        Some(BatchFrames { scenarios, frames, width: camera.width, height: camera.height, rgb, mask })
    }

    /// Frame `frame` of the scenario in `slot`.
    fn write(&self, slot: usize, frame: usize, rgb: &[u8], mask: &[u8]) {
        let at = slot * self.frames + frame;
        let mut all = self.rgb.lock().unwrap_or_else(|e| e.into_inner());
        all[at * rgb.len()..(at + 1) * rgb.len()].copy_from_slice(rgb);
        drop(all);
        let mut all = self.mask.lock().unwrap_or_else(|e| e.into_inner());
        all[at * mask.len()..(at + 1) * mask.len()].copy_from_slice(mask);
    }

    /// The filled buffers.
    pub fn into_frames(self) -> FrameArrays {
        let take = |m: Mutex<Vec<u8>>| m.into_inner().unwrap_or_else(|e| e.into_inner());
        FrameArrays { width: self.width, height: self.height, rgb: take(self.rgb), mask: take(self.mask) }
    }
}

/// Frame buffers handed back by their last reader ([`recycle_frame_buffer`]),
/// kept for the next scenario's frames: fresh memory must first be zeroed
/// by the kernel, which took a quarter of the in-memory frame rate
/// (measured with perf on a 1-thread stream of city scenarios).
static SPARE_FRAME_BUFFERS: Mutex<Vec<Vec<u8>>> = Mutex::new(Vec::new());

/// At most this many bytes of spare frame buffers are kept: a few
/// scenarios' frames (one 150-frame 1024 x 640 scenario holds 393 MB), or
/// three of the largest buffer asked for while the streams run when that is
/// more (a batch of such scenarios: the batch in use, the one being filled
/// and its masks must all be reused to stay off fresh pages).
pub const SPARE_FRAME_BYTES: usize = 1 << 30;

/// The largest frame buffer asked for since the spares were last freed.
static LARGEST_FRAME_BUFFER: AtomicUsize = AtomicUsize::new(0);

/// Buffers smaller than this are not worth keeping (their pages are few).
const SPARE_MIN_BYTES: usize = 16 << 20;

/// Streams running now ([`hold_spare_frame_buffers`]): spares are kept only
/// while one runs, so nothing stays allocated once the last one ends.
static SPARE_HOLDERS: AtomicUsize = AtomicUsize::new(0);

/// A stream of scenarios starts: buffers handed back are kept for it.
pub fn hold_spare_frame_buffers() {
    SPARE_HOLDERS.fetch_add(1, Ordering::SeqCst);
}

/// A stream ends: when it was the last, the spares are freed.
pub fn let_go_of_spare_frame_buffers() {
    let mut spares = SPARE_FRAME_BUFFERS.lock().unwrap_or_else(|e| e.into_inner());
    if SPARE_HOLDERS.fetch_sub(1, Ordering::SeqCst) == 1 {
        spares.clear();
        LARGEST_FRAME_BUFFER.store(0, Ordering::SeqCst);
    }
}

/// Hands a frame buffer back for reuse: kept while a stream runs and the
/// spares stay under [`SPARE_FRAME_BYTES`], else freed.
pub fn recycle_frame_buffer(buffer: Vec<u8>) {
    if buffer.capacity() < SPARE_MIN_BYTES {
        return;
    }
    let mut spares = SPARE_FRAME_BUFFERS.lock().unwrap_or_else(|e| e.into_inner());
    let kept: usize = spares.iter().map(Vec::capacity).sum();
    let limit = SPARE_FRAME_BYTES.max(LARGEST_FRAME_BUFFER.load(Ordering::SeqCst).saturating_mul(3));
    if SPARE_HOLDERS.load(Ordering::SeqCst) > 0 && kept + buffer.capacity() <= limit {
        spares.push(buffer);
    }
}

/// An empty buffer with room for `len` bytes of frames: a spare one of
/// about that size when there is one, else a fresh one. On Linux the kernel
/// is asked to back a fresh one with transparent huge pages (2 MiB): a
/// scenario's frames are hundreds of megabytes, written once, and filling
/// them 4 KiB page by page cost about as much as drawing them (measured:
/// 364 ms per 150-frame city scenario before, 188 ms after).
///
/// `None` when the memory cannot be had: the allocator refuses (a memory
/// limit), or the buffer is larger than the memory the OS has available,
/// which Linux would otherwise promise and then end the process over.
fn frame_buffer(len: usize) -> Option<Vec<u8>> {
    if len >= SPARE_MIN_BYTES {
        LARGEST_FRAME_BUFFER.fetch_max(len, Ordering::SeqCst);
        let mut spares = SPARE_FRAME_BUFFERS.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(i) = spares.iter().position(|b| b.capacity() >= len && b.capacity() <= len + len / 4) {
            let mut buffer = spares.swap_remove(i);
            buffer.clear();
            return Some(buffer);
        }
        if available_memory_bytes().is_some_and(|a| a < len as u64) {
            return None;
        }
    }
    let mut buffer = Vec::new();
    buffer.try_reserve_exact(len).ok()?;
    #[cfg(target_os = "linux")]
    {
        const HUGE_PAGE: usize = 2 << 20;
        let start = buffer.as_ptr() as usize;
        let (first, end) = (start.next_multiple_of(HUGE_PAGE), (start + len) / HUGE_PAGE * HUGE_PAGE);
        if end > first {
            // SAFETY: the range lies inside this vector's own allocation;
            // the advice changes how the kernel backs the pages, never
            // their contents or validity (an error leaves them as they were).
            unsafe { libc::madvise(first as *mut libc::c_void, end - first, libc::MADV_HUGEPAGE) };
        }
    }
    Some(buffer)
}

/// `len` zeroed bytes for a batch of frames that Python fills, taken from
/// the spares as [`frame_buffer`] does (`None` when the memory cannot be
/// had); handed back with [`recycle_frame_buffer`] when its reader lets go.
pub fn batch_frame_buffer(len: usize) -> Option<Vec<u8>> {
    let mut buffer = frame_buffer(len)?;
    buffer.resize(len, 0);
    Some(buffer)
}
