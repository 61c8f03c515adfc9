//! Confounders and their documented causal model. Weather and time of day act
//! on every car's driver parameters (and on the look of the scene), whatever
//! the leader-follower graph, so they confound it.
//!
//! How the confounders cause each other (structural equations, each with its
//! own exogenous draw `u_*`, uniform in [0, 1), drawn for every scenario in
//! the order hour, rain, snow, fog, wetness):
//! - hour := the spec's `hour` distribution at `u_hour` (exogenous; likewise
//!   rain at `u_rain` and snow at `u_snow`);
//! - fog := a density in [`FOG_DENSITY`] when `u_fog` falls under the chance
//!   of fog at that hour, else 0: [`FOG_CHANCE_EARLY`] in the early hours
//!   ([`FOG_WINDOW_H`]: radiation fog forms overnight and lifts in the
//!   morning), none in the afternoon and evening;
//! - wetness := min(1, rain x a [`WETNESS_PER_RAIN`] + snow x a
//!   [`WETNESS_PER_SNOW`] share, both at `u_wetness`, how much of the
//!   precipitation drainage and traffic leave on the road); a dry day is dry.
//!
//! A spec that gives fog or wetness replaces its equation by the given value
//! or distribution (a do-intervention); a `set_confounder` intervention does
//! the same from its time on, and every variable still set by its equation is
//! recomputed from its parents with the scenario's own exogenous draws.
//! The numbers are illustrative, chosen so the weather is plausible, not
//! fitted to a climate.
//!
//! How the confounders act on driving, with `darkness = 1 - daylight(hour)`:
//! - desired speed x (1 - 0.15 wetness)(1 - 0.25 fog)(1 - 0.20 snow)(1 - 0.15 darkness)
//! - time headway x (1 + 0.3 wetness + 0.4 fog + 0.3 snow)
//! - hard braking limit (grip) x (1 - 0.6 wetness)(1 - 0.4 snow); comfortable
//!   braking x (1 - 0.2 snow) only: drivers do not fully adapt to water on the
//!   road, so wet roads bring longer stops and more collisions
//! - perception noise + 0.10 fog + 0.04 rain + 0.04 darkness
//! - reaction time + 0.10 fog + 0.15 darkness (seconds)
//! - lateral wander + 0.25 wetness (metres; wet roads make steering less predictable)
//! - chance of running red lights + 0.06 wetness (cars that cannot stop on
//!   water; they are flagged and logged like forced runs)
//!
//! `daylight` is 1 from 08:00 to 17:00, 0 from 20:00 to 05:00, linear between.

use crate::spec::{ConfounderSpec, DriverParams};
use rand::RngExt;
use serde::Serialize;

/// Hours of the fog window: the chance of fog rises from 0 at the first to
/// full at the second, stays full until the third and falls to 0 at the
/// fourth (01:00, 04:00, 08:00, 11:00).
pub const FOG_WINDOW_H: [f64; 4] = [1.0, 4.0, 8.0, 11.0];
/// Chance of fog at the height of the fog window.
pub const FOG_CHANCE_EARLY: f64 = 0.6;
/// Range of fog density when there is fog.
pub const FOG_DENSITY: [f64; 2] = [0.3, 0.7];
/// Share of rain intensity that shows as road wetness (range over `u_wetness`).
pub const WETNESS_PER_RAIN: [f64; 2] = [0.7, 1.1];
/// Share of snowfall intensity that shows as road wetness (range over `u_wetness`).
pub const WETNESS_PER_SNOW: [f64; 2] = [0.4, 0.7];

fn between(range: [f64; 2], u: f64) -> f64 {
    range[0] + u * (range[1] - range[0])
}

/// The chance of fog at `hour`.
pub fn fog_chance(hour: f64) -> f64 {
    let h = hour.rem_euclid(24.0);
    let [rise, full, fade, gone] = FOG_WINDOW_H;
    let share = if h < rise || h >= gone {
        0.0
    } else if h < full {
        (h - rise) / (full - rise)
    } else if h <= fade {
        1.0
    } else {
        (gone - h) / (gone - fade)
    };
    FOG_CHANCE_EARLY * share
}

