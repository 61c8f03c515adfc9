//! A driver's decision (the target speed the car-following model gives for
//! everything it perceives, turned into an acceleration held until the next
//! decision) and the car's motion between decisions.

use super::car::{normal, SimCar};
use super::perception::Stop;
use super::Sim;
use crate::world::{BoundBy, Interaction};

/// Largest sideways wander from the lane centre, metres.
const MAX_WANDER: f64 = 0.4;
/// Correlation time of the sideways wander, seconds.
const WANDER_TIME: f64 = 3.0;

impl Sim<'_> {
    /// Car `i` decides at time `t`: the lowest speed the model wants for the
    /// free road, the leader ahead (gap seen with noise), a stop line, the
    /// curves and a merge it waits for, reached in `dt` seconds within the
    /// car's acceleration limits (m/s^2). Also draws the next perception
    /// error and wander target.
    pub(super) fn decide(&mut self, i: usize, t: f64, dt: f64) {
        if t < self.cars[i].hold_until {
            let car = &mut self.cars[i];
            car.accel = 0.0;
            car.binding = Interaction { bound_by: BoundBy::Collision, other_car: car.collided_with, light: None };
            return;
        }
        let model = self.model;
        let (p, v, desired) = {
            let car = &self.cars[i];
            (car.driver, car.v, car.desired())
        };
        // The lowest target wins; on a tie the constraint found first.
        // The free-road term is the same for every constraint below.
        let free = model.free_road(&p, v, desired);
        let mut target = model.free_speed_given(&p, v, free, dt);
        let mut binding = Interaction::FREE;
        let mut bind = |speed: f64, by: Interaction| {
            if speed < target {
                target = speed;
                binding = by;
            }
        };
        if let Some((gap, leader_speed, j)) = self.leader_ahead(i) {
            let perceived = gap * (p.perception_noise * self.cars[i].noise).exp();
            let other = Some(self.cars[j].plan.id);
            bind(
                model.follow_speed_given(&p, v, desired, free, perceived, leader_speed, dt),
                Interaction { bound_by: BoundBy::Car, other_car: other, light: None },
            );
        }
        if let Some((distance, stop)) = self.stop_ahead(i, t) {
            let by = match stop {
                Stop::Light(light) => Interaction { bound_by: BoundBy::Light, other_car: None, light: Some(light) },
                Stop::Crossing(j) => {
                    Interaction { bound_by: BoundBy::Conflict, other_car: Some(self.cars[j].plan.id), light: None }
                }
                Stop::GiveWay(j) => {
                    Interaction { bound_by: BoundBy::GiveWay, other_car: Some(self.cars[j].plan.id), light: None }
                }
                Stop::AllWayLine => Interaction { bound_by: BoundBy::StopLine, other_car: None, light: None },
            };
            bind(model.stop_speed_given(&p, v, desired, free, distance, dt), by);
        }
        // A curve limit below the speed is reached over a reaction time, not
        // in one step (the acceleration is held until the next decision).
        let curve = self.curve_limit(i);
        let curve_target = if curve < v { v + (curve - v) * (dt / p.reaction_time).min(1.0) } else { curve };
        bind(curve_target, Interaction { bound_by: BoundBy::Curve, other_car: None, light: None });
        if let Some(distance) = self.merge_wait(i, t) {
            let by = Interaction { bound_by: BoundBy::Merge, other_car: None, light: None };
            bind(model.stop_speed_given(&p, v, desired, free, distance, dt), by);
        }
        if t < self.cars[i].stopped_until {
            target = 0.0;
            binding = Interaction { bound_by: BoundBy::Intervention, other_car: None, light: None };
        }
        self.cars[i].binding = binding;
        let rho = (-p.reaction_time / 2.0).exp();
        let car = &mut self.cars[i];
        let draw = normal(&mut car.rng);
        let wander_draw = normal(&mut car.rng);
        car.accel = ((target - v) / dt).clamp(-p.max_deceleration, p.max_acceleration);
        car.noise = rho * car.noise + (1.0 - rho * rho).sqrt() * draw;
        // Sideways wander: an Ornstein-Uhlenbeck target per decision, approached smoothly.
        let wander_rho = (-p.reaction_time / WANDER_TIME).exp();
        car.wander_target = (wander_rho * car.wander_target
            + p.lateral_wander * (1.0 - wander_rho * wander_rho).sqrt() * wander_draw)
            .clamp(-MAX_WANDER, MAX_WANDER);
    }

    /// Moves car `i` from `t` to `t + dt` seconds, then logs a red light it
    /// ran and the route legs (actions) it completed.
    pub(super) fn advance(&mut self, i: usize, t: f64, dt: f64) {
        let now = t + dt;
        let Some((front_before, front_after)) = self.cars[i].drive(dt, now) else { return };
        self.log_red_light_runs(i, front_before, front_after, now);
        self.complete_legs(i, now);
    }
}

impl SimCar<'_> {
    /// Drives `dt` seconds at the held acceleration (never backwards, never
    /// past the desired speed when speeding up), easing the wander towards
    /// its target as the car moves. Returns the front's route position (metres) before and
    /// after, or `None` while the car is held after a collision (at rest
    /// until `now`).
    #[inline]
    fn drive(&mut self, dt: f64, now: f64) -> Option<(f64, f64)> {
        if now <= self.hold_until {
            self.v = 0.0;
            return None;
        }
        let front_before = self.front();
        let mut v_new = (self.v + self.accel * dt).max(0.0);
        if self.accel > 0.0 {
            // Speeding up towards the desired speed never overshoots it.
            v_new = v_new.min(self.desired().max(self.v));
        }
        let ds = (self.v + v_new) / 2.0 * dt;
        self.s += ds;
        self.v = v_new;
        // The wander advances with distance (one reaction time's worth of
        // it at the desired speed), so a standing car does not slide.
        let glide = (ds / (self.driver.reaction_time * self.desired().max(1e-3))).min(1.0);
        self.wander += (self.wander_target - self.wander) * glide;
        if self.v == 0.0 && self.accel < 0.0 {
            self.accel = 0.0;
        }
        Some((front_before, self.front()))
    }
}
