//! The city map shared by every world: a grid of roads running east-west and
//! north-south, crossing at four-way intersections. The default is the
//! original's city: four roads (A and B running east-west, C and D
//! north-south) crossing at four intersections around a central block. Each
//! road is cut into segments 0, 1, .. by the intersections it crosses (0, 1,
//! 2 in the default) and has four lanes: `w`, `x` travel towards +x (A, B) or +y (C, D), `y`,
//! `z` the other way; `w` and `z` are the outer (kerb-side) lanes, `x` and `y`
//! the inner ones (right-hand traffic). Outer lanes may go straight or turn
//! right, inner lanes straight or left. Roads continue off camera and loop
//! back with a U-turn, so every route can be extended forever.
//!
//! Units: metres and radians, x east, y north, origin at the centre of the
//! central block.

pub mod control;
pub mod curve;
pub mod import;
pub mod route;
pub mod signals;
pub mod sumo;

use control::{Axis, JunctionControl};
use curve::Curve;
use glam::DVec2;
use std::collections::HashMap;
use std::f64::consts::PI;

pub use route::{Action, Adaptation, AdaptationKind, LanePolicy, LegKind, Route, RouteError, RouteLeg};

/// Index of a lane in [`CityMap::lanes`].
pub type LaneId = usize;
/// Index of a connector in [`CityMap::connectors`].
pub type ConnectorId = usize;

/// Dimensions of the generated city: a grid of `east_west_roads` x
/// `north_south_roads` four-way intersections (2 x 2 by default).
#[derive(Debug, Clone, PartialEq)]
pub struct MapLayout {
    pub lane_width: f64,
    /// East-west roads: name and y of the centre line, ascending y; at least
    /// one.
    pub east_west_roads: Vec<(char, f64)>,
    /// North-south roads: name and x of the centre line, ascending x; at
    /// least one.
    pub north_south_roads: Vec<(char, f64)>,
    /// East-west roads run from -extent_x to +extent_x before looping back.
    pub extent_x: f64,
    /// North-south roads run from -extent_y to +extent_y before looping back.
    pub extent_y: f64,
    /// Distance along the lane over which a lane change (a merge, or one a
    /// driver plans for a turn) moves to the next lane, metres.
    pub lane_change_length: f64,
    /// Stop lines stand this far before the intersection box (the crosswalk
    /// lies between), metres.
    pub stop_line_setback: f64,
    /// Pavement between a road's kerb and the buildings, metres.
    pub sidewalk_width: f64,
    /// Road segments the town leaves out, as lanes name them (`C0`: road C
    /// up to its first crossing): the junctions at their ends become
    /// T-junctions. Empty: every road crosses every other.
    pub missing_segments: Vec<(char, u8)>,
    /// Lanes each way on every road: 2 (`w`, `x` one way, `y`, `z` the
    /// other, the original's), 1 (`w` and `z`, each turning any way) or 3
    /// (`w`, `m`, `x` and `y`, `n`, `z`: a middle lane that goes straight).
    pub lanes_per_direction: u8,
    /// Junctions without lights, by name (`AC`), and how they decide who
    /// goes; every other junction has traffic lights.
    pub junction_controls: Vec<(String, JunctionControl)>,
    /// Road segments cut short of one of their junctions, where they turn
    /// back in a U-turn loop (a cul-de-sac): (road, segment, whether the
    /// cut is at the segment's far end, east or north). The junction at
    /// the cut becomes a T-junction.
    pub dead_ends: Vec<(char, u8, bool)>,
}

impl Default for MapLayout {
    /// Roads 28 m apart both ways (a 16 m square central block) and every
    /// road 16 m long beyond its intersection, the least that
    /// [`MapLayout::min_approach_length`] allows: at the original's 40 m
    /// camera (80 m x 50 m) the east-west roads turn back almost wholly in
    /// view and the north-south ones 11 m beyond it, so cars spend little
    /// time off camera.
    fn default() -> Self {
        MapLayout {
            lane_width: 3.0,
            east_west_roads: vec![('B', -14.0), ('A', 14.0)],
            north_south_roads: vec![('C', -14.0), ('D', 14.0)],
            extent_x: 36.0,
            extent_y: 36.0,
            // About three lengths of the default 2.2 m car: a lane change at
            // the low speeds of the default (slowed, scaled) city.
            lane_change_length: 6.0,
            stop_line_setback: 3.6,
            sidewalk_width: 2.0,
            missing_segments: Vec::new(),
            lanes_per_direction: 2,
            junction_controls: Vec::new(),
            dead_ends: Vec::new(),
        }
    }
}

/// Room a car needs on a lane that ends at an intersection beyond the lane
/// change and the stop-line setback, metres: with both, the shortest such
/// lane on which a car can still change lanes before its turn.
pub const APPROACH_MARGIN_M: f64 = 4.0;

impl MapLayout {
    /// Half the width of a road: its lanes of one direction.
    pub fn road_half_width(&self) -> f64 {
        self.lanes_per_direction as f64 * self.lane_width
    }

    /// How far the centre of a direction's outer (kerb-side) lane lies from
    /// the road's centre line, metres.
    pub fn outer_lane_offset(&self) -> f64 {
        (self.lanes_per_direction as f64 - 0.5) * self.lane_width
    }

