//! Scenarios generated into memory instead of files, for loaders inside a
//! training loop (the Python package): the same plans, simulations and
//! frames as `gen`, `run` and `counterfactual`, returned as
//! [`ScenarioArrays`] that hold exactly what those commands write.

use super::handwritten::{pair_plans, simulate_pair, PairSummary, RunError};
use super::run::GenError;
use super::scenario_file::{load_interventions_text, load_text, FileOptions};
use crate::map::CityMap;
use crate::output::arrays::{
    available_memory_bytes, frame_bytes, scenario_arrays, BatchFrames, OutOfMemory, ScenarioArrays,
};
use crate::plan::{Expansion, ScenarioKey, ScenarioPlan};
use crate::render::{FrameCanvas, Renderer};
use crate::spec::Split;
use crate::timing::StageTimes;
use crate::world::Trajectories;
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex, OnceLock};
use std::time::{Duration, Instant};

/// Generates the scenarios of one expanded spec into memory; shared by
/// threads. The bird's-eye background is drawn once, on first use.
pub struct Generator {
    expansion: Expansion,
    /// One renderer per town, built on first use.
    renderers: Vec<OnceLock<Renderer>>,
}

/// A scenario key that names no scenario of the spec.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct KeyError(pub String);

impl Generator {
    pub fn new(expansion: Expansion) -> Self {
        let renderers = expansion.towns().iter().map(|_| OnceLock::new()).collect();
        Generator { expansion, renderers }
    }

    pub fn expansion(&self) -> &Expansion {
        &self.expansion
    }

    /// The key of scenario `index` of `group` (a name such as
    /// `cars08_edges50`) in `split`, checked against the spec.
    pub fn key(&self, group: &str, split: &str, index: u32) -> Result<ScenarioKey, KeyError> {
        let spec = &self.expansion.spec;
        let names: Vec<String> = spec.groups.iter().map(|g| g.name()).collect();
        let group_index = names.iter().position(|n| n == group).ok_or_else(|| {
            KeyError(format!("group {group:?} is not in spec {:?}: its groups are {}", spec.name, names.join(", ")))
        })?;
        let split = parse_split(split)?;
        let count = spec.splits.count(split);
        if index >= count {
            return Err(KeyError(format!(
                "index {index} is not in split {:?} of spec {:?}: it has {count} scenarios per group (0 to {})",
                split.name(),
                spec.name,
                count as i64 - 1
            )));
        }
        Ok(ScenarioKey { group: group.to_string(), group_index, split, index, name: None })
    }

    /// Every key of `split` (all splits when `None`), at most `limit` per
    /// split and group, in the dataset's fixed order (as `gen` numbers them).
    pub fn keys(&self, split: Option<Split>, limit: Option<u32>) -> Vec<ScenarioKey> {
        self.expansion.keys(limit).into_iter().filter(|k| split.is_none_or(|s| k.split == s)).collect()
    }

    /// The renderer of town `index` (of [`Expansion::towns`]); every
    /// town's canvas has the spec's image size, so any serves to make one.
    fn renderer(&self, index: usize) -> &Renderer {
        let town = &self.expansion.towns()[index];
        self.renderers[index].get_or_init(|| Renderer::new(&town.map, town.camera))
    }

    /// Plans and simulates one scenario; with `images`, renders its frames;
    /// with `effects`, measures its interventional effects as `gen` does
    /// (re-simulating it twice per car).
    pub fn scenario(&self, key: &ScenarioKey, images: bool, effects: bool) -> Result<ScenarioArrays, GenError> {
        let never = AtomicBool::new(false);
        self.scenario_until(key, images, effects, &never)
    }

    /// [`Generator::scenario`], giving up with [`GenError::Interrupted`] at
    /// the first simulated frame at which `stop` is set.
    pub fn scenario_until(
        &self,
        key: &ScenarioKey,
        images: bool,
        effects: bool,
        stop: &AtomicBool,
    ) -> Result<ScenarioArrays, GenError> {
        let mut canvas = images.then(|| self.renderer(0).canvas());
        self.scenario_with(key, canvas.as_mut(), effects, stop, None)
    }

    fn scenario_with(
        &self,
        key: &ScenarioKey,
        canvas: Option<&mut FrameCanvas>,
        effects: bool,
        stop: &AtomicBool,
        into: Option<(&BatchFrames, usize)>,
    ) -> Result<ScenarioArrays, GenError> {
        let plan = self.expansion.plan(key).map_err(|reason| GenError::Plan {
            scenario: format!("{}/{}/{}", key.group, key.split.name(), key.folder_name()),
            reason,
        })?;
        let town = plan.town_index();
        let map = &self.expansion.towns()[town].map;
        let interrupted = || GenError::Interrupted { done: 0, total: 0, out: PathBuf::new() };
        let (trajectories, effects) =
            super::run::simulate_with_effects(map, &plan, effects, stop, &StageTimes::default())
                .ok_or_else(interrupted)?;
        arrays(&self.expansion, &plan, &trajectories, effects, canvas.map(|c| (self.renderer(town), c)), into)
    }
}

