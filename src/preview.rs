//! `causalcity preview`: a look at one written scenario before spending GPU
//! hours on a dataset. Reads the scenario's files (rgb/, mask/, poses.csv,
//! scenario.json) and writes either an animated GIF (`.gif`) or a contact
//! sheet of frames spread over the scenario (`.png`), downscaled by
//! `scale`. Overlays: mask tint (each car's pixels in its colour), trails
//! (each car's path so far) and arrows from each leader to its follower.

use crate::dataset::{PoseLog, ScenarioSummary};
use crate::error::Error;
use crate::output::claim::{claim_file, FileKind, OutputFile};
use crate::output::frame_digits;
use crate::output::png::decode_gray8;
use crate::render::text::{draw_label, Canvas};
use image::codecs::gif::{GifEncoder, Repeat};
use image::{Delay, Frame, RgbaImage};
use std::path::Path;
use tiny_skia::{Color, LineCap, Paint, PathBuilder, Pixmap, Stroke, Transform};

/// What to draw and how small.
#[derive(Debug, Clone)]
pub struct PreviewOptions {
    /// 0 < scale <= 1.
    pub scale: f64,
    /// Use every Nth frame.
    pub every: u32,
    /// GIF frames per second; when None, the scenario's real speed, sped up
    /// so that the animation lasts at most [`LONGEST_DEFAULT_GIF_S`].
    pub fps: Option<f64>,
    pub masks: bool,
    pub trails: bool,
    pub arrows: bool,
    /// Contact sheet: how many frames, and how many per row.
    pub sheet_frames: u32,
    pub columns: u32,
}

/// The longest a GIF plays by default, seconds: a 150-frame city scenario
/// at the paper's 1 s per frame would otherwise take 2.5 minutes and look
/// frozen (2 s per shown frame).
pub const LONGEST_DEFAULT_GIF_S: f64 = 15.0;

/// What was written.
#[derive(Debug, Clone, serde::Serialize)]
pub struct PreviewSummary {
    /// The file written.
    pub path: std::path::PathBuf,
    pub frames: usize,
    pub width: u32,
    pub height: u32,
    pub bytes: u64,
    /// A GIF's frames per second and how many times the scenario's real
    /// speed that is.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fps: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub speed_up: Option<f64>,
}

impl std::fmt::Display for PreviewSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (path, w, h) = (self.path.display(), self.width, self.height);
        write!(f, "wrote {path} ({w}x{h}, {} frames, {:.0} KB", self.frames, self.bytes as f64 / 1e3)?;
        if let (Some(fps), Some(speed_up)) = (self.fps, self.speed_up) {
            write!(f, ", {fps:.1} frames/s, {speed_up:.1}x real time")?;
        }
        write!(f, ")")
    }
}

/// Writes the preview of the scenario in `scenario_dir` to `out`.
pub fn preview(scenario_dir: &Path, out: &Path, options: &PreviewOptions) -> Result<PreviewSummary, Error> {
    let kind = check_options(out, options).map_err(Error::Input)?;
    // No scenario folder (or extra camera's folder) there: a dataset's root,
    // a typo. The argument is wrong, not the data.
    if scenario_of_camera(scenario_dir).is_none() && !scenario_dir.join("scenario.json").is_file() {
        let hint = if scenario_dir.join("manifest.json").is_file() {
            ", it is a dataset: give one of its scenario folders, e.g. <dataset>/<group>/train/00000"
        } else {
            ": give a scenario folder (the one holding scenario.json)"
        };
        return Err(Error::Input(format!("{} holds no scenario.json{hint}", scenario_dir.display())));
    }
    let writes = match kind {
        Kind::Gif => FileKind::Gif,
        Kind::Sheet => FileKind::Png,
    };
    let file = claim_file(out, &[("the scenario folder it previews", scenario_dir)], writes)?;
    render(scenario_dir, &file, options, kind)
}

/// Most pixels of a contact sheet (8192 x 8192): its tiles, the sheet and
/// its RGB copy are then under a GB together.
const MAX_SHEET_PIXELS: u64 = 8192 * 8192;

/// Slowest and fastest GIF a preview writes, frames per second: a frame's
/// delay is whole centiseconds, 2 at least (viewers show shorter delays
/// slowed down), 200 at most (2 s a frame).
const MIN_FPS: f64 = 0.5;
const MAX_FPS: f64 = 50.0;

