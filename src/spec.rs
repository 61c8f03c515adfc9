//! The dataset spec: what a user asks for, read from JSON. Every field is
//! checked here with a message that names it, the value and what is allowed.

use crate::camera::{Camera, CameraKind, CameraPlan, Pinhole};
use crate::json::Shown;
use crate::map::signals::{ScheduleStep, Signal};
use crate::map::MapLayout;
use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::Path;

/// Which dynamics drive the cars.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum WorldKind {
    /// No agency: constant speed along the route, no lights, no collisions.
    Toy,
    /// Agency: car-following, lights, merges, collisions, confounders.
    City,
}

impl WorldKind {
    pub fn name(self) -> &'static str {
        match self {
            WorldKind::Toy => "toy",
            WorldKind::City => "city",
        }
    }
}

/// How the dataset's own bird's-eye frames are drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BirdsEyeView {
    /// A flat drawing seen straight down: every car the same shape wherever
    /// it is (the default; what the paper's pixel figures describe).
    #[default]
    Flat,
    /// The same camera as a true pinhole, in perspective: walls lean
    /// outwards and a car's roof sits off its footprint towards the edge,
    /// as the original's 40 m, 90 degree camera recorded. Ground points
    /// land on the same pixels, so the pose logs are the same.
    Pinhole,
}

impl BirdsEyeView {
    pub fn is_flat(&self) -> bool {
        *self == BirdsEyeView::Flat
    }
}

/// Image size of the bird's-eye camera, pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImageSize {
    pub width: u32,
    pub height: u32,
}

impl Default for ImageSize {
    fn default() -> Self {
        ImageSize { width: 1024, height: 640 }
    }
}

/// One experimental group: cars per scenario and the share of them in
/// leader-follower pairs.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GroupSpec {
    pub cars: u32,
    pub edge_proportion: f64,
}

impl GroupSpec {
    /// Leader-follower pairs per scenario: `round(proportion * cars / 2)`
    /// (halves round up), and at least 1 when the proportion is above 0.
    pub fn edges(&self) -> u32 {
        let edges = (self.edge_proportion * self.cars as f64 / 2.0).round() as u32;
        if self.edge_proportion > 0.0 {
            edges.max(1)
        } else {
            edges
        }
    }

    /// Folder name, e.g. `cars08_edges50` (edges = the proportion in percent).
    pub fn name(&self) -> String {
        format!("cars{:02}_edges{:02}", self.cars, (self.edge_proportion * 100.0).round() as u32)
    }
}

/// Scenarios per split, per group.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Splits {
    pub train: u32,
    pub val: u32,
    pub test: u32,
}

/// A dataset split.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Split {
    Train,
    Val,
    Test,
}

impl Split {
    pub const ALL: [Split; 3] = [Split::Train, Split::Val, Split::Test];

    pub fn name(self) -> &'static str {
        match self {
            Split::Train => "train",
            Split::Val => "val",
            Split::Test => "test",
        }
    }

    /// Its place in [`Split::ALL`]: train 0, val 1, test 2.
    pub fn index(self) -> usize {
        match self {
            Split::Train => 0,
            Split::Val => 1,
            Split::Test => 2,
        }
    }
}

impl Splits {
    pub fn count(&self, split: Split) -> u32 {
        match split {
            Split::Train => self.train,
            Split::Val => self.val,
            Split::Test => self.test,
        }
    }
}

/// A whole dataset request (`configs/*.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DatasetSpec {
    /// Dataset name; also the default output folder `data/<name>`.
    pub name: String,
    pub world: WorldKind,
    pub seed: u64,
    /// Frames per scenario.
    #[serde(default = "default_frames")]
    pub frames: u32,
    /// Seconds between frames: 0.1 for the toy world, 0.2 for the city when absent.
    #[serde(default)]
    pub frame_interval: Option<f64>,
    #[serde(default)]
    pub image: ImageSize,
    /// How the bird's-eye frames are drawn: `flat` (default) or `pinhole`.
    #[serde(default, skip_serializing_if = "BirdsEyeView::is_flat")]
    pub birds_eye: BirdsEyeView,
    pub groups: Vec<GroupSpec>,
    pub splits: Splits,
    /// High-level actions in each car's drive queue.
    #[serde(default = "default_actions")]
    pub actions_per_car: u32,
    /// Toy world: distance every car covers per frame, in pixels of `image`.
    #[serde(default = "default_toy_speed")]
    pub toy_speed_px_per_frame: f64,
    /// Toy world only (the paper's rule): distance along the shared path
    /// from follower to leader at the start, pixels; 30 when absent. The
    /// city draws its gaps from `city.start.follower_gap_m`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub leader_gap_px: Option<f64>,
    /// Car footprint, metres.
    #[serde(default = "default_car_length")]
    pub car_length_m: f64,
    #[serde(default = "default_car_width")]
    pub car_width_m: f64,
    /// City world only: agency, lights and confounders.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub city: Option<CitySpec>,
    /// Extra cameras beside the bird's-eye view (need images).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub cameras: Vec<CameraSpec>,
    /// The city map's dimensions and the bird's-eye camera's height.
    #[serde(default)]
    pub map: MapSpec,
}

