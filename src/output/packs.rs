//! Tar packs (`gen --format tar`): whole scenarios, a fixed number at a
//! time, in WebDataset-style tar files, so that a dataset of millions of
//! scenarios is thousands of files on a cluster file system.
//!
//! A pack holds consecutive scenarios of one group and split and lives in
//! that split's folder, named by the indices it holds:
//! `<group>/<split>/<first>-<last>.tar` (`cars08_edges50/train/00000-00063.tar`).
//! Its members are named as in the folder layout, relative to the dataset
//! (`cars08_edges50/train/00012/poses.csv`), scenario after scenario, each
//! scenario's files in name order, `checksums.sha256` among them, with the
//! same bytes. So `tar -xf P -C OUT` gives the folders `--format folders`
//! writes, byte for byte. Headers carry nothing that depends on the run
//! (mode 0644, owner 0, time 0): packs are byte-identical too.
//!
//! A `counterfactual --sweep --format tar` packs its pairs the same way:
//! each pair folder's `factual/` and `counterfactual/` runs (each by its
//! own checksum listing), `divergence.csv` and `summary.json`.

use super::{fresh_partial, hex, io_err, scenario_dir, WriteError, CHECKSUMS};
use crate::plan::expand::split_of;
use crate::plan::{KeySequence, ScenarioKey};
use crate::spec::Split;
use sha2::{Digest, Sha256};
use std::collections::BTreeMap;
use std::fs;
use std::io::{BufReader, BufWriter, Read, Write};
use std::ops::Range;
use std::path::{Path, PathBuf};

/// One tar's share of the dataset: consecutive scenarios of one group and
/// split.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Pack {
    pub group_index: usize,
    pub split: Split,
    /// Index (within its group and split) of its first scenario.
    pub first: u32,
    pub count: u32,
    /// Positions of its scenarios in the dataset's key order.
    pub positions: Range<usize>,
}

/// The packs of a dataset, in key order, computed from their number and
/// never listed: the same memory for ten scenarios as for ten million.
#[derive(Debug, Clone, Copy)]
pub struct Packs<'a> {
    sequence: KeySequence<'a>,
    per_tar: u64,
    /// Packs per group of each split of [`Split::ALL`].
    per_split: [u64; 3],
}

