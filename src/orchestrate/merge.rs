//! `causalcity merge`: turns the outputs of `gen --shard K/N` runs into one
//! dataset with one manifest, byte for byte what an unsharded run writes.
//! Shards may have written into one shared folder or into folders of their
//! own; either way the shard manifests say what each contains.

use super::run::GenError;
use crate::output::claim::{claim, ClaimError, Writer};
use crate::output::layout::ScenarioLayout;
use crate::output::manifest::{Manifest, ManifestRecord, Packing};
use crate::output::packs::Packs;
use crate::output::{
    io_err, scenario_dir, verify_layout, verify_scenario_of, write_atomically, CHECKSUMS, PARTIAL_PREFIX,
};
use crate::plan::KeySequence;
use rayon::prelude::*;
use std::collections::BTreeSet;
use std::fs;
use std::path::{Path, PathBuf};

/// Shard manifests found in `dir/shards/`.
fn shard_manifests(dir: &Path) -> Result<Vec<(PathBuf, ManifestRecord)>, GenError> {
    let mut found = Vec::new();
    let Ok(entries) = fs::read_dir(dir.join("shards")) else { return Ok(found) };
    let mut paths: Vec<PathBuf> = entries.filter_map(|e| e.ok().map(|e| e.path())).collect();
    paths.sort();
    for path in paths.into_iter().filter(|p| p.extension().is_some_and(|e| e == "json")) {
        if let Some(record) = ManifestRecord::read(&path).map_err(GenError::Manifest)? {
            if record.shard.is_some() {
                found.push((path, record));
            }
        }
    }
    Ok(found)
}

/// Copies a scenario folder (files, rgb/, mask/) when it cannot be renamed.
fn copy_tree(from: &Path, to: &Path) -> std::io::Result<()> {
    fs::create_dir_all(to)?;
    for entry in fs::read_dir(from)? {
        let entry = entry?;
        let target = to.join(entry.file_name());
        if entry.file_type()?.is_dir() {
            copy_tree(&entry.path(), &target)?;
        } else {
            fs::copy(entry.path(), target)?;
        }
    }
    Ok(())
}

