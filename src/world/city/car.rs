//! A car's state while the scenario runs: where it is on its own copy of the
//! route, how fast it goes, what its driver decided, and what interventions
//! changed about it. Its pose follows from the route.

use crate::geometry::OrientedBox;
use crate::map::{Action, Route};
use crate::plan::{CarAgency, CarPlan};
use crate::spec::DriverParams;
use crate::world::{CarState, Interaction};
use glam::DVec2;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::sync::Arc;

/// One car while the scenario runs. Cloning it is cheap (the route is
/// shared until the car changes it): effects re-runs keep snapshots.
#[derive(Clone)]
pub(super) struct SimCar<'p> {
    pub(super) plan: &'p CarPlan,
    pub(super) agency: &'p CarAgency,
    /// The car's own route, shared with the plan (and snapshots) until the
    /// car changes it: merges it defers and replaced actions re-plan it.
    pub(super) route: Arc<Route>,
    /// Drive-queue index of the route's first action.
    pub(super) action_base: usize,
    /// Merge distance per drive-queue action, metres along its lane
    /// (shared with snapshots until it changes).
    pub(super) merges: Arc<Vec<f64>>,
    /// Route arc length of the car's centre, metres.
    pub(super) s: f64,
    /// Speed along the route, m/s.
    pub(super) v: f64,
    /// Acceleration held until the next decision, m/s^2.
    pub(super) accel: f64,
    /// Index of the route leg the car's centre is on.
    pub(super) leg: usize,
    /// Time of the next decision, seconds.
    pub(super) next_decision: f64,
    /// After a collision: stand still until this time, seconds.
    pub(super) hold_until: f64,
    /// Drive-queue actions carried out so far.
    pub(super) actions_done: usize,
    /// Intersection connector the car has decided to drive through.
    pub(super) committed: Option<usize>,
    /// Sideways offset from the lane centre, metres.
    pub(super) wander: f64,
    /// Where the wander is heading, drawn at each decision, metres.
    pub(super) wander_target: f64,
    /// Standard-normal state of the perception error.
    pub(super) noise: f64,
    /// Half the footprint's diagonal: beyond twice this, two cars cannot touch.
    pub(super) reach: f64,
    /// This car's own random stream (decisions, collision stops).
    pub(super) rng: ChaCha8Rng,
    /// Forced through red lights (by the plan or an intervention).
    pub(super) runs_red_lights: bool,
    /// Intervention: hold still until this time, seconds.
    pub(super) stopped_until: f64,
    /// Intervention: desired speed replaced, m/s.
    pub(super) desired_override: Option<f64>,
    /// Intervention: taken off the map.
    pub(super) removed: bool,
    /// The drive queue: the plan's, until an intervention replaces the rest
    /// (shared with snapshots until it changes).
    pub(super) actions: Arc<Vec<Action>>,
    /// Intervention: actions (and merge distances) waiting to replace the
    /// rest once the car is on a lane.
    pub(super) pending_actions: Option<PendingQueue>,
    /// Drive-queue actions the driver gave up on (no gap came), skipped.
    pub(super) given_up: Vec<usize>,
    /// Drive-queue actions whose adaptation events.csv already has.
    pub(super) logged_adaptations: Vec<usize>,
    /// Since when the car has waited for a lane-change gap at the last
    /// point of its lane, seconds.
    pub(super) waiting_since: Option<f64>,
    /// Under cooperative lane changes, while it waits there: the lane it
    /// wants and the point on it (metres) that the car behind is asked to
    /// stop short of.
    pub(super) merge_claim: Option<(usize, f64)>,
    /// What bound the latest decision (for interactions.csv).
    pub(super) binding: Interaction,
    /// The car it last collided with.
    pub(super) collided_with: Option<u32>,
    /// The driver's parameters now (the plan's, until a confounder changes).
    pub(super) driver: DriverParams,
    /// Multiplies the planned desired speeds (a confounder change).
    pub(super) speed_factor: f64,
    /// Followers: the index of the car it follows (cars are in id order).
    pub(super) leader: Option<usize>,
    /// A centre-line point near the car, for the cheap distance bound of
    /// [`SimCar::near_point`]; `None` after the route changed.
    pub(super) anchor: Option<Anchor>,
}

/// Where the car's centre was at route arc length `s` and sideways offset
/// `wander` on route leg `leg`. While the car stays on that leg (one curve
/// parameterised by arc length), its centre is within
/// `ARC_SLACK·|Δs| + |Δwander| + |wander|·min(2, |Δs|)` of `point`: the
/// centre line moves at most the arc length, and the offset's direction
/// turns by at most the curvature (below 1 per metre on every road) times it.
#[derive(Debug, Clone, Copy)]
pub(super) struct Anchor {
    point: DVec2,
    s: f64,
    wander: f64,
    leg: usize,
}

