//! The static scene, drawn once per camera: ground, blocks and buildings, the
//! central park, roads, lane markings, stop lines and crosswalks. Flat colours
//! only, so frames compress well.

use crate::camera::Camera;
use crate::map::control::JunctionControl;
use crate::map::{CityMap, MapLayout};
use glam::DVec2;
use tiny_skia::{Color, FillRule, Paint, PathBuilder, Pixmap, Rect, Transform};

/// Bare ground (pavements, and beyond the drawn map).
pub const GROUND: [u8; 3] = [200, 198, 190];
const ASPHALT: [u8; 3] = [66, 68, 72];
const PARK: [u8; 3] = [122, 168, 98];
const PARK_PATH: [u8; 3] = [214, 204, 170];
const CENTRE_LINE: [u8; 3] = [232, 190, 40];
const WHITE: [u8; 3] = [240, 240, 240];
/// Stop and give-way signs at junctions without lights.
const STOP_SIGN: [u8; 3] = [196, 32, 36];
const ROOFS: [[u8; 3]; 4] = [[150, 110, 96], [128, 134, 150], [176, 160, 132], [104, 112, 118]];

/// The transform from world metres to tiny-skia pixel space (whose pixel `i`
/// spans `[i, i + 1)`, so its centre is at `i + 0.5`).
pub fn world_to_canvas(camera: &Camera) -> Transform {
    let ppm = camera.pixels_per_metre as f32;
    if camera.rotation_rad == 0.0 {
        let tx = camera.width as f32 / 2.0 - camera.centre_x as f32 * ppm;
        let ty = camera.height as f32 / 2.0 + camera.centre_y as f32 * ppm;
        return Transform::from_row(ppm, 0.0, 0.0, -ppm, tx, ty);
    }
    // Move the camera's centre to the origin, turn the view, then scale and flip.
    let (s, c) = (-camera.rotation_rad).sin_cos();
    let to_origin = Transform::from_translate(-camera.centre_x as f32, -camera.centre_y as f32);
    let turn = Transform::from_row(c as f32, s as f32, -s as f32, c as f32, 0.0, 0.0);
    let to_pixels = Transform::from_row(ppm, 0.0, 0.0, -ppm, camera.width as f32 / 2.0, camera.height as f32 / 2.0);
    to_pixels.pre_concat(turn).pre_concat(to_origin)
}

fn paint(rgb: [u8; 3]) -> Paint<'static> {
    let mut p = Paint { anti_alias: true, ..Paint::default() };
    p.set_color_rgba8(rgb[0], rgb[1], rgb[2], 255);
    p
}

/// An axis-aligned rectangle in world metres.
fn rect(pixmap: &mut Pixmap, t: Transform, x0: f64, y0: f64, x1: f64, y1: f64, rgb: [u8; 3]) {
    let (l, r) = (x0.min(x1) as f32, x0.max(x1) as f32);
    let (b, top) = (y0.min(y1) as f32, y0.max(y1) as f32);
    if let Some(rc) = Rect::from_ltrb(l, b, r, top) {
        pixmap.fill_rect(rc, &paint(rgb), t, None);
    }
}

/// The background of one camera and what each pixel shows.
pub struct Background {
    pub pixmap: Pixmap,
    /// Asphalt coverage per pixel (255 on the road), which weather uses.
    pub road: Vec<u8>,
    /// Roof coverage per pixel (255 on a building), for depth.
    pub buildings: Vec<u8>,
}

/// Height of every building, metres (for depth images).
pub const BUILDING_HEIGHT_M: f64 = 12.0;

/// What fills a block between the roads.
pub enum Block {
    /// The central park: [x0, y0, x1, y1], metres.
    Park([f64; 4]),
    /// A building [`BUILDING_HEIGHT_M`] tall on [x0, y0, x1, y1], metres,
    /// with its roof colour.
    Building { footprint: [f64; 4], roof: [u8; 3] },
}