/// Merges shard outputs in `sources` (and any already in `out`) into `out`.
pub fn merge(out: &Path, sources: &[PathBuf]) -> Result<String, GenError> {
    // A merge run again after it finished (a retried cluster task): its
    // shard folders are gone into --out, which is complete. Said, and done
    // (it was refused, exit 2, and a retrying scheduler saw a failure).
    let merged = ManifestRecord::read(&out.join("manifest.json")).ok().flatten().is_some_and(|m| m.complete)
        && !out.join("shards").exists();
    // (Shards that wrote into --out itself leave no folders to name.)
    if merged && sources.iter().all(|s| fs::symlink_metadata(s).is_err()) {
        let gone = if sources.is_empty() { "" } else { ", and the shard folders are gone into it" };
        return Ok(format!("nothing to merge: {} holds the complete dataset{gone} (merged before)", out.display()));
    }
    if let Some(finished) = finish_cut_off_merge(out, sources)? {
        return Ok(finished);
    }
    for (i, source) in sources.iter().enumerate() {
        if !source.is_dir() {
            let hint = match merged {
                true => format!(" ({} already holds a complete dataset: merged before?)", out.display()),
                false => String::new(),
            };
            return Err(GenError::Input(format!("{} is not a folder{hint}", source.display())));
        }
        let real = crate::output::claim::resolve(source);
        if let Some(twin) = sources[..i].iter().find(|s| crate::output::claim::resolve(s) == real) {
            return Err(GenError::Input(format!(
                "{} is given twice (as {} and {}): name each shard folder once; nothing was moved",
                real.display(),
                twin.display(),
                source.display()
            )));
        }
    }
    // No shard may still be running, and --out takes nothing but a dataset.
    let _claim = claim(out, Writer::Merge, "merge").map_err(GenError::Claim)?;
    // What a `gen --force` cut off left aside (shards running skip it).
    super::run::finish_removal(out)?;
    let others: Vec<&PathBuf> = sources.iter().filter(|s| real_paths(s, out).is_none_or(|(s, out)| s != out)).collect();
    let mut source_claims = Vec::new();
    let mut manifests = shard_manifests(out)?;
    for source in &others {
        // A shard folder is emptied and removed, so it may hold nothing of
        // the user's: said as the shard's, not as --out's ("Use another --out").
        let claimed = claim(source, Writer::Merge, "merge").map_err(|e| match e {
            ClaimError::Foreign { dir, what, .. } => GenError::Input(format!(
                "{} (a shard to merge) holds {what}: merge moves a shard's scenarios out and removes its folder, \
                 so it holds only what `gen --shard` wrote. Move the rest out of it, then rerun; nothing was moved",
                dir.display()
            )),
            other => GenError::Claim(other),
        })?;
        source_claims.push(claimed);
        let found = shard_manifests(source)?;
        if found.is_empty() {
            return Err(GenError::Input(format!(
                "{} holds no shard manifest (shards/K-of-N.json): it is no `gen --shard K/N` output; nothing was moved",
                source.display()
            )));
        }
        manifests.extend(found);
    }
    let Some((_, first)) = manifests.first().cloned() else {
        return Err(GenError::Input(format!(
            "no shard manifests (shards/K-of-N.json) in {}{}: run `causalcity gen --shard K/N` first",
            out.display(),
            if others.is_empty() { "" } else { " or the shard folders given" }
        )));
    };

    // Every shard must come from the same spec, version and settings.
    let count = first.shard.expect("shard manifests carry their shard").count;
    for (path, record) in &manifests {
        let shard = record.shard.expect("shard manifests carry their shard");
        if shard.index >= shard.count {
            return Err(GenError::Input(format!(
                "{}: shard index {} is not allowed: a shard of {} is numbered 0 to {}; nothing was moved",
                path.display(),
                shard.index,
                shard.count,
                shard.count.saturating_sub(1)
            )));
        }
        let differences = record.shard_differences(&first, ("here", "in the first"));
        if !differences.is_empty() {
            return Err(GenError::Input(format!(
                "{} belongs to another dataset than {}: {}; nothing was moved",
                path.display(),
                manifests[0].0.display(),
                differences.join("; ")
            )));
        }
    }
    let present: BTreeSet<u32> = manifests.iter().map(|(_, r)| r.shard.expect("shard").index).collect();
    // Counted, and the first few named: a count of 2^32 - 1 lists no more.
    let missing = count as usize - present.len();
    if missing > 0 {
        let first: Vec<String> = (0..count).filter(|i| !present.contains(i)).take(10).map(|i| i.to_string()).collect();
        let more = if missing > first.len() { format!(" and {} more", missing - first.len()) } else { String::new() };
        return Err(GenError::Input(format!(
            "shard{} {}{more} of {count} {} missing: run `causalcity gen --shard K/{count}` for {}",
            if missing == 1 { "" } else { "s" },
            first.join(", "),
            if missing == 1 { "is" } else { "are" },
            if missing == 1 { "it" } else { "them" }
        )));
    }
    let incomplete: Vec<String> =
        manifests.iter().filter(|(_, r)| !r.complete).map(|(_, r)| r.shard.expect("shard").index.to_string()).collect();
    if !incomplete.is_empty() {
        return Err(GenError::Input(format!(
            "{} did not finish: rerun {} to resume {}",
            if incomplete.len() == 1 {
                format!("shard {}", incomplete[0])
            } else {
                format!("shards {}", incomplete.join(", "))
            },
            if incomplete.len() == 1 { "its gen command" } else { "their gen commands" },
            if incomplete.len() == 1 { "it" } else { "them" }
        )));
    }
    if let Some(existing) = ManifestRecord::read(&out.join("manifest.json")).map_err(GenError::Manifest)? {
        // The dataset there and the shards' must be one in every option:
        // shards of --limit 1 merged into a whole dataset rewrote its
        // manifest with that limit, leaving most of it unlisted.
        let mut differences = existing.shard_differences(&first, ("there", "in the shards"));
        differences.retain(|d| !d.starts_with("shard count"));
        if !differences.is_empty() {
            return Err(GenError::Input(format!(
                "{} already holds another dataset ({}): merge into an empty folder; nothing was moved",
                out.display(),
                differences.join("; ")
            )));
        }
    }

    // The spec with its networks, from the first shard folder whose copies
    // read whole (each shard keeps one); none: bad input, nothing moved.
    // A copy that is a link is never read through (merge moves and removes
    // what is in the shard folders).
    let mut named: Option<crate::spec::DatasetSpec> = serde_json::from_value(first.spec.clone()).ok();
    let mut linked = |path: &Path| -> Option<PathBuf> {
        let root = path.parent().and_then(Path::parent).unwrap_or(Path::new("."));
        let copies = named.as_mut()?.network_copies(root);
        copies.into_iter().find(|c| fs::symlink_metadata(c).is_ok_and(|m| m.is_symlink()))
    };
    let mut expansions = manifests.iter().map(|(path, _)| match linked(path) {
        Some(link) => Err(format!(
            "{} is a link: a shard keeps its own copy of each network, and merge never reads through a link; put \
             the file itself there",
            link.display()
        )),
        None => crate::dataset::expansion_of(&first, path),
    });
    let first_error = match expansions.next().expect("a manifest, found above") {
        Ok(expansion) => Ok(expansion),
        Err(e) => expansions.find_map(Result::ok).ok_or(e),
    };
    let expansion = first_error.map_err(|e| GenError::Input(format!("{e}; nothing was moved")))?;
    // Keys are walked, never listed, and every pass below holds one chunk
    // of scenarios at a time: merging takes the same memory for ten
    // scenarios as for ten million.
    let sequence = expansion.key_sequence(first.limit);
    // Scenarios move out of the shard folders and into --out: never through
    // a link in either.
    for folder in std::iter::once(out).chain(others.iter().map(|p| p.as_path())) {
        super::run::refuse_linked_splits(folder, &expansion.spec)?;
    }
    // Once every scenario is checked and before the first moves, --out
    // holds every shard manifest: a merge cut off part way leaves a shard
    // folder (as shards writing into one folder make) that the same merge
    // command finishes, the scenarios already moved found in place.
    let mark_out = || keep_shard_manifests(out, &manifests);
    let (moved, already) = match first.packing() {
        Packing::Folders => {
            // The files every scenario holds, by the shards' products.
            let layout = ScenarioLayout::of_spec(&expansion.spec, first.products());
            merge_folders(out, &others, &sequence, (expansion.spec.seed, &layout), &mark_out)?
        }
        Packing::Tar { per_tar } => {
            merge_packs(out, &others, Packs::new(sequence, per_tar), expansion.spec.seed, &mark_out)?
        }
    };
    // The networks the spec names (read from the first shard's folder).
    super::run::keep_networks(&expansion.spec, out)?;
    let manifest = Manifest::new(
        &expansion.spec,
        &expansion.camera,
        first.effective_limit(),
        first.products(),
        first.packing(),
        true,
        None,
    )
    .to_json();
    write_atomically(&out.join("manifest.json"), &manifest)?;
    // The shard manifests: the shard folders' first, then their copies in
    // --out (the last to go, so that a merge cut off in between is still
    // finished by running it again).
    let copies: Vec<PathBuf> = manifests
        .iter()
        .map(|(path, _)| out.join("shards").join(path.file_name().expect("a shard manifest is a file")))
        .collect();
    let originals = manifests.iter().map(|(path, _)| path).filter(|path| !copies.contains(path));
    for manifest in originals.chain(&copies) {
        if fs::symlink_metadata(manifest).is_ok() {
            fs::remove_file(manifest).map_err(io_err(manifest))?;
        }
        if let Some(dir) = manifest.parent() {
            let _ = fs::remove_dir(dir); // only when empty
        }
    }
    // The shards' folder trees the scenarios left: empty split and group
    // folders go, and a shard folder that holds nothing else (once its
    // lock file has gone with its claim).
    drop(source_claims);
    for source in &others {
        for group in &expansion.spec.groups {
            let group = source.join(group.name());
            for split in crate::spec::Split::ALL {
                let _ = fs::remove_dir(group.join(split.name())); // only when empty
            }
            let _ = fs::remove_dir(&group);
        }
        let _ = remove_emptied_shard(source);
    }
    // A shard folder's copies of the networks, now kept in --out: its
    // networks/ goes when it holds those alone, then the folder if empty.
    // (Not --out's own, when it is given as a source too.)
    for source in &others {
        let folder = source.join(crate::spec::NETWORKS_FOLDER);
        if !fs::symlink_metadata(&folder).is_ok_and(|m| m.is_dir()) {
            continue;
        }
        for (name, network) in expansion.spec.networks() {
            let copy = folder.join(name);
            // A link there is left alone, never read through.
            if crate::output::holds_bytes(&copy, &network.bytes) {
                fs::remove_file(&copy).map_err(io_err(&copy))?;
            }
        }
        if fs::remove_dir(&folder).is_ok() {
            let _ = remove_emptied_shard(source);
        }
    }
    // (A packed dataset moves whole tar files: they were counted as scenarios.)
    let (moved_what, dropped_what) = match first.packing() {
        Packing::Folders => ("", "duplicates"),
        Packing::Tar { .. } => (" tar files", "duplicate tar files"),
    };
    Ok(format!(
        "merged {count} shards into {}: {} scenarios ({moved}{moved_what} moved, {already} {dropped_what} dropped); \
         wrote manifest.json",
        out.display(),
        sequence.len()
    ))
}

