//! The layout of a scenario folder, in one place: the writer names its files
//! from here and `validate` expects exactly these files and folders.
//!
//! ```text
//! scenario.json  poses.csv  pixels.npy  checksums.sha256
//! lights.csv  events.csv  interactions.csv    (city world; light_changes.csv
//!                                              for lights.csv with gen --lights changes)
//! annotations.json                            (--annotations)
//! effects.csv                                 (gen, unless --no-effects)
//! rgb/NNNN.png  mask/NNNN.png                 (images)
//! cameras/<name>/{rgb,mask,depth}/NNNN.png  cameras/<name>/poses.csv
//! ```

use super::annotations::ANNOTATIONS_FILE;
use super::manifest::Products;
use super::poses::PIXELS_FILE;
use super::CHECKSUMS;

/// The ground truth of the scenario.
pub const SCENARIO_JSON: &str = "scenario.json";
/// Every car's pose per frame.
pub const POSES_CSV: &str = "poses.csv";
/// City world: every light's colour per frame.
pub const LIGHTS_CSV: &str = "lights.csv";
/// City world with `gen --lights changes`: every light's colour at frame 0
/// and where it changes.
pub const LIGHT_CHANGES_CSV: &str = "light_changes.csv";
/// City world: what happened, in time order.
pub const EVENTS_CSV: &str = "events.csv";
/// What bound each car's speed, per frame (city world).
pub const INTERACTIONS_CSV: &str = "interactions.csv";
/// Which car moves which under interventions (`gen`, unless `--no-effects`).
pub const EFFECTS_CSV: &str = "effects.csv";
/// A folder at a dataset's root for the logs of the jobs that made it
/// (`examples/slurm` writes there); not part of the dataset, which
/// `validate` accepts beside it.
pub const JOB_LOGS_DIR: &str = "logs";

/// Where `gen --force` moves the old dataset's group folders, each by one
/// rename, before it deletes them: a removal cut off part way (a kill)
/// leaves whole scenario folders or none, and the next `gen` in the
/// folder finishes deleting what is here.
pub const REMOVING_DIR: &str = ".causalcity-removing";
/// Folder of the extra cameras.
pub const CAMERAS: &str = "cameras";

/// Kinds of per-frame image folder.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameKind {
    Rgb,
    Mask,
    /// 16-bit depth in millimetres (extra cameras that ask for it).
    Depth,
}

impl FrameKind {
    pub fn folder(self) -> &'static str {
        match self {
            FrameKind::Rgb => "rgb",
            FrameKind::Mask => "mask",
            FrameKind::Depth => "depth",
        }
    }
}

/// An extra camera as the layout sees it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CameraFolder {
    pub name: String,
    pub depth: bool,
}

/// What one scenario folder holds.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ScenarioLayout {
    pub frames: u32,
    /// Digits in frame file names.
    pub digits: usize,
    pub city: bool,
    pub images: bool,
    pub annotations: bool,
    pub effects: bool,
    /// City world: which file logs the lights.
    pub lights: super::manifest::LightsLog,
    /// Extra cameras; they write files only with images.
    pub cameras: Vec<CameraFolder>,
}

/// Digits in frame file names: at least 4 (`0000.png`), more for long scenarios.
pub fn frame_digits(frames: u32) -> usize {
    (frames.saturating_sub(1)).to_string().len().max(4)
}

impl ScenarioLayout {
    /// The files every scenario of a dataset made from `spec` with
    /// `products` holds (the readers' view: a spec's cameras, not a plan's).
    pub fn of_spec(spec: &crate::spec::DatasetSpec, products: Products) -> ScenarioLayout {
        let cameras = spec.cameras.iter().map(|c| CameraFolder { name: c.name.clone(), depth: c.depth }).collect();
        ScenarioLayout::new(spec.frames, spec.world == crate::spec::WorldKind::City, products, cameras)
    }

    pub fn new(frames: u32, city: bool, products: Products, cameras: Vec<CameraFolder>) -> ScenarioLayout {
        let images = products.images;
        ScenarioLayout {
            frames,
            digits: frame_digits(frames),
            city,
            images,
            annotations: products.annotations && images,
            effects: products.effects,
            lights: products.lights,
            cameras: if images { cameras } else { Vec::new() },
        }
    }

