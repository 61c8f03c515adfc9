//! Who may write into an output folder: one command at a time, and only a
//! command that would have written what the folder already holds.
//!
//! A writer *claims* its folder before it writes anything: it takes an
//! advisory lock on `<out>/.causalcity.lock` (exclusive; `gen --shard K/N`
//! takes it shared, plus an exclusive lock of its own shard, so the shards
//! of one job can share a folder while a duplicated shard cannot), then
//! checks the folder's top level against what it writes itself. The OS
//! drops a lock when its process ends, however it ends, so a killed run
//! never leaves a folder locked. A claim removes its lock files when it
//! ends; a killed run leaves its (hidden) one, which the next claim takes
//! over and `validate` ignores.

use std::fs::{self, File, TryLockError};
use std::io::Write;
use std::path::{Path, PathBuf};

/// The folder lock's file name.
pub const LOCK_FILE: &str = ".causalcity.lock";

/// How a shard's own lock file is named: `.causalcity-shard-K-of-N.lock`.
const SHARD_LOCK_PREFIX: &str = ".causalcity-shard-";

/// How every sweep.json's `format` begins.
pub const SWEEP_FORMAT_PREFIX: &str = "causalcity-counterfactual-sweep/";

/// Whether `name` (a file in an output folder's top level) is one of the
/// lock files claims leave.
pub fn is_lock_file(name: &str) -> bool {
    name.starts_with(".causalcity") && name.ends_with(".lock")
}

/// What a command writes into its folder, which decides what it may find
/// there.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Writer {
    /// `gen` (with its shard, if any): manifest.json, shards/, group folders.
    Gen { shard: Option<(u32, u32)> },
    /// `merge --out`: a dataset's files.
    Merge,
    /// `pack --out`: a packed dataset's files.
    Pack,
    /// `counterfactual --sweep`: sweep.json and group folders of pairs.
    Sweep,
    /// `run` / `counterfactual`: one folder per scenario of a file.
    Scenarios,
    /// `export nri|nsdr|vcdn`: arrays or per-scenario files, never inside a
    /// dataset.
    Export,
}

impl Writer {
    fn command(self) -> &'static str {
        match self {
            Writer::Gen { shard: None } => "gen",
            Writer::Gen { shard: Some(_) } => "gen --shard",
            Writer::Merge => "merge",
            Writer::Pack => "pack",
            Writer::Sweep => "counterfactual --sweep",
            Writer::Scenarios => "run / counterfactual",
            Writer::Export => "export",
        }
    }
}

/// Why a folder cannot be claimed; every case is the user's to resolve
/// (exit status 2), except [`ClaimError::Io`].
#[derive(Debug, thiserror::Error)]
pub enum ClaimError {
    #[error(
        "{dir} is in use by another causalcity process ({holder}): wait for it to finish, or stop it and rerun \
         (a stopped run resumes; the lock goes with its process, so a killed run never keeps a folder locked)"
    )]
    InUse { dir: PathBuf, holder: String },
    /// A dataset `gen --force` would remove while a reader has it open.
    #[error(
        "{dir} is open for reading (held by a causalcity reader: validate, stats, evaluate, export, pack, heatmap, \
         baseline, python -m causalcity.methods, or a causalcity.Dataset in Python, perhaps in this very process, \
         which lets go with its close()). Nothing was removed: let the reader finish, or close it, then rerun with \
         --force"
    )]
    BeingRead { dir: PathBuf },
    #[error("{dir} holds {what}: {command} writes only {writes}. Use another --out{hint}")]
    Foreign { dir: PathBuf, what: String, command: &'static str, writes: &'static str, hint: &'static str },
    #[error("{dir} is inside {inside} ({ancestor}), {harm}: write outside it")]
    Inside { dir: PathBuf, inside: &'static str, ancestor: PathBuf, harm: &'static str },
    #[error("cannot write {path}: {source}\nFix the folder's permissions, or choose another --out.")]
    Io { path: PathBuf, source: std::io::Error },
    /// A path to write that is a symbolic link: writing through it could
    /// land anywhere, so causalcity never does.
    #[error(
        "{path} is a symbolic link (to {target}): causalcity never writes through a link, which could reach \
         outside the folder asked for. Remove the link, or choose another path."
    )]
    Link { path: PathBuf, target: String },
    /// A file to write that the command is reading, or that lies inside
    /// what it reads.
    #[error("{path} is {what}: a command never writes onto its own input. Choose another path.")]
    OwnInput { path: PathBuf, what: String },
    /// A path that cannot be written as asked (empty, a folder given for a
    /// file, a path under a file).
    #[error("{path:?}: {why}")]
    BadPath { path: PathBuf, why: String },
}

impl ClaimError {
    /// 2 when the folder is the problem (in use, foreign content), 1 for
    /// an I/O failure.
    pub fn exit_code(&self) -> i32 {
        match self {
            ClaimError::Io { .. } => 1,
            _ => 2,
        }
    }
}

impl From<ClaimError> for crate::error::Error {
    fn from(e: ClaimError) -> Self {
        match e.exit_code() {
            2 => crate::error::Error::Input(e.to_string()),
            _ => crate::error::Error::Failure(e.to_string()),
        }
    }
}

