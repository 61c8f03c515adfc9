//! `causalcity stats DATASET`: per group and split, what a researcher checks
//! before training: scenarios, cars, mean and 95th-percentile speed (pixels
//! per frame), share of cars that stop (under 0.1 px/frame for 5 frames or
//! more) and that stop on an intersection approach (light stops), scenarios
//! with collisions, red-light runs, leader-follower distance (mean, and the
//! median over pairs of its coefficient of variation), the share of
//! car-frames on camera, the drivers' own lane choice (the share of cars
//! that made a lane change for a turn, the actions adapted or skipped), and
//! city traffic-flow figures (`flow.rs`): median headway and time gap while
//! following, queue discharge at green, and speed on free road; and how far
//! the causal graph is what happened (`interactions.csv`): how often true
//! leader-follower pairs actually interact, and how often non-edge pairs do;
//! and how far the designed graph is the causal one (`effects.csv`'s graphs
//! in scenario.json): designed edges backed by an interventional effect, and
//! effects no design explains.

use super::flow::{median, read_scenario_flow, FlowSamples};
use crate::dataset::{edge_pairs, Dataset};
use crate::map::CityMap;
use crate::spec::Split;
use rayon::prelude::*;
use serde::Serialize;
use std::fmt;
use std::path::Path;

/// Speed below which a car counts as standing, pixels per frame.
pub const STOP_SPEED_PX: f64 = 0.1;
/// Frames a car must stand to count as stopped.
pub const STOP_FRAMES: usize = 5;
/// How far before an intersection box a stop counts as a stop at its light, metres.
const APPROACH_M: f64 = 12.0;
const HISTOGRAM_BIN_PX: f64 = 0.01;
/// Share of its frames in which a pair must interact to count as "mostly
/// interacting".
pub const MOSTLY: f64 = 0.5;
const HISTOGRAM_BINS: usize = 3001;

/// Statistics of one group and split.
#[derive(Debug, Clone, Serialize)]
pub struct SplitStats {
    pub group: String,
    pub split: String,
    pub scenarios: usize,
    pub cars: usize,
    pub mean_speed_px: f64,
    pub p95_speed_px: f64,
    /// The same speeds in metres per second (poses.csv's `speed`).
    pub mean_speed_m_s: f64,
    pub p95_speed_m_s: f64,
    pub stopped_share: f64,
    pub light_stop_share: f64,
    pub collision_scenarios: usize,
    pub collisions: usize,
    pub red_light_runs: usize,
    pub gap_mean_m: Option<f64>,
    pub gap_cv_median: Option<f64>,
    pub in_view_share: f64,
    /// Share of cars that changed lanes for a turn at least once.
    pub lane_change_share: f64,
    pub actions_adapted: usize,
    pub actions_skipped: usize,
    /// City: median front-to-front headway while following, seconds.
    pub headway_median_s: Option<f64>,
    /// City: median time gap while following (bumper gap less min gap,
    /// over speed), seconds.
    pub time_gap_median_s: Option<f64>,
    /// City: queue discharge at green, vehicles per second per lane.
    pub discharge_per_lane_s: Option<f64>,
    /// City: median speed over desired speed on free road, moving.
    pub free_speed_ratio_median: Option<f64>,
    /// City: true pairs (a leader and its follower), as one of them binding
    /// the other's speed in interactions.csv (car, conflict, give way, collision).
    pub edge_pairs: PairInteraction,
    /// City: every other pair of cars, in the same sense.
    pub non_edge_pairs: PairInteraction,
    /// Designed against interventional edges; absent without effects.
    pub causal: Option<CausalTally>,
}

/// Designed leader-follower edges against the interventional ground truth
/// (scenario.json's `causal_edges` and `direct_edges`), summed over scenarios.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct CausalTally {
    pub designed_edges: usize,
    /// Designed edges that some intervention on the leader backs.
    pub designed_with_effect: usize,
    pub causal_edges: usize,
    pub direct_edges: usize,
    /// Causal edges that are not designed edges.
    pub causal_not_designed: usize,
}

impl CausalTally {
    fn merge(&mut self, other: &CausalTally) {
        self.designed_edges += other.designed_edges;
        self.designed_with_effect += other.designed_with_effect;
        self.causal_edges += other.causal_edges;
        self.direct_edges += other.direct_edges;
        self.causal_not_designed += other.causal_not_designed;
    }

    /// Share of designed edges backed by an effect.
    pub fn backed_share(&self) -> Option<f64> {
        (self.designed_edges > 0).then(|| self.designed_with_effect as f64 / self.designed_edges as f64)
    }

