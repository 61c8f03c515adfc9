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
//! of each leader-follower pair are set. Velocities are differences of loc:
//! backward (the default), `vel[t] = loc[t] - loc[t-1]` with `vel[0] =
//! loc[1] - loc[0]`; or forward, as the original's converter
//! (`causalcity2nri_data.py`) computed them, `vel[t] = loc[t+1] - loc[t]`
//! with the last repeated, `vel[T-1] = vel[T-2]`. `clip` clamps positions
//! to the image (0..width x 0..height) before differencing, as that
//! converter did. Car order is the scenario's (randomly permuted) ids. One
//! split is held in memory at a time.
//!
//! `dynamic` (city world) adds `dynamic_edges_<split><suffix>.npy`, uint8
//! [scenarios, frames, cars, cars]: the per-frame car-to-car graph for
//! methods that discover time-varying graphs (such as dNRI), read from
//! `interactions.csv`. `dynamic_edges[s, t, i, j] = 1` when car j bound car
//! i's speed choice at frame t (`bound_by` car, conflict, give way or collision with
//! `other_car` j); the same receiver/sender, `--directed` and identity
//! conventions as `edges`.

use crate::dataset::{Dataset, GraphKind, ScenarioSummary};
use crate::error::Error;
use crate::output::claim::{claim, Writer};
use crate::output::layout::INTERACTIONS_CSV;
use crate::output::logs::read_interactions;
use crate::output::poses::{read_pixels, PIXELS_FILE};
use crate::spec::{Split, WorldKind};
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// Array layout of the export.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NriLayout {
    /// loc/vel [scenarios, frames, cars, 2]; edges with the identity.
    Causalcity,
    /// loc/vel [scenarios, frames, 2, cars]; edges without self loops.
    Nri,
}

/// How velocities are differenced from positions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Velocity {
    /// `loc[t] - loc[t-1]`, the first frame taking the second's.
    #[default]
    Backward,
    /// `loc[t+1] - loc[t]`, the last frame repeating the one before (the
    /// original converter).
    Forward,
}

/// What `export nri` was asked for.
#[derive(Debug, Clone)]
pub struct NriOptions {
    pub layout: NriLayout,
    pub suffix: String,
    pub directed: bool,
    /// Clamp positions to the image, as the original converter did.
    pub clip: bool,
    pub velocity: Velocity,
    /// Also write the per-frame graph from interactions.csv (city world).
    pub dynamic: bool,
    /// Which graph `edges` holds.
    pub graph: GraphKind,
}

/// Split names as the NRI loaders spell them.
pub fn nri_split_name(split: Split) -> &'static str {
    match split {
        Split::Train => "train",
        Split::Val => "valid",
        Split::Test => "test",
    }
}

