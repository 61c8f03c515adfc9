//! `scenario.json`: the ground truth of one scenario (schema in
//! `data-schema/scenario.schema.json`).

use crate::map::Action;
use crate::orchestrate::plan::{Role, ScenarioPlan};
use crate::render::camera::Camera;
use serde::Serialize;

/// Format tag written into every scenario.json.
pub const SCENARIO_FORMAT: &str = "causalcity-scenario/1";

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
    camera: &'a Camera,
    #[serde(skip_serializing_if = "Option::is_none")]
    toy: Option<ToyRecord>,
    cars: Vec<CarRecord<'a>>,
    edges: Vec<[u32; 2]>,
}

/// Serialises the scenario record as pretty JSON.
pub fn scenario_json(plan: &ScenarioPlan, camera: &Camera, leader_gap_px: f64) -> Vec<u8> {
    let toy = (plan.world == crate::spec::WorldKind::Toy).then(|| ToyRecord {
        speed_px_per_frame: camera.metres_to_pixels(plan.toy_step_m),
        speed_m_per_s: plan.toy_step_m / plan.frame_interval,
        leader_gap_px,
        leader_gap_m: camera.pixels_to_metres(leader_gap_px),
    });
    let record = ScenarioRecord {
        format: SCENARIO_FORMAT,
        name: plan.key.folder_name(),
        group: &plan.key.group,
        split: plan.key.split.name(),
        index: plan.key.index,
        world: plan.world.name(),
        seed: plan.seed,
        stream_key: &plan.stream_key,
        frames: plan.frames,
        frame_interval: plan.frame_interval,
        camera,
        toy,
        cars: plan
            .cars
            .iter()
            .map(|c| CarRecord {
                id: c.id,
                name: &c.name,
                colour: format!("#{:02x}{:02x}{:02x}", c.colour[0], c.colour[1], c.colour[2]),
                mask_id: c.mask_id,
                spawn: &c.spawn_name,
                spawn_distance: c.spawn_distance,
                actions: &c.actions,
                merge_distances: &c.merge_distances,
                role: c.role,
                length_m: c.length,
                width_m: c.width,
            })
            .collect(),
        edges: plan.edges.iter().map(|&(l, f)| [l, f]).collect(),
    };
    let mut out = serde_json::to_vec_pretty(&record).expect("scenario record serialises");
    out.push(b'\n');
    out
}
