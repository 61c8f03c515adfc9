"""What every reference method shares: a dataset's scenarios of one group and
split as arrays, the method interface, progress lines, and the predictions
file ``causalcity evaluate`` scores."""

from __future__ import annotations

import json
import os
import stat
import sys
import time
import warnings
import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, Iterable, List, Optional, Sequence, Tuple

import numpy as np

from .. import InputError, _native

HISTORY = 100
"""Frames a method observes before the ones it predicts (the paper's 100)."""
STEPS = 20
"""Frames predicted after the history (the paper's 20)."""
SPLITS = ("train", "val", "test")


@dataclass
class Episodes:
    """The scenarios of one group and split, as arrays (car axes by car id)."""

    dataset: Path
    group: str
    split: str
    folders: List[str]
    """Each scenario's folder relative to the dataset (the predictions' names)."""
    pixels: np.ndarray
    """``[scenarios, frames, cars, 2]`` float64: bird's-eye px, py."""
    metres: np.ndarray
    """``[scenarios, frames, cars, 4]`` float64: x, y (metres), yaw (radians), speed (m/s)."""
    graph: np.ndarray
    """``[scenarios, cars, cars]`` uint8: designed edges, ``[i, j] = 1`` when car i leads car j."""
    image_size: Tuple[int, int]
    frame_interval: float

    def __len__(self) -> int:
        return len(self.folders)

    @property
    def cars(self) -> int:
        return int(self.pixels.shape[2])

    @property
    def frames(self) -> int:
        return int(self.pixels.shape[1])

    def part(self, rows: slice) -> "Episodes":
        """These scenarios' ``rows`` (a slice), as Episodes of their own."""
        return dataclasses.replace(self, folders=self.folders[rows], pixels=self.pixels[rows],
                                   metres=self.metres[rows], graph=self.graph[rows])  # fmt: skip


@dataclass
class Predicted:
    """A method's output on one :class:`Episodes`: either may be None."""

    edges: Optional[np.ndarray] = None
    """``[scenarios, cars, cars]``: ``[i, j]`` scores "car i leads car j"."""
    trajectories: Optional[np.ndarray] = None
    """``[scenarios, steps, cars, 2]``: bird's-eye px, py of frames history .. history + steps."""


class Method:
    """A reference method: :meth:`fit` on a group's train (and val) split,
    then :meth:`predict` any split of that group."""

    name = "method"
    discovers = False
    predicts = False

    def fit(self, train: Episodes, val: Optional[Episodes]) -> None:
        """Learns from ``train`` (``val`` for early choices); the default learns nothing."""

    def predict(self, episodes: Episodes) -> Predicted:
        raise NotImplementedError


class MethodFailed(Exception):
    """A method's own ``fit`` or ``predict`` raised (a bug in the method, not
    bad input): the message names the method, the call and the group; the
    method's exception is its ``__cause__``, whose traceback the command
    line prints (exit status 1). A user's ``ValueError`` or ``OSError`` was
    reported as bad input, exit 2, by its message alone."""


def _call(where: str, call, *args):
    """``call(*args)``, a method's exception raised as :class:`MethodFailed`
    naming ``where``; the package's own errors (bad input, a damaged
    dataset read through the episodes) and interrupts pass as they are."""
    try:
        return call(*args)
    except (InputError, DatasetError, _native.GenerationError, ImportError):
        raise  # (ImportError: a method's optional dependency, as before)
    except Exception as e:
        raise MethodFailed(f"{where} raised {type(e).__name__}: {e}") from e


class DatasetError(RuntimeError):
    """A file of a dataset that cannot be read as gen writes it (damaged or
    changed by hand): bad input, exit status 2 from the command line, as
    causalcity's readers (``evaluate``, ``stats``, ``export``) report it."""