/// Fills one scenario's block of loc, vel (frames x cars x 2, in the
/// layout's order) and edges (cars x cars) from its pixels.npy and
/// scenario.json.
fn fill_scenario(
    dir: &Path,
    (frames, cars): (usize, usize),
    image: (f32, f32),
    options: &NriOptions,
    (loc, vel, edges, dynamic): (&mut [f32], &mut [f32], &mut [i64], &mut [u8]),
) -> Result<(), String> {
    let scenario = ScenarioSummary::read_graph(dir, options.graph)?;
    if scenario.cars.len() != cars || scenario.frames as usize != frames {
        return Err(format!(
            "{}: {} cars x {} frames, the spec says {cars} x {frames}",
            dir.display(),
            scenario.cars.len(),
            scenario.frames
        ));
    }
    let mut pixels = read_pixels(&dir.join(PIXELS_FILE), frames, cars)?;
    if options.clip {
        for xy in pixels.chunks_exact_mut(2) {
            xy[0] = xy[0].clamp(0.0, image.0);
            xy[1] = xy[1].clamp(0.0, image.1);
        }
    }
    let at = |frame: usize, car: usize, axis: usize| pixels[(frame * cars + car) * 2 + axis];
    for frame in 0..frames {
        for car in 0..cars {
            for axis in 0..2 {
                let here = at(frame, car, axis);
                let step = |from: usize| at(from + 1, car, axis) - at(from, car, axis);
                let velocity = match (options.velocity, frame) {
                    _ if frames < 2 => 0.0,
                    (Velocity::Backward, 0) => step(0),
                    (Velocity::Backward, t) => step(t - 1),
                    (Velocity::Forward, t) if t + 1 == frames => step(t - 1),
                    (Velocity::Forward, t) => step(t),
                };
                let index = match options.layout {
                    NriLayout::Causalcity => (frame * cars + car) * 2 + axis,
                    NriLayout::Nri => (frame * 2 + axis) * cars + car,
                };
                loc[index] = here;
                vel[index] = velocity;
            }
        }
    }
    if options.layout == NriLayout::Causalcity {
        for i in 0..cars {
            edges[i * cars + i] = 1;
        }
    }
    for edge in &scenario.graph {
        let (leader, follower) = (edge[0] as usize, edge[1] as usize);
        edges[follower * cars + leader] = 1;
        if !options.directed {
            edges[leader * cars + follower] = 1;
        }
    }
    if options.dynamic {
        let records = read_interactions(&dir.join(INTERACTIONS_CSV), frames, cars)?;
        for (frame, graph) in dynamic.chunks_exact_mut(cars * cars).enumerate() {
            for receiver in 0..cars {
                if options.layout == NriLayout::Causalcity {
                    graph[receiver * cars + receiver] = 1;
                }
                if let Some(sender) = records[frame * cars + receiver].other_car {
                    graph[receiver * cars + sender] = 1;
                    if !options.directed {
                        graph[sender * cars + receiver] = 1;
                    }
                }
            }
        }
    }
    Ok(())
}

/// An array element written as little-endian bytes (the `<f4` / `<i8`
/// dtypes npyz declares for them).
trait LittleEndian: npyz::AutoSerialize + Copy {
    fn put(self, out: &mut Vec<u8>);
}

impl LittleEndian for f32 {
    fn put(self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.to_le_bytes());
    }
}

impl LittleEndian for u8 {
    fn put(self, out: &mut Vec<u8>) {
        out.push(self);
    }
}

impl LittleEndian for i64 {
    fn put(self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.to_le_bytes());
    }
}

/// Where [`write_npy`] writes `path` until the whole export has been written.
fn staged(path: &Path) -> PathBuf {
    path.with_extension("npy.partial")
}

/// Writes a C-order `.npy` at `staged(path)`: npyz writes the header (magic,
/// version, dtype, shape), the data follows as raw little-endian bytes,
/// streamed in chunks rather than element by element. The export renames
/// every file it staged once all are written.
fn write_npy<T: LittleEndian>(path: &Path, shape: &[u64], data: &[T]) -> Result<(), String> {
    use npyz::WriterBuilder;
    use std::io::Write;
    // (A leftover or a link planted at the staged name is removed first,
    // never written through.)
    let partial = crate::output::fresh_partial(path).map_err(|e| e.to_string())?;
    debug_assert_eq!(partial, staged(path));
    let write = || -> std::io::Result<()> {
        let mut file = std::io::BufWriter::with_capacity(1 << 20, std::fs::File::create(&partial)?);
        npyz::WriteOptions::<T>::new().default_dtype().shape(shape).writer(&mut file).write_header_only()?;
        let mut chunk = Vec::with_capacity(1 << 16);
        for part in data.chunks(1 << 13) {
            chunk.clear();
            for &value in part {
                value.put(&mut chunk);
            }
            file.write_all(&chunk)?;
        }
        file.flush()
    };
    write().map_err(|e| {
        let _ = std::fs::remove_file(&partial);
        format!("cannot write {}: {e}", path.display())
    })
}

