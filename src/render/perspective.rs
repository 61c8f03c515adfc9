//! Perspective views: the map and the cars as simple solids seen through a
//! [`Pinhole`]. The ground is the flat bird's-eye drawing, laid on the
//! plane z = 0 and looked up along each pixel's ray; buildings, light
//! poles, signal heads and cars are boxes, cut into triangles and drawn
//! with a depth buffer, so each pixel shows the nearest surface along its
//! ray. Masks and depth come from the same depth test as the colours: a
//! car's mask pixels are exactly those where it is the nearest surface (no
//! anti-aliasing), and depth is the distance along the ray to that surface.
//!
//! Why a depth buffer rather than the 2D rasteriser drawing solids far to
//! near: ordering whole solids gets occlusion wrong where they interleave
//! (a car beside a building's corner, a pole in front of a car), and masks
//! and depth must agree with the picture per pixel, which only a per-pixel
//! test gives. No maintained crate does CPU triangle rasterisation with a
//! depth buffer without pulling in a whole engine; this file is about 300
//! lines.

use super::background::{blocks, draw_background, Block, BUILDING_HEIGHT_M, GROUND};
use super::weather::SceneLook;
use super::{CarSprite, HeadSprite, CAR_HEIGHT_M};
use crate::camera::{Camera, Pinhole, NEAR_M};
use crate::map::signals::Colour;
use crate::map::CityMap;
use glam::{DVec2, DVec3};

/// Sky, where a ray meets nothing.
const SKY: [u8; 3] = [176, 200, 226];
/// A light pole and a signal head's housing.
const POLE: [u8; 3] = [70, 72, 76];
/// The glass of a car's cabin.
const GLASS: [u8; 3] = [52, 58, 72];
/// Height of a light pole (to the foot of its head), metres.
pub const POLE_HEIGHT_M: f64 = 3.0;
/// A light pole's side, metres.
const POLE_SIDE_M: f64 = 0.2;
/// A signal head's side and height, metres.
const HEAD_SIDE_M: f64 = 0.45;
const HEAD_TALL_M: f64 = 0.9;
/// A car's body reaches this share of [`CAR_HEIGHT_M`]; the cabin on top
/// of it the rest, over this share of the length and width.
const BODY_SHARE: f64 = 0.55;
const CABIN_LENGTH_SHARE: f64 = 0.5;
const CABIN_WIDTH_SHARE: f64 = 0.85;
/// Pixels of the ground texture per metre.
const TEXTURE_PX_PER_M: f64 = 10.0;
/// Most pixels along a side of the ground texture (a town or network over
/// 400 m across is drawn coarser): three 64 MB copies of it at most.
const MAX_TEXTURE_SIDE: f64 = 4096.0;
/// Direction towards the sun (unnormalised), for shading faces.
const SUN: [f64; 3] = [0.35, 0.55, 0.75];

/// A box: centre on the ground (metres), heading, length (along the
/// heading), width, bottom and top heights.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Solid {
    pub centre: DVec2,
    pub yaw: f64,
    pub length: f64,
    pub width: f64,
    pub bottom: f64,
    pub top: f64,
    pub colour: [u8; 3],
    /// The mask value of its pixels (0: not a car).
    pub mask_id: u8,
}

/// A car as the perspective view draws it: its body and, on top, its cabin
/// (the flat views' sprite, given height).
pub fn car_solids(car: &CarSprite) -> [Solid; 2] {
    let body_top = CAR_HEIGHT_M * BODY_SHARE;
    let back = DVec2::from_angle(car.yaw) * (-0.1 * car.length);
    let body = Solid {
        centre: car.position,
        yaw: car.yaw,
        length: car.length,
        width: car.width,
        bottom: 0.0,
        top: body_top,
        colour: car.colour,
        mask_id: car.mask_id,
    };
    let cabin = Solid {
        centre: car.position + back,
        length: car.length * CABIN_LENGTH_SHARE,
        width: car.width * CABIN_WIDTH_SHARE,
        bottom: body_top,
        top: CAR_HEIGHT_M,
        colour: GLASS,
        ..body
    };
    [body, cabin]
}

