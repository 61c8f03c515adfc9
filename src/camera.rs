//! The camera: the only place where metres become pixels.

use glam::{DVec2, DVec3};
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

/// A pinhole camera anywhere, looking any way: position (metres), yaw
/// (radians counter-clockwise from east, as a car's heading), pitch
/// (radians above the horizontal: -pi/2 looks straight down) and roll
/// (radians, clockwise as seen from behind), with a horizontal field of
/// view. Pixel coordinates as [`Camera`]'s: column `i` has its centre at
/// `px = i`, x right and y down.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Pinhole {
    pub width: u32,
    pub height: u32,
    pub position: [f64; 3],
    pub yaw_rad: f64,
    pub pitch_rad: f64,
    pub roll_rad: f64,
    pub horizontal_fov_deg: f64,
}

/// Closer than this to a pinhole (metres along its axis) nothing is drawn.
pub const NEAR_M: f64 = 0.05;

impl Pinhole {
    /// The original's bird's-eye camera as a true pinhole: 40 m over the
    /// centre, looking straight down with north up, 90 degrees across.
    pub fn original_birds_eye(width: u32, height: u32) -> Pinhole {
        Pinhole {
            width,
            height,
            position: [0.0, 0.0, ORIGINAL_ALTITUDE_M],
            yaw_rad: std::f64::consts::FRAC_PI_2,
            pitch_rad: -std::f64::consts::FRAC_PI_2,
            roll_rad: 0.0,
            horizontal_fov_deg: ORIGINAL_FOV_DEG,
        }
    }

    /// Focal length in pixels.
    pub fn focal_px(&self) -> f64 {
        (self.width as f64 / 2.0) / (self.horizontal_fov_deg.to_radians() / 2.0).tan()
    }

    /// The image centre in pixels.
    pub fn centre_px(&self) -> DVec2 {
        DVec2::new((self.width as f64 - 1.0) / 2.0, (self.height as f64 - 1.0) / 2.0)
    }

    pub fn position(&self) -> DVec3 {
        DVec3::from_array(self.position)
    }

    /// The camera's axes in the world: right, down and forward (unit vectors).
    pub fn axes(&self) -> [DVec3; 3] {
        let (sy, cy) = self.yaw_rad.sin_cos();
        let (sp, cp) = self.pitch_rad.sin_cos();
        let forward = DVec3::new(cp * cy, cp * sy, sp);
        let right = DVec3::new(sy, -cy, 0.0);
        let up = right.cross(forward);
        let (sr, cr) = self.roll_rad.sin_cos();
        let (right, up) = (right * cr - up * sr, up * cr + right * sr);
        [right, -up, forward]
    }

    /// A world point in the camera's axes (x right, y down, z forward), metres.
    pub fn to_camera(&self, p: DVec3) -> DVec3 {
        let [right, down, forward] = self.axes();
        let d = p - self.position();
        DVec3::new(d.dot(right), d.dot(down), d.dot(forward))
    }

    /// Pixel of a point in the camera's axes in front of it (z >= [`NEAR_M`]).
    pub fn camera_to_pixel(&self, c: DVec3) -> Option<DVec2> {
        (c.z >= NEAR_M).then(|| self.centre_px() + DVec2::new(c.x, c.y) * (self.focal_px() / c.z))
    }

    /// Pixel of a world point in front of the camera.
    pub fn to_pixel(&self, p: DVec3) -> Option<DVec2> {
        self.camera_to_pixel(self.to_camera(p))
    }

    /// The ray through pixel (px, py) in the world, scaled so that its
    /// component along the camera's axis is 1: a point at distance `z` along
    /// the axis lies at `position + z * ray`.
    pub fn ray(&self, px: f64, py: f64) -> DVec3 {
        let [right, down, forward] = self.axes();
        let c = self.centre_px();
        let f = self.focal_px();
        forward + right * ((px - c.x) / f) + down * ((py - c.y) / f)
    }

    /// A pixel position lies on the image.
    pub fn contains_pixel(&self, px: DVec2) -> bool {
        px.x >= -0.5 && px.y >= -0.5 && px.x < self.width as f64 - 0.5 && px.y < self.height as f64 - 0.5
    }
}

