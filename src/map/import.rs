//! A driveable [`CityMap`] from an imported SUMO network: the lanes cars can
//! keep driving on forever, the movements between them, the junctions with
//! their control, and U-turn loops where a road ends and its other direction
//! goes back.
//!
//! What drives like what:
//! - SUMO's lanes keep their ids and centre lines (polylines); the lanes of
//!   one edge are neighbours for lane changes (index 0 is the kerb side).
//! - Connections keep their turn and their path through the junction (every
//!   internal lane it crosses); of several from one lane with the same turn
//!   the first in the file is used, and a turnaround (`t`) is used only
//!   when it is the lane's only movement: it then crosses the junction as a
//!   left turn does.
//! - A lane that ends where no connection goes on (a `dead_end` junction)
//!   loops round onto the lane of the same index (or the nearest) of the
//!   edge that goes back, when there is one.
//! - Junctions: `traffic_light` junctions run the file's programme, one
//!   light per approach side and signal (straight, left) as in the grid
//!   towns, showing the state of the first link it governs, and a light of
//!   its own (a variant) for each other schedule its links run on;
//!   `priority` and `priority_stop` junctions give priority to the
//!   approaches of their highest-priority edge's axis; at
//!   `right_before_left` junctions traffic from the right goes first;
//!   `allway_stop`, `left_before_right` (left-hand traffic, which the
//!   city's lanes do not drive) and `unregulated` junctions drive as
//!   all-way stops. A lane's approach side (N, E, S, W) is the
//!   compass side behind its direction of travel at its end.
//! - Only the largest set of lanes from which every other can be reached is
//!   kept, so every route goes on forever; what is dropped is reported.

use super::control::{Axis, JunctionControl};
use super::curve::Curve;
use super::signals::{ActuatedPhase, ActuatedProgramme, Colour, Light, ScheduleStep, Signal, APPROACHES};
use super::sumo::{SumoJunctionKind, SumoNetwork};
use super::{CityMap, Connector, Intersection, Lane, LaneEnd, LaneId, LanePosition, MapLayout, Turn};
use glam::DVec2;
use std::collections::HashMap;
use std::f64::consts::PI;

/// Where an imported map's stop lines stand before the end of their lane,
/// metres. SUMO's lanes already end at the junction's outline (crossings lie
/// inside it), so the line is at the lane's end, less a car's nose.
pub const IMPORTED_STOP_LINE_SETBACK_M: f64 = 1.0;

/// What importing kept and dropped.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ImportReport {
    /// SUMO lanes cars drive on in the map.
    pub lanes: usize,
    /// U-turn loops added where a road ends.
    pub loops: usize,
    /// SUMO lanes left out, each with why, in file order.
    pub dropped: Vec<(String, &'static str)>,
}

/// Side of a junction that a lane ending with `heading` arrives from: 'N',
/// 'E', 'S' or 'W', the side behind its direction of travel (so every lane
/// of an edge arrives from the same side).
fn approach_side(heading: f64) -> char {
    let v = -DVec2::new(heading.cos(), heading.sin());
    if v.x.abs() >= v.y.abs() {
        if v.x < 0.0 {
            'W'
        } else {
            'E'
        }
    } else if v.y < 0.0 {
        'S'
    } else {
        'N'
    }
}

/// Most points of a dead end's loop: a half circle of 650 m radius at 0.5 m
/// (dead ends loop onto a lane a few metres away; a file whose back lane
/// starts kilometres away still gets a loop, drawn coarser).
const MAX_U_TURN_POINTS: usize = 4096;

/// A half circle to the left from `a` (heading `heading`) round to `b`: the
/// loop at a road's end. Points every 0.5 m or closer, up to
/// [`MAX_U_TURN_POINTS`].
fn u_turn(a: DVec2, heading: f64, b: DVec2) -> Option<Curve> {
    let centre = (a + b) / 2.0;
    let radius = a.distance(b) / 2.0;
    if radius < 0.05 {
        return None;
    }
    let forward = DVec2::new(heading.cos(), heading.sin());
    let u = (a - centre) / radius;
    // Turn the way that first heads forward.
    let sign = if u.perp().dot(forward) >= 0.0 { 1.0 } else { -1.0 };
    let n = ((PI * radius / 0.5).ceil() as usize).clamp(8, MAX_U_TURN_POINTS);
    let points: Vec<DVec2> = (0..=n)
        .map(|k| {
            let t = sign * PI * k as f64 / n as f64;
            centre + DVec2::new(u.x * t.cos() - u.y * t.sin(), u.x * t.sin() + u.y * t.cos()) * radius
        })
        .collect();
    Curve::polyline(&points)
}

/// The path of a movement: from the end of one lane through `via` (the
/// junction's internal lane, possibly empty) to the start of the next.
fn movement_path(from: &Curve, via: &[DVec2], to: &Curve) -> Curve {
    let mut points = vec![from.end()];
    points.extend_from_slice(via);
    points.push(to.start());
    Curve::polyline(&points).unwrap_or_else(|| {
        // The lanes meet end to start: a step of a centimetre keeps the
        // movement a curve with a length.
        let h = from.heading_at(from.length());
        Curve::line(from.end(), from.end() + DVec2::new(h.cos(), h.sin()) * 0.01)
    })
}

