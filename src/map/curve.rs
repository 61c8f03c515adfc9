//! Curves parameterised by arc length: the geometry every lane, connector and
//! lane change is made of. Units are metres and radians; headings are measured
//! counter-clockwise from the +x (east) axis.

use glam::DVec2;
use std::f64::consts::PI;

/// A planar curve that maps arc length `s` (metres from its start) to a point
/// and a heading. Lateral offsets are positive to the left of travel.
#[derive(Debug, Clone, PartialEq)]
pub enum Curve {
    Line(Line),
    Arc(Arc),
    LaneChange(LaneChange),
    /// Straight pieces joined end to end, as imported networks give lanes.
    Polyline(Polyline),
}

impl Curve {
    /// The straight segment from `start` to `end`.
    pub fn line(start: DVec2, end: DVec2) -> Curve {
        let d = end - start;
        let direction = d.normalize();
        let heading = direction.y.atan2(direction.x);
        Curve::Line(Line {
            start,
            direction,
            length: d.length(),
            heading,
            left: DVec2::new(-heading.sin(), heading.cos()),
        })
    }

    /// The arc leaving `start` with `heading`, turning by `sweep` radians
    /// (positive = left) on a circle of `radius`.
    pub fn arc(start: DVec2, heading: f64, radius: f64, sweep: f64) -> Curve {
        let left = DVec2::new(-heading.sin(), heading.cos());
        let centre = start + left * radius * sweep.signum();
        let d = start - centre;
        Curve::Arc(Arc { centre, radius, start_angle: d.y.atan2(d.x), sweep })
    }

    /// A smooth change of `shift` metres sideways (positive = left) over
    /// `run` metres of travel along `direction`, starting at `start`.
    pub fn lane_change(start: DVec2, direction: DVec2, run: f64, shift: f64) -> Curve {
        Curve::LaneChange(LaneChange::build(start, direction, run, shift))
    }

    /// A smooth change of `shift` metres sideways (positive = left) that
    /// follows `base` from `at` metres along it for `run` metres, as the
    /// straight [`Curve::lane_change`] does along a line, ending at `end`
    /// (the point of the target lane there): pieces of at most 0.25 m.
    pub fn lane_change_along(base: &Curve, at: f64, run: f64, shift: f64, end: DVec2) -> Curve {
        let n = ((run / 0.25).ceil() as usize).max(2);
        let mut points: Vec<DVec2> = (0..n)
            .map(|k| {
                let u = run * k as f64 / n as f64;
                base.position(at + u, shift * smootherstep(u / run))
            })
            .collect();
        points.push(end);
        Curve::polyline(&points).unwrap_or_else(|| Curve::line(base.position(at, 0.0), end))
    }

    /// The straight pieces through `points` in turn (repeated points
    /// dropped); `None` with fewer than two distinct points.
    pub fn polyline(points: &[DVec2]) -> Option<Curve> {
        let mut kept: Vec<DVec2> = Vec::with_capacity(points.len());
        for &p in points {
            if kept.last().is_none_or(|q| q.distance(p) > 1e-9) {
                kept.push(p);
            }
        }
        if kept.len() < 2 {
            return None;
        }
        let mut cumulative = vec![0.0];
        for w in kept.windows(2) {
            cumulative.push(cumulative.last().copied().unwrap_or(0.0) + w[0].distance(w[1]));
        }
        Some(Curve::Polyline(Polyline { points: kept, cumulative }))
    }

    /// How many straight pieces a polyline has (other curves: 1).
    #[cfg(test)]
    pub(crate) fn pieces(&self) -> usize {
        match self {
            Curve::Polyline(c) => c.points.len() - 1,
            _ => 1,
        }
    }

    /// Length of the curve in metres.
    pub fn length(&self) -> f64 {
        match self {
            Curve::Line(c) => c.length,
            Curve::Arc(c) => c.radius * c.sweep.abs(),
            Curve::LaneChange(c) => c.length,
            Curve::Polyline(c) => c.cumulative[c.cumulative.len() - 1],
        }
    }

    /// The point at arc length `longitudinal`, moved `lateral` metres to the
    /// left of the direction of travel. `longitudinal` is clamped to the curve.
    pub fn position(&self, longitudinal: f64, lateral: f64) -> DVec2 {
        self.pose(longitudinal, lateral).0
    }