    /// Share of causal edges that no designed edge explains.
    pub fn unexplained_share(&self) -> Option<f64> {
        (self.causal_edges > 0).then(|| self.causal_not_designed as f64 / self.causal_edges as f64)
    }

    /// The tally of one scenario.json (`None` without effects).
    pub fn of_scenario(scenario: &serde_json::Value) -> Option<CausalTally> {
        let pairs = |field: &str| edge_pairs(scenario, field);
        let (designed, causal, direct) = (pairs("edges")?, pairs("causal_edges")?, pairs("direct_edges")?);
        Some(CausalTally {
            designed_edges: designed.len(),
            designed_with_effect: designed.iter().filter(|e| causal.contains(e)).count(),
            causal_edges: causal.len(),
            direct_edges: direct.len(),
            causal_not_designed: causal.iter().filter(|e| !designed.contains(e)).count(),
        })
    }
}

/// How often a set of car pairs actually interacts (city world).
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct PairInteraction {
    pub pairs: usize,
    /// Share of pair-frames in which one car of the pair binds the other.
    pub frame_share: Option<f64>,
    /// Share of pairs that interact in at least [`MOSTLY`] of the frames.
    pub mostly_share: Option<f64>,
    #[serde(skip)]
    frames: usize,
    #[serde(skip)]
    interacting_frames: usize,
    #[serde(skip)]
    mostly: usize,
}

impl PairInteraction {
    /// Counts one pair that interacted in `interacting` of `frames` frames.
    fn add(&mut self, interacting: usize, frames: usize) {
        self.pairs += 1;
        self.frames += frames;
        self.interacting_frames += interacting;
        self.mostly += (interacting as f64 >= MOSTLY * frames as f64 && frames > 0) as usize;
    }

    fn merge(&mut self, other: &PairInteraction) {
        self.pairs += other.pairs;
        self.frames += other.frames;
        self.interacting_frames += other.interacting_frames;
        self.mostly += other.mostly;
    }

    fn finish(mut self) -> PairInteraction {
        self.frame_share = (self.frames > 0).then(|| self.interacting_frames as f64 / self.frames as f64);
        self.mostly_share = (self.pairs > 0).then(|| self.mostly as f64 / self.pairs as f64);
        self
    }
}

/// The whole table.
#[derive(Debug, Clone, Serialize)]
pub struct DatasetStats {
    pub world: String,
    pub rows: Vec<SplitStats>,
}

/// One column of the `stats` table: its heading, width, what it means and
/// how a row shows it.
struct Column {
    heading: &'static str,
    width: usize,
    /// Shown without `--wide`.
    narrow: bool,
    meaning: String,
    value: fn(&SplitStats) -> String,
}

fn opt(v: Option<f64>, d: usize) -> String {
    v.map_or("-".to_string(), |v| format!("{v:.d$}"))
}

fn pct(v: Option<f64>) -> String {
    v.map_or("-".to_string(), |v| format!("{:.1}%", 100.0 * v))
}

/// A column of the table.
fn column(
    heading: &'static str,
    width: usize,
    narrow: bool,
    meaning: impl Into<String>,
    value: fn(&SplitStats) -> String,
) -> Column {
    Column { heading, width, narrow, meaning: meaning.into(), value }
}

