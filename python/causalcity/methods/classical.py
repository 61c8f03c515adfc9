"""Reference methods without a neural network: the constant-velocity floor,
Granger causality, PCMCI, and the learned first-frame classifier (the leak
row). Discovery methods see the observed frames only (the first
:data:`~causalcity.methods.common.HISTORY`), as NRI's encoder does."""

from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor
from typing import Optional, Sequence

import numpy as np

from .. import InputError
from .common import HISTORY, STEPS, Episodes, Method, Predicted, Progress, auroc_of


def process_pool(workers: int) -> ProcessPoolExecutor:
    """Worker processes. While other threads of this process run (the
    paper's NRI training on a GPU beside Granger and PCMCI), they start
    from a fork server with this module loaded once in it, where the
    platform has one: a plain fork of a threaded process is not safe.
    Otherwise the platform's default, so that a user's script without an
    ``if __name__ == "__main__"`` guard keeps working."""
    import multiprocessing
    import threading

    if threading.active_count() == 1 or "forkserver" not in multiprocessing.get_all_start_methods():
        return ProcessPoolExecutor(workers)
    context = multiprocessing.get_context("forkserver")
    # What the workers import, loaded once in the server: each of Granger's
    # workers imported scipy.stats itself, in every pool (a pool per lag
    # and split), which made 5 Granger units of 10/4/4 toy scenarios take
    # 27 s in `paper` rather than 12. (A module that is missing is skipped.)
    context.set_forkserver_preload([__name__, "scipy.stats", __name__.rsplit(".", 1)[0] + ".pcmci"])
    return ProcessPoolExecutor(workers, mp_context=context)


def observed(episodes: Episodes) -> int:
    """Frames a method may look at: the history, or all when there are fewer."""
    return min(HISTORY, episodes.frames)


def velocities(pixels: np.ndarray) -> np.ndarray:
    """``[..., frames - 1, cars, 2]`` px per frame from ``[..., frames, cars, 2]``."""
    return np.diff(pixels, axis=-3)


class ConstantVelocity(Method):
    """Every car keeps the velocity of its last observed frame: the floor any
    dynamics model must beat."""

    name = "constant_velocity"
    predicts = True

    def __init__(self, steps: int = STEPS) -> None:
        self.steps = steps

    def predict(self, episodes: Episodes) -> Predicted:
        h = observed(episodes)
        steps = min(self.steps, episodes.frames - h)
        if steps < 1:
            return Predicted()
        last = episodes.pixels[:, h - 1]
        v = last - episodes.pixels[:, h - 2]
        k = np.arange(1, steps + 1, dtype=np.float64)[None, :, None, None]
        return Predicted(trajectories=last[:, None] + k * v[:, None])


def granger_scores(series: np.ndarray, lags: int) -> np.ndarray:
    """``[cars, cars]``: for each ordered pair (i, j), the largest over the
    series' components of -log10 p of the Granger F-test "i's past improves
    the prediction of j beyond j's own past" (``lags`` lags and a constant,
    statsmodels' ``ssr_ftest``). ``series``: ``[frames, cars, components]``.
    A component that does not vary scores 0."""
    from scipy.stats import f as f_dist

    frames, cars, components = series.shape
    rows = frames - lags
    scores = np.zeros((cars, cars))
    if rows - 2 * lags - 1 < 1:
        return scores

    def lagged(x: np.ndarray) -> np.ndarray:  # [rows, lags]: x(t - 1) .. x(t - lags)
        return np.stack([x[lags - k : frames - k] for k in range(1, lags + 1)], axis=1)

    ones = np.ones((rows, 1))
    for c in range(components):
        own = [lagged(series[:, j, c]) for j in range(cars)]
        for j in range(cars):
            y = series[lags:, j, c]
            if np.ptp(y) < 1e-9:
                continue
            restricted = np.hstack([ones, own[j]])
            rss_r = np.sum((y - restricted @ np.linalg.lstsq(restricted, y, rcond=None)[0]) ** 2)
            for i in range(cars):
                if i == j:
                    continue
                full = np.hstack([restricted, own[i]])
                rss_u = np.sum((y - full @ np.linalg.lstsq(full, y, rcond=None)[0]) ** 2)
                df = rows - 2 * lags - 1
                if rss_u <= 1e-12 * max(rss_r, 1e-300):
                    score = 300.0 if rss_r > 1e-12 else 0.0
                else:
                    stat = max((rss_r - rss_u) / lags / (rss_u / df), 0.0)
                    score = float(-f_dist.logsf(stat, lags, df) / np.log(10.0))
                scores[i, j] = max(scores[i, j], min(score, 300.0))
    return scores


