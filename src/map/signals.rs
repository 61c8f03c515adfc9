//! Traffic lights as data: every approach of every intersection has a
//! Straight signal (also used by right turns) and a Left signal, each running
//! a repeating schedule of (colour, seconds) shifted by an offset. The default
//! plan is the original's cycle; specs scale it, shift intersections, or
//! replace the schedule of any single light.

use serde::{Deserialize, Serialize};

/// Which movements a signal controls.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Signal {
    /// Straight on and right turns.
    Straight,
    /// Protected left turns.
    Left,
}

impl Signal {
    pub fn name(self) -> &'static str {
        match self {
            Signal::Straight => "straight",
            Signal::Left => "left",
        }
    }
}

/// How files name a light: `AC/W/straight` (intersection, the side its
/// traffic arrives from, signal), as scenario files' interventions and
/// `interactions.csv` write it.
pub fn light_label(intersection: &str, approach: impl std::fmt::Display, signal: &str) -> String {
    format!("{intersection}/{approach}/{signal}")
}

/// A signal's colour.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Colour {
    Green,
    Yellow,
    Red,
}

impl Colour {
    pub fn name(self) -> &'static str {
        match self {
            Colour::Green => "green",
            Colour::Yellow => "yellow",
            Colour::Red => "red",
        }
    }
}

/// One step of a repeating schedule.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScheduleStep {
    pub colour: Colour,
    /// Seconds.
    pub duration: f64,
}

impl ScheduleStep {
    /// Appends `duration` seconds of `colour` to `schedule`: to its last
    /// step when that shows the same colour, else as a step of its own.
    pub fn extend(schedule: &mut Vec<ScheduleStep>, colour: Colour, duration: f64) {
        match schedule.last_mut() {
            Some(last) if last.colour == colour => last.duration += duration,
            _ => schedule.push(ScheduleStep { colour, duration }),
        }
    }
}

/// A signal's label in files: `straight`, `left`, and for a light of the
/// same approach and signal whose movements run on another schedule
/// ([`Light::variant`] 1, 2, ..) `straight-2`, `left-2`, ..
pub fn signal_label(signal: Signal, variant: u8) -> String {
    match variant {
        0 => signal.name().to_string(),
        v => format!("{}-{}", signal.name(), u32::from(v) + 1),
    }
}

/// One light: where it stands and what it shows when.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Light {
    /// Intersection index in the map.
    pub intersection: usize,
    /// Side the controlled traffic arrives from: 'N', 'E', 'S' or 'W'.
    pub approach: char,
    pub signal: Signal,
    /// 0 for the approach's own `signal` light; 1, 2, .. for further
    /// lights of the same approach and signal, where an imported network's
    /// programme runs some of its movements on another schedule (a
    /// right-turn arrow, a U-turn on the permissive green only).
    pub variant: u8,
    /// Seconds added to the scenario clock before looking up the schedule.
    pub offset: f64,
    /// Repeats for ever.
    pub schedule: Vec<ScheduleStep>,
}

impl Light {
    /// Its signal's label in files ([`signal_label`]).
    pub fn signal_label(&self) -> String {
        signal_label(self.signal, self.variant)
    }
}

/// Seconds of travel at the lane's speed limit between an actuated
/// programme's detector and its stop line: SUMO's default `detector-gap`
/// (`--tls.actuated.detector-gap`, sumo.dlr.de/docs/Simulation/Traffic_Lights.html).
pub const DETECTOR_GAP_S: f64 = 2.0;

/// Longest time gap, seconds, between cars over an actuated phase's
/// detectors that still extends it: SUMO's default `max-gap`
/// (`--tls.actuated.max-gap`, same page).
pub const MAX_GAP_S: f64 = 3.0;

