//! The dataset spec: what a user asks for, read from JSON. Every field is
//! checked here with a message that names it, the value and what is allowed.
//!
//! One file per concept: this one holds the dataset (world, groups,
//! splits, image) and the checks they share; `map.rs` the map's
//! dimensions, `camera.rs` the extra cameras, `city.rs` the city world's
//! drivers, start, lights and confounders.

mod camera;
mod city;
mod graph;
mod held_out;
mod map;
mod network;

pub use camera::*;
pub use city::*;
pub use graph::*;
pub use held_out::*;
pub use map::*;
pub use network::*;

use crate::camera::{Camera, CameraKind, CameraPlan, Pinhole};
use crate::json::Shown;
use crate::map::control::JunctionControl;
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
    /// The designed leader-follower graph's shape: pairs unless given.
    #[serde(default, skip_serializing_if = "GraphSpec::is_pairs")]
    pub graph: GraphSpec,
    /// What val and test draw differently from train.
    #[serde(default, skip_serializing_if = "HeldOutSplits::is_empty")]
    pub held_out: HeldOutSplits,
}

/// 1 to 64 characters from A-Z a-z 0-9 - _ . not starting with a dot.
pub fn valid_folder_name(name: &str) -> bool {
    !name.is_empty()
        && name.len() <= 64
        && !name.starts_with('.')
        && name.chars().all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
}

