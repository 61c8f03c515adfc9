//! Effects re-runs that simulate only the cars an intervention has reached.
//!
//! The factual run records a tape (`Tape`): at every step, where each car stood
//! in the occupancy and its speed and actions done when the drivers decided,
//! where it was on its route after moving, and the tracks each decision
//! read; and a snapshot of a car at the end of every step in which something
//! besides its own motion changed it (it decided, or its leader showed it
//! new actions); and every drive queue a leader showed its followers as it
//! re-planned or gave up a lane change.
//!
//! A re-run simulates the intervened car and its followers (theirs, and so
//! on) and replays every other car from the tape. An intervened car whose
//! drive queue was replaced re-plans at the first step and is then
//! replayed too while its new route lies beyond all it reads ([`Deferred`]),
//! taking that route when it wakes. A replayed car is brought
//! up to date (its latest snapshot, moved on step by step) and simulated
//! from then on, with its followers, as soon as
//! - a decision it takes would read a track on which a simulated car stands
//!   elsewhere, or at another speed, than the tape says (at a position the
//!   read looks at: a search for the car ahead looks only ahead), and the
//!   decision, tried, ends the step otherwise than the tape's snapshot, or
//! - a simulated car touches it (a collision).
//!
//! A leader's re-plans reach its followers, so a simulated car's followers
//! are always simulated; a replayed leader's re-plans reach its simulated
//! followers from the tape, at the point of the step where the factual run
//! showed them.
//!
//! Until then it does what the factual run did, so a re-run's positions and
//! interactions are those of simulating every car, bit for bit
//! (`tests/incremental_effects.rs` runs both side by side). A re-run's steps
//! walk the simulated cars only, and it keeps only their frames
//! ([`RerunFrames`]): a replayed car's are the factual run's. Scenarios with
//! interventions of their own, a collision in the factual run, few cars or
//! a tape too long to hold are re-run in full, as is any re-run other than
//! one removal or action change of its cause at time 0.

use super::car::SimCar;
use super::events::{extent, may_touch};
use super::perception::{Places, LOOKAHEAD};
use super::{Sim, MAX_STEP};
use crate::geometry::OrientedBox;
use crate::map::CityMap;
use crate::map::{Action, LegKind, Route, RouteLeg};
use crate::plan::interventions::{Effect, Trigger};
use crate::plan::{CarPlan, CityPlan, ScenarioPlan, WorldPlan};
use crate::world::driver::{model_by_name, CarFollowing};
use crate::world::rerun::{RerunFrames, RerunTrajectories};
use crate::world::Trajectories;
use glam::DVec2;
use std::cell::RefCell;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// Fewest cars for which replaying pays. Measured with `gen --json` (one
/// core, no images, best of 3), side by side with full re-runs: 200
/// scenarios of 4 cars on the paper's compact map take 1.97 s to simulate
/// (recording) and measure effects against 2.10 s re-running every car
/// (-6 %; callgrind on `configs/city.json`'s 4-car group: effects -24 %
/// instructions). Since re-runs walk only their simulated cars, 4 cars pay;
/// they did not before (0.84x). Below 4 no paper group was measured.
pub const MIN_CARS_TO_REPLAY: usize = 4;

/// Largest tape a scenario records for its re-runs, bytes (one per worker
/// thread at a time): the paper's 12-car city scenario needs about 11 MB.
pub const MAX_TAPE_BYTES: usize = 64 << 20;

/// What the tape holds per car and step, bytes, with room: occupancy places
/// (56), speed and actions done (16), route position and wander (16),
/// collision bound (32), decisions and their reads (about 15), and a share of
/// the snapshots (an 840-byte car at every decision, about every 6 steps).
/// Measured on `configs/city.json`'s 12-car scenarios: 250-310 (a test
/// keeps it within this).
const TAPE_BYTES_PER_CAR_STEP: usize = 384;

/// What the factual run records for re-runs, step by step (`step * cars + car`).
pub(super) struct Tape<'a> {
    cars: usize,
    /// Where each car stood in the occupancy when the drivers decided.
    places: Vec<Places>,
    /// Speed (m/s) and drive-queue actions done when the drivers decided.
    speed: Vec<f64>,
    actions_done: Vec<usize>,
    /// After moving: route arc length and sideways wander (metres), and the
    /// collision check's near point and extent (`events::extent`; a NaN
    /// point when off the map, near nothing).
    s_wander: Vec<(f64, f64)>,
    near: Vec<(DVec2, f64)>,
    /// Per step `k`, how much one car can have eaten into a pair's gap
    /// (distance less both extents) since step `k - 1`: the largest, over
    /// the cars, of how far its near point moved plus how much its extent
    /// grew (infinite at step 0 and where a car came back onto the map). A
    /// re-run that found a simulated car clear of every taped one by a gap
    /// skips the pairs until its own moves and these have used the gap up.
    near_shift: Vec<f64>,
    /// Per car, `(step, route)` from the end of that step on, in step order.
    routes: Vec<Vec<(i64, Arc<Route>)>>,
    /// Each decision's reads (`DecisionReads`), in the order of `deciders`:
    /// the tracks it read, each with the position from which on a car
    /// there could change it, are `reads[start..end]`.
    decisions: Vec<DecisionReads>,
    reads: Vec<(usize, f64)>,
    /// The cars that decided, step by step in car order
    /// (`deciders[deciders_from[step]..deciders_from[step + 1]]`).
    deciders: Vec<usize>,
    deciders_from: Vec<usize>,
    /// Per car, `(step, state at the end of that step)` in step order; step
    /// -1 is the start.
    snapshots: Vec<Vec<(i64, SimCar<'a>)>>,
    /// What leaders showed their followers (their drive queues, when they
    /// re-planned), in step order.
    shown: Vec<Shown>,
    /// This step: where each car stood, and which cars something changed;
    /// whether the occupancy was filled (the drivers are deciding).
    current_places: Vec<Places>,
    touched: Vec<bool>,
    filled: bool,
    /// Whether any cars collided.
    pub(super) collided: bool,
}

/// The tracks one decision read: `Tape::reads[reads.0..reads.1]`, and a
/// bit for each (`track_bit`), so that a re-run can tell in one test that
/// none of them was marked changed (most of the time).
#[derive(Debug, Clone, Copy)]
struct DecisionReads {
    reads: (usize, usize),
    tracks: u64,
}