/// A traffic-actuated programme (an imported network's `tlLogic
/// type="actuated"`), as the map knows it: its phases in order, the lights
/// it drives with their colour in each phase, and where its detectors lie.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ActuatedProgramme {
    /// SUMO's id of the programme.
    pub id: String,
    /// Seconds added to the scenario clock, as written.
    pub offset: f64,
    /// Longest time gap, seconds, between cars over a phase's detectors
    /// that still extends it (`max-gap`, default [`MAX_GAP_S`]).
    pub max_gap: f64,
    pub phases: Vec<ActuatedPhase>,
    /// (intersection, approach, signal, variant) of each light it drives,
    /// and its colour in each phase.
    pub lights: Vec<(usize, char, Signal, u8, Vec<Colour>)>,
}

/// One phase of an [`ActuatedProgramme`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ActuatedPhase {
    /// Seconds, as written: the length of a phase without bounds, and where
    /// a scenario's clock starts in the programme.
    pub duration: f64,
    /// Shortest and longest length, seconds, of a phase that detected
    /// traffic extends; `None` for one of fixed length.
    pub bounds: Option<(f64, f64)>,
    /// Its detectors: (lane, metres along the lane's centre line), one on
    /// each lane whose every link is green in this phase (as SUMO chooses
    /// them), `detector-gap` (default [`DETECTOR_GAP_S`]) at the lane's
    /// speed limit before its stop line.
    pub detectors: Vec<(usize, f64)>,
}

/// An [`ActuatedProgramme`] as one scenario runs it: durations scaled by
/// `city.lights.cycle_scale`, its clock shifted by the scenario's phase,
/// and its lights as indices into the scenario's [`LightPlan`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ActuatedRun {
    pub offset: f64,
    /// Seconds, as [`ActuatedProgramme::max_gap`] (not scaled).
    pub max_gap: f64,
    pub phases: Vec<ActuatedPhase>,
    /// Each light's index in the plan and its colour in each phase.
    pub lights: Vec<(usize, Vec<Colour>)>,
}

impl ActuatedRun {
    /// `programme` as one scenario runs it: its lights as indices into
    /// `plan`, its durations scaled by `scale`, its clock shifted as its
    /// junction's (`offsets`, by intersection; none: 0). `None` if `plan`
    /// has none of its lights.
    pub fn new(programme: &ActuatedProgramme, plan: &LightPlan, offsets: &[f64], scale: f64) -> Option<ActuatedRun> {
        let lights: Vec<(usize, Vec<Colour>)> = programme
            .lights
            .iter()
            .filter_map(|(k, approach, signal, variant, colours)| {
                Some((plan.index(*k, *approach, *signal, *variant)?, colours.clone()))
            })
            .collect();
        let &(first, ..) = programme.lights.first()?;
        let phases = programme
            .phases
            .iter()
            .map(|p| ActuatedPhase {
                duration: p.duration * scale,
                bounds: p.bounds.map(|(lo, hi)| (lo * scale, hi * scale)),
                detectors: p.detectors.clone(),
            })
            .collect();
        (!lights.is_empty()).then(|| ActuatedRun {
            offset: programme.offset + offsets.get(first).copied().unwrap_or(0.0),
            max_gap: programme.max_gap,
            phases,
            lights,
        })
    }
}

/// A light's state at one moment.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LightState {
    pub colour: Colour,
    /// Seconds since the colour last changed. Lights run before the scenario
    /// starts, so this can exceed the scenario time.
    pub since_change: f64,
}

impl Light {
    /// Colour at scenario time `t` (seconds).
    pub fn state_at(&self, t: f64) -> LightState {
        let period: f64 = self.schedule.iter().map(|s| s.duration).sum();
        let mut local = crate::remainder::rem_euclid(t + self.offset, period);
        // Merge runs of one colour (a wrap from the last step to the first).
        for (i, step) in self.schedule.iter().enumerate() {
            if local < step.duration {
                let mut since = local;
                // Earlier steps of the same colour count too.
                let mut j = i;
                loop {
                    j = j.checked_sub(1).unwrap_or(self.schedule.len() - 1);
                    if j == i || self.schedule[j].colour != step.colour {
                        break;
                    }
                    since += self.schedule[j].duration;
                }
                return LightState { colour: step.colour, since_change: since };
            }
            local -= step.duration;
        }
        let last = self.schedule.last().expect("schedules are not empty");
        LightState { colour: last.colour, since_change: 0.0 }
    }
}