/// A claimed folder: the locks are held until this is dropped, and their
/// files removed then (the last of a job's shards removes the shared one),
/// so a finished folder holds no lock file; one left by a killed process
/// is simply taken over. A folder the claim created is removed again if
/// nothing was written into it (a command refused after claiming leaves no
/// trace).
#[derive(Debug)]
pub struct Claim {
    /// (path, open file holding the lock, shared).
    locks: Vec<(PathBuf, File, bool)>,
    /// False where the filesystem does not support locks (some network
    /// filesystems): the claim then only checked the folder's contents.
    pub locked: bool,
    /// The folders the claim made (the folder and any missing above it),
    /// deepest first.
    created: Vec<PathBuf>,
}

impl Claim {
    /// Runs `work` with the folder to this writer alone: a shard's shared
    /// folder lock is taken exclusively for it (and shared again after), so
    /// that `gen --shard --force` never removes a dataset other shards are
    /// writing. `Ok(None)`, and `work` not run, while another writer holds
    /// it. Converting a lock drops it first (flock(2)): one that cannot be
    /// shared again is an error, never a run going on unlocked.
    pub fn alone<T>(&mut self, work: impl FnOnce() -> T) -> Result<Option<T>, ClaimError> {
        let Some((path, file, true)) = self.locks.first() else {
            return Ok(Some(work())); // held exclusively already, or not locked
        };
        let lost = |path: &Path| {
            let dir = path.parent().unwrap_or(Path::new(".")).to_path_buf();
            ClaimError::InUse { holder: holders(&dir), dir }
        };
        if file.try_lock().is_err() {
            file.try_lock_shared().map_err(|_| lost(path))?;
            return Ok(None);
        }
        let done = work();
        file.try_lock_shared().map_err(|_| lost(path))?;
        Ok(Some(done))
    }
}

impl Drop for Claim {
    fn drop(&mut self) {
        for (path, file, shared) in self.locks.drain(..).rev() {
            // A shared lock's file goes only with its last holder: taking it
            // exclusively succeeds only then.
            if !shared || file.try_lock().is_ok() {
                // Held alone, the folder lock says no shard runs here: a
                // shard's lock file left by a killed shard goes with it
                // (a finished dataset held one after a plain gen finished
                // the job).
                if path.file_name().is_some_and(|n| n == LOCK_FILE) {
                    remove_shard_locks(path.parent().unwrap_or(Path::new(".")));
                }
                let _ = fs::remove_file(&path);
            }
            drop(file);
        }
        // Only while empty, the folder first, then those made above it (a
        // refused `--out new/data` left `new`).
        for dir in &self.created {
            if fs::remove_dir(dir).is_err() {
                break;
            }
        }
    }
}

/// Removes the shard lock files (`.causalcity-shard-K-of-N.lock`) in `dir`;
/// called only while holding its folder lock alone.
fn remove_shard_locks(dir: &Path) {
    for entry in fs::read_dir(dir).into_iter().flatten().flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        if name.starts_with(SHARD_LOCK_PREFIX) && is_lock_file(&name) {
            let _ = fs::remove_file(entry.path());
        }
    }
}

/// The folders `std::fs::create_dir_all(dir)` would make: `dir` and each
/// missing folder above it, deepest first.
pub(crate) fn missing_folders(dir: &Path) -> Vec<PathBuf> {
    dir.ancestors()
        .take_while(|a| !a.as_os_str().is_empty() && fs::symlink_metadata(a).is_err())
        .map(Path::to_path_buf)
        .collect()
}

/// Claims `dir` (created if missing) for `writer`: locks it, then checks
/// what it holds. `describe` says who holds the lock, for a refused second
/// writer (e.g. the command line).
pub fn claim(dir: &Path, writer: Writer, describe: &str) -> Result<Claim, ClaimError> {
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| ClaimError::Io { path, source }
    };
    if dir.as_os_str().is_empty() {
        return Err(ClaimError::BadPath {
            path: dir.to_path_buf(),
            why: "an empty path names no folder: give the output folder, e.g. data/toy".into(),
        });
    }
    // A file (or a dangling link) where the folder should be, or a file on
    // the way to it: the user's to fix, as the folder's contents are.
    match fs::symlink_metadata(dir) {
        Ok(m) if m.file_type().is_symlink() && !dir.is_dir() => return Err(link_error(dir)),
        Ok(m) if !m.is_dir() && !m.file_type().is_symlink() => {
            return Err(ClaimError::BadPath {
                path: dir.to_path_buf(),
                why: "is a file, not a folder: give --out a folder (a new one, or one this command wrote)".into(),
            })
        }
        _ => {}
    }
    // (A link on the way counts as what it leads to: a file, or nothing.)
    if let Some(file) = dir
        .ancestors()
        .skip(1)
        .filter(|a| !a.as_os_str().is_empty())
        .find(|a| fs::symlink_metadata(a).is_ok() && !a.is_dir())
    {
        return Err(ClaimError::BadPath {
            path: dir.to_path_buf(),
            why: format!("lies under {}, which is not a folder (a file, or a link to none)", file.display()),
        });
    }
    check_ancestors(dir)?;
    check_contents(dir, writer)?;
    let created = missing_folders(dir);
    fs::create_dir_all(dir).map_err(io(dir))?;
    let holder = holder_line(describe);
    let mut claim = Claim { locks: Vec::new(), locked: true, created };
    let shard = match writer {
        Writer::Gen { shard: Some((index, count)) } => {
            Some(dir.join(format!("{SHARD_LOCK_PREFIX}{index}-of-{count}.lock")))
        }
        _ => None,
    };
    lock_folder(&mut claim, dir, shard.is_some(), &holder)?;
    if let Some(shard_lock) = shard {
        match lock(&shard_lock, false)? {
            Lock::Held(file) => {
                record_holder(&file, &holder);
                claim.locks.push((shard_lock, file, false));
            }
            Lock::Busy => return Err(ClaimError::InUse { dir: dir.to_path_buf(), holder: read_holder(&shard_lock) }),
            Lock::Unsupported => claim.locked = false,
        }
    }
    // Checked again under the lock: another writer may have finished in between.
    check_contents(dir, writer)?;
    Ok(claim)
}