impl<'a> Packs<'a> {
    /// `per_tar` scenarios per pack (at least one).
    pub fn new(sequence: KeySequence<'a>, per_tar: u32) -> Packs<'a> {
        let per_tar = u64::from(per_tar.max(1));
        let per_split = Split::ALL.map(|s| (sequence.split_len(s) as u64).div_ceil(per_tar));
        Packs { sequence, per_tar, per_split }
    }

    pub fn len(&self) -> usize {
        (self.sequence.groups() as u64 * self.per_split.iter().sum::<u64>()) as usize
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The pack at `number` (`number < len()`).
    pub fn pack(&self, number: usize) -> Pack {
        let per_group: u64 = self.per_split.iter().sum();
        let group_index = (number as u64 / per_group) as usize;
        let (split, within) = split_of(number as u64 % per_group, &self.per_split);
        self.starting_at(group_index, split, within * self.per_tar)
    }

    /// The pack holding the scenario at `position`.
    pub fn of_position(&self, position: usize) -> Pack {
        let key = self.sequence.key(position);
        self.starting_at(key.group_index, key.split, u64::from(key.index) / self.per_tar * self.per_tar)
    }

    /// The numbers of the packs holding the scenarios at `positions` (not
    /// empty).
    pub fn numbers_of(&self, positions: std::ops::Range<usize>) -> std::ops::RangeInclusive<usize> {
        self.number_of(positions.start)..=self.number_of(positions.end - 1)
    }

    /// The number (see [`Packs::pack`]) of the pack holding the scenario at
    /// `position`.
    pub fn number_of(&self, position: usize) -> usize {
        let key = self.sequence.key(position);
        let per_group: u64 = self.per_split.iter().sum();
        let before: u64 = self.per_split[..key.split.index()].iter().sum();
        (key.group_index as u64 * per_group + before + u64::from(key.index) / self.per_tar) as usize
    }

    /// The pack of a group and split whose first scenario has index `first`.
    fn starting_at(&self, group_index: usize, split: Split, first: u64) -> Pack {
        let all = self.sequence.positions_of(group_index, split);
        let start = all.start + first as usize;
        let end = (start + self.per_tar as usize).min(all.end);
        Pack { group_index, split, first: first as u32, count: (end - start) as u32, positions: start..end }
    }

    /// The keys of `pack`'s scenarios, in order.
    pub fn keys(&self, pack: &Pack) -> Vec<ScenarioKey> {
        pack.positions.clone().map(|p| self.sequence.key(p)).collect()
    }

    /// Where `pack` lives in the dataset at `root`.
    pub fn path(&self, root: &Path, pack: &Pack) -> PathBuf {
        let group = self.sequence.key(pack.positions.start).group;
        root.join(group).join(pack.split.name()).join(file_name(pack.first, pack.count))
    }
}

/// `message` with each path into `scratch`, where packs of the dataset or
/// sweep at `root` were unpacked, told as where the file is: `<pack>:
/// <group>/<split>/<scenario>/<file>`, as `validate` names a file in a pack
/// (a path into a temporary folder, gone when the command ends, helps no
/// one).
pub fn name_unpacked_paths(message: String, scratch: &Path, root: &Path) -> String {
    let prefix = format!("{}/", scratch.display());
    let mut named = String::with_capacity(message.len());
    let mut rest = message.as_str();
    while let Some(at) = rest.find(&prefix) {
        named.push_str(&rest[..at]);
        let after = &rest[at + prefix.len()..];
        let end = after.find(|c: char| c == ':' || c == ',' || c.is_whitespace()).unwrap_or(after.len());
        let member = &after[..end];
        match pack_holding(root, member) {
            Some(pack) => named.push_str(&format!("{}: {member}", pack.display())),
            None => named.push_str(&format!("{} (in its tar pack)", root.join(member).display())),
        }
        rest = &after[end..];
    }
    named.push_str(rest);
    named
}

/// The pack under `root` that holds `member` (`<group>/<split>/<index>/...`):
/// the one whose name's index range takes in the scenario's.
fn pack_holding(root: &Path, member: &str) -> Option<PathBuf> {
    let mut parts = member.splitn(4, '/');
    let (group, split, scenario) = (parts.next()?, parts.next()?, parts.next()?);
    let index: u32 = scenario.parse().ok()?;
    let folder = root.join(group).join(split);
    std::fs::read_dir(&folder).ok()?.flatten().find_map(|entry| {
        let name = entry.file_name();
        let (first, last) = parse_file_name(name.to_str()?)?;
        (first..=last).contains(&index).then(|| folder.join(&name))
    })
}

/// A pack's file name: the first and last index it holds.
pub fn file_name(first: u32, count: u32) -> String {
    format!("{first:05}-{:05}.tar", first + count.max(1) - 1)
}

/// The (first, last) indices a pack's file name says it holds; `None` for
/// any other name.
pub fn parse_file_name(name: &str) -> Option<(u32, u32)> {
    let (first, last) = name.strip_suffix(".tar")?.split_once('-')?;
    let number = |s: &str| (s.len() >= 5 && s.bytes().all(|b| b.is_ascii_digit())).then(|| s.parse::<u32>().ok())?;
    let (first, last) = (number(first)?, number(last)?);
    (first <= last).then_some((first, last))
}

/// The files a finished scenario folder holds, by its checksum listing, in
/// name order (the listing among them).
fn listed_files(dir: &Path) -> Result<Vec<String>, WriteError> {
    let listing = dir.join(CHECKSUMS);
    let text = fs::read_to_string(&listing).map_err(io_err(&listing))?;
    let mut names: Vec<String> =
        text.lines().filter_map(|l| l.split_once("  ").map(|(_, name)| name.to_string())).collect();
    names.push(CHECKSUMS.to_string());
    names.sort();
    Ok(names)
}

/// The two runs of a counterfactual pair folder, each a scenario folder.
pub const PAIR_RUNS: [&str; 2] = ["factual", "counterfactual"];

/// The files a counterfactual pair folder holds beside its two runs.
pub const PAIR_FILES: [&str; 2] = ["divergence.csv", "summary.json"];

/// The files a finished counterfactual pair folder holds, in name order:
/// each run's by its checksum listing (`factual/poses.csv`, ...), and
/// [`PAIR_FILES`] (`summary.json`, written last, comes last).
fn pair_files(dir: &Path) -> Result<Vec<String>, WriteError> {
    let mut names = Vec::new();
    for run in PAIR_RUNS {
        names.extend(listed_files(&dir.join(run))?.into_iter().map(|name| format!("{run}/{name}")));
    }
    names.extend(PAIR_FILES.map(String::from));
    names.sort();
    Ok(names)
}

/// What a pack holds of each key: a scenario folder, or a counterfactual
/// pair folder.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PackUnit {
    Scenario,
    Pair,
}

impl PackUnit {
    fn files(self, dir: &Path) -> Result<Vec<String>, WriteError> {
        match self {
            PackUnit::Scenario => listed_files(dir),
            PackUnit::Pair => pair_files(dir),
        }
    }
}

/// Appends the folder `dir` to `tar` as members `<folder>/<file>`, its
/// files as `unit` lists them.
fn append_folder<W: Write>(
    tar: &mut tar::Builder<W>,
    unit: PackUnit,
    dir: &Path,
    folder: &str,
    temp: &Path,
) -> Result<(), WriteError> {
    for name in unit.files(dir)? {
        let path = dir.join(&name);
        // A regular file only: a pipe hung pack.
        let bytes = crate::input::read_data(&path).map_err(io_err(&path))?;
        let mut header = tar::Header::new_gnu();
        header.set_entry_type(tar::EntryType::Regular);
        header.set_mode(0o644);
        header.set_mtime(0);
        header.set_uid(0);
        header.set_gid(0);
        header.set_size(bytes.len() as u64);
        tar.append_data(&mut header, format!("{folder}/{name}"), &bytes[..]).map_err(io_err(temp))?;
    }
    Ok(())
}

/// A pack being written while its scenarios are: each finished scenario
/// folder is appended in key order as soon as those before it are (so
/// packing overlaps simulation), into a temporary file that
/// [`PackWriter::commit`] renames into place. The folders stay until then:
/// a run killed before the rename resumes from them. Dropped without a
/// commit, it removes its temporary file.
pub struct PackWriter {
    root: PathBuf,
    unit: PackUnit,
    keys: Vec<ScenarioKey>,
    target: PathBuf,
    temp: PathBuf,
    finished: std::sync::Mutex<Vec<bool>>,
    /// The tar and the index of the next scenario it takes; `None` once
    /// committed.
    tar: std::sync::Mutex<Option<(tar::Builder<BufWriter<fs::File>>, usize)>>,
}

type OpenTar = Option<(tar::Builder<BufWriter<fs::File>>, usize)>;

impl PackWriter {
    /// Starts the pack of `keys` (scenario folders under `root`) that will
    /// live at `target` (never written through a link there).
    pub fn begin(root: &Path, keys: Vec<ScenarioKey>, target: &Path) -> Result<PackWriter, WriteError> {
        PackWriter::begin_of(PackUnit::Scenario, root, keys, target)
    }

