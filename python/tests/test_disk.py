"""Datasets read back from disk (`causalcity.open_dataset`, `causalcity.load`)
equal what `simulate` gives for the same keys: every array, every log, every
frame, read from the folders `make test-python` wrote with `causalcity gen`.
"""

import dataclasses
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

import causalcity

ROOT = Path(__file__).resolve().parents[2]
DATA = Path(os.environ.get("CAUSALCITY_DATA", ROOT / "target" / "python-data"))
STOP_THE_LEADER = ROOT / "configs" / "examples" / "stop-the-leader.json"


def assert_same_scenario(loaded, simulated):
    """Every field of two Scenario objects equal, frames decoded in full."""
    compared = 0
    for field in dataclasses.fields(causalcity.Scenario):
        a, b = getattr(loaded, field.name), getattr(simulated, field.name)
        if field.name in ("rgb", "mask"):
            assert (a is None) == (b is None), field.name
            if b is not None:
                assert a.shape == b.shape and a.dtype == b.dtype
                np.testing.assert_array_equal(np.asarray(a), b, err_msg=field.name)
        elif dataclasses.is_dataclass(b):
            for part in dataclasses.fields(b):
                x, y = getattr(a, part.name), getattr(b, part.name)
                if isinstance(y, np.ndarray):
                    assert x.dtype == y.dtype and x.shape == y.shape, f"{field.name}.{part.name}"
                    np.testing.assert_array_equal(x, y, err_msg=f"{field.name}.{part.name}")
                else:
                    assert x == y, f"{field.name}.{part.name}"
        elif isinstance(b, np.ndarray):
            assert a.dtype == b.dtype and a.shape == b.shape, field.name
            np.testing.assert_array_equal(a, b, err_msg=field.name)
        else:
            assert a == b, field.name
        compared += 1
    assert compared == len(dataclasses.fields(causalcity.Scenario))


def test_a_city_dataset_read_from_disk_equals_simulate_frames_included():
    data = causalcity.open_dataset(DATA / "city")
    keys = data.keys()
    assert len(keys) == len(data) == 3 and data.images
    assert data.keys("test") == [k for k in keys if k.split == "test"]
    events = 0
    for key, loaded in zip(keys, data):
        assert loaded.key == key
        assert isinstance(loaded.rgb, causalcity.Frames) and isinstance(loaded.mask, causalcity.Frames)
        simulated = causalcity.simulate(data.spec, *key, images=True)
        assert_same_scenario(loaded, simulated)
        events += len(loaded.events)
        assert loaded.lights is not None and loaded.interactions is not None and loaded.effects is not None
    assert events > 0


def test_a_toy_dataset_read_from_disk_equals_simulate():
    data = causalcity.open_dataset(DATA / "toy")
    keys = data.keys()
    assert len(keys) == 8
    for key in keys:
        loaded = causalcity.load(DATA / "toy" / key.folder)
        assert loaded.key == key and loaded.lights is None and loaded.interactions is None
        assert_same_scenario(loaded, causalcity.simulate(data.spec, *key, images=True))
        np.testing.assert_array_equal(loaded.causal_graph, loaded.graph)


def test_counterfactual_folders_read_back_as_the_pair_simulates():
    (pair,) = causalcity.counterfactual(STOP_THE_LEADER)
    folder = DATA / "counterfactual" / pair.name
    factual = causalcity.load(folder / "factual", images=False)
    counterfactual = causalcity.load(folder / "counterfactual", images=False)
    assert factual.key is None and factual.rgb is None
    for loaded, simulated in ((factual, pair.factual), (counterfactual, pair.counterfactual)):
        assert_same_scenario(loaded, simulated)


