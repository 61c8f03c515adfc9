"""Packed datasets (``gen --format tar``) from Python: ``generate`` writes
them, ``open_dataset`` reads them into the same arrays as the folder
layout, ``read_tar`` streams a tar's scenarios with the folders' bytes, and
``evaluate`` scores them as it scores folders."""

import io
import json
import pickle
import shutil
import tarfile
from pathlib import Path

import numpy as np
import pytest

import causalcity

SPEC = {
    "name": "packed-py",
    "world": "city",
    "seed": 9,
    "frames": 24,
    "frame_interval": 0.5,
    "image": {"width": 128, "height": 80},
    "groups": [{"cars": 4, "edge_proportion": 0.5}, {"cars": 5, "edge_proportion": 0.5}],
    "splits": {"train": 3, "val": 2, "test": 2},
}


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    root = tmp_path_factory.mktemp("packs")
    folders, packed = root / "folders", root / "packed"
    causalcity.generate(SPEC, folders, progress=False)
    summary = causalcity.generate(SPEC, packed, progress=False, format="tar", scenarios_per_tar=2)
    assert summary["written"] == 14
    return folders, packed


def test_a_packed_dataset_is_a_few_tars_whose_scenarios_hold_the_folders_bytes(datasets):
    folders, packed = datasets
    tars = sorted(p.relative_to(packed).as_posix() for p in packed.rglob("*.tar"))
    # Each group: train 00000-00001, 00002-00002; val 00000-00001; test 00000-00001.
    assert len(tars) == 8 and "cars05_edges50/train/00002-00002.tar" in tars, tars
    assert sorted(p.name for p in packed.iterdir() if p.is_file()) == ["manifest.json"]
    seen = 0
    for tar in tars:
        for folder, files in causalcity.read_tar(packed / tar):
            on_disk = sorted(p.relative_to(folders / folder).as_posix() for p in (folders / folder).rglob("*") if p.is_file())
            assert sorted(files) == on_disk
            assert "rgb/0023.png" in files and "poses.csv" in files
            for name, data in files.items():
                assert data == (folders / folder / name).read_bytes(), f"{folder}/{name}"
            seen += 1
    assert seen == 14


def test_open_dataset_reads_packs_into_the_arrays_the_folders_give(datasets):
    folders, packed = datasets
    a, b = causalcity.open_dataset(folders), causalcity.open_dataset(packed)
    assert b.scenarios_per_tar == 2 and a.scenarios_per_tar is None
    assert a.keys() == b.keys() and len(b) == 14
    for key in b.keys():
        x, y = a.load(key), b.load(key)
        assert y.key == key == x.key
        for field in ("position", "rotation", "pixels", "speed", "in_view", "graph"):
            np.testing.assert_array_equal(getattr(x, field), getattr(y, field), err_msg=f"{key} {field}")
        np.testing.assert_array_equal(x.lights.colour, y.lights.colour)
        np.testing.assert_array_equal(np.asarray(x.rgb), np.asarray(y.rgb))
        np.testing.assert_array_equal(np.asarray(x.mask), np.asarray(y.mask))
        assert y.rgb.shape == (24, 80, 128, 3)
    assert b.pack_of(b.keys("test")[1]) == "cars04_edges50/test/00000-00001.tar"
    # To DataLoader workers it goes as a plain object, and reads there.
    copy = pickle.loads(pickle.dumps(causalcity.open_dataset(packed, "val")))
    np.testing.assert_array_equal(copy[0].position, a.load(copy.keys()[0]).position)
    with pytest.raises(KeyError):
        b.load(("cars04_edges50", "test", 7))
    # Frames read from the temporary folder outlive the Dataset that made it.
    scenario = causalcity.open_dataset(packed)[3]
    import gc

    gc.collect()
    np.testing.assert_array_equal(scenario.rgb[23], a[3].rgb[23])


def test_reading_a_packed_dataset_unpacks_one_scenario_at_a_time_and_leaves_nothing(datasets, tmp_path, monkeypatch):
    # A shuffled DataLoader over a paper-size packed dataset must not fill
    # TMPDIR: a scenario is unpacked alone, and goes when its frames do.
    import gc
    import tempfile

    folders, packed = datasets
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    dataset = causalcity.open_dataset(packed, "train")
    unpacked = lambda: sorted(p.relative_to(scratch).as_posix() for p in scratch.rglob("*") if p.is_file())
    without = dataset.load(dataset.keys()[1], images=False)
    assert without.rgb is None and unpacked() == []
    scenario = dataset[2]
    files = unpacked()
    on_disk = sorted(p.relative_to(folders / scenario.key.folder).as_posix() for p in (folders / scenario.key.folder).rglob("*") if p.is_file())
    # Only its own files, though its pack holds another scenario.
    assert len(files) == len(on_disk) and all(f.split("/", 1)[1] in on_disk for f in files), files[:5]
    np.testing.assert_array_equal(np.asarray(scenario.rgb), np.asarray(causalcity.open_dataset(folders)[scenario.key].rgb))
    assert scenario.key == dataset.keys()[2]
    del scenario
    gc.collect()
    assert unpacked() == []
    # An epoch leaves at most the scenario still held behind.
    for s in dataset:
        assert s.position.shape[0] > 0
        assert len({f.split("/", 1)[0] for f in unpacked()}) == 1
    del s
    gc.collect()
    assert unpacked() == []