/// Exports `dataset` into `out`; returns a one-line report per file group.
/// `dynamic` on a toy-world dataset is an input error, found before anything
/// is written.
pub fn export_nri(dataset: &Path, out: &Path, options: &NriOptions) -> Result<Vec<String>, Error> {
    let opened = Dataset::open_complete(dataset).map_err(Error::opening)?;
    opened.require_graph(options.graph).map_err(Error::Input)?;
    if options.dynamic && opened.spec().world != WorldKind::City {
        return Err(Error::Input(format!(
            "{}: --dynamic needs a city-world dataset (its interactions.csv); this one is {}-world",
            dataset.display(),
            opened.spec().world.name()
        )));
    }
    if opened.spec().frames < 2 {
        return Err(Error::Input(format!(
            "{}: its scenarios have 1 frame, and a velocity needs two (vel[0] = loc[1] - loc[0]): export nri \
             needs scenarios of 2 frames or more",
            dataset.display()
        )));
    }
    if !valid_suffix(&options.suffix) {
        return Err(Error::Input(format!(
            "--suffix {:?}: a suffix is part of a file name: letters, digits, '-', '_' and '.' only, no '..' \
             (e.g. _airsim_final)",
            options.suffix
        )));
    }
    let _claim = claim(out, Writer::Export, &format!("export nri {}", dataset.display()))?;
    refuse_earlier_export(&opened, out, options)?;
    // All or nothing: a failure part way (a scenario gone from the
    // dataset) leaves an earlier export as it was, never this export's
    // first splits beside an earlier one's others.
    let mut written = Vec::new();
    let (folders, damage) = (super::NewFolders::default(), super::Damage::default());
    let report = export_nri_groups(&opened, out, options, &mut written, (&folders, &damage));
    let commit = report.and_then(|report| {
        for path in &written {
            std::fs::rename(staged(path), path).map_err(|e| format!("cannot write {}: {e}", path.display()))?;
        }
        Ok(report)
    });
    if commit.is_err() {
        for path in &written {
            let _ = std::fs::remove_file(staged(path));
        }
        folders.remove();
    }
    commit.map_err(|e| damage.error(dataset, e))
}

/// The files this export writes, relative to `out`: an NRI loader reads a
/// group's splits as one set, so anything else there is refused.
fn refuse_earlier_export(opened: &Dataset, out: &Path, options: &NriOptions) -> Result<(), Error> {
    let mut kinds = vec!["loc", "vel", "edges"];
    if options.dynamic {
        kinds.push("dynamic_edges");
    }
    let mut writes = std::collections::BTreeSet::new();
    for key in opened.keys() {
        for kind in &kinds {
            let file =
                Path::new(&key.group).join(format!("{kind}_{}{}.npy", nri_split_name(key.split), options.suffix));
            // With what a cut-off run of it staged.
            writes.insert(staged(&file));
            writes.insert(file);
        }
    }
    super::refuse_earlier_export(out, 2, &writes, "a file")
}

/// Whether `suffix` keeps every file it names inside its group folder.
fn valid_suffix(suffix: &str) -> bool {
    suffix.len() <= 64
        && !suffix.contains("..")
        && suffix.chars().all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
}

