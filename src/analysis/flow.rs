//! Traffic-flow figures of one city scenario, from its files: what a traffic
//! engineer checks first. Every "following" and "free" frame comes from
//! `interactions.csv`, i.e. from what the driver model actually used.
//!
//! - **Headway** (front to front): while a car follows the car ahead
//!   steadily at speed (`bound_by = car`, at [`AT_SPEED`] of its desired
//!   speed or more, the two speeds within [`STEADY_SPEED_DIFFERENCE`] of the
//!   follower's), the distance
//!   between the two centres (equal to front-to-front for equal lengths)
//!   over the follower's speed, seconds.
//! - **Time gap** (the part that grows with speed): the same frames, the
//!   bumper-to-bumper gap less the follower's `min_gap`, over its speed.
//! - **Queue discharge**: when a signal turns green, its queue is the car
//!   standing at its stop line bound by that light and the cars standing
//!   behind it, each bound by the one ahead. They leave one after another;
//!   the headways between them where they have crossed the intersection (a
//!   road's width past the stop line along each car's path, where a queue's
//!   outflow is measured, past the start-up at the line) give the discharge
//!   flow, 1 / median headway, vehicles per second per lane.
//! - **Free speed**: while a car is bound by nothing (`bound_by = free`) and
//!   cruises at speed (speed changing by at most [`CRUISING_CHANGE`]), its
//!   speed over its desired speed for the current stretch of its drive queue
//!   (the stretch after as many turns and merges as `events.csv` shows done).

use crate::map::CityMap;
use crate::output::arrays::LIGHT_COLOURS;
use crate::output::logs::read_interactions;
use crate::world::BoundBy;
use glam::DVec2;
use std::collections::HashMap;
use std::path::Path;

/// Speed from which a car counts as moving, m/s.
pub const MOVING_SPEED: f64 = 0.3;
/// Share of its desired speed from which a car counts as driving at speed
/// (headways and free speed are traffic at speed, not creeping queues).
pub const AT_SPEED: f64 = 0.5;
/// Largest change of speed, m/s per second, at which a free car counts as
/// cruising.
pub const CRUISING_CHANGE: f64 = 0.2;
/// Largest speed difference, as a share of the follower's speed, at which a
/// car counts as following steadily (not closing in, not falling back).
pub const STEADY_SPEED_DIFFERENCE: f64 = 0.2;
/// Speed under which a car counts as standing in a queue, m/s.
const STANDING_SPEED: f64 = 0.1;

/// Samples of one scenario, in seconds (headways, time gaps, discharge
/// headways) and ratios (free speed).
#[derive(Debug, Default, Clone)]
pub struct FlowSamples {
    pub headways_s: Vec<f64>,
    pub time_gaps_s: Vec<f64>,
    pub discharge_headways_s: Vec<f64>,
    pub free_speed_ratios: Vec<f64>,
}

impl FlowSamples {
    pub fn extend(&mut self, other: FlowSamples) {
        self.headways_s.extend(other.headways_s);
        self.time_gaps_s.extend(other.time_gaps_s);
        self.discharge_headways_s.extend(other.discharge_headways_s);
        self.free_speed_ratios.extend(other.free_speed_ratios);
    }
}

/// The median of `values` (sorted in place), if any.
pub fn median(values: &mut [f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    values.sort_by(f64::total_cmp);
    let n = values.len();
    Some(if n % 2 == 1 { values[n / 2] } else { (values[n / 2 - 1] + values[n / 2]) / 2.0 })
}

/// One car at one frame, as poses.csv gives it.
#[derive(Debug, Clone, Copy)]
pub struct Pose {
    pub position: DVec2,
    pub speed: f64,
}

/// What `interactions.csv` says about one car at one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Bound {
    Free,
    Car(usize),
    /// A light, by index in [`ScenarioFlow::signals`].
    Light(usize),
    Other,
}

/// A car's fixed facts from scenario.json.
#[derive(Debug, Clone)]
pub struct CarFacts {
    pub length: f64,
    pub min_gap: f64,
    pub desired_speeds: Vec<f64>,
}

