"""causalcity.batches / collate: shuffled batches of tensors for a torch
DataLoader, the same batches for any number of workers, values as gen wrote
them. Needs torch (installed by `make test-python`)."""

import json
import os
import pickle
import traceback
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import causalcity

torch = pytest.importorskip("torch")

ROOT = Path(__file__).resolve().parents[2]
DATA = Path(os.environ.get("CAUSALCITY_DATA", ROOT / "target" / "python-data"))
TOY_SPEC = ROOT / "tests" / "python" / "toy.json"


def toy(train_per_group):
    spec = json.loads(TOY_SPEC.read_text())
    spec["splits"]["train"] = train_per_group
    return causalcity.Spec.from_dict(spec)


def loader_keys(batches, workers):
    loader = torch.utils.data.DataLoader(batches, batch_size=None, num_workers=workers)
    return [[tuple(k) for k in batch["key"]] for batch in loader]


@pytest.mark.filterwarnings("ignore:This DataLoader will create")
def test_shuffled_batches_are_one_group_each_the_same_for_any_workers_and_new_each_epoch():
    spec = toy(7)  # two groups of 7: batches of 3, 3 and 1 per group
    batches = causalcity.batches(spec, "train", batch_size=3, seed=5, effects=False)
    assert isinstance(batches, torch.utils.data.IterableDataset)
    assert len(batches) == 6
    epoch0 = loader_keys(batches, 0)
    assert [len(b) for b in sorted(epoch0, key=len)] == [1, 1, 3, 3, 3, 3]
    assert all(len({k[0] for k in batch}) == 1 for batch in epoch0)
    every = sorted(k for batch in epoch0 for k in batch)
    assert every == sorted(tuple(k) for k in spec.keys("train"))
    assert loader_keys(batches, 2) == epoch0
    assert loader_keys(batches, 3) == epoch0
    assert epoch0 != [[tuple(k) for k in ks] for ks in causalcity.batches(spec, "train", 3, shuffle=False).keys()]
    batches.set_epoch(1)
    epoch1 = loader_keys(batches, 2)
    assert epoch1 != epoch0 and sorted(k for b in epoch1 for k in b) == every
    assert loader_keys(batches, 0) == epoch1
    batches.set_epoch(0)
    assert loader_keys(batches, 0) == epoch0
    other_seed = causalcity.batches(spec, "train", batch_size=3, seed=6, effects=False)
    assert loader_keys(other_seed, 0) != epoch0


def test_batch_tensors_hold_the_scenarios_values():
    spec = toy(5)
    batches = causalcity.batches(spec, "train", batch_size=4, seed=1)
    batch = next(iter(torch.utils.data.DataLoader(batches, batch_size=None)))
    keys = batch["key"]
    assert len(keys) == 4
    cars = spec.to_dict()["groups"][spec.groups.index(keys[0].group)]["cars"]
    frames = spec.frames
    assert batch["position"].shape == (4, frames, cars, 3) and batch["position"].dtype == torch.float64
    assert batch["graph"].shape == (4, cars, cars)
    assert batch["car_mask"].all()
    for b, key in enumerate(keys):
        s = causalcity.simulate(spec, key.group, key.split, key.index)
        np.testing.assert_array_equal(batch["position"][b].numpy(), s.position)
        np.testing.assert_array_equal(batch["speed"][b].numpy(), s.speed)
        np.testing.assert_array_equal(batch["in_view"][b].numpy(), s.in_view)
        np.testing.assert_array_equal(batch["graph"][b].numpy(), s.graph)
        np.testing.assert_array_equal(batch["causal_graph"][b].numpy(), s.causal_graph)
        np.testing.assert_array_equal(batch["t"][b].numpy(), s.t)


