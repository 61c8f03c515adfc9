"""The counterfactual task on a ``causalcity counterfactual --sweep`` output
(docs/evaluation.md, "The counterfactual task"), in the manner of CLEVRER
and CoPhy:

- **Observed:** a pair's factual run, every frame (poses, pixels), and its
  intervention as data: which car, what (``stop`` for ``seconds``,
  ``remove``, ``set_desired_speed`` to ``speed``, ``run_red_light``) and
  from which frame (``summary.json``'s ``intervention``). Never the
  counterfactual run.
- **Predicted:** the counterfactual run's bird's-eye positions from the
  intervention's frame on (``[steps, cars, 2]``, at most :data:`CF_STEPS`),
  and a score per car that the intervention moves it.
- **Scored** by ``causalcity evaluate SWEEP predictions.npz``: position error
  by horizon (every car on the map, and the moved cars alone), and F1,
  AUROC and AUPRC of the affected cars (moved more than the 0.5 m effect
  threshold at some frame, as ``effects.csv`` decides), the intervened car
  left out.
- **Splits:** the sweep's train, val and test pairs. A method may learn from
  train's counterfactual runs and labels (:attr:`Pairs.truth`); it is
  scored on test.

Reference methods: :class:`FactualCopy` ("nothing changes"),
:class:`ConstantVelocity` (every car drives on at its velocity before the
intervention; affected scores by the path rule) and :class:`NriRollout`
(NRI trained on the factual runs, its decoder rolled out with the
intervened car stopped or removed; affected scores from the rollout).
"""

from __future__ import annotations

import json
import os
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, Iterable, Iterator, List, Optional, Sequence, Tuple

import numpy as np

from .. import InputError, _native
from .common import STEPS, DatasetError, Episodes, fit_per_group

CF_STEPS = STEPS
"""Frames predicted from the intervention's frame on (fewer where the run ends)."""

PARKED_BEYOND_M = 5000.0
"""A removed car is parked 10 km off the map; positions beyond this are not a car on it."""


@dataclass
class Truth:
    """What a method may learn from on train: the counterfactual runs."""

    pixels: np.ndarray
    """``[pairs, frames, cars, 2]``: the counterfactual run's bird's-eye positions."""
    affected: np.ndarray
    """``[pairs, cars]`` bool: moved more than the effect threshold (0.5 m)."""


@dataclass
class Pairs:
    """The pairs of one group and split of a sweep: what a method observes."""

    sweep: Path
    group: str
    split: str
    folders: List[str]
    """Each pair's folder relative to the sweep (the predictions' names)."""
    pixels: np.ndarray
    """``[pairs, frames, cars, 2]``: the factual run's bird's-eye px, py."""
    metres: np.ndarray
    """``[pairs, frames, cars, 4]``: the factual run's x, y (metres), yaw, speed."""
    interventions: List[dict]
    """Each pair's ``summary.json`` ``intervention``: car, do, frame, at_s, seconds or speed."""
    image_size: Tuple[int, int]
    frame_interval: float
    truth: Optional[Truth] = None
    """Train only (None elsewhere): the counterfactual runs."""

    def __len__(self) -> int:
        return len(self.folders)

    @property
    def cars(self) -> int:
        return int(self.pixels.shape[2])

    @property
    def frames(self) -> int:
        return int(self.pixels.shape[1])

    def steps(self, k: int) -> int:
        """Frames pair ``k`` can be predicted for from its intervention's frame."""
        return max(1, min(CF_STEPS, self.frames - int(self.interventions[k]["frame"])))

    def as_episodes(self) -> Episodes:
        """The factual runs as the discovery methods' :class:`Episodes`."""
        return Episodes(
            dataset=self.sweep,
            group=self.group,
            split=self.split,
            folders=self.folders,
            pixels=self.pixels,
            metres=self.metres,
            graph=np.zeros((len(self), self.cars, self.cars), dtype=np.uint8),
            image_size=self.image_size,
            frame_interval=self.frame_interval,
        )


@dataclass
class CounterfactualPrediction:
    positions: List[np.ndarray]
    """Per pair ``[steps, cars, 2]``: bird's-eye positions from the intervention's frame."""
    affected: np.ndarray
    """``[pairs, cars]``: higher means more likely moved by the intervention."""


class CounterfactualMethod:
    """A method of the counterfactual task: :meth:`fit` on a group's train
    pairs (and val), then :meth:`predict` any split's pairs."""

    name = "counterfactual"

    def fit(self, train: Pairs, val: Optional[Pairs]) -> None:
        """Learns from ``train`` (its :attr:`Pairs.truth` included); the default learns nothing."""

    def predict(self, pairs: Pairs) -> CounterfactualPrediction:
        raise NotImplementedError


