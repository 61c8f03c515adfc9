"""The paper's experiments on our data, one command: generates the toy and
city datasets, trains and evaluates every reference method on both, and
writes a results CSV, figures in the style of the paper's figures 4 and 5,
and a Markdown table::

    python -m causalcity.paper --quick            # about 55 min on 2 CPU cores (--plan projects it)
    python -m causalcity.paper --device cuda      # the paper's 4000/500/500

Both worlds use the paper's groups (4, 8 and 12 cars with 50 % of cars
linked; 20, 50 and 80 % at 8 cars) from ``configs/toy.json`` and
``configs/city.json``; ``--quick`` draws fewer scenarios per split and
trains for fewer epochs. Everything is seeded: the same command gives the
same numbers on the same machine (CPU). Needs the ``methods`` extra:
``pip install "./python[methods]"`` (``make paper`` installs it).

Written under ``--out`` (default ``results/paper`` or ``results/paper-quick``):
``results.csv`` (one value per row: world, method, group, split, graph,
metric, step, value, se), ``f1.png`` (figure 5: F1 by number of cars and by
share of linked cars), ``trajectory.png`` (figure 4: error 1..20 steps
ahead), ``results.md`` (the tables), and the datasets and predictions.

Your own method joins the table next to the references: ``--method path nri
mypkg.models:MyMethod`` runs any class with ``causalcity.methods.Method``'s
interface (see ``causalcity.methods``), trained and scored the same way.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import dataclasses
import hashlib
import io
import json
import math
import os
import re
import stat
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, Iterator, List, Optional, Sequence, Tuple

from . import InputError, Spec, _native, evaluate, generate
from .methods import is_user_method, make
from .methods.common import positive_int as _positive, run_method

WORLDS = ("toy", "city")
# The tables and figures a run writes at the top of --out (f1.png only
# where a method discovers edges), in the order the last line names them.
TOP_FILES = ("results.csv", "f1.png", "trajectory.png", "results.md")
# The lock a run holds in its --out (see `_only_run`).
PAPER_LOCK = ".causalcity-paper.lock"
# The table's order: the first frame only, the simple rule, classical,
# neural, and the supervised upper bound; the predictors among them.
METHOD_ORDER = (
    "frame0", "path", "granger", "pcmci", "constant_velocity", "interaction", "nri", "nri_trail", "supervised",
)  # fmt: skip
LABELS = {
    "frame0": "frame-0 classifier (leak: the first frame only)",
    "path": "path rule (simple: b drives where a drove)",
    "granger": "Granger",
    "pcmci": "PCMCI",
    "constant_velocity": "constant velocity",
    "interaction": "interaction net (no discovery; NS-DR's role)",
    "nri": "NRI",
    "nri_trail": "NRI, trail messages (a message says where the sender went from here)",
    "supervised": "supervised classifier (upper bound: trained on labels)",
}


def _label(method: str) -> str:
    """A method's name in tables and figures (a user's class as named)."""
    return LABELS.get(method, method)


def _ordered(rows: List[dict]) -> List[str]:
    """The methods of ``rows``: the references in the table's order, then
    the users' in the order they ran."""
    present = dict.fromkeys(r["method"] for r in rows)
    return [m for m in METHOD_ORDER if m in present] + [m for m in present if m not in METHOD_ORDER]


# The paper's groups: number of cars at 50 % linked, share linked at 8 cars.
BY_CARS = ("cars04_edges50", "cars08_edges50", "cars12_edges50")
BY_SHARE = ("cars08_edges20", "cars08_edges50", "cars08_edges80")
TRAJECTORY_GROUP = "cars08_edges50"


@dataclass
class Setting:
    """Sizes of one run of the experiments."""

    name: str
    splits: Dict[str, int]
    epochs: int
    batch_size: int = 128
    lr: float = 3e-3
    methods: Sequence[str] = METHOD_ORDER
    # A method's options on top of the shared ones, in every world...
    extra: Dict[str, dict] = field(default_factory=dict)
    # ...and in one world only (world -> method -> options), on top of those.
    world_extra: Dict[str, Dict[str, dict]] = field(default_factory=dict)

    def options_of(self, method: str, world: Optional[str] = None) -> dict:
        """The options this setting gives ``method`` on top of the shared
        ones, in ``world`` (None: those of every world only)."""
        return {**self.extra.get(method, {}), **self.world_extra.get(world or "", {}).get(method, {})}

    def with_epochs(self, epochs: int) -> "Setting":
        """This setting with every neural method trained ``epochs`` epochs
        (the per-method epochs too); every other option stays."""

        def drop(options: Dict[str, dict]) -> Dict[str, dict]:
            return {m: {k: v for k, v in o.items() if k != "epochs"} for m, o in options.items()}

        return dataclasses.replace(
            self, epochs=epochs, extra=drop(self.extra), world_extra={w: drop(o) for w, o in self.world_extra.items()}
        )