/// Everything the figures need of one scenario.
pub struct ScenarioFlow {
    pub frame_interval: f64,
    pub cars: Vec<CarFacts>,
    /// `tracks[car][frame]`.
    pub tracks: Vec<Vec<Pose>>,
    /// `bound[frame][car]`.
    pub bound: Vec<Vec<Bound>>,
    /// `named[frame][car]`: the other car its interactions.csv row names
    /// (bound by it as the car ahead, a conflict or a collision).
    pub named: Vec<Vec<Option<usize>>>,
    /// Per car, the frames at which it completed a turn or merge, ascending.
    pub actions_done: Vec<Vec<usize>>,
    /// Half a road's width (two lanes), metres.
    pub road_half_width: f64,
    /// Every light, named as interactions.csv names it (`AC/W/straight`),
    /// with its colour per frame.
    pub signals: Vec<(String, Vec<String>)>,
}

impl ScenarioFlow {
    /// The samples of this scenario.
    pub fn samples(&self) -> FlowSamples {
        let mut out = FlowSamples::default();
        for (frame, cars) in self.bound.iter().enumerate() {
            for (i, bound) in cars.iter().enumerate() {
                let me = self.tracks[i][frame];
                let speeds = &self.cars[i].desired_speeds;
                let done = self.actions_done[i].partition_point(|&f| f <= frame);
                let Some(&desired) = speeds.get(done.min(speeds.len().saturating_sub(1))) else { continue };
                if me.speed < MOVING_SPEED.max(AT_SPEED * desired) {
                    continue;
                }
                match *bound {
                    Bound::Car(j) => {
                        let other = self.tracks[j][frame];
                        if (other.speed - me.speed).abs() > STEADY_SPEED_DIFFERENCE * me.speed {
                            continue;
                        }
                        let centres = me.position.distance(other.position);
                        let gap = centres - (self.cars[i].length + self.cars[j].length) / 2.0;
                        out.headways_s.push(centres / me.speed);
                        out.time_gaps_s.push((gap - self.cars[i].min_gap) / me.speed);
                    }
                    Bound::Free => {
                        // Cruising: no longer speeding up or slowing down.
                        let before = self.tracks[i][frame.saturating_sub(1)].speed;
                        if (me.speed - before).abs() <= CRUISING_CHANGE * self.frame_interval {
                            out.free_speed_ratios.push(me.speed / desired);
                        }
                    }
                    Bound::Light(_) | Bound::Other => {}
                }
            }
        }
        out.discharge_headways_s = self.discharge_headways();
        out
    }

    /// Headways between successive stop-line crossings of the queues
    /// standing at each signal when it turns green, seconds.
    fn discharge_headways(&self) -> Vec<f64> {
        let mut headways = Vec::new();
        let frames = self.bound.len();
        for (light, (_, colours)) in self.signals.iter().enumerate() {
            for onset in 1..colours.len().min(frames) {
                if colours[onset] != "green" || colours[onset - 1] == "green" {
                    continue;
                }
                let standing = |i: usize| self.tracks[i][onset].speed < STANDING_SPEED;
                let bound = &self.bound[onset];
                // The queue, front to back.
                let Some(mut last) = (0..bound.len()).find(|&i| bound[i] == Bound::Light(light) && standing(i)) else {
                    continue;
                };
                let mut queue = vec![last];
                while let Some(next) = (0..bound.len()).find(|&j| bound[j] == Bound::Car(last) && standing(j)) {
                    if queue.contains(&next) {
                        break;
                    }
                    queue.push(next);
                    last = next;
                }
                // Each car has crossed the box once it has covered its distance
                // to the head car, the head's distance to the line and the box.
                let end = (onset..colours.len().min(frames)).find(|&f| colours[f] == "red").unwrap_or(frames);
                let head = self.tracks[queue[0]][onset].position;
                let box_width = 2.0 * self.road_half_width;
                let crossings: Vec<f64> = queue
                    .iter()
                    .map_while(|&i| {
                        let start = self.tracks[i][onset].position;
                        let to_head = start.distance(head);
                        (onset..end).find_map(|f| {
                            let moved = self.path_length(i, onset, f);
                            (moved >= to_head + HEAD_TO_LINE_M + box_width).then_some(f as f64 * self.frame_interval)
                        })
                    })
                    .collect();
                headways.extend(crossings.windows(2).map(|w| w[1] - w[0]));
            }
        }
        headways
    }

    /// Distance car `i` travelled from frame `from` to frame `to`, metres.
    fn path_length(&self, i: usize, from: usize, to: usize) -> f64 {
        self.tracks[i][from..=to].windows(2).map(|w| w[0].position.distance(w[1].position)).sum()
    }
}