/// Fog's structural equation.
pub fn fog_equation(hour: f64, u_fog: f64) -> f64 {
    let chance = fog_chance(hour);
    if u_fog < chance {
        between(FOG_DENSITY, u_fog / chance)
    } else {
        0.0
    }
}

/// Wetness's structural equation.
pub fn wetness_equation(rain: f64, snow: f64, u_wetness: f64) -> f64 {
    (rain * between(WETNESS_PER_RAIN, u_wetness) + snow * between(WETNESS_PER_SNOW, u_wetness)).min(1.0)
}

/// The exogenous draws of one scenario, uniform in [0, 1).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Exogenous {
    pub hour: f64,
    pub rain: f64,
    pub snow: f64,
    pub fog: f64,
    pub wetness: f64,
}

/// Where a confounder's value comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Source {
    /// Drawn from the spec (an exogenous variable, or a do-intervention on a
    /// derived one).
    Spec,
    /// Its structural equation.
    Equation,
    /// Set by a `set_confounder` intervention while the scenario ran.
    Intervention,
}

/// Where each confounder's value comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct Sources {
    pub rain: Source,
    pub fog: Source,
    pub snow: Source,
    pub wetness: Source,
    pub hour: Source,
}

/// One scenario's confounder model: its exogenous draws and which
/// variables their equations still set. Written to scenario.json.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ConfounderModel {
    pub exogenous: Exogenous,
    pub source: Sources,
}

impl ConfounderModel {
    /// Draws one scenario's confounders: the exogenous draws in their fixed
    /// order, the spec's distributions at them, the equations for the rest.
    pub fn draw<R: rand::Rng + ?Sized>(spec: &ConfounderSpec, rng: &mut R) -> (Confounders, ConfounderModel) {
        let mut u = || rng.random_range(0.0..1.0);
        let exogenous = Exogenous { hour: u(), rain: u(), snow: u(), fog: u(), wetness: u() };
        let given = |d: &Option<crate::spec::Distribution>, u: f64| d.as_ref().map(|d| d.quantile(u));
        let (fog, wetness) = (given(&spec.fog, exogenous.fog), given(&spec.wetness, exogenous.wetness));
        let source = |value: Option<f64>| if value.is_some() { Source::Spec } else { Source::Equation };
        let model = ConfounderModel {
            exogenous,
            source: Sources {
                rain: Source::Spec,
                fog: source(fog),
                snow: Source::Spec,
                wetness: source(wetness),
                hour: Source::Spec,
            },
        };
        let values = Confounders {
            rain: spec.rain.quantile(exogenous.rain),
            fog: fog.unwrap_or(0.0),
            snow: spec.snow.quantile(exogenous.snow),
            wetness: wetness.unwrap_or(0.0),
            hour: spec.hour.quantile(exogenous.hour),
        };
        (model.derive(values), model)
    }

    /// `values` with every variable still set by its equation recomputed
    /// from its parents (the hour before fog; rain and snow before wetness).
    pub fn derive(&self, mut values: Confounders) -> Confounders {
        if self.source.fog == Source::Equation {
            values.fog = fog_equation(values.hour, self.exogenous.fog);
        }
        if self.source.wetness == Source::Equation {
            values.wetness = wetness_equation(values.rain, values.snow, self.exogenous.wetness);
        }
        values
    }

    /// do(`name` := `value`) on `values`: the variable is held at `value`
    /// from now on and the variables still set by their equations follow.
    pub fn intervene(&mut self, values: Confounders, name: ConfounderName, value: f64) -> Confounders {
        let s = &mut self.source;
        *match name {
            ConfounderName::Rain => &mut s.rain,
            ConfounderName::Fog => &mut s.fog,
            ConfounderName::Snow => &mut s.snow,
            ConfounderName::Wetness => &mut s.wetness,
            ConfounderName::Hour => &mut s.hour,
        } = Source::Intervention;
        self.derive(name.set(values, value))
    }
}