def _regular(path: Path) -> Path:
    """``path`` when it is a regular file (or a link to one); else a
    :class:`DatasetError` naming what is there: a pipe would hang the read,
    a device read until memory ran out."""
    try:
        mode = path.stat().st_mode
    except OSError as e:
        raise DatasetError(f"{path}: cannot be read ({e.strerror}); causalcity validate tells what else is damaged") from None
    if not stat.S_ISREG(mode):
        kind = "a folder" if stat.S_ISDIR(mode) else "a pipe" if stat.S_ISFIFO(mode) else "not a regular file"
        raise DatasetError(f"{path}: {kind} where gen writes a file; causalcity validate tells what else is damaged")
    return path


def _read_json(path: Path) -> dict:
    try:
        return json.loads(_regular(path).read_text())
    except (OSError, UnicodeDecodeError, ValueError) as e:
        raise DatasetError(f"{path}: cannot be read as JSON ({e}); causalcity validate tells what else is damaged") from None


def _manifest(dataset: Path) -> dict:
    path = dataset / "manifest.json"
    if not path.is_file():
        if os.path.exists(path):
            raise InputError(f"{path}: not a regular file (a folder, a pipe or a device): not a dataset gen wrote")
        raise InputError(f"no manifest.json in {dataset}: not a dataset gen wrote")
    manifest = _read_json(path)
    groups = manifest.get("groups") if isinstance(manifest, dict) else None
    if not isinstance(groups, list) or not all(isinstance(g, dict) and "name" in g for g in groups):
        raise DatasetError(f"{path}: no list of groups: not a manifest gen wrote")
    if not isinstance(manifest.get("spec"), dict):
        raise DatasetError(f"{path}: no spec: not a manifest gen wrote")
    if not manifest.get("complete", False):
        raise InputError(f"{dataset} is not complete: finish it with its gen command first")
    return manifest


def _scenario_arrays(folder: Path) -> Tuple[dict, np.ndarray, np.ndarray]:
    """scenario.json, pixels.npy ``[frames, cars, 2]`` and poses.csv's x, y,
    yaw, speed ``[frames, cars, 4]`` of one scenario, or a
    :class:`DatasetError` naming the file that does not fit."""
    meta = _read_json(folder / "scenario.json")
    try:
        n, frames = len(meta["cars"]), int(meta["frames"])
        edges = [(int(a), int(b)) for a, b in meta["edges"]]
    except (KeyError, TypeError, ValueError) as e:
        raise DatasetError(f"{folder / 'scenario.json'}: not a scenario gen wrote (field {e})") from None
    try:
        pixels = np.load(_regular(folder / "pixels.npy")).astype(np.float64).reshape(frames, n, 2)
    except (OSError, ValueError, EOFError) as e:
        raise DatasetError(f"{folder / 'pixels.npy'}: not the [{frames}, {n}, 2] array gen writes ({e})") from None
    try:
        with warnings.catch_warnings():
            # (numpy's "input contained no data" for a file of no rows: the
            # shape check below says what is wrong with it)
            warnings.simplefilter("ignore", UserWarning)
            table = np.loadtxt(_regular(folder / "poses.csv"), delimiter=",", skiprows=1, ndmin=2)
        metres = table[:, [3, 4, 8, 11]].reshape(frames, n, 4)
    except (OSError, ValueError, IndexError) as e:
        raise DatasetError(f"{folder / 'poses.csv'}: not the {frames} x {n} rows gen writes ({e})") from None
    # (the pose rule's finiteness, as the package's own reader holds it)
    for name, values in (("pixels.npy", pixels), ("poses.csv", metres)):
        if not np.isfinite(values).all():
            at = np.argwhere(~np.isfinite(values))[0]
            raise DatasetError(f"{folder / name}: frame {at[0]}, car {at[1]} holds {values[tuple(at)]}: gen writes "
                               "finite numbers only; causalcity validate tells what else is damaged")  # fmt: skip
    if any(not (0 <= a < n and 0 <= b < n) for a, b in edges):
        raise DatasetError(f"{folder / 'scenario.json'}: an edge names a car outside 0..{n - 1}")
    return meta, pixels, metres


def positive_float(text: str) -> float:
    """A finite number above 0, for argparse."""
    import argparse

    value = _finite(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"{text} is not allowed: use a number above 0")
    return value


