//! `city`: the city world's drivers, start, lights and confounders.

use super::*;

/// One driver's car-following parameters (the city world's drivers), as
/// the spec gives them and, in plans, after confounders have acted on them.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DriverParams {
    /// Desired time gap to the car ahead, seconds.
    pub time_headway: f64,
    /// Bumper-to-bumper gap kept when stopped, metres.
    pub min_gap: f64,
    /// Maximum acceleration, m/s^2.
    pub max_acceleration: f64,
    /// Comfortable deceleration, m/s^2 (IDM's b; used to decide whether a yellow can be stopped for).
    pub comfortable_deceleration: f64,
    /// Hard braking limit, m/s^2: the car can never brake harder.
    pub max_deceleration: f64,
    /// Seconds between decisions; the acceleration is held in between.
    pub reaction_time: f64,
    /// Relative standard deviation of perceived gaps.
    pub perception_noise: f64,
    /// Standard deviation of the car's sideways wander in its lane, metres.
    pub lateral_wander: f64,
    /// Lateral acceleration accepted in curves, m/s^2 (sets curve speeds).
    pub curve_acceleration: f64,
}

impl Default for DriverParams {
    fn default() -> Self {
        DriverParams {
            time_headway: 1.0,
            min_gap: 0.8,
            max_acceleration: 1.2,
            comfortable_deceleration: 1.5,
            max_deceleration: 6.0,
            reaction_time: 0.3,
            perception_noise: 0.04,
            lateral_wander: 0.03,
            curve_acceleration: 1.2,
        }
    }
}

/// A value fixed by the spec or drawn per scenario: a number,
/// `{"uniform": [low, high]}` or `{"choice": [a, b, ...]}` (nothing else in
/// the object).
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum Distribution {
    Fixed(f64),
    /// `{"uniform": [low, high]}`
    Uniform {
        uniform: [f64; 2],
    },
    /// `{"choice": [a, b, ...]}`, each equally likely.
    Choice {
        choice: Vec<f64>,
    },
}

/// The object form of a [`Distribution`], as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawDistribution {
    uniform: Option<[f64; 2]>,
    choice: Option<Vec<f64>>,
}

impl<'de> Deserialize<'de> for Distribution {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct Visit;
        impl<'de> serde::de::Visitor<'de> for Visit {
            type Value = Distribution;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a number, {\"uniform\": [low, high]} or {\"choice\": [a, b, ...]}")
            }
            fn visit_f64<E>(self, v: f64) -> Result<Distribution, E> {
                Ok(Distribution::Fixed(v))
            }
            fn visit_u64<E>(self, v: u64) -> Result<Distribution, E> {
                Ok(Distribution::Fixed(v as f64))
            }
            fn visit_i64<E>(self, v: i64) -> Result<Distribution, E> {
                Ok(Distribution::Fixed(v as f64))
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(self, map: A) -> Result<Distribution, A::Error> {
                let raw = RawDistribution::deserialize(serde::de::value::MapAccessDeserializer::new(map))?;
                match (raw.uniform, raw.choice) {
                    (Some(uniform), None) => Ok(Distribution::Uniform { uniform }),
                    (None, Some(choice)) => Ok(Distribution::Choice { choice }),
                    _ => Err(serde::de::Error::custom(
                        "give exactly one of {\"uniform\": [low, high]} or {\"choice\": [a, b, ...]}",
                    )),
                }
            }
        }
        deserializer.deserialize_any(Visit)
    }
}

impl Distribution {
    fn check(&self, field: &str, lo: f64, hi: f64) -> Result<(), SpecError> {
        let values: Vec<f64> = match self {
            Distribution::Fixed(v) => vec![*v],
            Distribution::Uniform { uniform } => {
                if uniform[0] > uniform[1] {
                    return Err(SpecError::new(field, format!("uniform range {uniform:?} has low above high")));
                }
                uniform.to_vec()
            }
            Distribution::Choice { choice } => {
                if choice.is_empty() {
                    return Err(SpecError::new(field, "choice list is empty"));
                }
                choice.clone()
            }
        };
        for v in values {
            if !(v.is_finite() && v >= lo && v <= hi) {
                return Err(SpecError::new(field, format!("{} is not allowed: use {lo} to {hi}", Shown(v))));
            }
        }
        Ok(())
    }