/// The columns; `px_per_m_s` (pixels per frame in one metre per second,
/// when known) puts the stop threshold in m/s as well.
fn columns(px_per_m_s: Option<f64>) -> Vec<Column> {
    let stood = match px_per_m_s {
        Some(k) => format!("under {:.2} m/s ({STOP_SPEED_PX} px per frame)", STOP_SPEED_PX / k),
        None => format!("under {STOP_SPEED_PX} px per frame"),
    };
    vec![
        column("scen", 5, true, "scenarios", |r| r.scenarios.to_string()),
        column("cars", 5, true, "cars in them", |r| r.cars.to_string()),
        column("speed", 6, true, "mean speed, m/s", |r| format!("{:.2}", r.mean_speed_m_s)),
        column("p95", 6, true, "95th-percentile speed, m/s", |r| format!("{:.2}", r.p95_speed_m_s)),
        column("stopped", 7, true, format!("cars that stood still, {stood}, for {STOP_FRAMES}+ frames"), |r| {
            format!("{:.0}%", 100.0 * r.stopped_share)
        }),
        column(
            "lights",
            7,
            true,
            format!("cars that stopped within {APPROACH_M} m of an intersection at a red or yellow"),
            |r| format!("{:.0}%", 100.0 * r.light_stop_share),
        ),
        column("colli", 6, true, "scenarios with a collision", |r| r.collision_scenarios.to_string()),
        column("reds", 5, true, "red lights run", |r| r.red_light_runs.to_string()),
        column("gap m", 6, true, "mean leader-follower gap, metres", |r| opt(r.gap_mean_m, 2)),
        column("gapCV", 6, false, "median variation of a pair's gap (std / mean)", |r| opt(r.gap_cv_median, 2)),
        column("inview", 6, true, "car-frames inside the bird's-eye image", |r| {
            format!("{:.0}%", 100.0 * r.in_view_share)
        }),
        column("lanechg", 7, false, "cars that changed lanes for a turn", |r| {
            format!("{:.0}%", 100.0 * r.lane_change_share)
        }),
        column("adapt", 5, false, "actions adapted (events.csv)", |r| r.actions_adapted.to_string()),
        column("skip", 5, false, "actions skipped (events.csv)", |r| r.actions_skipped.to_string()),
        column("hdwy", 5, false, "median headway while following, s", |r| opt(r.headway_median_s, 2)),
        column("tgap", 5, false, "median time gap while following, s", |r| opt(r.time_gap_median_s, 2)),
        column("disch", 5, false, "queue discharge at green, vehicles/s/lane (- when no queue left at a green)", |r| {
            opt(r.discharge_per_lane_s, 2)
        }),
        column("free", 5, false, "median speed over desired speed on free road", |r| opt(r.free_speed_ratio_median, 2)),
        column("e-int", 6, false, "leader-follower pair-frames interacting (interactions.csv)", |r| {
            pct(r.edge_pairs.frame_share)
        }),
        column(
            "e-mst",
            6,
            false,
            format!("leader-follower pairs interacting in {:.0}%+ of frames", 100.0 * MOSTLY),
            |r| pct(r.edge_pairs.mostly_share),
        ),
        column("n-int", 6, false, "other pair-frames interacting", |r| pct(r.non_edge_pairs.frame_share)),
        column("n-mst", 6, false, format!("other pairs interacting in {:.0}%+ of frames", 100.0 * MOSTLY), |r| {
            pct(r.non_edge_pairs.mostly_share)
        }),
        column("backed", 6, true, "designed edges an intervention on the leader backs (effects.csv)", |r| {
            pct(r.causal.and_then(|c| c.backed_share()))
        }),
        column("c/scen", 6, true, "causal edges per scenario", |r| {
            opt(r.causal.map(|c| c.causal_edges as f64 / r.scenarios.max(1) as f64), 2)
        }),
        column("unexpl", 6, true, "causal edges that are no designed edge", |r| {
            pct(r.causal.and_then(|c| c.unexplained_share()))
        }),
    ]
}

impl DatasetStats {
    /// The table `stats` prints: about 110 columns wide with the main
    /// figures, every figure with `wide`; then one line per column saying
    /// what it means.
    pub fn table(&self, wide: bool) -> String {
        use std::fmt::Write;
        let px_per_m_s = self.rows.iter().find(|r| r.mean_speed_m_s > 0.0).map(|r| r.mean_speed_px / r.mean_speed_m_s);
        let columns: Vec<Column> = columns(px_per_m_s).into_iter().filter(|c| wide || c.narrow).collect();
        let mut out = String::new();
        let _ = write!(out, "{:<16} {:<5}", "group", "split");
        for c in &columns {
            let _ = write!(out, " {:>w$}", c.heading, w = c.width);
        }
        out.push('\n');
        for r in &self.rows {
            let _ = write!(out, "{:<16} {:<5}", r.group, r.split);
            for c in &columns {
                let _ = write!(out, " {:>w$}", (c.value)(r), w = c.width);
            }
            out.push('\n');
        }
        out.push('\n');
        for c in &columns {
            let _ = writeln!(out, "  {:<8} {}", c.heading, c.meaning);
        }
        if !wide {
            out.push_str(
                "  (--wide adds gap variation, lane changes, adaptations, headways, discharge and pair interactions)\n",
            );
        }
        out
    }
}

impl fmt::Display for DatasetStats {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.table(false).trim_end())
    }
}

