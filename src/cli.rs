//! Every command-line flag, defined once with its documentation, and the
//! dispatch from a parsed command line to the library. Nothing here is
//! domain logic: flags become the library's option types, results are
//! printed through their `Display` (or as JSON), and every failure is one
//! [`Error`] whose exit code `main` returns.

use causalcity::analysis::baseline::baseline;
use causalcity::analysis::evaluate::{evaluate, EvaluateOptions, DEFAULT_HISTORY_FRAMES};
use causalcity::analysis::heatmap::{heatmap, HeatmapFilter};
use causalcity::analysis::stats::dataset_stats;
use causalcity::dataset::GraphKind;
use causalcity::error::Error;
use causalcity::export::nri::{export_nri, NriLayout, NriOptions, Velocity};
use causalcity::export::nsdr::export_nsdr;
use causalcity::export::vcdn::export_vcdn;
use causalcity::map_view::{map_view, net_view};

/// Longer side of `causalcity map --net`'s picture, pixels.
const NET_PICTURE_PX: u32 = 1200;
use causalcity::orchestrate::handwritten::{counterfactual, run_file, sweep, RunOptions, SweepKind, SweepOptions};
use causalcity::orchestrate::merge::merge;
use causalcity::orchestrate::pack::pack_dataset;
use causalcity::orchestrate::run::{generate, GenOptions, Shard, MAX_THREADS};
use causalcity::output::claim::claim_file;
use causalcity::output::manifest::{LightsLog, Packing, Products};
use causalcity::preview::{preview, PreviewOptions};
use causalcity::progress::ProgressMode;
use causalcity::spec::{Split, WorldKind};
use causalcity::validate::validate;
use clap::{Args, Parser, Subcommand, ValueEnum};
use serde::Serialize;
use std::fmt::Display;
use std::io::Write;
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
    /// Pack a dataset of scenario folders (or a counterfactual sweep of pair
    /// folders) into tar files in a new folder: what `gen --format tar`
    /// (`counterfactual --sweep --format tar`) writes, byte for byte.
    Pack(PackArgs),
    /// Check a dataset against data-schema/ and its checksums.
    Validate(ValidateArgs),
    /// Per group and split: speeds, stops, collisions, red-light runs, leader-follower gaps.
    Stats(StatsArgs),
    /// Dwell-time heat map of all cars over the camera view (PNG with a colour bar).
    Heatmap(HeatmapArgs),
    /// A spec's road network: its junctions and lane ids (the spawn points
    /// scenario files name) and, with --out, a picture with every lane's id.
    Map(MapArgs),
    /// Turn a dataset into the inputs of other projects' loaders.
    #[command(subcommand)]
    Export(ExportCommand),
    /// A scenario's frames as a small animated GIF (or a PNG contact sheet),
    /// optionally with masks, trails and leader -> follower arrows.
    Preview(PreviewArgs),
    /// Non-learned causal-discovery baseline: lagged path-following scores,
    /// threshold picked on train, precision / recall / F1 on test per group.
    Baseline(BaselineArgs),
    /// Score a predictions file (.npz: edge scores and predicted trajectories
    /// per scenario) with the paper's metrics: F1 at a threshold from val,
    /// AUROC, AUPRC, SHD, and trajectory error 1..N steps ahead.
    Evaluate(EvaluateArgs),
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
    pub world: Option<WorldArg>,

    /// Write scenario.json and the logs only, no PNG frames or masks.
    #[arg(long)]
    pub no_images: bool,

    /// Also write NS-DR annotations.json per scenario.
    #[arg(long, conflicts_with = "no_images")]
    pub annotations: bool,

    #[command(flatten)]
    pub lights: LightsFlag,

    /// Exit 2 on the first action, merge distance or spawn that would need
    /// adapting (a turn from the wrong lane, a merge past its lane's end, a
    /// distance that is not a number, two cars on one spot), instead of
    /// adapting it with a warning.
    #[arg(long)]
    pub strict: bool,

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
    #[arg(long, value_name = "FILE")]
    pub intervention: Option<PathBuf>,

    /// Counterfactual pairs at scale from a `gen` spec (city world): one
    /// random intervention per scenario.
    #[arg(long, value_name = "SPEC")]
    pub sweep: Option<PathBuf>,

    /// --sweep: kinds of intervention to draw from [default:
    /// stop,set-desired-speed,run-red-light,remove].
    #[arg(long, value_enum, value_delimiter = ',')]
    pub kinds: Option<Vec<SweepKindArg>>,

    /// --sweep: how pairs are stored: `folders` (a folder each) or `tar`:
    /// whole pairs packed --scenarios-per-tar at a time into
    /// `<group>/<split>/<first>-<last>.tar`, with the folders' files and
    /// bytes inside (`tar -xf` gives the folders), as `gen --format tar`
    /// [default: folders].
    #[arg(long, value_enum)]
    pub format: Option<FormatArg>,

    /// --sweep with --format tar: pairs per tar file (the last of a split
    /// may hold fewer) [default: 64].
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=1_000_000))]
    pub scenarios_per_tar: Option<u32>,

    /// --sweep: at most N scenarios per split and group.
    #[arg(long, value_name = "N", allow_negative_numbers = true, value_parser = clap::value_parser!(u32).range(1..))]
    pub limit: Option<u32>,

    /// --sweep: worker threads [default: every core].
    #[arg(short = 'j', long = "threads", value_name = "THREADS", value_parser = clap::value_parser!(u32).range(1..=MAX_THREADS as i64))]
    pub threads: Option<u32>,

    /// Output folder [default: data/<file name>, or data/<spec name>-counterfactual].
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,

    /// World to run a scenario file in [default: the file's "world", else city].
    #[arg(long, value_enum)]
    pub world: Option<WorldArg>,

    /// Write scenario.json and the logs only, no PNG frames or masks.
    #[arg(long)]
    pub no_images: bool,

    #[command(flatten)]
    pub lights: LightsFlag,

    /// --scenario: exit 2 on the first action, merge distance or spawn
    /// that would need adapting, as `run --strict`.
    #[arg(long)]
    pub strict: bool,

    /// Print the summaries as JSON.
    #[arg(long)]
    pub json: bool,

    /// --sweep: no progress output.
    #[arg(short, long)]
    pub quiet: bool,
}

