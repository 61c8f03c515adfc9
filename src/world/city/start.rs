//! The start: every car begins at the speed its plan wishes for, or slower
//! where what its driver sees ahead at time 0 asks for less. One rule for
//! every car, whatever its role, so speeds in the first frame say nothing
//! about who follows whom.

use super::Sim;
use crate::world::driver::STOP_LINE_MARGIN;

/// Bisection steps for the highest acceptable speed (2^-40 of the range).
const SPEED_SEARCH_STEPS: usize = 40;

impl Sim<'_> {
    /// Lowers each car's start speed until its driver is content at time 0:
    /// no braking for the car ahead (at most the speed at which the model
    /// keeps the gap there is, given that car's own start speed), a stop line
    /// it must stop at reached at no more than its comfortable deceleration,
    /// and every curve within reach slowed for comfortably. Cars ahead are
    /// settled first, so a car is never faster than its gap to a slower car
    /// allows.
    pub(super) fn settle_start_speeds(&mut self) {
        self.fill_occupancy();
        // Speeds only ever fall, so this ends; a queue of n cars needs n passes.
        for _ in 0..=self.cars.len() {
            let mut changed = false;
            for i in 0..self.cars.len() {
                let limit = self.start_limit(i);
                if limit < self.cars[i].v {
                    self.cars[i].v = limit;
                    changed = true;
                }
            }
            if !changed {
                break;
            }
        }
    }

    /// The highest start speed (m/s) car `i`'s driver accepts for what it sees now.
    fn start_limit(&self, i: usize) -> f64 {
        let car = &self.cars[i];
        let (p, desired, v) = (car.driver, car.desired(), car.v);
        let mut limit = v.min(self.curve_limit(i));
        if let Some((gap, leader_speed, _)) = self.leader_ahead(i) {
            let content = |u: f64| self.model.follow_acceleration(&p, u, desired, gap, leader_speed) >= 0.0;
            limit = limit.min(highest(limit, content));
        }
        if let (Some((distance, _)), _) = self.stop_seen(i, 0.0) {
            // A stop line is a standing car, as the model's stop speed has it.
            let gap = distance + p.min_gap - STOP_LINE_MARGIN;
            let content =
                |u: f64| self.model.follow_acceleration(&p, u, desired, gap, 0.0) >= -p.comfortable_deceleration;
            limit = limit.min(highest(limit, content));
        }
        limit
    }
}

/// The highest speed in [0, top] for which `content` holds, assuming it
/// holds below some speed and not above; 0 when it never holds.
fn highest(top: f64, content: impl Fn(f64) -> bool) -> f64 {
    if content(top) {
        return top;
    }
    let (mut lo, mut hi) = (0.0, top);
    for _ in 0..SPEED_SEARCH_STEPS {
        let mid = (lo + hi) / 2.0;
        if content(mid) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    lo
}
