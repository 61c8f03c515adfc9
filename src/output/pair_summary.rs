//! `summary.json` of a counterfactual pair (`counterfactual`, `--sweep`):
//! the interventions, when the first fired, and the cars it moved.

use serde::Serialize;

/// One car's part in a counterfactual pair.
#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct CarDivergence {
    pub id: u32,
    pub name: String,
    /// Moved by the intervention at all: some frame of its poses.csv differs.
    pub affected: bool,
    pub max_divergence_m: f64,
    /// The first frame whose poses.csv row differs between the two runs.
    pub first_divergent_frame: Option<usize>,
}

/// A sweep's one intervention as data, for the counterfactual task: which
/// car, what, and when.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
pub struct InterventionRecord {
    /// The car's id (its index on every car axis) and name.
    pub car: u32,
    pub car_name: String,
    /// `stop`, `set_desired_speed`, `run_red_light` or `remove`, as a
    /// scenario file's `"do"` spells it.
    #[serde(rename = "do")]
    pub kind: String,
    /// When it fires, seconds, and the first frame that can show it.
    pub at_s: f64,
    pub frame: u64,
    /// `stop`: how long the car stays stopped, seconds.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub seconds: Option<f64>,
    /// `set_desired_speed`: the new desired speed, m/s.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub speed: Option<f64>,
}

impl InterventionRecord {
    /// Whether an intervention a summary says fired at `t` seconds is this
    /// one, due at `at_s`, in a run of frames `frame_interval` seconds
    /// apart: it fires at the first step at or after its time, so within
    /// half a frame of it.
    pub fn fired_at(&self, t: f64, frame_interval: f64) -> bool {
        (t - self.at_s).abs() <= frame_interval / 2.0
    }

    /// The record of `draw`, a sweep's intervention for `plan`, as
    /// `summary.json` holds it.
    pub fn of_draw(
        plan: &crate::plan::ScenarioPlan,
        draw: &crate::plan::interventions::SweepDraw,
    ) -> InterventionRecord {
        InterventionRecord {
            car: plan.cars[draw.car].id,
            car_name: plan.cars[draw.car].name.clone(),
            kind: draw.kind.name().to_string(),
            at_s: crate::output::number::logged_value(draw.at, 6),
            frame: draw.frame,
            seconds: draw.seconds,
            speed: draw.speed,
        }
    }

    /// In words, as a sentence says it: `stop car 3 (car03) at frame 40
    /// for 2.5 s`.
    pub fn describe(&self) -> String {
        let mut text = format!("{} car {} ({}) at frame {}", self.kind, self.car, self.car_name, self.frame);
        if let Some(seconds) = self.seconds {
            text.push_str(&format!(" for {seconds} s"));
        }
        if let Some(speed) = self.speed {
            text.push_str(&format!(" to {speed} m/s"));
        }
        text
    }
}

/// `summary.json` of a counterfactual pair.
#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct PairSummary {
    pub scenario: String,
    pub interventions: Vec<String>,
    /// A sweep's intervention as data (a scenario file's pairs have theirs
    /// in the file).
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub intervention: Option<InterventionRecord>,
    /// When the first intervention fired in the counterfactual (None if it never did).
    pub intervention_time_s: Option<f64>,
    /// The ground-truth effect set: names of the cars whose trajectory changed.
    pub affected: Vec<String>,
    pub cars: Vec<CarDivergence>,
}

impl std::fmt::Display for PairSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let affected = if self.affected.is_empty() { "none".to_string() } else { self.affected.join(", ") };
        // A file of `{"do": "none"}` intervenes on nothing: said so, not blank.
        let what =
            if self.interventions.is_empty() { "no intervention".to_string() } else { self.interventions.join("; ") };
        write!(
            f,
            "{}: {what} -> affected {} of {} cars: {affected}",
            self.scenario,
            self.affected.len(),
            self.cars.len()
        )
    }
}