/// Locks the folder `dir` as [`claim`] does for a writer of its own, but
/// leaves what it holds to the caller, who checks it under the lock by a
/// rule of its own (merge, finishing what a cut-off merge left in a shard
/// folder, which [`claim`] refuses for its empty group folders). A folder
/// a running command holds is refused.
pub fn lock_only(dir: &Path, describe: &str) -> Result<Claim, ClaimError> {
    let mut claim = Claim { locks: Vec::new(), locked: true, created: Vec::new() };
    lock_folder(&mut claim, dir, false, &holder_line(describe))?;
    Ok(claim)
}

/// What a lock file records of its holder: this process, its host and
/// `describe` (e.g. the command line).
fn holder_line(describe: &str) -> String {
    format!("pid {} on {}: {describe}", std::process::id(), host_name())
}

/// Takes `dir`'s folder lock into `claim`: shared by the shards of one
/// run (`shared`), or alone with `holder` recorded in it. A folder a
/// running command holds is refused, naming its holders.
fn lock_folder(claim: &mut Claim, dir: &Path, shared: bool, holder: &str) -> Result<(), ClaimError> {
    let folder_lock = dir.join(LOCK_FILE);
    match lock(&folder_lock, shared)? {
        Lock::Held(file) => {
            if !shared {
                record_holder(&file, holder);
            }
            claim.locks.push((folder_lock, file, shared));
        }
        Lock::Busy => return Err(ClaimError::InUse { dir: dir.to_path_buf(), holder: holders(dir) }),
        Lock::Unsupported => claim.locked = false,
    }
    Ok(())
}

/// The outcome of trying one lock file.
enum Lock {
    Held(File),
    Busy,
    Unsupported,
}

/// Takes the lock of the file at `path` without waiting. A holder removes
/// its file when it is done, so a lock taken on a file that is no longer
/// the one at `path` is let go and taken again on the new one.
fn lock(path: &Path, shared: bool) -> Result<Lock, ClaimError> {
    loop {
        let file = open_lock_file(path)?;
        let taken = if shared { file.try_lock_shared() } else { file.try_lock() };
        match taken {
            Ok(()) if is_at(&file, path) => return Ok(Lock::Held(file)),
            Ok(()) => continue,
            // Its holder may be removing it as it finishes.
            Err(TryLockError::WouldBlock) if !is_at(&file, path) => continue,
            Err(TryLockError::WouldBlock) => return Ok(Lock::Busy),
            Err(TryLockError::Error(e)) if e.kind() == std::io::ErrorKind::Unsupported => return Ok(Lock::Unsupported),
            Err(TryLockError::Error(e)) => return Err(ClaimError::Io { path: path.to_path_buf(), source: e }),
        }
    }
}

/// Opens (creating it if missing) a lock file without following a link:
/// a link planted at the lock's name (dangling or not) is refused, never
/// written through. So is anything but a file of its own: a hard link (a
/// second name of a file elsewhere, which the holder's line would
/// overwrite, and its removal unlink), a pipe or a device (opened without
/// waiting for a writer, never written).
fn open_lock_file(path: &Path) -> Result<File, ClaimError> {
    let mut options = fs::OpenOptions::new();
    options.read(true).write(true).create(true).truncate(false);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options.custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK);
    }
    let file = match options.open(path) {
        Ok(file) => file,
        Err(_) if fs::symlink_metadata(path).is_ok_and(|m| m.file_type().is_symlink()) => return Err(link_error(path)),
        // (exit 2, as for a pipe: it said "cannot write", exit 1)
        Err(_) if fs::symlink_metadata(path).is_ok_and(|m| m.is_dir()) => {
            return Err(ClaimError::BadPath {
                path: path.to_path_buf(),
                why: "a folder where a lock file should be: remove it".into(),
            })
        }
        Err(source) => return Err(ClaimError::Io { path: path.to_path_buf(), source }),
    };
    let meta = file.metadata().map_err(|source| ClaimError::Io { path: path.to_path_buf(), source })?;
    let refuse = |why: String| Err(ClaimError::BadPath { path: path.to_path_buf(), why });
    if !meta.is_file() {
        return refuse(
            "not a regular file (a pipe, a device or a socket) where a lock file should be: remove it".into(),
        );
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        if meta.nlink() > 1 {
            return refuse(format!(
                "a hard link ({} names of one file) where a lock file should be: causalcity never writes \
                 through a link; remove it",
                meta.nlink()
            ));
        }
    }
    Ok(file)
}

