"""Real clients load causalcity output unchanged: pandas reads the CSV logs
with the documented dtypes, Pillow and numpy read the frames and masks, and
numpy loads the NRI exports with the documented shapes and values that match
the CSVs. The data comes from `make test-python`, which generates it with the
built binary into $CAUSALCITY_DATA."""

import json
import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from PIL import Image

ROOT = Path(os.environ.get("CAUSALCITY_DATA", "target/python-data"))
TOY = ROOT / "toy"
CITY = ROOT / "city"
SPLITS = {"train": "train", "val": "valid", "test": "test"}


def scenarios(dataset):
    return sorted(p for p in dataset.glob("*/*/*") if (p / "scenario.json").exists())


@pytest.fixture(scope="module")
def toy_scenarios():
    found = scenarios(TOY)
    assert len(found) == 8, f"expected 8 toy scenarios under {TOY}"
    return found


def test_manifest_is_complete_json():
    for dataset in (TOY, CITY):
        manifest = json.loads((dataset / "manifest.json").read_text())
        assert manifest["complete"] is True
        assert manifest["format"] == "causalcity-dataset/1"


def test_poses_load_with_the_documented_dtypes(toy_scenarios):
    for d in toy_scenarios:
        scenario = json.loads((d / "scenario.json").read_text())
        poses = pd.read_csv(d / "poses.csv")
        assert list(poses.columns) == ["frame", "t", "car", "x", "y", "z", "roll", "pitch", "yaw", "px", "py", "speed", "in_view"]
        for column in ("frame", "car", "in_view"):
            assert poses[column].dtype == np.int64, column
        for column in ("t", "x", "y", "z", "roll", "pitch", "yaw", "px", "py", "speed"):
            assert poses[column].dtype == np.float64, column
        assert len(poses) == scenario["frames"] * len(scenario["cars"])
        assert poses.set_index(["frame", "car"]).index.is_monotonic_increasing
        assert set(poses.car) == {c["id"] for c in scenario["cars"]}


def test_pixels_npy_is_the_pose_logs_px_py(toy_scenarios):
    for d in scenarios(TOY) + scenarios(CITY):
        scenario = json.loads((d / "scenario.json").read_text())
        pixels = np.load(d / "pixels.npy")
        assert pixels.dtype == np.float32
        assert pixels.shape == (scenario["frames"], len(scenario["cars"]), 2)
        poses = pd.read_csv(d / "poses.csv")
        expected = poses[["px", "py"]].to_numpy(dtype=np.float32).reshape(pixels.shape)
        assert np.array_equal(pixels, expected)


def test_city_logs_load_with_the_documented_dtypes():
    for d in scenarios(CITY):
        lights = pd.read_csv(d / "light_changes.csv")
        assert list(lights.columns) == ["frame", "t", "intersection", "approach", "signal", "colour", "since_change", "head_px", "head_py"]
        assert lights.frame.dtype == np.int64 and lights.since_change.dtype == np.float64
        assert lights.head_px.dtype == np.float64 and lights.head_py.dtype == np.float64
        # A head stands still: one pixel per light over the whole scenario.
        assert (lights.groupby(["intersection", "approach", "signal"])[["head_px", "head_py"]].nunique() == 1).all().all()
        assert set(lights.colour) <= {"green", "yellow", "red"}
        # gen's default log: every light at frame 0, then only its changes.
        assert list(lights.frame[:32]) == [0] * 32 and (lights.frame[32:] > 0).all()
        assert 32 <= len(lights) < 30 * 32 and lights.frame.is_monotonic_increasing
        events = pd.read_csv(d / "events.csv", dtype={"car": "Int64", "other_car": "Int64"})
        assert list(events.columns) == ["frame", "t", "kind", "car", "other_car", "light", "detail"]
        # A light is never car 0: red-light runs name their car and their light.
        runs = events[events.kind == "red_light_run"]
        assert runs.car.notna().all() and runs.light.notna().all()
        assert set(events.kind) <= {"collision", "red_light_run", "merge_done", "turn_done", "lane_change", "action_adapted", "action_skipped", "actions_finished", "intervention"}


