"""Datasets read back from disk: what ``causalcity gen`` wrote, as the same
:class:`~causalcity.Scenario` objects :func:`~causalcity.simulate` gives.

>>> import causalcity
>>> data = causalcity.open_dataset("data/ci-city")
>>> data.keys("test")[:2]
>>> s = data.load(data.keys("test")[0])           # or causalcity.load(folder)
>>> s.position.shape, s.graph.shape
>>> s.rgb[10]                                      # frame 10, decoded from rgb/0010.png

Every number is the one the files hold, which is the one ``simulate`` gives
for the same key. Frames stay on disk until used: ``rgb`` and ``mask`` are
:class:`Frames`, which decode PNGs when indexed (``s.rgb[3]``,
``s.rgb[:10]``) and turn into a whole array with ``numpy.asarray(s.rgb)``.
"""

from __future__ import annotations

import json as _json
import os as _os
import re
import warnings as _warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any, Dict, Iterator, List, Optional, Tuple, Union

import numpy as _np

from . import _native
from ._native import InputError

if TYPE_CHECKING:
    from . import Counterfactual, Key, Scenario

PathLike = Union[str, "_os.PathLike[str]"]


class Frames:
    """A scenario's bird's-eye frames (``rgb``) or masks (``mask``) on disk,
    decoded from their PNGs when indexed: ``frames[i]`` is one frame,
    ``frames[a:b]`` several, ``numpy.asarray(frames)`` all of them
    (``[frames, height, width, 3]`` or ``[frames, height, width]`` uint8, as
    :func:`~causalcity.simulate` gives them)."""

    dtype = _np.dtype(_np.uint8)

    def __init__(self, folder: Path, kind: str, frames: int, width: int, height: int, cars: Optional[int] = None) -> None:
        self._folder = folder
        self.kind = kind
        self._frames, self._width, self._height = frames, width, height
        # A mask's values are 0 (no car) and a car's mask_id (its id + 1).
        self._cars = cars
        # A packed dataset's temporary folder that ``folder`` is in (kept
        # alive while these frames are; not sent to other processes).
        self._keep: Any = None
        # Where a packed dataset's frames come from: (``<pack>: <folder>``,
        # the run's folder within the scenario's, "" for a scenario's own).
        self._packed: Optional[Tuple[str, str]] = None
        # Where in the pack those frames lie, as its reader found them:
        # (the pack's identity then, [(name within the folder, offset,
        # size)]), so that a process they are sent to reads them straight
        # from there instead of reading the pack's headers up to them.
        self._located: Optional[Tuple[Tuple[int, ...], List[Tuple[str, int, int]]]] = None

    def __getstate__(self) -> Dict[str, Any]:
        # Frames unpacked into a temporary folder go to another process (a
        # DataLoader worker's scenario to the main process) without it:
        # the sender removes it once its own copy goes, so the receiver
        # unpacks them again from the pack when first read (it read a
        # removed folder: "cannot read /tmp/causalcity-scenario-...").
        state = dict(self.__dict__)
        state["_keep"] = None
        if self._packed is not None:
            state["_folder"] = None
        return state

    @property
    def folder(self) -> Path:
        """The folder the frames are read from (a packed dataset's: a
        temporary one, unpacked again from the pack in a process the frames
        were sent to)."""
        if self._folder is None and self._packed is not None:
            self._folder, self._keep = _unpack_frames(*self._packed, self.kind, self._located)
        return self._folder

    @property
    def shape(self) -> Tuple[int, ...]:
        base = (self._frames, self._height, self._width)
        return base + (3,) if self.kind == "rgb" else base

    @property
    def ndim(self) -> int:
        return len(self.shape)

    def __len__(self) -> int:
        return self._frames

    def _read(self, start: int, end: int) -> _np.ndarray:
        try:
            return self._read_from(self.folder, start, end)
        except InputError as e:
            if self._packed is None or self._keep is None:
                raise
            # named by its pack and member, not the temporary folder
            raise InputError(str(e).replace(self._keep.scratch.name, self._packed[0])) from None

    def _read_from(self, folder: Path, start: int, end: int) -> _np.ndarray:
        raw = _native.read_frames(_os.fspath(folder), self.kind, self._frames, start, end, self._width, self._height)
        out = _np.asarray(raw)
        if self.kind == "mask" and self._cars is not None and out.size and int(out.max()) > self._cars:
            frame = start + int(_np.argmax(out.reshape(len(out), -1).max(axis=1) > self._cars))
            raise InputError(
                f"{_os.fspath(folder)}: mask frame {frame} holds the value {int(out[frame - start].max())}, and "
                f"the scenario has {self._cars} cars: a mask holds 0 (no car) or a car's mask_id, 1 to {self._cars}"
            )
        return out

    def __getitem__(self, index: Any) -> _np.ndarray:
        index = index if isinstance(index, tuple) else (index,)
        if not index or any(i is Ellipsis or i is None for i in index):
            return _np.asarray(self)[index]  # the general case: decode every frame
        first, rest = index[0], index[1:]
        if isinstance(first, (int, _np.integer)) and not isinstance(first, bool):
            i = int(first) + (self._frames if first < 0 else 0)
            if not 0 <= i < self._frames:
                raise IndexError(f"frame {int(first)} is outside the scenario's {self._frames} frames")
            # (as the frame's position in one frame: numpy pairs an int
            # with the other index arrays, which out[rest] would not)
            return self._read(i, i + 1)[(0,) + rest]
        if isinstance(first, (bool, _np.bool_)) or (_np.ndim(first) > 1 and _np.asarray(first).dtype == bool):
            # numpy's new axis (or none), or a mask over frames and rows: as an array gives
            return _np.asarray(self)[index]
        chosen = _np.arange(self._frames)[first]
        if chosen.ndim == 0:
            return self._read(int(chosen), int(chosen) + 1)[(0,) + rest]
        # Only the frames chosen are decoded, each once (sorted); the index
        # then picks from them as it would from every frame.
        frames = _np.unique(chosen)
        if len(frames) == 0:
            decoded = self._read(0, 0)
        elif frames[-1] - frames[0] == len(frames) - 1:
            decoded = self._read(int(frames[0]), int(frames[-1]) + 1)
        else:
            decoded = _np.stack([self._read(int(i), int(i) + 1)[0] for i in frames])
        if isinstance(first, slice):  # basic indexing: the other indices apply to every frame taken
            return decoded[_np.searchsorted(frames, chosen)][(slice(None),) + rest]
        # An index array: numpy pairs it with the other index arrays.
        return decoded[(_np.searchsorted(frames, chosen),) + rest]

    def __iter__(self) -> Iterator[_np.ndarray]:
        for i in range(self._frames):
            yield self._read(i, i + 1)[0]

    def __array__(self, dtype: Any = None, copy: Any = None) -> _np.ndarray:
        out = self._read(0, self._frames)
        return out if dtype is None else out.astype(dtype)

    def __repr__(self) -> str:
        return f"Frames({self.kind!r}, shape={self.shape}, folder={_os.fspath(self.folder)!r})"


