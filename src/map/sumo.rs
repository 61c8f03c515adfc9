//! SUMO road networks (`.net.xml`, as `netconvert` writes them from
//! OpenStreetMap or OpenDRIVE): read with serde into raw types, then
//! resolved and checked in one pass into a [`SumoNetwork`]: the lanes a
//! passenger car may drive (centre-line polylines, metres), the junctions
//! with their control, the connections between lanes with their turn and
//! their path through the junction, and the traffic-light programmes.
//!
//! What is kept: normal edges and the lanes of them that allow passenger
//! cars; connections between kept lanes. Pedestrian crossings, walking
//! areas and lanes closed to cars are left out and counted. What is
//! refused, naming the element and its id: junction kinds with no
//! counterpart here (rail crossings, zippers, ...), malformed shapes and
//! references to elements the file does not have.

use super::signals::{DETECTOR_GAP_S, MAX_GAP_S};
use super::Turn;
use glam::DVec2;
use serde::Deserialize;
use std::collections::HashMap;

/// The `<net>` element, as written (attributes `@`-prefixed).
#[derive(Debug, Deserialize)]
struct RawNet {
    #[serde(rename = "@version")]
    version: Option<String>,
    #[serde(rename = "edge", default)]
    edges: Vec<RawEdge>,
    #[serde(rename = "tlLogic", default)]
    programmes: Vec<RawProgramme>,
    #[serde(rename = "junction", default)]
    junctions: Vec<RawJunction>,
    #[serde(rename = "connection", default)]
    connections: Vec<RawConnection>,
}

#[derive(Debug, Deserialize)]
struct RawEdge {
    #[serde(rename = "@id")]
    id: String,
    #[serde(rename = "@function")]
    function: Option<String>,
    #[serde(rename = "@from")]
    from: Option<String>,
    #[serde(rename = "@to")]
    to: Option<String>,
    #[serde(rename = "@priority")]
    priority: Option<i32>,
    #[serde(rename = "lane", default)]
    lanes: Vec<RawLane>,
}

#[derive(Debug, Deserialize)]
struct RawLane {
    #[serde(rename = "@id")]
    id: String,
    #[serde(rename = "@index")]
    index: u32,
    #[serde(rename = "@speed")]
    speed: f64,
    #[serde(rename = "@length")]
    length: f64,
    #[serde(rename = "@width")]
    width: Option<f64>,
    #[serde(rename = "@shape")]
    shape: String,
    #[serde(rename = "@allow")]
    allow: Option<String>,
    #[serde(rename = "@disallow")]
    disallow: Option<String>,
    /// How far before its junction the lane's written shape stops, metres
    /// (a stop line set back: SUMO cuts the shape it writes by it).
    #[serde(rename = "@endOffset")]
    end_offset: Option<f64>,
    /// The same at the lane's start.
    #[serde(rename = "@startOffset")]
    start_offset: Option<f64>,
}

#[derive(Debug, Deserialize)]
struct RawJunction {
    #[serde(rename = "@id")]
    id: String,
    #[serde(rename = "@type")]
    kind: String,
    #[serde(rename = "@x")]
    x: f64,
    #[serde(rename = "@y")]
    y: f64,
    #[serde(rename = "@shape")]
    shape: Option<String>,
}

#[derive(Debug, Deserialize)]
struct RawConnection {
    #[serde(rename = "@from")]
    from: String,
    #[serde(rename = "@to")]
    to: String,
    #[serde(rename = "@fromLane")]
    from_lane: u32,
    #[serde(rename = "@toLane")]
    to_lane: u32,
    #[serde(rename = "@via")]
    via: Option<String>,
    #[serde(rename = "@tl")]
    tl: Option<String>,
    /// -1 for a link the lights do not govern.
    #[serde(rename = "@linkIndex")]
    link_index: Option<i64>,
    #[serde(rename = "@dir")]
    dir: String,
}

#[derive(Debug, Deserialize)]
struct RawProgramme {
    #[serde(rename = "@id")]
    id: String,
    /// `static` (the default), `actuated`, ...
    #[serde(rename = "@type")]
    kind: Option<String>,
    #[serde(rename = "@offset", default)]
    offset: f64,
    /// `<param key=".." value=".."/>`: an actuated programme's `max-gap`
    /// and `detector-gap` are read.
    #[serde(rename = "param", default)]
    params: Vec<RawParam>,
    #[serde(rename = "phase", default)]
    phases: Vec<RawPhase>,
}

#[derive(Debug, Deserialize)]
struct RawParam {
    #[serde(rename = "@key", default)]
    key: String,
    #[serde(rename = "@value", default)]
    value: String,
}

#[derive(Debug, Deserialize)]
struct RawPhase {
    #[serde(rename = "@duration")]
    duration: f64,
    #[serde(rename = "@minDur")]
    min_duration: Option<f64>,
    #[serde(rename = "@maxDur")]
    max_duration: Option<f64>,
    #[serde(rename = "@state")]
    state: String,
}

/// How an imported junction decides who goes, as SUMO's `type` says.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SumoJunctionKind {
    /// `traffic_light`, `traffic_light_unregulated`, `traffic_light_right_on_red`.
    TrafficLight,
    /// `priority`, `priority_stop`: a priority road, the others give way.
    Priority,
    /// `right_before_left`: the car from the right goes first.
    RightBeforeLeft,
    /// `left_before_right`: the car from the left goes first (left-hand traffic).
    LeftBeforeRight,
    /// `allway_stop`.
    AllWayStop,
    /// `dead_end`: where a road stops.
    DeadEnd,
    /// `unregulated`: no rule at all.
    Unregulated,
}

impl SumoJunctionKind {
    fn of(kind: &str) -> Option<SumoJunctionKind> {
        Some(match kind {
            "traffic_light" | "traffic_light_unregulated" | "traffic_light_right_on_red" => {
                SumoJunctionKind::TrafficLight
            }
            "priority" | "priority_stop" => SumoJunctionKind::Priority,
            "right_before_left" => SumoJunctionKind::RightBeforeLeft,
            "left_before_right" => SumoJunctionKind::LeftBeforeRight,
            "allway_stop" => SumoJunctionKind::AllWayStop,
            "dead_end" => SumoJunctionKind::DeadEnd,
            "unregulated" => SumoJunctionKind::Unregulated,
            _ => return None,
        })
    }

    /// The word the listing and JSON use.
    pub fn name(self) -> &'static str {
        match self {
            SumoJunctionKind::TrafficLight => "traffic_light",
            SumoJunctionKind::Priority => "priority",
            SumoJunctionKind::RightBeforeLeft => "right_before_left",
            SumoJunctionKind::LeftBeforeRight => "left_before_right",
            SumoJunctionKind::AllWayStop => "all_way_stop",
            SumoJunctionKind::DeadEnd => "dead_end",
            SumoJunctionKind::Unregulated => "unregulated",
        }
    }
}

