//! `causalcity export nsdr`: NS-DR / CLEVRER-style `annotations.json` per
//! scenario, made from the written mask PNGs and poses.csv, into
//! `<out>/<group>/<split>/<scenario>/annotations.json`. The same bytes as
//! `gen --annotations` writes into the scenario folders (format in
//! `output::annotations`).

use crate::dataset::{Dataset, PoseLog, ScenarioSummary};
use crate::error::Error;
use crate::output::annotations::{AnnotatedCar, AnnotationsBuilder, ANNOTATIONS_FILE};
use crate::output::claim::{claim, Writer};
use crate::output::png::decode_gray8;
use crate::output::{frame_digits, io_err, write_atomically};
use crate::progress::{Progress, ProgressMode};
use std::path::{Path, PathBuf};

/// Writes annotations for every scenario of `dataset` under `out`; returns
/// how many scenarios were written.
pub fn export_nsdr(dataset: &Path, out: &Path, progress: ProgressMode) -> Result<usize, Error> {
    let opened = Dataset::open_complete(dataset).map_err(Error::opening)?.with_frames();
    if !opened.record.images {
        return Err(Error::Input(format!(
            "{} has no masks (made with --no-images): NS-DR annotations need them; regenerate without --no-images",
            dataset.display()
        )));
    }
    let _claim = claim(out, Writer::Export, &format!("export nsdr {}", dataset.display()))?;
    refuse_earlier_export(&opened, out)?;
    let (w, h) = (opened.spec().image.width, opened.spec().image.height);
    let digits = frame_digits(opened.spec().frames);
    let packed = opened.unpacked.is_some();
    let bar = Progress::new(opened.key_sequence().len() as u64, progress);
    // A split at a time: a packed dataset holds one split, frames and all,
    // in TMPDIR.
    let folders = super::NewFolders::default();
    let damage = super::Damage::default();
    let exported = opened.each_scenario_in_turn(
        |e| damage.note_unreadable(e),
        |source, relative| {
            let target = out.join(relative);
            let json = damage.note(annotate(source, w, h, digits))?;
            folders.create(&target)?;
            write_atomically(&target.join(ANNOTATIONS_FILE), &json).map_err(|e| e.to_string())?;
            match packed {
                false => link_frames(source, &target)?,
                // Unpacked into a temporary folder: links would outlive it.
                true => copy_frames(source, &target)?,
            }
            bar.inc();
            Ok(())
        },
    );
    if let Err(e) = exported {
        // The scenarios this run added go again (those of an earlier run
        // it replaced stay, as replaced).
        folders.remove();
        return Err(damage.error(dataset, e));
    }
    bar.finish();
    Ok(opened.key_sequence().len())
}

/// The scenario folders this export writes, relative to `out`; anything
/// else there is refused.
fn refuse_earlier_export(opened: &Dataset, out: &Path) -> Result<(), Error> {
    let writes = opened.keys().map(|k| PathBuf::from(k.relative_folder())).collect();
    super::refuse_earlier_export(out, 3, &writes, "a scenario")
}

/// `rgb/` and `mask/` beside an exported annotations.json, as links to the
/// dataset's own folders: its `frame_filename` and `mask_filename` are
/// relative to the scenario folder, so they resolve from the export too,
/// without copying a frame. (Unix; elsewhere the names stay relative to the
/// dataset's scenario folder.)
fn link_frames(source: &Path, target: &Path) -> Result<(), String> {
    #[cfg(unix)]
    for folder in ["rgb", "mask"] {
        let original = source.join(folder);
        let original = original.canonicalize().map_err(|e| format!("cannot read {}: {e}", original.display()))?;
        let link = target.join(folder);
        match std::fs::read_link(&link) {
            Ok(existing) if existing == original => continue, // a rerun
            Ok(_) => std::fs::remove_file(&link).map_err(|e| format!("cannot replace {}: {e}", link.display()))?,
            // Frames an earlier export copied (from a packed dataset): its
            // own, replaced by the link (a rerun from folders failed with
            // "File exists").
            Err(_) if std::fs::symlink_metadata(&link).is_ok_and(|m| m.is_dir()) => {
                std::fs::remove_dir_all(&link).map_err(|e| format!("cannot replace {}: {e}", link.display()))?
            }
            Err(_) => {}
        }
        std::os::unix::fs::symlink(&original, &link).map_err(|e| io_err(&link)(e).to_string())?;
    }
    #[cfg(not(unix))]
    let _ = (source, target);
    Ok(())
}

/// `rgb/` and `mask/` beside an exported annotations.json, copied from a
/// packed dataset's scenario (whose folders are temporary); a rerun
/// replaces them.
fn copy_frames(source: &Path, target: &Path) -> Result<(), String> {
    for folder in ["rgb", "mask"] {
        let (from, to) = (source.join(folder), target.join(folder));
        if std::fs::symlink_metadata(&to).is_ok_and(|m| !m.is_dir()) {
            std::fs::remove_file(&to).map_err(|e| format!("cannot replace {}: {e}", to.display()))?;
        }
        std::fs::create_dir_all(&to).map_err(|e| io_err(&to)(e).to_string())?;
        let entries = std::fs::read_dir(&from).map_err(|e| format!("cannot read {}: {e}", from.display()))?;
        for entry in entries {
            let entry = entry.map_err(|e| format!("cannot read {}: {e}", from.display()))?;
            // (regular files only: a pipe hung the export)
            let bytes = crate::input::read_data(&entry.path())
                .map_err(|e| format!("cannot read {}: {e}", entry.path().display()))?;
            write_atomically(&to.join(entry.file_name()), &bytes).map_err(|e| e.to_string())?;
        }
    }
    Ok(())
}

/// annotations.json of the scenario in `dir`.
pub fn annotate(dir: &Path, width: u32, height: u32, digits: usize) -> Result<Vec<u8>, String> {
    let scenario = ScenarioSummary::read(dir)?;
    let poses = PoseLog::read(dir, scenario.frames as usize, scenario.cars.len())?;
    let cars: Vec<AnnotatedCar> =
        scenario.cars.iter().map(|c| AnnotatedCar { id: c.id, name: c.name.clone(), mask_id: c.mask_id }).collect();
    let mut builder = AnnotationsBuilder::new(&scenario.name, width, height, &cars);
    let mut pixels = Vec::with_capacity(cars.len());
    for frame in 0..scenario.frames {
        let (rgb_name, mask_name) = (format!("rgb/{frame:0digits$}.png"), format!("mask/{frame:0digits$}.png"));
        let path = dir.join(&mask_name);
        let data = crate::input::read_data(&path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
        let mask = decode_gray8(&data, width, height).map_err(|e| format!("{}: {e}", path.display()))?;
        pixels.clear();
        pixels.extend(poses.frame(frame as usize).iter().map(|p| [p.px, p.py]));
        builder.add_frame(frame, rgb_name, mask_name, &mask, &pixels);
    }
    Ok(builder.to_json())
}