/// A merge cut off after it wrote `out`'s complete manifest, its last
/// step before removing the shard manifests and the emptied shard folders:
/// run again, it was refused ("holds group folders but no manifest.json",
/// or "is not a folder") and left them for good. Finished when every shard
/// manifest left (in `out/shards/` and in `sources`) is one of the dataset
/// `out` completes, and each shard folder holds nothing else but empty
/// folders, lock files and copies of `out`'s networks; anything else is
/// left to the merge's own checks.
fn finish_cut_off_merge(out: &Path, sources: &[PathBuf]) -> Result<Option<String>, GenError> {
    let Some(done) = ManifestRecord::read(&out.join("manifest.json")).ok().flatten().filter(|m| m.complete) else {
        return Ok(None);
    };
    let ours = |found: &[(PathBuf, ManifestRecord)]| {
        found.iter().all(|(_, r)| {
            r.complete && r.shard_differences(&done, ("", "")).iter().all(|d| d.starts_with("shard count"))
        })
    };
    let copies = shard_manifests(out).unwrap_or_default();
    if !ours(&copies) {
        return Ok(None);
    }
    let mut folders = Vec::new();
    for source in sources.iter().filter(|s| fs::symlink_metadata(s).is_ok()) {
        // (A folder inside --out is the dataset's own, never a shard's leftover.)
        let inside = real_paths(source, out).is_some_and(|(source, out)| source.starts_with(out));
        // (A shard named through a link to its folder, as merge takes it.)
        if !source.is_dir() || inside {
            return Ok(None);
        }
        folders.push(source);
    }
    // What each shard folder holds, looked at before anything is locked
    // (most merges are no such case) and again under the locks.
    let leftovers_of = |source: &Path| -> Option<Vec<PathBuf>> {
        let found = shard_manifests(source).ok()?;
        if !ours(&found) {
            return None;
        }
        let manifests: Vec<PathBuf> = found.into_iter().map(|(path, _)| path).collect();
        let mut files = Vec::new();
        only_merge_leftovers(out, source, source, &manifests, &mut files).then_some(files)
    };
    if folders.iter().any(|s| leftovers_of(s).is_none()) || (folders.is_empty() && copies.is_empty()) {
        return Ok(None);
    }
    let _claim = claim(out, Writer::Merge, "merge").map_err(GenError::Claim)?;
    let mut locked = Vec::new();
    for source in &folders {
        locked.push(crate::output::claim::lock_only(source, "merge").map_err(GenError::Claim)?);
    }
    let mut leftovers = Vec::new();
    for source in &folders {
        let Some(files) = leftovers_of(source) else { return Ok(None) };
        leftovers.push((source, files));
    }
    for (source, files) in &leftovers {
        for file in files {
            fs::remove_file(file).map_err(io_err(file))?;
        }
        remove_empty_folders(source);
    }
    // The locks go (their files with them, and a killed shard's), then the
    // emptied folders.
    drop(locked);
    for (source, _) in &leftovers {
        remove_emptied_shard(source).map_err(io_err(source))?;
    }
    for (copy, _) in &copies {
        fs::remove_file(copy).map_err(io_err(copy))?;
    }
    let _ = fs::remove_dir(out.join("shards")); // only when empty
    let folders: Vec<String> = leftovers.iter().map(|(s, _)| s.display().to_string()).collect();
    let removed =
        copies.len() + leftovers.iter().map(|(_, f)| f.iter().filter(|p| is_shard_manifest(p)).count()).sum::<usize>();
    Ok(Some(format!(
        "nothing to merge: {} holds the complete dataset (merged before); finished what the merge cut off left: \
         removed {removed} shard manifest{}{}",
        out.display(),
        if removed == 1 { "" } else { "s" },
        match folders.len() {
            0 => String::new(),
            1 => format!(" and the emptied shard folder {}", folders[0]),
            _ => format!(" and the emptied shard folders {}", folders.join(", ")),
        }
    )))
}

