//! `causalcity._native`: the Rust side of the Python package. It hands the
//! library's in-memory scenarios ([`causalcity::output::arrays`]) to Python
//! without copying them: every array is an [`Array`] that numpy wraps
//! through `__array_interface__`. The GIL is released while Rust works:
//! streams generate ahead on worker threads of their own
//! ([`causalcity::orchestrate::in_memory::Prefetch`]), `generate` and
//! `counterfactual` on rayon's. The public API (docstrings, types) lives
//! in `causalcity/__init__.py`.

use causalcity::analysis::baseline::pair_following_scores;
use causalcity::analysis::evaluate::{evaluate as evaluate_, DatasetIdentity, EvaluateOptions};
use causalcity::dataset::readback::{read_frames as read_frames_, read_scenario as read_scenario_};
use causalcity::dataset::GraphKind;
use causalcity::error::Error;
use causalcity::orchestrate::in_memory::{counterfactual_arrays, parse_split, Generator, PairArrays, Text};
use causalcity::orchestrate::in_memory::{Prefetch as Prefetch_, Waited};
use causalcity::orchestrate::run::{
    clear_stop, generate_expansion, load_spec, request_stop, GenError, GenOptions, Shard, MAX_THREADS,
};
use causalcity::output;
use causalcity::output::arrays::{batch_frame_buffer, recycle_frame_buffer, ScenarioArrays, LIGHT_COLOURS};
use causalcity::output::claim::{claim_file, resolve, FileKind};
use causalcity::output::layout::FrameKind;
use causalcity::plan::{Expansion, ScenarioKey};
use causalcity::progress::ProgressMode;
use causalcity::spec::{network_file_name, DatasetSpec};
use causalcity::world::effects::{EffectRow, InterventionKind};
use causalcity::world::BoundBy;
use pyo3::exceptions::{PyMemoryError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList, PyTuple};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

// Named causalcity.InputError / causalcity.GenerationError in tracebacks,
// as users import them (the package re-exports both).
pyo3::create_exception!(
    causalcity,
    InputError,
    PyValueError,
    "Bad input (a spec, scenario or intervention file, a key): the message names the file, field and value, as the command line's exit-status-2 errors do."
);
pyo3::create_exception!(
    causalcity,
    GenerationError,
    PyRuntimeError,
    "A failure while working (a full disk, a failed write), as the command line's exit-status-1 errors."
);

/// The library's one error, as the Python exception of its kind.
fn py_err(e: impl Into<Error>) -> PyErr {
    match e.into() {
        Error::Input(m) => InputError::new_err(m),
        Error::Failure(m) | Error::Interrupted(m) => GenerationError::new_err(m),
        Error::Memory(m) => PyMemoryError::new_err(m),
    }
}

/// How often a call that works on threads of its own looks for Ctrl-C.
const SIGNAL_POLL: Duration = Duration::from_millis(50);

/// Runs `work` on a thread of its own, without the GIL, while this thread
/// answers Ctrl-C: Python's signal handlers run every [`SIGNAL_POLL`], and
/// when one raises (KeyboardInterrupt), `on_signal` asks the work to stop,
/// the work is waited for (it gives up at its next frame) and the
/// handler's exception is raised. Without this, a KeyboardInterrupt would
/// wait until the whole call had finished.
fn interruptible<T: Send>(py: Python<'_>, on_signal: impl Fn() + Sync, work: impl FnOnce() -> T + Send) -> PyResult<T> {
    let on_signal = &on_signal;
    let (value, signal) = py.detach(|| {
        std::thread::scope(|scope| {
            let (send, receive) = std::sync::mpsc::channel();
            let worker = scope.spawn(move || {
                let _ = send.send(work());
            });
            let mut signal = None;
            let value = loop {
                match receive.recv_timeout(SIGNAL_POLL) {
                    Ok(value) => break Some(value),
                    Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => break None,
                    Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
                        if signal.is_none() {
                            if let Err(e) = Python::attach(|py| py.check_signals()) {
                                on_signal();
                                signal = Some(e);
                            }
                        }
                    }
                }
            };
            let _ = worker.join();
            (value, signal)
        })
    });
    match (signal, value) {
        (Some(e), _) => Err(e),
        (None, Some(value)) => Ok(value),
        (None, None) => {
            Err(GenerationError::new_err("internal error: the work panicked (please report it with the spec)"))
        }
    }
}

/// Typed values that numpy views without copying.
enum Data {
    U8(Vec<u8>),
    I16(Vec<i16>),
    I32(Vec<i32>),
    U32(Vec<u32>),
    F64(Vec<f64>),
}

