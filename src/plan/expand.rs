//! Spec expansion: turns a [`DatasetSpec`] into one [`ScenarioPlan`] per
//! scenario. Each scenario draws from its own ChaCha8 stream keyed by
//! SHA-256("causalcity/scenario/v1", seed, group, split, index), so its content
//! never depends on thread count, order, sharding or the other groups.

use super::confounders::ConfounderModel;
use super::{
    stream_key, CarAgency, CarPlan, CityPlan, Fallback, GivenCar, OnLeaderLost, PlannedTown, Role, ScenarioKey,
    ScenarioPlan, WorldPlan,
};
use crate::camera::Camera;
use crate::geometry::OrientedBox;
use crate::map::signals::{LightPlan, DEFAULT_CYCLE};
use crate::map::{Action, AdaptationKind, CityMap, LaneEnd, LaneId, LanePolicy, Route};
use crate::spec::{
    ActionDrawing, DatasetSpec, GraphShape, GroupSpec, LightPhase, MapSpec, SpecError, Split, WorldKind,
    DEFAULT_LEADER_GAP_PX,
};
use rand::seq::SliceRandom;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sha2::{Digest, Sha256};
use std::sync::Arc;

/// A car placed on the map before ids are assigned.
#[derive(Clone)]
struct PlacedCar {
    role: Role,
    spawn: LaneId,
    distance: f64,
    actions: Vec<Action>,
    merges: Vec<f64>,
    route: Arc<Route>,
    desired_speeds: Vec<f64>,
    /// A hard negative: the index of the car it starts right behind.
    behind: Option<usize>,
    /// A follower: the index of its leader.
    leader: Option<usize>,
    /// A follower: what it does once it loses its leader.
    on_leader_lost: Option<OnLeaderLost>,
}

/// A span of a spawn lane where a car's centre is on camera.
#[derive(Debug, Clone, Copy)]
struct SpawnSpan {
    lane: LaneId,
    lo: f64,
    hi: f64,
}

/// The spec checked against every town it can draw, able to plan any
/// scenario: one [`Planner`] per town, and each split's map section to
/// draw its scenarios' towns from.
#[derive(Debug)]
pub struct Expansion {
    pub spec: DatasetSpec,
    /// The first town's map and bird's-eye camera: the only town of a spec
    /// whose map draws nothing.
    pub map: Arc<CityMap>,
    pub camera: Camera,
    planners: Vec<Planner>,
    /// Per split of [`Split::ALL`]: the map section its towns are drawn
    /// from, and each town it can draw with its planner's index.
    split_towns: [SplitTowns; 3],
}

/// The towns one split draws from.
#[derive(Debug, Clone)]
struct SplitTowns {
    map: MapSpec,
    towns: Vec<(MapSpec, usize)>,
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
    spans: Vec<SpawnSpan>,
    leader_gap_m: f64,
    /// The closest two cars of one lane may start, centre to centre, metres:
    /// the toy's exact leader gap, or a car length plus the city's shortest
    /// follower gap.
    shortest_spacing_m: f64,
    toy_step_m: f64,
}

/// Keys the stream a scenario's light phase is drawn from.
const LIGHT_PHASE_TAG: &[u8] = b"causalcity/light-phase/v1";
/// Keys the stream followers' fallback drive queues are drawn from (its own,
/// so drawing them moves no other random number).
const FALLBACK_TAG: &[u8] = b"causalcity/follower-fallback/v1";

/// Clearance kept between cars at spawn, metres.
const SPAWN_CLEARANCE: f64 = 0.1;

/// The split that owns the start `s` metres along `lane` (to 0.1 mm, the
/// pose log's precision): train, val or test (0, 1, 2), by a hash that
/// interleaves the three finely along every lane. Every car of a split
/// starts on a point that split owns, so no car of one split starts where
/// a car of another does, and no car trajectory (starting point first) has
/// an identical twin in another split, while each split's starts still
/// cover every lane uniformly.
pub fn split_owning_start(lane: LaneId, s: f64) -> usize {
    // SplitMix64's finaliser over (lane, position in tenths of a millimetre).
    let mut z = ((lane as u64) << 40) ^ ((s * 1e4).round() as i64 as u64);
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    ((z ^ (z >> 31)) % 3) as usize
}