def non_negative_float(text: str) -> float:
    """A finite number of 0 or more, for argparse."""
    import argparse

    value = _finite(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text} is not allowed: use a number from 0 up")
    return value


def _finite(text: str) -> float:
    import argparse
    import math

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text} is not allowed: use a finite number")
    return value


def positive_int(text: str) -> int:
    """A whole number >= 1, for argparse (which then exits 2 with the message)."""
    return _whole_from(text, 1)


def warmup_epochs_arg(text: str) -> "int | str":
    """``auto`` or a whole number >= 0, for argparse (which then exits 2
    with the message)."""
    return "auto" if text == "auto" else _whole_from(text, 0, " or auto")


def _whole_from(text: str, least: int, other: str = "") -> int:
    """``text`` as a whole number of at least ``least``, or argparse's error
    (its allowed values ending with ``other``)."""
    import argparse

    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number{other}") from None
    if value < least:
        raise argparse.ArgumentTypeError(f"{value} is not allowed: use {least} or more{other}")
    return value


def groups_of(dataset: "str | Path") -> List[str]:
    """The dataset's group names, in its spec's order."""
    return [g["name"] for g in _manifest(Path(dataset))["groups"]]


def _split_scenarios(root: Path, manifest: dict, group: str, split: str, read) -> list:
    """``(folder, read(path, index))`` for every finished scenario of
    ``group``'s ``split`` in index order, ``folder`` relative to ``root`` and
    ``path`` where its files are, the count checked against the manifest's.
    A packed dataset's (``gen --format tar``) scenarios are unpacked one at
    a time, without frames, into a temporary folder that goes once read
    (errors name the pack and member, as the command line does)."""
    from ..disk import Dataset, _count_refused, _refuse_linked

    listed = next(g for g in manifest["groups"] if g["name"] == group).get("splits", {}).get(split)

    def refuse_count(found: int, what: str) -> None:
        refused = _count_refused(root, group, split, listed, found, what)
        if refused is not None:
            raise DatasetError(refused)

    if manifest.get("scenarios_per_tar"):
        with Dataset(root, split, images=False) as opened:
            keys = [k for k in opened.keys(split) if k.group == group]
            refuse_count(len(keys), "scenarios in its packs")
            return opened._read_unpacked(keys, lambda folder, key: (key.folder, read(folder, key.index)))
    # Hidden folders are scenarios being written; the manifest says how many
    # finished ones there are.
    folders = sorted(
        p for p in (root / group / split).glob("*") if not p.name.startswith(".") and (p / "scenario.json").is_file()
    )
    refuse_count(len(folders), "scenario folders")
    read_in = []
    for folder in folders:
        try:
            _refuse_linked(folder)  # (read through no link, as every reader)
        except InputError as e:
            raise DatasetError(str(e)) from None
        index = int(folder.name) if folder.name.isdigit() else folder.name
        read_in.append((str(folder.relative_to(root)).replace(os.sep, "/"), read(folder, index)))
    return read_in