def load(folder: PathLike, images: bool = True) -> "Scenario":
    """The scenario in ``folder``, as ``gen`` (or ``counterfactual``, for its
    ``factual`` and ``counterfactual`` folders) wrote it: the same
    :class:`~causalcity.Scenario` that :func:`~causalcity.simulate` gives for
    its key (``key`` is None for the runs of a scenario file or a
    counterfactual pair, as there), with ``rgb`` and ``mask`` as :class:`Frames` that decode the
    PNGs when used (None without images, or with ``images=False``).

    Raises ``FileNotFoundError`` for a folder without ``scenario.json``,
    and :class:`~causalcity.InputError` for a file that is not as ``gen``
    writes it (the message names the file, line and field)."""
    from . import Key, _scenario

    path = Path(folder)
    record = path / "scenario.json"
    if record.exists() and not record.is_file():
        kind = "a folder" if record.is_dir() else "not a regular file (a pipe or a device)"
        raise InputError(f"{_os.fspath(record)}: {kind}, so it is not read; a scenario folder holds gen's scenario.json")
    if not record.is_file():
        raise FileNotFoundError(
            f"{_os.fspath(path)}: no scenario.json; a scenario folder is one that gen wrote, "
            "e.g. data/ci-city/cars08_edges50/test/00000 (open_dataset reads a whole dataset)"
        )
    raw = _native.read_scenario(_os.fspath(path))
    meta = _json.loads(raw["scenario_json"])
    # A dataset's scenario has a key (its folder is group/split/name); the
    # runs of a scenario file or of a counterfactual pair have none, as in
    # simulate and counterfactual.
    key = None
    place = tuple(path.resolve().parts[-3:])
    if all(k in meta for k in ("group", "split", "index", "name")) and place == (meta["group"], meta["split"], meta["name"]):
        key = Key(meta["group"], meta["split"], _record_whole(record, meta, "index", 0))
    scenario = _scenario(raw, key)
    if images and (path / "rgb").is_dir():
        camera = meta.get("camera")
        if not isinstance(camera, dict):
            raise InputError(f"{_os.fspath(record)}: field camera: {camera!r} is not allowed: the camera's object "
                             "(width, height, ...), as gen writes it beside rgb/")  # fmt: skip
        width = _record_whole(record, camera, "width", 1, "camera.")
        height = _record_whole(record, camera, "height", 1, "camera.")
        frames = _record_whole(record, meta, "frames", 1)
        object.__setattr__(scenario, "rgb", Frames(path, "rgb", frames, width, height))
        object.__setattr__(scenario, "mask", Frames(path, "mask", frames, width, height, cars=scenario.cars))
    return scenario


_MAX_WHOLE = 1 << 31
"""The largest index, frame count or image side a scenario.json may give
(a spec's are far smaller)."""


def _record_whole(record: Path, values: Dict[str, Any], field: str, minimum: int, prefix: str = "") -> int:
    """``values[field]`` of the scenario.json at ``record``: a whole number
    from ``minimum``; :class:`~causalcity.InputError` naming the file,
    field and value otherwise (a width of -256 gave frames of a negative
    shape, ``true`` a width of 1, a missing one a KeyError)."""
    value = values.get(field)
    if isinstance(value, bool) or not isinstance(value, int) or not minimum <= value <= _MAX_WHOLE:
        raise InputError(f"{_os.fspath(record)}: field {prefix}{field}: {value!r} is not allowed: a whole number, "
                         f"{minimum} or more")  # fmt: skip
    return value


def _read_record(path: Path, what: str) -> Dict[str, Any]:
    """``manifest.json`` or ``sweep.json`` as gen or a sweep writes it: an
    object with a ``spec`` object, and ``scenarios_per_tar`` and ``limit``
    whole numbers above 0 where given; :class:`~causalcity.InputError`
    naming the file and field otherwise."""
    try:
        record = _json.loads(path.read_text())
    except ValueError as e:
        raise InputError(f"{_os.fspath(path)}: not JSON: {e}") from None
    if not isinstance(record, dict):
        raise InputError(f"{_os.fspath(path)}: expected an object, found {type(record).__name__}: not {what}")
    if not isinstance(record.get("spec"), dict):
        raise InputError(f"{_os.fspath(path)}: field spec: missing or not an object: not {what}")
    for field in ("scenarios_per_tar", "limit"):
        value = record.get(field)
        if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 1):
            raise InputError(f"{_os.fspath(path)}: field {field}: {value!r} is not allowed: a whole number above 0, or absent")
    # Flags read by truthiness took "false" for true.
    for field in ("images", "complete"):
        value = record.get(field)
        if value is not None and not isinstance(value, bool):
            raise InputError(f"{_os.fspath(path)}: field {field}: {value!r} is not allowed: true or false")
    return record


def _check_spec_hash(spec: Any, record: Dict[str, Any], path: Path, who: str, what: str) -> None:
    """Refuses a record (at ``path``) whose spec no longer hashes to the
    ``spec_sha256`` it recorded (records from before it was kept lack it):
    edited after ``who``, it describes other ``what`` than the ones on disk."""
    recorded = record.get("spec_sha256")
    if recorded is not None and recorded != spec._native.sha256:
        raise InputError(
            f"{_os.fspath(path)}: its spec does not hash to its spec_sha256 ({str(recorded)[:12]} recorded, "
            f"{spec._native.sha256[:12]} now): it was edited after {who}, so it no longer describes the {what} on "
            "disk; restore it (or regenerate)"
        )