/// The map as solids, shared by every perspective camera of a run: the
/// ground texture and the buildings.
pub struct World3d {
    texture: Camera,
    ground: Vec<u8>,
    buildings: Vec<Solid>,
}

impl World3d {
    /// The solids of `map` (the ground drawn once, flat, at
    /// [`TEXTURE_PX_PER_M`]).
    pub fn new(map: &CityMap) -> World3d {
        if map.is_imported() {
            // The network's own area (no blocks to raise), at most
            // MAX_TEXTURE_SIDE pixels a side.
            let (lo, hi) = map.drawn_bounds();
            let (lo, hi) = (lo - DVec2::splat(10.0), hi + DVec2::splat(10.0));
            let size = hi - lo;
            let ppm = TEXTURE_PX_PER_M.min(MAX_TEXTURE_SIDE / size.max_element());
            let (w, h) = (((size.x * ppm) as u32).max(1), ((size.y * ppm) as u32).max(1));
            let altitude = Camera::altitude_to_frame(w, h, size);
            let texture = Camera::birds_eye_over(w, h, (lo + hi) / 2.0, altitude);
            let pixmap = draw_background(map, &texture).pixmap;
            let ground = pixmap.data().chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]).collect();
            return World3d { texture, ground, buildings: Vec::new() };
        }
        let (half_x, half_y) = (map.layout.extent_x + 10.0, map.layout.extent_y + 10.0);
        // At most MAX_TEXTURE_SIDE pixels a side: a 5 km town at 10 px/m
        // asked for 40 GB.
        let ppm = TEXTURE_PX_PER_M.min(MAX_TEXTURE_SIDE / (2.0 * half_x.max(half_y)));
        let (w, h) = (((2.0 * half_x * ppm) as u32).max(1), ((2.0 * half_y * ppm) as u32).max(1));
        let altitude = Camera::altitude_to_frame(w, h, DVec2::new(2.0 * half_x, 2.0 * half_y));
        let texture = Camera::birds_eye_over(w, h, DVec2::ZERO, altitude);
        let pixmap = draw_background(map, &texture).pixmap;
        let ground = pixmap.data().chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]).collect();
        let buildings = blocks(map, DVec2::new(-half_x, -half_y), DVec2::new(half_x, half_y))
            .into_iter()
            .filter_map(|b| match b {
                Block::Building { footprint: [x0, y0, x1, y1], roof } => Some(Solid {
                    centre: DVec2::new((x0 + x1) / 2.0, (y0 + y1) / 2.0),
                    yaw: 0.0,
                    length: x1 - x0,
                    width: y1 - y0,
                    bottom: 0.0,
                    top: BUILDING_HEIGHT_M,
                    colour: roof,
                    mask_id: 0,
                }),
                Block::Park(_) => None,
            })
            .collect();
        World3d { texture, ground, buildings }
    }

    /// The colour of `ground` (this world's texture, or a shaded copy) at a
    /// point, metres: the nearest texture pixel; bare ground beyond it.
    #[inline]
    fn ground_at(&self, ground: &[u8], p: DVec2) -> [u8; 3] {
        let t = &self.texture;
        let px = (t.width as f64 - 1.0) / 2.0 + (p.x - t.centre_x) * t.pixels_per_metre;
        let py = (t.height as f64 - 1.0) / 2.0 - (p.y - t.centre_y) * t.pixels_per_metre;
        // Nearest pixel by truncation (round() is a library call on baseline x86-64).
        if px < -0.5 || py < -0.5 {
            return GROUND;
        }
        let (x, y) = ((px + 0.5) as usize, (py + 0.5) as usize);
        if x >= t.width as usize || y >= t.height as usize {
            return GROUND;
        }
        let i = (y * t.width as usize + x) * 3;
        [ground[i], ground[i + 1], ground[i + 2]]
    }
}