    /// [`PackWriter::begin`] for folders of `unit`'s kind.
    pub fn begin_of(
        unit: PackUnit,
        root: &Path,
        keys: Vec<ScenarioKey>,
        target: &Path,
    ) -> Result<PackWriter, WriteError> {
        if let Some(parent) = target.parent() {
            fs::create_dir_all(parent).map_err(io_err(parent))?;
        }
        let temp = fresh_partial(target)?;
        let file = fs::File::create(&temp).map_err(io_err(&temp))?;
        let tar = tar::Builder::new(BufWriter::with_capacity(1 << 20, file));
        Ok(PackWriter {
            root: root.to_path_buf(),
            unit,
            finished: std::sync::Mutex::new(vec![false; keys.len()]),
            keys,
            target: target.to_path_buf(),
            temp,
            tar: std::sync::Mutex::new(Some((tar, 0))),
        })
    }

    fn dir(&self, i: usize) -> PathBuf {
        let key = &self.keys[i];
        scenario_dir(&self.root, &key.group, key.split.name(), &key.folder_name())
    }

    /// Says the scenario at `i` (of the keys) is finished in its folder,
    /// and appends what can be appended, unless another thread is at it
    /// (then that thread, or `commit`, appends it).
    pub fn finished(&self, i: usize) -> Result<(), WriteError> {
        self.finished.lock().expect("a pack writer thread failed")[i] = true;
        let Ok(mut tar) = self.tar.try_lock() else { return Ok(()) };
        self.append_ready(&mut tar)
    }

    fn append_ready(&self, tar: &mut OpenTar) -> Result<(), WriteError> {
        let Some((tar, next)) = tar else { return Ok(()) };
        while *next < self.keys.len() && self.finished.lock().expect("a pack writer thread failed")[*next] {
            append_folder(tar, self.unit, &self.dir(*next), &self.keys[*next].relative_folder(), &self.temp)?;
            *next += 1;
        }
        Ok(())
    }

