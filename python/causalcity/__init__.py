"""causalcity from Python: traffic scenarios for causal discovery and
counterfactual reasoning, generated on the fly into numpy arrays.

The same Rust library as the ``causalcity`` command runs underneath, so a
scenario from :func:`simulate` holds exactly what ``causalcity gen`` writes
for the same spec and key: every number as its CSV log gives it, every frame
as its PNG decodes. Nothing goes through the disk; :func:`open_dataset` and
:func:`load` read what ``gen`` wrote back into the same objects.

>>> import causalcity
>>> spec = causalcity.Spec.load("configs/ci-city.json")
>>> s = causalcity.simulate(spec, "cars08_edges50", "train", 0)
>>> s.position.shape, s.graph.shape          # (frames, cars, 3), (cars, cars)
>>> for s in causalcity.stream(spec, "train", images=True):
...     frames = s.rgb                        # (frames, height, width, 3) uint8

The GIL is released while Rust works, and :func:`stream` generates the
next scenarios on all cores (one per DataLoader worker) while you use the
current one.
"""

from __future__ import annotations

import csv as _csv_module
import io as _io
import json as _json
import numbers as _numbers
import os as _os
import re as _re
import sys as _sys
import warnings as _warnings
from dataclasses import dataclass
from typing import Any, Dict, Iterator, List, Mapping, NamedTuple, Optional, Sequence, Tuple, Union

import numpy as _np

from . import _native
from ._native import GenerationError, InputError

__all__ = [
    "__version__",
    "Spec",
    "Key",
    "Scenario",
    "Lights",
    "Interactions",
    "Effects",
    "Event",
    "Counterfactual",
    "Stream",
    "Batches",
    "simulate",
    "load",
    "open_dataset",
    "open_sweep",
    "read_tar",
    "Dataset",
    "Sweep",
    "Frames",
    "map",
    "stream",
    "batches",
    "collate",
    "counterfactual",
    "generate",
    "evaluate",
    "save_predictions",
    "HISTORY_FRAMES",
    "MAX_THREADS",
    "InputError",
    "GenerationError",
]

try:
    from importlib.metadata import PackageNotFoundError as _PackageNotFoundError, version as _version

    __version__ = _version("causalcity")
    """The installed package's version (python/pyproject.toml)."""
except _PackageNotFoundError:  # run from a source tree without installing
    __version__ = "unknown"

PathLike = Union[str, "_os.PathLike[str]"]

_U32_MAX = 2**32 - 1
MAX_THREADS = _native.MAX_THREADS
"""The most worker threads ``threads=`` takes, as ``gen -j``."""


def _whole(name: str, value: Any, minimum: int, maximum: int, flag: Optional[str] = None) -> int:
    """``value`` as an int in ``minimum..=maximum``, else :class:`InputError`
    naming the argument, the value and the range (and the command line's
    flag, which has the same limits)."""
    as_flag = f" (as {flag})" if flag else ""
    if isinstance(value, bool) or not isinstance(value, _numbers.Integral):
        raise InputError(f"{name}={value!r} is not a whole number: use {minimum} to {maximum}{as_flag}")
    value = int(value)
    if not minimum <= value <= maximum:
        raise InputError(f"{name}={value} is out of range: use {minimum} to {maximum}{as_flag}")
    return value


def _flag(name: str, value: Any) -> bool:
    """``value`` of the argument ``name`` as a bool: True or False (a numpy
    bool too), never a string or a number taken by truthiness."""
    if isinstance(value, (bool, _np.bool_)):
        return bool(value)
    raise TypeError(f"{name}={value!r}: give True or False")


def _optional_whole(name: str, value: Any, minimum: int, maximum: int, flag: Optional[str] = None) -> Optional[int]:
    return None if value is None else _whole(name, value, minimum, maximum, flag)


def _shard_pair(value: Any, name: str = "shard") -> Tuple[int, int]:
    """(k, n) from ``(k, n)`` or ``"k/n"`` with 0 <= k < n, else :class:`InputError`."""
    if name == "worker":
        what, usage = "a worker", "use (worker id, workers) with 0 <= worker id < workers, e.g. (0, 2)"
    else:
        what, usage = "a shard", "use (k, n) or \"k/n\" with 0 <= k < n, e.g. (0, 2) or \"0/2\""
    if isinstance(value, str):
        parts = value.split("/")
        if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
            raise InputError(f"{name}={value!r} is not {what}: {usage}")
        pair: Tuple[Any, ...] = (int(parts[0]), int(parts[1]))
    elif isinstance(value, (tuple, list)) and len(value) == 2:
        pair = tuple(value)
    else:
        raise InputError(f"{name}={value!r} is not {what}: {usage}")
    if any(isinstance(v, bool) or not isinstance(v, _numbers.Integral) for v in pair):
        raise InputError(f"{name}={value!r} is not {what}: {usage}")
    k, n = int(pair[0]), int(pair[1])
    if not (0 <= k < n <= _U32_MAX):
        raise InputError(f"{name}={value!r} is not {what}: {usage}")
    return k, n


class Key(NamedTuple):
    """One scenario of a spec: its group (e.g. ``cars08_edges50``), split
    (``train``, ``val`` or ``test``) and index within the split, as ``gen``
    numbers the folders (``<group>/<split>/<index:05>``)."""

    group: str
    split: str
    index: int

    @property
    def folder(self) -> str:
        """The scenario's folder under a dataset made by ``gen``."""
        return f"{self.group}/{self.split}/{self.index:05d}"


