//! Output: where files go and how they are written. Writers take plans,
//! trajectories and rendered pixels as plain data; they know nothing of how
//! those were produced.
//!
//! Layout (documented in docs/output-layout.md and `data-schema/`): `OUT/manifest.json`,
//! `OUT/<group>/<split>/<scenario>/` as [`layout`] lists it.

pub mod annotations;
pub mod arrays;
pub mod claim;
pub mod footage;
pub mod layout;
pub mod logs;
pub mod manifest;
pub mod number;
pub mod packs;
pub mod pair_summary;
pub mod png;
pub mod poses;
pub mod rows;
pub mod scenario;
pub mod writer;

use crate::timing::{Stage, StageTimes};
pub use layout::frame_digits;
use layout::ScenarioLayout;
use std::time::Instant;

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

/// Bytes free for this user on the file system that holds `path` (an
/// existing file or folder); `None` where the OS cannot say.
pub fn free_disk_bytes(path: &Path) -> Option<u64> {
    #[cfg(unix)]
    {
        use std::os::unix::ffi::OsStrExt;
        let name = std::ffi::CString::new(path.as_os_str().as_bytes()).ok()?;
        let mut stats = std::mem::MaybeUninit::<libc::statvfs>::uninit();
        // SAFETY: `name` is a NUL-terminated path and `stats` room for one
        // statvfs record, which the call fills when it returns 0.
        let stats = unsafe {
            if libc::statvfs(name.as_ptr(), stats.as_mut_ptr()) != 0 {
                return None;
            }
            stats.assume_init()
        };
        Some((stats.f_bavail as u64).saturating_mul(stats.f_frsize as u64))
    }
    #[cfg(not(unix))]
    {
        let _ = path;
        None
    }
}

/// The folder of one scenario: `OUT/<group>/<split>/<NNNNN>`.
pub fn scenario_dir(root: &Path, group: &str, split: &str, folder: &str) -> PathBuf {
    root.join(group).join(split).join(folder)
}

/// The first folder below `root` on the way down to `dir` (`dir` included)
/// that is a symbolic link, if any: a dataset holds its own group, split,
/// scenario (pair, run) folders, and its readers read none through a link,
/// as `validate` names one and `gen` writes through none.
pub fn linked_below(root: &Path, dir: &Path) -> Option<PathBuf> {
    let mut below_root: Vec<&Path> = dir.ancestors().take_while(|a| *a != root).collect();
    below_root.reverse();
    below_root
        .into_iter()
        .find(|folder| fs::symlink_metadata(folder).is_ok_and(|m| m.is_symlink()))
        .map(Path::to_path_buf)
}

/// A reader's refusal of the linked folder `link` ([`linked_below`]).
pub fn linked_folder_error(link: &Path) -> String {
    let target = fs::read_link(link).map(|t| format!(" (to {})", t.display())).unwrap_or_default();
    format!(
        "{}: a symbolic link{target}: a dataset's scenarios are read from its own folders, never through a link \
         (replace it with the folder it points to); `causalcity validate` names what else is wrong",
        link.display()
    )
}

/// Name of the checksum file in every scenario folder (`sha256sum -c` format).
pub const CHECKSUMS: &str = "checksums.sha256";

/// Prefix of the hidden folder a scenario is written into before it is complete.
pub const PARTIAL_PREFIX: &str = ".partial-";

/// A scenario folder being written. Files go into a hidden temporary folder
/// beside the final one, each hashed (SHA-256) as it is written; `commit`
/// adds `checksums.sha256`, flushes and renames the folder into place, so a
/// scenario folder that exists is complete.
pub struct ScenarioDir<'t> {
    temp: PathBuf,
    target: PathBuf,
    folders: Vec<String>,
    committed: bool,
    fsync: bool,
    hashes: Vec<(String, [u8; 32])>,
    times: &'t StageTimes,
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

/// Where [`ScenarioDir::commit`] moves an older copy of `target` before
/// deleting it: hidden, and never another folder's temporary name (a
/// folder name never starts with a dot).
fn replaced_aside(target: &Path) -> PathBuf {
    let name = target.file_name().unwrap_or_default().to_string_lossy();
    target.with_file_name(format!("{PARTIAL_PREFIX}.replaced-{name}"))
}

