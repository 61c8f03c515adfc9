//! One writer for a simulated scenario folder: the ground truth, the logs
//! and, with images, the bird's-eye frames and every extra camera's frames,
//! masks, depth and pixel log, all through the same frame encoder and the
//! file names of [`super::layout`]. It takes plans, trajectories and
//! renderers as plain data; it knows nothing of dynamics.

use super::annotations::{AnnotatedCar, AnnotationsBuilder, ANNOTATIONS_FILE};
use super::footage::{signal_heads, Footage};
use super::layout::{
    CameraFolder, FrameKind, ScenarioLayout, EFFECTS_CSV, EVENTS_CSV, INTERACTIONS_CSV, POSES_CSV, SCENARIO_JSON,
};
use super::logs::{write_effects, write_events, write_interactions, write_lights};
use super::manifest::{LightsLog, Products};
use super::number::{logged_value, push_fixed};
use super::png::{encode_png, PixelFormat, PngSettings};
use super::poses::{write_pixels, write_poses, PIXELS_FILE, PIXEL_DECIMALS};
use super::scenario::scenario_json;
use super::{ScenarioDir, WriteError};
use crate::camera::{Camera, CameraKind, CameraPlan, Pinhole};
use crate::map::CityMap;
use crate::plan::ScenarioPlan;
use crate::render::perspective::{self, PerspectiveRenderer, World3d};
use crate::render::weather::SceneLook;
use crate::render::{FrameCanvas, Renderer, Scene, CAR_HEIGHT_M};
use crate::spec::BirdsEyeView;
use crate::timing::{Stage, StageTimes};
use crate::world::effects::EffectReport;
use crate::world::{CarState, Trajectories};
use glam::DVec2;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