/// An actuated phase's bounds: `Some((minDur, maxDur))` where they differ
/// (SUMO extends such a phase), `None` for a phase of fixed length. A
/// missing one is the written `duration` (kept on the right side of the
/// other); an error naming the programme for bounds that are not
/// `0 <= minDur <= maxDur`.
fn phase_bounds(programme: &str, phase: &RawPhase) -> Result<Option<(f64, f64)>, String> {
    let (min, max) = match (phase.min_duration, phase.max_duration) {
        (None, None) => return Ok(None),
        (Some(min), None) => (min, phase.duration.max(min)),
        (None, Some(max)) => (phase.duration.min(max), max),
        (Some(min), Some(max)) => (min, max),
    };
    if !(min.is_finite() && max.is_finite() && min >= 0.0 && min <= max) {
        return Err(format!(
            "<tlLogic id=\"{programme}\">: a phase has minDur {min} and maxDur {max}; allowed: 0 <= minDur <= maxDur"
        ));
    }
    Ok((min < max).then_some((min, max)))
}

/// An actuated programme's `<param key="KEY">` in seconds, `default` when
/// absent; an error naming the programme for one that is not a positive
/// number.
fn seconds_param(programme: &RawProgramme, key: &str, default: f64) -> Result<f64, String> {
    let Some(p) = programme.params.iter().find(|p| p.key == key) else { return Ok(default) };
    match p.value.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        _ => Err(format!(
            "<tlLogic id=\"{}\">: <param key=\"{key}\" value=\"{}\"/>; allowed: seconds above 0",
            programme.id, p.value
        )),
    }
}

/// Just the names of a `.net.xml`'s elements, read when the file itself
/// could not be: what [`unreadable`] names an element by.
#[derive(Debug, Default, Deserialize)]
struct Names {
    #[serde(rename = "edge", default)]
    edges: Vec<EdgeNames>,
    #[serde(rename = "junction", default)]
    junctions: Vec<Named>,
    #[serde(rename = "connection", default)]
    connections: Vec<ConnectionNames>,
    #[serde(rename = "tlLogic", default)]
    programmes: Vec<Named>,
}

#[derive(Debug, Default, Deserialize)]
struct EdgeNames {
    #[serde(rename = "@id")]
    id: Option<String>,
    #[serde(rename = "lane", default)]
    lanes: Vec<Named>,
}

#[derive(Debug, Default, Deserialize)]
struct Named {
    #[serde(rename = "@id")]
    id: Option<String>,
}

#[derive(Debug, Default, Deserialize)]
struct ConnectionNames {
    #[serde(rename = "@from")]
    from: Option<String>,
    #[serde(rename = "@to")]
    to: Option<String>,
}

/// The name of the document's first element (`None`: it has none).
fn root_element(text: &str) -> Result<Option<String>, quick_xml::Error> {
    use quick_xml::events::Event;
    let mut reader = quick_xml::Reader::from_str(text);
    loop {
        match reader.read_event()? {
            Event::Start(e) | Event::Empty(e) => return Ok(Some(e.name().into_inner().to_owned())),
            Event::Eof => return Ok(None),
            _ => {}
        }
    }
}

/// Most characters of a message quoted from a network file: a value of
/// millions of characters (or a file of zero bytes read as one) was quoted
/// whole, gigabytes of error.
const QUOTED_CHARS: usize = 240;

/// `message` with its middle left out when it is longer than
/// [`QUOTED_CHARS`], and control characters escaped.
fn clipped(message: &str) -> String {
    let shown = |s: &str| -> String {
        s.chars().map(|c| if c.is_control() { c.escape_debug().to_string() } else { c.to_string() }).collect()
    };
    let chars = message.chars().count();
    if chars <= QUOTED_CHARS {
        return shown(message);
    }
    let (head, tail) = (QUOTED_CHARS * 2 / 3, QUOTED_CHARS / 3);
    let (first, last): (String, String) =
        (message.chars().take(head).collect(), message.chars().skip(chars - tail).collect());
    format!("{} ... ({} characters left out) ... {}", shown(&first), chars - head - tail, shown(&last))
}

/// Why `text` is not a network, naming the element and the attribute
/// the reader stopped at (`<lane id="a_0">: speed: invalid type: string
/// "fast", expected a number`; `<junction id="J1">: no x attribute`),
/// in the words the JSON reader uses.
fn unreadable(text: &str, error: &serde_path_to_error::Error<quick_xml::DeError>) -> String {
    use serde_path_to_error::Segment;
    let mut elements: Vec<(&str, usize)> = Vec::new();
    let mut attribute = None;
    let segments: Vec<&Segment> = error.path().iter().collect();
    for (k, segment) in segments.iter().enumerate() {
        match (segment, segments.get(k + 1)) {
            (Segment::Map { key }, Some(Segment::Seq { index })) => elements.push((key.as_str(), *index)),
            (Segment::Map { key }, None) if key.starts_with('@') => attribute = Some(&key[1..]),
            _ => {}
        }
    }
    let inner = error.inner().to_string();
    if elements.is_empty() {
        return format!("not a SUMO network (.net.xml): {inner}");
    }
    let names: Names = quick_xml::de::from_str(text).unwrap_or_default();
    let id = |what: &str, id: Option<&Option<String>>, place: usize| match id.and_then(|i| i.as_deref()) {
        Some(id) => format!("<{what} id=\"{id}\">"),
        None => format!("<{what}> number {}", place + 1),
    };
    let element = match elements.as_slice() {
        [("edge", e)] => id("edge", names.edges.get(*e).map(|e| &e.id), *e),
        [("edge", e), ("lane", l)] => match names.edges.get(*e).and_then(|e| e.lanes.get(*l)) {
            Some(Named { id: Some(lane) }) => format!("<lane id=\"{lane}\">"),
            _ => format!("{}'s <lane> number {}", id("edge", names.edges.get(*e).map(|e| &e.id), *e), l + 1),
        },
        [("junction", j)] => id("junction", names.junctions.get(*j).map(|j| &j.id), *j),
        [("connection", c)] => match names.connections.get(*c) {
            Some(ConnectionNames { from: Some(from), to: Some(to) }) => {
                format!("<connection from=\"{from}\" to=\"{to}\">")
            }
            _ => format!("<connection> number {}", c + 1),
        },
        [("tlLogic", p)] => id("tlLogic", names.programmes.get(*p).map(|p| &p.id), *p),
        [("tlLogic", p), (inside, k)] => {
            format!("{}'s <{inside}> number {}", id("tlLogic", names.programmes.get(*p).map(|p| &p.id), *p), k + 1)
        }
        _ => format!("<{}>", elements.iter().map(|(name, _)| *name).collect::<Vec<_>>().join("> <")),
    };
    // `invalid type: string "fast", expected f64`: the value as written,
    // and what the attribute takes.
    let value = inner.strip_prefix("invalid type: string ").and_then(|m| m.rsplit_once(", expected "));
    let takes = |rust: &str| match rust {
        "f64" | "f32" => "a number",
        "u8" | "u16" | "u32" | "u64" | "usize" => "a whole number, 0 or more",
        _ => "a whole number",
    };
    match (attribute, inner.strip_prefix("missing field `@").and_then(|m| m.strip_suffix('`')), value) {
        (_, Some(missing), _) => format!("{element}: no {missing} attribute"),
        (Some(attribute), None, Some((written, rust))) => {
            format!("{element}: {attribute}={written}; allowed: {}", takes(rust))
        }
        (Some(attribute), None, None) => format!("{element}: {attribute}: {}", crate::json::in_plain_words(&inner)),
        (None, None, _) => format!("{element}: {}", crate::json::in_plain_words(&inner)),
    }
}