/// A track's bit in [`DecisionReads::tracks`]: tracks 64 apart share one.
fn track_bit(track: usize) -> u64 {
    1 << (track % 64)
}

/// A leader's drive queue shown to its followers (`Sim::show_followers`):
/// at step `step`, in its re-planning phase (before the drivers decide) or
/// as a driver gave up a lane change.
struct Shown {
    step: usize,
    replanning: bool,
    leader: usize,
    seen: Vec<Action>,
    merges: Vec<f64>,
}

impl<'a> Tape<'a> {
    /// An empty tape for `cars` (as they start) and `steps` steps of `dt`
    /// seconds.
    fn new(cars: &[SimCar<'a>], steps: usize, dt: f64) -> Tape<'a> {
        let n = cars.len();
        let size = n * steps;
        // A snapshot at every decision (one per reaction time) and a few
        // more: reserved, as copying a growing list of cars cost more than
        // taking them.
        let decisions = |c: &SimCar| (steps as f64 * dt / c.driver.reaction_time.max(dt)).ceil() as usize + 4;
        Tape {
            cars: n,
            places: Vec::with_capacity(size),
            speed: Vec::with_capacity(size),
            actions_done: Vec::with_capacity(size),
            s_wander: Vec::with_capacity(size),
            near: Vec::with_capacity(size),
            near_shift: Vec::with_capacity(steps),
            routes: cars.iter().map(|c| vec![(-1, Arc::clone(&c.route))]).collect(),
            decisions: Vec::new(),
            reads: Vec::new(),
            deciders: Vec::new(),
            deciders_from: Vec::with_capacity(steps + 1),
            snapshots: cars
                .iter()
                .map(|c| {
                    let mut snapshots = Vec::with_capacity(decisions(c));
                    snapshots.push((-1, c.clone()));
                    snapshots
                })
                .collect(),
            shown: Vec::new(),
            current_places: vec![Places::default(); n],
            touched: vec![false; n],
            filled: false,
            collided: false,
        }
    }

    /// Car `i` stands at `places` in this step's occupancy.
    pub(super) fn note_places(&mut self, i: usize, places: &Places) {
        self.current_places[i] = *places;
    }

    /// The collision check's near points and extents this step (`None`:
    /// off the map).
    #[inline]
    pub(super) fn note_extents(&mut self, extents: impl Iterator<Item = Option<(DVec2, f64)>>) {
        let from = self.near.len();
        self.near.extend(extents.map(|e| e.unwrap_or((DVec2::NAN, 0.0))));
        let (before, now) = self.near.split_at(from);
        let before = from.checked_sub(self.cars).map(|at| &before[at..]);
        let shift = |(k, &(point, extent)): (usize, &(DVec2, f64))| match before.map(|b| b[k]) {
            // Off the map: near nothing.
            _ if point.is_nan() => 0.0,
            Some((was, grown_from)) if !was.is_nan() => point.distance(was) + (extent - grown_from).max(0.0),
            // The first step, or back on the map.
            _ => f64::INFINITY,
        };
        self.near_shift.push(now.iter().enumerate().map(shift).fold(0.0, f64::max));
    }

    /// Car `car`'s footprint after moving in step `step`, as the factual
    /// run had it.
    fn footprint(&self, step: usize, car: usize, plan: &CarPlan) -> OrientedBox {
        let routes = &self.routes[car];
        let route = &routes[routes.partition_point(|(k, _)| *k <= step as i64) - 1].1;
        let (s, wander) = self.s_wander[self.index(step, car)];
        let (centre, heading) = route.pose_at(s, wander);
        OrientedBox { centre, heading, length: plan.length, width: plan.width }
    }

    /// Something besides its own motion changed car `i` in this step.
    pub(super) fn touch(&mut self, i: usize) {
        self.touched[i] = true;
    }

    /// Car `leader` showed its followers its drive queue `seen` (merges at
    /// `merges`) in this step.
    pub(super) fn note_shown(&mut self, leader: usize, seen: &[Action], merges: &[f64]) {
        let filled = self.places.len() / self.cars;
        let (step, replanning) = if self.filled { (filled - 1, false) } else { (filled, true) };
        self.shown.push(Shown { step, replanning, leader, seen: seen.to_vec(), merges: merges.to_vec() });
    }

    /// What leaders showed their followers at `step`.
    fn shown_at(&self, step: usize) -> &[Shown] {
        let start = self.shown.partition_point(|e| e.step < step);
        let end = start + self.shown[start..].partition_point(|e| e.step == step);
        &self.shown[start..end]
    }

    fn index(&self, step: usize, car: usize) -> usize {
        step * self.cars + car
    }

    /// The decisions taken at `step` (positions in `deciders`, in car order).
    fn decisions_at(&self, step: usize) -> std::ops::Range<usize> {
        let end = self.deciders_from.get(step + 1).copied().unwrap_or(self.deciders.len());
        self.deciders_from[step]..end
    }

    /// The tracks decision `d` (a position in `deciders`) read.
    fn reads_of(&self, d: usize) -> &[(usize, f64)] {
        let (start, end) = self.decisions[d].reads;
        &self.reads[start..end]
    }
}

impl Sim<'_> {
    /// Taping: the occupancy just filled, with each car's speed and actions done.
    pub(super) fn note_fill(&mut self) {
        let Some(tape) = &mut self.tape else { return };
        tape.places.extend_from_slice(&tape.current_places);
        tape.current_places.fill(Places::default());
        tape.filled = true;
        for car in &self.cars {
            tape.speed.push(car.v);
            tape.actions_done.push(car.actions_done);
        }
        tape.deciders_from.push(tape.deciders.len());
    }

    /// Taping: car `i` just decided, reading the tracks noted since it began.
    pub(super) fn note_decision(&mut self, i: usize) {
        let (Some(tape), Some(reads)) = (&mut self.tape, &self.reads) else { return };
        let start = tape.reads.len();
        tape.reads.extend(reads.borrow().iter().copied());
        let tracks = tape.reads[start..].iter().fold(0, |bits, &(track, _)| bits | track_bit(track));
        let step = tape.places.len() / tape.cars - 1;
        debug_assert!(
            tape.decisions_at(step).last().is_none_or(|d| tape.deciders[d] < i),
            "car {i} decided twice, or out of car order, in step {step}"
        );
        tape.decisions.push(DecisionReads { reads: (start, tape.reads.len()), tracks });
        tape.deciders.push(i);
        tape.touched[i] = true;
    }

    /// Taping: the end of a step: every car's pose, and a snapshot of each
    /// car something besides its motion changed.
    pub(super) fn note_step_end(&mut self) {
        let Some(tape) = &mut self.tape else { return };
        tape.filled = false;
        let step = (tape.places.len() / tape.cars) as i64 - 1;
        for (i, car) in self.cars.iter().enumerate() {
            tape.s_wander.push((car.s, car.wander));
            let routes = &mut tape.routes[i];
            if !Arc::ptr_eq(&routes[routes.len() - 1].1, &car.route) {
                routes.push((step, Arc::clone(&car.route)));
            }
            if std::mem::take(&mut tape.touched[i]) {
                tape.snapshots[i].push((step, car.clone()));
            }
        }
    }
}

/// A scenario's factual run recorded for its effects re-runs.
pub struct Recording<'a> {
    /// The drivers' car-following model.
    model: &'static dyn CarFollowing,
    map: &'a CityMap,
    plan: &'a ScenarioPlan,
    factual: Trajectories,
    tape: Tape<'a>,
    /// Each car's followers.
    followers: Vec<Vec<usize>>,
}

