//! The dataset spec: what a user asks for, read from JSON. Every field is
//! checked here with a message that names it, the value and what is allowed.

use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::Path;

/// Which dynamics drive the cars.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum WorldKind {
    /// No agency: constant speed along the route, no lights, no collisions.
    Toy,
    /// Agency, lights and confounders (not implemented yet).
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
    /// Seconds between frames.
    #[serde(default = "default_frame_interval")]
    pub frame_interval: f64,
    #[serde(default)]
    pub image: ImageSize,
    pub groups: Vec<GroupSpec>,
    pub splits: Splits,
    /// High-level actions in each car's drive queue.
    #[serde(default = "default_actions")]
    pub actions_per_car: u32,
    /// Toy world: distance every car covers per frame, in pixels of `image`.
    #[serde(default = "default_toy_speed")]
    pub toy_speed_px_per_frame: f64,
    /// Distance along the shared path from follower to leader at the start, pixels.
    #[serde(default = "default_leader_gap")]
    pub leader_gap_px: f64,
    /// Car footprint, metres.
    #[serde(default = "default_car_length")]
    pub car_length_m: f64,
    #[serde(default = "default_car_width")]
    pub car_width_m: f64,
}

fn default_frames() -> u32 {
    150
}
fn default_frame_interval() -> f64 {
    0.1
}
fn default_actions() -> u32 {
    5
}
fn default_toy_speed() -> f64 {
    2.0
}
fn default_leader_gap() -> f64 {
    30.0
}
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
    /// Parses and checks a spec from JSON text.
    pub fn from_json(text: &str) -> Result<DatasetSpec, SpecError> {
        let de = &mut serde_json::Deserializer::from_str(text);
        let spec: DatasetSpec = serde_path_to_error::deserialize(de).map_err(|e| {
            let path = e.path().to_string();
            let field = if path == "." { String::new() } else { path };
            SpecError::new(field, e.into_inner().to_string())
        })?;
        spec.validate()?;
        Ok(spec)
    }

    /// Reads, parses and checks a spec file.
    pub fn from_file(path: &Path) -> Result<DatasetSpec, SpecError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| SpecError::new("", format!("cannot read spec file {}: {e}", path.display())))?;
        DatasetSpec::from_json(&text)
    }

    /// Checks every field's range and the groups' consistency.
    pub fn validate(&self) -> Result<(), SpecError> {
        let name_ok = !self.name.is_empty()
            && self.name.len() <= 64
            && !self.name.starts_with('.')
            && self.name.chars().all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'));
        if !name_ok {
            return Err(SpecError::new(
                "name",
                format!(
                    "{:?} is not allowed: use 1 to 64 characters from A-Z a-z 0-9 - _ . (not starting with a dot); it names the output folder",
                    self.name
                ),
            ));
        }
        range("frames", self.frames, 1, MAX_FRAMES)?;
        if !(self.frame_interval.is_finite() && self.frame_interval > 0.0 && self.frame_interval <= 10.0) {
            return Err(SpecError::new(
                "frame_interval",
                format!("{} is not allowed: seconds between frames, above 0 and at most 10", self.frame_interval),
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
                        g.edge_proportion
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
        positive("leader_gap_px", self.leader_gap_px, 2000.0, "pixels")?;
        Ok(())
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
        return Err(SpecError::new(field, format!("{value} is not allowed: {unit}, above 0 and at most {hi}")));
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
}