impl CounterfactualArgs {
    /// The first flag given that only the other source (`--scenario` or
    /// `--sweep`) reads. (Clap's `requires` is not enforced beside the
    /// source group, so this is checked here.)
    fn flag_of_the_other_source(&self) -> Option<&'static str> {
        if self.sweep.is_some() {
            [
                ("--intervention", self.intervention.is_some()),
                ("--world", self.world.is_some()),
                ("--strict", self.strict),
            ]
            .into_iter()
            .find_map(|(flag, given)| given.then_some(flag))
        } else {
            [
                ("--kinds", self.kinds.is_some()),
                ("--format", self.format.is_some()),
                ("--scenarios-per-tar", self.scenarios_per_tar.is_some()),
                ("--limit", self.limit.is_some()),
                ("--threads", self.threads.is_some()),
            ]
            .into_iter()
            .find_map(|(flag, given)| given.then_some(flag))
        }
    }
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
    #[arg(long, default_value_t = 0.4, value_parser = scale_factor)]
    pub scale: f64,

    /// Use every Nth frame.
    #[arg(long, value_name = "N", default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..))]
    pub every: u32,

    /// GIF frames per second, 0.5 to 50 [default: the scenario's real speed
    /// at --every, sped up so that the GIF lasts at most 15 s].
    #[arg(long, value_parser = positive_number)]
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

    /// Longest lag of the following score, in seconds [default: the one of
    /// 2, 4, 8, 15, 30, 60 s, up to the scenario's length, with the best
    /// AUROC on each group's train split].
    #[arg(long, value_name = "SECONDS", value_parser = positive_number)]
    pub max_lag: Option<f64>,

    /// The graph to score against: designed (leader-follower edges), causal
    /// or direct (measured by intervention; not with gen --no-effects).
    #[arg(long, value_enum, default_value = "designed")]
    pub graph: GraphArg,

    /// Print the table as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct EvaluateArgs {
    /// Dataset folder (the one holding manifest.json), or a counterfactual
    /// --sweep output (the one holding sweep.json).
    #[arg(value_name = "DATASET")]
    pub dataset: PathBuf,

    /// Predictions (.npz, as numpy's np.savez writes it): per scenario, an
    /// array named by its folder (cars08_edges50/test/00000) of shape
    /// [cars, cars], [i, j] scoring "car i leads car j"; optionally
    /// <folder>/trajectory, [steps, cars, 2]: predicted bird's-eye pixel
    /// positions of the frames after the history; <folder>/frames (city),
    /// [frames, cars, cars]: [t, i, j] scoring "car i bound car j's speed
    /// at frame t" (interactions.csv); <folder>/counterfactual (a sweep),
    /// [steps, cars, 2]: the counterfactual run's positions after the
    /// history.
    #[arg(value_name = "PREDICTIONS")]
    pub predictions: PathBuf,

    /// The graphs to score edges against (repeat or separate with commas):
    /// designed, causal, direct (the last two not with gen --no-effects).
    #[arg(long, value_enum, value_delimiter = ',', default_value = "designed")]
    pub graph: Vec<GraphArg>,

    /// Frames observed before a predicted trajectory's first frame.
    #[arg(long, value_name = "FRAMES", default_value_t = DEFAULT_HISTORY_FRAMES)]
    pub history: usize,

    /// Call a pair linked when its score is above this [default: the
    /// threshold with the best F1 on each group's val split; 0.5 without val
    /// predictions].
    #[arg(long, value_name = "SCORE")]
    pub threshold: Option<f64>,

    /// Also write the results as a CSV table (one value per row) to FILE.
    #[arg(long, value_name = "FILE")]
    pub csv: Option<PathBuf>,

    /// Also write one row per scenario and graph to FILE (CSV): its
    /// counts, precision, recall, F1, SHD and AUROC at its group's
    /// threshold, and its mean trajectory error, to find the scenarios a
    /// method gets wrong.
    #[arg(long, value_name = "FILE")]
    pub per_scenario: Option<PathBuf>,

    /// Print the results as JSON on stdout.
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

    /// Every column (about 200 characters wide); by default the main ones
    /// (about 110).
    #[arg(long)]
    pub wide: bool,
}

