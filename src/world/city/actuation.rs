//! Traffic-actuated programmes (SUMO's `type="actuated"`, time-gap based):
//! a phase with bounds lasts at least its shortest length, and after that
//! goes on while cars keep passing its detectors no more than the
//! programme's `max-gap` apart ([`MAX_GAP_S`] by default), up to its
//! longest; a phase without bounds lasts its written length. A car is over
//! a detector while the detector lies within its length (on either lane
//! while it changes lanes). At the start every detector counts as just
//! passed: the lights ran before the scenario, with traffic it does not
//! know, so a phase already past its shortest gets one gap of grace
//! rather than ending at once. The programme's lights show each phase's colours, so the
//! cars' positions now decide when a light changes: a car can hold a green
//! for those behind it, or end one early by its absence.

use crate::map::signals::{ActuatedRun, Colour, LightState};

/// Slack on phase ends, seconds: steps of a frame add up to its time only
/// within rounding.
const EPS: f64 = 1e-9;

/// Every actuated programme of one scenario, as it runs.
pub(super) struct Actuation<'a> {
    programmes: Vec<Programme<'a>>,
    /// Per plan light: (programme, its place among the programme's lights).
    of_light: Vec<Option<(usize, usize)>>,
    /// Per lane: (programme, phase, detector, metres along the lane).
    on_lane: Vec<Vec<(usize, usize, usize, f64)>>,
    /// Time of the last [`Actuation::advance`], seconds.
    now: f64,
}

/// One programme as it runs.
struct Programme<'a> {
    run: &'a ActuatedRun,
    phase: usize,
    /// When the current phase began, seconds.
    started: f64,
    /// Per phase and detector, when a car was last over it (seconds).
    last_seen: Vec<Vec<f64>>,
    /// Per light, its colour and when it took it, now and before the last advance.
    shown: Vec<(Colour, f64)>,
    before: Vec<(Colour, f64)>,
}

impl<'a> Actuation<'a> {
    /// The programmes `runs` at time 0: each in the phase its clock
    /// starts in (written lengths), every light's time since its change
    /// that of `initial` (its plan light at time 0), for a plan of
    /// `lights` lights on a map of `lanes` lanes.
    pub(super) fn new(
        runs: &'a [ActuatedRun],
        lights: usize,
        lanes: usize,
        initial: impl Fn(usize) -> LightState,
    ) -> Actuation<'a> {
        let mut of_light = vec![None; if runs.is_empty() { 0 } else { lights }];
        let mut on_lane = vec![Vec::new(); if runs.is_empty() { 0 } else { lanes }];
        let mut programmes = Vec::with_capacity(runs.len());
        for (p, run) in runs.iter().enumerate() {
            let period: f64 = run.phases.iter().map(|ph| ph.duration).sum();
            let mut clock = run.offset.rem_euclid(period);
            let mut phase = 0;
            while phase + 1 < run.phases.len() && clock >= run.phases[phase].duration {
                clock -= run.phases[phase].duration;
                phase += 1;
            }
            for (k, ph) in run.phases.iter().enumerate() {
                for (d, &(lane, at)) in ph.detectors.iter().enumerate() {
                    on_lane[lane].push((p, k, d, at));
                }
            }
            let mut shown = Vec::with_capacity(run.lights.len());
            for (j, (light, colours)) in run.lights.iter().enumerate() {
                of_light[*light] = Some((p, j));
                let state = initial(*light);
                let colour = colours[phase];
                shown.push((colour, if state.colour == colour { -state.since_change } else { 0.0 }));
            }
            programmes.push(Programme {
                run,
                phase,
                started: -clock,
                last_seen: run.phases.iter().map(|ph| vec![0.0; ph.detectors.len()]).collect(),
                before: shown.clone(),
                shown,
            });
        }
        Actuation { programmes, of_light, on_lane, now: f64::NEG_INFINITY }
    }

    /// Light `index`'s state at `t`: now, or before the last advance for
    /// an earlier `t` (a trigger that compares a step with the one before).
    pub(super) fn state(&self, index: usize, t: f64) -> Option<LightState> {
        let (p, j) = (*self.of_light.get(index)?)?;
        let programme = &self.programmes[p];
        let (colour, since) = if t + EPS >= self.now { programme.shown[j] } else { programme.before[j] };
        Some(LightState { colour, since_change: t - since })
    }

    /// Whether [`Actuation::advance`] has anything to run.
    pub(super) fn is_empty(&self) -> bool {
        self.programmes.is_empty()
    }

    /// Brings every programme to time `t`: notes the detectors cars are
    /// over (`cars`: a lane, a car's centre in metres along it and the
    /// car's length), then ends each programme's phase if it is over (one
    /// a call: a phase lasts at least a step). A second call at the same
    /// time does nothing.
    pub(super) fn advance(&mut self, t: f64, cars: impl Iterator<Item = (usize, f64, f64)>) {
        if self.programmes.is_empty() || t <= self.now + EPS {
            return;
        }
        for (lane, along, length) in cars {
            for &(p, k, d, at) in &self.on_lane[lane] {
                if (along - at).abs() <= length / 2.0 {
                    self.programmes[p].last_seen[k][d] = t;
                }
            }
        }
        for programme in &mut self.programmes {
            programme.before.clone_from(&programme.shown);
            // One phase ends per advance at most: a phase lasts at least a
            // step, as in SUMO. (Phases shorter than a step would otherwise
            // end over and over without time moving on: every shortest
            // length 0, or a cycle scaled to nothing.)
            if let Some(end) = programme.phase_end(t) {
                // A phase kept past its end by the rule above ends now, in
                // this step: the next one starts here, not in the past.
                let end = if end <= self.now { t } else { end };
                programme.phase = (programme.phase + 1) % programme.run.phases.len();
                programme.started = end;
                for (shown, (_, colours)) in programme.shown.iter_mut().zip(&programme.run.lights) {
                    let colour = colours[programme.phase];
                    if shown.0 != colour {
                        *shown = (colour, end);
                    }
                }
            }
        }
        self.now = t;
    }
}

