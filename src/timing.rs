//! Where a run's time goes: seconds per stage (plan, simulate, render,
//! encode, write, checksum, effects), summed over every worker thread.

use serde::Serialize;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// A stage of making a scenario.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// Spec expansion: placing cars, drawing routes, drivers and confounders.
    Plan,
    /// The world's dynamics.
    Simulate,
    /// Drawing frames, masks and depth into memory.
    Render,
    /// PNG encoding.
    Encode,
    /// Formatting logs and writing bytes to files.
    Write,
    /// SHA-256 of every file written.
    Checksum,
    /// The interventional re-runs behind `effects.csv`.
    Effects,
}

const STAGES: usize = 7;

/// Nanoseconds per stage, added to from any thread.
#[derive(Debug, Default)]
pub struct StageTimes {
    nanos: [AtomicU64; STAGES],
}

impl StageTimes {
    /// Adds `elapsed` to `stage`.
    pub fn add(&self, stage: Stage, elapsed: Duration) {
        self.nanos[stage as usize].fetch_add(elapsed.as_nanos() as u64, Ordering::Relaxed);
    }

    /// Runs `work`, counting its time to `stage`.
    pub fn time<T>(&self, stage: Stage, work: impl FnOnce() -> T) -> T {
        let start = Instant::now();
        let value = work();
        self.add(stage, start.elapsed());
        value
    }

    /// The totals so far.
    pub fn seconds(&self) -> StageSeconds {
        let s = |stage: Stage| self.nanos[stage as usize].load(Ordering::Relaxed) as f64 / 1e9;
        StageSeconds {
            plan: s(Stage::Plan),
            simulate: s(Stage::Simulate),
            render: s(Stage::Render),
            encode: s(Stage::Encode),
            write: s(Stage::Write),
            checksum: s(Stage::Checksum),
            effects: s(Stage::Effects),
        }
    }
}

/// Seconds per stage, summed over threads (so they can add up to more than
/// the run's wall-clock time).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct StageSeconds {
    pub plan: f64,
    pub simulate: f64,
    pub render: f64,
    pub encode: f64,
    pub write: f64,
    pub checksum: f64,
    pub effects: f64,
}

impl StageSeconds {
    /// All stages together.
    pub fn total(&self) -> f64 {
        self.plan + self.simulate + self.render + self.encode + self.write + self.checksum + self.effects
    }
}
