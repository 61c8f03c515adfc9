//! Interventions: "at this moment, or when this happens, do that" — the
//! do-operator of a counterfactual. Plain data the city world applies while
//! it simulates; every one that fires is logged in `events.csv` as kind
//! `intervention`. Car and light fields are indices into the scenario's cars
//! (id order) and light plan.

use super::confounders::ConfounderName;
use crate::map::signals::{Colour, ScheduleStep};
use crate::map::Action;

/// Kinds of random intervention `counterfactual --sweep` draws from, as
/// `sweep.json` names them (`kinds`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SweepKind {
    /// Stop a random car for 2-6 s.
    Stop,
    /// Set a random car's desired speed to 30-60 % of the spec's.
    SetDesiredSpeed,
    /// Make a random car run red lights.
    RunRedLight,
    /// Remove a random car.
    Remove,
}

impl SweepKind {
    pub const ALL: [SweepKind; 4] =
        [SweepKind::Stop, SweepKind::SetDesiredSpeed, SweepKind::RunRedLight, SweepKind::Remove];

    /// The name `sweep.json` and `--kinds` use.
    pub fn name(self) -> &'static str {
        match self {
            SweepKind::Stop => "stop",
            SweepKind::SetDesiredSpeed => "set_desired_speed",
            SweepKind::RunRedLight => "run_red_light",
            SweepKind::Remove => "remove",
        }
    }

    pub fn from_name(name: &str) -> Option<SweepKind> {
        SweepKind::ALL.into_iter().find(|k| k.name() == name)
    }
}

/// The one intervention `counterfactual --sweep` draws for a scenario, from
/// a stream derived from the scenario's own key and the sweep's kinds (in
/// the order given): the same scenario and kinds always draw the same, so
/// a rerun and `validate` can tell a pair's recorded intervention from an
/// edited one.
#[derive(Debug, Clone, PartialEq)]
pub struct SweepDraw {
    pub kind: SweepKind,
    /// The car (index into the plan's cars).
    pub car: usize,
    /// The frame it fires on and its time, seconds.
    pub frame: u64,
    pub at: f64,
    /// `Stop`: how long the car stays stopped, seconds.
    pub seconds: Option<f64>,
    /// `SetDesiredSpeed`: the new desired speed, m/s.
    pub speed: Option<f64>,
    /// What the counterfactual run is given.
    pub intervention: Intervention,
}

impl SweepDraw {
    /// The draw for `plan` from `kinds` (at least one).
    pub fn of(plan: &super::ScenarioPlan, kinds: &[SweepKind]) -> SweepDraw {
        use rand::{RngExt, SeedableRng};
        use sha2::Digest;
        let mut seed = sha2::Sha256::new();
        seed.update(b"causalcity/sweep/v1\0");
        seed.update(plan.stream_key.as_bytes());
        let mut rng = rand_chacha::ChaCha8Rng::from_seed(seed.finalize().into());
        let kind = kinds[rng.random_range(0..kinds.len())];
        let car = rng.random_range(0..plan.cars.len());
        let duration = plan.frames.saturating_sub(1) as f64 * plan.frame_interval;
        // On a frame, in the first half of the scenario after a moment to get going.
        let frame = ((rng.random_range(0.1..0.5) * duration) / plan.frame_interval).round();
        let at = frame * plan.frame_interval;
        let (effect, seconds, speed) = match kind {
            SweepKind::Stop => {
                let seconds = (rng.random_range(2.0..6.0f64) * 10.0).round() / 10.0;
                (Effect::Stop { car, seconds }, Some(seconds), None)
            }
            SweepKind::SetDesiredSpeed => {
                let base = plan.world.city().and_then(|c| c.agency[car].desired_speeds.first().copied()).unwrap_or(1.8);
                let speed = (base * rng.random_range(0.3..0.6) * 100.0).round() / 100.0;
                (Effect::SetDesiredSpeed { car, speed }, None, Some(speed))
            }
            SweepKind::RunRedLight => (Effect::RunRedLights { car }, None, None),
            SweepKind::Remove => (Effect::Remove { car }, None, None),
        };
        let what = effect.describe(|c| plan.cars[c].name.clone(), |l| format!("light {l}"));
        let intervention =
            Intervention { trigger: Trigger::At(at), effect, label: format!("{what} (at frame {frame})") };
        SweepDraw { kind, car, frame: frame as u64, at, seconds, speed, intervention }
    }
}

