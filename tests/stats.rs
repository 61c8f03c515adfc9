//! `causalcity stats`: its table agrees with figures computed here straight
//! from the CSV logs, and tells the toy world from the city.

mod common;
use common::*;
use serde_json::Value;

fn stats(dir: &std::path::Path) -> Value {
    let output = run(&["stats", dir.to_str().unwrap(), "--json"]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    serde_json::from_slice(&output.stdout).unwrap()
}

#[test]
fn stats_match_the_logs_and_separate_the_worlds() {
    let dir = fresh_dir("stats");
    let toy = dir.join("toy");
    gen_ok(&write_spec(&dir, &toy_spec("stats-toy", &[(8, 0.5)], (3, 1, 1), 60)), &toy, &["--quiet", "--no-images"]);
    let city = dir.join("city");
    let city_spec_path = dir.join("city.json");
    std::fs::write(
        &city_spec_path,
        city_spec("stats-city", &[(12, 0.5)], (6, 1, 1), 150, r#"{"red_light_runner_probability": 0.3}"#),
    )
    .unwrap();
    gen_ok(&city_spec_path, &city, &["--quiet", "--no-images"]);

    let toy_stats = stats(&toy);
    assert_eq!(toy_stats["world"], "toy");
    for row in toy_stats["rows"].as_array().unwrap() {
        assert!((row["mean_speed_px"].as_f64().unwrap() - 2.0).abs() < 1e-3, "{row}");
        assert!((row["p95_speed_px"].as_f64().unwrap() - 2.0).abs() < 0.011);
        assert_eq!(row["stopped_share"], 0.0);
        assert_eq!(row["collisions"], 0);
        // Constant along the path; the straight-line distance shrinks only
        // on turns and the U-turn loops at the view's sides.
        assert!(row["gap_cv_median"].as_f64().unwrap() < 0.05, "toy gaps are constant: {row}");
    }

    let city_stats = stats(&city);
    let train = &city_stats["rows"][0];
    assert_eq!((train["group"].as_str(), train["split"].as_str()), (Some("cars12_edges50"), Some("train")));
    // Recompute the train row from the files.
    let (mut speed, mut n, mut cars, mut stopped, mut reds, mut in_view) =
        (0.0, 0usize, 0usize, 0usize, 0usize, 0usize);
    let mut speed_m_s = 0.0;
    let (mut changers, mut adapted, mut skipped) = (0usize, 0usize, 0usize);
    // Pair-frames in which one car of a pair names the other in
    // interactions.csv, for leader-follower pairs and the rest.
    let (mut edge_frames, mut edge_together, mut other_frames, mut other_together) = (0usize, 0usize, 0usize, 0usize);
    // Each designed pair's coefficient of variation of its gap (metres).
    let mut gap_cvs = Vec::new();
    for d in scenario_dirs(&city).into_iter().filter(|d| d.to_string_lossy().contains("/train/")) {
        let s = read_scenario(&d);
        let to_px = s.frame_interval * s.camera.pixels_per_metre;
        let by_car = poses_by_car(&read_poses(&d.join("poses.csv")));
        for e in &s.edges {
            let (a, b) = (&by_car[&e[0]], &by_car[&e[1]]);
            let gaps: Vec<f64> = a.iter().zip(b).map(|(p, q)| (p.x - q.x).hypot(p.y - q.y)).collect();
            let mean = gaps.iter().sum::<f64>() / gaps.len() as f64;
            let sd = (gaps.iter().map(|g| (g - mean).powi(2)).sum::<f64>() / gaps.len() as f64).sqrt();
            gap_cvs.push(sd / mean);
        }
        for track in by_car.values() {
            cars += 1;
            let (mut run, mut stop) = (0, false);
            for p in track {
                speed += p.speed * to_px;
                speed_m_s += p.speed;
                n += 1;
                in_view += p.in_view as usize;
                run = if p.speed * to_px < 0.1 { run + 1 } else { 0 };
                stop |= run >= 5;
            }
            stopped += stop as usize;
        }
        let events = read_csv::<EventRow>(&d.join("events.csv"));
        reds += events.iter().filter(|e| e.kind == "red_light_run").count();
        let changed: std::collections::BTreeSet<u32> =
            events.iter().filter(|e| e.kind == "lane_change").filter_map(|e| e.car).collect();
        changers += changed.len();
        adapted += events.iter().filter(|e| e.kind == "action_adapted").count();
        skipped += events.iter().filter(|e| e.kind == "action_skipped").count();
        let mut named = std::collections::BTreeSet::new();
        for row in read_csv::<InteractionRow>(&d.join("interactions.csv")) {
            if let Some(other) = row.other_car {
                named.insert((row.frame, row.car.min(other), row.car.max(other)));
            }
        }
        let n_cars = s.cars.len() as u32;
        for a in 0..n_cars {
            for b in a + 1..n_cars {
                let linked = s.edges.iter().any(|e| (e[0], e[1]) == (a, b) || (e[0], e[1]) == (b, a));
                let together = (0..s.frames).filter(|&f| named.contains(&(f, a, b))).count();
                if linked {
                    (edge_frames, edge_together) = (edge_frames + s.frames as usize, edge_together + together);
                } else {
                    (other_frames, other_together) = (other_frames + s.frames as usize, other_together + together);
                }
            }
        }
    }
    assert!(edge_frames > 0 && other_frames > 0);
    let share = |key: &str| train[key]["frame_share"].as_f64().unwrap();
    assert!((share("edge_pairs") - edge_together as f64 / edge_frames as f64).abs() < 1e-12);
    assert!((share("non_edge_pairs") - other_together as f64 / other_frames as f64).abs() < 1e-12);
    // Leaders hold up their followers far more often than unrelated cars meet.
    assert!(share("edge_pairs") > 3.0 * share("non_edge_pairs"), "{train}");
    assert_eq!(train["scenarios"], 6);
    assert_eq!(train["cars"], cars);
    assert!((train["mean_speed_px"].as_f64().unwrap() - speed / n as f64).abs() < 1e-9);
    assert!((train["mean_speed_m_s"].as_f64().unwrap() - speed_m_s / n as f64).abs() < 1e-9);
    assert!((train["stopped_share"].as_f64().unwrap() - stopped as f64 / cars as f64).abs() < 1e-12);
    assert!((train["in_view_share"].as_f64().unwrap() - in_view as f64 / n as f64).abs() < 1e-12);
    assert_eq!(train["red_light_runs"], reds);
    assert!(changers > 0, "city drivers change lanes for their turns");
    assert!((train["lane_change_share"].as_f64().unwrap() - changers as f64 / cars as f64).abs() < 1e-12);
    assert_eq!(
        (train["actions_adapted"].as_u64(), train["actions_skipped"].as_u64()),
        (Some(adapted as u64), Some(skipped as u64))
    );
    assert!(train["stopped_share"].as_f64().unwrap() > 0.2, "city cars stop");
    assert!(train["gap_cv_median"].as_f64().unwrap() > 0.05, "city gaps vary");
    // The median of an even count is the mean of the middle two (it took
    // the upper one).
    gap_cvs.sort_by(f64::total_cmp);
    let k = gap_cvs.len();
    assert!(k >= 2 && k % 2 == 0, "{k} pairs: an even count tells the two medians apart");
    let median = (gap_cvs[k / 2 - 1] + gap_cvs[k / 2]) / 2.0;
    assert!((train["gap_cv_median"].as_f64().unwrap() - median).abs() < 1e-9, "{train}: median {median}");
    assert!(train["p95_speed_px"].as_f64().unwrap() > train["mean_speed_px"].as_f64().unwrap());

    // The plain table fits a terminal (before: ~190 columns and a
    // 1,000-character legend line), speeds in m/s, each column explained.
    let table = String::from_utf8(run(&["stats", city.to_str().unwrap()]).stdout).unwrap();
    assert!(table.lines().all(|l| l.len() <= 120), "{table}");
    assert!(
        table.contains("cars12_edges50") && table.contains("mean speed, m/s") && table.contains("--wide"),
        "{table}"
    );
    let shown = format!("{:.2}", train["mean_speed_m_s"].as_f64().unwrap());
    assert!(table.lines().nth(1).unwrap().split_whitespace().any(|v| v == shown), "{shown} not in {table}");
    // --wide shows every column, each explained.
    let wide = String::from_utf8(run(&["stats", city.to_str().unwrap(), "--wide"]).stdout).unwrap();
    for column in ["gapCV", "lanechg", "e-int", "disch", "n-mst"] {
        assert!(wide.lines().next().unwrap().contains(column), "{column}: {wide}");
        assert!(wide.lines().any(|l| l.trim_start().starts_with(column)), "{column} unexplained: {wide}");
    }
}

#[test]
fn the_toy_heat_map_is_more_uniform_than_the_city_one() {
    let dir = fresh_dir("heatmap");
    let mut cvs = Vec::new();
    for world in ["toy", "city"] {
        let spec = std::fs::read_to_string(
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("configs/ci-{world}.json")),
        )
        .unwrap()
        .replace(r#""train": 2, "val": 1, "test": 1"#, r#""train": 20, "val": 1, "test": 1"#);
        let spec_path = dir.join(format!("{world}.json"));
        std::fs::write(&spec_path, spec).unwrap();
        let data = dir.join(world);
        gen_ok(&spec_path, &data, &["--quiet", "--no-images"]);
        let png = dir.join(format!("{world}.png"));
        let output =
            run(&["heatmap", data.to_str().unwrap(), "--out", png.to_str().unwrap(), "--split", "train", "--json"]);
        assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
        let summary: Value = serde_json::from_slice(&output.stdout).unwrap();
        assert_eq!(summary["scenarios"], 5 * 20, "--split train keeps the train scenarios of every group");
        let image = image::open(&png).unwrap().into_rgb8();
        assert_eq!(image.dimensions(), (1024 + 100, 18 + 640), "a title, the view, a colour bar and its labels");
        // The bar's tick labels: light digits right of the bar, top to bottom.
        let lit = (18..658).flat_map(|y| (1024 + 36..1024 + 100).map(move |x| (x, y)));
        let digits = lit.filter(|&(x, y)| image.get_pixel(x, y).0 == [235, 235, 235]).count();
        assert!(digits > 100, "colour bar labels: {digits} digit pixels");
        // A title in the band above the view.
        let title = (0..18).flat_map(|y| (0..1024).map(move |x| (x, y)));
        let letters = title.filter(|&(x, y)| image.get_pixel(x, y).0 == [235, 235, 235]).count();
        assert!(letters > 500, "title: {letters} text pixels");
        // The roads show where no car came (grey), the ground stays dark.
        let view = (18..658).flat_map(|y| (0..1024).map(move |x| (x, y)));
        let (mut road, mut ground) = (0, 0);
        for (x, y) in view {
            match image.get_pixel(x, y).0 {
                [88, 88, 96] => road += 1,
                [24, 24, 28] => ground += 1,
                _ => {}
            }
        }
        assert!(road > 10_000 && ground > 100_000, "{world}: {road} road and {ground} ground pixels");
        cvs.push(summary["visited_cell_cv"].as_f64().unwrap());
    }
    assert!(cvs[0] < 0.6 * cvs[1], "toy dwell CV {} should be well below the city's {}", cvs[0], cvs[1]);
    let bad = run(&["heatmap", dir.join("toy").to_str().unwrap(), "--out", "/tmp/x.png", "--group", "cars99_edges50"]);
    assert_eq!(bad.status.code(), Some(2), "a group the dataset lacks is bad input");
    assert!(String::from_utf8_lossy(&bad.stderr).contains("use one of cars04_edges50"));
    let gif = dir.join("h.gif");
    let bad = run(&["heatmap", dir.join("toy").to_str().unwrap(), "--out", gif.to_str().unwrap()]);
    assert_eq!(bad.status.code(), Some(2), "{}", String::from_utf8_lossy(&bad.stderr));
    assert!(String::from_utf8_lossy(&bad.stderr).contains(".png") && !gif.exists());
}

#[test]
fn the_city_presets_drive_like_traffic_by_the_stats_figures() {
    let dir = fresh_dir("stats-presets");
    let configs = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("configs");
    // The default (slowed, scaled) city: the time gap while following, the
    // part that grows with speed, is a real driver's 1-2 s.
    let city = dir.join("city");
    gen_ok(&configs.join("city.json"), &city, &["--quiet", "--no-images", "--limit", "12"]);
    let rows = stats(&city)["rows"].as_array().unwrap().clone();
    assert_eq!(rows.len(), 15);
    for row in &rows {
        let gap = row["time_gap_median_s"].as_f64().unwrap_or_else(|| panic!("no time gap: {row}"));
        assert!((1.0..=2.0).contains(&gap), "time gap {gap:.2} s: {row}");
        // One frame a second as the paper samples (issue 23): a car moves
        // about 10 px a frame on the 48 m camera (1.5-3 px at 0.2 s frames).
        let speed = row["mean_speed_px"].as_f64().unwrap();
        assert!((6.0..=14.0).contains(&speed), "mean {speed:.2} px per frame: {row}");
    }
    // The real-scale preset: headways of urban traffic, queues leaving at
    // the saturation flow of real signalised lanes, cars at their desired
    // speed on free road.
    let metric = dir.join("metric");
    gen_ok(&configs.join("city-metric.json"), &metric, &["--quiet", "--no-images", "--limit", "20"]);
    let rows = stats(&metric)["rows"].as_array().unwrap().clone();
    assert_eq!(rows.len(), 6);
    for row in &rows {
        let headway = row["headway_median_s"].as_f64().unwrap_or_else(|| panic!("no headway: {row}"));
        assert!((1.0..=2.5).contains(&headway), "headway {headway:.2} s: {row}");
        let free = row["free_speed_ratio_median"].as_f64().unwrap();
        assert!((0.9..=1.05).contains(&free), "free-road speed {free:.2} of desired: {row}");
        let discharge = row["discharge_per_lane_s"].as_f64().unwrap_or_else(|| panic!("no queue discharged: {row}"));
        assert!((0.4..=0.6).contains(&discharge), "queue discharge {discharge:.3} vehicles/s/lane: {row}");
    }
}

#[test]
fn every_reader_of_a_dataset_refuses_a_folder_that_is_none_with_exit_2() {
    let dir = fresh_dir("not-a-dataset");
    // Also a folder whose name reads like a reader's own write failing
    // (it was told by those words, and exited 1).
    let worded = dir.join("cannot write x");
    std::fs::create_dir_all(&worded).unwrap();
    let heatmap = dir.join("h.png");
    let mut checked = 0;
    for missing in [dir.join("nonexistent"), worded] {
        let missing = missing.to_str().unwrap();
        let commands: [&[&str]; 5] = [
            &["stats", missing],
            &["baseline", missing],
            &["evaluate", missing, "x.npz"],
            &["validate", missing],
            &["heatmap", missing, "--out", heatmap.to_str().unwrap()],
        ];
        for args in commands {
            let output = run(args);
            let stderr = String::from_utf8_lossy(&output.stderr);
            assert_eq!(output.status.code(), Some(2), "{args:?}: {stderr}");
            assert!(stderr.contains("no manifest.json"), "{args:?}: {stderr}");
            checked += 1;
        }
    }
    assert_eq!(checked, 10);
    assert!(!heatmap.exists());
}
