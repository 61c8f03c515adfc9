//! Rendering: the static background once per camera, then per frame the
//! signal heads and the cars into an RGB image and an 8-bit instance mask (0
//! = background, a car's `mask_id` on exactly its pixels, no anti-aliasing;
//! signal heads and brake lights are never in the mask).

pub mod background;
pub mod network;
pub mod palette;
pub mod perspective;
pub mod raster;
pub mod text;
pub mod weather;

use crate::camera::Camera;
use crate::map::signals::Colour;
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
    /// Brake lights on (drawn inside the body, so the mask is the same).
    pub braking: bool,
}

/// What the renderer needs to draw one signal head in one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeadSprite {
    /// Centre on the ground, metres.
    pub position: DVec2,
    /// The colour it shows.
    pub colour: Colour,
}

/// Side of a signal head's dark housing, metres.
pub const HEAD_HOUSING_M: f64 = 0.9;
/// Radius of its lit lamp, metres.
pub const HEAD_LAMP_RADIUS_M: f64 = 0.33;
/// A lamp's light in each colour (lamps shine: darkness does not dim them, fog veils them).
fn lamp_rgb(colour: Colour) -> [u8; 3] {
    match colour {
        Colour::Red => [235, 35, 30],
        Colour::Yellow => [250, 200, 20],
        Colour::Green => [30, 215, 90],
    }
}
const HOUSING_RGB: [u8; 3] = [28, 28, 30];
const BRAKE_LIGHT_RGB: [u8; 3] = [255, 30, 30];
/// Each brake light covers this share of the car's length from its rear,
/// and across from this to that share of its half width on either side.
const BRAKE_LIGHT_LENGTH: f32 = 0.12;
const BRAKE_LIGHT_ACROSS: (f32, f32) = (0.35, 0.9);

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
///
/// A frame is two layers. What stands still (the background and the signal
/// heads, which change colour every few seconds) is kept drawn, in RGBA for
/// tiny-skia and in RGB; what moves (cars and their beams, rain streaks and
/// snowflakes) is drawn straight into `rgb`. Between frames of one scene
/// the pixels that rain and snow covered are put back from a log saved as
/// they were drawn, then what the previous frame's cars drew, and the heads
/// that changed, are copied back from the still layer: a frame costs what
/// it draws, not its size. The next frame draws over `rgb` and `mask` as
/// this one left them, so callers only read them.
pub struct FrameCanvas {
    /// The background with the signal heads drawn over it.
    still_rgba: Pixmap,
    /// `still_rgba` as RGB rows: what every frame starts from.
    still_rgb: Vec<u8>,
    pub rgb: Vec<u8>,
    pub mask: Vec<u8>,
    /// The background `still_rgba` was drawn over (kept alive so that
    /// identity means the same pixels).
    background: Option<Arc<Pixmap>>,
    /// The signal heads on the still layer, and the look they were drawn under.
    heads: Option<(SceneLook, Vec<HeadSprite>)>,
    /// Their pixel rectangles, one per head (`None` off the image).
    head_rects: Vec<Option<PixelRect>>,
    /// Pixel rectangles this frame drew over the still layer, its cars'
    /// first.
    dirty: Vec<PixelRect>,
    /// How many of `dirty` are cars' (where the mask was written).
    cars_in_dirty: usize,
    /// The frame before's, then this frame's rectangles to copy back.
    previous: Vec<PixelRect>,
    /// How many of `previous` are the frame before's cars'.
    cars_in_previous: usize,
    /// The pixels under this frame's rain streaks and snowflakes, as they
    /// were before them.
    precipitation: raster::Undo,
}

/// A rectangle of pixels, `x0..x1` by `y0..y1`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct PixelRect {
    x0: usize,
    y0: usize,
    x1: usize,
    y1: usize,
}

/// Pixels added around a shape's exact bounds for anti-aliased edges (their
/// coverage reaches half a pixel past an edge along its normal).
const AA_MARGIN_PX: f32 = 1.0;
/// Beams reach this far ahead of a car's front, metres (weather.rs draws them).
const BEAM_REACH_M: f32 = 3.5;
/// Half the width a beam pair can span, metres, beyond 0.3 x the car's width.
const BEAM_HALF_SPREAD_M: f32 = 0.9;