def test_image_batches_decode_like_the_pngs_gen_wrote():
    spec = causalcity.Spec.load(TOY_SPEC)
    # Frames are drawn straight into each batch's arrays by several threads
    # (no workers) or by one per worker process: the same bytes either way.
    seen = 0
    for workers, threads in ((0, 2), (2, None)):
        batches = causalcity.batches(
            spec, "train", batch_size=2, shuffle=False, images=True, effects=False, threads=threads
        )
        seen += check_image_batches(spec, torch.utils.data.DataLoader(batches, batch_size=None, num_workers=workers))
    assert seen == 2 * len(spec.keys("train"))


def check_image_batches(spec, loader):
    seen = 0
    for batch in loader:
        assert batch["rgb"].dtype == torch.uint8 and batch["rgb"].shape[0] == 2
        for b, key in enumerate(batch["key"]):
            folder = DATA / "toy" / key.group / key.split / f"{key.index:05d}"
            for frame in range(spec.frames):
                rgb = np.asarray(Image.open(folder / "rgb" / f"{frame:04d}.png").convert("RGB"))
                np.testing.assert_array_equal(batch["rgb"][b, frame].numpy(), rgb)
                mask = np.asarray(Image.open(folder / "mask" / f"{frame:04d}.png"))
                np.testing.assert_array_equal(batch["mask"][b, frame].numpy(), mask)
            seen += 1
    return seen


def test_mixed_groups_pad_to_the_most_cars_and_mask_the_padding():
    spec = toy(3)
    batches = causalcity.batches(spec, "train", batch_size=6, seed=2, mix_groups=True, effects=False, tensors=False)
    (batch,) = list(batches)
    assert isinstance(batch["position"], np.ndarray)
    assert len({k.group for k in batch["key"]}) == 2
    cars = {g["cars"] for g in spec.to_dict()["groups"]}
    assert batch["position"].shape[2] == max(cars) and batch["car_mask"].shape == (6, max(cars))
    for b, key in enumerate(batch["key"]):
        s = causalcity.simulate(spec, key.group, key.split, key.index, effects=False)
        assert batch["car_mask"][b].sum() == s.cars
        np.testing.assert_array_equal(batch["position"][b, :, : s.cars], s.position)
        assert not batch["position"][b, :, s.cars :].any()
        assert not batch["graph"][b, s.cars :].any() and not batch["graph"][b, :, s.cars :].any()


def test_processes_split_the_batches_between_them():
    spec = toy(7)
    whole = [tuple(map(tuple, b)) for b in causalcity.batches(spec, "train", 3, seed=4).keys()]
    parts = [
        [tuple(map(tuple, b)) for b in causalcity.batches(spec, "train", 3, seed=4, shard=(rank, 2)).keys()]
        for rank in range(2)
    ]
    assert sorted(parts[0] + parts[1]) == sorted(whole) and not set(parts[0]) & set(parts[1])
    assert [len(p) for p in parts] == [len(causalcity.batches(spec, "train", 3, shard=f"{r}/2")) for r in range(2)]


def test_collate_is_a_collate_fn_for_scenario_streams():
    spec = toy(4)
    stream = causalcity.stream(spec, "train", groups=[spec.groups[0]], effects=False)
    loader = torch.utils.data.DataLoader(stream, batch_size=4, collate_fn=causalcity.collate)
    (batch,) = list(loader)
    assert batch["position"].shape[0] == 4 and isinstance(batch["position"], torch.Tensor)


def test_batch_arguments_are_checked_and_batches_pickle():
    spec = toy(2)
    with pytest.raises(causalcity.InputError, match="batch_size"):
        causalcity.batches(spec, "train", 0)
    with pytest.raises(causalcity.InputError, match="seed"):
        causalcity.batches(spec, "train", 2, seed=-1)
    with pytest.raises(causalcity.InputError, match="epoch"):
        causalcity.batches(spec, "train", 2).set_epoch(-1)
    with pytest.raises(causalcity.InputError, match="cars99"):
        causalcity.batches(spec, "train", 2, groups=["cars99"])
    batches = causalcity.batches(spec, "train", 2, seed=3)
    batches.set_epoch(4)
    copy = pickle.loads(pickle.dumps(batches))
    assert copy.keys() == batches.keys()


