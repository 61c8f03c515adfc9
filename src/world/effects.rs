//! Interventional ground truth: which cars move which. For every car `a` the
//! scenario is simulated again with `a` intervened on from the start, once
//! with `a` removed and once with its next action changed, every other car
//! keeping its own random stream (the counterfactual machinery guarantees
//! that), and every other car's trajectory is compared with the factual one.
//! A car `b` is an effect of `a` when one of these re-runs moves it more than
//! [`EFFECT_THRESHOLD_M`] at some frame; the effect is direct when `b`
//! reacted to `a` itself (it follows `a`, or `a` bound its speed at the frame
//! where it first moved), not through another car or a light.
//!
//! In the city world a re-run simulates only the cars the intervention has
//! reached and replays the others from a recording of the factual run
//! (`world/city/replay.rs`); in the toy world, only the cars whose route it
//! changed (`toy::rerun`): the same result bit for bit, at a fraction of
//! the cost. [`Rerun::Full`] keeps the reference path.
//!
//! Units: metres; frames are the scenario's frame indices.

use super::city::replay::Recording;
use super::rerun::RerunTrajectories;
use super::{simulate_until, toy, Interaction, Trajectories};
use crate::map::{Action, CityMap, LegKind, Turn};
use crate::plan::interventions::{Effect, Intervention, Trigger};
use crate::plan::{ScenarioPlan, WorldPlan};
use std::sync::atomic::AtomicBool;

/// How far (metres, at one frame) a car must move from its factual
/// trajectory to count as an effect: a change a camera sees, not a rounding
/// or a millimetre of drift. 0.5 m is 6.4 px in the default bird's-eye view
/// (12.8 px per metre), thousands of times the pose log's rounding (0.1 mm,
/// 0.001 px), a quarter of a default car's length and a ninth of a
/// real-scale car's.
pub const EFFECT_THRESHOLD_M: f64 = 0.5;

/// A car counts as having moved at all (for where an effect began) beyond
/// this, metres: re-runs that change nothing about a car reproduce it bit for
/// bit, so this only ignores round-off.
const ONSET_M: f64 = 1e-6;

/// The interventions each car gets, all from time 0.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum InterventionKind {
    /// The car is taken off the map.
    Remove,
    /// The first action of its drive queue is replaced by another (see
    /// [`changed_action`]).
    NextAction,
}

impl InterventionKind {
    pub const ALL: [InterventionKind; 2] = [InterventionKind::Remove, InterventionKind::NextAction];

    /// The name `effects.csv` uses.
    pub fn name(self) -> &'static str {
        match self {
            InterventionKind::Remove => "remove",
            InterventionKind::NextAction => "next_action",
        }
    }

    pub fn from_name(name: &str) -> Option<InterventionKind> {
        InterventionKind::ALL.into_iter().find(|k| k.name() == name)
    }
}

/// What one intervention on `cause` did to `effect` (car ids).
#[derive(Debug, Clone, PartialEq)]
pub struct EffectRow {
    pub cause: u32,
    pub effect: u32,
    pub intervention: InterventionKind,
    /// Largest distance between the factual and the re-run position over
    /// the frames, metres.
    pub max_divergence_m: f64,
    /// First frame where that distance exceeds the threshold; `None` when
    /// it never does (no effect).
    pub first_frame: Option<u32>,
    /// The car reacted to `cause` itself (see the module documentation);
    /// false when there is no effect.
    pub direct: bool,
}

/// Every car's effect on every other car, for one scenario.
#[derive(Debug, Clone, PartialEq)]
pub struct EffectReport {
    pub threshold_m: f64,
    /// By cause, then intervention, then effect.
    pub rows: Vec<EffectRow>,
}

impl EffectReport {
    /// (cause, effect) pairs with an effect under some intervention, sorted.
    pub fn causal_edges(&self) -> Vec<(u32, u32)> {
        self.edges(|_| true)
    }

    /// The causal edges where the effect is direct, sorted.
    pub fn direct_edges(&self) -> Vec<(u32, u32)> {
        self.edges(|r| r.direct)
    }