# Batches sized for the work: the batched decoder makes a batch of 128
# windows cost little more than one of 8 (make bench-methods), and at 8 the
# encoder's edges ranked worse (toy, 8 cars, 200 train, 20 epochs: AUROC
# 0.52 at batch 8, lr 1e-3; 0.89 at batch 128, lr 3e-3; 0.94 after 60
# epochs). The quick setting's 80 train scenarios make 320 windows an
# epoch: batch 32 and 60 epochs give 600 optimiser steps (toy AUROC 0.84,
# 50 s per group on 2 cores). The interaction net's val loss stops
# improving about halfway (it memorises train).
QUICK = Setting(
    name="quick", splits={"train": 80, "val": 30, "test": 30}, epochs=60, batch_size=32, lr=2e-3,
    extra={"interaction": {"epochs": 30}},
)  # fmt: skip
# At the full setting's size NRI's encoder switches every edge off and the
# val loss keeps a late epoch (docs/evaluation.md). On 1,000 of its toy
# training scenarios (40 epochs at batch 128, lr 3e-3, scored on 300 val
# scenarios that neither train nor the val loss see; `make bench-methods
# BENCH_ONLY=recipe`) the kept epoch's AUROC is 0.85 by default and 0.96 with
# the KL weighed 10x and a cosine learning rate: true pairs climb back to a
# mean p(edge) of 0.3 while the others stay near 0.07. (KL 100x: 0.94;
# cosine alone: 0.68.) The quick setting keeps the defaults: at its 80
# scenarios the same recipe scores 0.63 against 0.79.
# NRI with trail messages found every toy edge, the right way round, from
# 200 training scenarios in 60 epochs at batch 128 (375 optimiser steps);
# 20 epochs on 4,000 are 2,500 steps, and a fifth of NRI's GPU time. At
# this size and without a warm-up (toy, 8 cars, 50 %, 2-core CPU,
# 2026-12-07, 48 minutes) its test F1 is 0.96, AUROC 0.998, direction right
# 99.7 %; with 5 warm-up epochs (625 steps of the decoder alone) its encoder
# put every true edge on the no-message type: AUROC 0.00, F1 0.07
# (docs/evaluation.md, "Our NRI against NRI"). In the city, at this size
# with NRI's KL, its encoder gave most pairs an edge (mean p(edge) 0.59 on
# unlinked pairs): test F1 0.15, AUROC 0.73, below Granger's F1 of 0.22.
# With the KL weighed 10x and a cosine learning rate, NRI's recipe here
# (2-core CPU, same data): city F1 0.24, AUROC 0.80, unlinked pairs at
# 0.26, but toy F1 0.86 (true edges at p 0.38; AUROC 0.993). Neither
# serves both worlds, so each world takes the one its val split scores
# higher (F1 at val's best threshold and AUROC, cars08_edges50; test not
# read): the city the recipe (val F1 0.25, AUROC 0.80, against 0.15 and
# 0.73), the toy NRI's KL (val F1 0.97, AUROC 0.999, against 0.86 and 0.991).
FULL = Setting(
    name="full", splits={"train": 4000, "val": 500, "test": 500}, epochs=100, batch_size=128, lr=3e-3,
    extra={"nri": {"kl_weight": 10.0, "lr_schedule": "cosine"}, "nri_trail": {"epochs": 20, "warmup_epochs": 0}},
    world_extra={"city": {"nri_trail": {"kl_weight": 10.0, "lr_schedule": "cosine"}}},
)  # fmt: skip


def _spec(
    path: Path, world: str, setting: Setting, splits: Optional[Dict[str, int]], groups: Optional[Sequence[str]] = None
) -> Spec:
    """The world's spec at this setting's sizes; with ``groups``, only those
    of its groups (each group's scenarios are the same either way: they are
    drawn from the seed and the group's name)."""
    if not path.is_file():
        if os.path.exists(path):
            raise InputError(f"{path}: not a regular file (a folder, a pipe or a device): give a spec file as "
                             f"--{world}-spec")  # fmt: skip
        raise InputError(f"{path}: no such spec file (run from the repository root, or give --{world}-spec)")
    try:
        raw = json.loads(path.read_text())
    except (UnicodeDecodeError, ValueError) as e:
        raise InputError(f"{path}: not a spec file (JSON): {e}") from None
    if not isinstance(raw, dict):
        raise InputError(f"{path}: not a spec file (a JSON object with name, world, groups, ...)")
    if raw.get("world") != world:
        # (A city spec as --toy-spec ran, its rows filed as the toy world's.)
        raise InputError(f"{path}: world {json.dumps(raw.get('world'))} given as --{world}-spec: give a {world}-world "
                         f"spec (e.g. configs/{world}.json)")  # fmt: skip
    raw["name"] = f"paper-{setting.name}-{world}"
    raw["splits"] = dict(splits or setting.splits)
    if groups:
        named = {Spec.from_dict({**raw, "groups": [g]}, beside=path).groups[0]: g for g in raw.get("groups", [])}
        unknown = [g for g in groups if g not in named]
        if unknown:
            raise InputError(f"--group {' '.join(unknown)}: {path} has no such group (its groups: {', '.join(named)})")
        raw["groups"] = [g for name, g in named.items() if name in groups]
    # (a SUMO network the spec names is read beside its file, as gen reads it)
    return Spec.from_dict(raw, beside=path)


def _method_options(
    name: str, setting: Setting, device: str, seed: int, quiet: bool, world: Optional[str] = None
) -> dict:
    options: dict = {}
    if name in NEURAL:
        options = dict(epochs=setting.epochs, device=device, seed=seed, quiet=quiet, batch_size=setting.batch_size,
                       lr=setting.lr)  # fmt: skip
    elif name in ("granger", "pcmci"):
        options = dict(quiet=quiet)
    elif name == "frame0":
        options = dict(seed=seed)
    elif name == "supervised" or is_user_method(name):
        options = dict(seed=seed, quiet=quiet)
        if is_user_method(name):
            options["device"] = device
    return {**options, **setting.options_of(name, world)}


# Seconds per train scenario and per val or test scenario of the methods
# without a network, each unit's whole time (reading the splits, fitting,
# predicting, evaluate) as measured on a 2-core CPU: the basis of the
# projection printed before a run starts. From units of 400/100/100 and
# 100/100/100 toy scenarios (8 cars, 50 %; 2026-12-07). Granger fits on
# train at each of its three lags, PCMCI reads train and fits nothing.
# One figure per scenario of every split had projected a full-size toy
# unit of Granger at 2m06s (it took 4m57s; now 4m45s) and PCMCI at twice
# what the split sizes give.
SECONDS_PER_SCENARIO = {
    "constant_velocity": (0.005, 0.006),
    "path": (0.0075, 0.004),
    "frame0": (0.013, 0.0045),
    "supervised": (0.039, 0.034),
    "granger": (0.064, 0.027),
    "pcmci": (0.0096, 0.060),
}
# Seconds a unit takes whatever its size, measured on a 2-core CPU in runs
# of 10/4/4 toy scenarios of 4 and 8 cars (2026-12-07): Granger starts a
# pool of a process per core for each lag and split (1.5 s in all, since
# the fork server loads scipy.stats once rather than each worker: 4.5 s
# before, 5 toy units 27 s against 12); PCMCI's workers need less (0.4 s,
# 0.7 before); a neural method builds its model (0.5-0.9 s).
# RUN_START_SECONDS: the first unit's imports (2.3 s more than the next
# one's), counted in its projection. Without them --plan projected such a
# run at 3 s, and it took 12.
UNIT_START_SECONDS = {"granger": 1.5, "pcmci": 0.4, "nri": 0.5, "interaction": 0.5, "nri_trail": 0.6}
DEFAULT_UNIT_START_SECONDS = 0.1
RUN_START_SECONDS = 2.3
NEURAL = ("nri", "interaction", "nri_trail")
# Each neural method is projected from the calibration of the model it
# trains: the interaction net is NRI's decoder. A trail-message window's
# cost against one of NRI's is no constant: 2.0x in whole quick runs at
# batch 32 on a 2-core CPU (toy 926 s against NRI's 449 s, 2026-12-03),
# 1.5x in the full setting's epochs at batch 128 on the same CPU
# (2026-12-07), 1.4x on an H200; a constant 2.0 projected a full-size toy
# unit at 58 min that took 47.
CALIBRATED_AS = {"nri": "nri", "interaction": "nri", "nri_trail": "nri_trail"}
PARALLEL = ("granger", "pcmci")
"""The methods that run one process per core."""


