//! `map`: the city map's dimensions and the bird's-eye camera's height.

use super::*;

/// The city map's dimensions, metres (every field optional; the defaults
/// are the default layout, [`MapLayout::default`]), and the height of the
/// bird's-eye camera.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MapSpec {
    /// Width of every lane; a road is four lanes wide (a grid's may be two).
    pub lane_width: f64,
    /// y of the centre lines of the east-west roads B and A, ascending.
    pub east_west_roads: [f64; 2],
    /// x of the centre lines of the north-south roads C and D, ascending.
    pub north_south_roads: [f64; 2],
    /// East-west roads run from -extent_x to +extent_x, then loop back.
    pub extent_x: f64,
    /// North-south roads run from -extent_y to +extent_y, then loop back.
    pub extent_y: f64,
    /// Distance along the lane a lane change takes, metres.
    pub lane_change_m: f64,
    /// Height of the bird's-eye camera. Absent: the original's 40 m, or
    /// higher when the intersections and their stop lines do not fit the
    /// view from there.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub camera_altitude_m: Option<f64>,
    /// What the bird's-eye camera frames: the junctions (absent), the
    /// whole network, or an area.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub camera_area: Option<CameraArea>,
    /// A grid town instead of the four roads: `east_west_roads`,
    /// `north_south_roads` and the extents then come from it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub grid: Option<GridSpec>,
    /// A real road network instead: a SUMO `.net.xml` (as `netconvert`
    /// writes from OpenStreetMap or OpenDRIVE), relative to the spec file.
    /// `gen` keeps a copy in the dataset's `networks/` folder.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sumo: Option<String>,
    /// SHA-256 (hex) of the `sumo` file. Filled in when the file is read,
    /// so that the spec as run (in `manifest.json`) pins the network: a
    /// changed file is a different dataset. Given in a spec, the file must
    /// match it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sumo_sha256: Option<String>,
    /// The network `sumo` names, once read ([`DatasetSpec::read_networks`]).
    #[serde(skip)]
    pub network: LoadedNetwork,
}

/// A town of `rows` east-west roads crossing `columns` north-south ones,
/// `block_m` apart (centre line to centre line), centred on the origin;
/// every road runs `outer_m` beyond its outermost crossing before it turns
/// back. Roads are named as in the default city, which is the 2 x 2 case:
/// east-west roads `A`, `B`, .. from north to south, then north-south roads
/// from west to east with the letters that follow.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GridSpec {
    /// East-west roads, 1 to [`MAX_GRID_ROADS`]: a number, or drawn per
    /// scenario.
    pub rows: RoadCount,
    /// North-south roads, 1 to [`MAX_GRID_ROADS`]: a number, or drawn per
    /// scenario.
    pub columns: RoadCount,
    /// Distance between neighbouring parallel roads' centre lines, metres.
    #[serde(default = "default_block_m")]
    pub block_m: f64,
    /// How far roads run beyond their outermost crossing, metres.
    #[serde(default = "default_outer_m")]
    pub outer_m: f64,
    /// Road segments the town leaves out, named as lanes name them: road
    /// letter, then the segment's number counted from the west or south
    /// end (`C0`: road C up to its first crossing; `A1`: road A between
    /// its first and second crossings). The junctions at their ends become
    /// T-junctions.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub missing: Vec<String>,
    /// Lanes each way on every road: 2 (the original's), 1 or 3 (read
    /// wide, so that 1000 is told as what it is, not as "0 to 255").
    #[serde(default = "default_lanes", skip_serializing_if = "is_default_lanes")]
    pub lanes: u32,
    /// How junctions decide who goes: traffic lights everywhere (absent),
    /// one control for every junction (`"priority"`), or some junctions by
    /// name (`{"AC": "all_way_stop"}`, the rest with lights).
    #[serde(default, skip_serializing_if = "ControlSpec::is_signals")]
    pub control: ControlSpec,
    /// Road segments between two junctions that stay joined to one of them
    /// only and end in a U-turn loop short of the other (a cul-de-sac):
    /// segment name (as in `missing`) to the junction it keeps, e.g.
    /// `{"B2": "BE"}`. The junction it leaves becomes a T-junction.
    #[serde(default, skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub dead_ends: std::collections::BTreeMap<String, String>,
}

/// `map.grid.control`: one [`JunctionControl`] for every junction, or one
/// per named junction (the others keep their lights).
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
#[serde(untagged)]
pub enum ControlSpec {
    Every(JunctionControl),
    ByJunction(std::collections::BTreeMap<String, JunctionControl>),
}