/// Third-person view: metres behind the car, metres up, and the pitch.
pub const THIRD_PERSON_BEHIND_M: f64 = 8.0;
pub const THIRD_PERSON_UP_M: f64 = 4.0;
pub const THIRD_PERSON_PITCH_DEG: f64 = -18.0;
/// Share of the way a third-person camera turns and moves towards its
/// place behind the car each frame: it follows smoothly, not rigidly.
pub const THIRD_PERSON_FOLLOW: f64 = 0.25;
/// First-person view: eye height (a seated driver, metres) and how far
/// ahead of the car's centre the windscreen is, as a share of its length.
pub const FIRST_PERSON_EYE_M: f64 = 1.2;
pub const FIRST_PERSON_AHEAD: f64 = 0.15;
/// Field of view of the third- and first-person cameras, degrees.
pub const PERSON_FOV_DEG: f64 = 90.0;

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
    /// A fixed pinhole in perspective (`width` and `height` are its own).
    Pinhole(Pinhole),
    /// In perspective, behind and above car `car`, following it smoothly.
    ThirdPerson { car: usize },
    /// In perspective, at car `car`'s windscreen, looking ahead.
    FirstPerson { car: usize },
}

impl CameraKind {
    /// Seen in perspective (solids, depth along rays) rather than looking
    /// straight down on a flat drawing.
    pub fn is_perspective(&self) -> bool {
        matches!(self, CameraKind::Pinhole(_) | CameraKind::ThirdPerson { .. } | CameraKind::FirstPerson { .. })
    }

    /// The car a moving camera follows.
    pub fn followed_car(&self) -> Option<usize> {
        match self {
            CameraKind::Chase { car } | CameraKind::ThirdPerson { car } | CameraKind::FirstPerson { car } => Some(*car),
            CameraKind::Static { .. } | CameraKind::Pinhole(_) => None,
        }
    }
}

impl CameraPlan {
    /// A perspective camera's pinhole for a frame in which the followed car
    /// (if any) is at `position` (ground, metres) heading `yaw`, with car
    /// `length`; `previous` is the last frame's pinhole (third-person
    /// cameras move towards their place from there). None for the
    /// straight-down kinds.
    pub fn pinhole_at(&self, followed: Option<(DVec2, f64, f64)>, previous: Option<&Pinhole>) -> Option<Pinhole> {
        let (w, h) = (self.width, self.height);
        let person = |position: [f64; 3], yaw_rad: f64, pitch_deg: f64| Pinhole {
            width: w,
            height: h,
            position,
            yaw_rad,
            pitch_rad: pitch_deg.to_radians(),
            roll_rad: 0.0,
            horizontal_fov_deg: PERSON_FOV_DEG,
        };
        let (position, yaw, length) = followed.unwrap_or((DVec2::ZERO, 0.0, 0.0));
        match &self.kind {
            CameraKind::Pinhole(p) => Some(*p),
            CameraKind::FirstPerson { .. } => {
                let eye = position + DVec2::from_angle(yaw) * (FIRST_PERSON_AHEAD * length);
                Some(person([eye.x, eye.y, FIRST_PERSON_EYE_M], yaw, 0.0))
            }
            CameraKind::ThirdPerson { .. } => {
                let target_yaw = match previous {
                    Some(p) => {
                        let turn = (yaw - p.yaw_rad + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
                            - std::f64::consts::PI;
                        p.yaw_rad + THIRD_PERSON_FOLLOW * turn
                    }
                    None => yaw,
                };
                let behind = position - DVec2::from_angle(target_yaw) * THIRD_PERSON_BEHIND_M;
                let place = DVec3::new(behind.x, behind.y, THIRD_PERSON_UP_M);
                let place = match previous {
                    Some(p) => p.position() + (place - p.position()) * THIRD_PERSON_FOLLOW,
                    None => place,
                };
                Some(person(place.to_array(), target_yaw, THIRD_PERSON_PITCH_DEG))
            }
            CameraKind::Static { .. } | CameraKind::Chase { .. } => None,
        }
    }

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
            (CameraKind::Chase { .. }, None) | (_, _) => {
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
