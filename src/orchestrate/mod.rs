//! Orchestration: the jobs behind the commands (`gen`, `merge`, `pack`, `run`,
//! `counterfactual`): read inputs, plan, simulate, write in parallel.

pub mod handwritten;
pub mod in_memory;
pub mod merge;
pub mod pack;
pub mod run;
pub mod scenario_file;

/// A camera is pictures: without images it writes nothing, which
/// scenario.json (listing it) does not tell. The warning of `whose`
/// cameras (`the spec's`, `scenario "s": its`), `None` when images are
/// written or there are none.
fn cameras_without_images<'a>(images: bool, whose: &str, names: impl Iterator<Item = &'a str>) -> Option<String> {
    let names: Vec<&str> = names.collect();
    (!images && !names.is_empty())
        .then(|| format!("--no-images: {whose} cameras ({}) write nothing (no cameras/ folders)", names.join(", ")))
}