impl Default for ControlSpec {
    fn default() -> Self {
        ControlSpec::Every(JunctionControl::Signals)
    }
}

impl ControlSpec {
    fn is_signals(&self) -> bool {
        match self {
            ControlSpec::Every(c) => *c == JunctionControl::Signals,
            ControlSpec::ByJunction(by) => by.values().all(|c| *c == JunctionControl::Signals),
        }
    }

    /// The control of junction `name`.
    pub fn of(&self, name: &str) -> JunctionControl {
        match self {
            ControlSpec::Every(c) => *c,
            ControlSpec::ByJunction(by) => by.get(name).copied().unwrap_or_default(),
        }
    }
}

/// What [`ControlSpec`] accepts, for errors.
const CONTROL_FORMS: &str =
    "\"signals\", \"priority\", \"all_way_stop\", \"right_before_left\", or {\"JUNCTION\": one of \
     those, ...} (e.g. {\"AC\": \"priority\"})";

fn control_named<E: serde::de::Error>(v: &str) -> Result<JunctionControl, E> {
    JunctionControl::ALL
        .into_iter()
        .find(|c| c.name() == v)
        .ok_or_else(|| E::custom(format!("{v:?} is not allowed: use {CONTROL_FORMS}")))
}

impl<'de> Deserialize<'de> for ControlSpec {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct Visit;
        impl<'de> serde::de::Visitor<'de> for Visit {
            type Value = ControlSpec;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str(CONTROL_FORMS)
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<ControlSpec, E> {
                control_named(v).map(ControlSpec::Every)
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(self, mut map: A) -> Result<ControlSpec, A::Error> {
                let mut by = std::collections::BTreeMap::new();
                while let Some((junction, kind)) = map.next_entry::<String, String>()? {
                    let control = control_named(&kind)
                        .map_err(|e: A::Error| serde::de::Error::custom(format!("junction {junction}: {e}")))?;
                    if by.insert(junction.clone(), control).is_some() {
                        return Err(serde::de::Error::custom(format!("junction {junction} is named twice")));
                    }
                }
                Ok(ControlSpec::ByJunction(by))
            }
        }
        deserializer.deserialize_any(Visit)
    }
}

/// The original's roads: two lanes each way.
fn default_lanes() -> u32 {
    2
}

fn is_default_lanes(lanes: &u32) -> bool {
    *lanes == default_lanes()
}

/// What the bird's-eye camera frames: `"junctions"` (every junction box
/// and its stop lines, the default), `"network"` (every road to its U-turn
/// loop) or `{"x": [west, east], "y": [south, north]}` metres.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum CameraArea {
    Named(CameraAreaName),
    Area { x: [f64; 2], y: [f64; 2] },
}

/// The named areas of [`CameraArea`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum CameraAreaName {
    Junctions,
    Network,
}

/// The object form of a [`CameraArea`], as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCameraArea {
    x: [f64; 2],
    y: [f64; 2],
}

impl<'de> Deserialize<'de> for CameraArea {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct Visit;
        impl<'de> serde::de::Visitor<'de> for Visit {
            type Value = CameraArea;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("\"junctions\", \"network\" or {\"x\": [west, east], \"y\": [south, north]} (metres)")
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<CameraArea, E> {
                match v {
                    "junctions" => Ok(CameraArea::Named(CameraAreaName::Junctions)),
                    "network" => Ok(CameraArea::Named(CameraAreaName::Network)),
                    other => Err(E::custom(format!(
                        "{other:?} is not allowed: use \"junctions\", \"network\" or {{\"x\": [west, east], \"y\": [south, north]}}"
                    ))),
                }
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(self, map: A) -> Result<CameraArea, A::Error> {
                let raw = RawCameraArea::deserialize(serde::de::value::MapAccessDeserializer::new(map))?;
                Ok(CameraArea::Area { x: raw.x, y: raw.y })
            }
        }
        deserializer.deserialize_any(Visit)
    }
}

impl MapSpec {
    /// The area the bird's-eye camera frames (min corner, max corner), metres.
    pub fn camera_frame(&self) -> (glam::DVec2, glam::DVec2) {
        let layout = self.layout();
        if let (Some(network), None | Some(CameraArea::Named(_))) = (&self.network.0, &self.camera_area) {
            // An imported network is framed whole.
            return network.bounds;
        }
        match &self.camera_area {
            None | Some(CameraArea::Named(CameraAreaName::Junctions)) => layout.framed_area(),
            Some(CameraArea::Named(CameraAreaName::Network)) => layout.network_area(),
            Some(CameraArea::Area { x, y }) => (glam::DVec2::new(x[0], y[0]), glam::DVec2::new(x[1], y[1])),
        }
    }