def _as_key(key: Any) -> "Key":
    """``key`` (a :class:`~causalcity.Key` or a ``(group, split, index)``
    tuple) as a Key; TypeError naming what it is otherwise."""
    from . import Key

    parts = tuple(key) if isinstance(key, (tuple, list)) else None
    ok = (
        parts is not None
        and len(parts) == 3
        and isinstance(parts[0], str)
        and isinstance(parts[1], str)
        and isinstance(parts[2], (int, _np.integer))
        and not isinstance(parts[2], (bool, _np.bool_))
    )
    if not ok:
        raise TypeError(
            f"{key!r} is not a scenario key: give a causalcity.Key or a (group, split, index) tuple, "
            "e.g. ('cars08_edges50', 'test', 0), or an int position"
        )
    return Key(parts[0], parts[1], int(parts[2]))


def _check_split(split: Optional[str]) -> None:
    if split is not None and split not in ("train", "val", "test"):
        raise InputError(f"split {split!r} is not one of train, val, test")


class _Packed:
    """What the readers of a packed output (``gen`` or ``counterfactual
    --sweep`` with ``--format tar``) share: which tar file holds a key, and
    a key's folder unpacked alone."""

    root: Path
    scenarios_per_tar: Optional[int]

    def _index_packs(self, keys: List["Key"]) -> None:
        """Notes each split's size (from every key of the spec, ``keys``),
        which names the packs."""
        self._members: Dict[str, Dict[str, List[Any]]] = {}
        self._pack_identity: Dict[str, Tuple[int, ...]] = {}
        self._split_sizes: Dict[Tuple[str, str], int] = {}
        for k in keys:
            self._split_sizes[(k.group, k.split)] = self._split_sizes.get((k.group, k.split), 0) + 1

    def pack_of(self, key: "Key") -> str:
        """A packed output's tar file that holds ``key``'s folder, relative
        to the root (``cars08_edges50/train/00000-00063.tar``)."""
        per = self.scenarios_per_tar
        if not per:
            raise InputError(f"{_os.fspath(self.root)} is not packed: its scenarios are folders")
        first = key.index // per * per
        last = min(first + per, self._split_sizes[(key.group, key.split)]) - 1
        return f"{key.group}/{key.split}/{first:05d}-{last:05d}.tar"

    def _unpack(self, key: "Key", images: bool, into: Optional[Path] = None) -> Any:
        """The folder of ``key`` (a scenario, or a counterfactual pair),
        unpacked alone from its pack into a new temporary folder (a
        ``TemporaryDirectory``, removed when dropped), or into the new folder
        ``into`` (kept: ``cleanup()`` removes it), frames only when
        ``images``. :class:`~causalcity.InputError` names a pack that breaks
        the packs' rule (:class:`_MemberOrder`: a member twice was taken
        last copy winning; a pack cut short as one without its last
        scenarios)."""
        import tempfile

        pack = self.pack_of(key)
        path = self.root / pack
        with _open_pack(path) as tar:
            if pack not in self._members:
                # Reading the headers seeks past the members' bytes.
                order = _MemberOrder(path, f"{key.group}/{key.split}")
                by_folder: Dict[str, List[Any]] = {}
                with _naming_damage(path):
                    for member in tar:
                        if not member.isdir():
                            folder, _, _ = order.member(member)
                            by_folder.setdefault(folder, []).append(member)
                order.check_whole()
                self._members[pack] = by_folder
                self._pack_identity[pack] = _identity(_os.fstat(tar.fileobj.fileno()))
            members = self._members[pack].get(key.folder)
            if members is None:
                raise InputError(f"{_os.fspath(path)}: holds no member of {key.folder}: the pack is damaged")
            scratch = tempfile.TemporaryDirectory(prefix="causalcity-scenario-") if into is None else _Folder(into)
            with _naming_damage(path):
                for member in members:
                    _, name = _member_parts(path, member)
                    if not images and name.endswith(".png"):
                        continue
                    target = Path(scratch.name) / name
                    data = tar.extractfile(member)
                    try:
                        target.parent.mkdir(parents=True, exist_ok=True)
                        target.write_bytes(data.read() if data is not None else b"")
                    except (FileExistsError, NotADirectoryError, IsADirectoryError):
                        scratch.cleanup()
                        raise InputError(f"{_os.fspath(path)}: {member.name} is both a file and a folder of the "
                                         "pack's members: the pack is damaged") from None  # fmt: skip
        return scratch

    def _located(self, key: "Key") -> Optional[Tuple[Tuple[int, ...], List[Tuple[str, int, int]]]]:
        """Where ``key``'s members lie in its pack, as :meth:`_unpack` read
        them: (the pack's identity then, [(name within the folder, offset
        of the bytes, size)]); None when not read yet."""
        pack = self.pack_of(key)
        members = self._members.get(pack, {}).get(key.folder)
        # (A sparse member's bytes are not where its header says: unpacked.)
        if members is None or pack not in self._pack_identity or any(m.issparse() for m in members):
            return None
        path = self.root / pack
        return self._pack_identity[pack], [(_member_parts(path, m)[1], m.offset_data, m.size) for m in members]

    def _member_name(self, key: "Key") -> str:
        """How errors name ``key``'s folder in its pack: ``<pack>: <folder>``."""
        return f"{_os.fspath(self.root / self.pack_of(key))}: {key.folder}"

    def _member_source(self, key: "Key") -> str:
        """:meth:`_member_name` with the pack's absolute path: where frames
        sent to another process (another working directory) unpack from."""
        return f"{_os.path.abspath(self.root / self.pack_of(key))}: {key.folder}"

    def _read_unpacked(self, keys: List["Key"], read: Any, into: Optional[Path] = None) -> list:
        """``read(folder, key)`` of each of ``keys`` in turn, its folder
        unpacked without frames into a temporary folder removed once read
        (or, with ``into``, into ``into/<its folder>``, kept). An error that
        names the unpacked folder names its pack and member instead, as the
        command line does; it is raised as the same type."""
        results = []
        for key in keys:
            scratch = self._unpack(key, False, None if into is None else into / key.folder)
            try:
                results.append(read(Path(scratch.name), key))
            except (ValueError, RuntimeError, OSError) as e:
                raise _renamed(e, scratch.name, self._member_name(key)) from None
            finally:
                if into is None:
                    scratch.cleanup()
        return results

    def _as_members(self, scratch: Any, key: "Key") -> Any:
        """A context in which an :class:`~causalcity.InputError` naming a file
        of ``key``'s folder unpacked into ``scratch`` names it by its pack
        and member instead (as the command line does), and ``scratch`` is
        removed on any error."""
        import contextlib

        @contextlib.contextmanager
        def naming():
            try:
                yield
            except InputError as e:
                scratch.cleanup()
                raise InputError(str(e).replace(scratch.name, self._member_name(key))) from None
            except BaseException:
                scratch.cleanup()
                raise

        return naming()

    def __getstate__(self) -> Dict[str, Any]:
        state = dict(self.__dict__)
        state["_members"] = {}
        return state