    /// The lowest value it can draw.
    pub fn lowest(&self) -> f64 {
        match self {
            Distribution::Fixed(v) => *v,
            Distribution::Uniform { uniform } => uniform[0],
            Distribution::Choice { choice } => choice.iter().copied().fold(f64::INFINITY, f64::min),
        }
    }

    /// The value at `u` in [0, 1) of its inverse cumulative distribution:
    /// the draw a uniform exogenous `u` stands for.
    pub fn quantile(&self, u: f64) -> f64 {
        match self {
            Distribution::Fixed(v) => *v,
            Distribution::Uniform { uniform } => uniform[0] + u * (uniform[1] - uniform[0]),
            Distribution::Choice { choice } => {
                choice[((u * choice.len() as f64) as usize).min(choice.len().saturating_sub(1))]
            }
        }
    }

    /// Draws a value.
    pub fn sample<R: rand::Rng + ?Sized>(&self, rng: &mut R) -> f64 {
        use rand::RngExt;
        match self {
            Distribution::Fixed(v) => *v,
            Distribution::Uniform { uniform } => {
                if uniform[0] == uniform[1] {
                    uniform[0]
                } else {
                    rng.random_range(uniform[0]..uniform[1])
                }
            }
            Distribution::Choice { choice } => choice[rng.random_range(0..choice.len())],
        }
    }
}

/// Confounders per scenario (the causal model is in `plan/confounders.rs`).
/// Rain, snow and the hour are exogenous: the spec gives their
/// distribution. Fog and wetness follow their structural equations unless
/// the spec gives them, which replaces the equation by the given value or
/// distribution (a do-intervention on that variable).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ConfounderSpec {
    /// Rain intensity 0..1.
    pub rain: Distribution,
    /// Fog density 0..1; absent: its equation (fog in the early hours).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fog: Option<Distribution>,
    /// Snowfall 0..1.
    pub snow: Distribution,
    /// Water on the road 0..1; absent: its equation (from rain and snow).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub wetness: Option<Distribution>,
    /// Time of day, hours 0..24.
    pub hour: Distribution,
}

impl Default for ConfounderSpec {
    fn default() -> Self {
        ConfounderSpec {
            rain: Distribution::Fixed(0.0),
            fog: None,
            snow: Distribution::Fixed(0.0),
            wetness: None,
            hour: Distribution::Fixed(12.0),
        }
    }
}

/// Replaces the schedule of one light.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightOverride {
    /// Intersection name, e.g. `AC`.
    pub intersection: String,
    /// Side the controlled traffic arrives from: `N`, `E`, `S`, `W`.
    pub approach: char,
    pub signal: Signal,
    /// Seconds added to the scenario clock.
    #[serde(default)]
    pub offset: f64,
    /// Repeating (colour, seconds) steps.
    pub schedule: Vec<ScheduleStep>,
}

/// Traffic light control: the original cycle scaled, offsets per
/// intersection (high level) and single-light schedules (low level).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LightsSpec {
    /// Multiplies every duration of the original 60 s cycle.
    pub cycle_scale: f64,
    /// Seconds added to the clock of each intersection, in the order AC, AD, BC, BD.
    pub offsets: Vec<f64>,
    pub overrides: Vec<LightOverride>,
    /// Where in its cycle each scenario starts. Absent: `random` in a
    /// dataset spec, `fixed` in a scenario file (one scenario written out
    /// by hand, timed by its author).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub phase: Option<LightPhase>,
    /// Run an imported network's traffic-actuated programmes as SUMO does:
    /// detected traffic extends a phase between its `minDur` and `maxDur`.
    /// Off: every phase lasts its written `duration`.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub actuated: bool,
}