def _json_text(value: Any, origin: str) -> str:
    """``value`` as JSON text, or an InputError (``origin: field ...``)
    naming the first field whose value JSON cannot hold (NaN or infinity,
    a set, an object), where ``json.dumps`` would write ``NaN`` for the
    reader to call "not valid JSON" or raise a TypeError naming no field.
    NumPy's integers and floats are taken as Python's; keys must be
    strings (``json.dumps`` would turn ``1`` into ``"1"`` unasked)."""

    def plain(value: Any, field: str) -> Any:
        where = f"field `{field}`" if field else "the value"
        if isinstance(value, Mapping):
            for key in value:
                if not isinstance(key, str):
                    raise InputError(f"{origin}: {where}: key {key!r} is not a string: JSON keys are strings")
            return {key: plain(inner, f"{field}.{key}" if field else key) for key, inner in value.items()}
        if isinstance(value, (list, tuple)):
            return [plain(inner, f"{field}[{i}]") for i, inner in enumerate(value)]
        if value is None or isinstance(value, (str, bool, _np.bool_)):
            return bool(value) if isinstance(value, _np.bool_) else value
        if isinstance(value, _numbers.Integral):
            return int(value)
        if isinstance(value, _numbers.Real):
            if not _np.isfinite(float(value)):
                raise InputError(f"{origin}: {where}: {value} is not allowed: give a finite number")
            return float(value)
        raise InputError(
            f"{origin}: {where}: a {type(value).__name__} is not a JSON value: give a number, string, bool, list or dict"
        )

    return _json.dumps(plain(value, ""))


def _spec_json(spec: Any) -> str:
    """A spec dict as JSON text (see :func:`_json_text`)."""
    return _json_text(spec, "invalid spec <dict>")


class Spec:
    """A dataset spec, read and checked as ``causalcity gen`` reads it.

    Build one with :meth:`Spec.load` (a JSON file) or :meth:`Spec.from_dict`.
    Invalid specs raise :class:`InputError` with the command line's message,
    naming the field, the value and what is allowed.
    """

    def __init__(self, native: "_native.Spec") -> None:
        self._native = native

    @classmethod
    def load(cls, path: PathLike) -> "Spec":
        """Reads the spec file at ``path``."""
        return cls(_native.Spec.load(_os.fspath(path)))

    @classmethod
    def from_dict(
        cls, spec: Dict[str, Any], networks: Optional[PathLike] = None, beside: Optional[PathLike] = None
    ) -> "Spec":
        """A spec from a dict with the fields of a spec file. A SUMO network
        it names (``map.sumo``) is read from the folder ``networks`` by file
        name (a dataset's ``networks/``); else, given ``beside`` (the spec
        file the dict was read from, and then edited), relative to that
        file's folder, as :meth:`load` reads it; else from the working
        folder."""
        folder = None if networks is None else _os.fspath(networks)
        path = None if beside is None else _os.fspath(beside)
        origin = "<dict>" if path is None else f"<dict from {path}>"
        return cls(_native.Spec.from_json(_spec_json(spec), origin, path, folder))

    @property
    def name(self) -> str:
        return self._native.name

    @property
    def world(self) -> str:
        """``"toy"`` or ``"city"``."""
        return self._native.world

    @property
    def seed(self) -> int:
        return self._native.seed

    @property
    def frames(self) -> int:
        """Frames per scenario."""
        return self._native.frames

    @property
    def frame_interval(self) -> float:
        """Seconds between frames."""
        return self._native.frame_interval

    @property
    def image_size(self) -> Tuple[int, int]:
        """(width, height) of the bird's-eye frames, pixels."""
        return self._native.image_size

    @property
    def groups(self) -> List[str]:
        """Group names, e.g. ``["cars04_edges50", "cars08_edges20"]``."""
        return self._native.groups

    @property
    def splits(self) -> Dict[str, int]:
        """Scenarios per group in each split."""
        return dict(self._native.splits)

    @property
    def path(self) -> Optional[str]:
        """The file the spec was read from: :meth:`load`'s, or
        :meth:`from_dict`'s ``beside`` (None without one)."""
        return self._native.path

    def to_dict(self) -> Dict[str, Any]:
        """The spec's JSON as given."""
        return _json.loads(self._native.json)

    def keys(self, split: Optional[str] = None, limit: Optional[int] = None) -> List[Key]:
        """Every scenario of ``split`` (all splits when None), at most ``limit``
        per split and group, in ``gen``'s fixed order."""
        limit = _optional_whole("limit", limit, 1, _U32_MAX, "gen --limit")
        return [Key(*k) for k in self._native.keys(split, limit)]

    def __reduce__(self):
        # Picklable (DataLoader workers started with "spawn" receive a copy):
        # the JSON as read, not the file again.
        return (_spec_from_state, (self._native.json, self.path, self._native.networks))

    def __repr__(self) -> str:
        return f"Spec(name={self.name!r}, world={self.world!r}, groups={self.groups}, splits={self.splits})"


def _dataset_spec(raw: Dict[str, Any], root: PathLike, record: PathLike) -> Spec:
    """A dataset's own spec, from its record (``manifest.json`` or
    ``sweep.json``, which errors name), read to read the dataset: the gen
    that wrote it checked it, so it is planned with fewer trial plans than
    a spec about to be written (``Spec.from_dict`` checks that in full)."""
    networks = _os.fspath(_os.path.join(_os.fspath(root), "networks"))
    return Spec(_native.Spec.from_json(_spec_json(raw), _os.fspath(record), None, networks, True))


def _spec_from_state(text: str, path: Optional[str], networks: Optional[str] = None) -> Spec:
    return Spec(_native.Spec.from_json(text, path if path is not None else "<dict>", path, networks))


def _as_spec(spec: Union[Spec, PathLike, Dict[str, Any]]) -> Spec:
    if isinstance(spec, Spec):
        return spec
    if isinstance(spec, dict):
        return Spec.from_dict(spec)
    return Spec.load(spec)


class Event(NamedTuple):
    """One row of ``events.csv``. ``car`` is None for events of no car (a
    light or the weather changed); ``light`` names the light (``AC/W/straight``)."""

    frame: int
    t: float
    kind: str
    car: Optional[int]
    other_car: Optional[int]
    light: Optional[str]
    detail: str


