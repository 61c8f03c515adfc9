"""Files of a dataset damaged, edited or replaced, read by the Python
package: each is an InputError naming the file (and field) or gives what
numpy would, never another scenario's arrays under the key asked for, a
value outside the schema, a hang or a raw traceback from a library."""

import json
import os
import shutil
import tarfile
from pathlib import Path

import numpy as np
import pytest

import causalcity

SPEC = {
    "name": "damaged",
    "world": "toy",
    "seed": 5,
    "frames": 6,
    "image": {"width": 256, "height": 160},
    "groups": [{"cars": 4, "edge_proportion": 0.5}],
    "splits": {"train": 2, "val": 1, "test": 1},
}
CITY = dict(json.loads((Path(__file__).resolve().parents[2] / "configs" / "ci-city.json").read_text()))
GROUP = "cars04_edges50"
FIRST = f"{GROUP}/train/00000"


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    out = tmp_path_factory.mktemp("damaged") / "toy"
    causalcity.generate(SPEC, out, progress=False)
    return out


@pytest.fixture(scope="module")
def packed(tmp_path_factory):
    out = tmp_path_factory.mktemp("damaged") / "packed"
    causalcity.generate(SPEC, out, progress=False, images=False, format="tar", scenarios_per_tar=2)
    return out


@pytest.fixture(scope="module")
def city(tmp_path_factory):
    out = tmp_path_factory.mktemp("damaged") / "city"
    spec = dict(CITY, name="damaged-city", frames=12, groups=[{"cars": 4, "edge_proportion": 0.5}],
                splits={"train": 1, "val": 1, "test": 1})  # fmt: skip
    causalcity.generate(spec, out, progress=False, images=False)
    return out


def in_a_process(code, *args):
    """Runs ``code`` (given ``args`` as sys.argv[1:]) in a fresh Python, at
    most 60 s (a reader that opens a pipe waits for a writer forever, in
    native code no signal reaches): its stderr."""
    import subprocess
    import sys

    try:
        run = subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True, timeout=60)
    except subprocess.TimeoutExpired:
        pytest.fail(f"still reading after 60 s (a pipe was opened): {code}")
    return run.stderr


def copy_of(dataset, tmp_path, name="copy"):
    to = tmp_path / name
    shutil.copytree(dataset, to, symlinks=True)
    return to


def edit_json(path, edit):
    value = json.loads(path.read_text())
    edit(value)
    path.write_text(json.dumps(value))


def set_field(path, row, column, value):
    """CSV `path` with `column` of data row `row` set to `value`."""
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    fields = lines[row + 1].split(",")
    fields[header.index(column)] = value
    lines[row + 1] = ",".join(fields)
    path.write_text("\n".join(lines) + "\n")


def test_a_scenario_is_never_handed_back_under_another_key(toy, packed, tmp_path):
    # A folder linked to another scenario's, or an edited index: the other
    # scenario's arrays came back as the key asked for.
    linked = copy_of(toy, tmp_path, "linked")
    target = linked / FIRST
    shutil.rmtree(target)
    target.symlink_to(linked / GROUP / "train" / "00001", target_is_directory=True)
    data = causalcity.open_dataset(linked, "train")
    # A scenario folder that is a link is read from nowhere (as the
    # command line's readers have it).
    with pytest.raises(causalcity.InputError, match=r"train/00000 is a symbolic link \(to .*00001\)"):
        data.load((GROUP, "train", 0))
    assert data.load((GROUP, "train", 1)).key.index == 1, "the scenario itself still reads"
    # So do the reference methods' loaders (they read through it).
    from causalcity.methods.common import DatasetError, load_split
    from causalcity.reference import _scenario_folders

    with pytest.raises(DatasetError, match=r"train/00000 is a symbolic link \(to .*00001\)"):
        load_split(linked, GROUP, "train")
    with pytest.raises(causalcity.InputError, match=r"train/00000 is a symbolic link \(to .*00001\)"):
        with _scenario_folders(linked):
            pass
    with _scenario_folders(toy) as folders:
        assert len(load_split(toy, GROUP, "train")) == len(folders[(GROUP, "train")]) > 1

    edited = copy_of(toy, tmp_path, "edited")
    edit_json(edited / FIRST / "scenario.json", lambda v: v.update(index=7))
    with pytest.raises(causalcity.InputError, match="`index` is 7, but it lies at cars04_edges50/train/00000|"
                                                    "index 7, not cars04_edges50/train/00000"):  # fmt: skip
        causalcity.open_dataset(edited, "train").load((GROUP, "train", 0))

    # Two members of a pack renamed into each other's scenario.
    swapped = copy_of(packed, tmp_path, "swapped")
    pack = swapped / GROUP / "train" / "00000-00001.tar"
    with tarfile.open(pack) as tar:
        members = [(m, tar.extractfile(m).read()) for m in tar.getmembers()]
    with tarfile.open(pack, "w", format=tarfile.USTAR_FORMAT) as tar:
        renamed = []
        for m, data in members:
            m.name = m.name.replace("/00000/", "/0000X/").replace("/00001/", "/00000/").replace("/0000X/", "/00001/")
            renamed.append((m, data))
        for m, data in sorted(renamed, key=lambda md: md[0].name):
            tar.addfile(m, __import__("io").BytesIO(data))
    with pytest.raises(causalcity.InputError, match="`index` is 1, but it lies at cars04_edges50/train/00000|"
                                                    "index 1, not cars04_edges50/train/00000"):  # fmt: skip
        causalcity.open_dataset(swapped, "train").load((GROUP, "train", 0))