impl<'a> Recording<'a> {
    /// Simulates `plan` (its city parts `city`) recording the tape; `None`
    /// when `stop` was set. The run is the factual one: the same
    /// trajectories as simulating `plan` without recording.
    pub fn record(
        map: &'a CityMap,
        plan: &'a ScenarioPlan,
        city: &'a CityPlan,
        stop: &AtomicBool,
    ) -> Option<Recording<'a>> {
        let model = model_by_name(city.driver_model);
        let mut sim = Sim::new(map, plan, city, model);
        sim.reads = Some(RefCell::new(Vec::new()));
        let steps = (plan.frame_interval / MAX_STEP).ceil().max(1.0) as usize;
        let dt = plan.frame_interval / steps as f64;
        sim.tape = Some(Box::new(Tape::new(&sim.cars, steps * (plan.frames as usize).saturating_sub(1), dt)));
        let factual = sim.run(stop)?;
        let tape = *sim.tape.take().expect("set above");
        let mut followers = vec![Vec::new(); sim.cars.len()];
        for (i, car) in sim.cars.iter().enumerate() {
            if let Some(leader) = car.leader.filter(|&l| l < followers.len()) {
                followers[leader].push(i);
            }
        }
        Some(Recording { model, map, plan, factual, tape, followers })
    }

    /// The factual run's trajectories.
    pub fn factual(&self) -> &Trajectories {
        &self.factual
    }

    /// The factual run's trajectories, the recording dropped.
    pub fn into_factual(self) -> Trajectories {
        self.factual
    }

    /// Whether re-runs can replay cars from this recording: the plan has no
    /// interventions of its own or actuated lights, and no cars collided.
    pub fn replayable(&self) -> bool {
        let fixed_lights = self.plan.world.city().is_none_or(|c| c.lights.actuated.is_empty());
        self.plan.interventions.is_empty() && !self.tape.collided && !self.factual.states.is_empty() && fixed_lights
    }

    /// Whether recording `plan` for its re-runs can pay: it has no
    /// interventions of its own, at least [`MIN_CARS_TO_REPLAY`] cars (with
    /// fewer, recording and bookkeeping cost more than they save), and a
    /// tape within [`MAX_TAPE_BYTES`] (a very long scenario re-runs in full
    /// rather than hold gigabytes), and no actuated lights.
    pub fn pays_for(plan: &ScenarioPlan) -> bool {
        let steps = (plan.frame_interval / MAX_STEP).ceil().max(1.0) as usize * plan.frames as usize;
        let tape_bytes = plan.cars.len().saturating_mul(steps).saturating_mul(TAPE_BYTES_PER_CAR_STEP);
        // Actuated lights answer to every car, so a re-run's lights can
        // differ from the recording's: no car could be replayed on trust.
        let fixed_lights = plan.world.city().is_none_or(|c| c.lights.actuated.is_empty());
        plan.interventions.is_empty()
            && plan.cars.len() >= MIN_CARS_TO_REPLAY
            && tape_bytes <= MAX_TAPE_BYTES
            && fixed_lights
    }

    /// Re-simulates `changed` (the recorded plan with interventions on car
    /// `cause` only), replaying the cars it has not reached; the positions
    /// and interactions are those of simulating every car (no lights or
    /// events), and what it replayed. `None` when `stop` was set.
    /// Anything else (a recording that is not [`Recording::replayable`],
    /// other interventions) is simulated in full, with no car step replayed.
    pub fn rerun(&self, changed: &ScenarioPlan, cause: usize, stop: &AtomicBool) -> Option<(Trajectories, Replayed)> {
        let (run, replayed) = self.rerun_frames(changed, cause, stop)?;
        let trajectories = match run {
            RerunTrajectories::Full(trajectories) => trajectories,
            RerunTrajectories::Replayed(frames) => frames.to_trajectories(changed.frame_interval),
        };
        Some((trajectories, replayed))
    }

    /// [`Recording::rerun`], a replayed re-run kept as the frames of the
    /// cars it simulated (the others' are the factual run's).
    pub fn rerun_frames(
        &self,
        changed: &ScenarioPlan,
        cause: usize,
        stop: &AtomicBool,
    ) -> Option<(RerunTrajectories<'_>, Replayed)> {
        let WorldPlan::City(city) = &changed.world else { return None };
        if !self.replayable() || !replays(changed, cause) {
            let mut sim = Sim::new(self.map, changed, city, self.model);
            return Some((RerunTrajectories::Full(sim.run(stop)?), Replayed::default()));
        }
        // The start is the factual run's, as the tape has it (its cars only
        // differ by the intervention, which has not fired yet), and so is
        // the occupancy it left.
        let start = self.tape.snapshots.iter().map(|s| s[0].1.clone()).collect();
        let mut sim = Sim::with_cars(self.map, changed, city, self.model, start);
        sim.fill_occupancy();
        let n = sim.cars.len();
        // The cause and its followers (theirs, and so on) are simulated.
        sim.frozen = vec![true; n];
        sim.live.clear();
        for m in self.subtree(cause) {
            sim.thaw(m);
        }
        let steps = (changed.frame_interval / MAX_STEP).ceil().max(1.0) as usize;
        let dt = changed.frame_interval / steps as f64;
        let mut buffers = StepBuffers {
            dirty: vec![CLEAN; self.map.track_count()],
            clearances: vec![Clearance::default(); n],
            ..StepBuffers::default()
        };
        let frames = changed.frames as usize;
        let mut run = RerunFrames::new(&self.factual, n);
        let replaces_queue = matches!(changed.interventions[0].effect, Effect::ReplaceActions { .. });
        let (mut replayed, mut cause_replayed_steps) = (0, 0);
        for frame in 0..frames {
            if stop.load(Ordering::Relaxed) {
                return None;
            }
            if frame > 0 {
                for k in (frame - 1) * steps..frame * steps {
                    let t = Sim::step_time(k, steps, changed.frame_interval, dt);
                    if let Some(car) = sim.deferred.as_ref().filter(|d| d.wake_at == k).map(|d| d.car) {
                        sim.wake(self, car, k as i64 - 1, steps, dt);
                    }
                    sim.replay_step(self, k, t, dt, steps, &mut buffers);
                    cause_replayed_steps += usize::from(sim.deferred.is_some());
                    if k == 0 && replaces_queue {
                        sim.defer(self, cause, steps, dt, &mut run);
                    }
                    replayed += n - sim.live.len();
                }
            }
            let t = frame as f64 * changed.frame_interval;
            sim.fire_interventions(t, dt);
            // A car simulated once stays simulated.
            for &i in &sim.live {
                run.push(i, frame, sim.cars[i].state(), Some(sim.cars[i].binding));
            }
        }
        let run_steps = steps * frames.saturating_sub(1);
        let StepBuffers { shown_from_tape, tries, woke, .. } = buffers;
        let replayed = Replayed {
            car_steps: replayed,
            of: n * run_steps,
            steps: run_steps,
            shown_from_tape,
            tries,
            woke,
            cause_replayed_steps,
        };
        Some((RerunTrajectories::Replayed(run), replayed))
    }
}