#[derive(Debug, Args)]
pub struct MapArgs {
    /// Dataset spec (JSON), e.g. configs/city.json.
    #[arg(long, value_name = "FILE", required_unless_present = "net", conflicts_with = "net")]
    pub spec: Option<PathBuf>,

    /// A SUMO road network (.net.xml, as netconvert writes it from
    /// OpenStreetMap or OpenDRIVE) instead of a spec: list its junctions
    /// and the lanes cars may drive, and with --out draw it. A spec's
    /// `map.sumo` generates datasets on it (docs/sumo.md).
    #[arg(long, value_name = "FILE")]
    pub net: Option<PathBuf>,

    /// Also draw the bird's-eye view at the spec's image size, with every
    /// lane's id and junction's name, to this PNG.
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,

    /// Print the junctions and lanes as JSON.
    #[arg(long)]
    pub json: bool,

    /// The town to show when the spec's map draws several (its name, e.g.
    /// grid-3x4, as the listing says); the first when absent.
    #[arg(long, value_name = "NAME", conflicts_with = "net")]
    pub town: Option<String>,
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
    #[arg(long, value_enum)]
    pub split: Option<SplitArg>,

    /// Print the summary as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Subcommand)]
pub enum ExportCommand {
    /// NRI: loc/vel/edges .npy files per group and split (train, valid, test).
    Nri(ExportNriArgs),
    /// V-CDN: one HDF5 file per scenario (attrs, states, actions, rels).
    Vcdn(ExportVcdnArgs),
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
    pub layout: NriLayoutArg,

    /// Appended to every file name, e.g. `_city` gives loc_train_city.npy.
    #[arg(long, default_value = "")]
    pub suffix: String,

    /// Keep only leader -> follower edges (edges[s, follower, leader] = 1).
    #[arg(long)]
    pub directed: bool,

    /// Clamp pixel positions to the image (0..width x 0..height) before
    /// differencing, as the original converter did.
    #[arg(long)]
    pub clip: bool,

