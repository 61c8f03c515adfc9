//! `gen --format tar`: whole scenarios packed into WebDataset-style tar
//! files. Checked on real output: the packs unpacked by the system's own
//! `tar` are the folder layout byte for byte, on any thread count; a packed
//! run resumes, repairs and merges as a folder run does; and every reader
//! gives the same answers on packs as on folders.

mod common;

use common::{fresh_dir, gen_ok, hash_tree, read_json, run, sorted_entries, write_spec};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

/// A small city with images: two groups, 3/1/2 scenarios, 40 frames.
fn spec(dir: &Path) -> PathBuf {
    write_spec(
        dir,
        r#"{"name": "packed", "world": "city", "seed": 5, "frames": 40, "frame_interval": 0.5,
            "image": {"width": 192, "height": 120},
            "groups": [{"cars": 4, "edge_proportion": 0.5}, {"cars": 6, "edge_proportion": 0.5}],
            "splits": {"train": 3, "val": 1, "test": 2}}"#,
    )
}

const PACKED: &[&str] = &["--format", "tar", "--scenarios-per-tar", "2", "-q"];

/// Every file under `root` (its path relative to it).
fn files(root: &Path) -> Vec<String> {
    hash_tree(root).into_keys().collect()
}

/// The packs of a dataset, relative to it, sorted.
fn packs(root: &Path) -> Vec<String> {
    files(root).into_iter().filter(|f| f.ends_with(".tar")).collect()
}

/// Unpacks every pack of `packed` with the system's `tar` into `into`.
fn untar_all(packed: &Path, into: &Path) {
    std::fs::create_dir_all(into).unwrap();
    let found = packs(packed);
    assert!(!found.is_empty(), "no packs in {}", packed.display());
    for pack in found {
        let status = Command::new("tar").arg("-xf").arg(packed.join(&pack)).arg("-C").arg(into).status().unwrap();
        assert!(status.success(), "tar -xf {pack}");
    }
}

/// The tree without its manifest (which says how the scenarios are kept).
fn scenarios_only(root: &Path) -> BTreeMap<String, String> {
    let mut tree = hash_tree(root);
    tree.remove("manifest.json");
    tree
}

/// (folders dataset, packed dataset) of [`spec`], made once per test.
fn both(name: &str) -> (PathBuf, PathBuf, PathBuf) {
    let dir = fresh_dir(name);
    let spec = spec(&dir);
    let (folders, packed) = (dir.join("folders"), dir.join("packed"));
    gen_ok(&spec, &folders, &["-q", "-j", "2"]);
    gen_ok(&spec, &packed, &[PACKED, &["-j", "2"]].concat());
    (spec, folders, packed)
}

#[test]
fn packs_hold_the_folder_layouts_files_byte_for_byte_in_a_handful_of_files_on_any_thread_count() {
    let (spec, folders, packed) = both("packs-bytes");
    // Each group: train 00000-00001 and 00002-00002, val and test one each.
    let expected: Vec<String> = ["cars04_edges50", "cars06_edges50"]
        .iter()
        .flat_map(|g| {
            ["test/00000-00001.tar", "train/00000-00001.tar", "train/00002-00002.tar", "val/00000-00000.tar"]
                .map(|p| format!("{g}/{p}"))
        })
        .collect();
    assert_eq!(packs(&packed), expected);
    assert_eq!(files(&packed).len(), expected.len() + 1, "packs and the manifest only: {:?}", files(&packed));
    let folder_files = files(&folders).len();
    assert!(folder_files > 12 * 80, "the folder layout has {folder_files} files");

    // The system's tar gives back the folder layout, every byte.
    let untarred = folders.parent().unwrap().join("untarred");
    untar_all(&packed, &untarred);
    let (a, b) = (scenarios_only(&folders), hash_tree(&untarred));
    assert!(a.keys().any(|f| f.ends_with("/rgb/0039.png")) && a.len() == folder_files - 1);
    assert_eq!(a, b, "unpacked packs differ from the folders");

    // Members run scenario by scenario, each scenario's files in name order.
    let listing = Command::new("tar").arg("-tf").arg(packed.join(&expected[1])).output().unwrap();
    let names: Vec<String> = String::from_utf8(listing.stdout).unwrap().lines().map(str::to_string).collect();
    let first_of_second = names.iter().position(|n| n.contains("/train/00001/")).unwrap();
    assert!(names[..first_of_second].iter().all(|n| n.starts_with("cars04_edges50/train/00000/")));
    assert!(names[first_of_second..].iter().all(|n| n.starts_with("cars04_edges50/train/00001/")));
    let mut sorted = names[..first_of_second].to_vec();
    sorted.sort();
    assert_eq!(names[..first_of_second], sorted[..]);

    // The manifest says how; all else in it is the folder dataset's.
    let (mut m_folders, m_packed) =
        (read_json(&folders.join("manifest.json")), read_json(&packed.join("manifest.json")));
    assert_eq!(m_packed["scenarios_per_tar"], 2);
    common::assert_valid(&common::validator("manifest.schema.json"), &m_packed, &packed.join("manifest.json"));
    assert!(m_folders.get("scenarios_per_tar").is_none());
    m_folders["scenarios_per_tar"] = 2.into();
    assert_eq!(m_folders, m_packed);

    // One thread writes the same packs.
    let one = folders.parent().unwrap().join("one-thread");
    gen_ok(&spec, &one, &[PACKED, &["-j", "1"]].concat());
    assert_eq!(hash_tree(&one), hash_tree(&packed));

    let out = run(&["validate", packed.to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stdout));
    assert!(String::from_utf8_lossy(&out.stdout).contains("12 of 12 scenarios checked"));
}