fn link_error(path: &Path) -> ClaimError {
    let target = fs::read_link(path).map_or_else(|_| "somewhere".to_string(), |t| t.display().to_string());
    ClaimError::Link { path: path.to_path_buf(), target }
}

/// Whether `file` is the file now at `path`.
fn is_at(file: &File, path: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        match (file.metadata(), fs::metadata(path)) {
            (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
            _ => false,
        }
    }
    #[cfg(not(unix))]
    {
        let _ = (file, path);
        true
    }
}

/// Writes who holds a lock into its file (best effort: it only improves a
/// refused writer's message).
fn record_holder(mut file: &File, holder: &str) {
    let _ = file.set_len(0);
    let _ = file.write_all(format!("{holder}\n").as_bytes());
}

fn read_holder(path: &Path) -> String {
    match fs::read_to_string(path) {
        Ok(text) if !text.trim().is_empty() => text.trim().to_string(),
        _ => "a process that did not say who it is".to_string(),
    }
}

/// Who is writing `dir` now (a command holding its lock, or shards
/// running), if anyone: a reader then says so rather than report a folder
/// half written as damaged. Creates nothing; it tries each lock file's
/// shared lock and lets go at once (plain files only: never a pipe, never
/// through a link).
pub fn writer_at_work(dir: &Path) -> Option<String> {
    let busy = |path: &Path| {
        fs::symlink_metadata(path).is_ok_and(|m| m.is_file())
            && File::open(path).is_ok_and(|f| matches!(f.try_lock_shared(), Err(TryLockError::WouldBlock)))
    };
    let shards = fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .any(|e| e.file_name().to_string_lossy().starts_with(SHARD_LOCK_PREFIX) && busy(&e.path()));
    (shards || busy(&dir.join(LOCK_FILE))).then(|| holders(dir))
}

/// Who holds `dir`'s locks: the exclusive holder, or the shards running.
fn holders(dir: &Path) -> String {
    let mut shard_holders: Vec<String> = fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().starts_with(SHARD_LOCK_PREFIX))
        .filter(|e| File::open(e.path()).is_ok_and(|f| matches!(f.try_lock_shared(), Err(TryLockError::WouldBlock))))
        .map(|e| read_holder(&e.path()))
        .collect();
    shard_holders.sort();
    if shard_holders.is_empty() {
        read_holder(&dir.join(LOCK_FILE))
    } else {
        shard_holders.join("; ")
    }
}

fn host_name() -> String {
    fs::read_to_string("/proc/sys/kernel/hostname")
        .ok()
        .map(|h| h.trim().to_string())
        .filter(|h| !h.is_empty())
        .or_else(|| std::env::var("HOSTNAME").ok())
        .unwrap_or_else(|| "this host".to_string())
}

/// A group folder's name (`cars08_edges50`), as every spec names them.
pub fn is_group_folder(name: &str) -> bool {
    name.strip_prefix("cars").and_then(|rest| rest.split_once("_edges")).is_some_and(|(cars, edges)| {
        !cars.is_empty()
            && !edges.is_empty()
            && cars.chars().all(|c| c.is_ascii_digit())
            && edges.chars().all(|c| c.is_ascii_digit())
    })
}

/// What a folder's top level shows it to be.
struct Contents {
    /// manifest.json or shards/*.json: a `gen` dataset.
    dataset: bool,
    /// sweep.json: a counterfactual sweep.
    sweep: bool,
    /// Entries by name, with whether each is a folder.
    entries: Vec<(String, bool)>,
}

fn read_contents(dir: &Path) -> Result<Option<Contents>, ClaimError> {
    let listing = match fs::read_dir(dir) {
        Ok(listing) => listing,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) if e.kind() == std::io::ErrorKind::NotADirectory => {
            return Err(ClaimError::Io { path: dir.to_path_buf(), source: e });
        }
        Err(source) => return Err(ClaimError::Io { path: dir.to_path_buf(), source }),
    };
    let mut entries: Vec<(String, bool)> = listing
        .flatten()
        .map(|e| (e.file_name().to_string_lossy().into_owned(), e.file_type().is_ok_and(|t| t.is_dir())))
        .filter(|(name, _)| !is_lock_file(name))
        .collect();
    entries.sort();
    let has = |name: &str| entries.iter().any(|(n, _)| n == name);
    let shard_manifests = fs::read_dir(dir.join("shards"))
        .into_iter()
        .flatten()
        .flatten()
        .any(|e| e.file_name().to_string_lossy().ends_with(".json"));
    Ok(Some(Contents { dataset: has("manifest.json") || shard_manifests, sweep: has("sweep.json"), entries }))
}

/// A few names for a message.
fn some_names(names: &[&str]) -> String {
    let shown: Vec<String> = names.iter().take(3).map(|n| format!("{n:?}")).collect();
    match names.len() {
        n if n > 3 => format!("{} and {} more", shown.join(", "), n - 3),
        _ => shown.join(", "),
    }
}