/// One perspective frame: colours, car masks and distances along the rays.
#[derive(Debug, Clone)]
pub struct PerspectiveFrame {
    pub width: u32,
    pub height: u32,
    /// RGB, row by row.
    pub rgb: Vec<u8>,
    /// 0, or the mask id of the car nearest along the pixel's ray.
    pub mask: Vec<u8>,
    /// Metres along each pixel's ray to the first surface; infinite for sky.
    pub distance: Vec<f32>,
}

impl PerspectiveFrame {
    /// Depth for a 16-bit PNG: millimetres, 0 for sky; 65.535 m and farther
    /// is clipped to 65535 (docs/cameras.md says so).
    pub fn depth_mm(&self, out: &mut Vec<u16>) {
        out.clear();
        out.extend(self.distance.iter().map(|&d| {
            if d.is_finite() {
                (d as f64 * 1000.0).round().min(u16::MAX as f64) as u16
            } else {
                0
            }
        }));
    }

    /// Pixels whose mask holds `mask_id`.
    pub fn visible_pixels(&self, mask_id: u8) -> usize {
        self.mask.iter().filter(|&&m| m == mask_id).count()
    }

    /// Pixels per mask value, every value counted in one pass.
    pub fn mask_counts(&self) -> [usize; 256] {
        let mut counts = [0; 256];
        for &m in &self.mask {
            counts[m as usize] += 1;
        }
        counts
    }
}

/// Draws perspective frames of one camera; keeps the static part (ground
/// and buildings) while the camera does not move.
pub struct PerspectiveRenderer {
    statics: Option<(Pinhole, SceneLook, PerspectiveFrame)>,
    /// The ground texture under the last look (the clear one needs none).
    shaded: Option<(SceneLook, Vec<u8>)>,
    /// Each pixel's ray length per metre along the axis, for the lens of
    /// `lens` (width, height, field of view).
    ray_length: Vec<f32>,
    lens: (u32, u32, f64),
    /// The camera of the last frame drawn.
    last: Option<Pinhole>,
}

impl Default for PerspectiveRenderer {
    fn default() -> Self {
        Self::new()
    }
}

impl PerspectiveRenderer {
    pub fn new() -> Self {
        PerspectiveRenderer { statics: None, shaded: None, ray_length: Vec::new(), lens: (0, 0, 0.0), last: None }
    }