/// Most millimetres a drawn start moves forward to a point its split owns
/// (a pair needs both cars' points: one in nine on average).
const OWNED_START_SEARCH_MM: usize = 200;
const PLACEMENT_ATTEMPTS: usize = 2000;

/// (leader, follower) indices into a scenario's placed cars.
type LeaderFollowerPairs = Vec<(usize, usize)>;

/// The keys of [`Expansion::keys`], computed from their position: groups
/// in spec order, then splits in [`Split::ALL`] order, then indices.
#[derive(Debug, Clone, Copy)]
pub struct KeySequence<'a> {
    groups: &'a [GroupSpec],
    /// Scenarios of each split (of [`Split::ALL`]) per group.
    per_split: [u64; 3],
}

impl KeySequence<'_> {
    /// How many keys there are.
    pub fn len(&self) -> usize {
        (self.groups.len() as u64 * self.per_group()) as usize
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    fn per_group(&self) -> u64 {
        self.per_split.iter().sum()
    }

    /// The key at `position` (`position < len()`).
    pub fn key(&self, position: usize) -> ScenarioKey {
        let position = position as u64;
        let group_index = (position / self.per_group()) as usize;
        let mut within = position % self.per_group();
        let mut split = Split::ALL[0];
        for (s, &n) in Split::ALL.into_iter().zip(&self.per_split) {
            split = s;
            if within < n {
                break;
            }
            within -= n;
        }
        let group = self.groups[group_index].name();
        ScenarioKey { group, group_index, split, index: within as u32, name: None }
    }
}

/// Keys the stream a scenario's town is drawn from (its own, so drawing
/// it moves no other random number).
const TOWN_TAG: &[u8] = b"causalcity/town/v1";

impl Expansion {
    /// The spec's towns (`map` section), each with its map and camera,
    /// checked as [`Planner::new`] does.
    pub fn from_spec(spec: DatasetSpec) -> Result<Expansion, SpecError> {
        spec.map.validate()?;
        let mut planners: Vec<Planner> = Vec::new();
        let mut split_towns = Vec::new();
        for split in Split::ALL {
            let (section, graph) = (spec.map_of(split).clone(), *spec.graph_of(split));
            let held_out = spec.held_out.of(split).is_some_and(|h| h.map.is_some());
            let mut towns = Vec::new();
            for town in section.towns() {
                let index = match planners.iter().position(|p| p.spec.map == town && p.spec.graph == graph) {
                    Some(index) => index,
                    None => {
                        // The town's map is built once, whatever graphs plan on it.
                        let map = match planners.iter().find(|p| p.spec.map == town) {
                            Some(p) => p.map.clone(),
                            None => Arc::new(CityMap::new(town.layout())),
                        };
                        let town_spec = DatasetSpec { map: town.clone(), graph, ..spec.clone() };
                        let mut planner = Planner::new(town_spec, map)
                            .map_err(|e| in_town(e, &town, section.towns().len(), held_out.then_some(split)))?;
                        // Names are unique per map: a second town of the same name is numbered.
                        let same_name = |p: &&Planner| p.name == planner.name && p.spec.map != town;
                        if planners.iter().any(|p| same_name(&p)) {
                            let base = planner.name.clone();
                            let free =
                                (2..).map(|k| format!("{base}-{k}")).find(|n| planners.iter().all(|p| &p.name != n));
                            planner.name = free.unwrap_or(base);
                        } else if let Some(p) = planners.iter().find(|p| p.spec.map == town) {
                            planner.name = p.name.clone();
                        }
                        planners.push(planner);
                        planners.len() - 1
                    }
                };
                towns.push((town, index));
            }
            split_towns.push(SplitTowns { map: section, towns });
        }
        let split_towns: [SplitTowns; 3] = split_towns.try_into().expect("one per split");
        let (map, camera) = (planners[0].map.clone(), planners[0].camera);
        Ok(Expansion { spec, map, camera, planners, split_towns })
    }