def _sweep_record(root: Path) -> dict:
    path = root / "sweep.json"
    if not path.is_file():
        raise InputError(f"no sweep.json in {root}: not a counterfactual --sweep output")
    try:
        record = json.loads(path.read_text())
    except ValueError as e:
        raise DatasetError(f"{path}: not JSON ({e})") from None
    if not record.get("complete", False):
        raise InputError(f"{root} is not complete: finish it with its counterfactual --sweep command first")
    from ..disk import check_sweep_kinds

    check_sweep_kinds(record, path)
    return record


def is_sweep(root: "str | Path") -> bool:
    """Whether ``root`` is a ``counterfactual --sweep`` output."""
    return (Path(root) / "sweep.json").is_file()


def sweep_groups(root: "str | Path") -> List[str]:
    """The sweep's group names, in its spec's order."""
    from .. import Spec

    # (a SUMO network the spec names is the sweep's own copy, in networks/)
    return Spec.from_dict(_sweep_record(Path(root))["spec"], networks=Path(root) / "networks").groups


def _run_arrays(folder: Path) -> Tuple[np.ndarray, np.ndarray, dict]:
    try:
        raw = _native.read_scenario(os.fspath(folder))
    except InputError as e:
        raise DatasetError(str(e)) from None
    position, rotation, speed = (np.asarray(raw[k]) for k in ("position", "rotation", "speed"))
    metres = np.concatenate([position[..., :2], rotation[..., 2:3], speed[..., None]], axis=-1)
    return np.asarray(raw["pixels"]), metres, json.loads(raw["scenario_json"])


def _pair_folders(root: Path, record: dict, group: str, split: str) -> Iterator[Tuple[str, Path]]:
    """Each pair of ``group`` and ``split`` on disk, in order, as its folder
    relative to the sweep and a folder to read it from: its own, or (a
    packed sweep) a temporary one it is unpacked into without frames, which
    goes once the next pair is asked for."""
    if not record.get("scenarios_per_tar"):
        from ..disk import _refuse_linked

        # (A summary.json that is not a file is taken, and named when read.)
        for folder in sorted(p for p in (root / group / split).glob("*") if os.path.lexists(p / "summary.json")):
            try:
                _refuse_linked(folder)
            except InputError as e:
                raise DatasetError(str(e)) from None
            yield str(folder.relative_to(root)).replace(os.sep, "/"), folder
        return
    from ..disk import Sweep

    sweep = Sweep(root)
    for key in sweep.keys(split):
        if key.group == group:
            folder, scratch = sweep.pair_folder(key, images=False)
            try:
                yield key.folder, folder
            finally:
                scratch.cleanup()


def load_pairs(sweep: "str | Path", group: str, split: str) -> Pairs:
    """Reads every pair of ``group`` and ``split`` (from pair folders, or from
    a packed sweep's tar files): the factual runs, the interventions, and on
    train the counterfactual runs (:attr:`Pairs.truth`)."""
    root = Path(sweep)
    record = _sweep_record(root)
    spec = record["spec"]
    groups = sweep_groups(root)
    if group not in groups:
        raise InputError(f"group {group!r} is not in {root}: its groups are {', '.join(groups)}")
    names, pixels, metres, interventions, cf_pixels, affected = [], [], [], [], [], []
    interval = float(spec.get("frame_interval") or 0.1)
    # Each pair's intervention is held to the one the sweep draws for it.
    from .. import Spec

    drawn_by = Spec.from_dict(spec, networks=root / "networks")._native
    for name, folder in _pair_folders(root, record, group, split):
        names.append(name)
        index = name.rsplit("/", 1)[-1]
        if not re.fullmatch(r"[0-9]{5,}", index):
            raise DatasetError(f"{root / name}: not a pair folder of the sweep (they are named 00000, 00001, ...): "
                               "remove it, or make the sweep again into a new --out")  # fmt: skip
        try:
            # The pair's own runs and files, agreeing, as evaluate holds them.
            _native.check_pair(os.fspath(folder), group, split, int(index), drawn_by, record.get("kinds"))
        except InputError as e:
            raise DatasetError(str(e).replace(os.fspath(folder), os.fspath(root / name))) from None
        summary = json.loads((folder / "summary.json").read_text())
        if "intervention" not in summary:
            raise DatasetError(
                f"{root / name / 'summary.json'}: no intervention record: the sweep was made before summary.json "
                "recorded it; make it again into a new --out"
            )
        px, m, meta = _run_arrays(folder / "factual")
        interval = float(meta.get("frame_interval", interval))
        pixels.append(px)
        metres.append(m)
        interventions.append(summary["intervention"])
        if split == "train":
            cf_pixels.append(_run_arrays(folder / "counterfactual")[0])
            affected.append([c["max_divergence_m"] > 0.5 for c in summary["cars"]])
    image = spec.get("image", {"width": 1024, "height": 640})
    frames = int(spec["frames"])
    stack = (lambda arrays, shape: np.stack(arrays) if arrays else np.zeros(shape))  # noqa: E731
    return Pairs(
        sweep=root,
        group=group,
        split=split,
        folders=names,
        pixels=stack(pixels, (0, frames, 0, 2)),
        metres=stack(metres, (0, frames, 0, 4)),
        interventions=interventions,
        image_size=(int(image["width"]), int(image["height"])),
        frame_interval=interval,
        truth=Truth(stack(cf_pixels, (0, frames, 0, 2)), np.asarray(affected, dtype=bool)) if split == "train" else None,
    )