    fn validate_camera_area(&self) -> Result<(), SpecError> {
        if let Some(CameraArea::Area { x, y }) = &self.camera_area {
            for (axis, [lo, hi]) in [("x", x), ("y", y)] {
                if !(lo.is_finite()
                    && hi.is_finite()
                    && lo.abs() <= MAX_CAMERA_COORDINATE
                    && hi.abs() <= MAX_CAMERA_COORDINATE
                    && lo < hi)
                {
                    return Err(SpecError::new(
                        "map.camera_area",
                        format!(
                            "{axis} = [{}, {}] is not allowed: give two finite coordinates within +-{MAX_CAMERA_COORDINATE} m, the lower first",
                            crate::json::Shown(*lo),
                            crate::json::Shown(*hi)
                        ),
                    ));
                }
            }
        }
        Ok(())
    }
}

/// One grid town's concrete size (a [`GridSpec`] with its counts drawn).
#[derive(Debug, Clone, Copy)]
struct Grid {
    rows: usize,
    columns: usize,
    block_m: f64,
    outer_m: f64,
}

/// Most roads a grid has each way (8 x 8 junctions).
pub const MAX_GRID_ROADS: usize = 8;

/// A number of roads: fixed (`3`), or drawn per scenario from the seed,
/// uniformly from a whole range (`{"uniform": [2, 5]}`, both ends included)
/// or from a list (`{"choice": [2, 4]}`, each entry equally likely).
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
#[serde(untagged)]
pub enum RoadCount {
    Fixed(usize),
    Uniform { uniform: [usize; 2] },
    Choice { choice: Vec<usize> },
}

impl From<usize> for RoadCount {
    fn from(n: usize) -> Self {
        RoadCount::Fixed(n)
    }
}

/// The object form of a [`RoadCount`], as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRoadCount {
    uniform: Option<[usize; 2]>,
    choice: Option<Vec<usize>>,
}

impl<'de> Deserialize<'de> for RoadCount {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct Visit;
        impl<'de> serde::de::Visitor<'de> for Visit {
            type Value = RoadCount;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a whole number, {\"uniform\": [low, high]} or {\"choice\": [a, b, ...]}")
            }
            fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<RoadCount, E> {
                Ok(RoadCount::Fixed(v.min(usize::MAX as u64) as usize))
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(self, map: A) -> Result<RoadCount, A::Error> {
                let raw = RawRoadCount::deserialize(serde::de::value::MapAccessDeserializer::new(map))?;
                match (raw.uniform, raw.choice) {
                    (Some(uniform), None) => Ok(RoadCount::Uniform { uniform }),
                    (None, Some(choice)) => Ok(RoadCount::Choice { choice }),
                    _ => Err(serde::de::Error::custom(
                        "give exactly one of {\"uniform\": [low, high]} or {\"choice\": [a, b, ...]}",
                    )),
                }
            }
        }
        deserializer.deserialize_any(Visit)
    }
}

impl RoadCount {
    /// Every count it can draw, ascending, each once.
    pub fn values(&self) -> Vec<usize> {
        let mut values = match self {
            RoadCount::Fixed(n) => vec![*n],
            RoadCount::Uniform { uniform: [lo, hi] } => (*lo..=*hi).collect(),
            RoadCount::Choice { choice } => choice.clone(),
        };
        values.sort_unstable();
        values.dedup();
        values
    }

    /// One count, drawn from `rng` (a fixed count draws nothing).
    pub fn draw(&self, rng: &mut impl rand::Rng) -> usize {
        use rand::RngExt;
        match self {
            RoadCount::Fixed(n) => *n,
            RoadCount::Uniform { uniform: [lo, hi] } => rng.random_range(*lo..=*hi),
            RoadCount::Choice { choice } => choice[rng.random_range(0..choice.len())],
        }
    }