    /// One town, `map`, checked as [`Planner::new`] does (hand-written
    /// scenarios bring their own map).
    pub fn new(spec: DatasetSpec, map: Arc<CityMap>) -> Result<Expansion, SpecError> {
        let planner = Planner::new(spec.clone(), map)?;
        let towns = SplitTowns { map: spec.map.clone(), towns: vec![(spec.map.clone(), 0)] };
        let (map, camera) = (planner.map.clone(), planner.camera);
        Ok(Expansion { spec, map, camera, planners: vec![planner], split_towns: [towns.clone(), towns.clone(), towns] })
    }

    /// Every town a scenario can happen on, with the graph shape planned
    /// on it, in a fixed order: the first one's map and camera are
    /// [`Expansion::map`] and [`Expansion::camera`]. A town whose splits
    /// plan different graph shapes is listed once per shape, under one name.
    pub fn towns(&self) -> &[Planner] {
        &self.planners
    }

    /// The names of every town, each once, in order.
    pub fn all_town_names(&self) -> Vec<&str> {
        let mut names: Vec<&str> = Vec::new();
        for planner in &self.planners {
            if !names.contains(&planner.name.as_str()) {
                names.push(&planner.name);
            }
        }
        names
    }

    /// The names of the towns `split` draws from, each once, in order.
    pub fn town_names(&self, split: Split) -> Vec<&str> {
        let mut names: Vec<&str> = Vec::new();
        for (_, index) in &self.split_towns[split.index()].towns {
            let name = self.planners[*index].name.as_str();
            if !names.contains(&name) {
                names.push(name);
            }
        }
        names
    }

    /// The town a plan happens on.
    pub fn town_of(&self, plan: &ScenarioPlan) -> &Planner {
        &self.planners[plan.town.as_ref().map_or(0, |t| t.index)]
    }

    /// Plans one scenario on the town its split draws for it. Errors only
    /// when cars cannot be placed.
    pub fn plan(&self, key: &ScenarioKey) -> Result<ScenarioPlan, String> {
        let split = &self.split_towns[key.split.index()];
        let index = match split.towns.as_slice() {
            [(_, index)] => *index,
            towns => {
                let stream = stream_key(self.spec.seed, &key.group, key.split, key.index);
                let mut rng = ChaCha8Rng::from_seed(Sha256::digest([TOWN_TAG, &stream[..]].concat()).into());
                let drawn = split.map.draw_town(&mut rng);
                towns.iter().find(|(town, _)| *town == drawn).map(|(_, index)| *index).unwrap_or(towns[0].1)
            }
        };
        let planner = &self.planners[index];
        let mut plan = planner.plan(key)?;
        if self.planners.iter().any(|p| p.name != self.planners[0].name) {
            plan.town = Some(PlannedTown { index, name: planner.name.clone(), map: planner.spec.map.clone() });
        }
        Ok(plan)
    }

    /// Plans a scenario of given cars on the first town (see [`Planner::plan_given`]).
    pub fn plan_given(
        &self,
        key: &ScenarioKey,
        stream: [u8; 32],
        given: &[GivenCar],
        pairs: &[(usize, usize)],
    ) -> ScenarioPlan {
        self.planners[0].plan_given(key, stream, given, pairs)
    }

    /// The farthest any car can travel in a scenario of the first town, metres.
    pub fn max_travel(&self) -> f64 {
        self.planners[0].max_travel()
    }

    /// Every scenario of the dataset in a fixed order (group, split, index),
    /// with at most `limit` scenarios per split.
    pub fn keys(&self, limit: Option<u32>) -> Vec<ScenarioKey> {
        let sequence = self.key_sequence(limit);
        (0..sequence.len()).map(|i| sequence.key(i)).collect()
    }

    /// [`Expansion::keys`] without holding them: any key by its position,
    /// in memory independent of the split sizes (a spec at the largest
    /// split sizes has tens of millions of keys).
    pub fn key_sequence(&self, limit: Option<u32>) -> KeySequence<'_> {
        let per_split = Split::ALL.map(|s| self.spec.splits.count(s).min(limit.unwrap_or(u32::MAX)) as u64);
        KeySequence { groups: &self.spec.groups, per_split }
    }
}

