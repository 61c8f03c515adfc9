//! `causalcity heatmap DATASET --out heat.png`: where cars spend their time.
//! Every car-frame adds one to the cell (4 x 4 pixels) under the car's centre;
//! the image shows log(1 + count) over the camera view in a perceptual colour
//! ramp, over the map's roads (grey where no car came), with a title and a
//! colour bar in car-frames per cell. Uniform for the toy world, hot in
//! front of the lights for the city, as in the paper's figure.

use crate::dataset::Dataset;
use crate::error::Error;
use crate::output::claim::{claim_file, FileKind, OutputFile};
use crate::output::png::{encode_png, PixelFormat, PngSettings};
use crate::render::text::{draw_label, label_size, Canvas};
use crate::spec::Split;
use rayon::prelude::*;
use serde::Serialize;
use std::path::Path;

/// Side of a heat-map cell, pixels.
pub const CELL_PX: u32 = 4;
/// The colour bar's column: the bar, then its tick labels.
pub const BAR_WIDTH: u32 = 40 + LABEL_WIDTH;
/// Room for the tick labels (car-frames per cell) right of the bar.
const LABEL_WIDTH: u32 = 60;
/// Ticks on the colour bar, from top (the maximum) to bottom (1).
const TICKS: usize = 5;
/// The title band above the view, pixels.
pub const TITLE_HEIGHT: u32 = 18;
/// Where no car came: the road, and everything else.
const EMPTY_ROAD: [u8; 3] = [88, 88, 96];
const EMPTY_GROUND: [u8; 3] = [24, 24, 28];

/// What the heat map summarises.
#[derive(Debug, Clone, Serialize)]
pub struct HeatmapSummary {
    /// The PNG written.
    #[serde(skip)]
    pub path: std::path::PathBuf,
    pub scenarios: usize,
    pub car_frames: u64,
    pub cells_visited: usize,
    pub max_count: u64,
    /// Coefficient of variation of the counts over visited cells: low when
    /// dwell time is uniform, high with queues.
    pub visited_cell_cv: f64,
    pub width: u32,
    pub height: u32,
}

impl std::fmt::Display for HeatmapSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "wrote {} ({}x{}): {} scenarios, {} car-frames, {} cells visited, dwell CV {:.2}",
            self.path.display(),
            self.width,
            self.height,
            self.scenarios,
            self.car_frames,
            self.cells_visited,
            self.visited_cell_cv
        )
    }
}

/// Filters on which scenarios count.
#[derive(Debug, Clone, Default)]
pub struct HeatmapFilter {
    pub group: Option<String>,
    pub split: Option<Split>,
}

/// Writes the heat map of `dataset` to `out` (PNG).
pub fn heatmap(dataset: &Path, out: &Path, filter: &HeatmapFilter) -> Result<HeatmapSummary, Error> {
    if !out.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")) {
        return Err(Error::Input(format!("--out {}: a heat map is a PNG: give a name ending in .png", out.display())));
    }
    let opened = Dataset::open_complete(dataset).map_err(Error::opening)?;
    let spec = opened.spec();
    if let Some(g) = &filter.group {
        if !spec.groups.iter().any(|x| &x.name() == g) {
            let names: Vec<String> = spec.groups.iter().map(|x| x.name()).collect();
            return Err(Error::Input(format!("--group {g} is not in this dataset: use one of {}", names.join(", "))));
        }
    }
    let names = opened.expansion.all_town_names();
    if names.len() > 1 {
        return Err(Error::Input(format!(
            "{}: its scenarios happen on {} towns ({}), and a heat map draws one: generate a dataset of one town to map it",
            dataset.display(),
            names.len(),
            names.join(", ")
        )));
    }
    let chosen = opened
        .keys()
        .filter(|k| filter.group.as_ref().is_none_or(|g| g == &k.group) && filter.split.is_none_or(|s| s == k.split));
    if chosen.count() == 0 {
        return Err(Error::Input(format!(
            "{}: no scenarios{}{}: nothing to map",
            dataset.display(),
            filter.group.as_ref().map_or(String::new(), |g| format!(" in group {g}")),
            filter.split.map_or(String::new(), |s| format!(" in split {}", s.name()))
        )));
    }
    let file = claim_file(out, &[("the dataset it maps", dataset)], FileKind::Png)?;
    draw(dataset, &opened, &file, filter)
}