/// The city map's dimensions, metres (every field optional; the defaults
/// are the default layout, [`MapLayout::default`]), and the height of the
/// bird's-eye camera.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MapSpec {
    /// Width of every lane; a road is four lanes wide.
    pub lane_width: f64,
    /// y of the centre lines of the east-west roads B and A, ascending.
    pub east_west_roads: [f64; 2],
    /// x of the centre lines of the north-south roads C and D, ascending.
    pub north_south_roads: [f64; 2],
    /// East-west roads run from -extent_x to +extent_x, then loop back.
    pub extent_x: f64,
    /// North-south roads run from -extent_y to +extent_y, then loop back.
    pub extent_y: f64,
    /// Distance along the lane a lane change takes, metres.
    pub lane_change_m: f64,
    /// Height of the bird's-eye camera. Absent: the original's 40 m, or
    /// higher when the intersections and their stop lines do not fit the
    /// view from there.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub camera_altitude_m: Option<f64>,
}

impl Default for MapSpec {
    fn default() -> Self {
        let l = MapLayout::default();
        MapSpec {
            lane_width: l.lane_width,
            east_west_roads: [l.east_west_roads[0].1, l.east_west_roads[1].1],
            north_south_roads: [l.north_south_roads[0].1, l.north_south_roads[1].1],
            extent_x: l.extent_x,
            extent_y: l.extent_y,
            lane_change_m: l.lane_change_length,
            camera_altitude_m: None,
        }
    }
}

/// Largest map coordinate a spec may give, metres.
const MAX_MAP_EXTENT: f64 = 5000.0;

impl MapSpec {
    /// The layout the map is built from.
    pub fn layout(&self) -> MapLayout {
        let d = MapLayout::default();
        MapLayout {
            lane_width: self.lane_width,
            east_west_roads: [
                (d.east_west_roads[0].0, self.east_west_roads[0]),
                (d.east_west_roads[1].0, self.east_west_roads[1]),
            ],
            north_south_roads: [
                (d.north_south_roads[0].0, self.north_south_roads[0]),
                (d.north_south_roads[1].0, self.north_south_roads[1]),
            ],
            extent_x: self.extent_x,
            extent_y: self.extent_y,
            lane_change_length: self.lane_change_m,
            sidewalk_width: d.sidewalk_width,
            ..d
        }
    }

    /// Checks sizes, and that every lane ending at an intersection is at
    /// least [`MapLayout::min_approach_length`] long.
    pub fn validate(&self) -> Result<(), SpecError> {
        positive("map.lane_width", self.lane_width, 10.0, "metres")?;
        positive("map.lane_change_m", self.lane_change_m, 200.0, "metres")?;
        let layout = self.layout();
        let hw = layout.road_half_width();
        let need = layout.min_approach_length();
        let axes = [
            ("map.north_south_roads", self.north_south_roads, "map.extent_x", self.extent_x, "C", "D", "east-west"),
            ("map.east_west_roads", self.east_west_roads, "map.extent_y", self.extent_y, "B", "A", "north-south"),
        ];
        for (field, roads, extent_field, extent, first, second, crossing) in axes {
            if !roads.iter().all(|r| r.is_finite() && r.abs() <= MAX_MAP_EXTENT) {
                return Err(SpecError::new(
                    field,
                    format!(
                        "{roads:?} is not allowed: give two finite centre-line positions within +-{MAX_MAP_EXTENT} m"
                    ),
                ));
            }
            positive(extent_field, extent, MAX_MAP_EXTENT, "metres")?;
            let segments = [
                (format!("from -{extent_field} to road {first}"), roads[0] - hw + extent),
                (format!("between roads {first} and {second}"), roads[1] - roads[0] - 2.0 * hw),
                (format!("from road {second} to +{extent_field}"), extent - roads[1] - hw),
            ];
            for (what, length) in segments {
                if length < need - 1e-9 {
                    return Err(SpecError::new(
                        if what.contains("between") { field } else { extent_field },
                        format!(
                            "roads {first} and {second} at {roads:?} m with {extent_field} {extent} m leave {length:.2} m of the {crossing} roads {what}: every lane that ends at an intersection must be at least {need:.1} m long (lane change {} m + stop-line setback {} m + {} m) and roads are 4 lanes of {} m",
                            layout.lane_change_length,
                            layout.stop_line_setback,
                            crate::map::APPROACH_MARGIN_M,
                            self.lane_width
                        ),
                    ));
                }
            }
        }
        if let Some(altitude) = self.camera_altitude_m {
            positive("map.camera_altitude_m", altitude, 10_000.0, "metres")?;
        }
        Ok(())
    }
}

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

/// 1 to 64 characters from A-Z a-z 0-9 - _ . not starting with a dot.
pub fn valid_folder_name(name: &str) -> bool {
    !name.is_empty()
        && name.len() <= 64
        && !name.starts_with('.')
        && name.chars().all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
}

/// One driver's car-following parameters (the city world's drivers), as
/// the spec gives them and, in plans, after confounders have acted on them.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DriverParams {
    /// Desired time gap to the car ahead, seconds.
    pub time_headway: f64,
    /// Bumper-to-bumper gap kept when stopped, metres.
    pub min_gap: f64,
    /// Maximum acceleration, m/s^2.
    pub max_acceleration: f64,
    /// Comfortable deceleration, m/s^2 (IDM's b; used to decide whether a yellow can be stopped for).
    pub comfortable_deceleration: f64,
    /// Hard braking limit, m/s^2: the car can never brake harder.
    pub max_deceleration: f64,
    /// Seconds between decisions; the acceleration is held in between.
    pub reaction_time: f64,
    /// Relative standard deviation of perceived gaps.
    pub perception_noise: f64,
    /// Standard deviation of the car's sideways wander in its lane, metres.
    pub lateral_wander: f64,
    /// Lateral acceleration accepted in curves, m/s^2 (sets curve speeds).
    pub curve_acceleration: f64,
}

