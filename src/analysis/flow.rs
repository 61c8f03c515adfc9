//! Traffic-flow figures of one city scenario, from its files: what a traffic
//! engineer checks first. Every "following" and "free" frame comes from
//! `interactions.csv`, i.e. from what the driver model actually used.
//!
//! - **Headway** (front to front): while a car follows the car ahead
//!   steadily (`bound_by = car`, moving at [`MOVING_SPEED`] or more, the two
//!   speeds within [`STEADY_SPEED_DIFFERENCE`] of the follower's), the distance
//!   between the two centres (equal to front-to-front for equal lengths)
//!   over the follower's speed, seconds.
//! - **Time gap** (the part that grows with speed): the same frames, the
//!   bumper-to-bumper gap less the follower's `min_gap`, over its speed.
//! - **Queue discharge**: at every green onset of a straight signal, the
//!   cars standing on a lane that ends at that approach cross its stop line
//!   one after another; the headways between successive crossings in one
//!   lane (from the second car on, while the signal is not red again) give
//!   the saturation flow, 1 / median headway, vehicles per second per lane.
//! - **Free speed**: while a car is bound by nothing (`bound_by = free`) and
//!   moves, its speed over its desired speed for the current stretch of its
//!   drive queue (the stretch after as many turns and merges as
//!   `events.csv` shows done).

use crate::map::{CityMap, LaneEnd};
use glam::DVec2;
use std::collections::HashMap;
use std::path::Path;

/// Speed from which a car counts as moving, m/s.
pub const MOVING_SPEED: f64 = 0.3;
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
pub struct ScenarioFlow<'a> {
    pub map: &'a CityMap,
    pub frame_interval: f64,
    pub cars: Vec<CarFacts>,
    /// `tracks[car][frame]`.
    pub tracks: Vec<Vec<Pose>>,
    /// `bound[frame][car]`.
    pub bound: Vec<Vec<Bound>>,
    /// Per car, the frames at which it completed a turn or merge, ascending.
    pub actions_done: Vec<Vec<usize>>,
    /// (intersection name, approach side) -> colour of its straight signal per frame.
    pub straight_signals: HashMap<(String, char), Vec<String>>,
}

impl ScenarioFlow<'_> {
    /// The samples of this scenario.
    pub fn samples(&self) -> FlowSamples {
        let mut out = FlowSamples::default();
        for (frame, cars) in self.bound.iter().enumerate() {
            for (i, bound) in cars.iter().enumerate() {
                let me = self.tracks[i][frame];
                if me.speed < MOVING_SPEED {
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
                        let speeds = &self.cars[i].desired_speeds;
                        let done = self.actions_done[i].partition_point(|&f| f <= frame);
                        if let Some(&desired) = speeds.get(done.min(speeds.len().saturating_sub(1))) {
                            out.free_speed_ratios.push(me.speed / desired);
                        }
                    }
                    Bound::Other => {}
                }
            }
        }
        out.discharge_headways_s = self.discharge_headways();
        out
    }

    /// The lane a point lies on (within half a lane width of its centre
    /// line, heading within 30 degrees) and how far along it, if any.
    fn lane_at(&self, p: DVec2, heading: Option<f64>) -> Option<(usize, f64)> {
        let half = self.map.layout.lane_width / 2.0;
        self.map.lanes.iter().enumerate().find_map(|(k, lane)| {
            let (s, lateral) = lane.curve.local_coordinates(p);
            let on = s >= 0.0 && s <= lane.curve.length() && lateral.abs() < half;
            let aligned =
                heading.is_none_or(|h| crate::map::curve::wrap_angle(lane.curve.heading_at(s) - h).abs() < 0.5);
            (on && aligned).then_some((k, s))
        })
    }

    /// Headways between successive stop-line crossings of cars that stood
    /// queued on one lane when its straight signal turned green, seconds.
    fn discharge_headways(&self) -> Vec<f64> {
        let mut headways = Vec::new();
        let frames = self.bound.len();
        for ((intersection, side), colours) in &self.straight_signals {
            for onset in 1..colours.len().min(frames) {
                if colours[onset] != "green" || colours[onset - 1] == "green" {
                    continue;
                }
                // The signal's phase lasts until it is red again.
                let end = (onset..colours.len().min(frames)).find(|&f| colours[f] == "red").unwrap_or(frames);
                // Standing cars per lane of this approach: (car, lane).
                let mut by_lane: HashMap<usize, Vec<usize>> = HashMap::new();
                for (i, track) in self.tracks.iter().enumerate() {
                    let p = track[onset];
                    if p.speed >= STANDING_SPEED {
                        continue;
                    }
                    let Some((lane, _)) = self.lane_at(p.position, None) else { continue };
                    let LaneEnd::Intersection { intersection: k, approach } = self.map.lanes[lane].end else {
                        continue;
                    };
                    if self.map.intersections[k].name == *intersection && approach == *side {
                        by_lane.entry(lane).or_default().push(i);
                    }
                }
                for (lane, cars) in by_lane {
                    let line = self.map.lanes[lane].curve.length() - self.map.layout.stop_line_setback;
                    let mut crossings: Vec<f64> = cars
                        .iter()
                        .filter_map(|&i| {
                            let front = self.cars[i].length / 2.0;
                            (onset..end).find_map(|f| {
                                let p = self.tracks[i][f].position;
                                let (s, lateral) = self.map.lanes[lane].curve.local_coordinates(p);
                                let past = s + front >= line || lateral.abs() > self.map.layout.lane_width;
                                past.then_some(f as f64 * self.frame_interval)
                            })
                        })
                        .collect();
                    crossings.sort_by(f64::total_cmp);
                    headways.extend(crossings.windows(2).map(|w| w[1] - w[0]));
                }
            }
        }
        headways
    }
}