/// Counts and draws; a scenario file that cannot be read is the dataset's
/// damage ([`Error::damaged`]), a failed write a failure.
fn draw(dataset: &Path, opened: &Dataset, file: &OutputFile, filter: &HeatmapFilter) -> Result<HeatmapSummary, Error> {
    let out = file.path();
    let spec = opened.spec();
    let camera = opened.expansion.camera;
    let (w, h) = (camera.width, camera.height);
    let (cw, ch) = (w.div_ceil(CELL_PX) as usize, h.div_ceil(CELL_PX) as usize);
    // A split at a time: a packed dataset holds one split in TMPDIR.
    let mut counts = vec![0u64; cw * ch];
    let mut scenarios = 0;
    for group in spec.groups.iter().map(|g| g.name()).filter(|g| filter.group.as_ref().is_none_or(|f| f == g)) {
        for split in Split::ALL.into_iter().filter(|s| filter.split.is_none_or(|f| f == *s)) {
            let split_counts = opened.with_split(&group, split, |dirs| {
                scenarios += dirs.len();
                dirs.par_iter().map(|d| count_cells(d, cw, ch)).try_reduce(
                    || vec![0u64; cw * ch],
                    |mut a, b| {
                        a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
                        Ok(a)
                    },
                )
            });
            let split_counts = split_counts.map_err(|e| Error::reading(dataset, e))?;
            counts.iter_mut().zip(split_counts).for_each(|(x, y)| *x += y);
        }
    }
    let visited: Vec<f64> = counts.iter().filter(|&&c| c > 0).map(|&c| c as f64).collect();
    let mean = visited.iter().sum::<f64>() / visited.len().max(1) as f64;
    let sd = (visited.iter().map(|c| (c - mean).powi(2)).sum::<f64>() / visited.len().max(1) as f64).sqrt();
    let max = counts.iter().copied().max().unwrap_or(0);

    // Image: a title band; under it the heat over the view's roads, and a
    // colour bar on the right.
    let renderer = crate::render::Renderer::new(&opened.expansion.map, camera);
    let road = renderer.road_coverage();
    let (iw, ih) = (w + BAR_WIDTH, h + TITLE_HEIGHT);
    let mut rgb = vec![0u8; (iw * ih * 3) as usize];
    for pixel in rgb.chunks_exact_mut(3) {
        pixel.copy_from_slice(&EMPTY_GROUND);
    }
    let scale = ((1 + max) as f64).ln().max(1e-9);
    for y in 0..h {
        let row = y + TITLE_HEIGHT;
        for x in 0..w {
            let c = counts[(y / CELL_PX) as usize * cw + (x / CELL_PX) as usize];
            let colour = if c > 0 {
                ramp(((1 + c) as f64).ln() / scale)
            } else if road.get((y * w + x) as usize).is_some_and(|&r| r >= 128) {
                EMPTY_ROAD
            } else {
                EMPTY_GROUND
            };
            let i = ((row * iw + x) * 3) as usize;
            rgb[i..i + 3].copy_from_slice(&colour);
        }
        let level = 1.0 - y as f64 / (h - 1).max(1) as f64;
        for x in w + 8..w + 32 {
            let i = ((row * iw + x) * 3) as usize;
            rgb[i..i + 3].copy_from_slice(&ramp(level));
        }
    }
    let mut canvas = Canvas { data: &mut rgb, width: iw, height: ih, channels: 3 };
    // The title: what is counted, over what.
    let mut over = vec![format!("{scenarios} scenarios")];
    over.extend(filter.group.clone());
    over.extend(filter.split.map(|s| format!("split {}", s.name())));
    let title = format!(
        "{}: car-frames per {CELL_PX}x{CELL_PX} px cell ({:.2} m), log scale; {}; grey: road no car crossed",
        spec.name,
        CELL_PX as f64 / camera.pixels_per_metre,
        over.join(", ")
    );
    draw_label(&mut canvas, 4, 4, &title, 1, [235, 235, 235], EMPTY_GROUND);
    draw_label(&mut canvas, (w + 8) as i64, 4, "car-frames", 1, [235, 235, 235], EMPTY_GROUND);
    // Tick labels: the count each height of the bar stands for, each once.
    let mut shown = Vec::new();
    for k in 0..TICKS {
        let level = 1.0 - k as f64 / (TICKS - 1) as f64;
        let count = ((level * scale).exp() - 1.0).round().max(1.0) as u64;
        if shown.contains(&count) {
            continue;
        }
        shown.push(count);
        let y = (1.0 - level) * (h - 1) as f64 + TITLE_HEIGHT as f64;
        let text = count.to_string();
        let (_, lh) = label_size(&text, 1);
        let top = (y as i64 - lh as i64 / 2).clamp(TITLE_HEIGHT as i64, ih as i64 - lh as i64);
        draw_label(&mut canvas, (w + 36) as i64, top, &text, 1, [235, 235, 235], [24, 24, 28]);
    }
    let mut png = Vec::new();
    encode_png(&mut png, iw, ih, PixelFormat::Rgb8, &rgb, PngSettings::rgb())
        .map_err(|e| Error::Failure(format!("cannot write {}: {e}", out.display())))?;
    file.write(&png).map_err(Error::failure)?;
    Ok(HeatmapSummary {
        path: out.to_path_buf(),
        scenarios,
        car_frames: counts.iter().sum(),
        cells_visited: visited.len(),
        max_count: max,
        visited_cell_cv: if mean > 0.0 { sd / mean } else { 0.0 },
        width: iw,
        height: ih,
    })
}

