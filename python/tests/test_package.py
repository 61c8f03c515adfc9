"""The Python package against the files the command line writes.

`make test-python` installs the package (`pip install ./python`), generates
small datasets with `causalcity gen` / `counterfactual` into
$CAUSALCITY_DATA and runs these tests; $CAUSALCITY_CLI is the command that
runs the binary. Every comparison is exact: the package must hold the very
values the files hold. Needs numpy, pytest and Pillow (to decode the PNGs).
"""

import csv
import hashlib
import json
import os
import pickle
import shlex
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import causalcity

ROOT = Path(__file__).resolve().parents[2]
DATA = Path(os.environ.get("CAUSALCITY_DATA", ROOT / "target" / "python-data"))
CITY_SPEC = ROOT / "tests" / "python" / "city.json"
TOY_SPEC = ROOT / "tests" / "python" / "toy.json"
STOP_THE_LEADER = ROOT / "configs" / "examples" / "stop-the-leader.json"


def cli(*args, check=True):
    command = shlex.split(os.environ.get("CAUSALCITY_CLI", str(ROOT / "target" / "release" / "causalcity")))
    return subprocess.run(command + list(args), capture_output=True, text=True, check=check)


def read_csv(path):
    """{column: numpy array of cell texts}, "" for empty cells: numbers are
    parsed by number()."""
    with open(path, newline="", encoding="utf-8") as f:
        rows = list(csv.reader(f))
    header, body = rows[0], rows[1:]
    return {name: np.array([r[i] for r in body], dtype=object) for i, name in enumerate(header)}


def rows_in_order(table, order):
    return {name: column[order] for name, column in table.items()}


def number(column):
    """Python's exact decimal parsing (NaN for empty cells): the files'
    numbers read back to the very values logged."""
    return np.array([float(v) if v != "" else np.nan for v in column], dtype=np.float64)


def by_frame_and_car(table, column, frames, cars):
    ordered = rows_in_order(table, np.lexsort((number(table["car"]), number(table["frame"]))))
    assert len(ordered[column]) == frames * cars
    return number(ordered[column]).reshape(frames, cars)


def assert_poses_match(scenario, folder):
    """poses.csv, pixels.npy and scenario.json against the scenario's arrays."""
    frames, cars = scenario.frames, scenario.cars
    poses = read_csv(folder / "poses.csv")
    assert sorted(set(number(poses["car"]))) == list(scenario.car_ids)
    for column, values in {
        "x": scenario.position[..., 0],
        "y": scenario.position[..., 1],
        "z": scenario.position[..., 2],
        "roll": scenario.rotation[..., 0],
        "pitch": scenario.rotation[..., 1],
        "yaw": scenario.yaw,
        "px": scenario.pixels[..., 0],
        "py": scenario.pixels[..., 1],
        "speed": scenario.speed,
        "in_view": scenario.in_view.astype(np.float64),
    }.items():
        np.testing.assert_array_equal(values, by_frame_and_car(poses, column, frames, cars), err_msg=column)
    np.testing.assert_array_equal(scenario.t, by_frame_and_car(poses, "t", frames, cars)[:, 0])
    np.testing.assert_array_equal(scenario.pixels.astype(np.float32), np.load(folder / "pixels.npy"))
    metadata = json.loads((folder / "scenario.json").read_text())
    assert scenario.metadata == metadata
    expected_graph = np.zeros((cars, cars), dtype=np.uint8)
    for leader, follower in metadata["edges"]:
        expected_graph[leader, follower] = 1
    np.testing.assert_array_equal(scenario.graph, expected_graph)
    assert scenario.edges == [tuple(e) for e in metadata["edges"]]
    if (folder / "effects.csv").exists():
        assert_effects_match(scenario, folder, metadata)


def assert_effects_match(scenario, folder, metadata):
    """effects.csv and scenario.json's causal graphs against Scenario.effects."""
    effects = read_csv(folder / "effects.csv")
    e = scenario.effects
    assert len(e.cause) == len(effects["cause"]) > 0
    np.testing.assert_array_equal(e.cause, number(effects["cause"]))
    np.testing.assert_array_equal(e.effect, number(effects["effect"]))
    assert [e.interventions[k] for k in e.intervention] == list(effects["intervention"])
    np.testing.assert_array_equal(e.max_divergence_m, number(effects["max_divergence_m"]))
    first = number(effects["first_frame"])
    np.testing.assert_array_equal(e.first_frame, np.where(np.isnan(first), -1, first))
    np.testing.assert_array_equal(e.direct, number(effects["direct"]) == 1)
    for graph, field in ((scenario.causal_graph, "causal_edges"), (scenario.direct_graph, "direct_edges")):
        expected = np.zeros((scenario.cars, scenario.cars), dtype=np.uint8)
        for cause, effect in metadata[field]:
            expected[cause, effect] = 1
        np.testing.assert_array_equal(graph, expected, err_msg=field)