@dataclass(frozen=True)
class Lights:
    """The light log (``light_changes.csv``, gen's default, or ``lights.csv``)
    as arrays, every frame (city world): ``L`` lights in plan order."""

    names: List[str]
    """Each light's name, ``AC/W/straight``, as scenario files and events name it."""
    colour: _np.ndarray
    """``[frames, L]`` uint8: index into :attr:`colour_names`."""
    colour_names: List[str]
    """``["green", "yellow", "red"]``."""
    since_change: _np.ndarray
    """``[frames, L]`` float64: seconds since the colour changed."""
    head_pixels: _np.ndarray
    """``[L, 2]`` float64: the signal head in bird's-eye pixels (NaN without one)."""


@dataclass(frozen=True)
class Interactions:
    """``interactions.csv`` as arrays (city world): what bound each car's
    speed choice at each frame, as the driver model used it."""

    kinds: List[str]
    """``["free", "car", "light", "conflict", "merge", "curve", "collision",
    "intervention", "give_way", "stop_line"]``."""
    bound_by: _np.ndarray
    """``[frames, cars]`` uint8: index into :attr:`kinds`."""
    other_car: _np.ndarray
    """``[frames, cars]`` int16: the car that bound it, -1 for none."""
    light: _np.ndarray
    """``[frames, cars]`` int16: the light that bound it (index into the
    scenario's ``lights.names``), -1 for none."""

    def car_graph(self) -> _np.ndarray:
        """``[frames, cars, cars]`` uint8: ``[t, i, j] = 1`` when car j bound
        car i at frame t (``car``, ``conflict``, ``collision`` or ``give_way``), as ``export
        nri --dynamic --directed`` writes it."""
        frames, cars = self.bound_by.shape
        binding = _np.isin(self.bound_by, [self.kinds.index(k) for k in ("car", "conflict", "collision", "give_way")])
        binding &= self.other_car >= 0
        graph = _np.zeros((frames, cars, cars), dtype=_np.uint8)
        t, i = _np.nonzero(binding)
        graph[t, i, self.other_car[t, i]] = 1
        return graph


@dataclass(frozen=True)
class Effects:
    """``effects.csv`` as arrays: one row per cause, intervention and other
    car, in the file's order. Every car was intervened on in turn from time
    0 (``remove``: taken off the map; ``next_action``: its first action
    changed) and every other car compared with its factual trajectory."""

    interventions: List[str]
    """``["remove", "next_action"]``."""
    cause: _np.ndarray
    """``[rows]`` uint32: the car intervened on."""
    effect: _np.ndarray
    """``[rows]`` uint32: the car compared."""
    intervention: _np.ndarray
    """``[rows]`` uint8: index into :attr:`interventions`."""
    max_divergence_m: _np.ndarray
    """``[rows]`` float64: largest distance from the factual position, metres."""
    first_frame: _np.ndarray
    """``[rows]`` int32: first frame beyond the threshold, -1 for no effect."""
    direct: _np.ndarray
    """``[rows]`` bool: the effect car reacted to the cause itself."""

    def graph(self, cars: int, direct: bool = False, intervention: Optional[str] = None) -> _np.ndarray:
        """``[cars, cars]`` uint8: ``[i, j] = 1`` when intervening on car i
        moved car j beyond the threshold (only direct effects with
        ``direct=True``; only one kind of intervention when named)."""
        keep = self.first_frame >= 0
        if direct:
            keep &= self.direct
        if intervention is not None:
            if intervention not in self.interventions:
                raise InputError(f"intervention {intervention!r} is not one of {', '.join(self.interventions)}")
            keep &= self.intervention == self.interventions.index(intervention)
        graph = _np.zeros((cars, cars), dtype=_np.uint8)
        graph[self.cause[keep], self.effect[keep]] = 1
        return graph


@dataclass(frozen=True)
class Scenario:
    """One simulated scenario. Car axes follow the car ids (0-based); the
    values are those of the files ``gen`` writes for the same key."""

    key: Optional[Key]
    """Its key (None for scenario files)."""
    metadata: Dict[str, Any]
    """``scenario.json``: cars, roles, routes, confounders, lights, camera."""
    car_ids: _np.ndarray
    """``[cars]`` uint32."""
    car_names: List[str]
    t: _np.ndarray
    """``[frames]`` float64, seconds."""
    position: _np.ndarray
    """``[frames, cars, 3]`` float64: x, y, z in metres (x east, y north)."""
    rotation: _np.ndarray
    """``[frames, cars, 3]`` float64: roll, pitch, yaw in radians (yaw
    counter-clockwise from east)."""
    pixels: _np.ndarray
    """``[frames, cars, 2]`` float64: px, py in the bird's-eye image
    (``pixels.npy`` holds the same values as float32)."""
    speed: _np.ndarray
    """``[frames, cars]`` float64, metres per second."""
    in_view: _np.ndarray
    """``[frames, cars]`` bool: the car's centre is in the bird's-eye image."""
    graph: _np.ndarray
    """``[cars, cars]`` uint8: ``graph[i, j] = 1`` when car i leads car j
    (the causal graph, cause to effect)."""
    edges: List[Tuple[int, int]]
    """(leader, follower) pairs, as ``scenario.json``'s ``edges``."""
    effects: Optional[Effects]
    """The interventional ground truth (``effects.csv``); None with
    ``effects=False``."""
    lights: Optional[Lights]
    interactions: Optional[Interactions]
    events: List[Event]
    rgb: Optional[_np.ndarray]
    """With ``images=True``: ``[frames, height, width, 3]`` uint8 (from
    :func:`load`, a :class:`Frames` that decodes the PNGs when indexed)."""
    mask: Optional[_np.ndarray]
    """With ``images=True``: ``[frames, height, width]`` uint8, 0 for no
    car, else the car's id + 1 (from :func:`load`, a :class:`Frames`)."""

    @property
    def causal_graph(self) -> Optional[_np.ndarray]:
        """``[cars, cars]`` uint8: ``[i, j] = 1`` when intervening on car i
        moves car j (``scenario.json``'s ``causal_edges``); None without
        effects."""
        return None if self.effects is None else self.effects.graph(self.cars)

    @property
    def direct_graph(self) -> Optional[_np.ndarray]:
        """``[cars, cars]`` uint8: the causal graph's direct effects
        (``direct_edges``); None without effects."""
        return None if self.effects is None else self.effects.graph(self.cars, direct=True)

    def __repr__(self) -> str:
        # Short: a notebook shows this for every scenario it prints.
        parts = [f"key={self.key!r}" if self.key is not None else f"name={self.metadata.get('name', '?')!r}"]
        parts += [f"cars={self.cars}", f"frames={self.frames}", f"edges={self.edges!r}"]
        if self.rgb is not None:
            parts.append(f"images={self.rgb.shape[2]}x{self.rgb.shape[1]}")
        parts.append("effects" if self.effects is not None else "no effects")
        return f"Scenario({', '.join(parts)})"

    @property
    def town(self) -> Optional[str]:
        """The town it happens on when its spec draws several (``map.grid``
        rows or columns drawn per scenario), e.g. ``"grid-3x4"``;
        ``scenario.json``'s ``map`` rebuilds it. None when the dataset has
        one town."""
        return self.metadata.get("town")

    @property
    def yaw(self) -> _np.ndarray:
        """``[frames, cars]``: heading in radians."""
        return self.rotation[..., 2]

    @property
    def frames(self) -> int:
        return int(self.t.shape[0])

    @property
    def cars(self) -> int:
        return int(self.car_ids.shape[0])