    /// The `designed` (leader, follower) edges that no intervention backs.
    pub fn edges_without_effect(&self, designed: &[(u32, u32)]) -> Vec<(u32, u32)> {
        let causal = self.causal_edges();
        designed.iter().filter(|e| !causal.contains(e)).copied().collect()
    }

    fn edges(&self, keep: impl Fn(&EffectRow) -> bool) -> Vec<(u32, u32)> {
        let mut edges: Vec<(u32, u32)> =
            self.rows.iter().filter(|r| r.first_frame.is_some() && keep(r)).map(|r| (r.cause, r.effect)).collect();
        edges.sort_unstable();
        edges.dedup();
        edges
    }
}

/// The action that replaces `car`'s next action under
/// [`InterventionKind::NextAction`]: a turn becomes straight on; straight on
/// becomes a right turn where the lane it reaches the intersection in has
/// one, else a left turn; a merge goes to the other side. `None` for a car
/// with no actions.
pub fn changed_action(map: &CityMap, plan: &ScenarioPlan, car: usize) -> Option<Action> {
    let c = &plan.cars[car];
    let next = *c.actions.first()?;
    Some(match next {
        Action::Left | Action::Right | Action::SlightLeft | Action::SlightRight => Action::Straight,
        Action::MergeL => Action::MergeR,
        Action::MergeR => Action::MergeL,
        Action::Straight => {
            // The lane before the connector that carries out action 0.
            let legs = &c.route.legs;
            let approach =
                legs.iter().position(|l| l.action == Some(0)).and_then(|k| match legs[k.checked_sub(1)?].kind {
                    LegKind::Lane(lane) => Some(lane),
                    _ => None,
                });
            match approach {
                Some(lane) if map.exit(lane, Turn::Right).is_none() => Action::Left,
                _ => Action::Right,
            }
        }
    })
}

/// `plan` with `kind` applied to car `car` from time 0; `None` when the
/// intervention does not apply (no action to change).
pub fn intervened(map: &CityMap, plan: &ScenarioPlan, car: usize, kind: InterventionKind) -> Option<ScenarioPlan> {
    let intervention = intervention(map, plan, car, kind)?;
    let mut plan = plan.clone();
    plan.interventions.push(intervention);
    Some(plan)
}

/// The intervention that [`intervened`] adds to `plan`.
fn intervention(map: &CityMap, plan: &ScenarioPlan, car: usize, kind: InterventionKind) -> Option<Intervention> {
    let c = &plan.cars[car];
    let (effect, label) = match kind {
        InterventionKind::Remove => (Effect::Remove { car }, format!("remove {} (effects re-run)", c.name)),
        InterventionKind::NextAction => {
            let action = changed_action(map, plan, car)?;
            let mut actions = c.actions.clone();
            actions[0] = action;
            let label = format!("{} drives {action} first (effects re-run)", c.name);
            (Effect::ReplaceActions { car, actions, merge_distances: c.merge_distances.clone() }, label)
        }
    };
    Some(Intervention { trigger: Trigger::At(0.0), effect, label })
}

/// Re-simulates `plan` once per car and intervention and compares every
/// other car with `factual` (the plan's own simulation).
pub fn measure(map: &CityMap, plan: &ScenarioPlan, factual: &Trajectories) -> EffectReport {
    let never = AtomicBool::new(false);
    measure_until(map, plan, factual, &never).expect("a measurement that is never stopped finishes")
}

/// [`measure`], giving up (`None`) at the first re-simulated frame at which
/// `stop` is set.
pub fn measure_until(
    map: &CityMap,
    plan: &ScenarioPlan,
    factual: &Trajectories,
    stop: &AtomicBool,
) -> Option<EffectReport> {
    measure_with(map, plan, factual, Rerun::Incremental, stop).map(|(report, _)| report)
}

/// How the effects' re-runs simulate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rerun {
    /// Every car, every step: the reference.
    Full,
    /// Only the cars the intervention reached, the others replayed from the
    /// factual run, with the same result bit for bit. City world:
    /// `world/city/replay.rs`, in full where replaying does not apply or pay
    /// (`Recording::pays_for`). Toy world: the cars whose route the
    /// intervention changed (`toy::rerun`).
    Incremental,
}