impl Data {
    /// The values' address (taken mutably: numpy may write), numpy type and count.
    fn parts(&mut self) -> (usize, &'static str, usize) {
        match self {
            Data::U8(v) => (v.as_mut_ptr() as usize, "|u1", v.len()),
            Data::I16(v) => (v.as_mut_ptr() as usize, "<i2", v.len()),
            Data::I32(v) => (v.as_mut_ptr() as usize, "<i4", v.len()),
            Data::U32(v) => (v.as_mut_ptr() as usize, "<u4", v.len()),
            Data::F64(v) => (v.as_mut_ptr() as usize, "<f8", v.len()),
        }
    }
}

/// One array, owned by Rust and lent to numpy (`numpy.asarray(a)`), which
/// keeps this object alive as long as it views the values. The values never
/// move or change on the Rust side once lent.
#[pyclass(frozen, module = "causalcity._native")]
struct Array {
    data: Data,
    /// Where the values are, as numpy is told.
    address: usize,
    typestr: &'static str,
    shape: Vec<usize>,
}

impl Drop for Array {
    /// Frames go back to the library for the next scenario (bounded; see
    /// `causalcity::output::arrays::recycle_frame_buffer`).
    fn drop(&mut self) {
        if let Data::U8(values) = &mut self.data {
            recycle_frame_buffer(std::mem::take(values));
        }
    }
}

impl Array {
    /// An array of `shape`; an error (never an out-of-bounds view) when the
    /// values do not fill it exactly.
    fn new(mut data: Data, shape: &[usize]) -> PyResult<Array> {
        let (address, typestr, len) = data.parts();
        if len != shape.iter().product::<usize>() {
            return Err(GenerationError::new_err(format!(
                "internal error: {len} values for an array of shape {shape:?} (please report it)"
            )));
        }
        Ok(Array { data, address, typestr, shape: shape.to_vec() })
    }
}

#[pymethods]
impl Array {
    /// numpy's array interface (version 3): the values' address, type and shape.
    #[getter]
    fn __array_interface__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        d.set_item("version", 3)?;
        d.set_item("shape", PyTuple::new(py, &self.shape)?)?;
        d.set_item("typestr", self.typestr)?;
        d.set_item("data", (self.address, false))?;
        Ok(d)
    }
}

/// A checked, expanded dataset spec (see `causalcity.Spec`).
#[pyclass(frozen, module = "causalcity._native")]
struct Spec {
    generator: Arc<Generator>,
    /// The spec's JSON as read.
    json: String,
    /// The file it came from, if any.
    path: Option<PathBuf>,
    /// The folder its SUMO networks were read from by file name (a
    /// dataset's `networks/`), if not beside `path`.
    networks: Option<PathBuf>,
}

impl Spec {
    fn expansion(&self) -> &Expansion {
        self.generator.expansion()
    }
}

#[pymethods]
impl Spec {
    /// The road network of one town (the first when `town` is None) as
    /// JSON: `causalcity map --json`'s town, towns, junctions and lanes.
    #[pyo3(signature = (town=None))]
    fn map_json(&self, town: Option<String>) -> PyResult<String> {
        let towns = self.expansion().towns();
        let names: Vec<String> = self.expansion().all_town_names().into_iter().map(String::from).collect();
        let shown = match &town {
            None => &towns[0],
            Some(name) => towns.iter().find(|t| &t.name == name).ok_or_else(|| {
                InputError::new_err(format!(
                    "town {name:?}: the spec draws no such town: use one of {}",
                    names.join(", ")
                ))
            })?,
        };
        let summary = causalcity::map_view::MapSummary {
            town: shown.name.clone(),
            towns: names,
            ..causalcity::map_view::map_summary(&shown.map)
        };
        serde_json::to_string(&summary).map_err(|e| GenerationError::new_err(e.to_string()))
    }

    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<Spec> {
        match std::fs::read_to_string(&path) {
            Ok(text) => Spec::from_json(py, text, path.clone(), Some(path), None, false),
            // The command line's message for a file it cannot read.
            Err(_) => Err(py_err(
                py.detach(|| load_spec(&path))
                    .err()
                    .unwrap_or_else(|| GenError::Manifest(format!("cannot read spec file {}", path.display()))),
            )),
        }
    }