    /// Appends the rest (every scenario must be finished), ends the tar
    /// and renames it into place; returns its size. The folders stay.
    pub fn commit(self, fsync: bool) -> Result<u64, WriteError> {
        self.finished.lock().expect("a pack writer thread failed").iter_mut().for_each(|f| *f = true);
        let mut open = self.tar.lock().expect("a pack writer thread failed");
        self.append_ready(&mut open)?;
        let (tar, _) = open.take().expect("committed once");
        let temp = &self.temp;
        let file = tar
            .into_inner()
            .map_err(io_err(temp))?
            .into_inner()
            .map_err(|e| WriteError { path: temp.clone(), source: e.into_error() })?;
        if fsync {
            file.sync_all().map_err(io_err(temp))?;
        }
        let len = file.metadata().map_err(io_err(temp))?.len();
        fs::rename(temp, &self.target).map_err(io_err(&self.target))?;
        Ok(len)
    }
}

impl Drop for PackWriter {
    fn drop(&mut self) {
        // Not renamed into place (an error, an interruption): no half tar
        // stays. (After the rename, there is nothing at `temp`.)
        let _ = fs::remove_file(&self.temp);
    }
}

/// Reads a pack's members in order, each as its name (relative to the
/// dataset) and bytes, passing over folder entries. Refuses anything else
/// but plain files with relative names inside the dataset; errors name the
/// tar and the member.
pub fn read_members(path: &Path, each: impl FnMut(&str, Vec<u8>) -> Result<(), String>) -> Result<(), String> {
    read_members_where(path, &|_| true, each)
}

/// [`read_members`] of the members `wanted` names, seeking past the others
/// unread (a reader of the logs skips the frames' bytes).
pub fn read_members_where(
    path: &Path,
    wanted: &dyn Fn(&str) -> bool,
    each: impl FnMut(&str, Vec<u8>) -> Result<(), String>,
) -> Result<(), String> {
    read_members_noting_folders(path, wanted, each).map(|_| ())
}

/// [`read_members_where`], returning the pack's folder members with no file
/// member under them, as named in it (without the trailing `/`). `tar -cf`
/// of scenario folders lists each folder beside its files, and readers
/// pass over folder entries; but one with no file under it unpacks (`tar
/// -xf`) to an empty folder that the folder layout does not have.
fn read_members_noting_folders(
    path: &Path,
    wanted: &dyn Fn(&str) -> bool,
    mut each: impl FnMut(&str, Vec<u8>) -> Result<(), String>,
) -> Result<Vec<String>, String> {
    let (mut folders, mut holding) = (Vec::new(), std::collections::BTreeSet::new());
    let mut last_parent = String::new();
    let mut file = fs::File::open(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    ends_whole(&mut file).map_err(|e| format!("{}: {e}: the pack is damaged", path.display()))?;
    let mut archive = tar::Archive::new(Skipping(BufReader::with_capacity(1 << 20, file)));
    let bad = |e: std::io::Error| format!("{}: not a whole tar: {e}", path.display());
    for entry in archive.entries_with_seek().map_err(bad)? {
        let mut entry = entry.map_err(bad)?;
        let name = entry.path().map_err(bad)?.to_string_lossy().into_owned();
        // `tar -cf pack.tar ./group/...` names members from `./`.
        let name = match name.strip_prefix("./") {
            Some(rest) => rest.to_string(),
            None => name,
        };
        let kind = entry.header().entry_type();
        if kind.is_dir() {
            // `tar -cf` of scenario folders lists the folders too: no data.
            // (`tar -cf pack.tar .` lists the root itself as `./`.)
            let folder = name.trim_end_matches('/');
            if !folder.is_empty() && folder != "." {
                folders.push(folder.to_string());
            }
            continue;
        }
        if !kind.is_file() {
            return Err(format!(
                "{}: {name:?} is not a plain file ({kind:?}); a pack holds files only",
                path.display()
            ));
        }
        if name.starts_with('/') || name.split('/').any(|part| part == ".." || part.is_empty()) {
            return Err(format!("{}: {name:?} is not a path inside the dataset", path.display()));
        }
        // Every folder above a file holds it; scenario after scenario, most
        // files share the last one's folder.
        let parent = name.rsplit_once('/').map_or("", |(parent, _)| parent);
        if parent != last_parent {
            for (i, _) in name.match_indices('/') {
                holding.insert(name[..i].to_string());
            }
            last_parent = parent.to_string();
        }
        if !wanted(&name) {
            continue;
        }
        let mut bytes = Vec::new();
        entry.read_to_end(&mut bytes).map_err(|e| format!("{}: {name}: {e}", path.display()))?;
        each(&name, bytes)?;
    }
    folders.retain(|folder| !holding.contains(folder));
    Ok(folders)
}

/// Checks that `file` ends as every tar ends, in two empty 512-byte blocks
/// after whole blocks (a tar cut short at a member's header read as one
/// with fewer members, without a word); leaves it at its start.
fn ends_whole(file: &mut fs::File) -> Result<(), String> {
    use std::io::{Seek, SeekFrom};
    let len = file.metadata().map_err(|e| e.to_string())?.len();
    if len < 1024 || len % 512 != 0 {
        return Err(format!(
            "cut short or not a tar ({len} bytes, not whole 512-byte blocks ending in two empty ones)"
        ));
    }
    let mut end = [0u8; 1024];
    file.seek(SeekFrom::Start(len - 1024)).and_then(|_| file.read_exact(&mut end)).map_err(|e| e.to_string())?;
    if end.iter().any(|&b| b != 0) {
        return Err("cut short: it does not end in the two empty 512-byte blocks that end a tar".to_string());
    }
    file.seek(SeekFrom::Start(0)).map_err(|e| e.to_string())?;
    Ok(())
}

/// A buffered file whose forward seeks within the buffer keep it: `tar`
/// seeks past every member it skips, and `BufReader::seek` would drop the
/// buffer (and read it again) each time.
struct Skipping(BufReader<fs::File>);

impl std::io::Read for Skipping {
    fn read(&mut self, into: &mut [u8]) -> std::io::Result<usize> {
        self.0.read(into)
    }
}

impl std::io::Seek for Skipping {
    fn seek(&mut self, to: std::io::SeekFrom) -> std::io::Result<u64> {
        match to {
            std::io::SeekFrom::Current(by) => {
                self.0.seek_relative(by)?;
                self.0.stream_position()
            }
            other => self.0.seek(other),
        }
    }
}

/// A member's scenario folder (`<group>/<split>/<scenario>`) and its name
/// within that folder; `None` for a name with fewer parts.
pub fn split_member(name: &str) -> Option<(&str, &str)> {
    let at = name.match_indices('/').nth(2)?.0;
    Some((&name[..at], &name[at + 1..]))
}

/// The rule every reader holds a pack's members to, checked as they come:
/// each belongs to one of the pack's scenarios (by the pack's name), no
/// member comes twice, a scenario's members run together, and every
/// scenario has some.
struct MemberOrder<'a> {
    path: &'a Path,
    folders: BTreeMap<String, usize>,
    found: Vec<bool>,
    /// The scenario being read, and the names within it seen so far.
    current: Option<usize>,
    names: std::collections::BTreeSet<String>,
}

impl<'a> MemberOrder<'a> {
    fn new(path: &'a Path, keys: &[ScenarioKey]) -> MemberOrder<'a> {
        let folders = keys.iter().enumerate().map(|(i, k)| (k.relative_folder(), i)).collect();
        MemberOrder { path, folders, found: vec![false; keys.len()], current: None, names: Default::default() }
    }

    /// The scenario (its index in the keys) `name` belongs to, whether it
    /// is the first of that scenario's members, and its name within the
    /// scenario's folder.
    fn member<'n>(&mut self, name: &'n str) -> Result<(usize, bool, &'n str), String> {
        let path = self.path.display();
        let Some((i, within)) = split_member(name).and_then(|(f, w)| Some((*self.folders.get(f)?, w))) else {
            return Err(format!("{path}: {name} belongs to none of its scenarios (by the pack's name)"));
        };
        let first = self.current != Some(i);
        if first {
            if self.found[i] {
                return Err(format!("{path}: {name}: its scenario's members do not run together"));
            }
            self.found[i] = true;
            self.current = Some(i);
            self.names.clear();
        }
        if !self.names.insert(within.to_string()) {
            return Err(format!("{path}: {name} is in it twice"));
        }
        Ok((i, first, within))
    }