def _calibrate(setting: Setting, device: str, seed: int, name: str = "nri") -> Tuple[Tuple[float, float], str]:
    """Neural method ``name``'s windows per second with this setting's batch on ``device``, 8
    cars, 150 frames: (training, val loss), each timed on its own in the
    last of two short epochs of random walks (three on a GPU; a few seconds
    in all), and the device it ran on. Apart, because a val window is a
    forward pass alone, and on a GPU an eager one beside training steps
    replayed as CUDA graphs: one rate for both took the calibration's one
    val batch (a quarter of its windows, a thirtieth of the full
    setting's) for training, and projected NRI's H200 time at 1.4-1.8x
    what it took."""
    import numpy as np

    from .methods.common import Episodes

    rng = np.random.default_rng(seed)
    scenarios, frames, cars = 96, 150, 8
    pixels = np.cumsum(rng.normal(0, 2, (scenarios, frames, cars, 2)), axis=1) + 300
    walks = Episodes(
        dataset=Path("calibration"), group="cars08_edges50", split="train",
        folders=[f"calibration/{k}" for k in range(scenarios)], pixels=pixels,
        metres=np.zeros((scenarios, frames, cars, 4)), graph=np.zeros((scenarios, cars, cars), dtype=np.uint8),
        image_size=(1024, 640), frame_interval=0.1,
    )  # fmt: skip
    options = _method_options(name, setting, device, seed, quiet=True)
    # The last epoch is timed: on a GPU the first pays for the warm-up and
    # the second for capturing the CUDA graphs.
    on_gpu = options.get("device", "auto") != "cpu" and _torch_cuda()
    nri = make(name, **{**options, "epochs": 3 if on_gpu else 2, "warmup_epochs": 0})
    nri.fit(walks, None)
    training = max(nri.epoch_seconds[-1] - nri.val_seconds[-1], 1e-6)
    return (scenarios * nri.windows / training, scenarios / max(nri.val_seconds[-1], 1e-6)), str(nri.device)


def _torch_cuda() -> bool:
    import torch

    return torch.cuda.is_available()


def _projected_seconds(
    name: str, setting: Setting, cars: int, rates: Tuple[float, float], world: Optional[str] = None
) -> float:
    """One (world, method, group) unit's expected seconds; ``rates`` are
    the calibrated (training, forward-only) windows per second of the
    model a neural method trains (:data:`CALIBRATED_AS`)."""
    splits = setting.splits
    scenarios = sum(splits.values())
    if name in NEURAL:
        options = _method_options(name, setting, "cpu", 0, True, world)
        epochs = options.get("epochs", setting.epochs)
        training, forward = rates
        # Each epoch's val loss, and the predictions of every split at the end.
        seconds = 4 * splits["train"] * epochs / training + (splits["val"] * epochs + scenarios) / forward
        # A window costs about what its pairs cost: cars x (cars - 1), 56 at 8 cars.
        return _unit_start(name) + seconds * cars * (cars - 1) / 56
    per_train, per_scored = SECONDS_PER_SCENARIO.get(name, (0.05, 0.05))
    seconds = (per_train * splits["train"] + per_scored * (splits["val"] + splits["test"])) * max(cars, 4) / 8
    if name in PARALLEL:
        seconds *= 2 / max(os.cpu_count() or 1, 2)  # measured on 2 cores; they use every core
    return _unit_start(name) + seconds


def _unit_start(name: str) -> float:
    """Seconds a unit of method ``name`` takes whatever its size."""
    return UNIT_START_SECONDS.get(name, DEFAULT_UNIT_START_SECONDS)


def _unit_key(world: str, name: str, group: str, setting: Setting, device: str, seed: int, spec: Spec) -> dict:
    """What a finished unit must have been made with to be kept on a rerun:
    its world, method, group, the spec's contents (the group's own entry
    and every other field: another seed or map is another dataset, though
    paper names every spec alike), splits, the method's options and the seed."""
    return dict(world=world, method=name, group=group, spec=spec.name, spec_sha256=_group_spec_sha256(spec, group),
                splits=setting.splits,
                options={k: v for k, v in _method_options(name, setting, device, seed, True, world).items() if k != "quiet"},
                seed=seed)  # fmt: skip


def _group_spec_sha256(spec: Spec, group: str) -> str:
    """SHA-256 of ``spec``'s contents as they make ``group``'s scenarios:
    every field but the splits (the key's own field), with ``group``'s entry
    as the only group (a run of some groups and a run of all make the same
    scenarios of each)."""
    raw = spec.to_dict()
    raw.pop("splits", None)
    entries = dict(zip(spec.groups, raw.pop("groups", [])))
    raw["groups"] = [entries.get(group)]
    return hashlib.sha256(json.dumps(raw, sort_keys=True).encode()).hexdigest()


def _runs_beside(name: str) -> bool:
    """Whether ``name`` runs on the CPU thread beside the neural methods
    (built-in methods only: a user's may use torch and the GPU)."""
    return name in METHOD_ORDER and name not in NEURAL


def _overlapped(units, projected: dict, overlap: bool) -> float:
    """Projected seconds of ``units``: per world, the methods that run beside
    the neural ones and all the others, one after the other or
    (``overlap``) side by side."""
    total = 0.0
    for world in {u[0] for u in units}:
        beside = sum(projected[u] for u in units if u[0] == world and _runs_beside(u[1]))
        main = sum(projected[u] for u in units if u[0] == world and not _runs_beside(u[1]))
        total += max(beside, main) if overlap else beside + main
    return total


def _paced(projected: dict, paced: dict) -> dict:
    """``projected`` seconds per unit, each scaled by how long the units of
    its kind run so far took against their projection (``paced``, keyed by
    :func:`_runs_beside`; 1 before any has run)."""
    pace = {k: v["measured"] / v["projected"] if v["projected"] > 0 else 1.0 for k, v in paced.items()}
    return {u: seconds * pace[_runs_beside(u[1])] for u, seconds in projected.items()}


def _clock(seconds: float) -> str:
    seconds = max(0, int(seconds))
    return f"{seconds // 3600}h{seconds // 60 % 60:02d}m" if seconds >= 3600 else f"{seconds // 60}m{seconds % 60:02d}s"