impl PixelRect {
    /// The pixels that anti-aliased shapes inside the car-frame box
    /// `[x0, x1] x [y0, y1]` (metres) can touch under `transform`, clipped
    /// to a `w` x `h` image; `None` when wholly outside.
    fn around(transform: Transform, (x0, x1): (f32, f32), (y0, y1): (f32, f32), w: usize, h: usize) -> Option<Self> {
        let margin = AA_MARGIN_PX;
        let mut corners = [
            tiny_skia::Point::from_xy(x0, y0),
            tiny_skia::Point::from_xy(x1, y0),
            tiny_skia::Point::from_xy(x1, y1),
            tiny_skia::Point::from_xy(x0, y1),
        ];
        transform.map_points(&mut corners);
        let (mut lo_x, mut lo_y, mut hi_x, mut hi_y) =
            (f32::INFINITY, f32::INFINITY, f32::NEG_INFINITY, f32::NEG_INFINITY);
        for p in corners {
            lo_x = lo_x.min(p.x);
            lo_y = lo_y.min(p.y);
            hi_x = hi_x.max(p.x);
            hi_y = hi_y.max(p.y);
        }
        if !(lo_x.is_finite() && lo_y.is_finite() && hi_x.is_finite() && hi_y.is_finite()) {
            return None;
        }
        let rect = PixelRect {
            x0: raster::floor_within(lo_x - margin, w),
            y0: raster::floor_within(lo_y - margin, h),
            x1: raster::ceil_within(hi_x + margin, w),
            y1: raster::ceil_within(hi_y + margin, h),
        };
        (rect.x0 < rect.x1 && rect.y0 < rect.y1).then_some(rect)
    }

    /// Whether the two share a pixel.
    fn meets(&self, other: &PixelRect) -> bool {
        self.x0 < other.x1 && other.x0 < self.x1 && self.y0 < other.y1 && other.y0 < self.y1
    }
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