def assert_city_logs_match(scenario, folder):
    """The light log (lights.csv, or gen's default light_changes.csv),
    events.csv and interactions.csv against the arrays."""
    every_frame = (folder / "lights.csv").exists()
    lights = read_csv(folder / ("lights.csv" if every_frame else "light_changes.csv"))
    count = len(scenario.lights.names)
    assert count > 0
    colour = scenario.lights.colour
    if every_frame:
        # One row per frame and light.
        rows = np.ones(colour.shape, dtype=bool)
    else:
        # Every light at frame 0, then a row where its colour changed.
        rows = np.concatenate([np.ones((1, count), dtype=bool), colour[1:] != colour[:-1]])
        # Between rows, since_change grows by the frame interval.
        step = scenario.metadata["frame_interval"]
        held = ~rows
        grown = np.round((scenario.lights.since_change[:-1] + step) * 1000) / 1000
        np.testing.assert_allclose(scenario.lights.since_change[1:][held[1:]], grown[held[1:]], atol=1.5e-3, rtol=0)
    frame_of_row, light_of_row = np.nonzero(rows)
    np.testing.assert_array_equal(number(lights["frame"]), frame_of_row)
    names = lights["intersection"] + "/" + lights["approach"] + "/" + lights["signal"]
    assert list(names) == [scenario.lights.names[k] for k in light_of_row]
    colours = np.array(scenario.lights.colour_names)[colour[rows]]
    assert list(colours) == list(lights["colour"])
    np.testing.assert_array_equal(scenario.lights.since_change[rows], number(lights["since_change"]))
    heads = np.stack([number(lights["head_px"]), number(lights["head_py"])], axis=1)[:count]
    np.testing.assert_array_equal(scenario.lights.head_pixels, heads)

    events = read_csv(folder / "events.csv")
    assert len(events["kind"]) == len(scenario.events)

    def as_read(text, kind):
        return None if text == "" else kind(text)

    columns = ("frame", "t", "kind", "car", "other_car", "light", "detail")
    for row, event in zip(zip(*(events[c] for c in columns)), scenario.events):
        read = row
        kinds = (int, float, str, int, int, str, str)
        assert tuple(as_read(text, kind) for text, kind in zip(read, kinds)) == tuple(
            None if v == "" else v for v in event
        )

    interactions = read_csv(folder / "interactions.csv")
    frames, cars = scenario.frames, scenario.cars
    order = np.lexsort((number(interactions["car"]), number(interactions["frame"])))
    interactions = rows_in_order(interactions, order)
    kinds = np.array(scenario.interactions.kinds)[scenario.interactions.bound_by]
    assert list(kinds.reshape(-1)) == list(interactions["bound_by"])
    other = np.nan_to_num(number(interactions["other_car"]), nan=-1).reshape(frames, cars)
    np.testing.assert_array_equal(scenario.interactions.other_car, other)
    light_names = np.array(scenario.lights.names + [""], dtype=object)
    light = light_names[scenario.interactions.light].reshape(-1)
    assert list(light) == list(interactions["light"])


def assert_frames_match(scenario, folder):
    """Every RGB frame and mask decodes to the arrays, pixel for pixel."""
    rgb_files = sorted((folder / "rgb").glob("*.png"))
    mask_files = sorted((folder / "mask").glob("*.png"))
    assert len(rgb_files) == len(mask_files) == scenario.frames
    for frame, (rgb, mask) in enumerate(zip(rgb_files, mask_files)):
        np.testing.assert_array_equal(np.asarray(Image.open(rgb)), scenario.rgb[frame], err_msg=str(rgb))
        np.testing.assert_array_equal(np.asarray(Image.open(mask)), scenario.mask[frame], err_msg=str(mask))


def test_city_scenarios_equal_what_gen_writes():
    spec = causalcity.Spec.load(CITY_SPEC)
    keys = spec.keys()
    assert len(keys) == 3
    events = 0
    for key in keys:
        folder = DATA / "city" / key.folder
        scenario = causalcity.simulate(spec, *key, images=True)
        events += len(scenario.events)
        assert scenario.rgb.shape == (spec.frames, spec.image_size[1], spec.image_size[0], 3)
        assert scenario.rgb.dtype == np.uint8 and scenario.mask.shape == scenario.rgb.shape[:3]
        assert_poses_match(scenario, folder)
        assert_city_logs_match(scenario, folder)
        assert_frames_match(scenario, folder)
    assert events > 0


def test_toy_scenarios_equal_what_gen_writes():
    spec = causalcity.Spec.load(TOY_SPEC)
    keys = spec.keys()
    assert len(keys) == 8
    for key in keys:
        scenario = causalcity.simulate(spec, key.group, key.split, key.index)
        assert scenario.rgb is None and scenario.lights is None and scenario.interactions is None
        assert (DATA / "toy" / key.folder / "effects.csv").exists()
        assert_poses_match(scenario, DATA / "toy" / key.folder)
        # Toy: only followers react, each to its leader.
        np.testing.assert_array_equal(scenario.causal_graph, scenario.graph)
    # Without effects: the same scenario, no graph by intervention.
    bare = causalcity.simulate(spec, *keys[0], effects=False)
    assert bare.effects is None and bare.causal_graph is None
    assert "causal_edges" not in bare.metadata
    np.testing.assert_array_equal(bare.position, causalcity.simulate(spec, *keys[0]).position)
    key = keys[-1]
    assert_frames_match(causalcity.simulate(spec, *key, images=True), DATA / "toy" / key.folder)


def test_spec_from_a_dict_gives_the_same_scenarios_as_its_file():
    as_dict = json.loads(CITY_SPEC.read_text())
    from_dict = causalcity.simulate(as_dict, "cars08_edges50", "val", 0)
    from_file = causalcity.simulate(causalcity.Spec.load(CITY_SPEC), "cars08_edges50", "val", 0)
    np.testing.assert_array_equal(from_dict.position, from_file.position)
    assert from_dict.events == from_file.events
    assert causalcity.Spec.from_dict(as_dict).to_dict() == as_dict


def test_platoons_packed_too_tightly_are_refused_by_a_spec_from_a_dict_with_networks_too(tmp_path):
    # 100 cars in platoons of 4 with gaps of 1-12 m on a small town: seed 5
    # places the first scenario, and `gen` refuses it from its trial plans
    # (tests/spec_errors.rs). A dict spec given a networks folder is still a
    # spec about to be written: it was planned with a dataset's fewer trials,
    # and generate() then failed midway.
    raw = json.loads((ROOT / "configs" / "ci-city.json").read_text())
    raw.update(name="tight", seed=5, groups=[{"cars": 100, "edge_proportion": 0.5}],
               splits={"train": 20, "val": 5, "test": 5},
               map={"north_south_roads": [-24, 24], "extent_x": 44, "camera_altitude_m": 48})  # fmt: skip
    raw["city"]["start"] = {"follower_gap_m": {"uniform": [1, 12]}, "platoon_cars": 4}
    for networks in (None, tmp_path):
        with pytest.raises(causalcity.InputError, match="could not place 100 cars in platoons of 4"):
            causalcity.Spec.from_dict(raw, networks=networks)


