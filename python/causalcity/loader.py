"""Batches for training: :func:`batches` turns a split into shuffled batches
of stacked arrays (torch tensors once torch is imported), and :func:`collate`
stacks any list of :class:`~causalcity.Scenario` into one.

The fast path is the batch stream itself, handed to a DataLoader with
``batch_size=None``::

    batches = causalcity.batches("configs/ci-city.json", "train", batch_size=8, seed=0)
    loader = torch.utils.data.DataLoader(batches, batch_size=None)
    for epoch in range(10):
        batches.set_epoch(epoch)
        for batch in loader:
            batch["position"]   # [8, frames, cars, 3] float64 tensor

Scenarios are generated on all cores by Rust threads inside the loading
process, so no DataLoader worker is needed (``num_workers=0``): workers are
separate processes with one thread each, and every frame they make must be
copied to the training process. With workers, each still yields whole
batches (tensors move through shared memory), and the batches are the same.

Which scenarios share a batch, and the order of batches, depend only on the
spec, ``seed``, the epoch and ``batch_size``: never on ``num_workers``,
``threads`` or the number of processes. Each batch holds one group (the same
number of cars) unless ``mix_groups=True``, which pads to the most cars in
the batch and marks the real ones in ``car_mask``.
"""

from __future__ import annotations

import multiprocessing as _mp
import sys as _sys
from multiprocessing.context import get_spawning_popen as _spawning
from typing import Any, Dict, Iterator, List, Optional, Sequence, Tuple, Union

import numpy as _np

from . import _native
from . import (
    InputError,
    _STREAM_CHUNK,
    _U32_MAX,
    Key,
    Scenario,
    Spec,
    Stream,
    _as_spec,
    _flag,
    _scenario,
    _shard_pair,
    _torch_dataset_class,
    _whole,
    _worker,
)

__all__ = ["Batches", "batches", "collate"]

# Per-car arrays of a Scenario, stacked as [batch, frames, cars, ...] (cars padded).
_PER_CAR = ("position", "rotation", "pixels", "speed", "in_view")


def _torch():
    """torch when the program has imported it, else None (causalcity never
    imports torch itself)."""
    return _sys.modules.get("torch")