/// One scenario's contribution.
#[derive(Default)]
struct Tally {
    cars: usize,
    car_frames: usize,
    speed_sum: f64,
    /// Pixels per frame in one metre per second (the same for every
    /// scenario of a dataset: one camera, one frame interval).
    px_per_frame_per_m_s: f64,
    histogram: Vec<u64>,
    stopped: usize,
    light_stops: usize,
    collisions: usize,
    red_light_runs: usize,
    gap_means: Vec<f64>,
    gap_cvs: Vec<f64>,
    in_view: usize,
    /// Cars with a `lane_change` event.
    lane_changers: usize,
    actions_adapted: usize,
    actions_skipped: usize,
    flow: FlowSamples,
    edge_pairs: PairInteraction,
    non_edge_pairs: PairInteraction,
    causal: Option<CausalTally>,
}

/// Computes the statistics of the dataset in `dir`.
/// A folder that is no finished dataset, or one whose scenario files
/// cannot be read, is bad input (exit 2, [`Error::damaged`]).
pub fn dataset_stats(dir: &Path) -> Result<DatasetStats, crate::error::Error> {
    let dataset = Dataset::open_complete(dir).map_err(crate::error::Error::opening)?;
    let mut rows = Vec::new();
    for group in &dataset.spec().groups {
        for split in Split::ALL {
            let tallies: Vec<Tally> = dataset
                .with_split(&group.name(), split, |dirs| {
                    dirs.par_iter().map(|d| tally(d, dataset.expansion.towns())).collect()
                })
                .map_err(|e| crate::error::Error::reading(dir, e))?;
            if !tallies.is_empty() {
                rows.push(combine(group.name(), split.name(), tallies));
            }
        }
    }
    Ok(DatasetStats { world: dataset.spec().world.name().into(), rows })
}

fn combine(group: String, split: &str, tallies: Vec<Tally>) -> SplitStats {
    let scenarios = tallies.len();
    let mut all = Tally { histogram: vec![0; HISTOGRAM_BINS], ..Tally::default() };
    let mut collision_scenarios = 0;
    for t in tallies {
        all.cars += t.cars;
        all.car_frames += t.car_frames;
        all.speed_sum += t.speed_sum;
        all.px_per_frame_per_m_s = all.px_per_frame_per_m_s.max(t.px_per_frame_per_m_s);
        for (a, b) in all.histogram.iter_mut().zip(&t.histogram) {
            *a += b;
        }
        all.stopped += t.stopped;
        all.light_stops += t.light_stops;
        all.collisions += t.collisions;
        collision_scenarios += (t.collisions > 0) as usize;
        all.red_light_runs += t.red_light_runs;
        all.gap_means.extend(t.gap_means);
        all.gap_cvs.extend(t.gap_cvs);
        all.in_view += t.in_view;
        all.lane_changers += t.lane_changers;
        all.actions_adapted += t.actions_adapted;
        all.actions_skipped += t.actions_skipped;
        all.flow.extend(t.flow);
        all.edge_pairs.merge(&t.edge_pairs);
        all.non_edge_pairs.merge(&t.non_edge_pairs);
        if let Some(c) = &t.causal {
            all.causal.get_or_insert_with(CausalTally::default).merge(c);
        }
    }
    let target = (0.95 * all.car_frames as f64).ceil() as u64;
    let mut seen = 0;
    let mut p95 = 0.0;
    for (i, n) in all.histogram.iter().enumerate() {
        seen += n;
        if seen >= target {
            p95 = i as f64 * HISTOGRAM_BIN_PX;
            break;
        }
    }
    let frames = all.car_frames.max(1) as f64;
    SplitStats {
        group,
        split: split.into(),
        scenarios,
        cars: all.cars,
        mean_speed_px: all.speed_sum / frames,
        p95_speed_px: p95,
        mean_speed_m_s: if all.px_per_frame_per_m_s > 0.0 {
            all.speed_sum / frames / all.px_per_frame_per_m_s
        } else {
            0.0
        },
        p95_speed_m_s: if all.px_per_frame_per_m_s > 0.0 { p95 / all.px_per_frame_per_m_s } else { 0.0 },
        stopped_share: all.stopped as f64 / all.cars.max(1) as f64,
        light_stop_share: all.light_stops as f64 / all.cars.max(1) as f64,
        collision_scenarios,
        collisions: all.collisions,
        red_light_runs: all.red_light_runs,
        gap_mean_m: (!all.gap_means.is_empty()).then(|| all.gap_means.iter().sum::<f64>() / all.gap_means.len() as f64),
        // (the upper middle one was taken: the larger of two pairs)
        gap_cv_median: median(&mut all.gap_cvs),
        in_view_share: all.in_view as f64 / frames,
        lane_change_share: all.lane_changers as f64 / all.cars.max(1) as f64,
        actions_adapted: all.actions_adapted,
        actions_skipped: all.actions_skipped,
        headway_median_s: median(&mut all.flow.headways_s),
        time_gap_median_s: median(&mut all.flow.time_gaps_s),
        discharge_per_lane_s: median(&mut all.flow.discharge_headways_s).filter(|&h| h > 0.0).map(|h| 1.0 / h),
        free_speed_ratio_median: median(&mut all.flow.free_speed_ratios),
        edge_pairs: all.edge_pairs.finish(),
        non_edge_pairs: all.non_edge_pairs.finish(),
        causal: all.causal,
    }
}