SCHEMAS = Path(__file__).resolve().parents[2] / "data-schema"


def test_every_csv_loads_with_plain_read_csv_as_its_schema_says():
    """Plain pandas.read_csv gives int64 for required integers, float64 for
    numbers and strings for text, in the schema's column order; the integer
    columns that may be empty read as nullable Int64, as docs/output-layout.md says."""
    checked = {}
    for d in scenarios(TOY) + scenarios(CITY):
        for name in ["poses.csv", "light_changes.csv", "events.csv", "interactions.csv", "effects.csv"]:
            if not (d / name).exists():
                continue
            fields = json.loads((SCHEMAS / name.replace(".csv", ".schema.json")).read_text())["fields"]
            table = pd.read_csv(d / name)
            assert list(table.columns) == [f["name"] for f in fields], name
            if table.empty:  # a header alone has no dtypes to infer
                continue
            nullable = {}
            for f in fields:
                column = table[f["name"]]
                required = f.get("constraints", {}).get("required", False)
                if f["type"] == "integer" and required:
                    assert column.dtype == np.int64, (name, f["name"], column.dtype)
                elif f["type"] == "integer":
                    nullable[f["name"]] = "Int64"
                elif f["type"] == "number":
                    assert column.dtype == np.float64, (name, f["name"], column.dtype)
                elif f["type"] == "string" and column.notna().any():
                    assert pd.api.types.is_string_dtype(column), (name, f["name"], column.dtype)
            if nullable:
                typed = pd.read_csv(d / name, dtype=nullable)
                for column in nullable:
                    assert typed[column].dtype == pd.Int64Dtype(), (name, column)
            checked[name] = checked.get(name, 0) + 1
    assert set(checked) == {"poses.csv", "light_changes.csv", "events.csv", "interactions.csv", "effects.csv"}, checked


def test_frames_and_masks_decode_and_agree_with_the_poses(toy_scenarios):
    checked = 0
    for d in toy_scenarios:
        scenario = json.loads((d / "scenario.json").read_text())
        ids = {c["mask_id"] for c in scenario["cars"]}
        poses = pd.read_csv(d / "poses.csv")
        for frame in (0, 29):
            rgb = np.asarray(Image.open(d / "rgb" / f"{frame:04d}.png"))
            mask = np.asarray(Image.open(d / "mask" / f"{frame:04d}.png"))
            assert rgb.shape == (640, 1024, 3) and rgb.dtype == np.uint8
            assert mask.shape == (640, 1024) and mask.dtype == np.uint8
            assert set(np.unique(mask)) - {0} <= ids
            here = poses[poses.frame == frame]
            for car in scenario["cars"]:
                row = here[here.car == car["id"]].iloc[0]
                ys, xs = np.nonzero(mask == car["mask_id"])
                alone = ((here.px - row.px) ** 2 + (here.py - row.py) ** 2 > 40**2).sum() == len(here) - 1
                inside = 20 < row.px < 1003 and 20 < row.py < 619
                if alone and inside:
                    assert abs(xs.mean() - row.px) <= 1.5 and abs(ys.mean() - row.py) <= 1.5
                    checked += 1
    assert checked >= 10


def nri_dir(name):
    return ROOT / name