/// Strongly connected sets of `0..n` under `next`, as a component number
/// per node (iterative Kosaraju).
fn components(n: usize, next: &[Vec<usize>]) -> Vec<usize> {
    let mut order = Vec::with_capacity(n);
    let mut seen = vec![false; n];
    for root in 0..n {
        if seen[root] {
            continue;
        }
        seen[root] = true;
        let mut stack = vec![(root, 0usize)];
        while let Some(&mut (node, ref mut k)) = stack.last_mut() {
            if let Some(&m) = next[node].get(*k) {
                *k += 1;
                if !seen[m] {
                    seen[m] = true;
                    stack.push((m, 0));
                }
            } else {
                order.push(node);
                stack.pop();
            }
        }
    }
    let mut back = vec![Vec::new(); n];
    for (a, outs) in next.iter().enumerate() {
        for &b in outs {
            back[b].push(a);
        }
    }
    let mut component = vec![usize::MAX; n];
    let mut count = 0;
    for &root in order.iter().rev() {
        if component[root] != usize::MAX {
            continue;
        }
        let mut stack = vec![root];
        component[root] = count;
        while let Some(node) = stack.pop() {
            for &m in &back[node] {
                if component[m] == usize::MAX {
                    component[m] = count;
                    stack.push(m);
                }
            }
        }
        count += 1;
    }
    component
}

/// A SUMO link state as the colour of a `signal` light: green (`G`, and
/// `o`, `O`: no signal, the junction's own rules), yellow (`y`, `Y`), else
/// red (`r`, `R`, `s`, `u`). A permissive green (`g`: go, yielding to
/// oncoming traffic) is green for straight on and right turns and red for
/// left turns and U-turns: where the programme has a protected left phase,
/// drivers turn left on it only; where it has none, they turn on the
/// permissive green and give way to oncoming traffic
/// ([`CityMap::permissive_left`]).
fn colour_of(state: char, signal: Signal) -> Colour {
    match state {
        'g' if signal == Signal::Left => Colour::Red,
        'G' | 'g' | 'o' | 'O' => Colour::Green,
        'y' | 'Y' => Colour::Yellow,
        _ => Colour::Red,
    }
}

/// What an imported network's programmes make of its lights.
struct ProgrammedLights {
    /// As [`CityMap::programmed`].
    lights: Vec<Light>,
    /// As [`CityMap::link_variants`].
    link_variants: Vec<u8>,
    /// As [`CityMap::permissive_lefts`].
    permissive_lefts: Vec<usize>,
    actuated: Vec<ActuatedProgramme>,
}

/// The lights of `map`'s signalised junctions that the file's programmes
/// run (`ids`: the file's index of each of `map`'s lanes; `connection_of`:
/// each connector's connection in the file). Per
/// junction, approach side and signal, the links of its movements
/// (straight before right for the straight signal, left before U-turn for
/// the left one, each by lane): the first link's colours in each phase,
/// runs of one colour merged, make the light; a link whose colours differ
/// from every light's so far makes a light of its own, the next variant.
/// A left turn or U-turn whose link has no protected phase turns on the
/// permissive green, yielding to oncoming traffic.
fn programmed_lights(
    net: &SumoNetwork,
    map: &CityMap,
    ids: &[usize],
    connection_of: &[Option<usize>],
) -> Result<ProgrammedLights, String> {
    let mut out = ProgrammedLights {
        lights: Vec::new(),
        link_variants: vec![0; map.connectors.len()],
        permissive_lefts: Vec::new(),
        actuated: actuated_programmes(net, map, ids),
    };
    for &k in map.signalised() {
        for approach in APPROACHES {
            for signal in [Signal::Straight, Signal::Left] {
                let order: [Turn; 3] = match signal {
                    Signal::Straight => [Turn::Straight, Turn::Right, Turn::SlightRight],
                    Signal::Left => [Turn::Left, Turn::UTurn, Turn::SlightLeft],
                };
                // (programme, colours in its phases) of each light so far;
                // whether the first link turns on a permissive green; the
                // movements without a link, which follow the first.
                let mut variants: Vec<(usize, Vec<Colour>)> = Vec::new();
                let (mut first_permissive, mut unlinked) = (None, Vec::new());
                for turn in order {
                    for (id, c) in map.connectors.iter().enumerate() {
                        if c.intersection != Some(k) || c.turn != turn || map.approach_of(id) != Some(approach) {
                            continue;
                        }
                        let Some((programme, link)) = connection_of[id].and_then(|x| net.connections[x].signal) else {
                            unlinked.push(id);
                            continue;
                        };
                        let p = &net.programmes[programme];
                        let states: Vec<char> =
                            p.phases.iter().map(|(_, s)| s.chars().nth(link).unwrap_or('r')).collect();
                        let protected =
                            signal == Signal::Left && states.iter().any(|&c| colour_of(c, signal) == Colour::Green);
                        let read_as = if protected || signal == Signal::Straight { signal } else { Signal::Straight };
                        if read_as != signal {
                            out.permissive_lefts.push(id);
                        }
                        first_permissive.get_or_insert(read_as != signal);
                        let colours: Vec<Colour> = states.iter().map(|&c| colour_of(c, read_as)).collect();
                        let variant = match variants.iter().position(|v| v.0 == programme && v.1 == colours) {
                            Some(v) => v,
                            None => {
                                variants.push((programme, colours));
                                variants.len() - 1
                            }
                        };
                        out.link_variants[id] = u8::try_from(variant).map_err(|_| {
                            let x = &map.intersections[k].name;
                            format!("<junction id=\"{x}\">: the {} movements from {approach} run on more than 256 schedules", signal.name())
                        })?;
                    }
                }
                if first_permissive == Some(true) {
                    out.permissive_lefts.extend(unlinked);
                }
                for (variant, (programme, colours)) in variants.into_iter().enumerate() {
                    let p = &net.programmes[programme];
                    let mut schedule: Vec<ScheduleStep> = Vec::new();
                    for ((duration, _), &colour) in p.phases.iter().zip(&colours) {
                        ScheduleStep::extend(&mut schedule, colour, *duration);
                    }
                    let variant = variant as u8; // checked above
                    out.lights.push(Light { intersection: k, approach, signal, variant, offset: p.offset, schedule });
                    if let Some(a) = out.actuated.iter_mut().find(|a| a.id == p.id) {
                        a.lights.push((k, approach, signal, variant, colours));
                    }
                }
            }
        }
    }
    out.actuated.retain(|a| !a.lights.is_empty());
    out.permissive_lefts.sort_unstable();
    Ok(out)
}