    fn check(&self, field: &str) -> Result<(), SpecError> {
        match self {
            RoadCount::Uniform { uniform: [lo, hi] } if lo > hi => {
                return Err(SpecError::new(field, format!("uniform range [{lo}, {hi}] has low above high")))
            }
            RoadCount::Choice { choice } if choice.is_empty() => {
                return Err(SpecError::new(field, "choice list is empty"))
            }
            _ => {}
        }
        let allowed = 1..=MAX_GRID_ROADS;
        // A range is judged by its ends (listing it could take all memory).
        let refused = match self {
            RoadCount::Uniform { uniform: [lo, hi] } => (!allowed.contains(lo) || !allowed.contains(hi))
                .then(|| format!("uniform range [{lo}, {hi}] is not allowed")),
            _ => self.values().into_iter().find(|n| !allowed.contains(n)).map(|n| format!("{n} is not allowed")),
        };
        match refused {
            Some(what) => {
                Err(SpecError::new(field, format!("{what}: give a whole number of roads from 1 to {MAX_GRID_ROADS}")))
            }
            None => Ok(()),
        }
    }
}

/// The default city's block: roads 28 m apart.
fn default_block_m() -> f64 {
    28.0
}

/// The default city's roads run 22 m beyond their outermost crossing.
fn default_outer_m() -> f64 {
    22.0
}

impl Default for MapSpec {
    fn default() -> Self {
        let l = MapLayout::default();
        MapSpec {
            lane_width: l.lane_width,
            east_west_roads: [l.east_west_roads[0].1, l.east_west_roads[1].1],
            north_south_roads: [l.north_south_roads[0].1, l.north_south_roads[1].1],
            extent_x: l.extent_x,
            extent_y: l.extent_y,
            lane_change_m: l.lane_change_length,
            camera_altitude_m: None,
            camera_area: None,
            grid: None,
            sumo: None,
            sumo_sha256: None,
            network: LoadedNetwork::default(),
        }
    }
}

/// Largest map coordinate a spec may give for a grid's roads and extents,
/// metres.
const MAX_MAP_EXTENT: f64 = 5000.0;

/// Largest coordinate `map.camera_area` may give, metres. An imported
/// network's coordinates run from 0 to its size (netconvert moves its origin
/// to the south-west corner), so this admits a 100 km cut, a region larger
/// than any city.
/// It bounds every camera's position too (`cameras[i].static.centre`,
/// `cameras[i].pinhole.position`).
pub(super) const MAX_CAMERA_COORDINATE: f64 = 100_000.0;

impl MapSpec {
    /// Every town this map section can draw, as a map section of its own
    /// with fixed counts: grids by rows, then columns, ascending; one town
    /// (this section) when nothing is drawn.
    pub fn towns(&self) -> Vec<MapSpec> {
        let Some(grid) = &self.grid else { return vec![self.clone()] };
        let mut towns = Vec::new();
        for rows in grid.rows.values() {
            for columns in grid.columns.values() {
                let grid = GridSpec { rows: rows.into(), columns: columns.into(), ..grid.clone() };
                towns.push(MapSpec { grid: Some(grid), ..self.clone() });
            }
        }
        towns
    }

    /// Draws the town of one scenario from `rng`: rows, then columns.
    /// Returns it as [`MapSpec::towns`] lists it.
    pub fn draw_town(&self, rng: &mut impl rand::Rng) -> MapSpec {
        match &self.grid {
            Some(grid) if self.towns().len() > 1 => {
                let (rows, columns) = (grid.rows.draw(rng), grid.columns.draw(rng));
                let grid = GridSpec { rows: rows.into(), columns: columns.into(), ..grid.clone() };
                MapSpec { grid: Some(grid), ..self.clone() }
            }
            _ => self.clone(),
        }
    }

    /// A short name of a town: `default`, `custom` (four roads moved) or
    /// `grid-3x4` (rows x columns; `-b30-o20` when blocks or outer roads
    /// differ from the defaults).
    pub fn town_name(&self) -> String {
        if let Some(sumo) = &self.sumo {
            let file = network_file_name(sumo);
            return format!("sumo-{}", file.strip_suffix(".net.xml").unwrap_or(file));
        }
        match &self.grid {
            None if *self == MapSpec::default() => "default".into(),
            None => "custom".into(),
            Some(grid) => {
                let count = |c: &RoadCount| c.values().iter().map(|n| n.to_string()).collect::<Vec<_>>().join("-");
                let mut name = format!("grid-{}x{}", count(&grid.rows), count(&grid.columns));
                if grid.block_m != default_block_m() || grid.outer_m != default_outer_m() {
                    name += &format!("-b{}-o{}", grid.block_m, grid.outer_m);
                }
                if grid.lanes != default_lanes() {
                    name += &format!("-l{}", grid.lanes);
                }
                if !grid.missing.is_empty() {
                    name += &format!("-no-{}", grid.missing.join("-"));
                }
                if !grid.dead_ends.is_empty() {
                    let cut: Vec<&str> = grid.dead_ends.keys().map(String::as_str).collect();
                    name += &format!("-dead-{}", cut.join("-"));
                }
                match &grid.control {
                    ControlSpec::Every(c) if *c != JunctionControl::Signals => name += &format!("-{}", c.name()),
                    ControlSpec::ByJunction(by) => {
                        for (junction, c) in by.iter().filter(|(_, c)| **c != JunctionControl::Signals) {
                            name += &format!("-{junction}-{}", c.name());
                        }
                    }
                    ControlSpec::Every(_) => {}
                }
                name
            }
        }
    }

