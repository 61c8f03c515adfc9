//! One scenario planned on one town: cars placed (the graph's queues, then
//! singles), followers' fallbacks, ids, confounders, lights and each car's
//! driving.

use super::actions::{original_actions, random_actions};
use super::spawn::{spawn_spans, split_owning_start, SpawnSpan, OWNED_START_SEARCH_MM};
use crate::camera::Camera;
use crate::geometry::OrientedBox;
use crate::map::signals::{LightPlan, DEFAULT_CYCLE};
use crate::map::{Action, AdaptationKind, CityMap, LaneId, LanePolicy, LegKind, Route};
use crate::plan::confounders::ConfounderModel;
use crate::plan::{
    stream_key, CarAgency, CarPlan, CityPlan, Fallback, GivenCar, OnLeaderLost, Role, ScenarioKey, ScenarioPlan,
    WorldPlan,
};
use crate::spec::{
    ActionDrawing, DatasetSpec, GraphShape, GroupSpec, LightPhase, SpecError, Split, WorldKind, DEFAULT_LEADER_GAP_PX,
};
use rand::seq::SliceRandom;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sha2::{Digest, Sha256};
use std::sync::Arc;

/// A car placed on the map before ids are assigned.
#[derive(Clone)]
pub(super) struct PlacedCar {
    pub(super) role: Role,
    pub(super) spawn: LaneId,
    pub(super) distance: f64,
    pub(super) actions: Vec<Action>,
    pub(super) merges: Vec<f64>,
    pub(super) route: Arc<Route>,
    pub(super) desired_speeds: Vec<f64>,
    /// A hard negative: the index of the car it starts right behind.
    pub(super) behind: Option<usize>,
    /// A follower: the index of its leader.
    pub(super) leader: Option<usize>,
    /// A collider's follower: the index of the car it gives way to.
    pub(super) gives_way_to: Option<usize>,
    /// A follower: what it does once it loses its leader.
    pub(super) on_leader_lost: Option<OnLeaderLost>,
}

/// One town's planning: the spec with the town's map section, its map,
/// the bird's-eye camera that frames it, and where cars start on camera.
#[derive(Debug)]
pub struct Planner {
    /// The dataset spec, its `map` the town's own (no draws left).
    pub spec: DatasetSpec,
    /// The town's name ([`MapSpec::town_name`]).
    pub name: String,
    pub map: Arc<CityMap>,
    pub camera: Camera,
    pub(super) spans: Vec<SpawnSpan>,
    pub(super) leader_gap_m: f64,
    /// The closest two cars of one lane may start, centre to centre, metres:
    /// the toy's exact leader gap, or a car length plus the city's shortest
    /// follower gap.
    pub(super) shortest_spacing_m: f64,
    pub(super) toy_step_m: f64,
    /// Starts from nothing a scenario's platoons may take: a few while the
    /// spec is checked, many once it is taken ([`PLATOON_STARTS`]).
    pub(super) platoon_starts: usize,
}

/// Keys the stream a scenario's light phase is drawn from.
pub(super) const LIGHT_PHASE_TAG: &[u8] = b"causalcity/light-phase/v1";
/// Keys the stream followers' fallback drive queues are drawn from (its own,
/// so drawing them moves no other random number).
pub(super) const FALLBACK_TAG: &[u8] = b"causalcity/follower-fallback/v1";

/// Clearance kept between cars at spawn, metres.
pub(super) const SPAWN_CLEARANCE: f64 = 0.1;

pub(super) const PLACEMENT_ATTEMPTS: usize = 2000;

/// Starts from nothing at a scenario's platoons before planning gives up.
pub(super) const PLATOON_STARTS: usize = 64;

/// Scenarios of each platoon group planned before anything is written, and
/// the starts each may take there: a group whose platoons place within
/// [`CHECKED_PLATOON_STARTS`] starts in every one of [`CHECKED_PLATOON_SCENARIOS`]
/// places at a start with a chance of about 0.3 or more (at 0.3, all 16
/// pass once in 80; below, less often), so that [`PLATOON_STARTS`] leave
/// one scenario in about 10^10 unplaced (0.7^64). Platoons of 4 with gaps of 1-12 m
/// placed 100 cars at a first start 3 times in 4: one scenario in 4
/// failed midway through a dataset whose first scenario planned.
const CHECKED_PLATOON_SCENARIOS: u32 = 16;
const CHECKED_PLATOON_STARTS: usize = 4;

