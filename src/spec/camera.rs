//! `cameras`: the views beside the bird's-eye one.

use super::*;

/// An extra camera: `{"name", "static": {"centre": [x, y], "rotation_deg"}`
/// or `"chase": CAR`, and optional `zoom`, `width`, `height`, `depth`}.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSpec {
    /// Names the folder `cameras/<name>/`.
    pub name: String,
    /// Fixed over a point.
    #[serde(default, rename = "static", skip_serializing_if = "Option::is_none")]
    pub fixed: Option<StaticView>,
    /// Follows a car: its id in a spec, its Id in a scenario file.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub chase: Option<CarRef>,
    /// A fixed pinhole in perspective.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pinhole: Option<PinholeView>,
    /// In perspective, behind and above a car, following it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub third_person: Option<CarRef>,
    /// In perspective, at a car's windscreen.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub first_person: Option<CarRef>,
    /// Times the bird's-eye scale (12.8 px per metre).
    #[serde(default = "default_zoom")]
    pub zoom: f64,
    /// Pixels; 1024 x 640 for static cameras, 256 x 256 for chase cameras.
    #[serde(default)]
    pub width: Option<u32>,
    #[serde(default)]
    pub height: Option<u32>,
    /// Also write 16-bit depth frames.
    #[serde(default)]
    pub depth: bool,
    /// Free text.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub comment: Option<String>,
}

/// Where a static camera looks.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StaticView {
    /// Metres.
    pub centre: [f64; 2],
    /// Counter-clockwise; the image's up direction, 0 = north.
    #[serde(default)]
    pub rotation_deg: f64,
}

/// Where a pinhole camera stands and looks; every field defaults to the
/// original's bird's-eye camera (40 m over the centre, straight down, north
/// up, 90 degrees across).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PinholeView {
    /// Metres: x east, y north, z up.
    #[serde(default = "default_pinhole_position")]
    pub position: [f64; 3],
    /// Degrees counter-clockwise from east (the direction it looks).
    #[serde(default = "default_pinhole_yaw")]
    pub yaw_deg: f64,
    /// Degrees above the horizontal (-90 looks straight down).
    #[serde(default = "default_pinhole_pitch")]
    pub pitch_deg: f64,
    #[serde(default)]
    pub roll_deg: f64,
    /// Horizontal field of view, degrees.
    #[serde(default = "default_pinhole_fov")]
    pub fov_deg: f64,
}

fn default_pinhole_position() -> [f64; 3] {
    [0.0, 0.0, crate::camera::ORIGINAL_ALTITUDE_M]
}
fn default_pinhole_yaw() -> f64 {
    90.0
}
fn default_pinhole_pitch() -> f64 {
    -90.0
}
fn default_pinhole_fov() -> f64 {
    crate::camera::ORIGINAL_FOV_DEG
}

/// A car named by id (specs) or by name (scenario files).
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum CarRef {
    Id(u32),
    Name(String),
}

impl<'de> Deserialize<'de> for CarRef {
    /// An id (0, 1, ...) or a name; anything else is refused saying so
    /// (serde's untagged enums say only "did not match any variant").
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<CarRef, D::Error> {
        struct Visit;
        const EXPECTED: &str = "a car: its id (a whole number from 0) or its name";
        impl serde::de::Visitor<'_> for Visit {
            type Value = CarRef;
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str(EXPECTED)
            }
            fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<CarRef, E> {
                u32::try_from(v).map(CarRef::Id).map_err(|_| E::custom(format!("{v} is not {EXPECTED}")))
            }
            fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<CarRef, E> {
                match u64::try_from(v) {
                    Ok(v) => self.visit_u64(v),
                    Err(_) => Err(E::custom(format!("{v} is not {EXPECTED}"))),
                }
            }
            fn visit_f64<E: serde::de::Error>(self, v: f64) -> Result<CarRef, E> {
                Err(E::custom(format!("{} is not {EXPECTED}", crate::json::Shown(v))))
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<CarRef, E> {
                Ok(CarRef::Name(v.to_string()))
            }
        }
        deserializer.deserialize_any(Visit)
    }
}

fn default_zoom() -> f64 {
    1.0
}

impl CameraSpec {
    /// The checks a camera given as input passes beyond [`CameraSpec::plan`]'s
    /// (a spec recorded by an earlier version may predate them): a zoom on
    /// a perspective camera, which was taken and did nothing.
    pub fn check_input(&self, field: &str) -> Result<(), SpecError> {
        let kind = if self.pinhole.is_some() {
            Some(("pinhole", "; pinhole.fov_deg sets its view"))
        } else if self.third_person.is_some() {
            Some(("third_person", ""))
        } else if self.first_person.is_some() {
            Some(("first_person", ""))
        } else {
            None
        };
        match kind {
            Some((kind_name, instead)) if self.zoom != 1.0 => Err(SpecError::new(
                format!("{field}.zoom"),
                format!(
                    "{} does nothing for a {kind_name} camera (zoom scales the bird's-eye views, static and chase): \
                     leave it out{instead}",
                    Shown(self.zoom)
                ),
            )),
            _ => Ok(()),
        }
    }