impl<'t> ScenarioDir<'t> {
    /// Starts writing the scenario that will live at `target` with the
    /// folders of `layout`; leftovers of an interrupted attempt are
    /// discarded. With `fsync`, every file and the folder reach the disk
    /// before the rename (survives power loss, slower). Time spent writing
    /// and hashing is added to `times`.
    pub fn begin(
        target: PathBuf,
        layout: &ScenarioLayout,
        fsync: bool,
        times: &'t StageTimes,
    ) -> Result<ScenarioDir<'t>, WriteError> {
        let name = target.file_name().expect("scenario folder has a name").to_string_lossy().into_owned();
        let temp = target.with_file_name(format!("{PARTIAL_PREFIX}{name}"));
        // This attempt's leftovers, and an older copy a cut-off commit had
        // moved aside.
        for leftover in [&temp, &replaced_aside(&target)] {
            if fs::symlink_metadata(leftover).is_ok() {
                fs::remove_dir_all(leftover).map_err(io_err(leftover))?;
            }
        }
        fs::create_dir_all(&temp).map_err(io_err(&temp))?;
        let folders = layout.folders();
        for sub in &folders {
            let p = temp.join(sub);
            fs::create_dir(&p).map_err(io_err(&p))?;
        }
        Ok(ScenarioDir { temp, target, folders, committed: false, fsync, hashes: Vec::new(), times })
    }

    /// Writes a whole file into the scenario folder; returns its size.
    pub fn write_file(&mut self, name: &str, bytes: &[u8]) -> Result<u64, WriteError> {
        let hash: [u8; 32] = self.times.time(Stage::Checksum, || Sha256::digest(bytes).into());
        let start = Instant::now();
        let path = self.temp.join(name);
        let mut file = fs::File::create(&path).map_err(io_err(&path))?;
        file.write_all(bytes).map_err(io_err(&path))?;
        if self.fsync {
            file.sync_all().map_err(io_err(&path))?;
        }
        self.times.add(Stage::Write, start.elapsed());
        self.hashes.push((name.to_string(), hash));
        Ok(bytes.len() as u64)
    }

    /// Streams a file through `fill` (formatting, hashing and writing all
    /// count as writing); returns its size.
    pub fn write_with<E: Into<std::io::Error>>(
        &mut self,
        name: &str,
        fill: impl FnOnce(&mut dyn Write) -> Result<(), E>,
    ) -> Result<u64, WriteError> {
        let start = Instant::now();
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
        self.times.add(Stage::Write, start.elapsed());
        Ok(len)
    }

    /// Writes the checksums and moves the finished scenario into place,
    /// replacing an older copy. Returns the checksum file's size.
    pub fn commit(mut self) -> Result<u64, WriteError> {
        let mut hashes = std::mem::take(&mut self.hashes);
        hashes.sort();
        let listing: String = hashes.iter().map(|(name, h)| format!("{}  {name}\n", hex(h))).collect();
        let len = self.write_file(CHECKSUMS, listing.as_bytes())?;
        if self.fsync {
            let folders = std::iter::once(self.temp.clone()).chain(self.folders.iter().map(|f| self.temp.join(f)));
            for dir in folders {
                fs::File::open(&dir).and_then(|d| d.sync_all()).map_err(io_err(&dir))?;
            }
        }
        // An older copy leaves by one rename and is deleted after the new
        // one is in place: deleted where it stood, a kill part way left a
        // folder with some of its files and no checksums, which no rerun
        // could tell from a user's (a hidden leftover is swept on rerun).
        let mut old = None;
        if fs::symlink_metadata(&self.target).is_ok() {
            let aside = replaced_aside(&self.target);
            if fs::symlink_metadata(&aside).is_ok() {
                fs::remove_dir_all(&aside).map_err(io_err(&aside))?;
            }
            fs::rename(&self.target, &aside).map_err(io_err(&self.target))?;
            old = Some(aside);
        }
        fs::rename(&self.temp, &self.target).map_err(io_err(&self.target))?;
        self.committed = true;
        if let Some(old) = old {
            fs::remove_dir_all(&old).map_err(io_err(&old))?;
        }
        Ok(len)
    }
}

impl Drop for ScenarioDir<'_> {
    fn drop(&mut self) {
        if !self.committed {
            let _ = fs::remove_dir_all(&self.temp);
        }
    }
}