impl Default for DriverParams {
    fn default() -> Self {
        DriverParams {
            time_headway: 1.0,
            min_gap: 0.8,
            max_acceleration: 1.2,
            comfortable_deceleration: 1.5,
            max_deceleration: 6.0,
            reaction_time: 0.3,
            perception_noise: 0.04,
            lateral_wander: 0.03,
            curve_acceleration: 1.2,
        }
    }
}

/// A value fixed by the spec or drawn per scenario: a number,
/// `{"uniform": [low, high]}` or `{"choice": [a, b, ...]}` (nothing else in
/// the object).
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum Distribution {
    Fixed(f64),
    /// `{"uniform": [low, high]}`
    Uniform {
        uniform: [f64; 2],
    },
    /// `{"choice": [a, b, ...]}`, each equally likely.
    Choice {
        choice: Vec<f64>,
    },
}

/// The object form of a [`Distribution`], as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawDistribution {
    uniform: Option<[f64; 2]>,
    choice: Option<Vec<f64>>,
}

impl<'de> Deserialize<'de> for Distribution {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct Visit;
        impl<'de> serde::de::Visitor<'de> for Visit {
            type Value = Distribution;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a number, {\"uniform\": [low, high]} or {\"choice\": [a, b, ...]}")
            }
            fn visit_f64<E>(self, v: f64) -> Result<Distribution, E> {
                Ok(Distribution::Fixed(v))
            }
            fn visit_u64<E>(self, v: u64) -> Result<Distribution, E> {
                Ok(Distribution::Fixed(v as f64))
            }
            fn visit_i64<E>(self, v: i64) -> Result<Distribution, E> {
                Ok(Distribution::Fixed(v as f64))
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(self, map: A) -> Result<Distribution, A::Error> {
                let raw = RawDistribution::deserialize(serde::de::value::MapAccessDeserializer::new(map))?;
                match (raw.uniform, raw.choice) {
                    (Some(uniform), None) => Ok(Distribution::Uniform { uniform }),
                    (None, Some(choice)) => Ok(Distribution::Choice { choice }),
                    _ => Err(serde::de::Error::custom(
                        "give exactly one of {\"uniform\": [low, high]} or {\"choice\": [a, b, ...]}",
                    )),
                }
            }
        }
        deserializer.deserialize_any(Visit)
    }
}

impl Distribution {
    fn check(&self, field: &str, lo: f64, hi: f64) -> Result<(), SpecError> {
        let values: Vec<f64> = match self {
            Distribution::Fixed(v) => vec![*v],
            Distribution::Uniform { uniform } => {
                if uniform[0] > uniform[1] {
                    return Err(SpecError::new(field, format!("uniform range {uniform:?} has low above high")));
                }
                uniform.to_vec()
            }
            Distribution::Choice { choice } => {
                if choice.is_empty() {
                    return Err(SpecError::new(field, "choice list is empty"));
                }
                choice.clone()
            }
        };
        for v in values {
            if !(v.is_finite() && v >= lo && v <= hi) {
                return Err(SpecError::new(field, format!("{} is not allowed: use {lo} to {hi}", Shown(v))));
            }
        }
        Ok(())
    }

    /// The lowest value it can draw.
    pub fn lowest(&self) -> f64 {
        match self {
            Distribution::Fixed(v) => *v,
            Distribution::Uniform { uniform } => uniform[0],
            Distribution::Choice { choice } => choice.iter().copied().fold(f64::INFINITY, f64::min),
        }
    }

    /// The value at `u` in [0, 1) of its inverse cumulative distribution:
    /// the draw a uniform exogenous `u` stands for.
    pub fn quantile(&self, u: f64) -> f64 {
        match self {
            Distribution::Fixed(v) => *v,
            Distribution::Uniform { uniform } => uniform[0] + u * (uniform[1] - uniform[0]),
            Distribution::Choice { choice } => {
                choice[((u * choice.len() as f64) as usize).min(choice.len().saturating_sub(1))]
            }
        }
    }

    /// Draws a value.
    pub fn sample<R: rand::Rng + ?Sized>(&self, rng: &mut R) -> f64 {
        use rand::RngExt;
        match self {
            Distribution::Fixed(v) => *v,
            Distribution::Uniform { uniform } => {
                if uniform[0] == uniform[1] {
                    uniform[0]
                } else {
                    rng.random_range(uniform[0]..uniform[1])
                }
            }
            Distribution::Choice { choice } => choice[rng.random_range(0..choice.len())],
        }
    }
}

/// Confounders per scenario (the causal model is in `plan/confounders.rs`).
/// Rain, snow and the hour are exogenous: the spec gives their
/// distribution. Fog and wetness follow their structural equations unless
/// the spec gives them, which replaces the equation by the given value or
/// distribution (a do-intervention on that variable).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ConfounderSpec {
    /// Rain intensity 0..1.
    pub rain: Distribution,
    /// Fog density 0..1; absent: its equation (fog in the early hours).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fog: Option<Distribution>,
    /// Snowfall 0..1.
    pub snow: Distribution,
    /// Water on the road 0..1; absent: its equation (from rain and snow).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub wetness: Option<Distribution>,
    /// Time of day, hours 0..24.
    pub hour: Distribution,
}

