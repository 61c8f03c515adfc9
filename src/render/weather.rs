//! How confounders look: light level and tint by time of day, darker wet
//! asphalt, a fog veil, rain streaks and snowflakes, headlights at night.
//! Only the RGB frames are affected; masks never are.
//!
//! Light and fog are uniform over the image, so instead of post-processing
//! every frame they are applied once to the scenario's background and to each
//! car's colour (the same result for opaque shapes). Rain and snow are drawn
//! per frame from a seeded stream, so frames are reproducible.

use super::raster::{self, PlacedRect, RgbImage};
use crate::plan::ScenarioPlan;
use crate::world::Trajectories;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use tiny_skia::{Pixmap, Transform};

/// A rain streak's width at 1024 pixels across, pixels.
const STREAK_WIDTH_PX: f32 = 1.0;
/// A rain streak's colour and opacity (of 255).
const STREAK_RGB: [u8; 3] = [200, 210, 225];
const STREAK_ALPHA: u8 = 120;
/// Headlight beams' colour (their opacity grows with darkness).
const BEAM_RGB: [u8; 3] = [255, 236, 170];
/// A snowflake's colour and opacity (of 255).
const FLAKE_RGB: [u8; 3] = [250, 250, 252];
const FLAKE_ALPHA: u8 = 220;

/// Water on asphalt (`cover` 255 = wholly road): darker, with a faint blue sheen.
fn wet_rgb(rgb: [u8; 3], wet: f64, cover: u8) -> [u8; 3] {
    let k = 1.0 - wet * cover as f64 / 255.0;
    [(rgb[0] as f64 * k) as u8, (rgb[1] as f64 * k) as u8, (rgb[2] as f64 * (k + 0.08 * wet)).min(255.0) as u8]
}

/// Colour of fog, and how much of a colour full fog (1.0) replaces by it.
const FOG_RGB: [f64; 3] = [206.0, 208.0, 212.0];
const FOG_VEIL: f64 = 0.65;

/// The visual state of a scenario.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneLook {
    /// 1 in daylight, 0 at night.
    pub daylight: f64,
    pub wetness: f64,
    pub fog: f64,
    pub rain: f64,
    pub snow: f64,
    /// Seeds the precipitation of every frame.
    pub seed: u64,
}

impl SceneLook {
    /// A dry, clear day (the toy world).
    pub fn clear() -> SceneLook {
        SceneLook { daylight: 1.0, wetness: 0.0, fog: 0.0, rain: 0.0, snow: 0.0, seed: 0 }
    }

    /// How a scenario looks at `frame`: its confounders as planned, or as
    /// an intervention changed them; the toy world is always clear.
    pub fn at_frame(plan: &ScenarioPlan, trajectories: &Trajectories, frame: usize) -> SceneLook {
        match plan.world.city() {
            Some(city) => {
                let changed = trajectories.confounder_changes.iter().rev().find(|(from, _)| *from <= frame);
                let c = changed.map_or(&city.confounders, |(_, c)| c);
                let seed = u64::from_le_bytes(city.sim_stream[..8].try_into().expect("8 bytes"));
                SceneLook { daylight: c.daylight(), wetness: c.wetness, fog: c.fog, rain: c.rain, snow: c.snow, seed }
            }
            None => SceneLook::clear(),
        }
    }

    /// How much light falls on the scene: 1 by day, 0.28 at night.
    fn light_level(&self) -> f64 {
        0.28 + 0.72 * self.daylight
    }

    pub fn is_clear(&self) -> bool {
        self.daylight >= 1.0 && self.wetness == 0.0 && self.fog == 0.0 && self.rain == 0.0 && self.snow == 0.0
    }

    /// A colour under this scene's light and fog.
    pub fn shade(&self, rgb: [u8; 3]) -> [u8; 3] {
        let dark = 1.0 - self.daylight;
        let level = self.light_level();
        // Night is blue, dusk and dawn warm.
        let dusk = (std::f64::consts::PI * self.daylight).sin();
        let tint =
            [(1.0 - 0.25 * dark) * (1.0 + 0.10 * dusk), (1.0 - 0.12 * dark) * (1.0 - 0.02 * dusk), 1.0 - 0.12 * dusk];
        let (alpha, fog) = (FOG_VEIL * self.fog, FOG_RGB);
        let mut out = [0u8; 3];
        for k in 0..3 {
            let lit = rgb[k] as f64 * level * tint[k];
            let veiled = (1.0 - alpha) * lit + alpha * fog[k] * level;
            out[k] = veiled.round().clamp(0.0, 255.0) as u8;
        }
        out
    }

    /// A light source's colour under this scene's fog: darkness does not dim
    /// what shines, fog veils it as it veils everything.
    pub fn veil(&self, rgb: [u8; 3]) -> [u8; 3] {
        let (level, alpha, fog) = (self.light_level(), FOG_VEIL * self.fog, FOG_RGB);
        let mut out = [0u8; 3];
        for k in 0..3 {
            out[k] = ((1.0 - alpha) * rgb[k] as f64 + alpha * fog[k] * level).round().clamp(0.0, 255.0) as u8;
        }
        out
    }