/// Whether a lane with `links` (its links' indices in the programme) has
/// a detector in the phase of `state`: every link green, `G`, or `g` where
/// the lane is its edge's only one (`single_lane`) or the link is never
/// `G` (`ever_green`), as SUMO's actuated logic picks its detectors.
fn detects(state: &[u8], links: &[usize], single_lane: bool, ever_green: impl Fn(usize) -> bool) -> bool {
    !links.is_empty()
        && links.iter().all(|&link| match state.get(link) {
            Some(b'G') => true,
            Some(b'g') => single_lane || !ever_green(link),
            _ => false,
        })
}

/// The file's traffic-actuated programmes with a phase that traffic can
/// extend, their lights still to add. Per phase, a detector on each kept
/// lane whose every link of the programme is green in it, as SUMO picks
/// them: `G`, or `g` where that link is never `G` or its edge has one lane
/// (a turn pocket's permissive green waits for its protected phase). It
/// lies `detector-gap` at the lane's speed limit before the stop line, or
/// at the lane's start if that is shorter.
fn actuated_programmes(net: &SumoNetwork, map: &CityMap, ids: &[usize]) -> Vec<ActuatedProgramme> {
    let mut lanes_of_edge: HashMap<&str, usize> = HashMap::new();
    for lane in &net.lanes {
        *lanes_of_edge.entry(lane.edge.as_str()).or_default() += 1;
    }
    let mut programmes = Vec::new();
    for (index, p) in net.programmes.iter().enumerate() {
        if !p.actuated.iter().any(Option::is_some) {
            continue;
        }
        // Each lane's links of this programme, and which links are ever `G`.
        let mut links: HashMap<usize, Vec<usize>> = HashMap::new();
        for c in &net.connections {
            if let Some((programme, link)) = c.signal {
                if programme == index {
                    links.entry(c.from).or_default().push(link);
                }
            }
        }
        let ever_g = |link: usize| p.phases.iter().any(|(_, s)| s.as_bytes().get(link) == Some(&b'G'));
        let phases = p
            .phases
            .iter()
            .zip(&p.actuated)
            .map(|((duration, state), &bounds)| {
                let state = state.as_bytes();
                let detectors = ids
                    .iter()
                    .enumerate()
                    .filter(|&(_, l)| {
                        let single = lanes_of_edge.get(net.lanes[*l].edge.as_str()) == Some(&1);
                        links.get(l).is_some_and(|links| detects(state, links, single, ever_g))
                    })
                    .map(|(id, &l)| {
                        let line = map.lanes[id].curve.length() - map.layout.stop_line_setback;
                        (id, (line - p.detector_gap * net.lanes[l].speed).max(0.0))
                    })
                    .collect();
                ActuatedPhase { duration: *duration, bounds, detectors }
            })
            .collect();
        let (id, offset, max_gap) = (p.id.clone(), p.offset, p.max_gap);
        programmes.push(ActuatedProgramme { id, offset, max_gap, phases, lights: Vec::new() });
    }
    programmes
}

/// Metres two movements into one lane must run together before their end
/// (within [`MERGED_WITHIN_M`] of each other at equal distances from it)
/// to count as one path.
const MERGED_FOR_M: f64 = 3.0;
/// Two movements' paths count as one where their centre lines run closer
/// than this, metres: cars on them would touch side by side (a car is 1.8 m
/// wide by default, `car_width_m`).
const MERGED_WITHIN_M: f64 = 2.0;

/// How far two movements' paths run together, metres, from their starts
/// (`from_end` false) or back from their ends: within [`MERGED_WITHIN_M`]
/// of each other at equal distances along both, in steps of 0.25 m.
fn run_together(a: &Connector, b: &Connector, from_end: bool) -> f64 {
    let (la, lb) = (a.curve.length(), b.curve.length());
    let at = |len: f64, s: f64| if from_end { len - s } else { s };
    let mut s = 0.0;
    while s + 0.25 <= la.min(lb)
        && a.curve.position(at(la, s + 0.25), 0.0).distance(b.curve.position(at(lb, s + 0.25), 0.0)) <= MERGED_WITHIN_M
    {
        s += 0.25;
    }
    s
}

/// For each movement, the movements `related` to it that run together
/// with it (from the start, or back from the end) for `least` metres or
/// more, and for how long.
fn running_together(
    connectors: &[Connector],
    related: impl Fn(&Connector, &Connector) -> bool,
    from_end: bool,
    least: f64,
) -> Vec<Vec<(usize, f64)>> {
    connectors
        .iter()
        .enumerate()
        .map(|(i, a)| {
            connectors
                .iter()
                .enumerate()
                .filter(|&(j, b)| j != i && related(a, b))
                .map(|(j, b)| (j, run_together(a, b, from_end)))
                .filter(|&(_, s)| s >= least)
                .collect()
        })
        .collect()
}

/// For each movement, the movements of its junction from other lanes into
/// the same lane that share their last [`MERGED_FOR_M`] or more with it.
fn merging_movements(connectors: &[Connector]) -> Vec<Vec<usize>> {
    let into_one = |a: &Connector, b: &Connector| {
        a.intersection.is_some() && a.intersection == b.intersection && a.to == b.to && a.from != b.from
    };
    let found = running_together(connectors, into_one, true, MERGED_FOR_M);
    found.into_iter().map(|list| list.into_iter().map(|(j, _)| j).collect()).collect()
}

/// For each movement, the other movements from its lane that run with it
/// from the start for a metre or more, and for how long, metres.
fn splitting_movements(connectors: &[Connector]) -> Vec<Vec<(usize, f64)>> {
    running_together(connectors, |a, b| a.from == b.from, false, 1.0)
}

