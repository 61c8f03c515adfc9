"""Reference classifiers for who-follows-whom on a dataset ``gen`` wrote: the
strongest learned method we could build that sees only the first frame (the
"leak" a benchmark must not have), and the same kind of method watching the
whole scene. Both score every ordered pair (a, b), "a leads b", with a
gradient-boosted classifier (scikit-learn's HistGradientBoostingClassifier)
trained per group on the train split; the decision threshold maximises F1 on
the val split (train when there is none), and test is scored. Needs the
``reference`` extra: ``pip install "./python[reference]"``.

From the command line::

    python -m causalcity.reference data/city [--method frame0 trajectory] [--graph designed] [--json]

Features, per ordered pair, from ``poses.csv`` (metres, radians, m/s):

- ``frame0``: where a stands in b's heading frame (ahead, sideways,
  distance, heading difference), whether they share a lane and how many cars
  stand between them in it, whether a is the nearest car ahead of b, whether
  a and b are first in their lanes, how many cars are behind b, both speeds,
  both positions and headings, and the number of cars;
- ``trajectory``: the same at the first, middle and last frames, plus how
  closely b drives where a drove before (the following score at lags up to
  30 s, as a follower may trail its leader by many seconds, and the share of
  b's positions within 1.5 m of a's earlier path), the distance between
  them over time (mean, least, largest), how often a is ahead of b in its
  lane, how far each drove, and how alike their heading changes are over
  time.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import warnings
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Dict, Iterator, List, Optional, Sequence, Tuple

import numpy as np

METHODS = ("frame0", "trajectory")
GRAPHS = {"designed": "edges", "causal": "causal_edges", "direct": "direct_edges"}
SPLITS = ("train", "val", "test")
# Two cars share a lane when one is within this far sideways of the other's
# heading line (half the default 3 m lane) and they face the same way.
SAME_LANE_M = 1.5
SAME_HEADING_RAD = 0.5
# Longest lag of the following score, seconds (8 s scored the default city's
# platoons' trajectory F1 0.01-0.04 lower).
MAX_LAG_S = 30.0
# pose log columns
_X, _Y, _YAW, _SPEED = 3, 4, 8, 11


@dataclass
class Scored:
    """One method's result on one group's test split."""

    group: str
    method: str
    graph: str
    pairs: int
    linked: int
    threshold: float
    threshold_from: str
    precision: float
    recall: float
    f1: float
    auroc: Optional[float]
    """None when test has only one class."""
    same_lane_pairs: int
    same_lane_auroc: Optional[float]


def _wrap(angle: np.ndarray) -> np.ndarray:
    return (angle + np.pi) % (2 * np.pi) - np.pi


def _poses(folder: Path, frames: int, cars: int) -> np.ndarray:
    """[frames, cars, 4]: x, y, yaw, speed."""
    try:
        with warnings.catch_warnings():  # an empty log is named below, not warned of
            warnings.simplefilter("ignore", UserWarning)
            table = np.loadtxt(folder / "poses.csv", delimiter=",", skiprows=1, ndmin=2)
    except ValueError as e:
        raise ValueError(f"{folder / 'poses.csv'}: not the pose log gen writes ({e})") from None
    if table.shape[0] != frames * cars:
        raise ValueError(f"{folder / 'poses.csv'}: {table.shape[0]} rows, expected {frames} x {cars}")
    return table[:, [_X, _Y, _YAW, _SPEED]].reshape(frames, cars, 4)


def _frame_features(p: np.ndarray) -> np.ndarray:
    """[cars, cars, F] pair features of one frame (p: [cars, 4]); [a, b] is
    'a leads b', seen from b."""
    n = p.shape[0]
    x, y, yaw, v = p[:, 0], p[:, 1], p[:, 2], p[:, 3]
    dx = x[:, None] - x[None, :]  # [a, b]: a - b
    dy = y[:, None] - y[None, :]
    c, s = np.cos(yaw)[None, :], np.sin(yaw)[None, :]
    ahead = dx * c + dy * s
    side = -dx * s + dy * c
    turn = _wrap(yaw[:, None] - yaw[None, :])
    lane = (np.abs(side) <= SAME_LANE_M) & (np.abs(turn) <= SAME_HEADING_RAD)
    np.fill_diagonal(lane, False)
    in_front = lane & (ahead > 0)  # a ahead of b in b's lane
    # cars c strictly between b and a in b's lane
    between = np.zeros((n, n))
    for b in range(n):
        front = np.where(in_front[:, b], ahead[:, b], np.inf)
        between[:, b] = (front[None, :] < front[:, None]).sum(axis=1)
    nearest = in_front & (between == 0)
    first = ~in_front.any(axis=0)  # nobody ahead of b (as b sees it)
    behind = (lane & (ahead < 0)).sum(axis=0)  # cars behind b in its lane
    gap_ahead = np.where(in_front, ahead, np.inf).min(axis=0)
    gap_ahead = np.where(np.isfinite(gap_ahead), gap_ahead, 100.0)
    full = lambda col: np.broadcast_to(col, (n, n))  # noqa: E731
    feats = [
        ahead,
        side,
        np.hypot(dx, dy),
        turn,
        lane,
        in_front,
        np.where(in_front, between, -1),
        nearest,
        full(first[:, None]),  # a first in its lane
        full(first[None, :]),  # b first
        full(behind[None, :]),
        full(gap_ahead[None, :]),
        full(v[:, None]),
        full(v[None, :]),
        full(v[:, None]) - full(v[None, :]),
        full(x[:, None]),
        full(y[:, None]),
        full(yaw[:, None]),
        full(x[None, :]),
        full(y[None, :]),
        full(yaw[None, :]),
        np.full((n, n), float(n)),
    ]
    return np.stack([np.asarray(f, dtype=np.float64) for f in feats], axis=-1)


def _trajectory_features(poses: np.ndarray, frame_interval: float) -> np.ndarray:
    """[cars, cars, F] whole-scene pair features (poses: [frames, cars, 4])."""
    frames, n, _ = poses.shape
    xy = poses[:, :, :2]
    parts = [_frame_features(poses[k]) for k in (0, frames // 2, frames - 1)]
    max_lag = max(1, int(round(MAX_LAG_S / frame_interval)))
    step = max(1, frames // 50)  # subsample frames for the path measures
    ts = np.arange(0, frames, step)
    # following score: mean over t of the least distance from b(t) to a(t - lag)
    follow = np.zeros((n, n))
    near_path = np.zeros((n, n))
    for t_index, t in enumerate(ts):
        lo = max(0, t - max_lag)
        past = xy[lo:t] if t > 0 else xy[:1]
        d = np.linalg.norm(past[:, :, None, :] - xy[t][None, None, :, :], axis=-1)  # [lag, a, b]
        follow += d.min(axis=0)
        # a's whole path so far (every frame up to t)
        so_far = xy[: t + 1]
        d_all = np.linalg.norm(so_far[:, :, None, :] - xy[t][None, None, :, :], axis=-1)
        near_path += d_all.min(axis=0) <= SAME_LANE_M
    follow /= len(ts)
    near_path /= len(ts)
    dist = np.linalg.norm(xy[:, :, None, :] - xy[:, None, :, :], axis=-1)  # [t, a, b]
    frame_lane = np.stack([_frame_features(poses[t])[..., 5] for t in ts])  # a ahead of b in lane
    moved = np.linalg.norm(np.diff(xy, axis=0), axis=-1).sum(axis=0)  # [cars]
    dyaw = _wrap(np.diff(poses[:, :, 2], axis=0))  # [t-1, cars]
    # heading changes of a, shifted by lags, against b's
    turn_match = np.full((n, n), 0.0)
    for lag in range(0, max_lag + 1, max(1, max_lag // 8)):
        if dyaw.shape[0] - lag < 2:
            break
        a, b = dyaw[: dyaw.shape[0] - lag], dyaw[lag:]
        num = (a[:, :, None] * b[:, None, :]).sum(axis=0)
        den = np.sqrt((a**2).sum(axis=0)[:, None] * (b**2).sum(axis=0)[None, :]) + 1e-9
        turn_match = np.maximum(turn_match, num / den)
    full = lambda col: np.broadcast_to(col, (n, n))  # noqa: E731
    extra = np.stack(
        [
            follow,
            near_path,
            dist.mean(axis=0),
            dist.min(axis=0),
            dist.max(axis=0),
            frame_lane.mean(axis=0),
            full(moved[:, None]),
            full(moved[None, :]),
            turn_match,
        ],
        axis=-1,
    )
    return np.concatenate(parts + [extra], axis=-1)


def scenario_pairs(folder: Path, method: str, graph: str = "designed") -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Features [pairs, F], labels [pairs] (a leads b in ``graph``) and a
    same-lane mask [pairs] (at frame 0, a ahead of b in b's lane) for every
    ordered pair of the scenario in ``folder``."""
    meta = _read_json(folder / "scenario.json")
    field = GRAPHS[graph]
    if field not in meta:
        raise ValueError(f"{folder / 'scenario.json'} has no {field}: the dataset was made with gen --no-effects")
    n, frames = len(meta["cars"]), meta["frames"]
    poses = _poses(folder, frames, n)
    if method == "frame0":
        feats = _frame_features(poses[0])
    elif method == "trajectory":
        feats = _trajectory_features(poses, meta["frame_interval"])
    else:
        raise ValueError(f"method {method!r} is not one of {', '.join(METHODS)}")
    labels = np.zeros((n, n), dtype=bool)
    for a, b in meta[field]:
        labels[a, b] = True
    same_lane = _frame_features(poses[0])[..., 5].astype(bool)
    off = ~np.eye(n, dtype=bool)
    return feats[off], labels[off], same_lane[off]


