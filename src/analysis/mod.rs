//! Analysis of a written dataset (reads files only): summary statistics.

pub mod stats;