def test_map_gives_the_road_network_as_arrays_and_agrees_with_the_command(tmp_path):
    grid = json.loads(CITY_SPEC.read_text())
    grid["map"] = {"grid": {"rows": 3, "columns": 3}}
    town = causalcity.map(grid)
    assert town["junctions"] == ["CD", "CE", "CF", "BD", "BE", "BF", "AD", "AE", "AF"]
    # Junctions 28 m apart around the origin, A the northmost road.
    np.testing.assert_allclose(np.unique(town["junction_centres"][:, 0]), [-28, 0, 28])
    assert town["junction_centres"][town["junctions"].index("AD")].tolist() == [-28, 28]
    assert len(town["lanes"]) == len(set(town["lanes"])) == 96
    assert town["lane_start"].shape == town["lane_end"].shape == (96, 2)
    # Every lane that ends at a junction ends at its edge (road half width 6 m + a 3.6 m setback at most).
    ends = town["lane_junction"] >= 0
    assert ends.sum() == 9 * 8
    to_centre = np.abs(town["lane_end"][ends] - town["junction_centres"][town["lane_junction"][ends]]).max(axis=1)
    assert np.all((to_centre > 5.9) & (to_centre < 6.1)), to_centre
    np.testing.assert_allclose(np.linalg.norm(town["lane_end"] - town["lane_start"], axis=1), town["lane_length"], atol=0.05)
    assert all(t == [] for t, j in zip(town["lane_turns"], town["lane_junction"]) if j < 0)
    # The same lanes as `causalcity map`, and the default city's 48 original spawn points.
    spec_file = tmp_path / "grid.json"
    spec_file.write_text(json.dumps(grid))
    listed = json.loads(cli("map", "--spec", str(spec_file), "--json").stdout)
    assert [lane["name"] for lane in listed["lanes"]] == town["lanes"]
    default = causalcity.map(CITY_SPEC)
    assert len(default["lanes"]) == 48 and default["lanes"][0] == "A0w" and default["junctions"] == ["BC", "BD", "AC", "AD"]


def test_map_gives_a_town_of_one_lane_roads_and_t_junctions_as_arrays(tmp_path):
    spec = json.loads(CITY_SPEC.read_text())
    spec["map"] = {"grid": {"rows": 3, "columns": 3, "lanes": 1, "missing": ["D0", "B2", "E3"]}}
    town = causalcity.map(spec)
    # 6 roads of 4 segments of 2 lanes, less 3 segments; none on a missing one.
    assert len(town["lanes"]) == 48 - 6
    assert not any(name[:2] in ("D0", "B2", "E3") for name in town["lanes"])
    # One lane each way: every lane ending at a junction ends at its edge, 3 m from the centre.
    ends = town["lane_junction"] >= 0
    to_centre = np.abs(town["lane_end"][ends] - town["junction_centres"][town["lane_junction"][ends]]).max(axis=1)
    assert np.all((to_centre > 2.9) & (to_centre < 3.1)), to_centre
    # Four T-junctions take lanes from 3 sides, the other five from 4.
    per_junction = np.bincount(town["lane_junction"][ends], minlength=9)
    assert sorted(per_junction.tolist()) == [3] * 4 + [4] * 5
    # A full junction's lane turns every way; the stem of CD (D1 southbound) cannot go straight.
    turns = dict(zip(town["lanes"], town["lane_turns"]))
    assert sorted(turns["C1w"]) == ["left", "right", "straight"]
    assert "straight" not in turns["D1z"] and turns["D1z"]
    # Every junction keeps its lights unless map.grid.control says otherwise.
    assert town["junction_controls"] == ["signals"] * 9
    spec["map"]["grid"]["control"] = {"AE": "priority", "CF": "all_way_stop"}
    controls = dict(zip(causalcity.map(spec)["junctions"], causalcity.map(spec)["junction_controls"]))
    assert controls["AE"] == "priority" and controls["CF"] == "all_way_stop"
    assert sum(c == "signals" for c in controls.values()) == 7
    # A segment that is no segment of the town is refused, naming the field.
    spec["map"]["grid"]["missing"] = ["Q7"]
    with pytest.raises(causalcity.InputError, match=r"map\.grid\.missing\[0\]"):
        causalcity.map(spec)


def small_city_spec(name, train, frames, grid):
    """The test city spec: one group of 8 cars at 50 %, `train` scenarios of
    `frames` frames on a grid town."""
    spec = json.loads(CITY_SPEC.read_text())
    spec.update(name=name, frames=frames, map={"grid": grid})
    spec["groups"] = [{"cars": 8, "edge_proportion": 0.5}]
    spec["splits"] = {"train": train, "val": 0, "test": 0}
    return spec


def test_a_town_of_all_way_stops_streams_without_lights_and_its_give_way_edges_bind(tmp_path):
    spec = small_city_spec("stops", 6, 60, {"rows": 2, "columns": 2, "control": "all_way_stop"})
    kinds = set()
    scenarios = 0
    for scenario in causalcity.stream(spec, split="train", images=False):
        scenarios += 1
        assert scenario.lights.colour.shape == (60, 0) and scenario.lights.names == []
        inter = scenario.interactions
        kinds |= {inter.kinds[k] for k in np.unique(inter.bound_by)}
        give_way = inter.bound_by == inter.kinds.index("give_way")
        t, i = np.nonzero(give_way)
        # A car giving way names the car it waits for, and car_graph has that edge.
        assert np.all(inter.other_car[t, i] >= 0) and np.all(inter.other_car[t, i] != i)
        assert np.all(inter.car_graph()[t, i, inter.other_car[t, i]] == 1)
    assert scenarios == 6
    assert {"stop_line", "give_way"} <= kinds, kinds
    assert "light" not in kinds


def test_cooperative_rules_on_a_right_before_left_town_simulate_as_gen_writes(tmp_path):
    spec = small_city_spec("cooperative", 3, 40, {"rows": 2, "columns": 3, "control": {"AC": "right_before_left"}})
    spec.setdefault("city", {})["rules"] = "cooperative"
    spec_file = tmp_path / "cooperative.json"
    spec_file.write_text(json.dumps(spec))
    out = tmp_path / "cooperative"
    cli("gen", "--spec", str(spec_file), "--out", str(out), "--no-images", "--quiet")
    controls = dict(zip(causalcity.map(spec)["junctions"], causalcity.map(spec)["junction_controls"]))
    assert controls["AC"] == "right_before_left"
    checked = 0
    for key in causalcity.Spec.from_dict(spec).keys():
        folder = out / key.folder
        assert json.loads((folder / "scenario.json").read_text())["city"]["rules"] == "cooperative"
        scenario = causalcity.simulate(spec, *key, effects=True)
        assert_poses_match(scenario, folder)
        assert_city_logs_match(scenario, folder)
        checked += 1
    assert checked == 3
    # A rule that does not exist is refused, naming the field.
    spec["city"]["rules"] = "polite"
    with pytest.raises(causalcity.InputError, match="rules"):
        causalcity.simulate(spec, "cars08_edges50", "train", 0)