def test_evaluate_scores_a_packed_dataset_as_its_folders(datasets, tmp_path):
    folders, packed = datasets
    rng = np.random.default_rng(3)
    edges = {}
    for meta_path in sorted(folders.glob("*/*/*/scenario.json")):
        rel = meta_path.parent.relative_to(folders).as_posix()
        if "/train/" in rel:
            continue
        meta = json.loads(meta_path.read_text())
        n = len(meta["cars"])
        truth = np.zeros((n, n))
        for lead, follow in meta["edges"]:
            truth[lead, follow] = 1
        edges[rel] = truth * 0.5 + rng.random((n, n))
    path = tmp_path / "pred.npz"
    causalcity.save_predictions(path, edges, dataset=folders)
    a = causalcity.evaluate(folders, path, history=10)
    b = causalcity.evaluate(packed, path, history=10)
    for report in (a, b):
        report.pop("dataset", None)
    assert a["edges"] and a["scenarios"][0]["scenario"] == "cars04_edges50/test/00000"
    assert a == b


def test_generate_refuses_a_format_it_does_not_know_and_a_tar_size_without_tar(tmp_path):
    with pytest.raises(causalcity.InputError, match='format=.zip.: "folders" or "tar"'):
        causalcity.generate(SPEC, tmp_path / "a", format="zip", progress=False)
    with pytest.raises(causalcity.InputError, match="give it with format=.tar."):
        causalcity.generate(SPEC, tmp_path / "b", scenarios_per_tar=4, progress=False)
    with pytest.raises(causalcity.InputError, match="scenarios_per_tar=0 is out of range"):
        causalcity.generate(SPEC, tmp_path / "c", format="tar", scenarios_per_tar=0, progress=False)
    assert not any(tmp_path.iterdir())


def test_read_tar_reads_a_pack_made_by_hand_with_its_folder_entries(datasets, tmp_path):
    # `tar -cf` of scenario folders lists the folders as members too.
    folders, _ = datasets
    by_hand = tmp_path / "by-hand.tar"
    with tarfile.open(by_hand, "w") as tar:
        for folder in ["cars04_edges50/val/00000", "cars04_edges50/val/00001"]:
            tar.add(folders / folder, arcname=folder)
    assert any(m.isdir() for m in tarfile.open(by_hand).getmembers())
    read = {folder: files for folder, files in causalcity.read_tar(by_hand)}
    assert sorted(read) == ["cars04_edges50/val/00000", "cars04_edges50/val/00001"]
    for folder, files in read.items():
        assert files["poses.csv"] == (folders / folder / "poses.csv").read_bytes()
        assert len(files) == sum(1 for p in (folders / folder).rglob("*") if p.is_file())


def test_read_tar_refuses_a_member_outside_the_dataset(tmp_path):
    bad = tmp_path / "bad.tar"
    with tarfile.open(bad, "w") as tar:
        data = tmp_path / "x"
        data.write_bytes(b"x")
        tar.add(data, arcname="../../etc/x")
    with pytest.raises(causalcity.InputError, match="is not a scenario's file"):
        list(causalcity.read_tar(bad))


def test_the_pytorch_recipe_of_the_docs_streams_every_scenario_of_a_split(datasets):
    torch = pytest.importorskip("torch")
    folders, packed = datasets
    docs = (Path(__file__).resolve().parents[2] / "docs" / "python.md").read_text()
    recipe = docs.split("class PackedSplit", 1)[1].split("loader = ", 1)[0]
    scope = {}
    exec("import io, json\nfrom pathlib import Path\nimport numpy as np, torch, causalcity\nclass PackedSplit" + recipe, scope)
    loader = torch.utils.data.DataLoader(scope["PackedSplit"](packed, "train"), batch_size=None, num_workers=2)
    got = dict(loader)
    assert sorted(got) == sorted(f"{g}/train/{i:05d}" for g in ("cars04_edges50", "cars05_edges50") for i in range(3))
    for folder, xy in got.items():
        expected = causalcity.load(folders / folder).position[:, :, :2]
        np.testing.assert_array_equal(xy.numpy(), expected)