/// Whether `path` lies in a `shards/` folder.
fn is_shard_manifest(path: &Path) -> bool {
    path.parent().and_then(Path::file_name).is_some_and(|n| n == "shards")
}

/// Whether `dir` (under the shard folder `root`) holds nothing but
/// folders, lock files, the shard manifests `manifests` and copies of
/// `out`'s networks; the files to remove (not the locks) go to `files`.
/// A link is never followed: it is not a leftover.
fn only_merge_leftovers(out: &Path, root: &Path, dir: &Path, manifests: &[PathBuf], files: &mut Vec<PathBuf>) -> bool {
    let Ok(entries) = fs::read_dir(dir) else { return false };
    for entry in entries {
        let Ok(entry) = entry else { return false };
        let path = entry.path();
        let Ok(kind) = entry.file_type() else { return false };
        let name = entry.file_name().to_string_lossy().into_owned();
        if kind.is_dir() {
            if !only_merge_leftovers(out, root, &path, manifests, files) {
                return false;
            }
        } else if !kind.is_file() {
            return false;
        } else if dir == root && crate::output::claim::is_lock_file(&name) {
            // (the claim takes it)
        } else if manifests.contains(&path)
            || (dir == root.join(crate::spec::NETWORKS_FOLDER) && kept_in(out, &path, &name))
        {
            files.push(path);
        } else {
            return false;
        }
    }
    true
}