def _read_json(path: Path) -> dict:
    """A JSON object from ``path``; a ValueError naming it otherwise."""
    try:
        value = json.loads(path.read_text())
    except (UnicodeDecodeError, ValueError) as e:
        raise ValueError(f"{path}: cannot be read as JSON ({e}); causalcity validate tells what else is damaged") from None
    if not isinstance(value, dict):
        raise ValueError(f"{path}: not a file gen wrote (a JSON object)")
    return value


@contextlib.contextmanager
def _scenario_folders(root: Path, unpack: Optional[Sequence[str]] = None) -> Iterator[Dict[Tuple[str, str], List[Path]]]:
    """Every finished scenario folder of the complete dataset ``root``, by
    (group, split), checked against the counts its manifest lists. A packed
    dataset's (``gen --format tar``) scenarios (of the groups ``unpack``
    names, every group when None) are unpacked, without frames, into a
    temporary folder that goes when the context ends; errors about them
    name the pack and member, as the command line does."""
    from .disk import _count_refused, _refuse_linked

    if not root.is_dir():
        raise ValueError(f"{root} is not a folder: give the dataset folder gen wrote (the one holding manifest.json)")
    path = root / "manifest.json"
    if not path.is_file():
        raise ValueError(f"no manifest.json in {root}: not a dataset gen wrote")
    manifest = _read_json(path)
    groups = manifest.get("groups")
    if not isinstance(groups, list) or not all(isinstance(g, dict) and "name" in g for g in groups):
        raise ValueError(f"{path}: no list of groups: not a manifest gen wrote")
    if manifest.get("complete") is not True:
        raise ValueError(f"{root} is not complete: finish it with its gen command first")

    def refuse_count(group: dict, split: str, found: int, what: str) -> None:
        refused = _count_refused(root, group["name"], split, group.get("splits", {}).get(split), found, what)
        if refused is not None:
            raise ValueError(refused)

    folders = {}
    if manifest.get("scenarios_per_tar"):
        import tempfile

        from .disk import Dataset, _renamed

        with Dataset(root, images=False) as opened, tempfile.TemporaryDirectory(prefix="causalcity-reference-") as into:
            # Where each unpacked folder came from: `<pack>: <folder>`.
            came_from = {}
            for g in groups:
                for split in SPLITS:
                    keys = [k for k in opened.keys(split) if k.group == g["name"]]
                    refuse_count(g, split, len(keys), "scenarios in its packs")
                    folders[(g["name"], split)] = []
                    if unpack is not None and g["name"] not in unpack:
                        continue
                    for key, folder in opened._read_unpacked(keys, lambda folder, key: (key, folder), Path(into)):
                        folders[(g["name"], split)].append(folder)
                        came_from[str(folder)] = opened._member_name(key)
            try:
                yield folders
            except (ValueError, OSError) as e:  # named by its pack, not the temporary folder
                for target, origin in came_from.items():
                    e = _renamed(e, target, origin)
                raise e from None
        return
    for g in groups:
        for split in SPLITS:
            # Hidden folders are scenarios still being written.
            found = sorted(p for p in (root / g["name"] / split).glob("*") if p.is_dir() and not p.name.startswith("."))
            for folder in found:
                _refuse_linked(folder)  # (read through no link, as every reader)
            refuse_count(g, split, len(found), "scenario folders")
            folders[(g["name"], split)] = found
    yield folders


