//! `causalcity export nri`: per group and split, `loc_<split><suffix>.npy`,
//! `vel_<split><suffix>.npy` and `edges_<split><suffix>.npy`, splits named
//! train / valid / test as the NRI loaders expect, float32 pixel coordinates.
//!
//! Layouts:
//! - `causalcity` (the original CausalCity NRI fork): loc and vel
//!   [scenarios, frames, cars, 2]; edges [scenarios, cars, cars] = identity
//!   plus the causal links.
//! - `nri` (the NRI reference code): loc and vel [scenarios, frames, 2, cars];
//!   edges 0/1 without self loops.
//!
//! Edges follow NRI's receiver/sender convention: `edges[s, i, j] = 1` when
//! car j drives car i (j is i's leader). Without `--directed` both directions
//! of each leader-follower pair are set. `vel[t] = loc[t] - loc[t-1]`, with
//! `vel[0] = loc[1] - loc[0]`. Car order is the scenario's (randomly
//! permuted) ids. One split is held in memory at a time.

use crate::dataset::{Dataset, PoseLog, ScenarioSummary};
use crate::output::io_err;
use crate::spec::Split;
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// Array layout of the export.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum NriLayout {
    /// loc/vel [scenarios, frames, cars, 2]; edges with the identity.
    Causalcity,
    /// loc/vel [scenarios, frames, 2, cars]; edges without self loops.
    Nri,
}

/// What `export nri` was asked for.
#[derive(Debug, Clone)]
pub struct NriOptions {
    pub layout: NriLayout,
    pub suffix: String,
    pub directed: bool,
}

/// Split names as the NRI loaders spell them.
pub fn nri_split_name(split: Split) -> &'static str {
    match split {
        Split::Train => "train",
        Split::Val => "valid",
        Split::Test => "test",
    }
}

/// One scenario's pixel track and causal links.
struct Track {
    /// [frame][car] -> (px, py)
    loc: Vec<Vec<[f32; 2]>>,
    /// (leader, follower)
    edges: Vec<(usize, usize)>,
}

fn read_track(dir: &Path, cars: usize, frames: usize) -> Result<Track, String> {
    let scenario = ScenarioSummary::read(dir)?;
    if scenario.cars.len() != cars || scenario.frames as usize != frames {
        return Err(format!(
            "{}: {} cars x {} frames, the spec says {cars} x {frames}",
            dir.display(),
            scenario.cars.len(),
            scenario.frames
        ));
    }
    let poses = PoseLog::read(dir, frames, cars)?;
    let loc = (0..frames).map(|f| poses.frame(f).iter().map(|p| [p.px as f32, p.py as f32]).collect()).collect();
    let edges = scenario.edges.iter().map(|e| (e[0] as usize, e[1] as usize)).collect();
    Ok(Track { loc, edges })
}

fn write_npy<T: npyz::AutoSerialize + Copy>(path: &Path, shape: &[u64], data: &[T]) -> Result<(), String> {
    let partial = path.with_extension("npy.partial");
    let write = || -> std::io::Result<()> {
        let file = std::io::BufWriter::new(std::fs::File::create(&partial)?);
        use npyz::WriterBuilder;
        let mut writer = npyz::WriteOptions::<T>::new().default_dtype().shape(shape).writer(file).begin_nd()?;
        writer.extend(data.iter().copied())?;
        writer.finish()?;
        std::fs::rename(&partial, path)
    };
    write().map_err(|e| format!("cannot write {}: {e}", path.display()))
}

/// Exports `dataset` into `out`; returns a one-line report per file group.
pub fn export_nri(dataset: &Path, out: &Path, options: &NriOptions) -> Result<Vec<String>, String> {
    let opened = Dataset::open_complete(dataset)?;
    let frames = opened.spec().frames as usize;
    let mut report = Vec::new();
    for group in &opened.spec().groups {
        let cars = group.cars as usize;
        let group_dir: PathBuf = out.join(group.name());
        std::fs::create_dir_all(&group_dir).map_err(|e| io_err(&group_dir)(e).to_string())?;
        for split in Split::ALL {
            let dirs = opened.scenario_dirs(&group.name(), split);
            if dirs.is_empty() {
                continue;
            }
            let tracks: Vec<Track> = dirs.par_iter().map(|d| read_track(d, cars, frames)).collect::<Result<_, _>>()?;
            let s = tracks.len();
            let (loc, vel) = arrange(&tracks, frames, cars, options.layout);
            let mut edges = vec![0i64; s * cars * cars];
            for (k, t) in tracks.iter().enumerate() {
                let base = k * cars * cars;
                if options.layout == NriLayout::Causalcity {
                    for i in 0..cars {
                        edges[base + i * cars + i] = 1;
                    }
                }
                for &(leader, follower) in &t.edges {
                    edges[base + follower * cars + leader] = 1;
                    if !options.directed {
                        edges[base + leader * cars + follower] = 1;
                    }
                }
            }
            let (f, c) = (frames as u64, cars as u64);
            let loc_shape = match options.layout {
                NriLayout::Causalcity => [s as u64, f, c, 2],
                NriLayout::Nri => [s as u64, f, 2, c],
            };
            let name = |kind: &str| group_dir.join(format!("{kind}_{}{}.npy", nri_split_name(split), options.suffix));
            write_npy(&name("loc"), &loc_shape, &loc)?;
            write_npy(&name("vel"), &loc_shape, &vel)?;
            write_npy(&name("edges"), &[s as u64, c, c], &edges)?;
            report.push(format!(
                "{}: {} {} scenarios, loc/vel {:?}",
                group_dir.display(),
                nri_split_name(split),
                s,
                loc_shape
            ));
        }
    }
    Ok(report)
}

/// loc and vel in the layout's order.
fn arrange(tracks: &[Track], frames: usize, cars: usize, layout: NriLayout) -> (Vec<f32>, Vec<f32>) {
    let n = tracks.len() * frames * cars * 2;
    let (mut loc, mut vel) = (vec![0f32; n], vec![0f32; n]);
    for (k, t) in tracks.iter().enumerate() {
        for frame in 0..frames {
            for car in 0..cars {
                let here = t.loc[frame][car];
                let velocity = match frame {
                    0 if frames > 1 => sub(t.loc[1][car], here),
                    0 => [0.0, 0.0],
                    _ => sub(here, t.loc[frame - 1][car]),
                };
                for axis in 0..2 {
                    let index = match layout {
                        NriLayout::Causalcity => ((k * frames + frame) * cars + car) * 2 + axis,
                        NriLayout::Nri => ((k * frames + frame) * 2 + axis) * cars + car,
                    };
                    loc[index] = here[axis];
                    vel[index] = velocity[axis];
                }
            }
        }
    }
    (loc, vel)
}

fn sub(a: [f32; 2], b: [f32; 2]) -> [f32; 2] {
    [a[0] - b[0], a[1] - b[1]]
}