def test_a_scenario_of_another_dataset_is_never_handed_back_as_this_ones(toy, tmp_path):
    # Copied in at the same key, or linked there: the other dataset's
    # scenario came back as this one's, without a word.
    other = tmp_path / "other"
    causalcity.generate(dict(SPEC, seed=99), other, progress=False, images=False)
    checked = 0
    for how in ("copied", "linked"):
        copy = copy_of(toy, tmp_path, how)
        shutil.rmtree(copy / FIRST)
        if how == "copied":
            shutil.copytree(other / FIRST, copy / FIRST)
            says = r"its seed is 99, but the dataset's spec has seed 5"
        else:
            (copy / FIRST).symlink_to(other / FIRST, target_is_directory=True)
            says = r"is a symbolic link"
        data = causalcity.open_dataset(copy, "train", images=False)
        with pytest.raises(causalcity.InputError, match=says):
            data.load((GROUP, "train", 0))
        with pytest.raises(causalcity.InputError, match=says):
            list(data)
        assert data.load((GROUP, "train", 1)).metadata["seed"] == 5, "the dataset's own scenarios still read"
        checked += 1
    assert checked == 2


def test_pose_values_outside_the_schema_are_refused(toy, tmp_path):
    cases = [("speed", "nan", 'speed "nan" is not allowed'), ("x", "1e400", 'x "1e400" is not allowed'),
             ("speed", "-5", 'speed "-5" is not allowed'), ("t", "9.5", "t 9.5 differs from frame 1's t")]  # fmt: skip
    checked = 0
    for column, value, says in cases:
        copy = copy_of(toy, tmp_path, f"poses-{column}-{value}")
        set_field(copy / FIRST / "poses.csv", 5, column, value)
        with pytest.raises(causalcity.InputError, match=f"poses.csv line 7: {says}"):
            causalcity.load(copy / FIRST)
        checked += 1
    assert checked == len(cases)


def test_effects_must_agree_with_scenario_json(toy, tmp_path):
    # A repeated row, or a row that gives an edge scenario.json does not
    # list: read as written (causal_graph with an edge of no record).
    twice = copy_of(toy, tmp_path, "twice")
    path = twice / FIRST / "effects.csv"
    lines = path.read_text().splitlines()
    path.write_text("\n".join(lines + [lines[1]]) + "\n")
    with pytest.raises(causalcity.InputError, match="effects.csv: two rows for cause"):
        causalcity.load(twice / FIRST)

    disagrees = copy_of(toy, tmp_path, "disagrees")
    path = disagrees / FIRST / "effects.csv"
    rows = path.read_text().splitlines()
    meta = json.loads((disagrees / FIRST / "scenario.json").read_text())
    listed = {tuple(e) for e in meta["causal_edges"]}
    header = rows[0].split(",")
    for i, row in enumerate(rows[1:], start=1):
        fields = row.split(",")
        if (int(fields[0]), int(fields[1])) not in listed:
            fields[header.index("max_divergence_m")] = "3.0"
            fields[header.index("first_frame")] = "4"
            rows[i] = ",".join(fields)
            break
    else:
        pytest.fail("every pair is a causal edge: nothing to edit")
    path.write_text("\n".join(rows) + "\n")
    with pytest.raises(causalcity.InputError, match="scenario.json `causal_edges` is"):
        causalcity.load(disagrees / FIRST)

    edit_json(copy_of(toy, tmp_path, "threshold") / FIRST / "scenario.json", lambda v: v.update(effect_threshold_m="x"))
    with pytest.raises(causalcity.InputError, match='effect_threshold_m "x" is not allowed: metres above 0'):
        causalcity.load(tmp_path / "threshold" / FIRST)


