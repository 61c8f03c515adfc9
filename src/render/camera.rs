//! The camera: the only place where metres become pixels.

use glam::DVec2;
use serde::Serialize;

/// A pinhole camera looking straight down. Pixel coordinates are in
/// pixel-index units: pixel column `i` has its centre at `px = i`, so the mean
/// index of a car's mask pixels is its `(px, py)`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Camera {
    pub width: u32,
    pub height: u32,
    /// World point (metres) seen at the image centre.
    pub centre_x: f64,
    pub centre_y: f64,
    pub altitude_m: f64,
    pub horizontal_fov_deg: f64,
    pub pixels_per_metre: f64,
}

impl Camera {
    /// The original's dataset camera: 40 m up, 90 degree horizontal field of
    /// view, over the centre of the city (12.8 px per metre at 1024 px wide).
    pub fn birds_eye(width: u32, height: u32) -> Camera {
        let altitude_m = 40.0;
        let horizontal_fov_deg: f64 = 90.0;
        let focal_px = (width as f64 / 2.0) / (horizontal_fov_deg.to_radians() / 2.0).tan();
        Camera {
            width,
            height,
            centre_x: 0.0,
            centre_y: 0.0,
            altitude_m,
            horizontal_fov_deg,
            pixels_per_metre: focal_px / altitude_m,
        }
    }

    /// Ground point (metres) to pixel coordinates (x right, y down).
    pub fn to_pixel(&self, p: DVec2) -> DVec2 {
        DVec2::new(
            (self.width as f64 - 1.0) / 2.0 + (p.x - self.centre_x) * self.pixels_per_metre,
            (self.height as f64 - 1.0) / 2.0 - (p.y - self.centre_y) * self.pixels_per_metre,
        )
    }

    /// A pixel position lies on the image (its nearest pixel exists).
    pub fn contains_pixel(&self, px: DVec2) -> bool {
        px.x >= -0.5 && px.y >= -0.5 && px.x < self.width as f64 - 0.5 && px.y < self.height as f64 - 0.5
    }

    /// The ground rectangle seen by the camera: (min corner, max corner), metres.
    pub fn ground_view(&self) -> (DVec2, DVec2) {
        let half = DVec2::new(self.width as f64, self.height as f64) / (2.0 * self.pixels_per_metre);
        let c = DVec2::new(self.centre_x, self.centre_y);
        (c - half, c + half)
    }

    /// Metres to pixels for lengths.
    pub fn metres_to_pixels(&self, metres: f64) -> f64 {
        metres * self.pixels_per_metre
    }

    /// Pixels to metres for lengths.
    pub fn pixels_to_metres(&self, pixels: f64) -> f64 {
        pixels / self.pixels_per_metre
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_camera_matches_the_original() {
        let c = Camera::birds_eye(1024, 640);
        assert!((c.pixels_per_metre - 12.8).abs() < 1e-9);
        let (lo, hi) = c.ground_view();
        assert!((hi.x - lo.x - 80.0).abs() < 1e-9 && (hi.y - lo.y - 50.0).abs() < 1e-9);
        assert_eq!(c.to_pixel(DVec2::ZERO), DVec2::new(511.5, 319.5));
        // North is up.
        assert!(c.to_pixel(DVec2::new(0.0, 1.0)).y < 319.5);
    }
}