def _table(folders: Sequence[Path], method: str, graph: str):
    rows = [scenario_pairs(f, method, graph) for f in folders]
    if not rows:
        return None
    return tuple(np.concatenate(parts) for parts in zip(*rows))


def _auroc(scores: np.ndarray, labels: np.ndarray) -> Optional[float]:
    positives, negatives = labels.sum(), (~labels).sum()
    if positives == 0 or negatives == 0:
        return None
    from sklearn.metrics import roc_auc_score

    return float(roc_auc_score(labels, scores))


def _best_threshold(scores: np.ndarray, labels: np.ndarray) -> float:
    order = np.argsort(-scores, kind="stable")
    s, l = scores[order], labels[order]
    tp = np.cumsum(l)
    fp = np.cumsum(~l)
    f1 = 2 * tp / (tp + fp + l.sum())
    # only where the score changes, so that a threshold separates them
    last = np.r_[s[1:] != s[:-1], True]
    k = int(np.argmax(np.where(last, f1, -1)))
    return float(s[k])


def evaluate(
    dataset: "str | Path",
    methods: Sequence[str] = METHODS,
    graph: str = "designed",
    groups: Optional[Sequence[str]] = None,
    seed: int = 0,
) -> List[Scored]:
    """Trains and scores each method per group of ``dataset`` (a folder
    ``gen`` wrote, with train and test splits)."""
    try:
        from sklearn.ensemble import HistGradientBoostingClassifier
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError('the reference classifiers need scikit-learn: pip install "./python[reference]"') from e
    root = Path(dataset)
    if graph not in GRAPHS:
        raise ValueError(f"graph {graph!r} is not one of {', '.join(GRAPHS)}")
    with _scenario_folders(root, groups) as every:
        names = list(dict.fromkeys(group for group, _ in every))
        results = []
        for group in names if groups is None else groups:
            if group not in names:
                raise ValueError(f"group {group!r} is not in {root}: its groups are {', '.join(names)}")
            folders = {s: every[(group, s)] for s in SPLITS}
            for method in methods:
                train = _table(folders["train"], method, graph)
                test = _table(folders["test"], method, graph)
                if train is None or test is None or not train[1].any():
                    raise ValueError(f"{root / group}: needs train scenarios with links and test scenarios")
                model = HistGradientBoostingClassifier(max_iter=300, learning_rate=0.08, random_state=seed)
                model.fit(train[0], train[1])
                tune = _table(folders["val"], method, graph)
                source = "val" if tune is not None and tune[1].any() else "train"
                tune = tune if source == "val" else train
                threshold = _best_threshold(model.predict_proba(tune[0])[:, 1], tune[1])
                scores = model.predict_proba(test[0])[:, 1]
                called = scores >= threshold
                tp = int((called & test[1]).sum())
                precision = tp / max(int(called.sum()), 1)
                recall = tp / max(int(test[1].sum()), 1)
                f1 = 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
                lane = test[2]
                results.append(
                    Scored(
                        group=group,
                        method=method,
                        graph=graph,
                        pairs=int(len(scores)),
                        linked=int(test[1].sum()),
                        threshold=threshold,
                        threshold_from=source,
                        precision=precision,
                        recall=recall,
                        f1=f1,
                        auroc=_auroc(scores, test[1]),
                        same_lane_pairs=int(lane.sum()),
                        same_lane_auroc=_auroc(scores[lane], test[1][lane]),
                    )
                )
    return results