def path_rule_affected(pairs: Pairs, k: int, horizon: int) -> np.ndarray:
    """The simple rule for who is affected: minus the smallest distance
    (metres) between each car's factual positions in the ``horizon`` frames
    from the intervention and the intervened car's positions over the same
    frames and the ``horizon`` before (a car that drives where it drove, or
    is about to, is moved by it)."""
    f, car = int(pairs.interventions[k]["frame"]), int(pairs.interventions[k]["car"])
    xy = pairs.metres[k, :, :, :2]
    path = xy[max(0, f - horizon) : f + horizon, car]
    ahead = xy[f : f + horizon]
    d = np.linalg.norm(ahead[:, :, None, :] - path[None, None, :, :], axis=-1).min(axis=(0, 2))
    return -d


class FactualCopy(CounterfactualMethod):
    """"Nothing changes": the counterfactual is the factual run, and no car
    is affected (every score 0). The floor."""

    name = "cf_copy"

    def predict(self, pairs: Pairs) -> CounterfactualPrediction:
        positions = []
        for k in range(len(pairs)):
            f = int(pairs.interventions[k]["frame"])
            positions.append(pairs.pixels[k, f : f + pairs.steps(k)].copy())
        return CounterfactualPrediction(positions, np.zeros((len(pairs), pairs.cars)))


class ConstantVelocity(CounterfactualMethod):
    """Every car drives on at its velocity at the intervention's frame
    (which the factual run shows: an intervention changes motion only after
    it); a stopped car stands still for its ``seconds`` and then drives on,
    a removed car is not predicted (it has left). Affected cars by
    :func:`path_rule_affected`."""

    name = "cf_constant_velocity"

    def predict(self, pairs: Pairs) -> CounterfactualPrediction:
        positions, affected = [], np.zeros((len(pairs), pairs.cars))
        for k in range(len(pairs)):
            iv = pairs.interventions[k]
            f, car, steps = int(iv["frame"]), int(iv["car"]), pairs.steps(k)
            last = pairs.pixels[k, f]
            velocity = pairs.pixels[k, f] - pairs.pixels[k, max(f - 1, 0)]
            ahead = np.arange(steps)[:, None, None]
            out = last[None] + ahead * velocity[None]
            if iv["do"] == "stop":
                stopped = int(round(float(iv.get("seconds", 0.0)) / pairs.frame_interval))
                moving = np.clip(np.arange(steps) - stopped, 0, None)
                out[:, car] = last[car][None] + moving[:, None] * velocity[car][None]
            positions.append(out)
            affected[k] = path_rule_affected(pairs, k, steps)
        return CounterfactualPrediction(positions, affected)


