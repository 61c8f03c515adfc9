//! `scenario.json`: the ground truth of one scenario (schema in
//! `data-schema/scenario.schema.json`).

use crate::camera::Camera;
use crate::map::signals::Light;
use crate::map::Action;
use crate::plan::confounders::{ConfounderModel, Confounders, Effects};
use crate::plan::{CarPlan, OnLeaderLost, Role, ScenarioPlan, WorldPlan};
use crate::render::palette::{colour_of, hex_colour};
use crate::spec::DriverParams;
use crate::world::effects::{EffectReport, InterventionKind};
use serde::Serialize;

/// Format tag written into every scenario.json.
pub const SCENARIO_FORMAT: &str = "causalcity-scenario/1";

/// Whether `scenario.json`'s bytes are those of the scenario `key` of a
/// spec of `seed`, by the fields that say which scenario it is: a
/// scenario of another seed, group, split or index copied into a folder
/// (its checksums intact) is not that folder's. The error names the field,
/// its value and the one wanted.
pub fn check_identity(bytes: &[u8], key: &crate::plan::ScenarioKey, seed: u64) -> Result<(), String> {
    let value: serde_json::Value = serde_json::from_slice(bytes).map_err(|e| format!("not valid JSON: {e}"))?;
    let wanted = [
        ("group", serde_json::json!(key.group)),
        ("split", serde_json::json!(key.split.name())),
        ("index", serde_json::json!(key.index)),
        ("seed", serde_json::json!(seed)),
    ];
    for (field, want) in wanted {
        if value[field] != want {
            return Err(format!("`{field}` is {} there, {want} for this scenario of the dataset", value[field]));
        }
    }
    Ok(())
}

#[derive(Serialize)]
struct CarRecord<'a> {
    id: u32,
    name: &'a str,
    colour: String,
    mask_id: u8,
    spawn: &'a str,
    spawn_distance: f64,
    actions: &'a [Action],
    merge_distances: &'a [f64],
    role: Role,
    length_m: f64,
    width_m: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    desired_speeds: Option<&'a [f64]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    driver: Option<&'a DriverParams>,
    #[serde(skip_serializing_if = "Option::is_none")]
    runs_red_lights: Option<bool>,
    #[serde(skip_serializing_if = "Option::is_none")]
    hard_negative_behind: Option<u32>,
    /// Followers: the car it follows.
    #[serde(skip_serializing_if = "Option::is_none")]
    follows: Option<u32>,
    /// Colliders' followers: the car with priority it gives way to.
    #[serde(skip_serializing_if = "Option::is_none")]
    gives_way_to: Option<u32>,
    /// Followers: `"stop"`, or `{"drive": {actions, merge_distances}}`.
    #[serde(skip_serializing_if = "Option::is_none")]
    on_leader_lost: Option<LeaderLostRecord<'a>>,
}

#[derive(Serialize)]
#[serde(rename_all = "lowercase")]
enum LeaderLostRecord<'a> {
    Stop,
    Drive { actions: &'a [Action], merge_distances: &'a [f64] },
}

impl<'a> LeaderLostRecord<'a> {
    fn of(lost: &'a OnLeaderLost) -> LeaderLostRecord<'a> {
        match lost {
            OnLeaderLost::Stop => LeaderLostRecord::Stop,
            OnLeaderLost::Drive(f) => {
                LeaderLostRecord::Drive { actions: &f.actions, merge_distances: &f.merge_distances }
            }
        }
    }
}

/// The interventional ground truth's summary (effects.csv has every row).
#[derive(Serialize)]
struct EffectsRecord {
    /// A car moved more than this from its factual trajectory, metres.
    effect_threshold_m: f64,
    /// Applied to every car in turn, from time 0.
    effect_interventions: Vec<&'static str>,
    /// (cause, effect) pairs with an effect under some intervention.
    causal_edges: Vec<[u32; 2]>,
    /// The causal edges where the effect car reacted to the cause itself.
    direct_edges: Vec<[u32; 2]>,
    /// Designed edges that no intervention backs.
    edges_without_effect: Vec<[u32; 2]>,
}

#[derive(Serialize)]
struct LightRecord<'a> {
    intersection: &'a str,
    approach: char,
    /// `straight`, `left`, or a variant's `straight-2`, ..
    signal: String,
    offset: f64,
    schedule: &'a [crate::map::signals::ScheduleStep],
    /// Run by a traffic-actuated programme (`city.lights.actuated`): the
    /// schedule, at written lengths, is only where its clock starts.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    actuated: bool,
}

#[derive(Serialize)]
struct CityRecord<'a> {
    model: &'a str,
    confounders: &'a Confounders,
    confounder_model: &'a ConfounderModel,
    effects: &'a Effects,
    base_driver: &'a DriverParams,
    lights: Vec<LightRecord<'a>>,
    signal_heads: crate::spec::SignalHeads,
    /// Written only where a spec chose other than the original's rules.
    #[serde(skip_serializing_if = "crate::spec::DrivingRules::is_original")]
    rules: crate::spec::DrivingRules,
}

#[derive(Serialize)]
struct ToyRecord {
    speed_px_per_frame: f64,
    speed_m_per_s: f64,
    leader_gap_px: f64,
    leader_gap_m: f64,
}