/// What a re-run replayed from the factual run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Replayed {
    /// Car steps replayed, of all the re-run's car steps.
    pub car_steps: usize,
    pub of: usize,
    /// The re-run's steps (each car's: `of` is this times the cars).
    pub steps: usize,
    /// Drive queues that replayed leaders showed followers from the tape:
    /// simulated followers as the leaders re-planned, followers woken in
    /// that step, and simulated followers as the leaders gave up lane
    /// changes.
    pub shown_from_tape: [usize; 3],
    /// Decisions of replayed cars tried because they read where a simulated
    /// car differed from the tape, and how many of them woke their car.
    pub tries: usize,
    pub woke: usize,
    /// Steps in which the cause of a re-run that replaced its drive queue
    /// was replayed (its re-planned route could not matter yet: see
    /// `Recording::deferral_end`), rather than simulated.
    pub cause_replayed_steps: usize,
}

/// How clear a simulated car is of every taped car, as of the end of step
/// `step` (`usize::MAX`: never seen): its near point and extent then, and
/// a lower bound on the least `distance - extent - extent` over the taped
/// cars, metres (exact at a step that checked every pair; negative when a
/// pair was a candidate).
#[derive(Debug, Clone, Copy)]
struct Clearance {
    step: usize,
    point: DVec2,
    extent: f64,
    gap: f64,
}

impl Default for Clearance {
    fn default() -> Clearance {
        Clearance { step: usize::MAX, point: DVec2::NAN, extent: 0.0, gap: f64::NEG_INFINITY }
    }
}

/// What a simulated car must have to spare, metres, to skip the taped cars
/// in a collision check: far more than the round-off of the gaps summed
/// over a run (about 1e-10 m), far less than the gaps themselves (metres).
const CLEARANCE_MARGIN_M: f64 = 1e-3;

/// A track no simulated car marked, in [`StepBuffers::dirty`]. Tested with
/// `!= CLEAN`: a whole-track read's bound is negative infinity too, so
/// `>=` alone would find an unmarked track changed.
const CLEAN: f64 = f64::NEG_INFINITY;

/// What a re-run's steps reuse (nothing allocated per step): per track
/// the farthest position along it at which a simulated car stands, or
/// stood in the factual run, otherwise than the tape says ([`CLEAN`]:
/// none), the tracks marked, the decisions of replayed cars tried
/// (positions in the tape's `deciders`), and each car's clearance of the
/// taped cars.
#[derive(Default)]
struct StepBuffers {
    dirty: Vec<f64>,
    marked: Vec<usize>,
    trying: Vec<usize>,
    /// Per car, how clear of the taped cars it last was.
    clearances: Vec<Clearance>,
    /// Queues shown from the tape so far, decisions tried and cars they
    /// woke (see [`Replayed`]).
    shown_from_tape: [usize; 3],
    tries: usize,
    woke: usize,
}

/// Whether `changed`'s interventions are ones a re-run replays around:
/// one, from time 0, removing car `cause` or replacing its actions (what
/// the other cars read of it stays in the occupancy, its speed and its
/// actions done).
fn replays(changed: &ScenarioPlan, cause: usize) -> bool {
    match changed.interventions.as_slice() {
        [only] => {
            only.trigger == Trigger::At(0.0)
                && matches!(only.effect, Effect::Remove { car } | Effect::ReplaceActions { car, .. } if car == cause)
        }
        _ => false,
    }
}

/// A re-run's cause whose drive queue the intervention replaced at time 0,
/// replayed from the tape while it drives as the factual run did: its
/// re-planned route matches the factual one up to some leg, and until its
/// driving could read that leg (see [`Recording::deferral_end`]) nothing
/// it does can differ. It wakes then (or earlier, like any replayed car)
/// and takes its re-planned route and queue.
pub(super) struct Deferred<'a> {
    car: usize,
    /// The step at whose start it wakes at the latest.
    wake_at: usize,
    /// The car as re-planned at step 0 (its route and drive queue).
    replanned: SimCar<'a>,
}