def test_colliders_simulate_as_gen_writes_with_two_designed_causes_per_follower(tmp_path):
    spec = small_city_spec("colliders", 3, 40, {"rows": 3, "columns": 3, "control": "all_way_stop"})
    spec["graph"] = {"shape": "colliders"}
    spec_file = tmp_path / "colliders.json"
    spec_file.write_text(json.dumps(spec))
    out = tmp_path / "colliders"
    cli("gen", "--spec", str(spec_file), "--out", str(out), "--no-images", "--quiet")
    checked = 0
    for key in causalcity.Spec.from_dict(spec).keys():
        folder = out / key.folder
        scenario = causalcity.simulate(spec, *key, effects=True)
        assert_poses_match(scenario, folder)
        # One collider: a follower with two designed causes, its leader and
        # the car with priority it gives way to.
        (follower,) = np.flatnonzero(scenario.graph.sum(axis=0) == 2)
        car = scenario.metadata["cars"][follower]
        causes = set(np.flatnonzero(scenario.graph[:, follower]))
        assert causes == {car["follows"], car["gives_way_to"]}
        assert scenario.metadata["cars"][car["gives_way_to"]]["role"] == "priority"
        checked += 1
    assert checked == 3
    # The toy world has no one to give way to.
    toy = json.loads(TOY_SPEC.read_text())
    toy["graph"] = {"shape": "colliders"}
    with pytest.raises(causalcity.InputError, match="graph.shape"):
        causalcity.simulate(toy, "cars08_edges80", "train", 0)


def test_a_spec_that_draws_towns_names_each_scenarios_town_as_gen_records_it(tmp_path):
    spec = json.loads(CITY_SPEC.read_text())
    spec["name"] = "towns"
    spec["groups"] = [{"cars": 6, "edge_proportion": 0.5}]
    spec["splits"] = {"train": 8, "val": 0, "test": 0}
    spec["frames"] = 10
    spec["map"] = {"grid": {"rows": {"uniform": [1, 3]}, "columns": {"choice": [2, 4]}}}
    spec_file = tmp_path / "towns.json"
    spec_file.write_text(json.dumps(spec))
    out = tmp_path / "towns"
    cli("gen", "--spec", str(spec_file), "--out", str(out), "--no-images", "--no-effects", "--quiet")
    batch = next(iter(causalcity.batches(spec, "train", batch_size=8, shuffle=False, effects=False, tensors=False)))
    written = [
        json.loads((out / "cars06_edges50" / "train" / f"{key.index:05d}" / "scenario.json").read_text())
        for key in batch["key"]
    ]
    assert batch["town"] == [w["town"] for w in written]
    assert len(set(batch["town"])) >= 3, batch["town"]
    # Each town's pixels come from its own camera, as gen's.
    for b, w in enumerate(written):
        pixels = np.load(out / "cars06_edges50" / "train" / w["name"] / "pixels.npy")
        np.testing.assert_allclose(batch["pixels"][b], pixels, atol=1e-3)
    # causalcity.map lists the towns and shows the one asked for.
    shown = causalcity.map(spec, town=batch["town"][0])
    assert shown["town"] == batch["town"][0] and len(shown["towns"]) == 6
    rows, columns = written[0]["map"]["grid"]["rows"], written[0]["map"]["grid"]["columns"]
    assert len(shown["junctions"]) == rows * columns
    with pytest.raises(causalcity.InputError, match="no such town"):
        causalcity.map(spec, town="grid-9x9")
    # A spec with one town gives None.
    assert causalcity.simulate(CITY_SPEC, "cars08_edges50", "val", 0, effects=False).town is None


