//! Orchestration: spec expansion, the parallel run and its progress report.

pub mod merge;
pub mod plan;
pub mod progress;
pub mod run;