def _scenario(raw: Dict[str, Any], key: Optional[Key]) -> Scenario:
    lights = raw.get("lights")
    interactions = raw.get("interactions")
    effects = raw.get("effects")
    return Scenario(
        key=key,
        metadata=_json.loads(raw["scenario_json"]),
        car_ids=_np.asarray(raw["car_ids"]),
        car_names=raw["car_names"],
        t=_np.asarray(raw["t"]),
        position=_np.asarray(raw["position"]),
        rotation=_np.asarray(raw["rotation"]),
        pixels=_np.asarray(raw["pixels"]),
        speed=_np.asarray(raw["speed"]),
        in_view=_np.asarray(raw["in_view"]).view(_np.bool_),
        graph=_np.asarray(raw["graph"]),
        edges=raw["edges"],
        effects=None
        if effects is None
        else Effects(
            interventions=effects["interventions"],
            cause=_np.asarray(effects["cause"]),
            effect=_np.asarray(effects["effect"]),
            intervention=_np.asarray(effects["intervention"]),
            max_divergence_m=_np.asarray(effects["max_divergence_m"]),
            first_frame=_np.asarray(effects["first_frame"]),
            direct=_np.asarray(effects["direct"]).view(_np.bool_),
        ),
        lights=None
        if lights is None
        else Lights(
            names=lights["names"],
            colour=_np.asarray(lights["colour"]),
            colour_names=lights["colour_names"],
            since_change=_np.asarray(lights["since_change"]),
            head_pixels=_np.asarray(lights["head_pixels"]),
        ),
        interactions=None
        if interactions is None
        else Interactions(
            kinds=interactions["kinds"],
            bound_by=_np.asarray(interactions["bound_by"]),
            other_car=_np.asarray(interactions["other_car"]),
            light=_np.asarray(interactions["light"]),
        ),
        events=[Event(*e) for e in raw["events"]],
        rgb=_np.asarray(raw["rgb"]) if "rgb" in raw else None,
        mask=_np.asarray(raw["mask"]) if "mask" in raw else None,
    )


def simulate(
    spec: Union[Spec, PathLike, Dict[str, Any]],
    group: str,
    split: str,
    index: int,
    images: bool = False,
    effects: bool = True,
) -> Scenario:
    """Plans and simulates scenario ``index`` of ``group`` in ``split``; with
    ``images=True``, also renders its bird's-eye frames and masks; with
    ``effects=True`` (as ``gen``), measures its interventional effects
    (:attr:`Scenario.effects`, re-simulating it twice per car).

    ``spec`` is a :class:`Spec`, a spec file's path or a dict. Raises
    :class:`InputError` for a group, split or index the spec does not have.
    """
    spec = _as_spec(spec)
    index = _whole("index", index, 0, _U32_MAX)
    images, effects = _flag("images", images), _flag("effects", effects)
    raw = _native.simulate(spec._native, group, split, index, images, effects)
    return _scenario(raw, Key(group, split, index))


def map(  # noqa: A001 (causalcity.map, as the CLI's `map`)
    spec: Union[Spec, PathLike, Dict[str, Any]], town: Optional[str] = None
) -> Dict[str, Any]:
    """The spec's road network, as ``causalcity map`` lists it, with arrays:

    - ``town``: the town shown (``"custom"``, the four-intersection city;
      ``"grid-3x4"``, ..) and
      ``towns``, every town the spec draws (one unless ``map.grid`` draws
      rows or columns per scenario); ``town=`` picks one (the first when
      None), as ``Scenario.town`` names it;

    - ``junctions``: names (``"AC"``, ..), ``junction_controls`` (``"signals"``,
      ``"priority"``, ``"all_way_stop"`` or ``"right_before_left"``, as
      ``map.grid.control`` gives them)
      and ``junction_centres`` ``[J, 2]``;
    - ``lanes``: lane ids in id order (the spawn points scenario files name),
      ``lane_start`` and ``lane_end`` ``[L, 2]`` (centre line, metres, x east,
      y north), ``lane_length`` ``[L]``, ``lane_junction`` ``[L]`` (index
      into ``junctions`` of the junction the lane ends at, -1 before a
      U-turn loop) and ``lane_turns`` (the turns allowed at its end).

    ``spec`` is a :class:`Spec`, a spec file's path or a dict.
    """
    raw = _json.loads(_as_spec(spec)._native.map_json(town))
    lanes = raw["lanes"]
    return {
        "town": raw["town"],
        "towns": raw["towns"],
        "junctions": raw["junctions"],
        "junction_controls": raw["junction_controls"],
        "junction_centres": _np.array(raw["junction_centres"], dtype=_np.float64).reshape(-1, 2),
        "lanes": [lane["name"] for lane in lanes],
        "lane_start": _np.array([lane["start"] for lane in lanes], dtype=_np.float64).reshape(-1, 2),
        "lane_end": _np.array([lane["end"] for lane in lanes], dtype=_np.float64).reshape(-1, 2),
        "lane_length": _np.array([lane["length_m"] for lane in lanes], dtype=_np.float64),
        "lane_junction": _np.array(
            [-1 if lane["junction"] is None else lane["junction"] for lane in lanes], dtype=_np.int64
        ),
        "lane_turns": [lane["turns"] for lane in lanes],
    }