/// How many trial plans [`Planner::new`] makes of each group before it
/// takes a spec.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Trials {
    /// A spec about to be written: one plan per group, and
    /// [`CHECKED_PLATOON_SCENARIOS`] of a platoon group, so that none fails
    /// midway through a dataset.
    Writing,
    /// A dataset's own spec, which the `gen` that wrote it checked: one plan
    /// per group (the platoon trials cost opening a dataset 10-40 ms).
    Written,
}

/// (leader, follower) indices into a scenario's placed cars.
pub(super) type LeaderFollowerPairs = Vec<(usize, usize)>;

impl Planner {
    /// Checks that every group can be planned on this map and camera, as
    /// thoroughly as `trials` asks.
    pub fn new(spec: DatasetSpec, map: Arc<CityMap>, trials: Trials) -> Result<Planner, SpecError> {
        let camera = spec.birds_eye_camera()?;
        let leader_gap_m = camera.pixels_to_metres(spec.leader_gap_px());
        if spec.world == WorldKind::Toy && leader_gap_m < spec.car_length_m + SPAWN_CLEARANCE {
            return Err(SpecError::new(
                "leader_gap_px",
                format!(
                    "{} px ({leader_gap_m:.2} m) would make a follower overlap its leader: a car is {} m ({:.1} px) long, so use at least {:.1}",
                    spec.leader_gap_px(),
                    spec.car_length_m,
                    camera.metres_to_pixels(spec.car_length_m),
                    camera.metres_to_pixels(spec.car_length_m + SPAWN_CLEARANCE)
                ),
            ));
        }
        // Overrides name the grid's junctions (AC .. BD); an imported
        // network has none of them.
        if map.is_imported() {
            if let Some(o) = spec.city.iter().flat_map(|c| c.lights.overrides.first()).next() {
                return Err(SpecError::new(
                    "city.lights.overrides[0].intersection",
                    format!(
                        "{:?}: overrides apply to a grid town's junctions, and this town is the imported network {}, whose lights run its own programmes: leave city.lights.overrides out",
                        o.intersection, name_of_network(&spec)
                    ),
                ));
            }
        }
        let spans = spawn_spans(&map, &camera, spec.car_length_m);
        let slot = spec.car_length_m + SPAWN_CLEARANCE;
        let capacity: u32 = spans.iter().map(|s| ((s.hi - s.lo) / slot) as u32 + 1).sum();
        let toy_step_m = camera.pixels_to_metres(spec.toy_speed_px_per_frame);
        let shortest_spacing_m = match spec.world {
            WorldKind::Toy => leader_gap_m,
            WorldKind::City => spec.car_length_m + spec.city_settings().start.follower_gap_m.lowest(),
        };
        let name = spec.map.town_name();
        // A written spec's one plan may take every start a scenario may.
        let platoon_starts = if trials == Trials::Writing { CHECKED_PLATOON_STARTS } else { PLATOON_STARTS };
        let mut expansion =
            Planner { spec, name, map, camera, spans, leader_gap_m, shortest_spacing_m, toy_step_m, platoon_starts };
        let colliders = expansion.spec.graph.unit_cars();
        let wants_colliders = expansion.spec.graph.shape == GraphShape::Colliders
            && expansion.spec.groups.iter().any(|g| expansion.spec.graph.units(g.edges()).contains(&colliders));
        if wants_colliders && !expansion.has_give_way_junctions() {
            return Err(SpecError::new(
                "graph.shape",
                format!(
                    "\"colliders\" needs junctions where a driver gives way, and every junction of this town ({}) has lights with protected turns: use map.grid.control \"priority\", \"all_way_stop\" or \"right_before_left\", or an imported network with such junctions",
                    expansion.name
                ),
            ));
        }
        for (i, g) in expansion.spec.groups.iter().enumerate() {
            // Random placement needs room to spare: allow half the packed capacity.
            if g.cars > capacity / 2 {
                return Err(SpecError::new(
                    format!("groups[{i}].cars"),
                    format!(
                        "{} cars do not fit on the visible spawn lanes of a {}x{} view without overlapping: use at most {}",
                        g.cars,
                        expansion.spec.image.width,
                        expansion.spec.image.height,
                        capacity / 2
                    ),
                ));
            }
            let shortest_pair = expansion.shortest_spacing_m;
            if g.edges() > 0 && !expansion.spans.iter().any(|s| s.hi - s.lo >= shortest_pair) {
                let spec = &expansion.spec;
                let too_long = "longer than any visible spawn lane: no pair can start on camera";
                return Err(match spec.world {
                    // The toy gap is in pixels: a small image makes each pixel many metres.
                    WorldKind::Toy => SpecError::new(
                        // Blame the setting the user moved from its default.
                        if spec.leader_gap_px() != DEFAULT_LEADER_GAP_PX { "leader_gap_px" } else { "image" },
                        format!(
                            "a {}x{} image shows {:.2} px per metre, so leader_gap_px = {} puts leader and follower {shortest_pair:.2} m apart (centre to centre), {too_long}. Use a larger image (the default is 1024x640) or a smaller leader_gap_px",
                            spec.image.width,
                            spec.image.height,
                            expansion.camera.pixels_per_metre,
                            spec.leader_gap_px()
                        ),
                    ),
                    WorldKind::City => SpecError::new(
                        "city.start.follower_gap_m",
                        format!("a pair {shortest_pair:.2} m long from centre to centre is {too_long}"),
                    ),
                });
            }
            // A dry run proves the group can be planned before anything is
            // written (platoons: reliably, see CHECKED_PLATOON_SCENARIOS).
            let platoons = trials == Trials::Writing
                && expansion.spec.world == WorldKind::City
                && expansion.spec.city_settings().start.platoon_cars != 0;
            for index in 0..if platoons { CHECKED_PLATOON_SCENARIOS } else { 1 } {
                let key = ScenarioKey { group: g.name(), group_index: i, split: Split::Train, index, name: None };
                expansion.plan(&key).map_err(|e| {
                    let why = if index == 0 {
                        e
                    } else {
                        format!(
                            "{e} (in trial {} of the {CHECKED_PLATOON_SCENARIOS} trial plans of the group made \
                             before anything is written: the platoons fill the visible lanes too tightly to place \
                             every scenario reliably)",
                            index + 1
                        )
                    };
                    SpecError::new(format!("groups[{i}]"), why)
                })?;
            }
        }
        expansion.platoon_starts = PLATOON_STARTS;
        Ok(expansion)
    }