    /// backward: vel[t] = loc[t] - loc[t-1] (vel[0] = vel[1]); forward:
    /// vel[t] = loc[t+1] - loc[t] (vel[T-1] = vel[T-2]), the original converter's.
    #[arg(long, value_enum, default_value = "backward")]
    pub velocity: VelocityArg,

    /// Also write dynamic_edges_<split>.npy, uint8 [scenarios, frames, cars, cars]:
    /// per frame, edges[i, j] = 1 when car j bound car i's speed (interactions.csv;
    /// city world only), for time-varying graph methods such as dNRI.
    #[arg(long)]
    pub dynamic: bool,

    /// The graph `edges` holds: designed (leader-follower edges), causal or
    /// direct (measured by intervention; not with gen --no-effects).
    #[arg(long, value_enum, default_value = "designed")]
    pub graph: GraphArg,

    /// No output but errors (the files written are not listed).
    #[arg(short, long)]
    pub quiet: bool,
}

#[derive(Debug, Args)]
pub struct ExportVcdnArgs {
    #[command(flatten)]
    pub dir: ExportDirArgs,

    /// The graph `rels` and `edges` link: designed (leader-follower edges),
    /// causal or direct (measured by intervention; not with gen --no-effects).
    #[arg(long, value_enum, default_value = "designed")]
    pub graph: GraphArg,
}

/// A causal graph of a dataset.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum GraphArg {
    /// Leader-follower pairs, as designed (scenario.json `edges`).
    Designed,
    /// Pairs where intervening on the first car moves the second (`causal_edges`).
    Causal,
    /// The causal pairs where the second car reacts to the first itself (`direct_edges`).
    Direct,
}

impl From<GraphArg> for GraphKind {
    fn from(g: GraphArg) -> GraphKind {
        match g {
            GraphArg::Designed => GraphKind::Designed,
            GraphArg::Causal => GraphKind::Causal,
            GraphArg::Direct => GraphKind::Direct,
        }
    }
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
    #[arg(long, value_name = "N", allow_negative_numbers = true, value_parser = clap::value_parser!(u32).range(1..))]
    pub limit: Option<u32>,

    /// Worker threads [default: every core]. Output is identical for any value.
    #[arg(short = 'j', long = "threads", value_name = "THREADS", value_parser = clap::value_parser!(u32).range(1..=MAX_THREADS as i64))]
    pub threads: Option<u32>,

    /// Write scenario.json and the CSV logs only, no PNG frames or masks.
    #[arg(long)]
    pub no_images: bool,

    /// Also write NS-DR annotations.json per scenario: every car's mask per
    /// frame as COCO RLE (pycocotools.mask.decode reads it).
    #[arg(long, conflicts_with = "no_images")]
    pub annotations: bool,

    /// Skip the interventional ground truth (effects.csv, `causal_edges` and
    /// `direct_edges` in scenario.json): only the designed graph, and no
    /// re-runs (each scenario is otherwise simulated again twice per car).
    #[arg(long)]
    pub no_effects: bool,

    #[command(flatten)]
    pub lights: LightsFlag,

    /// How scenarios are stored: `folders` (a folder each) or `tar`: whole
    /// scenarios packed into WebDataset-style tar files of
    /// --scenarios-per-tar each, `<group>/<split>/<first>-<last>.tar`, with
    /// the folders' files and bytes inside (`tar -xf` gives the folders).
    /// For cluster file systems: the paper-size city is a few hundred files.
    #[arg(long, value_enum, default_value_t = FormatArg::Folders)]
    pub format: FormatArg,

    /// With --format tar: scenarios per tar file (the last of a split may
    /// hold fewer) [default: 64].
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=1_000_000))]
    pub scenarios_per_tar: Option<u32>,

    /// Generate only shard K of N (0 <= K < N), e.g. from a Slurm array or a
    /// Kubernetes Indexed Job; combine the shards with `causalcity merge`.
    #[arg(long, value_name = "K/N")]
    pub shard: Option<Shard>,

    /// Replace a dataset made from another spec or version in --out. Removes
    /// only what causalcity wrote (its manifests and group folders).
    #[arg(long)]
    pub force: bool,

    /// Write even when the disk looks too small. Before it starts, gen writes
    /// one scenario of the most cars, measures it and refuses (exit 2, with the figures) when
    /// that many bytes for every scenario still to write exceed the free space.
    #[arg(long)]
    pub force_space: bool,

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
pub struct PackArgs {
    /// The dataset of scenario folders to pack (the one holding
    /// manifest.json), or a counterfactual sweep of pair folders (sweep.json);
    /// only read.
    #[arg(value_name = "DATASET")]
    pub dataset: PathBuf,