/// Scenarios generated ahead of their reader on worker threads of their
/// own, handed out in the keys' order: the reader gets the same sequence
/// whatever the thread count, while every thread takes the next key as
/// soon as it is free. At most `ahead` scenarios are in flight (generating
/// or waiting), which bounds the memory when frames are asked for.
pub struct Prefetch {
    shared: Arc<(Mutex<Queue>, Condvar)>,
    workers: Vec<std::thread::JoinHandle<()>>,
    /// Set when the reader leaves: workers give up mid-scenario.
    halt: Arc<AtomicBool>,
}

/// Keys drawn into shared batch buffers ([`BatchFrames`]): batch `b` is
/// the `lengths[b]` keys from `starts[b]` on.
struct BatchPlan {
    starts: Vec<usize>,
    lengths: Vec<usize>,
    /// Buffers of the batches a worker has begun, made by the first
    /// (outside the queue's lock: the allocation can take a while).
    open: BTreeMap<usize, Arc<OnceLock<Option<BatchFrames>>>>,
}

impl BatchPlan {
    /// The batch of key `index` and its slot in it.
    fn place(&self, index: usize) -> (usize, usize) {
        let batch = self.starts.partition_point(|&s| s <= index) - 1;
        (batch, index - self.starts[batch])
    }
}

/// What [`Prefetch::next_within`] found.
pub enum Waited {
    /// The next scenario in key order.
    Ready(Box<Result<ScenarioArrays, GenError>>),
    /// Every key has been handed out.
    Done,
    /// Not ready within the wait: ask again.
    Pending,
}

struct Queue {
    keys: Vec<ScenarioKey>,
    /// The next key a worker takes, and the next the reader gets.
    next_key: usize,
    next_out: usize,
    ahead: usize,
    ready: BTreeMap<usize, Result<ScenarioArrays, GenError>>,
    /// With frames drawn in batches: which keys form each batch, and the
    /// buffers of the batches being drawn.
    batches: Option<BatchPlan>,
    stop: bool,
    /// A worker died (a bug): the reader gets an error instead of waiting forever.
    broken: bool,
}

impl Prefetch {
    /// Starts `threads` workers on `keys`, at most `ahead` scenarios (at
    /// least one per thread) ahead of the reader. With `batches` (lengths
    /// summing to the keys'), frames go into one buffer per batch of
    /// consecutive keys, handed out with each batch's last scenario
    /// ([`ScenarioArrays::batch`]) instead of each scenario's own.
    pub fn start(
        generator: Arc<Generator>,
        keys: Vec<ScenarioKey>,
        images: bool,
        effects: bool,
        threads: usize,
        ahead: usize,
        batches: Option<Vec<usize>>,
    ) -> Self {
        let threads = threads.clamp(1, keys.len().max(1));
        let ahead = ahead.max(threads);
        let batches = batches.filter(|_| images).map(|lengths| {
            let starts = lengths.iter().scan(0, |at, &n| Some(std::mem::replace(at, *at + n))).collect();
            BatchPlan { starts, lengths, open: BTreeMap::new() }
        });
        let queue = Queue {
            keys,
            next_key: 0,
            next_out: 0,
            ahead,
            ready: BTreeMap::new(),
            batches,
            stop: false,
            broken: false,
        };
        crate::output::arrays::hold_spare_frame_buffers();
        let shared = Arc::new((Mutex::new(queue), Condvar::new()));
        let halt = Arc::new(AtomicBool::new(false));
        let workers = (0..threads)
            .map(|_| {
                let (shared, generator, halt) = (shared.clone(), generator.clone(), halt.clone());
                std::thread::spawn(move || {
                    let work =
                        std::panic::AssertUnwindSafe(|| prefetch_worker(&shared, &generator, images, effects, &halt));
                    if std::panic::catch_unwind(work).is_err() {
                        let (lock, wake) = &*shared;
                        lock.lock().unwrap_or_else(|e| e.into_inner()).broken = true;
                        wake.notify_all();
                    }
                })
            })
            .collect();
        Prefetch { shared, workers, halt }
    }

    /// The next scenario in key order, waiting for it; `None` after the last.
    pub fn next(&self) -> Option<Result<ScenarioArrays, GenError>> {
        loop {
            match self.next_within(Duration::from_secs(3600)) {
                Waited::Ready(result) => return Some(*result),
                Waited::Done => return None,
                Waited::Pending => {}
            }
        }
    }