    /// `rgb/0042.png`.
    pub fn frame_name(&self, kind: FrameKind, frame: u32) -> String {
        format!("{}/{frame:0width$}.png", kind.folder(), width = self.digits)
    }

    /// `cameras/<name>`.
    pub fn camera_dir(camera: &str) -> String {
        format!("{CAMERAS}/{camera}")
    }

    /// `cameras/<name>/rgb/0042.png`.
    pub fn camera_frame_name(&self, camera: &str, kind: FrameKind, frame: u32) -> String {
        format!("{}/{}", Self::camera_dir(camera), self.frame_name(kind, frame))
    }

    /// `cameras/<name>/poses.csv`.
    pub fn camera_poses(camera: &str) -> String {
        format!("{}/{POSES_CSV}", Self::camera_dir(camera))
    }

    fn camera_kinds(camera: &CameraFolder) -> &'static [FrameKind] {
        if camera.depth {
            &[FrameKind::Rgb, FrameKind::Mask, FrameKind::Depth]
        } else {
            &[FrameKind::Rgb, FrameKind::Mask]
        }
    }

    /// The file that logs the lights (city world).
    pub fn lights_file(&self) -> &'static str {
        match self.lights {
            super::manifest::LightsLog::Frames => LIGHTS_CSV,
            super::manifest::LightsLog::Changes => LIGHT_CHANGES_CSV,
        }
    }

    /// Every folder inside the scenario folder, parents first.
    pub fn folders(&self) -> Vec<String> {
        let mut folders = Vec::new();
        if self.images {
            folders.extend([FrameKind::Rgb.folder().to_string(), FrameKind::Mask.folder().to_string()]);
            if !self.cameras.is_empty() {
                folders.push(CAMERAS.to_string());
            }
            for camera in &self.cameras {
                let base = Self::camera_dir(&camera.name);
                folders.push(base.clone());
                folders.extend(Self::camera_kinds(camera).iter().map(|k| format!("{base}/{}", k.folder())));
            }
        }
        folders
    }

    /// Every file of the scenario folder, the checksum listing last.
    pub fn files(&self) -> Vec<String> {
        let mut names: Vec<String> = vec![SCENARIO_JSON.into(), POSES_CSV.into(), PIXELS_FILE.into()];
        if self.city {
            names.extend([self.lights_file().into(), EVENTS_CSV.into(), INTERACTIONS_CSV.into()]);
        }
        if self.annotations {
            names.push(ANNOTATIONS_FILE.into());
        }
        if self.effects {
            names.push(EFFECTS_CSV.into());
        }
        if self.images {
            for kind in [FrameKind::Rgb, FrameKind::Mask] {
                names.extend((0..self.frames).map(|f| self.frame_name(kind, f)));
            }
            for camera in &self.cameras {
                for &kind in Self::camera_kinds(camera) {
                    names.extend((0..self.frames).map(|f| self.camera_frame_name(&camera.name, kind, f)));
                }
                names.push(Self::camera_poses(&camera.name));
            }
        }
        names.push(CHECKSUMS.into());
        names
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layout_lists_camera_folders_and_files() {
        let cameras = vec![CameraFolder { name: "corner".into(), depth: true }];
        let all = Products { images: true, annotations: false, effects: true, lights: Default::default() };
        let layout = ScenarioLayout::new(3, true, all, cameras.clone());
        let files = layout.files();
        assert!(files.contains(&"cameras/corner/depth/0002.png".to_string()));
        assert!(files.contains(&"cameras/corner/poses.csv".to_string()));
        assert!(files.contains(&"events.csv".to_string()));
        assert!(files.contains(&"interactions.csv".to_string()));
        assert!(files.contains(&"effects.csv".to_string()));
        assert_eq!(files.len(), 7 + 2 * 3 + 3 * 3 + 1 + 1);
        assert!(layout.folders().contains(&"cameras/corner/depth".to_string()));
        // Without images there are no frames and no camera files.
        let bare = ScenarioLayout::new(
            3,
            false,
            Products { images: false, annotations: true, effects: false, lights: Default::default() },
            cameras,
        );
        assert_eq!(bare.files(), vec!["scenario.json", "poses.csv", "pixels.npy", "checksums.sha256"]);
        assert!(bare.folders().is_empty());
    }
}