/// (frame, intersection, approach) where the straight signal showed red or
/// yellow, from lights.csv (none without lights).
fn red_approaches(
    dir: &Path,
    scenario: &serde_json::Value,
) -> Result<std::collections::HashSet<(usize, String, char)>, String> {
    let mut red = std::collections::HashSet::new();
    let layout = [crate::output::layout::LIGHTS_CSV, crate::output::layout::LIGHT_CHANGES_CSV];
    if !layout.iter().any(|file| dir.join(file).exists()) {
        return Ok(red);
    }
    // Either layout (lights.csv or gen --lights changes), every frame.
    let frames = scenario["frames"].as_u64().unwrap_or(0) as usize;
    let interval = scenario["frame_interval"].as_f64().unwrap_or(1.0);
    let lights = crate::dataset::readback::read_light_log(dir, frames, interval)?;
    let count = lights.names.len();
    for (k, name) in lights.names.iter().enumerate() {
        let mut parts = name.rsplitn(3, '/');
        let (Some("straight"), Some(side), Some(i)) = (parts.next(), parts.next(), parts.next()) else { continue };
        for frame in 0..frames {
            if lights.colour[frame * count + k] != 0 {
                red.insert((frame, i.to_string(), side.chars().next().unwrap_or('?')));
            }
        }
    }
    Ok(red)
}