/// Makes a write past the file-size limit (`ulimit -f`) fail with an error
/// the command reports (exit status 1, naming the file) instead of the
/// SIGXFSZ that would kill the process without a word. For the binary only:
/// a library inside another program leaves its signals alone.
pub fn report_file_size_limit_as_error() {
    #[cfg(unix)]
    // SAFETY: setting a signal's disposition to "ignore" has no handler to race.
    unsafe {
        libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
    }
}

/// Lower-case hex of bytes.
pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// The temporary file beside `path` that an atomic write fills first
/// (`<name>.partial`). Anything already there (a leftover, or a link
/// planted at that name) is removed, never written through.
pub fn fresh_partial(path: &Path) -> Result<PathBuf, WriteError> {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(".partial");
    let temp = path.with_file_name(name);
    match fs::symlink_metadata(&temp) {
        Ok(m) if !m.is_dir() => fs::remove_file(&temp).map_err(io_err(&temp))?,
        _ => {}
    }
    Ok(temp)
}

/// Whether `path` is a plain file (not a link, never read through one)
/// holding exactly `bytes`.
pub fn holds_bytes(path: &Path, bytes: &[u8]) -> bool {
    fs::symlink_metadata(path).is_ok_and(|m| m.is_file()) && fs::read(path).ok().as_deref() == Some(bytes)
}

/// A hash (hex) as messages show it: its first 12 characters.
pub fn short_hash(hash: &str) -> &str {
    hash.get(..12).unwrap_or(hash)
}

/// Writes `bytes` to `path` through a temporary file and a rename (which
/// replaces a link at `path` rather than writing through it).
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), WriteError> {
    let temp = fresh_partial(path)?;
    // A failed write (a full disk) leaves nothing behind, not a half file.
    let written =
        fs::write(&temp, bytes).map_err(io_err(&temp)).and_then(|()| fs::rename(&temp, path).map_err(io_err(path)));
    if written.is_err() {
        let _ = fs::remove_file(&temp);
    }
    written
}

/// Why causalcity will not write a folder: the way to it, or the folder
/// itself, is a link (writing through it could land anywhere), or the
/// folder holds files causalcity did not write, which replacing it would
/// remove. The user's to resolve (exit status 2); nothing is written or
/// removed.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct Refused(pub String);

/// Refuses a link at `path` or at any folder between `root` (the output
/// folder, whose own links its claim checks) and it. Components that do
/// not exist yet end the check: nothing below them exists either.
pub fn refuse_links_below(root: &Path, path: &Path) -> Result<(), Refused> {
    let Ok(rest) = path.strip_prefix(root) else { return Ok(()) };
    let mut at = root.to_path_buf();
    for part in rest.components() {
        at.push(part);
        match fs::symlink_metadata(&at) {
            Ok(m) if m.file_type().is_symlink() => {
                let to = fs::read_link(&at).map_or_else(|_| "somewhere".to_string(), |t| t.display().to_string());
                return Err(Refused(format!(
                    "{} is a link (to {to}) inside {}: causalcity never writes through a link. \
                     Put a real folder there (or remove the link) and rerun",
                    at.display(),
                    root.display()
                )));
            }
            Ok(_) => {}
            Err(_) => break,
        }
    }
    Ok(())
}

/// What causalcity writes in a folder it replaces whole: the files the
/// `checksums.sha256` of each folder in `listed` names (paths relative to
/// the folder; `""` the folder itself) and each path of `names` (a folder
/// named there counts whole: an interrupted write's leftover).
pub struct OwnFiles<'a> {
    pub listed: &'a [&'a str],
    pub names: &'a [&'a str],
}

impl OwnFiles<'_> {
    /// A scenario folder: what its own checksum listing names.
    pub const SCENARIO: OwnFiles<'static> = OwnFiles { listed: &[""], names: &[] };
}

