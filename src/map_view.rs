//! `causalcity map`: a spec's road network, as the list of lane ids that
//! scenario files name (spawn points) and, with `--out`, a picture of the
//! bird's-eye view with every lane's id on it.

use crate::error::Error;
use crate::map::{CityMap, LaneEnd};
use crate::output::claim::{claim_file, FileKind};
use crate::plan::expand::Expansion;
use crate::render::background::draw_background;
use crate::render::text::{draw_label, label_size, Canvas};
use crate::spec::DatasetSpec;
use serde::Serialize;
use std::fmt;
use std::path::{Path, PathBuf};

/// One lane of the network.
#[derive(Debug, Clone, Serialize)]
pub struct LaneRow {
    /// The id scenario files use (`Spawn`), e.g. `A0w`.
    pub name: String,
    /// Compass direction of travel: N, E, S or W.
    pub heading: char,
    pub length_m: f64,
    /// Where it ends: a junction's name and the side it arrives from
    /// (`AC from W`), or `loop` (the U-turn at the road's end).
    pub ends_at: String,
    /// Turns allowed at its end (empty before a loop).
    pub turns: Vec<String>,
    /// Where its centre line starts and ends, metres (x east, y north).
    pub start: [f64; 2],
    pub end: [f64; 2],
    /// Index into [`MapSummary::junctions`] of the junction it ends at.
    pub junction: Option<usize>,
}

/// What `causalcity map` found and wrote.
#[derive(Debug, Clone, Serialize)]
pub struct MapSummary {
    /// The town shown, and every town the spec's map draws (one for most).
    pub town: String,
    pub towns: Vec<String>,
    pub junctions: Vec<String>,
    /// How each junction decides who goes: `signals`, `priority` or
    /// `all_way_stop` (`map.grid.control`).
    pub junction_controls: Vec<String>,
    /// Each junction's centre, metres.
    pub junction_centres: Vec<[f64; 2]>,
    pub lanes: Vec<LaneRow>,
    /// The picture written, if `--out` was given.
    pub picture: Option<PathBuf>,
}

impl fmt::Display for MapSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.towns.len() > 1 {
            writeln!(
                f,
                "town {} of the {} the spec draws ({}); show another with --town NAME",
                self.town,
                self.towns.len(),
                self.towns.join(" ")
            )?;
        }
        let junctions: Vec<String> = self
            .junctions
            .iter()
            .zip(&self.junction_controls)
            .map(|(name, control)| if control == "signals" { name.clone() } else { format!("{name} ({control})") })
            .collect();
        writeln!(f, "{} junctions: {}", junctions.len(), junctions.join(" "))?;
        writeln!(f, "{} lanes (spawn points):", self.lanes.len())?;
        writeln!(f, "{:<6} {:>7} {:>8}  {:<12} turns", "lane", "heading", "length m", "ends at")?;
        for lane in &self.lanes {
            writeln!(
                f,
                "{:<6} {:>7} {:>8.1}  {:<12} {}",
                lane.name,
                lane.heading,
                lane.length_m,
                lane.ends_at,
                lane.turns.join(" ")
            )?;
        }
        if let Some(path) = &self.picture {
            writeln!(f, "wrote {}", path.display())?;
        }
        Ok(())
    }
}