def collate(scenarios: Sequence[Scenario], tensors: Optional[bool] = None) -> Dict[str, Any]:
    """Stacks scenarios into one batch: a dict of arrays with the batch
    first. ``tensors`` (default: whether torch is imported) gives torch
    tensors instead of numpy arrays. Usable as a DataLoader ``collate_fn``.

    Keys: ``key`` (list of :class:`~causalcity.Key`), ``town`` (list of
    each scenario's town name, None where the dataset has one town; a
    spec that draws towns gives each scenario its own camera, so pixels
    mean different places in different towns), ``t`` ``[B, frames]``,
    ``position``/``rotation`` ``[B, frames, cars, 3]``, ``pixels``
    ``[B, frames, cars, 2]``, ``speed``/``in_view`` ``[B, frames, cars]``,
    ``car_mask`` ``[B, cars]`` (False on padding), ``graph`` ``[B, cars,
    cars]`` (``graph[b, i, j] = 1``: car i leads car j), with effects
    ``causal_graph`` and ``direct_graph`` (same orientation, cause row,
    effect column), in the city ``bound_by``/``other_car`` ``[B, frames,
    cars]``, and with images ``rgb`` ``[B, frames, H, W, 3]`` and ``mask``
    ``[B, frames, H, W]``. Scenarios with fewer cars than the batch's most
    are padded with zeros (``other_car`` with -1).
    """
    try:
        scenarios = list(scenarios)
    except TypeError:
        raise InputError(f"collate: {type(scenarios).__name__} is not a list of causalcity.Scenario") from None
    if len(scenarios) == 0:
        raise InputError("collate needs at least one scenario")
    for i, s in enumerate(scenarios):
        if not isinstance(s, Scenario):
            raise InputError(f"collate: item {i} is {s!r}, not a causalcity.Scenario")
    frames = {s.frames for s in scenarios}
    if len(frames) != 1:
        raise InputError(f"scenarios of different lengths ({sorted(frames)} frames) cannot share a batch")
    intervals = {float(s.t[1] - s.t[0]) if s.frames > 1 else None for s in scenarios}
    if len(intervals) > 1:
        raise InputError(
            f"scenarios of different frame intervals ({sorted(i for i in intervals if i is not None)} s; another "
            "world or dataset?) cannot share a batch: their frames would not line up"
        )
    size, cars = len(scenarios), max(s.cars for s in scenarios)
    (count,) = frames
    out: Dict[str, Any] = {
        "key": [s.key for s in scenarios],
        "town": [s.town for s in scenarios],
        "t": _np.stack([s.t for s in scenarios]),
    }
    mask = _np.zeros((size, cars), dtype=bool)
    for b, s in enumerate(scenarios):
        mask[b, : s.cars] = True
    out["car_mask"] = mask
    for name in _PER_CAR:
        first = getattr(scenarios[0], name)
        stacked = _np.zeros((size, count, cars) + first.shape[2:], dtype=first.dtype)
        for b, s in enumerate(scenarios):
            stacked[b, :, : s.cars] = getattr(s, name)
        out[name] = stacked
    graphs = {"graph": [s.graph for s in scenarios]}
    if all(s.effects is not None for s in scenarios):
        graphs["causal_graph"] = [s.causal_graph for s in scenarios]
        graphs["direct_graph"] = [s.direct_graph for s in scenarios]
    for name, values in graphs.items():
        stacked = _np.zeros((size, cars, cars), dtype=_np.uint8)
        for b, value in enumerate(values):
            stacked[b, : value.shape[0], : value.shape[1]] = value
        out[name] = stacked
    if all(s.interactions is not None for s in scenarios):
        bound_by = _np.zeros((size, count, cars), dtype=_np.uint8)
        other = _np.full((size, count, cars), -1, dtype=_np.int16)
        for b, s in enumerate(scenarios):
            bound_by[b, :, : s.cars] = s.interactions.bound_by
            other[b, :, : s.cars] = s.interactions.other_car
        out["bound_by"], out["other_car"] = bound_by, other
    if all(s.rgb is not None for s in scenarios):
        sizes = {tuple(s.rgb.shape[1:3]) for s in scenarios}
        if len(sizes) > 1:
            named = ", ".join(f"{s.key or 'scenario ' + str(b)}: {s.rgb.shape[2]} x {s.rgb.shape[1]}" for b, s in enumerate(scenarios))
            raise InputError(f"scenarios of different image sizes cannot share a batch ({named}); images=False "
                             "batches them without frames")  # fmt: skip
        out["rgb"] = _np.stack([s.rgb for s in scenarios])
        out["mask"] = _np.stack([s.mask for s in scenarios])
    return _as_tensors(out, tensors)


def _as_tensors(out: Dict[str, Any], tensors: Optional[bool]) -> Dict[str, Any]:
    """``out`` with its arrays as torch tensors (no copies) when ``tensors``
    (default: when torch is imported)."""
    if tensors is None:
        tensors = _torch() is not None
    elif not isinstance(tensors, (bool, _np.bool_)):
        raise TypeError(f"tensors={tensors!r}: give True, False or None")
    if tensors:
        torch = _torch()
        if torch is None:
            import torch  # noqa: F811 (asked for explicitly)
        for name, value in out.items():
            if isinstance(value, _np.ndarray):
                out[name] = torch.from_numpy(value)
    return out


