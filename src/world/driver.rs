//! Longitudinal behaviour: one small car-following interface in the style of
//! SUMO (free speed, follow speed, stop speed) with the Intelligent Driver
//! Model, or its improved form (the default), behind it. Kinematic limits
//! (the hard braking limit, no reversing) are applied by the world, not the
//! model.

use crate::spec::DriverParams;

/// A car-following model: each method returns the speed the driver wants
/// `dt` seconds from now.
///
/// What a model reads of the free road ([`CarFollowing::free_road`], a power
/// of the speed in the IDM family) is the same for every constraint of one
/// decision, so a decision computes it once and hands it to the `_given`
/// forms; the plain forms compute it themselves.
pub trait CarFollowing: Send + Sync {
    fn name(&self) -> &'static str;
    /// The model's free-road term for a driver at `speed` wanting `desired`
    /// (m/s).
    fn free_road(&self, p: &DriverParams, speed: f64, desired: f64) -> FreeRoad;
    /// [`CarFollowing::free_speed`] given this speed's `free` road term.
    fn free_speed_given(&self, p: &DriverParams, speed: f64, free: FreeRoad, dt: f64) -> f64;
    /// [`CarFollowing::follow_acceleration`] given this speed's `free` road term.
    fn follow_acceleration_given(
        &self,
        p: &DriverParams,
        speed: f64,
        desired: f64,
        free: FreeRoad,
        gap: f64,
        leader_speed: f64,
    ) -> f64;
    /// On an empty road, towards `desired`.
    fn free_speed(&self, p: &DriverParams, speed: f64, desired: f64, dt: f64) -> f64 {
        self.free_speed_given(p, speed, self.free_road(p, speed, desired), dt)
    }
    /// The acceleration (m/s^2, negative when braking) the driver wants
    /// behind a car `gap` metres ahead (bumper to bumper) driving at
    /// `leader_speed`, before any kinematic limit.
    fn follow_acceleration(&self, p: &DriverParams, speed: f64, desired: f64, gap: f64, leader_speed: f64) -> f64 {
        self.follow_acceleration_given(p, speed, desired, self.free_road(p, speed, desired), gap, leader_speed)
    }
    /// Behind a car `gap` metres ahead (bumper to bumper) driving at `leader_speed`.
    fn follow_speed(&self, p: &DriverParams, speed: f64, desired: f64, gap: f64, leader_speed: f64, dt: f64) -> f64 {
        self.follow_speed_given(p, speed, desired, self.free_road(p, speed, desired), gap, leader_speed, dt)
    }
    /// [`CarFollowing::follow_speed`] given this speed's `free` road term.
    #[allow(clippy::too_many_arguments)]
    fn follow_speed_given(
        &self,
        p: &DriverParams,
        speed: f64,
        desired: f64,
        free: FreeRoad,
        gap: f64,
        leader_speed: f64,
        dt: f64,
    ) -> f64 {
        (speed + self.follow_acceleration_given(p, speed, desired, free, gap, leader_speed) * dt).max(0.0)
    }
    /// Stopping for a standing obstacle (a stop line) `distance` metres ahead.
    fn stop_speed(&self, p: &DriverParams, speed: f64, desired: f64, distance: f64, dt: f64) -> f64 {
        self.stop_speed_given(p, speed, desired, self.free_road(p, speed, desired), distance, dt)
    }
    /// [`CarFollowing::stop_speed`] given this speed's `free` road term.
    fn stop_speed_given(
        &self,
        p: &DriverParams,
        speed: f64,
        desired: f64,
        free: FreeRoad,
        distance: f64,
        dt: f64,
    ) -> f64 {
        // A stop line is a standing car whose back is `distance` + min_gap away.
        self.follow_speed_given(p, speed, desired, free, distance + p.min_gap - STOP_LINE_MARGIN, 0.0, dt)
    }
}

/// What a car-following model reads of the free road at one speed (the
/// IDM's `(v / v0)^delta`, the IIDM's free-road acceleration in m/s^2),
/// made by [`CarFollowing::free_road`] for the same model and speed only.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FreeRoad(f64);

