//! `manifest.json`: what the dataset is (the effective spec, tool version,
//! camera) and what it holds (counts per group and split). Contains nothing
//! that depends on time or thread count, so identical runs give identical bytes.

use crate::camera::Camera;
use crate::spec::{DatasetSpec, Split};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::collections::BTreeMap;
use std::path::Path;

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
    /// The splits that hold the car count out (`held_out.<split>.cars`):
    /// their cars and edges per scenario, in place of `cars` and `edges`.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub held_out: BTreeMap<&'static str, HeldOutCars>,
}

/// A split's own car count in a group ([`GroupEntry::held_out`]).
#[derive(Debug, Serialize)]
pub struct HeldOutCars {
    pub cars: u32,
    pub edges: u32,
}

/// The manifest record.
#[derive(Debug, Serialize)]
pub struct Manifest<'a> {
    pub format: &'static str,
    pub tool: &'static str,
    pub version: &'static str,
    /// SHA-256 of the spec as run (with defaults filled in), compact JSON.
    pub spec_sha256: String,
    pub spec: &'a DatasetSpec,
    /// Scenarios per split were capped at this (`--limit`).
    pub limit: Option<u32>,
    pub images: bool,
    /// Scenarios carry NS-DR annotations.json (`gen --annotations`).
    pub annotations: bool,
    /// Scenarios carry effects.csv and causal graphs (off with `gen --no-effects`).
    pub effects: bool,
    /// How the lights' colours are written (`gen --lights`); absent: `frames`.
    #[serde(skip_serializing_if = "LightsLog::is_frames")]
    pub lights: LightsLog,
    /// Scenarios are packed into tar files of this many (`gen --format
    /// tar`); absent: a folder per scenario.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scenarios_per_tar: Option<u32>,
    pub camera: &'a Camera,
    pub frames_per_scenario: u32,
    pub frame_file_digits: usize,
    pub scenarios: u64,
    pub groups: Vec<GroupEntry>,
    /// False while a run is writing; true once every scenario is in place.
    pub complete: bool,
    /// Only in the per-shard manifests under `shards/`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub shard: Option<ShardEntry>,
}

/// Which optional files every scenario of a dataset has.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Products {
    /// rgb/ and mask/ PNG frames.
    pub images: bool,
    /// annotations.json (needs images).
    pub annotations: bool,
    /// effects.csv and the causal graphs in scenario.json (`gen`; off with
    /// `--no-effects`).
    pub effects: bool,
    /// City world: lights.csv (every light every frame) or
    /// light_changes.csv (each light at frame 0 and where it changes).
    pub lights: LightsLog,
}

/// How a city scenario logs its lights' colours.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LightsLog {
    /// `lights.csv`: one row per light and frame.
    #[default]
    Frames,
    /// `light_changes.csv`: one row per light at frame 0, then one per
    /// light and frame where its colour differs from the frame before.
    Changes,
}

impl LightsLog {
    pub fn is_frames(&self) -> bool {
        *self == LightsLog::Frames
    }

    /// As `gen --lights` names it.
    pub fn name(self) -> &'static str {
        match self {
            LightsLog::Frames => "frames",
            LightsLog::Changes => "changes",
        }
    }
}

/// How a dataset stores its scenarios on disk (`gen --format`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Packing {
    /// `<group>/<split>/<scenario>/`, a folder per scenario.
    #[default]
    Folders,
    /// Whole scenarios packed `per_tar` at a time into tar files
    /// ([`crate::output::packs`]).
    Tar { per_tar: u32 },
}

impl Packing {
    /// The manifest's `scenarios_per_tar`.
    pub fn scenarios_per_tar(self) -> Option<u32> {
        match self {
            Packing::Folders => None,
            Packing::Tar { per_tar } => Some(per_tar),
        }
    }

    /// As `gen` takes it: `--format folders`, `--format tar
    /// --scenarios-per-tar N`.
    pub fn describe(self) -> String {
        match self {
            Packing::Folders => "folders".into(),
            Packing::Tar { per_tar } => format!("tar ({per_tar} scenarios per tar)"),
        }
    }
}

/// Which part of the dataset a shard run writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct ShardEntry {
    /// 0-based.
    pub index: u32,
    pub count: u32,
    /// Scenarios in this shard.
    pub scenarios: u64,
}