fn tally(dir: &Path, towns: &[crate::plan::expand::Planner]) -> Result<Tally, String> {
    let path = dir.join("scenario.json");
    let bytes = crate::input::read_record(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    // Checked as every reader checks it (car ids, edges, frames).
    let summary = crate::dataset::ScenarioSummary::parse(&bytes, &path, crate::dataset::GraphKind::Designed)?;
    let scenario: serde_json::Value = serde_json::from_slice(&bytes).map_err(|e| format!("{}: {e}", path.display()))?;
    // The scenario's town (a dataset of several names it), else the only one.
    let map: &CityMap = match scenario["town"].as_str() {
        Some(name) => {
            &towns
                .iter()
                .find(|t| t.name == name)
                .ok_or_else(|| format!("{}: town {name:?} is not one the dataset's spec draws", path.display()))?
                .map
        }
        None => &towns[0].map,
    };
    let cars = scenario["cars"].as_array().map_or(0, Vec::len);
    let to_px = scenario["frame_interval"].as_f64().unwrap_or(0.0)
        * scenario["camera"]["pixels_per_metre"].as_f64().unwrap_or(0.0);
    // Every frame of every car, once, as every reader takes it (an empty
    // or edited log gave speeds of 0 or NaN before).
    let log = crate::dataset::PoseLog::read(dir, summary.frames as usize, cars)?;
    // Per car: (x, y, speed px/frame) per frame.
    let mut tracks: Vec<Vec<(f64, f64, f64)>> = vec![Vec::with_capacity(log.frames); cars];
    let red = red_approaches(dir, &scenario)?;
    let causal = CausalTally::of_scenario(&scenario);
    let mut t =
        Tally { cars, histogram: vec![0; HISTOGRAM_BINS], causal, px_per_frame_per_m_s: to_px, ..Tally::default() };
    for frame in 0..log.frames {
        for (car, pose) in log.frame(frame).iter().enumerate() {
            let px = pose.speed * to_px;
            tracks[car].push((pose.x, pose.y, px));
            t.car_frames += 1;
            t.speed_sum += px;
            t.histogram[((px / HISTOGRAM_BIN_PX).round() as usize).min(HISTOGRAM_BINS - 1)] += 1;
            t.in_view += pose.in_view as usize;
        }
    }
    let hw = map.layout.road_half_width();
    // The intersection arm a point stands on, as (intersection, the side
    // its traffic arrives from).
    let approach = |x: f64, y: f64| {
        map.intersections.iter().find_map(|i| {
            let (dx, dy) = (x - i.centre.x, y - i.centre.y);
            let arm = |along: f64, across: f64| across.abs() < hw && along.abs() >= hw && along.abs() < hw + APPROACH_M;
            let side = if arm(dy, dx) {
                if dy > 0.0 {
                    'N'
                } else {
                    'S'
                }
            } else if arm(dx, dy) {
                if dx > 0.0 {
                    'E'
                } else {
                    'W'
                }
            } else {
                return None;
            };
            Some((i.name.as_str(), side))
        })
    };
    for track in &tracks {
        let (mut run, mut stopped, mut light) = (0, false, false);
        for (frame, &(x, y, px)) in track.iter().enumerate() {
            run = if px < STOP_SPEED_PX { run + 1 } else { 0 };
            if run == STOP_FRAMES {
                stopped = true;
                // The stop began STOP_FRAMES - 1 frames ago.
                let began = frame + 1 - STOP_FRAMES;
                light |= approach(x, y).is_some_and(|(i, side)| red.contains(&(began, i.to_string(), side)));
            }
        }
        t.stopped += stopped as usize;
        t.light_stops += light as usize;
    }
    for edge in scenario["edges"].as_array().into_iter().flatten() {
        let (Some(l), Some(f)) = (edge[0].as_u64(), edge[1].as_u64()) else { continue };
        let (a, b) = (&tracks[l as usize], &tracks[f as usize]);
        let gaps: Vec<f64> = a.iter().zip(b).map(|(p, q)| ((p.0 - q.0).powi(2) + (p.1 - q.1).powi(2)).sqrt()).collect();
        if gaps.is_empty() {
            continue;
        }
        let mean = gaps.iter().sum::<f64>() / gaps.len() as f64;
        let sd = (gaps.iter().map(|g| (g - mean).powi(2)).sum::<f64>() / gaps.len() as f64).sqrt();
        t.gap_means.push(mean);
        t.gap_cvs.push(if mean > 0.0 { sd / mean } else { 0.0 });
    }
    let events = dir.join("events.csv");
    if events.exists() {
        let mut reader = csv::Reader::from_path(&events).map_err(|e| format!("{}: {e}", events.display()))?;
        let columns = reader.headers().map_err(|e| format!("{}: {e}", events.display()))?;
        if !columns.iter().eq(crate::output::logs::EVENT_COLUMNS.iter().copied()) {
            return Err(format!(
                "{}: columns {:?}, expected {}",
                events.display(),
                columns.iter().collect::<Vec<_>>(),
                crate::output::logs::EVENT_COLUMNS.join(",")
            ));
        }
        let mut changers = std::collections::BTreeSet::new();
        for row in reader.records() {
            let row = row.map_err(|e| format!("{}: {e}", events.display()))?;
            match row.get(2) {
                Some("collision") => t.collisions += 1,
                Some("red_light_run") => t.red_light_runs += 1,
                Some("lane_change") => {
                    changers.insert(row.get(3).unwrap_or_default().to_string());
                }
                Some("action_adapted") => t.actions_adapted += 1,
                Some("action_skipped") => t.actions_skipped += 1,
                _ => {}
            }
        }
        t.lane_changers = changers.len();
    }
    if let Some(flow) = read_scenario_flow(dir, map)? {
        t.flow = flow.samples();
        let mut linked = vec![false; cars * cars];
        for edge in scenario["edges"].as_array().into_iter().flatten() {
            if let (Some(l), Some(f)) = (edge[0].as_u64(), edge[1].as_u64()) {
                let (l, f) = (l as usize, f as usize);
                if l < cars && f < cars {
                    linked[l * cars + f] = true;
                    linked[f * cars + l] = true;
                }
            }
        }
        // Per unordered pair (a < b), the frames in which one binds the other.
        let mut together = vec![0usize; cars * cars];
        for frame in &flow.named {
            for (a, other) in frame.iter().enumerate() {
                if let Some(b) = other.filter(|&b| b != a) {
                    // Counted once per frame when both bind each other.
                    if frame[b] != Some(a) || a < b {
                        together[a.min(b) * cars + a.max(b)] += 1;
                    }
                }
            }
        }
        let frames = flow.named.len();
        for a in 0..cars {
            for b in a + 1..cars {
                let tally = if linked[a * cars + b] { &mut t.edge_pairs } else { &mut t.non_edge_pairs };
                tally.add(together[a * cars + b], frames);
            }
        }
    }
    Ok(t)
}
