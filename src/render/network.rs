//! A picture of an imported road network from above: the lanes cars drive
//! (asphalt, with their edges marked), the junctions' outlines, and a mark
//! on each junction for its control. Flat colours, like the background.

use crate::map::sumo::{SumoJunctionKind, SumoNetwork};
use glam::DVec2;
use tiny_skia::{Color, FillRule, Paint, PathBuilder, Pixmap, Stroke, Transform};

const GROUND: [u8; 3] = [200, 198, 190];
const ASPHALT: [u8; 3] = [66, 68, 72];
const LANE_EDGE: [u8; 3] = [240, 240, 240];
/// Junction marks: lights green, priority yellow, stops red, others grey.
fn mark(kind: SumoJunctionKind) -> Option<[u8; 3]> {
    match kind {
        SumoJunctionKind::TrafficLight => Some([40, 170, 70]),
        SumoJunctionKind::Priority => Some([232, 190, 40]),
        SumoJunctionKind::AllWayStop => Some([196, 32, 36]),
        SumoJunctionKind::RightBeforeLeft | SumoJunctionKind::LeftBeforeRight | SumoJunctionKind::Unregulated => {
            Some([120, 120, 200])
        }
        SumoJunctionKind::DeadEnd => None,
    }
}

fn paint(rgb: [u8; 3]) -> Paint<'static> {
    let mut p = Paint::default();
    p.set_color_rgba8(rgb[0], rgb[1], rgb[2], 255);
    p.anti_alias = true;
    p
}

/// Where a network picture puts the world: `ppm` pixels per metre, the
/// world point `lo` at the picture's lower-left corner plus a margin.
#[derive(Debug, Clone, Copy)]
pub struct NetworkView {
    pub width: u32,
    pub height: u32,
    pub ppm: f64,
    lo: DVec2,
    margin: f64,
}

impl NetworkView {
    /// The view that fits `net` into `longest` pixels along its longer side.
    pub fn fitting(net: &SumoNetwork, longest: u32) -> NetworkView {
        let (lo, hi) = net.bounds();
        let size = (hi - lo).max(DVec2::splat(1.0));
        let margin = 10.0;
        let ppm = (longest as f64 - 2.0 * margin) / size.x.max(size.y);
        let width = (size.x * ppm + 2.0 * margin).ceil() as u32;
        let height = (size.y * ppm + 2.0 * margin).ceil() as u32;
        NetworkView { width, height, ppm, lo, margin }
    }

    /// Pixel of world point `p` (y up in the world, down in the picture).
    pub fn to_pixel(&self, p: DVec2) -> DVec2 {
        DVec2::new(
            self.margin + (p.x - self.lo.x) * self.ppm,
            self.height as f64 - self.margin - (p.y - self.lo.y) * self.ppm,
        )
    }
}

/// Draws `net` as `view` frames it.
pub fn draw_network(net: &SumoNetwork, view: &NetworkView) -> Pixmap {
    let mut pixmap = Pixmap::new(view.width, view.height).expect("a picture of positive size");
    pixmap.fill(Color::from_rgba8(GROUND[0], GROUND[1], GROUND[2], 255));
    let path_of = |points: &[DVec2], close: bool| {
        let mut pb = PathBuilder::new();
        for (k, p) in points.iter().enumerate() {
            let q = view.to_pixel(*p);
            if k == 0 {
                pb.move_to(q.x as f32, q.y as f32);
            } else {
                pb.line_to(q.x as f32, q.y as f32);
            }
        }
        if close {
            pb.close();
        }
        pb.finish()
    };
    for junction in net.junctions.iter().filter(|j| j.shape.len() >= 3) {
        if let Some(path) = path_of(&junction.shape, true) {
            pixmap.fill_path(&path, &paint(ASPHALT), FillRule::Winding, Transform::identity(), None);
        }
    }
    for lane in &net.lanes {
        let Some(path) = path_of(&lane.shape, false) else { continue };
        let width = (lane.width * view.ppm) as f32;
        let road = Stroke { width, ..Stroke::default() };
        pixmap.stroke_path(&path, &paint(ASPHALT), &road, Transform::identity(), None);
        // A thin line on the lane's centre shows where cars drive.
        let centre = Stroke { width: (0.15 * view.ppm as f32).max(0.5), ..Stroke::default() };
        pixmap.stroke_path(&path, &paint(LANE_EDGE), &centre, Transform::identity(), None);
    }
    for junction in &net.junctions {
        let Some(rgb) = mark(junction.kind) else { continue };
        let p = view.to_pixel(junction.centre);
        let r = (1.5 * view.ppm).max(2.5) as f32;
        if let Some(path) = PathBuilder::from_circle(p.x as f32, p.y as f32, r) {
            pixmap.fill_path(&path, &paint(rgb), FillRule::Winding, Transform::identity(), None);
        }
    }
    pixmap
}