/// Where each scenario's lights start in their cycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LightPhase {
    /// Each scenario draws one point of the cycle (uniform over one period),
    /// shared by every light, on top of `offsets`: the intersections keep
    /// their relative timing.
    Random,
    /// Each scenario draws a point of the cycle per intersection, on top of
    /// `offsets`.
    RandomPerIntersection,
    /// Every scenario starts the cycle at 0, shifted by `offsets` only.
    Fixed,
}

impl Default for LightsSpec {
    fn default() -> Self {
        LightsSpec { cycle_scale: 0.5, offsets: vec![0.0; 4], overrides: Vec::new(), phase: None, actuated: false }
    }
}

/// The car-following model city drivers use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DriverModel {
    /// The Intelligent Driver Model (Treiber, Hennecke and Helbing 2000).
    Idm,
    /// The Improved IDM (Treiber and Kesting 2013): the IDM without its
    /// widened gaps near the desired speed.
    Iidm,
}

/// How `gen` draws a city car's actions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ActionDrawing {
    /// As the original's `scenarioGenerator.py`: left, right or straight at
    /// random whatever lane the car will be in; the drivers change lanes
    /// for their turns, and a turn that cannot be prepared is skipped.
    Original,
    /// Only actions the lane the car is in allows, with merges where they
    /// fit (no lane changes needed).
    LaneValid,
}

/// Most a desired speed may be, m/s (72 km/h): the spec's mean, a scenario
/// file's per-leg speeds and an intervention's all stay within it, the
/// city being streets with signalised junctions (the original CausalCity's
/// cars keep to town speeds).
pub const MAX_DESIRED_SPEED_M_S: f64 = 20.0;

/// City-world settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CitySpec {
    /// Mean desired speed, m/s.
    pub desired_speed: f64,
    /// Each leg's desired speed is `desired_speed x (1 +- spread)`, uniform.
    pub desired_speed_spread: f64,
    /// Chance that a car is forced through red lights.
    pub red_light_runner_probability: f64,
    /// How `gen` draws each car's drive queue.
    pub action_drawing: ActionDrawing,
    /// The drivers' car-following model.
    pub driver_model: DriverModel,
    /// Base driver parameters, before confounders.
    pub driver: DriverParams,
    /// How `gen` starts cars: gaps, speeds, hard negatives.
    pub start: StartSpec,
    pub lights: LightsSpec,
    pub confounders: ConfounderSpec,
    /// Whether frames show the signal heads (the lights, a confounder of
    /// every car) or hide them.
    pub signal_heads: SignalHeads,
    /// The original's driving rules, or the cooperative ones. Written into
    /// a resolved spec only when not the original's, so existing specs keep
    /// their bytes.
    #[serde(skip_serializing_if = "DrivingRules::is_original")]
    pub rules: DrivingRules,
}

/// Which reading of the city's driving rules the drivers follow. The
/// original's is the default, so existing specs keep their bytes; the
/// cooperative one removes the ways in which the original's leaves cars
/// waiting for good, giving their turns up or meeting in a junction box
/// (docs/city.md#driving-rules).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DrivingRules {
    /// A driver who must change lanes waits at the last point of its lane
    /// for a gap to come by itself and gives the action up after 20 s;
    /// nobody lets it in, so beside a queue at a red light none comes. At a
    /// junction with lights a car behind that has claimed another movement
    /// from the same lane counts as in front of the cars ahead of it.
    #[default]
    Original,
    /// A driver waiting at the last point of its lane asks the car behind
    /// that point in the lane it wants to hold back, and that car does when
    /// it can still stop comfortably (SUMO's cooperative lane changing,
    /// MOBIL's politeness); its 20 s of patience run only while the lane it
    /// wants moves. A car still before the box counts as in front of no
    /// car of its lane, at every junction, and between its line and the
    /// box it still stops for a car crossing its path.
    Cooperative,
}