    /// The folder to write the packed dataset into (empty, or an earlier pack run's to resume).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,

    /// Scenarios (or pairs) per tar file (the last of a split may hold fewer).
    #[arg(long, value_name = "N", default_value_t = DEFAULT_SCENARIOS_PER_TAR, value_parser = clap::value_parser!(u32).range(1..=1_000_000))]
    pub scenarios_per_tar: u32,

    /// Worker threads [default: every core]. Output is identical for any value.
    #[arg(short = 'j', long = "threads", value_name = "THREADS", value_parser = clap::value_parser!(u32).range(1..=MAX_THREADS as i64))]
    pub threads: Option<u32>,

    /// No progress output.
    #[arg(short, long)]
    pub quiet: bool,
}

#[derive(Debug, Args)]
pub struct ValidateArgs {
    /// Dataset folder (the one holding manifest.json).
    #[arg(value_name = "DIR")]
    pub dir: PathBuf,

    /// Worker threads [default: every core].
    #[arg(short = 'j', long = "threads", value_name = "THREADS", value_parser = clap::value_parser!(u32).range(1..=MAX_THREADS as i64))]
    pub threads: Option<u32>,

    /// Print the report as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

/// `--world`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum WorldArg {
    /// No agency: constant speed along the route, no lights, no collisions.
    Toy,
    /// Agency: car-following, lights, merges, collisions, confounders.
    City,
}

impl From<WorldArg> for WorldKind {
    fn from(w: WorldArg) -> WorldKind {
        match w {
            WorldArg::Toy => WorldKind::Toy,
            WorldArg::City => WorldKind::City,
        }
    }
}

/// `gen --format`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum FormatArg {
    /// A folder per scenario.
    Folders,
    /// Tar files of whole scenarios (--scenarios-per-tar each).
    Tar,
}

/// `--format` and `--scenarios-per-tar` (of `gen` and `counterfactual
/// --sweep`) as one packing.
fn packing(format: FormatArg, per_tar: Option<u32>) -> Result<Packing, Error> {
    match (format, per_tar) {
        (FormatArg::Folders, None) => Ok(Packing::Folders),
        (FormatArg::Folders, Some(n)) => {
            Err(Error::input(format!("--scenarios-per-tar {n} packs tar files: give it with --format tar")))
        }
        (FormatArg::Tar, n) => Ok(Packing::Tar { per_tar: n.unwrap_or(DEFAULT_SCENARIOS_PER_TAR) }),
    }
}

/// `gen --scenarios-per-tar`'s default: the paper-size city (25,000
/// scenarios) in about 400 tars, a few MB each without images and a few
/// hundred MB with them (WebDataset's advice: 100 MB to 1 GB).
pub const DEFAULT_SCENARIOS_PER_TAR: u32 = 64;

/// `--lights` of `gen`, `run` and `counterfactual`.
#[derive(Debug, Args)]
pub struct LightsFlag {
    /// City world: how the lights' colours are logged. `changes` (the
    /// default): light_changes.csv, every light at frame 0 and then only
    /// where its colour changes; `frames`: lights.csv, every light at every
    /// frame, about ten times the bytes (most of a poses-only scenario's).
    /// Same columns; the Python package, validate and stats read both.
    #[arg(long, value_enum, default_value_t = LightsArg::Changes)]
    pub lights: LightsArg,
}

impl LightsFlag {
    /// The light log the flag asks for.
    pub fn log(&self) -> LightsLog {
        self.lights.into()
    }
}

/// `--lights`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum LightsArg {
    /// lights.csv: every light at every frame.
    Frames,
    /// light_changes.csv: every light at frame 0, then where it changes.
    Changes,
}