    /// The map of this section's town: the imported network, or the town
    /// built from [`MapSpec::layout`].
    pub fn city_map(&self) -> Result<std::sync::Arc<crate::map::CityMap>, SpecError> {
        match (&self.sumo, &self.network.0) {
            (None, _) => Ok(std::sync::Arc::new(crate::map::CityMap::new(self.layout()))),
            (Some(_), Some(network)) => Ok(network.map.clone()),
            (Some(sumo), None) => Err(SpecError::new(
                "map.sumo",
                format!("the network {sumo:?} was not read: a spec naming a SUMO network is read from its file (its path is relative to the spec)"),
            )),
        }
    }

    /// The layout the map is built from (a section that draws its town:
    /// the first of [`MapSpec::towns`]).
    pub fn layout(&self) -> MapLayout {
        if let Some(network) = &self.network.0 {
            return network.map.layout.clone();
        }
        let d = MapLayout::default();
        if let Some(spec) = self.grid.as_ref() {
            let grid = Grid {
                rows: spec.rows.values()[0],
                columns: spec.columns.values()[0],
                block_m: spec.block_m,
                outer_m: spec.outer_m,
            };
            let centres = |n: usize| (0..n).map(move |k| (k as f64 - n.saturating_sub(1) as f64 / 2.0) * grid.block_m);
            let reach = |n: usize| n.saturating_sub(1) as f64 / 2.0 * grid.block_m + grid.outer_m;
            // A, B, .. from north to south (ascending y: reversed), then the
            // north-south roads west to east.
            let letter = |k: usize| (b'A' + k as u8) as char;
            let east_west: Vec<(char, f64)> =
                centres(grid.rows).enumerate().map(|(k, y)| (letter(grid.rows - 1 - k), y)).collect();
            let north_south: Vec<(char, f64)> =
                centres(grid.columns).enumerate().map(|(k, x)| (letter(grid.rows + k), x)).collect();
            let junction_controls = (0..grid.rows)
                .flat_map(|r| north_south.iter().map(move |ns| format!("{}{}", letter(r), ns.0)))
                .map(|name| (spec.control.of(&name), name))
                .filter(|(c, _)| *c != JunctionControl::Signals)
                .map(|(c, name)| (name, c))
                .collect();
            let dead_ends = spec
                .dead_ends
                .iter()
                .filter_map(|(segment, kept)| {
                    let (road, k) = parse_segment(segment)?;
                    let [near, _] = segment_junctions(&east_west, &north_south, road, k)?;
                    // Kept at its near end: cut at the far one.
                    Some((road, k, *kept == near))
                })
                .collect();
            return MapLayout {
                lane_width: self.lane_width,
                east_west_roads: east_west,
                north_south_roads: north_south,
                extent_x: reach(grid.columns),
                extent_y: reach(grid.rows),
                lane_change_length: self.lane_change_m,
                missing_segments: spec.missing.iter().filter_map(|name| parse_segment(name)).collect(),
                lanes_per_direction: u8::try_from(spec.lanes).unwrap_or(u8::MAX),
                junction_controls,
                dead_ends,
                ..d
            };
        }
        MapLayout {
            lane_width: self.lane_width,
            east_west_roads: d.east_west_roads.iter().zip(self.east_west_roads).map(|(r, y)| (r.0, y)).collect(),
            north_south_roads: d.north_south_roads.iter().zip(self.north_south_roads).map(|(r, x)| (r.0, x)).collect(),
            extent_x: self.extent_x,
            extent_y: self.extent_y,
            lane_change_length: self.lane_change_m,
            sidewalk_width: d.sidewalk_width,
            ..d
        }
    }