/// Room (metres) a deferred cause keeps from the first leg of its re-planned
/// route that differs, beyond what its perception reads: more than a car's
/// half length plus a step's travel (the front, the legs a step completes).
const DEFERRAL_MARGIN_M: f64 = 5.0;

impl<'s> Sim<'s> {
    /// After step 0 of a re-run that replaced car `cause`'s drive queue
    /// (it re-planned in that step, showing its followers): replays the car
    /// from the tape until its re-planned route can matter, if it drives as
    /// the factual run did so far ([`Recording::deferral_end`]).
    fn defer(&mut self, rec: &Recording<'s>, cause: usize, steps: usize, dt: f64, run: &mut RerunFrames) {
        let replanned = self.cars[cause].clone();
        // Its frame 0 is the factual one (pushed before the intervention fired).
        debug_assert!(run.state(0, cause) == &rec.factual.states[0][cause]);
        self.catch_up(rec, cause, 0, steps, dt);
        let factual = &self.cars[cause];
        let start = &rec.tape.snapshots[cause][0].1;
        let alike = replanned.pending_actions.is_none()
            && replanned.action_base == start.action_base
            && replanned.same_motion(factual)
            && factual.same_queue(start);
        let wake_at = if alike { rec.deferral_end(cause, &replanned) } else { 0 };
        if wake_at < 2 {
            self.cars[cause] = replanned;
            return;
        }
        self.frozen[cause] = true;
        self.live.retain(|&i| i != cause);
        run.forget(cause);
        self.deferred = Some(Box::new(Deferred { car: cause, wake_at, replanned }));
    }
}

impl Recording<'_> {
    /// The step at whose start car `car`, re-planned as `replanned` at step
    /// 0, must be simulated at the latest (0: throughout): the first at
    /// which the factual car changed its route or queue, or showed its
    /// followers one, or at which its driving could read the first leg `m`
    /// where the re-planned route differs:
    /// - perception reads the legs that start within [`LOOKAHEAD`] of the
    ///   car's centre, and a claim at the stop line before leg `m`;
    /// - by index, the legs after its own: the next leg's kind and start
    ///   (claims, completed legs, a lane change ahead), the one after it
    ///   for the connector the car committed to (one of the legs before
    ///   `m`: checked that neither route has it again at `m` or `m + 1`),
    ///   and a lane change's next leg when the car moves the change along
    ///   its lane (`Route::move_lane_change`), which it does only near the
    ///   change. So the legs from `m` on are out of index reach while the
    ///   car is two legs before the `edge` (`m`, or `m - 1` when that leg
    ///   is a lane change), and on the leg just before the edge while it
    ///   decides moving and far from the edge: a lane change at the edge
    ///   matters to a decision only near it or at rest (`Sim::merge_wait`).
    fn deferral_end(&self, car: usize, replanned: &SimCar) -> usize {
        let tape = &self.tape;
        let start = &tape.snapshots[car][0].1;
        let steps = tape.s_wander.len() / tape.cars;
        let (old, new) = (&start.route.legs, &replanned.route.legs);
        let m = old.iter().zip(new.iter()).take_while(|(a, b)| a == b).count();
        // The centre's route position at the start of step `k`.
        let s_at = |k: usize| if k == 0 { start.s } else { tape.s_wander[tape.index(k - 1, car)].0 };
        let horizon = if m == old.len() && m == new.len() {
            // The same legs: the route cannot matter.
            steps
        } else if m == 0 {
            0
        } else {
            // Perception's reach: leg m (in either route) and the stop line
            // before it beyond it.
            let leg_m = [old.get(m), new.get(m)].into_iter().flatten().map(|l| l.route_start);
            let reach = LOOKAHEAD.max(self.map.layout.stop_line_setback + start.plan.length);
            let read_from = leg_m.fold(f64::INFINITY, f64::min) - reach - DEFERRAL_MARGIN_M;
            // The index reach.
            let connector = |l: &RouteLeg| match l.kind {
                LegKind::Connector(c) => Some(c),
                _ => None,
            };
            let committed_again = |legs: &[RouteLeg]| {
                legs.iter()
                    .skip(m)
                    .take(2)
                    .filter_map(connector)
                    .any(|c| old[..m].iter().any(|l| connector(l) == Some(c)))
            };
            let committed_again = committed_again(old) || committed_again(new);
            let edge = if matches!(old[m - 1].kind, LegKind::LaneChange { .. }) { m - 1 } else { m };
            // Free on the legs before `free_until` (route metres, with room);
            // on the leg before the edge only as its decisions allow.
            let before = |leg: usize| old[leg].route_start - DEFERRAL_MARGIN_M;
            let (free_until, edge_leg_ok) = match (committed_again, edge) {
                // Free only at least three legs before the edge, whatever is committed.
                (true, edge) if edge >= 3 => (before(edge - 2), false),
                (true, _) => (f64::NEG_INFINITY, false),
                (false, edge) if edge >= 2 => (before(edge - 1), true),
                (false, _) => (f64::NEG_INFINITY, true),
            };
            let edge_start = [old.get(edge), new.get(edge)].into_iter().flatten().map(|l| l.route_start);
            let edge_start = edge_start.fold(f64::INFINITY, f64::min);
            let both_go_on = old.len() > edge && new.len() > edge;
            // The driver changes only with a confounder intervention, and a
            // deferred re-run has only its own intervention.
            let reaction_time = start.driver.reaction_time;
            let drives_alike = |k: usize| {
                let s = s_at(k);
                if s >= read_from {
                    return false;
                }
                if s < free_until {
                    return true;
                }
                if !(edge_leg_ok && both_go_on && s < edge_start) {
                    return false;
                }
                // On the leg before the edge: at a decision, moving and far off.
                let decides = tape.decisions_at(k).any(|d| tape.deciders[d] == car);
                let v = tape.speed[tape.index(k, car)];
                let near = v * (reaction_time + 0.5) + 1.5 + DEFERRAL_MARGIN_M;
                !decides || (v >= 0.1 && edge_start - s > near)
            };
            (0..steps).find(|&k| !drives_alike(k)).unwrap_or(steps)
        };
        // A snapshot or route from the end of step j: awake at its start.
        let from_step = |step: i64| usize::try_from(step).unwrap_or(0);
        let route_changed = tape.routes[car].get(1).map_or(steps, |&(step, _)| from_step(step));
        let queue_changed = tape.snapshots[car][1..]
            .iter()
            .find(|(_, snapshot)| !snapshot.same_queue(start))
            .map_or(steps, |&(step, _)| from_step(step));
        let showed = tape.shown.iter().find(|e| e.leader == car).map_or(steps, |e| e.step);
        horizon.min(route_changed).min(queue_changed).min(showed)
    }

    /// Car `c` and its followers, theirs, and so on: a leader's re-planning
    /// reaches its followers, so a simulated car's followers are simulated
    /// too, while its leader can be replayed (its re-plans shown to it from
    /// the tape).
    fn subtree(&self, c: usize) -> Vec<usize> {
        let mut cars = vec![c];
        let mut next = 0;
        while next < cars.len() {
            for &f in &self.followers[cars[next]] {
                if !cars.contains(&f) {
                    cars.push(f);
                }
            }
            next += 1;
        }
        cars
    }
}