    /// A spec from its JSON; errors name `origin`; `path` is the file it
    /// came from, if any; `networks` the folder that keeps the SUMO
    /// networks it names by file name (a dataset's `networks/`); `written`:
    /// a dataset's own spec, read to read the dataset, which the gen that
    /// wrote it checked (fewer trial plans: `Expansion::from_written_spec`).
    #[staticmethod]
    #[pyo3(signature = (text, origin, path=None, networks=None, written=false))]
    fn from_json(
        py: Python<'_>,
        text: String,
        origin: PathBuf,
        path: Option<PathBuf>,
        networks: Option<PathBuf>,
        written: bool,
    ) -> PyResult<Spec> {
        let expansion = py
            .detach(|| {
                let spec_err = |error| GenError::Spec { path: origin.clone(), error };
                let mut spec = DatasetSpec::from_json(&text).map_err(spec_err)?;
                // A SUMO network the spec names: in a dataset's folder, beside
                // the spec's file, or from the working folder.
                match (&networks, &path) {
                    (Some(folder), _) => spec.read_networks(|sumo| folder.join(network_file_name(sumo))),
                    (None, Some(file)) => spec.read_networks_beside(file),
                    (None, None) => spec.read_networks(|sumo| PathBuf::from(sumo)),
                }
                .map_err(spec_err)?;
                if written { Expansion::from_written_spec(spec) } else { Expansion::from_spec(spec) }.map_err(spec_err)
            })
            .map_err(py_err)?;
        Ok(Spec { generator: Arc::new(Generator::new(expansion)), json: text, path, networks })
    }

    #[getter]
    fn name(&self) -> String {
        self.expansion().spec.name.clone()
    }

    #[getter]
    fn world(&self) -> &'static str {
        self.expansion().spec.world.name()
    }

    #[getter]
    fn seed(&self) -> u64 {
        self.expansion().spec.seed
    }

    #[getter]
    fn frames(&self) -> u32 {
        self.expansion().spec.frames
    }

    #[getter]
    fn frame_interval(&self) -> f64 {
        self.expansion().spec.frame_interval()
    }

    #[getter]
    fn image_size(&self) -> (u32, u32) {
        (self.expansion().camera.width, self.expansion().camera.height)
    }

    #[getter]
    fn groups(&self) -> Vec<String> {
        self.expansion().spec.groups.iter().map(|g| g.name()).collect()
    }

    #[getter]
    fn splits(&self) -> Vec<(&'static str, u32)> {
        let splits = &self.expansion().spec.splits;
        causalcity::spec::Split::ALL.iter().map(|&s| (s.name(), splits.count(s))).collect()
    }

    #[getter]
    fn json(&self) -> &str {
        &self.json
    }

    /// SHA-256 (hex) of the spec as a manifest's `spec_sha256` records it.
    #[getter]
    fn sha256(&self) -> String {
        causalcity::output::manifest::spec_sha256(&self.expansion().spec)
    }

    #[getter]
    fn path(&self) -> Option<String> {
        self.path.as_ref().map(|p| p.to_string_lossy().into_owned())
    }

    #[getter]
    fn networks(&self) -> Option<String> {
        self.networks.as_ref().map(|p| p.to_string_lossy().into_owned())
    }

    /// (group, split, index) of every scenario of `split` (all when None), at
    /// most `limit` per split and group, in the order `gen` numbers them.
    #[pyo3(signature = (split=None, limit=None))]
    fn keys(&self, split: Option<&str>, limit: Option<u32>) -> PyResult<Vec<(String, &'static str, u32)>> {
        let split = split.map(parse_split).transpose().map_err(|e| InputError::new_err(e.0))?;
        Ok(self.generator.keys(split, limit).into_iter().map(|k| (k.group, k.split.name(), k.index)).collect())
    }
}

fn key_of(spec: &Spec, (group, split, index): (String, String, u32)) -> PyResult<ScenarioKey> {
    spec.generator.key(&group, &split, index).map_err(|e| InputError::new_err(e.0))
}

/// One scenario of `spec` as a dict of arrays (see `causalcity.Scenario`).
#[pyfunction]
#[pyo3(signature = (spec, group, split, index, images=false, effects=true))]
fn simulate<'py>(
    py: Python<'py>,
    spec: &Spec,
    group: String,
    split: String,
    index: u32,
    images: bool,
    effects: bool,
) -> PyResult<Bound<'py, PyDict>> {
    let key = key_of(spec, (group, split, index))?;
    let generator = spec.generator.clone();
    let stop = AtomicBool::new(false);
    let work = || generator.scenario_until(&key, images, effects, &stop);
    let arrays = interruptible(py, || stop.store(true, Ordering::SeqCst), work)?.map_err(py_err)?;
    scenario_dict(py, arrays)
}