/// Refuses a folder that holds anything `writer` would not have written.
fn check_contents(dir: &Path, writer: Writer) -> Result<(), ClaimError> {
    let Some(contents) = read_contents(dir)? else { return Ok(()) };
    let foreign = |what: String, writes: &'static str, hint: &'static str| {
        Err(ClaimError::Foreign { dir: dir.to_path_buf(), what, command: writer.command(), writes, hint })
    };
    let unknown = |allowed: &dyn Fn(&str, bool) -> bool| -> Vec<&str> {
        contents.entries.iter().filter(|(n, is_dir)| !allowed(n, *is_dir)).map(|(n, _)| n.as_str()).collect()
    };
    match writer {
        Writer::Gen { .. } | Writer::Merge | Writer::Pack => {
            const WRITES: &str = "a dataset (manifest.json, shards/, networks/, group folders such as cars08_edges50/)";
            if contents.sweep {
                return foreign("a counterfactual sweep (sweep.json)".into(), WRITES, "");
            }
            // (A link is no folder here: a linked networks/ is refused.)
            let dataset_entry = |n: &str, is_dir: bool| {
                matches!(n, "manifest.json" | "manifest.json.partial")
                    || (is_dir
                        && (n == "shards"
                            || n == super::layout::JOB_LOGS_DIR
                            || n == super::layout::REMOVING_DIR
                            || n == crate::spec::NETWORKS_FOLDER
                            || is_group_folder(n)))
            };
            let strangers = unknown(&dataset_entry);
            if !strangers.is_empty() {
                return foreign(format!("what no dataset holds ({})", some_names(&strangers)), WRITES, "");
            }
            let groups: Vec<&str> =
                contents.entries.iter().filter(|(n, d)| *d && is_group_folder(n)).map(|(n, _)| n.as_str()).collect();
            if !contents.dataset && !groups.is_empty() {
                return foreign(
                    format!(
                        "group folders ({}) but no manifest.json, so no dataset says it wrote them",
                        some_names(&groups)
                    ),
                    WRITES,
                    ", or move them away if they are yours",
                );
            }
        }
        Writer::Sweep => {
            const WRITES: &str = "counterfactual pairs (sweep.json, group folders such as cars08_edges50/)";
            if contents.dataset {
                return foreign("a gen dataset (manifest.json)".into(), WRITES, "");
            }
            let sweep_entry = |n: &str, is_dir: bool| {
                matches!(n, "sweep.json" | "sweep.json.partial")
                    || (is_dir && (n == crate::spec::NETWORKS_FOLDER || is_group_folder(n)))
            };
            let strangers = unknown(&sweep_entry);
            if !strangers.is_empty() {
                return foreign(format!("what no sweep holds ({})", some_names(&strangers)), WRITES, "");
            }
            let has_groups = contents.entries.iter().any(|(n, d)| *d && is_group_folder(n));
            if !contents.sweep && has_groups {
                return foreign(
                    "group folders but no sweep.json, so no sweep says it wrote them".into(),
                    WRITES,
                    ", or move them away if they are yours",
                );
            }
        }
        Writer::Scenarios | Writer::Export => {
            let writes = if writer == Writer::Scenarios {
                "one folder per scenario of the file"
            } else {
                "an export (group folders such as cars08_edges50/ of .npy arrays, or of per-scenario annotations \
                 or .h5 files)"
            };
            if contents.dataset {
                return foreign("a gen dataset (manifest.json)".into(), writes, "");
            }
            if contents.sweep {
                return foreign("a counterfactual sweep (sweep.json)".into(), writes, "");
            }
            // An export writes group folders (cars08_edges50/) and nothing
            // else: a folder of the user's beside them is refused, not mixed.
            let own = |n: &str, is_dir: bool| match writer {
                Writer::Export => is_dir && is_group_folder(n),
                _ => is_dir,
            };
            let strangers = unknown(&own);
            if !strangers.is_empty() {
                return foreign(format!("files it did not write ({})", some_names(&strangers)), writes, "");
            }
        }
    }
    Ok(())
}

/// Refuses a folder inside a dataset or sweep (an export or scenario run
/// into `data/toy/exports` would make the dataset fail `validate`).
fn check_ancestors(dir: &Path) -> Result<(), ClaimError> {
    // On the path with its links resolved: a link into a dataset is inside it.
    let absolute = resolve(dir);
    let holds = |path: PathBuf, format: &str| {
        path.is_file() && fs::read(&path).is_ok_and(|b| b.windows(format.len()).any(|w| w == format.as_bytes()))
    };
    // A `gen --shard` folder before its merge has no manifest.json yet,
    // only its shards' (`shards/K-of-N.json`).
    let sharded = |dir: &Path| {
        fs::read_dir(dir.join("shards")).is_ok_and(|entries| {
            entries.flatten().any(|e| {
                let name = e.file_name();
                let name = name.to_string_lossy();
                name.contains("-of-") && name.ends_with(".json") && holds(e.path(), super::manifest::MANIFEST_FORMAT)
            })
        })
    };
    let fails_validate = "which it would then fail to validate";
    for ancestor in absolute.ancestors().skip(1) {
        let (inside, harm) = if holds(ancestor.join("manifest.json"), super::manifest::MANIFEST_FORMAT) {
            ("a gen dataset", fails_validate)
        } else if sharded(ancestor) {
            ("a gen dataset written in shards (shards/K-of-N.json)", fails_validate)
        } else if holds(ancestor.join("sweep.json"), SWEEP_FORMAT_PREFIX) {
            ("a counterfactual sweep", fails_validate)
        } else if is_export(ancestor) {
            ("an export", "which holds only what export writes (a file beside it, and export refuses to update it)")
        } else {
            continue;
        };
        let ancestor = ancestor.to_path_buf();
        return Err(ClaimError::Inside { dir: dir.to_path_buf(), inside, ancestor, harm });
    }
    Ok(())
}