    /// Draws `world`, the signal heads and the cars (less any car whose
    /// mask id is `hidden`, the first-person camera's own) into `frame`,
    /// under `look`'s light and fog ([`draw_precipitation`] adds rain and
    /// snow).
    #[allow(clippy::too_many_arguments)]
    pub fn render(
        &mut self,
        world: &World3d,
        camera: &Pinhole,
        look: &SceneLook,
        heads: &[HeadSprite],
        cars: &[CarSprite],
        hidden: Option<u8>,
        frame: &mut PerspectiveFrame,
    ) {
        let lens = (camera.width, camera.height, camera.horizontal_fov_deg);
        if self.lens != lens {
            let (c, f) = (camera.centre_px(), camera.focal_px());
            self.ray_length = (0..camera.height as usize)
                .flat_map(|y| {
                    (0..camera.width as usize).map(move |x| {
                        let (u, v) = ((x as f64 - c.x) / f, (y as f64 - c.y) / f);
                        (1.0 + u * u + v * v).sqrt() as f32
                    })
                })
                .collect();
            self.lens = lens;
            self.statics = None;
        }
        if !look.is_clear() && !matches!(&self.shaded, Some((l, _)) if l == look) {
            let texture = world.ground.chunks_exact(3).flat_map(|p| look.shade([p[0], p[1], p[2]])).collect();
            self.shaded = Some((*look, texture));
        }
        let ground: &[u8] = match &self.shaded {
            Some((_, texture)) if !look.is_clear() => texture,
            _ => &world.ground,
        };
        let ray_length = &self.ray_length;
        let still = matches!(&self.statics, Some((c, l, _)) if c == camera && l == look);
        if still {
            // The camera has not moved: start from its ground and buildings.
            let (_, _, statics) = self.statics.as_ref().expect("checked above");
            frame.width = statics.width;
            frame.height = statics.height;
            frame.rgb.clone_from(&statics.rgb);
            frame.mask.clone_from(&statics.mask);
            frame.distance.clone_from(&statics.distance);
        } else {
            let n = camera.width as usize * camera.height as usize;
            (frame.width, frame.height) = (camera.width, camera.height);
            frame.rgb.resize(n * 3, 0);
            frame.distance.resize(n, f32::INFINITY);
            frame.mask.clear();
            frame.mask.resize(n, 0);
            draw_ground(world, ground, camera, ray_length, frame);
            for solid in &world.buildings {
                draw_solid(camera, ray_length, &shaded(solid, look), frame);
            }
            // A camera that stood still since the last frame is a fixed one:
            // its ground and buildings are kept for the frames to come.
            if self.last.as_ref() == Some(camera) {
                self.statics = Some((*camera, *look, frame.clone()));
            }
        }
        self.last = Some(*camera);
        for head in heads {
            let [pole, lamp] = head_solids(head);
            draw_solid(camera, ray_length, &shaded(&pole, look), frame);
            // A lit lamp is not dimmed by the dark, only veiled by fog.
            draw_solid(camera, ray_length, &Solid { colour: look.veil(lamp.colour), ..lamp }, frame);
        }
        for car in cars.iter().filter(|c| Some(c.mask_id) != hidden) {
            for solid in car_solids(car) {
                draw_solid(camera, ray_length, &shaded(&solid, look), frame);
            }
        }
    }
}

/// Rain streaks and snowflakes of frame `index` over a drawn frame, as the
/// flat views draw them (in image space; the masks stay as they are).
pub fn draw_precipitation(look: &SceneLook, index: u32, frame: &mut PerspectiveFrame) {
    let (w, h) = (frame.width as usize, frame.height as usize);
    if let Some(mut image) = super::raster::RgbImage::new(&mut frame.rgb, w, h) {
        look.draw_precipitation(&mut image, index);
    }
}

/// A solid in `look`'s light.
fn shaded(solid: &Solid, look: &SceneLook) -> Solid {
    Solid { colour: look.shade(solid.colour), ..*solid }
}

/// An empty frame of `camera`'s size.
pub fn empty_frame(camera: &Pinhole) -> PerspectiveFrame {
    let n = camera.width as usize * camera.height as usize;
    PerspectiveFrame {
        width: camera.width,
        height: camera.height,
        rgb: vec![0; n * 3],
        mask: vec![0; n],
        distance: vec![f32::INFINITY; n],
    }
}

/// A light pole and its head, lit in `colour`.
fn head_solids(head: &HeadSprite) -> [Solid; 2] {
    let lamp = match head.colour {
        Colour::Green => [40, 220, 90],
        Colour::Yellow => [250, 200, 40],
        Colour::Red => [235, 45, 40],
    };
    let base = Solid {
        centre: head.position,
        yaw: 0.0,
        length: POLE_SIDE_M,
        width: POLE_SIDE_M,
        bottom: 0.0,
        top: POLE_HEIGHT_M,
        colour: POLE,
        mask_id: 0,
    };
    let lit = Solid {
        length: HEAD_SIDE_M,
        width: HEAD_SIDE_M,
        bottom: POLE_HEIGHT_M,
        top: POLE_HEIGHT_M + HEAD_TALL_M,
        colour: lamp,
        ..base
    };
    [base, lit]
}

