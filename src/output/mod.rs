//! Output: where files go and how they are written. Writers take plans,
//! trajectories and rendered pixels as plain data; they know nothing of how
//! those were produced.
//!
//! Layout (documented in README and `data-schema/`):
//! `OUT/manifest.json`, `OUT/<group>/<split>/<scenario>/{scenario.json,
//! poses.csv, rgb/NNNN.png, mask/NNNN.png}`.

pub mod annotations;
pub mod logs;
pub mod manifest;
pub mod number;
pub mod png;
pub mod poses;
pub mod scenario;

use sha2::{Digest, Sha256};
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

/// Name of the checksum file in every scenario folder (`sha256sum -c` format).
pub const CHECKSUMS: &str = "checksums.sha256";

/// Prefix of the hidden folder a scenario is written into before it is complete.
pub const PARTIAL_PREFIX: &str = ".partial-";

/// A scenario folder being written. Files go into a hidden temporary folder
/// beside the final one, each hashed (SHA-256) as it is written; `commit`
/// adds `checksums.sha256`, flushes and renames the folder into place, so a
/// scenario folder that exists is complete.
pub struct ScenarioDir {
    temp: PathBuf,
    target: PathBuf,
    frame_digits: usize,
    committed: bool,
    fsync: bool,
    hashes: Vec<(String, [u8; 32])>,
}

/// Passes bytes through to a writer and hashes them on the way.
struct HashingWriter<W: Write> {
    inner: W,
    hasher: Sha256,
}

impl<W: Write> Write for HashingWriter<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.hasher.update(&buf[..n]);
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

impl ScenarioDir {
    /// Starts writing the scenario that will live at `target`; leftovers of
    /// an interrupted attempt are discarded. With `fsync`, every file and the
    /// folder reach the disk before the rename (survives power loss, slower).
    pub fn begin(target: PathBuf, frames: u32, images: bool, fsync: bool) -> Result<ScenarioDir, WriteError> {
        let name = target.file_name().expect("scenario folder has a name").to_string_lossy().into_owned();
        let temp = target.with_file_name(format!("{PARTIAL_PREFIX}{name}"));
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
        Ok(ScenarioDir {
            temp,
            target,
            frame_digits: frame_digits(frames),
            committed: false,
            fsync,
            hashes: Vec::new(),
        })
    }

    /// Writes a whole file into the scenario folder.
    pub fn write_file(&mut self, name: &str, bytes: &[u8]) -> Result<u64, WriteError> {
        self.write_with(name, |w| w.write_all(bytes))
    }

    /// Streams a file through `fill`; returns its size.
    pub fn write_with<E: Into<std::io::Error>>(
        &mut self,
        name: &str,
        fill: impl FnOnce(&mut dyn Write) -> Result<(), E>,
    ) -> Result<u64, WriteError> {
        let path = self.temp.join(name);
        let file = fs::File::create(&path).map_err(io_err(&path))?;
        let mut w = HashingWriter { inner: BufWriter::with_capacity(1 << 16, file), hasher: Sha256::new() };
        fill(&mut w).map_err(|e| WriteError { path: path.clone(), source: e.into() })?;
        w.flush().map_err(io_err(&path))?;
        let HashingWriter { inner, hasher } = w;
        let file = inner.into_inner().map_err(|e| WriteError { path: path.clone(), source: e.into_error() })?;
        if self.fsync {
            file.sync_all().map_err(io_err(&path))?;
        }
        let len = file.metadata().map_err(io_err(&path))?.len();
        self.hashes.push((name.to_string(), hasher.finalize().into()));
        Ok(len)
    }

    /// Creates a folder (and its parents) inside the scenario folder.
    pub fn create_folder(&mut self, relative: &str) -> Result<(), WriteError> {
        let path = self.temp.join(relative);
        fs::create_dir_all(&path).map_err(io_err(&path))
    }

    /// Relative path of frame `frame` in image folder `kind` (`rgb` or `mask`).
    pub fn frame_name(&self, kind: &str, frame: u32) -> String {
        format!("{kind}/{frame:0width$}.png", width = self.frame_digits)
    }

    /// Writes the checksums and moves the finished scenario into place,
    /// replacing an older copy. Returns the checksum file's size.
    pub fn commit(mut self) -> Result<u64, WriteError> {
        let mut hashes = std::mem::take(&mut self.hashes);
        hashes.sort();
        let listing: String = hashes.iter().map(|(name, h)| format!("{}  {name}\n", hex(h))).collect();
        let len = self.write_file(CHECKSUMS, listing.as_bytes())?;
        if self.fsync {
            for dir in [self.temp.clone(), self.temp.join("rgb"), self.temp.join("mask")] {
                if dir.exists() {
                    fs::File::open(&dir).and_then(|d| d.sync_all()).map_err(io_err(&dir))?;
                }
            }
        }
        if self.target.exists() {
            fs::remove_dir_all(&self.target).map_err(io_err(&self.target))?;
        }
        fs::rename(&self.temp, &self.target).map_err(io_err(&self.target))?;
        self.committed = true;
        Ok(len)
    }
}

impl Drop for ScenarioDir {
    fn drop(&mut self) {
        if !self.committed {
            let _ = fs::remove_dir_all(&self.temp);
        }
    }
}

/// Lower-case hex of bytes.
pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Writes `bytes` to `path` through a temporary file and a rename.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), WriteError> {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(".partial");
    let temp = path.with_file_name(name);
    fs::write(&temp, bytes).map_err(io_err(&temp))?;
    fs::rename(&temp, path).map_err(io_err(path))
}