impl DrivingRules {
    /// Whether these are the original's rules (the default).
    pub fn is_original(&self) -> bool {
        *self == DrivingRules::Original
    }
}

/// Whether the frames show the traffic lights' signal heads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SignalHeads {
    /// Drawn at every approach in their current colour: a measured confounder.
    #[default]
    Visible,
    /// Not drawn: the lights act on the cars but no frame shows them (a
    /// hidden confounder).
    Hidden,
}

/// How `gen` starts the city's cars (hand-written scenario files start
/// every car at rest where the file puts it, as the original did).
///
/// A follower starts behind its leader on the leader's route, `follower_gap_m`
/// from bumper to bumper. A *hard negative* is a car with no leader (an
/// independent car, or the leader of a pair) that starts in the same way
/// right behind another car, with a first action different from that car's:
/// in the first frame it looks like a follower, and the two part ways at the
/// next intersection. Every car then starts at `speed_fraction` of its first
/// desired speed, or slower where what it sees ahead at the start (a car, a
/// stop line it must stop at, a curve) asks for less, by the same rule for
/// every car whatever its role.
///
/// With `platoon_cars`, the first frame is drawn blind to roles instead:
/// every car starts in a platoon of that many cars on the two lanes of one
/// direction of one road segment, each car in one of the two lanes drawn at
/// random and queued `follower_gap_m` behind the car ahead in its lane; the
/// leader-follower pairs are then drawn uniformly among the ordered (ahead,
/// behind) pairs of each platoon. Where a pair stands says nothing about
/// whether it is an edge: every pair of a platoon is one with the same
/// chance.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StartSpec {
    /// Bumper-to-bumper gap behind the car ahead, metres, for followers and
    /// hard negatives; never below `city.driver.min_gap`.
    pub follower_gap_m: Distribution,
    /// Share of cars without a leader that start as hard negatives, 0..1
    /// (without platoons only).
    pub hard_negative_share: f64,
    /// Cars per platoon, 2..=16, the last platoon of a scenario taking the
    /// rest; 0 (the default) for none.
    #[serde(skip_serializing_if = "is_zero_u32")]
    pub platoon_cars: u32,
    /// Starting speed as a share of the car's first desired speed, 0..1,
    /// before what it sees ahead limits it.
    pub speed_fraction: Distribution,
}

/// Most cars one platoon may hold: two lanes of the longest on-camera
/// segment hold about this many queued cars.
const MAX_PLATOON_CARS: u32 = 16;
/// Smallest `lights.cycle_scale`: the original's shortest phase (a 4 s
/// yellow) then lasts 0.04 s. At 1e-300 every light changed at every frame.
const MIN_CYCLE_SCALE: f64 = 0.01;
/// Shortest step of a light's override schedule, seconds (as short as the
/// shortest phase `MIN_CYCLE_SCALE` allows).
const MIN_PHASE_S: f64 = 0.04;
/// Most steps in one override schedule: every scenario.json holds a copy
/// of the spec (a million steps wrote 8.6 MB per scenario).
const MAX_SCHEDULE_STEPS: usize = 1000;

fn is_zero_u32(n: &u32) -> bool {
    *n == 0
}

impl Default for StartSpec {
    fn default() -> Self {
        StartSpec {
            follower_gap_m: Distribution::Uniform { uniform: [1.0, 6.0] },
            hard_negative_share: 0.0,
            platoon_cars: 0,
            speed_fraction: Distribution::Uniform { uniform: [0.5, 1.0] },
        }
    }
}

impl Default for CitySpec {
    fn default() -> Self {
        CitySpec {
            desired_speed: 1.8,
            desired_speed_spread: 0.25,
            red_light_runner_probability: 0.02,
            action_drawing: ActionDrawing::Original,
            driver_model: DriverModel::Iidm,
            driver: DriverParams::default(),
            start: StartSpec::default(),
            lights: LightsSpec::default(),
            confounders: ConfounderSpec::default(),
            signal_heads: SignalHeads::Visible,
            rules: DrivingRules::Original,
        }
    }
}