    /// The first scenario of which no member came.
    fn missing(&self) -> Option<usize> {
        self.found.iter().position(|f| !f)
    }
}

/// What [`read_scenarios`] found in a pack.
pub struct ScenariosRead {
    /// Per key, whether any member of its folder came.
    pub found: Vec<bool>,
    /// Folder members with no file member under them, as named in the pack:
    /// `tar -xf` unpacks each to an empty folder that the folder layout
    /// does not have (readers pass over folder entries).
    pub empty_folders: Vec<String>,
}

/// Reads the pack at `path` a scenario at a time: calls `each(i, members)`
/// with the members of the `i`-th of `keys`, by name within its folder, in
/// the pack's order. Refuses what [`MemberOrder`] refuses but a scenario
/// with no members.
pub fn read_scenarios(
    path: &Path,
    keys: &[ScenarioKey],
    mut each: impl FnMut(usize, BTreeMap<String, Vec<u8>>) -> Result<(), String>,
) -> Result<ScenariosRead, String> {
    let mut order = MemberOrder::new(path, keys);
    let mut current: Option<(usize, BTreeMap<String, Vec<u8>>)> = None;
    let empty_folders = read_members_noting_folders(path, &|_| true, |name, bytes| {
        let (i, first, within) = order.member(name)?;
        if first {
            if let Some((c, members)) = current.replace((i, BTreeMap::new())) {
                each(c, members)?;
            }
        }
        if let Some((_, members)) = current.as_mut() {
            members.insert(within.to_string(), bytes);
        }
        Ok(())
    })?;
    if let Some((c, members)) = current {
        each(c, members)?;
    }
    Ok(ScenariosRead { found: order.found, empty_folders })
}

/// Checks that the pack at `path` holds exactly the scenarios of `keys`,
/// each whole by its `checksums.sha256`: every file it lists, with its hash,
/// and nothing else. Says what is wrong otherwise (gen writes such a pack
/// again).
pub fn verify(path: &Path, keys: &[ScenarioKey]) -> Result<(), String> {
    verify_of(PackUnit::Scenario, path, keys)
}

/// [`verify`] of a pack of a dataset whose spec has `seed`: each scenario's
/// `scenario.json` says it is the scenario of its key
/// ([`super::scenario::check_identity`]).
pub fn verify_scenarios_of(path: &Path, keys: &[ScenarioKey], seed: u64) -> Result<(), String> {
    let read = read_scenarios(path, keys, |i, members| {
        let folder = keys[i].relative_folder();
        let json = members.get(super::layout::SCENARIO_JSON).cloned();
        verify_listed(path, &folder, members)?;
        let json =
            json.ok_or_else(|| format!("{}: {folder}/{} is missing", path.display(), super::layout::SCENARIO_JSON))?;
        super::scenario::check_identity(&json, &keys[i], seed)
            .map_err(|e| format!("{}: {folder}/{}: {e}", path.display(), super::layout::SCENARIO_JSON))
    })?;
    whole(path, keys, &read)
}

/// After a pack's scenarios were verified (`read` of `keys`): that it
/// holds every one of them, and no folder entry with no file under it.
fn whole(path: &Path, keys: &[ScenarioKey], read: &ScenariosRead) -> Result<(), String> {
    if let Some(i) = read.found.iter().position(|f| !f) {
        return Err(format!("{}: {}/{CHECKSUMS} is missing", path.display(), keys[i].relative_folder()));
    }
    match read.empty_folders.first() {
        Some(folder) => Err(format!(
            "{}: {folder}/ is a folder with no file in the pack (unpacked, an empty folder that the folder layout \
             does not have)",
            path.display()
        )),
        None => Ok(()),
    }
}

/// [`verify`] for packs of `unit`'s folders. A pair is whole when both its
/// runs are, by their listings, and it has its [`PAIR_FILES`], a summary
/// that reads, and nothing else.
pub fn verify_of(unit: PackUnit, path: &Path, keys: &[ScenarioKey]) -> Result<(), String> {
    let read = read_scenarios(path, keys, |i, members| {
        let folder = keys[i].relative_folder();
        match unit {
            PackUnit::Scenario => verify_listed(path, &folder, members),
            PackUnit::Pair => {
                let mut split = split_pair(members);
                for name in PAIR_FILES {
                    if !split.pair.contains_key(name) {
                        return Err(format!("{}: {folder}/{name} is missing", path.display()));
                    }
                }
                let summary = split.pair.remove("summary.json").unwrap_or_default();
                if let Err(e) = serde_json::from_slice::<crate::output::pair_summary::PairSummary>(&summary) {
                    return Err(format!("{}: {folder}/summary.json: not a pair summary: {e}", path.display()));
                }
                if let Some(extra) = split.pair.keys().find(|name| !PAIR_FILES.contains(&name.as_str())) {
                    return Err(format!("{}: {folder}/{extra} is not part of a pair", path.display()));
                }
                for (run, members) in PAIR_RUNS.into_iter().zip(split.runs) {
                    verify_listed(path, &format!("{folder}/{run}"), members)?;
                }
                Ok(())
            }
        }
    })?;
    whole(path, keys, &read)
}

/// A pair's members split by where they lie: each run's (by name within
/// the run, in [`PAIR_RUNS`] order), and the pair folder's own.
pub struct PairMembers {
    pub runs: [BTreeMap<String, Vec<u8>>; 2],
    pub pair: BTreeMap<String, Vec<u8>>,
}

/// Splits a pair folder's members (by name within the pair) into its runs'
/// and its own.
pub fn split_pair(members: BTreeMap<String, Vec<u8>>) -> PairMembers {
    let mut split = PairMembers { runs: [BTreeMap::new(), BTreeMap::new()], pair: BTreeMap::new() };
    for (name, bytes) in members {
        let run =
            name.split_once('/').and_then(|(run, within)| Some((PAIR_RUNS.iter().position(|r| *r == run)?, within)));
        match run {
            Some((r, within)) => {
                split.runs[r].insert(within.to_string(), bytes);
            }
            None => {
                split.pair.insert(name, bytes);
            }
        }
    }
    split
}

/// Checks that `members` (of the folder `folder`, in the pack at `path`)
/// are exactly the files its `checksums.sha256` lists, with their hashes.
fn verify_listed(path: &Path, folder: &str, mut members: BTreeMap<String, Vec<u8>>) -> Result<(), String> {
    let listing =
        members.remove(CHECKSUMS).ok_or_else(|| format!("{}: {folder}/{CHECKSUMS} is missing", path.display()))?;
    let listing =
        String::from_utf8(listing).map_err(|_| format!("{}: {folder}/{CHECKSUMS} is not text", path.display()))?;
    for line in listing.lines() {
        let (hash, name) = line
            .split_once("  ")
            .ok_or_else(|| format!("{}: {folder}/{CHECKSUMS}: {line:?} is not a checksum line", path.display()))?;
        match members.remove(name) {
            Some(bytes) if hex(&Sha256::digest(&bytes)) == hash => {}
            Some(_) => return Err(format!("{}: {folder}/{name}: its checksum does not match", path.display())),
            None => return Err(format!("{}: {folder}/{name} is missing", path.display())),
        }
    }
    match members.keys().next() {
        Some(extra) => Err(format!("{}: {folder}/{extra} is not in its {CHECKSUMS}", path.display())),
        None => Ok(()),
    }
}

/// Unpacks the pack at `path`, which holds the scenarios of `keys`, under
/// `root`: each member `keep` keeps, at its name, as `tar -xf` does. For
/// readers of scenario folders; `root` must be a folder of the reader's
/// own. Holds every member, kept or not, to [`MemberOrder`]'s rule (a
/// member twice was unpacked last copy winning; one of another scenario
/// landed beside the pack's own).
pub fn unpack(
    path: &Path,
    keys: &[ScenarioKey],
    root: &Path,
    keep: &(dyn Fn(&str) -> bool + Sync),
) -> Result<(), String> {
    let order = std::cell::RefCell::new(MemberOrder::new(path, keys));
    let refused = std::cell::RefCell::new(None);
    // A member the rule refuses is taken, so that `each` stops the read.
    let wanted = |name: &str| match order.borrow_mut().member(name) {
        Ok(_) => keep(name),
        Err(e) => {
            *refused.borrow_mut() = Some(e);
            true
        }
    };
    read_members_where(path, &wanted, |name, bytes| {
        if let Some(e) = refused.borrow_mut().take() {
            return Err(e);
        }
        let target = root.join(name);
        if let Some(parent) = target.parent() {
            fs::create_dir_all(parent).map_err(|e| format!("cannot write {}: {e}", parent.display()))?;
        }
        let mut file = fs::File::create(&target).map_err(|e| format!("cannot write {}: {e}", target.display()))?;
        file.write_all(&bytes).map_err(|e| format!("cannot write {}: {e}", target.display()))
    })?;
    let missing = order.borrow().missing();
    match missing {
        Some(i) => Err(format!(
            "{}: holds no member of {}, which its name says it holds: the pack is damaged (validate says more)",
            path.display(),
            keys[i].relative_folder()
        )),
        None => Ok(()),
    }
}

/// A private folder under the system's temporary folder (`TMPDIR`) that
/// readers unpack packs into; removed with everything in it when dropped.
#[derive(Debug)]
pub struct Scratch {
    root: PathBuf,
}

impl Scratch {
    /// Makes a new, empty folder only this user can read.
    pub fn new() -> Result<Scratch, String> {
        use std::sync::atomic::{AtomicU64, Ordering};
        static MADE: AtomicU64 = AtomicU64::new(0);
        let base = std::env::temp_dir();
        for _ in 0..100 {
            let nanos =
                std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.subsec_nanos());
            let n = MADE.fetch_add(1, Ordering::Relaxed);
            let prefix = crate::error::UNPACK_FOLDER_PREFIX;
            let root = base.join(format!("{prefix}{}-{n}-{nanos}", std::process::id()));
            let mut builder = fs::DirBuilder::new();
            #[cfg(unix)]
            std::os::unix::fs::DirBuilderExt::mode(&mut builder, 0o700);
            match builder.create(&root) {
                Ok(()) => return Ok(Scratch { root }),
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
                Err(e) => return Err(format!("cannot make a folder to unpack into in {}: {e}", base.display())),
            }
        }
        Err(format!("cannot make a folder to unpack into in {}", base.display()))
    }