def test_every_reader_refuses_a_pack_with_a_member_twice_apart_a_stranger_or_cut_short(datasets, tmp_path):
    # read_tar yielded a scenario twice (a member after the next scenario's), took the last of two copies and
    # read a pack cut short at a member's header as one with fewer scenarios; open_dataset took the last copy.
    import io
    import shutil

    _, packed = datasets
    rel = "cars04_edges50/val/00000-00001.tar"
    with tarfile.open(packed / rel) as tar:
        members = [(m.name, tar.extractfile(m).read()) for m in tar]
    poses = "cars04_edges50/val/00000/poses.csv"
    at = [name for name, _ in members].index(poses)
    edited = members[at][1][: members[at][1].index(b"\n") + 1]

    def tar_of(items):
        out = io.BytesIO()
        with tarfile.open(fileobj=out, mode="w") as tar:
            for name, data in items:
                info = tarfile.TarInfo(name)
                info.size = len(data)
                tar.addfile(info, io.BytesIO(data))
        return out.getvalue()

    whole = tar_of(members)
    last_header = whole.rindex(members[-1][0].encode()) // 512 * 512
    cases = {
        "twice": (tar_of(members[: at + 1] + [(poses, edited)] + members[at + 1 :]), "is in it twice"),
        "apart": (tar_of(members + [(poses, edited)]), "do not run together"),
        "stranger": (tar_of(members + [("cars05_edges50/val/00000/poses.csv", edited)]), "belongs to none of its"),
        "cut": (whole[:last_header], "cut short"),
    }
    for case, (data, says) in cases.items():
        copy = tmp_path / case
        shutil.copytree(packed, copy)
        (copy / rel).write_bytes(data)
        with pytest.raises(causalcity.InputError, match=says) as raised:
            list(causalcity.read_tar(copy / rel))
        assert str(copy / rel) in str(raised.value), raised.value
        with pytest.raises(causalcity.InputError, match=says):
            causalcity.open_dataset(copy, images=False)[("cars04_edges50", "val", 1)]
    # Members named from `./` (`tar -cf pack.tar ./group/...`) are read as the pack gen wrote.
    dotted = tmp_path / "dotted"
    shutil.copytree(packed, dotted)
    (dotted / rel).write_bytes(tar_of([("./" + name, data) for name, data in members]))
    assert list(causalcity.read_tar(dotted / rel)) == list(causalcity.read_tar(packed / rel))
    key = ("cars04_edges50", "val", 1)
    got, want = causalcity.open_dataset(dotted, images=False)[key], causalcity.open_dataset(packed, images=False)[key]
    np.testing.assert_array_equal(got.position, want.position)


def test_the_reference_methods_read_a_packed_dataset_as_its_folders(datasets, tmp_path):
    # methods.load_split and reference globbed scenario folders only: a
    # packed dataset that validate called valid was "0 scenario folders,
    # but manifest.json lists 3", exit 2, though python.md says a packed
    # dataset opens the same way.
    import subprocess
    import sys

    from causalcity import reference
    from causalcity.methods import load_split

    folders, packed = datasets
    compared = 0
    for group in ("cars04_edges50", "cars05_edges50"):
        for split in ("train", "val", "test"):
            a, b = load_split(folders, group, split), load_split(packed, group, split)
            assert a.folders == b.folders and len(b.folders) == SPEC["splits"][split]
            for field in ("pixels", "metres", "graph"):
                np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=f"{group} {split} {field}")
            compared += 1
    assert compared == 6
    scores = {}
    for name, data in (("folders", folders), ("packed", packed)):
        out = tmp_path / f"{name}.npz"
        run = subprocess.run([sys.executable, "-m", "causalcity.methods", "path", str(data), "--out", str(out), "--quiet"],
                             capture_output=True, text=True)  # fmt: skip
        assert run.returncode == 0, run.stderr
        with np.load(out) as arrays:
            scores[name] = {k: arrays[k] for k in arrays.files if k.count("/") == 2}
    assert len(scores["packed"]) == 2 * (SPEC["splits"]["val"] + SPEC["splits"]["test"]), sorted(scores["packed"])
    assert scores["folders"].keys() == scores["packed"].keys()
    for k in scores["folders"]:
        np.testing.assert_array_equal(scores["folders"][k], scores["packed"][k], err_msg=k)
    assert reference.evaluate(packed, methods=["frame0"]) == reference.evaluate(folders, methods=["frame0"])


def test_the_reference_classifiers_name_a_damaged_pack_not_the_folder_they_unpacked_it_into(datasets, tmp_path):
    from causalcity import reference

    _, packed = datasets
    for damage in ("missing", "emptied"):
        data = tmp_path / damage
        shutil.copytree(packed, data)
        pack = data / "cars04_edges50/val/00000-00001.tar"
        with tarfile.open(pack) as tar:
            members = [(m, tar.extractfile(m).read() if m.isfile() else None) for m in tar.getmembers()]
        with tarfile.open(pack, "w") as tar:
            for member, data_bytes in members:
                if member.name.endswith("00000/poses.csv"):
                    if damage == "missing":
                        continue
                    data_bytes, member.size = b"", 0
                tar.addfile(member, io.BytesIO(data_bytes) if data_bytes is not None else None)
        with pytest.raises((ValueError, OSError)) as raised:
            reference.evaluate(data, methods=["frame0"], groups=["cars04_edges50"])
        said = str(raised.value)
        assert f"{pack}: cars04_edges50/val/00000" in said, said
        assert "causalcity-reference" not in said, said