    /// The lane letters of one road segment, kerb to kerb: forward
    /// (outer, middle, inner), then backward (inner, middle, outer); `w`
    /// and `z` alone with one lane each way, no middle lanes with two.
    pub fn lane_letters(&self) -> &'static [char] {
        match self.lanes_per_direction {
            1 => &['w', 'z'],
            3 => &['w', 'm', 'x', 'y', 'n', 'z'],
            _ => &['w', 'x', 'y', 'z'],
        }
    }

    /// Shortest allowed lane ending at an intersection, metres:
    /// `lane_change_length` for each lane change a turn may need, plus
    /// `stop_line_setback + APPROACH_MARGIN_M`.
    pub fn min_approach_length(&self) -> f64 {
        self.lane_change_length * self.lane_changes_to_turn() as f64 + self.stop_line_setback + APPROACH_MARGIN_M
    }

    /// Lane changes a driver may need before a turn: from the outer lane
    /// to the inner one (at least one, as the original's roads need).
    pub fn lane_changes_to_turn(&self) -> u8 {
        self.lanes_per_direction.saturating_sub(1).max(1)
    }

    /// What the bird's-eye camera must show: every intersection box and the
    /// stop lines before them, as (min corner, max corner), metres.
    pub fn framed_area(&self) -> (DVec2, DVec2) {
        let reach = self.road_half_width() + self.stop_line_setback;
        let (x0, x1) = span(&self.north_south_roads);
        let (y0, y1) = span(&self.east_west_roads);
        (DVec2::new(x0 - reach, y0 - reach), DVec2::new(x1 + reach, y1 + reach))
    }

    /// The whole network: every road out to its U-turn loop, with its
    /// sidewalks, as (min corner, max corner), metres.
    pub fn network_area(&self) -> (DVec2, DVec2) {
        let reach = self.road_half_width() + self.sidewalk_width;
        (
            DVec2::new(-self.extent_x - reach, -self.extent_y - reach),
            DVec2::new(self.extent_x + reach, self.extent_y + reach),
        )
    }

    /// Intersections: every east-west road crosses every north-south one
    /// (four-way, or three-way where a segment is missing).
    pub fn intersection_count(&self) -> usize {
        self.east_west_roads.len() * self.north_south_roads.len()
    }

    /// Whether segment `segment` of road `road` is part of the town.
    pub fn has_segment(&self, road: char, segment: u8) -> bool {
        !self.missing_segments.contains(&(road, segment))
    }

    /// Where segment `segment` of road `road` is cut short, if it is a dead
    /// end: at its far end (east or north, `true`) or its near end.
    pub fn dead_end(&self, road: char, segment: u8) -> Option<bool> {
        self.dead_ends.iter().find(|d| d.0 == road && d.1 == segment).map(|d| d.2)
    }

    /// How far short of a junction's box a dead end turns back, metres:
    /// room for its U-turn loop (the road's half width) and the pavement.
    pub fn dead_end_setback(&self) -> f64 {
        self.road_half_width() + self.sidewalk_width
    }

    /// Centre lines of the east-west roads (y, ascending).
    pub fn east_west_centres(&self) -> Vec<f64> {
        self.east_west_roads.iter().map(|r| r.1).collect()
    }

    /// Centre lines of the north-south roads (x, ascending).
    pub fn north_south_centres(&self) -> Vec<f64> {
        self.north_south_roads.iter().map(|r| r.1).collect()
    }
}

/// Lowest and highest centre line of `roads` (ascending, at least one).
fn span(roads: &[(char, f64)]) -> (f64, f64) {
    (roads.first().map_or(0.0, |r| r.1), roads.last().map_or(0.0, |r| r.1))
}

/// Which lane of its direction a lane is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LanePosition {
    /// Kerb side: straight or right at intersections.
    Outer,
    /// Centre side: straight or left at intersections.
    Inner,
    /// The only lane of its direction (one-lane roads): straight, right
    /// or left.
    Single,
    /// Between the outer and the inner lane (three-lane roads): straight.
    Middle,
}

/// A movement through an intersection (or the U-turn at a road's far end).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Turn {
    Left,
    Right,
    Straight,
    /// The off-camera loop at the end of a road.
    UTurn,
    /// The lesser of two left turns from one lane (SUMO's `L` beside an
    /// `l`), at a junction of five arms or more.
    #[serde(rename = "slight_left")]
    SlightLeft,
    /// The lesser of two right turns from one lane (SUMO's `R` beside an
    /// `r`), at a junction of five arms or more.
    #[serde(rename = "slight_right")]
    SlightRight,
}

/// How many kinds of [`Turn`] there are: the slots of a lane's exits.
const TURN_KINDS: usize = 6;

impl Turn {
    /// Index of the turn in a per-lane table of exits.
    fn slot(self) -> usize {
        match self {
            Turn::Left => 0,
            Turn::Right => 1,
            Turn::Straight => 2,
            Turn::UTurn => 3,
            Turn::SlightLeft => 4,
            Turn::SlightRight => 5,
        }
    }

    /// Its name in listings and `scenario.json`: `left`, `right`,
    /// `straight`, `uturn`, `slight_left`, `slight_right`.
    pub fn name(self) -> &'static str {
        match self {
            Turn::Left => "left",
            Turn::Right => "right",
            Turn::Straight => "straight",
            Turn::UTurn => "uturn",
            Turn::SlightLeft => "slight_left",
            Turn::SlightRight => "slight_right",
        }
    }

    /// Whether the movement turns across oncoming traffic (a left turn of
    /// either kind, or a U-turn): it runs on its side's `left` light and,
    /// without a protected phase, gives way to oncoming traffic.
    pub fn crosses_oncoming(self) -> bool {
        matches!(self, Turn::Left | Turn::SlightLeft | Turn::UTurn)
    }

    /// Whether the movement bears left, so that a driver making it keeps to
    /// the left lanes: a left turn of either kind.
    pub fn bears_left(self) -> bool {
        matches!(self, Turn::Left | Turn::SlightLeft)
    }
}

/// Per lane (of `lanes` lanes), whether `turns` (lane, turn) give it a
/// full right (`[0]`) and a full left (`[1]`): where a lane has one, a
/// partial turn the same way is a slight one.
pub(crate) fn full_turns(lanes: usize, turns: impl IntoIterator<Item = (LaneId, Turn)>) -> Vec<[bool; 2]> {
    let mut full = vec![[false; 2]; lanes];
    for (lane, turn) in turns {
        match turn {
            Turn::Right => full[lane][0] = true,
            Turn::Left => full[lane][1] = true,
            _ => {}
        }
    }
    full
}

/// What a lane runs into.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LaneEnd {
    /// The stop line of an intersection approach.
    Intersection {
        intersection: usize,
        /// Side of the intersection the lane arrives from: 'N', 'E', 'S', 'W'.
        approach: char,
    },
    /// The U-turn loop at the end of the road.
    Loop(ConnectorId),
}

/// One lane of one road segment, the unit cars spawn on (`A0w` .. `D2z`).
#[derive(Debug, Clone)]
pub struct Lane {
    pub name: String,
    pub road: char,
    pub segment: u8,
    pub letter: char,
    pub position: LanePosition,
    pub curve: Curve,
    pub end: LaneEnd,
}

/// A path linking the end of one lane to the start of another.
#[derive(Debug, Clone)]
pub struct Connector {
    pub from: LaneId,
    pub to: LaneId,
    pub turn: Turn,
    pub intersection: Option<usize>,
    pub curve: Curve,
}