/// Reads one city scenario folder's files into a [`ScenarioFlow`].
pub fn read_scenario_flow<'a>(dir: &Path, map: &'a CityMap) -> Result<Option<ScenarioFlow<'a>>, String> {
    let interactions = dir.join("interactions.csv");
    if !interactions.exists() {
        return Ok(None);
    }
    let err = |path: &Path, e: &dyn std::fmt::Display| format!("{}: {e}", path.display());
    let path = dir.join("scenario.json");
    let scenario: serde_json::Value = std::fs::read(&path)
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
    let mut bound = vec![vec![Bound::Other; n]; frames];
    let mut reader = csv::Reader::from_path(&interactions).map_err(|e| err(&interactions, &e))?;
    for row in reader.records() {
        let row = row.map_err(|e| err(&interactions, &e))?;
        let (Some(frame), Some(car)) =
            (row.get(0).and_then(|v| v.parse::<usize>().ok()), row.get(1).and_then(|v| v.parse::<usize>().ok()))
        else {
            return Err(format!("{}: malformed row", interactions.display()));
        };
        let other = row.get(3).and_then(|v| v.parse::<usize>().ok()).filter(|&j| j < n);
        let b = match (row.get(2), other) {
            (Some("free"), _) => Bound::Free,
            (Some("car"), Some(j)) => Bound::Car(j),
            _ => Bound::Other,
        };
        if frame < frames && car < n {
            bound[frame][car] = b;
        }
    }
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
    let mut straight_signals: HashMap<(String, char), Vec<String>> = HashMap::new();
    let path = dir.join("lights.csv");
    let mut reader = csv::Reader::from_path(&path).map_err(|e| err(&path, &e))?;
    for row in reader.records() {
        let row = row.map_err(|e| err(&path, &e))?;
        if row.get(4) != Some("straight") {
            continue;
        }
        let (Some(i), Some(side), Some(colour)) = (row.get(2), row.get(3).and_then(|s| s.chars().next()), row.get(5))
        else {
            return Err(format!("{}: malformed row", path.display()));
        };
        straight_signals.entry((i.to_string(), side)).or_default().push(colour.to_string());
    }
    Ok(Some(ScenarioFlow { map, frame_interval, cars, tracks, bound, actions_done, straight_signals }))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn facts(length: f64) -> CarFacts {
        CarFacts { length, min_gap: 1.0, desired_speeds: vec![10.0, 5.0] }
    }

    #[test]
    fn headway_time_gap_and_free_speed_come_from_the_bound_frames() {
        let map = CityMap::default();
        // Car 1 follows car 0 at 10 m/s, centres 20 m apart; car 2 drives
        // free at 8 m/s, its first action done at frame 1.
        let at = |x: f64, speed: f64| Pose { position: DVec2::new(x, 100.0), speed };
        let tracks = vec![
            vec![at(20.0, 10.0), at(22.0, 10.0)],
            vec![at(0.0, 10.0), at(2.0, 10.0)],
            vec![at(50.0, 8.0), at(51.6, 4.0)],
        ];
        let flow = ScenarioFlow {
            map: &map,
            frame_interval: 0.2,
            cars: vec![facts(4.0), facts(4.0), facts(4.0)],
            tracks,
            bound: vec![vec![Bound::Free, Bound::Car(0), Bound::Free]; 2],
            actions_done: vec![vec![], vec![], vec![1]],
            straight_signals: HashMap::new(),
        };
        let s = flow.samples();
        assert_eq!(s.headways_s, vec![2.0, 2.0]);
        // (20 - 4 - 1) / 10
        assert_eq!(s.time_gaps_s, vec![1.5, 1.5]);
        // Car 0 at 10 of 10 m/s; car 2 at 8 of 10, then 4 of 5 after its action.
        assert_eq!(s.free_speed_ratios, vec![1.0, 0.8, 1.0, 0.8]);
        assert!(s.discharge_headways_s.is_empty());
    }

    #[test]
    fn a_queue_discharging_at_green_gives_the_crossing_headways() {
        let map = CityMap::default();
        // Three cars stand on A1w before AD's stop line; the light turns
        // green at frame 1 and they cross at frames 3, 13 and 23 (2 s apart).
        let lane = map.lane_by_name("A1w").unwrap();
        let curve = &map.lanes[lane].curve;
        let line = curve.length() - map.layout.stop_line_setback;
        let length = 2.2;
        let mut tracks = Vec::new();
        for (k, cross) in [3usize, 13, 23].into_iter().enumerate() {
            let start = line - length / 2.0 - 0.3 - k as f64 * 3.0;
            // Standing until it crosses, then past the line.
            let track: Vec<Pose> = (0..30)
                .map(|f| match f < cross {
                    true => Pose { position: curve.lane_center_at(start), speed: 0.0 },
                    false => Pose { position: curve.lane_center_at(line), speed: 1.0 },
                })
                .collect();
            tracks.push(track);
        }
        let mut colours = vec!["red".to_string()];
        colours.extend(std::iter::repeat_n("green".to_string(), 29));
        let mut signals = HashMap::new();
        signals.insert(("AD".to_string(), 'W'), colours);
        let flow = ScenarioFlow {
            map: &map,
            frame_interval: 0.2,
            cars: vec![facts(length), facts(length), facts(length)],
            tracks,
            bound: vec![vec![Bound::Other; 3]; 30],
            actions_done: vec![vec![]; 3],
            straight_signals: signals,
        };
        let mut h = flow.samples().discharge_headways_s;
        assert_eq!(h.len(), 2, "{h:?}");
        assert!(h.iter().all(|x| (x - 2.0).abs() < 1e-9), "{h:?}");
        assert_eq!(median(&mut h), Some(2.0));
    }
}