/// A scenario folder `gen` or `counterfactual` wrote, read back as the
/// dict [`simulate`] gives (without frames: see [`read_frames`]).
/// Checks the counterfactual pair in `dir`, read as `(group, split,
/// index)` of its sweep, by the rule every reader of a sweep holds
/// (`causalcity::dataset::pairs`), and, given the sweep's `spec` and
/// `kinds`, that its summary records the intervention the sweep draws for
/// it (`causalcity::dataset::check_drawn`): `InputError` naming the file
/// otherwise.
#[pyfunction]
#[pyo3(signature = (dir, group, split, index, spec=None, kinds=None))]
fn check_pair(
    py: Python<'_>,
    dir: PathBuf,
    group: String,
    split: String,
    index: u64,
    spec: Option<&Spec>,
    kinds: Option<Vec<String>>,
) -> PyResult<()> {
    let key = match spec {
        Some(spec) => {
            let at = u32::try_from(index).map_err(|_| InputError::new_err(format!("index {index} is no pair's")))?;
            Some(key_of(spec, (group.clone(), split.clone(), at))?)
        }
        None => None,
    };
    // Given the spec, the kinds must be given too (a sweep.json without
    // them was edited): none names no draw.
    let kinds = kinds.unwrap_or_default();
    py.detach(|| {
        let summary = causalcity::dataset::pairs::check_pair(&dir, (&group, &split, index))?;
        if let (Some(spec), Some(key)) = (spec, &key) {
            causalcity::dataset::check_drawn(spec.expansion(), &kinds, key, &summary)
                .map_err(|e| format!("{}: {e}", dir.join("summary.json").display()))?;
        }
        Ok::<(), String>(())
    })
    .map_err(InputError::new_err)
}

#[pyfunction]
fn read_scenario(py: Python<'_>, dir: PathBuf) -> PyResult<Bound<'_, PyDict>> {
    let arrays = py.detach(|| read_scenario_(&dir)).map_err(InputError::new_err)?;
    scenario_dict(py, arrays)
}

/// Frames `start..end` of a scenario folder of `frames` frames of
/// `width` x `height`, decoded from its PNGs: `kind` "rgb" gives
/// `[n, height, width, 3]` uint8, "mask" `[n, height, width]`.
#[pyfunction]
#[allow(clippy::too_many_arguments)] // the folder, the kind and the frames' range and size, each once
fn read_frames<'py>(
    py: Python<'py>,
    dir: PathBuf,
    kind: &str,
    frames: u32,
    start: u32,
    end: u32,
    width: u32,
    height: u32,
) -> PyResult<Bound<'py, Array>> {
    let (kind, channels) = match kind {
        "rgb" => (FrameKind::Rgb, 3),
        "mask" => (FrameKind::Mask, 1),
        other => return Err(InputError::new_err(format!("frame kind {other:?} is not rgb or mask"))),
    };
    let bytes =
        py.detach(|| read_frames_(&dir, kind, frames, (start, end), (width, height))).map_err(InputError::new_err)?;
    let mut shape = vec![end.saturating_sub(start) as usize, height as usize, width as usize];
    if channels == 3 {
        shape.push(3);
    }
    array(py, Data::U8(bytes), &shape)
}

/// Scenarios of `spec` generated ahead on `threads` worker threads, yielded
/// in the order of `keys` (see `causalcity.stream`).
#[pyclass(frozen, module = "causalcity._native")]
struct Prefetch {
    inner: Prefetch_,
}

#[pymethods]
impl Prefetch {
    /// With `batches` (lengths summing to the keys'), frames come as one
    /// array per batch (`batch_rgb`, `batch_mask`) with its last scenario.
    #[new]
    #[pyo3(signature = (spec, keys, images=false, effects=true, threads=None, ahead=None, batches=None))]
    fn new(
        spec: &Spec,
        keys: Vec<(String, String, u32)>,
        images: bool,
        effects: bool,
        threads: Option<usize>,
        ahead: Option<usize>,
        batches: Option<Vec<usize>>,
    ) -> PyResult<Prefetch> {
        if let Some(lengths) = &batches {
            if lengths.iter().sum::<usize>() != keys.len() || lengths.contains(&0) {
                return Err(InputError::new_err("batches: lengths from 1 up that add up to the number of keys"));
            }
        }
        let keys: Vec<ScenarioKey> = keys.into_iter().map(|k| key_of(spec, k)).collect::<PyResult<_>>()?;
        let threads = threads
            .filter(|&t| t > 0)
            .unwrap_or_else(|| std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1));
        let ahead = ahead.unwrap_or(threads + 1);
        let generator = spec.generator.clone();
        Ok(Prefetch { inner: Prefetch_::start(generator, keys, images, effects, threads, ahead, batches) })
    }

    fn __iter__(slf: Bound<'_, Self>) -> Bound<'_, Self> {
        slf
    }

    fn __next__<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        loop {
            match py.detach(|| self.inner.next_within(SIGNAL_POLL)) {
                Waited::Done => return Ok(None),
                Waited::Ready(result) => return scenario_dict(py, (*result).map_err(py_err)?).map(Some),
                // Ctrl-C while waiting raises here; the workers stop when the stream is dropped.
                Waited::Pending => py.check_signals()?,
            }
        }
    }
}