/// How far ahead of a queue's head car (its centre, standing at the stop
/// line) a car counts as having crossed the line, metres: the head stands
/// with its front a few decimetres before the line, so a car whose centre
/// has moved this far beyond the head's has its front across.
const HEAD_TO_LINE_M: f64 = 3.0;

/// Reads one city scenario folder's files into a [`ScenarioFlow`].
pub fn read_scenario_flow(dir: &Path, map: &CityMap) -> Result<Option<ScenarioFlow>, String> {
    let interactions = dir.join("interactions.csv");
    if !interactions.exists() {
        return Ok(None);
    }
    let err = |path: &Path, e: &dyn std::fmt::Display| format!("{}: {e}", path.display());
    let path = dir.join("scenario.json");
    let scenario: serde_json::Value = crate::input::read_record(&path)
        .map_err(|e| err(&path, &e))
        .and_then(|b| serde_json::from_slice(&b).map_err(|e| err(&path, &e)))?;
    let cars: Vec<CarFacts> = scenario["cars"]
        .as_array()
        .ok_or_else(|| format!("{}: no cars", path.display()))?
        .iter()
        .map(|c| CarFacts {
            length: c["length_m"].as_f64().unwrap_or(0.0),
            min_gap: c["driver"]["min_gap"].as_f64().unwrap_or(0.0),
            desired_speeds: c["desired_speeds"]
                .as_array()
                .map(|v| v.iter().filter_map(|x| x.as_f64()).collect())
                .unwrap_or_default(),
        })
        .collect();
    let frames = scenario["frames"].as_u64().unwrap_or(0) as usize;
    let frame_interval = scenario["frame_interval"].as_f64().unwrap_or(0.0);
    let n = cars.len();
    let mut tracks = vec![vec![Pose { position: DVec2::ZERO, speed: 0.0 }; frames]; n];
    let path = dir.join("poses.csv");
    let mut reader = csv::Reader::from_path(&path).map_err(|e| err(&path, &e))?;
    for row in reader.records() {
        let row = row.map_err(|e| err(&path, &e))?;
        let num = |i: usize| row.get(i).and_then(|v| v.parse::<f64>().ok());
        let (Some(frame), Some(car), Some(x), Some(y), Some(speed)) = (num(0), num(2), num(3), num(4), num(11)) else {
            return Err(format!("{}: malformed row", path.display()));
        };
        let (frame, car) = (frame as usize, car as usize);
        if frame < frames && car < n {
            tracks[car][frame] = Pose { position: DVec2::new(x, y), speed };
        }
    }
    let mut signals: Vec<(String, Vec<String>)> = Vec::new();
    let mut light_index: HashMap<String, usize> = HashMap::new();
    // Either layout (lights.csv or gen --lights changes), every frame.
    let lights = crate::dataset::readback::read_light_log(dir, frames, frame_interval)?;
    let count = lights.names.len();
    for (k, name) in lights.names.iter().enumerate() {
        light_index.insert(name.clone(), k);
        let colours = (0..frames).map(|f| LIGHT_COLOURS[lights.colour[f * count + k] as usize].name().to_string());
        signals.push((name.clone(), colours.collect()));
    }
    let records = read_interactions(&interactions, frames, n)?;
    let named =
        (0..frames).map(|frame| records[frame * n..(frame + 1) * n].iter().map(|r| r.other_car).collect()).collect();
    let bound = (0..frames)
        .map(|frame| {
            records[frame * n..(frame + 1) * n]
                .iter()
                .map(|r| match (r.bound_by, r.other_car, &r.light) {
                    (BoundBy::Free, _, _) => Bound::Free,
                    (BoundBy::Car, Some(j), _) => Bound::Car(j),
                    (BoundBy::Light, _, Some(name)) => light_index.get(name).map_or(Bound::Other, |&k| Bound::Light(k)),
                    _ => Bound::Other,
                })
                .collect()
        })
        .collect();
    let mut actions_done = vec![Vec::new(); n];
    let path = dir.join("events.csv");
    let mut reader = csv::Reader::from_path(&path).map_err(|e| err(&path, &e))?;
    for row in reader.records() {
        let row = row.map_err(|e| err(&path, &e))?;
        if matches!(row.get(2), Some("turn_done" | "merge_done")) {
            if let (Some(frame), Some(car)) =
                (row.get(0).and_then(|v| v.parse::<usize>().ok()), row.get(3).and_then(|v| v.parse::<usize>().ok()))
            {
                if car < n {
                    actions_done[car].push(frame);
                }
            }
        }
    }
    let road_half_width = map.layout.road_half_width();
    Ok(Some(ScenarioFlow { frame_interval, cars, tracks, bound, named, actions_done, road_half_width, signals }))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn facts(length: f64) -> CarFacts {
        CarFacts { length, min_gap: 1.0, desired_speeds: vec![10.0, 5.0] }
    }

    #[test]
    fn headway_time_gap_and_free_speed_come_from_the_bound_frames() {
        // Car 1 follows car 0 at 10 m/s, centres 20 m apart; car 2 drives
        // free at 8 m/s, its first action done at frame 1.
        let at = |x: f64, speed: f64| Pose { position: DVec2::new(x, 100.0), speed };
        let tracks = vec![
            vec![at(20.0, 10.0), at(22.0, 10.0)],
            vec![at(0.0, 10.0), at(2.0, 10.0)],
            vec![at(50.0, 8.0), at(51.6, 4.0)],
        ];
        let flow = ScenarioFlow {
            frame_interval: 0.2,
            cars: vec![facts(4.0), facts(4.0), facts(4.0)],
            tracks,
            bound: vec![vec![Bound::Free, Bound::Car(0), Bound::Free]; 2],
            named: vec![vec![None, Some(0), None]; 2],
            actions_done: vec![vec![], vec![], vec![1]],
            road_half_width: 6.0,
            signals: Vec::new(),
        };
        let s = flow.samples();
        assert_eq!(s.headways_s, vec![2.0, 2.0]);
        // (20 - 4 - 1) / 10
        assert_eq!(s.time_gaps_s, vec![1.5, 1.5]);
        // Car 0 cruises at 10 of 10 m/s; car 2 at 8 of 10, then it brakes to
        // 4 (of 5 after its action): not cruising, not counted.
        assert_eq!(s.free_speed_ratios, vec![1.0, 0.8, 1.0]);
        assert!(s.discharge_headways_s.is_empty());
    }

    #[test]
    fn a_queue_discharging_at_green_gives_the_headways_past_the_box() {
        // Three cars stand in a queue along x (car 0 at the line, bound by
        // light 0; car 1 behind it, bound by car 0; car 2 behind car 1); the
        // light turns green at frame 1. Each then drives at 5 m/s (1 m per
        // frame), starting 2 s after the one ahead.
        let spacing = 6.0;
        let mut tracks = Vec::new();
        for k in 0..3usize {
            let start = -(k as f64) * spacing;
            let go = 1 + 10 * k;
            let track: Vec<Pose> = (0..80usize)
                .map(|f| {
                    let moved = f.saturating_sub(go) as f64;
                    Pose { position: DVec2::new(start + moved, 0.0), speed: if f > go { 5.0 } else { 0.0 } }
                })
                .collect();
            tracks.push(track);
        }
        let mut colours = vec!["red".to_string()];
        colours.extend(std::iter::repeat_n("green".to_string(), 79));
        let mut bound = vec![vec![Bound::Light(0), Bound::Car(0), Bound::Car(1)]; 80];
        bound[0] = vec![Bound::Other; 3];
        let flow = ScenarioFlow {
            frame_interval: 0.2,
            cars: vec![facts(4.0), facts(4.0), facts(4.0)],
            tracks,
            bound,
            named: Vec::new(),
            actions_done: vec![vec![]; 3],
            road_half_width: 6.0,
            signals: vec![("AD/W/straight".to_string(), colours)],
        };
        let mut h = flow.samples().discharge_headways_s;
        // Car k leaves 2 s after car k - 1 and has 6 m further to go: 3.2 s.
        assert_eq!(h.len(), 2, "{h:?}");
        assert!(h.iter().all(|x| (x - 3.2).abs() < 1e-9), "{h:?}");
        assert!((median(&mut h).unwrap() - 3.2).abs() < 1e-9);
        // Without the chain (car 2 not bound by car 1) the queue is two cars.
        let mut flow = flow;
        for b in &mut flow.bound {
            b[2] = Bound::Free;
        }
        assert_eq!(flow.samples().discharge_headways_s.len(), 1);
    }
}