def _worker() -> Tuple[int, int]:
    """(worker id, workers) of the DataLoader worker this runs in, else (0, 1).
    torch is asked only when the program has imported it already."""
    if "torch" in _sys.modules:
        try:
            info = _sys.modules["torch"].utils.data.get_worker_info()
        except AttributeError:
            info = None
        if info is not None:
            return int(info.id), int(info.num_workers)
    return 0, 1


def _process_shard(shard: Optional[Tuple[int, int]]) -> Tuple[int, int]:
    """(rank, processes): ``shard``, else the RANK / WORLD_SIZE that
    torch.distributed launchers set, else (0, 1)."""
    if shard is not None:
        return _shard_pair(shard)
    rank, world = _os.environ.get("RANK"), _os.environ.get("WORLD_SIZE")
    if rank is None or world is None:
        return (0, 1)
    values = []
    for variable, text in (("RANK", rank), ("WORLD_SIZE", world)):
        try:
            values.append(int(text))
        except ValueError:
            raise InputError(
                f"environment variable {variable}={text!r} is not a whole number: torch.distributed launchers "
                "set RANK and WORLD_SIZE to integers; unset them or pass shard=(rank, processes)"
            ) from None
    if not 0 <= values[0] < values[1]:
        raise InputError(
            f"environment variables RANK={rank!r} and WORLD_SIZE={world!r} are not a shard: "
            "use 0 <= RANK < WORLD_SIZE, or pass shard=(rank, processes)"
        )
    return values[0], values[1]