/// The poses of the scenario in `dir` counted per `CELL_PX` cell, read as
/// every reader reads them (every frame of every car of its scenario.json,
/// once, finite; an empty or edited log was counted as it came).
fn count_cells(dir: &Path, cw: usize, ch: usize) -> Result<Vec<u64>, String> {
    let mut counts = vec![0u64; cw * ch];
    let summary = crate::dataset::ScenarioSummary::read(dir)?;
    let log = crate::dataset::PoseLog::read(dir, summary.frames as usize, summary.cars.len())?;
    for pose in (0..log.frames).flat_map(|frame| log.frame(frame)) {
        let (cx, cy) = ((pose.px + 0.5) / CELL_PX as f64, (pose.py + 0.5) / CELL_PX as f64);
        if cx >= 0.0 && cy >= 0.0 && (cx as usize) < cw && (cy as usize) < ch {
            counts[cy as usize * cw + cx as usize] += 1;
        }
    }
    Ok(counts)
}

/// A perceptual ramp (after viridis) from 0 to 1.
fn ramp(t: f64) -> [u8; 3] {
    const STOPS: [[f64; 3]; 5] =
        [[68.0, 1.0, 84.0], [59.0, 82.0, 139.0], [33.0, 145.0, 140.0], [94.0, 201.0, 98.0], [253.0, 231.0, 37.0]];
    let t = t.clamp(0.0, 1.0) * (STOPS.len() - 1) as f64;
    let i = (t.floor() as usize).min(STOPS.len() - 2);
    let f = t - i as f64;
    let mut out = [0u8; 3];
    for k in 0..3 {
        out[k] = (STOPS[i][k] + (STOPS[i + 1][k] - STOPS[i][k]) * f).round() as u8;
    }
    out
}