impl<'s> Sim<'s> {
    /// One step of a re-run (global step `k`, from `t` to `t + dt` seconds):
    /// [`Sim::step`] for the simulated cars, the tape for the replayed ones.
    #[inline(always)]
    fn replay_step(&mut self, rec: &Recording<'s>, k: usize, t: f64, dt: f64, steps: usize, buffers: &mut StepBuffers) {
        let n = self.cars.len();
        self.fire_interventions(t, dt);
        // Re-planning in car order, a replayed leader's re-plans shown to its
        // simulated followers from the tape.
        // (Most steps nothing was shown: only the simulated cars' own
        // re-plans, in car order.)
        let shown = rec.tape.shown_at(k);
        if shown.is_empty() {
            for at in 0..self.live.len() {
                let i = self.live[at];
                if self.cars[i].pending_actions.is_some() {
                    self.replace_actions(i, t);
                }
            }
        } else {
            for i in 0..n {
                if !self.frozen[i] {
                    if self.cars[i].pending_actions.is_some() {
                        self.replace_actions(i, t);
                    }
                } else {
                    buffers.shown_from_tape[0] += self.show_taped(shown, true, i, |sim, f| !sim.frozen[f]);
                }
            }
        }
        // Replayed cars about to decide on what may differ from the factual
        // run try the decision; those who decide otherwise wake up. (Most
        // steps no replayed car decides, and nothing need be marked.)
        let StepBuffers { dirty, marked, trying, clearances, shown_from_tape, tries, woke } = buffers;
        trying.clear();
        trying.extend(rec.tape.decisions_at(k).filter(|&d| self.frozen[rec.tape.deciders[d]]));
        if !trying.is_empty() {
            self.mark_dirty(rec, k, dirty, marked);
            if marked.is_empty() {
                trying.clear();
            } else {
                let changed = |&(track, from): &(usize, f64)| dirty[track] != CLEAN && dirty[track] >= from;
                let marked_bits = marked.iter().fold(0, |bits, &track| bits | track_bit(track));
                trying.retain(|&d| {
                    rec.tape.decisions[d].tracks & marked_bits != 0 && rec.tape.reads_of(d).iter().any(changed)
                });
            }
            for &track in marked.iter() {
                dirty[track] = CLEAN;
            }
        }
        let mut waking = Vec::new();
        // Whether the occupancy and the replayed cars' speeds are this
        // step's as the simulated drivers about to decide must see them.
        let mut filled_now = false;
        if !trying.is_empty() {
            self.fill_replayed(rec, k);
            filled_now = true;
            *tries += trying.len();
            for &c in trying.iter().map(|&d| &rec.tape.deciders[d]) {
                if !self.decides_as_taped(rec, c, k, t, dt, steps) {
                    waking.push(c);
                }
            }
            *woke += waking.len();
        }
        if !waking.is_empty() {
            // The woken cars are simulated now: the occupancy is filled again.
            filled_now = false;
            let mut woken = vec![false; n];
            for c in waking {
                for m in self.wake(rec, c, k as i64 - 1, steps, dt) {
                    woken[m] = true;
                }
            }
            // Their re-planning this step, as the factual run had it (they
            // were replayed until now): in car order, what their leaders
            // showed them from the tape (simulated followers were shown it
            // above).
            self.quiet_followers = true;
            for i in 0..n {
                if woken[i] && self.cars[i].pending_actions.is_some() {
                    self.replace_actions(i, t);
                }
                if !shown.is_empty() {
                    shown_from_tape[1] += self.show_taped(shown, true, i, |_, f| woken[f]);
                }
            }
            self.quiet_followers = false;
        }
        // A step that simulates no car on the map (a removed cause and no
        // followers, or none while a deferred cause has none) ends here, as
        // about a third of a re-run's steps do in `make bench`'s 8-car city
        // effects (0.2 s frames): no one decides or moves, and the collision
        // check would find no pair and end any contact.
        if shown.is_empty() && self.live.iter().all(|&i| self.cars[i].removed) {
            self.contacts.clear();
            return;
        }
        // What the simulated drivers deciding now see, replayed cars as taped.
        let due = |car: &SimCar| !car.removed && t + 1e-9 >= car.next_decision;
        if self.live.iter().any(|&i| due(&self.cars[i])) {
            // A try leaves the occupancy as it found it, and its car's speed
            // and actions done as taped: what the tries saw stands, unless
            // one woke its car.
            if !filled_now {
                self.fill_replayed(rec, k);
            }
            for at in 0..self.live.len() {
                let i = self.live[at];
                if due(&self.cars[i]) {
                    self.decide(i, t, dt);
                    self.cars[i].next_decision = t + self.cars[i].driver.reaction_time;
                }
            }
        }
        // Lane changes replayed leaders gave up as they decided, shown to
        // their simulated followers.
        if !shown.is_empty() {
            for i in 0..n {
                if self.frozen[i] {
                    shown_from_tape[2] += self.show_taped(shown, false, i, |sim, f| !sim.frozen[f]);
                }
            }
        }
        for at in 0..self.live.len() {
            let i = self.live[at];
            if !self.cars[i].removed {
                self.advance(i, t, dt);
            }
        }
        self.replayed_collisions(rec, k, t + dt, steps, dt, clearances);
    }