    /// Asphalt coverage of each pixel of the empty map (0 to 255, row-major),
    /// for figures drawn over the roads (the heat map).
    pub fn road_coverage(&self) -> &[u8] {
        &self.road
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
            still_rgba: Pixmap::new(w, h).expect("image size was validated"),
            still_rgb: vec![0; (w * h * 3) as usize],
            rgb: vec![0; (w * h * 3) as usize],
            mask: vec![0; (w * h) as usize],
            background: None,
            heads: None,
            head_rects: Vec::new(),
            dirty: Vec::new(),
            cars_in_dirty: 0,
            previous: Vec::new(),
            cars_in_previous: 0,
            precipitation: raster::Undo::default(),
        }
    }

    /// Draws frame `frame` of `scene` with its signal `heads` (on the
    /// pavement, under everything else) and `cars` (later ones on top) into
    /// `canvas.rgb` and `canvas.mask`.
    pub fn render(
        &self,
        canvas: &mut FrameCanvas,
        scene: &Scene,
        cars: &[CarSprite],
        heads: &[HeadSprite],
        frame: u32,
    ) {
        let look = &scene.look;
        let (w, h) = (self.camera.width as usize, self.camera.height as usize);
        let world = background::world_to_canvas(&self.camera);
        // Car frame: x forward, y left, origin at the car's centre.
        let car_frame = |car: &CarSprite| {
            let (c, s) = (car.yaw.cos() as f32, car.yaw.sin() as f32);
            world.pre_concat(Transform::from_row(c, s, -s, c, car.position.x as f32, car.position.y as f32))
        };
        let whole_frame = !canvas.background.as_ref().is_some_and(|b| Arc::ptr_eq(b, &scene.background));
        std::mem::swap(&mut canvas.dirty, &mut canvas.previous);
        canvas.cars_in_previous = canvas.cars_in_dirty;
        canvas.dirty.clear();
        // A car's rectangle reaches over its beams only when they shine.
        let beams = look.shows_beams();
        canvas.dirty.extend(cars.iter().filter_map(|car| {
            let (hl, hw) = ((car.length / 2.0) as f32, (car.width / 2.0) as f32);
            let (reach, half_span) =
                if beams { (BEAM_REACH_M, hw.max(0.3 * car.width as f32 + BEAM_HALF_SPREAD_M)) } else { (0.0, hw) };
            PixelRect::around(car_frame(car), (-hl, hl + reach), (-half_span, half_span), w, h)
        }));
        canvas.cars_in_dirty = canvas.dirty.len();
        if whole_frame {
            canvas.still_rgba.data_mut().copy_from_slice(scene.background.data());
            canvas.background = Some(scene.background.clone());
            canvas.heads = None;
            canvas.head_rects.clear();
        }
        // The still layer: heads other than those drawn (colours, places,
        // the look, or none) go back to the background and are drawn again.
        // When only some heads changed colour and none of their rectangles
        // meets another head's, only those are: every other head would be
        // drawn again on the same background, to the same pixels. Their
        // rectangles join the ones to copy into the frame.
        let redrawn_from = canvas.previous.len();
        let half_housing = (HEAD_HOUSING_M / 2.0) as f32;
        let head_frame = |head: &HeadSprite| world.pre_translate(head.position.x as f32, head.position.y as f32);
        let drawn = match &canvas.heads {
            Some((l, drawn)) if l == look && drawn.len() == heads.len() => Some(drawn),
            _ => None,
        };
        let changed: Option<Vec<usize>> = drawn.and_then(|drawn| {
            if drawn.iter().zip(heads).any(|(a, b)| a.position != b.position) {
                return None;
            }
            let changed: Vec<usize> = (0..heads.len()).filter(|&i| drawn[i].colour != heads[i].colour).collect();
            let alone = |i: usize| {
                canvas.head_rects[i].is_none_or(|r| {
                    canvas.head_rects.iter().enumerate().all(|(j, o)| j == i || o.is_none_or(|o| !r.meets(&o)))
                })
            };
            changed.iter().all(|&i| alone(i)).then_some(changed)
        });
        let all_heads = changed.is_none();
        let redraw: Vec<usize> = match changed {
            Some(changed) => changed,
            None => {
                for r in canvas.head_rects.drain(..).flatten() {
                    restore(&mut canvas.still_rgba, &scene.background, r);
                    canvas.previous.push(r);
                }
                let housing = (-half_housing, half_housing);
                canvas
                    .head_rects
                    .extend(heads.iter().map(|head| PixelRect::around(head_frame(head), housing, housing, w, h)));
                (0..heads.len()).collect()
            }
        };
        let mut paint = Paint { anti_alias: true, ..Paint::default() };
        for &i in &redraw {
            let head = &heads[i];
            if !all_heads {
                // Alone: its rectangle holds only its own pixels.
                if let Some(r) = canvas.head_rects[i] {
                    restore(&mut canvas.still_rgba, &scene.background, r);
                }
            }
            let t = head_frame(head);
            let rgb = look.shade(HOUSING_RGB);
            paint.set_color_rgba8(rgb[0], rgb[1], rgb[2], 255);
            let body = Rect::from_ltrb(-half_housing, -half_housing, half_housing, half_housing).expect("fixed size");
            canvas.still_rgba.fill_rect(body, &paint, t, None);
            let rgb = look.veil(lamp_rgb(head.colour));
            paint.set_color_rgba8(rgb[0], rgb[1], rgb[2], 255);
            if let Some(lamp) = PathBuilder::from_circle(0.0, 0.0, HEAD_LAMP_RADIUS_M as f32) {
                canvas.still_rgba.fill_path(&lamp, &paint, FillRule::Winding, t, None);
            }
            canvas.previous.extend(canvas.head_rects[i]);
        }
        if all_heads || !redraw.is_empty() {
            canvas.heads = Some((*look, heads.to_vec()));
        }
        // The frame starts from the still layer where the last frame drew
        // (or everywhere, over a new background: converted once into the
        // still layer's RGB, then copied row by row, which costs less than
        // converting again; one memcpy of the whole frame measured slower).
        if whole_frame {
            convert(&canvas.still_rgba, &mut canvas.still_rgb, PixelRect { x0: 0, y0: 0, x1: w, y1: h });
            for (to, from) in canvas.rgb.chunks_exact_mut(w * 3).zip(canvas.still_rgb.chunks_exact(w * 3)) {
                to.copy_from_slice(from);
            }
            canvas.mask.fill(0);
            canvas.precipitation.clear();
        } else {
            // Rain and snow came last: unwound first, the frame is the
            // still layer plus the last frame's cars, which the rectangles
            // below put back.
            canvas.precipitation.restore(&mut canvas.rgb);
            for r in &canvas.previous[redrawn_from..] {
                convert(&canvas.still_rgba, &mut canvas.still_rgb, *r);
            }
            for r in &canvas.previous {
                copy_rgb(&canvas.still_rgb, &mut canvas.rgb, w, *r);
            }
            for r in &canvas.previous[..canvas.cars_in_previous] {
                for y in r.y0..r.y1 {
                    canvas.mask[y * w + r.x0..y * w + r.x1].fill(0);
                }
            }
        }
        // What moves, straight into the frame. Beams lie on the road, under
        // every car; rain and snow over everything.
        let mut image = raster::RgbImage::new(&mut canvas.rgb, w, h).expect("sized for this camera");
        look.draw_headlights(&mut image, cars.iter().map(|c| (car_frame(c), c.length as f32, c.width as f32)));
        for car in cars {
            let t = car_frame(car);
            let (hl, hw) = ((car.length / 2.0) as f32, (car.width / 2.0) as f32);
            let Some(body) = raster::PlacedRect::new(t, (-hl, hl), (-hw, hw)) else { continue };
            raster::fill_aa(&mut image, &body, look.shade(car.colour));
            // Windscreen towards the front shows the heading.
            if let Some(glass) = raster::PlacedRect::new(t, (hl * 0.15, hl * 0.55), (-hw * 0.8, hw * 0.8)) {
                raster::fill_aa(&mut image, &glass, look.shade([36, 40, 52]));
            }
            if car.braking {
                let rgb = look.veil(BRAKE_LIGHT_RGB);
                let (back, front) = (-hl, -hl + 2.0 * hl * BRAKE_LIGHT_LENGTH);
                let (inner, outer) = (hw * BRAKE_LIGHT_ACROSS.0, hw * BRAKE_LIGHT_ACROSS.1);
                for across in [(inner, outer), (-outer, -inner)] {
                    if let Some(light) = raster::PlacedRect::new(t, (back, front), across) {
                        raster::fill_aa(&mut image, &light, rgb);
                    }
                }
            }
            // The mask: exactly the pixels whose centres the body covers,
            // later cars over earlier ones.
            raster::stamp(&mut canvas.mask, w, &body, car.mask_id);
        }
        look.draw_precipitation_saving(&mut image, frame, Some(&mut canvas.precipitation));
    }
}