class NriRollout(CounterfactualMethod):
    """NRI (:class:`~causalcity.methods.nri.Nri`) trained on the train pairs'
    factual runs, its edges from the factual history, its decoder rolled out
    from the intervention's frame (which it takes from the factual run: an
    intervention changes motion only after it) with the intervened car held
    still (``stop``, for its seconds) or sending no messages (``remove``);
    ``set_desired_speed`` and ``run_red_light`` are rolled out unchanged. A
    car's affected score is how far (pixels) its rollout with the
    intervention moves from the same rollout without it."""

    name = "cf_nri"

    def __init__(self, epochs: int = 30, seed: int = 0, device: str = "auto", quiet: bool = False, **options) -> None:
        from .nri import Nri

        self.nri = Nri(epochs=epochs, seed=seed, device=device, quiet=quiet, **options)

    def fit(self, train: Pairs, val: Optional[Pairs]) -> None:
        self.nri.fit(train.as_episodes(), val.as_episodes() if val is not None and len(val) else None)

    def predict(self, pairs: Pairs) -> CounterfactualPrediction:
        import torch

        nri = self.nri
        nri._train_mode(False)
        nri.epoch = nri.epochs
        episodes = pairs.as_episodes()
        hist, _ = nri._frames(episodes)
        nri._wire(episodes.cars)
        w, h = pairs.image_size
        std = torch.as_tensor(nri.std, dtype=torch.float32, device=nri.device)
        mean = torch.as_tensor(nri.mean, dtype=torch.float32, device=nri.device)
        still_velocity = (torch.zeros(2, device=nri.device) - mean[2:]) / std[2:]
        positions, affected = [], np.zeros((len(pairs), pairs.cars))
        with torch.no_grad():
            x_all = nri._tensor(nri._states(episodes))
            for k in range(len(pairs)):
                iv = pairs.interventions[k]
                f, car, steps = int(iv["frame"]), int(iv["car"]), pairs.steps(k)
                # Truth up to frame f (the factual run's), predictions after it.
                warm = max(1, min(nri.warm, f + 1))
                x = x_all[k : k + 1]
                edges, _, _ = nri._edges(x, hist, sample=False)
                start = torch.tensor([f - warm + 1], device=nri.device)
                seq, past = nri._window(x, start, warm + steps - 1)
                held = x[0, f, car].clone()
                stop_frames = int(round(float(iv.get("seconds", 0.0)) / pairs.frame_interval))

                def rollout(intervene: bool) -> torch.Tensor:
                    e = edges.clone()
                    if intervene and iv["do"] == "remove":
                        for index, (i, _j) in enumerate(nri.pairs):
                            if i == car:
                                # no message: the "none" type, or no weight with one type
                                e[:, index] = 0.0
                                if e.shape[-1] > 1:
                                    e[:, index, 0] = 1.0
                    weights, grid = nri.decoder._message_weights(), nri.decoder.grid(e)
                    hidden = torch.zeros(1, pairs.cars, nri.decoder.hidden, device=nri.device)
                    state, memory, out = seq[:, 0], past, [seq[0, warm - 1]]
                    for t in range(warm + steps - 2):
                        if t < warm:
                            state = seq[:, t]
                        memory = torch.cat([state[:, :, None], memory[:, :, :-1]], dim=2)
                        state, hidden = nri.decoder.step(state, hidden, grid, memory, weights)
                        frame = f - warm + t + 2
                        if intervene and iv["do"] == "stop" and f < frame <= f + stop_frames:
                            state = state.clone()
                            state[:, car, :2] = held[:2]
                            state[:, car, 2:] = still_velocity
                        if frame > f:
                            out.append(state[0])
                    # frames f (the factual one) .. f + steps - 1
                    return torch.stack(out)

                with_it, without = rollout(True), rollout(False)
                px = (with_it * std + mean)[..., :2].cpu().double().numpy() * np.array([w, h])
                base = (without * std + mean)[..., :2].cpu().double().numpy() * np.array([w, h])
                positions.append(px)
                affected[k] = np.linalg.norm(px - base, axis=-1).max(axis=0)
        return CounterfactualPrediction(positions, affected)


COUNTERFACTUAL_METHODS = {
    "cf_copy": FactualCopy,
    "cf_constant_velocity": ConstantVelocity,
    "cf_nri": NriRollout,
}
"""The counterfactual task's reference methods by name."""


def run_counterfactual_method(
    make_method,
    sweep: "str | Path",
    out: "str | Path",
    groups: Optional[Sequence[str]] = None,
    splits: Iterable[str] = ("val", "test"),
    quiet: bool = False,
) -> Path:
    """Fits a fresh method (``make_method()``) per group of ``sweep`` on its
    train pairs and writes its counterfactuals and affected-car scores for
    ``splits`` to ``out`` (for ``causalcity evaluate``)."""
    from .. import save_predictions

    root = Path(sweep)
    _native.claim_output(os.fspath(out), [("the sweep it reads", os.fspath(root))])
    names = sweep_groups(root) if groups is None else groups
    counterfactuals: Dict[str, np.ndarray] = {}
    affected: Dict[str, np.ndarray] = {}
    for pairs, predicted in fit_per_group(
        make_method, root, names, load_pairs, splits, quiet, unit="pairs", parts={"positions": True, "affected": True}
    ):
        for k, folder in enumerate(pairs.folders):
            counterfactuals[folder] = predicted.positions[k]
            affected[folder] = predicted.affected[k]
    if not counterfactuals:
        raise InputError(f"{root}: no pairs in {', '.join(splits)} to predict")
    save_predictions(
        out,
        counterfactuals={k: counterfactuals[k] for k in sorted(counterfactuals)},
        affected={k: affected[k] for k in sorted(affected)},
        dataset=root,
    )
    return Path(out)