#[derive(Serialize)]
struct ScenarioRecord<'a> {
    format: &'a str,
    name: String,
    group: &'a str,
    split: &'a str,
    index: u32,
    world: &'a str,
    seed: u64,
    stream_key: &'a str,
    frames: u32,
    frame_interval: f64,
    /// Datasets of several towns: the scenario's town's name.
    #[serde(skip_serializing_if = "Option::is_none")]
    town: Option<&'a str>,
    /// Datasets of several towns: the town's map section, enough to
    /// rebuild it (a spec's `map`).
    #[serde(skip_serializing_if = "Option::is_none")]
    map: Option<&'a crate::spec::MapSpec>,
    camera: &'a Camera,
    #[serde(skip_serializing_if = "Option::is_none")]
    toy: Option<ToyRecord>,
    #[serde(skip_serializing_if = "Option::is_none")]
    city: Option<CityRecord<'a>>,
    cars: Vec<CarRecord<'a>>,
    edges: Vec<[u32; 2]>,
    #[serde(flatten, skip_serializing_if = "Option::is_none")]
    effects: Option<EffectsRecord>,
    /// Extra cameras, each writing under cameras/<name>/.
    #[serde(skip_serializing_if = "<[_]>::is_empty")]
    cameras: &'a [crate::camera::CameraPlan],
}

/// Serialises the scenario record as pretty JSON. `intersection_names` and
/// `model` describe the city world's lights and car-following model;
/// `effects`, where measured, adds the causal graphs.
pub fn scenario_json(
    plan: &ScenarioPlan,
    camera: &Camera,
    leader_gap_px: f64,
    intersection_names: &[String],
    model: &str,
    effects: Option<&EffectReport>,
) -> Vec<u8> {
    let pairs = |edges: &[(u32, u32)]| edges.iter().map(|&(a, b)| [a, b]).collect::<Vec<_>>();
    let effects = effects.map(|report| EffectsRecord {
        effect_threshold_m: report.threshold_m,
        effect_interventions: InterventionKind::ALL.iter().map(|k| k.name()).collect(),
        causal_edges: pairs(&report.causal_edges()),
        direct_edges: pairs(&report.direct_edges()),
        edges_without_effect: pairs(&report.edges_without_effect(&plan.edges)),
    });
    let light_record =
        |l: &'_ Light| -> (usize, char, String, f64) { (l.intersection, l.approach, l.signal_label(), l.offset) };
    let city = plan.world.city().map(|c| CityRecord {
        model,
        confounders: &c.confounders,
        confounder_model: &c.confounder_model,
        effects: &c.effects,
        base_driver: &c.base_driver,
        signal_heads: c.signal_heads,
        rules: c.rules,
        lights: c
            .lights
            .lights
            .iter()
            .enumerate()
            .map(|(index, l)| {
                let (i, approach, signal, offset) = light_record(l);
                let actuated = c.lights.actuated.iter().any(|run| run.lights.iter().any(|(light, _)| *light == index));
                let intersection = &intersection_names[i];
                LightRecord { intersection, approach, signal, offset, schedule: &l.schedule, actuated }
            })
            .collect(),
    });
    let toy = match plan.world {
        WorldPlan::Toy { step_m } => Some(ToyRecord {
            speed_px_per_frame: camera.metres_to_pixels(step_m),
            speed_m_per_s: step_m / plan.frame_interval,
            leader_gap_px,
            leader_gap_m: camera.pixels_to_metres(leader_gap_px),
        }),
        WorldPlan::City(_) => None,
    };
    let agency = |c: &CarPlan| plan.world.city().map(|city| &city.agency[c.id as usize]);
    let record = ScenarioRecord {
        format: SCENARIO_FORMAT,
        name: plan.key.folder_name(),
        group: &plan.key.group,
        split: plan.key.split.name(),
        index: plan.key.index,
        world: plan.world.kind().name(),
        seed: plan.seed,
        stream_key: &plan.stream_key,
        frames: plan.frames,
        frame_interval: plan.frame_interval,
        town: plan.town.as_ref().map(|t| t.name.as_str()),
        map: plan.town.as_ref().map(|t| &t.map),
        camera,
        toy,
        city,
        cars: plan
            .cars
            .iter()
            .map(|c| CarRecord {
                id: c.id,
                name: &c.name,
                colour: hex_colour(colour_of(c)),
                mask_id: c.mask_id,
                spawn: &c.spawn_name,
                spawn_distance: c.spawn_distance,
                actions: &c.actions,
                merge_distances: &c.merge_distances,
                role: c.role,
                length_m: c.length,
                width_m: c.width,
                desired_speeds: agency(c).map(|a| a.desired_speeds.as_slice()),
                driver: agency(c).map(|a| &a.driver),
                runs_red_lights: agency(c).map(|a| a.runs_red_lights),
                hard_negative_behind: c.hard_negative_behind,
                follows: c.leader,
                gives_way_to: c.gives_way_to,
                on_leader_lost: c.on_leader_lost.as_ref().map(LeaderLostRecord::of),
            })
            .collect(),
        edges: pairs(&plan.edges),
        effects,
        cameras: &plan.cameras,
    };
    let mut out = serde_json::to_vec_pretty(&record).expect("scenario record serialises");
    out.push(b'\n');
    out
}