/// The options' errors, found before anything is read (exit status 2), and
/// what the output's extension asks for.
fn check_options(out: &Path, options: &PreviewOptions) -> Result<Kind, String> {
    if !(options.scale > 0.0 && options.scale <= 1.0) {
        return Err(format!("--scale must be in (0, 1], not {}", options.scale));
    }
    if let Some(fps) = options.fps {
        if !(MIN_FPS..=MAX_FPS).contains(&fps) {
            return Err(format!(
                "--fps must be from {MIN_FPS} to {MAX_FPS} (a GIF holds each frame whole hundredths of a second, at least 2 of them, and this writer at most 200), not {fps}"
            ));
        }
    }
    match out.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
        Some("gif") => Ok(Kind::Gif),
        Some("png") => Ok(Kind::Sheet),
        _ => Err(format!("--out {}: the output must end in .gif (animation) or .png (contact sheet)", out.display())),
    }
}

/// The scenario folder of an extra camera's folder
/// (`<scenario>/cameras/<name>`), if `dir` is one.
fn scenario_of_camera(dir: &Path) -> Option<&Path> {
    dir.parent()
        .filter(|p| p.file_name().is_some_and(|n| n == "cameras") && !dir.join("scenario.json").exists())
        .and_then(Path::parent)
        .filter(|s| s.join("scenario.json").exists())
}