/// Whether `dir` is an export: group folders and nothing else, as `export`
/// takes a folder for its own (a file beside them, and it refuses to update
/// them), each holding only what an export writes there, and some of it:
/// NRI's arrays (`loc_train.npy`, `edges_valid_x.npy`, ...), or split
/// folders of V-CDN's `.h5` files or NS-DR's scenario folders (each with its
/// annotations). An export under way or cut off midway (killed or
/// interrupted, it leaves its lock file) holds its lock too, and may hold
/// empty folders and files still staged (`.partial`). A user's own folders
/// of that shape, and a folder of datasets named after their groups (each
/// with a manifest), are none.
fn is_export(dir: &Path) -> bool {
    let cut_off = fs::read_dir(dir)
        .is_ok_and(|entries| entries.flatten().any(|e| is_lock_file(&e.file_name().to_string_lossy()) && is_file(&e)));
    let groups = std::cell::Cell::new(0);
    let exported = |entry: &fs::DirEntry, name: &str| exported(entry, name, cut_off);
    let top = every_entry(dir, false, &|entry, name| {
        let group = is_group_folder(name) && is_dir(entry) && every_entry(&entry.path(), cut_off, &exported);
        groups.set(groups.get() + usize::from(group));
        group || (is_lock_file(name) && is_file(entry))
    });
    top && groups.get() > 0
}

/// Whether every entry of folder `dir` is of `kind` and there is one (or
/// none, where `empty_too`).
fn every_entry(dir: &Path, empty_too: bool, kind: &dyn Fn(&fs::DirEntry, &str) -> bool) -> bool {
    fs::read_dir(dir).is_ok_and(|entries| {
        let mut seen = 0;
        for entry in entries {
            match entry {
                Ok(entry) if kind(&entry, &entry.file_name().to_string_lossy()) => seen += 1,
                _ => return false,
            }
        }
        seen > 0 || empty_too
    })
}

/// Whether `entry` (named `name`) of a group folder is what an export
/// writes there: NRI's arrays or a split folder of scenarios, also still
/// staged where the export was `cut_off`.
fn exported(entry: &fs::DirEntry, name: &str, cut_off: bool) -> bool {
    let finished =
        |name: &str| if cut_off { name.strip_suffix(".partial").unwrap_or(name).to_string() } else { name.to_string() };
    let array = finished(name).ends_with(".npy")
        && ["loc_", "vel_", "edges_", "dynamic_edges_"].iter().any(|p| name.starts_with(p));
    if array {
        return is_file(entry);
    }
    let scenario = |entry: &fs::DirEntry, name: &str| {
        if is_dir(entry) {
            // NS-DR writes a scenario's annotations, then links its frames:
            // cut off, its folder may hold nothing yet, or the annotations
            // still staged.
            let (dir, annotations) = (entry.path(), super::annotations::ANNOTATIONS_FILE);
            let staged = |e: &fs::DirEntry, n: &str| n.strip_suffix(".partial") == Some(annotations) && is_file(e);
            dir.join(annotations).is_file() || (cut_off && every_entry(&dir, true, &staged))
        } else {
            finished(name).ends_with(".h5") && is_file(entry)
        }
    };
    matches!(name, "train" | "val" | "valid" | "test")
        && is_dir(entry)
        && every_entry(&entry.path(), cut_off, &scenario)
}

fn is_dir(entry: &fs::DirEntry) -> bool {
    entry.file_type().is_ok_and(|t| t.is_dir())
}

fn is_file(entry: &fs::DirEntry) -> bool {
    entry.file_type().is_ok_and(|t| t.is_file())
}

/// `path` made absolute with every link resolved: its longest existing
/// part canonicalised, the rest (not yet created) appended, `..` taken
/// lexically there.
pub fn resolve(path: &Path) -> PathBuf {
    let absolute = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let mut missing = Vec::new();
    let mut existing = absolute.as_path();
    loop {
        if let Ok(real) = fs::canonicalize(existing) {
            let mut resolved = real;
            for part in missing.iter().rev() {
                match part {
                    std::path::Component::ParentDir => {
                        resolved.pop();
                    }
                    std::path::Component::CurDir => {}
                    other => resolved.push(other.as_os_str()),
                }
            }
            return resolved;
        }
        match (existing.parent(), existing.components().next_back()) {
            (Some(parent), Some(last)) => {
                missing.push(last);
                existing = parent;
            }
            _ => return absolute,
        }
    }
}