    /// Shows the followers of car `leader` for which `to` holds what the
    /// tape says `leader` showed them at this step (`shown`), in its
    /// re-planning phase or not (`replanning`); returns how many it showed.
    fn show_taped(
        &mut self,
        shown: &[Shown],
        replanning: bool,
        leader: usize,
        to: impl Fn(&Sim, usize) -> bool,
    ) -> usize {
        let mut count = 0;
        for event in shown.iter().filter(|e| e.leader == leader && e.replanning == replanning) {
            for follower in self.followers_of(leader) {
                if to(self, follower) {
                    self.show_queue(follower, &event.seen, &event.merges);
                    count += 1;
                }
            }
        }
        count
    }

    /// Whether replayed car `c`, deciding at step `k` (time `t`) on this
    /// step's occupancy, ends the step as the factual run had it: brought up
    /// to date, it re-plans, decides and moves (its followers told nothing),
    /// and is compared with its snapshot. Either way it stays replayed.
    fn decides_as_taped(&mut self, rec: &Recording<'s>, c: usize, k: usize, t: f64, dt: f64, steps: usize) -> bool {
        self.catch_up(rec, c, k as i64 - 1, steps, dt);
        self.quiet_followers = true;
        if self.cars[c].pending_actions.is_some() {
            self.replace_actions(c, t);
            // If the decision changed the route instead, the comparison
            // below fails and the car simply wakes.
            self.take_taped_route(rec, c, k as i64);
        }
        self.decide(c, t, dt);
        self.cars[c].next_decision = t + self.cars[c].driver.reaction_time;
        self.advance(c, t, dt);
        self.quiet_followers = false;
        let snapshots = &rec.tape.snapshots[c];
        let (step, taped) = &snapshots[snapshots.partition_point(|(step, _)| *step <= k as i64) - 1];
        let same = *step == k as i64 && self.cars[c].same_state(taped);
        // Replayed again: what others read of it is the tape's.
        let index = rec.tape.index(k, c);
        self.cars[c].v = rec.tape.speed[index];
        self.cars[c].actions_done = rec.tape.actions_done[index];
        same
    }

    /// What simulated drivers deciding at step `k` see: the occupancy,
    /// simulated cars where they are and replayed ones where the tape has
    /// them, and the replayed cars' speeds and actions done as taped.
    fn fill_replayed(&mut self, rec: &Recording<'s>, k: usize) {
        self.clear_occupancy();
        for i in 0..self.cars.len() {
            let places = if self.frozen[i] {
                let index = rec.tape.index(k, i);
                self.cars[i].v = rec.tape.speed[index];
                self.cars[i].actions_done = rec.tape.actions_done[index];
                rec.tape.places[index]
            } else if self.cars[i].removed {
                continue;
            } else {
                self.places(i)
            };
            for &(track, pos) in places.iter() {
                self.occupy(track, i, pos);
            }
        }
    }

    /// Marks in `dirty` every track on which a simulated car stands, or stood
    /// in the factual run, when it is not where and as fast as the tape says
    /// at step `k`, with the farthest such position along it; lists the
    /// tracks marked in `marked`.
    #[inline(always)]
    fn mark_dirty(&self, rec: &Recording<'s>, k: usize, dirty: &mut [f64], marked: &mut Vec<usize>) {
        marked.clear();
        for &i in &self.live {
            let index = rec.tape.index(k, i);
            let taped = rec.tape.places[index];
            let car = &self.cars[i];
            let now = if car.removed { Places::default() } else { self.places(i) };
            let same = !car.removed
                && now == taped
                && car.v == rec.tape.speed[index]
                && car.actions_done == rec.tape.actions_done[index];
            if !same {
                for &(track, pos) in now.iter().chain(taped.iter()) {
                    if dirty[track] == CLEAN {
                        marked.push(track);
                    }
                    // The farthest along; a position that is not a number
                    // marks the whole track.
                    dirty[track] = if pos.is_nan() { f64::INFINITY } else { dirty[track].max(pos) };
                }
            }
        }
    }

    /// Brings car `c` and its replayed followers (theirs, and so on) up to
    /// the end of step `to` (-1: the start) from the tape and simulates them
    /// from then on; returns the cars woken.
    fn wake(&mut self, rec: &Recording<'s>, c: usize, to: i64, steps: usize, dt: f64) -> Vec<usize> {
        let woken: Vec<usize> = rec.subtree(c).into_iter().filter(|&m| self.frozen[m]).collect();
        for &m in &woken {
            self.catch_up(rec, m, to, steps, dt);
            if let Some(deferred) = self.deferred.take_if(|d| d.car == m) {
                // Its queue and route as the factual run had them until now:
                // the re-planned ones take their place.
                debug_assert!(self.cars[m].same_queue(&rec.tape.snapshots[m][0].1), "car {m}'s queue changed");
                self.cars[m].take_queue(&deferred.replanned);
            }
            self.thaw(m);
        }
        woken
    }

    /// Car `m` is simulated from now on.
    fn thaw(&mut self, m: usize) {
        self.frozen[m] = false;
        if let Err(at) = self.live.binary_search(&m) {
            self.live.insert(at, m);
        }
    }

    /// Car `m` as the factual run had it at the end of step `to`: its latest
    /// snapshot, moved on by the steps since (re-planning and motion only:
    /// nothing else changed it in between, or there would be a later
    /// snapshot).
    fn catch_up(&mut self, rec: &Recording<'s>, m: usize, to: i64, steps: usize, dt: f64) {
        let snapshots = &rec.tape.snapshots[m];
        let (from, snapshot) = &snapshots[snapshots.partition_point(|(step, _)| *step <= to) - 1];
        self.cars[m] = snapshot.clone();
        self.quiet_followers = true;
        for k in (from + 1)..=to {
            let t = Sim::step_time(k as usize, steps, self.plan.frame_interval, dt);
            if self.cars[m].pending_actions.is_some() {
                self.replace_actions(m, t);
                self.take_taped_route(rec, m, k);
            }
            self.advance(m, t, dt);
        }
        self.quiet_followers = false;
    }