/// The confounder values of one scenario.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Confounders {
    /// Rain intensity, 0..1.
    pub rain: f64,
    /// Fog density, 0..1.
    pub fog: f64,
    /// Snowfall intensity, 0..1.
    pub snow: f64,
    /// Water on the road, 0..1.
    pub wetness: f64,
    /// Time of day, hours 0..24.
    pub hour: f64,
}

impl Default for Confounders {
    fn default() -> Self {
        Confounders { rain: 0.0, fog: 0.0, snow: 0.0, wetness: 0.0, hour: 12.0 }
    }
}

/// Factors the confounders apply, written into scenario.json.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Effects {
    pub daylight: f64,
    pub desired_speed_factor: f64,
    pub time_headway_factor: f64,
    /// Multiplies the hard braking limit.
    pub grip_factor: f64,
    /// Multiplies the comfortable deceleration drivers plan with.
    pub comfortable_braking_factor: f64,
    pub perception_noise_added: f64,
    pub reaction_time_added: f64,
    pub lateral_wander_added: f64,
    pub red_light_run_probability_added: f64,
}

impl Confounders {
    /// 1 in full daylight, 0 at night.
    pub fn daylight(&self) -> f64 {
        let h = self.hour.rem_euclid(24.0);
        if (8.0..=17.0).contains(&h) {
            1.0
        } else if !(5.0..=20.0).contains(&h) {
            0.0
        } else if h < 8.0 {
            (h - 5.0) / 3.0
        } else {
            (20.0 - h) / 3.0
        }
    }

    /// The causal model's factors for these values.
    pub fn effects(&self) -> Effects {
        let darkness = 1.0 - self.daylight();
        Effects {
            daylight: self.daylight(),
            desired_speed_factor: (1.0 - 0.15 * self.wetness)
                * (1.0 - 0.25 * self.fog)
                * (1.0 - 0.20 * self.snow)
                * (1.0 - 0.15 * darkness),
            time_headway_factor: 1.0 + 0.3 * self.wetness + 0.4 * self.fog + 0.3 * self.snow,
            grip_factor: (1.0 - 0.6 * self.wetness) * (1.0 - 0.4 * self.snow),
            comfortable_braking_factor: 1.0 - 0.2 * self.snow,
            perception_noise_added: 0.10 * self.fog + 0.04 * self.rain + 0.04 * darkness,
            reaction_time_added: 0.10 * self.fog + 0.15 * darkness,
            lateral_wander_added: 0.25 * self.wetness,
            red_light_run_probability_added: 0.06 * self.wetness,
        }
    }
}