/// Whether the network file at `path` has the bytes of `out`'s own copy
/// named `name`: a file of its own there, never a link (which may lead
/// back to `path`, the dataset's only copy) nor `path` itself.
fn kept_in(out: &Path, path: &Path, name: &str) -> bool {
    use std::os::unix::fs::MetadataExt;
    let folder = out.join(crate::spec::NETWORKS_FOLDER);
    let copy = folder.join(name);
    let (Ok(kept), Ok(here), Ok(networks)) =
        (fs::symlink_metadata(&copy), fs::symlink_metadata(path), fs::symlink_metadata(&folder))
    else {
        return false;
    };
    networks.is_dir()
        && kept.is_file()
        && (kept.dev(), kept.ino()) != (here.dev(), here.ino())
        && same_bytes(path, &copy)
}

/// Removes the empty folders below `dir`, deepest first (never a file).
fn remove_empty_folders(dir: &Path) {
    for entry in fs::read_dir(dir).into_iter().flatten().flatten() {
        if entry.file_type().is_ok_and(|k| k.is_dir()) {
            remove_empty_folders(&entry.path());
            let _ = fs::remove_dir(entry.path());
        }
    }
}

/// Copies into `out/shards/` each shard manifest of `manifests` that it
/// lacks (never through a link).
fn keep_shard_manifests(out: &Path, manifests: &[(PathBuf, ManifestRecord)]) -> Result<(), GenError> {
    let folder = out.join("shards");
    for (path, _) in manifests {
        let target = folder.join(path.file_name().expect("a shard manifest is a file"));
        if fs::symlink_metadata(&target).is_ok() {
            continue;
        }
        crate::output::refuse_links_below(out, &target).map_err(|why| GenError::Input(why.to_string()))?;
        fs::create_dir_all(&folder).map_err(io_err(&folder))?;
        write_atomically(&target, &crate::input::read_record(path).map_err(io_err(path))?)?;
    }
    Ok(())
}