impl CitySpec {
    pub fn validate(&self) -> Result<(), SpecError> {
        self.validate_as(false)
    }

    /// [`CitySpec::validate`], of a spec given as input or (`recorded`)
    /// read back from a dataset an earlier version wrote: the light timing
    /// limits added since are then not applied.
    pub fn validate_as(&self, recorded: bool) -> Result<(), SpecError> {
        positive("city.desired_speed", self.desired_speed, MAX_DESIRED_SPEED_M_S, "m/s")?;
        unit_interval("city.desired_speed_spread", self.desired_speed_spread, 0.9)?;
        unit_interval("city.red_light_runner_probability", self.red_light_runner_probability, 1.0)?;
        let d = &self.driver;
        positive("city.driver.time_headway", d.time_headway, 10.0, "seconds")?;
        positive("city.driver.min_gap", d.min_gap, 20.0, "metres")?;
        positive("city.driver.max_acceleration", d.max_acceleration, 10.0, "m/s^2")?;
        positive("city.driver.comfortable_deceleration", d.comfortable_deceleration, 10.0, "m/s^2")?;
        positive("city.driver.max_deceleration", d.max_deceleration, 15.0, "m/s^2")?;
        if d.max_deceleration < d.comfortable_deceleration {
            return Err(SpecError::new(
                "city.driver.max_deceleration",
                format!(
                    "{} is below comfortable_deceleration {}: the hard limit must be the larger",
                    Shown(d.max_deceleration),
                    Shown(d.comfortable_deceleration)
                ),
            ));
        }
        positive("city.driver.reaction_time", d.reaction_time, 3.0, "seconds")?;
        unit_interval("city.driver.perception_noise", d.perception_noise, 1.0)?;
        unit_interval("city.driver.lateral_wander", d.lateral_wander, 0.5)?;
        positive("city.driver.curve_acceleration", d.curve_acceleration, 10.0, "m/s^2")?;
        let start = &self.start;
        if let Err(e) = start.follower_gap_m.check("city.start.follower_gap_m", d.min_gap, 200.0) {
            return Err(SpecError::new(
                e.field,
                format!(
                    "{} (bumper-to-bumper metres: a driver accepts no gap below city.driver.min_gap = {})",
                    e.message, d.min_gap
                ),
            ));
        }
        unit_interval("city.start.hard_negative_share", start.hard_negative_share, 1.0)?;
        if start.platoon_cars != 0 && !(2..=MAX_PLATOON_CARS).contains(&start.platoon_cars) {
            return Err(SpecError::new(
                "city.start.platoon_cars",
                format!(
                    "{} is not allowed: give 2 to {MAX_PLATOON_CARS} cars per platoon, or 0 for none",
                    start.platoon_cars
                ),
            ));
        }
        if start.platoon_cars != 0 && start.hard_negative_share != 0.0 {
            return Err(SpecError::new(
                "city.start.hard_negative_share",
                format!(
                    "{} is not allowed with city.start.platoon_cars = {}: in a platoon every car already starts behind another, so remove hard_negative_share (or set it to 0)",
                    start.hard_negative_share, start.platoon_cars
                ),
            ));
        }
        start.speed_fraction.check("city.start.speed_fraction", 0.0, 1.0)?;
        let scale = self.lights.cycle_scale;
        let lowest = if recorded { f64::MIN_POSITIVE } else { MIN_CYCLE_SCALE };
        if !(scale.is_finite() && (lowest..=10.0).contains(&scale)) {
            return Err(SpecError::new(
                "city.lights.cycle_scale",
                format!(
                    "{} is not allowed: a factor from {MIN_CYCLE_SCALE} to 10 (the original's 4 s yellow then lasts \
                     0.04 s; below, every light changes at every frame)",
                    Shown(scale)
                ),
            ));
        }
        let max = crate::map::sumo::MAX_LIGHT_OFFSET_S;
        if self.lights.offsets.len() != 4 || self.lights.offsets.iter().any(|o| !(o.is_finite() && o.abs() <= max)) {
            return Err(SpecError::new(
                "city.lights.offsets",
                format!(
                    "{:?} is not allowed: give 4 offsets in seconds, each from -{max} to {max} (the longest \
                     scenario), for AC, AD, BC, BD",
                    self.lights.offsets
                ),
            ));
        }
        for (i, o) in self.lights.overrides.iter().enumerate() {
            let field = format!("city.lights.overrides[{i}]");
            if !["AC", "AD", "BC", "BD"].contains(&o.intersection.as_str()) {
                return Err(SpecError::new(
                    format!("{field}.intersection"),
                    format!("{:?} is not an intersection: use AC, AD, BC or BD", o.intersection),
                ));
            }
            if !['N', 'E', 'S', 'W'].contains(&o.approach) {
                return Err(SpecError::new(
                    format!("{field}.approach"),
                    format!("{:?} is not allowed: use N, E, S or W", o.approach),
                ));
            }
            let (most_steps, shortest) =
                if recorded { (usize::MAX, f64::MIN_POSITIVE) } else { (MAX_SCHEDULE_STEPS, MIN_PHASE_S) };
            if o.schedule.is_empty() || o.schedule.len() > most_steps {
                return Err(SpecError::new(
                    format!("{field}.schedule"),
                    format!(
                        "{} steps: give 1 to {MAX_SCHEDULE_STEPS} {{\"colour\": \"green\"|\"yellow\"|\"red\", \
                         \"duration\": seconds}} (every scenario.json holds a copy)",
                        o.schedule.len()
                    ),
                ));
            }
            // (A phase longer than the longest scenario never ends in one:
            // 1e300 s was taken and written as such to light_changes.csv.)
            if let Some((k, st)) = o
                .schedule
                .iter()
                .enumerate()
                .find(|(_, st)| !(st.duration.is_finite() && st.duration >= shortest && st.duration <= max))
            {
                return Err(SpecError::new(
                    format!("{field}.schedule[{k}].duration"),
                    format!(
                        "{} is not allowed: seconds, from {MIN_PHASE_S} to {max} (the longest scenario)",
                        Shown(st.duration)
                    ),
                ));
            }
            if let Some(first) = self.lights.overrides[..i]
                .iter()
                .position(|e| (&e.intersection, e.approach, e.signal) == (&o.intersection, o.approach, o.signal))
            {
                return Err(SpecError::new(
                    field,
                    format!(
                        "{} {} {} is given twice (also overrides[{first}]): give each light one schedule",
                        o.intersection,
                        o.approach,
                        o.signal.name()
                    ),
                ));
            }
            if !(o.offset.is_finite() && o.offset.abs() <= max) {
                return Err(SpecError::new(
                    format!("{field}.offset"),
                    format!(
                        "{} is not allowed: a number of seconds from -{max} to {max} (the longest scenario)",
                        Shown(o.offset)
                    ),
                ));
            }
        }
        self.confounders.validate("city.confounders")
    }
}

impl ConfounderSpec {
    /// Every distribution within its variable's range; errors name
    /// `<field>.<variable>`.
    pub fn validate(&self, field: &str) -> Result<(), SpecError> {
        self.rain.check(&format!("{field}.rain"), 0.0, 1.0)?;
        if let Some(fog) = &self.fog {
            fog.check(&format!("{field}.fog"), 0.0, 1.0)?;
        }
        self.snow.check(&format!("{field}.snow"), 0.0, 1.0)?;
        if let Some(wetness) = &self.wetness {
            wetness.check(&format!("{field}.wetness"), 0.0, 1.0)?;
        }
        self.hour.check(&format!("{field}.hour"), 0.0, 24.0)
    }
}
