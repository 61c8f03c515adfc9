//! A scenario file's vehicles: spawn points, drive queues, merge distances
//! and the per-car extensions, resolved on the map; and the leader-follower
//! pairs the original's format implies.

use super::raw::RawVehicle;
use super::{Here, ScenarioFileError};
use crate::json::Shown;
use crate::map::{Action, CityMap, LanePolicy, Route};
use crate::plan::GivenCar;
use crate::spec::WorldKind;
use serde_json::Value;
use std::sync::Arc;

/// Most actions one list of a scenario file may hold (a `DriveQueue`, an
/// intervention's `actions`): a car's route is planned whole when it is
/// read, about 700 bytes an action, and 5 million aborted `run` out of
/// memory. The original's files hold a handful (its README's example, 5);
/// a spec draws at most 100 (`actions_per_car`).
pub const MAX_ACTIONS_IN_A_LIST: usize = 1000;

/// Actions by name; `list` is the JSON path of the list and `field(i)` of
/// entry `i`.
pub(super) fn resolve_actions(
    names: &[String],
    list: &str,
    field: impl Fn(usize) -> String,
) -> Result<Vec<Action>, (String, String)> {
    if names.len() > MAX_ACTIONS_IN_A_LIST {
        return Err((
            list.to_string(),
            format!("{} actions: at most {MAX_ACTIONS_IN_A_LIST} (its route is planned whole)", names.len()),
        ));
    }
    names
        .iter()
        .enumerate()
        .map(|(i, a)| {
            Action::from_name(a).ok_or_else(|| (field(i), format!("{a:?} is not an action: use {}", action_names())))
        })
        .collect()
}