/// Whether a scenario folder or pack `path` in the dataset or shard folder
/// `root` is there (`kind` says what counts); a link there is refused:
/// merge never takes one as the scenario already in place, nor moves,
/// reads or removes anything through it.
fn there(root: &Path, path: &Path, kind: impl Fn(&fs::Metadata) -> bool) -> Result<bool, GenError> {
    let metadata = fs::symlink_metadata(path);
    if metadata.as_ref().is_ok_and(|m| m.file_type().is_symlink()) {
        crate::output::refuse_links_below(root, path).map_err(|why| GenError::Input(why.to_string()))?;
    }
    Ok(metadata.is_ok_and(|m| !m.file_type().is_symlink() && kind(&m)))
}

/// Moves every scenario folder into `out` from the shard folders
/// `others` (checked first, all of them); returns how many moved and how
/// many duplicate copies were dropped.
fn merge_folders(
    out: &Path,
    others: &[&PathBuf],
    sequence: &KeySequence<'_>,
    (seed, layout): (u64, &ScenarioLayout),
    before_moving: &dyn Fn() -> Result<(), GenError>,
) -> Result<(usize, usize), GenError> {
    // Where the scenario at `position` is; with `compare`, copies of it in
    // two folders must hold the same checksums.
    let locate = |position: usize, compare: bool| -> Result<Located, GenError> {
        let key = sequence.key(position);
        let to = scenario_dir(out, &key.group, key.split.name(), &key.folder_name());
        let found = there(out, &to, |m| m.is_dir())?.then(|| to.clone());
        let mut located = Located { found, to, moved: false, duplicates: Vec::new() };
        for source in others {
            let from = scenario_dir(source, &key.group, key.split.name(), &key.folder_name());
            if !there(source, &from, |m| m.is_dir())? {
                continue;
            }
            match &located.found {
                Some(first) => {
                    let (a, b) = (fs::read(from.join(CHECKSUMS)).ok(), fs::read(first.join(CHECKSUMS)).ok());
                    if compare && (a.is_none() || a != b) {
                        return Err(GenError::Input(format!(
                            "{} and {} hold the same scenario with different contents; nothing was moved",
                            from.display(),
                            first.display()
                        )));
                    }
                    located.duplicates.push(from);
                }
                None => {
                    located.found = Some(from);
                    located.moved = true;
                }
            }
        }
        Ok(located)
    };

    // Check every scenario before anything moves, a chunk at a time, each
    // chunk's results read in key order (so the first problem named is the
    // same on any thread count): first that each is in --out or in a shard
    // folder and that copies of one scenario agree (cheap), then that its
    // files are there and match its checksums (every byte read).
    let chunks =
        || (0..sequence.len()).step_by(MERGE_CHUNK).map(|start| start..(start + MERGE_CHUNK).min(sequence.len()));
    let (mut absent, mut first_absent) = (0usize, Vec::new());
    for chunk in chunks() {
        let located: Vec<Result<Located, GenError>> =
            chunk.clone().into_par_iter().map(|position| locate(position, true)).collect();
        for (position, located) in chunk.zip(located) {
            if located?.found.is_none() {
                absent += 1;
                if first_absent.len() < 3 {
                    let key = sequence.key(position);
                    first_absent.push(format!("{}/{}/{}", key.group, key.split.name(), key.folder_name()));
                }
            }
        }
    }
    if absent > 0 {
        return Err(GenError::Input(format!(
            "{absent} scenarios are in no shard (first: {}): were all shard folders given? Nothing was moved",
            first_absent.join(", ")
        )));
    }
    let (mut damaged, mut first_damaged) = (0usize, None);
    for chunk in chunks() {
        let broken: Vec<Option<String>> = chunk
            .into_par_iter()
            .map(|position| {
                let located = locate(position, false).ok()?;
                let key = sequence.key(position);
                located
                    .found
                    .as_deref()
                    .and_then(|dir| verify_scenario_of(dir, &key, seed).and_then(|()| verify_layout(dir, layout)).err())
            })
            .collect();
        for broken in broken.into_iter().flatten() {
            damaged += 1;
            first_damaged.get_or_insert(broken);
        }
    }
    if let Some(first_damaged) = first_damaged {
        return Err(GenError::Input(format!(
            "{damaged} scenarios are damaged or hold what is not theirs (first: {first_damaged}): rerun their shards' gen \
             commands, which rewrite damaged scenarios, and move out any file that is not the scenario's; nothing was \
             moved"
        )));
    }

    // Move every scenario into place, and drop the copies of those already
    // there (checked above: the copy kept is whole), scenario by scenario.
    before_moving()?;
    let (mut moved, mut already) = (0, 0);
    for position in 0..sequence.len() {
        let located = locate(position, false)?;
        if let (true, Some(from)) = (located.moved, &located.found) {
            let to = &located.to;
            let parent = to.parent().expect("scenario folders have parents");
            fs::create_dir_all(parent).map_err(io_err(parent))?;
            if fs::rename(from, to).is_err() {
                // Another filesystem: copy, then remove the source.
                let name = to.file_name().unwrap_or_default().to_string_lossy();
                let partial = parent.join(format!("{PARTIAL_PREFIX}{name}"));
                copy_tree(from, &partial).map_err(io_err(&partial))?;
                fs::rename(&partial, to).map_err(io_err(to))?;
                fs::remove_dir_all(from).map_err(io_err(from))?;
            }
            moved += 1;
        }
        for from in &located.duplicates {
            fs::remove_dir_all(from).map_err(io_err(from))?;
            already += 1;
        }
    }
    Ok((moved, already))
}