/// Lists the lanes of the spec at `spec_path` and, with `out` (a `.png`),
/// draws its bird's-eye view at the spec's image size with every lane id.
/// `town` picks one of the towns the spec's map draws (the first when `None`).
pub fn map_view(spec_path: &Path, out: Option<&Path>, town: Option<&str>) -> Result<MapSummary, Error> {
    if let Some(out) = out {
        if !out.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")) {
            return Err(Error::Input(format!(
                "--out {}: a map picture is a PNG: give a name ending in .png",
                out.display()
            )));
        }
    }
    let invalid = |e| Error::Input(format!("invalid spec {}: {e}", spec_path.display()));
    let expansion = Expansion::from_spec(DatasetSpec::from_file(spec_path).map_err(invalid)?).map_err(invalid)?;
    let towns: Vec<String> = expansion.all_town_names().into_iter().map(String::from).collect();
    let shown = match town {
        None => &expansion.towns()[0],
        Some(name) => expansion.towns().iter().find(|t| t.name == name).ok_or_else(|| {
            Error::Input(format!("--town {name}: the spec draws no such town: use one of {}", towns.join(", ")))
        })?,
    };
    let map = &shown.map;
    let summary =
        MapSummary { picture: out.map(Path::to_path_buf), town: shown.name.clone(), towns, ..map_summary(map) };
    if let Some(out) = out {
        let file = claim_file(out, &[("the spec it draws", spec_path)], FileKind::Png)?;
        let camera = shown.camera;
        let mut rgba = draw_background(map, &camera).pixmap.take();
        let mut canvas = Canvas { data: &mut rgba, width: camera.width, height: camera.height, channels: 4 };
        // Junction names on their centres, lane ids half way along each lane
        // (on an imported network, small, and lane ids only where a lane
        // is long enough in the picture to carry one).
        let scale = if map.is_imported() { 1 } else { 2 };
        for junction in &map.intersections {
            let p = camera.to_pixel(junction.centre);
            let (w, h) = label_size(&junction.name, scale);
            let (x, y) = (p.x as i64 - w as i64 / 2, p.y as i64 - h as i64 / 2);
            draw_label(&mut canvas, x, y, &junction.name, scale, [255, 255, 255], [150, 30, 30]);
        }
        let fits = |lane: &&crate::map::Lane| {
            !map.is_imported() || lane.curve.length() * camera.pixels_per_metre >= label_size(&lane.name, 1).0 as f64
        };
        for lane in map.lanes.iter().filter(fits) {
            let p = camera.to_pixel(lane.curve.position(lane.curve.length() / 2.0, 0.0));
            let (w, h) = label_size(&lane.name, 1);
            let (x, y) = (p.x as i64 - w as i64 / 2, p.y as i64 - h as i64 / 2);
            draw_label(&mut canvas, x, y, &lane.name, 1, [20, 20, 20], [250, 235, 120]);
        }
        write_picture(&file, out, camera.width, camera.height, rgba)?;
    }
    Ok(summary)
}

/// Encodes an RGBA picture as an RGB PNG into the claimed `file` (`out`, for errors).
fn write_picture(
    file: &crate::output::claim::OutputFile,
    out: &Path,
    width: u32,
    height: u32,
    rgba: Vec<u8>,
) -> Result<(), Error> {
    let image = image::RgbaImage::from_raw(width, height, rgba)
        .ok_or_else(|| Error::Failure("the map picture has the wrong size".into()))?;
    let mut png = Vec::new();
    image::DynamicImage::ImageRgba8(image)
        .to_rgb8()
        .write_with_encoder(image::codecs::png::PngEncoder::new(&mut png))
        .map_err(|e| Error::Failure(format!("cannot encode {}: {e}", out.display())))?;
    file.write(&png).map_err(|e| Error::Failure(e.to_string()))
}

/// The junctions and lanes (in lane-id order) of `map` (its town's name
/// and the spec's towns left for the caller to fill in).
pub fn map_summary(map: &CityMap) -> MapSummary {
    MapSummary {
        town: String::new(),
        towns: Vec::new(),
        junctions: map.intersections.iter().map(|i| i.name.clone()).collect(),
        junction_controls: map.intersections.iter().map(|i| i.control.name().to_string()).collect(),
        junction_centres: map.intersections.iter().map(|i| [i.centre.x, i.centre.y]).collect(),
        lanes: map.spawn_points().into_iter().map(|id| lane_row(map, id)).collect(),
        picture: None,
    }
}