/// A town's spec error, said to be the town's when the map draws several
/// or when a split holds it out (`held_out`).
fn in_town(e: SpecError, town: &MapSpec, towns: usize, held_out: Option<Split>) -> SpecError {
    let field = match held_out {
        Some(split) if e.field.starts_with("map.") => format!("held_out.{}.{}", split.name(), e.field),
        _ => e.field.clone(),
    };
    match (towns > 1, held_out) {
        (_, Some(split)) => {
            SpecError::new(field, format!("in the {} town {} holds out: {}", town.town_name(), split.name(), e.message))
        }
        (true, None) => SpecError::new(field, format!("in the {} town: {}", town.town_name(), e.message)),
        (false, None) => e,
    }
}

impl Planner {
    /// Checks that every group can be planned on this map and camera.
    pub fn new(spec: DatasetSpec, map: Arc<CityMap>) -> Result<Planner, SpecError> {
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
        let spans = spawn_spans(&map, &camera, spec.car_length_m);
        let slot = spec.car_length_m + SPAWN_CLEARANCE;
        let capacity: u32 = spans.iter().map(|s| ((s.hi - s.lo) / slot) as u32 + 1).sum();
        let toy_step_m = camera.pixels_to_metres(spec.toy_speed_px_per_frame);
        let shortest_spacing_m = match spec.world {
            WorldKind::Toy => leader_gap_m,
            WorldKind::City => spec.car_length_m + spec.city_settings().start.follower_gap_m.lowest(),
        };
        let name = spec.map.town_name();
        let expansion = Planner { spec, name, map, camera, spans, leader_gap_m, shortest_spacing_m, toy_step_m };
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
            // A dry run proves the group can be planned before anything is written.
            let key = ScenarioKey { group: g.name(), group_index: i, split: Split::Train, index: 0, name: None };
            expansion.plan(&key).map_err(|e| SpecError::new(format!("groups[{i}]"), e))?;
        }
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
        for &size in &unit_sizes {
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
                done = true;
                break;
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
    fn finish(
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

    /// City with platoons (see [`crate::spec::StartSpec`]): places every car
    /// of the group in platoons, blind to roles, then draws the
    /// leader-follower pairs uniformly among each platoon's (ahead, behind)
    /// pairs (or the chains and forks among its cars). Returns the cars and
    /// the (leader, follower) indices.
    fn place_platoons(
        &self,
        key: &ScenarioKey,
        rng: &mut ChaCha8Rng,
        city: &crate::spec::CitySpec,
        group: &GroupSpec,
    ) -> Result<(Vec<PlacedCar>, LeaderFollowerPairs), String> {
        let size = city.start.platoon_cars as usize;
        let total = group.cars as usize;
        let split = key.split.index();
        let travel = self.max_travel();
        let mut boxes: Vec<OrientedBox> = Vec::new();
        let mut cars: Vec<PlacedCar> = Vec::new();
        let mut platoon_of: Vec<usize> = Vec::new();
        for (platoon, first) in (0..total).step_by(size).enumerate() {
            let count = size.min(total - first);
            let placed = (0..PLACEMENT_ATTEMPTS).find_map(|_| self.try_platoon(rng, city, split, count, &cars, &boxes));
            let Some(starts) = placed else {
                return Err(format!(
                    "could not place {} cars in platoons of {size} without overlap after {PLACEMENT_ATTEMPTS} tries: use fewer cars or smaller platoons",
                    group.cars
                ));
            };
            for (lane, s) in starts {
                boxes.push(self.car_box(lane, s));
                let (mut actions, merges) = self.draw_actions(rng, city.action_drawing, lane, s);
                let route = Arc::new(self.plan_feasible_route(lane, s, &mut actions, &merges, travel)?);
                let desired_speeds = draw_desired_speeds(rng, Some(city), actions.len());
                cars.push(PlacedCar {
                    role: Role::Independent,
                    spawn: lane,
                    distance: s,
                    actions,
                    merges,
                    route,
                    desired_speeds,
                    behind: None,
                    leader: None,
                    on_leader_lost: None,
                });
                platoon_of.push(platoon);
            }
        }
        let pairs = if self.spec.graph.is_pairs() {
            self.draw_platoon_pairs(rng, &cars, &platoon_of, group.edges() as usize, size)?
        } else {
            self.draw_platoon_parts(rng, &cars, &platoon_of, group.edges())?
        };
        // A follower drives what its leader drives, from where it starts
        // (a chain's edges come front to back, so a car copies its leader's
        // queue after the leader has copied its own).
        for &(leader, follower) in &pairs {
            let (actions, merges) = (cars[leader].actions.clone(), cars[leader].merges.clone());
            let f = &cars[follower];
            let route = Arc::new(self.plan_route(f.spawn, f.distance, &actions, &merges, travel)?);
            // A chain's middle car keeps the follower's role (it has a leader).
            if cars[leader].role == Role::Independent {
                cars[leader].role = Role::Leader;
            }
            let f = &mut cars[follower];
            f.role = Role::Follower;
            f.leader = Some(leader);
            f.actions = actions;
            f.merges = merges;
            f.route = route;
        }
        Ok((cars, pairs))
    }

    /// The leader-follower pairs of platoon starts: every (ahead, behind)
    /// pair of a platoon in random order, taken while both cars are free,
    /// so each is a pair with the same chance. Sorted by index.
    fn draw_platoon_pairs(
        &self,
        rng: &mut ChaCha8Rng,
        cars: &[PlacedCar],
        platoon_of: &[usize],
        wanted: usize,
        size: usize,
    ) -> Result<LeaderFollowerPairs, String> {
        let mut candidates: Vec<(usize, usize)> = Vec::new();
        for a in 0..cars.len() {
            for b in 0..cars.len() {
                if platoon_of[a] == platoon_of[b] && cars[a].distance > cars[b].distance && self.can_follow(cars, a, b)
                {
                    candidates.push((a, b));
                }
            }
        }
        candidates.shuffle(rng);
        let mut taken = vec![false; cars.len()];
        let mut pairs = Vec::new();
        for (a, b) in candidates {
            if pairs.len() < wanted && !taken[a] && !taken[b] {
                taken[a] = true;
                taken[b] = true;
                pairs.push((a, b));
            }
        }
        if pairs.len() < wanted {
            return Err(format!(
                "{wanted} leader-follower pairs do not fit in platoons of {size} cars (a car is in one pair at most): use an even city.start.platoon_cars"
            ));
        }
        pairs.sort_unstable();
        Ok(pairs)
    }

    /// Whether car `follower` can take the turns of car `leader`'s queue
    /// from where it starts (no turn skipped for want of room to change
    /// lanes before it). Grid towns only: the four-road city keeps its
    /// draw, so that existing datasets stay byte for byte the same.
    fn can_follow(&self, cars: &[PlacedCar], leader: usize, follower: usize) -> bool {
        if self.spec.map.grid.is_none() {
            return true;
        }
        let (l, f) = (&cars[leader], &cars[follower]);
        let Ok(route) = self.plan_route(f.spawn, f.distance, &l.actions, &l.merges, self.max_travel()) else {
            return false;
        };
        !route
            .adaptations
            .iter()
            .any(|a| a.kind == AdaptationKind::Skipped && !a.action.is_merge() && a.action != Action::Straight)
    }

    /// The edges of chains or forks among platoon starts: for each part of
    /// [`crate::spec::GraphSpec::units`], largest first, a set of that many
    /// free cars of one platoon drawn uniformly, ordered front to back (a
    /// chain links each to the car behind it, a fork the first to every
    /// other). Chains' edges come front to back.
    fn draw_platoon_parts(
        &self,
        rng: &mut ChaCha8Rng,
        cars: &[PlacedCar],
        platoon_of: &[usize],
        edges: u32,
    ) -> Result<LeaderFollowerPairs, String> {
        let graph = &self.spec.graph;
        let mut taken = vec![false; cars.len()];
        let mut links = Vec::new();
        for size in graph.units(edges) {
            let size = size as usize;
            // Every set of `size` free cars of one platoon, front to back,
            // whose followers can each drive the part's queue.
            let mut candidates: Vec<Vec<usize>> = Vec::new();
            for platoon in 0..=platoon_of.iter().copied().max().unwrap_or(0) {
                let mut members: Vec<usize> =
                    (0..cars.len()).filter(|&c| platoon_of[c] == platoon && !taken[c]).collect();
                members.sort_by(|&a, &b| cars[b].distance.total_cmp(&cars[a].distance).then(a.cmp(&b)));
                subsets(&members, size, &mut Vec::new(), &mut candidates);
            }
            candidates.retain(|part| part[1..].iter().all(|&f| self.can_follow(cars, part[0], f)));
            let drawn = (!candidates.is_empty()).then(|| rng.random_range(0..candidates.len()));
            let Some(part) = drawn.map(|k| candidates.swap_remove(k)) else {
                return Err(format!(
                    "{edges} edges in {} of {} cars do not fit in these platoons (a car is in one chain or fork at most): use fewer edges or larger city.start.platoon_cars",
                    graph.shape.name(),
                    graph.unit_cars()
                ));
            };
            for (j, &follower) in part.iter().enumerate().skip(1) {
                taken[follower] = true;
                let leader = if graph.shape == GraphShape::Chains { part[j - 1] } else { part[0] };
                links.push((leader, follower));
            }
            taken[part[0]] = true;
        }
        Ok(links)
    }

    /// One try at the starts (lane, metres along it) of a platoon of `count`
    /// cars: a random on-camera stretch of one direction of one road
    /// segment, each car in one of its lanes at random, queued in its lane
    /// `follower_gap_m` apart, every start on a point the split owns and
    /// clear of the cars already placed.
    fn try_platoon(
        &self,
        rng: &mut ChaCha8Rng,
        city: &crate::spec::CitySpec,
        split: usize,
        count: usize,
        cars: &[PlacedCar],
        boxes: &[OrientedBox],
    ) -> Option<Vec<(LaneId, f64)>> {
        let span = self.spans[rng.random_range(0..self.spans.len())];
        let mut lanes = vec![span];
        let beside = self.map.adjacent_lane(span.lane, true).or_else(|| self.map.adjacent_lane(span.lane, false));
        if let Some(other) = beside.and_then(|l| self.spans.iter().find(|s| s.lane == l)) {
            lanes.push(*other);
        }
        let lane_of: Vec<usize> = (0..count).map(|_| rng.random_range(0..lanes.len())).collect();
        let mut starts = Vec::with_capacity(count);
        for (i, lane) in lanes.iter().enumerate() {
            let queued = lane_of.iter().filter(|&&l| l == i).count();
            if queued == 0 {
                continue;
            }
            let spacings: Vec<f64> = (1..queued).map(|_| self.draw_spacing(rng, Some(city))).collect();
            let length: f64 = spacings.iter().sum();
            if lane.hi - lane.lo < length {
                return None;
            }
            let mut s = round_mm(rng.random_range(lane.lo + length..=lane.hi));
            let mut queue = vec![s];
            for spacing in spacings {
                s = round_mm(s - spacing);
                queue.push(s);
            }
            // Each start moved forward to the nearest point this split owns.
            for s in queue {
                let owned = (0..OWNED_START_SEARCH_MM)
                    .map(|mm| round_mm(s + mm as f64 / 1000.0))
                    .find(|&o| split_owning_start(lane.lane, o) == split)?;
                if owned > lane.hi {
                    return None;
                }
                starts.push((lane.lane, owned));
            }
        }
        // No car closer to another of its lane than the shortest follower
        // gap, and none overlapping another.
        let spaced = starts.iter().enumerate().all(|(i, &(lane, s))| {
            let others = cars.iter().map(|c| (c.spawn, c.distance)).chain(starts[i + 1..].iter().copied());
            others.filter(|&(l, _)| l == lane).all(|(_, o)| (o - s).abs() >= self.shortest_spacing_m - 1e-6)
        });
        if !spaced {
            return None;
        }
        let mut grown: Vec<OrientedBox> = boxes.iter().map(|b| b.inflated(SPAWN_CLEARANCE / 2.0)).collect();
        for &(lane, s) in &starts {
            let b = self.car_box(lane, s).inflated(SPAWN_CLEARANCE / 2.0);
            if grown.iter().any(|p| b.overlaps(p)) {
                return None;
            }
            grown.push(b);
        }
        Some(starts)
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
    fn draw_spacing(&self, rng: &mut ChaCha8Rng, city: Option<&crate::spec::CitySpec>) -> f64 {
        match city {
            Some(c) => round_mm(self.spec.car_length_m + c.start.follower_gap_m.sample(rng)),
            None => self.leader_gap_m,
        }
    }

    /// As [`Self::plan_route`], with every turn the route must skip (no
    /// room to change into its lane from the start) written as the straight
    /// on the car drives instead, so the queue says what the car does and a
    /// follower copying it takes the turns its leader takes.
    fn plan_feasible_route(
        &self,
        lane: LaneId,
        front: f64,
        actions: &mut [Action],
        merges: &[f64],
        travel: f64,
    ) -> Result<Route, String> {
        let mut route = self.plan_route(lane, front, actions, merges, travel)?;
        // Each pass can only turn skipped turns into straights: it ends.
        for _ in 0..actions.len() {
            let skipped: Vec<usize> = route
                .adaptations
                .iter()
                .filter(|a| a.kind == AdaptationKind::Skipped && !a.action.is_merge() && a.action != Action::Straight)
                .map(|a| a.action_index)
                .collect();
            if skipped.is_empty() {
                break;
            }
            for k in skipped {
                actions[k] = Action::Straight;
            }
            route = self.plan_route(lane, front, actions, merges, travel)?;
        }
        Ok(route)
    }

    /// The footprint of a car centred `s` metres along `lane`.
    fn car_box(&self, lane: LaneId, s: f64) -> OrientedBox {
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
    fn draw_actions(
        &self,
        rng: &mut ChaCha8Rng,
        drawing: ActionDrawing,
        lane: LaneId,
        s: f64,
    ) -> (Vec<Action>, Vec<f64>) {
        let count = self.spec.actions_per_car;
        match drawing {
            ActionDrawing::Original => original_actions(rng, count),
            _ => random_actions(rng, &self.map, lane, s, count),
        }
    }

    /// The route of a car entering at `front` metres along `lane`, `travel`
    /// metres long (enough for the whole scenario).
    fn plan_route(
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
            WorldKind::City => WorldPlan::City(self.city_plan(stream, &mut rng, &cars, ids)),
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
    fn city_plan(&self, stream: [u8; 32], rng: &mut ChaCha8Rng, cars: &[PlacedCar], ids: &[u32]) -> CityPlan {
        let c = self.spec.city_settings();
        let cs = &c.confounders;
        let (confounders, confounder_model) = ConfounderModel::draw(cs, rng);
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
        let mut plan = LightPlan::cycle(n, lights.cycle_scale, &offsets);
        for o in &lights.overrides {
            let Some(intersection) = self.map.intersections.iter().position(|i| i.name == o.intersection) else {
                continue; // names were checked with the spec
            };
            let index = plan.index(intersection, o.approach, o.signal);
            plan.lights[index].offset = o.offset + phases[intersection];
            plan.lights[index].schedule = o.schedule.clone();
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

/// City world: a desired speed per leg (before the first of `actions`
/// actions and after each), `desired_speed x (1 +- spread)`; none for toy.
fn draw_desired_speeds(rng: &mut ChaCha8Rng, city: Option<&crate::spec::CitySpec>, actions: usize) -> Vec<f64> {
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

fn round_mm(x: f64) -> f64 {
    (x * 1000.0).round() / 1000.0
}

/// Chance that a lane-valid drawn action is a merge, where one fits.
const MERGE_SHARE: f64 = 0.25;

/// A random drive queue drawn as the original's `scenarioGenerator.py`
/// draws it, whatever lane the car will be in: each action `left`, `right`
/// or `straight` with equal chance. (The original writes merge names only
/// into `MergeAtDistances`, where its engine never carried them out, so no
/// merges are drawn.) Drivers plan the lane changes their turns need.
fn original_actions(rng: &mut ChaCha8Rng, count: u32) -> (Vec<Action>, Vec<f64>) {
    (0..count).map(|_| ([Action::Left, Action::Right, Action::Straight][rng.random_range(0..3)], 0.0)).unzip()
}

/// A valid random drive queue from `lane`, where the first car on the route
/// starts `entry` metres along it. Merges are drawn only where they fit.
fn random_actions(
    rng: &mut ChaCha8Rng,
    map: &CityMap,
    spawn: LaneId,
    entry: f64,
    count: u32,
) -> (Vec<Action>, Vec<f64>) {
    let mut lane = spawn;
    let mut earliest = entry;
    let run = map.layout.lane_change_length;
    let mut actions = Vec::new();
    let mut merges = Vec::new();
    for _ in 0..count {
        let len = map.lanes[lane].curve.length();
        // Merge distances on a 0.1 m grid that fits before the lane ends.
        // At least 1 m after the car, so a car can check the gap before it starts.
        let lo = ((earliest + 1.0) * 10.0).ceil() / 10.0;
        let hi = ((len - run) * 10.0).floor() / 10.0;
        let merge_side = map
            .adjacent_lane(lane, true)
            .map(|l| (Action::MergeL, l))
            .or_else(|| map.adjacent_lane(lane, false).map(|l| (Action::MergeR, l)));
        if let (Some((action, target)), true) = (merge_side, lo <= hi) {
            if rng.random_bool(MERGE_SHARE) {
                let at = ((rng.random_range(lo..=hi) * 10.0).round() / 10.0).clamp(lo, hi);
                actions.push(action);
                merges.push(at);
                lane = target;
                earliest = at + run;
                continue;
            }
        }
        // A turn applies at the next intersection, after any off-camera loop.
        let mut approach = lane;
        if let LaneEnd::Loop(c) = map.lanes[lane].end {
            approach = map.connectors[c].to;
        }
        let turns = map.allowed_turns(approach);
        let turn = turns[rng.random_range(0..turns.len())];
        let action = match turn {
            crate::map::Turn::Left => Action::Left,
            crate::map::Turn::Right => Action::Right,
            _ => Action::Straight,
        };
        actions.push(action);
        merges.push(0.0);
        let connector = map.exit(approach, turn).expect("allowed turn has a connector");
        lane = map.connectors[connector].to;
        earliest = 0.0;
    }
    (actions, merges)
}

/// Appends to `out` every subset of `items` with `size` members, each in
/// `items`' order.
fn subsets(items: &[usize], size: usize, chosen: &mut Vec<usize>, out: &mut Vec<Vec<usize>>) {
    if chosen.len() == size {
        out.push(chosen.clone());
        return;
    }
    for (k, &item) in items.iter().enumerate() {
        if items.len() - k < size - chosen.len() {
            break;
        }
        chosen.push(item);
        subsets(&items[k + 1..], size, chosen, out);
        chosen.pop();
    }
}

/// Spans of each spawn lane where a car lies wholly on camera.
fn spawn_spans(map: &CityMap, camera: &Camera, car_length: f64) -> Vec<SpawnSpan> {
    let (lo, hi) = camera.ground_view();
    let margin = car_length;
    let step = 0.05;
    let mut spans = Vec::new();
    for lane in map.spawn_points() {
        let curve = &map.lanes[lane].curve;
        // Cars start behind the stop line, never on the crosswalk.
        let end = match map.lanes[lane].end {
            LaneEnd::Intersection { .. } => curve.length() - map.layout.stop_line_setback - 0.5,
            LaneEnd::Loop(_) => curve.length(),
        };
        let mut first = None;
        let mut last = None;
        let mut s = car_length / 2.0;
        while s <= end - car_length / 2.0 {
            let p = curve.lane_center_at(s);
            if p.x >= lo.x + margin && p.x <= hi.x - margin && p.y >= lo.y + margin && p.y <= hi.y - margin {
                first.get_or_insert(s);
                last = Some(s);
            }
            s += step;
        }
        if let (Some(a), Some(b)) = (first, last) {
            spans.push(SpawnSpan { lane, lo: a, hi: b });
        }
    }
    spans
}
