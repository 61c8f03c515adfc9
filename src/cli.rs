//! Every command-line flag, defined once with its documentation.

use clap::{Args, Parser, Subcommand};
use std::path::PathBuf;

/// Generates traffic datasets for causal discovery and counterfactual
/// reasoning: leader-follower scenarios on a four-intersection city, written
/// as bird's-eye PNG frames, instance masks, CSV pose logs and causal graphs.
#[derive(Debug, Parser)]
#[command(name = "causalcity", version, propagate_version = true)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Generate a dataset from a spec file (see configs/).
    Gen(GenArgs),
}

#[derive(Debug, Args)]
pub struct GenArgs {
    /// Dataset spec (JSON), e.g. configs/toy.json.
    #[arg(long, value_name = "FILE")]
    pub spec: PathBuf,

    /// Output folder [default: data/<spec name>].
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,

    /// Generate at most N scenarios per split and group: a quick sample of a big spec.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..))]
    pub limit: Option<u32>,

    /// Worker threads [default: every core]. Output is identical for any value.
    #[arg(short = 'j', long = "threads", value_name = "THREADS", value_parser = clap::value_parser!(u32).range(1..1025))]
    pub threads: Option<u32>,

    /// Write scenario.json and poses.csv only, no PNG frames or masks.
    #[arg(long)]
    pub no_images: bool,

    /// No progress output (the final summary is still printed).
    #[arg(short, long)]
    pub quiet: bool,
}