/// `causalcity counterfactual` into memory: one dict per scenario of the file.
#[pyfunction]
#[pyo3(signature = (scenario_text, scenario_origin, intervention_text=None, intervention_origin=None, images=false))]
fn counterfactual<'py>(
    py: Python<'py>,
    scenario_text: String,
    scenario_origin: PathBuf,
    intervention_text: Option<String>,
    intervention_origin: Option<PathBuf>,
    images: bool,
) -> PyResult<Bound<'py, PyList>> {
    let intervention_origin = intervention_origin.unwrap_or_else(|| PathBuf::from("<intervention>"));
    let stop = AtomicBool::new(false);
    let work = || {
        let scenarios = Text { origin: &scenario_origin, text: &scenario_text };
        let interventions = intervention_text.as_deref().map(|text| Text { origin: &intervention_origin, text });
        counterfactual_arrays(scenarios, interventions, images, &stop)
    };
    let pairs = interruptible(py, || stop.store(true, Ordering::SeqCst), work)?.map_err(py_err)?;
    let list = PyList::empty(py);
    for pair in pairs {
        list.append(pair_dict(py, pair)?)?;
    }
    Ok(list)
}

/// `causalcity gen` from Python: the run's summary as JSON text.
#[pyfunction]
#[pyo3(signature = (spec, out, limit=None, threads=None, images=true, annotations=false, effects=true, shard=None, force=false, fsync=false, progress=true, force_space=false, lights="changes", scenarios_per_tar=None))]
#[allow(clippy::too_many_arguments)]
fn generate(
    py: Python<'_>,
    spec: &Spec,
    out: Option<PathBuf>,
    limit: Option<u32>,
    threads: Option<usize>,
    images: bool,
    annotations: bool,
    effects: bool,
    shard: Option<String>,
    force: bool,
    fsync: bool,
    progress: bool,
    force_space: bool,
    lights: &str,
    scenarios_per_tar: Option<u32>,
) -> PyResult<String> {
    let lights = match lights {
        "frames" => causalcity::output::manifest::LightsLog::Frames,
        "changes" => causalcity::output::manifest::LightsLog::Changes,
        other => return Err(InputError::new_err(format!("lights: {other:?} is not \"frames\" or \"changes\""))),
    };
    let shard: Option<Shard> =
        shard.map(|s| s.parse()).transpose().map_err(|e: String| InputError::new_err(format!("shard: {e}")))?;
    let options = GenOptions {
        spec_path: spec.path.clone().unwrap_or_else(|| PathBuf::from("<dict>")),
        out,
        limit,
        threads,
        images,
        annotations,
        effects,
        lights,
        packing: match scenarios_per_tar {
            None => causalcity::output::manifest::Packing::Folders,
            Some(per_tar) => causalcity::output::manifest::Packing::Tar { per_tar: per_tar.max(1) },
        },
        progress: if progress { ProgressMode::Auto } else { ProgressMode::Quiet },
        shard,
        force,
        force_space,
        fsync,
        handle_signals: false,
    };
    let generator = spec.generator.clone();
    // Ctrl-C stops the run as it stops `gen`: every worker gives up at its
    // next frame, what is complete stays, and the same call resumes.
    let work = || generate_expansion(generator.expansion(), &options, Instant::now());
    let result = interruptible(py, request_stop, work);
    clear_stop();
    let summary = result?.map_err(py_err)?;
    serde_json::to_string(&summary).map_err(|e| GenerationError::new_err(e.to_string()))
}

/// Checks by the one write rule (never inside a dataset or sweep, never
/// onto an input, never through a link, never over a file of another kind)
/// that a file holding `writes` ("zip", "png", "json" or "text") may be
/// written at `path`; `inputs` are (what, path) of what the caller reads.
#[pyfunction]
#[pyo3(signature = (path, inputs=Vec::new(), writes="zip"))]
fn claim_output(path: PathBuf, inputs: Vec<(String, PathBuf)>, writes: &str) -> PyResult<()> {
    let inputs: Vec<(&str, &Path)> = inputs.iter().map(|(what, p)| (what.as_str(), p.as_path())).collect();
    let writes = match writes {
        "zip" => FileKind::Zip,
        "png" => FileKind::Png,
        "json" => FileKind::Json,
        "text" => FileKind::Text,
        other => return Err(InputError::new_err(format!("writes={other:?}: use zip, png, json or text"))),
    };
    claim_file(&path, &inputs, writes).map_err(py_err)?;
    Ok(())
}