impl Default for ConfounderSpec {
    fn default() -> Self {
        ConfounderSpec {
            rain: Distribution::Fixed(0.0),
            fog: None,
            snow: Distribution::Fixed(0.0),
            wetness: None,
            hour: Distribution::Fixed(12.0),
        }
    }
}

/// Replaces the schedule of one light.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightOverride {
    /// Intersection name, e.g. `AC`.
    pub intersection: String,
    /// Side the controlled traffic arrives from: `N`, `E`, `S`, `W`.
    pub approach: char,
    pub signal: Signal,
    /// Seconds added to the scenario clock.
    #[serde(default)]
    pub offset: f64,
    /// Repeating (colour, seconds) steps.
    pub schedule: Vec<ScheduleStep>,
}

/// Traffic light control: the original cycle scaled, offsets per
/// intersection (high level) and single-light schedules (low level).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LightsSpec {
    /// Multiplies every duration of the original 60 s cycle.
    pub cycle_scale: f64,
    /// Seconds added to the clock of each intersection, in the order AC, AD, BC, BD.
    pub offsets: Vec<f64>,
    pub overrides: Vec<LightOverride>,
    /// Where in its cycle each scenario starts. Absent: `random` in a
    /// dataset spec, `fixed` in a scenario file (one scenario written out
    /// by hand, timed by its author).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub phase: Option<LightPhase>,
}

/// Where each scenario's lights start in their cycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LightPhase {
    /// Each scenario draws one point of the cycle (uniform over one period),
    /// shared by every light, on top of `offsets`: the intersections keep
    /// their relative timing.
    Random,
    /// Each scenario draws a point of the cycle per intersection, on top of
    /// `offsets`.
    RandomPerIntersection,
    /// Every scenario starts the cycle at 0, shifted by `offsets` only.
    Fixed,
}

impl Default for LightsSpec {
    fn default() -> Self {
        LightsSpec { cycle_scale: 0.5, offsets: vec![0.0; 4], overrides: Vec::new(), phase: None }
    }
}

/// The car-following model city drivers use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DriverModel {
    /// The Intelligent Driver Model (Treiber, Hennecke and Helbing 2000).
    Idm,
    /// The Improved IDM (Treiber and Kesting 2013): the IDM without its
    /// widened gaps near the desired speed.
    Iidm,
}

/// How `gen` draws a city car's actions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ActionDrawing {
    /// As the original's `scenarioGenerator.py`: left, right or straight at
    /// random whatever lane the car will be in; the drivers change lanes
    /// for their turns, and a turn that cannot be prepared is skipped.
    Original,
    /// Only actions the lane the car is in allows, with merges where they
    /// fit (no lane changes needed).
    LaneValid,
}

/// City-world settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CitySpec {
    /// Mean desired speed, m/s.
    pub desired_speed: f64,
    /// Each leg's desired speed is `desired_speed x (1 +- spread)`, uniform.
    pub desired_speed_spread: f64,
    /// Chance that a car is forced through red lights.
    pub red_light_runner_probability: f64,
    /// How `gen` draws each car's drive queue.
    pub action_drawing: ActionDrawing,
    /// The drivers' car-following model.
    pub driver_model: DriverModel,
    /// Base driver parameters, before confounders.
    pub driver: DriverParams,
    /// How `gen` starts cars: gaps, speeds, hard negatives.
    pub start: StartSpec,
    pub lights: LightsSpec,
    pub confounders: ConfounderSpec,
    /// Whether frames show the signal heads (the lights, a confounder of
    /// every car) or hide them.
    pub signal_heads: SignalHeads,
}

/// Whether the frames show the traffic lights' signal heads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SignalHeads {
    /// Drawn at every approach in their current colour: a measured confounder.
    #[default]
    Visible,
    /// Not drawn: the lights act on the cars but no frame shows them (a
    /// hidden confounder).
    Hidden,
}

/// How `gen` starts the city's cars (hand-written scenario files start
/// every car at rest where the file puts it, as the original did).
///
/// A follower starts behind its leader on the leader's route, `follower_gap_m`
/// from bumper to bumper. A *hard negative* is a car with no leader (an
/// independent car, or the leader of a pair) that starts in the same way
/// right behind another car, with a first action different from that car's:
/// in the first frame it looks like a follower, and the two part ways at the
/// next intersection. Every car then starts at `speed_fraction` of its first
/// desired speed, or slower where what it sees ahead at the start (a car, a
/// stop line it must stop at, a curve) asks for less, by the same rule for
/// every car whatever its role.
///
/// With `platoon_cars`, the first frame is drawn blind to roles instead:
/// every car starts in a platoon of that many cars on the two lanes of one
/// direction of one road segment, each car in one of the two lanes drawn at
/// random and queued `follower_gap_m` behind the car ahead in its lane; the
/// leader-follower pairs are then drawn uniformly among the ordered (ahead,
/// behind) pairs of each platoon. Where a pair stands says nothing about
/// whether it is an edge: every pair of a platoon is one with the same
/// chance.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StartSpec {
    /// Bumper-to-bumper gap behind the car ahead, metres, for followers and
    /// hard negatives; never below `city.driver.min_gap`.
    pub follower_gap_m: Distribution,
    /// Share of cars without a leader that start as hard negatives, 0..1
    /// (without platoons only).
    pub hard_negative_share: f64,
    /// Cars per platoon, 2..=16, the last platoon of a scenario taking the
    /// rest; 0 (the default) for none.
    #[serde(skip_serializing_if = "is_zero_u32")]
    pub platoon_cars: u32,
    /// Starting speed as a share of the car's first desired speed, 0..1,
    /// before what it sees ahead limits it.
    pub speed_fraction: Distribution,
}