fn render(
    scenario_dir: &Path,
    file: &OutputFile,
    options: &PreviewOptions,
    kind: Kind,
) -> Result<PreviewSummary, Error> {
    let out = file.path();
    // An extra camera's folder (`<scenario>/cameras/<name>`): its frames,
    // the scenario's cars. Trails and arrows are drawn in bird's-eye pixels,
    // so only on the bird's-eye view.
    let scenario_of_camera = scenario_of_camera(scenario_dir);
    let camera = scenario_of_camera.is_some();
    let meta_dir = scenario_of_camera.unwrap_or(scenario_dir);
    // A scenario folder that cannot be read is bad input, as for every reader.
    let scenario = ScenarioSummary::read(meta_dir).map_err(Error::Input)?;
    let (frames, cars) = (scenario.frames as usize, scenario.cars.len());
    let poses = PoseLog::read(meta_dir, frames, cars).map_err(Error::Input)?;
    let options = &PreviewOptions {
        trails: options.trails && !camera,
        arrows: options.arrows && !camera,
        masks: options.masks && scenario_dir.join("mask").is_dir(),
        ..options.clone()
    };
    let digits = frame_digits(scenario.frames);
    let first = scenario_dir.join(format!("rgb/{:0digits$}.png", 0));
    if !first.exists() {
        return Err(Error::Input(format!(
            "{} has no frames (made with --no-images?): nothing to preview",
            scenario_dir.display()
        )));
    }
    let colours: Vec<[u8; 3]> = scenario
        .cars
        .iter()
        .map(|c| crate::render::palette::parse_hex_colour(&c.colour).unwrap_or([128, 128, 128]))
        .collect();

    let chosen: Vec<usize> = match kind {
        Kind::Gif => (0..frames).step_by(options.every as usize).collect(),
        Kind::Sheet => {
            let n = (options.sheet_frames as usize).min(frames);
            (0..n).map(|i| if n == 1 { 0 } else { i * (frames - 1) / (n - 1) }).collect()
        }
    };
    let draw = |frame: usize| -> Result<RgbaImage, String> {
        let rgb_path = scenario_dir.join(format!("rgb/{frame:0digits$}.png"));
        // Regular files only: a pipe hung preview.
        let rgb_bytes =
            crate::input::read_data(&rgb_path).map_err(|e| format!("cannot read {}: {e}", rgb_path.display()))?;
        let rgb = image::load_from_memory_with_format(&rgb_bytes, image::ImageFormat::Png)
            .map_err(|e| format!("{}: {e}", rgb_path.display()))?
            .to_rgba8();
        let (w, h) = rgb.dimensions();
        let mut pixmap = Pixmap::from_vec(rgb.into_raw(), tiny_skia::IntSize::from_wh(w, h).ok_or("empty frame")?)
            .ok_or("frame size")?;
        if options.masks {
            let mask_path = scenario_dir.join(format!("mask/{frame:0digits$}.png"));
            let data =
                crate::input::read_data(&mask_path).map_err(|e| format!("cannot read {}: {e}", mask_path.display()))?;
            // (The size expected is the rgb frame's: either may be the odd one.)
            let mask = decode_gray8(&data, w, h)
                .map_err(|e| format!("{}: {e} (the size of {})", mask_path.display(), rgb_path.display()))?;
            let mut by_mask = [None; 256];
            for (car, c) in scenario.cars.iter().enumerate() {
                by_mask[c.mask_id as usize] = Some(colours[car]);
            }
            for (pixel, &id) in pixmap.data_mut().chunks_exact_mut(4).zip(&mask) {
                if let Some(colour) = by_mask[id as usize] {
                    for k in 0..3 {
                        pixel[k] = ((pixel[k] as u16 + 2 * colour[k] as u16) / 3) as u8;
                    }
                }
            }
        }
        let line = |width: f32| Stroke { width, line_cap: LineCap::Round, ..Stroke::default() };
        let thickness = (2.0 / options.scale as f32).max(2.0);
        if options.trails {
            for (car, colour) in colours.iter().enumerate() {
                let mut path = PathBuilder::new();
                for f in 0..=frame {
                    let p = poses.at(f, car);
                    if f == 0 {
                        path.move_to(p.px as f32, p.py as f32);
                    } else {
                        path.line_to(p.px as f32, p.py as f32);
                    }
                }
                if let Some(path) = path.finish() {
                    let mut paint = Paint::default();
                    paint.set_color_rgba8(colour[0], colour[1], colour[2], 200);
                    pixmap.stroke_path(&path, &paint, &line(thickness), Transform::identity(), None);
                }
            }
        }
        if options.arrows {
            let mut paint = Paint::default();
            paint.set_color(Color::from_rgba8(255, 235, 40, 255));
            for edge in &scenario.edges {
                let (l, f) = (poses.at(frame, edge[0] as usize), poses.at(frame, edge[1] as usize));
                if let Some(path) = arrow([l.px, l.py], [f.px, f.py], 6.0 * thickness) {
                    pixmap.stroke_path(&path, &paint, &line(thickness), Transform::identity(), None);
                }
            }
        }
        let full = RgbaImage::from_raw(w, h, pixmap.take()).ok_or("frame size")?;
        let (sw, sh) = scaled_size(w, h, options.scale);
        Ok(image::imageops::resize(&full, sw, sh, image::imageops::FilterType::Triangle))
    };

    // Real time at --every, sped up to last at most LONGEST_DEFAULT_GIF_S.
    let real_fps = 1.0 / (scenario.frame_interval * options.every as f64);
    let fps = options.fps.unwrap_or(real_fps.max(chosen.len() as f64 / LONGEST_DEFAULT_GIF_S)).clamp(MIN_FPS, MAX_FPS);
    // GIF delays are whole hundredths of a second (players round finer ones).
    let delay_cs = (100.0 / fps).round().max(2.0);
    let fps = 100.0 / delay_cs;
    let partial = file.partial().map_err(|e| Error::Failure(e.to_string()))?;
    let result = (|| -> Result<(u32, u32), Error> {
        let failure = Error::Failure;
        let file =
            std::fs::File::create(&partial).map_err(|e| failure(format!("cannot write {}: {e}", partial.display())))?;
        let writer = std::io::BufWriter::new(file);
        match kind {
            Kind::Gif => {
                let delay = Delay::from_numer_denom_ms(delay_cs as u32 * 10, 1);
                let mut encoder = GifEncoder::new_with_speed(writer, 10);
                encoder.set_repeat(Repeat::Infinite).map_err(|e| failure(e.to_string()))?;
                let mut size = (0, 0);
                for &frame in &chosen {
                    let image = draw(frame).map_err(failure)?;
                    size = image.dimensions();
                    encoder
                        .encode_frame(Frame::from_parts(image, 0, 0, delay))
                        .map_err(|e| failure(format!("cannot write {}: {e}", out.display())))?;
                }
                Ok(size)
            }
            Kind::Sheet => {
                // The first tile gives the sheet's size, checked before the
                // others are drawn (a sheet of ten 8192 px frames needed 8 GB).
                let first = draw(chosen[0]).map_err(failure)?;
                let (tw, th) = first.dimensions();
                let columns = (options.columns as usize).min(chosen.len()) as u32;
                let rows = chosen.len().div_ceil(columns as usize) as u32;
                let gap = 4;
                let (sw, sh) =
                    (columns as u64 * (tw + gap) as u64 + gap as u64, rows as u64 * (th + gap) as u64 + gap as u64);
                if sw * sh > MAX_SHEET_PIXELS {
                    // The flags asked for it: bad input, nothing written.
                    return Err(Error::Input(format!(
                        "a contact sheet of {} frames of {tw}x{th} in {columns} columns would be {sw}x{sh} pixels, over the {MAX_SHEET_PIXELS} a sheet may have: use a smaller --scale or fewer --sheet-frames",
                        chosen.len()
                    )));
                }
                let (sw, sh) = (sw as u32, sh as u32);
                let mut tiles = vec![first];
                for &f in &chosen[1..] {
                    tiles.push(draw(f).map_err(failure)?);
                }
                let mut sheet = RgbaImage::from_pixel(sw, sh, image::Rgba([24, 24, 24, 255]));
                for (i, tile) in tiles.iter().enumerate() {
                    let (c, r) = (i as u32 % columns, i as u32 / columns);
                    let (x, y) = ((gap + c * (tw + gap)) as i64, (gap + r * (th + gap)) as i64);
                    image::imageops::overlay(&mut sheet, tile, x, y);
                    // Which frame, and when.
                    let frame = chosen[i];
                    let label = format!("frame {frame}  {:.1} s", frame as f64 * scenario.frame_interval);
                    let (sw, sh) = sheet.dimensions();
                    let mut canvas = Canvas { data: &mut sheet, width: sw, height: sh, channels: 4 };
                    draw_label(&mut canvas, x, y, &label, 1, [245, 245, 245], [20, 20, 20]);
                }
                let rgb = image::DynamicImage::ImageRgba8(sheet).to_rgb8();
                rgb.write_with_encoder(image::codecs::png::PngEncoder::new(writer))
                    .map_err(|e| failure(format!("cannot write {}: {e}", out.display())))?;
                Ok((sw, sh))
            }
        }
    })();
    let (width, height) = match result {
        Ok(size) => size,
        Err(e) => {
            let _ = std::fs::remove_file(&partial);
            return Err(e);
        }
    };
    file.commit(&partial).map_err(|e| Error::Failure(e.to_string()))?;
    let bytes = std::fs::metadata(out).map(|m| m.len()).unwrap_or(0);
    let gif = matches!(kind, Kind::Gif);
    Ok(PreviewSummary {
        path: out.to_path_buf(),
        frames: chosen.len(),
        width,
        height,
        bytes,
        fps: gif.then_some(fps),
        speed_up: gif.then_some(fps / real_fps),
    })
}

enum Kind {
    Gif,
    Sheet,
}

/// The size of a `w` x `h` frame at `scale` (at least 1 x 1).
pub fn scaled_size(w: u32, h: u32, scale: f64) -> (u32, u32) {
    (((w as f64 * scale).round() as u32).max(1), ((h as f64 * scale).round() as u32).max(1))
}

/// A line from `from` to `to` with a head of `head` pixels at `to`.
fn arrow(from: [f64; 2], to: [f64; 2], head: f32) -> Option<tiny_skia::Path> {
    let (dx, dy) = ((to[0] - from[0]) as f32, (to[1] - from[1]) as f32);
    let length = (dx * dx + dy * dy).sqrt();
    if length < 1.0 {
        return None;
    }
    let (ux, uy) = (dx / length, dy / length);
    let (tx, ty) = (to[0] as f32, to[1] as f32);
    let mut path = PathBuilder::new();
    path.move_to(from[0] as f32, from[1] as f32);
    path.line_to(tx, ty);
    for side in [-1.0f32, 1.0] {
        path.move_to(tx, ty);
        path.line_to(tx - head * (ux * 0.87 - side * uy * 0.5), ty - head * (uy * 0.87 + side * ux * 0.5));
    }
    path.finish()
}