class _Folder:
    """A folder made to unpack into, kept (as a ``TemporaryDirectory``'s
    ``name`` and ``cleanup()``, which removes it)."""

    def __init__(self, path: Path) -> None:
        path.mkdir(parents=True)
        self.name = _os.fspath(path)

    def cleanup(self) -> None:
        import shutil

        shutil.rmtree(self.name, ignore_errors=True)


def _renamed(error: BaseException, path: str, name: str) -> BaseException:
    """``error`` as the same type with ``path`` named ``name`` in its
    message (``error`` itself where it does not name ``path``, or where its
    type is not made from a message alone)."""
    message = str(error)
    if path not in message:
        return error
    try:
        if isinstance(error, OSError) and error.errno is not None:  # (its errno and file kept)
            filename = error.filename if error.filename is None else _os.fspath(error.filename).replace(path, name)
            return type(error)(error.errno, error.strerror, filename)
        return type(error)(message.replace(path, name))
    except Exception:  # (a UnicodeDecodeError is made from five values)
        return error


def _count_refused(root: Path, group: str, split: str, listed: Optional[int], found: int, what: str) -> Optional[str]:
    """Why ``found`` finished scenarios (``what`` they are) of ``group``'s
    ``split`` do not agree with the ``listed`` count of ``root``'s manifest,
    or None when they agree or it lists none."""
    if listed is None or found == listed:
        return None
    return (f"{root / group / split}: {found} {what}, but {root / 'manifest.json'} lists {listed}; "
            f"causalcity validate {root} tells what is missing")  # fmt: skip


def _refuse_linked(folder: Path) -> None:
    """Refuses a scenario (or pair) folder ``group/split/name`` read through
    a link at any of its three levels: a dataset holds its own scenarios,
    and one read through a link may be anyone's (as causalcity's readers
    and validate have it)."""
    linked = next((p for p in (folder.parent.parent, folder.parent, folder) if p.is_symlink()), None)
    if linked is not None:
        raise InputError(
            f"{_os.fspath(linked)} is a symbolic link (to {_os.readlink(linked)}): a dataset's scenarios are "
            "read from its own folders, never through a link; causalcity validate names what else is wrong"
        )


def _check_is(scenario: "Scenario", key: "Key", record: Path, seed: Any) -> None:
    """Refuses a scenario whose scenario.json (at ``record``) names another
    key than the one it was read for, or another spec seed than the
    dataset's (``seed``): a folder linked to another scenario's, an edited
    index, pack members renamed, or a scenario copied in from another
    dataset at the same key were handed back as ``key`` with the other
    scenario's arrays."""
    meta = scenario.metadata
    found = (meta.get("group"), meta.get("split"), meta.get("index"))
    if found != (key.group, key.split, key.index):
        raise InputError(
            f"{_os.fspath(record)}: it is scenario {found[0]}/{found[1]} index {found[2]}, not {key.folder} "
            f"(index {key.index}) where it was read: a linked or renamed folder, or an edited scenario.json; "
            "causalcity validate names what else is wrong"
        )
    if meta.get("seed") != seed:
        raise InputError(
            f"{_os.fspath(record)}: its seed is {meta.get('seed')!r}, but the dataset's spec has seed {seed!r}: a "
            "scenario of another dataset, copied or moved in, or an edited scenario.json; causalcity validate names "
            "what else is wrong"
        )


def _keep_with_frames(scratch: Any, scenarios: List["Scenario"], member: str, located: Any = None) -> None:
    """Hands the temporary folder ``scenarios`` were read from (unpacked
    from ``member``: ``<pack>: <folder>``, its members where ``located``
    says: :meth:`_Packed._located`) to their frames, which read from it
    while they live; without frames it goes now."""
    kept, holder = False, _Kept(scratch)
    for scenario in scenarios:
        for frames in (scenario.rgb, scenario.mask):
            if isinstance(frames, Frames):
                inside = Path(frames.folder).relative_to(scratch.name).as_posix().strip(".")
                frames._keep, frames._packed, kept = holder, (member, inside), True
                if located is not None:
                    prefix = _frames_prefix(inside, frames.kind)
                    frames._located = (located[0], [m for m in located[1] if m[0].startswith(prefix)])
    if not kept:
        scratch.cleanup()


def _frames_prefix(inside: str, kind: str) -> str:
    """Where the ``kind`` frames lie within a scenario's folder in its pack:
    under its run ``inside`` ("" for the scenario's own)."""
    return f"{inside}/{kind}/" if inside else f"{kind}/"


def _identity(stat: Any) -> Tuple[int, ...]:
    """What tells a file from its replacement: a pack written again (gen
    writes one through a temporary file and a rename) is another file."""
    return (stat.st_dev, stat.st_ino, stat.st_size, stat.st_mtime_ns)


def _unpack_frames(member: str, inside: str, kind: str, located: Any = None) -> Tuple[Path, "_Kept"]:
    """The ``kind`` frames (``rgb`` or ``mask``) of ``member`` (``<pack>:
    <folder>``; of its run ``inside``, "" for the scenario's own), unpacked
    alone into a new temporary folder: (the folder they are in, its holder).
    Read straight from where ``located`` (:attr:`Frames._located`) says they
    lie while the pack is the file they were found in; else found by
    reading the pack's headers up to them (a pack of 64 scenarios: about
    a second for its last)."""
    import tempfile

    pack, folder = member.rsplit(": ", 1)
    path = Path(pack)
    prefix = _frames_prefix(inside, kind)
    scratch = tempfile.TemporaryDirectory(prefix="causalcity-scenario-")
    kept = _Kept(scratch)
    where = Path(scratch.name) / inside if inside else Path(scratch.name)
    if located is not None and _read_located(path, located, Path(scratch.name)):
        return where, kept
    with _open_pack(path) as tar, _naming_damage(path):
        seen = False
        for entry in tar:
            if entry.isdir():
                continue
            owner, name = _member_parts(path, entry)
            if seen and owner != folder:
                break  # a scenario's members run together (the packs' rule)
            seen = owner == folder
            if seen and name.startswith(prefix):
                target = Path(scratch.name) / name
                target.parent.mkdir(parents=True, exist_ok=True)
                data = tar.extractfile(entry)
                target.write_bytes(data.read() if data is not None else b"")
    return where, kept