/// Puts the background back in `r`.
fn restore(rgba: &mut Pixmap, background: &Pixmap, r: PixelRect) {
    let w = rgba.width() as usize;
    let (rgba, back) = (rgba.data_mut(), background.data());
    for y in r.y0..r.y1 {
        let (from, to) = ((y * w + r.x0) * 4, (y * w + r.x1) * 4);
        rgba[from..to].copy_from_slice(&back[from..to]);
    }
}

/// Copies `r` of one `w`-wide RGB image into another.
fn copy_rgb(from: &[u8], to: &mut [u8], w: usize, r: PixelRect) {
    for y in r.y0..r.y1 {
        let (a, b) = ((y * w + r.x0) * 3, (y * w + r.x1) * 3);
        raster::copy_short(&mut to[a..b], &from[a..b]);
    }
}

/// Copies `r` of the RGBA still layer into an RGB image of its size (its
/// RGB copy, or a whole frame).
fn convert(rgba: &Pixmap, rgb: &mut [u8], r: PixelRect) {
    let w = rgba.width() as usize;
    let rgba = rgba.data();
    for y in r.y0..r.y1 {
        let row = y * w;
        let src = &rgba[(row + r.x0) * 4..(row + r.x1) * 4];
        let dst = &mut rgb[(row + r.x0) * 3..(row + r.x1) * 3];
        convert_row(src, dst);
    }
}

/// RGBA pixels into RGB: four pixels (16 bytes) at a time are packed into
/// three little-endian words (12 bytes), which the compiler turns into
/// vector shuffles; the remaining pixels are copied one by one.
pub(crate) fn convert_row(src: &[u8], dst: &mut [u8]) {
    let n = src.len() / 4;
    let quads = n / 4;
    for (s, d) in src.chunks_exact(16).zip(dst.chunks_exact_mut(12)) {
        let quad = u128::from_le_bytes(s.try_into().expect("16 bytes"));
        let (p0, p1, p2, p3) = (quad as u32, (quad >> 32) as u32, (quad >> 64) as u32, (quad >> 96) as u32);
        d[0..4].copy_from_slice(&((p0 & 0x00ff_ffff) | (p1 << 24)).to_le_bytes());
        d[4..8].copy_from_slice(&(((p1 >> 8) & 0xffff) | (p2 << 16)).to_le_bytes());
        d[8..12].copy_from_slice(&(((p2 >> 16) & 0xff) | (p3 << 8)).to_le_bytes());
    }
    for i in quads * 4..n {
        dst[i * 3..i * 3 + 3].copy_from_slice(&src[i * 4..i * 4 + 3]);
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn rgba_rows_convert_to_their_rgb_bytes_at_every_length() {
        for n in 0..19usize {
            let src: Vec<u8> = (0..n * 4).map(|b| (b * 7 + 1) as u8).collect();
            let expected: Vec<u8> = src.chunks_exact(4).flat_map(|p| p[..3].to_vec()).collect();
            let mut dst = vec![0xAA; n * 3];
            super::convert_row(&src, &mut dst);
            assert_eq!(dst, expected, "{n} pixels");
        }
    }

    #[test]
    fn short_copies_write_every_byte_of_every_length() {
        for n in 0..80usize {
            let from: Vec<u8> = (0..n).map(|b| (b * 13 + 5) as u8).collect();
            let mut to = vec![0u8; n];
            super::raster::copy_short(&mut to, &from);
            assert_eq!(to, from, "copy of {n} bytes");
        }
    }
}