/// Why `name` may not name a folder beside `others`, which name `what`s (a
/// scenario, a camera): it is one of them, or differs from one only in
/// case (one folder on macOS and Windows, where the second would land in
/// the first's). `None` when it may.
pub fn folder_name_clash<'a>(name: &str, others: impl IntoIterator<Item = &'a str>, what: &str) -> Option<String> {
    let other = others.into_iter().find(|other| other.eq_ignore_ascii_case(name))?;
    Some(if other == name {
        format!("{name:?} names another {what} too: names must be unique (they name folders)")
    } else {
        format!(
            "{name:?} differs from another {what}'s name {other:?} only in case: they name folders, which macOS and \
             Windows do not tell apart by case"
        )
    })
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
/// Most frames a scenario has.
pub const MAX_FRAMES: u32 = 100_000;
/// Most seconds between two frames.
pub const MAX_FRAME_INTERVAL_S: f64 = 10.0;
/// Fewest seconds between two frames: a millisecond (a 1 kHz camera),
/// over which a car at 15 m/s moves 15 mm, where poses are logged to the
/// millimetre (below it, frames repeat one another and speeds in stats
/// ran to hundreds of digits).
pub const MIN_FRAME_INTERVAL_S: f64 = 0.001;
/// The longest scenario a spec allows, seconds ([`MAX_FRAMES`] frames
/// [`MAX_FRAME_INTERVAL_S`] apart): a time an intervention holds, or a
/// light plan's offset, needs no more.
pub const MAX_SCENARIO_S: f64 = MAX_FRAMES as f64 * MAX_FRAME_INTERVAL_S;
const MAX_SCENARIOS_PER_SPLIT: u32 = 10_000_000;
const MAX_ACTIONS: u32 = 100;

impl DatasetSpec {
    /// Parses and checks a spec from JSON text (strictly: no duplicate
    /// keys, no trailing data, objects where the spec has objects).
    pub fn from_json(text: &str) -> Result<DatasetSpec, SpecError> {
        let spec: DatasetSpec = crate::json::parse_strict(text).map_err(|e| {
            let message = field_range_said(&e.path, e.message);
            SpecError::new(e.path, message)
        })?;
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
            graph: GraphSpec::default(),
            held_out: HeldOutSplits::default(),
        }
    }

    /// Reads, parses and checks a spec file.
    pub fn from_file(path: &Path) -> Result<DatasetSpec, SpecError> {
        let text = crate::input::read_record_text(path)
            .map_err(|e| SpecError::new("", format!("cannot read spec file {}: {e}", path.display())))?;
        let mut spec = DatasetSpec::from_json(&text)?;
        spec.read_networks_beside(path)?;
        Ok(spec)
    }

    /// Checks every field's range and the groups' consistency, as a spec
    /// given as input.
    pub fn validate(&self) -> Result<(), SpecError> {
        self.validate_as(false)
    }

    /// [`DatasetSpec::validate`] of a spec recorded in a dataset or sweep
    /// (its manifest.json, sweep.json): limits added since an earlier
    /// version wrote it are not applied, so that what it wrote still reads
    /// (the lowest frame_interval, cycle_scale and schedule step, a zoom on
    /// a perspective camera).
    pub fn validate_recorded(&self) -> Result<(), SpecError> {
        self.validate_as(true)
    }

    fn validate_as(&self, recorded: bool) -> Result<(), SpecError> {
        if !valid_folder_name(&self.name) {
            return Err(SpecError::new(
                "name",
                format!(
                    "{} is not allowed: use 1 to 64 characters from A-Z a-z 0-9 - _ . (not starting with a dot); it names the output folder",
                    crate::json::ShownText(&self.name)
                ),
            ));
        }
        whole("frames", self.frames)?;
        let interval = self.frame_interval();
        let lowest = if recorded { f64::MIN_POSITIVE } else { MIN_FRAME_INTERVAL_S };
        if !(interval.is_finite() && (lowest..=MAX_FRAME_INTERVAL_S).contains(&interval)) {
            return Err(SpecError::new(
                "frame_interval",
                format!(
                    "{} is not allowed: seconds between frames, from {MIN_FRAME_INTERVAL_S} to {MAX_FRAME_INTERVAL_S}",
                    Shown(interval)
                ),
            ));
        }
        whole("image.width", self.image.width)?;
        whole("image.height", self.image.height)?;
        if self.groups.is_empty() {
            return Err(SpecError::new(
                "groups",
                "the list is empty: give at least one {\"cars\": N, \"edge_proportion\": P}",
            ));
        }
        self.graph.validate()?;
        for split in [Split::Val, Split::Test] {
            if let Some(graph) = self.held_out.of(split).and_then(|h| h.graph.as_ref()) {
                graph.validate().map_err(|e| held_out_field(split, e))?;
            }
        }
        for split in [Split::Val, Split::Test] {
            if let Some(cars) = self.held_out.of(split).and_then(|h| h.cars) {
                whole(&format!("held_out.{}.cars", split.name()), cars)?;
            }
        }
        let mut names = std::collections::HashSet::new();
        for (i, g) in self.groups.iter().enumerate() {
            whole(&format!("groups[{i}].cars"), g.cars)?;
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
            for split in Split::ALL {
                let graph = self.graph_of(split);
                let g = &self.group_of(split, g);
                if graph.cars_needed(g.edges()) > g.cars {
                    let joined = match graph.shape {
                        GraphShape::Pairs => "leader-follower pairs".to_string(),
                        shape => format!("edges in {} of {} cars", shape.name(), graph.unit_cars()),
                    };
                    let held = self.held_out.of(split);
                    let whose = match (held.and_then(|h| h.graph.as_ref()), held.and_then(|h| h.cars)) {
                        (Some(_), _) => format!(" in {} (held_out.{}.graph)", split.name(), split.name()),
                        (None, Some(_)) => format!(" in {} (held_out.{}.cars)", split.name(), split.name()),
                        (None, None) => String::new(),
                    };
                    return Err(SpecError::new(
                        field,
                        format!(
                            "{} with {} cars asks for {} {joined}{whose} (round(proportion x cars / 2)), which need {} cars: lower the proportion or add cars",
                            g.edge_proportion,
                            g.cars,
                            g.edges(),
                            graph.cars_needed(g.edges())
                        ),
                    ));
                }
            }
            if !names.insert(g.name()) {
                return Err(SpecError::new(
                    format!("groups[{i}]"),
                    format!("duplicates group {}: every (cars, edge_proportion) pair may appear once", g.name()),
                ));
            }
        }
        for split in Split::ALL {
            whole(&format!("splits.{}", split.name()), self.splits.count(split))?;
        }
        if Split::ALL.iter().all(|s| self.splits.count(*s) == 0) {
            return Err(SpecError::new("splits", "all splits are 0: ask for at least one scenario"));
        }
        whole("actions_per_car", self.actions_per_car)?;
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
            (Some(city), WorldKind::City) => {
                city.validate_as(recorded)?;
                let platoon = city.start.platoon_cars;
                for split in Split::ALL {
                    let graph = self.graph_of(split);
                    if platoon != 0 && graph.queued_cars() > platoon {
                        let field = match self.held_out.of(split).and_then(|h| h.graph.as_ref()) {
                            // A collider's queue is a pair: the platoon is too small.
                            _ if graph.shape == GraphShape::Colliders => "city.start.platoon_cars".to_string(),
                            Some(_) => format!("held_out.{}.graph.cars", split.name()),
                            None => "graph.cars".to_string(),
                        };
                        return Err(SpecError::new(
                            field,
                            format!(
                                "{} is not allowed with city.start.platoon_cars = {platoon}: the cars of one {} start in one platoon, so it can have {platoon} cars at most",
                                graph.queued_cars(),
                                &graph.shape.name()[..graph.shape.name().len() - 1]
                            ),
                        ));
                    }
                }
            }
            (Some(_), WorldKind::Toy) => {
                return Err(SpecError::new("city", "applies to \"world\": \"city\" only: remove it or change world"))
            }
            (None, WorldKind::Toy) => {
                for split in Split::ALL {
                    if self.graph_of(split).shape == GraphShape::Colliders {
                        let field = match self.held_out.of(split).and_then(|h| h.graph.as_ref()) {
                            Some(_) => format!("held_out.{}.graph.shape", split.name()),
                            None => "graph.shape".to_string(),
                        };
                        return Err(SpecError::new(
                            field,
                            "\"colliders\" needs \"world\": \"city\": a toy car gives way to no one; use pairs, chains or forks",
                        ));
                    }
                }
            }
            (None, WorldKind::City) => {}
        }
        self.map.validate()?;
        for split in [Split::Val, Split::Test] {
            if let Some(map) = self.held_out.of(split).and_then(|h| h.map.as_ref()) {
                map.validate().map_err(|e| held_out_field(split, e))?;
            }
            if let Some(confounders) = self.held_out.of(split).and_then(|h| h.confounders.as_ref()) {
                if self.world != WorldKind::City {
                    return Err(SpecError::new(
                        format!("held_out.{}.confounders", split.name()),
                        "applies to \"world\": \"city\" only (the toy world has no confounders): remove it",
                    ));
                }
                confounders.validate(&format!("held_out.{}.confounders", split.name()))?;
            }
        }
        self.check_overridden_lights()?;
        self.check_actuated_lights()?;
        // A SUMO map is framed by its own bounds, checked once it is read
        // (before, this checked it against the default four-road city).
        if self.map.sumo.is_none() || self.map.network.0.is_some() {
            self.birds_eye_camera()?;
        }
        let fewest_cars = Split::ALL.iter().flat_map(|&s| self.groups_of(s)).map(|g| g.cars).min().unwrap_or(0);
        for (i, camera) in self.cameras.iter().enumerate() {
            let field = format!("cameras[{i}]");
            if !recorded {
                camera.check_input(&field)?;
            }
            camera.plan(&field, |car| match car {
                CarRef::Id(id) if *id < fewest_cars => Ok(*id as usize),
                CarRef::Id(id) => Err(format!(
                    "car {id} is not in every scenario: ids run from 0 to {} in the smallest group",
                    fewest_cars.saturating_sub(1)
                )),
                CarRef::Name(name) => Err(format!("{name:?}: in a spec, name the car by its id (0, 1, ...)")),
            })?;
            if let Some(why) =
                folder_name_clash(&camera.name, self.cameras[..i].iter().map(|c| c.name.as_str()), "camera")
            {
                return Err(SpecError::new(format!("{field}.name"), why));
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
        let (lo, hi) = self.map.camera_frame();
        let (width, height) = (self.image.width, self.image.height);
        let original = Camera::birds_eye(width, height);
        let fits = Camera::altitude_to_frame(width, height, hi - lo);
        let altitude = match self.map.camera_altitude_m {
            Some(a) if a < fits - 1e-9 => {
                return Err(SpecError::new(
                    "map.camera_altitude_m",
                    format!(
                        "{a} m shows less than {} ({:.1} m x {:.1} m) in a {width}x{height} image: use at least {:.2} m, or leave it out",
                        match self.map.camera_area {
                            // An imported network is framed whole.
                            None | Some(CameraArea::Named(_)) if self.map.network.0.is_some() => "the whole network",
                            None | Some(CameraArea::Named(CameraAreaName::Junctions)) => "every intersection and its stop lines",
                            Some(CameraArea::Named(CameraAreaName::Network)) => "the whole network",
                            Some(CameraArea::Area { .. }) => "map.camera_area",
                        },
                        hi.x - lo.x,
                        hi.y - lo.y,
                        fits
                    ),
                ));
            }
            Some(a) => a,
            // The junctions: the original's 40 m unless they need more; a
            // named area or the network: just what frames it.
            None => match self.map.camera_area {
                None | Some(CameraArea::Named(CameraAreaName::Junctions)) => original.altitude_m.max(fits),
                Some(_) => fits,
            },
        };
        Ok(Camera::birds_eye_over(width, height, (lo + hi) / 2.0, altitude))
    }

    /// In the city, when the bird's-eye view shows a car (`car_length_m` x
    /// `car_width_m`) as less than a pixel: why, for a warning (the frames
    /// and masks then miss most cars while `poses.csv` has them in view).
    pub fn cars_below_a_pixel(&self) -> Option<String> {
        let camera = self.birds_eye_camera().ok()?;
        let area = self.car_length_m * self.car_width_m * camera.pixels_per_metre.powi(2);
        (self.world == WorldKind::City && area < 1.0).then(|| {
            format!(
                "a {}x{} image from {:.1} m up shows {:.3} px per metre, so a car ({} m x {} m) covers {area:.2} of a pixel: the frames and masks will miss most cars. Use a larger image (the default is 1024x640), a smaller map.camera_area or a lower map.camera_altitude_m",
                camera.width, camera.height, camera.altitude_m, camera.pixels_per_metre, self.car_length_m, self.car_width_m
            )
        })
    }

    /// `city.lights.actuated` needs an imported network in some split: a
    /// grid town's lights run the fixed cycle.
    fn check_actuated_lights(&self) -> Result<(), SpecError> {
        let Some(city) = &self.city else { return Ok(()) };
        if city.lights.actuated && Split::ALL.iter().all(|&split| self.map_of(split).sumo.is_none()) {
            return Err(SpecError::new(
                "city.lights.actuated",
                "true, but no split drives a SUMO network (map.sumo): only an imported network's traffic-actuated programmes (tlLogic type=\"actuated\") are actuated; a grid town's lights run the fixed cycle. Leave it out, or give map.sumo",
            ));
        }
        Ok(())
    }

    /// `city.lights.overrides` may only name junctions with lights in
    /// every town the spec draws.
    fn check_overridden_lights(&self) -> Result<(), SpecError> {
        let Some(city) = &self.city else { return Ok(()) };
        for (i, o) in city.lights.overrides.iter().enumerate() {
            for split in Split::ALL {
                for town in self.map_of(split).towns() {
                    let Some(grid) = &town.grid else { continue };
                    let control = grid.control.of(&o.intersection);
                    if control != JunctionControl::Signals {
                        return Err(SpecError::new(
                            format!("city.lights.overrides[{i}].intersection"),
                            format!(
                                "{:?} has no traffic lights in the {} town (map.grid.control makes it {}): override a junction with lights, or give it \"signals\"",
                                o.intersection,
                                town.town_name(),
                                control.name()
                            ),
                        ));
                    }
                }
            }
        }
        Ok(())
    }

    /// The map section `split` draws its towns from: its held-out one, else the dataset's.
    pub fn map_of(&self, split: Split) -> &MapSpec {
        self.held_out.of(split).and_then(|h| h.map.as_ref()).unwrap_or(&self.map)
    }

    /// The confounder ranges `split` draws from (city world): its held-out
    /// ones, or the city section's.
    pub fn confounders_of(&self, split: Split) -> ConfounderSpec {
        match self.held_out.of(split).and_then(|h| h.confounders.as_ref()) {
            Some(held) => held.clone(),
            None => self.city_settings().confounders.clone(),
        }
    }

    /// The graph shape of `split`'s scenarios: its held-out one, else the dataset's.
    pub fn graph_of(&self, split: Split) -> &GraphSpec {
        self.held_out.of(split).and_then(|h| h.graph.as_ref()).unwrap_or(&self.graph)
    }

    /// Group `group` as `split` draws it: with the split's held-out car
    /// count (`held_out.<split>.cars`), else as the spec gives it. Its
    /// folder name stays [`GroupSpec::name`] of the spec's group.
    pub fn group_of(&self, split: Split, group: &GroupSpec) -> GroupSpec {
        match self.held_out.of(split).and_then(|h| h.cars) {
            Some(cars) => GroupSpec { cars, ..*group },
            None => *group,
        }
    }

    /// Every group as `split` draws it ([`DatasetSpec::group_of`]), in spec order.
    pub fn groups_of(&self, split: Split) -> Vec<GroupSpec> {
        self.groups.iter().map(|g| self.group_of(split, g)).collect()
    }

    /// The field that sets group `i`'s car count in `split`:
    /// `held_out.<split>.cars` when the split holds it out, else `groups[i].cars`.
    pub fn cars_field(&self, split: Split, i: usize) -> String {
        match self.held_out.of(split).and_then(|h| h.cars) {
            Some(_) => format!("held_out.{}.cars", split.name()),
            None => format!("groups[{i}].cars"),
        }
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

/// A parse error's `message` about whole-number `field` (of a spec, or
/// the same field of a hand-written scenario) with the field's own range
/// allowed: a fraction, a negative or a huge number named the type's range
/// ("from 0 to 4294967295" for frames, whose range is 1 to 100000).
pub fn field_range_said(field: &str, message: String) -> String {
    match whole_range(field) {
        Some((lo, hi)) => ["use a whole number from 0 to 4294967295", "use a whole number, 0 or more"]
            .iter()
            .fold(message, |m, said| m.replace(said, &format!("use a whole number from {lo} to {hi}"))),
        None => message,
    }
}

/// The spec's whole-number fields narrower than their type, and their
/// ranges: one table for the checks and for the parser's messages.
fn whole_range(field: &str) -> Option<(u32, u32)> {
    // `groups[3].cars` as `groups[].cars`, `held_out.test.cars` as `held_out.*.cars`.
    let general = match field.split_once('[').zip(field.split_once(']')) {
        Some(((before, _), (_, after))) => format!("{before}[]{after}"),
        None => field.to_string(),
    };
    let general = match general.strip_prefix("held_out.").and_then(|rest| rest.split_once('.')) {
        Some((_, after)) => format!("held_out.*.{after}"),
        None => general,
    };
    Some(match general.as_str() {
        "frames" => (1, MAX_FRAMES),
        "image.width" | "image.height" => (MIN_IMAGE_SIDE, MAX_IMAGE_SIDE),
        "groups[].cars" | "held_out.*.cars" => (1, MAX_CARS),
        "splits.train" | "splits.val" | "splits.test" => (0, MAX_SCENARIOS_PER_SPLIT),
        "actions_per_car" => (0, MAX_ACTIONS),
        _ => return None,
    })
}

/// `value` of `field` within its [`whole_range`].
fn whole(field: &str, value: u32) -> Result<(), SpecError> {
    debug_assert!(whole_range(field).is_some(), "{field} has no range in whole_range");
    let (lo, hi) = whole_range(field).unwrap_or((u32::MIN, u32::MAX));
    range(field, value, lo, hi)
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
    fn a_sumo_lights_offset_is_bounded_by_the_longest_scenario() {
        assert_eq!(crate::map::sumo::MAX_LIGHT_OFFSET_S, MAX_SCENARIO_S);
    }

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