def test_city_logs_outside_the_schema_are_refused(city, tmp_path):
    scenario = f"{GROUP}/train/00000"
    meta = json.loads((city / scenario / "scenario.json").read_text())
    cases = []
    events = (city / scenario / "events.csv").read_text().splitlines()
    if len(events) > 1:
        cases += [("events.csv", 0, "frame", str(meta["frames"]), "is beyond the scenario's"),
                  ("events.csv", 0, "t", "nan", "t NaN is not allowed: seconds, 0 or more")]  # fmt: skip
    cases += [("light_changes.csv", 0, "since_change", "-7", "since_change -7 is not allowed: seconds, 0 or more"),
              ("light_changes.csv", 0, "head_px", "inf", "head_px inf is not allowed: a finite pixel")]  # fmt: skip
    interactions = (city / scenario / "interactions.csv").read_text().splitlines()
    header = interactions[0].split(",")
    free = next(i for i, r in enumerate(interactions[1:]) if r.split(",")[header.index("bound_by")] == "free")
    car = interactions[free + 1].split(",")[header.index("car")]
    other = "1" if car != "1" else "0"
    cases += [("interactions.csv", free, "other_car", other, "bound_by free names an other_car"),
              ("interactions.csv", free, "other_car", car, f"car {car} is bound by itself")]  # fmt: skip
    checked = 0
    for n, (file, row, column, value, says) in enumerate(cases):
        copy = copy_of(city, tmp_path, f"city-{n}")
        set_field(copy / scenario / file, row, column, value)
        with pytest.raises(causalcity.InputError, match=f"{file}.*{says}"):
            causalcity.load(copy / scenario)
        checked += 1
    assert checked == len(cases) >= 4
    # A pipe for a log hung the reader (events, interactions, lights alike).
    for n, file in enumerate(["events.csv", "interactions.csv", "light_changes.csv"]):
        copy = copy_of(city, tmp_path, f"city-pipe-{n}")
        (copy / scenario / file).unlink()
        os.mkfifo(copy / scenario / file)
        said = in_a_process("import sys, causalcity; causalcity.load(sys.argv[1])", copy / scenario)
        assert f"{file}: not a regular file" in said, said


def test_frames_and_records_that_cannot_be_read_are_named(toy, tmp_path):
    copy = copy_of(toy, tmp_path, "frames")
    scenario = copy / FIRST
    # A pipe where a frame should be hung the reader; a link to /dev/zero filled memory.
    (scenario / "rgb" / "0003.png").unlink()
    os.mkfifo(scenario / "rgb" / "0003.png")
    (scenario / "rgb" / "0004.png").unlink()
    (scenario / "rgb" / "0004.png").symlink_to("/dev/zero")
    read = "import sys, causalcity; causalcity.load(sys.argv[1]).rgb[int(sys.argv[2])]"
    for frame in (3, 4):
        said = in_a_process(read, scenario, frame)
        assert f"InputError: cannot read {scenario}/rgb/000{frame}.png: not a regular file" in said, said
    s = causalcity.load(scenario)
    # A mask value that is no car of the scenario (4 cars: mask_ids 1 to 4).
    mask = np.asarray(s.mask[0]).copy()
    mask[0, 0] = 99
    from PIL import Image

    Image.fromarray(mask).save(scenario / "mask" / "0000.png")
    with pytest.raises(causalcity.InputError, match="mask frame 0 holds the value 99, and the scenario has 4 cars"):
        causalcity.load(scenario).mask[0]
    # Camera sizes that are no image's (a negative shape; true taken as 1; missing: a KeyError).
    for camera, says in [({"width": -256, "height": 160}, "camera.width: -256"), ({"width": True, "height": 160}, "camera.width: True"),
                         ({"height": 160}, "camera.width: None"), (None, "field camera: None")]:  # fmt: skip
        edit_json(scenario / "scenario.json", lambda v: v.update(camera=camera))
        with pytest.raises(causalcity.InputError, match=says):
            causalcity.load(scenario)
    # scenario.json a folder: named as one, not "no scenario.json".
    (scenario / "scenario.json").unlink()
    (scenario / "scenario.json").mkdir()
    with pytest.raises(causalcity.InputError, match="scenario.json: a folder"):
        causalcity.load(scenario)


