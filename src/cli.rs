//! Every command-line flag, defined once with its documentation.

use crate::orchestrate::run::Shard;
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
    /// Generate a dataset from a spec file (see configs/). Rerunning the same
    /// command resumes an interrupted run.
    Gen(GenArgs),
    /// Combine the outputs of `gen --shard K/N` runs into one dataset.
    Merge(MergeArgs),
    /// Check a dataset against data-schema/ and its checksums.
    Validate(ValidateArgs),
    /// Per group and split: speeds, stops, collisions, red-light runs, leader-follower gaps.
    Stats(StatsArgs),
    /// Dwell-time heat map of all cars over the camera view (PNG with a colour bar).
    Heatmap(HeatmapArgs),
    /// Turn a dataset into the inputs of other projects' loaders.
    #[command(subcommand)]
    Export(ExportCommand),
    /// A scenario's frames as a small animated GIF (or a PNG contact sheet),
    /// optionally with masks, trails and leader -> follower arrows.
    Preview(PreviewArgs),
    /// Non-learned causal-discovery baseline: lagged path-following scores,
    /// threshold picked on train, precision / recall / F1 on test per group.
    Baseline(BaselineArgs),
    /// Run hand-written scenarios (the original CausalCity scenario format,
    /// plus extensions) into one scenario folder each.
    Run(RunArgs),
    /// Factual and counterfactual runs of hand-written scenarios: identical
    /// until an intervention, with per-car divergence and the effect set.
    Counterfactual(CounterfactualArgs),
}

#[derive(Debug, Args)]
pub struct RunArgs {
    /// Scenario file (JSON): a list of {"Name", "Vehicles": [...]}, see configs/examples/.
    #[arg(long, value_name = "FILE")]
    pub scenario: PathBuf,

    /// Output folder; one subfolder per scenario [default: data/<file name>].
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,

    /// World to run in [default: the file's "world", else city].
    #[arg(long, value_enum)]
    pub world: Option<crate::spec::WorldKind>,

    /// Write scenario.json and the logs only, no PNG frames or masks.
    #[arg(long)]
    pub no_images: bool,

    /// Also write NS-DR annotations.json per scenario.
    #[arg(long, conflicts_with = "no_images")]
    pub annotations: bool,

    /// Print what was written as JSON.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
#[command(group(clap::ArgGroup::new("source").required(true).args(["scenario", "sweep"])))]
pub struct CounterfactualArgs {
    /// Scenario file (JSON), as for `run`.
    #[arg(long, value_name = "FILE")]
    pub scenario: Option<PathBuf>,

    /// Interventions to add for the counterfactual (a JSON list, as a
    /// scenario's "interventions"); without it, the scenario's own
    /// interventions make the counterfactual.
    #[arg(long, value_name = "FILE", requires = "scenario")]
    pub intervention: Option<PathBuf>,

    /// Counterfactual pairs at scale from a `gen` spec (city world): one
    /// random intervention per scenario.
    #[arg(long, value_name = "SPEC")]
    pub sweep: Option<PathBuf>,

    /// --sweep: kinds of intervention to draw from.
    #[arg(long, value_enum, value_delimiter = ',', default_value = "stop,set-desired-speed,run-red-light,remove")]
    pub kinds: Vec<crate::orchestrate::handwritten::SweepKind>,

    /// --sweep: at most N scenarios per split and group.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..))]
    pub limit: Option<u32>,

    /// --sweep: worker threads [default: every core].
    #[arg(short = 'j', long = "threads", value_name = "THREADS", value_parser = clap::value_parser!(u32).range(1..1025))]
    pub threads: Option<u32>,

    /// Output folder [default: data/<file name>, or data/<spec name>-counterfactual].
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,

    /// World to run a scenario file in [default: the file's "world", else city].
    #[arg(long, value_enum, requires = "scenario")]
    pub world: Option<crate::spec::WorldKind>,

    /// Write scenario.json and the logs only, no PNG frames or masks.
    #[arg(long)]
    pub no_images: bool,

    /// Print the summaries as JSON.
    #[arg(long)]
    pub json: bool,

    /// --sweep: no progress output.
    #[arg(short, long)]
    pub quiet: bool,
}

#[derive(Debug, Args)]
pub struct PreviewArgs {
    /// Scenario folder (the one holding scenario.json, rgb/ and mask/).
    #[arg(value_name = "SCENARIO")]
    pub scenario: PathBuf,

    /// Output file: .gif for an animation, .png for a contact sheet.
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,

    /// Scale factor of the frames (0 < scale <= 1).
    #[arg(long, default_value_t = 0.4)]
    pub scale: f64,

    /// Use every Nth frame.
    #[arg(long, value_name = "N", default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..))]
    pub every: u32,

    /// GIF frames per second [default: the scenario's real time at --every].
    #[arg(long)]
    pub fps: Option<f64>,

    /// Tint every car's mask pixels with its instance colour.
    #[arg(long)]
    pub masks: bool,

