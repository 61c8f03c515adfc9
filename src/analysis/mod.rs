//! Analysis of a written dataset (reads files only): summary statistics.

pub mod heatmap;
pub mod stats;
