//! Rendering: the static background once per camera, then per frame the cars
//! into an RGB image and an 8-bit instance mask (0 = background, a car's
//! `mask_id` on exactly its pixels, no anti-aliasing).

pub mod background;
pub mod palette;
pub mod weather;

use crate::camera::Camera;
use glam::DVec2;
use std::sync::Arc;
use tiny_skia::{FillRule, Paint, PathBuilder, Pixmap, Rect, Transform};
use weather::SceneLook;

/// What the renderer needs to draw one car in one frame.
#[derive(Debug, Clone, Copy)]
pub struct CarSprite {
    /// Centre on the ground, metres.
    pub position: DVec2,
    /// Heading, radians counter-clockwise from east.
    pub yaw: f64,
    pub length: f64,
    pub width: f64,
    pub colour: [u8; 3],
    pub mask_id: u8,
}

/// Draws frames for one camera over a pre-rendered background.
#[derive(Clone)]
pub struct Renderer {
    pub camera: Camera,
    background: Arc<Pixmap>,
    /// Asphalt coverage per pixel, for wet roads.
    road: Arc<Vec<u8>>,
    /// Roof coverage per pixel, for depth.
    buildings: Arc<Vec<u8>>,
}

/// Height of a car's roof above the road, metres (for depth images).
pub const CAR_HEIGHT_M: f64 = 1.5;

/// One scenario's look: its background under its light, water and fog.
pub struct Scene {
    background: Arc<Pixmap>,
    pub look: SceneLook,
}

/// Reusable per-thread buffers: the finished frame is in `rgb` (row-major,
/// 3 bytes a pixel) and `mask` (1 byte a pixel).
pub struct FrameCanvas {
    rgba: Pixmap,
    mask_rgba: Pixmap,
    pub rgb: Vec<u8>,
    pub mask: Vec<u8>,
}

impl Renderer {
    /// Renders the background of `map` for `camera`, once.
    pub fn new(map: &crate::map::CityMap, camera: Camera) -> Renderer {
        let drawn = background::draw_background(map, &camera);
        Renderer {
            camera,
            background: Arc::new(drawn.pixmap),
            road: Arc::new(drawn.road),
            buildings: Arc::new(drawn.buildings),
        }
    }

    /// Distance from the camera to what each pixel shows, in millimetres
    /// (16-bit, saturating), given the frame's instance mask: cars are
    /// `CAR_HEIGHT_M` tall, buildings `BUILDING_HEIGHT_M`, the ground 0. The
    /// distance runs along the pixel's ray to that height.
    pub fn depth_mm(&self, mask: &[u8], out: &mut Vec<u16>) {
        let camera = &self.camera;
        let (w, h) = (camera.width as usize, camera.height as usize);
        let (cx, cy, focal) = ((w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0, camera.focal_px());
        out.clear();
        out.reserve(w * h);
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let height = if mask[i] != 0 {
                    CAR_HEIGHT_M
                } else if self.buildings[i] >= 128 {
                    background::BUILDING_HEIGHT_M
                } else {
                    0.0
                };
                let (u, v) = ((x as f64 - cx) / focal, (y as f64 - cy) / focal);
                let distance = (camera.altitude_m - height).max(0.0) * (1.0 + u * u + v * v).sqrt();
                out.push((distance * 1000.0).round().min(u16::MAX as f64) as u16);
            }
        }
    }

    /// Prepares the background of a scenario that looks like `look`.
    pub fn scene(&self, look: SceneLook) -> Scene {
        let background = if look.is_clear() {
            self.background.clone()
        } else {
            Arc::new(look.apply_to_background(&self.background, &self.road))
        };
        Scene { background, look }
    }

    /// Buffers sized for this renderer's camera.
    pub fn canvas(&self) -> FrameCanvas {
        let (w, h) = (self.camera.width, self.camera.height);
        FrameCanvas {
            rgba: Pixmap::new(w, h).expect("image size was validated"),
            mask_rgba: Pixmap::new(w, h).expect("image size was validated"),
            rgb: vec![0; (w * h * 3) as usize],
            mask: vec![0; (w * h) as usize],
        }
    }

    /// Draws frame `frame` of `scene` with `cars` (later ones on top) into
    /// `canvas.rgb` and `canvas.mask`.
    pub fn render(&self, canvas: &mut FrameCanvas, scene: &Scene, cars: &[CarSprite], frame: u32) {
        let look = &scene.look;
        canvas.rgba.data_mut().copy_from_slice(scene.background.data());
        canvas.mask_rgba.data_mut().fill(0);
        let world = background::world_to_canvas(&self.camera);
        // Car frame: x forward, y left, origin at the car's centre.
        let car_frame = |car: &CarSprite| {
            let (c, s) = (car.yaw.cos() as f32, car.yaw.sin() as f32);
            world.pre_concat(Transform::from_row(c, s, -s, c, car.position.x as f32, car.position.y as f32))
        };
        // Beams lie on the road, under every car.
        look.draw_headlights(&mut canvas.rgba, cars.iter().map(|c| (car_frame(c), c.length as f32, c.width as f32)));
        for car in cars {
            let t = car_frame(car);
            let (hl, hw) = ((car.length / 2.0) as f32, (car.width / 2.0) as f32);
            let body = Rect::from_ltrb(-hl, -hw, hl, hw).expect("car size was validated");
            let mut paint = Paint { anti_alias: true, ..Paint::default() };
            let body_colour = look.shade(car.colour);
            paint.set_color_rgba8(body_colour[0], body_colour[1], body_colour[2], 255);
            canvas.rgba.fill_rect(body, &paint, t, None);
            // Windscreen towards the front shows the heading.
            let glass_colour = look.shade([36, 40, 52]);
            paint.set_color_rgba8(glass_colour[0], glass_colour[1], glass_colour[2], 255);
            if let Some(glass) = Rect::from_ltrb(hl * 0.15, -hw * 0.8, hl * 0.55, hw * 0.8) {
                canvas.rgba.fill_rect(glass, &paint, t, None);
            }
            let mut mask_paint = Paint { anti_alias: false, ..Paint::default() };
            mask_paint.set_color_rgba8(car.mask_id, 0, 0, 255);
            let path = PathBuilder::from_rect(body);
            canvas.mask_rgba.fill_path(&path, &mask_paint, FillRule::Winding, t, None);
        }
        look.draw_precipitation(&mut canvas.rgba, frame);
        for (dst, src) in canvas.rgb.chunks_exact_mut(3).zip(canvas.rgba.data().chunks_exact(4)) {
            dst.copy_from_slice(&src[..3]);
        }
        for (dst, src) in canvas.mask.iter_mut().zip(canvas.mask_rgba.data().chunks_exact(4)) {
            *dst = src[0];
        }
    }
}
