//! Analysis of a written dataset (reads files only): summary statistics,
//! dwell-time heat maps and a causal-discovery baseline.

pub mod baseline;
pub mod evaluate;
pub mod flow;
pub mod heatmap;
pub mod metrics;
pub mod predictions;
pub mod stats;