def _read_located(path: Path, located: Any, into: Path) -> bool:
    """Writes each member ``located`` names (see :attr:`Frames._located`)
    under ``into`` from its bytes in the pack at ``path``; False (and
    nothing to rely on under ``into``) when the pack is no longer the file
    they were found in, or does not hold them whole."""
    import stat

    identity, members = located
    found = []
    try:
        # (Opening a pipe put at the pack's name would block: unpacked, the
        # pack is refused by name.)
        if not stat.S_ISREG(_os.stat(path).st_mode):
            return False
        with open(path, "rb") as f:
            if _identity(_os.fstat(f.fileno())) != tuple(identity):
                return False
            for name, offset, size in members:
                f.seek(offset)
                found.append((name, f.read(size)))
    except OSError:
        return False
    if not members or any(len(data) != size for (_, data), (_, _, size) in zip(found, members)):
        return False
    for name, data in found:
        target = into / name
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(data)
    return True


class _Kept:
    """A temporary folder that frames read from, removed once the last of
    them goes. Removed by a finaliser that holds the folder's
    ``TemporaryDirectory``, so that the directory's own finaliser, which
    warns "Implicitly cleaning up" (under ``-W always`` and pytest), never
    runs first: it did when both were collected in one reference cycle
    (frames held by an exception's traceback)."""

    def __init__(self, scratch: Any) -> None:
        import weakref

        self.scratch = scratch
        weakref.finalize(self, scratch.cleanup)


class _ReadHold:
    """A reader's hold on a dataset: a shared lock on its folder, as the
    command line's readers take it. ``gen --force`` takes that lock
    exclusively before it removes anything, so it refuses to remove a
    dataset held open here, and a dataset being removed is never opened.
    Nothing is written; the lock goes with :meth:`close` (in the process
    that took it, even while forked DataLoader workers still hold the
    open file) or with the process."""

    def __init__(self, root: Path) -> None:
        self._fd: Optional[int] = None
        self._pid = _os.getpid()
        try:
            import fcntl
        except ImportError:  # no POSIX locks here: read unheld
            return
        # Kept for close: a hold collected as the interpreter shuts down
        # can import nothing (a DataLoader script printed a traceback).
        self._fcntl = fcntl
        try:
            fd = _os.open(root, _os.O_RDONLY | getattr(_os, "O_DIRECTORY", 0) | getattr(_os, "O_NONBLOCK", 0))
        except OSError:  # the dataset's reader names what is wrong
            return
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            _os.close(fd)
            raise InputError(
                f"{_os.fspath(root)} is being removed by gen --force: wait for it to finish, then open the dataset it "
                "writes there"
            ) from None
        except OSError:  # a filesystem without locks: read unheld
            _os.close(fd)
            return
        self._fd = fd

    def close(self) -> None:
        if self._fd is None:
            return
        fd, self._fd = self._fd, None
        # Only the process that took the lock lets it go: a forked worker
        # shares the open file, and its unlock would be its parent's.
        if _os.getpid() == self._pid:
            try:
                self._fcntl.flock(fd, self._fcntl.LOCK_UN)
            except OSError:
                pass
        try:
            _os.close(fd)
        except OSError:
            pass

    def __del__(self) -> None:
        self.close()