/// Writes every group's and split's files at their [`staged`] paths,
/// listing each in `written` as it is begun and each folder it makes in
/// `folders`.
fn export_nri_groups(
    opened: &Dataset,
    out: &Path,
    options: &NriOptions,
    written: &mut Vec<PathBuf>,
    (folders, damage): (&super::NewFolders, &super::Damage),
) -> Result<Vec<String>, String> {
    let frames = opened.spec().frames as usize;
    let image = (opened.spec().image.width as f32, opened.spec().image.height as f32);
    let mut report = Vec::new();
    for group in &opened.spec().groups {
        let group_dir: PathBuf = out.join(group.name());
        folders.create(&group_dir)?;
        for split in Split::ALL {
            // A split that holds the car count out has its own.
            let cars = opened.spec().group_of(split, group).cars as usize;
            let dirs = damage.note_reading(opened.scenario_dirs(&group.name(), split))?;
            if dirs.is_empty() {
                // Said, not silent: NRI's loaders read all three splits.
                report.push(format!(
                    "{}: {} 0 scenarios (the dataset's {} split is empty): no *_{}{}.npy written, which NRI's \
                     loaders expect",
                    group_dir.display(),
                    nri_split_name(split),
                    split.name(),
                    nri_split_name(split),
                    options.suffix
                ));
                continue;
            }
            let s = dirs.len();
            let block = frames * cars * 2;
            let at = || format!("{} {}", group_dir.display(), split.name());
            let (mut loc, mut vel) = (zeroed::<f32>(s, block, &at)?, zeroed::<f32>(s, block, &at)?);
            let mut edges = zeroed::<i64>(s, cars * cars, &at)?;
            // Without `dynamic`, a placeholder byte per scenario keeps the zip even.
            let graphs = if options.dynamic { frames * cars * cars } else { 1 };
            let mut dynamic = zeroed::<u8>(s, graphs, &at)?;
            loc.par_chunks_mut(block)
                .zip(vel.par_chunks_mut(block))
                .zip(edges.par_chunks_mut(cars * cars))
                .zip(dynamic.par_chunks_mut(graphs))
                .zip(dirs.par_iter())
                .try_for_each(|((((loc, vel), edges), dynamic), dir)| {
                    damage.note(fill_scenario(dir, (frames, cars), image, options, (loc, vel, edges, dynamic)))
                })
                .map_err(|e| opened.name_packed_paths(e))?;
            opened.release(&group.name(), split)?;
            let (f, c) = (frames as u64, cars as u64);
            let loc_shape = match options.layout {
                NriLayout::Causalcity => [s as u64, f, c, 2],
                NriLayout::Nri => [s as u64, f, 2, c],
            };
            let name = |kind: &str| group_dir.join(format!("{kind}_{}{}.npy", nri_split_name(split), options.suffix));
            written.extend(["loc", "vel", "edges"].map(name));
            if options.dynamic {
                written.push(name("dynamic_edges"));
            }
            let (wrote_loc, (wrote_vel, wrote_edges)) = rayon::join(
                || write_npy(&name("loc"), &loc_shape, &loc),
                || {
                    rayon::join(
                        || write_npy(&name("vel"), &loc_shape, &vel),
                        || write_npy(&name("edges"), &[s as u64, c, c], &edges),
                    )
                },
            );
            wrote_loc.and(wrote_vel).and(wrote_edges)?;
            if options.dynamic {
                write_npy(&name("dynamic_edges"), &[s as u64, f, c, c], &dynamic)?;
            }
            report.push(format!(
                "{}: {} {} scenarios, loc/vel {:?}{}",
                group_dir.display(),
                nri_split_name(split),
                s,
                loc_shape,
                if options.dynamic { format!(", dynamic_edges {:?}", [s as u64, f, c, c]) } else { String::new() }
            ));
        }
    }
    Ok(report)
}

/// `scenarios` x `each` zeros, or an error naming `at` where memory cannot
/// hold them (a manifest edited to claim more scenarios, frames or cars
/// than its files hold aborted the export before a scenario was read).
fn zeroed<T: Clone + Default>(scenarios: usize, each: usize, at: &dyn Fn() -> String) -> Result<Vec<T>, String> {
    let too_many = || {
        let bytes = (scenarios as f64) * (each as f64) * std::mem::size_of::<T>() as f64;
        format!("{}: {scenarios} scenarios of {each} values each ({bytes:.3e} bytes) are more than memory holds", at())
    };
    let n = scenarios.checked_mul(each).ok_or_else(too_many)?;
    let mut values = Vec::new();
    values.try_reserve_exact(n).map_err(|_| too_many())?;
    values.resize(n, T::default());
    Ok(values)
}