/// The write rule below an output folder `root` that a caller fills with
/// folders of its own: refuses (`InputError`) a symbolic link at any of
/// `paths` or on the way to it from `root`, as `gen` does below `--out`.
#[pyfunction]
fn refuse_links_below(root: PathBuf, paths: Vec<PathBuf>) -> PyResult<()> {
    for path in &paths {
        output::refuse_links_below(&root, path).map_err(|e| InputError::new_err(e.to_string()))?;
    }
    Ok(())
}

/// The record of the dataset (or sweep) in `dir` that a predictions file
/// carries, as JSON text (see `evaluate`'s `DATASET_RECORD`).
#[pyfunction]
fn dataset_identity(dir: PathBuf) -> PyResult<String> {
    let identity = DatasetIdentity::of(&dir).map_err(InputError::new_err)?;
    serde_json::to_string(&identity).map_err(|e| GenerationError::new_err(e.to_string()))
}

/// Writes `data` to `path` by the one write rule, through a temporary file
/// and a rename.
#[pyfunction]
fn write_output(py: Python<'_>, path: PathBuf, data: Vec<u8>) -> PyResult<()> {
    let file = claim_file(&path, &[], FileKind::of(&data[..data.len().min(4096)])).map_err(py_err)?;
    py.detach(|| file.write(&data)).map_err(|e| GenerationError::new_err(e.to_string()))
}

/// `causalcity evaluate` from Python: the report as JSON text and as CSV
/// (also written to `csv`, checked before scoring as `--csv` is).
#[pyfunction]
#[pyo3(signature = (dataset, predictions, graphs, history, threshold=None, csv=None, per_scenario=None))]
#[allow(clippy::too_many_arguments)] // evaluate's flags, each once
fn evaluate(
    py: Python<'_>,
    dataset: PathBuf,
    predictions: PathBuf,
    graphs: Vec<String>,
    history: usize,
    threshold: Option<f64>,
    csv: Option<PathBuf>,
    per_scenario: Option<PathBuf>,
) -> PyResult<(String, String, String)> {
    let inputs = [("the dataset it scores", dataset.as_path()), ("the predictions file", predictions.as_path())];
    if csv.is_some() && csv.as_deref().map(resolve) == per_scenario.as_deref().map(resolve) {
        return Err(InputError::new_err("csv and per_scenario name the same file: give each table its own file"));
    }
    use causalcity::analysis::evaluate::{PER_SCENARIO_CSV, TABLE_CSV};
    let claim = |kind| move |path: PathBuf| claim_file(&path, &inputs, kind);
    let csv = csv.map(claim(TABLE_CSV)).transpose().map_err(py_err)?;
    let per_scenario = per_scenario.map(claim(PER_SCENARIO_CSV)).transpose().map_err(py_err)?;
    let mut kinds: Vec<GraphKind> = Vec::new();
    for name in &graphs {
        let Some(kind) = GraphKind::ALL.into_iter().find(|k| k.name() == name) else {
            return Err(InputError::new_err(format!("graph {name:?} is not one of designed, causal, direct")));
        };
        if !kinds.contains(&kind) {
            kinds.push(kind);
        }
    }
    let options = EvaluateOptions { graphs: kinds, history, threshold };
    let report = py.detach(|| evaluate_(&dataset, &predictions, &options)).map_err(py_err)?;
    let json = serde_json::to_string(&report).map_err(|e| GenerationError::new_err(e.to_string()))?;
    let table = report.to_csv();
    if let Some(csv) = csv {
        csv.write(table.as_bytes()).map_err(|e| GenerationError::new_err(e.to_string()))?;
    }
    let scenarios = report.per_scenario_csv();
    if let Some(file) = per_scenario {
        file.write(scenarios.as_bytes()).map_err(|e| GenerationError::new_err(e.to_string()))?;
    }
    Ok((json, table, scenarios))
}

fn array<'py>(py: Python<'py>, data: Data, shape: &[usize]) -> PyResult<Bound<'py, Array>> {
    Bound::new(py, Array::new(data, shape)?)
}