fn lane_row(map: &CityMap, id: usize) -> LaneRow {
    let lane = &map.lanes[id];
    let heading = lane.curve.heading_at(0.0).to_degrees().rem_euclid(360.0);
    let compass = ['E', 'N', 'W', 'S'][((heading + 45.0) / 90.0) as usize % 4];
    let ends_at = match lane.end {
        LaneEnd::Intersection { intersection, approach } => {
            format!("{} from {approach}", map.intersections[intersection].name)
        }
        LaneEnd::Loop(_) => "loop".to_string(),
    };
    LaneRow {
        name: lane.name.clone(),
        heading: compass,
        length_m: lane.curve.length(),
        ends_at,
        turns: map.allowed_turns(id).iter().map(|t| t.name().to_string()).collect(),
        start: [lane.curve.start().x, lane.curve.start().y],
        end: [lane.curve.end().x, lane.curve.end().y],
        junction: match lane.end {
            LaneEnd::Intersection { intersection, .. } => Some(intersection),
            LaneEnd::Loop(_) => None,
        },
    }
}

/// One imported junction, as `causalcity map --net` lists it.
#[derive(Debug, Clone, Serialize)]
pub struct NetJunctionRow {
    pub id: String,
    /// `traffic_light`, `priority`, `right_before_left`, `all_way_stop`,
    /// `dead_end` or `unregulated`.
    pub kind: &'static str,
    /// Metres, in the network's coordinates.
    pub centre: [f64; 2],
}

/// One imported lane cars may drive.
#[derive(Debug, Clone, Serialize)]
pub struct NetLaneRow {
    /// SUMO's lane id.
    pub id: String,
    /// Compass direction of travel at its end: N, E, S or W.
    pub heading: char,
    pub length_m: f64,
    pub speed_limit_ms: f64,
    /// Index into `junctions` of the junction it ends at.
    pub junction: usize,
    /// Movements from its end (`straight`, `left`, `right`, `uturn`);
    /// empty for a dead end.
    pub turns: Vec<String>,
}

/// What `causalcity map --net` read and wrote.
#[derive(Debug, Clone, Serialize)]
pub struct NetSummary {
    pub net: PathBuf,
    pub junctions: Vec<NetJunctionRow>,
    pub lanes: Vec<NetLaneRow>,
    pub connections: usize,
    /// Traffic-light programmes.
    pub programmes: usize,
    /// Of those, the traffic-actuated ones with a phase that traffic
    /// extends (`city.lights.actuated` runs them so).
    pub actuated_programmes: usize,
    /// What the file has that cars do not drive on: (what, how many).
    pub left_out: Vec<(String, usize)>,
    /// Lower and upper corners of the network, metres.
    pub bounds: [[f64; 2]; 2],
    /// What a spec's `map.sumo` would drive of it (with the default
    /// lane change): the lanes kept, the U-turn loops added where roads
    /// end, the lanes dropped and why; or why it cannot be driven.
    pub driving: Result<NetDriving, String>,
    /// The picture written, if `--out` was given.
    pub picture: Option<PathBuf>,
}

/// What driving keeps of an imported network ([`crate::map::CityMap::from_sumo`]).
#[derive(Debug, Clone, Serialize)]
pub struct NetDriving {
    pub lanes: usize,
    pub loops: usize,
    /// (lane id, why) for every lane left out.
    pub dropped: Vec<(String, String)>,
    /// Lights of their own for movements whose links run on another
    /// schedule than the first of their approach's signal (a right-turn
    /// arrow): (light name, `lane turn` of each movement it governs).
    pub variant_lights: Vec<(String, Vec<String>)>,
}