def test_stream_shards_over_processes_and_workers_without_overlap_or_gap():
    spec = json.loads(TOY_SPEC.read_text())
    spec["splits"]["train"] = 11
    spec = causalcity.Spec.from_dict(spec)
    every = spec.keys("train")
    assert len(every) == 22
    for processes, workers in [(1, 1), (2, 2), (3, 2), (2, 4)]:
        seen = []
        for rank in range(processes):
            stream = causalcity.stream(spec, "train", shard=(rank, processes))
            mine = [k for w in range(workers) for k in stream.keys(worker=(w, workers))]
            # A process's length is what its workers yield together, and
            # ranks differ by at most one scenario.
            assert len(stream) == len(mine) in (len(every) // processes, len(every) // processes + 1)
            seen.extend(mine)
        assert sorted(seen) == sorted(every) and len(set(seen)) == len(every), (processes, workers)
    # Iterating yields exactly its keys, each scenario as simulate gives it.
    stream = causalcity.stream(spec, "train", shard=(1, 2), threads=2, ahead=2)
    got = list(stream)
    assert [s.key for s in got] == every[1::2] and len(got) == len(stream)
    for s in got:
        np.testing.assert_array_equal(s.position, causalcity.simulate(spec, *s.key).position)


def test_specs_and_streams_pickle():
    spec = causalcity.Spec.load(TOY_SPEC)
    copy = pickle.loads(pickle.dumps(spec))
    assert copy.path == spec.path == str(TOY_SPEC) and copy.to_dict() == spec.to_dict()
    as_dict = pickle.loads(pickle.dumps(causalcity.Spec.from_dict(spec.to_dict())))
    assert as_dict.path is None and as_dict.keys() == spec.keys()
    stream = pickle.loads(pickle.dumps(causalcity.stream(spec, "val", threads=1)))
    assert [s.key for s in stream] == spec.keys("val")


def test_stream_order_and_values_do_not_depend_on_threads():
    spec = causalcity.Spec.load(TOY_SPEC)
    one = list(causalcity.stream(spec, "train", threads=1, images=True))
    two = list(causalcity.stream(spec, "train", threads=2, ahead=3, images=True))
    assert [s.key for s in one] == [s.key for s in two] == spec.keys("train")
    assert len(one) == 4
    for a, b in zip(one, two):
        np.testing.assert_array_equal(a.position, b.position)
        np.testing.assert_array_equal(a.rgb, b.rgb)
    # Consumed one at a time, each scenario's frame buffers are reused for
    # the next ones: the pixels must still be each scenario's own.
    def digest(s):
        return hashlib.sha256(s.rgb.tobytes() + s.mask.tobytes()).hexdigest()

    digests = [digest(s) for s in causalcity.stream(spec, "train", threads=1, images=True)]
    assert digests == [digest(s) for s in one]
    assert len(set(digests)) == len(digests)
    # Leaving early stops the workers: with one scenario allowed ahead, the
    # worker waits for the reader until told to stop (this would hang).
    for s in causalcity.stream(spec, "train", threads=1, ahead=1, images=True):
        break


def test_stream_follows_rank_and_world_size(monkeypatch):
    monkeypatch.setenv("RANK", "2")
    monkeypatch.setenv("WORLD_SIZE", "3")
    spec = causalcity.Spec.load(TOY_SPEC)
    stream = causalcity.stream(spec, "train", groups=["cars08_edges80"])
    assert [k for k in stream.keys()] == [k for k in spec.keys("train") if k.group == "cars08_edges80"][2::3]
    with pytest.raises(causalcity.InputError, match="cars99"):
        causalcity.stream(spec, "train", groups=["cars99"])


def test_stream_in_torch_dataloader_workers():
    torch = pytest.importorskip("torch")
    spec = causalcity.Spec.load(TOY_SPEC)
    stream = causalcity.stream(spec, "train", threads=1)
    assert isinstance(stream, torch.utils.data.IterableDataset)
    loader = torch.utils.data.DataLoader(stream, batch_size=None, num_workers=2)
    keys = [s.key for s in loader]
    assert sorted(keys) == sorted(spec.keys("train")) and len(set(keys)) == len(keys)


def test_errors_carry_the_command_lines_messages(tmp_path):
    bad = tmp_path / "bad.json"
    spec = json.loads(CITY_SPEC.read_text())
    spec["frames"] = 0
    bad.write_text(json.dumps(spec))
    result = cli("gen", "--spec", str(bad), "--out", str(tmp_path / "out"), check=False)
    assert result.returncode == 2
    message = result.stderr.strip().removeprefix("error: ")
    assert "frames" in message
    with pytest.raises(causalcity.InputError) as error:
        causalcity.Spec.load(bad)
    assert str(error.value) == message
    with pytest.raises(ValueError, match="frames"):
        causalcity.Spec.from_dict(spec)
    good = causalcity.Spec.load(CITY_SPEC)
    with pytest.raises(causalcity.InputError, match='split "holdout" is not one of train, val, test'):
        causalcity.simulate(good, "cars08_edges50", "holdout", 0)
    with pytest.raises(causalcity.InputError, match="index 1 is not in split"):
        causalcity.simulate(good, "cars08_edges50", "val", 1)
    with pytest.raises(causalcity.InputError, match="Car_9"):
        causalcity.counterfactual(STOP_THE_LEADER, {"at": 1.0, "do": "stop", "car": "Car_9", "seconds": 2})


def test_counterfactual_equals_the_command_and_is_identical_before_the_intervention():
    (pair,) = causalcity.counterfactual(STOP_THE_LEADER)
    folder = DATA / "counterfactual" / pair.name
    assert_poses_match(pair.factual, folder / "factual")
    assert_poses_match(pair.counterfactual, folder / "counterfactual")
    assert_city_logs_match(pair.counterfactual, folder / "counterfactual")
    divergence = read_csv(folder / "divergence.csv")
    np.testing.assert_array_equal(
        pair.divergence, by_frame_and_car(divergence, "distance_m", pair.factual.frames, pair.factual.cars)
    )
    assert pair.summary == json.loads((folder / "summary.json").read_text())
    # Before the intervention fires both runs are the same; afterwards only its effects differ.
    fired = int(np.ceil(pair.intervention_time / pair.factual.metadata["frame_interval"] - 1e-6))
    assert fired > 0
    np.testing.assert_array_equal(pair.factual.position[:fired], pair.counterfactual.position[:fired])
    assert not pair.divergence[:fired].any()
    moved = [pair.factual.car_names[c] for c in range(pair.factual.cars) if pair.divergence[:, c].any()]
    assert moved == pair.affected and "Car_3" not in moved and "Car_1" in moved


def test_counterfactual_from_dicts():
    scenario = json.loads(STOP_THE_LEADER.read_text())
    del scenario[0]["interventions"]
    (pair,) = causalcity.counterfactual(scenario, {"at": 3.0, "do": "stop", "car": "Car_1", "seconds": 6})
    (from_file,) = causalcity.counterfactual(STOP_THE_LEADER)
    np.testing.assert_array_equal(pair.counterfactual.position, from_file.counterfactual.position)
    np.testing.assert_array_equal(pair.divergence, from_file.divergence)


def test_generate_writes_the_dataset_gen_writes(tmp_path):
    spec = causalcity.Spec.load(TOY_SPEC)
    summary = causalcity.generate(spec, tmp_path / "toy", images=False, progress=False, limit=1)
    assert summary["written"] == summary["scenarios"] == len(spec.keys(limit=1)) == 6
    manifest = json.loads((tmp_path / "toy" / "manifest.json").read_text())
    assert manifest["complete"] is True
    for key in spec.keys(limit=1):
        folder = tmp_path / "toy" / key.folder
        assert not (folder / "rgb").exists()
        assert (folder / "poses.csv").read_bytes() == (DATA / "toy" / key.folder / "poses.csv").read_bytes()
    with pytest.raises(causalcity.InputError, match="made differently"):
        causalcity.generate(causalcity.Spec.load(CITY_SPEC), tmp_path / "toy", progress=False)


def test_the_gil_is_released_while_rust_works():
    spec = causalcity.Spec.load(CITY_SPEC)
    # Threads swap every 10 us: holding the GIL would let the counter run
    # only for such slivers, never for most of the call.
    switch = sys.getswitchinterval()
    sys.setswitchinterval(1e-5)
    counter = [0]
    done = threading.Event()

    def count():
        while not done.is_set():
            counter[0] += 1

    thread = threading.Thread(target=count)
    thread.start()
    try:
        # The counter's pace while the main thread only sleeps (sleep releases the GIL).
        start, began = counter[0], time.perf_counter()
        time.sleep(0.2)
        free_rate = (counter[0] - start) / (time.perf_counter() - began)
        start, began = counter[0], time.perf_counter()
        causalcity.simulate(spec, "cars08_edges50", "test", 0, images=True)
        rate = (counter[0] - start) / (time.perf_counter() - began)
    finally:
        done.set()
        thread.join()
        sys.setswitchinterval(switch)
    assert free_rate > 0
    assert rate > 0.3 * free_rate, (rate, free_rate)


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda s: causalcity.simulate(s, "cars08_edges50", "val", -1), r"index=-1 is out of range: use 0 to 4294967295"),
        (lambda s: causalcity.simulate(s, "cars08_edges50", "val", 2**40), r"index=1099511627776 is out of range"),
        (lambda s: causalcity.stream(s, "val", limit=-1), r"limit=-1 is out of range: use 1 to .*gen --limit"),
        (lambda s: causalcity.stream(s, "val", threads=0), r"threads=0 is out of range: use 1 to 1024 \(as gen -j\)"),
        (lambda s: causalcity.stream(s, "val", ahead=-2), r"ahead=-2 is out of range"),
        (lambda s: causalcity.stream(s, "val", limit=1.5), r"limit=1.5 is not a whole number"),
        (lambda s: causalcity.stream(s, "val", shard=(1,)), r"shard=\(1,\) is not a shard: use \(k, n\) or \"k/n\""),
        (lambda s: causalcity.stream(s, "val", shard="2/2"), r"shard='2/2' is not a shard"),
        (lambda s: causalcity.stream(s, "val").keys(worker=(0, 0)), r"worker=\(0, 0\) is not a worker: use \(worker id, workers\)"),
        (lambda s: causalcity.stream(s, "val").keys(worker=(5, 2)), r"worker=\(5, 2\) is not a worker"),
        (lambda s: causalcity.generate(s, "never-written", limit=0), r"limit=0 is out of range: use 1 to .*gen --limit"),
        (lambda s: causalcity.generate(s, "never-written", threads=0), r"threads=0 is out of range: use 1 to 1024"),
        (lambda s: causalcity.generate(s, "never-written", threads=100000), r"threads=100000 is out of range: use 1 to 1024"),
        (lambda s: causalcity.generate(s, "never-written", annotations=True, images=False), r"annotations=True needs images=True"),
        (lambda s: causalcity.generate(s, "never-written", shard=(1,)), r"shard=\(1,\) is not a shard"),
        (lambda s: causalcity.generate(s, "never-written", shard="1/x"), r"shard='1/x' is not a shard"),
        (lambda s: s.keys(limit=-5), r"limit=-5 is out of range"),
    ],
)
def test_bad_arguments_raise_input_error_naming_argument_and_value(tmp_path, monkeypatch, call, message):
    # Every argument is checked as the command line checks its flag: an
    # InputError naming the argument, the value and what is allowed, and
    # nothing written (before: OverflowError, IndexError, "too many values
    # to unpack", or an empty dataset marked complete).
    monkeypatch.chdir(tmp_path)
    spec = causalcity.Spec.load(CITY_SPEC)
    with pytest.raises(causalcity.InputError, match=message):
        call(spec)
    assert list(tmp_path.iterdir()) == []