    /// After car `m` re-planned at step `k`: the factual run's route from
    /// that step, if it has one (the same route, re-planned alike), so that
    /// the car compares equal to its later snapshots.
    fn take_taped_route(&mut self, rec: &Recording<'s>, m: usize, k: i64) {
        let routes = &rec.tape.routes[m];
        if let Ok(at) = routes.binary_search_by_key(&k, |(step, _)| *step) {
            self.cars[m].route = Arc::clone(&routes[at].1);
        }
    }

    /// [`Sim::detect_collisions`] at the end of step `k` (time `now`), a
    /// replayed car's footprint from the tape; a replayed car that a
    /// simulated one touches wakes up (with its followers) before the collision.
    #[inline(always)]
    fn replayed_collisions(
        &mut self,
        rec: &Recording<'s>,
        k: usize,
        now: f64,
        steps: usize,
        dt: f64,
        clearances: &mut [Clearance],
    ) {
        // Near points and extents: replayed cars' as taped, simulated ones'
        // (in `live` order) as they are now.
        let taped = &rec.tape.near[rec.tape.index(k, 0)..rec.tape.index(k + 1, 0)];
        let mut points = std::mem::take(&mut self.scratch_points);
        points.clear();
        for at in 0..self.live.len() {
            let car = &mut self.cars[self.live[at]];
            points.push((!car.removed).then(|| {
                let (point, radius) = car.near_point();
                (point, extent(car.reach, radius))
            }));
        }
        // Pairs of replayed cars did what they did in the factual run (no
        // collision): only pairs with a simulated car are looked at, by the
        // factual check's test (`Sim::candidate_pairs`).
        let mut candidates = std::mem::take(&mut self.scratch_pairs);
        candidates.clear();
        for (a, &i) in self.live.iter().enumerate() {
            let Some((pi, ei)) = points[a] else { continue };
            // Every replayed car, unless this one was clear of them all at
            // the step before by more than they and it can have closed in
            // since (what it had to spare, less its own point's move and its
            // extent's growth, less the most any taped car's did).
            let last = &mut clearances[i];
            let clear = last.step.checked_add(1) == Some(k) && {
                last.gap -= pi.distance(last.point) + (ei - last.extent).max(0.0) + rec.tape.near_shift[k];
                last.gap > CLEARANCE_MARGIN_M
            };
            *last = Clearance { step: k, point: pi, extent: ei, gap: last.gap };
            if !clear {
                let mut gap = f64::INFINITY;
                for (j, (&(pj, ej), &frozen)) in taped.iter().zip(&self.frozen).enumerate() {
                    if frozen {
                        if may_touch(pi, ei, pj, ej) {
                            candidates.push((i.min(j), i.max(j)));
                        }
                        // Not a number off the map: never the least.
                        gap = gap.min(pi.distance(pj) - ei - ej);
                    }
                }
                last.gap = gap;
            }
            // The simulated cars after it (a pair of simulated cars once).
            for (b, &j) in self.live.iter().enumerate().skip(a + 1) {
                if points[b].is_some_and(|(pj, ej)| may_touch(pi, ei, pj, ej)) {
                    candidates.push((i, j));
                }
            }
        }
        candidates.sort_unstable();
        let footprint = |sim: &Sim, x: usize| {
            if sim.frozen[x] {
                rec.tape.footprint(k, x, sim.cars[x].plan)
            } else {
                sim.cars[x].footprint()
            }
        };
        // A replayed car a simulated one touches wakes (with its followers) first.
        let wake = |sim: &mut Sim<'s>, i: usize, j: usize| {
            for x in [i, j] {
                if sim.frozen[x] {
                    sim.wake(rec, x, k as i64, steps, dt);
                }
            }
        };
        self.settle_pairs(&candidates, now, footprint, wake);
        self.scratch_points = points;
        self.scratch_pairs = candidates;
    }
}

#[cfg(test)]
impl Tape<'_> {
    /// Bytes the tape holds, its vectors' capacities and each snapshot's
    /// car with the vectors it owns (routes are shared with the plan).
    fn bytes(&self) -> usize {
        use std::mem::size_of;
        let snapshot = |car: &SimCar| {
            size_of::<(i64, SimCar)>()
                + car.actions.capacity() * size_of::<crate::map::Action>()
                + (car.merges.capacity() + car.given_up.capacity() + car.logged_adaptations.capacity()) * 8
        };
        self.places.capacity() * size_of::<Places>()
            + self.speed.capacity() * 8
            + self.actions_done.capacity() * 8
            + self.s_wander.capacity() * 16
            + self.near.capacity() * size_of::<(DVec2, f64)>()
            + self.near_shift.capacity() * 8
            + self.decisions.capacity() * size_of::<DecisionReads>()
            + self.reads.capacity() * size_of::<(usize, f64)>()
            + (self.deciders.capacity() + self.deciders_from.capacity()) * 8
            + self.snapshots.iter().flatten().map(|(_, car)| snapshot(car)).sum::<usize>()
            + self.shown.iter().map(|e| size_of::<Shown>() + e.seen.capacity() + e.merges.capacity() * 8).sum::<usize>()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::Expansion;
    use crate::spec::DatasetSpec;

    #[test]
    fn a_tape_stays_within_its_estimate_per_car_step() {
        let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/configs/city.json")).unwrap();
        let expansion = Expansion::new(DatasetSpec::from_json(&text).unwrap(), Arc::new(CityMap::default())).unwrap();
        let never = AtomicBool::new(false);
        let mut checked = 0;
        for key in expansion.keys(Some(2)).into_iter().filter(|k| k.group.starts_with("cars12")) {
            let plan = expansion.plan(&key).unwrap();
            let map = &expansion.town_of(&plan).map;
            let WorldPlan::City(city) = &plan.world else { panic!("a city plan") };
            let recording = Recording::record(map, &plan, city, &never).unwrap();
            let steps = (plan.frame_interval / MAX_STEP).ceil() as usize * (plan.frames as usize - 1);
            let per_car_step = recording.tape.bytes() as f64 / (plan.cars.len() * steps) as f64;
            assert!(
                per_car_step <= TAPE_BYTES_PER_CAR_STEP as f64,
                "{key:?}: {per_car_step:.0} bytes per car step, estimated {TAPE_BYTES_PER_CAR_STEP}"
            );
            checked += 1;
        }
        assert!(checked >= 2);
    }
}