/// Most cars one platoon may hold: two lanes of the longest on-camera
/// segment hold about this many queued cars.
const MAX_PLATOON_CARS: u32 = 16;

fn is_zero_u32(n: &u32) -> bool {
    *n == 0
}

impl Default for StartSpec {
    fn default() -> Self {
        StartSpec {
            follower_gap_m: Distribution::Uniform { uniform: [1.0, 6.0] },
            hard_negative_share: 0.0,
            platoon_cars: 0,
            speed_fraction: Distribution::Uniform { uniform: [0.5, 1.0] },
        }
    }
}

impl Default for CitySpec {
    fn default() -> Self {
        CitySpec {
            desired_speed: 1.8,
            desired_speed_spread: 0.25,
            red_light_runner_probability: 0.02,
            action_drawing: ActionDrawing::Original,
            driver_model: DriverModel::Iidm,
            driver: DriverParams::default(),
            start: StartSpec::default(),
            lights: LightsSpec::default(),
            confounders: ConfounderSpec::default(),
            signal_heads: SignalHeads::Visible,
        }
    }
}

impl CitySpec {
    pub fn validate(&self) -> Result<(), SpecError> {
        positive("city.desired_speed", self.desired_speed, 20.0, "m/s")?;
        unit_interval("city.desired_speed_spread", self.desired_speed_spread, 0.9)?;
        unit_interval("city.red_light_runner_probability", self.red_light_runner_probability, 1.0)?;
        let d = &self.driver;
        positive("city.driver.time_headway", d.time_headway, 10.0, "seconds")?;
        positive("city.driver.min_gap", d.min_gap, 20.0, "metres")?;
        positive("city.driver.max_acceleration", d.max_acceleration, 10.0, "m/s^2")?;
        positive("city.driver.comfortable_deceleration", d.comfortable_deceleration, 10.0, "m/s^2")?;
        positive("city.driver.max_deceleration", d.max_deceleration, 15.0, "m/s^2")?;
        if d.max_deceleration < d.comfortable_deceleration {
            return Err(SpecError::new(
                "city.driver.max_deceleration",
                format!(
                    "{} is below comfortable_deceleration {}: the hard limit must be the larger",
                    Shown(d.max_deceleration),
                    Shown(d.comfortable_deceleration)
                ),
            ));
        }
        positive("city.driver.reaction_time", d.reaction_time, 3.0, "seconds")?;
        unit_interval("city.driver.perception_noise", d.perception_noise, 1.0)?;
        unit_interval("city.driver.lateral_wander", d.lateral_wander, 0.5)?;
        positive("city.driver.curve_acceleration", d.curve_acceleration, 10.0, "m/s^2")?;
        let start = &self.start;
        if let Err(e) = start.follower_gap_m.check("city.start.follower_gap_m", d.min_gap, 200.0) {
            return Err(SpecError::new(
                e.field,
                format!(
                    "{} (bumper-to-bumper metres: a driver accepts no gap below city.driver.min_gap = {})",
                    e.message, d.min_gap
                ),
            ));
        }
        unit_interval("city.start.hard_negative_share", start.hard_negative_share, 1.0)?;
        if start.platoon_cars != 0 && !(2..=MAX_PLATOON_CARS).contains(&start.platoon_cars) {
            return Err(SpecError::new(
                "city.start.platoon_cars",
                format!(
                    "{} is not allowed: give 2 to {MAX_PLATOON_CARS} cars per platoon, or 0 for none",
                    start.platoon_cars
                ),
            ));
        }
        if start.platoon_cars != 0 && start.hard_negative_share != 0.0 {
            return Err(SpecError::new(
                "city.start.hard_negative_share",
                format!(
                    "{} is not allowed with city.start.platoon_cars = {}: in a platoon every car already starts behind another, so remove hard_negative_share (or set it to 0)",
                    start.hard_negative_share, start.platoon_cars
                ),
            ));
        }
        start.speed_fraction.check("city.start.speed_fraction", 0.0, 1.0)?;
        positive("city.lights.cycle_scale", self.lights.cycle_scale, 10.0, "factor")?;
        if self.lights.offsets.len() != 4 || self.lights.offsets.iter().any(|o| !o.is_finite()) {
            return Err(SpecError::new(
                "city.lights.offsets",
                format!(
                    "{:?} is not allowed: give 4 finite offsets in seconds, for AC, AD, BC, BD",
                    self.lights.offsets
                ),
            ));
        }
        for (i, o) in self.lights.overrides.iter().enumerate() {
            let field = format!("city.lights.overrides[{i}]");
            if !["AC", "AD", "BC", "BD"].contains(&o.intersection.as_str()) {
                return Err(SpecError::new(
                    format!("{field}.intersection"),
                    format!("{:?} is not an intersection: use AC, AD, BC or BD", o.intersection),
                ));
            }
            if !['N', 'E', 'S', 'W'].contains(&o.approach) {
                return Err(SpecError::new(
                    format!("{field}.approach"),
                    format!("{:?} is not allowed: use N, E, S or W", o.approach),
                ));
            }
            if o.schedule.is_empty() || o.schedule.iter().any(|st| !(st.duration.is_finite() && st.duration > 0.0)) {
                return Err(SpecError::new(
                    format!("{field}.schedule"),
                    "give at least one {\"colour\": \"green\"|\"yellow\"|\"red\", \"duration\": seconds above 0}",
                ));
            }
            if !o.offset.is_finite() {
                return Err(SpecError::new(format!("{field}.offset"), "must be a finite number of seconds"));
            }
        }
        let c = &self.confounders;
        c.rain.check("city.confounders.rain", 0.0, 1.0)?;
        if let Some(fog) = &c.fog {
            fog.check("city.confounders.fog", 0.0, 1.0)?;
        }
        c.snow.check("city.confounders.snow", 0.0, 1.0)?;
        if let Some(wetness) = &c.wetness {
            wetness.check("city.confounders.wetness", 0.0, 1.0)?;
        }
        c.hour.check("city.confounders.hour", 0.0, 24.0)?;
        Ok(())
    }
}