/// The ground: each pixel whose ray goes down meets the plane z = 0. With
/// no roll the camera's right axis is level, so along a row every ray meets
/// the ground at the same depth and the hit point moves in equal steps:
/// one division per row, not per pixel.
fn draw_ground(world: &World3d, ground: &[u8], camera: &Pinhole, ray_length: &[f32], frame: &mut PerspectiveFrame) {
    let (w, h) = (camera.width as usize, camera.height as usize);
    let origin = camera.position();
    let [right, down, forward] = camera.axes();
    let (centre, focal) = (camera.centre_px(), camera.focal_px());
    let level = right.z.abs() < 1e-12;
    for y in 0..h {
        let row = forward + down * ((y as f64 - centre.y) / focal);
        let pixels = y * w..(y + 1) * w;
        if level {
            if row.z >= 0.0 || origin.z <= 0.0 {
                frame.distance[pixels.clone()].fill(f32::INFINITY);
                for px in frame.rgb[pixels.start * 3..pixels.end * 3].chunks_exact_mut(3) {
                    px.copy_from_slice(&SKY);
                }
                continue;
            }
            let t = -origin.z / row.z;
            let first = origin + (row + right * (-centre.x / focal)) * t;
            let step = right * (t / focal);
            for (x, i) in pixels.enumerate() {
                let hit = first + step * x as f64;
                frame.distance[i] = ray_length[i] * t as f32;
                let colour = world.ground_at(ground, DVec2::new(hit.x, hit.y));
                frame.rgb[i * 3..i * 3 + 3].copy_from_slice(&colour);
            }
            continue;
        }
        for (x, i) in pixels.enumerate() {
            let ray = row + right * ((x as f64 - centre.x) / focal);
            let colour = if ray.z < 0.0 && origin.z > 0.0 {
                let t = -origin.z / ray.z;
                let hit = origin + ray * t;
                frame.distance[i] = ray_length[i] * t as f32;
                world.ground_at(ground, DVec2::new(hit.x, hit.y))
            } else {
                frame.distance[i] = f32::INFINITY;
                SKY
            };
            frame.rgb[i * 3..i * 3 + 3].copy_from_slice(&colour);
        }
    }
}

/// A box's eight corners: bottom four then top four, counter-clockwise.
fn corners(s: &Solid) -> [DVec3; 8] {
    let (along, across) =
        (DVec2::from_angle(s.yaw) * (s.length / 2.0), DVec2::from_angle(s.yaw).perp() * (s.width / 2.0));
    let ground =
        [s.centre - along - across, s.centre + along - across, s.centre + along + across, s.centre - along + across];
    let mut c = [DVec3::ZERO; 8];
    for (k, g) in ground.iter().enumerate() {
        c[k] = DVec3::new(g.x, g.y, s.bottom);
        c[k + 4] = DVec3::new(g.x, g.y, s.top);
    }
    c
}

/// The faces of a box as corner indices, counter-clockwise seen from outside.
const FACES: [[usize; 4]; 6] = [[4, 5, 6, 7], [0, 3, 2, 1], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]];

/// Draws a box's faces that face the camera, with a depth test.
fn draw_solid(camera: &Pinhole, ray_length: &[f32], solid: &Solid, frame: &mut PerspectiveFrame) {
    let world = corners(solid);
    let cam = world.map(|p| camera.to_camera(p));
    let origin = camera.position();
    let sun = DVec3::from_array(SUN).normalize();
    for face in FACES {
        let [a, b, _, d] = face.map(|k| world[k]);
        let normal = (b - a).cross(d - a).normalize_or_zero();
        // Back faces (facing away from the camera) are hidden by the front ones.
        if normal.dot(origin - a) <= 0.0 {
            continue;
        }
        let shade = 0.62 + 0.38 * normal.dot(sun).max(0.0);
        let colour = solid.colour.map(|v| (v as f64 * shade).round().min(255.0) as u8);
        let quad = face.map(|k| cam[k]);
        for triangle in [[quad[0], quad[1], quad[2]], [quad[0], quad[2], quad[3]]] {
            draw_triangle(camera, ray_length, triangle, colour, solid.mask_id, frame);
        }
    }
}

