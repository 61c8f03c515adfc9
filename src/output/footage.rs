//! What the frames of one scenario show, and the one loop that draws its
//! bird's-eye frames: shared by the file writer and the in-memory arrays, so
//! both hold the same pixels.

use crate::camera::{Camera, Pinhole};
use crate::map::CityMap;
use crate::plan::ScenarioPlan;
use crate::render::palette::colour_of;
use crate::render::perspective::{draw_precipitation, empty_frame, PerspectiveRenderer, World3d};
use crate::render::weather::SceneLook;
use crate::render::{CarSprite, FrameCanvas, HeadSprite, Renderer};
use crate::spec::{BirdsEyeView, SignalHeads};
use crate::timing::{Stage, StageTimes};
use crate::world::{CarState, Trajectories};
use glam::DVec2;

/// Where each light of a city plan has its signal head (in light-plan
/// order), metres; empty for the toy world.
pub fn signal_heads(map: &CityMap, plan: &ScenarioPlan) -> Vec<Option<DVec2>> {
    plan.world.city().map_or_else(Vec::new, |city| {
        city.lights.lights.iter().map(|l| map.signal_head(l.intersection, l.approach, l.signal, l.variant)).collect()
    })
}

/// The signal heads the frames draw: all of them, unless the plan hides them.
fn drawn_heads(plan: &ScenarioPlan, heads: &[Option<DVec2>]) -> Vec<Option<DVec2>> {
    match plan.world.city() {
        Some(city) if city.signal_heads == SignalHeads::Visible => heads.to_vec(),
        _ => Vec::new(),
    }
}

/// What the frames of one scenario show: its plan, what happened, and the
/// signal heads they draw (metres, in light-plan order; none when hidden).
pub struct Footage<'a> {
    pub plan: &'a ScenarioPlan,
    pub trajectories: &'a Trajectories,
    pub heads: Vec<Option<DVec2>>,
}

impl<'a> Footage<'a> {
    /// The footage of a simulated scenario; `heads` as [`signal_heads`] gives them.
    pub fn new(plan: &'a ScenarioPlan, trajectories: &'a Trajectories, heads: &[Option<DVec2>]) -> Self {
        Footage { plan, trajectories, heads: drawn_heads(plan, heads) }
    }

    /// The cars and signal heads of `frame` as the renderer draws them;
    /// brake lights in the city world only (the toy world has no drivers).
    pub fn fill_sprites(&self, sprites: &mut Vec<CarSprite>, head_sprites: &mut Vec<HeadSprite>, frame: usize) {
        let (plan, trajectories) = (self.plan, self.trajectories);
        let states: &[CarState] = &trajectories.states[frame];
        let city = plan.world.city().is_some();
        sprites.clear();
        // A removed car (parked off the map) is drawn by no camera, though
        // one may look at its parking spot.
        let on_map = plan.cars.iter().zip(states).enumerate().filter(|(_, (car, s))| !s.is_parked(car.id));
        sprites.extend(on_map.map(|(i, (car, s))| CarSprite {
            position: s.position,
            yaw: s.yaw,
            length: car.length,
            width: car.width,
            colour: colour_of(car),
            mask_id: car.mask_id,
            braking: city && trajectories.braking(frame, i),
        }));
        head_sprites.clear();
        if let Some(colours) = trajectories.lights.get(frame) {
            head_sprites.extend(
                self.heads
                    .iter()
                    .zip(colours)
                    .filter_map(|(head, state)| head.map(|position| HeadSprite { position, colour: state.colour })),
            );
        }
    }

    /// Draws every bird's-eye frame in order and hands each to `each`
    /// (frame index, RGB, mask); stops at `each`'s first error. Flat frames
    /// are drawn into `canvas`, the scene's look redrawn only where an
    /// intervention changed the confounders; a plan that asks for the
    /// pinhole view is drawn in perspective over `world` (needed then).
    pub fn birds_eye<E>(
        &self,
        renderer: &Renderer,
        canvas: &mut FrameCanvas,
        world: Option<&World3d>,
        times: &StageTimes,
        mut each: impl FnMut(u32, &[u8], &[u8]) -> Result<(), E>,
    ) -> Result<(), E> {
        let (plan, trajectories) = (self.plan, self.trajectories);
        let mut sprites = Vec::with_capacity(plan.cars.len());
        let mut head_sprites = Vec::with_capacity(self.heads.len());
        if let (BirdsEyeView::Pinhole, Some(world)) = (plan.birds_eye, world) {
            let pinhole = birds_eye_pinhole(&renderer.camera);
            let mut perspective = PerspectiveRenderer::new();
            let mut frame = empty_frame(&pinhole);
            let mut look = SceneLook::at_frame(plan, trajectories, 0);
            for f in 0..trajectories.frames() {
                if f > 0 && trajectories.confounder_changes.iter().any(|(from, _)| *from == f) {
                    look = SceneLook::at_frame(plan, trajectories, f);
                }
                self.fill_sprites(&mut sprites, &mut head_sprites, f);
                times.time(Stage::Render, || {
                    perspective.render(world, &pinhole, &look, &head_sprites, &sprites, None, &mut frame);
                    draw_precipitation(&look, f as u32, &mut frame);
                });
                each(f as u32, &frame.rgb, &frame.mask)?;
            }
            return Ok(());
        }
        // The scenario's background under its light and water is drawing
        // too: it counts as rendering.
        let mut scene = times.time(Stage::Render, || renderer.scene(SceneLook::at_frame(plan, trajectories, 0)));
        for frame in 0..trajectories.frames() {
            if frame > 0 && trajectories.confounder_changes.iter().any(|(from, _)| *from == frame) {
                scene = times.time(Stage::Render, || renderer.scene(SceneLook::at_frame(plan, trajectories, frame)));
            }
            self.fill_sprites(&mut sprites, &mut head_sprites, frame);
            let frame = frame as u32;
            times.time(Stage::Render, || renderer.render(canvas, &scene, &sprites, &head_sprites, frame));
            each(frame, &canvas.rgb, &canvas.mask)?;
        }
        Ok(())
    }
}

/// A straight-down bird's-eye camera as the pinhole it models: the same
/// place, altitude, lens and image, so ground points land on the same pixels.
pub fn birds_eye_pinhole(camera: &Camera) -> Pinhole {
    Pinhole {
        width: camera.width,
        height: camera.height,
        position: [camera.centre_x, camera.centre_y, camera.altitude_m],
        yaw_rad: std::f64::consts::FRAC_PI_2 + camera.rotation_rad,
        pitch_rad: -std::f64::consts::FRAC_PI_2,
        roll_rad: 0.0,
        horizontal_fov_deg: camera.horizontal_fov_deg,
    }
}