/// How far before a stop line a car's front comes to rest, metres.
pub const STOP_LINE_MARGIN: f64 = 0.2;

/// The gap (metres) a driver at `speed` wants behind a car at
/// `leader_speed`: the IDM's and the IIDM's `s*`, the min gap plus the time
/// headway plus a braking term while closing in.
fn desired_gap(p: &DriverParams, speed: f64, leader_speed: f64) -> f64 {
    let approach = speed - leader_speed;
    p.min_gap
        + (speed * p.time_headway + speed * approach / (2.0 * (p.max_acceleration * p.comfortable_deceleration).sqrt()))
            .max(0.0)
}

/// The IDM's acceleration exponent, 4 in the original paper (Treiber,
/// Hennecke, Helbing 2000), which the IIDM keeps.
const IDM_DELTA: f64 = 4.0;

/// The Intelligent Driver Model (Treiber, Hennecke, Helbing 2000).
#[derive(Debug, Clone, Copy)]
pub struct Idm {
    /// Acceleration exponent, 4 in the original paper.
    pub delta: f64,
}

impl Default for Idm {
    fn default() -> Self {
        Idm { delta: IDM_DELTA }
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

    fn free_road(&self, _: &DriverParams, speed: f64, desired: f64) -> FreeRoad {
        FreeRoad(self.free_term(speed, desired))
    }

    fn free_speed_given(&self, p: &DriverParams, speed: f64, free: FreeRoad, dt: f64) -> f64 {
        let a = p.max_acceleration * (1.0 - free.0);
        (speed + a * dt).max(0.0)
    }

    fn follow_acceleration_given(
        &self,
        p: &DriverParams,
        speed: f64,
        _: f64,
        free: FreeRoad,
        gap: f64,
        leader_speed: f64,
    ) -> f64 {
        let gap = gap.max(0.01);
        let wanted = desired_gap(p, speed, leader_speed);
        p.max_acceleration * (1.0 - free.0 - (wanted / gap).powi(2))
    }
}

/// The Improved Intelligent Driver Model (Treiber and Kesting, "Traffic
/// Flow Dynamics", 2013, section 11.3.5): the IDM's interaction term, but
/// the free-road term no longer widens the gap near the desired speed, so
/// the equilibrium gap is exactly `min_gap + speed x time_headway` below
/// the desired speed (the IDM's is that over `sqrt(1 - (v / v0)^delta)`,
/// twice as long at 95 % of the desired speed).
#[derive(Debug, Clone, Copy)]
pub struct Iidm {
    /// Acceleration exponent, 4 as in the IDM.
    pub delta: f64,
}

impl Default for Iidm {
    fn default() -> Self {
        Iidm { delta: IDM_DELTA }
    }
}

impl Iidm {
    /// Acceleration on a free road, m/s^2: the IDM's below the desired
    /// speed, a comfortable deceleration towards it above.
    fn free_acceleration(&self, p: &DriverParams, speed: f64, desired: f64) -> f64 {
        if desired <= 0.0 {
            return -p.comfortable_deceleration;
        }
        if speed <= desired {
            p.max_acceleration * (1.0 - (speed / desired).powf(self.delta))
        } else {
            -p.comfortable_deceleration
                * (1.0 - (desired / speed).powf(p.max_acceleration * self.delta / p.comfortable_deceleration))
        }
    }
}

impl CarFollowing for Iidm {
    fn name(&self) -> &'static str {
        "iidm"
    }

    fn free_road(&self, p: &DriverParams, speed: f64, desired: f64) -> FreeRoad {
        FreeRoad(self.free_acceleration(p, speed, desired))
    }

    fn free_speed_given(&self, _: &DriverParams, speed: f64, free: FreeRoad, dt: f64) -> f64 {
        (speed + free.0 * dt).max(0.0)
    }