/// Flips one byte of `member`'s data inside the pack at `path`.
fn damage(path: &Path, member: &str) {
    let mut bytes = std::fs::read(path).unwrap();
    let at = bytes.windows(member.len()).position(|w| w == member.as_bytes()).expect("member in the pack");
    // The data starts one 512-byte header block after the name.
    let data = (at / 512 + 1) * 512;
    bytes[data + 10] ^= 0x20;
    std::fs::write(path, bytes).unwrap();
}

#[test]
fn validate_names_the_pack_and_the_file_of_damage_and_gen_writes_that_pack_again() {
    let (spec, _, packed) = both("packs-damage");
    let before = hash_tree(&packed);
    let pack = packed.join("cars06_edges50/train/00000-00001.tar");
    damage(&pack, "cars06_edges50/train/00001/poses.csv");
    let out = run(&["validate", packed.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{text}");
    assert!(
        text.contains(&format!("{}: cars06_edges50/train/00001/poses.csv", pack.display())),
        "validate should name the pack and the member: {text}"
    );

    let out = gen_ok(&spec, &packed, PACKED);
    let said = String::from_utf8_lossy(&out.stderr);
    assert!(said.contains("writing the pack again"), "{said}");
    assert_eq!(hash_tree(&packed), before, "the rewritten pack is the original, byte for byte");
}

#[test]
fn a_reader_names_the_pack_and_member_it_could_not_read_not_a_temporary_folder() {
    let (_, _, packed) = both("packs-reader-damage");
    let pack = packed.join("cars04_edges50/test/00000-00001.tar");
    let member = "cars04_edges50/test/00001/poses.csv";
    // The first pose row's frame number made unreadable (same length: the pack stays a tar).
    let mut bytes = std::fs::read(&pack).unwrap();
    let at = bytes.windows(member.len()).position(|w| w == member.as_bytes()).expect("member in the pack");
    let data = (at / 512 + 1) * 512;
    let row = data + bytes[data..].iter().position(|&b| b == b'\n').unwrap() + 1;
    bytes[row] = b'x';
    std::fs::write(&pack, bytes).unwrap();
    let mut checked = 0;
    for command in ["stats", "baseline"] {
        let out = run(&[command, packed.to_str().unwrap()]);
        let said = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{command}: a damaged dataset is bad input: {said}");
        assert!(said.contains("is damaged: `causalcity validate"), "{command}: {said}");
        assert!(said.contains(&format!("{}: {member}", pack.display())), "{command} names the pack and member: {said}");
        assert!(!said.contains("causalcity-unpacked"), "{command} names a temporary folder: {said}");
        checked += 1;
    }
    assert_eq!(checked, 2);
}

#[test]
fn a_reader_that_cannot_unpack_into_tmpdir_fails_without_calling_the_dataset_damaged() {
    let (_, _, packed) = both("packs-reader-tmpdir");
    // No file may grow past 0 bytes (as on a full TMPDIR): unpacking fails
    // on its first write.
    let mut checked = 0;
    for command in ["stats", "baseline"] {
        let script = format!("trap '' XFSZ; ulimit -f 0; exec \"$0\" {command} \"$1\"");
        let out = Command::new("sh")
            .args(["-c", &script, env!("CARGO_BIN_EXE_causalcity"), packed.to_str().unwrap()])
            .output()
            .unwrap();
        let said = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{command}: a failure while working: {said}");
        assert!(said.contains("cannot write") && said.contains("causalcity-unpacked"), "{command}: {said}");
        assert!(!said.contains("is damaged"), "{command}: the dataset is whole: {said}");
        checked += 1;
    }
    assert_eq!(checked, 2);
    // A TMPDIR where no folder can be made (a file): exit 2 before, as if
    // the dataset were the problem.
    let file = packed.parent().unwrap().join("tmpdir-is-a-file");
    std::fs::write(&file, "").unwrap();
    let export = packed.parent().unwrap().join("export");
    for args in
        [vec!["stats"], vec!["baseline"], vec!["validate"], vec!["export", "nri", "--out", export.to_str().unwrap()]]
    {
        let mut args = args.clone();
        args.insert(args.len().min(2), packed.to_str().unwrap());
        let out = Command::new(common::bin()).args(&args).env("TMPDIR", &file).output().unwrap();
        let said = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{args:?}: a failure while working: {said}");
        assert!(said.contains("cannot make a folder to unpack into"), "{args:?}: {said}");
        checked += 1;
    }
    assert_eq!(checked, 6);
    // pack of a packed dataset says so first (it named the folder it
    // could not make).
    let repack = packed.parent().unwrap().join("repack");
    let args = ["pack", packed.to_str().unwrap(), "--out", repack.to_str().unwrap()];
    let out = Command::new(common::bin()).args(args).env("TMPDIR", &file).output().unwrap();
    let said = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{said}");
    assert!(said.contains("is packed already") && !said.contains("unpack into"), "{said}");
}

#[test]
fn pack_that_cannot_write_its_packs_says_so_and_never_blames_its_input() {
    // A pack file that cannot grow is a failure writing (exit 1), however
    // --out is spelled: one spelled under the input (`in/../out`) was told
    // as "cannot read ... the dataset changed", exit 2 (review).
    let (_, folders, _) = both("packs-cannot-write");
    let spelled = format!("{}/../packed-nowhere", folders.display());
    let script = "trap '' XFSZ; ulimit -f 8; exec \"$0\" pack \"$1\" --out \"$2\" -q";
    let out = Command::new("sh")
        .args(["-c", script, env!("CARGO_BIN_EXE_causalcity"), folders.to_str().unwrap(), &spelled])
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{said}");
    assert!(said.contains("cannot write") && said.contains(".tar"), "{said}");
    assert!(!said.contains("cannot read") && !said.contains("changed while"), "{said}");
}

#[test]
fn validate_says_when_a_pack_lacks_a_scenario_or_holds_a_stranger_and_gen_repairs_both() {
    let (spec, folders, packed) = both("packs-membership");
    let before = hash_tree(&packed);
    // Packs made by hand with `tar` from the folders' scenarios.
    let tar_cf = |pack: &Path, scenarios: &[&str]| {
        let status =
            Command::new("tar").args(["--sort=name", "-cf"]).arg(pack).arg("-C").arg(&folders).args(scenarios).status();
        assert!(status.unwrap().success(), "tar -cf {}", pack.display());
    };
    // One of its two scenarios left out.
    let short = packed.join("cars06_edges50/train/00000-00001.tar");
    tar_cf(&short, &["cars06_edges50/train/00000"]);
    // A scenario of another pack beside its own.
    let crowded = packed.join("cars04_edges50/test/00000-00001.tar");
    tar_cf(&crowded, &["cars04_edges50/test/00000", "cars04_edges50/test/00001", "cars04_edges50/val/00000"]);

    let out = run(&["validate", packed.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{text}");
    assert!(
        text.contains(&format!("{}: cars06_edges50/train/00001 is not in it", short.display())),
        "validate should name the pack and the scenario it lacks: {text}"
    );
    assert!(
        text.contains(&format!("{}: cars04_edges50/val/00000/", crowded.display()))
            && text.contains("belongs to none of its scenarios"),
        "validate should name the pack and the stranger in it: {text}"
    );

    let out = gen_ok(&spec, &packed, PACKED);
    let said = String::from_utf8_lossy(&out.stderr);
    assert_eq!(said.matches("writing the pack again").count(), 2, "{said}");
    assert_eq!(hash_tree(&packed), before, "both packs rewritten as they were, byte for byte");
}

#[test]
fn an_interrupted_packed_run_resumes_to_the_same_bytes_and_leaves_nothing_behind() {
    let (spec, _, packed) = both("packs-resume");
    let before = hash_tree(&packed);
    let split = packed.join("cars04_edges50/train");
    // A run killed while writing the first pack: one of its scenarios
    // finished as a folder, the tar half written.
    let scratch = packed.parent().unwrap().join("scratch");
    std::fs::create_dir_all(&scratch).unwrap();
    let status = Command::new("tar")
        .arg("-xf")
        .arg(split.join("00000-00001.tar"))
        .arg("-C")
        .arg(&scratch)
        .arg("cars04_edges50/train/00001")
        .status()
        .unwrap();
    assert!(status.success());
    std::fs::rename(scratch.join("cars04_edges50/train/00001"), split.join("00001")).unwrap();
    std::fs::remove_file(split.join("00000-00001.tar")).unwrap();
    std::fs::write(split.join("00000-00001.tar.partial"), b"half a tar").unwrap();
    // ... and killed after packing the second, before removing its folder.
    let status =
        Command::new("tar").arg("-xf").arg(split.join("00002-00002.tar")).arg("-C").arg(&scratch).status().unwrap();
    assert!(status.success());
    std::fs::rename(scratch.join("cars04_edges50/train/00002"), split.join("00002")).unwrap();
    let mut manifest = read_json(&packed.join("manifest.json"));
    manifest["complete"] = false.into();
    std::fs::write(packed.join("manifest.json"), serde_json::to_vec_pretty(&manifest).unwrap()).unwrap();

    let out = run(&["validate", packed.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        text.contains("missing pack") && text.contains("not packed yet") && text.contains("did not finish"),
        "{text}"
    );

    let out = gen_ok(&spec, &packed, &[PACKED, &["--json"]].concat());
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    // The folder kept is not simulated again; its pack partner is.
    assert_eq!(summary["written"], 1, "{summary}");
    assert_eq!(summary["skipped"], 11, "{summary}");
    assert_eq!(hash_tree(&packed), before, "resumed packs, byte for byte, and no leftovers");
}

#[test]
fn readers_give_the_same_answers_on_packs_as_on_folders() {
    let (_, folders, packed) = both("packs-readers");
    let (f, p) = (folders.to_str().unwrap(), packed.to_str().unwrap());
    // Readers unpack into TMPDIR, and leave nothing there.
    let tmp = folders.parent().unwrap().join("tmp");
    std::fs::create_dir_all(&tmp).unwrap();
    let run = |args: &[&str]| Command::new(common::bin()).args(args).env("TMPDIR", &tmp).output().unwrap();
    for command in [&["stats", "--json"][..], &["baseline", "--json"][..]] {
        let (a, b) = (run(&[command, &[f]].concat()), run(&[command, &[p]].concat()));
        assert!(a.status.success() && b.status.success(), "{command:?}: {}", String::from_utf8_lossy(&b.stderr));
        let parse = |out: &[u8]| {
            let mut report: serde_json::Value = serde_json::from_slice(out).unwrap();
            // The dataset's path, the one thing that differs.
            report.as_object_mut().unwrap().remove("dataset");
            report
        };
        let (a, b) = (parse(&a.stdout), parse(&b.stdout));
        assert!(a.to_string().len() > 500 && a.to_string().contains("cars06_edges50"), "{a}");
        assert_eq!(a, b, "{command:?}");
    }
    let root = folders.parent().unwrap();
    for (name, dataset) in [("nri-folders", f), ("nri-packed", p)] {
        let out = run(&["export", "nri", dataset, "--out", root.join(name).to_str().unwrap()]);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    }
    let (a, b) = (hash_tree(&root.join("nri-folders")), hash_tree(&root.join("nri-packed")));
    assert!(a.keys().any(|k| k.ends_with(".npy")), "{a:?}");
    assert_eq!(a, b);
    for (name, dataset) in [("heat-folders.png", f), ("heat-packed.png", p)] {
        let out = run(&["heatmap", dataset, "--out", root.join(name).to_str().unwrap()]);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    }
    assert_eq!(
        std::fs::read(root.join("heat-folders.png")).unwrap(),
        std::fs::read(root.join("heat-packed.png")).unwrap()
    );
    // V-CDN (with HDF5): the same files, with the same arrays in them.
    #[cfg(feature = "hdf5")]
    {
        for (name, dataset) in [("vcdn-folders", f), ("vcdn-packed", p)] {
            let out = run(&["export", "vcdn", dataset, "--out", root.join(name).to_str().unwrap(), "-q"]);
            assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        }
        let (a, b) = (hash_tree(&root.join("vcdn-folders")), hash_tree(&root.join("vcdn-packed")));
        assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
        assert_eq!(a.len(), 12, "{a:?}");
        for name in a.keys() {
            let read = |export: &str| -> Vec<f32> {
                let file = hdf5::File::open(root.join(export).join(name)).unwrap();
                file.dataset("states").unwrap().read_raw().unwrap()
            };
            let (x, y) = (read("vcdn-folders"), read("vcdn-packed"));
            assert!(!x.is_empty());
            assert_eq!(x, y, "{name}");
        }
    }
    // NS-DR: the same annotations; a folder dataset's frames are linked, a
    // packed one's copied (its unpacked folders are temporary).
    for (name, dataset) in [("nsdr-folders", f), ("nsdr-packed", p)] {
        let out = run(&["export", "nsdr", dataset, "--out", root.join(name).to_str().unwrap()]);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    }
    let (a, b) = (hash_tree(&root.join("nsdr-folders")), hash_tree(&root.join("nsdr-packed")));
    assert!(a.keys().any(|k| k.ends_with("cars06_edges50/test/00001/annotations.json")), "{a:?}");
    assert!(a.keys().any(|k| k.ends_with("cars06_edges50/test/00001/rgb/0039.png")), "{a:?}");
    assert_eq!(a, b);
    let frame = root.join("nsdr-packed/cars06_edges50/test/00001/mask/0039.png");
    assert!(!std::fs::symlink_metadata(frame.parent().unwrap()).unwrap().file_type().is_symlink());
    assert_eq!(
        std::fs::read(&frame).unwrap(),
        std::fs::read(folders.join("cars06_edges50/test/00001/mask/0039.png")).unwrap()
    );
    // Nothing was unpacked into the dataset, and nothing is left in the
    // temporary folder.
    assert_eq!(files(&packed).len(), 9);
    assert!(sorted_entries(&tmp).is_empty(), "{:?}", sorted_entries(&tmp));
}

#[test]
fn a_format_other_than_the_datasets_is_refused_and_scenarios_per_tar_needs_tar() {
    let (spec, folders, packed) = both("packs-mixed");
    let before = hash_tree(&packed);
    let out = run(&["gen", "--spec", spec.to_str().unwrap(), "--out", packed.to_str().unwrap(), "-q"]);
    let said = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{said}");
    assert!(said.contains("format: tar (2 scenarios per tar) there, folders now"), "{said}");
    assert_eq!(hash_tree(&packed), before);
    let out =
        run(&["gen", "--spec", spec.to_str().unwrap(), "--out", folders.to_str().unwrap(), "--format", "tar", "-q"]);
    let said = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{said}");
    assert!(said.contains("format: folders there, tar (64 scenarios per tar) now"), "{said}");
    // More scenarios would make other packs and leave the first ones behind.
    let small = folders.parent().unwrap().join("small");
    gen_ok(&spec, &small, &[PACKED, &["--limit", "1"]].concat());
    let small_before = hash_tree(&small);
    let out =
        run(&["gen", "--spec", spec.to_str().unwrap(), "--out", small.to_str().unwrap(), "--format", "tar", "-q"]);
    let said = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{said}");
    assert!(said.contains("a packed dataset keeps its --limit"), "{said}");
    assert_eq!(hash_tree(&small), small_before);
    let empty = folders.parent().unwrap().join("never");
    let out =
        run(&["gen", "--spec", spec.to_str().unwrap(), "--out", empty.to_str().unwrap(), "--scenarios-per-tar", "3"]);
    let said = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{said}");
    assert!(said.contains("--scenarios-per-tar 3 packs tar files: give it with --format tar"), "{said}");
    assert!(!empty.exists());
    // --force replaces a packed dataset (its packs are causalcity's own).
    gen_ok(&spec, &packed, &["-q", "--force"]);
    assert!(packs(&packed).is_empty());
    assert_eq!(scenarios_only(&packed), scenarios_only(&folders));
}

#[test]
fn packed_shards_merge_into_the_packs_of_one_run() {
    let (spec, _, packed) = both("packs-merge");
    let root = packed.parent().unwrap();
    let (a, b, out) = (root.join("shard-a"), root.join("shard-b"), root.join("merged"));
    gen_ok(&spec, &a, &[PACKED, &["--shard", "0/3"]].concat());
    gen_ok(&spec, &b, &[PACKED, &["--shard", "1/3"]].concat());
    gen_ok(&spec, &b, &[PACKED, &["--shard", "2/3"]].concat());
    // Shard 0 of 3 writes whole packs: the 1st, 4th and 7th.
    assert_eq!(
        packs(&a),
        [
            "cars04_edges50/test/00000-00001.tar",
            "cars04_edges50/train/00000-00001.tar",
            "cars06_edges50/val/00000-00000.tar"
        ]
    );
    let merged = run(&["merge", "--out", out.to_str().unwrap(), a.to_str().unwrap(), b.to_str().unwrap()]);
    assert!(merged.status.success(), "{}", String::from_utf8_lossy(&merged.stderr));
    assert_eq!(hash_tree(&out), hash_tree(&packed));
    assert!(!a.exists() && !b.exists(), "the shard folders are emptied and removed");
}

#[test]
fn the_files_of_a_packed_dataset_are_few_however_many_scenarios() {
    // 3 groups x 300 scenarios without images, effects or lights: 900
    // scenarios of 6+ files in 15 packs of 64.
    let dir = fresh_dir("packs-few");
    let spec = write_spec(&dir, &common::toy_spec("few", &[(3, 0.5), (4, 0.5), (5, 0.5)], (200, 50, 50), 5));
    let out = dir.join("out");
    gen_ok(&spec, &out, &["--format", "tar", "--no-images", "--no-effects", "-q"]);
    let found = files(&out);
    assert_eq!(found.len(), 3 * (4 + 1 + 1) + 1, "{found:?}");
    assert!(found.contains(&"cars03_edges50/train/00192-00199.tar".to_string()), "{found:?}");
    let entries = sorted_entries(&out.join("cars05_edges50/val"));
    assert_eq!(entries.len(), 1);
}

#[test]
fn pack_turns_a_folder_dataset_into_the_packs_gen_writes_and_leaves_its_input_alone() {
    let (_, folders, packed) = both("packs-pack");
    let input = hash_tree(&folders);
    let out = folders.parent().unwrap().join("packed-later");
    let (f, o) = (folders.to_str().unwrap(), out.to_str().unwrap());
    let done = run(&["pack", f, "--out", o, "--scenarios-per-tar", "2", "-q", "-j", "2"]);
    assert!(done.status.success(), "{}", String::from_utf8_lossy(&done.stderr));
    assert!(
        String::from_utf8_lossy(&done.stdout).contains("packed 12 scenarios"),
        "{}",
        String::from_utf8_lossy(&done.stdout)
    );
    assert_eq!(hash_tree(&out), hash_tree(&packed), "pack writes what gen --format tar writes");
    assert_eq!(hash_tree(&folders), input, "the input is only read");

    // Resumes: a lost pack is written again, the others kept.
    let lost = out.join("cars06_edges50/test/00000-00001.tar");
    std::fs::remove_file(&lost).unwrap();
    std::fs::write(out.join("cars06_edges50/test/00000-00001.tar.partial"), b"half").unwrap();
    let again = run(&["pack", f, "--out", o, "--scenarios-per-tar", "2"]);
    let stderr = String::from_utf8_lossy(&again.stderr);
    assert!(again.status.success(), "{stderr}");
    assert!(String::from_utf8_lossy(&again.stdout).contains("7 packs already there kept"));
    // Progress counts what it packs: "6/6 scenarios" was shown for 12.
    assert!(stderr.contains("progress: 8/8 tar files (100 %)"), "{stderr}");
    assert_eq!(hash_tree(&out), hash_tree(&packed));

    // Refused, exit 2, nothing written: into itself, a packed input, another size into a pack.
    for (args, says) in [
        (vec!["pack", f, "--out", f], "is the dataset itself"),
        (
            vec!["pack", packed.to_str().unwrap(), "--out", folders.parent().unwrap().join("x").to_str().unwrap()],
            "is packed already",
        ),
        (vec!["pack", f, "--out", o, "--scenarios-per-tar", "3"], "already holds another dataset"),
    ] {
        let refused = run(&args);
        let said = String::from_utf8_lossy(&refused.stderr);
        assert_eq!(refused.status.code(), Some(2), "{args:?}: {said}");
        assert!(said.contains(says), "{args:?}: {said}");
    }
    assert!(!folders.parent().unwrap().join("x").exists());
    assert_eq!(hash_tree(&folders), input);
    assert_eq!(hash_tree(&out), hash_tree(&packed));
}

#[test]
fn a_link_planted_at_a_packs_name_is_replaced_never_written_through() {
    let (spec, _, packed) = both("packs-link");
    let before = hash_tree(&packed);
    let victim = packed.parent().unwrap().join("victim.txt");
    std::fs::write(&victim, b"not yours").unwrap();
    let pack = packed.join("cars04_edges50/val/00000-00000.tar");
    std::fs::remove_file(&pack).unwrap();
    std::os::unix::fs::symlink(&victim, &pack).unwrap();
    let out = gen_ok(&spec, &packed, PACKED);
    assert!(String::from_utf8_lossy(&out.stderr).contains("writing the pack again"));
    assert_eq!(std::fs::read(&victim).unwrap(), b"not yours");
    assert!(std::fs::symlink_metadata(&pack).unwrap().file_type().is_file());
    assert_eq!(hash_tree(&packed), before);
}

#[test]
fn a_reader_done_with_a_split_of_a_packed_dataset_frees_its_unpacked_folders() {
    use causalcity::dataset::Dataset;
    use causalcity::spec::Split;
    // Readers go a group's split at a time: TMPDIR holds one split's logs,
    // not the dataset's.
    let (_, folders, packed) = both("packs-release");
    let dataset = Dataset::open(&packed).unwrap();
    let train = dataset.scenario_dirs("cars04_edges50", Split::Train).unwrap();
    assert_eq!(train.len(), 3);
    for dir in &train {
        assert!(dir.join("poses.csv").is_file(), "{} unpacked", dir.display());
        assert!(!dir.join("rgb").exists(), "frames stay in the pack for a reader of the logs");
    }
    dataset.release("cars04_edges50", Split::Train).unwrap();
    assert!(train.iter().all(|d| !d.exists()), "released folders are gone");
    // Asked for again, they are unpacked again, with the folders' bytes.
    let again = dataset.scenario_dirs("cars04_edges50", Split::Train).unwrap();
    for dir in &again {
        let name = dir.file_name().unwrap();
        let folder = folders.join("cars04_edges50/train").join(name);
        assert_eq!(std::fs::read(dir.join("poses.csv")).unwrap(), std::fs::read(folder.join("poses.csv")).unwrap());
    }
    assert!(dataset.scenario_dirs("cars06_edges50", Split::Test).unwrap()[0].join("scenario.json").is_file());
    assert!(again[0].exists(), "releasing one split leaves the others");
}

#[test]
fn a_reader_going_a_split_at_a_time_holds_only_that_split_unpacked() {
    use causalcity::dataset::Dataset;
    use causalcity::spec::Split;
    // heatmap, evaluate and the exports read through `with_split`: while a
    // split is read its folders are there, and no other split's are.
    let (_, folders, packed) = both("packs-with-split");
    let dataset = Dataset::open(&packed).unwrap();
    let root = dataset.folders_root_unread().to_path_buf();
    let held = || -> Vec<String> {
        let mut held = Vec::new();
        for group in sorted_entries(&root) {
            for split in sorted_entries(&group) {
                held.push(split.strip_prefix(&root).unwrap().to_string_lossy().into_owned());
            }
        }
        held
    };
    let mut read = Vec::new();
    for group in ["cars04_edges50", "cars06_edges50"] {
        for split in Split::ALL {
            let seen = dataset
                .with_split(group, split, |dirs| {
                    for dir in dirs {
                        let name = dir.file_name().unwrap();
                        let folder = folders.join(group).join(split.name()).join(name);
                        assert_eq!(
                            std::fs::read(dir.join("poses.csv")).unwrap(),
                            std::fs::read(folder.join("poses.csv")).unwrap()
                        );
                    }
                    Ok((dirs.len(), held()))
                })
                .unwrap();
            assert_eq!(seen.1, vec![format!("{group}/{}", split.name())], "only the split being read is unpacked");
            read.push(seen.0);
        }
    }
    assert_eq!(read, vec![3, 1, 2, 3, 1, 2], "every split was read, each whole");
    assert!(held().is_empty(), "nothing is left unpacked: {:?}", held());
    // The sizes evaluate matches predictions against come from the packs
    // without unpacking anything, and agree with the folders' scenario.json.
    let sizes = dataset.packed_scenario_sizes().unwrap().unwrap();
    assert_eq!(sizes.len(), 12);
    assert_eq!(sizes["cars06_edges50/test/00001"], (6, 40));
    assert!(held().is_empty());
    assert_eq!(Dataset::open(&folders).unwrap().packed_scenario_sizes().unwrap(), None);
}

/// The members of the pack at `path`, in order: (name, bytes).
fn members(path: &Path) -> Vec<(String, Vec<u8>)> {
    let mut archive = tar::Archive::new(std::fs::File::open(path).unwrap());
    let mut found = Vec::new();
    for entry in archive.entries().unwrap() {
        let mut entry = entry.unwrap();
        let name = entry.path().unwrap().to_string_lossy().into_owned();
        let mut bytes = Vec::new();
        std::io::Read::read_to_end(&mut entry, &mut bytes).unwrap();
        found.push((name, bytes));
    }
    found
}

/// A tar of `members`, in order.
fn tar_of(members: &[(String, Vec<u8>)]) -> Vec<u8> {
    let mut builder = tar::Builder::new(Vec::new());
    append_files(&mut builder, members);
    builder.into_inner().unwrap()
}

/// Appends `members` to `builder` as plain files, in order.
fn append_files(builder: &mut tar::Builder<Vec<u8>>, members: &[(String, Vec<u8>)]) {
    for (name, bytes) in members {
        let mut header = tar::Header::new_gnu();
        header.set_size(bytes.len() as u64);
        header.set_mode(0o644);
        builder.append_data(&mut header, name, bytes.as_slice()).unwrap();
    }
}

#[test]
fn every_reader_refuses_a_pack_with_a_member_twice_a_stranger_or_cut_short() {
    // Only validate held packs to their rule: the readers unpacked a member
    // twice with the last copy winning (other speeds, exit 0), a member of
    // another scenario beside the pack's own, and a pack cut short at a
    // member's header as one with fewer scenarios.
    let (_, folders, packed) = both("packs-tampered");
    let rel = "cars04_edges50/test/00000-00001.tar";
    let original = members(&packed.join(rel));
    let poses = "cars04_edges50/test/00001/poses.csv";
    let at = original.iter().position(|(name, _)| name == poses).expect("poses.csv in the pack");
    let mut twice = original.clone();
    let mut edited = original[at].1.clone();
    let row = edited.iter().position(|&b| b == b'\n').unwrap() + 1;
    edited.truncate(row);
    twice.push((poses.to_string(), edited));
    let mut stranger = original.clone();
    stranger.push(("cars06_edges50/test/00000/poses.csv".to_string(), original[at].1.clone()));
    let whole = tar_of(&original);
    let last = original.last().unwrap().0.as_bytes();
    let header = whole.windows(last.len()).rposition(|w| w == last).unwrap() / 512 * 512;
    let cases = [
        ("twice", tar_of(&twice), "is in it twice"),
        ("stranger", tar_of(&stranger), "belongs to none of its scenarios"),
        ("cut", whole[..header].to_vec(), "cut short"),
    ];
    let mut checked = 0;
    for (case, bytes, says) in cases {
        let dir = fresh_dir(&format!("packs-tampered-{case}"));
        let data = dir.join("data");
        for (file, _) in hash_tree(&packed) {
            std::fs::create_dir_all(data.join(&file).parent().unwrap()).unwrap();
            std::fs::copy(packed.join(&file), data.join(&file)).unwrap();
        }
        std::fs::write(data.join(rel), &bytes).unwrap();
        // The exports too: they exited 1, as if writing had failed.
        let exports = dir.join("exports");
        for command in ["stats", "baseline", "validate", "export nri", "export nsdr"] {
            let mut args: Vec<&str> = command.split(' ').collect();
            args.push(data.to_str().unwrap());
            let export = exports.join(command.replace(' ', "-"));
            if command.starts_with("export") {
                args.extend(["--out", export.to_str().unwrap(), "-q"]);
            }
            let out = run(&args);
            let said = String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
            // validate finds a problem (1); a reader is given bad input (2).
            let code = if command == "validate" { 1 } else { 2 };
            assert_eq!(out.status.code(), Some(code), "{case}: {command}: {said}");
            assert!(said.contains(&data.join(rel).display().to_string()), "{case}: {command} names the pack: {said}");
            assert!(said.contains(says), "{case}: {command} says {says:?}: {said}");
            assert!(!said.contains("causalcity-unpacked"), "{case}: {command} names a temporary folder: {said}");
            checked += 1;
        }
    }
    assert_eq!(checked, 15);
    // The rule takes a pack made by hand with `tar -cf pack.tar ./group/...`,
    // whose members' names start `./` (stats took it, validate did not).
    let dotted = fresh_dir("packs-tampered-dotted").join("data");
    for (file, _) in hash_tree(&packed) {
        std::fs::create_dir_all(dotted.join(&file).parent().unwrap()).unwrap();
        std::fs::copy(packed.join(&file), dotted.join(&file)).unwrap();
    }
    let status = Command::new("tar")
        .args(["--sort=name", "-cf"])
        .arg(dotted.join(rel))
        .arg("-C")
        .arg(&folders)
        .args(["./cars04_edges50/test/00000", "./cars04_edges50/test/00001"])
        .status();
    assert!(status.unwrap().success());
    assert!(members(&dotted.join(rel)).iter().all(|(name, _)| name.starts_with("./")));
    let out = run(&["validate", dotted.to_str().unwrap()]);
    let said = String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success() && said.contains("valid"), "{said}");
    let stats = |data: &Path| run(&["stats", data.to_str().unwrap(), "--json"]).stdout;
    let (theirs, ours) = (stats(&dotted), stats(&packed));
    assert!(ours.len() > 100, "stats --json of the packed dataset: {}", String::from_utf8_lossy(&ours));
    assert_eq!(theirs, ours, "stats of the hand-made pack are those of gen's");
}

#[test]
fn validate_finds_an_empty_folder_in_a_pack_and_gen_or_the_sweep_rerun_writes_that_pack_again() {
    // Readers pass over a pack's folder entries (`tar -cf` of scenario
    // folders lists them), so a folder entry with no file under it went
    // unseen: validate said "valid", yet `tar -xf` unpacked it as a folder
    // the layout does not have, which validate refuses in a folder dataset.
    let (spec, folders, packed) = both("packs-empty-folder");
    let before = hash_tree(&packed);
    let rel = "cars04_edges50/train/00000-00001.tar";
    let cases: Vec<_> = ["cars04_edges50/train/00001/junk/", "cars04_edges50/train/00007/"]
        .into_iter()
        .map(|folder| (folder, with_folder(&packed.join(rel), folder)))
        .collect();
    let mut checked = 0;
    for (folder, bytes) in cases {
        std::fs::write(packed.join(rel), bytes).unwrap();
        let unpacked = fresh_dir("packs-empty-folder-untar");
        untar_all(&packed, &unpacked);
        assert!(unpacked.join(folder).is_dir(), "tar -xf makes {folder}");
        let out = run(&["validate", packed.to_str().unwrap()]);
        let said = String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{folder}: {said}");
        let name = folder.trim_end_matches('/');
        assert!(said.contains(&format!("{}: {name}/: a folder with no file", packed.join(rel).display())), "{said}");
        // As a folder dataset refuses that folder.
        let copy = fresh_dir("packs-empty-folder-copy");
        for (file, _) in hash_tree(&folders) {
            std::fs::create_dir_all(copy.join(&file).parent().unwrap()).unwrap();
            std::fs::copy(folders.join(&file), copy.join(&file)).unwrap();
        }
        assert!(run(&["validate", copy.to_str().unwrap()]).status.success());
        std::fs::create_dir_all(copy.join(folder)).unwrap();
        assert_eq!(run(&["validate", copy.to_str().unwrap()]).status.code(), Some(1), "{folder} in a folder dataset");
        // gen, resuming, no longer keeps the pack as finished.
        let out = gen_ok(&spec, &packed, PACKED);
        let said = String::from_utf8_lossy(&out.stderr);
        assert!(said.contains("writing the pack again"), "{folder}: {said}");
        assert_eq!(hash_tree(&packed), before, "{folder}: the rewritten pack is the original, byte for byte");
        checked += 1;
    }
    assert_eq!(checked, 2);
    // A counterfactual sweep's packs of pairs, rerun, write theirs again too.
    let sweep = spec.parent().unwrap().join("sweep");
    let args = ["counterfactual", "--sweep", spec.to_str().unwrap(), "--out", sweep.to_str().unwrap(), "--no-images"];
    let args = [&args[..], &["--kinds", "stop", "--format", "tar", "--scenarios-per-tar", "2", "-q"]].concat();
    assert!(run(&args).status.success());
    let made = hash_tree(&sweep);
    let pack = sweep.join("cars04_edges50/test/00000-00001.tar");
    std::fs::write(&pack, with_folder(&pack, "cars04_edges50/test/00000/factual/junk/")).unwrap();
    let out = run(&["validate", sweep.to_str().unwrap()]);
    let said = String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{said}");
    assert!(said.contains("cars04_edges50/test/00000/factual/junk/: a folder with no file"), "{said}");
    let again = run(&args);
    assert!(String::from_utf8_lossy(&again.stderr).contains("writing the pack again"), "the sweep rerun");
    assert_eq!(hash_tree(&sweep), made, "the sweep's pack written again, byte for byte");
}

/// The pack at `path` with a folder entry `folder` (ending in `/`) added
/// after its members.
fn with_folder(path: &Path, folder: &str) -> Vec<u8> {
    let mut builder = tar::Builder::new(Vec::new());
    append_files(&mut builder, &members(path));
    let mut header = tar::Header::new_gnu();
    header.set_entry_type(tar::EntryType::Directory);
    header.set_size(0);
    header.set_mode(0o755);
    builder.append_data(&mut header, folder, std::io::empty()).unwrap();
    builder.into_inner().unwrap()
}