/// A scenario's arrays as a dict (no copies: each array moves into an [`Array`]).
fn scenario_dict(py: Python<'_>, a: ScenarioArrays) -> PyResult<Bound<'_, PyDict>> {
    let (t, c) = (a.frames, a.cars);
    let d = PyDict::new(py);
    d.set_item("scenario_json", String::from_utf8_lossy(&a.scenario_json))?;
    d.set_item("car_names", a.car_names)?;
    d.set_item("car_ids", array(py, Data::U32(a.car_ids), &[c])?)?;
    d.set_item("t", array(py, Data::F64(a.t), &[t])?)?;
    d.set_item("position", array(py, Data::F64(a.position), &[t, c, 3])?)?;
    d.set_item("rotation", array(py, Data::F64(a.rotation), &[t, c, 3])?)?;
    d.set_item("pixels", array(py, Data::F64(a.pixels), &[t, c, 2])?)?;
    d.set_item("speed", array(py, Data::F64(a.speed), &[t, c])?)?;
    d.set_item("in_view", array(py, Data::U8(a.in_view), &[t, c])?)?;
    d.set_item("graph", array(py, Data::U8(a.graph), &[c, c])?)?;
    d.set_item("edges", a.edges.iter().map(|e| (e[0], e[1])).collect::<Vec<_>>())?;
    if let Some(rows) = a.effects {
        let n = rows.len();
        let ed = PyDict::new(py);
        ed.set_item("interventions", InterventionKind::ALL.map(|k| k.name()).to_vec())?;
        ed.set_item("cause", array(py, Data::U32(rows.iter().map(|r| r.cause).collect()), &[n])?)?;
        ed.set_item("effect", array(py, Data::U32(rows.iter().map(|r| r.effect).collect()), &[n])?)?;
        let kind = |r: &EffectRow| InterventionKind::ALL.iter().position(|&k| k == r.intervention).unwrap_or(0) as u8;
        ed.set_item("intervention", array(py, Data::U8(rows.iter().map(kind).collect()), &[n])?)?;
        let divergence = rows.iter().map(|r| r.max_divergence_m).collect();
        ed.set_item("max_divergence_m", array(py, Data::F64(divergence), &[n])?)?;
        let first = rows.iter().map(|r| r.first_frame.map_or(-1, |f| f.min(i32::MAX as u32) as i32)).collect();
        ed.set_item("first_frame", array(py, Data::I32(first), &[n])?)?;
        ed.set_item("direct", array(py, Data::U8(rows.iter().map(|r| r.direct as u8).collect()), &[n])?)?;
        d.set_item("effects", ed)?;
    }
    if let Some(lights) = a.lights {
        let l = lights.names.len();
        let ld = PyDict::new(py);
        ld.set_item("colour_names", LIGHT_COLOURS.map(|c| c.name()).to_vec())?;
        ld.set_item("names", lights.names)?;
        ld.set_item("colour", array(py, Data::U8(lights.colour), &[t, l])?)?;
        ld.set_item("since_change", array(py, Data::F64(lights.since_change), &[t, l])?)?;
        ld.set_item("head_pixels", array(py, Data::F64(lights.head_pixels), &[l, 2])?)?;
        d.set_item("lights", ld)?;
    }
    if let Some(i) = a.interactions {
        let id = PyDict::new(py);
        id.set_item("kinds", BoundBy::ALL.map(|b| b.name()).to_vec())?;
        id.set_item("bound_by", array(py, Data::U8(i.bound_by), &[t, c])?)?;
        id.set_item("other_car", array(py, Data::I16(i.other_car), &[t, c])?)?;
        id.set_item("light", array(py, Data::I16(i.light), &[t, c])?)?;
        d.set_item("interactions", id)?;
    }
    let events = PyList::empty(py);
    for e in a.events {
        events.append((e.frame, e.t, e.kind, e.car, e.other_car, e.light, e.detail))?;
    }
    d.set_item("events", events)?;
    if let Some(images) = a.images {
        let (h, w) = (images.height as usize, images.width as usize);
        d.set_item("rgb", array(py, Data::U8(images.rgb), &[t, h, w, 3])?)?;
        d.set_item("mask", array(py, Data::U8(images.mask), &[t, h, w])?)?;
    }
    if let Some(batch) = a.batch {
        let (h, w) = (batch.height as usize, batch.width as usize);
        let n = batch.mask.len() / (t * h * w).max(1);
        d.set_item("batch_rgb", array(py, Data::U8(batch.rgb), &[n, t, h, w, 3])?)?;
        d.set_item("batch_mask", array(py, Data::U8(batch.mask), &[n, t, h, w])?)?;
    }
    Ok(d)
}

fn pair_dict(py: Python<'_>, p: PairArrays) -> PyResult<Bound<'_, PyDict>> {
    let d = PyDict::new(py);
    let (t, c) = (p.factual.frames, p.factual.cars);
    d.set_item("name", p.name)?;
    d.set_item("summary", serde_json::to_string(&p.summary).map_err(|e| GenerationError::new_err(e.to_string()))?)?;
    d.set_item("divergence", array(py, Data::F64(p.divergence_m), &[t, c])?)?;
    d.set_item("factual", scenario_dict(py, p.factual)?)?;
    d.set_item("counterfactual", scenario_dict(py, p.counterfactual)?)?;
    Ok(d)
}

/// `causalcity baseline`'s following score for every ordered pair of every
/// scenario, at each of `lags` (frames), in one pass: `positions` is the
/// bytes of a C-order float64 array `[scenarios, frames, cars, 2]`
/// (metres); the result `[scenarios, lags, cars, cars]`, `[s, l, a, b]`
/// the mean distance from b to a's path over the last `lags[l]` frames
/// (small when b follows a; the diagonal 0). Runs on every core.
#[pyfunction]
fn following_scores<'py>(
    py: Python<'py>,
    positions: Vec<u8>,
    shape: (usize, usize, usize),
    lags: Vec<usize>,
) -> PyResult<Bound<'py, Array>> {
    let (scenarios, frames, cars) = shape;
    let per_scenario = frames.checked_mul(cars).and_then(|n| n.checked_mul(2));
    if per_scenario.and_then(|n| n.checked_mul(scenarios)).and_then(|n| n.checked_mul(8)) != Some(positions.len()) {
        return Err(InputError::new_err(format!(
            "following_scores: {} bytes are not a float64 array of shape [{scenarios}, {frames}, {cars}, 2]",
            positions.len()
        )));
    }
    if lags.is_empty() || lags.contains(&0) {
        return Err(InputError::new_err(format!("following_scores: lags {lags:?} must be one or more, each >= 1")));
    }
    let xy: Vec<[f64; 2]> = positions
        .chunks_exact(16)
        .map(|c| {
            let v = |at: usize| f64::from_le_bytes(c[at..at + 8].try_into().expect("8 bytes"));
            [v(0), v(8)]
        })
        .collect();
    let out = py.detach(|| pair_following_scores(&xy, (scenarios, frames, cars), &lags));
    array(py, Data::F64(out), &[scenarios, lags.len(), cars, cars])
}