/// Refuses `inputs` (files a command reads, each described for the
/// message) that lie inside `folder`, which it is about to write: a run
/// whose input sits in its own output folder would write over it.
pub fn refuse_inputs_inside(folder: &Path, inputs: &[(&str, &Path)]) -> Result<(), ClaimError> {
    let resolved = resolve(folder);
    for (what, input) in inputs {
        if resolve(input).starts_with(&resolved) {
            return Err(ClaimError::OwnInput {
                path: folder.to_path_buf(),
                what: format!("where {what} {} lies, and this command writes that folder", input.display()),
            });
        }
    }
    Ok(())
}

/// A single file a command writes beside its main output or instead of
/// one (a report, an image, a predictions file), checked by the one write
/// rule: never inside a dataset or sweep (the command owns no file there),
/// never onto its own input, never through a link. [`OutputFile::write`]
/// then writes it through a temporary file and a rename, which replaces a
/// link that appeared since rather than following it.
#[derive(Debug)]
pub struct OutputFile {
    path: PathBuf,
}

/// What a single output file holds, told by its first bytes. A file
/// already at the path is replaced only by one holding the same kind: a
/// predictions `.npz` never lands on a spec, nor a CSV table on an image.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FileKind {
    /// A zip archive (`.npz`).
    Zip,
    Png,
    Gif,
    /// A JSON object or array.
    Json,
    /// Other UTF-8 text (CSV, Markdown).
    Text,
    /// A CSV table whose first line is this header: it replaces only an
    /// earlier table of the same columns, or of one of the earlier headers
    /// given (the table as an earlier version wrote it), never notes or a
    /// script.
    Table(&'static str, &'static [&'static str]),
    /// Anything else.
    Binary,
}

impl FileKind {
    /// The kind of a file that begins with `head` (its first few KB).
    pub fn of(head: &[u8]) -> FileKind {
        if head.starts_with(b"PK\x03\x04") || head.starts_with(b"PK\x05\x06") {
            return FileKind::Zip;
        }
        if head.starts_with(b"\x89PNG\r\n\x1a\n") {
            return FileKind::Png;
        }
        if head.starts_with(b"GIF87a") || head.starts_with(b"GIF89a") {
            return FileKind::Gif;
        }
        // Text cut short at the end of `head` is still text.
        let text = match std::str::from_utf8(head) {
            Ok(text) => text,
            Err(e) if e.error_len().is_none() => std::str::from_utf8(&head[..e.valid_up_to()]).unwrap_or_default(),
            Err(_) => return FileKind::Binary,
        };
        match text.trim_start().chars().next() {
            Some('{' | '[') => FileKind::Json,
            _ => FileKind::Text,
        }
    }

    fn name(self) -> &'static str {
        match self {
            FileKind::Zip => "a zip archive (such as an .npz)",
            FileKind::Png => "a PNG image",
            FileKind::Gif => "a GIF",
            FileKind::Json => "JSON (such as a spec)",
            FileKind::Text => "text (such as a CSV table)",
            FileKind::Table(..) => "a CSV table",
            FileKind::Binary => "binary data",
        }
    }
}

/// Checks that a command may write the file `path`, holding `writes`:
/// `inputs` are the files and folders it reads (a dataset, a predictions
/// file, a scenario), each described for the message (e.g. `("the
/// dataset", path)`). A file already there is replaced only if it holds
/// the same kind of contents (an earlier run's output), or nothing. The
/// folder it goes into is created by [`OutputFile::write`] if missing.
pub fn claim_file(path: &Path, inputs: &[(&str, &Path)], writes: FileKind) -> Result<OutputFile, ClaimError> {
    let not_a_file = |why: String| Err(ClaimError::BadPath { path: path.to_path_buf(), why });
    let named = path.file_name().is_some_and(|n| n != "." && n != "..");
    if !named {
        return not_a_file("is not a file name: give a path such as results/report.csv".into());
    }
    match fs::symlink_metadata(path) {
        Ok(m) if m.file_type().is_symlink() => return Err(link_error(path)),
        Ok(m) if m.is_dir() => return not_a_file("is a folder: give the path of a file to write".into()),
        // Renamed over, a device node (as root, /dev/null) or a FIFO became this command's file.
        Ok(m) if !m.is_file() => {
            return not_a_file(format!(
                "is {}, not a regular file: nothing is written there; give the path of a file",
                special_file(&m.file_type())
            ))
        }
        _ => {}
    }
    // A part of the path that exists must be a folder.
    let absolute = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    if let Some(file) = absolute.ancestors().skip(1).find(|a| fs::metadata(a).is_ok_and(|m| !m.is_dir())) {
        return not_a_file(format!("{} is a file, so nothing can be written under it", file.display()));
    }
    let resolved = resolve(path);
    check_ancestors(&resolved)?;
    for (what, input) in inputs {
        let input = resolve(input);
        if resolved == input {
            return Err(ClaimError::OwnInput { path: path.to_path_buf(), what: what.to_string() });
        }
        if resolved.starts_with(&input) {
            return Err(ClaimError::OwnInput { path: path.to_path_buf(), what: format!("inside {what}") });
        }
    }
    if let Some(head) = existing_head(path) {
        let held = FileKind::of(&head);
        let (same, held) = match writes {
            FileKind::Table(header, earlier) if held == FileKind::Text => {
                let first = head.split(|&b| b == b'\n').next().unwrap_or_default();
                let ours = std::iter::once(header).chain(earlier.iter().copied()).any(|h| first == h.as_bytes());
                (ours, "text other than this command's table (its first line differs)")
            }
            _ => (held == writes, held.name()),
        };
        if !same {
            return not_a_file(format!(
                "already holds {held}, and this command writes {} there: nothing is replaced. Remove it, or choose \
                 another path",
                writes.name()
            ));
        }
    }
    Ok(OutputFile { path: path.to_path_buf() })
}

