//! Orchestration: the jobs behind the commands (`gen`, `merge`, `pack`, `run`,
//! `counterfactual`): read inputs, plan, simulate, write in parallel.

pub mod handwritten;
pub mod in_memory;
pub mod merge;
pub mod pack;
pub mod run;
pub mod scenario_file;
