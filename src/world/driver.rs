//! Longitudinal behaviour: one small car-following interface in the style of
//! SUMO (free speed, follow speed, stop speed) with the Intelligent Driver
//! Model behind it. Kinematic limits (the hard braking limit, no reversing)
//! are applied by the world, not the model.

use crate::spec::DriverParams;

/// A car-following model: each method returns the speed the driver wants
/// `dt` seconds from now.
pub trait CarFollowing: Send + Sync {
    fn name(&self) -> &'static str;
    /// On an empty road, towards `desired`.
    fn free_speed(&self, p: &DriverParams, speed: f64, desired: f64, dt: f64) -> f64;
    /// Behind a car `gap` metres ahead (bumper to bumper) driving at `leader_speed`.
    fn follow_speed(&self, p: &DriverParams, speed: f64, desired: f64, gap: f64, leader_speed: f64, dt: f64) -> f64;
    /// Stopping for a standing obstacle (a stop line) `distance` metres ahead.
    fn stop_speed(&self, p: &DriverParams, speed: f64, desired: f64, distance: f64, dt: f64) -> f64 {
        // A stop line is a standing car whose back is `distance` + min_gap away.
        self.follow_speed(p, speed, desired, distance + p.min_gap - STOP_LINE_MARGIN, 0.0, dt)
    }
}

/// How far before a stop line a car's front comes to rest, metres.
pub const STOP_LINE_MARGIN: f64 = 0.2;

/// The Intelligent Driver Model (Treiber, Hennecke, Helbing 2000).
#[derive(Debug, Clone, Copy)]
pub struct Idm {
    /// Acceleration exponent, 4 in the original paper.
    pub delta: f64,
}

impl Default for Idm {
    fn default() -> Self {
        Idm { delta: 4.0 }
    }
}

impl Idm {
    fn free_term(&self, speed: f64, desired: f64) -> f64 {
        if desired <= 0.0 {
            return 1.0 + speed;
        }
        (speed / desired).powf(self.delta)
    }
}

impl CarFollowing for Idm {
    fn name(&self) -> &'static str {
        "idm"
    }

    fn free_speed(&self, p: &DriverParams, speed: f64, desired: f64, dt: f64) -> f64 {
        let a = p.max_acceleration * (1.0 - self.free_term(speed, desired));
        (speed + a * dt).max(0.0)
    }

    fn follow_speed(&self, p: &DriverParams, speed: f64, desired: f64, gap: f64, leader_speed: f64, dt: f64) -> f64 {
        let gap = gap.max(0.01);
        let approach = speed - leader_speed;
        let wanted = p.min_gap
            + (speed * p.time_headway
                + speed * approach / (2.0 * (p.max_acceleration * p.comfortable_deceleration).sqrt()))
            .max(0.0);
        let a = p.max_acceleration * (1.0 - self.free_term(speed, desired) - (wanted / gap).powi(2));
        (speed + a * dt).max(0.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn idm_accelerates_follows_and_stops() {
        let idm = Idm::default();
        let p = DriverParams::default();
        assert!(idm.free_speed(&p, 0.0, 2.0, 0.1) > 0.0);
        assert!(idm.free_speed(&p, 2.0, 2.0, 0.1) < 2.0 + 1e-9);
        // Closing in on a standing car brakes.
        assert!(idm.follow_speed(&p, 2.0, 2.0, 1.0, 0.0, 0.1) < 2.0);
        // Simulate a stop line 10 m ahead: the car stops before it.
        let (mut s, mut v) = (0.0, 2.0);
        for _ in 0..2000 {
            let next = idm.stop_speed(&p, v, 2.0, 10.0 - s, 0.01);
            s += (v + next) / 2.0 * 0.01;
            v = next;
        }
        assert!(s < 10.0 && s > 9.0, "stopped at {s}");
        assert!(v < 0.05);
    }
}