/// The stages of the original's cycle, in seconds: (axis, signal, green, yellow).
/// Axis `EW` covers approaches E and W, `NS` covers N and S.
pub const DEFAULT_CYCLE: [(&str, Signal, f64, f64); 4] = [
    ("EW", Signal::Straight, 15.0, 4.0),
    ("NS", Signal::Left, 7.0, 4.0),
    ("NS", Signal::Straight, 15.0, 4.0),
    ("EW", Signal::Left, 7.0, 4.0),
];

/// Every light of the map for one scenario.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LightPlan {
    pub lights: Vec<Light>,
    /// Programmes whose phases detected traffic extends
    /// (`city.lights.actuated`): their lights' schedules are only where
    /// their clocks start; the simulation runs them.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub actuated: Vec<ActuatedRun>,
}

impl super::CityMap {
    /// The lights of one scenario on this map: the cycle at every
    /// signalised junction, an imported network's programmes where it has
    /// them, every duration scaled by `scale` (not a programme's `offset`)
    /// and each junction's clock shifted by its `offsets` entry (seconds,
    /// by intersection); with `actuated`, the network's traffic-actuated
    /// programmes run as such. The lights of movements on schedules of
    /// their own (variants) follow the cycle's lights, in the map's order.
    pub fn light_plan(&self, scale: f64, offsets: &[f64], actuated: bool) -> LightPlan {
        let mut plan = LightPlan::cycle(self.signalised(), scale, offsets);
        for programmed in &self.programmed {
            let light = Light {
                offset: programmed.offset + offsets.get(programmed.intersection).copied().unwrap_or(0.0),
                schedule: programmed
                    .schedule
                    .iter()
                    .map(|s| ScheduleStep { colour: s.colour, duration: s.duration * scale })
                    .collect(),
                ..programmed.clone()
            };
            match programmed.variant {
                0 => {
                    let at = plan.index(light.intersection, light.approach, light.signal, 0);
                    if let Some(index) = at {
                        plan.lights[index] = light;
                    }
                }
                _ => plan.lights.push(light),
            }
        }
        if actuated {
            plan.actuated = self.actuated.iter().filter_map(|p| ActuatedRun::new(p, &plan, offsets, scale)).collect();
        }
        plan
    }
}

/// Approaches in the order lights are listed.
pub const APPROACHES: [char; 4] = ['N', 'E', 'S', 'W'];

/// Lights of one intersection: a straight and a left signal per approach.
pub const LIGHTS_PER_INTERSECTION: usize = 2 * APPROACHES.len();

/// Where a light stands among its intersection's
/// [`LIGHTS_PER_INTERSECTION`]: by approach (N, E, S, W), then Straight
/// before Left. A plan lists its signalised intersections' lights in turn
/// (`CityMap::light_index`).
pub fn light_offset(approach: char, signal: Signal) -> usize {
    let a = APPROACHES.iter().position(|&c| c == approach).expect("approach is N, E, S or W");
    a * 2 + if signal == Signal::Left { 1 } else { 0 }
}

/// The light at `index` of a plan: (signalised intersection's place among
/// the signalised ones, approach, signal).
pub fn light_at(index: usize) -> (usize, char, Signal) {
    let signal = if index % 2 == 1 { Signal::Left } else { Signal::Straight };
    (index / LIGHTS_PER_INTERSECTION, APPROACHES[(index % LIGHTS_PER_INTERSECTION) / 2], signal)
}