    /// The next scenario in key order, waiting at most `wait` for it (a
    /// reader that must answer Ctrl-C meanwhile asks again).
    pub fn next_within(&self, wait: Duration) -> Waited {
        let deadline = Instant::now() + wait;
        let (lock, wake) = &*self.shared;
        let mut queue = lock.lock().unwrap_or_else(|e| e.into_inner());
        loop {
            if queue.next_out >= queue.keys.len() {
                return Waited::Done;
            }
            let index = queue.next_out;
            if let Some(mut result) = queue.ready.remove(&index) {
                queue.next_out += 1;
                // A batch's last scenario brings the batch's frames: every
                // slot is drawn (their workers let go of the buffer before
                // handing in their results, all read by now).
                if let Some(plan) = queue.batches.as_mut() {
                    let (batch, slot) = plan.place(index);
                    if slot + 1 == plan.lengths[batch] {
                        let frames = plan.open.remove(&batch).and_then(|b| Arc::try_unwrap(b).ok());
                        let frames = frames.and_then(OnceLock::into_inner).flatten().map(BatchFrames::into_frames);
                        if let Ok(arrays) = result.as_mut() {
                            arrays.batch = frames;
                        }
                    }
                }
                wake.notify_all();
                return Waited::Ready(Box::new(result));
            }
            if queue.broken {
                let key = &queue.keys[index];
                let scenario = format!("{}/{}/{}", key.group, key.split.name(), key.folder_name());
                queue.next_out = queue.keys.len();
                return Waited::Ready(Box::new(Err(GenError::Plan {
                    scenario,
                    reason: "internal error: a worker thread panicked (please report it with the spec)".into(),
                })));
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Waited::Pending;
            }
            queue = wake.wait_timeout(queue, left).unwrap_or_else(|e| e.into_inner()).0;
        }
    }
}

impl Drop for Prefetch {
    /// Stops the workers (each finishes the scenario it is on), waits for
    /// them, and frees the spare frame buffers unless another stream runs.
    fn drop(&mut self) {
        let (lock, wake) = &*self.shared;
        self.halt.store(true, Ordering::SeqCst);
        lock.lock().unwrap_or_else(|e| e.into_inner()).stop = true;
        wake.notify_all();
        for worker in self.workers.drain(..) {
            let _ = worker.join();
        }
        crate::output::arrays::let_go_of_spare_frame_buffers();
    }
}

/// One worker: takes the next key while the reader is less than `ahead`
/// behind, generates it, and queues the result under its index.
fn prefetch_worker(
    shared: &(Mutex<Queue>, Condvar),
    generator: &Generator,
    images: bool,
    effects: bool,
    halt: &AtomicBool,
) {
    let (lock, wake) = shared;
    let mut canvas = images.then(|| generator.renderer(0).canvas());
    loop {
        let (index, key, batch) = {
            let mut queue = lock.lock().unwrap_or_else(|e| e.into_inner());
            loop {
                if queue.stop || queue.next_key >= queue.keys.len() {
                    return;
                }
                if queue.next_key < queue.next_out + queue.ahead {
                    break;
                }
                queue = wake.wait(queue).unwrap_or_else(|e| e.into_inner());
            }
            queue.next_key += 1;
            let index = queue.next_key - 1;
            let batch = queue.batches.as_mut().map(|plan| {
                let (batch, slot) = plan.place(index);
                let scenarios = plan.lengths[batch];
                (plan.open.entry(batch).or_default().clone(), slot, scenarios)
            });
            (index, queue.keys[index].clone(), batch)
        };
        let expansion = generator.expansion();
        let frames = batch.as_ref().map(|(buffer, slot, scenarios)| {
            let made =
                buffer.get_or_init(|| BatchFrames::new(*scenarios, expansion.spec.frames as usize, &expansion.camera));
            (made.as_ref(), *slot)
        });
        let work = std::panic::AssertUnwindSafe(|| match frames {
            Some((None, _)) => Err(GenError::Memory(OutOfMemory {
                scenario: key.folder_name(),
                bytes: frame_bytes(expansion.spec.frames as usize, &expansion.camera)
                    * batch.as_ref().map_or(1, |b| b.2 as u64),
                frames: expansion.spec.frames as usize,
                width: expansion.camera.width,
                height: expansion.camera.height,
                available: available_memory_bytes(),
            })),
            Some((Some(buffer), slot)) => {
                generator.scenario_with(&key, canvas.as_mut(), effects, halt, Some((buffer, slot)))
            }
            None => generator.scenario_with(&key, canvas.as_mut(), effects, halt, None),
        });
        let result = std::panic::catch_unwind(work).unwrap_or_else(|_| {
            // A bug, not the user's input: the reader gets an error instead of waiting forever.
            Err(GenError::Plan {
                scenario: format!("{}/{}/{}", key.group, key.split.name(), key.folder_name()),
                reason: "internal error: the simulation panicked (please report it with the spec)".into(),
            })
        });
        drop(batch); // before the result: the reader takes the batch's buffer with its last one
        lock.lock().unwrap_or_else(|e| e.into_inner()).ready.insert(index, result);
        wake.notify_all();
    }
}