/// Moves every pack into `out` from the shard folders `others` (checked
/// first, all of them: each pack somewhere, copies alike, each whole);
/// returns how many moved and how many duplicate copies were dropped.
fn merge_packs(
    out: &Path,
    others: &[&PathBuf],
    packs: Packs<'_>,
    seed: u64,
    before_moving: &dyn Fn() -> Result<(), GenError>,
) -> Result<(usize, usize), GenError> {
    // Where pack `number` is: (its place in --out, the copy kept, whether
    // that copy moves, other copies to drop).
    let locate = |number: usize, compare: bool| -> Result<(PathBuf, Option<PathBuf>, bool, Vec<PathBuf>), GenError> {
        let pack = packs.pack(number);
        let to = packs.path(out, &pack);
        let (mut found, mut moved, mut duplicates) =
            (there(out, &to, |m| m.is_file())?.then(|| to.clone()), false, Vec::new());
        for source in others {
            let from = packs.path(source, &pack);
            if !there(source, &from, |m| m.is_file())? {
                continue;
            }
            match &found {
                Some(first) => {
                    if compare && !same_bytes(&from, first) {
                        return Err(GenError::Input(format!(
                            "{} and {} hold the same pack with different contents; nothing was moved",
                            from.display(),
                            first.display()
                        )));
                    }
                    duplicates.push(from);
                }
                None => {
                    found = Some(from);
                    moved = true;
                }
            }
        }
        Ok((to, found, moved, duplicates))
    };
    let (mut absent, mut first_absent) = (0usize, Vec::new());
    for number in 0..packs.len() {
        let (to, found, ..) = locate(number, true)?;
        if found.is_none() {
            absent += 1;
            if first_absent.len() < 3 {
                first_absent.push(to.display().to_string());
            }
        }
    }
    if absent > 0 {
        return Err(GenError::Input(format!(
            "{absent} packs are in no shard (first: {}): were all shard folders given? Nothing was moved",
            first_absent.join(", ")
        )));
    }
    let damaged: Vec<String> = (0..packs.len())
        .into_par_iter()
        .filter_map(|number| {
            let (_, found, ..) = locate(number, false).ok()?;
            let keys = packs.keys(&packs.pack(number));
            crate::output::packs::verify_scenarios_of(found.as_deref()?, &keys, seed).err()
        })
        .collect();
    if let Some(first_damaged) = damaged.first() {
        return Err(GenError::Input(format!(
            "{} packs are damaged (first: {first_damaged}): rerun their shards' gen commands, which rewrite damaged \
             packs; nothing was moved",
            damaged.len()
        )));
    }
    before_moving()?;
    let (mut moved, mut already) = (0, 0);
    for number in 0..packs.len() {
        let (to, found, moves, duplicates) = locate(number, false)?;
        if let (true, Some(from)) = (moves, &found) {
            let parent = to.parent().expect("packs have parents");
            fs::create_dir_all(parent).map_err(io_err(parent))?;
            if fs::rename(from, &to).is_err() {
                // Another filesystem: copy, then remove the source.
                let partial = crate::output::fresh_partial(&to)?;
                let copied = fs::copy(from, &partial)
                    .map_err(io_err(&partial))
                    .and_then(|_| fs::rename(&partial, &to).map_err(io_err(&to)));
                if copied.is_err() {
                    let _ = fs::remove_file(&partial);
                }
                copied?;
                fs::remove_file(from).map_err(io_err(from))?;
            }
            moved += 1;
        }
        for from in &duplicates {
            fs::remove_file(from).map_err(io_err(from))?;
            already += 1;
        }
    }
    Ok((moved, already))
}