/// The lanes, ascending, that arrive at a priority junction from a side of
/// its priority road on a lesser road than another arm from that side
/// (`priority`: each lane's edge priority, as netconvert set it). A
/// compass side can hold two arms, at a junction of five arms or more or
/// where a side street joins at a slant. Only the arms of the side's
/// highest-priority edge are the priority road's, as in SUMO, whose
/// netconvert makes the others' links yield (state `m`).
fn side_roads(map: &CityMap, priority: impl Fn(LaneId) -> i32) -> Vec<LaneId> {
    let arriving = |lane: LaneId| match map.lanes[lane].end {
        LaneEnd::Intersection { intersection, approach } => Some((intersection, approach)),
        LaneEnd::Loop(_) => None,
    };
    let mut top: HashMap<(usize, char), i32> = HashMap::new();
    for lane in 0..map.lanes.len() {
        if let Some(side) = arriving(lane) {
            let p = top.entry(side).or_insert(i32::MIN);
            *p = (*p).max(priority(lane));
        }
    }
    (0..map.lanes.len())
        .filter(|&lane| {
            arriving(lane).is_some_and(|(k, approach)| {
                let x = &map.intersections[k];
                x.control == JunctionControl::Priority
                    && x.major.holds(approach)
                    && priority(lane) < top[&(k, approach)]
            })
        })
        .collect()
}

/// Why no network is left once the lanes that lead nowhere or are cut off
/// are dropped (`dropped`, in the order they were), naming the first few:
/// cars drive round for the whole run, so they need lanes that lead back.
fn nothing_left(net: &SumoNetwork, dropped: &[(usize, &str)]) -> String {
    const NAMED: usize = 4;
    let named: Vec<String> = dropped
        .iter()
        .take(NAMED)
        .map(|&(l, why)| format!("{} {}", net.lanes[l].id, why.split(':').next().unwrap_or(why)))
        .collect();
    let more = dropped.len().saturating_sub(NAMED);
    format!(
        "no two lanes cars drive reach each other: {} left out ({}{}). Cars drive \
         round for the whole run, so a network needs lanes that lead back to where they start: a street both \
         ways, or a loop (a one-way street between dead ends has none)",
        match (net.lanes.len(), dropped.len()) {
            (1, _) => "the one lane cars may drive is".to_string(),
            (lanes, 1) => format!("of {lanes} lanes cars may drive, 1 is"),
            (lanes, dropped) => format!("of {lanes} lanes cars may drive, {dropped} are"),
        },
        named.join("; "),
        if more > 0 { format!("; {more} more: `causalcity map --net` lists them") } else { String::new() }
    )
}