def run(
    out: Path,
    setting: Setting,
    worlds: Sequence[str] = WORLDS,
    methods: Optional[Sequence[str]] = None,
    device: str = "auto",
    seed: int = 0,
    specs: Optional[Dict[str, Path]] = None,
    splits: Optional[Dict[str, int]] = None,
    quiet: bool = False,
    plan_only: bool = False,
    overlap: Optional[bool] = None,
    groups: Optional[Sequence[str]] = None,
    report_only: bool = False,
) -> List[dict]:
    """Runs the experiments and writes everything under ``out``; returns the
    result rows. Work is done in units of (world, method, group), each kept
    under ``out/units/`` when finished: a rerun of the same command skips
    them, so a run that was cut off continues where it stopped.
    ``plan_only`` prints the projected time per world and method and stops
    there, writing nothing. ``overlap`` runs the methods without a network
    on a thread of their own beside the neural ones (default: when those
    train on a GPU); the results are the same either way. ``groups`` runs
    only those groups of each world (``--group``), with their data in a
    folder of their own. ``report_only`` (``--report``) writes the table
    and figures of the units finished so far, runs nothing, and names the
    units not yet run."""
    methods = list(methods or setting.methods)
    # A name given twice would run its units twice over one file each.
    for flag, given in (("--method", methods), ("--group", groups or []), ("--world", worlds)):
        twice = sorted({g for g in given if list(given).count(g) > 1})
        if twice:
            raise InputError(f"{flag} names {', '.join(twice)} twice: give each once")
    for name in methods:
        if name not in METHOD_ORDER and not is_user_method(name):
            raise InputError(f"--method {name} is not one of {', '.join(METHOD_ORDER)}, nor package.module:Class")
        if is_user_method(name):
            make(name, **_method_options(name, setting, device, seed, quiet))  # refused now, not after hours
    specs = specs or {w: Path("configs") / f"{w}.json" for w in WORLDS}
    loaded = {world: _spec(Path(specs[world]), world, setting, splits, groups) for world in worlds}
    say = (lambda *a: None) if quiet else (lambda text: print(f"[paper] {text}", file=sys.stderr, flush=True))
    chosen = {world: list(loaded[world].groups) for world in worlds}
    cars = {g: int(g[len("cars") : g.index("_")]) for world in worlds for g in chosen[world]}
    units = [(world, name, group) for world in worlds for name in methods for group in chosen[world]]
    # A rerun projects only the units left, and calibrates NRI only when a
    # neural unit is among them. Records are read from below --out only,
    # never through a link.
    _refuse_links_below(out, [_unit_path(out, *u) for u in units])
    finished = {u: _read_unit(_unit_path(out, *u), _unit_key(*u, setting, device, seed, loaded[u[0]])) for u in units}
    left = [u for u in units if finished[u] is None]
    if report_only:
        if len(left) == len(units):
            raise InputError(f"{out}: no unit of this setting has finished there (a unit counts when made with the "
                             "same --device, --splits, --epochs and --seed)")  # fmt: skip
        for u in left:
            say(f"not run yet, so not in the table: {u[0]} {_label(u[1])} {u[2]}")
        rows = [row for u in units if finished[u] is not None for row in finished[u]["rows"]]
        _write_tables(out, rows, setting, worlds)
        return rows
    # Each model a neural unit left trains is calibrated once.
    rates: Dict[str, Tuple[float, float]] = {}
    calibrated, on = "", device
    for model in sorted({CALIBRATED_AS[u[1]] for u in left if u[1] in NEURAL}):
        rates[model], on = _calibrate(setting, device, seed, model)
        calibrated += (f"{'NRI' if model == 'nri' else model} calibrated at {rates[model][0]:.0f} training "
                       f"windows/s and {rates[model][1]:.0f} val windows/s on {on}; ")  # fmt: skip
    projected = {
        u: _projected_seconds(u[1], setting, cars[u[2]], rates.get(CALIBRATED_AS.get(u[1], ""), (1.0, 1.0)), u[0])
        if u in left else 0.0
        for u in units
    }  # fmt: skip
    if left:
        projected[left[0]] += RUN_START_SECONDS  # the first unit run pays the imports
    if overlap is None:
        overlap = on.startswith("cuda") and any(u[1] in NEURAL for u in units)
    beside = " with the CPU methods beside the GPU's" if overlap else ""
    kept = f", {len(units) - len(left)} of them finished earlier" if len(left) < len(units) else ""
    say(
        f"{len(units)} unit{'' if len(units) == 1 else 's'} (world x method x group){kept}, projected {_clock(_overlapped(units, projected, overlap))}"
        f"{beside} besides "
        f"generating the data ({calibrated}the classical methods "
        f"from 2-core CPU figures, Granger and PCMCI scaled to {os.cpu_count()} cores)"
    )
    if plan_only:
        for world in worlds:
            for name in methods:
                seconds = sum(v for (w, m, _), v in projected.items() if (w, m) == (world, name))
                say(f"  {world} {_label(name)}: {_clock(seconds)}")
        return []
    # Refused now, not after hours: an --out inside a dataset or a sweep, or
    # through a link (every file below is written by the same rule), and a
    # link anywhere on the way to what the run writes below --out.
    _native.claim_output(os.fspath(out / "results.csv"), writes="text")
    data_of = {world: out / "data" / (world if not groups else "-".join([world, *chosen[world]])) for world in worlds}
    # What this run writes: the units left, their worlds' data, the tables.
    writes = [p for u in left for p in (_unit_path(out, *u), _predictions_path(out, *u), data_of[u[0]])]
    _refuse_links_below(out, writes + [out / n for n in (*TOP_FILES, "timings.json")])
    out.mkdir(parents=True, exist_ok=True)
    # One run at a time in --out: two would run the same units and write
    # the same tables at once.
    with _only_run(out):
        records: Dict[Tuple[str, str, str], dict] = {}
        timings: Dict[str, float] = {}
        lock = threading.Lock()
        # Projected and measured seconds of the units run so far, kept apart
        # for the methods beside the neural ones (projected from fixed
        # figures) and the rest (calibrated on this machine): a classical
        # unit's pace says nothing of a neural one's.
        started = time.monotonic()
        paced = {beside: dict(projected=0.0, measured=0.0) for beside in (True, False)}

        def finish(world: str, name: str, group: str, data: Path, spec: Spec) -> None:
            """Runs one unit, or keeps it from an earlier run, and says so."""
            unit = (world, name, group)
            record = _unit_path(out, world, name, group)
            key = _unit_key(world, name, group, setting, device, seed, spec)
            kept = _read_unit(record, key)
            if kept is None:
                start = time.monotonic()
                predictions = _predictions_path(out, world, name, group)
                _refuse_links_below(out, [record, predictions])  # one made since the start
                options = _method_options(name, setting, device, seed, quiet, world)
                run_method(lambda: make(name, **options), data, predictions, groups=[group], quiet=quiet)
                report = evaluate(data, predictions, graph=["designed", "causal"], csv=None)
                seconds = time.monotonic() - start
                kept = dict(key=key, seconds=seconds, rows=_rows(world, name, report))
                _write_unit(record, kept)
                verb = f"done in {_clock(seconds)}"
            else:
                seconds, verb = 0.0, "kept from an earlier run"
            with lock:
                if seconds:
                    paced[_runs_beside(name)]["projected"] += projected[unit]
                    paced[_runs_beside(name)]["measured"] += seconds
                records[unit] = kept
                timings[f"{world}/{name}"] = timings.get(f"{world}/{name}", 0.0) + kept["seconds"]
                left = [u for u in units if u not in records]
                eta = _overlapped(left, _paced(projected, paced), overlap)
                say(f"{len(records)}/{len(units)} {world} {_label(name)} {group}: {verb}; "
                    f"elapsed {_clock(time.monotonic() - started)}, ETA {_clock(eta)}")  # fmt: skip

        for world in worlds:
            spec = loaded[world]
            # Another selection of groups is another dataset (gen refuses to mix specs).
            data = data_of[world]
            start = time.monotonic()
            mine = [u for u in units if u[0] == world]
            if any(u in left for u in mine):
                say(f"generating {world}: {spec.splits} per group into {data}")
                try:
                    generate(spec, data, images=False, progress=not quiet)
                except InputError as e:
                    if "made differently" not in str(e):
                        raise
                    # (gen's own advice, --force, is not a flag of this command.)
                    differences = str(e).split("\n")[1:-1]
                    raise InputError(
                        f"{data} holds {world} data made with another setting:\n" + "\n".join(differences)
                        + f"\nUse another --out, or remove {data} to generate it again (the finished units under "
                        f"{out / 'units'} are kept either way)"
                    ) from None
                timings[f"{world}/generate"] = time.monotonic() - start
            else:
                say(f"every {world} unit finished earlier: its data is not needed")
            host = [u for u in mine if _runs_beside(u[1])] if overlap else []
            # The methods without a network run on the CPU's cores while the
            # neural ones train on the GPU.
            stop = threading.Event()

            def run_host() -> None:
                for u in host:
                    if stop.is_set():
                        return  # the main thread failed or was interrupted
                    finish(*u, data, spec)

            with ThreadPoolExecutor(1) as beside:
                pending = beside.submit(run_host)
                try:
                    for u in mine:
                        if u not in host:
                            if pending.done():
                                pending.result()  # a failed CPU unit stops the run now, not after the GPU's
                            finish(*u, data, spec)
                    pending.result()
                except BaseException:
                    # The CPU thread ends after the unit it is in; this error, not
                    # the thread's, is the one raised.
                    stop.set()
                    raise
        rows = [row for u in units for row in records[u]["rows"]]
        _write(out / "timings.json", json.dumps({k: round(v, 1) for k, v in timings.items()}, indent=2) + "\n")
        _write_tables(out, rows, setting, worlds)
        return rows