class Dataset(_Packed):
    """A dataset folder ``gen`` wrote, opened for reading: its manifest, the
    spec it was made from (:attr:`spec`, a :class:`~causalcity.Spec`), its
    keys and its scenarios, read lazily one at a time. ``dataset[key]``,
    ``dataset[i]`` (the i-th of :meth:`keys`) and iteration give
    :class:`~causalcity.Scenario` objects, so that with ``split`` it is a
    map-style PyTorch dataset: ``DataLoader(open_dataset(root, "train"),
    collate_fn=causalcity.collate)``.

    While it is open, ``gen --force`` refuses to remove the dataset (as
    while any command reads it): :meth:`close` it, or use it in a ``with``
    block, to let go sooner than the object goes."""

    def __init__(self, root: PathLike, split: Optional[str] = None, images: bool = True) -> None:
        from . import _dataset_spec

        self.root = Path(root)
        manifest = self.root / "manifest.json"
        if not manifest.is_file():
            sweep = " (it is a counterfactual sweep: use causalcity.open_sweep)" if (self.root / "sweep.json").is_file() else ""
            raise FileNotFoundError(f"{_os.fspath(self.root)}: no manifest.json, so not a dataset gen wrote{sweep}")
        self._hold: Optional[_ReadHold] = _ReadHold(self.root)
        self.manifest: Dict[str, Any] = _read_record(manifest, "a manifest gen wrote")
        if not self.manifest.get("complete", False):
            _warnings.warn(
                f"{_os.fspath(self.root)} is unfinished (manifest.json's complete is false): "
                "only the scenarios written so far are listed",
                stacklevel=2,
            )
        self.spec = _dataset_spec(self.manifest["spec"], self.root, manifest)
        _check_spec_hash(self.spec, self.manifest, manifest, "gen wrote the dataset", "scenarios")
        self.images = bool(self.manifest.get("images", False))
        self.split = split
        """The split it holds (all when None)."""
        self.scenarios_per_tar: Optional[int] = self.manifest.get("scenarios_per_tar")
        """``gen --format tar``: scenarios per tar file (None: a folder per scenario)."""
        self._images = images
        # A packed dataset's scenario is unpacked, when read, into a
        # temporary folder of its own, which lives as long as its frames do.
        # Each pack's members are listed once per process (not pickled, so a
        # Dataset goes to DataLoader workers as a plain object).
        self._index_packs(self.spec.keys(None, self.manifest.get("limit")) if self.scenarios_per_tar else [])
        # Listed once: a dataset gen finished does not change under its readers.
        keys = self.spec.keys(split, self.manifest.get("limit"))
        if self.scenarios_per_tar:
            self._keys = [k for k in keys if (self.root / self.pack_of(k)).is_file()]
        else:
            self._keys = [k for k in keys if (self.root / k.folder / "scenario.json").is_file()]
        self._key_set = set(self._keys)
        missing = len(keys) - len(self._keys)
        if self.manifest.get("complete", False) and missing > 0:
            first = next(k for k in keys if k not in self._key_set)
            _warnings.warn(
                f"{_os.fspath(self.root)}: {missing} of the {len(keys)} scenarios its manifest lists{' in ' + split if split else ''} are not on disk "
                f"(first: {first.folder}), though it says it is complete: they are left out; `causalcity validate` "
                "checks it",
                stacklevel=2,
            )

    def close(self) -> None:
        """Lets go of the dataset, so that ``gen --force`` may remove it;
        reading on is then at the reader's own risk."""
        if self._hold is not None:
            self._hold.close()
            self._hold = None

    def __enter__(self) -> "Dataset":
        return self

    def __exit__(self, *_: Any) -> None:
        self.close()

    def __getstate__(self) -> Dict[str, Any]:
        # A copy in a DataLoader worker reads under its parent's hold.
        state = super().__getstate__()
        state["_hold"] = None
        return state

    def keys(self, split: Optional[str] = None) -> List["Key"]:
        """The keys of the scenarios on disk, in ``gen``'s order (groups,
        then train, val, test, then index); ``split`` keeps one split. A
        sharded or unfinished dataset lists only the folders it has."""
        _check_split(split)
        return [k for k in self._keys if split is None or k.split == split]

    def load(self, key: "Key", images: Optional[bool] = None) -> "Scenario":
        """The scenario of ``key`` (a :class:`~causalcity.Key` or a
        ``(group, split, index)`` tuple), as :func:`load` reads it."""
        from . import _flag

        key = _as_key(key)
        # Only this dataset's keys (of its split, when opened with one): a
        # group or split that is not one, or a name with ../, is refused.
        if key not in self._key_set:
            held = f"'s {self.split} split" if self.split else ""
            raise KeyError(f"{tuple(key)} is not in {_os.fspath(self.root)}{held}: no such scenario on disk")
        images = self._images if images is None else _flag("images", images)
        if not self.scenarios_per_tar:
            folder = self.root / key.folder
            _refuse_linked(folder)
            if not (folder / "scenario.json").is_file():
                # (listed: the dataset's own key, so its folder is damaged)
                raise InputError(f"{_os.fspath(folder / 'scenario.json')}: missing, and manifest.json lists "
                                 f"{tuple(key)}: the dataset is damaged (causalcity validate names what else is)")
            self._require_frames(folder, images)
            scenario = load(folder, images=images)
            _check_is(scenario, key, folder / "scenario.json", self.spec.seed)
            return scenario
        scratch = self._unpack(key, images)
        if not (Path(scratch.name) / "scenario.json").is_file():
            scratch.cleanup()
            raise InputError(f"{self._member_name(key)}/scenario.json: missing from its pack, and manifest.json "
                             f"lists {tuple(key)}: the pack is damaged (causalcity validate names what else is)")
        with self._as_members(scratch, key):
            self._require_frames(Path(scratch.name), images, self.pack_of(key))
            scenario = load(Path(scratch.name), images=images)
            _check_is(scenario, key, Path(scratch.name) / "scenario.json", self.spec.seed)
        # Read from the temporary folder, the scenario has the key it has here.
        object.__setattr__(scenario, "key", key)
        _keep_with_frames(scratch, [scenario], self._member_source(key), self._located(key))
        return scenario

    def _require_frames(self, folder: Path, images: bool, pack: Optional[str] = None) -> None:
        """Frames asked for from a dataset with images: a scenario without
        its ``rgb/`` or ``mask/`` is damaged, not a scenario without images."""
        if not (images and self.images):
            return
        for kind in ("rgb", "mask"):
            if not (folder / kind).is_dir():
                where = f"its pack {pack}" if pack else _os.fspath(folder)
                raise InputError(
                    f"{where}: no {kind}/ though the dataset has images (manifest.json images: true): the scenario "
                    "is damaged (causalcity validate names what is missing); images=False reads it without frames"
                )

    def scenarios(self, split: Optional[str] = None, images: Optional[bool] = None) -> Iterator["Scenario"]:
        """Every scenario of ``split`` (or all), read one at a time."""
        _check_split(split)
        for key in self.keys(split):
            yield self.load(key, images=images)

    def __getitem__(self, key: Any) -> "Scenario":
        if isinstance(key, (int, _np.integer)) and not isinstance(key, (bool, _np.bool_)):
            if not -len(self._keys) <= int(key) < len(self._keys):
                held = f" ({self.split} split)" if self.split else ""
                raise IndexError(
                    f"position {int(key)} is outside the {len(self._keys)} scenarios of {_os.fspath(self.root)}{held}"
                )
            return self.load(self._keys[int(key)])
        return self.load(key)

    def __iter__(self) -> Iterator["Scenario"]:
        return self.scenarios()

    def __len__(self) -> int:
        return len(self.keys())

    def __repr__(self) -> str:
        return f"Dataset({_os.fspath(self.root)!r}, spec={self.spec.name!r}, scenarios={len(self)})"


def _member_parts(path: Path, member: Any) -> Tuple[str, str]:
    """A pack member's scenario folder (``group/split/scenario``) and its name
    within it (a name may start ``./``, as ``tar -cf pack.tar ./group``
    writes); :class:`~causalcity.InputError` for a member that is not a
    scenario's plain file."""
    name = member.name[2:] if member.name.startswith("./") else member.name
    parts = name.split("/")
    if not member.isfile() or len(parts) < 4 or any(p in ("", ".", "..") for p in parts):
        raise InputError(f"{_os.fspath(path)}: {member.name!r} is not a scenario's file (a pack holds those only)")
    return "/".join(parts[:3]), "/".join(parts[3:])