/// The blocks between the roads within the box (lo, hi), metres: two
/// buildings per block, split along the longer side, and a park in the
/// middle. Shared by the flat drawing and the perspective solids.
pub fn blocks(map: &CityMap, lo: DVec2, hi: DVec2) -> Vec<Block> {
    if map.is_imported() {
        return Vec::new(); // an imported network has no blocks to fill
    }
    let layout = &map.layout;
    let hw = layout.road_half_width();
    let far = 1000.0;
    // Block edges: beyond the outermost roads, then between each pair.
    let edges = |centres: Vec<f64>| [vec![-far], centres, vec![far]].concat();
    let (xs, ys) = (edges(layout.north_south_centres()), edges(layout.east_west_centres()));
    let (columns, rows) = (xs.len() - 1, ys.len() - 1);
    let mut found = Vec::new();
    for i in 0..columns {
        for j in 0..rows {
            let x0 = (xs[i] + if i == 0 { 0.0 } else { hw + layout.sidewalk_width }).max(lo.x);
            let x1 = (xs[i + 1] - if i == columns - 1 { 0.0 } else { hw + layout.sidewalk_width }).min(hi.x);
            let y0 = (ys[j] + if j == 0 { 0.0 } else { hw + layout.sidewalk_width }).max(lo.y);
            let y1 = (ys[j + 1] - if j == rows - 1 { 0.0 } else { hw + layout.sidewalk_width }).min(hi.y);
            if x1 <= x0 || y1 <= y0 {
                continue;
            }
            // The park: the middle block (the central one of the default city).
            if i == columns / 2 && j == rows / 2 {
                found.push(Block::Park([x0, y0, x1, y1]));
                continue;
            }
            let gap = 1.5;
            let roof = |k: usize| ROOFS[(i * rows + j + k) % ROOFS.len()];
            let halves = if x1 - x0 >= y1 - y0 {
                let mid = (x0 + x1) / 2.0;
                [[x0, y0, mid - gap / 2.0, y1], [mid + gap / 2.0, y0, x1, y1]]
            } else {
                let mid = (y0 + y1) / 2.0;
                [[x0, y0, x1, mid - gap / 2.0], [x0, mid + gap / 2.0, x1, y1]]
            };
            for (k, footprint) in halves.into_iter().enumerate() {
                found.push(Block::Building { footprint, roof: roof(k) });
            }
        }
    }
    found
}