    /// [`Curve::position`] and [`Curve::heading_at`] together, each piece
    /// of the geometry computed once (a car's pose, every step).
    pub fn pose(&self, longitudinal: f64, lateral: f64) -> (DVec2, f64) {
        let s = longitudinal.clamp(0.0, self.length());
        let (centre, heading) = match self {
            Curve::Line(c) => {
                // The cached left normal is what sin and cos of the heading give.
                let centre = c.start + c.direction * s;
                return (if lateral == 0.0 { centre } else { centre + c.left * lateral }, c.heading);
            }
            Curve::Arc(c) => {
                let angle = c.angle_at(s);
                (c.point_at_angle(angle), c.heading_at_angle(angle))
            }
            Curve::LaneChange(c) => {
                let u = c.longitudinal_at_arc_length(s);
                (c.point_at(u), c.heading_at_longitudinal(u))
            }
            Curve::Polyline(c) => {
                let k = c.piece_at(s);
                let d = c.points[k + 1] - c.points[k];
                (c.points[k] + d.normalize() * (s - c.cumulative[k]), d.y.atan2(d.x))
            }
        };
        if lateral == 0.0 {
            return (centre, heading);
        }
        (centre + DVec2::new(-heading.sin(), heading.cos()) * lateral, heading)
    }

    /// The centre-line point at arc length `s`.
    pub fn lane_center_at(&self, s: f64) -> DVec2 {
        self.position(s, 0.0)
    }

    /// Heading (radians, counter-clockwise from east) at arc length `s`.
    pub fn heading_at(&self, s: f64) -> f64 {
        let s = s.clamp(0.0, self.length());
        match self {
            Curve::Line(c) => c.heading,
            Curve::Arc(c) => c.heading_at_angle(c.angle_at(s)),
            Curve::LaneChange(c) => c.heading_at_longitudinal(c.longitudinal_at_arc_length(s)),
            Curve::Polyline(c) => {
                let k = c.piece_at(s);
                let d = c.points[k + 1] - c.points[k];
                d.y.atan2(d.x)
            }
        }
    }

    /// Inverse of [`Curve::position`]: `(longitudinal, lateral)` of `point`
    /// relative to this curve (nearest point, clamped to the curve's extent).
    pub fn local_coordinates(&self, point: DVec2) -> (f64, f64) {
        match self {
            Curve::Line(c) => {
                let d = point - c.start;
                let s = d.dot(c.direction);
                (s, c.direction.perp_dot(d))
            }
            Curve::Arc(c) => {
                let d = point - c.centre;
                let angle = d.y.atan2(d.x);
                let delta = wrap_angle(angle - c.start_angle);
                let s = delta * c.sweep.signum() * c.radius;
                // Left of travel is towards the centre for a left (ccw) turn.
                let lateral = (c.radius - d.length()) * c.sweep.signum();
                (s, lateral)
            }
            Curve::Polyline(c) => {
                // The nearest point of the nearest piece.
                let mut best = (f64::INFINITY, 0.0, 0.0);
                for k in 0..c.points.len() - 1 {
                    let (a, b) = (c.points[k], c.points[k + 1]);
                    let length = c.cumulative[k + 1] - c.cumulative[k];
                    let direction = (b - a) / length;
                    let d = point - a;
                    let along = d.dot(direction);
                    // Beyond the ends only on the first and last piece.
                    let t = match (k == 0, k + 2 == c.points.len()) {
                        (true, true) => along,
                        (true, false) => along.min(length),
                        (false, true) => along.max(0.0),
                        (false, false) => along.clamp(0.0, length),
                    };
                    let distance = (d - direction * t).length_squared();
                    if distance < best.0 {
                        best = (distance, c.cumulative[k] + t, direction.perp_dot(d));
                    }
                }
                (best.1, best.2)
            }
            Curve::LaneChange(c) => {
                // Nearest sample, then refine on the tangent: lane changes are
                // short and gently curved, so this is accurate to millimetres.
                let n = 64;
                let len = c.length;
                let mut best = (0.0, f64::INFINITY);
                for i in 0..=n {
                    let s = len * i as f64 / n as f64;
                    let dist = self.lane_center_at(s).distance_squared(point);
                    if dist < best.1 {
                        best = (s, dist);
                    }
                }
                let mut s0 = best.0;
                for _ in 0..4 {
                    let h = self.heading_at(s0);
                    let t = DVec2::new(h.cos(), h.sin());
                    s0 += (point - self.lane_center_at(s0)).dot(t);
                }
                let h = self.heading_at(s0);
                let t = DVec2::new(h.cos(), h.sin());
                let d = point - self.lane_center_at(s0);
                (s0 + d.dot(t), t.perp_dot(d))
            }
        }
    }

    /// First point of the curve.
    pub fn start(&self) -> DVec2 {
        self.lane_center_at(0.0)
    }

    /// Last point of the curve.
    pub fn end(&self) -> DVec2 {
        self.lane_center_at(self.length())
    }
}

/// Straight pieces joined end to end: the points and the arc length at
/// each (from 0).
#[derive(Debug, Clone, PartialEq)]
pub struct Polyline {
    points: Vec<DVec2>,
    cumulative: Vec<f64>,
}