/// `split` by name, or an error listing the names.
pub fn parse_split(split: &str) -> Result<Split, KeyError> {
    Split::ALL.into_iter().find(|s| s.name() == split).ok_or_else(|| {
        let names: Vec<&str> = Split::ALL.iter().map(|s| s.name()).collect();
        KeyError(format!("split {split:?} is not one of {}", names.join(", ")))
    })
}

fn arrays(
    expansion: &Expansion,
    plan: &ScenarioPlan,
    trajectories: &Trajectories,
    effects: Option<crate::world::effects::EffectReport>,
    renderer: Option<(&Renderer, &mut FrameCanvas)>,
    into: Option<(&BatchFrames, usize)>,
) -> Result<ScenarioArrays, GenError> {
    let spec = &expansion.spec;
    let town = expansion.town_of(plan);
    let (map, camera) = (&town.map, &town.camera);
    scenario_arrays(map, camera, spec.leader_gap_px(), plan, trajectories, effects, renderer, into)
        .map_err(GenError::Memory)
}

/// A scenario file's or an intervention file's text, and the name its
/// errors give it (the file's path, or a label such as `<dict>`).
#[derive(Debug, Clone, Copy)]
pub struct Text<'a> {
    pub origin: &'a Path,
    pub text: &'a str,
}

/// One scenario's factual and counterfactual runs, as `counterfactual`
/// writes them under `<out>/<Name>/`.
pub struct PairArrays {
    pub name: String,
    pub factual: ScenarioArrays,
    pub counterfactual: ScenarioArrays,
    /// Metres between each car's factual and counterfactual positions,
    /// `[frames, cars]` (divergence.csv's `distance_m`).
    pub divergence_m: Vec<f64>,
    /// summary.json.
    pub summary: PairSummary,
}

/// `causalcity counterfactual` into memory: every scenario of `scenarios`
/// with the interventions of `interventions` added (or, without them, the
/// scenario's own interventions against a run without), in file order.
/// Gives up with [`GenError::Interrupted`] once `stop` is set.
pub fn counterfactual_arrays(
    scenarios: Text,
    interventions: Option<Text>,
    images: bool,
    stop: &AtomicBool,
) -> Result<Vec<PairArrays>, RunError> {
    let map = Arc::new(CityMap::default());
    let loaded = load_text(scenarios.origin, scenarios.text, FileOptions::default(), &map).map_err(RunError::Input)?;
    let extras = match interventions {
        Some(i) => Some(load_interventions_text(i.origin, i.text, &loaded).map_err(RunError::Input)?),
        None => None,
    };
    let pairs = pair_plans(scenarios.origin, &loaded, extras)?;
    if images {
        // Every pair's frames are held at once: refuse up front what the
        // machine cannot hold (uncapped, 60 scenarios grew to 24 GB).
        let needed: u64 =
            pairs.iter().map(|(s, f, _)| 2 * frame_bytes(f.frames as usize + 1, &s.expansion.camera)).sum();
        if let Some(available) = available_memory_bytes().filter(|&a| a < needed) {
            return Err(RunError::Write(GenError::Memory(OutOfMemory {
                scenario: format!("{} ({} pairs together)", scenarios.origin.display(), pairs.len()),
                bytes: needed,
                frames: pairs.iter().map(|(_, f, _)| 2 * f.frames as usize).sum(),
                width: pairs[0].0.expansion.camera.width,
                height: pairs[0].0.expansion.camera.height,
                available: Some(available),
            })));
        }
    }
    pairs
        .par_iter()
        .map(|(s, factual, counterfactual)| {
            let pair = simulate_pair(&s.expansion, &s.name, factual, counterfactual, stop)
                .ok_or(GenError::Interrupted { done: 0, total: 0, out: PathBuf::new() })?;
            let renderer = images.then(|| Renderer::new(&s.expansion.map, s.expansion.camera));
            let mut canvas = renderer.as_ref().map(Renderer::canvas);
            let mut run = |plan: &ScenarioPlan, trajectories: &Trajectories| {
                let r = renderer.as_ref().zip(canvas.as_mut());
                arrays(&s.expansion, plan, trajectories, None, r, None)
            };
            Ok(PairArrays {
                name: s.name.clone(),
                factual: run(factual, &pair.factual)?,
                counterfactual: run(counterfactual, &pair.counterfactual)?,
                divergence_m: pair.divergence_m,
                summary: pair.summary,
            })
        })
        .collect::<Result<_, GenError>>()
        .map_err(RunError::Write)
}