/// Draws the background for `map` as seen by `camera`.
pub fn draw_background(map: &CityMap, camera: &Camera) -> Background {
    let mut pixmap = Pixmap::new(camera.width, camera.height).expect("image size was validated");
    let mut road = Pixmap::new(camera.width, camera.height).expect("image size was validated");
    let mut buildings = Pixmap::new(camera.width, camera.height).expect("image size was validated");
    pixmap.fill(Color::from_rgba8(GROUND[0], GROUND[1], GROUND[2], 255));
    let t = world_to_canvas(camera);
    if map.is_imported() {
        draw_network_roads(map, &mut pixmap, &mut road, t);
        let alpha = |p: &Pixmap| p.data().chunks_exact(4).map(|px| px[3]).collect();
        return Background { road: alpha(&road), buildings: alpha(&buildings), pixmap };
    }
    let layout = &map.layout;
    let hw = layout.road_half_width();
    let (view_lo, view_hi) = camera.ground_view();

    // Blocks between the roads: buildings, and a park in the middle.
    for block in blocks(map, view_lo - DVec2::splat(5.0), view_hi + DVec2::splat(5.0)) {
        match block {
            Block::Park([x0, y0, x1, y1]) => {
                rect(&mut pixmap, t, x0, y0, x1, y1, PARK);
                let (cx, cy) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
                rect(&mut pixmap, t, x0, cy - 0.8, x1, cy + 0.8, PARK_PATH);
                rect(&mut pixmap, t, cx - 0.8, y0, cx + 0.8, y1, PARK_PATH);
            }
            Block::Building { footprint: [a, b, c, d], roof } => {
                rect(&mut pixmap, t, a, b, c, d, roof);
                rect(&mut buildings, t, a, b, c, d, WHITE);
            }
        }
    }

    // Asphalt, including the turning circles at the far ends.
    // A road runs its whole length unless the town leaves a segment out.
    for target in [&mut pixmap, &mut road] {
        for &(name, y) in &layout.east_west_roads {
            let (runs, loops) = road_runs(layout, name, &layout.north_south_centres(), layout.extent_x);
            for (x0, x1) in runs {
                rect(target, t, x0, y - hw, x1, y + hw, ASPHALT);
            }
            for x in loops {
                circle(target, t, x, y, hw, ASPHALT);
            }
        }
        for &(name, x) in &layout.north_south_roads {
            let (runs, loops) = road_runs(layout, name, &layout.east_west_centres(), layout.extent_y);
            for (y0, y1) in runs {
                rect(target, t, x - hw, y0, x + hw, y1, ASPHALT);
            }
            for y in loops {
                circle(target, t, x, y, hw, ASPHALT);
            }
        }
    }

    // Markings along every lane of every segment, drawn in the lane's frame.
    for lane in &map.lanes {
        if lane.letter != 'w' && lane.letter != 'z' {
            continue;
        }
        let curve = &lane.curve;
        let len = curve.length();
        let lw = layout.lane_width;
        // The road's centre line, to the left of this kerb-side lane.
        let centre = layout.outer_lane_offset();
        // Dividers between the lanes of this direction: dashed white.
        for k in 1..layout.lanes_per_direction {
            let lateral = (k as f64 - 0.5) * lw;
            let mut s = 1.0;
            while s + 3.0 <= len - 1.0 {
                quad_along(&mut pixmap, t, curve, s, s + 3.0, lateral - 0.07, lateral + 0.07, WHITE);
                s += 6.0;
            }
        }
        // Half of the double yellow centre line, on this direction's side.
        quad_along(&mut pixmap, t, curve, 0.0, len, centre - 0.25, centre - 0.1, CENTRE_LINE);
        if let crate::map::LaneEnd::Intersection { intersection, approach } = lane.end {
            // Crosswalk across the whole road just before the box, stop line behind it.
            let mut k = -hw + 0.25;
            while k + 0.5 <= hw {
                let lateral = k + centre;
                quad_along(&mut pixmap, t, curve, len - 2.8, len - 0.3, lateral, lateral + 0.5, WHITE);
                k += 1.0;
            }
            let junction = &map.intersections[intersection];
            let sign = map.signal_head(intersection, approach, crate::map::signals::Signal::Straight, 0);
            match junction.control {
                JunctionControl::Signals => {
                    quad_along(&mut pixmap, t, curve, len - 3.6, len - 3.2, -0.5 * lw, centre - 0.3, WHITE);
                }
                JunctionControl::AllWayStop => {
                    quad_along(&mut pixmap, t, curve, len - 3.7, len - 3.1, -0.5 * lw, centre - 0.3, WHITE);
                    if let Some(p) = sign {
                        circle(&mut pixmap, t, p.x, p.y, 0.55, WHITE);
                        circle(&mut pixmap, t, p.x, p.y, 0.45, STOP_SIGN);
                    }
                }
                // The priority road runs through unmarked; the other gives
                // way at a dashed line, under a triangle.
                // Right before left: no markings, as in residential streets.
                JunctionControl::RightBeforeLeft => {}
                JunctionControl::Priority if junction.major.holds(approach) => {}
                JunctionControl::Priority => {
                    let mut k = -0.5 * lw;
                    while k < centre - 0.3 {
                        let end = (k + 0.6).min(centre - 0.3);
                        quad_along(&mut pixmap, t, curve, len - 3.6, len - 3.2, k, end, WHITE);
                        k += 1.0;
                    }
                    if let Some(p) = sign {
                        let ahead = curve.position(len, 0.0) - curve.position(len - 1.0, 0.0);
                        give_way_triangle(&mut pixmap, t, p, ahead.normalize_or_zero());
                    }
                }
            }
        }
    }
    let alpha = |p: &Pixmap| p.data().chunks_exact(4).map(|px| px[3]).collect();
    Background { road: alpha(&road), buildings: alpha(&buildings), pixmap }
}