def _print(results: List[Scored]) -> None:
    print(f"{'group':<16} {'method':<11} {'pairs':>6} {'linked':>6} {'P':>6} {'R':>6} {'F1':>6} {'AUROC':>6} {'lane':>6} {'lAUROC':>7}")
    for r in results:
        lane = "-" if r.same_lane_auroc is None else f"{r.same_lane_auroc:.3f}"
        auroc = "-" if r.auroc is None else f"{r.auroc:.3f}"
        print(
            f"{r.group:<16} {r.method:<11} {r.pairs:>6} {r.linked:>6} {r.precision:>6.3f} {r.recall:>6.3f} "
            f"{r.f1:>6.3f} {auroc:>6} {r.same_lane_pairs:>6} {lane:>7}"
        )
    print(
        "gradient-boosted classifiers per group, trained on train, threshold for the best F1 on val, scored on "
        "test; lane: test pairs in one lane one behind the other at frame 0, lAUROC: AUROC among them"
    )


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m causalcity.reference", description=__doc__.split("\n\n")[0])
    parser.add_argument("dataset", help="a dataset folder gen wrote (the one holding manifest.json)")
    parser.add_argument("--method", nargs="+", choices=METHODS, default=list(METHODS))
    parser.add_argument("--graph", choices=list(GRAPHS), default="designed")
    parser.add_argument("--group", nargs="+", help="only these groups")
    parser.add_argument("--json", action="store_true", help="print the results as JSON")
    args = parser.parse_args(argv)
    try:
        results = evaluate(args.dataset, args.method, args.graph, args.group)
    except (ValueError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps([asdict(r) for r in results], indent=2))
    else:
        _print(results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
