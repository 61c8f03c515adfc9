//! Reading a real SUMO network (`causalcity map --net`): what it keeps, the
//! picture it draws, and what it refuses.

mod common;
use common::*;

fn berlin() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/sumo/berlin-small.net.xml")
}

#[test]
fn a_real_network_is_listed_with_its_junctions_and_the_lanes_cars_drive_and_drawn() {
    let dir = fresh_dir("sumo-berlin");
    let picture = dir.join("berlin.png");
    let listed = run(&["map", "--net", berlin().to_str().unwrap(), "--out", picture.to_str().unwrap(), "--json"]);
    assert!(listed.status.success(), "{}", String::from_utf8_lossy(&listed.stderr));
    let summary: serde_json::Value = serde_json::from_slice(&listed.stdout).unwrap();
    let junctions = summary["junctions"].as_array().unwrap();
    let kinds = |kind: &str| junctions.iter().filter(|j| j["kind"] == kind).count();
    assert_eq!((junctions.len(), kinds("traffic_light"), kinds("priority"), kinds("dead_end")), (17, 2, 14, 1));
    // Only lanes that allow cars; the crossings and walking areas are counted as left out.
    let lanes = summary["lanes"].as_array().unwrap();
    assert_eq!(lanes.len(), 48);
    assert!(lanes.iter().all(|l| !l["id"].as_str().unwrap().starts_with(':')), "an internal or pedestrian lane");
    assert_eq!(summary["actuated_programmes"], 1);
    let left_out: Vec<(String, u64)> = serde_json::from_value(summary["left_out"].clone()).unwrap();
    assert!(left_out.contains(&("pedestrian crossings".into(), 27)), "{left_out:?}");
    // Every lane ends at a listed junction; most lead on.
    let leading = lanes.iter().filter(|l| !l["turns"].as_array().unwrap().is_empty()).count();
    assert!(leading >= 44, "only {leading} lanes lead on");
    assert!(lanes.iter().all(|l| (l["junction"].as_u64().unwrap() as usize) < junctions.len()));

    // The picture: asphalt along the lanes, a green mark on each junction with lights.
    let image = image::open(&picture).unwrap().to_rgb8();
    assert_eq!(image.width().max(image.height()), 1200);
    let count = |rgb: [u8; 3]| image.pixels().filter(|p| p.0 == rgb).count();
    let asphalt = count([66, 68, 72]);
    assert!(asphalt > 20_000, "{asphalt} asphalt pixels");
    assert!(count([40, 170, 70]) > 10, "no traffic-light mark");
    // The text listing says the same.
    let text = run(&["map", "--net", berlin().to_str().unwrap()]);
    let stdout = String::from_utf8_lossy(&text.stdout);
    assert!(stdout.contains("17 junctions (14 priority, 1 dead_end, 2 traffic_light)"), "{stdout}");
    // Both programmes are type="actuated"; one has a phase with minDur < maxDur.
    assert!(stdout.contains("48 lanes cars drive, 79 connections, 2 traffic-light programmes (1 actuated"), "{stdout}");
    // What a spec's map.sumo would drive of it: every lane, with loops where its 4 dead-end lanes end.
    assert!(
        stdout.contains("as map.sumo: 48 lanes driven, 4 U-turn loops added where roads end, 0 lanes left out"),
        "{stdout}"
    );
    assert_eq!(summary["driving"]["Ok"]["lanes"], 48);
}