    /// Metres every toy car covers per frame.
    pub fn toy_step_m(&self) -> f64 {
        self.toy_step_m
    }

    /// Plans one scenario on this town. Errors only when cars cannot be placed.
    pub fn plan(&self, key: &ScenarioKey) -> Result<ScenarioPlan, String> {
        let spec = &self.spec;
        let group: &GroupSpec = &spec.groups[key.group_index];
        let stream = stream_key(spec.seed, &key.group, key.split, key.index);
        let mut rng = ChaCha8Rng::from_seed(stream);
        let travel = self.max_travel();
        let city = (spec.world == WorldKind::City).then(|| spec.city_settings());
        if let Some(c) = city.as_ref().filter(|c| c.start.platoon_cars > 0) {
            let (cars, pair_indices) = self.place_platoons(key, &mut rng, c, group)?;
            return Ok(self.finish(key, stream, rng, cars, &pair_indices));
        }

        // Units to place: the graph's connected parts first (they need the
        // most room), then singles. A part is a queue in one lane: its
        // leader first, then its followers, each a drawn spacing behind.
        let parts = spec.graph.units(group.edges());
        let singles = group.cars as usize - parts.iter().sum::<u32>() as usize;
        let unit_sizes: Vec<usize> = parts.iter().map(|&n| n as usize).chain(std::iter::repeat_n(1, singles)).collect();
        let mut placed: Vec<OrientedBox> = Vec::new();
        let mut cars: Vec<PlacedCar> = Vec::new();
        let mut pair_indices = Vec::new();
        let split = key.split.index();
        let colliders = spec.graph.shape == GraphShape::Colliders;
        for &unit in &unit_sizes {
            // A collider's third car comes from the crossing road: its queue
            // is the leader and the follower.
            let collider = colliders && unit == spec.graph.unit_cars() as usize;
            let size = if collider { spec.graph.queued_cars() as usize } else { unit };
            let in_graph = size > 1;
            // City: a car with no leader may start right behind another car
            // (a hard negative), decided once per unit.
            let hard_negative = match &city {
                Some(c) if !cars.is_empty() && c.start.hard_negative_share > 0.0 => {
                    rng.random_bool(c.start.hard_negative_share)
                }
                _ => false,
            };
            let mut done = false;
            for attempt in 0..PLACEMENT_ATTEMPTS {
                // Centre-to-centre from each car to the one behind it.
                let spacings: Vec<f64> = (1..size).map(|_| self.draw_spacing(&mut rng, city.as_ref())).collect();
                let spacing: f64 = spacings.iter().sum();
                // A hard negative that finds no room in half the attempts starts anywhere.
                let behind =
                    (hard_negative && attempt < PLACEMENT_ATTEMPTS / 2).then(|| rng.random_range(0..cars.len()));
                let (span, front, back) = match behind {
                    Some(k) => {
                        let ahead = &cars[k];
                        let Some(span) = self.spans.iter().find(|s| s.lane == ahead.spawn).copied() else { continue };
                        let front = round_mm(ahead.distance - self.draw_spacing(&mut rng, city.as_ref()));
                        if front - spacing < span.lo {
                            continue;
                        }
                        (span, front, front - spacing)
                    }
                    None => {
                        let span = self.spans[rng.random_range(0..self.spans.len())];
                        if span.hi - span.lo < spacing {
                            continue;
                        }
                        let back = round_mm(rng.random_range(span.lo..=span.hi - spacing));
                        (span, back + spacing, back)
                    }
                };
                // Each car's start relative to the last car's, front first.
                let mut offsets = vec![front - back];
                let mut ahead = front;
                for &gap in spacings.iter().take(size.saturating_sub(2)) {
                    ahead = round_mm(ahead - gap);
                    offsets.push(ahead - back);
                }
                if in_graph {
                    offsets.push(0.0);
                }
                // The nearest start forward (in whole millimetres) that this
                // split owns, for every car of the unit.
                let owned = (0..OWNED_START_SEARCH_MM)
                    .map(|mm| round_mm(back + mm as f64 / 1000.0))
                    .find(|&b| offsets.iter().all(|&o| split_owning_start(span.lane, b + o) == split));
                let Some(owned_back) = owned else { continue };
                let starts: Vec<f64> = offsets.iter().map(|&o| owned_back + o).collect();
                let front = starts[0];
                if front > span.hi {
                    continue;
                }
                // The toy world always draws lane-valid actions.
                let drawing = city.as_ref().map_or(ActionDrawing::LaneValid, |c| c.action_drawing);
                let (actions, merges) = self.draw_actions(&mut rng, drawing, span.lane, front);
                // A hard negative parts ways with the car ahead at the next intersection.
                if let Some(k) = behind {
                    if actions.is_empty() || actions.first() == cars[k].actions.first() {
                        continue;
                    }
                }
                // Checked on the spawn lane before the (costlier) route is planned.
                let boxes: Vec<OrientedBox> = starts.iter().map(|&s| self.car_box(span.lane, s)).collect();
                let clear = boxes.iter().all(|b| {
                    let grown = b.inflated(SPAWN_CLEARANCE / 2.0);
                    placed.iter().all(|p| !grown.overlaps(&p.inflated(SPAWN_CLEARANCE / 2.0)))
                });
                // City: no car starts closer to another in its lane than the
                // shortest follower gap, so no driver starts below its min gap.
                let spaced = city.is_none()
                    || cars
                        .iter()
                        .filter(|o| o.spawn == span.lane)
                        .all(|o| starts.iter().all(|s| (o.distance - s).abs() >= self.shortest_spacing_m - 1e-6));
                if !clear || !spaced {
                    continue;
                }
                let (placed_before, cars_before, pairs_before) = (placed.len(), cars.len(), pair_indices.len());
                placed.extend(boxes);
                let route = Arc::new(self.plan_route(span.lane, front, &actions, &merges, travel)?);
                let desired_speeds = draw_desired_speeds(&mut rng, city.as_ref(), actions.len());
                let role = if in_graph { Role::Leader } else { Role::Independent };
                let car = PlacedCar {
                    role,
                    spawn: span.lane,
                    distance: front,
                    actions,
                    merges,
                    route,
                    desired_speeds,
                    behind,
                    leader: None,
                    gives_way_to: None,
                    on_leader_lost: None,
                };
                let first = cars.len();
                for (j, &start) in starts.iter().enumerate().skip(1) {
                    // A chain's car follows the car right ahead; a fork's (and
                    // a pair's) follows the first.
                    let leader = match spec.graph.shape {
                        GraphShape::Chains => first + j - 1,
                        _ => first,
                    };
                    pair_indices.push((leader, first + j));
                    // A follower drives what its leader drives, not its own
                    // personality (the toy has no speeds to draw).
                    let desired_speeds = draw_desired_speeds(&mut rng, city.as_ref(), car.actions.len());
                    let follower = PlacedCar {
                        role: Role::Follower,
                        distance: start,
                        desired_speeds,
                        behind: None,
                        leader: Some(leader),
                        ..car.clone()
                    };
                    if j == 1 {
                        cars.push(car.clone());
                    }
                    cars.push(follower);
                }
                if !in_graph {
                    cars.push(car);
                }
                if collider {
                    let (leader, follower) = (cars_before, cars_before + 1);
                    // A city shape (checked with the spec; a manifest's spec is not).
                    let Some(c) = city.as_ref() else {
                        return Err("graph.shape \"colliders\" needs \"world\": \"city\"".to_string());
                    };
                    match self.place_priority_car(&mut rng, c, split, (leader, follower), &cars, &placed) {
                        Some(priority) => {
                            placed.push(self.car_box(priority.spawn, priority.distance));
                            pair_indices.push((cars.len(), follower));
                            cars[follower].gives_way_to = Some(cars.len());
                            cars.push(priority);
                        }
                        None => {
                            placed.truncate(placed_before);
                            cars.truncate(cars_before);
                            pair_indices.truncate(pairs_before);
                            continue;
                        }
                    }
                }
                done = true;
                break;
            }
            if !done && collider {
                return Err(format!(
                    "could not place a collider (a leader, its follower and a car with priority timed to meet the follower at its first junction) after {PLACEMENT_ATTEMPTS} tries: colliders need junctions where drivers give way with approaches long enough to start the car with priority on {}, or fewer cars",
                    self.longer_approaches()
                ));
            }
            if !done {
                return Err(format!(
                    "could not place {} cars without overlap after {PLACEMENT_ATTEMPTS} tries: use fewer cars",
                    group.cars
                ));
            }
        }

        Ok(self.finish(key, stream, rng, cars, &pair_indices))
    }