/// One vehicle resolved; under `strict` nothing is adapted, otherwise
/// each quirk read leniently adds a sentence to `warnings`.
#[allow(clippy::too_many_arguments)]
pub(super) fn resolve_vehicle(
    here: &Here<'_>,
    k: usize,
    vehicle: &RawVehicle,
    map: &CityMap,
    world: WorldKind,
    travel: f64,
    earlier: &[GivenCar],
    strict: bool,
    warnings: &mut Vec<String>,
) -> Result<GivenCar, ScenarioFileError> {
    let id = vehicle.id.clone();
    if id.is_empty() {
        return Err(here.err(
            None,
            format!("Vehicles[{k}].Id"),
            "is empty: every vehicle needs an Id such as \"Car_1\"",
        ));
    }
    let car = Some(id.as_str());
    if earlier.iter().any(|c| c.name == id) {
        return Err(here.err(car, "Id", "duplicate car id: every vehicle of a scenario needs its own"));
    }
    let spawn_name = vehicle.spawn.as_str();
    let spawn = map.lane_by_name(spawn_name).ok_or_else(|| {
        if map.is_imported() {
            let example = map.spawn_points().first().map(|&l| map.lanes[l].name.clone()).unwrap_or_default();
            return here.err(
                car,
                "Spawn",
                format!(
                    "{spawn_name:?} is not a lane of the network: give a SUMO lane id cars drive, e.g. {example:?} (causalcity map --net lists them)"
                ),
            );
        }
        let layout = &map.layout;
        let mut roads: Vec<char> =
            layout.east_west_roads.iter().chain(&layout.north_south_roads).map(|(name, _)| *name).collect();
        roads.sort_unstable();
        let segments = layout.east_west_roads.len().max(layout.north_south_roads.len());
        let (first, last) = (roads.first().copied().unwrap_or('A'), roads.last().copied().unwrap_or('A'));
        // A lane of the map, never the refused one (a lane a town's
        // map.grid.missing leaves out was offered as the example).
        let example = map
            .spawn_points()
            .iter()
            .map(|&l| map.lanes[l].name.as_str())
            .find(|name| *name != spawn_name)
            .unwrap_or("C0w");
        here.err(
            car,
            "Spawn",
            format!(
                "{spawn_name:?} is not a spawn point of this town: its lanes are named by road {first}-{last}, segment \
                 0-{segments} and lane w-z, where the town has them (map.grid's missing, dead_ends and lanes leave \
                 some out), e.g. {example:?} (causalcity map lists them)"
            ),
        )
    })?;
    let lane_length = map.lanes[spawn].curve.length();
    let spawn_distance = vehicle.spawn_at_distance;
    if !(0.0..lane_length).contains(&spawn_distance) {
        return Err(here.err(
            car,
            "SpawnAtDistance",
            format!(
                "{} is not allowed: metres along lane {spawn_name}, from 0 to below {lane_length:.2}",
                Shown(spawn_distance)
            ),
        ));
    }
    let actions = resolve_actions(&vehicle.drive_queue, "DriveQueue", |i| format!("DriveQueue[{i}]"))
        .map_err(|(field, message)| here.err(car, field, message))?;
    let merge_distances: Vec<f64> = match &vehicle.merge_at_distances {
        None => vec![0.0; actions.len()],
        Some(list) => {
            if list.len() != actions.len() {
                return Err(here.err(
                    car,
                    "MergeAtDistances",
                    format!(
                        "{} entries for {} actions: give one per DriveQueue entry (0 for turns)",
                        list.len(),
                        actions.len()
                    ),
                ));
            }
            let mut distances = Vec::with_capacity(list.len());
            let mut names_read = Vec::new();
            for (i, entry) in list.iter().enumerate() {
                let field = format!("MergeAtDistances[{i}]");
                match entry {
                    Value::Number(n) => match n.as_f64().filter(|d| d.is_finite() && *d >= 0.0) {
                        Some(d) => distances.push(d),
                        None => {
                            return Err(here.err(
                                car,
                                field,
                                format!("{n} is not allowed: metres along the lane, 0 or more"),
                            ))
                        }
                    },
                    // The original generator writes action names here.
                    Value::String(_) if !strict => {
                        names_read.push(i);
                        distances.push(0.0);
                    }
                    other => {
                        return Err(here.err(
                            car,
                            field,
                            format!("{other} is not allowed: metres along the lane, 0 or more"),
                        ))
                    }
                }
            }
            if !names_read.is_empty() {
                let texts: Vec<String> = names_read.iter().map(|&i| list[i].to_string()).collect();
                warnings.push(format!(
                    "car {id:?}, field MergeAtDistances{names_read:?}: {} {} not distances (the original generator writes merge names there): read as no distance given (0)",
                    texts.join(", "),
                    if texts.len() == 1 { "is" } else { "are" }
                ));
            }
            distances
        }
    };
    let policy = if strict { LanePolicy::Strict } else { LanePolicy::Adapt };
    let route = Route::plan(map, spawn, spawn_distance, &actions, &merge_distances, spawn_distance + travel, &policy)
        .map_err(|e| {
        let field = if e.action.is_merge() && e.reason.contains("merge distance") {
            format!("MergeAtDistances[{}]", e.action_index)
        } else {
            format!("DriveQueue[{}]", e.action_index)
        };
        here.err(car, field, format!("{}: {}", e.action, e.reason))
    })?;

    if world == WorldKind::Toy {
        let given = [
            ("desired_speeds", vehicle.desired_speeds.is_some()),
            ("time_headway", vehicle.time_headway.is_some()),
            ("runs_red_lights", vehicle.runs_red_lights.is_some()),
        ];
        if let Some((field, _)) = given.iter().find(|(_, given)| *given) {
            return Err(here.err(car, *field, "applies to the city world only (toy cars have no agency)"));
        }
    }
    let desired_speeds = match &vehicle.desired_speeds {
        None => None,
        Some(list) if list.len() == actions.len() + 1 => {
            let max = crate::spec::MAX_DESIRED_SPEED_M_S;
            if let Some((i, v)) = list.iter().enumerate().find(|(_, v)| !(**v > 0.0 && **v <= max)) {
                return Err(here.err(
                    car,
                    format!("desired_speeds[{i}]"),
                    format!("{} is not allowed: m/s, above 0 and at most {max}", Shown(*v)),
                ));
            }
            Some(list.clone())
        }
        Some(_) => {
            return Err(here.err(
                car,
                "desired_speeds",
                format!("expected {} speeds (m/s): one before the first action and one after each", actions.len() + 1),
            ))
        }
    };
    if let Some(h) = vehicle.time_headway {
        if !(h > 0.0 && h <= 10.0) {
            return Err(here.err(
                car,
                "time_headway",
                format!("{} is not allowed: seconds, above 0 and at most 10", Shown(h)),
            ));
        }
    }
    let colour = match &vehicle.colour {
        None => None,
        Some(text) => Some(crate::render::palette::parse_hex_colour(text).ok_or_else(|| {
            here.err(car, "colour", format!("{text:?} is not allowed: \"#rrggbb\", e.g. \"#ff8800\""))
        })?),
    };
    Ok(GivenCar {
        name: id,
        spawn,
        spawn_distance,
        actions,
        merge_distances,
        route: Arc::new(route),
        desired_speeds,
        time_headway: vehicle.time_headway,
        runs_red_lights: vehicle.runs_red_lights,
        colour,
    })
}

/// Every action's name, for messages.
fn action_names() -> String {
    Action::ALL.iter().map(|a| a.name()).collect::<Vec<_>>().join(", ")
}

/// Leader-follower pairs: cars sharing spawn lane, actions and merge
/// distances, each leading the next one behind it.
pub(super) fn infer_pairs(cars: &[GivenCar]) -> Vec<(usize, usize)> {
    let mut pairs = Vec::new();
    let mut seen = vec![false; cars.len()];
    for i in 0..cars.len() {
        if seen[i] {
            continue;
        }
        let mut group: Vec<usize> = (i..cars.len())
            .filter(|&j| {
                cars[j].spawn == cars[i].spawn
                    && cars[j].actions == cars[i].actions
                    && cars[j].merge_distances == cars[i].merge_distances
            })
            .collect();
        for &j in &group {
            seen[j] = true;
        }
        group.sort_by(|&a, &b| cars[b].spawn_distance.total_cmp(&cars[a].spawn_distance));
        pairs.extend(group.windows(2).map(|w| (w[0], w[1])));
    }
    pairs.sort_unstable();
    pairs
}