class _Plan:
    """The batches of one epoch as positions into a stream's keys (group
    ``position // per_group``, index ``position % per_group``). In order
    without shuffling (computed on demand); with shuffling, one permutation
    of the positions (4 bytes a scenario) and one of the batches."""

    def __init__(self, groups: int, per_group: int, size: int, drop_last: bool, mix: bool, rng) -> None:
        self.size = size
        total = groups * per_group
        # Batches as (start, length) into `order`, kept whole within a group unless mixing.
        spans = [(0, total)] if mix else [(g * per_group, per_group) for g in range(groups)]
        starts, lengths = [], []
        for first, length in spans:
            whole, rest = divmod(length, size)
            starts.extend(range(first, first + whole * size, size))
            lengths.extend([size] * whole)
            if rest and not drop_last:
                starts.append(first + whole * size)
                lengths.append(rest)
        self.starts = _np.asarray(starts, dtype=_np.int64)
        self.lengths = _np.asarray(lengths, dtype=_np.int64)
        if rng is None:
            self.order = None
            return
        dtype = _np.uint32 if total <= _U32_MAX else _np.uint64
        self.order = _np.empty(total, dtype=dtype)
        for first, length in spans:
            self.order[first : first + length] = first + rng.permutation(length).astype(dtype)
        batches = rng.permutation(len(self.starts))
        self.starts, self.lengths = self.starts[batches], self.lengths[batches]

    def __len__(self) -> int:
        return len(self.starts)

    def positions(self, batch: int) -> _np.ndarray:
        start, length = int(self.starts[batch]), int(self.lengths[batch])
        if self.order is None:
            return _np.arange(start, start + length)
        return self.order[start : start + length]