    /// A plan from placed cars: followers' fallbacks, random ids (so the
    /// index order never gives the roles away), then the rest.
    pub(super) fn finish(
        &self,
        key: &ScenarioKey,
        stream: [u8; 32],
        mut rng: ChaCha8Rng,
        mut cars: Vec<PlacedCar>,
        pair_indices: &[(usize, usize)],
    ) -> ScenarioPlan {
        self.draw_fallbacks(stream, &mut cars);
        let mut ids: Vec<u32> = (0..cars.len() as u32).collect();
        ids.shuffle(&mut rng);
        self.assemble(key, stream, rng, cars, pair_indices, &ids)
    }

    /// What every follower does when it loses its leader: in the toy world
    /// it stops (no agency); in the city it drives a queue of its own, drawn
    /// as an independent car's from its start (from a stream of its own).
    fn draw_fallbacks(&self, stream: [u8; 32], cars: &mut [PlacedCar]) {
        let mut rng = ChaCha8Rng::from_seed(Sha256::digest([FALLBACK_TAG, &stream[..]].concat()).into());
        for car in cars.iter_mut().filter(|c| c.leader.is_some()) {
            let drawing = match self.spec.world {
                WorldKind::Toy => {
                    car.on_leader_lost = Some(OnLeaderLost::Stop);
                    continue;
                }
                WorldKind::City => self.spec.city_settings().action_drawing,
            };
            let (actions, merges) = self.draw_actions(&mut rng, drawing, car.spawn, car.distance);
            // Its route is planned when it is needed, from where the follower is then.
            car.on_leader_lost = Some(OnLeaderLost::Drive(Fallback { actions, merge_distances: merges }));
        }
    }