/// SUMO junction types this reader refuses, and why.
const UNSUPPORTED_JUNCTIONS: [(&str, &str); 4] = [
    ("rail_crossing", "rail crossings"),
    ("rail_signal", "rail signals"),
    ("zipper", "zipper merges"),
    ("district", "districts"),
];

/// One imported junction.
#[derive(Debug, Clone)]
pub struct SumoJunction {
    pub id: String,
    pub kind: SumoJunctionKind,
    /// Metres, in the network's own coordinates.
    pub centre: DVec2,
    /// Its outline (empty when the file gives none).
    pub shape: Vec<DVec2>,
}

/// One lane a passenger car may drive.
#[derive(Debug, Clone)]
pub struct SumoLane {
    /// SUMO's id, `EDGE_INDEX`.
    pub id: String,
    pub edge: String,
    /// 0 is the rightmost lane of its edge.
    pub index: u32,
    /// Speed limit, m/s.
    pub speed: f64,
    /// Length along its shape, metres.
    pub length: f64,
    /// Width, metres (SUMO's default 3.2 when the file gives none).
    pub width: f64,
    /// Centre line, metres, at least two points.
    pub shape: Vec<DVec2>,
    /// Junctions (indices into [`SumoNetwork::junctions`]) at its start and end.
    pub from: usize,
    pub to: usize,
    /// How far its written shape stops before its start and end junctions
    /// (`startOffset`, `endOffset`), metres.
    pub set_back: (f64, f64),
    /// Its edge's priority (higher: the priority road), as netconvert set it.
    pub priority: i32,
}

/// A movement from the end of one kept lane to the start of another.
#[derive(Debug, Clone)]
pub struct SumoConnection {
    /// Indices into [`SumoNetwork::lanes`].
    pub from: usize,
    pub to: usize,
    /// Its turn: a partial one (`dir` `R` or `L`) is a slight turn where
    /// its lane also has a full one of its kind (`r` or `l`: a junction of
    /// five arms or more), else a right or left.
    pub turn: Turn,
    /// Its path through the junction (the shapes of the internal lanes it
    /// crosses, in turn), metres; empty when the file has none (a straight
    /// join).
    pub path: Vec<DVec2>,
    /// The traffic light governing it: (index into
    /// [`SumoNetwork::programmes`], index into each phase's state).
    pub signal: Option<(usize, usize)>,
}

/// A traffic-light programme: phases of (seconds, one state letter per link).
#[derive(Debug, Clone)]
pub struct SumoProgramme {
    pub id: String,
    /// Seconds.
    pub offset: f64,
    pub phases: Vec<(f64, String)>,
    /// Per phase of a traffic-actuated programme (`type="actuated"`), the
    /// bounds (`minDur`, `maxDur`, seconds) between which detected traffic
    /// sets its length; `None` for a phase of fixed length. Empty for any
    /// other programme.
    pub actuated: Vec<Option<(f64, f64)>>,
    /// An actuated programme's longest time gap between cars that extends
    /// a phase (`max-gap`) and its detectors' distance before the stop
    /// line in seconds at the lane's speed limit (`detector-gap`): its
    /// params, else SUMO's defaults.
    pub max_gap: f64,
    pub detector_gap: f64,
}

