//! Orchestration: spec expansion, the parallel run and its progress report.

pub mod handwritten;
pub mod merge;
pub mod plan;
pub mod progress;
pub mod run;
pub mod scenario_file;