/// A four-way junction of one east-west and one north-south road.
#[derive(Debug, Clone)]
pub struct Intersection {
    /// East-west road then north-south road, e.g. `AC`.
    pub name: String,
    pub centre: DVec2,
    /// Half the side of the square box the connectors cross.
    pub half_size: f64,
    /// Lights, a priority road or stop lines.
    pub control: JunctionControl,
    /// The priority road's approaches (where `control` is `Priority`).
    pub major: Axis,
    /// The junction's outline, metres, as an imported network draws it
    /// (empty in a grid town, whose boxes are squares of `half_size`).
    pub outline: Vec<DVec2>,
}

/// The whole road network: lanes, connectors and intersections.
#[derive(Debug, Clone)]
pub struct CityMap {
    pub layout: MapLayout,
    pub lanes: Vec<Lane>,
    pub connectors: Vec<Connector>,
    pub intersections: Vec<Intersection>,
    lane_by_name: HashMap<String, LaneId>,
    /// Per lane, the connector leaving it for each turn (indexed by
    /// [`Turn::slot`]): looked up at every decision, so a table, not a hash.
    exits: Vec<[Option<ConnectorId>; TURN_KINDS]>,
    /// For each connector, the connectors of the same intersection whose
    /// paths cross or meet it (cars on them could collide).
    conflicts: Vec<Vec<ConnectorId>>,
    /// The signalised intersections, in index order: a light plan lists
    /// their lights only, [`signals::LIGHTS_PER_INTERSECTION`] each.
    signalised: Vec<usize>,
    /// Per lane, the parallel lane of the same direction on its left and on
    /// its right, where there is one (lane changes and merges go there).
    beside: Vec<[Option<LaneId>; 2]>,
    /// Lights that run a programme of their own instead of the cycle (an
    /// imported network's traffic-light programmes): each of variant 0
    /// replaces the cycle's light of its junction, approach and signal;
    /// the others are lights of their own, after the cycle's in a plan, in
    /// this order. Empty in a grid town.
    pub programmed: Vec<signals::Light>,
    /// Per connector, the variant of its approach's signal that governs it
    /// ([`signals::Light::variant`]). Empty where every movement follows
    /// its approach's own light (a grid town).
    pub(crate) link_variants: Vec<u8>,
    /// The imported network's traffic-actuated programmes (their lights are
    /// in `programmed` too, at their written durations). Empty in a grid
    /// town.
    pub actuated: Vec<signals::ActuatedProgramme>,
    /// The left turns and U-turns of imported networks, ascending, that go
    /// on a permissive green: their links' programme gives them no
    /// protected phase.
    pub(crate) permissive_lefts: Vec<ConnectorId>,
    /// Per connector, the connectors of its junction whose paths run into
    /// one with it before they end, on the same lane (an imported network's
    /// movements that share internal lanes): cars on them are in line.
    /// Empty in a grid town, whose movements meet only where they end.
    pub(crate) merging: Vec<Vec<ConnectorId>>,
    /// Per connector, the other movements from its lane whose paths run
    /// with it from the start, and for how long, metres (an imported
    /// network's movements that share internal lanes before they split).
    /// Empty in a grid town.
    pub(crate) splitting: Vec<Vec<(ConnectorId, f64)>>,
    /// Lanes, ascending, that arrive at a priority junction from a side of
    /// its priority road but not on it: another arm from the same compass
    /// side is the more important road (an imported network's side street
    /// joining at a slant, or a junction of five arms or more). They give
    /// way as the other road does. Empty in a grid town, which has one arm
    /// per side.
    pub(crate) side_roads: Vec<LaneId>,
}

impl Default for CityMap {
    fn default() -> Self {
        CityMap::new(MapLayout::default())
    }
}

/// Distance between the straight and the left signal head of one approach,
/// metres: the left head stands this far before the straight one.
pub const SIGNAL_HEAD_SPACING_M: f64 = 1.1;

impl CityMap {
    /// A light as scenario files and logs name it, e.g. `AC/W/straight`
    /// (or `J1/S/straight-2`, a variant).
    pub fn light_name(&self, index: usize) -> String {
        let (intersection, approach, signal, variant) = self.light_at(index);
        let label = signals::signal_label(signal, variant);
        signals::light_label(&self.intersections[intersection].name, approach, &label)
    }

    /// The signalised intersections, in index order.
    pub fn signalised(&self) -> &[usize] {
        &self.signalised
    }

    /// How many lights a light plan of this map holds.
    pub fn light_count(&self) -> usize {
        self.signalised.len() * signals::LIGHTS_PER_INTERSECTION + self.variant_lights().count()
    }

    /// The lights of variant 1 and up, in plan order, after the cycle's.
    fn variant_lights(&self) -> impl Iterator<Item = &signals::Light> {
        self.programmed.iter().filter(|l| l.variant > 0)
    }

    /// Where light (`intersection`, `approach`, `signal`) stands in this
    /// map's light plans: by signalised intersection, then approach (N, E,
    /// S, W), then straight before left. `None` at a junction without lights.
    pub fn light_index(&self, intersection: usize, approach: char, signal: signals::Signal) -> Option<usize> {
        let k = self.signalised.binary_search(&intersection).ok()?;
        Some(k * signals::LIGHTS_PER_INTERSECTION + signals::light_offset(approach, signal))
    }

    /// Where variant `variant` of light (`intersection`, `approach`,
    /// `signal`) stands in this map's light plans: variant 0 as
    /// [`CityMap::light_index`], the others after the cycle's lights.
    pub fn variant_index(
        &self,
        intersection: usize,
        approach: char,
        signal: signals::Signal,
        variant: u8,
    ) -> Option<usize> {
        if variant == 0 {
            return self.light_index(intersection, approach, signal);
        }
        let found = self.variant_lights().position(|l| {
            (l.intersection, l.approach, l.signal, l.variant) == (intersection, approach, signal, variant)
        })?;
        Some(self.signalised.len() * signals::LIGHTS_PER_INTERSECTION + found)
    }

    /// The light at `index` of a plan: (intersection, approach, signal,
    /// variant).
    pub fn light_at(&self, index: usize) -> (usize, char, signals::Signal, u8) {
        let cycle = self.signalised.len() * signals::LIGHTS_PER_INTERSECTION;
        if let Some(l) = index.checked_sub(cycle).and_then(|v| self.variant_lights().nth(v)) {
            return (l.intersection, l.approach, l.signal, l.variant);
        }
        let (k, approach, signal) = signals::light_at(index);
        (self.signalised[k], approach, signal, 0)
    }