    /// Centre-to-centre distance from a car to the car starting right
    /// behind it, metres: the toy world's exact `leader_gap_px`, or a car
    /// length plus a bumper gap drawn from `city.start.follower_gap_m`.
    pub(super) fn draw_spacing(&self, rng: &mut ChaCha8Rng, city: Option<&crate::spec::CitySpec>) -> f64 {
        match city {
            Some(c) => round_mm(self.spec.car_length_m + c.start.follower_gap_m.sample(rng)),
            None => self.leader_gap_m,
        }
    }

    /// As [`Self::plan_route`], with every turn the route must skip (no
    /// room to change into its lane from the start) written as the straight
    /// on the car drives instead, so the queue says what the car does and a
    /// follower copying it takes the turns its leader takes.
    pub(super) fn plan_feasible_route(
        &self,
        lane: LaneId,
        front: f64,
        actions: &mut [Action],
        merges: &[f64],
        travel: f64,
    ) -> Result<Route, String> {
        let mut route = self.plan_route(lane, front, actions, merges, travel)?;
        // A skipped turn becomes the movement the car makes there instead:
        // straight on, or at a T-junction's stem its lane's turn. Each pass
        // only turns skipped actions into ones their lanes make: it ends.
        for _ in 0..actions.len() {
            let skipped: Vec<usize> = route
                .adaptations
                .iter()
                .filter(|a| a.kind == AdaptationKind::Skipped && !a.action.is_merge())
                .map(|a| a.action_index)
                .collect();
            let before = actions.to_vec();
            for k in skipped {
                let made = route.legs.iter().find(|l| l.action == Some(k)).and_then(|l| match l.kind {
                    LegKind::Connector(c) => Some(self.map.connectors[c].turn),
                    _ => None,
                });
                actions[k] = made.map_or(Action::Straight, Action::making);
            }
            if actions == before.as_slice() {
                break;
            }
            route = self.plan_route(lane, front, actions, merges, travel)?;
        }
        Ok(route)
    }