/// When an intervention fires (once, at the first step its condition holds).
#[derive(Debug, Clone, PartialEq)]
pub enum Trigger {
    /// At scenario time (seconds; a frame is `frame x frame_interval`).
    At(f64),
    /// When the car's front reaches the stop line of the intersection (or
    /// it is already inside it).
    CarReaches { car: usize, intersection: usize },
    /// When the light changes to the colour.
    LightTurns { light: usize, colour: Colour },
}

/// What an intervention does.
#[derive(Debug, Clone, PartialEq)]
pub enum Effect {
    /// The car brakes (up to its hard braking limit) to a stop and stays
    /// stopped for `seconds`, then drives on.
    Stop { car: usize, seconds: f64 },
    /// The car drives through every red and yellow light from now on.
    RunRedLights { car: usize },
    /// The car's desired speed is `speed` m/s from now on.
    SetDesiredSpeed { car: usize, speed: f64 },
    /// The car leaves the scene: it is parked far off the map (speed 0, never
    /// in view) and no other car sees it.
    Remove { car: usize },
    /// The light shows `colour` for `seconds`, then its plan resumes.
    SetLight { light: usize, colour: Colour, seconds: f64 },
    /// The light runs a new plan (schedule and clock offset) from now on.
    SetLightPlan { light: usize, offset: f64, schedule: Vec<ScheduleStep> },
    /// The car's remaining actions are replaced, re-planning its route from
    /// where it is (at the first moment it is on a lane, not mid-turn or
    /// mid-merge). Merge distances are metres along the lane, as in scenario
    /// files. If the new actions cannot be driven from there (a turn the lane
    /// does not allow), the car keeps its old ones and `events.csv` says so.
    ReplaceActions { car: usize, actions: Vec<Action>, merge_distances: Vec<f64> },
    /// A confounder takes a new value from now on: the look of the scene
    /// and every driver change as the causal model says (relative to the
    /// conditions before; red-light runners stay as drawn).
    SetConfounder { confounder: ConfounderName, value: f64 },
}

/// One intervention of a scenario.
#[derive(Debug, Clone, PartialEq)]
pub struct Intervention {
    pub trigger: Trigger,
    pub effect: Effect,
    /// How `events.csv` describes it, e.g. `stop Car_2 for 4 s (at 6 s)`.
    pub label: String,
}

impl Effect {
    /// What the effect does, in words (for events.csv), given how to name a
    /// car and a light by index.
    pub fn describe(&self, car: impl Fn(usize) -> String, light: impl Fn(usize) -> String) -> String {
        match self {
            Effect::Stop { car: c, seconds } => format!("stop {} for {seconds} s", car(*c)),
            Effect::RunRedLights { car: c } => format!("{} runs red lights", car(*c)),
            Effect::SetDesiredSpeed { car: c, speed } => format!("{} desired speed {speed} m/s", car(*c)),
            Effect::Remove { car: c } => format!("remove {}", car(*c)),
            Effect::SetLight { light: l, colour, seconds } => {
                format!("{} {} for {seconds} s", light(*l), colour.name())
            }
            Effect::SetLightPlan { light: l, schedule, .. } => {
                let period: f64 = schedule.iter().map(|s| s.duration).sum();
                format!("{} runs a new {period} s plan", light(*l))
            }
            Effect::ReplaceActions { car: c, actions, .. } => {
                let names: Vec<&str> = actions.iter().map(|a| a.name()).collect();
                let names = if names.is_empty() { "no further actions".to_string() } else { names.join(", ") };
                format!("{} drives {names} from now on", car(*c))
            }
            Effect::SetConfounder { confounder, value } => format!("{} becomes {value}", confounder.name()),
        }
    }

    /// The car the effect acts on, if any.
    pub fn car(&self) -> Option<usize> {
        match self {
            Effect::Stop { car, .. }
            | Effect::RunRedLights { car }
            | Effect::SetDesiredSpeed { car, .. }
            | Effect::Remove { car }
            | Effect::ReplaceActions { car, .. } => Some(*car),
            Effect::SetLight { .. } | Effect::SetLightPlan { .. } | Effect::SetConfounder { .. } => None,
        }
    }

    /// The light the effect acts on, if any (index in the light plan).
    pub fn light(&self) -> Option<usize> {
        match self {
            Effect::SetLight { light, .. } | Effect::SetLightPlan { light, .. } => Some(*light),
            _ => None,
        }
    }
}
