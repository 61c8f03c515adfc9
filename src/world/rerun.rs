//! An effects re-run's trajectories ([`super::effects`]) as either world
//! makes them: every car simulated, or only the cars the intervention
//! reached, the others being the factual run's, bit for bit (the city's
//! replay, `city/replay.rs`; the toy's, `toy::rerun`).

use super::{CarState, Interaction, Trajectories};

/// A re-run's cars, simulated in full or in part.
pub enum RerunTrajectories<'r> {
    /// Every car simulated.
    Full(Trajectories),
    /// The cars it simulated; the others replayed.
    Replayed(RerunFrames<'r>),
}

impl RerunTrajectories<'_> {
    /// The frames.
    pub fn frames(&self) -> usize {
        match self {
            RerunTrajectories::Full(run) => run.states.len(),
            RerunTrajectories::Replayed(run) => run.frames(),
        }
    }

    /// The first frame in which car `car` was simulated (0 in a full re-run).
    pub fn first_simulated(&self, car: usize) -> usize {
        match self {
            RerunTrajectories::Full(_) => 0,
            RerunTrajectories::Replayed(run) => run.first_simulated(car),
        }
    }

    /// Car `car` at frame `frame`.
    pub fn state(&self, frame: usize, car: usize) -> &CarState {
        match self {
            RerunTrajectories::Full(run) => &run.states[frame][car],
            RerunTrajectories::Replayed(run) => run.state(frame, car),
        }
    }

    /// What bound car `car`'s latest decision at frame `frame`, if the
    /// world records it (the city does).
    pub fn interaction(&self, frame: usize, car: usize) -> Option<&Interaction> {
        match self {
            RerunTrajectories::Full(run) => run.interactions.get(frame).and_then(|cars| cars.get(car)),
            RerunTrajectories::Replayed(run) => run.interaction(frame, car),
        }
    }
}

/// A replayed re-run's cars: each car's frames from the first one in which
/// it was simulated; before that (and for a car replayed throughout) the
/// factual run's, bit for bit.
pub struct RerunFrames<'r> {
    factual: &'r Trajectories,
    /// Per car, the first frame simulated (the frame count: none).
    from: Vec<usize>,
    /// Per car, its states and what bound it from `from` on (no bindings
    /// in a world that records none: the toy).
    states: Vec<Vec<CarState>>,
    interactions: Vec<Vec<Interaction>>,
}

impl<'r> RerunFrames<'r> {
    /// A re-run of `factual`'s `cars` cars that has simulated none yet.
    pub(super) fn new(factual: &'r Trajectories, cars: usize) -> RerunFrames<'r> {
        let frames = factual.states.len();
        RerunFrames {
            factual,
            from: vec![frames; cars],
            states: vec![Vec::new(); cars],
            interactions: vec![Vec::new(); cars],
        }
    }

    /// Car `car`'s state (and binding, where the world records one) at the
    /// next frame: the first call names the frame from which it is simulated
    /// (its states from then on follow, one per frame).
    pub(super) fn push(&mut self, car: usize, frame: usize, state: CarState, binding: Option<Interaction>) {
        if self.from[car] == self.frames() {
            self.from[car] = frame;
            let left = self.frames() - frame;
            self.states[car].reserve_exact(left);
            if binding.is_some() {
                self.interactions[car].reserve_exact(left);
            }
        }
        self.states[car].push(state);
        self.interactions[car].extend(binding);
    }

    /// Takes back every frame pushed for car `car`: it is the factual run's
    /// again in every frame so far. A re-run that defers its cause pushed
    /// the cause's frame 0 (it re-planned there) and then found it driving
    /// as the factual car does; from its waking on, it is pushed again.
    pub(super) fn forget(&mut self, car: usize) {
        self.from[car] = self.frames();
        self.states[car].clear();
        self.interactions[car].clear();
    }

    /// The frames (the factual run's count).
    pub fn frames(&self) -> usize {
        self.factual.states.len()
    }

    /// The first frame in which car `car` was simulated (before it, the
    /// re-run's car is the factual run's); [`RerunFrames::frames`] when never.
    pub fn first_simulated(&self, car: usize) -> usize {
        self.from[car]
    }

    /// Car `car` at frame `frame`.
    pub fn state(&self, frame: usize, car: usize) -> &CarState {
        match frame.checked_sub(self.from[car]) {
            Some(at) => &self.states[car][at],
            None => &self.factual.states[frame][car],
        }
    }

    /// What bound car `car`'s latest decision at frame `frame`; `None` in a
    /// world that records no bindings.
    pub fn interaction(&self, frame: usize, car: usize) -> Option<&Interaction> {
        match frame.checked_sub(self.from[car]) {
            Some(at) => self.interactions[car].get(at),
            None => self.factual.interactions.get(frame).and_then(|cars| cars.get(car)),
        }
    }

    /// Every car, frame by frame (no lights or events), as a full re-run
    /// gives them: the bindings too where the world records them.
    pub fn to_trajectories(&self, frame_interval: f64) -> Trajectories {
        let cars = self.from.len();
        let frames = 0..self.frames();
        let bindings = !self.factual.interactions.is_empty();
        Trajectories {
            frame_interval,
            states: frames.clone().map(|f| (0..cars).map(|c| *self.state(f, c)).collect()).collect(),
            lights: Vec::new(),
            events: Vec::new(),
            confounder_changes: Vec::new(),
            interactions: if bindings {
                frames.map(|f| (0..cars).filter_map(|c| self.interaction(f, c).copied()).collect()).collect()
            } else {
                Vec::new()
            },
        }
    }
}