/// A road network read from a SUMO `.net.xml`, checked.
#[derive(Debug, Clone)]
pub struct SumoNetwork {
    pub junctions: Vec<SumoJunction>,
    pub lanes: Vec<SumoLane>,
    pub connections: Vec<SumoConnection>,
    pub programmes: Vec<SumoProgramme>,
    /// What the file has that cars do not drive on and was left out:
    /// (what, how many).
    pub left_out: Vec<(&'static str, usize)>,
}

/// Width SUMO gives a lane whose file says none, metres (SUMO's
/// `default.lanewidth`).
pub const SUMO_DEFAULT_LANE_WIDTH_M: f64 = 3.2;

/// Largest coordinate of any point of an imported network, metres, on
/// either axis: 10,000 km, which UTM coordinates never reach (netconvert
/// keeps them with `--offset.disable-normalization`; by default it moves
/// the origin to the network's south-west corner).
pub const MAX_NETWORK_COORDINATE_M: f64 = 1.0e7;

/// Largest span of an imported network's points, metres, on either axis:
/// 1,000 km, more than any region a scenario drives. A larger one is a
/// broken file, and geometry built from it (the loop at a dead end, a
/// lane's route) would not fit in memory.
pub const MAX_NETWORK_SPAN_M: f64 = 1.0e6;

/// Farthest a lane's end may lie beyond the outline of the junction it
/// starts or ends at, metres. netconvert writes a lane's ends on the
/// outline (0 m beyond it in every network under tests/data/sumo); 50 m
/// leaves room for hand-made files whose junctions have no outline.
pub const MAX_LANE_END_GAP_M: f64 = 50.0;

/// Largest offset (either sign) of a light programme, seconds: the longest
/// scenario a spec allows (`spec::MAX_SCENARIO_S`, which a test holds it
/// to). A light's clock is the scenario's time plus its offset, which
/// beyond that would lose the time itself (1e300 s froze every light).
pub const MAX_LIGHT_OFFSET_S: f64 = 1.0e6;

/// Widest lane an imported network may give, metres: roads' lanes are a
/// few metres wide (SUMO's default [`SUMO_DEFAULT_LANE_WIDTH_M`]).
pub const MAX_LANE_WIDTH_M: f64 = 50.0;

/// An id that is empty (or blank, or holds control characters): no name a
/// scenario file or a reader can use.
fn blank_id(id: &str) -> bool {
    id.trim().is_empty() || id.chars().any(char::is_control)
}

/// Parses `"x1,y1 x2,y2 ..."`.
fn polyline(text: &str) -> Option<Vec<DVec2>> {
    text.split_whitespace()
        .map(|pair| {
            let mut parts = pair.split(',');
            let x: f64 = parts.next()?.parse().ok()?;
            let y: f64 = parts.next()?.parse().ok()?;
            // A third value (z) is allowed and ignored.
            within_reach(x, y).then_some(DVec2::new(x, y))
        })
        .collect()
}

/// What a shape or position must be, for messages.
const POINTS_ALLOWED: &str = "x,y points in metres, each number from -10000000 to 10000000";

/// Whether `x, y` is a point a network may have: finite, and within
/// [`MAX_NETWORK_COORDINATE_M`] of the origin on both axes.
fn within_reach(x: f64, y: f64) -> bool {
    x.abs() <= MAX_NETWORK_COORDINATE_M && y.abs() <= MAX_NETWORK_COORDINATE_M
}

/// Whether a lane with these `allow` / `disallow` lists lets passenger cars on.
fn allows_cars(allow: Option<&str>, disallow: Option<&str>) -> bool {
    let has = |list: Option<&str>, word: &str| list.is_some_and(|l| l.split_whitespace().any(|w| w == word));
    match allow {
        Some(list) => has(Some(list), "passenger") || has(Some(list), "all"),
        None => !has(disallow, "passenger") && !has(disallow, "all"),
    }
}

/// SUMO's `dir` as a turn.
fn turn_of(dir: &str) -> Option<Turn> {
    Some(match dir {
        "s" => Turn::Straight,
        "l" | "L" => Turn::Left,
        "r" | "R" => Turn::Right,
        "t" => Turn::UTurn,
        _ => return None,
    })
}

impl SumoNetwork {
    /// Reads the text of a `.net.xml`; errors name the element, its id and
    /// what is wrong (the file's name is the caller's to add).
    pub fn from_xml(text: &str) -> Result<SumoNetwork, String> {
        match root_element(text) {
            Ok(Some(root)) if root != "net" => {
                return Err(format!(
                    "its root element is <{}>, not <net>: not a SUMO network (.net.xml, as netconvert writes it)",
                    clipped(&root)
                ))
            }
            Ok(Some(_)) => {}
            Ok(None) => return Err("it holds no XML element: not a SUMO network (.net.xml)".into()),
            Err(e) => return Err(clipped(&format!("not XML, so not a SUMO network (.net.xml): {e}"))),
        }
        let mut de = quick_xml::de::Deserializer::from_str(text);
        let raw: RawNet = serde_path_to_error::deserialize(&mut de).map_err(|e| clipped(&unreadable(text, &e)))?;
        if raw.version.is_none() {
            return Err("<net> has no version attribute: not a network netconvert wrote".into());
        }
        let mut left_out: HashMap<&'static str, usize> = HashMap::new();

        // Every junction but the internal ones; a kind with no counterpart
        // here is refused once a lane cars drive reaches it.
        let mut junctions = Vec::new();
        let mut junction_index = HashMap::new();
        let mut unsupported: HashMap<&str, &str> = HashMap::new();
        let mut junction_ids = std::collections::HashSet::new();
        for j in &raw.junctions {
            if blank_id(&j.id) {
                return Err(format!("<junction id={:?}>: an empty id; give each junction a name", j.id));
            }
            if !junction_ids.insert(j.id.as_str()) {
                return Err(format!("<junction id=\"{}\">: defined twice; each junction's id must be unique", j.id));
            }
            if j.kind == "internal" {
                continue;
            }
            let Some(kind) = SumoJunctionKind::of(&j.kind) else {
                unsupported.insert(j.id.as_str(), j.kind.as_str());
                continue;
            };
            if !within_reach(j.x, j.y) {
                return Err(format!("<junction id=\"{}\">: x {}, y {}; allowed: {POINTS_ALLOWED}", j.id, j.x, j.y));
            }
            let shape = match &j.shape {
                Some(text) => polyline(text)
                    .ok_or_else(|| format!("<junction id=\"{}\">: shape {text:?}; allowed: {POINTS_ALLOWED}", j.id))?,
                None => Vec::new(),
            };
            junction_index.insert(j.id.as_str(), junctions.len());
            junctions.push(SumoJunction { id: j.id.clone(), kind, centre: DVec2::new(j.x, j.y), shape });
        }

        // Every edge and lane of the file (internal ones and those cars do
        // not drive included), for connections to name.
        let mut edge_lanes: HashMap<&str, Vec<u32>> = HashMap::new();
        let mut lane_ids = std::collections::HashSet::new();
        for e in &raw.edges {
            if edge_lanes.contains_key(e.id.as_str()) {
                return Err(format!("<edge id=\"{}\">: defined twice; each edge's id must be unique", e.id));
            }
            if blank_id(&e.id) {
                return Err(format!("<edge id={:?}>: an empty id; give each edge a name", e.id));
            }
            let indices = edge_lanes.entry(e.id.as_str()).or_default();
            for l in &e.lanes {
                if blank_id(&l.id) {
                    return Err(format!(
                        "<lane id={:?}> of <edge id=\"{}\">: an empty id; give each lane a name (SUMO's are EDGE_INDEX)",
                        l.id, e.id
                    ));
                }
                if indices.contains(&l.index) {
                    return Err(format!(
                        "<edge id=\"{}\">: two lanes have index {}; each lane of an edge has its own",
                        e.id, l.index
                    ));
                }
                if !lane_ids.insert(l.id.as_str()) {
                    return Err(format!("<lane id=\"{}\">: defined twice; each lane's id must be unique", l.id));
                }
                indices.push(l.index);
            }
        }

        let mut lanes = Vec::new();
        let mut lane_index: HashMap<(&str, u32), usize> = HashMap::new();
        let mut internal_shapes: HashMap<&str, &str> = HashMap::new();
        for e in &raw.edges {
            match e.function.as_deref() {
                None | Some("normal") => {}
                Some("internal") => {
                    for l in &e.lanes {
                        internal_shapes.insert(l.id.as_str(), l.shape.as_str());
                    }
                    continue;
                }
                Some("crossing") => {
                    *left_out.entry("pedestrian crossings").or_default() += 1;
                    continue;
                }
                Some("walkingarea") => {
                    *left_out.entry("walking areas").or_default() += 1;
                    continue;
                }
                Some(other) => {
                    return Err(format!(
                        "<edge id=\"{}\" function=\"{other}\">: this kind of edge cannot be imported",
                        e.id
                    ))
                }
            }
            if !e.lanes.iter().any(|l| allows_cars(l.allow.as_deref(), l.disallow.as_deref())) {
                *left_out.entry("edges closed to cars").or_default() += 1;
                continue;
            }
            let end = |name: &str, value: &Option<String>| -> Result<usize, String> {
                let id = value.as_deref().ok_or_else(|| format!("<edge id=\"{}\">: no {name} junction", e.id))?;
                if let Some(kind) = unsupported.get(id) {
                    let why = UNSUPPORTED_JUNCTIONS.iter().find(|(k, _)| k == kind).map_or("this kind", |(_, w)| w);
                    return Err(format!(
                        "<junction id=\"{id}\" type=\"{kind}\"> (reached by <edge id=\"{}\">, which cars drive): {why} cannot be imported; supported: traffic_light, priority, priority_stop, right_before_left, allway_stop, dead_end, unregulated",
                        e.id
                    ));
                }
                junction_index
                    .get(id)
                    .copied()
                    .ok_or_else(|| format!("<edge id=\"{}\">: {name}=\"{id}\" is no junction of the file", e.id))
            };
            let (from, to) = (end("from", &e.from)?, end("to", &e.to)?);
            for l in &e.lanes {
                if !allows_cars(l.allow.as_deref(), l.disallow.as_deref()) {
                    *left_out.entry("lanes closed to cars").or_default() += 1;
                    continue;
                }
                let shape = polyline(&l.shape).filter(|s| s.len() >= 2).ok_or_else(|| {
                    format!("<lane id=\"{}\">: shape {:?}; allowed: two or more {POINTS_ALLOWED}", l.id, l.shape)
                })?;
                // (A length of inf was told it "must be positive": each
                // value now with its own range. Listed by `map`, and no
                // longer than the network spans.)
                if !(l.length.is_finite() && l.length > 0.0 && l.length <= MAX_NETWORK_SPAN_M) {
                    // (1e15 written so, not as sixteen digits)
                    let length = match l.length {
                        big if big.is_finite() && big.abs() >= 1e6 => format!("{big:e}"),
                        other => other.to_string(),
                    };
                    return Err(format!(
                        "<lane id=\"{}\">: length {length} m; allowed: a number above 0 and at most \
                         {MAX_NETWORK_SPAN_M} m (1,000 km, the largest span of a network)",
                        l.id
                    ));
                }
                if !(l.speed.is_finite() && l.speed > 0.0) {
                    return Err(format!("<lane id=\"{}\">: speed {} m/s; allowed: a number above 0", l.id, l.speed));
                }
                let width = l.width.unwrap_or(SUMO_DEFAULT_LANE_WIDTH_M);
                if !(width > 0.0 && width <= MAX_LANE_WIDTH_M) {
                    return Err(format!(
                        "<lane id=\"{}\">: width {width} m; allowed: above 0 and at most {MAX_LANE_WIDTH_M} m",
                        l.id
                    ));
                }
                // (SUMO cuts a lane's written shape by its start and end
                // offsets, which set its ends back from the outline.)
                let offset = |value: Option<f64>| value.filter(|v| v.is_finite()).unwrap_or(0.0).clamp(0.0, l.length);
                lane_index.insert((e.id.as_str(), l.index), lanes.len());
                lanes.push(SumoLane {
                    id: l.id.clone(),
                    edge: e.id.clone(),
                    index: l.index,
                    speed: l.speed,
                    length: l.length,
                    width,
                    shape,
                    from,
                    to,
                    set_back: (offset(l.start_offset), offset(l.end_offset)),
                    priority: e.priority.unwrap_or(-1),
                });
            }
        }

        let mut programmes = Vec::new();
        let mut programme_index = HashMap::new();
        for p in &raw.programmes {
            if programme_index.contains_key(p.id.as_str()) {
                continue; // another programme of the same lights: the first one runs
            }
            if !(p.offset.is_finite() && p.offset.abs() <= MAX_LIGHT_OFFSET_S) {
                return Err(format!(
                    "<tlLogic id=\"{}\">: offset {:?}; allowed: a finite number of seconds from -{max} to {max} \
                     (the longest scenario)",
                    p.id,
                    p.offset,
                    max = MAX_LIGHT_OFFSET_S
                ));
            }
            let (mut phases, mut actuated) = (Vec::new(), Vec::new());
            for ph in &p.phases {
                // Bounded as an offset is: a cycle of longer phases could
                // add up to infinity (1e308 s wrote since_change inf into
                // light_changes.csv, which validate then refused).
                if !(ph.duration.is_finite() && ph.duration > 0.0 && ph.duration <= MAX_LIGHT_OFFSET_S) {
                    return Err(format!(
                        "<tlLogic id=\"{}\">: a phase lasts {:?} s; allowed: seconds above 0, at most {MAX_LIGHT_OFFSET_S} \
                         (the longest scenario)",
                        p.id, ph.duration
                    ));
                }
                if let Some(bad) = ph.state.chars().find(|c| !"rRyYgGsuoO".contains(*c)) {
                    return Err(format!(
                        "<tlLogic id=\"{}\">: phase state {:?} has {bad:?}; allowed: r R y Y g G s u o O",
                        p.id, ph.state
                    ));
                }
                // One letter per link in every phase (SUMO refuses phases of
                // other lengths; the links beyond the shortest had no state).
                if let Some((_, first)) = phases.first().filter(|(_, s): &&(f64, String)| s.len() != ph.state.len()) {
                    return Err(format!(
                        "<tlLogic id=\"{}\">: phase state {} has {} letters, the first phase's {} has {}; allowed: one \
                         letter per link in every phase, all of the same length",
                        p.id,
                        clipped(&format!("{:?}", ph.state)),
                        ph.state.len(),
                        clipped(&format!("{first:?}")),
                        first.len()
                    ));
                }
                phases.push((ph.duration, ph.state.clone()));
                if p.kind.as_deref() == Some("actuated") {
                    actuated.push(phase_bounds(&p.id, ph)?);
                }
            }
            if phases.is_empty() {
                return Err(format!("<tlLogic id=\"{}\">: no phases", p.id));
            }
            programme_index.insert(p.id.as_str(), programmes.len());
            let (max_gap, detector_gap) = if p.kind.as_deref() == Some("actuated") {
                (seconds_param(p, "max-gap", MAX_GAP_S)?, seconds_param(p, "detector-gap", DETECTOR_GAP_S)?)
            } else {
                (MAX_GAP_S, DETECTOR_GAP_S)
            };
            programmes.push(SumoProgramme {
                id: p.id.clone(),
                offset: p.offset,
                phases,
                actuated,
                max_gap,
                detector_gap,
            });
        }

        // Where a movement goes on from an internal lane: a movement that
        // waits inside a junction (a left turn) crosses two or more.
        let onward: HashMap<(&str, u32, &str, u32), &str> = raw
            .connections
            .iter()
            .filter(|c| c.from.starts_with(':'))
            .filter_map(|c| Some(((c.from.as_str(), c.from_lane, c.to.as_str(), c.to_lane), c.via.as_deref()?)))
            .collect();
        let mut connections = Vec::new();
        // Connections with a partial turn (`R`, `L`), ascending.
        let mut partial = Vec::new();
        for c in &raw.connections {
            let name = || format!("<connection from=\"{}_{}\" to=\"{}_{}\">", c.from, c.from_lane, c.to, c.to_lane);
            for (end, edge, lane) in [("from", &c.from, c.from_lane), ("to", &c.to, c.to_lane)] {
                let Some(indices) = edge_lanes.get(edge.as_str()) else {
                    return Err(format!("{}: {end}=\"{edge}\" is no <edge> of the file", name()));
                };
                if !indices.contains(&lane) {
                    return Err(format!("{}: <edge id=\"{edge}\"> has no lane of index {lane}", name()));
                }
            }
            if let Some(tl) = c.tl.as_deref().filter(|tl| !programme_index.contains_key(tl)) {
                return Err(format!("{}: tl=\"{tl}\" is no <tlLogic> of the file", name()));
            }
            if let Some(link) = c.link_index.filter(|&l| l < -1) {
                return Err(format!("{}: linkIndex {link}; allowed: -1 (no light) or 0 and above", name()));
            }
            let (Some(&from), Some(&to)) =
                (lane_index.get(&(c.from.as_str(), c.from_lane)), lane_index.get(&(c.to.as_str(), c.to_lane)))
            else {
                continue; // to or from a lane left out (or an internal lane)
            };
            let turn = turn_of(&c.dir)
                .ok_or_else(|| format!("{}: dir=\"{}\" is not allowed: s, l, L, r, R or t", name(), c.dir))?;
            let mut path = Vec::new();
            let mut via = c.via.as_deref();
            // The internal lanes passed, so that a chain leading back into
            // itself ends (one of empty shapes added no points and looped
            // for ever).
            let mut passed: Vec<&str> = Vec::new();
            while let Some(lane) = via {
                if passed.contains(&lane) {
                    return Err(format!(
                        "{}: its internal lanes lead round in a circle (via {lane} comes back to {lane})",
                        name()
                    ));
                }
                passed.push(lane);
                // A via naming no internal lane left the path cut short
                // without a word.
                let text = internal_shapes.get(lane).ok_or_else(|| {
                    format!(
                        "{}: via {lane:?} is no internal lane of the file (an <edge function=\"internal\">'s lane)",
                        name()
                    )
                })?;
                path.extend(
                    polyline(text).ok_or_else(|| {
                        format!("{}: internal lane {lane}'s shape; allowed: {POINTS_ALLOWED}", name())
                    })?,
                );
                // `:J_9_0` is lane 0 of internal edge `:J_9`.
                let (edge, index) = lane.rsplit_once('_').unwrap_or((lane, ""));
                let index: u32 = index.parse().unwrap_or(0);
                via = onward.get(&(edge, index, c.to.as_str(), c.to_lane)).copied();
            }
            let signal = match (&c.tl, c.link_index.and_then(|l| usize::try_from(l).ok())) {
                (Some(tl), Some(link)) => {
                    let p = programme_index[tl.as_str()];
                    if let Some((_, state)) = programmes[p].phases.iter().find(|(_, s)| link >= s.len()) {
                        return Err(format!(
                            "{}: linkIndex {link} is beyond the {} links of <tlLogic id=\"{tl}\">'s phase {state:?}",
                            name(),
                            state.len()
                        ));
                    }
                    Some((p, link))
                }
                _ => None,
            };
            if c.dir == "R" || c.dir == "L" {
                partial.push(connections.len());
            }
            connections.push(SumoConnection { from, to, turn, path, signal });
        }
        // A lane with a full and a partial right (or left) drives the
        // partial one as a slight turn.
        let full = super::full_turns(
            lanes.len(),
            connections
                .iter()
                .enumerate()
                .filter(|(k, _)| partial.binary_search(k).is_err())
                .map(|(_, c)| (c.from, c.turn)),
        );
        for &k in &partial {
            let c = &mut connections[k];
            match c.turn {
                Turn::Right if full[c.from][0] => c.turn = Turn::SlightRight,
                Turn::Left if full[c.from][1] => c.turn = Turn::SlightLeft,
                _ => {}
            }
        }
        if lanes.is_empty() {
            return Err("the network has no lane a passenger car may drive".into());
        }
        if !unsupported.is_empty() {
            *left_out.entry("junctions of edges closed to cars").or_default() += unsupported.len();
        }
        let mut left_out: Vec<(&'static str, usize)> = left_out.into_iter().collect();
        left_out.sort();
        let network = SumoNetwork { junctions, lanes, connections, programmes, left_out };
        network.refuse_too_wide()?;
        network.refuse_stray_lane_ends()?;
        Ok(network)
    }

    /// Refuses a lane whose shape starts or ends more than
    /// [`MAX_LANE_END_GAP_M`] beyond the outline of the junction its edge
    /// names (and its offset there). netconvert writes a lane's ends on the
    /// outline; a shape that ends elsewhere contradicts the connections
    /// from it, and cars drove the straight line between (500 m over no
    /// road). After the span check, which names a far point first.
    fn refuse_stray_lane_ends(&self) -> Result<(), String> {
        for l in &self.lanes {
            let ends = [
                ("starts", l.shape[0], l.from, l.set_back.0),
                ("ends", l.shape[l.shape.len() - 1], l.to, l.set_back.1),
            ];
            for (what, point, junction, set_back) in ends {
                let j = &self.junctions[junction];
                let outline = j.shape.iter().map(|p| p.distance(j.centre)).fold(0.0, f64::max);
                let away = point.distance(j.centre);
                if away > outline + set_back + MAX_LANE_END_GAP_M {
                    return Err(format!(
                        "<lane id=\"{}\">: {what} at ({}, {}), {away:.1} m from <junction id=\"{}\"> at ({}, {}), \
                         which its edge names: allowed: within the junction's outline, the lane's offset there and \
                         {MAX_LANE_END_GAP_M} m (MAX_LANE_END_GAP_M); its shape contradicts the network",
                        l.id, point.x, point.y, j.id, j.centre.x, j.centre.y
                    ));
                }
            }
        }
        Ok(())
    }

    /// Refuses a network spanning more than [`MAX_NETWORK_SPAN_M`] on an
    /// axis, naming the lane or junction outline farthest from the bulk of
    /// it (the median lane point): where to look in the file.
    fn refuse_too_wide(&self) -> Result<(), String> {
        // Every point anything is built from: lanes, junction outlines and
        // centres, and the paths through junctions (one far point of an
        // internal lane, unchecked, had the map built for minutes, growing
        // past a gigabyte).
        let name = |lane: usize| &self.lanes[lane].id;
        let paths = self.connections.iter().flat_map(|c| {
            c.path.iter().map(move |p| {
                (*p, format!("<connection from lane {} to lane {}>'s internal lane", name(c.from), name(c.to)))
            })
        });
        let centres = self.junctions.iter().map(|j| (j.centre, format!("<junction id=\"{}\">'s x, y", j.id)));
        let (lo, hi) = self.bounds();
        let (lo, hi) = paths.clone().chain(centres.clone()).fold((lo, hi), |(lo, hi), (p, _)| (lo.min(p), hi.max(p)));
        let span = hi - lo;
        if span.max_element() <= MAX_NETWORK_SPAN_M {
            return Ok(());
        }
        let median = |axis: fn(&DVec2) -> f64| {
            let mut values: Vec<f64> = self.lanes.iter().flat_map(|l| l.shape.iter().map(axis)).collect();
            values.sort_by(f64::total_cmp);
            values[values.len() / 2]
        };
        let centre = DVec2::new(median(|p| p.x), median(|p| p.y));
        let lanes =
            self.lanes.iter().flat_map(|l| l.shape.iter().map(move |p| (*p, format!("<lane id=\"{}\">", l.id))));
        let outlines = self
            .junctions
            .iter()
            .flat_map(|j| j.shape.iter().map(move |p| (*p, format!("<junction id=\"{}\">", j.id))));
        let (point, element) = lanes
            .chain(outlines)
            .chain(paths)
            .chain(centres)
            .max_by(|a, b| a.0.distance(centre).total_cmp(&b.0.distance(centre)))
            .expect("a network with lanes has points");
        Err(format!(
            "the network spans {:.0} m x {:.0} m (its farthest point {element} at {}, {}); allowed: at most {MAX_NETWORK_SPAN_M} m a side",
            span.x, span.y, point.x, point.y
        ))
    }

    /// Lower and upper corners of everything drawn (lanes and junction
    /// outlines), metres.
    pub fn bounds(&self) -> (DVec2, DVec2) {
        let points = self.lanes.iter().flat_map(|l| l.shape.iter()).chain(self.junctions.iter().flat_map(|j| &j.shape));
        points.fold((DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY)), |(lo, hi), p| {
            (lo.min(*p), hi.max(*p))
        })
    }

