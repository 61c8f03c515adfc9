//! Spec expansion: turns a [`DatasetSpec`] into one [`ScenarioPlan`] per
//! scenario. Each scenario draws from its own ChaCha8 stream keyed by
//! SHA-256("causalcity/scenario/v1", seed, group, split, index), so its content
//! never depends on thread count, order, sharding or the other groups.

//!
//! One file per concept: this one holds the dataset level (the towns each
//! split draws from, the keys); `planner.rs` plans one scenario on one
//! town; `platoons.rs` its platoon starts; `spawn.rs` where cars may start;
//! `actions.rs` the drive queues drawn.

mod actions;
mod colliders;
mod planner;
mod platoons;
mod spawn;

pub use planner::{Planner, Trials};
pub use spawn::split_owning_start;

use super::{stream_key, GivenCar, PlannedTown, ScenarioKey, ScenarioPlan};
use crate::camera::Camera;
use crate::map::CityMap;
use crate::spec::{DatasetSpec, GroupSpec, MapSpec, SpecError, Split};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use sha2::{Digest, Sha256};
use std::sync::Arc;

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
    /// More than one town name among the planners: plans then say theirs.
    several_towns: bool,
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

    /// How many groups the keys cover.
    pub fn groups(&self) -> usize {
        self.groups.len()
    }

    /// How many keys each group has of `split`.
    pub fn split_len(&self, split: Split) -> usize {
        self.per_split[Split::ALL.iter().position(|s| *s == split).unwrap_or(0)] as usize
    }

    /// Every key in order, each made when it is reached.
    pub fn iter(&self) -> impl ExactSizeIterator<Item = ScenarioKey> + '_ {
        (0..self.len()).map(|i| self.key(i))
    }

    /// The positions of group `group_index`'s keys of `split`.
    pub fn positions_of(&self, group_index: usize, split: Split) -> std::ops::Range<usize> {
        let before: u64 =
            Split::ALL.iter().zip(&self.per_split).take_while(|(s, _)| **s != split).map(|(_, n)| n).sum();
        let start = (group_index as u64 * self.per_group() + before) as usize;
        start..start + self.per_split[Split::ALL.iter().position(|s| *s == split).unwrap_or(0)] as usize
    }

    /// The key at `position` (`position < len()`).
    pub fn key(&self, position: usize) -> ScenarioKey {
        let position = position as u64;
        let group_index = (position / self.per_group()) as usize;
        let (split, within) = split_of(position % self.per_group(), &self.per_split);
        let group = self.groups[group_index].name();
        ScenarioKey { group, group_index, split, index: within as u32, name: None }
    }
}

/// Which split the `within`-th item of a group falls in, when each split of
/// [`Split::ALL`] holds `per_split` items (in that order), and its place
/// within that split.
pub fn split_of(mut within: u64, per_split: &[u64; 3]) -> (Split, u64) {
    let mut split = Split::ALL[0];
    for (s, &n) in Split::ALL.into_iter().zip(per_split) {
        split = s;
        if within < n {
            break;
        }
        within -= n;
    }
    (split, within)
}

/// Keys the stream a scenario's town is drawn from (its own, so drawing
/// it moves no other random number).
const TOWN_TAG: &[u8] = b"causalcity/town/v1";

impl Expansion {
    /// The spec's towns (`map` section), each with its map and camera,
    /// checked as [`Planner::new`] does for a spec about to be written.
    pub fn from_spec(spec: DatasetSpec) -> Result<Expansion, SpecError> {
        Expansion::checked(spec, Trials::Writing)
    }

    /// [`Expansion::from_spec`] for a dataset's own spec, which the `gen`
    /// that wrote it checked: fewer trial plans ([`Trials::Written`]).
    pub fn from_written_spec(spec: DatasetSpec) -> Result<Expansion, SpecError> {
        Expansion::checked(spec, Trials::Written)
    }

    fn checked(spec: DatasetSpec, trials: Trials) -> Result<Expansion, SpecError> {
        spec.map.validate()?;
        let mut planners: Vec<Planner> = Vec::new();
        let mut split_towns = Vec::new();
        for split in Split::ALL {
            let (section, graph, groups) = (spec.map_of(split).clone(), *spec.graph_of(split), spec.groups_of(split));
            let held_out = spec.held_out.of(split).is_some_and(|h| h.map.is_some());
            let held_cars = spec.held_out.of(split).is_some_and(|h| h.cars.is_some());
            let mut towns = Vec::new();
            for town in section.towns() {
                let same_plans = |p: &Planner| p.spec.map == town && p.spec.graph == graph && p.spec.groups == groups;
                let index = match planners.iter().position(same_plans) {
                    Some(index) => index,
                    None => {
                        // The town's map is built once, whatever graphs plan on it.
                        let map = match planners.iter().find(|p| p.spec.map == town) {
                            Some(p) => p.map.clone(),
                            None => town.city_map()?,
                        };
                        let town_spec =
                            DatasetSpec { map: town.clone(), graph, groups: groups.clone(), ..spec.clone() };
                        let mut planner = Planner::new(town_spec, map, trials).map_err(|e| {
                            let e = if held_cars { held_cars_field(e, split) } else { e };
                            in_town(e, &town, section.towns().len(), held_out.then_some(split))
                        })?;
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
        let several_towns = unique_names(planners.iter()).len() > 1;
        Ok(Expansion { spec, map, camera, planners, several_towns, split_towns })
    }

    /// One town, `map`, checked as [`Planner::new`] does (hand-written
    /// scenarios bring their own map).
    pub fn new(spec: DatasetSpec, map: Arc<CityMap>) -> Result<Expansion, SpecError> {
        let planner = Planner::new(spec.clone(), map, Trials::Writing)?;
        let towns = SplitTowns { map: spec.map.clone(), towns: vec![(spec.map.clone(), 0)] };
        let (map, camera) = (planner.map.clone(), planner.camera);
        Ok(Expansion {
            spec,
            map,
            camera,
            planners: vec![planner],
            several_towns: false,
            split_towns: [towns.clone(), towns.clone(), towns],
        })
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
        unique_names(self.planners.iter())
    }

    /// The names of the towns `split` draws from, each once, in order.
    pub fn town_names(&self, split: Split) -> Vec<&str> {
        unique_names(self.split_towns[split.index()].towns.iter().map(|(_, index)| &self.planners[*index]))
    }

    /// The town a plan happens on.
    pub fn town_of(&self, plan: &ScenarioPlan) -> &Planner {
        &self.planners[plan.town_index()]
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
        if self.several_towns {
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

/// The planners' names, each once, in order.
fn unique_names<'a>(planners: impl Iterator<Item = &'a Planner>) -> Vec<&'a str> {
    let mut names: Vec<&str> = Vec::new();
    for planner in planners {
        if !names.contains(&planner.name.as_str()) {
            names.push(&planner.name);
        }
    }
    names
}

/// A planner's error about `groups[i].cars`, said to be about
/// `held_out.<split>.cars` when `split` holds the car count out.
fn held_cars_field(e: SpecError, split: Split) -> SpecError {
    if e.field.starts_with("groups[") && (e.field.ends_with("].cars") || e.field.ends_with(']')) {
        let message = format!("in {}: {}", split.name(), e.message);
        SpecError::new(format!("held_out.{}.cars", split.name()), message)
    } else {
        e
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