impl LightPlan {
    /// The original cycle at the `signalised` intersections (indices,
    /// ascending) with every duration multiplied by `scale`, each
    /// intersection shifted by its `offsets` entry (seconds, by
    /// intersection index).
    pub fn cycle(signalised: &[usize], scale: f64, offsets: &[f64]) -> LightPlan {
        let mut lights = Vec::new();
        for &intersection in signalised {
            for approach in APPROACHES {
                let axis = if approach == 'E' || approach == 'W' { "EW" } else { "NS" };
                for signal in [Signal::Straight, Signal::Left] {
                    // Walk the cycle: green and yellow in this light's stage, red elsewhere.
                    let mut schedule: Vec<ScheduleStep> = Vec::new();
                    for &(stage_axis, stage_signal, green, yellow) in &DEFAULT_CYCLE {
                        let mine = stage_axis == axis && stage_signal == signal;
                        let steps = if mine {
                            vec![(Colour::Green, green), (Colour::Yellow, yellow)]
                        } else {
                            vec![(Colour::Red, green + yellow)]
                        };
                        for (colour, d) in steps {
                            ScheduleStep::extend(&mut schedule, colour, d * scale);
                        }
                    }
                    let offset = offsets.get(intersection).copied().unwrap_or(0.0);
                    lights.push(Light { intersection, approach, signal, variant: 0, offset, schedule });
                }
            }
        }
        LightPlan { lights, actuated: Vec::new() }
    }

    /// Index of the light for (intersection, approach, signal, variant),
    /// if the plan has it.
    pub fn index(&self, intersection: usize, approach: char, signal: Signal, variant: u8) -> Option<usize> {
        self.lights.iter().position(|l| {
            l.intersection == intersection && l.approach == approach && l.signal == signal && l.variant == variant
        })
    }

    /// States of every light at time `t`.
    pub fn states_at(&self, t: f64) -> Vec<LightState> {
        self.lights.iter().map(|l| l.state_at(t)).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_cycle_runs_the_original_phases() {
        let plan = LightPlan::cycle(&[0, 1, 2, 3], 1.0, &[0.0; 4]);
        assert_eq!(plan.lights.len(), 32);
        let ew = &plan.lights[plan.index(0, 'W', Signal::Straight, 0).unwrap()];
        assert_eq!(ew.state_at(0.0).colour, Colour::Green);
        assert_eq!(ew.state_at(15.5).colour, Colour::Yellow);
        assert_eq!(ew.state_at(19.5).colour, Colour::Red);
        assert!((ew.state_at(30.0).since_change - 11.0).abs() < 1e-9);
        assert_eq!(ew.state_at(60.1).colour, Colour::Green);
        let ns_left = &plan.lights[plan.index(2, 'N', Signal::Left, 0).unwrap()];
        assert_eq!(ns_left.state_at(20.0).colour, Colour::Green);
        assert_eq!(ns_left.state_at(27.0).colour, Colour::Yellow);
        let ew_left = &plan.lights[plan.index(1, 'E', Signal::Left, 0).unwrap()];
        assert_eq!(ew_left.state_at(50.0).colour, Colour::Green);
        // Never two conflicting greens: EW straight and NS straight.
        for k in 0..600 {
            let t = k as f64 * 0.1;
            let a = plan.lights[plan.index(0, 'E', Signal::Straight, 0).unwrap()].state_at(t).colour;
            let b = plan.lights[plan.index(0, 'N', Signal::Straight, 0).unwrap()].state_at(t).colour;
            assert!(!(a != Colour::Red && b != Colour::Red), "t={t}");
        }
    }

    #[test]
    fn scale_and_offset_shift_the_schedule() {
        let plan = LightPlan::cycle(&[0, 1, 2, 3], 0.5, &[0.0, 5.0, 0.0, 0.0]);
        let a = &plan.lights[plan.index(0, 'W', Signal::Straight, 0).unwrap()];
        assert_eq!(a.state_at(7.0).colour, Colour::Green);
        assert_eq!(a.state_at(8.0).colour, Colour::Yellow);
        let b = &plan.lights[plan.index(1, 'W', Signal::Straight, 0).unwrap()];
        assert_eq!(b.state_at(3.0).colour, Colour::Yellow);
    }
}