/// Clips a triangle (camera axes) to z >= NEAR_M: up to four corners.
fn clip_near(triangle: [DVec3; 3]) -> Vec<DVec3> {
    let mut out = Vec::with_capacity(4);
    for k in 0..3 {
        let (p, q) = (triangle[k], triangle[(k + 1) % 3]);
        let (p_in, q_in) = (p.z >= NEAR_M, q.z >= NEAR_M);
        if p_in {
            out.push(p);
        }
        if p_in != q_in {
            let t = (NEAR_M - p.z) / (q.z - p.z);
            out.push(p + (q - p) * t);
        }
    }
    out
}

/// Rasterises a triangle given in the camera's axes: pixels whose centres it
/// covers, where it is nearer than what is there. Barycentric weights and
/// 1/z are linear in screen space, so they are stepped along each row.
fn draw_triangle(
    camera: &Pinhole,
    ray_length: &[f32],
    triangle: [DVec3; 3],
    colour: [u8; 3],
    mask_id: u8,
    frame: &mut PerspectiveFrame,
) {
    let polygon = clip_near(triangle);
    if polygon.len() < 3 {
        return;
    }
    let (w, h) = (camera.width as usize, camera.height as usize);
    let (centre, focal) = (camera.centre_px(), camera.focal_px());
    // Screen position and 1/z of each corner.
    let screen: Vec<(DVec2, f64)> =
        polygon.iter().map(|p| (centre + DVec2::new(p.x, p.y) * (focal / p.z), 1.0 / p.z)).collect();
    for k in 1..screen.len() - 1 {
        let [(p0, z0), (p1, z1), (p2, z2)] = [screen[0], screen[k], screen[k + 1]];
        let area = (p1 - p0).perp_dot(p2 - p0);
        if area.abs() < 1e-12 {
            continue;
        }
        let (lo, hi) = (p0.min(p1).min(p2), p0.max(p1).max(p2));
        if hi.x < 0.0 || hi.y < 0.0 || lo.x > w as f64 - 1.0 || lo.y > h as f64 - 1.0 {
            continue;
        }
        let (x0, x1) = (lo.x.ceil().max(0.0) as usize, hi.x.floor().min(w as f64 - 1.0) as usize);
        let (y0, y1) = (lo.y.ceil().max(0.0) as usize, hi.y.floor().min(h as f64 - 1.0) as usize);
        // w0 = weight of p0 (from edge p1 -> p2), w1 of p1 (edge p2 -> p0); linear in x and y.
        let (e0, e1) = (p2 - p1, p0 - p2);
        let (dw0_dx, dw0_dy) = (-e0.y / area, e0.x / area);
        let (dw1_dx, dw1_dy) = (-e1.y / area, e1.x / area);
        let start = DVec2::new(x0 as f64, y0 as f64);
        let (w0_start, w1_start) = (e0.perp_dot(start - p1) / area, e1.perp_dot(start - p2) / area);
        for y in y0..=y1 {
            let dy = (y - y0) as f64;
            let mut w0 = w0_start + dw0_dy * dy;
            let mut w1 = w1_start + dw1_dy * dy;
            for x in x0..=x1 {
                let w2 = 1.0 - w0 - w1;
                // A pixel on an edge belongs to the triangle.
                if w0 >= -1e-9 && w1 >= -1e-9 && w2 >= -1e-9 {
                    let i = y * w + x;
                    let z = 1.0 / (w0 * z0 + w1 * z1 + w2 * z2);
                    let distance = z as f32 * ray_length[i];
                    if distance < frame.distance[i] {
                        frame.distance[i] = distance;
                        frame.mask[i] = mask_id;
                        frame.rgb[i * 3..i * 3 + 3].copy_from_slice(&colour);
                    }
                }
                w0 += dw0_dx;
                w1 += dw1_dx;
            }
        }
    }
}
