//! Small planar geometry shared by worlds and planners: oriented boxes (car
//! footprints) and their overlap test.

use glam::DVec2;

/// A rectangle centred on `centre`, `length` along `heading`, `width` across.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OrientedBox {
    pub centre: DVec2,
    pub heading: f64,
    pub length: f64,
    pub width: f64,
}

impl OrientedBox {
    /// The four corners, counter-clockwise from front-left.
    pub fn corners(&self) -> [DVec2; 4] {
        let forward = DVec2::new(self.heading.cos(), self.heading.sin()) * (self.length / 2.0);
        let left = DVec2::new(-self.heading.sin(), self.heading.cos()) * (self.width / 2.0);
        let c = self.centre;
        [c + forward + left, c - forward + left, c - forward - left, c + forward - left]
    }

    /// This box grown by `margin` on every side.
    pub fn inflated(&self, margin: f64) -> OrientedBox {
        OrientedBox { length: self.length + 2.0 * margin, width: self.width + 2.0 * margin, ..*self }
    }

    /// True when the two boxes share any area (separating axis test).
    pub fn overlaps(&self, other: &OrientedBox) -> bool {
        let (a, b) = (self.corners(), other.corners());
        let axes = [
            DVec2::new(self.heading.cos(), self.heading.sin()),
            DVec2::new(-self.heading.sin(), self.heading.cos()),
            DVec2::new(other.heading.cos(), other.heading.sin()),
            DVec2::new(-other.heading.sin(), other.heading.cos()),
        ];
        axes.iter().all(|axis| {
            let project = |pts: &[DVec2; 4]| {
                pts.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                    let d = p.dot(*axis);
                    (lo.min(d), hi.max(d))
                })
            };
            let (a0, a1) = project(&a);
            let (b0, b1) = project(&b);
            a0 < b1 && b0 < a1
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn boxes_overlap_only_when_they_touch() {
        let a = OrientedBox { centre: DVec2::ZERO, heading: 0.0, length: 4.0, width: 2.0 };
        let near = OrientedBox { centre: DVec2::new(3.9, 0.0), ..a };
        let far = OrientedBox { centre: DVec2::new(4.1, 0.0), ..a };
        assert!(a.overlaps(&near));
        assert!(!a.overlaps(&far));
        // Rotated 45 degrees: the corner reaches further than the side.
        let rotated = OrientedBox { centre: DVec2::new(0.0, 2.2), heading: std::f64::consts::FRAC_PI_4, ..a };
        assert!(a.overlaps(&rotated));
        let beside = OrientedBox { centre: DVec2::new(0.0, 3.5), heading: std::f64::consts::FRAC_PI_4, ..a };
        assert!(!a.overlaps(&beside));
    }
}