fn unit_interval(field: &str, value: f64, hi: f64) -> Result<(), SpecError> {
    if !(value.is_finite() && (0.0..=hi).contains(&value)) {
        return Err(SpecError::new(field, format!("{} is not allowed: use 0 to {hi}", Shown(value))));
    }
    Ok(())
}

fn default_frames() -> u32 {
    150
}
fn default_actions() -> u32 {
    5
}
fn default_toy_speed() -> f64 {
    2.0
}
/// The paper's toy-world start gap from follower to leader, pixels.
pub const DEFAULT_LEADER_GAP_PX: f64 = 30.0;
fn default_car_length() -> f64 {
    2.2
}
fn default_car_width() -> f64 {
    1.1
}

/// A spec problem: which field, and what is wrong with it.
#[derive(Debug, Clone, PartialEq)]
pub struct SpecError {
    /// Dotted path of the field, e.g. `groups[1].cars`; empty for the whole file.
    pub field: String,
    pub message: String,
}

impl SpecError {
    pub fn new(field: impl Into<String>, message: impl Into<String>) -> SpecError {
        SpecError { field: field.into(), message: message.into() }
    }
}

impl fmt::Display for SpecError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.field.is_empty() {
            f.write_str(&self.message)
        } else {
            write!(f, "field `{}`: {}", self.field, self.message)
        }
    }
}

impl std::error::Error for SpecError {}

/// Largest mask id: masks are 8-bit with 0 for background.
pub const MAX_CARS: u32 = 255;
const MAX_IMAGE_SIDE: u32 = 8192;
const MIN_IMAGE_SIDE: u32 = 32;
const MAX_FRAMES: u32 = 100_000;
const MAX_SCENARIOS_PER_SPLIT: u32 = 10_000_000;
const MAX_ACTIONS: u32 = 100;

impl DatasetSpec {
    /// Parses and checks a spec from JSON text (strictly: no duplicate
    /// keys, no trailing data, objects where the spec has objects).
    pub fn from_json(text: &str) -> Result<DatasetSpec, SpecError> {
        let spec: DatasetSpec = crate::json::parse_strict(text).map_err(|e| SpecError::new(e.path, e.message))?;
        spec.validate()?;
        Ok(spec.resolved())
    }

    /// Frames per scenario when a file gives none.
    pub fn default_frames() -> u32 {
        default_frames()
    }

    /// A one-scenario spec for cars given by hand (scenario files): every
    /// setting not named here takes the spec's default.
    pub fn for_given_cars(
        name: String,
        world: WorldKind,
        seed: u64,
        frames: u32,
        frame_interval: Option<f64>,
        city: Option<CitySpec>,
    ) -> DatasetSpec {
        DatasetSpec {
            name,
            world,
            seed,
            frames,
            frame_interval,
            image: ImageSize::default(),
            birds_eye: BirdsEyeView::Flat,
            groups: Vec::new(),
            splits: Splits { train: 1, val: 0, test: 0 },
            actions_per_car: 0,
            toy_speed_px_per_frame: default_toy_speed(),
            leader_gap_px: None,
            car_length_m: default_car_length(),
            car_width_m: default_car_width(),
            // A hand-written scenario is timed by its author: lights start at 0 unless it says otherwise.
            city: city.map(|mut c| {
                c.lights.phase.get_or_insert(LightPhase::Fixed);
                c
            }),
            cameras: Vec::new(),
            map: MapSpec::default(),
        }
    }