    /// The scenario's background from the clear-day one and its road coverage
    /// (255 on asphalt).
    pub fn apply_to_background(&self, base: &Pixmap, road: &[u8]) -> Pixmap {
        let mut out = base.clone();
        let wet = 0.38 * self.wetness;
        // shade() acts on each channel alone: tabulate it once, and likewise
        // for fully covered wet asphalt; only road edges need arithmetic.
        let mut table = [[0u8; 256]; 3];
        let mut wet_table = [[0u8; 256]; 3];
        for v in 0..256 {
            let shaded = self.shade([v as u8; 3]);
            let wet_shaded = self.shade(wet_rgb([v as u8; 3], wet, 255));
            for k in 0..3 {
                table[k][v] = shaded[k];
                wet_table[k][v] = wet_shaded[k];
            }
        }
        for (px, &cover) in out.data_mut().chunks_exact_mut(4).zip(road) {
            let (rgb, lut) = match cover {
                _ if cover == 0 || wet == 0.0 => ([px[0], px[1], px[2]], &table),
                255 => ([px[0], px[1], px[2]], &wet_table),
                _ => (wet_rgb([px[0], px[1], px[2]], wet, cover), &table),
            };
            for k in 0..3 {
                px[k] = lut[k][rgb[k] as usize];
            }
        }
        out
    }

    /// Headlight beams (at dusk and night) of every car, each given as its
    /// car-frame transform (x forward, y left, metres) and length and width,
    /// drawn over the road in one pass.
    pub fn draw_headlights(&self, image: &mut RgbImage, cars: impl Iterator<Item = (Transform, f32, f32)>) {
        if !self.shows_beams() {
            return;
        }
        let strength = (1.0 - self.daylight) as f32;
        // Soft translucent light: hard edges look alike and cost far less.
        let alpha = (110.0 * strength) as u8;
        for (to_canvas, length, width) in cars {
            let front = length / 2.0;
            let beams = [-1.0f32, 1.0].map(|side| {
                let y = side * width * 0.3;
                let mut points = [
                    tiny_skia::Point::from_xy(front, y - 0.1),
                    tiny_skia::Point::from_xy(front + 3.5, y - 0.9),
                    tiny_skia::Point::from_xy(front + 3.5, y + 0.9),
                    tiny_skia::Point::from_xy(front, y + 0.1),
                ];
                to_canvas.map_points(&mut points);
                raster::ConvexQuad::new(points.map(|p| (p.x, p.y)))
            });
            // A car's two beams overlap ahead of it: that light is not doubled.
            raster::fill_hard_union(image, beams, BEAM_RGB, alpha);
        }
    }

    /// Whether cars' headlights draw beams (at dusk and night).
    pub fn shows_beams(&self) -> bool {
        (1.0 - self.daylight) as f32 > 0.05
    }

    /// Rain streaks and snowflakes of frame `frame`, in pixel space.
    pub fn draw_precipitation(&self, image: &mut RgbImage, frame: u32) {
        self.draw_precipitation_saving(image, frame, None);
    }

    /// [`SceneLook::draw_precipitation`], saving in `undo` (when given)
    /// every pixel before a streak or flake changes it.
    pub fn draw_precipitation_saving(&self, image: &mut RgbImage, frame: u32, mut undo: Option<&mut raster::Undo>) {
        if self.rain <= 0.0 && self.snow <= 0.0 {
            return;
        }
        let (w, h) = (image.width as f32, image.height as f32);
        let scale = w / 1024.0;
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed ^ (frame as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15));
        let streaks = (200.0 * self.rain * (w * h / (1024.0 * 640.0)) as f64) as usize;
        for _ in 0..streaks {
            let x = rng.random_range(0.0..w);
            let y = rng.random_range(0.0..h);
            let len = rng.random_range(8.0..16.0) * scale;
            // Along the streak from its top, and across it.
            let (dx, dy) = (-0.35 * len, len);
            let reach = (dx * dx + dy * dy).sqrt();
            let (ux, uy) = (dx / reach, dy / reach);
            let along = Transform::from_row(ux, uy, -uy, ux, x, y);
            let half = STREAK_WIDTH_PX * scale;
            // Hard-edged streaks: cheaper to draw and to compress, alike to the eye.
            if let Some(streak) = PlacedRect::new(along, (0.0, reach), (-half / 2.0, half / 2.0)) {
                raster::fill_hard(image, &streak, STREAK_RGB, STREAK_ALPHA, undo.as_deref_mut());
            }
        }
        let flakes = (420.0 * self.snow * (w * h / (1024.0 * 640.0)) as f64) as usize;
        for _ in 0..flakes {
            let x = rng.random_range(0.0..w);
            let y = rng.random_range(0.0..h);
            let size = rng.random_range(1.5..3.5) * scale;
            if let Some(flake) = PlacedRect::new(Transform::identity(), (x, x + size), (y, y + size)) {
                raster::fill_hard(image, &flake, FLAKE_RGB, FLAKE_ALPHA, undo.as_deref_mut());
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn night_is_darker_and_fog_greyer() {
        let clear = SceneLook::clear();
        assert_eq!(clear.shade([100, 150, 200]), [100, 150, 200]);
        let night = SceneLook { daylight: 0.0, ..clear };
        let n = night.shade([100, 150, 200]);
        assert!(n.iter().zip([100, 150, 200]).all(|(a, b)| (*a as i32) < b));
        let fog = SceneLook { fog: 1.0, ..clear }.shade([0, 0, 0]);
        assert!(fog[0] > 100);
    }
}