    fn follow_acceleration_given(
        &self,
        p: &DriverParams,
        speed: f64,
        desired: f64,
        free: FreeRoad,
        gap: f64,
        leader_speed: f64,
    ) -> f64 {
        let gap = gap.max(0.01);
        let wanted = desired_gap(p, speed, leader_speed);
        let z = wanted / gap;
        let free = free.0;
        let a = p.max_acceleration;
        if speed <= desired {
            if z >= 1.0 {
                a * (1.0 - z * z)
            } else if free > 0.0 {
                free * (1.0 - z.powf(2.0 * a / free))
            } else {
                0.0
            }
        } else if z >= 1.0 {
            free + a * (1.0 - z * z)
        } else {
            free
        }
    }
}

/// A car-following model by name, as specs and scenario.json give it, with
/// its default parameters; shared, as a recording of a run
/// (`city::replay::Recording`) outlives any one world.
pub fn model_by_name(name: crate::spec::DriverModel) -> &'static dyn CarFollowing {
    static IDM: Idm = Idm { delta: IDM_DELTA };
    static IIDM: Iidm = Iidm { delta: IDM_DELTA };
    match name {
        crate::spec::DriverModel::Idm => &IDM,
        crate::spec::DriverModel::Iidm => &IIDM,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every car-following model the crate offers.
    fn models() -> Vec<Box<dyn CarFollowing>> {
        let models: Vec<Box<dyn CarFollowing>> = vec![Box::new(Idm::default()), Box::new(Iidm::default())];
        assert!(!models.is_empty());
        models
    }

    /// Decision step, seconds.
    const DT: f64 = 0.1;

    /// Integrates `speed_for(position m, speed m/s, time s)` for `seconds`
    /// from position `s0` (m) at speed `v0` (m/s), trapezoidal like the city
    /// world: (time s, position m, speed m/s) at every step.
    fn drive(s0: f64, v0: f64, seconds: f64, mut speed_for: impl FnMut(f64, f64, f64) -> f64) -> Vec<(f64, f64, f64)> {
        let (mut s, mut v) = (s0, v0);
        let mut track = vec![(0.0, s, v)];
        for k in 1..=(seconds / DT).round() as usize {
            let next = speed_for(s, v, k as f64 * DT);
            s += (v + next) / 2.0 * DT;
            v = next;
            track.push((k as f64 * DT, s, v));
        }
        track
    }

    #[test]
    fn free_road_accelerates_towards_and_never_beyond_the_desired_speed() {
        let p = DriverParams::default();
        let desired = 2.0;
        for model in models() {
            let track = drive(0.0, 0.0, 60.0, |_, v, _| model.free_speed(&p, v, desired, DT));
            for w in track.windows(2) {
                let ((_, _, before), (t, _, after)) = (w[0], w[1]);
                assert!(after >= before - 1e-12, "{}: slowed from {before} to {after} m/s at {t:.1} s", model.name());
                assert!(after <= desired + 1e-9, "{}: {after} m/s beyond the desired {desired} m/s", model.name());
                assert!(
                    after - before <= p.max_acceleration * DT + 1e-9,
                    "{}: faster than max acceleration",
                    model.name()
                );
            }
            let at = |t: f64| track[(t / DT).round() as usize].2;
            assert!(at(1.0) > 0.5 * p.max_acceleration, "{}: {:.2} m/s after 1 s", model.name(), at(1.0));
            assert!(at(20.0) > 0.95 * desired, "{}: only {:.2} m/s after 20 s", model.name(), at(20.0));
            // Starting too fast, it slows down to the desired speed.
            let fast = drive(0.0, 3.0, 20.0, |_, v, _| model.free_speed(&p, v, desired, DT));
            let end = fast[fast.len() - 1].2;
            assert!(end < 3.0 && end > desired - 0.01, "{}: from 3 m/s ends at {end:.3} m/s", model.name());
        }
    }

    #[test]
    fn following_keeps_at_least_the_min_gap_and_settles_behind_the_leader() {
        let p = DriverParams::default();
        let (desired, leader_speed, length) = (3.0, 1.5, 4.0);
        for model in models() {
            // The leader's centre starts 20 m ahead and drives at 1.5 m/s; the
            // follower closes in at 3 m/s.
            let leader = |t: f64| 20.0 + leader_speed * t;
            let mut gaps = Vec::new();
            let track = drive(0.0, desired, 60.0, |s, v, t| {
                let gap = leader(t - DT) - s - length;
                gaps.push(gap);
                model.follow_speed(&p, v, desired, gap, leader_speed, DT)
            });
            assert_eq!(gaps.len(), 600);
            let closest = gaps.iter().copied().fold(f64::INFINITY, f64::min);
            assert!(closest >= p.min_gap, "{}: came within {closest:.3} m (min gap {} m)", model.name(), p.min_gap);
            let (_, _, v) = track[track.len() - 1];
            let settled = gaps[gaps.len() - 1];
            assert!((v - leader_speed).abs() < 0.05, "{}: follows at {v:.3} m/s, leader {leader_speed}", model.name());
            // The equilibrium gap is min gap + v T, widened by the IDM (not the
            // IIDM) by 1 / sqrt(1 - (v / v0)^4).
            let wanted = p.min_gap + leader_speed * p.time_headway;
            assert!(
                settled > 0.98 * wanted && settled < 1.5 * wanted,
                "{}: settles {settled:.2} m behind",
                model.name()
            );

            // Behind a standing car it comes to rest at about the min gap.
            let mut gaps = Vec::new();
            drive(0.0, 2.0, 60.0, |s, v, _| {
                gaps.push(20.0 - s - length);
                model.follow_speed(&p, v, desired, 20.0 - s - length, 0.0, DT)
            });
            let closest = gaps.iter().copied().fold(f64::INFINITY, f64::min);
            assert!(closest > 0.9 * p.min_gap, "{}: came within {closest:.3} m of a standing car", model.name());
            assert!(closest < p.min_gap + 0.3, "{}: stopped {closest:.3} m short", model.name());
        }
    }

    #[test]
    fn stop_speed_brings_the_car_to_rest_before_the_stop_line() {
        let p = DriverParams::default();
        for model in models() {
            for (line, v0) in [(10.0, 2.0), (20.0, 3.0), (4.0, 1.0)] {
                // `s` is the front of the car, metres; the line stands at `line`.
                let track = drive(0.0, v0, 60.0, |s, v, _| model.stop_speed(&p, v, v0, line - s, DT));
                let (_, front, v) = track[track.len() - 1];
                let furthest = track.iter().map(|&(_, s, _)| s).fold(f64::NEG_INFINITY, f64::max);
                let name = model.name();
                assert!(v < 0.01, "{name}: still {v:.3} m/s {:.2} m before a line {line} m ahead", line - front);
                assert!(furthest < line, "{name}: front reached {furthest:.3} m, past the line at {line} m");
                assert!(
                    line - front < STOP_LINE_MARGIN + 0.5,
                    "{name}: stopped {:.2} m short of the line",
                    line - front
                );
            }
        }
    }

    #[test]
    fn near_the_desired_speed_the_iidm_keeps_its_time_headway_and_the_idm_does_not() {
        let p = DriverParams::default();
        let (desired, leader_speed, length) = (2.0, 1.9, 4.0);
        let settle = |model: &dyn CarFollowing| {
            let leader = |t: f64| 30.0 + leader_speed * t;
            let mut gap = 0.0;
            drive(0.0, leader_speed, 300.0, |s, v, t| {
                gap = leader(t - DT) - s - length;
                model.follow_speed(&p, v, desired, gap, leader_speed, DT)
            });
            gap
        };
        let wanted = p.min_gap + leader_speed * p.time_headway;
        let (iidm, idm) = (settle(&Iidm::default()), settle(&Idm::default()));
        assert!((iidm / wanted - 1.0).abs() < 0.03, "IIDM settles {iidm:.2} m behind, s0 + vT = {wanted:.2} m");
        // 1 / sqrt(1 - 0.95^4) = 2.3
        assert!(idm > 2.0 * wanted, "IDM settles {idm:.2} m behind, s0 + vT = {wanted:.2} m");
    }
}