/// Whether two files hold the same bytes (read a block at a time).
fn same_bytes(a: &Path, b: &Path) -> bool {
    use std::io::Read;
    // (regular files only: a pipe is never opened)
    let regular = |p: &Path| fs::metadata(p).is_ok_and(|m| m.is_file());
    if !(regular(a) && regular(b)) {
        return false;
    }
    let (Ok(fa), Ok(fb)) = (fs::File::open(a), fs::File::open(b)) else { return false };
    if fa.metadata().map(|m| m.len()).ok() != fb.metadata().map(|m| m.len()).ok() {
        return false;
    }
    let (mut ra, mut rb) = (std::io::BufReader::new(fa), std::io::BufReader::new(fb));
    let (mut ba, mut bb) = (vec![0u8; 1 << 16], vec![0u8; 1 << 16]);
    loop {
        match (ra.read(&mut ba), rb.read_exact(&mut bb[..0])) {
            (Ok(0), _) => return true,
            (Ok(n), Ok(())) => {
                if rb.read_exact(&mut bb[..n]).is_err() || ba[..n] != bb[..n] {
                    return false;
                }
            }
            _ => return false,
        }
    }
}

/// Where one scenario is before a merge: its place in `--out`, the folder
/// holding it (that place, or a shard folder's it moves from), and copies
/// in other shard folders to drop.
struct Located {
    to: PathBuf,
    found: Option<PathBuf>,
    /// `found` is a shard folder's copy, to move to `to`.
    moved: bool,
    duplicates: Vec<PathBuf>,
}

/// Scenarios checked at a time (in parallel) before anything moves.
const MERGE_CHUNK: usize = 256;

/// Removes the shard folder `source` when merge has emptied it (an error
/// when it holds anything). Named through a link (`l0` or `l0/`), the link
/// goes, then the folder it leads to: a shard named so was left as an
/// empty folder behind its link, and a retried merge, finding the link,
/// refused to say "merged before" (exit 2). (Cut off between the two, the
/// retry finds the shard gone; an empty folder no one named is left.)
fn remove_emptied_shard(source: &Path) -> std::io::Result<()> {
    // `l0/` is the folder a link leads to; `l0` is the link.
    let source: PathBuf = source.components().collect();
    if !fs::symlink_metadata(&source)?.file_type().is_symlink() {
        return fs::remove_dir(&source);
    }
    let folder = source.canonicalize()?;
    if fs::read_dir(&folder)?.next().is_some() {
        return Err(std::io::Error::new(std::io::ErrorKind::DirectoryNotEmpty, "it holds more than merge moved"));
    }
    fs::remove_file(&source)?;
    fs::remove_dir(&folder)
}

/// `a` and `b` as their real paths (links resolved), when both exist.
fn real_paths(a: &Path, b: &Path) -> Option<(PathBuf, PathBuf)> {
    Some((a.canonicalize().ok()?, b.canonicalize().ok()?))
}
