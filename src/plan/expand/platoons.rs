//! Platoon starts (`city.start.platoon_cars`): every car placed blind to
//! roles in queues on the two lanes of one direction, then the pairs,
//! chains or forks drawn among each platoon's cars.

use super::planner::{
    draw_desired_speeds, round_mm, LeaderFollowerPairs, PlacedCar, Planner, PLACEMENT_ATTEMPTS, SPAWN_CLEARANCE,
};
use super::spawn::{split_owning_start, OWNED_START_SEARCH_MM};
use crate::geometry::OrientedBox;
use crate::map::{Action, AdaptationKind, LaneId};
use crate::plan::{Role, ScenarioKey};
use crate::spec::{GraphShape, GroupSpec};

/// Tries at a colliders scenario's platoons before planning gives up.
const COLLIDER_PLATOON_TRIES: usize = 1000;

use rand::seq::SliceRandom;
use rand::RngExt;
use rand_chacha::ChaCha8Rng;
use std::sync::Arc;

impl Planner {
    /// City with platoons (see [`crate::spec::StartSpec`]): places every car
    /// of the group in platoons, blind to roles, then draws the
    /// leader-follower pairs uniformly among each platoon's (ahead, behind)
    /// pairs (or the chains and forks among its cars). Returns the cars and
    /// the (leader, follower) indices.
    pub(super) fn place_platoons(
        &self,
        key: &ScenarioKey,
        rng: &mut ChaCha8Rng,
        city: &crate::spec::CitySpec,
        group: &GroupSpec,
    ) -> Result<(Vec<PlacedCar>, LeaderFollowerPairs), String> {
        if self.spec.graph.shape != GraphShape::Colliders {
            // Platoons placed one by one can leave no room for the last
            // (one 100-car scenario in 4 failed midway through a dataset
            // whose first scenario planned): start again, the stream going
            // on, so a scenario that placed at once keeps its bytes.
            let mut failed = String::new();
            for _ in 0..self.platoon_starts {
                match self.place_platoons_once(key, rng, city, group, 0) {
                    Ok(placed) => return Ok(placed),
                    Err(e) => failed = e,
                }
            }
            return Err(failed);
        }
        // Colliders: the platoons hold every car but those with priority,
        // which come after; a try whose followers cannot all be given one
        // (a junction where they have the right of way) starts again.
        let units = self.spec.graph.units(group.edges());
        let colliders = units.iter().filter(|&&n| n == self.spec.graph.unit_cars()).count();
        let (mut failed, mut reached_priority) = (None, false);
        for _ in 0..COLLIDER_PLATOON_TRIES {
            // Pairs that do not fit these platoons (a follower that cannot
            // take its leader's turns) are drawn again too.
            let (mut cars, mut pairs) = match self.place_platoons_once(key, rng, city, group, colliders) {
                Ok(placed) => placed,
                Err(e) => {
                    failed = Some(e);
                    continue;
                }
            };
            let mut boxes: Vec<OrientedBox> = cars.iter().map(|c| self.car_box(c.spawn, c.distance)).collect();
            let mut given = 0;
            for k in 0..pairs.len() {
                if given == colliders {
                    break;
                }
                let (leader, follower) = pairs[k];
                let split = key.split.index();
                if let Some(priority) = self.place_priority_car(rng, city, split, (leader, follower), &cars, &boxes) {
                    boxes.push(self.car_box(priority.spawn, priority.distance));
                    pairs.push((cars.len(), follower));
                    cars[follower].gives_way_to = Some(cars.len());
                    cars.push(priority);
                    given += 1;
                }
            }
            if given == colliders {
                return Ok((cars, pairs));
            }
            reached_priority = true;
        }
        // The platoons' own error only where no try got as far as the cars
        // with priority.
        let failed = failed.filter(|_| !reached_priority);
        Err(failed.unwrap_or_else(|| format!(
            "could not give {colliders} followers a car with priority at their first junction after {COLLIDER_PLATOON_TRIES} tries: colliders need junctions where drivers give way (no lights, or left turns on a permissive green) with approaches long enough to start the car with priority on {}, or fewer cars",
                    self.longer_approaches()
        )))
    }

    /// [`Self::place_platoons`]'s cars, less `colliders` cars with priority
    /// placed afterwards, whose (leader, follower) pairs the pairs drawn
    /// here include (a collider's queue is a pair).
    fn place_platoons_once(
        &self,
        key: &ScenarioKey,
        rng: &mut ChaCha8Rng,
        city: &crate::spec::CitySpec,
        group: &GroupSpec,
        colliders: usize,
    ) -> Result<(Vec<PlacedCar>, LeaderFollowerPairs), String> {
        let size = city.start.platoon_cars as usize;
        let total = group.cars as usize - colliders;
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
                    "could not place {} cars in platoons of {size} without overlap ({PLACEMENT_ATTEMPTS} tries at a platoon): use fewer cars, smaller platoons (city.start.platoon_cars) or wider gaps within them (city.start.follower_gap_m)",
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
                    gives_way_to: None,
                    on_leader_lost: None,
                });
                platoon_of.push(platoon);
            }
        }
        let pairs = if self.spec.graph.is_pairs() {
            self.draw_platoon_pairs(rng, &cars, &platoon_of, group.edges() as usize, size)?
        } else if colliders > 0 || self.spec.graph.shape == GraphShape::Colliders {
            // One pair per collider, and one for an odd edge left over.
            let wanted = self.spec.graph.units(group.edges()).len();
            self.draw_platoon_pairs(rng, &cars, &platoon_of, wanted, size)?
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