impl Polyline {
    /// The piece arc length `s` lies on (the last one at its end).
    fn piece_at(&self, s: f64) -> usize {
        self.cumulative.partition_point(|&c| c <= s).clamp(1, self.points.len() - 1) - 1
    }
}

/// A straight segment.
#[derive(Debug, Clone, PartialEq)]
pub struct Line {
    pub start: DVec2,
    /// Unit vector of travel.
    pub direction: DVec2,
    pub length: f64,
    /// `direction`'s heading, radians, and the unit normal to its left
    /// (from that heading's sine and cosine, as other curves compute theirs).
    heading: f64,
    left: DVec2,
}

/// A circular arc; positive `sweep` turns left (counter-clockwise).
#[derive(Debug, Clone, PartialEq)]
pub struct Arc {
    pub centre: DVec2,
    pub radius: f64,
    /// Angle of the start point as seen from the centre.
    pub start_angle: f64,
    /// Signed angle swept, radians.
    pub sweep: f64,
}

impl Arc {
    fn angle_at(&self, s: f64) -> f64 {
        self.start_angle + self.sweep.signum() * s / self.radius
    }

    fn point_at_angle(&self, angle: f64) -> DVec2 {
        self.centre + DVec2::new(angle.cos(), angle.sin()) * self.radius
    }

    fn heading_at_angle(&self, angle: f64) -> f64 {
        wrap_angle(angle + self.sweep.signum() * PI / 2.0)
    }
}

/// A smooth lane change: the path moves from one straight lane to a parallel
/// one, its lateral offset following a quintic smoothstep (zero curvature at
/// both ends). Arc length is mapped through a precomputed table.
#[derive(Debug, Clone, PartialEq)]
pub struct LaneChange {
    pub start: DVec2,
    /// Unit vector of travel of both lanes.
    pub direction: DVec2,
    /// Distance along `direction` over which the change happens.
    pub run: f64,
    /// Signed lateral shift, positive to the left.
    pub shift: f64,
    /// Total arc length.
    pub length: f64,
    /// Arc length at `run * i / (n - 1)`, for inverting arc length.
    arc_table: Vec<f64>,
}

const LANE_CHANGE_TABLE: usize = 65;

impl LaneChange {
    fn build(start: DVec2, direction: DVec2, run: f64, shift: f64) -> LaneChange {
        let mut lc =
            LaneChange { start, direction, run, shift, length: 0.0, arc_table: Vec::with_capacity(LANE_CHANGE_TABLE) };
        // Integrate |p'(u)| with Simpson's rule on each table interval.
        let mut acc = 0.0;
        lc.arc_table.push(0.0);
        let step = run / (LANE_CHANGE_TABLE - 1) as f64;
        for i in 0..LANE_CHANGE_TABLE - 1 {
            let a = i as f64 * step;
            let speed = |u: f64| lc.speed(u);
            acc += step / 6.0 * (speed(a) + 4.0 * speed(a + step / 2.0) + speed(a + step));
            lc.arc_table.push(acc);
        }
        lc.length = acc;
        lc
    }

    fn longitudinal_at_arc_length(&self, s: f64) -> f64 {
        let table = &self.arc_table;
        let i = table.partition_point(|&a| a < s).clamp(1, table.len() - 1);
        let (a0, a1) = (table[i - 1], table[i]);
        let step = self.run / (table.len() - 1) as f64;
        let (u0, u1) = ((i - 1) as f64 * step, i as f64 * step);
        let h = a1 - a0;
        if h <= 0.0 {
            return u0;
        }
        // Cubic Hermite on u(s), with du/ds = 1 / |p'(u)| known at both nodes.
        let t = ((s - a0) / h).clamp(0.0, 1.0);
        let (m0, m1) = (1.0 / self.speed(u0), 1.0 / self.speed(u1));
        let (t2, t3) = (t * t, t * t * t);
        (2.0 * t3 - 3.0 * t2 + 1.0) * u0
            + (t3 - 2.0 * t2 + t) * h * m0
            + (-2.0 * t3 + 3.0 * t2) * u1
            + (t3 - t2) * h * m1
    }

    /// |dp/du|: metres of path per metre along the lane.
    fn speed(&self, u: f64) -> f64 {
        (1.0 + (self.shift * smootherstep_derivative(u / self.run) / self.run).powi(2)).sqrt()
    }

    fn point_at(&self, u: f64) -> DVec2 {
        let left = self.direction.perp();
        self.start + self.direction * u + left * self.shift * smootherstep(u / self.run)
    }

    fn heading_at_longitudinal(&self, u: f64) -> f64 {
        let left = self.direction.perp();
        let d = self.direction + left * self.shift * smootherstep_derivative(u / self.run) / self.run;
        d.y.atan2(d.x)
    }
}