def test_frames_are_decoded_when_used_and_index_like_the_array():
    key = causalcity.open_dataset(DATA / "city").keys("val")[0]
    whole = causalcity.simulate(causalcity.open_dataset(DATA / "city").spec, *key, images=True)
    loaded = causalcity.load(DATA / "city" / key.folder)
    frames = loaded.rgb
    assert len(frames) == whole.frames and frames.shape == whole.rgb.shape and frames.ndim == 4
    np.testing.assert_array_equal(frames[3], whole.rgb[3])
    np.testing.assert_array_equal(frames[-1], whole.rgb[-1])
    np.testing.assert_array_equal(frames[5:9], whole.rgb[5:9])
    np.testing.assert_array_equal(frames[::7], whole.rgb[::7])
    np.testing.assert_array_equal(frames[[0, 4]], whole.rgb[[0, 4]])
    np.testing.assert_array_equal(frames[2, 100:110, 5], whole.rgb[2, 100:110, 5])
    np.testing.assert_array_equal(frames[:3, 10:20], whole.rgb[:3, 10:20])
    np.testing.assert_array_equal(frames[[0, 2], 5], whole.rgb[[0, 2], 5])
    np.testing.assert_array_equal(frames[..., 0], whole.rgb[..., 0])
    np.testing.assert_array_equal(frames[np.int64(4)], whole.rgb[4])
    for empty in (slice(5, 2, 2), slice(3, 3), []):
        assert frames[empty].shape == whole.rgb[empty].shape
    np.testing.assert_array_equal(loaded.mask[1:3], whole.mask[1:3])
    assert sum(1 for _ in loaded.mask) == whole.frames
    with pytest.raises(IndexError, match="frame 30 is outside"):
        frames[whole.frames]


def test_frames_stay_on_disk_until_used(tmp_path):
    key = causalcity.open_dataset(DATA / "city").keys("train")[0]
    folder = tmp_path / "scenario"
    shutil.copytree(DATA / "city" / key.folder, folder)
    loaded = causalcity.load(folder)
    (folder / "rgb" / "0004.png").unlink()
    np.testing.assert_array_equal(loaded.rgb[3], np.asarray(causalcity.load(DATA / "city" / key.folder).rgb[3]))
    with pytest.raises(causalcity.InputError, match=r"rgb/0004\.png"):
        loaded.rgb[4]


def test_bad_folders_are_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="no scenario.json"):
        causalcity.load(tmp_path)
    with pytest.raises(FileNotFoundError, match="no manifest.json"):
        causalcity.open_dataset(tmp_path)
    with pytest.raises(FileNotFoundError, match="open_sweep"):
        causalcity.open_dataset(DATA / "sweep")
    key = causalcity.open_dataset(DATA / "city").keys("test")[0]
    folder = tmp_path / "broken"
    shutil.copytree(DATA / "city" / key.folder, folder)
    poses = (folder / "poses.csv").read_text().splitlines()
    cells = poses[5].split(",")
    cells[4] = "north"
    poses[5] = ",".join(cells)
    (folder / "poses.csv").write_text("\n".join(poses) + "\n")
    with pytest.raises(causalcity.InputError, match=r"poses\.csv line 6: y \"north\""):
        causalcity.load(folder)
    with pytest.raises(KeyError, match="not in"):
        causalcity.open_dataset(DATA / "city").load(("cars08_edges50", "test", 7))
    lights = folder / "light_changes.csv"
    shutil.copy(DATA / "city" / key.folder / "poses.csv", folder / "poses.csv")
    rows = lights.read_text().splitlines()
    lights.write_text("\n".join(rows[:1] + [rows[1].replace(",red,", ",blue,").replace(",green,", ",blue,").replace(",yellow,", ",blue,")] + rows[2:]) + "\n")
    with pytest.raises(causalcity.InputError, match=r"light_changes\.csv line 2: colour \"blue\""):
        causalcity.load(folder)
    # A city folder must hold its logs, and effects where scenario.json lists causal edges.
    for name in ("light_changes.csv", "effects.csv"):
        shutil.copy(DATA / "city" / key.folder / "light_changes.csv", lights)
        (folder / name).rename(folder / (name + ".away"))
        with pytest.raises(causalcity.InputError, match=f"{name}.*No such file"):
            causalcity.load(folder)
        (folder / (name + ".away")).rename(folder / name)
    # A scenario.json claiming more poses than poses.csv holds is refused before any memory is taken.
    meta = json.loads((folder / "scenario.json").read_text())
    # (The most frames a scenario may have; beyond that the count itself is refused.)
    meta["frames"] = 100_000
    (folder / "scenario.json").write_text(json.dumps(meta))
    with pytest.raises(causalcity.InputError, match="more rows than .*poses.csv"):
        causalcity.load(folder)


def test_an_unfinished_dataset_warns_and_lists_what_it_has(tmp_path):
    root = tmp_path / "partial"
    shutil.copytree(DATA / "city", root)
    manifest = json.loads((root / "manifest.json").read_text())
    manifest["complete"] = False
    (root / "manifest.json").write_text(json.dumps(manifest))
    key = causalcity.open_dataset(DATA / "city").keys("val")[0]
    shutil.rmtree(root / key.folder)
    with pytest.warns(UserWarning, match="unfinished"):
        data = causalcity.open_dataset(root)
    assert len(data.keys()) == 2 and key not in data.keys()