/// Refuses to replace the folder `dir` (when there is one) if it holds
/// anything else than `own` (every empty folder must be one of them or hold
/// one). `what` names what would replace it in the message (`a new
/// scenario folder`).
pub fn refuse_foreign(dir: &Path, own: &OwnFiles, what: &str) -> Result<(), Refused> {
    let mut known: std::collections::HashSet<String> = own.names.iter().map(|n| n.to_string()).collect();
    for folder in own.listed {
        let prefix = if folder.is_empty() { String::new() } else { format!("{folder}/") };
        known.insert(format!("{prefix}{CHECKSUMS}"));
        let Ok(listing) = fs::read_to_string(dir.join(folder).join(CHECKSUMS)) else { continue };
        for name in listing.lines().filter_map(|line| line.split_once("  ").map(|(_, n)| n)) {
            let full = format!("{prefix}{name}");
            let mut parent = full.as_str();
            while let Some((up, _)) = parent.rsplit_once('/') {
                known.insert(up.to_string());
                parent = up;
            }
            known.insert(full);
        }
    }
    let mut foreign = Vec::new();
    let mut stack = vec![(dir.to_path_buf(), String::new())];
    while let Some((folder, prefix)) = stack.pop() {
        let entries = match fs::read_dir(&folder) {
            Ok(entries) => entries,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => continue,
            Err(e) => return Err(Refused(format!("cannot read {}: {e}", folder.display()))),
        };
        let mut empty = true;
        for entry in entries {
            let entry = entry.map_err(|e| Refused(format!("cannot read {}: {e}", folder.display())))?;
            empty = false;
            let name = format!("{prefix}{}", entry.file_name().to_string_lossy());
            let real_dir = entry.file_type().is_ok_and(|t| t.is_dir());
            if real_dir && own.names.contains(&name.as_str()) {
                continue;
            }
            if real_dir {
                stack.push((entry.path(), format!("{name}/")));
            } else if !known.contains(&name) {
                foreign.push(entry.path());
            }
        }
        let this = prefix.trim_end_matches('/');
        if empty && !this.is_empty() && !known.contains(this) {
            foreign.push(folder);
        }
    }
    if foreign.is_empty() {
        return Ok(());
    }
    foreign.sort();
    let shown: Vec<String> = foreign.iter().take(5).map(|p| format!("  {}", p.display())).collect();
    let more = foreign.len().saturating_sub(shown.len());
    Err(Refused(format!(
        "{} would be replaced by {what}, but it holds {} path(s) that are not files causalcity wrote there \
         (named in its checksums.sha256):\n{}{}\nNothing was replaced. Move them out of it (or use another \
         --out), then rerun.",
        dir.display(),
        foreign.len(),
        shown.join("\n"),
        if more > 0 { format!("\n  ... and {more} more") } else { String::new() }
    )))
}

/// The first symbolic link on the way from `dir` to the file `name` (a
/// path relative to it), if any: a scenario holds its own files, and one
/// read through a link may be anyone's.
pub fn link_below(dir: &Path, name: &str) -> Option<PathBuf> {
    let mut at = dir.to_path_buf();
    for part in Path::new(name).components() {
        at.push(part);
        if fs::symlink_metadata(&at).is_ok_and(|m| m.file_type().is_symlink()) {
            return Some(at);
        }
    }
    None
}

/// Checks the files `names` of the scenario folder `dir` against its
/// `checksums.sha256`, as a reader that scores or trusts them must: each is
/// listed there, is no symbolic link, and has the hash listed. The rest of
/// the folder is not read (a dataset with images holds hundreds of frames
/// its scores never look at). Errors name the file and say what is wrong.
pub fn verify_files(dir: &Path, names: &[&str]) -> Result<(), String> {
    let (listing_path, listing) = read_listing(dir)?;
    for &name in names {
        let Some(hash) = listing.lines().find_map(|l| l.split_once("  ").filter(|(_, n)| *n == name).map(|(h, _)| h))
        else {
            return Err(format!(
                "{}: does not list {name}, so nothing shows that {name} is the one written with it",
                listing_path.display()
            ));
        };
        check_listed(dir, name, hash)?;
    }
    Ok(())
}