/// What a file that is neither a regular file, a folder nor a link is.
fn special_file(kind: &fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        match () {
            _ if kind.is_char_device() => return "a character device",
            _ if kind.is_block_device() => return "a block device",
            _ if kind.is_fifo() => return "a FIFO (named pipe)",
            _ if kind.is_socket() => return "a socket",
            _ => {}
        }
    }
    let _ = kind;
    "a special file"
}

/// The first 4 KB of the regular file at `path` (`None`: no file, not a
/// plain file, or an empty one).
fn existing_head(path: &Path) -> Option<Vec<u8>> {
    use std::io::Read;
    let metadata = fs::symlink_metadata(path).ok()?;
    if !metadata.is_file() || metadata.len() == 0 {
        return None;
    }
    let mut head = Vec::with_capacity(4096);
    File::open(path).ok()?.take(4096).read_to_end(&mut head).ok()?;
    Some(head)
}

impl OutputFile {
    /// The path as given.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Writes `bytes` (its folder created if missing) through a temporary
    /// file beside it and a rename.
    pub fn write(&self, bytes: &[u8]) -> Result<(), super::WriteError> {
        let partial = self.partial()?;
        if let Err(e) = fs::write(&partial, bytes) {
            let _ = fs::remove_file(&partial);
            return Err(super::io_err(&partial)(e));
        }
        self.commit(&partial)
    }

    /// The temporary path to stream a large file into before
    /// [`OutputFile::commit`] (its folder created if missing).
    pub fn partial(&self) -> Result<PathBuf, super::WriteError> {
        if let Some(parent) = self.path.parent().filter(|p| !p.as_os_str().is_empty()) {
            fs::create_dir_all(parent).map_err(super::io_err(parent))?;
        }
        super::fresh_partial(&self.path)
    }

    /// Moves the finished [`OutputFile::partial`] (`partial`) into place,
    /// or removes it when the move fails.
    pub fn commit(&self, partial: &Path) -> Result<(), super::WriteError> {
        fs::rename(partial, &self.path).map_err(|e| {
            let _ = fs::remove_file(partial);
            super::io_err(&self.path)(e)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn group_folders_are_recognised_by_name() {
        assert!(is_group_folder("cars08_edges50"));
        assert!(is_group_folder("cars12_edges100"));
        assert!(!is_group_folder("cars_edges50"));
        assert!(!is_group_folder("cars08_edges"));
        assert!(!is_group_folder("Scenario_1"));
    }
}

/// A reader's hold on a dataset: a shared lock on its folder, kept while
/// the dataset is open. `gen --force` takes that lock exclusively before
/// it removes anything ([`exclude_readers`]), so it refuses to remove a
/// dataset being read, and a reader refuses to open one being removed. The
/// folder, not its manifest: a plain `gen` replaces the manifest whole, and
/// a hold on the file it replaced held nothing. Nothing is written.
#[derive(Debug)]
pub struct ReadHold {
    /// None where the filesystem has no locks (some network filesystems).
    _folder: Option<File>,
}

/// Opens a folder to lock it (read only, never waiting: a pipe named as
/// the folder is not one).
fn open_folder(dir: &Path) -> Option<File> {
    if !fs::metadata(dir).is_ok_and(|m| m.is_dir()) {
        return None;
    }
    let mut options = fs::OpenOptions::new();
    options.read(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options.custom_flags(libc::O_DIRECTORY | libc::O_NONBLOCK);
    }
    options.open(dir).ok()
}

/// Takes a reader's hold on the dataset in `dir`; an error, naming the
/// folder and who is removing it, while a `gen --force` removes it.
pub fn hold_for_reading(dir: &Path) -> Result<ReadHold, String> {
    let Some(folder) = open_folder(dir) else { return Ok(ReadHold { _folder: None }) };
    match folder.try_lock_shared() {
        Ok(()) => Ok(ReadHold { _folder: Some(folder) }),
        Err(TryLockError::WouldBlock) => Err(format!(
            "{} is being removed by gen --force ({}): wait for it to finish, then read the dataset it writes there",
            dir.display(),
            holders(dir)
        )),
        // No locks here: read unheld.
        Err(TryLockError::Error(_)) => Ok(ReadHold { _folder: None }),
    }
}

/// Before the dataset in `dir` is removed: every reader's hold taken away,
/// by an exclusive lock on the folder, kept while the returned file lives.
/// [`ClaimError::BeingRead`] while a reader holds it; a filesystem without
/// locks is passed over.
pub fn exclude_readers(dir: &Path) -> Result<Option<File>, ClaimError> {
    let Some(folder) = open_folder(dir) else { return Ok(None) };
    match folder.try_lock() {
        Ok(()) => Ok(Some(folder)),
        Err(TryLockError::WouldBlock) => Err(ClaimError::BeingRead { dir: dir.to_path_buf() }),
        Err(TryLockError::Error(_)) => Ok(None),
    }
}
