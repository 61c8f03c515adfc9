//! The camera: the only place where metres become pixels.

use glam::DVec2;
use serde::Serialize;

/// The original's dataset camera height, metres.
pub const ORIGINAL_ALTITUDE_M: f64 = 40.0;
/// The original's horizontal field of view, degrees.
pub const ORIGINAL_FOV_DEG: f64 = 90.0;

/// Focal length in pixels of the bird's-eye lens for an image `width` wide.
fn birds_eye_focal_px(width: u32) -> f64 {
    (width as f64 / 2.0) / (ORIGINAL_FOV_DEG.to_radians() / 2.0).tan()
}

/// A pinhole camera looking straight down, possibly turned about the
/// vertical. Pixel coordinates are in pixel-index units: pixel column `i` has
/// its centre at `px = i`, so the mean index of a car's mask pixels is its
/// `(px, py)`.
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
    /// World direction shown as "up" in the image, radians counter-clockwise
    /// from north (0: north up, as the bird's-eye view).
    #[serde(skip_serializing_if = "is_zero")]
    pub rotation_rad: f64,
}

fn is_zero(x: &f64) -> bool {
    *x == 0.0
}

impl Camera {
    /// The original's dataset camera: 40 m up, 90 degree horizontal field of
    /// view, over the centre of the city (12.8 px per metre at 1024 px wide).
    pub fn birds_eye(width: u32, height: u32) -> Camera {
        Camera::birds_eye_over(width, height, DVec2::ZERO, ORIGINAL_ALTITUDE_M)
    }

    /// The bird's-eye lens (90 degree horizontal field of view) looking
    /// straight down on `centre` from `altitude_m` metres.
    pub fn birds_eye_over(width: u32, height: u32, centre: DVec2, altitude_m: f64) -> Camera {
        Camera {
            width,
            height,
            centre_x: centre.x,
            centre_y: centre.y,
            altitude_m,
            horizontal_fov_deg: ORIGINAL_FOV_DEG,
            pixels_per_metre: birds_eye_focal_px(width) / altitude_m,
            rotation_rad: 0.0,
        }
    }

    /// The lowest altitude (metres) from which the bird's-eye lens shows a
    /// ground box of `size` metres (width, height) whole in a `width` x
    /// `height` image.
    pub fn altitude_to_frame(width: u32, height: u32, size: DVec2) -> f64 {
        let ppm = (width as f64 / size.x).min(height as f64 / size.y);
        birds_eye_focal_px(width) / ppm
    }

    /// A camera with the bird's-eye lens (90 degree field of view) over
    /// `centre`, turned by `rotation_rad`, at `zoom` times the bird's-eye
    /// scale (12.8 px per metre at zoom 1, whatever the image size: a small
    /// image is a crop, flown lower).
    pub fn looking_down(width: u32, height: u32, centre: DVec2, rotation_rad: f64, zoom: f64) -> Camera {
        let base = Camera::birds_eye(width, height);
        Camera {
            centre_x: centre.x,
            centre_y: centre.y,
            altitude_m: base.altitude_m * (width as f64 / 1024.0) / zoom,
            pixels_per_metre: base.pixels_per_metre * zoom * 1024.0 / width as f64,
            rotation_rad,
            ..base
        }
    }

    /// Focal length in pixels.
    pub fn focal_px(&self) -> f64 {
        self.pixels_per_metre * self.altitude_m
    }

    /// Ground point (metres) to pixel coordinates (x right, y down).
    pub fn to_pixel(&self, p: DVec2) -> DVec2 {
        let d = self.view_axes_of(p - DVec2::new(self.centre_x, self.centre_y));
        DVec2::new(
            (self.width as f64 - 1.0) / 2.0 + d.x * self.pixels_per_metre,
            (self.height as f64 - 1.0) / 2.0 - d.y * self.pixels_per_metre,
        )
    }