@contextlib.contextmanager
def _only_run(out: Path) -> Iterator[None]:
    """Holds ``out``'s lock (``.causalcity-paper.lock``, an exclusive
    ``flock`` released when the run ends, however it ends): a second run on
    the same ``--out`` is refused, naming the first's process. The lock file
    is opened without following a link."""
    import fcntl

    path = out / PAPER_LOCK
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK, 0o644)
    except OSError as e:
        raise InputError(f"{path}: cannot open this run's lock file ({e.strerror}; a link there is not followed)") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise InputError(f"{path}: not a regular file where this run's lock file should be: remove it")
        if st.st_nlink > 1:
            # a second name of a file elsewhere, which the process id would overwrite
            raise InputError(f"{path}: a hard link ({st.st_nlink} names of one file) where this run's lock file "
                             "should be: causalcity never writes through a link; remove it")  # fmt: skip
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
            raise InputError(f"{out}: another paper run (process {holder}) is running there: wait for it to end, or "
                             "give another --out") from None  # fmt: skip
        except OSError as e:
            # A filesystem without locks (some network filesystems), as gen takes it: said, and run.
            print(f"[paper] warning: {out} cannot be locked ({e.strerror}): nothing stops a second run there",
                  file=sys.stderr)  # fmt: skip
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield
    finally:
        os.close(fd)


def _write(path: Path, data: "str | bytes") -> None:
    """Writes a file of the results by the one write rule (never inside a
    dataset or sweep, never through a link), whole or not at all (a
    temporary file and a rename)."""
    _native.write_output(os.fspath(path), data.encode() if isinstance(data, str) else data)


def _write_tables(out: Path, rows: List[dict], setting: Setting, worlds: Sequence[str]) -> None:
    """results.csv, the figures and results.md of ``rows``."""
    _write_csv(out / "results.csv", rows)
    _figures(out, rows, worlds)
    _write(out / "results.md", markdown(rows, setting, worlds))


def _folder(name: str) -> str:
    """A method's folder under ``units/`` and ``predictions/`` (a user's
    ``package.module:Class`` as a name a folder may have)."""
    return name.replace(":", "-")


def _unit_path(out: Path, world: str, name: str, group: str) -> Path:
    """Where a finished unit's record lies."""
    return out / "units" / world / _folder(name) / f"{group}.json"


def _predictions_path(out: Path, world: str, name: str, group: str) -> Path:
    """Where a unit's predictions file lies."""
    return out / "predictions" / world / _folder(name) / f"{group}.npz"


def _refuse_links_below(out: Path, paths: Sequence[Path]) -> None:
    """The write rule below ``--out`` (Rust's, the one ``gen`` applies below
    its own): raises ``InputError`` naming the first symbolic link at any of
    ``paths`` or on the way to it (``units/``, ``predictions/``, ``data/``
    and what is in them)."""
    try:
        _native.refuse_links_below(os.fspath(out), [os.fspath(p) for p in paths])
    except InputError as e:
        raise InputError(f"{e} (to keep paper's results on another disk, give that folder as --out)") from None