class _MemberOrder:
    """The rule every reader holds a pack's members to, checked as they
    come, as the command line's readers do: each belongs to one of the
    scenarios the pack's name gives (``<first>-<last>.tar`` of one group
    and split), no member comes twice, a scenario's members run together,
    and (:meth:`check_whole`) every scenario has some."""

    def __init__(self, path: Path, group_split: Optional[str]) -> None:
        self.path = path
        found = re.fullmatch(r"([0-9]{5,})-([0-9]{5,})\.tar", path.name)
        self.range = (int(found[1]), int(found[2])) if found and int(found[1]) <= int(found[2]) else None
        # Unknown for a pack read alone: its first member's then.
        self.group_split = group_split
        self.found: set = set()
        self.current: Optional[str] = None
        self.names: set = set()

    def member(self, member: Any) -> Tuple[str, str, bool]:
        """The member's scenario folder, its name within it, and whether it
        is that scenario's first member."""
        where = _os.fspath(self.path)
        folder, name = _member_parts(self.path, member)
        group_split, _, index = folder.rpartition("/")
        if self.group_split is None:
            self.group_split = group_split
        # A scenario folder is its index in 5 or more ASCII digits (00012), as gen names it.
        named = re.fullmatch(r"[0-9]{5,}", index) is not None and index == f"{int(index):05d}"
        in_range = named and (self.range is None or self.range[0] <= int(index) <= self.range[1])
        if group_split != self.group_split or not in_range:
            raise InputError(f"{where}: {member.name} belongs to none of its scenarios (by the pack's name)")
        first = folder != self.current
        if first:
            if int(index) in self.found:
                raise InputError(f"{where}: {member.name}: its scenario's members do not run together")
            self.found.add(int(index))
            self.current, self.names = folder, set()
        if name in self.names:
            raise InputError(f"{where}: {member.name} is in it twice")
        self.names.add(name)
        return folder, name, first

    def check_whole(self) -> None:
        """Refuses a pack without members of a scenario its name gives."""
        if self.range is None:
            return
        for index in range(self.range[0], self.range[1] + 1):
            if index not in self.found:
                scenario = f"{self.group_split}/{index:05d}" if self.group_split else f"scenario {index:05d}"
                raise InputError(
                    f"{_os.fspath(self.path)}: holds no member of {scenario}, which its name says it holds: the pack "
                    "is damaged"
                )


def _open_pack(path: Path) -> Any:
    """The tar file at ``path``, opened for reading after checking that it
    ends as a tar ends (two empty 512-byte blocks after whole blocks: one
    cut short at a member's header read as one with fewer members);
    :class:`~causalcity.InputError` naming it otherwise."""
    import tarfile

    import stat

    where = _os.fspath(path)
    try:
        if not stat.S_ISREG(_os.stat(path).st_mode):  # a pipe blocked open() until its writer came
            raise InputError(f"{where}: not a regular file (a folder, a pipe or a device), so it is not read as a pack")
        with open(path, "rb") as f:
            size = f.seek(0, 2)
            end = b""
            if size >= 1024 and size % 512 == 0:
                f.seek(size - 1024)
                end = f.read(1024)
    except OSError as e:
        raise InputError(f"{where}: cannot read it: {e}") from None
    if end != bytes(1024):
        raise InputError(f"{where}: cut short or not a tar ({size} bytes; a tar ends in two empty 512-byte "
                         "blocks): the pack is damaged")  # fmt: skip
    with _naming_damage(path):
        return tarfile.open(where, "r:")


class _naming_damage:
    """Turns what :mod:`tarfile` raises on a damaged pack (a ``ReadError``,
    an overflowing size field) into an :class:`~causalcity.InputError`
    naming the pack."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def __enter__(self) -> None:
        return None

    def __exit__(self, kind: Any, error: Any, trace: Any) -> bool:
        import tarfile

        # (A size field past any offset raises ValueError on the seek.)
        if kind is not None and issubclass(kind, InputError):
            return False  # already says what is wrong (a ValueError too)
        if kind is not None and issubclass(kind, (tarfile.TarError, OverflowError, EOFError, ValueError)):
            raise InputError(f"{_os.fspath(self.path)}: not a whole tar ({error}): the pack is damaged") from None
        return False


def read_tar(path: PathLike) -> Iterator[Tuple[str, Dict[str, bytes]]]:
    """The scenarios of one tar file of a packed dataset (``gen --format
    tar``), streamed in order, one at a time: each as its folder relative
    to the dataset (``cars08_edges50/train/00012``) and its files by name
    within it (``"poses.csv"``, ``"rgb/0000.png"``, ...), holding the bytes
    the folder layout holds. For streaming pipelines (a PyTorch
    ``IterableDataset`` over the tar files); :func:`open_dataset` reads a
    packed dataset as :class:`~causalcity.Scenario` objects.

    Raises :class:`~causalcity.InputError` for a member that is not a plain
    file inside the dataset, and for a pack that breaks the packs' rule: a
    member of none of the scenarios its name (``<first>-<last>.tar``) gives,
    a member twice, a scenario's members apart, a scenario with none, or a
    pack cut short. A scenario is yielded once all of it has been read."""
    path = Path(path)
    order = _MemberOrder(path, None)
    current: Optional[str] = None
    files: Dict[str, bytes] = {}
    with _open_pack(path) as tar, _naming_damage(path):
        for member in tar:
            if member.isdir():  # `tar -cf` of scenario folders lists them too
                continue
            folder, name, first = order.member(member)
            if first:
                if current is not None:
                    yield current, files
                current, files = folder, {}
            data = tar.extractfile(member)
            files[name] = data.read() if data is not None else b""
    order.check_whole()
    if current is not None:
        yield current, files


def open_dataset(root: PathLike, split: Optional[str] = None, images: bool = True) -> Dataset:
    """The dataset ``gen`` wrote in ``root``, opened for reading (see
    :class:`Dataset`); ``split`` keeps one split, ``images=False`` reads
    no frames."""
    from . import _flag

    _check_split(split)
    return Dataset(root, split, _flag("images", images))



def _read_divergence(path: Path, frames: int, cars: int) -> _np.ndarray:
    """A pair's ``divergence.csv`` (``frame,t,car,distance_m,distance_px``, a
    row per frame and car in that order) as ``[frames, cars]`` metres, once
    the pair rule (``_native.check_pair``) has checked every row."""
    rows = path.read_text().splitlines()[1:]
    return _np.array([float(row.split(",")[3]) for row in rows]).reshape(frames, cars)


def check_sweep_kinds(record: Dict[str, Any], path: Path) -> None:
    """Refuses a sweep record (read from ``path``) whose ``kinds`` are not a
    non-empty list of names: every sweep records the ``--kinds`` it drew its
    pairs' interventions from, and they decide which one each pair had."""
    kinds = record.get("kinds")
    if not (isinstance(kinds, list) and kinds and all(isinstance(k, str) for k in kinds)):
        raise InputError(
            f"{_os.fspath(path)}: kinds {kinds!r} is not allowed: every sweep records the --kinds it drew its "
            "interventions from, a list of names, so this record was edited (rerun its counterfactual --sweep "
            "command into a new --out)"
        )


