//! Opening a dataset or a sweep, and merging shards, walk the spec's
//! scenario keys instead of listing them: the memory they take does not
//! grow with the number of scenarios. Measured with an allocator that
//! counts the bytes live at once (this test binary's own), on real files.

mod common;
use causalcity::dataset::{Dataset, Sweep};
use common::*;
use serde_json::Value;
use std::alloc::{GlobalAlloc, Layout, System};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

/// The system allocator, counting the bytes live and their peak.
struct Counting;

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            let live = LIVE.fetch_add(layout.size(), Ordering::Relaxed) + layout.size();
            PEAK.fetch_max(live, Ordering::Relaxed);
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) };
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// The tests of this file one at a time, so that each measures its own.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

/// What `f` returns, and the most bytes live at once while it ran beyond
/// those live when it started. The thread pool's workers are started
/// first, so that no measurement pays for them.
fn peak_growth<T>(f: impl FnOnce() -> T) -> (T, usize) {
    rayon::broadcast(|_| ());
    let start = LIVE.load(Ordering::Relaxed);
    PEAK.store(start, Ordering::Relaxed);
    let value = f();
    (value, PEAK.load(Ordering::Relaxed).saturating_sub(start))
}

/// A copy of the finished dataset `from` whose manifest's spec asks for
/// `per_split` scenarios in every split, and whose run had no limit: a
/// manifest as large as a paper-size run's, on small files.
fn claiming(from: &Path, to: &Path, per_split: u32) -> PathBuf {
    std::fs::create_dir_all(to).unwrap();
    let mut manifest: Value = serde_json::from_slice(&std::fs::read(from.join("manifest.json")).unwrap()).unwrap();
    manifest["spec"]["splits"] = serde_json::json!({"train": per_split, "val": per_split, "test": per_split});
    manifest["limit"] = Value::Null;
    // Its hash as gen records it, for the spec it now claims.
    let spec: causalcity::spec::DatasetSpec = serde_json::from_value(manifest["spec"].clone()).unwrap();
    let spec = causalcity::plan::Expansion::from_spec(spec).unwrap().spec;
    manifest["spec_sha256"] = causalcity::output::manifest::spec_sha256(&spec).into();
    std::fs::write(to.join("manifest.json"), manifest.to_string()).unwrap();
    to.to_path_buf()
}

#[test]
fn opening_a_dataset_or_a_sweep_takes_the_same_memory_for_a_thousand_scenarios_as_for_three_million() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let dir = fresh_dir("bounded-open");
    let spec = write_spec(&dir, &toy_spec("bounded", &[(4, 0.5)], (2, 1, 1), 5));
    let made = dir.join("made");
    gen_ok(&spec, &made, &["--quiet", "--no-images", "--no-effects"]);
    // Once unmeasured: whatever is made once per process is made here.
    let opened = Dataset::open(&made).unwrap();
    // One group and split's folders are its run of the key sequence.
    for split in causalcity::spec::Split::ALL {
        let listed: Vec<String> = opened
            .keys()
            .filter(|k| k.split == split)
            .map(|k| format!("{}/{}", k.split.name(), k.folder_name()))
            .collect();
        let dirs = opened.scenario_dirs("cars04_edges50", split).unwrap();
        let named: Vec<String> =
            dirs.iter().map(|d| d.strip_prefix(made.join("cars04_edges50")).unwrap().display().to_string()).collect();
        assert_eq!(named, listed);
        assert!(dirs.iter().all(|d| d.join("scenario.json").is_file()));
    }
    drop(opened);
    let mut peaks = Vec::new();
    for per_split in [1_000u32, 1_000_000] {
        let folder = claiming(&made, &dir.join(format!("claims-{per_split}")), per_split);
        let (walked, peak) = peak_growth(|| {
            let dataset = Dataset::open(&folder).unwrap();
            // Walking every key costs no more than opening.
            dataset.keys().filter(|k| k.index + 1 == per_split).count()
        });
        assert_eq!(walked, 3, "one last scenario per split");
        // A sweep's record names the same spec.
        let manifest: Value = serde_json::from_slice(&std::fs::read(folder.join("manifest.json")).unwrap()).unwrap();
        let sweep_dir = dir.join(format!("sweep-{per_split}"));
        std::fs::create_dir_all(&sweep_dir).unwrap();
        let record = serde_json::json!({"format": "causalcity-counterfactual-sweep/1", "spec": manifest["spec"], "limit": null, "complete": true, "kinds": ["stop"]});
        std::fs::write(sweep_dir.join("sweep.json"), record.to_string()).unwrap();
        let (pairs, sweep_peak) = peak_growth(|| Sweep::open(&sweep_dir).unwrap().unwrap().key_sequence().len());
        assert_eq!(pairs, 3 * per_split as usize);
        eprintln!("{per_split} per split: open and walk {peak} bytes at most, sweep {sweep_peak}");
        peaks.push((peak, sweep_peak));
    }
    // Listing 3 million keys would take more than 100 MB.
    let (small, large) = (peaks[0], peaks[1]);
    assert!(small.0 < 1024 * 1024 && small.1 < 1024 * 1024, "{small:?} bytes to open 3,000 scenarios");
    assert!(large.0 < small.0 + 64 * 1024, "opening: {} bytes for 3,000 scenarios, {} for 3 million", small.0, large.0);
    assert!(large.1 < small.1 + 64 * 1024, "sweep: {} bytes for 3,000 pairs, {} for 3 million", small.1, large.1);
}

#[test]
fn merging_shards_takes_the_same_memory_for_three_hundred_scenarios_as_for_twelve_hundred() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let dir = fresh_dir("bounded-merge");
    let mut peaks = Vec::new();
    for train in [300u32, 1200] {
        let spec = write_spec(&dir, &toy_spec(&format!("merge{train}"), &[(4, 0.5)], (train, 0, 0), 3));
        let (shard0, shard1, out) =
            (dir.join(format!("s0-{train}")), dir.join(format!("s1-{train}")), dir.join(format!("out-{train}")));
        gen_ok(&spec, &shard0, &["--quiet", "--no-images", "--no-effects", "--shard", "0/2"]);
        gen_ok(&spec, &shard1, &["--quiet", "--no-images", "--no-effects", "--shard", "1/2"]);
        let (merged, peak) = peak_growth(|| causalcity::orchestrate::merge::merge(&out, &[shard0, shard1]));
        let message = merged.unwrap_or_else(|e| panic!("merge failed: {e}"));
        assert!(message.contains(&format!("{train} scenarios")), "{message}");
        assert_eq!(scenario_dirs(&out).len(), train as usize);
        eprintln!("{train} scenarios: merge {peak} bytes at most");
        peaks.push(peak);
    }
    // Listing them, with their moves, would take about 300 bytes a scenario.
    assert!(peaks[0] < 4 * 1024 * 1024, "merge: {} bytes for 300 scenarios", peaks[0]);
    assert!(peaks[1] < peaks[0] + 64 * 1024, "merge: {} bytes for 300 scenarios, {} for 1,200", peaks[0], peaks[1]);
}