def _read_unit(path: Path, key: dict) -> Optional[dict]:
    """A finished unit's record, made as ``key`` says; ``None`` when there
    is none. A record that is not this run's to keep is refused
    (``InputError``), before anything is run or written: one made with
    another setting (its results would be replaced), one edited or damaged
    (its numbers would go into the table), or something other than a file."""
    if not os.path.lexists(path):
        return None
    again = "remove it to run the unit again"
    mode = os.lstat(path).st_mode
    if not stat.S_ISREG(mode):
        kind = "a folder" if stat.S_ISDIR(mode) else "a link" if stat.S_ISLNK(mode) else "not a regular file"
        raise InputError(f"{path}: {kind} where a finished unit's record should be: {again}")
    try:
        record = json.loads(path.read_text(), parse_constant=_no_constant)
    except (OSError, UnicodeDecodeError, ValueError) as e:
        raise InputError(f"{path}: a damaged unit record ({e}): {again}") from None
    if not isinstance(record, dict) or not isinstance(record.get("key"), dict):
        raise InputError(f"{path}: not a unit record (a JSON object with key, seconds and rows): {again}")
    theirs, ours = record["key"], json.loads(json.dumps(key))
    if "spec_sha256" not in theirs:
        raise InputError(f"{path}: a unit record of an earlier causalcity, whose key does not hold the spec's "
                         "contents (every record now does, so that another spec's results are never kept): remove it to run the "
                         "unit again (or remove the whole units folder), or give another --out")  # fmt: skip
    differ = [k for k in sorted(set(theirs) | set(ours)) if theirs.get(k) != ours.get(k)]
    if differ:
        said = "; ".join(
            f"the spec's contents (--{key['world']}-spec): sha256 {str(theirs.get(k))[:12]}... there, "
            f"{str(ours.get(k))[:12]}... now" if k == "spec_sha256"
            else f"{k}: {_short(theirs.get(k))} there, {_short(ours.get(k))} now"
            for k in differ
        )  # fmt: skip
        raise InputError(f"{path}: a unit made with another setting ({said}). Its result would be replaced: give "
                         f"another --out, or {again}")  # fmt: skip
    seconds = record.get("seconds")
    if not (_real(seconds) and seconds >= 0):
        raise InputError(f"{path}: seconds {_short(seconds)} is not allowed: the unit's time, 0 or more: {again}")
    _check_rows(path, record.get("rows"), (key["world"], key["method"], key["group"]), again)
    return record


def _no_constant(name: str):
    raise ValueError(f"{name} is not a number JSON allows")


def _short(value) -> str:
    text = json.dumps(value, sort_keys=True)
    return text if len(text) <= 80 else text[:77] + "..."