    /// A ground offset in the camera's axes (x right, y up in the image).
    fn view_axes_of(&self, d: DVec2) -> DVec2 {
        if self.rotation_rad == 0.0 {
            return d;
        }
        let (s, c) = (-self.rotation_rad).sin_cos();
        DVec2::new(c * d.x - s * d.y, s * d.x + c * d.y)
    }

    /// A pixel position lies on the image (its nearest pixel exists).
    pub fn contains_pixel(&self, px: DVec2) -> bool {
        px.x >= -0.5 && px.y >= -0.5 && px.x < self.width as f64 - 0.5 && px.y < self.height as f64 - 0.5
    }

    /// The ground seen by the camera, as an axis-aligned box around it (the
    /// view itself when not turned): (min corner, max corner), metres.
    pub fn ground_view(&self) -> (DVec2, DVec2) {
        let half = DVec2::new(self.width as f64, self.height as f64) / (2.0 * self.pixels_per_metre);
        let (s, c) = self.rotation_rad.sin_cos();
        let half = DVec2::new(c.abs() * half.x + s.abs() * half.y, s.abs() * half.x + c.abs() * half.y);
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

/// An extra camera of a scenario, beside the bird's-eye view: it writes its
/// own frames under `cameras/<name>/`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CameraPlan {
    pub name: String,
    pub width: u32,
    pub height: u32,
    /// Times the bird's-eye scale (12.8 px per metre).
    pub zoom: f64,
    /// Also write 16-bit depth frames.
    pub depth: bool,
    pub kind: CameraKind,
}

/// Where an extra camera looks.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum CameraKind {
    /// Fixed over `centre` (metres), turned by `rotation_deg` (counter-
    /// clockwise; the image's up direction, 0 = north).
    Static { centre: [f64; 2], rotation_deg: f64 },
    /// Follows car `car` (index in id order), centred on it and turned so
    /// that it drives up the image.
    Chase { car: usize },
}

impl CameraPlan {
    /// The camera for a frame in which the chased car (if any) is at
    /// `position` heading `yaw` (radians counter-clockwise from east).
    pub fn camera_at(&self, chased: Option<(DVec2, f64)>) -> Camera {
        match (&self.kind, chased) {
            (CameraKind::Chase { .. }, Some((position, yaw))) => {
                Camera::looking_down(self.width, self.height, position, yaw - std::f64::consts::FRAC_PI_2, self.zoom)
            }
            (CameraKind::Static { centre, rotation_deg }, _) => Camera::looking_down(
                self.width,
                self.height,
                DVec2::new(centre[0], centre[1]),
                rotation_deg.to_radians(),
                self.zoom,
            ),
            (CameraKind::Chase { .. }, None) => {
                Camera::looking_down(self.width, self.height, DVec2::ZERO, 0.0, self.zoom)
            }
        }
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

    #[test]
    fn a_turned_camera_shows_its_direction_up() {
        // Turned a quarter to the left: west is up, north is to the right.
        let c = Camera::looking_down(200, 100, DVec2::new(5.0, 5.0), std::f64::consts::FRAC_PI_2, 2.0);
        let centre = c.to_pixel(DVec2::new(5.0, 5.0));
        assert!((centre - DVec2::new(99.5, 49.5)).length() < 1e-9);
        let west = c.to_pixel(DVec2::new(4.0, 5.0));
        assert!((west - DVec2::new(99.5, 49.5 - c.pixels_per_metre)).length() < 1e-9);
        let north = c.to_pixel(DVec2::new(5.0, 6.0));
        assert!((north - DVec2::new(99.5 + c.pixels_per_metre, 49.5)).length() < 1e-9);
        // Zoom 1 is the bird's-eye scale, 12.8 px per metre, whatever the size.
        assert!((c.pixels_per_metre - 2.0 * 12.8).abs() < 1e-9);
        assert!((c.focal_px() - 100.0).abs() < 1e-9);
    }
}