def test_frames_index_as_numpy_does(toy):
    s = causalcity.open_dataset(toy, "train").load((GROUP, "train", 0))
    whole = np.asarray(s.rgb)
    picks = np.array([[1, 2], [3, 0]])
    assert s.rgb[picks].shape == whole[picks].shape == (2, 2, 160, 256, 3)
    np.testing.assert_array_equal(s.rgb[picks], whole[picks])
    assert s.rgb[True].shape == whole[True].shape == (1, 6, 160, 256, 3)
    # Index arrays after the first pair with it, as numpy pairs them (a
    # second array gave (2, 2, 256, 3) where numpy gives (2, 256, 3)), and
    # an int with an array apart from it moves their axis first.
    checked = 0
    for index in [([1, 3], [1, 3]), ([1, 3], slice(None), [0, 1]), (2, slice(None), [0, 2]), ([3, 1, 3], 5, [0, 2, 1]),
                  (np.array([[0, 2], [5, 1]]), [[1], [2]]), (slice(1, 4), slice(None), [0, 1]), ([], []),
                  (np.eye(6, 160, dtype=bool),)]:  # fmt: skip
        assert s.rgb[index].shape == whole[index].shape, index
        np.testing.assert_array_equal(s.rgb[index], whole[index])
        checked += 1
    assert checked == 8


def test_a_packed_scenarios_frames_read_where_a_dataloader_worker_sends_them(tmp_path, monkeypatch):
    # A packed dataset's scenario pickled (as a DataLoader worker sends it)
    # kept the path of its temporary folder, which the sender removed once
    # its own copy went: "cannot read /tmp/causalcity-scenario-.../rgb/0005.png".
    import gc
    import pickle

    causalcity.generate(SPEC, tmp_path / "folders", progress=False)
    causalcity.generate(SPEC, tmp_path / "packed", progress=False, format="tar", scenarios_per_tar=2)
    monkeypatch.chdir(tmp_path)  # opened by a relative path, as a user in the dataset's parent would
    folders, packed = (causalcity.open_dataset(n, "train") for n in ("folders", "packed"))
    for position in range(len(packed)):
        sent = pickle.dumps(packed[position])
        gc.collect()  # the sender's copy and its folder are gone
        with monkeypatch.context() as m:
            m.chdir(tmp_path / "folders")  # (a receiver elsewhere: the pack named whole)
            received = pickle.loads(sent)
            received.rgb[0]
        np.testing.assert_array_equal(np.asarray(received.rgb), np.asarray(folders[position].rgb))
        np.testing.assert_array_equal(received.mask[[5, 1]], np.asarray(folders[position].mask)[[5, 1]])
    assert position == len(folders) - 1 > 0