    /// Checks sizes, and that every lane ending at an intersection is at
    /// least [`MapLayout::min_approach_length`] long.
    pub fn validate(&self) -> Result<(), SpecError> {
        positive("map.lane_width", self.lane_width, 10.0, "metres")?;
        positive("map.lane_change_m", self.lane_change_m, 200.0, "metres")?;
        if let Some(altitude) = self.camera_altitude_m {
            positive("map.camera_altitude_m", altitude, 10_000.0, "metres")?;
        }
        self.validate_camera_area()?;
        if let Some(sha) = &self.sumo_sha256 {
            if self.sumo.is_none() {
                return Err(SpecError::new("map.sumo_sha256", "pins a SUMO network, but map.sumo names none"));
            }
            if sha.len() != 64 || !sha.chars().all(|c| c.is_ascii_digit() || ('a'..='f').contains(&c)) {
                return Err(SpecError::new(
                    "map.sumo_sha256",
                    format!("{sha:?} is not allowed: 64 lower-case hex digits (sha256sum of the file)"),
                ));
            }
        }
        if let Some(sumo) = &self.sumo {
            let default = MapSpec::default();
            let moved = [
                ("map.grid", self.grid.is_some()),
                ("map.lane_width", self.lane_width != default.lane_width),
                ("map.east_west_roads", self.east_west_roads != default.east_west_roads),
                ("map.north_south_roads", self.north_south_roads != default.north_south_roads),
                ("map.extent_x", self.extent_x != default.extent_x),
                ("map.extent_y", self.extent_y != default.extent_y),
            ];
            if let Some((field, _)) = moved.iter().find(|m| m.1) {
                return Err(SpecError::new(
                    *field,
                    format!("the SUMO network {sumo:?} brings its own roads and lanes: leave {field} out (map.lane_change_m, map.camera_area and map.camera_altitude_m still apply)"),
                ));
            }
            if !sumo.ends_with(".xml") || sumo.trim().is_empty() {
                return Err(SpecError::new(
                    "map.sumo",
                    format!("{sumo:?} is not allowed: give the path of a SUMO network file, e.g. \"nets/town.net.xml\" (relative to the spec file)"),
                ));
            }
            return Ok(());
        }
        if let Some(grid) = &self.grid {
            grid.rows.check("map.grid.rows")?;
            grid.columns.check("map.grid.columns")?;
            for town in self.towns() {
                town.validate_grid()?;
            }
            return Ok(());
        }
        let layout = self.layout();
        let hw = layout.road_half_width();
        let need = layout.min_approach_length();
        let axes = [
            ("map.north_south_roads", self.north_south_roads, "map.extent_x", self.extent_x, "C", "D", "east-west"),
            ("map.east_west_roads", self.east_west_roads, "map.extent_y", self.extent_y, "B", "A", "north-south"),
        ];
        for (field, roads, extent_field, extent, first, second, crossing) in axes {
            if !roads.iter().all(|r| r.is_finite() && r.abs() <= MAX_MAP_EXTENT) {
                return Err(SpecError::new(
                    field,
                    format!(
                        "{roads:?} is not allowed: give two finite centre-line positions within +-{MAX_MAP_EXTENT} m"
                    ),
                ));
            }
            positive(extent_field, extent, MAX_MAP_EXTENT, "metres")?;
            // (Told as it is: a negative road length between them said
            // nothing of the order.)
            if roads[1] <= roads[0] {
                return Err(SpecError::new(
                    field,
                    format!(
                        "{roads:?} is not allowed: give road {first}'s centre line first, then road {second}'s, \
                         the second greater{}",
                        if roads[0] == roads[1] { String::new() } else { format!(" ([{}, {}])", roads[1], roads[0]) }
                    ),
                ));
            }
            let segments = [
                (format!("from -{extent_field} to road {first}"), roads[0] - hw + extent),
                (format!("between roads {first} and {second}"), roads[1] - roads[0] - 2.0 * hw),
                (format!("from road {second} to +{extent_field}"), extent - roads[1] - hw),
            ];
            for (what, length) in segments {
                if length < need - 1e-9 {
                    return Err(SpecError::new(
                        if what.contains("between") { field } else { extent_field },
                        format!(
                            "roads {first} and {second} at {roads:?} m with {extent_field} {extent} m leave {length:.2} m of the {crossing} roads {what}: {}",
                            approach_rule(&layout)
                        ),
                    ));
                }
            }
        }
        Ok(())
    }