impl Effects {
    /// A driver's parameters under these effects (desired speeds are scaled
    /// separately, per leg).
    pub fn apply(&self, base: &DriverParams) -> DriverParams {
        DriverParams {
            time_headway: base.time_headway * self.time_headway_factor,
            comfortable_deceleration: (base.comfortable_deceleration * self.comfortable_braking_factor)
                .min(base.max_deceleration * self.grip_factor),
            max_deceleration: base.max_deceleration * self.grip_factor,
            perception_noise: base.perception_noise + self.perception_noise_added,
            reaction_time: base.reaction_time + self.reaction_time_added,
            lateral_wander: base.lateral_wander + self.lateral_wander_added,
            ..*base
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::spec::Distribution;
    use rand::SeedableRng;

    #[test]
    fn rain_wets_the_road_fog_comes_early_and_a_given_value_overrides_its_equation() {
        let mut spec = ConfounderSpec {
            rain: Distribution::Uniform { uniform: [0.0, 1.0] },
            hour: Distribution::Uniform { uniform: [0.0, 24.0] },
            ..ConfounderSpec::default()
        };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let (mut early_fog, mut late_fog, mut wet_checked) = (0, 0, 0);
        for _ in 0..2000 {
            let (c, model) = ConfounderModel::draw(&spec, &mut rng);
            assert_eq!(model.source.wetness, Source::Equation);
            if c.rain >= 0.5 {
                assert!(c.wetness >= 0.3, "{c:?}");
                wet_checked += 1;
            }
            assert_eq!(c.wetness > 0.0, c.rain > 0.0, "{c:?}");
            if (4.0..8.0).contains(&c.hour) {
                early_fog += (c.fog > 0.0) as usize;
            }
            if (12.0..24.0).contains(&c.hour) {
                late_fog += (c.fog > 0.0) as usize;
            }
        }
        assert!(wet_checked > 500 && early_fog > 100 && late_fog == 0, "{wet_checked} {early_fog} {late_fog}");
        // Given in the spec: held whatever the rain.
        spec.wetness = Some(Distribution::Fixed(0.0));
        for _ in 0..100 {
            let (c, model) = ConfounderModel::draw(&spec, &mut rng);
            assert_eq!((c.wetness, model.source.wetness), (0.0, Source::Spec));
        }
    }

    #[test]
    fn an_intervention_on_rain_rewets_the_road_but_not_a_held_wetness() {
        let spec = ConfounderSpec::default();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let (dry, mut model) = ConfounderModel::draw(&spec, &mut rng);
        assert_eq!((dry.rain, dry.wetness, dry.fog), (0.0, 0.0, 0.0));
        let wet = model.intervene(dry, ConfounderName::Rain, 0.8);
        assert_eq!(wet.wetness, wetness_equation(0.8, 0.0, model.exogenous.wetness));
        assert!(wet.wetness >= 0.56);
        let held = model.intervene(wet, ConfounderName::Wetness, 0.1);
        let still = model.intervene(held, ConfounderName::Rain, 1.0);
        assert_eq!((still.rain, still.wetness), (1.0, 0.1));
        assert_eq!(model.source.wetness, Source::Intervention);
        // Dawn brings fog when u_fog lies under the chance at 06:00.
        let dawn = model.intervene(still, ConfounderName::Hour, 6.0);
        assert_eq!(dawn.fog, fog_equation(6.0, model.exogenous.fog));
    }

    #[test]
    fn wet_roads_slow_cars_and_weaken_brakes() {
        let dry = Confounders::default().effects();
        let wet = Confounders { wetness: 1.0, ..Default::default() }.effects();
        assert_eq!(dry.desired_speed_factor, 1.0);
        assert!(wet.desired_speed_factor < 0.9);
        assert!(wet.grip_factor <= 0.5);
        assert!(wet.time_headway_factor > dry.time_headway_factor);
        let night = Confounders { hour: 23.0, ..Default::default() };
        assert_eq!(night.daylight(), 0.0);
        assert!(Confounders { hour: 18.5, ..Default::default() }.daylight() > 0.0);
    }
}

/// The confounders an intervention can change.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ConfounderName {
    Rain,
    Fog,
    Snow,
    Wetness,
    Hour,
}

impl ConfounderName {
    pub const ALL: [(ConfounderName, &'static str); 5] = [
        (ConfounderName::Rain, "rain"),
        (ConfounderName::Fog, "fog"),
        (ConfounderName::Snow, "snow"),
        (ConfounderName::Wetness, "wetness"),
        (ConfounderName::Hour, "hour"),
    ];

    /// The name scenario files use.
    pub fn name(self) -> &'static str {
        ConfounderName::ALL.iter().find(|(c, _)| *c == self).map(|(_, n)| *n).expect("every confounder is listed")
    }

    /// `confounders` with this one set to `value`.
    pub fn set(self, confounders: Confounders, value: f64) -> Confounders {
        let mut c = confounders;
        match self {
            ConfounderName::Rain => c.rain = value,
            ConfounderName::Fog => c.fog = value,
            ConfounderName::Snow => c.snow = value,
            ConfounderName::Wetness => c.wetness = value,
            ConfounderName::Hour => c.hour = value,
        }
        c
    }
}