def test_frames_sent_to_another_process_read_the_pack_as_it_is_when_it_was_written_again(tmp_path):
    # Frames a worker sends carry where their bytes lie in the pack (the
    # receiver read the pack's headers up to them: 1.3 s for the rgb frames
    # of the last scenario of a pack of 64, against 0.07 s); a pack written
    # again meanwhile, its bytes elsewhere, is read again from its headers.
    import io
    import pickle

    causalcity.generate(SPEC, tmp_path / "folders", progress=False)
    causalcity.generate(SPEC, tmp_path / "packed", progress=False, format="tar", scenarios_per_tar=2)
    folders, packed = (causalcity.open_dataset(tmp_path / n, "train") for n in ("folders", "packed"))
    sent = [pickle.dumps(packed[i]) for i in range(len(packed))]
    assert all(pickle.loads(s).rgb._located for s in sent), "where the frames lie goes with them"
    for pack in sorted((tmp_path / "packed" / GROUP / "train").glob("*.tar")):
        with tarfile.open(pack) as tar:
            members = [(m, tar.extractfile(m).read()) for m in tar.getmembers()]
        with tarfile.open(pack.with_suffix(".new"), "w", format=tarfile.PAX_FORMAT) as tar:
            for m, data in members:
                m.pax_headers = {"comment": "moved"}  # an extra header block before each member
                tar.addfile(m, io.BytesIO(data))
        os.replace(pack.with_suffix(".new"), pack)
    for position, message in enumerate(sent):
        received = pickle.loads(message)
        np.testing.assert_array_equal(np.asarray(received.rgb), np.asarray(folders[position].rgb))
        np.testing.assert_array_equal(np.asarray(received.mask), np.asarray(folders[position].mask))
    assert position == len(folders) - 1 > 0


def test_a_damaged_packs_frames_and_missing_files_are_named_by_the_pack(tmp_path):
    # A frame missing from a pack was named by the removed temporary folder,
    # and a listed scenario whose scenario.json was missing from its pack
    # raised a KeyError, as for a key the dataset does not have.
    causalcity.generate(SPEC, tmp_path / "p", progress=False, format="tar", scenarios_per_tar=2)
    pack = tmp_path / "p" / GROUP / "train" / "00000-00001.tar"
    with tarfile.open(pack) as tar:
        members = [(m, tar.extractfile(m).read()) for m in tar.getmembers()]

    def rewrite(leave_out):
        with tarfile.open(pack, "w", format=tarfile.USTAR_FORMAT) as tar:
            for m, data in members:
                if not m.name.endswith(leave_out):
                    tar.addfile(m, __import__("io").BytesIO(data))

    rewrite("00000/rgb/0005.png")
    scenario = causalcity.open_dataset(tmp_path / "p", "train")[0]
    with pytest.raises(causalcity.InputError) as error:
        scenario.rgb[5]
    assert f"cannot read {pack}: {GROUP}/train/00000/rgb/0005.png" in str(error.value), str(error.value)
    rewrite("00001/scenario.json")
    with pytest.raises(causalcity.InputError) as error:
        causalcity.open_dataset(tmp_path / "p", "train").load((GROUP, "train", 1))
    assert f"{pack}: {GROUP}/train/00001/scenario.json: missing from its pack" in str(error.value), str(error.value)


def test_flags_and_batches_of_the_wrong_kind_are_named(toy, tmp_path):
    copy = copy_of(toy, tmp_path, "flags")
    edit_json(copy / "manifest.json", lambda v: v.update(images="false"))
    with pytest.raises(causalcity.InputError, match="manifest.json: field images: 'false' is not allowed: true or false"):
        causalcity.open_dataset(copy)
    data = causalcity.open_dataset(toy, "train")
    with pytest.raises(TypeError, match="tensors='no'"):
        causalcity.collate([data[0]], tensors="no")
    # Scenarios of two image sizes: numpy's "all input arrays must have the same shape".
    bigger = dict(SPEC, name="bigger", image={"width": 320, "height": 160})
    causalcity.generate(bigger, tmp_path / "bigger", progress=False, limit=1)
    other = causalcity.open_dataset(tmp_path / "bigger", "train")[0]
    with pytest.raises(causalcity.InputError, match="scenarios of different image sizes cannot share a batch"):
        causalcity.collate([data[0], other], tensors=False)