/// SHA-256 (hex) of a spec's compact JSON.
pub fn spec_sha256(spec: &DatasetSpec) -> String {
    super::hex(&Sha256::digest(serde_json::to_vec(spec).expect("spec serialises")))
}

/// What a run into an existing folder must agree on.
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct ManifestRecord {
    pub version: String,
    pub spec_sha256: String,
    pub spec: serde_json::Value,
    pub images: bool,
    #[serde(default)]
    pub annotations: bool,
    /// Datasets written before effects existed have none.
    #[serde(default)]
    pub effects: bool,
    #[serde(default)]
    pub lights: LightsLog,
    /// Absent: a folder per scenario.
    #[serde(default)]
    pub scenarios_per_tar: Option<u32>,
    pub limit: Option<u32>,
    pub groups: Vec<GroupRecord>,
    pub complete: bool,
    #[serde(default)]
    pub shard: Option<ShardEntry>,
    /// Fields gen derives from the spec, as written (`validate` compares
    /// them with the spec's): scenario and frame counts, frame file digits.
    #[serde(default)]
    pub scenarios: serde_json::Value,
    #[serde(default)]
    pub frames_per_scenario: serde_json::Value,
    #[serde(default)]
    pub frame_file_digits: serde_json::Value,
}

/// A group as read back from a manifest: its name, and its cars and split
/// sizes as written (derived from the spec).
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct GroupRecord {
    pub name: String,
    #[serde(default)]
    pub cars: serde_json::Value,
    #[serde(default)]
    pub splits: serde_json::Value,
}

impl ManifestRecord {
    /// Reads a manifest; `Ok(None)` when there is none.
    pub fn read(path: &Path) -> Result<Option<ManifestRecord>, String> {
        match crate::input::read_record(path) {
            Ok(bytes) => serde_json::from_slice(&bytes)
                .map(Some)
                .map_err(|e| format!("{} is not a causalcity manifest: {e}", path.display())),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(e) => Err(format!("cannot read {}: {e}", path.display())),
        }
    }

    /// The per-scenario files this dataset was written with.
    pub fn products(&self) -> Products {
        Products { images: self.images, annotations: self.annotations, effects: self.effects, lights: self.lights }
    }

    /// How its scenarios are stored.
    pub fn packing(&self) -> Packing {
        match self.scenarios_per_tar {
            None => Packing::Folders,
            Some(per_tar) => Packing::Tar { per_tar },
        }
    }

    /// What differs between this manifest and a run of `spec` writing
    /// `products` stored as `packing`, one line per difference; empty when
    /// they agree.
    pub fn differences(&self, spec: &DatasetSpec, products: Products, packing: Packing) -> Vec<String> {
        let images = products.images;
        let mut out = Vec::new();
        if self.version != env!("CARGO_PKG_VERSION") {
            out.push(format!("tool version: {} wrote it, this is {}", self.version, env!("CARGO_PKG_VERSION")));
        }
        if self.images != images {
            out.push(format!("images: {} there, {} now (--no-images)", self.images, images));
        }
        if self.annotations != products.annotations {
            out.push(format!("annotations: {} there, {} now (--annotations)", self.annotations, products.annotations));
        }
        if self.effects != products.effects {
            out.push(format!("effects: {} there, {} now (--no-effects)", self.effects, products.effects));
        }
        if self.lights != products.lights {
            out.push(format!("lights: {} there, {} now (--lights)", self.lights.name(), products.lights.name()));
        }
        if self.packing() != packing {
            out.push(format!(
                "format: {} there, {} now (--format, --scenarios-per-tar)",
                self.packing().describe(),
                packing.describe()
            ));
        }
        if self.spec_sha256 != spec_sha256(spec) {
            let new = serde_json::to_value(spec).expect("spec serialises");
            diff_values("spec", &self.spec, &new, ("there", "now"), &mut out);
            if out.is_empty() {
                out.push("spec: contents differ".into());
            }
        }
        out
    }

    /// The limit as it acts on the spec's split sizes: `None` when there
    /// is none or it is at or above the largest split.
    pub fn effective_limit(&self) -> Option<u32> {
        let largest = ["train", "val", "test"].iter().filter_map(|s| self.spec["splits"][s].as_u64()).max();
        self.limit.filter(|&l| largest.is_none_or(|largest| u64::from(l) < largest))
    }