    /// Checks a grid town: its size, and that every lane ending at an
    /// intersection is long enough to change lanes before it.
    fn validate_grid(&self) -> Result<(), SpecError> {
        let Some(spec) = &self.grid else { return Ok(()) };
        let grid = Grid {
            rows: spec.rows.values()[0],
            columns: spec.columns.values()[0],
            block_m: spec.block_m,
            outer_m: spec.outer_m,
        };
        let default = MapSpec::default();
        if self.east_west_roads != default.east_west_roads
            || self.north_south_roads != default.north_south_roads
            || self.extent_x != default.extent_x
            || self.extent_y != default.extent_y
        {
            return Err(SpecError::new(
                "map.grid",
                "a grid places its own roads: leave out map.east_west_roads, map.north_south_roads, map.extent_x and map.extent_y (use grid.block_m and grid.outer_m)",
            ));
        }
        if !(1..=3).contains(&spec.lanes) {
            return Err(SpecError::new(
                "map.grid.lanes",
                format!("{} is not allowed: lanes each way on every road, 1 to 3", spec.lanes),
            ));
        }
        positive("map.grid.block_m", grid.block_m, MAX_MAP_EXTENT / MAX_GRID_ROADS as f64, "metres")?;
        positive("map.grid.outer_m", grid.outer_m, MAX_MAP_EXTENT, "metres")?;
        let layout = self.layout();
        let hw = layout.road_half_width();
        let need = layout.min_approach_length();
        let lanes = [
            (
                "map.grid.block_m",
                grid.block_m - 2.0 * hw,
                "between neighbouring roads",
                grid.rows.max(grid.columns) > 1,
            ),
            ("map.grid.outer_m", grid.outer_m - hw, "beyond the outermost roads", true),
        ];
        for (field, length, what, applies) in lanes {
            if applies && length < need - 1e-9 {
                return Err(SpecError::new(
                    field,
                    format!("leaves {length:.2} m of road {what}: {}", approach_rule(&layout)),
                ));
            }
        }
        self.validate_missing(&layout)?;
        self.validate_dead_ends(&layout)?;
        self.validate_control(&layout)
    }

    /// Checks `grid.dead_ends`: each names a segment between two junctions
    /// of this town and one of those two, leaves a long enough approach,
    /// and what is left is a network a car can drive all of.
    fn validate_dead_ends(&self, layout: &MapLayout) -> Result<(), SpecError> {
        let Some(spec) = &self.grid else { return Ok(()) };
        if spec.dead_ends.is_empty() {
            return Ok(());
        }
        let town = self.town_name();
        for (segment, kept) in &spec.dead_ends {
            let field = format!("map.grid.dead_ends.{segment}");
            let ends = parse_segment(segment)
                .and_then(|(road, k)| segment_junctions(&layout.east_west_roads, &layout.north_south_roads, road, k));
            let Some([near, far]) = ends else {
                return Err(SpecError::new(
                    field,
                    format!(
                        "{segment:?} is not a road segment between two junctions of the {town} town: a road letter and a segment number from 1 to one less than the road's junctions (`causalcity map` lists the lanes); outer segments already end in a loop"
                    ),
                ));
            };
            if spec.missing.contains(segment) {
                return Err(SpecError::new(field, format!("{segment:?} is also in map.grid.missing: give it once")));
            }
            if *kept != near && *kept != far {
                return Err(SpecError::new(
                    field,
                    format!("{kept:?} is not a junction at an end of {segment}: give {near} or {far}, the junction it stays joined to"),
                ));
            }
            let length = spec.block_m - 2.0 * layout.road_half_width() - layout.dead_end_setback();
            if length < layout.min_approach_length() - 1e-9 {
                return Err(SpecError::new(
                    field,
                    format!(
                        "leaves {length:.2} m of road before {kept} once its loop ({:.1} m) is taken off: {} (raise map.grid.block_m)",
                        layout.dead_end_setback(),
                        approach_rule(layout)
                    ),
                ));
            }
        }
        if let Some(problem) = crate::map::CityMap::new(layout.clone()).network_problem() {
            let cut: Vec<&str> = spec.dead_ends.keys().map(String::as_str).collect();
            return Err(SpecError::new("map.grid.dead_ends", format!("with dead ends {}: {problem}", cut.join(", "))));
        }
        Ok(())
    }