/// What the re-runs of one scenario simulated.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RerunCost {
    /// Re-runs made, and how many of them replayed cars.
    pub reruns: usize,
    pub incremental: usize,
    /// Car steps replayed from the factual run, of all car steps of the
    /// incremental re-runs.
    pub replayed_car_steps: usize,
    pub car_steps: usize,
    /// Decisions of replayed cars tried, and how many woke their car
    /// ([`crate::world::city::replay::Replayed`]).
    pub tries: usize,
    pub woke: usize,
    /// Steps of next-action re-runs in which the cause was replayed
    /// (`Replayed::cause_replayed_steps`), of those re-runs' steps.
    pub cause_replayed_steps: usize,
    pub next_action_steps: usize,
}

/// [`measure_until`] with re-runs made as `how` says, and what they cost.
pub fn measure_with(
    map: &CityMap,
    plan: &ScenarioPlan,
    factual: &Trajectories,
    how: Rerun,
    stop: &AtomicBool,
) -> Option<(EffectReport, RerunCost)> {
    let recording = match how {
        Rerun::Incremental => record_if_it_pays(map, plan, stop)?,
        Rerun::Full => None,
    };
    debug_assert!(recording.as_ref().is_none_or(|r| r.factual().states == factual.states), "the factual run");
    measure_runs(map, plan, factual, recording.as_ref(), how, stop)
}

/// A scenario's factual run, as its effects' re-runs reuse it.
pub enum FactualRun<'a> {
    /// Recorded while simulated, for re-runs that replay the cars an
    /// intervention has not reached (city world, where that pays:
    /// [`Recording::pays_for`]).
    Recorded(Box<Recording<'a>>),
    /// Simulated alone: its re-runs simulate every car.
    Simulated(Trajectories),
}

impl FactualRun<'_> {
    /// The factual run's trajectories.
    pub fn trajectories(&self) -> &Trajectories {
        match self {
            FactualRun::Recorded(recording) => recording.factual(),
            FactualRun::Simulated(trajectories) => trajectories,
        }
    }

    /// The factual run's trajectories, any recording dropped.
    pub fn into_trajectories(self) -> Trajectories {
        match self {
            FactualRun::Recorded(recording) => recording.into_factual(),
            FactualRun::Simulated(trajectories) => trajectories,
        }
    }
}

/// Simulates `plan` as [`simulate_until`] does, with the same trajectories,
/// recording the run where its effects' re-runs can replay it: measuring the
/// effects ([`measure_recorded`]) then needs no second factual simulation.
/// `None` when `stop` was set.
pub fn simulate_recorded<'a>(map: &'a CityMap, plan: &'a ScenarioPlan, stop: &AtomicBool) -> Option<FactualRun<'a>> {
    match record_if_it_pays(map, plan, stop)? {
        Some(recording) => Some(FactualRun::Recorded(Box::new(recording))),
        None => simulate_until(map, plan, stop).map(FactualRun::Simulated),
    }
}

/// `plan` simulated and recorded for its re-runs where replaying pays
/// ([`Recording::pays_for`]); `Some(None)` where it does not (nothing
/// simulated), `None` when `stop` was set.
fn record_if_it_pays<'a>(map: &'a CityMap, plan: &'a ScenarioPlan, stop: &AtomicBool) -> Option<Option<Recording<'a>>> {
    match &plan.world {
        WorldPlan::City(city) if Recording::pays_for(plan) => Recording::record(map, plan, city, stop).map(Some),
        _ => Some(None),
    }
}

/// [`measure_until`] on a factual run that [`simulate_recorded`] made of
/// `plan`: the same report.
pub fn measure_recorded(
    map: &CityMap,
    plan: &ScenarioPlan,
    run: &FactualRun,
    stop: &AtomicBool,
) -> Option<EffectReport> {
    let recording = match run {
        FactualRun::Recorded(recording) => Some(&**recording),
        FactualRun::Simulated(_) => None,
    };
    measure_runs(map, plan, run.trajectories(), recording, Rerun::Incremental, stop).map(|(report, _)| report)
}