    /// The light (index in a plan) that governs entering `connector`: its
    /// approach's left signal for left turns and U-turns, its straight
    /// signal otherwise, or the variant of it that runs the movement's own
    /// schedule. `None` at a junction without lights.
    pub fn light_of(&self, connector: ConnectorId) -> Option<usize> {
        let c = &self.connectors[connector];
        let intersection = c.intersection?;
        let approach = self.approach_of(connector)?;
        let signal = if c.turn.crosses_oncoming() { signals::Signal::Left } else { signals::Signal::Straight };
        match self.link_variants.get(connector).copied().unwrap_or(0) {
            0 => self.light_index(intersection, approach, signal),
            variant => self.variant_index(intersection, approach, signal, variant),
        }
    }

    /// The index of the light called `text` (`AC/W/straight`), or a message
    /// naming this map's intersections.
    pub fn light_by_name(&self, text: &str) -> Result<usize, String> {
        let parts: Vec<&str> = text.split('/').collect();
        let found = match parts.as_slice() {
            [intersection, approach, signal] => {
                let k = self.intersections.iter().position(|x| x.name == *intersection);
                let a = approach.chars().next().filter(|c| approach.len() == 1 && signals::APPROACHES.contains(c));
                // `left`, or a variant: `left-2`, ...
                let (base, variant) = match signal.split_once('-') {
                    Some((base, n))
                        if !n.starts_with('0') && !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()) =>
                    {
                        (base, n.parse::<u32>().ok().filter(|&v| v >= 2).and_then(|v| u8::try_from(v - 1).ok()))
                    }
                    Some((base, _)) => (base, None),
                    None => (*signal, Some(0)),
                };
                let s = match base {
                    "straight" => Some(signals::Signal::Straight),
                    "left" => Some(signals::Signal::Left),
                    _ => None,
                };
                match (k, a, s, variant) {
                    (Some(k), Some(a), Some(s), Some(v)) if v > 0 => match self.variant_index(k, a, s, v) {
                        Some(index) => Some(index),
                        None if self.light_index(k, a, s).is_some() => {
                            let mut labels = vec![s.name().to_string()];
                            labels.extend(
                                self.variant_lights()
                                    .filter(|l| (l.intersection, l.approach, l.signal) == (k, a, s))
                                    .map(|l| l.signal_label()),
                            );
                            return Err(format!(
                                "{text:?} is not a light: the {} movements from {}/{a} run on {} ({})",
                                s.name(),
                                self.intersections[k].name,
                                if labels.len() == 1 { "one light" } else { "these lights" },
                                labels.join(", ")
                            ));
                        }
                        None => return Err(self.without_lights(text, k)),
                    },
                    (Some(k), Some(a), Some(s), Some(_)) => match self.light_index(k, a, s) {
                        Some(index) => Some(index),
                        None => return Err(self.without_lights(text, k)),
                    },
                    _ => None,
                }
            }
            _ => None,
        };
        found.ok_or_else(|| {
            let mut names: Vec<&str> =
                self.signalised.iter().map(|&k| self.intersections[k].name.as_str()).collect();
            names.sort_unstable();
            let example = names.first().copied().unwrap_or("AC");
            // Numbered lights only where this map has them.
            let numbered = match self.variant_lights().next() {
                Some(_) => format!("; numbered lights of their own too, e.g. {}", self.light_name(self.light_count() - 1)),
                None => String::new(),
            };
            format!(
                "{text:?} is not a light: INTERSECTION/APPROACH/SIGNAL, e.g. \"{example}/W/straight\" ({}; N E S W; straight left){numbered}",
                names.join(" ")
            )
        })
    }

    /// Why `text` names no light: junction `k` has none.
    fn without_lights(&self, text: &str, k: usize) -> String {
        let x = &self.intersections[k];
        format!(
            "{text:?} is not a light: junction {} has no traffic lights (its control is {})",
            x.name,
            x.control.name()
        )
    }

    /// The control of the junction `connector` crosses (`None`: a U-turn loop).
    pub fn control_of(&self, connector: ConnectorId) -> Option<JunctionControl> {
        self.connectors[connector].intersection.map(|k| self.intersections[k].control)
    }

    /// The side `connector`'s traffic arrives from ('N', 'E', 'S', 'W'),
    /// where it crosses a junction.
    pub fn approach_of(&self, connector: ConnectorId) -> Option<char> {
        match self.lanes[self.connectors[connector].from].end {
            LaneEnd::Intersection { approach, .. } => Some(approach),
            LaneEnd::Loop(_) => None,
        }
    }

    /// Whether `lane` arrives at its junction on the junction's priority
    /// road: from a side of the junction's [`Axis`], and not a
    /// [side road](CityMap::side_roads) arriving from that side too.
    pub fn on_priority_road(&self, lane: LaneId) -> bool {
        match self.lanes[lane].end {
            LaneEnd::Intersection { intersection, approach } => {
                self.intersections[intersection].major.holds(approach) && self.side_roads.binary_search(&lane).is_err()
            }
            LaneEnd::Loop(_) => false,
        }
    }

    /// Right of way at a junction without lights, as a key: of two
    /// conflicting movements the one with the lower key goes first. At a
    /// priority junction the priority road's straight and right turns
    /// come first, then its left turns, then the other road's straight
    /// and right turns, then its left turns; at an all-way stop every
    /// movement ranks alike. Ties go to the lower connector index.
    pub fn right_of_way(&self, connector: ConnectorId) -> (u8, ConnectorId) {
        let c = &self.connectors[connector];
        let Some(k) = c.intersection else { return (0, connector) };
        let x = &self.intersections[k];
        let class = match x.control {
            JunctionControl::Priority => {
                let major = self.on_priority_road(c.from);
                2 * u8::from(!major) + u8::from(c.turn.crosses_oncoming())
            }
            JunctionControl::Signals | JunctionControl::AllWayStop | JunctionControl::RightBeforeLeft => 0,
        };
        (class, connector)
    }

    /// Whether, of two conflicting movements, traffic on `first` goes before
    /// traffic on `then`. At a junction without lights by
    /// [`CityMap::right_of_way`], except right before left: there traffic
    /// from the right goes first, and of two oncoming movements the one not
    /// turning left; where neither rule decides (two oncoming left turns,
    /// skewed arms), [`CityMap::right_of_way`]'s fixed order does. At lights
    /// (where it matters for a left turn on a permissive green,
    /// [`CityMap::permissive_left`]) oncoming traffic not turning left goes
    /// before a left turn.
    pub fn goes_before(&self, first: ConnectorId, then: ConnectorId) -> bool {
        use std::f64::consts::{FRAC_PI_4, PI, TAU};
        let heading = |c: ConnectorId| {
            let lane = &self.lanes[self.connectors[c].from].curve;
            lane.heading_at(lane.length())
        };
        let left = |c: ConnectorId| self.connectors[c].turn.crosses_oncoming();
        // Whether `a` goes first by the rules of the road alone: from `b`'s
        // right (its heading turned a quarter counter-clockwise from `b`'s),
        // or oncoming while `b` turns left and `a` does not.
        let by_rule = |a: ConnectorId, b: ConnectorId, right_before_left: bool| {
            let turned = PI - (PI - (heading(a) - heading(b))).rem_euclid(TAU);
            let oncoming = turned.abs() > 3.0 * FRAC_PI_4 && left(b) && !left(a);
            oncoming || (right_before_left && (FRAC_PI_4..3.0 * FRAC_PI_4).contains(&turned))
        };
        match self.control_of(then) {
            Some(JunctionControl::RightBeforeLeft) => {
                by_rule(first, then, true)
                    || (!by_rule(then, first, true) && self.right_of_way(first) < self.right_of_way(then))
            }
            Some(JunctionControl::Signals) => by_rule(first, then, false),
            _ => self.right_of_way(first) < self.right_of_way(then),
        }
    }

    /// Whether `connector` is a left turn (or U-turn) that goes on a
    /// permissive green, yielding to oncoming traffic: on imported networks,
    /// where its link's programme gives it no protected phase.
    pub fn permissive_left(&self, connector: ConnectorId) -> bool {
        self.permissive_lefts.binary_search(&connector).is_ok()
    }

    /// Whether a driver entering `connector` must give way to others at its
    /// line: every movement of an all-way stop, and at a priority junction
    /// all but the priority road's straight and right turns.
    pub fn gives_way(&self, connector: ConnectorId) -> bool {
        match self.control_of(connector) {
            Some(JunctionControl::AllWayStop | JunctionControl::RightBeforeLeft) => true,
            Some(JunctionControl::Priority) => self.right_of_way(connector).0 > 0,
            _ => false,
        }
    }

    /// Where the head of light (`intersection`, `approach`, `signal`,
    /// `variant`) stands, metres: on the pavement beside the kerb of the
    /// approach's outer lane, level with its stop line (the left head
    /// [`SIGNAL_HEAD_SPACING_M`] further back, each variant's two spacings
    /// behind its signal's), where no car drives over it. Where two arms
    /// arrive from the approach's side, beside the arm of the first movement
    /// the light governs. `None` for an approach the map does not have.
    pub fn signal_head(
        &self,
        intersection: usize,
        approach: char,
        signal: signals::Signal,
        variant: u8,
    ) -> Option<DVec2> {
        let arriving = |l: &Lane| matches!(l.end, LaneEnd::Intersection { intersection: i, approach: a } if i == intersection && a == approach);
        let mut lane = self.lanes.iter().position(|l| l.position != LanePosition::Inner && arriving(l))?;
        if self.arms_from_side(lane) > 1 {
            let governed = (0..self.connectors.len()).find(|&c| {
                self.connectors[c].intersection == Some(intersection)
                    && self.approach_of(c) == Some(approach)
                    && self.light_of(c).is_some_and(|index| {
                        let (_, _, s, v) = self.light_at(index);
                        (s, v) == (signal, variant)
                    })
            });
            if let Some(c) = governed {
                lane = self.kerb_lane(self.connectors[c].from);
            }
        }
        Some(self.beside_line(lane, signal, variant))
    }

    /// Where the sign of `lane`'s arm stands at its junction (a stop sign or
    /// a give-way triangle; [`CityMap::signal_head`]'s place for straight
    /// on), beside the arm's own kerb where its side has two arms.
    pub fn sign_of(&self, lane: LaneId) -> Option<DVec2> {
        let LaneEnd::Intersection { intersection, approach } = self.lanes[lane].end else { return None };
        if self.arms_from_side(lane) > 1 {
            return Some(self.beside_line(self.kerb_lane(lane), signals::Signal::Straight, 0));
        }
        self.signal_head(intersection, approach, signals::Signal::Straight, 0)
    }

    /// The road an imported lane belongs to: SUMO's edge, from the lane's
    /// id (`EDGE_INDEX`), with its index.
    fn edge_and_index(&self, lane: LaneId) -> (&str, u32) {
        let name = self.lanes[lane].name.as_str();
        name.rsplit_once('_').and_then(|(edge, i)| Some((edge, i.parse().ok()?))).unwrap_or((name, 0))
    }

    /// The kerb-side lane of `lane`'s arm: of the lanes of its edge that
    /// arrive where it does, the one of the lowest index (a lane closed to
    /// cars between them does not split the arm). A grid town's lane is its
    /// own arm's here; its sides have one arm each.
    fn kerb_lane(&self, lane: LaneId) -> LaneId {
        let (edge, _) = self.edge_and_index(lane);
        let end = self.lanes[lane].end;
        (0..self.lanes.len())
            .filter(|&l| self.lanes[l].end == end && self.edge_and_index(l).0 == edge)
            .min_by_key(|&l| self.edge_and_index(l).1)
            .unwrap_or(lane)
    }

    /// How many arms (edges) arrive at `lane`'s junction from its side: one
    /// in a grid town.
    fn arms_from_side(&self, lane: LaneId) -> usize {
        if !self.is_imported() {
            return 1;
        }
        let end = self.lanes[lane].end;
        let mut edges: Vec<&str> =
            (0..self.lanes.len()).filter(|&l| self.lanes[l].end == end).map(|l| self.edge_and_index(l).0).collect();
        edges.sort_unstable();
        edges.dedup();
        edges.len()
    }

    /// A point on the pavement beside `lane`'s kerb, level with its stop
    /// line, the places of `signal` and `variant` further back.
    fn beside_line(&self, lane: LaneId, signal: signals::Signal, variant: u8) -> DVec2 {
        let lane = &self.lanes[lane];
        let spacings = f64::from(variant) * 2.0 + if signal == signals::Signal::Left { 1.0 } else { 0.0 };
        let back = self.layout.stop_line_setback + spacings * SIGNAL_HEAD_SPACING_M;
        let kerb = self.layout.lane_width / 2.0;
        lane.curve.position(lane.curve.length() - back, -(kerb + self.layout.sidewalk_width / 2.0))
    }

    /// Builds the network for `layout`.
    pub fn new(layout: MapLayout) -> CityMap {
        let hw = layout.road_half_width();
        let lw = layout.lane_width;
        let mut intersections = Vec::new();
        for &(ew, y) in &layout.east_west_roads {
            for &(ns, x) in &layout.north_south_roads {
                let name = format!("{ew}{ns}");
                let control =
                    layout.junction_controls.iter().find(|(n, _)| *n == name).map_or(JunctionControl::Signals, |c| c.1);
                let centre = DVec2::new(x, y);
                let major = Axis::EastWest;
                intersections.push(Intersection { name, centre, half_size: hw, control, major, outline: Vec::new() });
            }
        }
        let columns = layout.north_south_roads.len();
        let intersection_at = |ew: usize, ns: usize| ew * columns + ns;

        let mut lanes = Vec::new();
        // (road name, origin, axis direction, crossing coordinates, extent, is east-west, road index)
        let mut roads = Vec::new();
        for (i, &(name, y)) in layout.east_west_roads.iter().enumerate() {
            let crossings = layout.north_south_centres();
            roads.push((name, DVec2::new(0.0, y), DVec2::X, crossings, layout.extent_x, true, i));
        }
        for (j, &(name, x)) in layout.north_south_roads.iter().enumerate() {
            let crossings = layout.east_west_centres();
            roads.push((name, DVec2::new(x, 0.0), DVec2::Y, crossings, layout.extent_y, false, j));
        }
        let mut pending_loops = Vec::new();
        for (name, origin, axis, crossings, extent, east_west, road_index) in roads {
            let right = DVec2::new(axis.y, -axis.x);
            // Segment k runs from crossing k - 1 (or the road's start) to
            // crossing k (or its end).
            let mut bounds = Vec::with_capacity(crossings.len() + 1);
            let mut from = -extent;
            for &c in &crossings {
                bounds.push((from, c - hw));
                from = c + hw;
            }
            bounds.push((from, extent));
            for (segment, &(a0, a1)) in bounds.iter().enumerate() {
                if !layout.has_segment(name, segment as u8) {
                    continue;
                }
                // A dead end stops short of the junction at its cut and turns back there.
                let cut = layout.dead_end(name, segment as u8);
                let (a0, a1) = match cut {
                    Some(true) => (a0, a1 - layout.dead_end_setback()),
                    Some(false) => (a0 + layout.dead_end_setback(), a1),
                    None => (a0, a1),
                };
                let outer = layout.outer_lane_offset();
                let kerb_side =
                    if layout.lanes_per_direction == 1 { LanePosition::Single } else { LanePosition::Outer };
                for &letter in layout.lane_letters() {
                    let (offset, forward, position) = match letter {
                        'w' => (outer, true, kerb_side),
                        'x' => (0.5 * lw, true, LanePosition::Inner),
                        'm' => (1.5 * lw, true, LanePosition::Middle),
                        'n' => (-1.5 * lw, false, LanePosition::Middle),
                        'y' => (-0.5 * lw, false, LanePosition::Inner),
                        _ => (-outer, false, kerb_side),
                    };
                    let p0 = origin + axis * a0 + right * offset;
                    let p1 = origin + axis * a1 + right * offset;
                    let (start, end) = if forward { (p0, p1) } else { (p1, p0) };
                    // Index of the crossing this lane runs into, if any: the
                    // one after its segment going forward, before it going back.
                    let crossing =
                        if forward { (segment < crossings.len()).then_some(segment) } else { segment.checked_sub(1) };
                    let crossing = crossing.filter(|_| cut != Some(forward));
                    let end_kind = match crossing {
                        Some(k) => {
                            let intersection =
                                if east_west { intersection_at(road_index, k) } else { intersection_at(k, road_index) };
                            let approach = match (east_west, forward) {
                                (true, true) => 'W',
                                (true, false) => 'E',
                                (false, true) => 'S',
                                (false, false) => 'N',
                            };
                            LaneEnd::Intersection { intersection, approach }
                        }
                        None => {
                            pending_loops.push(lanes.len());
                            LaneEnd::Loop(usize::MAX)
                        }
                    };
                    lanes.push(Lane {
                        name: format!("{name}{segment}{letter}"),
                        road: name,
                        segment: segment as u8,
                        letter,
                        position,
                        curve: Curve::line(start, end),
                        end: end_kind,
                    });
                }
            }
        }

        // The lane a connector ends on; none where its segment is missing.
        let lane_starting_at = |lanes: &[Lane], p: DVec2, heading: f64| -> Option<LaneId> {
            lanes.iter().position(|l| {
                l.curve.start().distance(p) < 1e-6 && curve::wrap_angle(l.curve.heading_at(0.0) - heading).abs() < 1e-6
            })
        };

        let mut connectors = Vec::new();
        for from in 0..lanes.len() {
            let lane = &lanes[from];
            let end = lane.curve.end();
            let heading = lane.curve.heading_at(lane.curve.length());
            let mut add = |curve: Curve, turn: Turn, intersection: Option<usize>| {
                let to = lane_starting_at(&lanes, curve.end(), curve.heading_at(curve.length()));
                // A U-turn always ends on its own segment; a movement into a
                // missing segment does not exist.
                debug_assert!(
                    to.is_some() || !layout.missing_segments.is_empty() || !layout.dead_ends.is_empty(),
                    "no lane starts at {:?}",
                    curve.end()
                );
                if let Some(to) = to {
                    connectors.push(Connector { from, to, turn, intersection, curve });
                }
                to.is_some()
            };
            match lane.end {
                LaneEnd::Intersection { intersection, .. } => {
                    let travel = DVec2::new(heading.cos(), heading.sin());
                    let straight = add(Curve::line(end, end + travel * 2.0 * hw), Turn::Straight, Some(intersection));
                    // A turn ends on the crossing road's lane as far from its
                    // centre line as this one is from its own.
                    let offset = layout.outer_lane_offset();
                    let right = Curve::arc(end, heading, hw - offset, -PI / 2.0);
                    let left = Curve::arc(end, heading, hw + 0.5 * lw, PI / 2.0);
                    match lane.position {
                        LanePosition::Outer => {
                            add(right, Turn::Right, Some(intersection));
                        }
                        LanePosition::Inner => {
                            add(left, Turn::Left, Some(intersection));
                        }
                        LanePosition::Single => {
                            add(right, Turn::Right, Some(intersection));
                            add(left, Turn::Left, Some(intersection));
                        }
                        // Straight on; on a T-junction's stem, where there is
                        // none, either way into the bar's middle lanes.
                        LanePosition::Middle if !straight => {
                            add(Curve::arc(end, heading, hw - 1.5 * lw, -PI / 2.0), Turn::Right, Some(intersection));
                            add(Curve::arc(end, heading, hw + 1.5 * lw, PI / 2.0), Turn::Left, Some(intersection));
                        }
                        LanePosition::Middle => {}
                    }
                }
                LaneEnd::Loop(_) => {
                    let radius = match lane.position {
                        LanePosition::Outer | LanePosition::Single => layout.outer_lane_offset(),
                        LanePosition::Inner => 0.5 * lw,
                        LanePosition::Middle => 1.5 * lw,
                    };
                    add(Curve::arc(end, heading, radius, PI), Turn::UTurn, None);
                }
            }
        }
        for (id, c) in connectors.iter().enumerate() {
            if c.turn == Turn::UTurn {
                lanes[c.from].end = LaneEnd::Loop(id);
            }
        }
        debug_assert!(pending_loops.iter().all(|&l| matches!(lanes[l].end, LaneEnd::Loop(c) if c != usize::MAX)));

        let by_name: HashMap<String, LaneId> = lanes.iter().enumerate().map(|(i, l)| (l.name.clone(), i)).collect();
        let beside = lanes
            .iter()
            .map(|l| {
                [true, false].map(|to_left| grid_neighbour(&layout, l, to_left).and_then(|n| by_name.get(&n).copied()))
            })
            .collect();
        let mut map = CityMap::assemble(layout, lanes, connectors, intersections, beside);
        for k in 0..map.intersections.len() {
            map.intersections[k].major = Axis::major(&map.approaches(k));
        }
        map
    }

    /// The map of these parts: lanes, the connectors between them (at most
    /// one per lane and turn: a later one replaces an earlier), the
    /// junctions and, per lane, its neighbours on the left and right. Finds
    /// the connectors' conflicts and the signalised junctions.
    pub(crate) fn assemble(
        layout: MapLayout,
        lanes: Vec<Lane>,
        connectors: Vec<Connector>,
        intersections: Vec<Intersection>,
        beside: Vec<[Option<LaneId>; 2]>,
    ) -> CityMap {
        let lane_by_name = lanes.iter().enumerate().map(|(i, l)| (l.name.clone(), i)).collect();
        let mut exits = vec![[None; TURN_KINDS]; lanes.len()];
        for (i, c) in connectors.iter().enumerate() {
            exits[c.from][c.turn.slot()] = Some(i);
        }
        let conflicts = find_conflicts(&connectors);
        let signalised =
            (0..intersections.len()).filter(|&k| intersections[k].control == JunctionControl::Signals).collect();
        let (programmed, merging, splitting) = (Vec::new(), Vec::new(), Vec::new());
        CityMap {
            layout,
            lanes,
            connectors,
            intersections,
            lane_by_name,
            exits,
            conflicts,
            signalised,
            beside,
            programmed,
            link_variants: Vec::new(),
            actuated: Vec::new(),
            permissive_lefts: Vec::new(),
            merging,
            splitting,
            side_roads: Vec::new(),
        }
    }

    /// The lane named like the original's spawn points, e.g. `C0w`.
    pub fn lane_by_name(&self, name: &str) -> Option<LaneId> {
        self.lane_by_name.get(name).copied()
    }

    /// Lower and upper corners of every lane and movement's centre line,
    /// metres (sampled every 2 m and at their ends).
    pub fn drawn_bounds(&self) -> (DVec2, DVec2) {
        let curves = self.lanes.iter().map(|l| &l.curve).chain(self.connectors.iter().map(|c| &c.curve));
        let mut bounds = (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
        for curve in curves {
            let n = (curve.length() / 2.0).ceil().max(1.0) as usize;
            for k in 0..=n {
                let p = curve.position(curve.length() * k as f64 / n as f64, 0.0);
                bounds = (bounds.0.min(p), bounds.1.max(p));
            }
        }
        bounds
    }

    /// Whether the map is an imported network (not a grid town).
    pub fn is_imported(&self) -> bool {
        self.layout.east_west_roads.is_empty()
    }

    /// Every spawn point (every lane of every road segment: the original's
    /// 48 in the default city), in name order.
    pub fn spawn_points(&self) -> Vec<LaneId> {
        let mut ids: Vec<LaneId> = (0..self.lanes.len()).collect();
        ids.sort_by(|a, b| self.lanes[*a].name.cmp(&self.lanes[*b].name));
        ids
    }

    /// The connector that performs `turn` at the end of `lane`, if allowed.
    pub fn exit(&self, lane: LaneId, turn: Turn) -> Option<ConnectorId> {
        self.exits.get(lane).and_then(|slots| slots[turn.slot()])
    }

    /// Every connector leaving the end of `lane`.
    pub fn exits_from(&self, lane: LaneId) -> impl Iterator<Item = ConnectorId> + '_ {
        [Turn::Left, Turn::Straight, Turn::Right, Turn::UTurn, Turn::SlightLeft, Turn::SlightRight]
            .into_iter()
            .filter_map(move |t| self.exit(lane, t))
    }

    /// Connectors that run into one path with `connector`'s before its end
    /// (imported networks only; see [`CityMap::merging`]).
    pub fn merging(&self, connector: ConnectorId) -> &[ConnectorId] {
        self.merging.get(connector).map_or(&[], Vec::as_slice)
    }

    /// How far `sibling`, another movement from `connector`'s lane, runs
    /// on one path with it from the start, metres: 0 in a grid town, where
    /// movements part at once.
    pub fn shared_start(&self, connector: ConnectorId, sibling: ConnectorId) -> f64 {
        self.splitting.get(connector).and_then(|s| s.iter().find(|x| x.0 == sibling)).map_or(0.0, |x| x.1)
    }

    /// Connectors whose paths cross or merge with `connector`'s.
    pub fn conflicts(&self, connector: ConnectorId) -> &[ConnectorId] {
        &self.conflicts[connector]
    }

    /// Lanes and connectors share one index space ("tracks"): lanes first.
    pub fn track_count(&self) -> usize {
        self.lanes.len() + self.connectors.len()
    }

    /// Track index of a connector.
    pub fn connector_track(&self, connector: ConnectorId) -> usize {
        self.lanes.len() + connector
    }

    /// The parallel lane of the same direction on the left (`to_left`) or right.
    pub fn adjacent_lane(&self, lane: LaneId, to_left: bool) -> Option<LaneId> {
        self.beside[lane][usize::from(!to_left)]
    }

    /// The lane beside `lane` towards the one that makes `turn` at the end
    /// of its segment (left for a left turn, right otherwise), when that
    /// lane or one further that way does: the next lane change a driver
    /// makes for the turn.
    pub fn lane_towards(&self, lane: LaneId, turn: Turn) -> Option<LaneId> {
        let to_left = turn.bears_left();
        let next = self.adjacent_lane(lane, to_left)?;
        let mut probe = Some(next);
        while let Some(l) = probe {
            if self.exit(l, turn).is_some() {
                return Some(next);
            }
            probe = self.adjacent_lane(l, to_left);
        }
        None
    }

    /// The sides traffic arrives at `intersection` from ('E', 'N', 'S',
    /// 'W', sorted): four at a crossing, three at a T-junction.
    pub fn approaches(&self, intersection: usize) -> std::collections::BTreeSet<char> {
        self.lanes
            .iter()
            .filter_map(|l| match l.end {
                LaneEnd::Intersection { intersection: k, approach } if k == intersection => Some(approach),
                _ => None,
            })
            .collect()
    }

    /// Why this network cannot be driven, if it cannot: a junction left
    /// with fewer than three roads, or a lane from which some other lane
    /// cannot be reached (following connectors and lane changes).
    pub fn network_problem(&self) -> Option<String> {
        for (k, x) in self.intersections.iter().enumerate() {
            let arms = self.approaches(k);
            if arms.len() < 3 {
                return Some(format!(
                    "junction {} would keep {} roads ({}): a junction needs at least 3",
                    x.name,
                    arms.len(),
                    arms.iter().map(char::to_string).collect::<Vec<_>>().join(" ")
                ));
            }
        }
        let next = |lane: LaneId| {
            let mut out: Vec<LaneId> = self.exits_from(lane).map(|c| self.connectors[c].to).collect();
            out.extend([true, false].into_iter().filter_map(|left| self.adjacent_lane(lane, left)));
            out
        };
        let mut ahead = vec![Vec::new(); self.lanes.len()];
        let mut behind = vec![Vec::new(); self.lanes.len()];
        for (lane, out) in ahead.iter_mut().enumerate() {
            for to in next(lane) {
                out.push(to);
                behind[to].push(lane);
            }
        }
        let reach = |edges: &[Vec<LaneId>]| {
            let mut seen = vec![false; self.lanes.len()];
            let mut stack = vec![0];
            while let Some(lane) = stack.pop() {
                if !std::mem::replace(&mut seen[lane], true) {
                    stack.extend(edges[lane].iter().copied().filter(|&l| !seen[l]));
                }
            }
            seen
        };
        if self.lanes.is_empty() {
            return Some("the network has no lanes".into());
        }
        if let Some(stuck) = (0..self.lanes.len()).find(|&l| self.exits_from(l).next().is_none()) {
            return Some(format!("lane {} leads nowhere", self.lanes[stuck].name));
        }
        let (forward, backward) = (reach(&ahead), reach(&behind));
        let cut = (0..self.lanes.len()).find(|&l| !forward[l] || !backward[l])?;
        Some(format!(
            "the network falls apart: lane {} cannot be reached from lane {}, or cannot reach it",
            self.lanes[cut].name, self.lanes[0].name
        ))
    }

    /// The movement a driver with no action left makes at the end of
    /// `lane`: straight on, or at a T-junction's stem the lane's only turn.
    pub fn default_turn(&self, lane: LaneId) -> Turn {
        [Turn::Straight, Turn::Right, Turn::Left, Turn::UTurn, Turn::SlightRight, Turn::SlightLeft]
            .into_iter()
            .find(|&t| self.exit(lane, t).is_some())
            .unwrap_or(Turn::Straight)
    }

    /// Whether the junction at the end of `lane` offers its road a choice:
    /// two or more of left, straight and right from it or the lanes beside
    /// it. Every junction of a grid town does; where an imported road only
    /// goes on (a bend, a change of lane count), an action waits for the
    /// next junction.
    pub fn has_choice(&self, lane: LaneId) -> bool {
        let mut turns = std::collections::BTreeSet::new();
        for to_left in [true, false] {
            let mut probe = Some(lane);
            while let Some(l) = probe {
                turns.extend(self.allowed_turns(l));
                probe = self.adjacent_lane(l, to_left);
            }
        }
        turns.len() >= 2
    }

    /// Turns allowed at the end of `lane` (none for lanes that end in a loop).
    pub fn allowed_turns(&self, lane: LaneId) -> Vec<Turn> {
        [Turn::Left, Turn::Straight, Turn::Right, Turn::SlightLeft, Turn::SlightRight]
            .into_iter()
            .filter(|&t| self.exit(lane, t).is_some())
            .collect()
    }
}