def test_shards_are_accepted_as_pairs_and_text_alike(monkeypatch):
    spec = causalcity.Spec.load(TOY_SPEC)
    as_text = causalcity.stream(spec, "train", shard="1/3").keys()
    assert as_text == causalcity.stream(spec, "train", shard=(1, 3)).keys() == spec.keys("train")[1::3]
    assert as_text and causalcity.stream(spec, "train", shard=[1, 3]).keys() == as_text


@pytest.mark.parametrize("rank, world, named", [("abc", "2", "RANK='abc'"), ("0", "two", "WORLD_SIZE='two'"), ("3", "2", "RANK='3' and WORLD_SIZE='2'")])
def test_malformed_rank_and_world_size_are_named(monkeypatch, rank, world, named):
    monkeypatch.setenv("RANK", rank)
    monkeypatch.setenv("WORLD_SIZE", world)
    with pytest.raises(causalcity.InputError, match=named.replace("(", r"\(")):
        causalcity.stream(causalcity.Spec.load(TOY_SPEC), "train")


def _wait_for(path, child, seconds=60):
    """Waits until ``path`` exists (the run got going), failing if the child ends first."""
    deadline = time.monotonic() + seconds
    while not path.exists():
        assert child.poll() is None, child.communicate()
        assert time.monotonic() < deadline, f"{path} never appeared"
        time.sleep(0.02)


def _generate_in_child(tmp_path, spec, **options):
    """Starts ``causalcity.generate(spec, <tmp>/out, **options)`` in a child
    interpreter (to be interrupted); returns the child, the spec file and ``out``."""
    spec_file = tmp_path / "spec.json"
    spec_file.write_text(json.dumps(spec))
    out = tmp_path / "out"
    arguments = ", ".join(f"{k}={v!r}" for k, v in options.items())
    script = f"import causalcity\ncausalcity.generate({str(spec_file)!r}, {str(out)!r}, {arguments})\n"
    child = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=_default_sigint)
    return child, spec_file, out


def test_ctrl_c_stops_generate_early_and_the_same_call_resumes(tmp_path):
    # Before: KeyboardInterrupt arrived only once the whole dataset was
    # written (the manifest then said complete). Now the run stops at the
    # next frame, keeps what is complete and the same call resumes.
    spec = json.loads(CITY_SPEC.read_text())
    spec["splits"] = {"train": 40, "val": 0, "test": 0}
    spec["frames"] = 150
    child, spec_file, out = _generate_in_child(tmp_path, spec, images=False, threads=1, progress=False)
    _wait_for(out / "cars08_edges50" / "train" / "00000", child)
    child.send_signal(signal.SIGINT)
    _, stderr = child.communicate(timeout=60)
    assert "KeyboardInterrupt" in stderr, stderr
    assert child.returncode != 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["complete"] is False, "the run finished before it was interrupted"
    kept = sorted(p.name for p in (out / "cars08_edges50" / "train").iterdir() if not p.name.startswith("."))
    assert 1 <= len(kept) < 40, kept
    # Resumed by the same call: what was kept is skipped, the rest written.
    summary = causalcity.generate(str(spec_file), out, images=False, progress=False)
    assert summary["skipped"] == len(kept) and summary["written"] == 40 - len(kept)
    report = cli("validate", str(out), check=False)
    assert report.returncode == 0, report.stdout + report.stderr


LONG_SPEC = {
    "name": "long",
    "world": "city",
    "seed": 5,
    "frames": 100000,
    "groups": [{"cars": 80, "edge_proportion": 0.5}],
    "splits": {"train": 1, "val": 0, "test": 0},
}


