//! causalcity: traffic datasets for causal discovery and counterfactual
//! reasoning. Data flows one way: a [`spec::DatasetSpec`] is expanded into
//! [`orchestrate::plan::ScenarioPlan`]s, a [`world`] simulates each into
//! trajectories, [`render`] turns them into frames and [`output`] writes files.

pub mod analysis;
pub mod cli;
pub mod dataset;
pub mod export;
pub mod geometry;
pub mod map;
pub mod orchestrate;
pub mod output;
pub mod preview;
pub mod render;
pub mod spec;
pub mod validate;
pub mod world;