@pytest.mark.parametrize("export, layout, directed", [("nri-causalcity", "causalcity", False), ("nri-reference", "nri", True)])
def test_nri_exports_match_the_csvs(export, layout, directed):
    for group, cars in (("cars04_edges50", 4), ("cars08_edges80", 8)):
        for split, nri_split in SPLITS.items():
            folder = nri_dir(export) / group
            loc = np.load(folder / f"loc_{nri_split}.npy")
            vel = np.load(folder / f"vel_{nri_split}.npy")
            edges = np.load(folder / f"edges_{nri_split}.npy")
            dirs = sorted((TOY / group / split).iterdir())
            if layout == "causalcity":
                assert loc.shape == (len(dirs), 30, cars, 2)
            else:
                assert loc.shape == (len(dirs), 30, 2, cars)
                loc, vel = loc.transpose(0, 1, 3, 2), vel.transpose(0, 1, 3, 2)
            assert loc.dtype == np.float32 and vel.shape == loc.shape and edges.shape == (len(dirs), cars, cars)
            np.testing.assert_array_equal(vel[:, 1:], loc[:, 1:] - loc[:, :-1])
            for s, d in enumerate(dirs):
                poses = pd.read_csv(d / "poses.csv").sort_values(["frame", "car"])
                px = poses.px.to_numpy(np.float32).reshape(30, cars)
                py = poses.py.to_numpy(np.float32).reshape(30, cars)
                np.testing.assert_array_equal(loc[s, :, :, 0], px)
                np.testing.assert_array_equal(loc[s, :, :, 1], py)
                expected = np.eye(cars, dtype=np.int64) if layout == "causalcity" else np.zeros((cars, cars), np.int64)
                for leader, follower in json.loads((d / "scenario.json").read_text())["edges"]:
                    expected[follower, leader] = 1
                    if not directed:
                        expected[leader, follower] = 1
                np.testing.assert_array_equal(edges[s], expected)


def test_nri_export_as_the_original_converter_clipped_and_forward(toy_scenarios):
    """export nri --clip --velocity forward --suffix _airsim_final: the files
    the original CausalCity NRI fork loads, with positions clamped to the
    1024 x 640 image and vel[t] = loc[t+1] - loc[t], the last repeated."""
    clipped = 0
    for group, cars in (("cars04_edges50", 4), ("cars08_edges80", 8)):
        for split, nri_split in SPLITS.items():
            folder = nri_dir("nri-original") / group
            loc = np.load(folder / f"loc_{nri_split}_airsim_final.npy")
            vel = np.load(folder / f"vel_{nri_split}_airsim_final.npy")
            dirs = sorted((TOY / group / split).iterdir())
            assert loc.shape == (len(dirs), 30, cars, 2)
            assert loc[..., 0].min() >= 0 and loc[..., 0].max() <= 1024
            assert loc[..., 1].min() >= 0 and loc[..., 1].max() <= 640
            np.testing.assert_array_equal(vel[:, :-1], loc[:, 1:] - loc[:, :-1])
            np.testing.assert_array_equal(vel[:, -1], vel[:, -2])
            for s, d in enumerate(dirs):
                poses = pd.read_csv(d / "poses.csv").sort_values(["frame", "car"])
                px = poses.px.to_numpy(np.float32).reshape(30, cars)
                py = poses.py.to_numpy(np.float32).reshape(30, cars)
                np.testing.assert_array_equal(loc[s, :, :, 0], np.clip(px, 0, 1024))
                np.testing.assert_array_equal(loc[s, :, :, 1], np.clip(py, 0, 640))
                clipped += int(((px < 0) | (px > 1024)).sum() + ((py < 0) | (py > 640)).sum())
    # The toy data has cars off the image, so clipping was exercised.
    assert clipped > 0