/// An imported network's roads: asphalt along every lane and movement and
/// over every junction's outline; dashed white lines between lanes of one
/// direction, a yellow line on the left of each direction, and at each
/// junction the marks of its control (a stop line at lights and all-way
/// stops with a stop sign, a dashed give-way line with a triangle on the
/// minor approaches of a priority junction).
fn draw_network_roads(map: &CityMap, pixmap: &mut Pixmap, road: &mut Pixmap, t: Transform) {
    let half = map.layout.lane_width / 2.0;
    for target in [&mut *pixmap, &mut *road] {
        for x in map.intersections.iter().filter(|x| x.outline.len() >= 3) {
            fill_polygon(target, t, &x.outline, ASPHALT);
        }
        let curves = map.lanes.iter().map(|l| &l.curve).chain(map.connectors.iter().map(|c| &c.curve));
        for curve in curves {
            quad_along(target, t, curve, 0.0, curve.length(), -half - 0.05, half + 0.05, ASPHALT);
        }
    }
    for (id, lane) in map.lanes.iter().enumerate() {
        let curve = &lane.curve;
        let len = curve.length();
        if map.adjacent_lane(id, true).is_some() {
            let mut s = 1.0;
            while s + 3.0 <= len - 1.0 {
                quad_along(pixmap, t, curve, s, s + 3.0, half - 0.07, half + 0.07, WHITE);
                s += 6.0;
            }
        } else {
            quad_along(pixmap, t, curve, 0.0, len, half - 0.2, half - 0.05, CENTRE_LINE);
        }
        let crate::map::LaneEnd::Intersection { intersection, .. } = lane.end else { continue };
        let line = len - map.layout.stop_line_setback;
        let junction = &map.intersections[intersection];
        // A stop sign or give-way triangle, on the kerb side only.
        let kerb_side = map.adjacent_lane(id, false).is_none();
        let sign = || if kerb_side { map.sign_of(id) } else { None };
        match junction.control {
            JunctionControl::Signals => quad_along(pixmap, t, curve, line, line + 0.4, -half, half, WHITE),
            JunctionControl::AllWayStop => {
                quad_along(pixmap, t, curve, line - 0.1, line + 0.5, -half, half, WHITE);
                if let Some(p) = sign() {
                    circle(pixmap, t, p.x, p.y, 0.55, WHITE);
                    circle(pixmap, t, p.x, p.y, 0.45, STOP_SIGN);
                }
            }
            JunctionControl::RightBeforeLeft => {}
            JunctionControl::Priority if map.on_priority_road(id) => {}
            JunctionControl::Priority => {
                let mut k = -half;
                while k < half {
                    quad_along(pixmap, t, curve, line, line + 0.4, k, (k + 0.6).min(half), WHITE);
                    k += 1.0;
                }
                if let Some(p) = sign() {
                    let ahead = curve.position(len, 0.0) - curve.position(len - 1.0, 0.0);
                    give_way_triangle(pixmap, t, p, ahead.normalize_or_zero());
                }
            }
        }
    }
}

/// One polygon along `curve` over `s` between the lateral offsets `lat`
/// (positive = left of travel), in `pieces` straight pieces: one side
/// forward, the other back (no seams between pieces).
fn band(
    pixmap: &mut Pixmap,
    t: Transform,
    curve: &crate::map::curve::Curve,
    s: [f64; 2],
    lat: [f64; 2],
    pieces: usize,
    rgb: [u8; 3],
) {
    let at = |k: usize| if k == pieces { s[1] } else { s[0] + (s[1] - s[0]) * k as f64 / pieces as f64 };
    let mut pts: Vec<DVec2> = (0..=pieces).map(|k| curve.position(at(k), lat[0])).collect();
    pts.extend((0..=pieces).rev().map(|k| curve.position(at(k), lat[1])));
    fill_polygon(pixmap, t, &pts, rgb);
}