impl fmt::Display for NetSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut kinds: Vec<(&str, usize)> = Vec::new();
        for j in &self.junctions {
            match kinds.iter_mut().find(|(k, _)| *k == j.kind) {
                Some(entry) => entry.1 += 1,
                None => kinds.push((j.kind, 1)),
            }
        }
        let kinds: Vec<String> = kinds.iter().map(|(k, n)| format!("{n} {k}")).collect();
        let [lo, hi] = self.bounds;
        writeln!(
            f,
            "{}: {} junctions ({}), {:.0} x {:.0} m",
            self.net.display(),
            self.junctions.len(),
            kinds.join(", "),
            hi[0] - lo[0],
            hi[1] - lo[1]
        )?;
        write!(
            f,
            "{} lanes cars drive, {} connections, {} traffic-light programmes",
            self.lanes.len(),
            self.connections,
            self.programmes
        )?;
        match self.actuated_programmes {
            0 => writeln!(f)?,
            n => writeln!(f, " ({n} actuated: with city.lights.actuated, traffic extends their phases)")?,
        }
        if !self.left_out.is_empty() {
            let what: Vec<String> = self.left_out.iter().map(|(w, n)| format!("{n} {w}")).collect();
            writeln!(f, "left out: {}", what.join(", "))?;
        }
        let dead: Vec<&str> = self.lanes.iter().filter(|l| l.turns.is_empty()).map(|l| l.id.as_str()).collect();
        if !dead.is_empty() {
            writeln!(f, "{} lanes lead nowhere (dead ends): {}", dead.len(), dead.join(" "))?;
        }
        match &self.driving {
            Ok(d) => {
                writeln!(
                    f,
                    "as map.sumo: {} lanes driven, {} U-turn loops added where roads end, {} lanes left out",
                    d.lanes,
                    d.loops,
                    d.dropped.len()
                )?;
                for (lane, why) in d.dropped.iter().take(10) {
                    writeln!(f, "  {lane}: {why}")?;
                }
                if d.dropped.len() > 10 {
                    writeln!(f, "  ... and {} more (--json lists all)", d.dropped.len() - 10)?;
                }
                if !d.variant_lights.is_empty() {
                    let count = match d.variant_lights.len() {
                        1 => "1 light of its own".to_string(),
                        n => format!("{n} lights of their own"),
                    };
                    writeln!(f, "{count}, for movements whose links run on another schedule than their signal's:")?;
                    for (light, movements) in &d.variant_lights {
                        writeln!(f, "  {light}: {}", movements.join(", "))?;
                    }
                }
            }
            Err(why) => writeln!(f, "as map.sumo: cannot be driven: {why}")?,
        }
        writeln!(f, "{:<24} {:>7} {:>8} {:>6}  {:<24} turns", "lane", "heading", "length m", "m/s", "ends at")?;
        for lane in &self.lanes {
            let junction = &self.junctions[lane.junction];
            writeln!(
                f,
                "{:<24} {:>7} {:>8.1} {:>6.1}  {:<24} {}",
                lane.id,
                lane.heading,
                lane.length_m,
                lane.speed_limit_ms,
                format!("{} ({})", junction.id, junction.kind),
                lane.turns.join(" ")
            )?;
        }
        if let Some(path) = &self.picture {
            writeln!(f, "wrote {}", path.display())?;
        }
        Ok(())
    }
}