def test_damaged_packs_are_named_once_and_a_pipe_never_read(packed, tmp_path):
    copy = copy_of(packed, tmp_path, "packs")
    pack = copy / GROUP / "train" / "00000-00001.tar"
    # A member that is both a file and a folder: a raw FileExistsError.
    with tarfile.open(pack) as tar:
        members = [(m, tar.extractfile(m).read()) for m in tar.getmembers()]
    with tarfile.open(pack, "w", format=tarfile.USTAR_FORMAT) as tar:
        for m, data in members:
            tar.addfile(m, __import__("io").BytesIO(data))
        clash = tarfile.TarInfo(f"{GROUP}/train/00001/poses.csv/extra")
        clash.size = 1
        tar.addfile(clash, __import__("io").BytesIO(b"x"))
    with pytest.raises(causalcity.InputError, match="is both a file and a folder") as error:
        causalcity.open_dataset(copy, "train").load((GROUP, "train", 1))
    assert "not a whole tar" not in str(error.value)
    # A member the rule refuses is named once, not as "not a whole tar (...)".
    with tarfile.open(pack, "w", format=tarfile.USTAR_FORMAT) as tar:
        for m, data in members + members[-1:]:
            tar.addfile(m, __import__("io").BytesIO(data))
    with pytest.raises(causalcity.InputError, match="is in it twice") as error:
        list(causalcity.read_tar(pack))
    assert "not a whole tar" not in str(error.value)
    # A pipe for a pack: open() blocked until a writer came.
    pipe = tmp_path / "00000-00001.tar"
    os.mkfifo(pipe)
    said = in_a_process("import sys, causalcity; list(causalcity.read_tar(sys.argv[1]))", pipe)
    assert f"InputError: {pipe}: not a regular file" in said, said


def test_a_packed_scenarios_temporary_folder_goes_with_its_last_frames_without_a_warning(tmp_path):
    import gc
    import glob
    import tempfile
    import warnings

    causalcity.generate(dict(SPEC, frames=3), tmp_path / "p", progress=False, format="tar", scenarios_per_tar=2)
    data = causalcity.open_dataset(tmp_path / "p", "train")
    pattern = os.path.join(tempfile.gettempdir(), "causalcity-scenario-*")
    before = set(glob.glob(pattern))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        s = data[0]
        (made,) = set(glob.glob(pattern)) - before
        rgb = s.rgb
        del s
        gc.collect()
        assert rgb[2].shape == (160, 256, 3) and os.path.isdir(made), "kept while frames read from it"
        del rgb
        gc.collect()
        assert not os.path.exists(made), "removed with the last frames"
    # TemporaryDirectory's own finaliser warned "Implicitly cleaning up".
    assert not [w for w in caught if issubclass(w.category, ResourceWarning)], [str(w.message) for w in caught]


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    import shlex
    import subprocess

    folder = tmp_path_factory.mktemp("damaged-sweep")
    spec = dict(CITY, name="damaged-sweep", frames=20, groups=[{"cars": 4, "edge_proportion": 0.5}],
                splits={"train": 1, "val": 1, "test": 1})  # fmt: skip
    (folder / "spec.json").write_text(json.dumps(spec))
    command = shlex.split(os.environ.get("CAUSALCITY_CLI", "target/release/causalcity"))
    args = ["counterfactual", "--sweep", folder / "spec.json", "--no-images", "--quiet", "--kinds", "stop"]
    subprocess.run(command + [str(a) for a in args] + ["--out", str(folder / "sweep")], check=True)
    return folder / "sweep"


