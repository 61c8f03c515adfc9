//! Orchestration: the jobs behind the commands (`gen`, `merge`, `run`,
//! `counterfactual`): read inputs, plan, simulate, write in parallel.

pub mod handwritten;
pub mod in_memory;
pub mod merge;
pub mod run;
pub mod scenario_file;