/// Reads the SUMO network at `net_path` (`.net.xml`), lists its junctions
/// and the lanes cars may drive, and with `out` (a `.png`) draws it from
/// above, `longest` pixels along its longer side.
pub fn net_view(net_path: &Path, out: Option<&Path>, longest: u32) -> Result<NetSummary, Error> {
    if let Some(out) = out {
        if !out.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")) {
            return Err(Error::Input(format!(
                "--out {}: a map picture is a PNG: give a name ending in .png",
                out.display()
            )));
        }
    }
    let bytes = crate::spec::read_network_file(net_path).map_err(Error::Input)?;
    let text = String::from_utf8(bytes)
        .map_err(|_| Error::Input(format!("{}: not UTF-8 text, so not a .net.xml", net_path.display())))?;
    let net = crate::map::sumo::SumoNetwork::from_xml(&text)
        .map_err(|e| Error::Input(format!("{}: {e}", net_path.display())))?;
    let mut turns = vec![Vec::new(); net.lanes.len()];
    for c in &net.connections {
        turns[c.from].push(c.turn.name().to_string());
    }
    let lanes = net
        .lanes
        .iter()
        .zip(turns)
        .map(|(lane, turns)| {
            let n = lane.shape.len();
            let d = lane.shape[n - 1] - lane.shape[n - 2];
            let heading = d.y.atan2(d.x).to_degrees().rem_euclid(360.0);
            NetLaneRow {
                id: lane.id.clone(),
                heading: ['E', 'N', 'W', 'S'][((heading + 45.0) / 90.0) as usize % 4],
                length_m: lane.length,
                speed_limit_ms: lane.speed,
                junction: lane.to,
                turns,
            }
        })
        .collect();
    let (lo, hi) = net.bounds();
    let driving = crate::map::CityMap::from_sumo(&net, crate::map::MapLayout::default().lane_change_length).map(
        |(map, report)| NetDriving {
            lanes: report.lanes,
            loops: report.loops,
            dropped: report.dropped.into_iter().map(|(lane, why)| (lane, why.to_string())).collect(),
            variant_lights: variant_lights(&map),
        },
    );
    let summary = NetSummary {
        driving,
        net: net_path.to_path_buf(),
        junctions: net
            .junctions
            .iter()
            .map(|j| NetJunctionRow { id: j.id.clone(), kind: j.kind.name(), centre: [j.centre.x, j.centre.y] })
            .collect(),
        lanes,
        connections: net.connections.len(),
        programmes: net.programmes.len(),
        actuated_programmes: net.programmes.iter().filter(|p| p.actuated.iter().any(Option::is_some)).count(),
        left_out: net.left_out.iter().map(|(w, n)| (w.to_string(), *n)).collect(),
        bounds: [[lo.x, lo.y], [hi.x, hi.y]],
        picture: out.map(Path::to_path_buf),
    };
    if let Some(out) = out {
        let file = claim_file(out, &[("the network it draws", net_path)], FileKind::Png)?;
        let view = crate::render::network::NetworkView::fitting(&net, longest);
        let mut rgba = crate::render::network::draw_network(&net, &view).take();
        let mut canvas = Canvas { data: &mut rgba, width: view.width, height: view.height, channels: 4 };
        // Junction ids where they fit: a small network's every junction.
        if net.junctions.len() <= 40 {
            for junction in net.junctions.iter().filter(|j| j.kind != crate::map::sumo::SumoJunctionKind::DeadEnd) {
                let p = view.to_pixel(junction.centre);
                let (w, _) = label_size(&junction.id, 1);
                draw_label(
                    &mut canvas,
                    p.x as i64 - w as i64 / 2,
                    p.y as i64 + 6,
                    &junction.id,
                    1,
                    [255, 255, 255],
                    [150, 30, 30],
                );
            }
        }
        write_picture(&file, out, view.width, view.height, rgba)?;
    }
    Ok(summary)
}

/// `map`'s lights of variant 1 and up, by name, with the movements (`lane
/// turn`) each governs.
fn variant_lights(map: &crate::map::CityMap) -> Vec<(String, Vec<String>)> {
    let mut lights: Vec<(usize, Vec<String>)> = Vec::new();
    for (c, connector) in map.connectors.iter().enumerate() {
        let Some(light) = map.light_of(c) else { continue };
        if map.light_at(light).3 == 0 {
            continue;
        }
        let movement = format!("{} {}", map.lanes[connector.from].name, connector.turn.name());
        match lights.iter_mut().find(|(l, _)| *l == light) {
            Some((_, movements)) => movements.push(movement),
            None => lights.push((light, vec![movement])),
        }
    }
    lights.sort_by_key(|(l, _)| *l);
    lights.into_iter().map(|(l, movements)| (map.light_name(l), movements)).collect()
}