    pub fn path(&self) -> &Path {
        &self.root
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = fs::remove_dir_all(&self.root);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_path_into_the_unpacked_folder_is_named_by_its_pack_and_member() {
        let base = std::env::temp_dir().join(format!("causalcity-name-unpacked-{}", std::process::id()));
        let (root, scratch) = (base.join("data"), base.join("scratch"));
        let split = root.join("cars04_edges50/test");
        std::fs::create_dir_all(&split).unwrap();
        for name in ["00000-00001.tar", "00002-00003.tar"] {
            std::fs::write(split.join(name), b"").unwrap();
        }
        let message = format!(
            "{}/cars04_edges50/test/00003/counterfactual/poses.csv: row 2 is not a pose; {}/cars04_edges50/val/00000",
            scratch.display(),
            scratch.display()
        );
        let named = name_unpacked_paths(message, &scratch, &root);
        assert_eq!(
            named,
            format!(
                "{}: cars04_edges50/test/00003/counterfactual/poses.csv: row 2 is not a pose; {} (in its tar pack)",
                split.join("00002-00003.tar").display(),
                root.join("cars04_edges50/val/00000").display()
            )
        );
        assert!(!named.contains(&scratch.display().to_string()));
        std::fs::remove_dir_all(&base).unwrap();
    }

    #[test]
    fn pack_names_say_which_indices_they_hold_and_nothing_else_parses() {
        assert_eq!(file_name(0, 64), "00000-00063.tar");
        assert_eq!(file_name(128, 7), "00128-00134.tar");
        assert_eq!(parse_file_name("00128-00134.tar"), Some((128, 134)));
        assert_eq!(parse_file_name("123456-123460.tar"), Some((123456, 123460)));
        for other in ["00001.tar", "0001-00002.tar", "00002-00001.tar", "00000-00063.tar.partial", "a0000-00001.tar"] {
            assert_eq!(parse_file_name(other), None, "{other}");
        }
    }

    #[test]
    fn every_scenario_is_in_exactly_the_pack_its_number_names() {
        let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/configs/ci-toy.json")).unwrap();
        let spec = crate::spec::DatasetSpec::from_json(&text).unwrap();
        let expansion = crate::plan::Expansion::new(spec, std::sync::Arc::new(crate::map::CityMap::default())).unwrap();
        // 5 groups of 2 + 1 + 1 scenarios; 2 per tar: packs of 2, 1, 1 per group.
        let packs = Packs::new(expansion.key_sequence(None), 2);
        assert_eq!(packs.len(), 15);
        let mut seen = vec![0; expansion.key_sequence(None).len()];
        for number in 0..packs.len() {
            let pack = packs.pack(number);
            for position in pack.positions.clone() {
                assert_eq!(packs.number_of(position), number, "position {position}");
                assert_eq!(packs.of_position(position).positions, pack.positions);
                seen[position] += 1;
            }
        }
        assert_eq!(seen, vec![1; 20], "each scenario in one pack");
    }
}