impl CityMap {
    /// The driveable map of `net`, with lane changes `lane_change_m` long.
    /// Refused when no two lanes reach each other.
    pub fn from_sumo(net: &SumoNetwork, lane_change_m: f64) -> Result<(CityMap, ImportReport), String> {
        let n = net.lanes.len();
        // Lanes of each edge by index, kerb side first.
        let mut by_edge: HashMap<&str, Vec<usize>> = HashMap::new();
        for (i, l) in net.lanes.iter().enumerate() {
            by_edge.entry(l.edge.as_str()).or_default().push(i);
        }
        for lanes in by_edge.values_mut() {
            lanes.sort_by_key(|&i| net.lanes[i].index);
        }
        let neighbour = |lane: usize, to_left: bool| -> Option<usize> {
            let l = &net.lanes[lane];
            let want = if to_left { l.index.checked_add(1)? } else { l.index.checked_sub(1)? };
            by_edge[l.edge.as_str()].iter().copied().find(|&j| net.lanes[j].index == want)
        };

        // Movements out of each lane: the file's connections (a turnaround
        // only where it is the lane's only one), else a loop onto the road
        // back.
        let mut moves: Vec<Vec<(usize, Turn, Option<usize>)>> = vec![Vec::new(); n];
        for (k, c) in net.connections.iter().enumerate() {
            let slot = &mut moves[c.from];
            if !slot.iter().any(|m| m.1 == c.turn) {
                slot.push((c.to, c.turn, Some(k)));
            }
        }
        for slot in moves.iter_mut() {
            if slot.len() > 1 {
                slot.retain(|m| m.1 != Turn::UTurn);
            }
        }
        for (slot, l) in moves.iter_mut().zip(&net.lanes) {
            if !slot.is_empty() {
                continue;
            }
            let back = net
                .lanes
                .iter()
                .enumerate()
                .filter(|(_, b)| b.from == l.to && b.to == l.from && b.edge != l.edge)
                .min_by_key(|(_, b)| (b.index.abs_diff(l.index), b.index));
            if let Some((b, _)) = back {
                slot.push((b, Turn::UTurn, None));
            }
        }

        // Keep the largest set of lanes that all reach each other, then drop
        // lanes left with no movement inside it, until nothing changes.
        let mut kept = vec![true; n];
        let mut dropped: Vec<(usize, &'static str)> = Vec::new();
        loop {
            let next: Vec<Vec<usize>> = (0..n)
                .map(|lane| {
                    if !kept[lane] {
                        return Vec::new();
                    }
                    let mut out: Vec<usize> = moves[lane].iter().map(|m| m.0).filter(|&t| kept[t]).collect();
                    out.extend([true, false].into_iter().filter_map(|left| neighbour(lane, left)).filter(|&t| kept[t]));
                    out
                })
                .collect();
            let component = components(n, &next);
            let mut size: HashMap<usize, usize> = HashMap::new();
            for lane in (0..n).filter(|&l| kept[l]) {
                *size.entry(component[lane]).or_default() += 1;
            }
            let Some((&largest, _)) = size.iter().max_by_key(|(c, s)| (**s, std::cmp::Reverse(**c))) else {
                return Err(nothing_left(net, &dropped));
            };
            let mut changed = false;
            for lane in 0..n {
                if !kept[lane] {
                    continue;
                }
                let why = if component[lane] != largest {
                    Some("cut off: cars cannot drive from it to the rest of the network and back")
                } else if !moves[lane].iter().any(|m| kept[m.0] && component[m.0] == largest) {
                    Some("leads nowhere: no movement from its end stays in the network")
                } else {
                    None
                };
                if let Some(why) = why {
                    kept[lane] = false;
                    dropped.push((lane, why));
                    changed = true;
                }
            }
            if !changed {
                break;
            }
        }
        let ids: Vec<usize> = (0..n).filter(|&l| kept[l]).collect();
        if ids.len() < 2 {
            return Err(nothing_left(net, &dropped));
        }
        let new_id: HashMap<usize, LaneId> = ids.iter().enumerate().map(|(k, &l)| (l, k)).collect();

        // Junctions that movements cross, in file order.
        let crosses = |l: usize| moves[l].iter().any(|m| m.2.is_some() && kept[m.0]);
        let mut crossed: Vec<usize> = ids.iter().filter(|&&l| crosses(l)).map(|&l| net.lanes[l].to).collect();
        crossed.sort_unstable();
        crossed.dedup();
        let junction_of: HashMap<usize, usize> = crossed.iter().enumerate().map(|(k, &j)| (j, k)).collect();
        let intersections: Vec<Intersection> = crossed
            .iter()
            .map(|&j| {
                let x = &net.junctions[j];
                let control = match x.kind {
                    SumoJunctionKind::TrafficLight => JunctionControl::Signals,
                    SumoJunctionKind::Priority | SumoJunctionKind::DeadEnd => JunctionControl::Priority,
                    SumoJunctionKind::RightBeforeLeft => JunctionControl::RightBeforeLeft,
                    SumoJunctionKind::AllWayStop
                    | SumoJunctionKind::LeftBeforeRight
                    | SumoJunctionKind::Unregulated => JunctionControl::AllWayStop,
                };
                let (lo, hi) = x.shape.iter().fold((x.centre, x.centre), |(lo, hi), p| (lo.min(*p), hi.max(*p)));
                let half_size = ((hi.x - lo.x) + (hi.y - lo.y)) / 4.0;
                Intersection {
                    name: x.id.clone(),
                    centre: x.centre,
                    half_size: half_size.max(1.0),
                    control,
                    major: Axis::EastWest,
                    outline: x.shape.clone(),
                }
            })
            .collect();

        // Lanes.
        let mut widths = Vec::new();
        let mut lanes = Vec::with_capacity(ids.len());
        for &l in &ids {
            let s = &net.lanes[l];
            widths.push(s.width);
            let curve =
                Curve::polyline(&s.shape).ok_or_else(|| format!("<lane id=\"{}\">: its shape has no length", s.id))?;
            let on_edge: Vec<usize> = by_edge[s.edge.as_str()].iter().copied().filter(|j| kept[*j]).collect();
            let position = match on_edge.iter().position(|&j| j == l) {
                _ if on_edge.len() == 1 => LanePosition::Single,
                Some(0) => LanePosition::Outer,
                Some(k) if k + 1 == on_edge.len() => LanePosition::Inner,
                _ => LanePosition::Middle,
            };
            let letter = match position {
                LanePosition::Outer | LanePosition::Single => 'w',
                LanePosition::Inner => 'x',
                LanePosition::Middle => 'm',
            };
            let end = match junction_of.get(&s.to) {
                Some(&k) if crosses(l) => {
                    let h = curve.heading_at(curve.length());
                    LaneEnd::Intersection { intersection: k, approach: approach_side(h) }
                }
                _ => LaneEnd::Loop(usize::MAX),
            };
            lanes.push(Lane { name: s.id.clone(), road: '~', segment: 0, letter, position, curve, end });
        }

        // Movements.
        let (mut connectors, mut connection_of) = (Vec::new(), Vec::new());
        for (k, &l) in ids.iter().enumerate() {
            for &(to, turn, connection) in &moves[l] {
                let Some(&to_id) = new_id.get(&to) else { continue };
                let (from_curve, to_curve) = (&lanes[k].curve, &lanes[to_id].curve);
                let (curve, intersection) = match (lanes[k].end, connection) {
                    (LaneEnd::Intersection { intersection, .. }, Some(c)) => {
                        (movement_path(from_curve, &net.connections[c].path, to_curve), Some(intersection))
                    }
                    (LaneEnd::Loop(_), None) => {
                        let h = from_curve.heading_at(from_curve.length());
                        let curve = u_turn(from_curve.end(), h, to_curve.start())
                            .unwrap_or_else(|| movement_path(from_curve, &[], to_curve));
                        (curve, None)
                    }
                    _ => continue,
                };
                connectors.push(Connector { from: k, to: to_id, turn, intersection, curve });
                connection_of.push(connection);
            }
        }
        for (id, c) in connectors.iter().enumerate() {
            if c.intersection.is_none() {
                lanes[c.from].end = LaneEnd::Loop(id);
            }
        }
        // A lane whose full right (or left) leads to a lane left out drives
        // its slight one as its right (left).
        let full = super::full_turns(lanes.len(), connectors.iter().map(|c| (c.from, c.turn)));
        for c in &mut connectors {
            match c.turn {
                Turn::SlightRight if !full[c.from][0] => c.turn = Turn::Right,
                Turn::SlightLeft if !full[c.from][1] => c.turn = Turn::Left,
                _ => {}
            }
        }
        if let Some(l) = lanes.iter().find(|l| matches!(l.end, LaneEnd::Loop(usize::MAX))) {
            return Err(format!("<lane id=\"{}\">: no movement leads on from it", l.name));
        }

        let beside = ids
            .iter()
            .map(|&l| [true, false].map(|left| neighbour(l, left).and_then(|j| new_id.get(&j).copied())))
            .collect();
        widths.sort_by(f64::total_cmp);
        let layout = MapLayout {
            lane_width: widths[widths.len() / 2],
            east_west_roads: Vec::new(),
            north_south_roads: Vec::new(),
            lane_change_length: lane_change_m,
            stop_line_setback: IMPORTED_STOP_LINE_SETBACK_M,
            ..MapLayout::default()
        };
        let mut map = CityMap::assemble(layout, lanes, connectors, intersections, beside);
        // The priority road: the axis of the highest-priority edge arriving.
        for k in 0..map.intersections.len() {
            let top = ids
                .iter()
                .enumerate()
                .filter_map(|(i, &l)| match map.lanes[i].end {
                    LaneEnd::Intersection { intersection, approach } if intersection == k => {
                        Some((net.lanes[l].priority, approach))
                    }
                    _ => None,
                })
                .max_by_key(|(p, a)| (*p, std::cmp::Reverse(*a)));
            map.intersections[k].major = match top {
                Some((_, 'N' | 'S')) => Axis::NorthSouth,
                _ => Axis::EastWest,
            };
        }
        map.side_roads = side_roads(&map, |lane| net.lanes[ids[lane]].priority);
        let lights = programmed_lights(net, &map, &ids, &connection_of)?;
        (map.programmed, map.link_variants, map.permissive_lefts, map.actuated) =
            (lights.lights, lights.link_variants, lights.permissive_lefts, lights.actuated);
        map.merging = merging_movements(&map.connectors);
        map.splitting = splitting_movements(&map.connectors);
        let loops = map.connectors.iter().filter(|c| c.intersection.is_none()).count();
        let report = ImportReport {
            lanes: ids.len(),
            loops,
            dropped: dropped.into_iter().map(|(l, why)| (net.lanes[l].id.clone(), why)).collect(),
        };
        Ok((map, report))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_actuated_phase_detects_on_lanes_whose_every_link_it_gives_green() {
        let never = |_| false;
        let link_1_protected_elsewhere = |link: usize| link == 1;
        // A lane with a straight (link 0) and a left (link 1).
        assert!(detects(b"GG", &[0, 1], false, never));
        assert!(!detects(b"Gr", &[0, 1], false, never), "the left waits");
        // A permissive left that is never protected counts ...
        assert!(detects(b"Gg", &[0, 1], false, never));
        // ... one that waits for its own protected phase does not, unless
        // the lane is its road's only one.
        assert!(!detects(b"Gg", &[0, 1], false, link_1_protected_elsewhere));
        assert!(detects(b"Gg", &[0, 1], true, link_1_protected_elsewhere));
        // Yellow, red, a lane without links of the programme: none.
        assert!(!detects(b"yy", &[0, 1], false, never));
        assert!(!detects(b"GG", &[], false, never));
    }

    #[test]
    fn a_dead_ends_loop_has_points_every_half_metre_up_to_a_bound() {
        // Onto the back lane 3.2 m away: a half circle of 5 m in 11 pieces.
        let near = u_turn(DVec2::ZERO, 0.0, DVec2::new(0.0, 3.2)).unwrap();
        assert_eq!(near.pieces(), 11);
        assert!((near.length() - PI * 1.6).abs() < 0.05, "{}", near.length());
        // A broken file's back lane 1,900 km away (coordinates within the
        // import's bounds): the same half circle, in no more pieces than the
        // bound (at 0.5 m it would take 6 million points).
        let far = u_turn(DVec2::ZERO, 0.0, DVec2::new(0.0, 1.9e6)).unwrap();
        assert_eq!(far.pieces(), MAX_U_TURN_POINTS);
        assert!((far.length() / (PI * 0.95e6) - 1.0).abs() < 1e-3, "{}", far.length());
    }

    #[test]
    fn berlins_actuated_programme_detects_on_the_lane_of_its_one_movement() {
        let text = include_str!("../../tests/data/sumo/berlin-small.net.xml");
        let net = SumoNetwork::from_xml(text).unwrap();
        let (map, _) = CityMap::from_sumo(&net, 6.0).unwrap();
        // Only GS_cluster_... has phases traffic extends; its one movement
        // for cars is the U-turn from 143308590#0's left lane, `g` but
        // never `G`.
        assert_eq!(map.actuated.len(), 1);
        let programme = &map.actuated[0];
        assert!(programme.id.starts_with("GS_cluster_1560223815"), "{}", programme.id);
        assert_eq!((programme.max_gap, programme.phases[0].bounds), (3.0, Some((5.0, 50.0))));
        let lanes: Vec<&str> = programme.phases[0].detectors.iter().map(|&(l, _)| map.lanes[l].name.as_str()).collect();
        assert_eq!(lanes, ["143308590#0_2"]);
        assert!(programme.phases[3].detectors.is_empty(), "red for it");
    }

    #[test]
    fn a_movement_whose_link_runs_another_schedule_gets_a_light_of_its_own() {
        let text = include_str!("../../tests/data/sumo/grid2-arrows.net.xml");
        let (map, _) = CityMap::from_sumo(&SumoNetwork::from_xml(text).unwrap(), 6.0).unwrap();
        let b1 = map.intersections.iter().position(|x| x.name == "B1").unwrap();
        let from = |lane: &str, turn: Turn| {
            let l = map.lanes.iter().position(|x| x.name == lane).unwrap();
            map.connectors.iter().position(|c| c.from == l && c.turn == turn).unwrap()
        };
        // From the south, the right turn's link is green in the arrow phase
        // too; the straight links are not.
        let (right, ahead) = (from("B0B1_0", Turn::Right), from("B0B1_0", Turn::Straight));
        let arrow = map.light_of(right).unwrap();
        assert_eq!(map.light_of(ahead), map.light_index(b1, 'S', Signal::Straight));
        assert_eq!(map.light_of(from("B0B1_1", Turn::Straight)), map.light_of(ahead));
        assert_eq!(
            (map.light_at(arrow), map.light_name(arrow)),
            ((b1, 'S', Signal::Straight, 1), "B1/S/straight-2".into())
        );
        assert_eq!(arrow, 4 * 8, "after the cycle's 8 lights of each of 4 junctions");
        assert_eq!(map.light_count(), 4 * 8 + 1);
        let light = map.programmed.iter().find(|l| l.variant == 1).unwrap();
        let steps: Vec<(Colour, f64)> = light.schedule.iter().map(|s| (s.colour, s.duration)).collect();
        use Colour::{Green, Red, Yellow};
        assert_eq!(steps, [(Green, 36.0), (Yellow, 3.0), (Green, 6.0), (Yellow, 3.0), (Red, 39.0)]);
        // Scenario files name it; a variant B1/S does not have is refused
        // naming the ones it has.
        assert_eq!(map.light_by_name("B1/S/straight-2"), Ok(arrow));
        let wrong = map.light_by_name("B1/S/straight-3").unwrap_err();
        assert!(wrong.contains("straight, straight-2"), "{wrong}");
        assert!(map.light_by_name("B1/S/straight-1").is_err());
        for wrong in ["B1/S/straight-02", "B1/S/straight-+2", "B1/S/straight-", "B1/S/straight-256"] {
            assert!(map.light_by_name(wrong).is_err(), "{wrong}");
        }
        // Lefts without a protected phase go on the permissive green; the
        // west's, protected in the arrow phase, does not.
        assert!(!map.permissive_left(from("A1B1_1", Turn::Left)));
        assert!(map.permissive_left(from("top1B1_1", Turn::Left)));
        assert!(!map.permissive_left(ahead));
    }

    /// SUMO's own answer for each movement of `text`'s priority junctions:
    /// `(from lane, to lane) -> whether its link yields` (state `m`, where
    /// `M` is the priority road's).
    fn sumo_yields(text: &str) -> HashMap<(String, String), bool> {
        // Read apart from the import's parser: each `<connection .../>`'s
        // attributes, as the file spells them.
        let attribute = |tag: &str, name: &str| -> String {
            let start = tag.find(&format!(" {name}=\"")).unwrap_or_else(|| panic!("{name} in {tag}")) + name.len() + 3;
            tag[start..start + tag[start..].find('"').unwrap()].to_string()
        };
        text.split("<connection ")
            .skip(1)
            .map(|rest| &rest[..rest.find("/>").unwrap()])
            .map(|tag| format!(" {tag}"))
            .filter(|tag| !attribute(tag, "from").starts_with(':'))
            .filter_map(|tag| {
                let state = attribute(&tag, "state");
                let from = format!("{}_{}", attribute(&tag, "from"), attribute(&tag, "fromLane"));
                let to = format!("{}_{}", attribute(&tag, "to"), attribute(&tag, "toLane"));
                (state == "M" || state == "m").then(|| ((from, to), state == "m"))
            })
            .collect()
    }

    /// The map of `text`, with SUMO's yield answer for each of its
    /// movements at a priority junction: `(connector, SUMO yields)`.
    fn against_sumo(text: &str) -> (CityMap, Vec<(usize, bool)>) {
        let map = CityMap::from_sumo(&SumoNetwork::from_xml(text).unwrap(), 6.0).unwrap().0;
        let sumo = sumo_yields(text);
        let name = |lane: LaneId| map.lanes[lane].name.clone();
        let movements = (0..map.connectors.len())
            .filter(|&c| map.control_of(c) == Some(JunctionControl::Priority))
            .filter_map(|c| {
                let key = (name(map.connectors[c].from), name(map.connectors[c].to));
                sumo.get(&key).map(|&yields| (c, yields))
            })
            .collect();
        (map, movements)
    }

    #[test]
    fn at_a_junction_of_five_arms_a_side_street_from_the_priority_roads_side_gives_way_as_sumo_says() {
        let text = include_str!("../../tests/data/sumo/star5-priority.net.xml");
        let (map, movements) = against_sumo(text);
        // The priority road runs north-south (edges nC, sC: priority 3); the
        // side street nwC (priority 1) arrives from the north too, 30
        // degrees off the priority road.
        let lane = |name: &str| map.lane_by_name(name).unwrap();
        assert_eq!(map.lanes[lane("nwC_0")].end, map.lanes[lane("nC_0")].end, "both arrive from the north");
        assert!(map.on_priority_road(lane("nC_0")) && map.on_priority_road(lane("sC_0")));
        for side in ["nwC_0", "eC_0", "swC_0"] {
            assert!(!map.on_priority_road(lane(side)), "{side} is on the priority road");
        }
        // Every movement this map keeps yields exactly where SUMO's does.
        assert!(movements.len() >= 15, "only {} movements compared", movements.len());
        for &(c, yields) in &movements {
            let (from, to) = (&map.lanes[map.connectors[c].from].name, &map.lanes[map.connectors[c].to].name);
            assert_eq!(map.gives_way(c), yields, "{from} -> {to}: SUMO says yields = {yields}");
        }
        // The side street's straight on gives way to the priority road's.
        let from = |name: &str, turn: Turn| map.exit(lane(name), turn).unwrap();
        // Both go on into Cs.
        let (side, main) = (from("nwC_0", Turn::Straight), from("nC_0", Turn::Straight));
        assert!(map.conflicts(side).contains(&main));
        assert!(map.goes_before(main, side) && !map.goes_before(side, main));
    }

    #[test]
    fn on_berlins_priority_junctions_straight_on_and_left_turns_yield_where_sumos_do() {
        let (map, movements) = against_sumo(include_str!("../../tests/data/sumo/berlin-small.net.xml"));
        // Right turns and U-turns are left out: SUMO makes the priority
        // road's right turns yield to the pedestrian crossings this import
        // leaves out, and its turnarounds yield to no one.
        let compared: Vec<_> = movements
            .into_iter()
            .filter(|&(c, _)| matches!(map.connectors[c].turn, Turn::Straight | Turn::Left))
            .collect();
        assert!(compared.len() >= 25, "only {} movements compared", compared.len());
        assert!(compared.iter().any(|&(_, yields)| yields), "no yielding movement compared");
        for &(c, yields) in &compared {
            let (from, to) = (&map.lanes[map.connectors[c].from].name, &map.lanes[map.connectors[c].to].name);
            assert_eq!(map.gives_way(c), yields, "{from} -> {to}: SUMO says yields = {yields}");
        }
    }

    #[test]
    fn at_a_junction_of_five_arms_each_arms_lights_and_signs_stand_beside_that_arm() {
        let lights = include_str!("../../tests/data/sumo/star5-lights.net.xml");
        let map = CityMap::from_sumo(&SumoNetwork::from_xml(lights).unwrap(), 6.0).unwrap().0;
        let lane = |name: &str| map.lane_by_name(name).unwrap();
        let from = |name: &str, turn: Turn| map.exit(lane(name), turn).unwrap();
        let line = |map: &CityMap, name: &str| {
            let curve = &map.lanes[map.lane_by_name(name).unwrap()].curve;
            curve.position(curve.length(), 0.0)
        };
        // nC and nwC both arrive from the north; netconvert's programme gives
        // nwC a phase of its own, so its straight on runs on a light of its own.
        let (main, side) =
            (map.light_of(from("nC_0", Turn::Straight)).unwrap(), map.light_of(from("nwC_0", Turn::Straight)).unwrap());
        assert_eq!((map.light_name(main), map.light_name(side)), ("C/N/straight".into(), "C/N/straight-2".into()));
        let head = |index: usize| {
            let (k, approach, signal, variant) = map.light_at(index);
            map.signal_head(k, approach, signal, variant).unwrap()
        };
        for (light, own, other) in [(main, "nC_0", "nwC_0"), (side, "nwC_0", "nC_0")] {
            let (near, far) = (head(light).distance(line(&map, own)), head(light).distance(line(&map, other)));
            assert!(
                near < 12.0 && near < far,
                "{}: {near:.1} m from {own}'s line, {far:.1} m from {other}'s",
                map.light_name(light)
            );
        }
        // At the priority junction each minor arm's give-way sign stands at
        // its own line.
        let priority = include_str!("../../tests/data/sumo/star5-priority.net.xml");
        let map = CityMap::from_sumo(&SumoNetwork::from_xml(priority).unwrap(), 6.0).unwrap().0;
        let sign = map.sign_of(map.lane_by_name("nwC_0").unwrap()).unwrap();
        let (near, far) = (sign.distance(line(&map, "nwC_0")), sign.distance(line(&map, "nC_0")));
        assert!(near < 6.0 && near < far, "the sign stands {near:.1} m from nwC's line, {far:.1} m from nC's");
    }

    #[test]
    fn at_a_junction_of_five_arms_every_movement_of_the_file_is_driven_the_lesser_of_two_rights_or_lefts_as_slight() {
        let text = include_str!("../../tests/data/sumo/star5-priority.net.xml");
        let map = CityMap::from_sumo(&SumoNetwork::from_xml(text).unwrap(), 6.0).unwrap().0;
        let wanted: Vec<(String, String)> = sumo_yields(text).into_keys().collect();
        assert_eq!(wanted.len(), 20, "the file's movements through C");
        let name = |lane: LaneId| map.lanes[lane].name.clone();
        for (from, to) in &wanted {
            let lane = map.lane_by_name(from).unwrap();
            let driven: Vec<String> = map.exits_from(lane).map(|c| name(map.connectors[c].to)).collect();
            assert!(driven.contains(to), "{from} -> {to} is not driven (it drives to {driven:?})");
        }
        // From the north: the sharp right into the side street from the
        // north-west, the slight one into the south-west's; from the south:
        // the left into the south-west, the slight one into the north-west.
        let exit =
            |from: &str, turn: Turn| name(map.connectors[map.exit(map.lane_by_name(from).unwrap(), turn).unwrap()].to);
        assert_eq!((exit("nC_0", Turn::Right), exit("nC_0", Turn::SlightRight)), ("Cnw_0".into(), "Csw_0".into()));
        assert_eq!((exit("sC_0", Turn::Left), exit("sC_0", Turn::SlightLeft)), ("Csw_0".into(), "Cnw_0".into()));
        let lane = map.lane_by_name("nC_0").unwrap();
        assert_eq!(map.allowed_turns(lane), [Turn::Left, Turn::Straight, Turn::Right, Turn::SlightRight]);
        // A slight left crosses oncoming traffic: it yields at the priority
        // junction and runs on the left signal at lights.
        let slight_left = map.exit(map.lane_by_name("sC_0").unwrap(), Turn::SlightLeft).unwrap();
        assert!(map.gives_way(slight_left));
        let lights = include_str!("../../tests/data/sumo/star5-lights.net.xml");
        let lit = CityMap::from_sumo(&SumoNetwork::from_xml(lights).unwrap(), 6.0).unwrap().0;
        let slight_left = lit.exit(lit.lane_by_name("sC_0").unwrap(), Turn::SlightLeft).unwrap();
        assert_eq!(lit.light_at(lit.light_of(slight_left).unwrap()).2, Signal::Left);
    }
}