def load_split(dataset: "str | Path", group: str, split: str) -> Episodes:
    """Reads every scenario of ``group`` and ``split`` (pixels.npy, poses.csv,
    scenario.json), from its folders or its packs."""
    root = Path(dataset)
    manifest = _manifest(root)
    spec = manifest["spec"]
    if group not in groups_of(root):
        raise InputError(f"group {group!r} is not in {root}: its groups are {', '.join(groups_of(root))}")
    if split not in SPLITS:
        raise InputError(f"split {split!r} is not one of {', '.join(SPLITS)}")

    def read(folder: Path, index) -> Tuple[dict, np.ndarray, np.ndarray]:
        meta, scenario_pixels, scenario_metres = _scenario_arrays(folder)
        # (a scenario moved or copied from elsewhere was read as this one)
        place = {"group": group, "split": split, "index": index, "seed": spec.get("seed")}
        wrong = next((k for k, v in place.items() if meta.get(k) != v), None)
        if wrong is not None:
            named = f"{index:05}" if isinstance(index, int) else index
            raise DatasetError(f"{folder / 'scenario.json'}: {wrong} {meta.get(wrong)!r}, but it lies in {root} at "
                               f"{group}/{split}/{named} ({wrong} {place[wrong]!r}): a scenario moved or copied "
                               f"from elsewhere; causalcity validate {root} tells what else is")  # fmt: skip
        return meta, scenario_pixels, scenario_metres

    scenarios = _split_scenarios(root, manifest, group, split, read)
    pixels, metres, graphs = [], [], []
    interval = float(spec.get("frame_interval") or 0.1)
    for _, (meta, scenario_pixels, scenario_metres) in scenarios:
        n = len(meta["cars"])
        interval = float(meta.get("frame_interval", interval))
        pixels.append(scenario_pixels)
        metres.append(scenario_metres)
        g = np.zeros((n, n), dtype=np.uint8)
        for a, b in meta["edges"]:
            g[a, b] = 1
        graphs.append(g)
    image = spec.get("image", {"width": 1024, "height": 640})
    shape_px, shape_m = (0, spec["frames"], 0, 2), (0, spec["frames"], 0, 4)
    return Episodes(
        dataset=root,
        group=group,
        split=split,
        folders=[folder for folder, _ in scenarios],
        pixels=np.stack(pixels) if pixels else np.zeros(shape_px),
        metres=np.stack(metres) if metres else np.zeros(shape_m),
        graph=np.stack(graphs) if graphs else np.zeros((0, 0, 0), dtype=np.uint8),
        image_size=(int(image["width"]), int(image["height"])),
        frame_interval=interval,
    )


def auroc_of(scores: np.ndarray, graph: np.ndarray) -> float:
    """AUROC of ``[scenarios, cars, cars]`` edge scores against the graph
    over every off-diagonal pair (ties count half); 0.5 without both kinds."""
    n = graph.shape[-1]
    off = ~np.eye(n, dtype=bool)
    s, y = scores[:, off].ravel(), graph[:, off].ravel().astype(bool)
    positives, negatives = int(y.sum()), int((~y).sum())
    if positives == 0 or negatives == 0:
        return 0.5
    order = np.argsort(s, kind="stable")
    ranks = np.empty(len(s))
    sorted_s = s[order]
    # average ranks over ties
    starts = np.r_[0, np.flatnonzero(sorted_s[1:] != sorted_s[:-1]) + 1]
    ends = np.r_[starts[1:], len(s)]
    for a, b in zip(starts, ends):
        ranks[order[a:b]] = (a + b + 1) / 2.0
    return float((ranks[y].sum() - positives * (positives + 1) / 2.0) / (positives * negatives))


def direction_right(scores: np.ndarray, graph: np.ndarray) -> float:
    """Share of the true edges ``graph[s, a, b] = 1`` whose reverse is not
    one scored above their reverse (``scores[s, a, b] > scores[s, b, a]``),
    ties counting half: 0.5 is chance. ``evaluate``'s ``direction``."""
    reverse = scores.transpose(0, 2, 1)
    one_way = (graph == 1) & (graph.transpose(0, 2, 1) != 1)
    return float(((scores > reverse) + 0.5 * (scores == reverse))[one_way].mean())