/// Bound on metres of path per metre of route arc length: 1 on lines and
/// arcs; a lane change's arc length is a cubic Hermite fit, off by far less
/// than this allows.
const ARC_SLACK: f64 = 1.1;
/// How far (metres) the bound may grow before the anchor moves to the car.
const ANCHOR_REACH: f64 = 0.5;

/// A drive queue waiting to replace the rest of a car's own.
#[derive(Clone, PartialEq)]
pub(super) struct PendingQueue {
    pub(super) actions: Vec<Action>,
    /// Merge distance per action, metres along its lane.
    pub(super) merges: Vec<f64>,
    /// The drive-queue index of the first action, when the queue is a slice
    /// of another (a follower's of its leader's, or of its fallback): actions
    /// the car carries out before the queue is applied are dropped from its
    /// front. `None`: it replaces whatever comes next (an intervention's).
    pub(super) from: Option<usize>,
}

impl PendingQueue {
    /// `actions[from..]` (and the merges beside them) as a queue that
    /// starts at drive-queue index `from`.
    pub(super) fn slice(actions: &[Action], merges: &[f64], from: usize) -> PendingQueue {
        let (a, m) = (from.min(actions.len()), from.min(merges.len()));
        PendingQueue { actions: actions[a..].to_vec(), merges: merges[m..].to_vec(), from: Some(from) }
    }

    /// The actions and merges still to apply for a car that has done `done`
    /// actions.
    pub(super) fn remaining(&self, done: usize) -> (&[Action], &[f64]) {
        let skip = self.from.map_or(0, |from| done.saturating_sub(from));
        (&self.actions[skip.min(self.actions.len())..], &self.merges[skip.min(self.merges.len())..])
    }
}

/// A standard normal draw (Box-Muller).
pub(super) fn normal(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = rng.random::<f64>().max(1e-12);
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

impl<'p> SimCar<'p> {
    /// The car of `plan` at its spawn point at its planned start speed (the
    /// world may lower it before the first step), its random stream keyed
    /// by the scenario's `sim_stream` and its id.
    pub(super) fn new(plan: &'p CarPlan, agency: &'p CarAgency, sim_stream: [u8; 32]) -> SimCar<'p> {
        let mut rng = ChaCha8Rng::from_seed(sim_stream);
        rng.set_stream(plan.id as u64 + 1);
        let route = Arc::clone(&plan.route);
        let leg = route.leg_index_at(plan.spawn_distance);
        SimCar {
            plan,
            agency,
            route,
            action_base: 0,
            merges: Arc::new(plan.merge_distances.clone()),
            s: plan.spawn_distance,
            v: agency.start_speed,
            accel: 0.0,
            leg,
            // Drivers do not all decide in lockstep.
            next_decision: rng.random_range(0.0..agency.driver.reaction_time),
            hold_until: f64::NEG_INFINITY,
            actions_done: 0,
            committed: None,
            wander: 0.0,
            wander_target: 0.0,
            noise: normal(&mut rng),
            reach: plan.length.hypot(plan.width) / 2.0,
            rng,
            runs_red_lights: agency.runs_red_lights,
            stopped_until: f64::NEG_INFINITY,
            desired_override: None,
            removed: false,
            actions: Arc::new(plan.actions.clone()),
            pending_actions: None,
            given_up: Vec::new(),
            logged_adaptations: Vec::new(),
            waiting_since: None,
            merge_claim: None,
            binding: Interaction::FREE,
            collided_with: None,
            driver: agency.driver,
            speed_factor: 1.0,
            leader: plan.leader.map(|id| id as usize),
            anchor: None,
        }
    }
}