/// The scenario folder `dir`'s `checksums.sha256`: its path and text.
fn read_listing(dir: &Path) -> Result<(PathBuf, String), String> {
    let path = dir.join(CHECKSUMS);
    let text = crate::input::read_record_text(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    Ok((path, text))
}

/// Checks file `name` of the scenario folder `dir` against `hash`, its
/// listed SHA-256: a regular file of the folder's own (no symbolic link on
/// the way; a pipe hung merge, pack and a resumed gen) with that hash.
fn check_listed(dir: &Path, name: &str, hash: &str) -> Result<(), String> {
    if let Some(link) = link_below(dir, name) {
        return Err(format!("{}: a symbolic link, not a file of the scenario's own", link.display()));
    }
    let path = dir.join(name);
    let data = crate::input::read_data(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    if hex(&Sha256::digest(&data)) != hash {
        return Err(format!(
            "{}: its checksum does not match {CHECKSUMS}: the file changed after it was written",
            path.display()
        ));
    }
    Ok(())
}

/// [`verify_scenario`] of the folder that holds scenario `key` of a spec of
/// `seed`, and its `scenario.json` says it is that scenario
/// ([`scenario::check_identity`]).
pub fn verify_scenario_of(dir: &Path, key: &crate::plan::ScenarioKey, seed: u64) -> Result<(), String> {
    verify_scenario(dir)?;
    let path = dir.join(layout::SCENARIO_JSON);
    let bytes = crate::input::read_record(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    scenario::check_identity(&bytes, key, seed).map_err(|e| format!("{}: {e}", path.display()))
}

/// Whether the scenario folder `dir` holds exactly the files of `layout`:
/// its `checksums.sha256` lists every one of them and nothing else, and
/// the folder holds no other file (a user's note, a file of another
/// layout: a `--no-effects` dataset's scenario holding `effects.csv`). The
/// checksums themselves are [`verify_scenario`]'s.
pub fn verify_layout(dir: &Path, layout: &ScenarioLayout) -> Result<(), String> {
    let (listing_path, listing) = read_listing(dir)?;
    let wanted: std::collections::BTreeSet<String> = layout.files().into_iter().filter(|n| n != CHECKSUMS).collect();
    let listed: std::collections::BTreeSet<String> =
        listing.lines().filter_map(|l| l.split_once("  ").map(|(_, name)| name.to_string())).collect();
    if let Some(extra) = listed.difference(&wanted).next() {
        return Err(format!(
            "{}: lists {extra}, which is not a file of this dataset's scenarios (its manifest's products)",
            listing_path.display()
        ));
    }
    if let Some(missing) = wanted.difference(&listed).next() {
        return Err(format!("{}: does not list {missing}, a file of this dataset's scenarios", listing_path.display()));
    }
    // Every file and folder there, below the scenario's own folders too.
    let own_folders: std::collections::BTreeSet<String> = layout.folders().into_iter().collect();
    let mut folders = vec![dir.to_path_buf()];
    while let Some(folder) = folders.pop() {
        let entries = fs::read_dir(&folder).map_err(|e| format!("{}: {e}", folder.display()))?;
        for entry in entries {
            let entry = entry.map_err(|e| format!("{}: {e}", folder.display()))?;
            let path = entry.path();
            let name = path.strip_prefix(dir).unwrap_or(&path).to_string_lossy().into_owned();
            if entry.file_type().is_ok_and(|t| t.is_dir()) {
                if !own_folders.contains(&name) {
                    return Err(format!(
                        "{}: not a folder of the scenario (the dataset's layout): move it out of the dataset",
                        path.display()
                    ));
                }
                folders.push(path);
                continue;
            }
            if name != CHECKSUMS && !listed.contains(&name) {
                return Err(format!(
                    "{}: not a file of the scenario (not in its {CHECKSUMS}): move it out of the dataset",
                    path.display()
                ));
            }
        }
    }
    Ok(())
}

/// Checks a finished scenario folder against its `checksums.sha256`: the
/// listing is there and every file it lists is there with its hash, none
/// of them through a symbolic link. Says
/// what is wrong otherwise (a rerun rewrites such a scenario; `merge`
/// refuses it).
pub fn verify_scenario(dir: &Path) -> Result<(), String> {
    let (listing_path, listing) = read_listing(dir)?;
    let mut listed = 0usize;
    for line in listing.lines() {
        let Some((hash, name)) = line.split_once("  ") else {
            return Err(format!("{}: {line:?} is not a checksum line", listing_path.display()));
        };
        if name.contains("..") || name.starts_with('/') {
            return Err(format!("{}: {name:?} is not a file of the scenario", listing_path.display()));
        }
        check_listed(dir, name, hash)?;
        listed += 1;
    }
    if listed == 0 {
        return Err(format!("{}: lists no files", listing_path.display()));
    }
    Ok(())
}