class Progress:
    """A progress line on stderr: redrawn in place on a terminal, every tenth
    of the work otherwise (logs), silent with ``quiet``."""

    def __init__(self, label: str, total: int, quiet: bool = False) -> None:
        self.label, self.total, self.done, self.quiet = label, max(total, 1), 0, quiet
        self.start = time.monotonic()
        self.tty = sys.stderr.isatty()
        self._last_tenth = -1

    def step(self, n: int = 1, note: str = "") -> None:
        self.done += n
        if self.quiet:
            return
        tenth = self.done * 10 // self.total
        elapsed = time.monotonic() - self.start
        eta = elapsed / self.done * (self.total - self.done) if self.done else 0.0
        width = 24
        bar = "#" * (self.done * width // self.total) + "." * (width - self.done * width // self.total)
        line = f"{self.label} [{bar}] {self.done}/{self.total} {elapsed:.0f}s eta {eta:.0f}s {note}"
        if self.tty:
            sys.stderr.write("\r" + line[:150].ljust(150))
            if self.done >= self.total:
                sys.stderr.write("\n")
            sys.stderr.flush()
        elif tenth != self._last_tenth or self.done >= self.total:
            self._last_tenth = tenth
            sys.stderr.write(line + "\n")
            sys.stderr.flush()


def write_predictions(
    path: "str | Path",
    edges: Dict[str, np.ndarray],
    trajectories: Dict[str, np.ndarray],
    dataset: "Optional[str | Path]" = None,
) -> None:
    """Saves the predictions file (see :func:`causalcity.save_predictions`),
    its arrays in sorted order so that the same predictions give the same
    bytes, with the record of ``dataset`` when given."""
    from .. import save_predictions

    save_predictions(
        path,
        edges={k: edges[k] for k in sorted(edges)},
        trajectories={k: trajectories[k] for k in sorted(trajectories)},
        dataset=dataset,
    )


def run_method(
    make_method,
    dataset: "str | Path",
    out: "str | Path",
    groups: Optional[Sequence[str]] = None,
    splits: Iterable[str] = ("val", "test"),
    quiet: bool = False,
) -> Path:
    """Fits a fresh method (``make_method()``) per group of ``dataset`` on its
    train split and writes its predictions for ``splits`` to ``out``."""
    root = Path(dataset)
    # The input first: a folder that is no dataset is named so (an --out
    # inside /tmp was called "inside the dataset it reads").
    all_groups = groups_of(root)
    # The one write rule, checked before any training: never into a
    # dataset, never onto the input, never through a link.
    _native.claim_output(os.fspath(out), [("the dataset it reads", os.fspath(root))])
    # Held while the method trains and predicts, group by group: gen
    # --force removed the dataset under it, and later groups were read from
    # the new one (exit 0).
    from ..disk import _ReadHold

    hold = _ReadHold(root)
    try:
        return _run_method(make_method, root, out, all_groups if groups is None else groups, splits, quiet)
    finally:
        hold.close()


def _run_method(make_method, root: Path, out: "str | Path", names, splits: Iterable[str], quiet: bool) -> Path:
    """:func:`run_method` under its hold on ``root``."""
    edges: Dict[str, np.ndarray] = {}
    trajectories: Dict[str, np.ndarray] = {}
    frames = None
    for episodes, predicted in fit_per_group(make_method, root, names, load_split, splits, quiet):
        frames = episodes.frames
        for k, folder in enumerate(episodes.folders):
            if predicted.edges is not None:
                edges[folder] = predicted.edges[k]
            if predicted.trajectories is not None:
                trajectories[folder] = predicted.trajectories[k]
        # Scenarios shorter than the history and its steps: what was
        # predicted comes after fewer frames than evaluate's default
        # history, which then refused the file without saying why.
        steps = predicted.trajectories.shape[1] if predicted.trajectories is not None else 0
        if steps and episodes.frames < HISTORY + steps:
            warnings.warn(
                f"{episodes.group}: its scenarios have {episodes.frames} frames, fewer than {HISTORY} frames of "
                f"history and {steps} steps: trajectories are predicted after frame {episodes.frames - steps}; "
                f"score them with causalcity evaluate --history {episodes.frames - steps}",
                stacklevel=2,
            )
    if not edges and not trajectories and frames is not None:
        raise InputError(
            f"{root}: the method predicted nothing: its scenarios have {frames} frames, and trajectories are predicted "
            f"after {HISTORY} frames of history ({HISTORY + STEPS} frames for the paper's {STEPS} steps); generate "
            "longer scenarios, or use a method that scores edges"
        )
    write_predictions(out, edges, trajectories, dataset=root)
    return Path(out)


def fit_per_group(
    make_method,
    root: Path,
    groups,
    load,
    splits: Iterable[str],
    quiet: bool,
    unit: str = "scenarios",
    parts: Dict[str, bool] = {"edges": False, "trajectories": False},
):
    """For each group: a fresh method (``make_method()``) fitted on
    ``load(root, group, "train")`` (and val), then ``(data, predicted)``
    for each split of ``splits`` that has data. Bad groups or splits are
    refused before any reading. ``parts`` names the prediction's fields
    (``True``: it may not be None), each of which must hold one entry per
    scenario (pair) of the data, or a method's mistake is named."""
    if isinstance(groups, (str, bytes)):
        raise InputError(f"groups={groups!r} is one string: give a list of group names, e.g. [{groups!r}]")
    splits = list(splits)
    for split in splits:
        if split not in SPLITS:
            raise InputError(f"split {split!r} is not one of {', '.join(SPLITS)}")
    for group in list(groups):
        method = make_method()
        label = _label(method)
        train = load(root, group, "train")
        val = load(root, group, "val")
        if len(train) == 0:
            raise InputError(f"{root / group}: no train {unit} to fit {label} on")
        if not quiet:
            print(f"{label}: {group} (train {len(train)} {unit}, val {len(val)})", file=sys.stderr)
        _call(f"{label}.fit on {root / group}", method.fit, train, val if len(val) else None)
        for split in splits:
            data = val if split == "val" else load(root, group, split)
            if len(data) > 0:
                predicted = _call(f"{label}.predict on {root / group}/{split}", method.predict, data)
                _check_predicted(predicted, data, parts, f"{label}.predict on {root / group}/{split}", unit)
                yield data, predicted


def _label(method) -> str:
    """A method's name in progress lines and errors: its ``name``, or its
    class's where it keeps the base classes' (a user's class read as
    "method")."""
    name = getattr(method, "name", None)
    return type(method).__name__ if name in (None, Method.name, "counterfactual") else str(name)


def _unread(part: str, value: np.ndarray, data, i: int):
    """Where evaluate does not read entry ``i`` of a prediction's ``part``
    (``True``): a car's score for itself, the intervened car's affected
    score."""
    unread = np.zeros(value.shape, dtype=bool)
    if part == "edges" and value.ndim == 2 and value.shape[0] == value.shape[1]:
        np.fill_diagonal(unread, True)
    elif part == "affected" and value.ndim == 1 and hasattr(data, "interventions"):
        car = data.interventions[i].get("car")
        if isinstance(car, int) and 0 <= car < len(unread):
            unread[car] = True
    return unread


def _check_predicted(predicted, data, parts: Dict[str, bool], where: str, unit: str) -> None:
    """Refuses a method's output that does not hold one entry per
    scenario (pair) of ``data`` in each of ``parts`` (a short one failed
    with an IndexError, a long one was cut silently), or that holds NaN or
    infinity (written, and refused only by evaluate)."""
    one = unit[:-1] if unit.endswith("s") else unit
    for part, required in parts.items():
        if not hasattr(predicted, part):
            raise InputError(f"{where} returned a {type(predicted).__name__}, which has no {part!r}: return a "
                             f"prediction with {' and '.join(parts)}")  # fmt: skip
        values = getattr(predicted, part)
        if values is None and not required:
            continue
        try:
            count = len(values)
        except TypeError:
            count = None
        if count != len(data):
            held = f"{count} {unit}" if count is not None else f"a {type(values).__name__}"
            raise InputError(f"{where} returned {part} for {held}, and it has {len(data)}: return one per {one}, "
                             f"in the order given")  # fmt: skip
        for i, value in enumerate(values):
            try:
                value = np.asarray(value, dtype=np.float64)
            except (TypeError, ValueError):
                continue  # not numbers: the writer names it
            bad = np.argwhere(~np.isfinite(value) & ~_unread(part, value, data, i))
            if len(bad):
                at = tuple(int(x) for x in bad[0])
                raise InputError(f"{where} returned {part} holding {value[at]} for {one} {i} at {list(at)}: every "
                                 f"value must be a finite number (evaluate refuses the file)")  # fmt: skip
