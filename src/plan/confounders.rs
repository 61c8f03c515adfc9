//! Confounders and their documented causal model. Weather and time of day act
//! on every car's driver parameters (and on the look of the scene), whatever
//! the leader-follower graph, so they confound it.
//!
//! The model, with `darkness = 1 - daylight(hour)`:
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

use crate::spec::DriverParams;
use serde::Serialize;

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