class Granger(Method):
    """Pairwise Granger causality on each car's velocity (px per frame, x and
    y): scores -log10 p of the F-test, at the lag of ``lags`` with the best
    AUROC on the train split."""

    name = "granger"
    discovers = True

    def __init__(self, lags: Sequence[int] = (4, 8, 16), workers: int = 0, quiet: bool = False) -> None:
        self.lag_grid = tuple(lags)
        self.lags = self.lag_grid[-1]
        self.quiet = quiet
        self.workers = workers or (os.cpu_count() or 1)

    def _scores(self, episodes: Episodes, lags: int, label: str) -> np.ndarray:
        h = observed(episodes)
        progress = Progress(f"granger {label}", len(episodes), self.quiet)
        series = [velocities(episodes.pixels[s, :h]) for s in range(len(episodes))]
        out = []
        if self.workers > 1 and len(series) > 8:
            # On every core, results in scenario order: the same scores
            # whatever the number of workers.
            with process_pool(self.workers) as pool:
                for scores in pool.map(granger_scores, series, [lags] * len(series), chunksize=8):
                    out.append(scores)
                    progress.step()
        else:
            for one in series:
                out.append(granger_scores(one, lags))
                progress.step()
        return np.stack(out) if out else np.zeros((0, episodes.cars, episodes.cars))

    def fit(self, train: Episodes, val: Optional[Episodes]) -> None:
        if len(self.lag_grid) == 1:
            return
        usable = [lag for lag in self.lag_grid if observed(train) - 1 - 3 * lag >= 2] or [min(self.lag_grid)]
        best = max(usable, key=lambda lag: auroc_of(self._scores(train, lag, f"{train.group} lag {lag}"), train.graph))
        self.lags = best

    def predict(self, episodes: Episodes) -> Predicted:
        return Predicted(edges=self._scores(episodes, self.lags, f"{episodes.group} {episodes.split}"))