impl From<LightsArg> for LightsLog {
    fn from(l: LightsArg) -> LightsLog {
        match l {
            LightsArg::Frames => LightsLog::Frames,
            LightsArg::Changes => LightsLog::Changes,
        }
    }
}

/// `--split`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum SplitArg {
    Train,
    Val,
    Test,
}

impl From<SplitArg> for Split {
    fn from(s: SplitArg) -> Split {
        match s {
            SplitArg::Train => Split::Train,
            SplitArg::Val => Split::Val,
            SplitArg::Test => Split::Test,
        }
    }
}

/// `export nri --layout`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum NriLayoutArg {
    /// loc/vel [scenarios, frames, cars, 2]; edges with the identity.
    Causalcity,
    /// loc/vel [scenarios, frames, 2, cars]; edges without self loops.
    Nri,
}

impl From<NriLayoutArg> for NriLayout {
    fn from(l: NriLayoutArg) -> NriLayout {
        match l {
            NriLayoutArg::Causalcity => NriLayout::Causalcity,
            NriLayoutArg::Nri => NriLayout::Nri,
        }
    }
}

/// `export nri --velocity`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum VelocityArg {
    /// vel[t] = loc[t] - loc[t-1], the first frame taking the second's.
    Backward,
    /// vel[t] = loc[t+1] - loc[t], the last frame repeating (the original converter).
    Forward,
}

impl From<VelocityArg> for Velocity {
    fn from(v: VelocityArg) -> Velocity {
        match v {
            VelocityArg::Backward => Velocity::Backward,
            VelocityArg::Forward => Velocity::Forward,
        }
    }
}

/// `counterfactual --kinds`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum SweepKindArg {
    /// Stop a random car for 2-6 s.
    Stop,
    /// Set a random car's desired speed to 30-60 % of the spec's.
    SetDesiredSpeed,
    /// Make a random car run red lights.
    RunRedLight,
    /// Remove a random car.
    Remove,
}

impl SweepKindArg {
    /// Every kind: `--kinds`' default.
    fn every() -> Vec<SweepKindArg> {
        vec![SweepKindArg::Stop, SweepKindArg::SetDesiredSpeed, SweepKindArg::RunRedLight, SweepKindArg::Remove]
    }
}

impl From<SweepKindArg> for SweepKind {
    fn from(k: SweepKindArg) -> SweepKind {
        match k {
            SweepKindArg::Stop => SweepKind::Stop,
            SweepKindArg::SetDesiredSpeed => SweepKind::SetDesiredSpeed,
            SweepKindArg::RunRedLight => SweepKind::RunRedLight,
            SweepKindArg::Remove => SweepKind::Remove,
        }
    }
}

/// A finite number above 0.
fn positive_number(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(x) if x.is_finite() && x > 0.0 => Ok(x),
        _ => Err(format!("{text:?} is not allowed: use a number above 0")),
    }
}

/// A number in (0, 1].
fn scale_factor(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(x) if x > 0.0 && x <= 1.0 => Ok(x),
        _ => Err(format!("{text:?} is not allowed: use a number above 0 and at most 1")),
    }
}

fn progress(quiet: bool) -> ProgressMode {
    if quiet {
        ProgressMode::Quiet
    } else {
        ProgressMode::Auto
    }
}

/// `export`'s formats.
fn export(command: ExportCommand) -> Result<(), Error> {
    match command {
        ExportCommand::Nri(args) => {
            let options = NriOptions {
                layout: args.layout.into(),
                suffix: args.suffix,
                directed: args.directed,
                clip: args.clip,
                velocity: args.velocity.into(),
                dynamic: args.dynamic,
                graph: args.graph.into(),
            };
            for line in export_nri(&args.dataset, &args.out, &options)? {
                if !args.quiet {
                    say(line)?;
                }
            }
            Ok(())
        }
        ExportCommand::Nsdr(args) => {
            let n = export_nsdr(&args.dataset, &args.out, progress(args.quiet))?;
            say(format!("wrote annotations.json for {n} scenarios under {}", args.out.display()))
        }
        ExportCommand::Vcdn(args) => {
            let ExportVcdnArgs { dir, graph } = args;
            let n = export_vcdn(&dir.dataset, &dir.out, graph.into(), progress(dir.quiet))?;
            say(format!("wrote {n} V-CDN HDF5 files under {}", dir.out.display()))
        }
    }
}