/// Re-runs `plan` once per car and intervention, replaying from `recording`
/// where it is replayable (city) or simulating only the cars the
/// intervention reached (toy, [`Rerun::Incremental`]), and compares every
/// other car with `factual`.
fn measure_runs(
    map: &CityMap,
    plan: &ScenarioPlan,
    factual: &Trajectories,
    recording: Option<&Recording>,
    how: Rerun,
    stop: &AtomicBool,
) -> Option<(EffectReport, RerunCost)> {
    let recording = recording.filter(|r| r.replayable());
    let mut rows = Vec::new();
    let mut cost = RerunCost::default();
    // One copy of the plan for every re-run, which differ only in the
    // intervention added (copying the cars' plans for each re-run cost
    // about 2 % of the effects).
    let mut changed = plan.clone();
    for (a, cause) in plan.cars.iter().enumerate() {
        for kind in InterventionKind::ALL {
            let Some(intervention) = intervention(map, plan, a, kind) else { continue };
            changed.interventions.truncate(plan.interventions.len());
            changed.interventions.push(intervention);
            cost.reruns += 1;
            let rerun = match recording {
                Some(recording) => {
                    let (rerun, replayed) = recording.rerun_frames(&changed, a, stop)?;
                    cost.incremental += 1;
                    cost.replayed_car_steps += replayed.car_steps;
                    cost.car_steps += replayed.of;
                    cost.tries += replayed.tries;
                    cost.woke += replayed.woke;
                    if kind == InterventionKind::NextAction {
                        cost.cause_replayed_steps += replayed.cause_replayed_steps;
                        cost.next_action_steps += replayed.steps;
                    }
                    rerun
                }
                None => match (&plan.world, how) {
                    (WorldPlan::Toy { step_m }, Rerun::Incremental) => {
                        let run = toy::rerun(map, plan, &changed, factual, *step_m, stop)?;
                        let frames = run.frames();
                        cost.incremental += 1;
                        cost.car_steps += frames * plan.cars.len();
                        cost.replayed_car_steps +=
                            (0..plan.cars.len()).map(|car| run.first_simulated(car)).sum::<usize>();
                        RerunTrajectories::Replayed(run)
                    }
                    _ => RerunTrajectories::Full(simulate_until(map, &changed, stop)?),
                },
            };
            for (b, effect) in plan.cars.iter().enumerate().filter(|&(b, _)| b != a) {
                rows.push(compare(plan, factual, &rerun, b, cause.id, effect.id, kind));
            }
        }
    }
    Some((EffectReport { threshold_m: EFFECT_THRESHOLD_M, rows }, cost))
}

/// How car `b` (index; id `effect`) differs between the factual run and the
/// re-run with car `cause` intervened on.
fn compare(
    plan: &ScenarioPlan,
    factual: &Trajectories,
    rerun: &RerunTrajectories,
    b: usize,
    cause: u32,
    effect: u32,
    intervention: InterventionKind,
) -> EffectRow {
    let frames = factual.states.len().min(rerun.frames());
    let mut max_divergence_m = 0.0f64;
    let mut first_frame = None;
    let mut onset = None;
    // Before the first frame the re-run simulated car b in, it is the
    // factual car: no distance.
    for frame in rerun.first_simulated(b).min(frames)..frames {
        let d = factual.states[frame][b].position.distance(rerun.state(frame, b).position);
        max_divergence_m = max_divergence_m.max(d);
        if d > ONSET_M && onset.is_none() {
            onset = Some(frame);
        }
        if d > EFFECT_THRESHOLD_M && first_frame.is_none() {
            first_frame = Some(frame as u32);
        }
    }
    let follows = plan.cars[b].leader == Some(cause);
    // What bound b's speed where it first moved (and the frame before, as a
    // decision shows at the frame after it), in either run.
    let bound_by_a = onset.is_some_and(|f| {
        let names_a = |i: Option<&Interaction>| i.is_some_and(|i| i.other_car == Some(cause));
        (f.saturating_sub(1)..=f).any(|frame| {
            names_a(factual.interactions.get(frame).and_then(|cars| cars.get(b)))
                || names_a(rerun.interaction(frame, b))
        })
    });
    EffectRow {
        cause,
        effect,
        intervention,
        max_divergence_m,
        first_frame,
        direct: first_frame.is_some() && (follows || bound_by_a),
    }
}
