//! Output: where files go and how they are written. Writers take plans,
//! trajectories and rendered pixels as plain data; they know nothing of how
//! those were produced.
//!
//! Layout (documented in README and `data-schema/`):
//! `OUT/manifest.json`, `OUT/<group>/<split>/<scenario>/{scenario.json,
//! poses.csv, rgb/NNNN.png, mask/NNNN.png}`.

pub mod logs;
pub mod manifest;
pub mod png;
pub mod poses;
pub mod scenario;

use std::fs;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// An output failure, with the path it concerns.
#[derive(Debug, thiserror::Error)]
#[error("cannot write {path}: {source}")]
pub struct WriteError {
    pub path: PathBuf,
    #[source]
    pub source: std::io::Error,
}

pub(crate) fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> WriteError + '_ {
    move |source| WriteError { path: path.to_path_buf(), source }
}

/// Digits in frame file names: at least 4 (`0000.png`), more for long scenarios.
pub fn frame_digits(frames: u32) -> usize {
    (frames.saturating_sub(1)).to_string().len().max(4)
}

/// The folder of one scenario: `OUT/<group>/<split>/<NNNNN>`.
pub fn scenario_dir(root: &Path, group: &str, split: &str, folder: &str) -> PathBuf {
    root.join(group).join(split).join(folder)
}

/// A scenario folder being written. Files go into a hidden temporary folder
/// beside the final one, which is renamed into place by [`ScenarioDir::commit`],
/// so a scenario folder that exists is complete.
pub struct ScenarioDir {
    temp: PathBuf,
    target: PathBuf,
    frame_digits: usize,
    committed: bool,
}

impl ScenarioDir {
    /// Starts writing the scenario that will live at `target`.
    pub fn begin(target: PathBuf, frames: u32, images: bool) -> Result<ScenarioDir, WriteError> {
        let name = target.file_name().expect("scenario folder has a name").to_string_lossy().into_owned();
        let temp = target.with_file_name(format!(".partial-{name}"));
        if temp.exists() {
            fs::remove_dir_all(&temp).map_err(io_err(&temp))?;
        }
        fs::create_dir_all(&temp).map_err(io_err(&temp))?;
        if images {
            for sub in ["rgb", "mask"] {
                let p = temp.join(sub);
                fs::create_dir(&p).map_err(io_err(&p))?;
            }
        }
        Ok(ScenarioDir { temp, target, frame_digits: frame_digits(frames), committed: false })
    }

    /// Writes a whole file into the scenario folder.
    pub fn write_file(&self, name: &str, bytes: &[u8]) -> Result<u64, WriteError> {
        let path = self.temp.join(name);
        fs::write(&path, bytes).map_err(io_err(&path))?;
        Ok(bytes.len() as u64)
    }

    /// Streams a file through `fill`; returns its size.
    pub fn write_with<E: Into<std::io::Error>>(
        &self,
        name: &str,
        fill: impl FnOnce(&mut BufWriter<fs::File>) -> Result<(), E>,
    ) -> Result<u64, WriteError> {
        let path = self.temp.join(name);
        let file = fs::File::create(&path).map_err(io_err(&path))?;
        let mut w = BufWriter::with_capacity(1 << 16, file);
        fill(&mut w).map_err(|e| WriteError { path: path.clone(), source: e.into() })?;
        w.flush().map_err(io_err(&path))?;
        let len = w.get_ref().metadata().map_err(io_err(&path))?.len();
        Ok(len)
    }

    /// Relative path of frame `frame` in image folder `kind` (`rgb` or `mask`).
    pub fn frame_name(&self, kind: &str, frame: u32) -> String {
        format!("{kind}/{frame:0width$}.png", width = self.frame_digits)
    }

    /// Moves the finished scenario into place, replacing an older copy.
    pub fn commit(mut self) -> Result<(), WriteError> {
        if self.target.exists() {
            fs::remove_dir_all(&self.target).map_err(io_err(&self.target))?;
        }
        fs::rename(&self.temp, &self.target).map_err(io_err(&self.target))?;
        self.committed = true;
        Ok(())
    }
}

impl Drop for ScenarioDir {
    fn drop(&mut self) {
        if !self.committed {
            let _ = fs::remove_dir_all(&self.temp);
        }
    }
}

/// Writes `bytes` to `path` through a temporary file and a rename.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), WriteError> {
    let temp = path.with_extension("json.partial");
    fs::write(&temp, bytes).map_err(io_err(&temp))?;
    fs::rename(&temp, path).map_err(io_err(path))
}