impl SimCar<'_> {
    /// Route arc length of the front bumper, metres.
    pub(super) fn front(&self) -> f64 {
        self.s + self.plan.length / 2.0
    }

    /// Desired speed now, m/s: an intervention's, else the plan's for the
    /// current stretch of the drive queue scaled by confounder changes.
    pub(super) fn desired(&self) -> f64 {
        if let Some(speed) = self.desired_override {
            return speed;
        }
        let speeds = &self.agency.desired_speeds;
        self.speed_factor * speeds.get(self.actions_done.min(speeds.len().saturating_sub(1))).copied().unwrap_or(1.0)
    }

    /// Centre (metres) and heading (radians) on the map, wander included.
    pub(super) fn pose(&self) -> (DVec2, f64) {
        self.route.pose_at_near(self.leg, self.s, self.wander)
    }

    /// A point and a radius (metres) such that the car's centre is within
    /// the radius of the point, without the trigonometry of [`SimCar::pose`]
    /// most of the time: collision checks skip pairs that are clearly apart.
    #[inline]
    pub(super) fn near_point(&mut self) -> (DVec2, f64) {
        let radius = |a: &Anchor, car: &SimCar| {
            let ds = (car.s - a.s).abs();
            ARC_SLACK * ds + (car.wander - a.wander).abs() + a.wander.abs() * ds.min(2.0)
        };
        // A polyline (an imported network's lanes and movements) turns at its
        // points: a car off its centre line steps sideways there, beyond
        // what the radius allows, so its pose is computed every time.
        let bent = matches!(self.route.legs[self.leg].curve, crate::map::curve::Curve::Polyline(_));
        let fresh = !bent && self.anchor.is_some_and(|a| a.leg == self.leg && radius(&a, self) <= ANCHOR_REACH);
        if !fresh {
            let point = self.pose().0;
            self.anchor = Some(Anchor { point, s: self.s, wander: self.wander, leg: self.leg });
        }
        let a = self.anchor.expect("set above");
        let r = radius(&a, self);
        debug_assert!(
            self.pose().0.distance(a.point) <= r + 1e-9,
            "car {} is {} m from its anchor, beyond the bound {r}",
            self.plan.id,
            self.pose().0.distance(a.point)
        );
        (a.point, r)
    }

    /// Whether `other` is this car in the same state: every field but the
    /// collision check's anchor (a cache), the route compared by identity
    /// (a re-planned or changed route is a new one).
    pub(super) fn same_state(&self, other: &SimCar) -> bool {
        self.same_motion(other) && self.same_queue(other)
    }

    /// Whether `other` has this car's route and drive queue: the route by
    /// identity, the queue (actions, merges, pending and given-up actions,
    /// adaptations logged) by value.
    pub(super) fn same_queue(&self, other: &SimCar) -> bool {
        Arc::ptr_eq(&self.route, &other.route)
            && self.action_base == other.action_base
            && self.merges == other.merges
            && self.actions == other.actions
            && self.pending_actions == other.pending_actions
            && self.given_up == other.given_up
            && self.logged_adaptations == other.logged_adaptations
    }

    /// Whether `other` is this car in the same state apart from its route
    /// and drive queue ([`SimCar::same_queue`]) and the anchor: where it is
    /// on its route, how it moves, its driver and random stream.
    pub(super) fn same_motion(&self, other: &SimCar) -> bool {
        std::ptr::eq(self.plan, other.plan)
            && self.s == other.s
            && self.v == other.v
            && self.accel == other.accel
            && self.leg == other.leg
            && self.next_decision == other.next_decision
            && self.hold_until == other.hold_until
            && self.actions_done == other.actions_done
            && self.committed == other.committed
            && self.wander == other.wander
            && self.wander_target == other.wander_target
            && self.noise == other.noise
            && self.rng == other.rng
            && self.runs_red_lights == other.runs_red_lights
            && self.stopped_until == other.stopped_until
            && self.desired_override == other.desired_override
            && self.removed == other.removed
            && self.waiting_since == other.waiting_since
            && self.merge_claim == other.merge_claim
            && self.binding == other.binding
            && self.collided_with == other.collided_with
            && self.driver == other.driver
            && self.speed_factor == other.speed_factor
            && self.leader == other.leader
    }

    /// Takes `other`'s route and drive queue ([`SimCar::same_queue`]),
    /// keeping its own motion; the anchor is dropped (a new route).
    pub(super) fn take_queue(&mut self, other: &SimCar<'_>) {
        self.route = Arc::clone(&other.route);
        self.action_base = other.action_base;
        self.merges = Arc::clone(&other.merges);
        self.actions = Arc::clone(&other.actions);
        self.pending_actions = other.pending_actions.clone();
        self.given_up.clone_from(&other.given_up);
        self.logged_adaptations.clone_from(&other.logged_adaptations);
        self.anchor = None;
    }

    /// The car's rectangle on the ground.
    pub(super) fn footprint(&self) -> OrientedBox {
        let (centre, heading) = self.pose();
        OrientedBox { centre, heading, length: self.plan.length, width: self.plan.width }
    }

    /// The state a frame records (removed cars parked far away, at rest).
    pub(super) fn state(&self) -> CarState {
        if self.removed {
            return CarState::parked(self.plan.id);
        }
        let (position, yaw) = self.pose();
        CarState { position, z: 0.0, roll: 0.0, pitch: 0.0, yaw, speed: self.v }
    }

    /// Takes a re-planned `route` that starts on the car's current lane,
    /// where the car stands `lane_s` metres along it; the route's first
    /// action is drive-queue action `action_base`.
    pub(super) fn follow_route(&mut self, route: Route, lane_s: f64, action_base: usize) {
        self.route = Arc::new(route);
        self.anchor = None;
        self.merge_claim = None;
        self.s = lane_s;
        self.leg = self.route.leg_index_at(lane_s);
        self.action_base = action_base;
    }
}