    /// Draw each car's path so far.
    #[arg(long)]
    pub trails: bool,

    /// Draw an arrow from each leader to its follower.
    #[arg(long)]
    pub arrows: bool,

    /// Contact sheet: frames shown (spread over the scenario).
    #[arg(long, default_value_t = 12, value_parser = clap::value_parser!(u32).range(1..=100))]
    pub sheet_frames: u32,

    /// Contact sheet: frames per row.
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=20))]
    pub columns: u32,
}

#[derive(Debug, Args)]
pub struct BaselineArgs {
    /// Dataset folder (the one holding manifest.json).
    #[arg(value_name = "DATASET")]
    pub dataset: PathBuf,

    /// Longest lag tried, in seconds.
    #[arg(long, value_name = "SECONDS", default_value_t = 8.0)]
    pub max_lag: f64,

    /// Print the table as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct StatsArgs {
    /// Dataset folder (the one holding manifest.json).
    #[arg(value_name = "DATASET")]
    pub dataset: PathBuf,

    /// Print the table as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct HeatmapArgs {
    /// Dataset folder (the one holding manifest.json).
    #[arg(value_name = "DATASET")]
    pub dataset: PathBuf,

    /// The PNG to write.
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,

    /// Only this group, e.g. cars08_edges50.
    #[arg(long)]
    pub group: Option<String>,

    /// Only this split.
    #[arg(long, value_parser = ["train", "val", "test"])]
    pub split: Option<String>,

    /// Print the summary as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Subcommand)]
pub enum ExportCommand {
    /// NRI: loc/vel/edges .npy files per group and split (train, valid, test).
    Nri(ExportNriArgs),
    /// V-CDN: one HDF5 file per scenario (attrs, states, actions, rels).
    Vcdn(ExportDirArgs),
    /// NS-DR: annotations.json per scenario, masks as COCO RLE.
    Nsdr(ExportDirArgs),
}

#[derive(Debug, Args)]
pub struct ExportDirArgs {
    /// Dataset folder (the one holding manifest.json).
    #[arg(value_name = "DATASET")]
    pub dataset: PathBuf,

    /// Output folder; files go under <group>/<split>/.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,

    /// No progress output.
    #[arg(short, long)]
    pub quiet: bool,
}

#[derive(Debug, Args)]
pub struct ExportNriArgs {
    /// Dataset folder (the one holding manifest.json).
    #[arg(value_name = "DATASET")]
    pub dataset: PathBuf,

    /// Output folder; one subfolder per group.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,

    /// causalcity: [scenarios, frames, cars, 2] with identity edges (the original
    /// CausalCity NRI fork); nri: [scenarios, frames, 2, cars], no self loops.
    #[arg(long, value_enum, default_value = "causalcity")]
    pub layout: crate::export::nri::NriLayout,

    /// Appended to every file name, e.g. `_city` gives loc_train_city.npy.
    #[arg(long, default_value = "")]
    pub suffix: String,

    /// Keep only leader -> follower edges (edges[s, follower, leader] = 1).
    #[arg(long)]
    pub directed: bool,
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

    /// Write scenario.json and the CSV logs only, no PNG frames or masks.
    #[arg(long)]
    pub no_images: bool,

    /// Also write NS-DR annotations.json per scenario: every car's mask per
    /// frame as COCO RLE (pycocotools.mask.decode reads it).
    #[arg(long, conflicts_with = "no_images")]
    pub annotations: bool,

    /// Generate only shard K of N (0 <= K < N), e.g. from a Slurm array or a
    /// Kubernetes Indexed Job; combine the shards with `causalcity merge`.
    #[arg(long, value_name = "K/N")]
    pub shard: Option<Shard>,

    /// Replace a dataset made from another spec or version in --out. Removes
    /// only what causalcity wrote (its manifests and group folders).
    #[arg(long)]
    pub force: bool,

    /// fsync every file before a scenario is moved into place, so finished
    /// scenarios survive a power cut (slower; a killed process never needs it).
    #[arg(long)]
    pub fsync: bool,

    /// Print the final summary as JSON on stdout.
    #[arg(long)]
    pub json: bool,

    /// No progress output (the final summary is still printed).
    #[arg(short, long)]
    pub quiet: bool,
}

#[derive(Debug, Args)]
pub struct MergeArgs {
    /// The dataset folder to complete; shards may already be in it.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,

    /// Shard output folders to move into --out (none when every shard wrote into --out).
    #[arg(value_name = "SHARD_DIR")]
    pub shards: Vec<PathBuf>,
}

#[derive(Debug, Args)]
pub struct ValidateArgs {
    /// Dataset folder (the one holding manifest.json).
    #[arg(value_name = "DIR")]
    pub dir: PathBuf,

    /// Worker threads [default: every core].
    #[arg(short = 'j', long = "threads", value_name = "THREADS", value_parser = clap::value_parser!(u32).range(1..1025))]
    pub threads: Option<u32>,

    /// Print the report as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}