def _default_sigint():
    """In the child before it starts: Ctrl-C as a terminal sends it. A
    runner that starts the tests in the background (``cmd &`` in a script)
    hands them SIGINT ignored, and Python installs no KeyboardInterrupt
    handler for a signal it inherits ignored."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _interrupted(call_source, setup=""):
    """Runs ``call_source`` (an expression) in a child interpreter, sends it
    SIGINT 0.3 s after it starts, and returns (what happened, the peak
    memory the child ever held, in bytes): ``interrupted`` when the call
    raised KeyboardInterrupt, else ``finished``."""
    script = (
        "import causalcity, json\n"
        f"{setup}"
        "print('started', flush=True)\n"
        "try:\n"
        f"    {call_source}\n"
        "    print('finished', 0)\n"
        "except KeyboardInterrupt:\n"
        "    peak = [l for l in open('/proc/self/status') if l.startswith('VmHWM:')][0].split()[1]\n"
        "    print('interrupted', int(peak) * 1024)\n"
    )
    child = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=_default_sigint)
    assert child.stdout.readline().strip() == "started"
    time.sleep(0.3)
    child.send_signal(signal.SIGINT)
    stdout, stderr = child.communicate(timeout=300)
    word, peak = stdout.split()
    assert word == "interrupted", stdout + stderr
    return word, int(peak)


def test_ctrl_c_interrupts_a_long_simulate():
    # One scenario of 100,000 frames and 80 cars takes seconds to simulate
    # and about a gigabyte to hold; Ctrl-C must not wait for it (before:
    # the call ran to its end, then raised). Stopped early shows in the
    # memory the process ever held: far less than the whole scenario's.
    setup = f"spec = causalcity.Spec.from_dict(json.loads({json.dumps(json.dumps(LONG_SPEC))}))\n"
    _, peak = _interrupted("causalcity.simulate(spec, 'cars80_edges50', 'train', 0, effects=False)", setup)
    # The whole scenario's arrays alone are 100,000 x 80 x 8 float64 = 512 MB.
    assert peak < 400e6, f"peak memory {peak / 1e6:.0f} MB: the simulation ran on"


def test_ctrl_c_stops_generate_inside_a_long_scenario(tmp_path):
    # Before: the poses-only scenario was simulated and written to its end
    # (28 s, 958 MB) before the KeyboardInterrupt arrived.
    child, _, out = _generate_in_child(tmp_path, LONG_SPEC, images=False, effects=False, progress=False)
    _wait_for(out / "manifest.json", child)
    time.sleep(0.3)
    child.send_signal(signal.SIGINT)
    _, stderr = child.communicate(timeout=120)
    assert "KeyboardInterrupt" in stderr, stderr
    assert not (out / "cars80_edges50" / "train" / "00000").exists(), "the scenario was finished"
    assert json.loads((out / "manifest.json").read_text())["complete"] is False
    report = cli("validate", str(out), check=False)
    assert report.returncode == 1 and "did not finish" in report.stdout + report.stderr, report.stdout + report.stderr


def _under_memory_limit(body, headroom=1 << 30):
    """Runs ``body`` (Python source) in a child whose address space is
    capped at its size now plus ``headroom``; returns the child."""
    script = (
        "import resource, causalcity, json\n"
        "size = int([l for l in open('/proc/self/status') if l.startswith('VmSize:')][0].split()[1]) * 1024\n"
        f"resource.setrlimit(resource.RLIMIT_AS, (size + {headroom}, resource.RLIM_INFINITY))\n" + body
    )
    return subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="RLIMIT_AS as Linux applies it")
def test_frames_that_do_not_fit_raise_memory_error_not_an_abort(tmp_path):
    # 3,000 frames of 1024 x 640 need 7.9 GB; under a 1 GB headroom the
    # interpreter aborted ("memory allocation failed", SIGABRT). Now:
    # MemoryError naming the size, and the interpreter goes on.
    spec = json.loads(CITY_SPEC.read_text())
    spec.update(frames=3000, image={"width": 1024, "height": 640})
    scenarios = json.loads(STOP_THE_LEADER.read_text())
    scenarios[0]["frames"] = 3000
    body = (
        f"spec = causalcity.Spec.from_dict(json.loads({json.dumps(json.dumps(spec))}))\n"
        "for call in (lambda: causalcity.simulate(spec, 'cars08_edges50', 'train', 0, images=True, effects=False),\n"
        "             lambda: next(iter(causalcity.stream(spec, 'train', images=True, effects=False))),\n"
        f"             lambda: causalcity.counterfactual(json.loads({json.dumps(json.dumps(scenarios))}), images=True)):\n"
        "    try:\n"
        "        call()\n"
        "        print('no error')\n"
        "    except MemoryError as e:\n"
        "        print('MemoryError:', e)\n"
        "s = causalcity.simulate(spec, 'cars08_edges50', 'train', 0, effects=False)\n"
        "print('still running', s.frames)\n"
    )
    child = _under_memory_limit(body)
    assert child.returncode == 0, child.stdout + child.stderr
    lines = child.stdout.splitlines()
    assert len(lines) == 4, child.stdout + child.stderr
    for line in lines[:3]:
        assert line.startswith("MemoryError: not enough memory for the frames"), line
    assert "7.86 GB are needed (3000 frames of 1024 x 640" in lines[0], lines[0]
    assert lines[3] == "still running 3000"


def test_a_stream_at_the_largest_split_sizes_starts_at_once_in_little_memory():
    # 10,000,000 per split in two groups: before, the stream listed its 20
    # million keys first (gigabytes); now keys come from their position.
    script = (
        "import causalcity, itertools, resource\n"
        "spec = causalcity.Spec.from_dict({'name': 'largest', 'world': 'toy', 'seed': 5, 'frames': 20,\n"
        "    'groups': [{'cars': 4, 'edge_proportion': 0.5}, {'cars': 8, 'edge_proportion': 0.5}],\n"
        "    'splits': {'train': 10000000, 'val': 10000000, 'test': 10000000}})\n"
        "s = causalcity.stream(spec, 'train', shard=(1, 3), effects=False)\n"
        "print(len(s))\n"
        "print([tuple(x.key) for x in itertools.islice(s, 3)])\n"
        # VmHWM, not ru_maxrss: the latter keeps the forking test process's
        # peak across exec (hundreds of MB once torch is imported).
        "print(int([l for l in open('/proc/self/status') if l.startswith('VmHWM:')][0].split()[1]) * 1024)\n"
    )
    child = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert child.returncode == 0, child.stderr
    length, first, peak = child.stdout.splitlines()
    assert int(length) == 20_000_000 // 3 + 1
    assert first == str([("cars04_edges50", "train", i) for i in (1, 4, 7)])
    assert int(peak) < 300e6, f"peak memory {int(peak) / 1e6:.0f} MB"


def test_a_stream_handed_over_in_chunks_keeps_its_order(monkeypatch):
    spec = causalcity.Spec.load(TOY_SPEC)
    whole = [s.key for s in causalcity.stream(spec, "train", effects=False)]
    monkeypatch.setattr(causalcity, "_STREAM_CHUNK", 3)
    chunked = list(causalcity.stream(spec, "train", effects=False, threads=2))
    assert [s.key for s in chunked] == whole == spec.keys("train") and len(whole) > 3
    for s in chunked:
        np.testing.assert_array_equal(s.position, causalcity.simulate(spec, *s.key, effects=False).position)


def test_ctrl_c_interrupts_counterfactual():
    # 40 long pairs hold 1.4 GB of arrays when finished; before, Ctrl-C
    # waited for all of them. Stopped early shows in the memory held.
    base = json.loads(STOP_THE_LEADER.read_text())[0]
    scenarios = [dict(base, Name=f"pair_{i}", frames=30000) for i in range(40)]
    setup = f"scenarios = json.loads({json.dumps(json.dumps(scenarios))})\n"
    _, peak = _interrupted("causalcity.counterfactual(scenarios)", setup)
    assert peak < 400e6, f"peak memory {peak / 1e6:.0f} MB: the pairs ran on"


def test_a_real_network_from_sumo_maps_streams_and_reads_back_from_its_dataset(tmp_path):
    network = ROOT / "tests" / "data" / "sumo" / "berlin-small.net.xml"
    (tmp_path / "berlin-small.net.xml").write_bytes(network.read_bytes())
    spec = json.loads(CITY_SPEC.read_text())
    spec["name"] = "berlin"
    spec["groups"] = [{"cars": 8, "edge_proportion": 0.5}]
    spec["splits"] = {"train": 3, "val": 0, "test": 0}
    spec["frames"] = 40
    spec["map"] = {"sumo": "berlin-small.net.xml"}
    spec_file = tmp_path / "berlin.json"
    spec_file.write_text(json.dumps(spec))
    # The network as arrays: SUMO's lane and junction ids, its lights.
    town = causalcity.map(spec_file)
    sumo_lanes = set(l.split('"')[0] for l in network.read_text().split('<lane id="')[1:])
    assert len(town["lanes"]) == 48 and set(town["lanes"]) <= sumo_lanes
    controls = dict(zip(town["junctions"], town["junction_controls"]))
    assert controls["cluster_1560223404_2335739502_3273797701"] == "signals"
    assert town["town"] == "sumo-berlin-small"
    # Streamed scenarios drive on it.
    streamed = list(causalcity.stream(spec_file, split="train", images=False))
    assert len(streamed) == 3
    for scenario in streamed:
        assert np.all((scenario.position[..., 0] > 850) & (scenario.position[..., 0] < 1410))
        assert np.abs(np.diff(scenario.position[..., :2], axis=0)).sum() > 100
    # gen keeps the network in the dataset: it reads back without the spec's copy,
    # equal to the stream, and its spec survives pickling (DataLoader workers).
    out = tmp_path / "out"
    cli("gen", "--spec", str(spec_file), "--out", str(out), "--no-images")
    (tmp_path / "berlin-small.net.xml").unlink()
    data = causalcity.open_dataset(out)
    assert len(data) == 3
    copy = pickle.loads(pickle.dumps(data.spec))
    for loaded, scenario in zip(data, streamed):
        np.testing.assert_array_equal(loaded.position, scenario.position)
        np.testing.assert_array_equal(causalcity.simulate(copy, *loaded.key).position, scenario.position)


def test_lights_logged_as_changes_read_back_as_the_arrays_of_lights_csv(tmp_path):
    """gen's default light_changes.csv (every light at frame 0, then only its
    changes) reads back as the arrays of gen --lights frames' lights.csv, the
    colours exactly and since_change to the millisecond, in a tenth of the
    bytes."""
    spec = json.loads(CITY_SPEC.read_text())
    spec.update(name="changes", frames=150)
    spec["groups"] = [{"cars": 8, "edge_proportion": 0.5}]
    spec["splits"] = {"train": 3, "val": 0, "test": 0}
    spec_file = tmp_path / "changes.json"
    spec_file.write_text(json.dumps(spec))
    frames, changes = tmp_path / "frames", tmp_path / "changes"
    cli("gen", "--spec", str(spec_file), "--out", str(changes), "--no-images", "--no-effects")
    # causalcity.generate's lights= is gen --lights.
    causalcity.generate(spec_file, frames, images=False, effects=False, lights="frames", progress=False)
    assert not list(frames.rglob("light_changes.csv"))
    with pytest.raises(causalcity.InputError, match="frames"):
        causalcity.generate(spec_file, tmp_path / "never", lights="compact")
    assert not (tmp_path / "never").exists()
    full, compact = causalcity.open_dataset(frames), causalcity.open_dataset(changes)
    assert len(full) == len(compact) == 3
    for a, b in zip(full, compact):
        assert a.lights.names == b.lights.names and len(a.lights.names) == 32
        np.testing.assert_array_equal(a.lights.colour, b.lights.colour)
        np.testing.assert_allclose(a.lights.since_change, b.lights.since_change, atol=1.5e-3, rtol=0)
        np.testing.assert_array_equal(a.lights.head_pixels, b.lights.head_pixels)
        np.testing.assert_array_equal(a.interactions.light, b.interactions.light)
        np.testing.assert_array_equal(a.position, b.position)
    folders = sorted(p.parent for p in changes.rglob("light_changes.csv"))
    assert len(folders) == 3 and not list(changes.rglob("lights.csv"))
    small = sum((f / "light_changes.csv").stat().st_size for f in folders)
    large = sum(p.stat().st_size for p in frames.rglob("lights.csv"))
    assert small * 5 < large, (small, large)