class Sweep(_Packed):
    """A ``counterfactual --sweep`` output opened for reading: its record
    (``sweep.json``), the spec it was made from, and its pairs, each a
    :class:`~causalcity.Counterfactual` read from disk (the factual and
    counterfactual runs as :func:`load` reads them, ``divergence.csv``,
    ``summary.json`` with its ``intervention``), from pair folders or from
    the tar files of ``--format tar``."""

    def __init__(self, root: PathLike) -> None:
        from . import _dataset_spec

        self.root = Path(root)
        record = self.root / "sweep.json"
        if not record.is_file():
            dataset = " (it is a dataset: use causalcity.open_dataset)" if (self.root / "manifest.json").is_file() else ""
            raise FileNotFoundError(f"{_os.fspath(self.root)}: no sweep.json, so not a counterfactual --sweep output{dataset}")
        self.record: Dict[str, Any] = _read_record(record, "a counterfactual sweep's record")
        form = self.record.get("format")
        if not (isinstance(form, str) and form.startswith("causalcity-counterfactual-sweep/")):
            # (as every command refuses it)
            raise InputError(f"{_os.fspath(record)}: format {form!r} is not causalcity-counterfactual-sweep/1")
        if not self.record.get("complete", False):
            _warnings.warn(f"{_os.fspath(self.root)} is unfinished (sweep.json's complete is false)", stacklevel=2)
        check_sweep_kinds(self.record, record)
        self.spec = _dataset_spec(self.record["spec"], self.root, record)
        _check_spec_hash(self.spec, self.record, record, "the sweep was run", "pairs")
        self.scenarios_per_tar: Optional[int] = self.record.get("scenarios_per_tar")
        """``--format tar``: pairs per tar file (None: a folder per pair)."""
        self._index_packs(self.spec.keys(None, self.record.get("limit")) if self.scenarios_per_tar else [])
        self._all_keys = set(self.spec.keys(None, self.record.get("limit")))

    def keys(self, split: Optional[str] = None) -> List["Key"]:
        """The keys of the pairs on disk (in pair folders, or in the packs
        there), in the sweep's order."""
        _check_split(split)
        keys = self.spec.keys(split, self.record.get("limit"))
        if self.scenarios_per_tar:
            return [k for k in keys if (self.root / self.pack_of(k)).is_file()]
        # (A summary.json that is not a file is listed, and named when loaded.)
        return [k for k in keys if _os.path.lexists(self.root / k.folder / "summary.json")]

    def pair_folder(self, key: "Key", images: bool = True) -> Tuple[Path, Any]:
        """The folder of ``key``'s pair, and what keeps it: for a packed
        sweep, a new temporary folder the pair is unpacked into (frames only
        when ``images``; it goes when that ``TemporaryDirectory`` is
        dropped or cleaned up), else the pair's own folder and None."""
        key = _as_key(key)
        if key not in self._all_keys:
            raise KeyError(f"{tuple(key)} is not a pair of {_os.fspath(self.root)}")
        if not self.scenarios_per_tar:
            folder = self.root / key.folder
            _refuse_linked(folder)
            if not _os.path.lexists(folder / "summary.json"):
                raise KeyError(f"{tuple(key)} is not in {_os.fspath(self.root)} (no {key.folder}/summary.json)")
            return folder, None
        if not (self.root / self.pack_of(key)).is_file():
            raise InputError(f"{_os.fspath(self.root / self.pack_of(key))}: missing, and sweep.json lists "
                             f"{tuple(key)} in it: the sweep is damaged (causalcity validate names what else is)")
        scratch = self._unpack(key, images)
        if not (Path(scratch.name) / "summary.json").is_file():
            scratch.cleanup()
            raise InputError(f"{self._member_name(key)}/summary.json: missing from its pack, and sweep.json lists "
                             f"{tuple(key)}: the pack is damaged (causalcity validate names what else is)")
        return Path(scratch.name), scratch

    def load(self, key: "Key", images: bool = True) -> "Counterfactual":
        """The pair of ``key``: its two runs, divergence and summary."""
        from . import Counterfactual, _flag

        images = _flag("images", images)
        key = _as_key(key)
        folder, scratch = self.pair_folder(key, images)
        import contextlib

        with self._as_members(scratch, key) if scratch is not None else contextlib.nullcontext():
            # The pair's own runs and files, agreeing (a linked run or an
            # edited summary.json was handed back as this pair).
            _native.check_pair(_os.fspath(folder), key.group, key.split, key.index, self.spec._native,
                               self.record.get("kinds"))  # fmt: skip
            factual = load(folder / "factual", images=images)
            counterfactual = load(folder / "counterfactual", images=images)
            divergence = _read_divergence(folder / "divergence.csv", factual.frames, factual.cars)
            summary = _json.loads((folder / "summary.json").read_text())
        if scratch is not None:
            _keep_with_frames(scratch, [factual, counterfactual], self._member_source(key), self._located(key))
        return Counterfactual(name=summary["scenario"], factual=factual, counterfactual=counterfactual,
                              divergence=divergence, summary=summary)  # fmt: skip

    def __iter__(self) -> Iterator["Counterfactual"]:
        for key in self.keys():
            yield self.load(key)

    def __len__(self) -> int:
        return len(self.keys())

    def __repr__(self) -> str:
        return f"Sweep({_os.fspath(self.root)!r}, spec={self.spec.name!r}, pairs={len(self)})"


def open_sweep(root: PathLike) -> Sweep:
    """The ``counterfactual --sweep`` output in ``root``, opened for reading
    (see :class:`Sweep`)."""
    return Sweep(root)
