//! `manifest.json`: what the dataset is (the effective spec, tool version,
//! camera) and what it holds (counts per group and split). Contains nothing
//! that depends on time or thread count, so identical runs give identical bytes.

use crate::render::camera::Camera;
use crate::spec::{DatasetSpec, Split};
use serde::Serialize;
use std::collections::BTreeMap;

/// Format tag written into every manifest.
pub const MANIFEST_FORMAT: &str = "causalcity-dataset/1";

/// One group's entry in the manifest.
#[derive(Debug, Serialize)]
pub struct GroupEntry {
    pub name: String,
    pub cars: u32,
    pub edge_proportion: f64,
    pub edges: u32,
    pub splits: BTreeMap<&'static str, u32>,
}

/// The manifest record.
#[derive(Debug, Serialize)]
pub struct Manifest<'a> {
    pub format: &'static str,
    pub tool: &'static str,
    pub version: &'static str,
    pub spec: &'a DatasetSpec,
    /// Scenarios per split were capped at this (`--limit`).
    pub limit: Option<u32>,
    pub images: bool,
    pub camera: &'a Camera,
    pub frames_per_scenario: u32,
    pub frame_file_digits: usize,
    pub scenarios: u64,
    pub groups: Vec<GroupEntry>,
}

impl<'a> Manifest<'a> {
    pub fn new(spec: &'a DatasetSpec, camera: &'a Camera, limit: Option<u32>, images: bool) -> Manifest<'a> {
        let groups = spec
            .groups
            .iter()
            .map(|g| GroupEntry {
                name: g.name(),
                cars: g.cars,
                edge_proportion: g.edge_proportion,
                edges: g.edges(),
                splits: Split::ALL
                    .iter()
                    .map(|s| (s.name(), spec.splits.count(*s).min(limit.unwrap_or(u32::MAX))))
                    .collect(),
            })
            .collect();
        Manifest {
            format: MANIFEST_FORMAT,
            tool: "causalcity",
            version: env!("CARGO_PKG_VERSION"),
            spec,
            limit,
            images,
            camera,
            frames_per_scenario: spec.frames,
            frame_file_digits: super::frame_digits(spec.frames),
            scenarios: spec.scenario_count(limit),
            groups,
        }
    }

    pub fn to_json(&self) -> Vec<u8> {
        let mut out = serde_json::to_vec_pretty(self).expect("manifest serialises");
        out.push(b'\n');
        out
    }
}