impl Programme<'_> {
    /// When the current phase ends, if it has by time `t`: at its written
    /// length without bounds; with bounds, at the longest, or now once it
    /// has lasted the shortest and no car has been over its detectors for
    /// more than the programme's `max_gap`.
    fn phase_end(&self, t: f64) -> Option<f64> {
        let phase = &self.run.phases[self.phase];
        let lasted = t - self.started;
        match phase.bounds {
            None => (lasted + EPS >= phase.duration).then_some(self.started + phase.duration),
            Some((_, longest)) if lasted + EPS >= longest => Some(self.started + longest),
            Some((shortest, _)) => {
                let gap = self.last_seen[self.phase].iter().map(|&seen| t - seen).fold(f64::INFINITY, f64::min);
                (lasted + EPS >= shortest && gap > self.run.max_gap).then_some(t)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::signals::ActuatedPhase;

    /// Two phases: green for the light, extendable between 5 and 20 s by a
    /// detector on lane 0 at 10 m, then 4 s of red.
    fn run() -> ActuatedRun {
        ActuatedRun {
            offset: 0.0,
            max_gap: 3.0,
            phases: vec![
                ActuatedPhase { duration: 12.0, bounds: Some((5.0, 20.0)), detectors: vec![(0, 10.0)] },
                ActuatedPhase { duration: 4.0, bounds: None, detectors: vec![] },
            ],
            lights: vec![(0, vec![Colour::Green, Colour::Red])],
        }
    }

    /// Runs `run` for `seconds` in steps of 0.05 s with a 4 m car on lane
    /// 0 at `position(t)` metres (none where `None`); the times the light
    /// turned red.
    fn reds(run: &ActuatedRun, seconds: f64, position: impl Fn(f64) -> Option<f64>) -> Vec<f64> {
        let state0 = LightState { colour: Colour::Green, since_change: 0.0 };
        let mut a = Actuation::new(std::slice::from_ref(run), 1, 1, |_| state0);
        let mut turned = Vec::new();
        let mut last = Colour::Green;
        for k in 0..=(seconds / 0.05).round() as usize {
            let t = k as f64 * 0.05;
            a.advance(t, position(t).map(|s| (0, s, 4.0)).into_iter());
            let state = a.state(0, t).unwrap();
            if state.colour == Colour::Red && last != Colour::Red {
                turned.push(t - state.since_change);
            }
            last = state.colour;
        }
        turned
    }

    #[test]
    fn without_traffic_a_phase_ends_at_its_shortest() {
        let turned = reds(&run(), 30.0, |_| None);
        // Green 0-5, red 5-9, green 9-14, red 14-18, ...
        assert_eq!(turned.len(), 3, "{turned:?}");
        for (got, want) in turned.iter().zip([5.0, 14.0, 23.0]) {
            assert!((got - want).abs() < 0.06, "{turned:?}");
        }
    }

    #[test]
    fn cars_closer_than_the_gap_extend_it_up_to_the_longest() {
        // A car over the detector every 2 s (gap under 3 s) for ever: the
        // phase lasts its longest, 20 s.
        let turned = reds(&run(), 30.0, |t| ((t % 2.0) < 0.3).then_some(10.0));
        assert!((turned[0] - 20.0).abs() < 0.06, "{turned:?}");
    }

    #[test]
    fn one_car_holds_the_green_for_the_gap_after_it_passed() {
        // One car passes the detector from 4.0 to 4.4 s (moving at 10 m/s
        // over 4 m of car): the phase ends 3 s after it left, past its
        // shortest 5 s.
        let turned = reds(&run(), 12.0, |t| (4.0..=4.4).contains(&t).then_some(10.0 + (t - 4.2) * 10.0));
        assert!((turned[0] - 7.45).abs() < 0.06, "{turned:?}");
        // And a car that never reaches the detector changes nothing.
        let far = reds(&run(), 12.0, |_| Some(30.0));
        assert!((far[0] - 5.0).abs() < 0.06, "{far:?}");
    }

    #[test]
    fn a_phase_lasts_at_least_a_step_even_when_its_shortest_is_zero() {
        // Every phase may end at once (minDur 0, no traffic): before, the
        // programme went round its phases without end at the first gap.
        // Each phase now lasts one step of 0.05 s, so 2 s of steps show 20
        // reds (the green phase and the red one take turns). Run on a
        // thread of its own, so that a loop that never ends fails the test.
        let zero = ActuatedRun {
            phases: vec![
                ActuatedPhase { duration: 12.0, bounds: Some((0.0, 20.0)), detectors: vec![(0, 10.0)] },
                ActuatedPhase { duration: 4.0, bounds: Some((0.0, 6.0)), detectors: vec![(0, 10.0)] },
            ],
            ..run()
        };
        let (done, finished) = std::sync::mpsc::channel();
        std::thread::spawn(move || done.send(reds(&zero, 5.0, |_| None)).unwrap());
        let turned = finished.recv_timeout(std::time::Duration::from_secs(20)).expect("5 s of steps end");
        // The first gap ends the green 3 s in (every detector counts as just
        // passed at the start); from then on every other step is red.
        assert!((turned[0] - 3.05).abs() < 0.06, "{turned:?}");
        assert_eq!(turned.len(), 20, "{turned:?}");
        for pair in turned.windows(2) {
            assert!((pair[1] - pair[0] - 0.1).abs() < 1e-6, "{turned:?}");
        }
    }

    #[test]
    fn phases_shorter_than_a_step_start_in_the_step_that_shows_them() {
        // Fixed phases of 0.01 s (a cycle scaled to almost nothing): each
        // lasts a step, and a light's time since its change never reaches
        // back before the step that showed the change (it grew by most of
        // a step each step before).
        let short = ActuatedRun {
            phases: vec![
                ActuatedPhase { duration: 0.01, bounds: None, detectors: vec![] },
                ActuatedPhase { duration: 0.01, bounds: None, detectors: vec![] },
            ],
            ..run()
        };
        let state0 = LightState { colour: Colour::Green, since_change: 0.0 };
        let mut a = Actuation::new(std::slice::from_ref(&short), 1, 1, |_| state0);
        let mut changes = 0;
        let mut last = Colour::Green;
        for k in 0..=100 {
            let t = k as f64 * 0.05;
            a.advance(t, std::iter::empty());
            let state = a.state(0, t).unwrap();
            assert!(state.since_change <= 0.05 + 1e-9, "at {t} s: {state:?}");
            changes += usize::from(state.colour != last);
            last = state.colour;
        }
        assert_eq!(changes, 100, "a change every step");
    }

    #[test]
    fn the_clock_starts_where_the_offset_puts_it() {
        // 14 s into the written cycle of 16 s: in the red phase, 2 s left.
        let late = ActuatedRun { offset: 14.0, ..run() };
        let mut a = Actuation::new(std::slice::from_ref(&late), 1, 1, |_| LightState {
            colour: Colour::Red,
            since_change: 2.0,
        });
        a.advance(0.0, std::iter::empty());
        assert_eq!(a.state(0, 0.0).unwrap(), LightState { colour: Colour::Red, since_change: 2.0 });
        a.advance(2.05, std::iter::empty());
        assert_eq!(a.state(0, 2.05).unwrap().colour, Colour::Green);
        assert!((a.state(0, 2.05).unwrap().since_change - 0.05).abs() < 1e-9);
        // The step before, as a trigger compares it.
        assert_eq!(a.state(0, 2.0).unwrap().colour, Colour::Red);
    }
}