    /// The footprint of a car centred `s` metres along `lane`.
    /// How a refusal of colliders says to get longer approaches: a grid's
    /// blocks, or (an imported network, where map.grid is refused) another
    /// network.
    pub(super) fn longer_approaches(&self) -> &'static str {
        if self.map.is_imported() {
            "(this network has too few such approaches: another network)"
        } else {
            "(longer blocks, map.grid.block_m, help)"
        }
    }

    pub(super) fn car_box(&self, lane: LaneId, s: f64) -> OrientedBox {
        let curve = &self.map.lanes[lane].curve;
        OrientedBox {
            centre: curve.position(s, 0.0),
            heading: curve.heading_at(s),
            length: self.spec.car_length_m,
            width: self.spec.car_width_m,
        }
    }

    /// A city drive queue as `drawing` draws it for a car starting `s`
    /// metres along `lane`.
    pub(super) fn draw_actions(
        &self,
        rng: &mut ChaCha8Rng,
        drawing: ActionDrawing,
        lane: LaneId,
        s: f64,
    ) -> (Vec<Action>, Vec<f64>) {
        let count = self.spec.actions_per_car;
        match drawing {
            ActionDrawing::Original => original_actions(rng, &self.map, lane, count),
            _ => random_actions(rng, &self.map, lane, s, count),
        }
    }

    /// The route of a car entering at `front` metres along `lane`, `travel`
    /// metres long (enough for the whole scenario).
    pub(super) fn plan_route(
        &self,
        lane: LaneId,
        front: f64,
        actions: &[Action],
        merges: &[f64],
        travel: f64,
    ) -> Result<Route, String> {
        Route::plan(&self.map, lane, front, actions, merges, front + travel, &LanePolicy::Adapt)
            .map_err(|e| format!("internal planning error on {}: {e}", self.map.lanes[lane].name))
    }

    /// Plans a scenario of given cars (hand-written scenario files): ids in
    /// the given order, (leader, follower) index pairs, desired speeds drawn
    /// from the scenario stream where not given. Names, colours and driving
    /// overrides of `GivenCar` are applied on top.
    pub fn plan_given(
        &self,
        key: &ScenarioKey,
        stream: [u8; 32],
        given: &[GivenCar],
        pairs: &[(usize, usize)],
    ) -> ScenarioPlan {
        let mut rng = ChaCha8Rng::from_seed(stream);
        let city = (self.spec.world == WorldKind::City).then(|| self.spec.city_settings());
        let mut cars: Vec<PlacedCar> = given
            .iter()
            .map(|g| {
                let desired_speeds = draw_desired_speeds(&mut rng, city.as_ref(), g.actions.len());
                PlacedCar {
                    role: Role::Independent,
                    spawn: g.spawn,
                    distance: g.spawn_distance,
                    actions: g.actions.clone(),
                    merges: g.merge_distances.clone(),
                    route: g.route.clone(),
                    desired_speeds,
                    behind: None,
                    leader: None,
                    gives_way_to: None,
                    on_leader_lost: None,
                }
            })
            .collect();
        for &(leader, follower) in pairs {
            cars[leader].role = Role::Leader;
            let f = &mut cars[follower];
            f.role = Role::Follower;
            f.leader = Some(leader);
            // A written follower falls back on its own written actions (toy: stops).
            f.on_leader_lost = Some(match self.spec.world {
                WorldKind::Toy => OnLeaderLost::Stop,
                WorldKind::City => {
                    OnLeaderLost::Drive(Fallback { actions: f.actions.clone(), merge_distances: f.merges.clone() })
                }
            });
        }
        let ids: Vec<u32> = (0..cars.len() as u32).collect();
        let mut plan = self.assemble(key, stream, rng, cars, pairs, &ids);
        for (car, g) in plan.cars.iter_mut().zip(given) {
            car.name = g.name.clone();
            car.colour = g.colour;
        }
        if let WorldPlan::City(city) = &mut plan.world {
            for (agency, g) in city.agency.iter_mut().zip(given) {
                if let Some(speeds) = &g.desired_speeds {
                    agency.desired_speeds = speeds.clone();
                }
                if let Some(headway) = g.time_headway {
                    agency.driver.time_headway = headway;
                }
                if let Some(runs) = g.runs_red_lights {
                    agency.runs_red_lights = runs;
                }
                // Hand-written scenarios start every car at rest, as the original did.
                agency.start_speed = 0.0;
            }
        }
        plan
    }

    /// The rest of a plan once cars are placed: confounders, lights, each
    /// car's driving, ids (`ids[i]` for `cars[i]`) and edges.
    fn assemble(
        &self,
        key: &ScenarioKey,
        stream: [u8; 32],
        mut rng: ChaCha8Rng,
        cars: Vec<PlacedCar>,
        pair_indices: &[(usize, usize)],
        ids: &[u32],
    ) -> ScenarioPlan {
        let spec = &self.spec;
        let world = match spec.world {
            WorldKind::Toy => WorldPlan::Toy { step_m: self.toy_step_m },
            WorldKind::City => WorldPlan::City(self.city_plan(key.split, stream, &mut rng, &cars, ids)),
        };
        let mut planned: Vec<CarPlan> = cars
            .into_iter()
            .enumerate()
            .map(|(i, placed)| {
                let PlacedCar {
                    role,
                    spawn,
                    distance: spawn_distance,
                    actions,
                    merges: merge_distances,
                    route,
                    behind,
                    leader,
                    gives_way_to,
                    on_leader_lost,
                    ..
                } = placed;
                let id = ids[i];
                CarPlan {
                    id,
                    name: format!("Car_{}", id + 1),
                    colour: None,
                    mask_id: (id + 1) as u8,
                    spawn,
                    spawn_name: self.map.lanes[spawn].name.clone(),
                    spawn_distance,
                    actions,
                    merge_distances,
                    role,
                    length: spec.car_length_m,
                    width: spec.car_width_m,
                    route,
                    hard_negative_behind: behind.map(|k| ids[k]),
                    leader: leader.map(|k| ids[k]),
                    gives_way_to: gives_way_to.map(|k| ids[k]),
                    on_leader_lost,
                }
            })
            .collect();
        let mut edges: Vec<(u32, u32)> = pair_indices.iter().map(|&(l, f)| (ids[l], ids[f])).collect();
        edges.sort_unstable();
        planned.sort_by_key(|c| c.id);
        ScenarioPlan {
            key: key.clone(),
            world,
            seed: spec.seed,
            stream_key: stream.iter().map(|b| format!("{b:02x}")).collect(),
            frames: spec.frames,
            frame_interval: spec.frame_interval(),
            cars: planned,
            edges,
            interventions: Vec::new(),
            town: None,
            birds_eye: spec.birds_eye,
            // Checked with the spec; chased cars are named by id, and cars are in id order.
            cameras: spec
                .cameras
                .iter()
                .filter_map(|c| {
                    c.plan("cameras", |car| match car {
                        crate::spec::CarRef::Id(id) => Ok(*id as usize),
                        crate::spec::CarRef::Name(_) => Err(String::new()),
                    })
                    .ok()
                })
                .collect(),
        }
    }

    /// City world: confounders, lights and each car's driving (`ids[i]` for
    /// `cars[i]`), drawn after placement, in placement order.
    fn city_plan(
        &self,
        split: Split,
        stream: [u8; 32],
        rng: &mut ChaCha8Rng,
        cars: &[PlacedCar],
        ids: &[u32],
    ) -> CityPlan {
        let c = self.spec.city_settings();
        let (confounders, confounder_model) = ConfounderModel::draw(&self.spec.confounders_of(split), rng);
        let effects = confounders.effects();
        let mut sim_stream = stream;
        sim_stream[31] ^= 0x5a;
        let p_run = (c.red_light_runner_probability + effects.red_light_run_probability_added).min(1.0);
        let mut agency: Vec<(u32, CarAgency)> = cars
            .iter()
            .zip(ids)
            .map(|(placed, &id)| {
                let runs_red_lights = rng.random_bool(p_run);
                let desired_speeds = placed.desired_speeds.iter().map(|v| v * effects.desired_speed_factor).collect();
                (id, CarAgency { desired_speeds, start_speed: 0.0, driver: effects.apply(&c.driver), runs_red_lights })
            })
            .collect();
        // Drawn after everything else, so the draws above stay as they were.
        for (_, a) in agency.iter_mut() {
            a.start_speed = a.desired_speeds.first().copied().unwrap_or(0.0) * c.start.speed_fraction.sample(rng);
        }
        agency.sort_by_key(|(id, _)| *id);
        CityPlan {
            confounders,
            confounder_model,
            effects,
            lights: self.light_plan(&c, stream),
            base_driver: c.driver,
            driver_model: c.driver_model,
            signal_heads: c.signal_heads,
            rules: c.rules,
            sim_stream: Sha256::digest(sim_stream).into(),
            agency: agency.into_iter().map(|(_, a)| a).collect(),
        }
    }

    /// The lights of the scenario with stream key `stream`: the cycle, its
    /// offsets and overrides, every light's clock shifted by the scenario's
    /// phase (`lights.phase`). The phase comes from a stream of its own
    /// (keyed by the scenario's), so drawing it moves no other random number.
    fn light_plan(&self, city: &crate::spec::CitySpec, stream: [u8; 32]) -> LightPlan {
        let lights = &city.lights;
        let n = self.map.intersections.len();
        let period: f64 =
            DEFAULT_CYCLE.iter().map(|(_, _, green, yellow)| green + yellow).sum::<f64>() * lights.cycle_scale;
        let mut rng = ChaCha8Rng::from_seed(Sha256::digest([LIGHT_PHASE_TAG, &stream[..]].concat()).into());
        let mut draw = || round_mm(rng.random_range(0.0..period));
        let phases: Vec<f64> = match lights.phase.unwrap_or(LightPhase::Random) {
            LightPhase::Fixed => vec![0.0; n],
            LightPhase::Random => vec![draw(); n],
            LightPhase::RandomPerIntersection => (0..n).map(|_| draw()).collect(),
        };
        let offsets: Vec<f64> = (0..n).map(|i| lights.offsets.get(i).copied().unwrap_or(0.0) + phases[i]).collect();
        let mut plan = self.map.light_plan(lights.cycle_scale, &offsets, lights.actuated);
        for o in &lights.overrides {
            let Some(intersection) = self.map.intersections.iter().position(|i| i.name == o.intersection) else {
                continue; // names were checked with the spec
            };
            // Every light of the approach's signal, its variants included
            // (the junction's having lights was checked with the spec too).
            for light in plan.lights.iter_mut() {
                if light.intersection == intersection && light.approach == o.approach && light.signal == o.signal {
                    light.offset = o.offset + phases[intersection];
                    light.schedule = o.schedule.clone();
                }
            }
        }
        plan
    }

    /// The farthest any car can travel in a scenario, metres, plus a margin.
    pub fn max_travel(&self) -> f64 {
        let duration = self.spec.frame_interval() * self.spec.frames as f64;
        let distance = match self.spec.world {
            WorldKind::Toy => self.toy_step_m * self.spec.frames as f64,
            WorldKind::City => {
                let c = self.spec.city_settings();
                c.desired_speed * (1.0 + c.desired_speed_spread) * duration
            }
        };
        distance + 10.0
    }
}

/// The file name of the SUMO network a town's spec names.
fn name_of_network(spec: &DatasetSpec) -> &str {
    spec.map.sumo.as_deref().map_or("", crate::spec::network_file_name)
}

/// City world: a desired speed per leg (before the first of `actions`
/// actions and after each), `desired_speed x (1 +- spread)`; none for toy.
pub(super) fn draw_desired_speeds(
    rng: &mut ChaCha8Rng,
    city: Option<&crate::spec::CitySpec>,
    actions: usize,
) -> Vec<f64> {
    match city {
        Some(c) => (0..=actions)
            .map(|_| {
                let spread = c.desired_speed_spread;
                let factor = if spread > 0.0 { rng.random_range(1.0 - spread..=1.0 + spread) } else { 1.0 };
                c.desired_speed * factor
            })
            .collect(),
        None => Vec::new(),
    }
}

pub(super) fn round_mm(x: f64) -> f64 {
    (x * 1000.0).round() / 1000.0
}