/// Why a scenario was not written.
#[derive(Debug, thiserror::Error)]
pub enum ScenarioWriteError {
    #[error(transparent)]
    Write(#[from] WriteError),
    /// The stop flag was raised; nothing of the scenario is kept.
    #[error("interrupted")]
    Interrupted,
    /// The way to the folder is a link, or the folder there holds what
    /// causalcity did not write; nothing is written.
    #[error(transparent)]
    Refused(#[from] super::Refused),
}

/// Writes scenarios of one run; shared by the run's threads.
pub struct ScenarioWriter {
    map: Arc<CityMap>,
    camera: Camera,
    renderer: Option<Renderer>,
    leader_gap_px: f64,
    intersection_names: Vec<String>,
    fsync: bool,
    products: Products,
    /// The map as solids, for perspective cameras (built on first use).
    world3d: std::sync::OnceLock<World3d>,
}

/// One thread's reusable buffers: the bird's-eye canvas, encoded PNG bytes
/// and depth values.
pub struct WriterBuffers {
    canvas: Option<FrameCanvas>,
    png: Vec<u8>,
    depth: Vec<u16>,
    depth_bytes: Vec<u8>,
}

impl ScenarioWriter {
    /// A writer for scenarios seen by `camera` over `map`; the bird's-eye
    /// background is drawn here, once, when images are asked for.
    pub fn new(map: Arc<CityMap>, camera: Camera, leader_gap_px: f64, products: Products, fsync: bool) -> Self {
        ScenarioWriter {
            renderer: products.images.then(|| Renderer::new(&map, camera)),
            intersection_names: map.intersections.iter().map(|i| i.name.clone()).collect(),
            map,
            camera,
            leader_gap_px,
            fsync,
            products: Products { annotations: products.annotations && products.images, ..products },
            world3d: std::sync::OnceLock::new(),
        }
    }

    /// Buffers for one thread.
    pub fn buffers(&self) -> WriterBuffers {
        WriterBuffers {
            canvas: self.renderer.as_ref().map(Renderer::canvas),
            png: Vec::new(),
            depth: Vec::new(),
            depth_bytes: Vec::new(),
        }
    }

    /// Which optional files this writer writes.
    pub fn products(&self) -> Products {
        self.products
    }

    /// The files `plan` gets from this writer.
    pub fn layout(&self, plan: &ScenarioPlan) -> ScenarioLayout {
        ScenarioLayout::new(
            plan.frames,
            plan.world.city().is_some(),
            self.products,
            plan.cameras.iter().map(|c| CameraFolder { name: c.name.clone(), depth: c.depth }).collect(),
        )
    }

    /// Writes a simulated scenario into the folder `target` inside the
    /// output folder `root`, atomically; returns the bytes written. Checks
    /// `stop` every frame. `effects` are the scenario's measured
    /// interventional effects, written when this writer's products ask for
    /// them. Refuses a link on the way from `root`, and a folder at
    /// `target` that holds files causalcity did not write (a rewrite
    /// replaces the folder whole).
    #[allow(clippy::too_many_arguments)]
    pub fn write(
        &self,
        plan: &ScenarioPlan,
        trajectories: &Trajectories,
        effects: Option<&EffectReport>,
        (root, target): (&Path, PathBuf),
        buffers: &mut WriterBuffers,
        stop: &AtomicBool,
        times: &StageTimes,
    ) -> Result<u64, ScenarioWriteError> {
        let layout = self.layout(plan);
        super::refuse_links_below(root, &target)?;
        if std::fs::symlink_metadata(&target).is_ok_and(|m| m.is_dir()) {
            super::refuse_foreign(&target, &super::OwnFiles::SCENARIO, "a new scenario folder")?;
        }
        let camera = &self.camera;
        let mut dir = ScenarioDir::begin(target, &layout, self.fsync, times)?;
        let model = crate::world::model_name(&plan.world);
        let effects = effects.filter(|_| layout.effects);
        let record = scenario_json(plan, camera, self.leader_gap_px, &self.intersection_names, model, effects);
        let mut bytes = dir.write_file(SCENARIO_JSON, &record)?;
        let ids: Vec<u32> = plan.cars.iter().map(|c| c.id).collect();
        bytes += dir.write_with(POSES_CSV, |w| write_poses(w, &ids, trajectories, camera))?;
        bytes += dir.write_with(PIXELS_FILE, |w| write_pixels(w, trajectories, camera))?;
        let heads = signal_heads(&self.map, plan);
        if let Some(city) = plan.world.city() {
            let names = &self.intersection_names;
            let head_pixels: Vec<Option<DVec2>> = heads.iter().map(|h| h.map(|p| camera.to_pixel(p))).collect();
            let changes = layout.lights == LightsLog::Changes;
            bytes += dir.write_with(layout.lights_file(), |w| {
                write_lights(w, &city.lights, names, &head_pixels, trajectories, changes)
            })?;
            bytes += dir.write_with(EVENTS_CSV, |w| write_events(w, &city.lights, names, trajectories))?;
            bytes += dir.write_with(INTERACTIONS_CSV, |w| write_interactions(w, &city.lights, names, trajectories))?;
        }
        if let Some(report) = effects {
            bytes += dir.write_with(EFFECTS_CSV, |w| write_effects(w, report))?;
        }
        if let (Some(renderer), Some(canvas)) = (&self.renderer, buffers.canvas.as_mut()) {
            let mut frames = FrameWriter { dir: &mut dir, layout: &layout, png: &mut buffers.png, times, stop };
            let footage = Footage::new(plan, trajectories, &heads);
            let world =
                (plan.birds_eye == BirdsEyeView::Pinhole).then(|| self.world3d.get_or_init(|| World3d::new(&self.map)));
            bytes += frames.birds_eye(renderer, canvas, world, &footage, self.products.annotations)?;
            for camera_plan in &plan.cameras {
                bytes += if camera_plan.kind.is_perspective() {
                    let world = self.world3d.get_or_init(|| World3d::new(&self.map));
                    frames.perspective_camera(
                        world,
                        &footage,
                        camera_plan,
                        &mut buffers.depth,
                        &mut buffers.depth_bytes,
                    )?
                } else {
                    frames.extra_camera(
                        &self.map,
                        &footage,
                        camera_plan,
                        &mut buffers.depth,
                        &mut buffers.depth_bytes,
                    )?
                };
            }
        }
        // A stop raised while simulating may have cut the trajectories
        // short: nothing is committed once it is set.
        if stop.load(Ordering::Relaxed) {
            return Err(ScenarioWriteError::Interrupted);
        }
        bytes += dir.commit()?;
        Ok(bytes)
    }
}

/// Renders, encodes and writes frames into one scenario folder.
struct FrameWriter<'a, 't> {
    dir: &'a mut ScenarioDir<'t>,
    layout: &'a ScenarioLayout,
    png: &'a mut Vec<u8>,
    times: &'t StageTimes,
    stop: &'a AtomicBool,
}

impl FrameWriter<'_, '_> {
    fn check_stop(&self) -> Result<(), ScenarioWriteError> {
        if self.stop.load(Ordering::Relaxed) {
            return Err(ScenarioWriteError::Interrupted);
        }
        Ok(())
    }

    /// Encodes an image into the PNG buffer, then writes it as `name`.
    fn image(&mut self, name: &str, (w, h): (u32, u32), format: PixelFormat, data: &[u8]) -> Result<u64, WriteError> {
        let start = Instant::now();
        self.png.clear();
        encode_png(&mut *self.png, w, h, format, data, PngSettings::for_format(format))
            .map_err(|e| WriteError { path: PathBuf::from(name), source: std::io::Error::other(e) })?;
        self.times.add(Stage::Encode, start.elapsed());
        self.dir.write_file(name, self.png)
    }

    /// Millimetres as a 16-bit PNG (big-endian samples, through `bytes`).
    fn depth_image(
        &mut self,
        name: &str,
        size: (u32, u32),
        mm: &[u16],
        bytes: &mut Vec<u8>,
    ) -> Result<u64, WriteError> {
        let start = Instant::now();
        bytes.clear();
        bytes.extend(mm.iter().flat_map(|d| d.to_be_bytes()));
        self.times.add(Stage::Render, start.elapsed());
        self.image(name, size, PixelFormat::Gray16, bytes)
    }

    /// A frame's RGB image and instance mask.
    fn rgb_and_mask(&mut self, names: [&str; 2], canvas: &FrameCanvas, size: (u32, u32)) -> Result<u64, WriteError> {
        Ok(self.image(names[0], size, PixelFormat::Rgb8, &canvas.rgb)?
            + self.image(names[1], size, PixelFormat::Gray8, &canvas.mask)?)
    }

    /// The bird's-eye view: rgb/, mask/ and, when asked, annotations.json.
    fn birds_eye(
        &mut self,
        renderer: &Renderer,
        canvas: &mut FrameCanvas,
        world: Option<&World3d>,
        footage: &Footage,
        annotations: bool,
    ) -> Result<u64, ScenarioWriteError> {
        let Footage { plan, trajectories, .. } = *footage;
        let size = (renderer.camera.width, renderer.camera.height);
        let scenario_name = plan.key.folder_name();
        let annotated_cars: Vec<AnnotatedCar> =
            plan.cars.iter().map(|c| AnnotatedCar { id: c.id, name: c.name.clone(), mask_id: c.mask_id }).collect();
        let mut builder = annotations.then(|| AnnotationsBuilder::new(&scenario_name, size.0, size.1, &annotated_cars));
        let mut pixels = Vec::with_capacity(plan.cars.len());
        let mut bytes = 0;
        let times = self.times;
        footage.birds_eye(renderer, canvas, world, times, |frame, rgb, mask| {
            self.check_stop()?;
            let rgb_name = self.layout.frame_name(FrameKind::Rgb, frame);
            let mask_name = self.layout.frame_name(FrameKind::Mask, frame);
            bytes += self.image(&rgb_name, size, PixelFormat::Rgb8, rgb)?;
            bytes += self.image(&mask_name, size, PixelFormat::Gray8, mask)?;
            if let Some(builder) = builder.as_mut() {
                pixels.clear();
                pixels.extend(trajectories.states[frame as usize].iter().map(|s| {
                    let p = renderer.camera.to_pixel(s.position);
                    [logged_value(p.x, PIXEL_DECIMALS), logged_value(p.y, PIXEL_DECIMALS)]
                }));
                times.time(Stage::Encode, || builder.add_frame(frame, rgb_name, mask_name, mask, &pixels));
            }
            Ok::<(), ScenarioWriteError>(())
        })?;
        if let Some(builder) = builder {
            bytes += self.dir.write_file(ANNOTATIONS_FILE, &builder.to_json())?;
        }
        Ok(bytes)
    }

    /// One perspective camera under `cameras/<name>/`: rgb/, mask/, depth/
    /// (16-bit, millimetres along each pixel's ray) when asked, and
    /// poses.csv (frame, car, px, py, in_view, visible_px): each car's
    /// centre (half its height up) in this camera's pixels (empty when
    /// behind it), whether that lies on the image, and how many pixels of
    /// the car are visible.
    fn perspective_camera(
        &mut self,
        world: &World3d,
        footage: &Footage,
        camera_plan: &CameraPlan,
        depth: &mut Vec<u16>,
        depth_bytes: &mut Vec<u8>,
    ) -> Result<u64, ScenarioWriteError> {
        let Footage { plan, trajectories, .. } = *footage;
        let name = &camera_plan.name;
        let size = (camera_plan.width, camera_plan.height);
        let followed = camera_plan.kind.followed_car();
        let hidden = match camera_plan.kind {
            CameraKind::FirstPerson { car } => plan.cars.get(car).map(|c| c.mask_id),
            _ => None,
        };
        let mut renderer = PerspectiveRenderer::new();
        let mut look = SceneLook::clear();
        let mut pinhole: Option<Pinhole> = None;
        let mut frame_buffer = None;
        let mut poses = b"frame,car,px,py,in_view,visible_px\n".to_vec();
        let mut bytes = 0;
        let (mut sprites, mut head_sprites) = (Vec::new(), Vec::new());
        // A camera whose car is removed stays where the car left.
        let mut last_follow = None;
        for (frame, states) in trajectories.states.iter().enumerate() {
            self.check_stop()?;
            let follow = followed
                .and_then(|k| Some((states.get(k)?, plan.cars.get(k)?)))
                .filter(|(s, car)| !s.is_parked(car.id))
                .or(last_follow);
            last_follow = follow;
            let camera = camera_plan
                .pinhole_at(follow.map(|(s, c)| (s.position, s.yaw, c.length)), pinhole.as_ref())
                .expect("a perspective kind has a pinhole");
            pinhole = Some(camera);
            footage.fill_sprites(&mut sprites, &mut head_sprites, frame);
            let target = frame_buffer.get_or_insert_with(|| perspective::empty_frame(&camera));
            if frame == 0 || trajectories.confounder_changes.iter().any(|(from, _)| *from == frame) {
                look = SceneLook::at_frame(plan, trajectories, frame);
            }
            let frame = frame as u32;
            self.times.time(Stage::Render, || {
                renderer.render(world, &camera, &look, &head_sprites, &sprites, hidden, target);
                perspective::draw_precipitation(&look, frame, target);
            });
            let [rgb_name, mask_name, depth_name] = [FrameKind::Rgb, FrameKind::Mask, FrameKind::Depth]
                .map(|k| self.layout.camera_frame_name(name, k, frame));
            bytes += self.image(&rgb_name, size, PixelFormat::Rgb8, &target.rgb)?;
            bytes += self.image(&mask_name, size, PixelFormat::Gray8, &target.mask)?;
            if camera_plan.depth {
                self.times.time(Stage::Render, || target.depth_mm(depth));
                bytes += self.depth_image(&depth_name, size, depth, depth_bytes)?;
            }
            let visible = target.mask_counts();
            for (car, state) in plan.cars.iter().zip(states) {
                let centre = glam::DVec3::new(state.position.x, state.position.y, CAR_HEIGHT_M / 2.0);
                let pixel = camera.to_pixel(centre);
                let in_view = !state.is_parked(car.id) && pixel.is_some_and(|p| camera.contains_pixel(p));
                push_camera_pose(&mut poses, frame, car.id, pixel, in_view, Some(visible[car.mask_id as usize]));
            }
        }
        bytes += self.dir.write_file(&ScenarioLayout::camera_poses(name), &poses)?;
        Ok(bytes)
    }

    /// One extra camera under `cameras/<name>/`: rgb/, mask/, depth/
    /// (16-bit, millimetres) when asked, and poses.csv (frame, car, px, py,
    /// in_view) in this camera's pixels.
    fn extra_camera(
        &mut self,
        map: &CityMap,
        footage: &Footage,
        camera_plan: &CameraPlan,
        depth: &mut Vec<u16>,
        depth_bytes: &mut Vec<u8>,
    ) -> Result<u64, ScenarioWriteError> {
        let Footage { plan, trajectories, .. } = *footage;
        let name = &camera_plan.name;
        let chased = |states: &[CarState]| match camera_plan.kind {
            CameraKind::Chase { car } => {
                let id = plan.cars.get(car)?.id;
                states.get(car).filter(|s| !s.is_parked(id)).map(|s| (s.position, s.yaw))
            }
            _ => None,
        };
        let size = (camera_plan.width, camera_plan.height);
        // A static camera draws its background once; a chase camera every frame.
        let mut fixed: Option<(Renderer, Scene)> = None;
        let mut canvas: Option<FrameCanvas> = None;
        let mut poses = b"frame,car,px,py,in_view\n".to_vec();
        let mut bytes = 0;
        let mut sprites = Vec::with_capacity(plan.cars.len());
        let mut head_sprites = Vec::with_capacity(footage.heads.len());
        // A chase camera whose car is removed stays where the car left.
        let mut last_chased = None;
        for (frame, states) in trajectories.states.iter().enumerate() {
            self.check_stop()?;
            last_chased = chased(states).or(last_chased);
            let camera = camera_plan.camera_at(last_chased);
            let look = SceneLook::at_frame(plan, trajectories, frame);
            if trajectories.confounder_changes.iter().any(|(from, _)| *from == frame) {
                fixed = None;
            }
            // Drawing the background (once for a fixed camera, every frame
            // for a moving one) counts as rendering.
            let background = || {
                self.times.time(Stage::Render, || {
                    let r = Renderer::new(map, camera);
                    let s = r.scene(look);
                    (r, s)
                })
            };
            let owned;
            let (renderer, scene) = match camera_plan.kind {
                CameraKind::Static { .. } => {
                    let (r, s) = fixed.get_or_insert_with(background);
                    (&*r, &*s)
                }
                _ => {
                    owned = background();
                    (&owned.0, &owned.1)
                }
            };
            let canvas = canvas.get_or_insert_with(|| renderer.canvas());
            footage.fill_sprites(&mut sprites, &mut head_sprites, frame);
            let frame = frame as u32;
            self.times.time(Stage::Render, || renderer.render(canvas, scene, &sprites, &head_sprites, frame));
            let [rgb_name, mask_name, depth_name] = [FrameKind::Rgb, FrameKind::Mask, FrameKind::Depth]
                .map(|k| self.layout.camera_frame_name(name, k, frame));
            bytes += self.rgb_and_mask([&rgb_name, &mask_name], canvas, size)?;
            if camera_plan.depth {
                self.times.time(Stage::Render, || renderer.depth_mm(&canvas.mask, depth));
                bytes += self.depth_image(&depth_name, size, depth, depth_bytes)?;
            }
            for (car, state) in plan.cars.iter().zip(states) {
                let pixel = camera.to_pixel(state.position);
                let in_view = !state.is_parked(car.id) && camera.contains_pixel(pixel);
                push_camera_pose(&mut poses, frame, car.id, Some(pixel), in_view, None);
            }
        }
        bytes += self.dir.write_file(&ScenarioLayout::camera_poses(name), &poses)?;
        Ok(bytes)
    }
}

/// One row of an extra camera's poses.csv: frame, car, px, py (both empty
/// for a car behind a perspective camera), in_view, and visible_px where the
/// camera counts it.
fn push_camera_pose(
    out: &mut Vec<u8>,
    frame: u32,
    car: u32,
    pixel: Option<DVec2>,
    in_view: bool,
    visible_px: Option<usize>,
) {
    use std::io::Write;
    // Writing into a Vec cannot fail.
    let _ = write!(out, "{frame},{car},");
    if let Some(p) = pixel {
        push_fixed(out, p.x, PIXEL_DECIMALS);
        out.push(b',');
        push_fixed(out, p.y, PIXEL_DECIMALS);
    } else {
        out.push(b',');
    }
    let _ = write!(out, ",{}", in_view as u8);
    if let Some(n) = visible_px {
        let _ = write!(out, ",{n}");
    }
    out.push(b'\n');
}