    /// What differs between this shard manifest and `other`'s, which
    /// `labels` name (`here`, `in the first`), one line per difference;
    /// empty when they are shards of one dataset.
    pub fn shard_differences(&self, other: &ManifestRecord, labels: (&str, &str)) -> Vec<String> {
        let (a, b) = labels;
        let mut out = Vec::new();
        let mut differ = |field: &str, mine: String, theirs: String| {
            if mine != theirs {
                out.push(format!("{field}: {mine} {a}, {theirs} {b}"));
            }
        };
        differ("tool version", self.version.clone(), other.version.clone());
        differ("images (--no-images)", self.images.to_string(), other.images.to_string());
        differ("annotations (--annotations)", self.annotations.to_string(), other.annotations.to_string());
        differ("effects (--no-effects)", self.effects.to_string(), other.effects.to_string());
        differ("lights (--lights)", self.lights.name().into(), other.lights.name().into());
        differ("format (--format, --scenarios-per-tar)", self.packing().describe(), other.packing().describe());
        // A limit at or above every split's size is the same dataset as no
        // limit, as gen takes it (merge refused shards gen had let in).
        let limit = |l: Option<u32>| l.map_or("none".to_string(), |l| l.to_string());
        if self.effective_limit() != other.effective_limit() {
            differ("--limit", limit(self.limit), limit(other.limit));
        }
        let count = |r: &ManifestRecord| r.shard.map_or("none".to_string(), |s| s.count.to_string());
        differ("shard count (--shard K/N)", count(self), count(other));
        if self.spec_sha256 != other.spec_sha256 {
            let before = out.len();
            diff_values("spec", &self.spec, &other.spec, labels, &mut out);
            if out.len() == before {
                out.push("spec: contents differ".into());
            }
        }
        out
    }
}

/// One line per value that differs between `old` and `new` (at JSON
/// `path`), each side named by `labels` (`8 there, 7 now`).
fn diff_values(
    path: &str,
    old: &serde_json::Value,
    new: &serde_json::Value,
    labels: (&str, &str),
    out: &mut Vec<String>,
) {
    use serde_json::Value;
    match (old, new) {
        (Value::Object(a), Value::Object(b)) => {
            let keys: std::collections::BTreeSet<&String> = a.keys().chain(b.keys()).collect();
            for k in keys {
                let null = Value::Null;
                diff_values(&format!("{path}.{k}"), a.get(k).unwrap_or(&null), b.get(k).unwrap_or(&null), labels, out);
            }
        }
        _ if old != new => {
            let short = |v: &serde_json::Value| {
                let text = v.to_string();
                if text.chars().count() > 60 {
                    format!("{}...", text.chars().take(57).collect::<String>())
                } else {
                    text
                }
            };
            out.push(format!("{path}: {} {}, {} {}", short(old), labels.0, short(new), labels.1))
        }
        _ => {}
    }
}

impl<'a> Manifest<'a> {
    pub fn new(
        spec: &'a DatasetSpec,
        camera: &'a Camera,
        limit: Option<u32>,
        products: Products,
        packing: Packing,
        complete: bool,
        shard: Option<ShardEntry>,
    ) -> Manifest<'a> {
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
                held_out: Split::ALL
                    .iter()
                    .filter(|s| spec.held_out.of(**s).is_some_and(|h| h.cars.is_some()))
                    .map(|&s| {
                        let own = spec.group_of(s, g);
                        (s.name(), HeldOutCars { cars: own.cars, edges: own.edges() })
                    })
                    .collect(),
            })
            .collect();
        Manifest {
            format: MANIFEST_FORMAT,
            tool: "causalcity",
            version: env!("CARGO_PKG_VERSION"),
            spec_sha256: spec_sha256(spec),
            spec,
            limit,
            images: products.images,
            annotations: products.annotations,
            effects: products.effects,
            lights: products.lights,
            scenarios_per_tar: packing.scenarios_per_tar(),
            camera,
            frames_per_scenario: spec.frames,
            frame_file_digits: super::frame_digits(spec.frames),
            scenarios: spec.scenario_count(limit),
            groups,
            complete,
            shard,
        }
    }

    pub fn to_json(&self) -> Vec<u8> {
        let mut out = serde_json::to_vec_pretty(self).expect("manifest serialises");
        out.push(b'\n');
        out
    }
}