def test_dynamic_edges_load_and_match_interactions_csv():
    """export nri --dynamic --directed (causalcity layout): uint8 [scenarios,
    frames, cars, cars], the identity plus 1 where interactions.csv names the
    car that bound the receiver."""
    checked = 0
    for group in sorted(p.name for p in CITY.iterdir() if p.is_dir()):
        for split, nri_split in SPLITS.items():
            dirs = sorted((CITY / group / split).glob("*"))
            if not dirs:
                continue
            graph = np.load(ROOT / "nri-dynamic" / group / f"dynamic_edges_{nri_split}.npy")
            assert graph.dtype == np.uint8
            for s, d in enumerate(dirs):
                rows = pd.read_csv(d / "interactions.csv", dtype={"other_car": "Int64"})
                frames = rows.frame.max() + 1
                cars = rows.car.max() + 1
                assert graph.shape[1:] == (frames, cars, cars)
                expected = np.zeros((frames, cars, cars), dtype=np.uint8)
                expected[:, np.arange(cars), np.arange(cars)] = 1
                named = rows[rows.other_car.notna()]
                expected[named.frame.to_numpy(), named.car.to_numpy(), named.other_car.to_numpy(dtype=np.int64)] = 1
                np.testing.assert_array_equal(graph[s], expected)
                checked += int(expected.sum()) - frames * cars
    assert checked > 0


def test_annotations_rle_decodes_to_the_mask_pngs(toy_scenarios):
    """gen --annotations: pycocotools decodes every car's RLE back to exactly
    its pixels in the mask PNG, and every car in a mask is annotated."""
    from pycocotools import mask as coco_mask

    checked = 0
    for d in toy_scenarios:
        annotations = json.loads((d / "annotations.json").read_text())
        assert annotations["format"] == "causalcity-nsdr/1"
        scenario = json.loads((d / "scenario.json").read_text())
        poses = pd.read_csv(d / "poses.csv").set_index(["frame", "car"])
        assert len(annotations["frames"]) == scenario["frames"]
        for frame in annotations["frames"]:
            mask = np.asarray(Image.open(d / frame["mask_filename"]))
            assert {o["mask_id"] for o in frame["objects"]} == set(np.unique(mask)) - {0}
            for obj in frame["objects"]:
                rle = {"size": obj["mask"]["size"], "counts": obj["mask"]["counts"].encode()}
                decoded = coco_mask.decode(rle)
                assert decoded.shape == mask.shape
                assert np.array_equal(decoded.astype(bool), mask == obj["mask_id"]), (d, frame["frame_index"], obj["name"])
                assert int(coco_mask.area(rle)) == obj["area"]
                assert list(coco_mask.toBbox(rle)) == obj["bbox"]
                pose = poses.loc[(frame["frame_index"], obj["id"])]
                assert (obj["px"], obj["py"]) == (pose.px, pose.py)
                checked += 1
    assert checked > 100


def test_export_nsdr_writes_what_gen_annotations_wrote(toy_scenarios):
    for d in toy_scenarios:
        exported = ROOT / "nsdr" / d.relative_to(TOY) / "annotations.json"
        assert exported.read_bytes() == (d / "annotations.json").read_bytes()


def test_city_annotations_cover_every_visible_car():
    from pycocotools import mask as coco_mask

    for d in scenarios(CITY):
        folder = ROOT / "nsdr-city" / d.relative_to(CITY)
        exported = json.loads((folder / "annotations.json").read_text())
        for frame in exported["frames"][::7]:
            mask = np.asarray(Image.open(d / frame["mask_filename"]))
            # The file names resolve from the export folder too (rgb/ and mask/ link to the dataset's).
            assert np.array_equal(np.asarray(Image.open(folder / frame["mask_filename"])), mask)
            assert (folder / frame["frame_filename"]).read_bytes() == (d / frame["frame_filename"]).read_bytes()
            union = np.zeros(mask.shape, dtype=bool)
            for obj in frame["objects"]:
                union |= coco_mask.decode({"size": obj["mask"]["size"], "counts": obj["mask"]["counts"].encode()}).astype(bool)
            assert np.array_equal(union, mask > 0)