def test_a_split_opened_from_disk_is_a_map_style_dataset_for_a_dataloader():
    torch = pytest.importorskip("torch")
    data = causalcity.open_dataset(DATA / "city", "test", images=False)
    assert len(data) == 1 and data.keys() == causalcity.open_dataset(DATA / "city").keys("test")
    loader = torch.utils.data.DataLoader(data, batch_size=1, collate_fn=causalcity.collate)
    (batch,) = list(loader)
    simulated = causalcity.simulate(data.spec, *data.keys()[0])
    assert batch["key"] == [simulated.key] and "rgb" not in batch
    np.testing.assert_array_equal(batch["position"][0].numpy(), simulated.position)
    np.testing.assert_array_equal(batch["graph"][0].numpy(), simulated.graph)
    with pytest.raises(causalcity.InputError, match="split 'dev'"):
        causalcity.open_dataset(DATA / "city", "dev")


def test_a_dataset_hands_out_only_its_own_scenarios_by_key(tmp_path):
    # Keys outside the dataset were read: another split's (opened with one),
    # and with ../ in the group, another dataset's.
    train = causalcity.open_dataset(DATA / "city", "train", images=False)
    test_key = causalcity.open_dataset(DATA / "city").keys("test")[0]
    with pytest.raises(KeyError, match="'s train split"):
        train.load(test_key)
    with pytest.raises(KeyError, match="is not in"):
        train[tuple(test_key)]
    sneaky = (f"{test_key.group}/train/00000/../../../../toy/cars04_edges50", "train", 0)
    with pytest.raises(KeyError, match="is not in"):
        causalcity.open_dataset(DATA / "city").load(sneaky)
    for bad in ["cars08_edges50/train/00000", ("cars08_edges50", "train", "0"), True, 1.5, None]:
        with pytest.raises(TypeError, match="not a scenario key"):
            train[bad]
    for split in ("bogus", 0):
        with pytest.raises(causalcity.InputError, match="is not one of train, val, test"):
            train.keys(split)
        with pytest.raises(causalcity.InputError, match="is not one of train, val, test"):
            list(train.scenarios(split))
    # Its own keys still load, by key, tuple and position.
    key = train.keys()[0]
    assert train.load(key).key == key == train[tuple(key)].key == train[0].key
    assert train[-1].key == train.keys()[-1]
    # A position past the end names the count (it said "list index out of range").
    with pytest.raises(IndexError, match=rf"position {len(train)} is outside the {len(train)} scenarios of .* \(train split\)"):
        train[len(train)]


def test_a_manifest_edited_or_malformed_is_named_and_a_missing_scenario_is_told(tmp_path):
    def copy_with(name, edit):
        root = tmp_path / name
        shutil.copytree(DATA / "city", root)
        manifest = json.loads((root / "manifest.json").read_text())
        manifest = edit(manifest)
        (root / "manifest.json").write_text(json.dumps(manifest))
        return root

    def reseed(m):
        m["spec"]["seed"] += 1
        return m

    # Another seed: open_dataset took it, and simulate(spec, key) no longer
    # gave the scenario on disk.
    with pytest.raises(causalcity.InputError, match=r"manifest\.json: its spec does not hash to its spec_sha256"):
        causalcity.open_dataset(copy_with("seed", reseed))
    for name, edit, says in [
        ("list", lambda m: [m], "expected an object, found list"),
        ("nospec", lambda m: {k: v for k, v in m.items() if k != "spec"}, "field spec: missing"),
        ("pertar", lambda m: {**m, "scenarios_per_tar": "x"}, "field scenarios_per_tar: 'x'"),
        ("limit", lambda m: {**m, "limit": -1}, "field limit: -1"),
    ]:
        with pytest.raises(causalcity.InputError, match=f"manifest.json: {says}"):
            causalcity.open_dataset(copy_with(name, edit))
    # A complete dataset missing a scenario folder says so.
    root = copy_with("missing", lambda m: m)
    key = causalcity.open_dataset(root).keys("val")[0]
    shutil.rmtree(root / key.folder)
    with pytest.warns(UserWarning, match=f"1 of the 3 scenarios its manifest lists are not on disk \\(first: {key.folder}\\)"):
        data = causalcity.open_dataset(root)
    assert key not in data.keys()