def _real(value) -> bool:
    """A finite int or float (not a bool)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


#: What each metric's value may be: within [0, 1], or 0 or more.
_UNIT_METRICS = {"f1": 1.0, "auroc": 1.0, "auprc": 1.0, "direction": 1.0, "shd": math.inf, "trajectory_mse": math.inf}
#: Round-off a record's value may carry beyond its metric's range: evaluate
#: summed AUPRC's terms as fractions until 2026-12-07, and a perfect toy
#: ranking's came to 1.0000000000000004 (its own run then refused the record).
_ROUND_OFF = 1e-12


def _check_rows(path: Path, rows, unit: Tuple[str, str, str], again: str) -> None:
    """A unit record's rows as :func:`_rows` makes them, each of ``unit``
    (world, method, group), every number finite and within its metric's
    range; raises ``InputError`` naming the row, field and value."""
    if not isinstance(rows, list) or not rows:
        raise InputError(f"{path}: rows {_short(rows)} is not a list of result rows: {again}")
    for i, row in enumerate(rows):
        where = f"{path}: rows[{i}]"
        if not isinstance(row, dict) or set(row) != set(COLUMNS):
            raise InputError(f"{where} is not a result row (an object of {', '.join(COLUMNS)}): {again}")
        for column, own in zip(("world", "method", "group"), unit):
            if row[column] != own:
                raise InputError(f"{where}: {column} {_short(row[column])} is not this unit's ({_short(own)}): {again}")
        metric, value, se, step, scenarios = (row[c] for c in ("metric", "value", "se", "step", "scenarios"))
        bad = None
        if metric not in _UNIT_METRICS:
            bad = f"metric {_short(metric)} is not one of {', '.join(_UNIT_METRICS)}"
        elif row["split"] not in ("train", "val", "test"):
            bad = f"split {_short(row['split'])} is not train, val or test"
        elif not isinstance(row["graph"], str):
            bad = f"graph {_short(row['graph'])} is not a graph's name"
        elif value is not None and not (_real(value) and 0 <= value <= _UNIT_METRICS[metric] + _ROUND_OFF):
            top = "1" if _UNIT_METRICS[metric] == 1.0 else "any finite number"
            bad = f"value {_short(value)} is not allowed for {metric}: from 0 to {top}, or null"
        elif se is not None and not (_real(se) and se >= 0):
            bad = f"se {_short(se)} is not allowed: a finite number from 0 up, or null"
        elif not (step == "" or (isinstance(step, int) and not isinstance(step, bool) and step >= 1)):
            bad = f"step {_short(step)} is not allowed: empty, or a whole number from 1 up"
        elif not (isinstance(scenarios, int) and not isinstance(scenarios, bool) and scenarios >= 0):
            bad = f"scenarios {_short(scenarios)} is not allowed: a whole number from 0 up"
        if bad:
            raise InputError(f"{where}: {bad}: {again}")


def _write_unit(path: Path, record: dict) -> None:
    _write(path, json.dumps(record) + "\n")


def _rows(world: str, method: str, report: dict) -> List[dict]:
    """One row per value of an evaluation report (``evaluate(...)``'s JSON)."""

    def row(entry: dict, graph: str, metric: str, step, value, se, scenarios) -> dict:
        return dict(world=world, method=method, group=entry["group"], split=entry["split"], graph=graph,
                    metric=metric, step=step, value=value, se=se, scenarios=scenarios)  # fmt: skip

    rows = []
    for e in report["edges"]:
        for metric, se in (("f1", "f1_se"), ("auroc", None), ("auprc", None), ("direction", None), ("shd", "shd_se")):
            rows.append(row(e, e["graph"], metric, "", e[metric], e[se] if se else None, e["scenarios"]))
    for t in report["trajectories"]:
        for s in t["steps"]:
            rows.append(row(t, "", "trajectory_mse", s["step"], s["mse"], s["se"], s["scenarios"]))
    return rows


COLUMNS = ("world", "method", "group", "split", "graph", "metric", "step", "value", "se", "scenarios")


def _fmt(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


def _write_csv(path: Path, rows: List[dict]) -> None:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(COLUMNS)
    for r in rows:
        w.writerow([_fmt(r[c]) for c in COLUMNS])
    _write(path, buf.getvalue())


def read_results(path: "str | Path") -> List[dict]:
    """Rows of a results.csv, numbers parsed."""
    rows = []
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            r["value"] = float(r["value"]) if r["value"] else None
            r["se"] = float(r["se"]) if r["se"] else None
            r["step"] = int(r["step"]) if r["step"] else None
            r["scenarios"] = int(r["scenarios"])
            rows.append(r)
    return rows


def _get(rows, **match) -> Optional[dict]:
    for r in rows:
        if all(r[k] == v for k, v in match.items()):
            return r
    return None


def _savefig(fig, path: Path) -> None:
    buffer = io.BytesIO()
    fig.savefig(buffer, dpi=110, format="png")
    _write(path, buffer.getvalue())


def _figures(out: Path, rows: List[dict], worlds: Sequence[str]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = {"nri": "#1f77b4", "granger": "#ff7f0e", "pcmci": "#2ca02c", "frame0": "#7f7f7f",
               "constant_velocity": "#7f7f7f", "interaction": "#d62728", "path": "#9467bd",
               "supervised": "#000000", "nri_trail": "#17becf"}
    spare = iter(["#8c564b", "#e377c2", "#bcbd22", "#aec7e8", "#ffbb78", "#98df8a"] * 4)
    for method in _ordered(rows):
        colours.setdefault(method, next(spare))
    discovering = [m for m in _ordered(rows) if any(r["method"] == m and r["metric"] == "f1" for r in rows)]
    if discovering:
        _f1_figure(plt, out, rows, worlds, discovering, colours)
    _error_figure(plt, out, rows, worlds, colours)


def _f1_figure(plt, out: Path, rows: List[dict], worlds: Sequence[str], discovering: List[str], colours: dict) -> None:
    """f1.png: each discovering method's test F1 per group (none without one)."""
    fig, axes = plt.subplots(len(worlds), 2, figsize=(11, 3.6 * len(worlds)), squeeze=False)
    for wi, world in enumerate(worlds):
        for ci, (groups, xlabel, ticks) in enumerate(
            [(BY_CARS, "cars (50 % linked)", ["4", "8", "12"]), (BY_SHARE, "share of cars linked (8 cars)", ["20 %", "50 %", "80 %"])]
        ):
            ax = axes[wi][ci]
            width = 0.8 / max(len(discovering), 1)
            for mi, method in enumerate(discovering):
                values, errors = [], []
                for g in groups:
                    r = _get(rows, world=world, method=method, group=g, split="test", graph="designed", metric="f1")
                    values.append(r["value"] if r else float("nan"))  # a group not run: no bar
                    errors.append((r["se"] or 0.0) if r else 0.0)
                xs = [k + (mi - (len(discovering) - 1) / 2) * width for k in range(len(groups))]
                hatch = "//" if method == "frame0" else None
                ax.bar(xs, values, width, yerr=errors, capsize=3, label=_label(method), color=colours[method],
                       hatch=hatch, alpha=0.9)
            ax.set_xticks(range(len(groups)), ticks)
            ax.set_xlabel(xlabel)
            ax.set_ylabel("F1 (test)")
            ax.set_ylim(0, 1.05)
            ax.set_title(f"{world}: edge discovery F1 by {'number of cars' if ci == 0 else 'share linked'}")
    handles, labels = axes[0][0].get_legend_handles_labels()
    # Three to a row: the labels say what each row of the table is, and a
    # single row of them was wider than the figure.
    fig.legend(handles, labels, loc="lower center", ncol=min(3, len(labels)), fontsize=8)
    fig.tight_layout(rect=(0, 0.03 * ((len(labels) + 2) // 3 + 1), 1, 1))
    _savefig(fig, out / "f1.png")
    plt.close(fig)


def _error_figure(plt, out: Path, rows: List[dict], worlds: Sequence[str], colours: dict) -> None:
    """trajectory.png: each predicting method's test error by steps ahead."""
    predicting = [m for m in _ordered(rows) if any(r["method"] == m and r["metric"] == "trajectory_mse" for r in rows)]
    fig, axes = plt.subplots(1, len(worlds), figsize=(5.5 * len(worlds), 3.8), squeeze=False)
    for wi, world in enumerate(worlds):
        ax = axes[0][wi]
        for method in predicting:
            pts = sorted(
                (r["step"], r["value"], r["se"] or 0.0)
                for r in rows
                if r["world"] == world and r["method"] == method and r["group"] == TRAJECTORY_GROUP
                and r["split"] == "test" and r["metric"] == "trajectory_mse"
            )
            if not pts:
                continue
            steps, values, ses = zip(*pts)
            style = "--" if method == "constant_velocity" else "-"
            ax.plot(steps, values, style, label=_label(method), color=colours[method])
            ax.fill_between(steps, [v - s for v, s in zip(values, ses)], [v + s for v, s in zip(values, ses)],
                            color=colours[method], alpha=0.2)
        ax.set_yscale("log")
        ax.set_xlabel("steps ahead (frames)")
        ax.set_ylabel("MSE, positions normalised by image size")
        ax.set_title(f"{world}: trajectory prediction, 8 cars, 50 % linked (test)")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    fig.tight_layout()
    _savefig(fig, out / "trajectory.png")
    plt.close(fig)


def _setting_words(setting: Setting, methods: Sequence[str], worlds: Sequence[str] = ()) -> str:
    """The setting a table ran with, as its header says it: the sizes, the
    neural methods' training, and the options of its own that the setting
    gives a method of the table (as the method takes them), in every world
    and in each of ``worlds`` alone, so that a method trained otherwise is
    not read as trained like the rest."""
    splits = setting.splits
    words = (f"{setting.name} ({splits['train']}/{splits['val']}/{splits['test']} scenarios per group, "
             f"{setting.epochs} epochs at batch {setting.batch_size} and learning rate {setting.lr:g} for the "
             "neural methods")  # fmt: skip

    def listed(options: dict) -> str:
        return ", ".join(f"{k}={v!r}" for k, v in options.items())

    for method in methods:
        parts = [listed(setting.extra[method])] if setting.extra.get(method) else []
        for world in worlds:
            own = setting.world_extra.get(world, {}).get(method)
            if own:
                parts.append(f"in the {world} world {listed(own)}")
        if parts:
            words += f"; {method}: " + "; ".join(parts)
    return words + ")"


def markdown(rows: List[dict], setting: Setting, worlds: Sequence[str]) -> str:
    """The results as Markdown tables: F1 (test, designed graph) per group and
    method, AUROC and the direction right at 8 cars, 50 %, and trajectory
    error at 1, 10 and 20 steps."""
    groups = list(dict.fromkeys(BY_CARS + BY_SHARE))
    lines = [f"Setting: {_setting_words(setting, _ordered(rows), worlds)}; test split, designed graph; "
             "F1 at the threshold with the best F1 on val, ± standard error over scenarios.", ""]
    lines.append("| world | method | " + " | ".join(f"F1 {g}" for g in groups)
                 + " | AUROC 8 cars 50 % | direction right 8 cars 50 % |")  # fmt: skip
    lines.append("|---" * (len(groups) + 4) + "|")
    for world in worlds:
        for method in _ordered(rows):
            cells = []
            for g in groups:
                r = _get(rows, world=world, method=method, group=g, split="test", graph="designed", metric="f1")
                cells.append("" if r is None else f"{r['value']:.2f} ± {r['se'] or 0:.2f}")
            if not any(cells):
                continue
            at = dict(world=world, method=method, group=TRAJECTORY_GROUP, split="test", graph="designed")
            a, d = _get(rows, **at, metric="auroc"), _get(rows, **at, metric="direction")
            auroc = "" if a is None or a["value"] is None else f"{a['value']:.2f}"
            direction = "" if d is None or d["value"] is None else f"{100 * d['value']:.0f} %"
            lines.append(f"| {world} | {_label(method)} | " + " | ".join(cells) + f" | {auroc} | {direction} |")
    lines += ["", "Trajectory error (MSE of positions normalised by image size; 8 cars, 50 % linked; test):", ""]
    table = ["| world | method | 1 step | 10 steps | 20 steps |", "|---|---|---|---|---|"]
    for world in worlds:
        for method in _ordered(rows):
            cells = []
            for step in (1, 10, 20):
                r = _get(rows, world=world, method=method, group=TRAJECTORY_GROUP, split="test",
                         metric="trajectory_mse", step=step)
                cells.append("" if r is None else f"{r['value']:.2e}")
            if any(cells):
                table.append(f"| {world} | {_label(method)} | " + " | ".join(cells) + " |")
    if len(table) == 2:
        # (a header with no rows was printed when the group was left out)
        table = [f"None: this run has no method that predicts trajectories on {TRAJECTORY_GROUP}, the group this "
                 "table reads (constant_velocity, interaction, nri or nri_trail, with that group in --group)."]  # fmt: skip
    lines += table
    return "\n".join(lines) + "\n"


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m causalcity.paper", description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer scenarios and epochs: about 55 min on 2 CPU cores (--plan projects it)")
    parser.add_argument("--out", type=Path, help="output folder [results/paper or results/paper-quick]")
    parser.add_argument("--world", nargs="+", choices=WORLDS, default=list(WORLDS))
    parser.add_argument("--group", nargs="+", metavar="GROUP",
                        help="only these groups, e.g. cars08_edges50 (default: every group of the spec)")
    parser.add_argument("--method", nargs="+", metavar="METHOD",
                        help=f"only these methods: {', '.join(METHOD_ORDER)}, or your own as package.module:Class")
    parser.add_argument("--device", default="auto", help="cpu, cuda or auto (default: cuda when available)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--toy-spec", type=Path, default=Path("configs/toy.json"))
    parser.add_argument("--city-spec", type=Path, default=Path("configs/city.json"))
    parser.add_argument("--splits", help="override scenarios per split, e.g. 40/10/10 (train/val/test)")
    parser.add_argument("--epochs", type=_positive, help="override the neural methods' epochs")
    parser.add_argument("--quiet", action="store_true")
    parser.add_argument("--plan", action="store_true", help="print the projected time per world and method, then stop")
    parser.add_argument("--report", action="store_true",
                        help="write the table and figures of the units finished so far under --out, running nothing "
                             "(give the run's --device, --splits, --epochs and --group)")
    args = parser.parse_args(argv)
    if args.plan and args.report:
        print("error: --plan and --report: give one (--plan projects a run, --report tables a finished one)",
              file=sys.stderr)  # fmt: skip
        return 2
    if not re.fullmatch(r"auto|cpu|cuda(:[0-9]+)?", args.device):
        # (said here whichever methods run: with the path rule alone it was taken)
        print(f"error: --device {args.device!r} is not a device: use auto, cpu, cuda or cuda:N", file=sys.stderr)
        return 2
    setting = QUICK if args.quick else FULL
    splits = None
    if args.splits:
        try:
            train, val, test = (int(v) for v in args.splits.split("/"))
        except ValueError:
            print(f"error: --splits {args.splits!r}: give train/val/test counts, e.g. 40/10/10", file=sys.stderr)
            return 2
        if train < 1 or val < 0 or test < 1:
            print(f"error: --splits {args.splits!r}: give at least 1 train and 1 test scenario per group (and 0 or "
                  "more val), e.g. 40/10/10", file=sys.stderr)  # fmt: skip
            return 2
        splits = {"train": train, "val": val, "test": test}
        setting = dataclasses.replace(setting, splits=splits)
    if args.epochs is not None:
        # every neural method's epochs, the setting's per-method ones too;
        # their other options (NRI's KL recipe, nri_trail's warm-up) stay
        setting = setting.with_epochs(args.epochs)
    out = args.out or Path("results") / ("paper-quick" if args.quick else "paper")
    start, started_at = time.monotonic(), time.time()
    try:
        run(out, setting, args.world, args.method, args.device, args.seed,
            {"toy": args.toy_spec, "city": args.city_spec}, splits, args.quiet and not args.plan, plan_only=args.plan,
            groups=args.group, report_only=args.report)
    except (InputError, ValueError, FileNotFoundError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        # Each finished unit is on disk; the one cut off is run again.
        units = out / "units"
        finished = units.is_dir() and any(p.is_file() for p in units.rglob("*.json"))
        if finished:
            print(f"\ninterrupted: the finished units are kept in {units}; rerun the same command to go on",
                  file=sys.stderr)  # fmt: skip
        else:
            print("\ninterrupted before any unit finished: nothing to keep; rerun the same command to start again",
                  file=sys.stderr)  # fmt: skip
        return 130
    if args.plan:
        return 0
    print((out / "results.md").read_text())
    wrote = [str(out / n) for n in TOP_FILES if (out / n).is_file() and (out / n).stat().st_mtime >= started_at - 1]
    print(f"wrote {', '.join(wrote[:-1])} and {wrote[-1]} in {time.monotonic() - start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