class Batches:
    """A split as batches of stacked arrays, shuffled per epoch. See
    :func:`batches`."""

    def __init__(
        self,
        stream: Stream,
        batch_size: int,
        shuffle: bool,
        seed: int,
        drop_last: bool,
        mix_groups: bool,
        tensors: Optional[bool],
    ) -> None:
        self.stream = stream
        self.batch_size = _whole("batch_size", batch_size, 1, _U32_MAX)
        self.shuffle = _flag("shuffle", shuffle)
        self.seed = _whole("seed", seed, 0, 2**64 - 1)
        self.drop_last = _flag("drop_last", drop_last)
        self.mix_groups = _flag("mix_groups", mix_groups)
        self.tensors = None if tensors is None else _flag("tensors", tensors)
        # Shared memory: DataLoader workers, persistent ones included, read
        # the epoch set here after they started.
        self._epoch = _mp.RawValue("q", 0)

    @property
    def epoch(self) -> int:
        """The epoch whose shuffle the next iteration gives."""
        return int(self._epoch.value)

    def set_epoch(self, epoch: int) -> None:
        """Shuffles for ``epoch`` (as torch's DistributedSampler): call it
        before each epoch; the same epoch gives the same batches. It reaches
        DataLoader workers that are already running
        (``persistent_workers=True``), forked or spawned."""
        self._epoch.value = _whole("epoch", epoch, 0, 2**63 - 1)

    def __getstate__(self) -> Dict[str, Any]:
        state = self.__dict__.copy()
        # A worker being started shares the epoch's memory; any other pickle
        # (a copy, a file) carries the value.
        state["_epoch"] = self._epoch if _spawning() is not None else self.epoch
        return state

    def __setstate__(self, state: Dict[str, Any]) -> None:
        if isinstance(state["_epoch"], int):
            state["_epoch"] = _mp.RawValue("q", state["_epoch"])
        self.__dict__.update(state)

    def _plan(self) -> _Plan:
        s = self.stream
        rng = _np.random.default_rng([self.seed, self.epoch]) if self.shuffle else None
        return _Plan(len(s._groups), s._per_group, self.batch_size, self.drop_last, self.mix_groups, rng)

    def _mine(self, plan: _Plan, worker_id: int, workers: int) -> range:
        """The batches of ``plan`` for this process and worker: every
        (processes x workers)-th, so that together they cover each once."""
        rank, processes = self.stream.shard
        return range(len(plan))[worker_id * processes + rank :: processes * workers]

    def keys(self, worker: Optional[Tuple[int, int]] = None) -> List[List[Key]]:
        """The keys of the batches this process (and DataLoader worker)
        yields in this epoch, batch by batch; ``worker`` overrides the
        detected (worker id, workers)."""
        worker_id, workers = _worker() if worker is None else _shard_pair(worker, "worker")
        plan = self._plan()
        return [[self.stream._key(int(p)) for p in plan.positions(b)] for b in self._mine(plan, worker_id, workers)]

    def __len__(self) -> int:
        """Batches this process yields in an epoch (over all its workers)."""
        rank, processes = self.stream.shard
        return len(range(len(self._plan()))[rank::processes])

    def __iter__(self) -> Iterator[Dict[str, Any]]:
        s = self.stream
        worker_id, workers = _worker()
        threads = s.threads if s.threads is not None else (1 if workers > 1 else None)
        plan = self._plan()
        mine = self._mine(plan, worker_id, workers)
        # Keys go to the generator a few thousand at a time, whole batches each.
        per_chunk = max(1, _STREAM_CHUNK // self.batch_size)
        for first in range(0, len(mine), per_chunk):
            chosen = [[s._key(int(p)) for p in plan.positions(b)] for b in mine[first : first + per_chunk]]
            flat = [tuple(k) for keys in chosen for k in keys]
            # With images, each batch's frames are drawn straight into one
            # buffer, which comes with the batch's last scenario.
            lengths = [len(keys) for keys in chosen] if s.images else None
            scenarios = iter(_native.Prefetch(s.spec._native, flat, s.images, s.effects, threads, s.ahead, lengths))
            for keys in chosen:
                yield self._batch(keys, scenarios)

    def _batch(self, keys: List[Key], scenarios: Iterator[Dict[str, Any]]) -> Dict[str, Any]:
        """The next ``len(keys)`` scenarios as one batch. With images the
        library has drawn their frames into the batch's own arrays (which
        come with the last scenario): stacking them here cost a third of
        the rate (measured in ``make bench``)."""
        raws = [next(scenarios) for _ in keys]
        frames = (raws[-1].pop("batch_rgb", None), raws[-1].pop("batch_mask", None))
        out = collate([_scenario(raw, key) for raw, key in zip(raws, keys)], tensors=False)
        if self.stream.images:
            if frames[0] is None:  # a bug, never the input: say so rather than hand out a batch without frames
                raise _native.GenerationError("internal error: a batch's frames did not arrive (please report it)")
            out["rgb"], out["mask"] = (_np.asarray(f) for f in frames)
        return _as_tensors(out, self.tensors)


def __getattr__(name: str) -> Any:
    # causalcity.loader.TorchBatches, for pickle in a fresh worker process.
    if name == "TorchBatches":
        return _torch_dataset_class(Batches)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def batches(
    spec: Union[Spec, str, Dict[str, Any]],
    split: str,
    batch_size: int,
    *,
    shuffle: bool = True,
    seed: int = 0,
    drop_last: bool = False,
    mix_groups: bool = False,
    groups: Optional[Sequence[str]] = None,
    limit: Optional[int] = None,
    images: bool = False,
    effects: bool = True,
    shard: Union[str, Tuple[int, int], None] = None,
    threads: Optional[int] = None,
    ahead: Optional[int] = None,
    tensors: Optional[bool] = None,
) -> Batches:
    """The scenarios of ``split`` as batches of ``batch_size`` stacked by
    :func:`collate` (torch tensors when torch is imported, or as
    ``tensors`` says), generated on the fly.

    Shuffling (``shuffle=True``, the default) is seeded by ``seed`` and the
    epoch set with :meth:`Batches.set_epoch`: each epoch gives other
    batches, the same epoch the same ones, for any ``num_workers``,
    ``threads`` or ``shard``. Batches hold one group each (the last of a
    group may be short unless ``drop_last``); ``mix_groups=True`` draws
    them from all groups and pads to the most cars (``car_mask``). With
    ``shuffle=False`` batches follow ``gen``'s order.

    The other arguments are :func:`~causalcity.stream`'s. When torch is
    imported the result is a ``torch.utils.data.IterableDataset``: give the
    DataLoader ``batch_size=None``. Processes (``shard``, or ``RANK`` /
    ``WORLD_SIZE``) and DataLoader workers take every n-th batch.
    """
    inner = Stream(_as_spec(spec), split, groups, limit, images, shard, threads, ahead, effects)
    args = (inner, batch_size, shuffle, seed, drop_last, mix_groups, tensors)
    if _torch() is not None:
        return _torch_dataset_class(Batches)(*args)
    return Batches(*args)
