//! Spec expansion, checked from written datasets: counts, edges, roles,
//! placement, id permutation and determinism across thread counts.

mod common;
use causalcity::geometry::OrientedBox;
use common::*;
use glam::DVec2;
use std::collections::{BTreeMap, BTreeSet};

fn expected_edges(cars: u32, p: f64) -> usize {
    let e = (p * cars as f64 / 2.0).round() as usize;
    if p > 0.0 {
        e.max(1)
    } else {
        e
    }
}

#[test]
fn counts_edges_and_roles_follow_the_spec() {
    let dir = fresh_dir("expansion-counts");
    let groups = [(4, 0.5), (8, 0.2), (8, 0.8), (12, 0.5), (5, 0.0), (7, 0.6)];
    let spec = write_spec(&dir, &toy_spec("counts", &groups, (3, 2, 1), 20));
    let out = dir.join("out");
    gen_ok(&spec, &out, &["--no-images", "--quiet"]);

    let manifest = read_json(&out.join("manifest.json"));
    assert_eq!(manifest["scenarios"], 6 * groups.len());
    for (cars, p) in groups {
        let group = format!("cars{cars:02}_edges{:02}", (p * 100.0_f64).round() as u32);
        for (split, n) in [("train", 3), ("val", 2), ("test", 1)] {
            let dirs = sorted_entries(&out.join(&group).join(split));
            assert_eq!(dirs.len(), n, "{group}/{split}");
            for (i, d) in dirs.iter().enumerate() {
                assert_eq!(d.file_name().unwrap().to_str().unwrap(), format!("{i:05}"));
                let s = read_scenario(d);
                assert_eq!(s.cars.len(), cars as usize);
                let edges = expected_edges(cars, p);
                assert_eq!(s.edges.len(), edges, "{}", d.display());
                let count = |role: &str| s.cars.iter().filter(|c| c.role == role).count();
                assert_eq!(count("leader"), edges);
                assert_eq!(count("follower"), edges);
                assert_eq!(count("independent"), cars as usize - 2 * edges);
                let gap_m = s.toy.as_ref().unwrap().leader_gap_m;
                for [l, f] in &s.edges {
                    let (leader, follower) = (&s.cars[*l as usize], &s.cars[*f as usize]);
                    assert_eq!((leader.role.as_str(), follower.role.as_str()), ("leader", "follower"));
                    assert_eq!(leader.spawn, follower.spawn);
                    assert_eq!(leader.actions, follower.actions);
                    assert_eq!(leader.merge_distances, follower.merge_distances);
                    assert!((leader.spawn_distance - follower.spawn_distance - gap_m).abs() < 2e-3);
                }
                for c in &s.cars {
                    assert_eq!(c.actions.len(), 5);
                    assert_eq!(c.merge_distances.len(), 5);
                }
            }
        }
    }
}

#[test]
fn limit_caps_every_split() {
    let dir = fresh_dir("expansion-limit");
    let spec = write_spec(&dir, &toy_spec("limit", &[(4, 0.5), (8, 0.5)], (4000, 500, 500), 10));
    let out = dir.join("out");
    gen_ok(&spec, &out, &["--no-images", "--quiet", "--limit", "2"]);
    assert_eq!(scenario_dirs(&out).len(), 2 * 3 * 2);
    let manifest = read_json(&out.join("manifest.json"));
    assert_eq!(manifest["limit"], 2);
    assert_eq!(manifest["groups"][0]["splits"]["train"], 2);
}

#[test]
fn no_two_cars_start_overlapping() {
    let dir = fresh_dir("expansion-overlap");
    let spec = write_spec(&dir, &toy_spec("overlap", &[(12, 0.5), (12, 1.0), (30, 0.5)], (20, 0, 0), 2));
    let out = dir.join("out");
    gen_ok(&spec, &out, &["--no-images", "--quiet"]);
    for d in scenario_dirs(&out) {
        let s = read_scenario(&d);
        let first: Vec<Pose> = read_poses(&d.join("poses.csv")).into_iter().filter(|p| p.frame == 0).collect();
        let boxes: Vec<OrientedBox> = first
            .iter()
            .map(|p| {
                let car = &s.cars[p.car as usize];
                OrientedBox { centre: DVec2::new(p.x, p.y), heading: p.yaw, length: car.length_m, width: car.width_m }
            })
            .collect();
        for i in 0..boxes.len() {
            for j in i + 1..boxes.len() {
                assert!(!boxes[i].overlaps(&boxes[j]), "{}: cars {i} and {j} overlap at frame 0", d.display());
            }
            assert_eq!(first[i].in_view, 1, "cars start on camera");
        }
    }
}

#[test]
fn ids_are_permuted_so_the_index_hides_the_role() {
    let dir = fresh_dir("expansion-ids");
    let spec = write_spec(&dir, &toy_spec("ids", &[(8, 0.5)], (30, 0, 0), 2));
    let out = dir.join("out");
    gen_ok(&spec, &out, &["--no-images", "--quiet"]);
    let mut role_patterns = BTreeSet::new();
    let mut leader_first = 0;
    let mut follower_first = 0;
    for d in scenario_dirs(&out) {
        let s = read_scenario(&d);
        let ids: BTreeSet<u32> = s.cars.iter().map(|c| c.id).collect();
        assert_eq!(ids, (0..8).collect(), "ids are 0..N-1");
        role_patterns.insert(s.cars.iter().map(|c| c.role.clone()).collect::<Vec<_>>());
        for [l, f] in &s.edges {
            if l < f {
                leader_first += 1;
            } else {
                follower_first += 1;
            }
        }
    }
    assert!(role_patterns.len() >= 10, "role order by id should vary, saw {} patterns", role_patterns.len());
    assert!(leader_first > 0 && follower_first > 0, "leader/follower id order should vary");
}

#[test]
fn same_spec_same_bytes_for_any_thread_count() {
    let dir = fresh_dir("expansion-determinism");
    let spec = write_spec(&dir, &toy_spec("det", &[(4, 0.5), (8, 0.8)], (3, 1, 1), 12));
    let runs: Vec<BTreeMap<String, String>> = [("j1", "1"), ("j2", "2"), ("j2-again", "2")]
        .iter()
        .map(|(name, threads)| {
            let out = dir.join(name);
            gen_ok(&spec, &out, &["--quiet", "-j", threads]);
            hash_tree(&out)
        })
        .collect();
    assert!(runs[0].len() > 10 * 24, "images were written");
    assert_eq!(runs[0], runs[1], "-j 1 and -j 2 differ");
    assert_eq!(runs[1], runs[2], "two identical runs differ");
    // A different seed changes the content.
    let other = write_spec(
        &dir,
        &toy_spec("det", &[(4, 0.5), (8, 0.8)], (3, 1, 1), 12).replace("\"seed\": 11", "\"seed\": 12"),
    );
    let out = dir.join("other-seed");
    gen_ok(&other, &out, &["--quiet", "--no-images"]);
    let a = std::fs::read(dir.join("j1/cars04_edges50/train/00000/poses.csv")).unwrap();
    let b = std::fs::read(out.join("cars04_edges50/train/00000/poses.csv")).unwrap();
    assert_ne!(a, b, "the seed should matter");
}