def test_a_sweeps_divergence_csv_is_read_as_written_or_named(tmp_path):
    root = tmp_path / "sweep"
    shutil.copytree(DATA / "sweep", root)
    sweep = causalcity.open_sweep(root)
    key = sweep.keys()[0]
    pair = sweep.load(key, images=False)
    path = root / key.folder / "divergence.csv"
    text = path.read_text()
    rows = text.splitlines()
    # The array is the file's: spot-check a row against the CSV.
    frame, _, car, metres, _ = rows[len(rows) // 2].split(",")
    assert pair.divergence[int(frame), int(car)] == float(metres)
    # Edited files were read without a check: IndexError, numpy errors, or a
    # frame -1 written silently into the last frame.
    for edit, says in [
        (rows[:1], "0 rows, expected"),
        ([rows[0]] + [rows[1].replace("0,", "999,", 1)] + rows[2:], "line 2: .*expected frame 0, car 0"),
        ([rows[0]] + [",".join(rows[1].split(",")[:3] + ["abc"] + rows[1].split(",")[4:])] + rows[2:], "line 2"),
        ([rows[0]] + ["-1,0.0,-1,7.0,1.0"] + rows[2:], "line 2"),
        (["frame,car"] + rows[1:], "line 1: expected the header"),
    ]:
        path.write_text("\n".join(edit) + "\n")
        with pytest.raises(causalcity.InputError, match=f"divergence.csv: {says}"):
            sweep.load(key, images=False)
    path.unlink()
    with pytest.raises(causalcity.InputError, match="divergence.csv: cannot read it"):
        sweep.load(key, images=False)
    with pytest.raises(KeyError, match="not a pair of"):
        sweep.load(("cars08_edges50/../..", "train", 0))


def test_a_sweep_whose_spec_was_edited_is_refused(tmp_path):
    # sweep.json recorded no hash: a sweep edited to another seed opened,
    # and simulate(sweep.spec, key) no longer gave its factual runs.
    root = tmp_path / "sweep"
    shutil.copytree(DATA / "sweep", root)
    record = json.loads((root / "sweep.json").read_text())
    assert record["spec_sha256"] == causalcity.open_sweep(root).spec._native.sha256
    record["spec"]["seed"] += 1
    (root / "sweep.json").write_text(json.dumps(record))
    with pytest.raises(causalcity.InputError, match=r"sweep\.json: its spec does not hash to its spec_sha256"):
        causalcity.open_sweep(root)
    # A sweep from before the hash was recorded opens as it did.
    del record["spec_sha256"]
    (root / "sweep.json").write_text(json.dumps(record))
    assert causalcity.open_sweep(root).keys()


def test_a_renamed_interactions_column_is_named(tmp_path):
    # interactions.csv's header was not read: a renamed column loaded as if
    # it were the one expected (poses.csv's header was checked).
    key = causalcity.open_dataset(DATA / "city").keys("test")[0]
    folder = tmp_path / "renamed"
    shutil.copytree(DATA / "city" / key.folder, folder)
    path = folder / "interactions.csv"
    lines = path.read_text().splitlines()
    assert lines[0] == "frame,car,bound_by,other_car,light"
    path.write_text("\n".join(["frame,car,bound_by,77,light"] + lines[1:]) + "\n")
    with pytest.raises(causalcity.InputError, match=r'interactions\.csv: columns .*"77"'):
        causalcity.load(folder)


def test_a_scenario_without_its_frames_in_a_dataset_with_images_is_named(tmp_path):
    root = tmp_path / "city"
    shutil.copytree(DATA / "city", root)
    key = causalcity.open_dataset(root).keys("test")[0]
    shutil.rmtree(root / key.folder / "rgb")
    with pytest.raises(causalcity.InputError, match="no rgb/ though the dataset has images"):
        causalcity.open_dataset(root).load(key)
    assert causalcity.open_dataset(root, images=False).load(key).rgb is None


def test_gen_force_never_removes_a_dataset_held_open_and_none_is_opened_while_removed(tmp_path):
    # Readers took no lock: gen --force removed a dataset under a training
    # loop, which then failed part way through an epoch.
    import fcntl
    import pickle
    import shlex
    import subprocess

    from causalcity.methods.common import Method, Predicted, run_method

    spec = {"name": "held", "world": "toy", "seed": 5, "frames": 6, "groups": [{"cars": 4, "edge_proportion": 0.5}],
            "splits": {"train": 2, "val": 1, "test": 1}}  # fmt: skip
    out = tmp_path / "held"
    causalcity.generate(spec, out, progress=False, images=False)
    (tmp_path / "other.json").write_text(json.dumps(dict(spec, seed=6)))
    command = shlex.split(os.environ.get("CAUSALCITY_CLI", "target/release/causalcity"))
    force = command + ["gen", "--quiet", "--no-images", "--force", "--spec", str(tmp_path / "other.json"), "--out", str(out)]

    def files():
        return {p.relative_to(out): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}

    data = causalcity.open_dataset(out, "train")
    # A plain gen replaces the manifest whole; the hold is on the folder.
    causalcity.generate(spec, out, progress=False, images=False)
    before = files()
    refused = subprocess.run(force, capture_output=True, text=True)
    assert refused.returncode == 2 and "is open for reading" in refused.stderr, refused.stderr
    assert files() == before
    # In this very process too, and a copy for a DataLoader worker reads
    # under the hold of the one it came from.
    with pytest.raises(causalcity.InputError, match="is open for reading"):
        causalcity.generate(dict(spec, seed=6), out, progress=False, images=False, force=True)
    copy = pickle.loads(pickle.dumps(data))
    assert copy[0].key == data[0].key and files() == before
    # A forked worker shares the open folder: its letting go is not its
    # parent's, and its parent's close() lets go while it still runs.
    child = os.fork()
    if child == 0:
        data.close()
        os._exit(0)
    os.waitpid(child, 0)
    assert subprocess.run(force, capture_output=True, text=True).returncode == 2
    read, write = os.pipe()
    child = os.fork()
    if child == 0:
        os.read(read, 1)
        os._exit(0)
    data.close()
    forced = subprocess.run(force, capture_output=True, text=True)
    os.write(write, b"x")
    os.waitpid(child, 0)
    assert forced.returncode == 0, forced.stderr
    assert files() != before
    with causalcity.open_dataset(out) as data:
        assert data.spec.seed == 6 and len(data) == 4
    after = files()
    causalcity.generate(spec, out, progress=False, images=False, force=True)
    assert files() != after, "a with block kept its hold"

    # The reference methods hold it while they train: a gen --force run
    # from inside fit is refused.
    class Regenerates(Method):
        def fit(self, train, val):
            self.forced = subprocess.run(force, capture_output=True, text=True)

        def predict(self, episodes):
            return Predicted(edges=np.zeros((len(episodes), episodes.cars, episodes.cars)))

    made = []
    run_method(lambda: made.append(Regenerates()) or made[-1], out, tmp_path / "pred.npz", quiet=True)
    assert made and made[0].forced.returncode == 2 and "is open for reading" in made[0].forced.stderr

    # gen --force holds the folder alone while it removes, as here: the
    # dataset is not opened half gone.
    folder = os.open(out, os.O_RDONLY)
    try:
        fcntl.flock(folder, fcntl.LOCK_EX | fcntl.LOCK_NB)
        with pytest.raises(causalcity.InputError, match="is being removed by gen --force"):
            causalcity.open_dataset(out)
    finally:
        os.close(folder)
    assert len(causalcity.open_dataset(out)) == 4


def test_a_dataset_still_open_as_the_interpreter_exits_says_nothing(tmp_path):
    # python.md's DataLoader loop, run as a script that leaves its dataset
    # open: the hold let go as the interpreter shut down imported fcntl,
    # which failed ("Exception ignored in: <function _ReadHold.__del__ ...>"
    # and a traceback on stderr, every run with torch imported).
    import subprocess
    import sys

    script = tmp_path / "loop.py"
    script.write_text(
        "import torch, causalcity\n"
        f"data = causalcity.open_dataset({os.fspath(DATA / 'city')!r}, 'train', images=False)\n"
        "loader = torch.utils.data.DataLoader(data, batch_size=3, shuffle=True, collate_fn=causalcity.collate)\n"
        "batches = sum(1 for batch in loader)\n"
        "print(batches)\n"
    )
    seen = []
    for _ in range(2):
        done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, env=os.environ.copy())
        assert done.returncode == 0, done.stderr
        assert int(done.stdout) >= 1, "the loop read no batch"
        seen.append(done.stderr)
    assert seen == ["", ""], seen