    /// Checks the camera (at JSON path `field`); `car_index` resolves a
    /// chased car to its index or says which cars there are.
    pub fn plan(
        &self,
        field: &str,
        car_index: impl Fn(&CarRef) -> Result<usize, String>,
    ) -> Result<CameraPlan, SpecError> {
        if !valid_folder_name(&self.name) {
            return Err(SpecError::new(
                format!("{field}.name"),
                format!(
                    "{:?} is not allowed: 1 to 64 characters from A-Z a-z 0-9 - _ . (it names a folder)",
                    self.name
                ),
            ));
        }
        let given = [
            self.fixed.is_some(),
            self.chase.is_some(),
            self.pinhole.is_some(),
            self.third_person.is_some(),
            self.first_person.is_some(),
        ];
        if given.iter().filter(|&&g| g).count() != 1 {
            return Err(SpecError::new(
                field,
                "give exactly one of \"static\": {\"centre\": [x, y], \"rotation_deg\": r}, \"chase\": CAR, \"pinhole\": {\"position\": [x, y, z], \"yaw_deg\", \"pitch_deg\", \"roll_deg\", \"fov_deg\"}, \"third_person\": CAR or \"first_person\": CAR",
            ));
        }
        let car = |name: &str, car: &CarRef| car_index(car).map_err(|e| SpecError::new(format!("{field}.{name}"), e));
        let kind = if let Some(view) = &self.fixed {
            if !(view.centre.iter().all(|c| c.is_finite()) && view.rotation_deg.is_finite()) {
                return Err(SpecError::new(format!("{field}.static"), "centre and rotation_deg must be numbers"));
            }
            within_reach(&format!("{field}.static.centre"), &view.centre)?;
            CameraKind::Static { centre: view.centre, rotation_deg: view.rotation_deg }
        } else if let Some(c) = &self.chase {
            CameraKind::Chase { car: car("chase", c)? }
        } else if let Some(c) = &self.third_person {
            CameraKind::ThirdPerson { car: car("third_person", c)? }
        } else if let Some(c) = &self.first_person {
            CameraKind::FirstPerson { car: car("first_person", c)? }
        } else {
            let view = self.pinhole.as_ref().expect("exactly one kind was given");
            let here = format!("{field}.pinhole");
            if !(view.position.iter().chain([&view.yaw_deg, &view.pitch_deg, &view.roll_deg]).all(|v| v.is_finite())) {
                return Err(SpecError::new(here, "position, yaw_deg, pitch_deg and roll_deg must be numbers"));
            }
            within_reach(&format!("{here}.position"), &view.position)?;
            if view.position[2] <= 0.0 {
                return Err(SpecError::new(
                    format!("{here}.position[2]"),
                    format!(
                        "{} is not allowed: the camera's height in metres must be above the ground (z > 0); below it the camera sees through the road",
                        Shown(view.position[2])
                    ),
                ));
            }
            if !(1.0..=170.0).contains(&view.fov_deg) {
                return Err(SpecError::new(
                    format!("{here}.fov_deg"),
                    format!("{} is not allowed: a horizontal field of view from 1 to 170 degrees", Shown(view.fov_deg)),
                ));
            }
            CameraKind::Pinhole(Pinhole {
                width: 0,
                height: 0,
                position: view.position,
                yaw_rad: view.yaw_deg.to_radians(),
                pitch_rad: view.pitch_deg.to_radians(),
                roll_rad: view.roll_deg.to_radians(),
                horizontal_fov_deg: view.fov_deg,
            })
        };
        positive(&format!("{field}.zoom"), self.zoom, 20.0, "times the bird's-eye scale")?;
        let (w, h) = match kind {
            CameraKind::Chase { .. } => (256, 256),
            _ => (1024, 640),
        };
        let (width, height) = (self.width.unwrap_or(w), self.height.unwrap_or(h));
        range(&format!("{field}.width"), width, MIN_IMAGE_SIDE, MAX_IMAGE_SIDE)?;
        range(&format!("{field}.height"), height, MIN_IMAGE_SIDE, MAX_IMAGE_SIDE)?;
        let kind = match kind {
            CameraKind::Pinhole(p) => CameraKind::Pinhole(Pinhole { width, height, ..p }),
            other => other,
        };
        Ok(CameraPlan { name: self.name.clone(), width, height, zoom: self.zoom, depth: self.depth, kind })
    }
}

/// A camera's position (`centre` [x, y] or `position` [x, y, z], metres)
/// within [`MAX_CAMERA_COORDINATE`] on every axis, as `map.camera_area`
/// is: far beyond any map a camera sees nothing, and its pixel
/// coordinates of the cars overflow.
fn within_reach(field: &str, position: &[f64]) -> Result<(), SpecError> {
    match position.iter().position(|v| v.abs() > MAX_CAMERA_COORDINATE) {
        Some(k) => Err(SpecError::new(
            format!("{field}[{k}]"),
            format!(
                "{} is not allowed: metres within +-{MAX_CAMERA_COORDINATE} (the coordinates map.camera_area may give)",
                Shown(position[k])
            ),
        )),
        None => Ok(()),
    }
}
