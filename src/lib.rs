//! causalcity: traffic datasets for causal discovery and counterfactual
//! reasoning. Data flows one way, and every layer imports only the ones
//! before it:
//!
//! [`json`], [`input`], [`geometry`], [`camera`], [`map`] -> [`spec`] -> [`plan`] -> [`world`] ->
//! [`render`] -> [`output`] -> [`dataset`], [`validate`], [`analysis`],
//! [`export`], [`preview`] -> [`orchestrate`].
//!
//! A [`spec::DatasetSpec`] is expanded into [`plan::ScenarioPlan`]s, a
//! [`world`] simulates each into trajectories, [`render`] turns them into
//! frames and [`output`] writes files. The command line lives in the binary.

pub mod analysis;
pub mod camera;
pub mod dataset;
pub mod error;
pub mod export;
pub mod geometry;
pub mod input;
pub mod json;
pub mod map;
pub mod map_view;
pub mod orchestrate;
pub mod output;
pub mod plan;
pub mod preview;
pub mod progress;
pub mod remainder;
pub mod render;
pub mod spec;
pub mod timing;
pub mod validate;
pub mod world;