def test_a_pair_is_read_only_as_itself_with_files_that_agree(sweep, tmp_path):
    from causalcity.methods.common import DatasetError
    from causalcity.methods.counterfactual import load_pairs

    test = f"{GROUP}/test/00000"
    # The test pair linked to the val pair: both runs, summary and
    # divergence of another pair were handed back (and scored) as this one.
    linked = copy_of(sweep, tmp_path, "linked-pair")
    shutil.rmtree(linked / test)
    (linked / test).symlink_to(linked / GROUP / "val" / "00000", target_is_directory=True)
    # (read through no link, as validate and every reader of a dataset have it)
    with pytest.raises(causalcity.InputError, match=f"{test} is a symbolic link .*never through a link"):
        causalcity.open_sweep(linked).load((GROUP, "test", 0))
    with pytest.raises(DatasetError, match=f"{test} is a symbolic link .*never through a link"):
        load_pairs(linked, GROUP, "test")
    # A run copied in from another pair: not this pair's.
    moved = copy_of(sweep, tmp_path, "moved-run")
    shutil.rmtree(moved / test / "factual")
    shutil.copytree(moved / GROUP / "val" / "00000" / "factual", moved / test / "factual")
    with pytest.raises(causalcity.InputError, match='it is a run of "cars04_edges50"/"val" index 0'):
        causalcity.open_sweep(moved).load((GROUP, "test", 0))
    with pytest.raises(DatasetError, match="not of cars04_edges50/test index 0"):
        load_pairs(moved, GROUP, "test")

    # A car's max_divergence_m edited: its affected label changed silently.
    edited = copy_of(sweep, tmp_path, "edited-pair")
    summary = json.loads((edited / test / "summary.json").read_text())
    moved = next(i for i, c in enumerate(summary["cars"]) if c["max_divergence_m"] > 0.01)
    summary["cars"][moved]["max_divergence_m"] = 0.0
    (edited / test / "summary.json").write_text(json.dumps(summary))
    says = f"car {moved}'s largest divergence is"
    with pytest.raises(causalcity.InputError, match=says):
        causalcity.open_sweep(edited).load((GROUP, "test", 0))
    with pytest.raises(DatasetError, match=says):
        load_pairs(edited, GROUP, "test")
    predictions = tmp_path / "cf.npz"
    from causalcity.methods.__main__ import main

    assert main(["cf_copy", str(sweep), "--out", str(predictions), "--quiet"]) == 0
    # A damaged dataset is bad input, as on the command line (exit 2).
    with pytest.raises(causalcity.InputError, match=says):
        causalcity.evaluate(edited, predictions)

    # Another car's id and name in the intervention record, as the runs
    # name them: the pair's files agree, but it is not the intervention the
    # sweep drew for this pair (it was read as the task's truth).
    other = copy_of(sweep, tmp_path, "other-car")
    summary = json.loads((other / test / "summary.json").read_text())
    car = (summary["intervention"]["car"] + 1) % len(summary["cars"])
    summary["intervention"].update(car=car, car_name=summary["cars"][car]["name"])
    (other / test / "summary.json").write_text(json.dumps(summary))
    says = f"records stop car {car} .*, but this sweep"
    with pytest.raises(causalcity.InputError, match=says):
        causalcity.open_sweep(other).load((GROUP, "test", 0))
    with pytest.raises(DatasetError, match=says):
        load_pairs(other, GROUP, "test")
    with pytest.raises(causalcity.InputError, match=says):
        causalcity.evaluate(other, predictions)

    # Without sweep.json's kinds nothing says which intervention a pair had.
    kindless = copy_of(sweep, tmp_path, "kindless")
    record = json.loads((kindless / "sweep.json").read_text())
    del record["kinds"]
    (kindless / "sweep.json").write_text(json.dumps(record))
    with pytest.raises(causalcity.InputError, match="sweep.json: kinds None is not allowed"):
        causalcity.open_sweep(kindless)
    with pytest.raises(causalcity.InputError, match="sweep.json: kinds None is not allowed"):
        load_pairs(kindless, GROUP, "test")
    with pytest.raises(causalcity.InputError, match="kinds is missing or empty"):
        causalcity.evaluate(kindless, predictions)
    record["kinds"] = "stop"
    (kindless / "sweep.json").write_text(json.dumps(record))
    with pytest.raises(causalcity.InputError, match="sweep.json: kinds 'stop' is not allowed"):
        causalcity.open_sweep(kindless)

    # A stray folder among the pairs is named, not read as one.
    stray = copy_of(sweep, tmp_path, "stray-pair")
    shutil.copytree(stray / test, stray / GROUP / "test" / "copy-of-00000")
    with pytest.raises(DatasetError, match="copy-of-00000: not a pair folder of the sweep"):
        load_pairs(stray, GROUP, "test")

    # A pipe for divergence.csv hung the reader.
    piped = copy_of(sweep, tmp_path, "piped-pair")
    (piped / test / "divergence.csv").unlink()
    os.mkfifo(piped / test / "divergence.csv")
    said = in_a_process("import sys, causalcity; s = causalcity.open_sweep(sys.argv[1]); s.load(s.keys('test')[0])", piped)
    assert "divergence.csv: cannot read it: not a regular file" in said, said

    # A record of another format was opened (every command refuses it).
    other = copy_of(sweep, tmp_path, "other-format")
    edit_json(other / "sweep.json", lambda v: v.update(format="something-else/9"))
    with pytest.raises(causalcity.InputError, match="format 'something-else/9' is not causalcity-counterfactual-sweep/1"):
        causalcity.open_sweep(other)