    /// Checks that `grid.control` names junctions of this town.
    fn validate_control(&self, layout: &MapLayout) -> Result<(), SpecError> {
        let Some(ControlSpec::ByJunction(by)) = self.grid.as_ref().map(|g| &g.control) else { return Ok(()) };
        let names: Vec<String> = layout
            .east_west_roads
            .iter()
            .flat_map(|ew| layout.north_south_roads.iter().map(move |ns| format!("{}{}", ew.0, ns.0)))
            .collect();
        for junction in by.keys() {
            if !names.contains(junction) {
                return Err(SpecError::new(
                    format!("map.grid.control.{junction}"),
                    format!(
                        "{junction:?} is not a junction of the {} town: its junctions are {} (east-west road, then north-south road)",
                        self.town_name(),
                        names.join(" ")
                    ),
                ));
            }
        }
        Ok(())
    }

    /// Checks `grid.missing`: each names a segment of this town, once, and
    /// what is left is a network a car can drive all of.
    fn validate_missing(&self, layout: &MapLayout) -> Result<(), SpecError> {
        let Some(spec) = &self.grid else { return Ok(()) };
        if spec.missing.is_empty() {
            return Ok(());
        }
        let roads: Vec<(char, usize)> = (layout.east_west_roads.iter().map(|r| (r.0, layout.north_south_roads.len())))
            .chain(layout.north_south_roads.iter().map(|r| (r.0, layout.east_west_roads.len())))
            .collect();
        let town = self.town_name();
        for (i, name) in spec.missing.iter().enumerate() {
            let field = format!("map.grid.missing[{i}]");
            let known = parse_segment(name)
                .and_then(|(road, segment)| roads.iter().find(|r| r.0 == road).filter(|r| segment as usize <= r.1));
            if known.is_none() {
                let example: Vec<String> = roads.iter().take(2).map(|(r, n)| format!("{r}0 .. {r}{n}")).collect();
                return Err(SpecError::new(
                    field,
                    format!(
                        "{name:?} is not a road segment of the {town} town: a road letter and a segment number, e.g. {} (`causalcity map` lists the lanes)",
                        example.join(", ")
                    ),
                ));
            }
            if spec.missing[..i].contains(name) {
                return Err(SpecError::new(field, format!("{name:?} is named twice")));
            }
        }
        if let Some(problem) = crate::map::CityMap::new(layout.clone()).network_problem() {
            return Err(SpecError::new("map.grid.missing", format!("without {}: {problem}", spec.missing.join(", "))));
        }
        Ok(())
    }
}

/// The junctions at the near (west or south) and far ends of segment `k`
/// of road `road`, by name, when it runs between two junctions.
fn segment_junctions(east_west: &[(char, f64)], north_south: &[(char, f64)], road: char, k: u8) -> Option<[String; 2]> {
    let k = k as usize;
    if east_west.iter().any(|r| r.0 == road) {
        (k >= 1 && k < north_south.len())
            .then(|| [format!("{road}{}", north_south[k - 1].0), format!("{road}{}", north_south[k].0)])
    } else if north_south.iter().any(|r| r.0 == road) {
        // East-west roads ascend in y: the near (south) junction first.
        (k >= 1 && k < east_west.len())
            .then(|| [format!("{}{road}", east_west[k - 1].0), format!("{}{road}", east_west[k].0)])
    } else {
        None
    }
}

/// `"C0"` as (road, segment): one capital letter, then a number.
fn parse_segment(name: &str) -> Option<(char, u8)> {
    let mut chars = name.chars();
    let road = chars.next().filter(char::is_ascii_uppercase)?;
    let digits = chars.as_str();
    if digits.is_empty() || !digits.chars().all(|c| c.is_ascii_digit()) || digits.len() > 2 {
        return None;
    }
    Some((road, digits.parse().ok()?))
}

/// Why a lane that ends at an intersection has a least length, for the
/// errors of both map forms.
fn approach_rule(layout: &MapLayout) -> String {
    format!(
        "every lane that ends at an intersection must be at least {:.1} m long ({} lane change{} of {} m + stop-line setback {} m + {} m) and roads are {} lanes of {} m",
        layout.min_approach_length(),
        layout.lane_changes_to_turn(),
        if layout.lane_changes_to_turn() == 1 { "" } else { "s" },
        layout.lane_change_length,
        layout.stop_line_setback,
        crate::map::APPROACH_MARGIN_M,
        2 * layout.lanes_per_direction,
        layout.lane_width
    )
}