    /// Reads, parses and checks a spec file.
    pub fn from_file(path: &Path) -> Result<DatasetSpec, SpecError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| SpecError::new("", format!("cannot read spec file {}: {e}", path.display())))?;
        DatasetSpec::from_json(&text)
    }

    /// Checks every field's range and the groups' consistency.
    pub fn validate(&self) -> Result<(), SpecError> {
        if !valid_folder_name(&self.name) {
            return Err(SpecError::new(
                "name",
                format!(
                    "{:?} is not allowed: use 1 to 64 characters from A-Z a-z 0-9 - _ . (not starting with a dot); it names the output folder",
                    self.name
                ),
            ));
        }
        range("frames", self.frames, 1, MAX_FRAMES)?;
        let interval = self.frame_interval();
        if !(interval.is_finite() && interval > 0.0 && interval <= 10.0) {
            return Err(SpecError::new(
                "frame_interval",
                format!("{} is not allowed: seconds between frames, above 0 and at most 10", Shown(interval)),
            ));
        }
        range("image.width", self.image.width, MIN_IMAGE_SIDE, MAX_IMAGE_SIDE)?;
        range("image.height", self.image.height, MIN_IMAGE_SIDE, MAX_IMAGE_SIDE)?;
        if self.groups.is_empty() {
            return Err(SpecError::new(
                "groups",
                "the list is empty: give at least one {\"cars\": N, \"edge_proportion\": P}",
            ));
        }
        let mut names = std::collections::HashSet::new();
        for (i, g) in self.groups.iter().enumerate() {
            range(&format!("groups[{i}].cars"), g.cars, 1, MAX_CARS)?;
            let field = format!("groups[{i}].edge_proportion");
            if !(g.edge_proportion.is_finite() && (0.0..=1.0).contains(&g.edge_proportion)) {
                return Err(SpecError::new(
                    field,
                    format!(
                        "{} is not allowed: the share of cars in leader-follower pairs, from 0 to 1",
                        Shown(g.edge_proportion)
                    ),
                ));
            }
            if 2 * g.edges() > g.cars {
                return Err(SpecError::new(
                    field,
                    format!(
                        "{} with {} cars asks for {} leader-follower pairs (round(proportion x cars / 2)), which need {} cars: lower the proportion or add cars",
                        g.edge_proportion,
                        g.cars,
                        g.edges(),
                        2 * g.edges()
                    ),
                ));
            }
            if !names.insert(g.name()) {
                return Err(SpecError::new(
                    format!("groups[{i}]"),
                    format!("duplicates group {}: every (cars, edge_proportion) pair may appear once", g.name()),
                ));
            }
        }
        for split in Split::ALL {
            range(&format!("splits.{}", split.name()), self.splits.count(split), 0, MAX_SCENARIOS_PER_SPLIT)?;
        }
        if Split::ALL.iter().all(|s| self.splits.count(*s) == 0) {
            return Err(SpecError::new("splits", "all splits are 0: ask for at least one scenario"));
        }
        range("actions_per_car", self.actions_per_car, 0, MAX_ACTIONS)?;
        positive("toy_speed_px_per_frame", self.toy_speed_px_per_frame, 100.0, "pixels per frame")?;
        positive("car_length_m", self.car_length_m, 20.0, "metres")?;
        positive("car_width_m", self.car_width_m, 3.0, "metres")?;
        match (self.leader_gap_px, self.world) {
            (Some(gap), WorldKind::Toy) => positive("leader_gap_px", gap, 2000.0, "pixels")?,
            (Some(gap), WorldKind::City) => {
                return Err(SpecError::new(
                    "leader_gap_px",
                    format!(
                        "{gap} applies to \"world\": \"toy\" only (the paper's exact start gap); the city draws each follower's gap from city.start.follower_gap_m (metres): remove it"
                    ),
                ))
            }
            (None, _) => {}
        }
        match (&self.city, self.world) {
            (Some(city), WorldKind::City) => city.validate()?,
            (Some(_), WorldKind::Toy) => {
                return Err(SpecError::new("city", "applies to \"world\": \"city\" only: remove it or change world"))
            }
            (None, _) => {}
        }
        self.map.validate()?;
        self.birds_eye_camera()?;
        let fewest_cars = self.groups.iter().map(|g| g.cars).min().unwrap_or(0);
        let mut names = std::collections::HashSet::new();
        for (i, camera) in self.cameras.iter().enumerate() {
            let field = format!("cameras[{i}]");
            camera.plan(&field, |car| match car {
                CarRef::Id(id) if *id < fewest_cars => Ok(*id as usize),
                CarRef::Id(id) => Err(format!(
                    "car {id} is not in every scenario: ids run from 0 to {} in the smallest group",
                    fewest_cars.saturating_sub(1)
                )),
                CarRef::Name(name) => Err(format!("{name:?}: in a spec, name the car by its id (0, 1, ...)")),
            })?;
            if !names.insert(camera.name.as_str()) {
                return Err(SpecError::new(
                    format!("{field}.name"),
                    format!("{:?} names another camera too", camera.name),
                ));
            }
        }
        Ok(())
    }

    /// Seconds between frames, with the world's default filled in.
    pub fn frame_interval(&self) -> f64 {
        self.frame_interval.unwrap_or(match self.world {
            WorldKind::Toy => 0.1,
            WorldKind::City => 0.2,
        })
    }

    /// The bird's-eye camera over the map: centred on the four
    /// intersections, at `map.camera_altitude_m`, or else at the original's
    /// 40 m ([`Camera::birds_eye`]) unless the intersections and their stop
    /// lines do not fit the view from there, then just high enough that they
    /// do. Errs when a given altitude leaves them out of view.
    pub fn birds_eye_camera(&self) -> Result<Camera, SpecError> {
        let (lo, hi) = self.map.layout().framed_area();
        let (width, height) = (self.image.width, self.image.height);
        let original = Camera::birds_eye(width, height);
        let fits = Camera::altitude_to_frame(width, height, hi - lo);
        let altitude = match self.map.camera_altitude_m {
            Some(a) if a < fits - 1e-9 => {
                return Err(SpecError::new(
                    "map.camera_altitude_m",
                    format!(
                        "{a} m shows less than the four intersections and their stop lines ({:.1} m x {:.1} m) in a {width}x{height} image: use at least {:.2} m, or leave it out",
                        hi.x - lo.x,
                        hi.y - lo.y,
                        fits
                    ),
                ))
            }
            Some(a) => a,
            None => original.altitude_m.max(fits),
        };
        Ok(Camera::birds_eye_over(width, height, (lo + hi) / 2.0, altitude))
    }

    /// Toy world: pixels from follower to leader along their path at the start.
    pub fn leader_gap_px(&self) -> f64 {
        self.leader_gap_px.unwrap_or(DEFAULT_LEADER_GAP_PX)
    }

    /// The city settings (defaults when the spec has none).
    pub fn city_settings(&self) -> CitySpec {
        self.city.clone().unwrap_or_default()
    }

    /// The spec with every default written out, as recorded in manifests.
    pub fn resolved(&self) -> DatasetSpec {
        let mut spec = self.clone();
        spec.frame_interval = Some(self.frame_interval());
        if self.world == WorldKind::Toy {
            spec.leader_gap_px = Some(self.leader_gap_px());
        }
        if self.world == WorldKind::City {
            let mut city = self.city_settings();
            city.lights.phase.get_or_insert(LightPhase::Random);
            spec.city = Some(city);
        }
        spec
    }

    /// Scenarios in the whole dataset, or with at most `limit` per split.
    pub fn scenario_count(&self, limit: Option<u32>) -> u64 {
        let per_group: u64 =
            Split::ALL.iter().map(|s| self.splits.count(*s).min(limit.unwrap_or(u32::MAX)) as u64).sum();
        per_group * self.groups.len() as u64
    }
}