class Pcmci(Method):
    """PCMCI (partial correlations) over every car's velocity (x and y, px
    per ``every`` frames, sampled every ``every`` frames) with lags up to
    ``tau_max`` samples (16 frames by default: a toy follower is 15 frames
    behind its leader): scores the largest absolute partial correlation
    from any of car i's components at any lag to any of car j's.

    ``backend="numpy"`` (the default) runs :func:`causalcity.methods.pcmci.run_pcmci`,
    tigramite's algorithm without its per-test overhead (about 50x faster,
    the same scores to 1e-10); ``backend="tigramite"`` runs tigramite
    itself."""

    name = "pcmci"
    discovers = True
    BACKENDS = ("numpy", "tigramite")

    def __init__(self, tau_max: int = 8, every: int = 2, pc_alpha: float = 0.05, workers: int = 0, quiet: bool = False,
                 backend: str = "numpy") -> None:  # fmt: skip
        if backend not in self.BACKENDS:
            raise InputError(f"pcmci backend {backend!r} is not one of {', '.join(self.BACKENDS)}")
        self.tau_max, self.every, self.pc_alpha, self.quiet, self.backend = tau_max, every, pc_alpha, quiet, backend
        self.workers = workers or (os.cpu_count() or 1)

    def _val_matrix(self, data: np.ndarray, tau_max: int) -> np.ndarray:
        """MCI's partial correlations ``[source, target, lag]`` of ``data``."""
        if self.backend == "numpy":
            from .pcmci import run_pcmci

            return run_pcmci(data, tau_max, self.pc_alpha)
        try:
            from tigramite import data_processing as pp
            from tigramite.independence_tests.parcorr import ParCorr
            from tigramite.pcmci import PCMCI
        except ImportError as e:  # pragma: no cover - depends on the environment
            raise ImportError('pcmci\'s tigramite backend needs tigramite: pip install tigramite') from e
        pcmci = PCMCI(dataframe=pp.DataFrame(data), cond_ind_test=ParCorr(significance="analytic"), verbosity=0)
        return pcmci.run_pcmci(tau_min=1, tau_max=tau_max, pc_alpha=self.pc_alpha)["val_matrix"]

    def scores(self, series: np.ndarray) -> np.ndarray:
        """``[cars, cars]`` from ``[frames, cars, components]``."""
        frames, cars, components = series.shape
        data = series.reshape(frames, cars * components)
        # Components that never vary carry nothing and break partial correlations.
        varies = np.ptp(data, axis=0) > 1e-9
        scores = np.zeros((cars, cars))
        if varies.sum() < 2:
            return scores
        keep = np.flatnonzero(varies)
        noise = np.random.default_rng(0).normal(0.0, 1e-6, size=(frames, len(keep)))
        tau_max = max(1, min(self.tau_max, frames // 4))
        if frames <= 2 * tau_max:
            return scores  # no sample has a past of 2 tau_max frames to test on
        val = self._val_matrix(data[:, keep] + noise, tau_max)
        strength = np.nan_to_num(np.abs(val[:, :, 1:]).max(axis=2))  # [source, target]
        car = keep // components
        for a in range(len(keep)):
            for b in range(len(keep)):
                i, j = car[a], car[b]
                if i != j:
                    scores[i, j] = max(scores[i, j], strength[a, b])
        return scores

    def predict(self, episodes: Episodes) -> Predicted:
        h = observed(episodes)
        progress = Progress(f"pcmci {episodes.group} {episodes.split}", len(episodes), self.quiet)
        series = [velocities(episodes.pixels[s, :h : self.every]) for s in range(len(episodes))]
        out = []
        if self.workers > 1 and len(series) > 1:
            # One scenario per process, results in scenario order: the same
            # scores whatever the number of workers.
            with process_pool(self.workers) as pool:
                for scores in pool.map(self.scores, series):
                    out.append(scores)
                    progress.step()
        else:
            for one in series:
                out.append(self.scores(one))
                progress.step()
        return Predicted(edges=np.stack(out) if out else np.zeros((0, episodes.cars, episodes.cars)))


class _PairClassifier(Method):
    """A gradient-boosted classifier of ordered pairs (a, b), "a leads b",
    trained on the train split's labels: subclasses say which features
    each scenario's pairs get (:meth:`features`, ``[cars, cars, F]``)."""

    discovers = True

    def __init__(self, seed: int = 0, quiet: bool = True) -> None:
        self.seed, self.quiet = seed, quiet
        self.model = None

    def features(self, episodes: Episodes, s: int) -> np.ndarray:
        raise NotImplementedError

    def _pairs(self, episodes: Episodes):
        n = episodes.cars
        off = ~np.eye(n, dtype=bool)
        progress = Progress(f"{self.name} {episodes.group} {episodes.split}", len(episodes), self.quiet)
        feats = []
        for s in range(len(episodes)):
            feats.append(self.features(episodes, s)[off])
            progress.step()
        x = np.concatenate(feats) if feats else np.zeros((0, 1))
        labels = [episodes.graph[s][off] for s in range(len(episodes))]
        y = np.concatenate(labels).astype(bool) if labels else np.zeros(0, dtype=bool)
        return x, y, off

    def fit(self, train: Episodes, val: Optional[Episodes]) -> None:
        try:
            from sklearn.ensemble import HistGradientBoostingClassifier
        except ImportError as e:  # pragma: no cover - depends on the environment
            raise ImportError(f'{self.name} needs scikit-learn: pip install "./python[methods]"') from e
        x, y, _ = self._pairs(train)
        if y.all() or not y.any():
            self.model = float(y.mean()) if len(y) else 0.0
            return
        self.model = HistGradientBoostingClassifier(max_iter=300, learning_rate=0.08, random_state=self.seed)
        self.model.fit(x, y)

    def predict(self, episodes: Episodes) -> Predicted:
        x, _, off = self._pairs(episodes)
        n = episodes.cars
        p = np.full(len(x), self.model) if isinstance(self.model, float) else self.model.predict_proba(x)[:, 1]
        edges = np.zeros((len(episodes), n, n))
        edges[:, off] = p.reshape(len(episodes), -1)
        return Predicted(edges=edges)


class Frame0(_PairClassifier):
    """The learned first-frame classifier of :mod:`causalcity.reference`
    (gradient boosting on where each car stands relative to each other at
    frame 0): how much of a score the first frame alone explains."""

    name = "frame0"

    def features(self, episodes: Episodes, s: int) -> np.ndarray:
        from ..reference import _frame_features

        return _frame_features(episodes.metres[s, 0])


class PathFollowing(Method):
    """The simple rule (``causalcity baseline``'s following score as a
    method): b follows a when b drives where a drove a moment before. The
    pair (a, b) scores minus the mean, over the observed frames, of the
    distance (metres) from b to the nearest point of a's path over the last
    ``lag`` seconds; the lag is the one of :data:`LAGS_S` with the best
    AUROC on train. Nothing else is learned: this is the row a new method
    must beat before anything clever counts."""

    name = "path"
    discovers = True
    LAGS_S = (2.0, 4.0, 8.0, 15.0, 30.0, 60.0)
    """``causalcity baseline``'s lag grid (``LAG_GRID_S``), seconds."""

    def __init__(self, lag_s: Optional[float] = None) -> None:
        self.lag_s = lag_s
        self.aurocs: dict = {}
        """Train AUROC per lag tried, seconds."""

    def _lags(self, episodes: Episodes, lags_s: Sequence[float]) -> list:
        frames = observed(episodes)
        return [max(1, min(frames - 1, int(round(s / episodes.frame_interval)))) for s in lags_s]

    def _scores(self, episodes: Episodes, lags_s: Sequence[float]) -> np.ndarray:
        """``[scenarios, lags, cars, cars]`` following distances (metres)."""
        from .. import _native

        xy = np.ascontiguousarray(episodes.metres[:, : observed(episodes), :, :2], dtype="<f8")
        s, t, n, _ = xy.shape
        if s == 0:
            return np.zeros((0, len(lags_s), n, n))
        return np.asarray(_native.following_scores(xy.tobytes(), (s, t, n), self._lags(episodes, lags_s)))

    def fit(self, train: Episodes, val: Optional[Episodes]) -> None:
        if self.lag_s is not None:
            return
        duration = observed(train) * train.frame_interval
        covering = next((k for k, s in enumerate(self.LAGS_S) if s >= duration), len(self.LAGS_S) - 1)
        grid = self.LAGS_S[: covering + 1]
        scores = self._scores(train, grid)
        self.aurocs = {s: auroc_of(-scores[:, k], train.graph) for k, s in enumerate(grid)}
        self.lag_s = max(grid, key=lambda s: self.aurocs[s])

    def predict(self, episodes: Episodes) -> Predicted:
        lag_s = self.lag_s if self.lag_s is not None else self.LAGS_S[1]
        return Predicted(edges=-self._scores(episodes, [lag_s])[:, 0])


class Supervised(_PairClassifier):
    """The supervised upper bound: :mod:`causalcity.reference`'s learned
    whole-scene classifier (gradient boosting on each pair's features over
    the observed frames: positions and headings at three frames, the
    following score, distances over time, heading changes alike) trained on
    the train split's labels. No discovery method sees labels; this row says
    how much a method that did could find."""

    name = "supervised"

    def __init__(self, seed: int = 0, quiet: bool = False) -> None:
        super().__init__(seed, quiet)

    def features(self, episodes: Episodes, s: int) -> np.ndarray:
        from ..reference import _trajectory_features

        return _trajectory_features(episodes.metres[s, : observed(episodes)], episodes.frame_interval)
