//! `causalcity export vcdn`: one HDF5 file per scenario,
//! `<out>/<group>/<split>/<scenario>.h5`, as the original's V-CDN converter
//! produced (T frames, N cars, pixel units, float32):
//! - `attrs` [T, N, 1]: object type, 1 for every car;
//! - `states` [T, N, 4]: x, y, vx, vy, with v[t] = p[t] - p[t-1] and
//!   v[0] = v[1] (as in `export nri`);
//! - `actions` [T, N, 2]: the second difference a[t] = v[t] - v[t-1], a[0] = 0;
//! - `rels` [T, N(N-1)/2, 2]: per pair (i, j), i < j in row order
//!   (0,1), (0,2), ..., (1,2), ...: the link flag (1 when either leads the
//!   other) and the pair's mean distance over the scenario in pixels, the
//!   same in every frame;
//! - `edges` [E, 2] int64: (leader, follower) ids, for directed use.
//!
//! HDF5 needs the system library, so this export is behind the `hdf5` cargo
//! feature (`make` installs the library and turns it on).

use crate::dataset::{Dataset, GraphKind, PoseLog, ScenarioSummary};
use crate::error::Error;
use crate::progress::{Progress, ProgressMode};
use std::path::{Path, PathBuf};

/// The arrays of one scenario's V-CDN file, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct VcdnArrays {
    pub frames: usize,
    pub cars: usize,
    pub attrs: Vec<f32>,
    pub states: Vec<f32>,
    pub actions: Vec<f32>,
    pub rels: Vec<f32>,
    pub edges: Vec<i64>,
}

/// Builds the V-CDN arrays of the scenario in `dir`, linking the pairs of
/// `graph`.
pub fn vcdn_arrays(dir: &Path, graph: GraphKind) -> Result<VcdnArrays, String> {
    let scenario = ScenarioSummary::read_graph(dir, graph)?;
    let (t_count, n) = (scenario.frames as usize, scenario.cars.len());
    let poses = PoseLog::read(dir, t_count, n)?;
    let position = |t: usize, car: usize| {
        let p = poses.at(t, car);
        [p.px, p.py]
    };
    let velocity = |t: usize, car: usize| -> [f64; 2] {
        let t = if t == 0 { 1.min(t_count - 1) } else { t };
        if t == 0 {
            return [0.0, 0.0];
        }
        let (a, b) = (position(t, car), position(t - 1, car));
        [a[0] - b[0], a[1] - b[1]]
    };
    let mut states = Vec::with_capacity(t_count * n * 4);
    let mut actions = Vec::with_capacity(t_count * n * 2);
    for t in 0..t_count {
        for car in 0..n {
            let (p, v) = (position(t, car), velocity(t, car));
            states.extend([p[0] as f32, p[1] as f32, v[0] as f32, v[1] as f32]);
            let a = if t == 0 {
                [0.0, 0.0]
            } else {
                let before = velocity(t - 1, car);
                [v[0] - before[0], v[1] - before[1]]
            };
            actions.extend([a[0] as f32, a[1] as f32]);
        }
    }
    let mut pair_values = Vec::new();
    for i in 0..n {
        for j in i + 1..n {
            let linked = scenario.graph.iter().any(|e| {
                let (l, f) = (e[0] as usize, e[1] as usize);
                (l, f) == (i, j) || (l, f) == (j, i)
            });
            let mean_distance = (0..t_count)
                .map(|t| {
                    let (a, b) = (position(t, i), position(t, j));
                    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()
                })
                .sum::<f64>()
                / t_count.max(1) as f64;
            pair_values.push([linked as u8 as f32, mean_distance as f32]);
        }
    }
    let rels = (0..t_count).flat_map(|_| pair_values.iter().flatten().copied()).collect();
    Ok(VcdnArrays {
        frames: t_count,
        cars: n,
        attrs: vec![1.0; t_count * n],
        states,
        actions,
        rels,
        edges: scenario.graph.iter().flat_map(|e| [e[0] as i64, e[1] as i64]).collect(),
    })
}

/// Exports every scenario of `dataset` into `out`, linking the pairs of
/// `graph`; returns how many files were written.
pub fn export_vcdn(dataset: &Path, out: &Path, graph: GraphKind, progress: ProgressMode) -> Result<usize, Error> {
    let opened = Dataset::open_complete(dataset).map_err(Error::opening)?;
    opened.require_graph(graph).map_err(Error::Input)?;
    if !cfg!(feature = "hdf5") {
        return Err(Error::Failure(NO_HDF5.into()));
    }
    let _claim = crate::output::claim::claim(
        out,
        crate::output::claim::Writer::Export,
        &format!("export vcdn {}", dataset.display()),
    )?;
    // Its scenario files, and their partial writes a cut-off run left.
    let writes = opened
        .keys()
        .flat_map(|k| ["h5", "h5.partial"].map(|ext| PathBuf::from(k.relative_folder()).with_extension(ext)))
        .collect();
    super::refuse_earlier_export(out, 3, &writes, "a scenario file")?;
    let bar = Progress::new(opened.key_sequence().len() as u64, progress);
    // A split at a time: a packed dataset holds one split in TMPDIR.
    let folders = super::NewFolders::default();
    let damage = super::Damage::default();
    let exported = opened.each_scenario_in_turn(
        |e| damage.note_unreadable(e),
        |source, relative| {
            let target = out.join(relative).with_extension("h5");
            let arrays = damage.note(vcdn_arrays(source, graph))?;
            folders.create(target.parent().expect("files have a folder"))?;
            let partial = target.with_extension("h5.partial");
            let written = write_hdf5(&partial, &arrays)
                .and_then(|()| std::fs::rename(&partial, &target).map_err(|e| e.to_string()))
                .map_err(|e| format!("cannot write {}: {e}", target.display()));
            if written.is_err() {
                let _ = std::fs::remove_file(&partial);
            }
            written?;
            bar.inc();
            Ok(())
        },
    );
    if let Err(e) = exported {
        // The files this run added go again with their folders.
        folders.remove();
        return Err(damage.error(dataset, e));
    }
    bar.finish();
    Ok(opened.key_sequence().len())
}

const NO_HDF5: &str = "this causalcity was built without HDF5, which V-CDN export needs: \
     install the HDF5 library (Debian/Ubuntu: apt-get install libhdf5-dev) and rebuild with \
     `cargo build --release --features hdf5` (make does both)";

#[cfg(feature = "hdf5")]
fn write_hdf5(path: &Path, a: &VcdnArrays) -> Result<(), String> {
    let (t, n) = (a.frames, a.cars);
    let pairs = n * n.saturating_sub(1) / 2;
    let err = |e: hdf5::Error| e.to_string();
    let file = hdf5::File::create(path).map_err(err)?;
    let put = |name: &str, shape: &[usize], data: &[f32]| -> Result<(), String> {
        file.new_dataset::<f32>().shape(shape).create(name).map_err(err)?.write_raw(data).map_err(err)
    };
    put("attrs", &[t, n, 1], &a.attrs)?;
    put("states", &[t, n, 4], &a.states)?;
    put("actions", &[t, n, 2], &a.actions)?;
    put("rels", &[t, pairs, 2], &a.rels)?;
    file.new_dataset::<i64>()
        .shape([a.edges.len() / 2, 2])
        .create("edges")
        .map_err(err)?
        .write_raw(&a.edges)
        .map_err(err)?;
    file.close().map_err(err)
}

#[cfg(not(feature = "hdf5"))]
fn write_hdf5(_path: &Path, _arrays: &VcdnArrays) -> Result<(), String> {
    Err(NO_HDF5.into())
}
