//! What the frames of one scenario show, and the one loop that draws its
//! bird's-eye frames: shared by the file writer and the in-memory arrays, so
//! both hold the same pixels.

use crate::map::CityMap;
use crate::plan::ScenarioPlan;
use crate::render::palette::colour_of;
use crate::render::weather::SceneLook;
use crate::render::{CarSprite, FrameCanvas, HeadSprite, Renderer};
use crate::spec::SignalHeads;
use crate::timing::{Stage, StageTimes};
use crate::world::{CarState, Trajectories};
use glam::DVec2;

/// Where each light of a city plan has its signal head (in light-plan
/// order), metres; empty for the toy world.
pub fn signal_heads(map: &CityMap, plan: &ScenarioPlan) -> Vec<Option<DVec2>> {
    plan.world.city().map_or_else(Vec::new, |city| {
        city.lights.lights.iter().map(|l| map.signal_head(l.intersection, l.approach, l.signal)).collect()
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
        sprites.extend(plan.cars.iter().zip(states).enumerate().map(|(i, (car, s))| CarSprite {
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

    /// Draws every bird's-eye frame into `canvas` in order and hands each to
    /// `each` (frame index, the drawn canvas); stops at `each`'s first error.
    /// The scene's look is redrawn only where an intervention changed the
    /// confounders.
    pub fn birds_eye<E>(
        &self,
        renderer: &Renderer,
        canvas: &mut FrameCanvas,
        times: &StageTimes,
        mut each: impl FnMut(u32, &FrameCanvas) -> Result<(), E>,
    ) -> Result<(), E> {
        let (plan, trajectories) = (self.plan, self.trajectories);
        let mut scene = renderer.scene(SceneLook::at_frame(plan, trajectories, 0));
        let mut sprites = Vec::with_capacity(plan.cars.len());
        let mut head_sprites = Vec::with_capacity(self.heads.len());
        for frame in 0..trajectories.frames() {
            if frame > 0 && trajectories.confounder_changes.iter().any(|(from, _)| *from == frame) {
                scene = renderer.scene(SceneLook::at_frame(plan, trajectories, frame));
            }
            self.fill_sprites(&mut sprites, &mut head_sprites, frame);
            let frame = frame as u32;
            times.time(Stage::Render, || renderer.render(canvas, &scene, &sprites, &head_sprites, frame));
            each(frame, canvas)?;
        }
        Ok(())
    }
}
