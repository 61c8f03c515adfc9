//! Exports: a generated dataset turned into the inputs other projects' loaders
//! read unchanged. Exports read only the written files (manifest, CSV logs,
//! scenario.json), never the simulation.

pub mod nri;
pub mod nsdr;
pub mod vcdn;

use crate::error::Error;
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// The folders an export created under its `--out`: removed again, with
/// what the export wrote into them, when it fails, so that a failed export
/// leaves `--out` as it found it (its group folders stayed behind, and
/// `export nsdr` kept the scenarios before the one that failed). Shared by
/// the threads of a split.
#[derive(Default)]
struct NewFolders(std::sync::Mutex<Vec<PathBuf>>);

impl NewFolders {
    /// `std::fs::create_dir_all(dir)`, noting each folder it made.
    fn create(&self, dir: &Path) -> Result<(), String> {
        let missing = crate::output::claim::missing_folders(dir);
        // Noted first: a creation that fails part way (a full disk) leaves
        // the folders it made noted too.
        self.0.lock().unwrap_or_else(|poisoned| poisoned.into_inner()).extend(missing);
        std::fs::create_dir_all(dir).map_err(|e| crate::output::io_err(dir)(e).to_string())
    }

    /// After a failure: removes every folder made with what the export
    /// wrote into it (a link inside is removed, never followed).
    fn remove(self) {
        for dir in self.0.into_inner().unwrap_or_else(|poisoned| poisoned.into_inner()) {
            let _ = std::fs::remove_dir_all(dir);
        }
    }
}

/// Whether an export failed on the dataset's own files (a scenario it
/// could not read: bad input) or while writing, noted by the threads of a
/// split as they fail.
#[derive(Default)]
struct Damage(std::sync::atomic::AtomicBool);

impl Damage {
    /// `read`'s error noted as the dataset's.
    fn note<T>(&self, read: Result<T, String>) -> Result<T, String> {
        if read.is_err() {
            self.0.store(true, std::sync::atomic::Ordering::Relaxed);
        }
        read
    }

    /// A failure to read the dataset itself (unpacking a packed split)
    /// noted as the dataset's, unless it was a write of the reader's own
    /// ([`Error::reading`]'s rule): a truncated pack exited 1.
    fn note_unreadable(&self, message: &str) {
        if !Error::is_own_write(message) {
            self.0.store(true, std::sync::atomic::Ordering::Relaxed);
        }
    }

    /// [`Damage::note_unreadable`] of `read`'s error.
    fn note_reading<T>(&self, read: Result<T, String>) -> Result<T, String> {
        read.inspect_err(|e| self.note_unreadable(e))
    }

    /// The export's error: a damaged dataset is bad input ([`Error::damaged`],
    /// exit 2); anything else a failure (exit 1). A truncated pixels.npy
    /// exited 1 with "failed to fill whole buffer".
    fn error(&self, dataset: &Path, message: String) -> Error {
        if self.0.load(std::sync::atomic::Ordering::Relaxed) {
            Error::damaged(dataset, message)
        } else {
            Error::Failure(message)
        }
    }
}

/// Refuses an `out` holding, `depth` folders down, an entry this export
/// would not write (`writes`, relative to `out`): an earlier export's, of
/// another dataset, split sizes or options, would stay beside this one's,
/// and a loader would read part of one dataset and part of another. Files
/// at the top of `out` (the lock) are not an export's; a file where a
/// folder of this export's layout goes is a stray; what this export
/// writes is replaced. `entry` names the kind of thing at `depth` (`a
/// file`, `a scenario`).
fn refuse_earlier_export(out: &Path, depth: usize, writes: &BTreeSet<PathBuf>, entry: &str) -> Result<(), Error> {
    let children = |dir: &Path| -> Vec<PathBuf> {
        let mut found: Vec<PathBuf> =
            std::fs::read_dir(dir).into_iter().flatten().flatten().map(|e| e.path()).collect();
        found.sort();
        found
    };
    // A link in the export's layout is never written through (a linked
    // split folder took a scenario's files outside --out).
    let linked = |path: &Path| -> Result<(), Error> {
        match std::fs::symlink_metadata(path) {
            Ok(m) if m.is_symlink() => Err(Error::Input(format!(
                "{} is a symbolic link: an export never writes through one, which could reach outside --out. \
                 Remove it, or export into an empty --out",
                path.display()
            ))),
            _ => Ok(()),
        }
    };
    let mut level: Vec<PathBuf> = Vec::new();
    for child in children(out) {
        if child.is_dir() {
            linked(&child)?;
            level.push(child);
        }
    }
    for down in 2..=depth {
        let mut next = Vec::new();
        for folder in &level {
            for child in children(folder) {
                linked(&child)?;
                let relative = child.strip_prefix(out).unwrap_or(&child).to_path_buf();
                let stray = match down == depth {
                    true => !writes.contains(&relative),
                    false => !child.is_dir(),
                };
                if stray {
                    return Err(Error::Input(format!(
                        "{} is not {entry} this export writes (an earlier export's, of another dataset, split sizes \
                         or options?): left beside this one, a loader would mix the two. Remove it (or the folder's \
                         earlier export), or export into an empty --out",
                        child.display()
                    )));
                }
                next.push(child);
            }
        }
        level = next;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn writes(paths: &[&str]) -> BTreeSet<PathBuf> {
        paths.iter().map(PathBuf::from).collect()
    }

    #[test]
    fn an_earlier_exports_entries_are_refused_and_this_exports_own_and_the_lock_are_not() {
        let scratch = crate::output::packs::Scratch::new().unwrap();
        let out = scratch.path();
        let own = writes(&["g/train/s0.h5", "g/train/s0.h5.partial"]);
        std::fs::write(out.join(".lock"), "").unwrap();
        std::fs::create_dir_all(out.join("g/train")).unwrap();
        std::fs::write(out.join("g/train/s0.h5"), "").unwrap();
        assert!(refuse_earlier_export(out, 3, &own, "a scenario").is_ok());

        std::fs::write(out.join("g/train/s1.h5"), "").unwrap();
        let err = refuse_earlier_export(out, 3, &own, "a scenario").unwrap_err().to_string();
        assert!(err.contains("g/train/s1.h5 is not a scenario this export writes"), "{err}");
        std::fs::remove_file(out.join("g/train/s1.h5")).unwrap();

        std::fs::write(out.join("g/notes.txt"), "").unwrap();
        let err = refuse_earlier_export(out, 3, &own, "a scenario").unwrap_err().to_string();
        assert!(err.contains("g/notes.txt is not a scenario"), "{err}");
    }
}