def test_a_spec_dict_json_cannot_hold_is_named_by_its_field():
    spec = json.loads(TOY_SPEC.read_text())
    # NaN was written as NaN and read back as "not valid JSON"; a set raised
    # json's TypeError naming no field.
    for field, value, says in [
        ("seed", float("nan"), "field `seed`: nan is not allowed: give a finite number"),
        ("frame_interval", float("inf"), "field `frame_interval`: inf is not allowed"),
        ("seed", {1, 2}, "field `seed`: a set is not a JSON value"),
    ]:
        with pytest.raises(causalcity.InputError) as error:
            causalcity.Spec.from_dict({**spec, field: value})
        assert says in str(error.value), error.value
    group = dict(spec["groups"][0], edge_proportion=float("nan"))
    with pytest.raises(causalcity.InputError, match=r"field `groups\[0\]\.edge_proportion`: nan"):
        causalcity.Spec.from_dict({**spec, "groups": [group]})
    # NumPy's numbers are numbers.
    assert causalcity.Spec.from_dict({**spec, "seed": np.int64(5), "frame_interval": np.float64(0.1)}).seed == 5
    # So for a scenario given as a dict.
    scenario = [{"Name": "a", "seed": float("nan"), "Vehicles": []}]
    with pytest.raises(causalcity.InputError, match=r"<dict>: field `\[0\]\.seed`: nan is not allowed"):
        causalcity.counterfactual(scenario)


def test_the_package_shows_its_api_a_version_and_short_reprs():
    assert causalcity.__version__ != "unknown" and causalcity.__version__[0].isdigit()
    names = dir(causalcity)
    assert "batches" in names and "stream" in names
    assert not {"np", "os", "sys", "json", "_np"} & set(names)
    assert not hasattr(causalcity, "np") and not hasattr(causalcity, "json")
    with pytest.raises(causalcity.InputError) as error:
        causalcity.Spec.from_dict({"name": "x"})
    shown = "".join(traceback.format_exception(error.value))
    assert shown.strip().splitlines()[-1].startswith("causalcity.InputError: "), shown
    assert causalcity.GenerationError.__module__ == "causalcity"
    s = causalcity.simulate(toy(1), "cars04_edges50", "train", 0, images=True)
    text = repr(s)
    assert len(text) < 300 and "cars04_edges50" in text and "cars=4" in text


def test_flags_are_true_or_false_and_a_batch_never_mixes_frame_intervals(tmp_path):
    data = Path(os.environ.get("CAUSALCITY_DATA", ROOT / "target" / "python-data"))
    city = causalcity.open_dataset(data / "city", images=False)
    for flag in ("shuffle", "drop_last", "mix_groups", "tensors"):
        with pytest.raises(TypeError, match=f"{flag}='no': give True or False"):
            causalcity.batches(city.spec, "train", 2, **{flag: "no"})
    # generate's too, before anything is written (force="no" named no argument).
    for flag in ("force", "fsync", "force_space"):
        with pytest.raises(TypeError, match=f"{flag}='no': give True or False"):
            causalcity.generate(city.spec, tmp_path / "never-written", **{flag: "no"})
        assert not (tmp_path / "never-written").exists()
    # A toy and a city scenario (frames 0.1 s and 1 s apart) were stacked
    # as one batch silently.
    toy = causalcity.open_dataset(data / "toy", images=False)
    with pytest.raises(causalcity.InputError, match="frame intervals"):
        causalcity.collate([toy[0], city[0]])
    # One scenario twice (a sampler drawing with replacement) is a batch.
    assert causalcity.collate([city[0], city[0]], tensors=False)["position"].shape[0] == 2


def test_a_stream_of_no_groups_is_refused():
    data = Path(os.environ.get("CAUSALCITY_DATA", ROOT / "target" / "python-data"))
    spec = causalcity.open_dataset(data / "city", images=False).spec
    with pytest.raises(causalcity.InputError, match=r"groups=\[\] names no group"):
        causalcity.stream(spec, "train", groups=[])