/// Writes `text` to stdout. A closed pipe (`causalcity stats D | head`)
/// ends the program quietly.
fn say(text: impl Display) -> Result<(), Error> {
    let mut stdout = std::io::stdout().lock();
    match writeln!(stdout, "{text}").and_then(|()| stdout.flush()) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => std::process::exit(0),
        Err(e) => Err(Error::failure(format!("cannot write to stdout: {e}"))),
    }
}

/// The value as pretty JSON, or its text form.
fn report<T: Serialize + Display>(value: &T, json: bool) -> Result<(), Error> {
    if json {
        say(serde_json::to_string_pretty(value).map_err(Error::failure)?)
    } else {
        say(value.to_string().trim_end())
    }
}

/// Runs the parsed command line.
pub fn run(cli: Cli) -> Result<(), Error> {
    match cli.command {
        Command::Gen(args) => {
            let options = GenOptions {
                spec_path: args.spec,
                out: args.out,
                limit: args.limit,
                threads: args.threads.map(|t| t as usize),
                images: !args.no_images,
                annotations: args.annotations,
                effects: !args.no_effects,
                lights: args.lights.log(),
                packing: packing(args.format, args.scenarios_per_tar)?,
                progress: progress(args.quiet),
                shard: args.shard,
                force: args.force,
                force_space: args.force_space,
                fsync: args.fsync,
                handle_signals: true,
            };
            report(&generate(&options)?, args.json)
        }
        Command::Merge(args) => {
            causalcity::orchestrate::run::install_quit_handler("merge");
            say(merge(&args.out, &args.shards)?)
        }
        Command::Pack(args) => {
            causalcity::orchestrate::run::install_quit_handler("pack");
            let threads = args.threads.map(|t| t as usize);
            say(pack_dataset(&args.dataset, &args.out, args.scenarios_per_tar, threads, progress(args.quiet))?)
        }
        Command::Export(command) => {
            causalcity::orchestrate::run::install_quit_handler("export");
            export(command)
        }
        Command::Preview(args) => {
            let options = PreviewOptions {
                scale: args.scale,
                every: args.every,
                fps: args.fps,
                masks: args.masks,
                trails: args.trails,
                arrows: args.arrows,
                sheet_frames: args.sheet_frames,
                columns: args.columns,
            };
            say(preview(&args.scenario, &args.out, &options)?)
        }
        Command::Baseline(args) => report(&baseline(&args.dataset, args.max_lag, args.graph.into())?, args.json),
        Command::Evaluate(args) => {
            let mut graphs: Vec<GraphKind> = Vec::new();
            for graph in args.graph.into_iter().map(GraphKind::from) {
                if !graphs.contains(&graph) {
                    graphs.push(graph);
                }
            }
            let options = EvaluateOptions { graphs, history: args.history, threshold: args.threshold };
            // Checked before any scoring: a refused --csv costs nothing.
            let inputs =
                [("the dataset it scores", args.dataset.as_path()), ("the predictions file", &args.predictions)];
            if let (Some(a), Some(b)) = (&args.csv, &args.per_scenario) {
                if causalcity::output::claim::resolve(a) == causalcity::output::claim::resolve(b) {
                    return Err(Error::Input(format!(
                        "--csv and --per-scenario both name {}: give each table its own file",
                        a.display()
                    )));
                }
            }
            use causalcity::analysis::evaluate::{PER_SCENARIO_CSV, TABLE_CSV};
            let claim = |kind| move |path: &std::path::Path| claim_file(path, &inputs, kind);
            let csv = args.csv.as_deref().map(claim(TABLE_CSV)).transpose()?;
            let per_scenario = args.per_scenario.as_deref().map(claim(PER_SCENARIO_CSV)).transpose()?;
            let evaluated = evaluate(&args.dataset, &args.predictions, &options)?;
            if let Some(csv) = csv {
                csv.write(evaluated.to_csv().as_bytes()).map_err(Error::failure)?;
            }
            if let Some(file) = per_scenario {
                file.write(evaluated.per_scenario_csv().as_bytes()).map_err(Error::failure)?;
            }
            if args.json {
                // The table shows them first; JSON carries them, and a person reads them here.
                for warning in &evaluated.warnings {
                    causalcity::progress::note(format_args!("warning: {warning}"));
                }
            }
            report(&evaluated, args.json)
        }
        Command::Run(args) => {
            causalcity::orchestrate::run::install_signal_handler();
            let options = RunOptions {
                scenario_file: args.scenario,
                out: args.out,
                world: args.world.map(Into::into),
                images: !args.no_images,
                annotations: args.annotations,
                lights: args.lights.log(),
                strict: args.strict,
            };
            let written = run_file(&options)?;
            for warning in written.iter().flat_map(|w| &w.warnings) {
                causalcity::progress::note(format_args!("warning: {warning}"));
            }
            if args.json {
                return say(serde_json::to_string_pretty(&written).map_err(Error::failure)?);
            }
            for w in &written {
                say(w)?;
            }
            Ok(())
        }
        Command::Counterfactual(args) => {
            causalcity::orchestrate::run::install_signal_handler();
            let images = !args.no_images;
            if let Some(flag) = args.flag_of_the_other_source() {
                let (this, other) =
                    if args.sweep.is_some() { ("--sweep", "--scenario") } else { ("--scenario", "--sweep") };
                return Err(Error::input(format!(
                    "{flag} belongs to {other}, not {this}: leave it out (it would be ignored); nothing was written"
                )));
            }
            if let Some(spec_path) = args.sweep {
                let options = SweepOptions {
                    spec_path,
                    out: args.out,
                    limit: args.limit,
                    kinds: args.kinds.unwrap_or_else(SweepKindArg::every).into_iter().map(Into::into).collect(),
                    products: Products { images, annotations: false, effects: false, lights: args.lights.log() },
                    packing: packing(args.format.unwrap_or(FormatArg::Folders), args.scenarios_per_tar)?,
                    threads: args.threads.map(|t| t as usize),
                    progress: progress(args.quiet),
                };
                return report(&sweep(&options)?, args.json);
            }
            let Some(scenario_file) = args.scenario else {
                return Err(Error::input("give --scenario FILE or --sweep SPEC"));
            };
            let options = RunOptions {
                scenario_file,
                out: args.out,
                world: args.world.map(Into::into),
                images,
                annotations: false,
                lights: args.lights.log(),
                strict: args.strict,
            };
            let pairs = counterfactual(&options, args.intervention.as_deref())?;
            for warning in pairs.iter().flat_map(|p| &p.warnings) {
                causalcity::progress::note(format_args!("warning: {warning}"));
            }
            let summaries: Vec<_> = pairs.into_iter().map(|p| p.summary).collect();
            if args.json {
                return say(serde_json::to_string_pretty(&summaries).map_err(Error::failure)?);
            }
            for summary in &summaries {
                say(summary)?;
            }
            Ok(())
        }
        Command::Stats(args) => {
            let stats = dataset_stats(&args.dataset)?;
            if args.wide && !args.json {
                return say(stats.table(true).trim_end());
            }
            report(&stats, args.json)
        }
        Command::Map(args) => match (&args.spec, &args.net) {
            (_, Some(net)) => report(&net_view(net, args.out.as_deref(), NET_PICTURE_PX)?, args.json),
            (Some(spec), None) => report(&map_view(spec, args.out.as_deref(), args.town.as_deref())?, args.json),
            (None, None) => Err(Error::Input("map: give --spec FILE or --net FILE".into())),
        },
        Command::Heatmap(args) => {
            let filter = HeatmapFilter { group: args.group, split: args.split.map(Into::into) };
            report(&heatmap(&args.dataset, &args.out, &filter)?, args.json)
        }
        Command::Validate(args) => {
            let found = validate(&args.dir, args.threads.map(|t| t as usize)).map_err(Error::opening)?;
            report(&found, args.json)?;
            if found.problems.is_empty() {
                Ok(())
            } else {
                Err(Error::Failure(match found.problems.len() {
                    1 => "1 problem found".to_string(),
                    n => format!("{n} problems found"),
                }))
            }
        }
    }
}