#[test]
fn a_network_that_cannot_be_imported_is_refused_naming_the_element_and_nothing_is_written() {
    let dir = fresh_dir("sumo-refused");
    let text = std::fs::read_to_string(berlin()).unwrap();
    // A rail crossing where cars drive; a lane with a broken shape.
    let junction = r#"<junction id="1560592097" type="priority""#;
    let lane = r#"<lane id="-172014854#1_1" index="1""#;
    assert!(text.contains(junction) && text.contains(lane));
    let broken_shape = {
        let start = text.find(lane).unwrap();
        let shape = start + text[start..].find("shape=\"").unwrap() + 7;
        format!("{}12,x{}", &text[..shape], &text[shape..])
    };
    // The same lane moved 5 km east (its ends no longer on the junctions its
    // edge names: cars drove a straight line over no road to its
    // connections), and given a length of inf ("must be positive").
    let (moved, endless) = {
        let start = text.find(lane).unwrap();
        let shape = start + text[start..].find("shape=\"").unwrap() + 7;
        let end = shape + text[shape..].find('"').unwrap();
        let points: Vec<String> = text[shape..end]
            .split(' ')
            .map(|p| {
                let (x, y) = p.split_once(',').unwrap();
                format!("{},{y}", x.parse::<f64>().unwrap() + 5000.0)
            })
            .collect();
        let length = start + text[start..].find("length=\"").unwrap() + 8;
        let length_end = length + text[length..].find('"').unwrap();
        (
            format!("{}{}{}", &text[..shape], points.join(" "), &text[end..]),
            format!("{}inf{}", &text[..length], &text[length_end..]),
        )
    };
    // A 201 m lane whose written shape stops 40 m along it: refused, unless
    // its endOffset says it ends that far before its junction (SUMO cuts
    // the shape it writes by it: a stop line set back).
    let (cut, set_back) = {
        let long = r#"<lane id="190083608#1_1""#;
        let start = text.find(long).unwrap();
        let shape = start + text[start..].find("shape=\"").unwrap() + 7;
        let end = shape + text[shape..].find('"').unwrap();
        let points: Vec<(f64, f64)> = text[shape..end]
            .split(' ')
            .map(|p| {
                let (x, y) = p.split_once(',').unwrap();
                (x.parse().unwrap(), y.parse().unwrap())
            })
            .collect();
        let (mut kept, mut along) = (vec![points[0]], 0.0);
        for pair in points.windows(2) {
            let ((x0, y0), (x1, y1)) = (pair[0], pair[1]);
            let step = ((x1 - x0).powi(2) + (y1 - y0).powi(2)).sqrt();
            if along + step >= 40.0 {
                let f = (40.0 - along) / step;
                kept.push((x0 + f * (x1 - x0), y0 + f * (y1 - y0)));
                break;
            }
            along += step;
            kept.push((x1, y1));
        }
        let shape_text: Vec<String> = kept.iter().map(|(x, y)| format!("{x:.2},{y:.2}")).collect();
        let cut = format!("{}{}{}", &text[..shape], shape_text.join(" "), &text[end..]);
        let set_back = cut.replacen(long, &format!(r#"{long} endOffset="161.24""#), 1);
        (cut, set_back)
    };
    let accepted = dir.join("set-back.net.xml");
    std::fs::write(&accepted, set_back).unwrap();
    let listed = run(&["map", "--net", accepted.to_str().unwrap()]);
    assert!(listed.status.success(), "endOffset: {}", String::from_utf8_lossy(&listed.stderr));
    for (name, bad, needle) in [
        ("cut", cut, r#"<lane id="190083608#1_1">: ends at"#),
        ("moved", moved, r#"<lane id="-172014854#1_1">: starts at"#),
        ("endless", endless, r#"<lane id="-172014854#1_1">: length inf m; allowed: a number above 0"#),
        (
            "rail",
            text.replacen(junction, r#"<junction id="1560592097" type="rail_crossing""#, 1),
            r#"<junction id="1560592097" type="rail_crossing">"#,
        ),
        ("shape", broken_shape, r#"<lane id="-172014854#1_1">: shape"#),
        ("not-xml", "<html><body>hello".to_string(), "not a SUMO network"),
        // A junction given twice (the second replaced the first and its
        // light was dropped), a connection from an edge the file does not
        // have (dropped, and the lanes behind it with it): refused.
        (
            "twice",
            text.replacen("</net>", r#"<junction id="1560592097" type="priority" x="0" y="0"/></net>"#, 1),
            r#"<junction id="1560592097">: defined twice"#,
        ),
        (
            "typo",
            text.replacen(r#"<connection from=""#, r#"<connection from="no-such-edge"#, 1),
            r#"from="no-such-edge"#,
        ),
    ] {
        let net = dir.join(format!("{name}.net.xml"));
        std::fs::write(&net, bad).unwrap();
        let out = dir.join(format!("{name}.png"));
        let refused = run(&["map", "--net", net.to_str().unwrap(), "--out", out.to_str().unwrap()]);
        let stderr = String::from_utf8_lossy(&refused.stderr);
        assert_eq!(refused.status.code(), Some(2), "{name}: {stderr}");
        assert!(stderr.contains(needle), "{name}: {stderr}");
        assert!(!out.exists(), "{name}: wrote a picture");
    }
    // A missing file, a picture that is no PNG, the network as its own
    // picture, and --spec with --net: exit 2, the input untouched.
    let before = std::fs::read(berlin()).unwrap();
    for args in [
        vec!["map", "--net", "/no/such.net.xml"],
        vec!["map", "--net", berlin().to_str().unwrap(), "--out", dir.join("x.jpg").to_str().unwrap()],
        vec!["map", "--net", berlin().to_str().unwrap(), "--out", berlin().to_str().unwrap()],
        vec!["map", "--net", berlin().to_str().unwrap(), "--spec", "configs/city.json"],
    ] {
        let refused = run(&args);
        assert_eq!(refused.status.code(), Some(2), "{args:?}: {}", String::from_utf8_lossy(&refused.stderr));
    }
    assert_eq!(std::fs::read(berlin()).unwrap(), before);
    // A named pipe given as the network was waited on for ever: refused.
    let fifo = dir.join("pipe.net.xml");
    assert!(std::process::Command::new("mkfifo").arg(&fifo).status().unwrap().success());
    let refused = run_within(&["map", "--net", fifo.to_str().unwrap()], 60);
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert_eq!(refused.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("pipe.net.xml: not a regular file"), "{stderr}");
}

#[test]
fn a_damaged_network_is_refused_in_a_few_words_and_never_hangs() {
    // From a helper's audit: an internal lane leading on into itself (its
    // shape empty) looped for ever in `map`, `gen` and `run`; a file of
    // zero bytes, or an attribute of millions of characters, was quoted
    // whole (a 1 GB file gave 2 GB of error); a root other than <net>, and
    // phases of different lengths, were taken as a network.
    let dir = fresh_dir("sumo-damaged");
    let grid = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/sumo/grid2-arrows.net.xml");
    let text = std::fs::read_to_string(&grid).unwrap();
    let (lane, onward) = (
        r#"<lane id=":A1_8_0" index="0" speed="6.51" length="9.03" shape=""#,
        r#"<connection from=":A1_8" to="A1B1" fromLane="0" toLane="0" "#,
    );
    assert!(text.contains(lane) && text.contains(onward));
    let circle = {
        let start = text.find(lane).unwrap() + lane.len();
        let end = start + text[start..].find('"').unwrap();
        let emptied = format!("{}{}", &text[..start], &text[end..]);
        emptied.replacen(onward, &format!(r#"{onward}via=":A1_8_0" "#), 1)
    };
    let programme = text.find("<phase ").map(|at| at + text[at..].find("state=\"").unwrap() + 7).unwrap();
    let short_phase =
        format!("{}rG\"/>{}", &text[..programme], &text[programme + text[programme..].find("/>").unwrap() + 2..]);
    let long_value = text.replacen(r#"speed="6.51""#, &format!(r#"speed="{}x""#, "9".repeat(1_000_000)), 1);
    let osm = text.replacen("<net ", "<osm ", 1).replacen("</net>", "</osm>", 1);
    let mut checked = 0;
    for (name, bad, needle) in [
        ("circle", circle, "its internal lanes lead round in a circle (via :A1_8_0 comes back to :A1_8_0)"),
        ("zeros", "\0".repeat(1 << 20), "it holds no XML element: not a SUMO network"),
        ("long-value", long_value, "characters left out"),
        ("osm", osm, "its root element is <osm>, not <net>"),
        ("phases", short_phase, "letters, the first phase's"),
    ] {
        let net = dir.join(format!("{name}.net.xml"));
        std::fs::write(&net, bad).unwrap();
        let out = dir.join(format!("{name}.png"));
        let refused = run_within(&["map", "--net", net.to_str().unwrap(), "--out", out.to_str().unwrap()], 60);
        let stderr = String::from_utf8_lossy(&refused.stderr);
        assert_eq!(refused.status.code(), Some(2), "{name}: {stderr}");
        assert!(stderr.contains(needle), "{name}: {stderr}");
        assert!(stderr.len() < 1000, "{name}: {} bytes of error", stderr.len());
        assert!(!out.exists(), "{name}: wrote a picture");
        checked += 1;
    }
    assert_eq!(checked, 5);
    // gen through a spec naming the circular network: refused, not hung.
    let spec = r#"{"name": "circle", "world": "city", "seed": 1, "frames": 5, "frame_interval": 1.0,
        "groups": [{"cars": 4, "edge_proportion": 0.5}], "splits": {"train": 1, "val": 0, "test": 0},
        "map": {"sumo": "circle.net.xml"}}"#;
    std::fs::write(dir.join("circle.json"), spec).unwrap();
    let (spec, out) = (dir.join("circle.json"), dir.join("data"));
    let refused = run_within(&["gen", "--spec", spec.to_str().unwrap(), "--out", out.to_str().unwrap(), "-q"], 60);
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert_eq!(refused.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("lead round in a circle"), "{stderr}");
    assert!(!out.exists());
}

#[test]
fn imported_traffic_lights_run_the_files_programmes_without_crossing_greens() {
    use causalcity::map::signals::{Colour, Signal};
    let text = std::fs::read_to_string(berlin()).unwrap();
    let net = causalcity::map::sumo::SumoNetwork::from_xml(&text).unwrap();
    let (map, report) = causalcity::map::CityMap::from_sumo(&net, 6.0).unwrap();
    assert_eq!((report.lanes, report.dropped.len()), (48, 0));
    let signalised: Vec<&str> = map.signalised().iter().map(|&k| map.intersections[k].name.as_str()).collect();
    assert_eq!(signalised.len(), 2, "{signalised:?}");
    let (mut checked, mut programmed) = (0, 0);
    for &k in map.signalised() {
        let name = &map.intersections[k].name;
        // The programme the junction's connections name.
        let junction = net.junctions.iter().position(|j| &j.id == name).unwrap();
        let programme = net
            .connections
            .iter()
            .filter(|c| net.lanes[c.from].to == junction)
            .find_map(|c| c.signal)
            .map(|(p, _)| &net.programmes[p])
            .expect("a programme per light junction");
        let cycle: f64 = programme.phases.iter().map(|p| p.0).sum();
        let lights: Vec<_> = map.programmed.iter().filter(|l| l.intersection == k).collect();
        assert!(!lights.is_empty(), "{name}: no programmed light");
        programmed += lights.len();
        for light in &lights {
            let period: f64 = light.schedule.iter().map(|s| s.duration).sum();
            assert!((period - cycle).abs() < 1e-9, "{name}: a light's period {period} s, the programme's {cycle} s");
            // Each shows a real programme: green and red in turn.
            assert!(light.schedule.iter().any(|s| s.colour == Colour::Green));
            assert!(light.schedule.iter().any(|s| s.colour == Colour::Red));
        }
        // Straight-on traffic from crossing sides is never green at once.
        let straight = |a: char| lights.iter().find(|l| l.approach == a && l.signal == Signal::Straight);
        for (a, b) in [('N', 'E'), ('N', 'W'), ('S', 'E'), ('S', 'W')] {
            let (Some(x), Some(y)) = (straight(a), straight(b)) else { continue };
            for step in 0..(cycle * 4.0) as usize {
                let t = step as f64 / 4.0;
                let both = x.state_at(t).colour == Colour::Green && y.state_at(t).colour == Colour::Green;
                assert!(!both, "{name}: {a} and {b} straight both green at {t} s");
            }
            checked += 1;
        }
    }
    assert!(checked >= 2, "only {checked} pairs of crossing approaches compared");
    assert_eq!(programmed, map.programmed.len());
    assert!(programmed >= 5, "{programmed} lights run a programme");
}

#[test]
fn a_network_cars_cannot_drive_round_says_why() {
    // One one-way street between two dead ends: "no lane cars drive is
    // left", with no word of why.
    let dir = fresh_dir("sumo-one-way");
    let net = dir.join("one-way.net.xml");
    std::fs::write(
        &net,
        r#"<net version="1.9">
  <location netOffset="0.00,0.00" convBoundary="0.00,0.00,200.00,0.00" origBoundary="0,0,200,0" projParameter="!"/>
  <edge id="AB" from="A" to="B" priority="1">
    <lane id="AB_0" index="0" speed="13.89" length="200.00" shape="0.00,-1.60 200.00,-1.60"/>
  </edge>
  <junction id="A" type="dead_end" x="0.00" y="0.00" incLanes="" intLanes="" shape="0.00,0.00 0.00,-3.20"/>
  <junction id="B" type="dead_end" x="200.00" y="0.00" incLanes="AB_0" intLanes="" shape="200.00,-3.20 200.00,0.00"/>
</net>"#,
    )
    .unwrap();
    let listed = run(&["map", "--net", net.to_str().unwrap()]);
    let stdout = String::from_utf8_lossy(&listed.stdout);
    assert!(
        stdout.contains("cannot be driven: no two lanes cars drive reach each other: the one lane cars may drive is left out (AB_0 leads nowhere)"),
        "{stdout}"
    );
    assert!(stdout.contains("a street both ways, or a loop"), "{stdout}");
    // A spec naming it is refused the same way, nothing written.
    let spec = dir.join("spec.json");
    std::fs::write(
        &spec,
        city_spec("one-way", &[(2, 0.5)], (1, 0, 0), 5, "{}").replacen(
            "\"world\": \"city\",",
            &format!("\"world\": \"city\", \"map\": {{\"sumo\": {:?}}},", net.to_str().unwrap()),
            1,
        ),
    )
    .unwrap();
    let out = dir.join("out");
    let refused = run(&["gen", "--spec", spec.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert_eq!(refused.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("AB_0 leads nowhere") && stderr.contains("map.sumo"), "{stderr}");
    assert!(!out.exists());
}