/// The name of a grid lane's parallel neighbour on the left (`to_left`) or
/// right: same road and segment, the next letter kerb to centre.
fn grid_neighbour(layout: &MapLayout, l: &Lane, to_left: bool) -> Option<String> {
    let middle = layout.lanes_per_direction == 3;
    let target = match (l.letter, to_left) {
        ('w', true) if middle => 'm',
        ('m', true) => 'x',
        ('x', false) if middle => 'm',
        ('m', false) => 'w',
        ('z', true) if middle => 'n',
        ('n', true) => 'y',
        ('y', false) if middle => 'n',
        ('n', false) => 'z',
        ('w', true) => 'x',
        ('x', false) => 'w',
        ('z', true) => 'y',
        ('y', false) => 'z',
        _ => return None,
    };
    Some(format!("{}{}{}", l.road, l.segment, target))
}

/// Pairs of connectors in one intersection that come from different lanes and
/// either end in the same lane or pass within 2 m of each other.
fn find_conflicts(connectors: &[Connector]) -> Vec<Vec<ConnectorId>> {
    let samples: Vec<Vec<DVec2>> = connectors
        .iter()
        .map(|c| {
            let n = (c.curve.length() / 0.25).ceil() as usize;
            (0..=n).map(|i| c.curve.lane_center_at(c.curve.length() * i as f64 / n as f64)).collect()
        })
        .collect();
    let mut conflicts = vec![Vec::new(); connectors.len()];
    for (i, a) in connectors.iter().enumerate() {
        for (j, b) in connectors.iter().enumerate() {
            if i == j || a.intersection.is_none() || a.intersection != b.intersection || a.from == b.from {
                continue;
            }
            let close =
                a.to == b.to || samples[i].iter().any(|p| samples[j].iter().any(|q| p.distance_squared(*q) < 4.0));
            if close {
                conflicts[i].push(j);
            }
        }
    }
    conflicts
}