class Stream:
    """Scenarios of one split generated on the fly, in ``gen``'s order,
    deterministic per key. See :func:`stream`."""

    def __init__(
        self,
        spec: Spec,
        split: str,
        groups: Optional[Sequence[str]] = None,
        limit: Optional[int] = None,
        images: bool = False,
        shard: Union[str, Tuple[int, int], None] = None,
        threads: Optional[int] = None,
        ahead: Optional[int] = None,
        effects: bool = True,
    ) -> None:
        self.spec = spec
        self.split = split
        self.images = _flag("images", images)
        self.effects = _flag("effects", effects)
        self.threads = _optional_whole("threads", threads, 1, MAX_THREADS, "gen -j")
        self.ahead = _optional_whole("ahead", ahead, 1, _U32_MAX)
        self.shard = _process_shard(shard)
        limit = _optional_whole("limit", limit, 1, _U32_MAX, "gen --limit")
        if not isinstance(split, str):
            raise InputError(f"split={split!r} is not a split name: use one of {', '.join(spec.splits)}")
        if split not in spec.splits:
            spec.keys(split, 1)  # raises InputError naming the splits there are
        if isinstance(groups, (str, bytes)):
            raise InputError(f"groups={groups!r} is one string: give a list of group names, e.g. groups=[{groups!r}]")
        if groups is not None:
            try:
                groups = list(groups)
            except TypeError:
                raise InputError(f"groups={groups!r} is not a list of group names, e.g. [{spec.groups[0]!r}]") from None
            if not groups:
                raise InputError("groups=[] names no group, so the stream would be empty: leave it out for every group")
            unknown = [g for g in groups if g not in spec.groups]
            if unknown:
                raise InputError(
                    f"groups {unknown} are not in spec {spec.name!r}: its groups are {', '.join(spec.groups)}"
                )
        # Keys are computed from their position (group, then index), never
        # listed: a spec at the largest split sizes has millions of them.
        self._groups = [g for g in spec.groups if groups is None or g in groups]
        self._per_group = min(spec.splits[split], _U32_MAX if limit is None else limit)
        self._positions = range(len(self._groups) * self._per_group)

    def _key(self, position: int) -> Key:
        return Key(self._groups[position // self._per_group], self.split, position % self._per_group)

    def _worker_positions(self, worker_id: int, workers: int) -> range:
        rank, processes = self.shard
        slot, slots = worker_id * processes + rank, processes * workers
        return self._positions[slot::slots]

    def keys(self, worker: Optional[Tuple[int, int]] = None) -> List[Key]:
        """The keys this process (and DataLoader worker) generates: process
        ``rank`` of ``processes`` takes every ``processes``-th key from its
        rank on, and its workers share those in turn, so processes and
        workers never overlap and together cover every key. ``worker``
        overrides the detected (worker id, workers)."""
        worker_id, workers = _worker() if worker is None else _shard_pair(worker, "worker")
        return [self._key(p) for p in self._worker_positions(worker_id, workers)]

    def __len__(self) -> int:
        """Scenarios this process yields (over all its DataLoader workers)."""
        rank, processes = self.shard
        return len(self._positions[rank::processes])

    def __iter__(self) -> Iterator[Scenario]:
        worker_id, workers = _worker()
        # Inside a DataLoader worker each worker is one process: one thread each.
        threads = self.threads if self.threads is not None else (1 if workers > 1 else None)
        positions = self._worker_positions(worker_id, workers)
        # Handed to the generator a chunk at a time, so that memory does not
        # grow with the split sizes.
        for start in range(0, len(positions), _STREAM_CHUNK):
            keys = [self._key(p) for p in positions[start : start + _STREAM_CHUNK]]
            scenarios = _native.Prefetch(
                self.spec._native, [tuple(k) for k in keys], self.images, self.effects, threads, self.ahead
            )
            for key, raw in zip(keys, scenarios):
                yield _scenario(raw, key)


_STREAM_CHUNK = 4096
"""Keys a stream hands its generator at once."""


def stream(
    spec: Union[Spec, PathLike, Dict[str, Any]],
    split: str,
    *,
    groups: Optional[Sequence[str]] = None,
    limit: Optional[int] = None,
    images: bool = False,
    effects: bool = True,
    shard: Union[str, Tuple[int, int], None] = None,
    threads: Optional[int] = None,
    ahead: Optional[int] = None,
) -> Stream:
    """An iterable of the scenarios of ``split`` (of ``groups``, all when
    None; at most ``limit`` per group), generated on the fly.

    Sharding: across processes by ``shard=(rank, processes)`` or
    ``"rank/processes"`` (default: the
    ``RANK`` and ``WORLD_SIZE`` environment variables when both are set), and
    across ``torch.utils.data.DataLoader`` workers by
    ``torch.utils.data.get_worker_info()``. Each key goes to exactly one
    process and worker. When torch has been imported, the stream is a
    ``torch.utils.data.IterableDataset``; give the DataLoader
    ``batch_size=None`` (or your own ``collate_fn``) since items are
    :class:`Scenario` objects.

    Work: ``threads`` worker threads (default: all cores; one per
    DataLoader worker) generate the next scenarios while you use the
    current one, each taking the next key as soon as it is free; at most
    ``ahead`` scenarios (default: threads + 1) wait or are under way, which
    bounds the memory with ``images=True`` (a 150-frame 1024 x 640 scenario
    holds 393 MB of frames). The order is the keys' order whatever the
    thread count. ``effects=False`` skips the interventional ground truth
    (``Scenario.effects``), which re-simulates each scenario twice per car:
    poses-only streams run several times faster without it.
    """
    spec = _as_spec(spec)
    args = (spec, split, groups, limit, images, shard, threads, ahead, effects)
    if "torch" in _sys.modules:
        return _torch_dataset_class(Stream)(*args)
    return Stream(*args)


_TORCH_CLASSES: Dict[str, type] = {}


def _torch_dataset_class(base: type) -> type:
    """``Torch<base>``: ``base`` as a ``torch.utils.data.IterableDataset``,
    made on first use so that importing causalcity never imports torch, and
    picklable by name from ``base``'s module (DataLoader workers started
    with "spawn" look it up there through the module's ``__getattr__``)."""
    name = "Torch" + base.__name__
    key = f"{base.__module__}.{name}"
    if key not in _TORCH_CLASSES:
        from torch.utils.data import IterableDataset

        class TorchDataset(base, IterableDataset):  # type: ignore[misc, valid-type]
            pass

        TorchDataset.__doc__ = f"A :class:`{base.__name__}` that is a torch IterableDataset."
        TorchDataset.__name__ = TorchDataset.__qualname__ = name
        TorchDataset.__module__ = base.__module__
        _TORCH_CLASSES[key] = TorchDataset
    return _TORCH_CLASSES[key]


def __getattr__(name: str) -> Any:
    # causalcity.TorchStream, for pickle in a fresh worker process.
    if name == "TorchStream":
        return _torch_dataset_class(Stream)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


@dataclass(frozen=True)
class Counterfactual:
    """One scenario's factual and counterfactual runs (as ``causalcity
    counterfactual`` writes them): everything before the intervention fires
    is identical; afterwards only what it causes differs."""

    name: str
    factual: Scenario
    counterfactual: Scenario
    divergence: _np.ndarray
    """``[frames, cars]`` float64: metres between each car's factual and
    counterfactual positions (``divergence.csv``)."""
    summary: Dict[str, Any]
    """``summary.json``: the interventions, when the first fired, and the
    cars it moved (the effect set)."""

    def __repr__(self) -> str:
        return (
            f"Counterfactual(name={self.name!r}, cars={self.factual.cars}, frames={self.factual.frames}, "
            f"affected={self.affected!r})"
        )

    @property
    def affected(self) -> List[str]:
        """Names of the cars whose trajectory changed."""
        return list(self.summary["affected"])

    @property
    def intervention_time(self) -> Optional[float]:
        """Seconds at which the first intervention fired (None if never)."""
        return self.summary["intervention_time_s"]


def _json_input(value: Union[PathLike, Dict[str, Any], List[Any]], label: str) -> Tuple[str, str]:
    """(text, origin) of a file path or an already parsed JSON value."""
    if isinstance(value, (dict, list)):
        return _json_text(value, label), label
    path = _os.fspath(value)
    try:
        with open(path, encoding="utf-8") as f:
            return f.read(), path
    except OSError as e:
        raise InputError(f"{path}: cannot read the file: {e.strerror}") from None


def counterfactual(
    scenario: Union[PathLike, Dict[str, Any], List[Any]],
    intervention: Union[PathLike, Dict[str, Any], List[Any], None] = None,
    *,
    images: bool = False,
) -> List[Counterfactual]:
    """Factual and counterfactual runs of every scenario of a scenario file
    (a path, or the file's JSON as a dict or list), one per scenario in file
    order. The counterfactual adds ``intervention`` (an intervention file's
    path, or its JSON: one intervention object or a list); without it, the
    scenario's own ``interventions`` make the counterfactual and the factual
    runs without them. City world only; see docs/handwritten-scenarios.md.
    """
    text, origin = _json_input(scenario, "<dict>")
    images = _flag("images", images)
    if intervention is None:
        raws = _native.counterfactual(text, origin, None, None, images)
    else:
        itext, iorigin = _json_input(intervention, "<intervention>")
        raws = _native.counterfactual(text, origin, itext, iorigin, images)
    return [
        Counterfactual(
            name=r["name"],
            factual=_scenario(r["factual"], None),
            counterfactual=_scenario(r["counterfactual"], None),
            divergence=_np.asarray(r["divergence"]),
            summary=_json.loads(r["summary"]),
        )
        for r in raws
    ]


def generate(
    spec: Union[Spec, PathLike, Dict[str, Any]],
    out: Optional[PathLike] = None,
    *,
    limit: Optional[int] = None,
    threads: Optional[int] = None,
    images: bool = True,
    annotations: bool = False,
    effects: bool = True,
    shard: Union[str, Tuple[int, int], None] = None,
    force: bool = False,
    fsync: bool = False,
    progress: bool = True,
    force_space: bool = False,
    lights: str = "changes",
    format: str = "folders",  # noqa: A002 (gen --format)
    scenarios_per_tar: Optional[int] = None,
) -> Dict[str, Any]:
    """``causalcity gen`` from Python: writes the dataset to ``out`` (default
    ``data/<spec name>``), resuming an interrupted run, and returns the
    run's summary (as ``gen --json`` prints it). The keywords are ``gen``'s
    flags: ``images=False`` is ``--no-images``, ``effects=False`` is
    ``--no-effects``, ``shard=(k, n)`` or ``"k/n"``
    is ``--shard k/n``, ``progress=False`` is ``--quiet``,
    ``force_space=True`` is ``--force-space`` (a disk too small for the
    run raises :class:`InputError` with the figures), ``lights="frames"``
    is ``--lights frames`` (``lights.csv``, every light at every frame,
    instead of the default ``light_changes.csv``), ``format="tar"`` is
    ``--format tar`` (whole scenarios in tar files of ``scenarios_per_tar``
    each, 64 by default; :func:`open_dataset` and :func:`read_tar` read
    them).
    """
    spec = _as_spec(spec)
    limit = _optional_whole("limit", limit, 1, _U32_MAX, "gen --limit")
    threads = _optional_whole("threads", threads, 1, MAX_THREADS, "gen -j")
    images, annotations, effects = _flag("images", images), _flag("annotations", annotations), _flag("effects", effects)
    # (force="no" said "'str' object is not an instance of 'bool'", naming no argument)
    force, fsync, force_space = _flag("force", force), _flag("fsync", fsync), _flag("force_space", force_space)
    if annotations and not images:
        raise InputError(
            "annotations=True needs images=True: annotations.json holds the frames' masks "
            "(gen refuses --annotations with --no-images)"
        )
    if lights not in ("frames", "changes"):
        raise InputError(f'lights={lights!r}: "frames" (lights.csv) or "changes" (light_changes.csv), as gen --lights')
    if format not in ("folders", "tar"):
        raise InputError(f'format={format!r}: "folders" or "tar", as gen --format')
    if format == "folders" and scenarios_per_tar is not None:
        raise InputError(f'scenarios_per_tar={scenarios_per_tar!r} packs tar files: give it with format="tar"')
    per_tar = None
    if format == "tar":
        per_tar = _whole("scenarios_per_tar", 64 if scenarios_per_tar is None else scenarios_per_tar, 1, 1_000_000, "gen --scenarios-per-tar")
    if shard is not None:
        k, n = _shard_pair(shard)
        shard = f"{k}/{n}"
    summary = _native.generate(
        spec._native,
        None if out is None else _os.fspath(out),
        limit,
        threads,
        images,
        annotations,
        effects,
        shard,
        force,
        fsync,
        progress,
        force_space,
        lights,
        per_tar,
    )
    return _json.loads(summary)


_DATASET_RECORD = "causalcity-dataset"
"""The array a predictions file records its dataset in."""

HISTORY_FRAMES = 100
"""Frames observed before a predicted trajectory's first frame, as in the
paper (``causalcity evaluate --history``'s default)."""


# A scenario or pair folder as a Key names it: group/split/index.
_FOLDER_KEY = _re.compile(r"(?!\.\.?/)[^/\\]+/(train|val|test)/[0-9]+")


def save_predictions(
    path: PathLike,
    edges: Optional[Mapping[str, _np.ndarray]] = None,
    trajectories: Optional[Mapping[str, _np.ndarray]] = None,
    *,
    frames: Optional[Mapping[str, _np.ndarray]] = None,
    counterfactuals: Optional[Mapping[str, _np.ndarray]] = None,
    affected: Optional[Mapping[str, _np.ndarray]] = None,
    dataset: Optional[PathLike] = None,
) -> None:
    """Writes a predictions file for :func:`evaluate` (``_np.savez_compressed``).

    ``dataset``, the folder the predictions were made on (a ``gen``
    dataset or a sweep), is recorded in the file (array
    ``causalcity-dataset``: its spec's hash, name, world, seed, split
    sizes, and a sweep's ``--kinds``), and :func:`evaluate` then refuses to score the file against
    any other dataset. Without it, ``evaluate`` warns that nothing checks
    the match.

    ``edges`` maps a scenario folder (``Key.folder``, e.g.
    ``cars08_edges50/test/00000``) to its ``[cars, cars]`` edge scores,
    ``[i, j]`` scoring "car i leads car j" as :attr:`Scenario.graph` is
    oriented, higher meaning more likely. ``trajectories`` maps a folder to
    ``[steps, cars, 2]`` predicted bird's-eye pixel positions of the frames
    after the first :data:`HISTORY_FRAMES` (the history the method saw).
    ``frames`` (city world) maps a folder to ``[frames, cars, cars]``
    per-frame edge scores, ``[t, i, j]`` scoring "car i bound car j's speed
    at frame t" (scored against ``interactions.csv``; note that
    :meth:`Interactions.car_graph` is ``[t, j, i]``, receiver first).
    ``counterfactuals`` (a ``counterfactual --sweep`` output, the
    counterfactual task of docs/evaluation.md) maps a pair's folder to
    ``[steps, cars, 2]`` predicted bird's-eye positions of its
    counterfactual run from the intervention's frame on (step 1 is frame
    ``summary.json``'s ``intervention.frame``); ``affected`` maps it to
    ``[cars]`` scores that the intervention moves each car (the intervened
    car's own score is not counted).
    """
    arrays: Dict[str, _np.ndarray] = {}
    kinds = (("edges", "", edges), ("trajectories", "/trajectory", trajectories), ("frames", "/frames", frames), ("counterfactuals", "/counterfactual", counterfactuals), ("affected", "/affected", affected))
    for label, suffix, given in kinds:
        if given is not None and not isinstance(given, Mapping):
            raise InputError(f"save_predictions: {label} is a {type(given).__name__}: give a dict of scenario folder -> array")
        for folder, values in (given or {}).items():
            # A Key names its folder; any other name must be a folder's.
            folder = folder.folder if isinstance(folder, Key) else folder
            # (an empty name, or one reaching out with ../, was written as given)
            if not isinstance(folder, str) or not _FOLDER_KEY.fullmatch(folder):
                raise InputError(
                    f"save_predictions: {label} key {folder!r} is not a scenario folder: give Key.folder "
                    "(e.g. 'cars08_edges50/test/00000') or a Key"
                )
            try:
                if _np.iscomplexobj(values):
                    raise InputError(f"save_predictions: {label}[{folder!r}] holds complex numbers: give real scores")
                values = _np.asarray(values)
                # Numbers only: dates, durations and text ("0.5") became numbers.
                if values.dtype.kind not in "biuf":
                    raise InputError(f"save_predictions: {label}[{folder!r}] holds {values.dtype} values: give "
                                     "numbers (scores, or metres)")  # fmt: skip
                # float16 and float32 are read as they are: half the bytes or less
                arrays[f"{folder}{suffix}"] = values if values.dtype in (_np.float16, _np.float32) else values.astype(_np.float64)
            except InputError:
                raise
            except (TypeError, ValueError) as e:
                raise InputError(f"save_predictions: {label}[{folder!r}] is not an array of numbers: {e}") from None
    if not arrays:
        raise InputError("save_predictions: give edge scores, trajectories, per-frame scores, counterfactuals or affected-car scores for at least one scenario")
    if dataset is not None:
        record = _native.dataset_identity(_os.fspath(dataset)).encode()
        arrays[_DATASET_RECORD] = _np.frombuffer(record, dtype=_np.uint8)
    # Written by the one write rule (never into a dataset, never through a
    # link), through a temporary file and a rename.
    buffer = _io.BytesIO()
    _np.savez_compressed(buffer, **arrays)
    _native.write_output(_os.fspath(path), buffer.getbuffer().tobytes())


def evaluate(
    dataset: PathLike,
    predictions: PathLike,
    *,
    graph: Union[str, Sequence[str]] = "designed",
    history: int = HISTORY_FRAMES,
    threshold: Optional[float] = None,
    csv: Optional[PathLike] = None,
    per_scenario: Optional[PathLike] = None,
) -> Dict[str, Any]:
    """``causalcity evaluate`` from Python: scores the predictions file
    ``predictions`` (see :func:`save_predictions`) against the dataset
    ``gen`` wrote to ``dataset`` (or a ``counterfactual --sweep`` output),
    and returns the report as ``evaluate --json`` prints it: ``edges`` (per
    graph, group and split: F1 at the threshold with the best F1 on val,
    with its standard error, precision, recall, AUROC, AUPRC, ``direction``
    (the linked pairs scored above their unlinked reverse, ties half), SHD;
    graph ``per-frame`` for per-frame scores), ``trajectories`` and
    ``counterfactuals`` (per group and split: normalised squared error at
    each step ahead). ``graph`` is one of
    ``designed``, ``causal``, ``direct`` or a list of them; ``csv`` also
    writes the table as ``--csv`` does. ``report["scenarios"]`` holds one
    dict per scenario and graph (its counts, precision, recall, F1, SHD,
    AUROC and direction at its group's threshold, its mean trajectory error), as
    ``--per-scenario`` writes them to ``per_scenario``. Bad predictions (a wrong shape, a
    NaN, a partly scored split) raise :class:`InputError`.
    """
    graphs = [graph] if isinstance(graph, str) else list(graph)
    history = _whole("history", history, 0, 2**63 - 1, "evaluate --history")
    csv = None if csv is None else _os.fspath(csv)
    per_scenario = None if per_scenario is None else _os.fspath(per_scenario)
    text, _table, scenarios = _native.evaluate(
        _os.fspath(dataset), _os.fspath(predictions), graphs, history, threshold, csv, per_scenario
    )
    report = _json.loads(text)
    report["scenarios"] = [_per_scenario_row(row) for row in _csv_module.DictReader(_io.StringIO(scenarios))]
    for warning in report.get("warnings", []):
        _warnings.warn(warning, stacklevel=2)
    return report


def _per_scenario_row(row: Dict[str, str]) -> Dict[str, Any]:
    """A ``--per-scenario`` CSV row with numbers as numbers (None for empty cells)."""
    text = {"scenario", "group", "split", "graph"}
    whole = {"cars", "true_edges", "predicted_edges", "true_positives"}
    return {
        k: v if k in text else None if v == "" else int(v) if k in whole else float(v) for k, v in row.items()
    }


from .loader import Batches, batches, collate  # noqa: E402 (needs the definitions above)
from .disk import Dataset, Frames, Sweep, load, open_dataset, open_sweep, read_tar  # noqa: E402 (needs the definitions above)


def __dir__() -> List[str]:
    # dir(causalcity) and tab completion list the API, not its imports.
    return sorted(set(__all__) | {"loader", "reference", "methods", "paper"} & set(globals()))