    /// Lanes from which no connection leads on (they end at a dead end, or
    /// every movement from them was left out).
    pub fn dead_end_lanes(&self) -> Vec<usize> {
        let mut leads = vec![false; self.lanes.len()];
        for c in &self.connections {
            leads[c.from] = true;
        }
        (0..self.lanes.len()).filter(|&l| !leads[l]).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TINY: &str = r#"<net version="1.9">
        <edge id=":J1_0" function="internal"><lane id=":J1_0_0" index="0" speed="10" length="5" shape="10,0 15,0"/></edge>
        <edge id="a" from="J0" to="J1" priority="1">
            <lane id="a_0" index="0" speed="13.9" length="10" shape="0,0 10,0"/>
            <lane id="a_1" index="1" speed="13.9" length="10" disallow="passenger" shape="0,3 10,3"/>
        </edge>
        <edge id="b" from="J1" to="J2" priority="1"><lane id="b_0" index="0" speed="13.9" length="10" shape="15,0 25,0"/></edge>
        <edge id=":c" function="crossing"><lane id=":c_0" index="0" speed="1" length="5" shape="0,0 1,1"/></edge>
        <tlLogic id="J1" type="static" programID="0" offset="2"><phase duration="30" state="G"/><phase duration="3" state="y"/></tlLogic>
        <junction id="J0" type="dead_end" x="0" y="0"/>
        <junction id="J1" type="traffic_light" x="12" y="0" shape="10,-2 15,-2 15,2 10,2"/>
        <junction id=":J1_0_0" type="internal" x="12" y="0"/>
        <junction id="J2" type="priority" x="25" y="0"/>
        <connection from="a" to="b" fromLane="0" toLane="0" via=":J1_0_0" tl="J1" linkIndex="0" dir="s" state="O"/>
        <connection from=":J1_0" to="b" fromLane="0" toLane="0" dir="s" state="M"/>
    </net>"#;

    #[test]
    fn a_tiny_network_keeps_the_car_lanes_their_connection_and_its_light() {
        let net = SumoNetwork::from_xml(TINY).unwrap();
        assert_eq!(net.lanes.iter().map(|l| l.id.as_str()).collect::<Vec<_>>(), ["a_0", "b_0"]);
        assert_eq!(net.junctions.len(), 3, "internal junctions are not junctions");
        assert_eq!(net.junctions[1].kind, SumoJunctionKind::TrafficLight);
        assert_eq!(net.connections.len(), 1);
        let c = &net.connections[0];
        assert_eq!((c.from, c.to, c.turn, c.signal), (0, 1, Turn::Straight, Some((0, 0))));
        assert_eq!(c.path, vec![DVec2::new(10.0, 0.0), DVec2::new(15.0, 0.0)]);
        assert_eq!(net.programmes[0].offset, 2.0);
        assert_eq!(net.left_out, vec![("lanes closed to cars", 1), ("pedestrian crossings", 1)]);
        assert_eq!(net.dead_end_lanes(), vec![1]);
        assert_eq!(net.bounds(), (DVec2::new(0.0, -2.0), DVec2::new(25.0, 2.0)));
    }

    #[test]
    fn an_actuated_programme_keeps_its_bounds_and_gap_params() {
        let actuated = TINY.replace(
            r#"type="static" programID="0" offset="2"><phase duration="30" state="G"/>"#,
            r#"type="actuated" programID="0" offset="2"><param key="max-gap" value="2.5"/><phase duration="30" state="G" minDur="5"/>"#,
        );
        let net = SumoNetwork::from_xml(&actuated).unwrap();
        let p = &net.programmes[0];
        // maxDur missing: the written duration; the yellow has no bounds.
        assert_eq!(p.actuated, vec![Some((5.0, 30.0)), None]);
        assert_eq!((p.max_gap, p.detector_gap), (2.5, DETECTOR_GAP_S));
        // Params between phases are read as well (netedit writes them anywhere).
        let interleaved = TINY.replace(
            r#"type="static" programID="0" offset="2"><phase duration="30" state="G"/>"#,
            r#"type="actuated" programID="0" offset="2"><phase duration="30" state="G" minDur="5"/><param key="detector-gap" value="1.5"/>"#,
        );
        assert_eq!(SumoNetwork::from_xml(&interleaved).unwrap().programmes[0].detector_gap, 1.5);
        // A static programme's bounds are not read.
        assert!(SumoNetwork::from_xml(TINY).unwrap().programmes[0].actuated.is_empty());
    }

    #[test]
    fn what_cannot_be_imported_is_refused_naming_the_element_and_its_id() {
        for (from, to, needle) in [
            (
                r#"type="priority" x="25""#,
                r#"type="rail_crossing" x="25""#,
                r#"<junction id="J2" type="rail_crossing"> (reached by <edge id="b">, which cars drive): rail crossings"#,
            ),
            (r#"shape="15,0 25,0""#, r#"shape="15,0""#, r#"<lane id="b_0">: shape"#),
            (r#"dir="s" state="O""#, r#"dir="x" state="O""#, r#"dir="x" is not allowed"#),
            (r#"linkIndex="0""#, r#"linkIndex="4""#, "linkIndex 4 is beyond the 1 links"),
            (r#"to="J2" priority"#, r#"to="J9" priority"#, r#"<edge id="b">: to="J9" is no junction"#),
            (r#"state="G"/>"#, r#"state="Gx"/>"#, r#"phase state "Gx" has 'x'"#),
            ("<net version=\"1.9\">", "<net>", "no version attribute"),
            (
                r#"type="static" programID="0" offset="2"><phase duration="30" state="G"/>"#,
                r#"type="actuated" programID="0" offset="2"><phase duration="30" state="G" minDur="40" maxDur="20"/>"#,
                r#"<tlLogic id="J1">: a phase has minDur 40 and maxDur 20; allowed: 0 <= minDur <= maxDur"#,
            ),
            (
                r#"type="static" programID="0" offset="2">"#,
                r#"type="actuated" programID="0" offset="2"><param key="max-gap" value="soon"/>"#,
                r#"<tlLogic id="J1">: <param key="max-gap" value="soon"/>; allowed: seconds above 0"#,
            ),
            // A missing or malformed attribute: the element by its id.
            (r#"id="b_0" index="0" speed="13.9""#, r#"id="b_0" index="0""#, r#"<lane id="b_0">: no speed attribute"#),
            (
                r#"id="a_1" index="1""#,
                r#"id="a_1" index="-1""#,
                r#"<lane id="a_1">: index="-1"; allowed: a whole number, 0 or more"#,
            ),
            (
                r#"<phase duration="3" state="y"/>"#,
                r#"<phase duration="soon" state="y"/>"#,
                r#"<tlLogic id="J1">'s <phase> number 2: duration="soon"; allowed: a number"#,
            ),
            // What a broken file has that was taken, or silently dropped, before.
            (
                r#"<junction id="J2" type="priority" x="25" y="0"/>"#,
                r#"<junction id="J2" type="priority" x="25" y="0"/><junction id="J1" type="priority" x="9" y="9"/>"#,
                r#"<junction id="J1">: defined twice; each junction's id must be unique"#,
            ),
            (
                r#"<edge id=":c" function="crossing">"#,
                r#"<edge id="b"><lane id="b_9" index="0" speed="5" length="5" shape="0,9 5,9"/></edge><edge id=":c" function="crossing">"#,
                r#"<edge id="b">: defined twice; each edge's id must be unique"#,
            ),
            (r#"id="a_1" index="1""#, r#"id="a_1" index="0""#, r#"<edge id="a">: two lanes have index 0"#),
            (
                r#"offset="2""#,
                r#"offset="NaN""#,
                r#"<tlLogic id="J1">: offset NaN; allowed: a finite number of seconds"#,
            ),
            (r#"offset="2""#, r#"offset="inf""#, r#"<tlLogic id="J1">: offset inf; allowed"#),
            (
                r#"offset="2""#,
                r#"offset="1e300""#,
                r#"<tlLogic id="J1">: offset 1e300; allowed: a finite number of seconds from -1000000 to 1000000"#,
            ),
            // Phases of 1e308 s add up to an infinite cycle (light_changes.csv
            // said since_change inf, which validate refused).
            (
                r#"<phase duration="3" state="y"/>"#,
                r#"<phase duration="1e308" state="y"/>"#,
                r#"<tlLogic id="J1">: a phase lasts 1e308 s; allowed: seconds above 0, at most 1000000 (the longest"#,
            ),
            (
                r#"speed="13.9" length="10" shape="15,0 25,0""#,
                r#"speed="13.9" length="1e15" shape="15,0 25,0""#,
                r#"<lane id="b_0">: length 1e15 m; allowed: a number above 0 and at most 1000000 m"#,
            ),
            (
                r#"<connection from="a" to="b""#,
                r#"<connection from="aa" to="b""#,
                r#"<connection from="aa_0" to="b_0">: from="aa" is no <edge> of the file"#,
            ),
            (
                r#"to="b" fromLane="0" toLane="0" via"#,
                r#"to="b" fromLane="0" toLane="3" via"#,
                r#"<connection from="a_0" to="b_3">: <edge id="b"> has no lane of index 3"#,
            ),
            (r#"tl="J1" linkIndex="0""#, r#"tl="J7""#, r#"tl="J7" is no <tlLogic> of the file"#),
            (r#"linkIndex="0""#, r#"linkIndex="-5""#, "linkIndex -5; allowed: -1 (no light) or 0 and above"),
            (
                r#"shape="0,0 10,0""#,
                r#"shape="-1e308,0 10,0""#,
                r#"<lane id="a_0">: shape "-1e308,0 10,0"; allowed: two or more x,y points in metres, each number from -10000000 to 10000000"#,
            ),
            (
                r#"shape="10,-2 15,-2 15,2 10,2""#,
                r#"shape="10,-2 1e8,-2 15,2 10,2""#,
                r#"<junction id="J1">: shape "10,-2 1e8,-2 15,2 10,2"; allowed: x,y points"#,
            ),
            (r#"x="12" y="0" shape"#, r#"x="12" y="2e7" shape"#, r#"<junction id="J1">: x 12, y 20000000; allowed"#),
            // Within the coordinates' bounds, but 2,000 km across.
            (
                r#"shape="0,0 10,0""#,
                r#"shape="-2e6,0 10,0""#,
                r#"the network spans 2000025 m x 4 m (its farthest point <lane id="a_0"> at -2000000, 0); allowed: at most 1000000 m a side"#,
            ),
            // A via naming no internal lane (helper audit).
            (
                r#"toLane="0" via=":J1_0_0""#,
                r#"toLane="0" via=":J1_7_0""#,
                r#"<connection from="a_0" to="b_0">: via ":J1_7_0" is no internal lane of the file"#,
            ),
            // Empty ids: a lane listed and recorded as spawn "" that no
            // scenario file can name (helper audit).
            (r#"<lane id="b_0""#, r#"<lane id="""#, r#"<lane id=""> of <edge id="b">: an empty id"#),
            (r#"<edge id="b""#, r#"<edge id=" ""#, r#"<edge id=" ">: an empty id"#),
            (r#"<junction id="J2""#, r#"<junction id="""#, r#"<junction id="">: an empty id"#),
            // A far point of an internal lane, or a junction's centre far
            // off: unchecked, the first built the map for minutes, past a
            // gigabyte (helper audit).
            (
                r#"length="5" shape="10,0 15,0""#,
                r#"length="5" shape="10,0 9e6,9e6 15,0""#,
                r#"(its farthest point <connection from lane a_0 to lane b_0>'s internal lane at 9000000, 9000000)"#,
            ),
            (
                r#"<junction id="J2" type="priority" x="25" y="0""#,
                r#"<junction id="J2" type="priority" x="5e6" y="0""#,
                r#"(its farthest point <junction id="J2">'s x, y at 5000000, 0)"#,
            ),
            (
                r#"length="10" shape="15,0 25,0""#,
                r#"length="10" width="1e9" shape="15,0 25,0""#,
                r#"<lane id="b_0">: width 1000000000 m; allowed: above 0 and at most 50 m"#,
            ),
        ] {
            assert!(TINY.contains(from), "{from}");
            let err = SumoNetwork::from_xml(&TINY.replacen(from, to, 1)).unwrap_err();
            assert!(err.contains(needle), "{needle}: {err}");
        }
        assert!(SumoNetwork::from_xml("<html/>").is_err());
    }
}