fn range(field: &str, value: u32, lo: u32, hi: u32) -> Result<(), SpecError> {
    if value < lo || value > hi {
        return Err(SpecError::new(field, format!("{value} is not allowed: use {lo} to {hi}")));
    }
    Ok(())
}

fn positive(field: &str, value: f64, hi: f64, unit: &str) -> Result<(), SpecError> {
    if !(value.is_finite() && value > 0.0 && value <= hi) {
        return Err(SpecError::new(
            field,
            format!("{} is not allowed: {unit}, above 0 and at most {hi}", Shown(value)),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn edges_follow_the_documented_rule() {
        let g = |cars, p| GroupSpec { cars, edge_proportion: p }.edges();
        assert_eq!(g(8, 0.5), 2);
        assert_eq!(g(12, 0.5), 3);
        assert_eq!(g(4, 0.5), 1);
        assert_eq!(g(8, 0.2), 1);
        assert_eq!(g(8, 0.8), 3);
        assert_eq!(g(4, 0.1), 1);
        assert_eq!(g(4, 0.0), 0);
        assert_eq!(GroupSpec { cars: 8, edge_proportion: 0.5 }.name(), "cars08_edges50");
    }

    fn spec_with_map(map: &str) -> DatasetSpec {
        DatasetSpec::from_json(&format!(
            r#"{{"name": "m", "world": "city", "seed": 1, "groups": [{{"cars": 4, "edge_proportion": 0.5}}],
                "splits": {{"train": 1, "val": 0, "test": 0}}, "map": {map}}}"#
        ))
        .unwrap()
    }

    #[test]
    fn the_camera_frames_the_intersections_whatever_their_size() {
        // The default layout: the original's camera, 40 m up, 12.8 px per metre, over the centre.
        let c = spec_with_map("{}").birds_eye_camera().unwrap();
        assert_eq!((c.altitude_m, c.centre_x, c.centre_y), (40.0, 0.0, 0.0));
        assert!((c.pixels_per_metre - 12.8).abs() < 1e-9);
        // Blocks too big for 40 m: the camera climbs until the intersections and stop lines fit, centred on them.
        let spec = spec_with_map(
            r#"{"east_west_roads": [-30, 30], "north_south_roads": [-50, 40], "extent_x": 100, "extent_y": 80}"#,
        );
        let c = spec.birds_eye_camera().unwrap();
        let (lo, hi) = spec.map.layout().framed_area();
        let (view_lo, view_hi) = c.ground_view();
        assert!(c.altitude_m > 40.0);
        assert!(view_lo.x <= lo.x + 1e-9 && view_lo.y <= lo.y + 1e-9, "{view_lo} {lo}");
        assert!(view_hi.x >= hi.x - 1e-9 && view_hi.y >= hi.y - 1e-9, "{view_hi} {hi}");
        // Just high enough: the tighter side (here the height, 60 + 2 x 9.6 m) fills the image.
        assert!(((view_hi.y - view_lo.y) - (hi.y - lo.y)).abs() < 1e-9);
        assert_eq!((c.centre_x, c.centre_y), (-5.0, 0.0));
        // A given altitude is used as given.
        let c = spec_with_map(r#"{"east_west_roads": [-30, 30], "extent_y": 80, "camera_altitude_m": 90}"#)
            .birds_eye_camera()
            .unwrap();
        assert_eq!(c.altitude_m, 90.0);
    }
}