def test_vcdn_hdf5_matches_the_csvs(toy_scenarios):
    """h5py reads every V-CDN file with the documented shapes; states,
    actions and rels agree with poses.csv and scenario.json."""
    h5py = pytest.importorskip("h5py")
    vcdn = ROOT / "vcdn"
    if not vcdn.exists():
        pytest.skip("built without the hdf5 feature (make FEATURES=)")
    for d in toy_scenarios:
        scenario = json.loads((d / "scenario.json").read_text())
        n, t = len(scenario["cars"]), scenario["frames"]
        poses = pd.read_csv(d / "poses.csv")
        loc = np.stack([poses.pivot(index="frame", columns="car", values=c).to_numpy() for c in ("px", "py")], axis=-1)
        with h5py.File(vcdn / d.relative_to(TOY).parent / f"{d.name}.h5", "r") as f:
            assert f["attrs"].shape == (t, n, 1) and np.all(f["attrs"][()] == 1)
            assert f["states"].shape == (t, n, 4) and f["states"].dtype == np.float32
            assert f["actions"].shape == (t, n, 2)
            assert f["rels"].shape == (t, n * (n - 1) // 2, 2)
            states = f["states"][()]
            assert np.allclose(states[..., :2], loc, atol=1e-3)
            vel = np.diff(loc, axis=0)
            assert np.allclose(states[1:, :, 2:], vel, atol=1e-3)
            assert np.allclose(f["actions"][2:], np.diff(vel, axis=0), atol=1e-3)
            linked = {frozenset(e) for e in scenario["edges"]}
            pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
            flags = f["rels"][0, :, 0]
            assert [bool(x) for x in flags] == [frozenset(p) in linked for p in pairs]
            for k, (i, j) in enumerate(pairs):
                mean = np.linalg.norm(loc[:, i] - loc[:, j], axis=-1).mean()
                assert abs(f["rels"][5, k, 1] - mean) < 1e-2
            assert sorted(map(tuple, f["edges"][()])) == sorted(map(tuple, scenario["edges"]))


def test_counterfactual_outputs_load():
    """divergence.csv and summary.json of a counterfactual pair load as
    documented, and agree with the two pose logs."""
    pair = ROOT / "counterfactual" / "stop_the_leader"
    divergence = pd.read_csv(pair / "divergence.csv")
    assert list(divergence.columns) == ["frame", "t", "car", "distance_m", "distance_px"]
    assert divergence.frame.dtype == np.int64 and divergence.distance_m.dtype == np.float64
    summary = json.loads((pair / "summary.json").read_text())
    factual = pd.read_csv(pair / "factual" / "poses.csv")
    counterfactual = pd.read_csv(pair / "counterfactual" / "poses.csv")
    gap = np.hypot(factual.x - counterfactual.x, factual.y - counterfactual.y)
    assert np.allclose(gap.to_numpy(), divergence.distance_m.to_numpy(), atol=2e-4)
    moved = set(divergence[divergence.distance_m > 0].car)
    names = {c["id"]: c["name"] for c in summary["cars"]}
    assert {names[c] for c in moved} <= set(summary["affected"])
    assert summary["affected"] == ["Car_1", "Car_2"]


def test_camera_frames_and_depth_load():
    scenario = ROOT / "cameras" / "cameras"
    chase = scenario / "cameras" / "chase_car1"
    depth = np.asarray(Image.open(chase / "depth" / "0010.png"))
    assert depth.dtype in (np.uint16, np.int32) and depth.shape == (256, 256)
    mask = np.asarray(Image.open(chase / "mask" / "0010.png"))
    # The followed car (mask id 1) sits at the centre, 1.5 m closer than the road beside it.
    assert mask[128, 128] == 1 and mask[128, 148] == 0
    assert int(depth[128, 148]) - int(depth[128, 128]) > 1000
    poses = pd.read_csv(chase / "poses.csv")
    assert list(poses.columns) == ["frame", "car", "px", "py", "in_view"]
    followed = poses[poses.car == 0]
    assert np.allclose(followed.px, 127.5, atol=1e-3) and np.allclose(followed.py, 127.5, atol=1e-3)