/// The stretches of road `name` (crossing others at `crossings`, running
/// from -`extent` to `extent`) that the town has, each covering the
/// junction boxes at its ends, merged where segments meet; and the ends
/// that turn back in a loop. A whole road is one stretch with two loops.
fn road_runs(layout: &MapLayout, name: char, crossings: &[f64], extent: f64) -> (Vec<(f64, f64)>, Vec<f64>) {
    let hw = layout.road_half_width();
    let last = crossings.len();
    let mut runs: Vec<(f64, f64)> = Vec::new();
    let mut loops = Vec::new();
    for k in (0..=last).filter(|&k| layout.has_segment(name, k as u8)) {
        let mut from = if k == 0 { -extent } else { crossings[k - 1] - hw };
        let mut to = if k == last { extent } else { crossings[k] + hw };
        // A dead end stops short of the junction at its cut, in a loop.
        match layout.dead_end(name, k as u8).filter(|_| k > 0 && k < last) {
            Some(true) => {
                to = crossings[k] - hw - layout.dead_end_setback();
                loops.push(to);
            }
            Some(false) => {
                from = crossings[k - 1] + hw + layout.dead_end_setback();
                loops.push(from);
            }
            None => {}
        }
        match runs.last_mut() {
            Some(run) if run.1 >= from => run.1 = to,
            _ => runs.push((from, to)),
        }
    }
    loops.extend(
        [(0, -extent), (last, extent)]
            .into_iter()
            .filter(|&(k, _)| layout.has_segment(name, k as u8))
            .map(|(_, at)| at),
    );
    (runs, loops)
}

fn circle(pixmap: &mut Pixmap, t: Transform, x: f64, y: f64, r: f64, rgb: [u8; 3]) {
    if let Some(path) = PathBuilder::from_circle(x as f32, y as f32, r as f32) {
        pixmap.fill_path(&path, &paint(rgb), FillRule::Winding, t, None);
    }
}

/// A give-way sign seen from above: a white triangle with a red rim,
/// pointing back at the traffic it faces (`ahead`: that traffic's
/// direction of travel).
fn give_way_triangle(pixmap: &mut Pixmap, t: Transform, centre: DVec2, ahead: DVec2) {
    let side = DVec2::new(-ahead.y, ahead.x);
    for (size, rgb) in [(0.6, STOP_SIGN), (0.38, WHITE)] {
        let pts = [
            centre - ahead * size,
            centre + ahead * size * 0.6 + side * size,
            centre + ahead * size * 0.6 - side * size,
        ];
        fill_polygon(pixmap, t, &pts, rgb);
    }
}

/// Fills the polygon through `pts` (world metres under `t`).
fn fill_polygon(pixmap: &mut Pixmap, t: Transform, pts: &[DVec2], rgb: [u8; 3]) {
    let mut pb = PathBuilder::new();
    pb.move_to(pts[0].x as f32, pts[0].y as f32);
    for p in &pts[1..] {
        pb.line_to(p.x as f32, p.y as f32);
    }
    pb.close();
    if let Some(path) = pb.finish() {
        pixmap.fill_path(&path, &paint(rgb), FillRule::Winding, t, None);
    }
}

/// A band along `curve` from `s0` to `s1`, between two lateral offsets
/// (positive = left of travel): one quadrilateral on a grid town's straight
/// or round pieces, and on a polyline (an imported network's) pieces of at
/// most a metre, so that it bends with it.
#[allow(clippy::too_many_arguments)]
fn quad_along(
    pixmap: &mut Pixmap,
    t: Transform,
    curve: &crate::map::curve::Curve,
    s0: f64,
    s1: f64,
    lat0: f64,
    lat1: f64,
    rgb: [u8; 3],
) {
    let pieces = match curve {
        crate::map::curve::Curve::Polyline(_) => ((s1 - s0) / 1.0).ceil().max(1.0) as usize,
        _ => 1,
    };
    band(pixmap, t, curve, [s0, s1], [lat0, lat1], pieces, rgb);
}
