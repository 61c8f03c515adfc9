//! Exports: a generated dataset turned into the inputs other projects' loaders
//! read unchanged. Exports read only the written files (manifest, CSV logs,
//! scenario.json), never the simulation.

pub mod nri;
pub mod nsdr;
pub mod vcdn;