/// `nbytes` zeroed bytes (uint8, 1-D) for a batch of frames, from the
/// frame buffers streams hand back (fresh memory costs the kernel's zeroing
/// on every page); handed back in turn when the array is dropped.
#[pyfunction]
fn frame_buffer(py: Python<'_>, nbytes: usize) -> PyResult<Bound<'_, Array>> {
    let buffer = py.detach(|| batch_frame_buffer(nbytes));
    let buffer = buffer.ok_or_else(|| {
        PyMemoryError::new_err(format!(
            "a batch of frames needs {:.1} GB, more than this machine has free: use a smaller batch_size",
            nbytes as f64 / 1e9
        ))
    })?;
    array(py, Data::U8(buffer), &[nbytes])
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Spec>()?;
    m.add_class::<Array>()?;
    m.add("InputError", m.py().get_type::<InputError>())?;
    m.add("GenerationError", m.py().get_type::<GenerationError>())?;
    m.add("MAX_THREADS", MAX_THREADS)?;
    m.add_function(wrap_pyfunction!(simulate, m)?)?;
    m.add_function(wrap_pyfunction!(read_scenario, m)?)?;
    m.add_function(wrap_pyfunction!(check_pair, m)?)?;
    m.add_function(wrap_pyfunction!(read_frames, m)?)?;
    m.add_class::<Prefetch>()?;
    m.add_function(wrap_pyfunction!(counterfactual, m)?)?;
    m.add_function(wrap_pyfunction!(generate, m)?)?;
    m.add_function(wrap_pyfunction!(evaluate, m)?)?;
    m.add_function(wrap_pyfunction!(claim_output, m)?)?;
    m.add_function(wrap_pyfunction!(refuse_links_below, m)?)?;
    m.add_function(wrap_pyfunction!(following_scores, m)?)?;
    m.add_function(wrap_pyfunction!(dataset_identity, m)?)?;
    m.add_function(wrap_pyfunction!(write_output, m)?)?;
    m.add_function(wrap_pyfunction!(frame_buffer, m)?)?;
    Ok(())
}