fn smootherstep(t: f64) -> f64 {
    let t = t.clamp(0.0, 1.0);
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

fn smootherstep_derivative(t: f64) -> f64 {
    let t = t.clamp(0.0, 1.0);
    30.0 * t * t * (t - 1.0) * (t - 1.0)
}

/// Wraps an angle to (-pi, pi].
pub fn wrap_angle(a: f64) -> f64 {
    let mut a = crate::remainder::fmod(a, 2.0 * PI);
    if a <= -PI {
        a += 2.0 * PI;
    } else if a > PI {
        a -= 2.0 * PI;
    }
    a
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arc_quarter_turn_ends_where_expected() {
        let arc = Curve::arc(DVec2::new(0.0, 0.0), 0.0, 2.0, PI / 2.0);
        let end = arc.end();
        assert!((end - DVec2::new(2.0, 2.0)).length() < 1e-9, "{end:?}");
        assert!((arc.heading_at(arc.length()) - PI / 2.0).abs() < 1e-9);
        let right = Curve::arc(DVec2::new(0.0, 0.0), 0.0, 2.0, -PI / 2.0);
        assert!((right.end() - DVec2::new(2.0, -2.0)).length() < 1e-9);
        assert!((right.heading_at(right.length()) + PI / 2.0).abs() < 1e-9);
    }

    #[test]
    fn lane_change_is_parameterised_by_arc_length() {
        let c = Curve::lane_change(DVec2::ZERO, DVec2::X, 8.0, 3.0);
        assert!((c.end() - DVec2::new(8.0, 3.0)).length() < 1e-9);
        // Equal steps of s give equal chord lengths (up to curvature).
        let n = 40;
        let step = c.length() / n as f64;
        for i in 0..n {
            let a = c.lane_center_at(i as f64 * step);
            let b = c.lane_center_at((i + 1) as f64 * step);
            assert!((a.distance(b) - step).abs() < 1e-3, "step {i}: {}", a.distance(b));
        }
        assert!(c.heading_at(0.0).abs() < 1e-9 && c.heading_at(c.length()).abs() < 1e-9);
    }

    #[test]
    fn local_coordinates_invert_position() {
        let curves = [
            Curve::line(DVec2::new(1.0, 1.0), DVec2::new(1.0, 9.0)),
            Curve::arc(DVec2::new(0.0, 0.0), 0.3, 7.5, PI / 2.0),
            Curve::arc(DVec2::new(0.0, 0.0), 0.3, 1.5, -PI / 2.0),
            Curve::lane_change(DVec2::ZERO, DVec2::Y, 8.0, -3.0),
        ];
        for c in &curves {
            for &(s, lat) in &[(0.5, 0.0), (1.0, 0.4), (2.0, -0.3)] {
                let p = c.position(s, lat);
                let (s2, lat2) = c.local_coordinates(p);
                assert!((s2 - s).abs() < 1e-3 && (lat2 - lat).abs() < 1e-3, "{c:?} {s} {lat} -> {s2} {lat2}");
            }
        }
    }
}

#[cfg(test)]
mod polyline_tests {
    use super::*;

    #[test]
    fn a_polyline_is_parameterised_by_arc_length_and_inverts() {
        // East 10 m, then north 5 m; a repeated point is dropped.
        let pts = [DVec2::new(0.0, 0.0), DVec2::new(10.0, 0.0), DVec2::new(10.0, 0.0), DVec2::new(10.0, 5.0)];
        let c = Curve::polyline(&pts).unwrap();
        assert!((c.length() - 15.0).abs() < 1e-12);
        assert!(c.position(4.0, 1.0).distance(DVec2::new(4.0, 1.0)) < 1e-12, "1 m to the left of travel");
        assert!(c.position(12.0, 1.0).distance(DVec2::new(9.0, 2.0)) < 1e-12);
        assert!((c.heading_at(3.0) - 0.0).abs() < 1e-12);
        assert!((c.heading_at(12.0) - PI / 2.0).abs() < 1e-12);
        assert_eq!((c.start(), c.end()), (DVec2::new(0.0, 0.0), DVec2::new(10.0, 5.0)));
        let mut checked = 0;
        for (s, lateral) in [(1.0, 0.5), (7.5, -0.8), (12.5, 0.3), (14.0, -0.5)] {
            let (s2, l2) = c.local_coordinates(c.position(s, lateral));
            assert!((s2 - s).abs() < 1e-9 && (l2 - lateral).abs() < 1e-9, "({s}, {lateral}) came back as ({s2}, {l2})");
            checked += 1;
        }
        assert_eq!(checked, 4);
        // Beyond its ends, along the first and last pieces.
        assert!((c.local_coordinates(DVec2::new(-2.0, 0.0)).0 + 2.0).abs() < 1e-12);
        assert!(Curve::polyline(&[DVec2::ZERO, DVec2::ZERO]).is_none());
    }
}
