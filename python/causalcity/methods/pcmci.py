"""PCMCI with partial correlations, as tigramite runs it, without its
per-test overhead.

:func:`run_pcmci` follows tigramite 5.2's ``PCMCI.run_pcmci(tau_min=1,
tau_max=..., pc_alpha=...)`` with ``ParCorr(significance="analytic")`` step
for step (Runge et al. 2019, "Detecting and quantifying causal associations
in large nonlinear time series datasets"):

- **PC1**, for each variable j on its own: every lagged variable starts as a
  candidate parent; at condition size 0, 1, 2, ... each candidate is tested
  against j given the first that many of the other candidates (one
  combination per size), the candidates with p > ``pc_alpha`` are dropped
  together at the end of the size (PC-stable), and the rest are sorted by
  the weakest |partial correlation| each has had, strongest first;
- **MCI**: every lagged link i(t - tau) -> j(t) is tested given j's parents
  and i's parents shifted by tau; its partial correlation is
  ``val_matrix[i, j, tau]``.

Every test uses the samples t = 2 tau_max .. T - 1 (tigramite's cut-off),
standardises each series, regresses X and Y on the conditions by least
squares and correlates the residuals; the p-value is Student's t with
T - 2 tau_max - (2 + conditions) degrees of freedom.

Tigramite builds each test's array through its data frame, hashes it for a
cache, and calls SciPy's general ``pearsonr`` and ``t.sf``: on one 8-car
scenario's 16 series that overhead is nearly all of about 3,800 tests. Here
each lagged series is standardised once, and every test of one size is a
slice of those rows in one stacked QR decomposition. Same decisions, same ``val_matrix`` to rounding
(``python/tests/test_methods.py`` compares both on toy and city scenarios).
"""

from __future__ import annotations

import math
import sys
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np
from scipy.special import stdtr

Node = Tuple[int, int]
"""A variable at a lag: (variable, -lag), lag >= 0, as tigramite writes it."""


class _Tests:
    """Partial-correlation tests on one multivariate series, every test on
    the same samples t = 2 tau_max .. T - 1, so each lagged series is
    standardised once and tests are solved many at a time."""

    def __init__(self, data: np.ndarray, tau_max: int) -> None:
        frames, variables = data.shape
        cut = 2 * tau_max
        self.samples = frames - cut
        self.lags = cut + 1
        # lagged[var * lags + lag] = the series of var, lag frames back, at each sample
        lagged = np.stack([data[cut - lag : frames - lag].T for lag in range(self.lags)], axis=1)
        lagged = lagged.reshape(variables * self.lags, self.samples)
        lagged = lagged - lagged.mean(axis=1, keepdims=True)
        std = lagged.std(axis=1)
        self.constant = std == 0.0
        self.rows = lagged / np.where(self.constant, 1.0, std)[:, None]

    def _row(self, node: Node) -> int:
        return node[0] * self.lags - node[1]

    def _nodes(self, x: Node, y: Node, z: Sequence[Node]) -> Optional[List[int]]:
        """The rows of a test, x and y first, as tigramite's construct_array
        takes them (conditions without repeats, none of them x or y, no
        constant one); None when x or y is constant."""
        rows = [self._row(x), self._row(y)]
        if self.constant[rows].any():
            return None
        return rows + [r for r in (self._row(node) for node in dict.fromkeys(z) if node != x and node != y)
                       if not self.constant[r]]  # fmt: skip

    def _regressed(self, rows: List[int]) -> float:
        """The partial correlation of rows 0 and 1 given the others by least
        squares on the samples, tigramite's way: for tests with no more
        samples than rows, where a QR has no row left for y's residual."""
        data = self.rows[rows]
        if len(rows) > 2:
            conditions = data[2:].T
            beta = np.linalg.lstsq(conditions, data[:2].T, rcond=None)[0]
            data = data[:2] - (conditions @ beta).T
        rx, ry = data[0] - data[0].mean(), data[1] - data[1].mean()
        with np.errstate(invalid="ignore", divide="ignore"):
            return float(rx @ ry / (math.sqrt(rx @ rx) * math.sqrt(ry @ ry)))

    def run(self, tests: Sequence[Tuple[Node, Node, Sequence[Node]]]) -> Tuple[np.ndarray, np.ndarray]:
        """For each (x, y, z): the partial correlation of x and y given z
        and its two-sided p-value; (0, 1) when x or y is constant, as in
        tigramite. The tests with as many conditions are stacked into one
        QR decomposition of their samples, conditions first: x's residual
        on them is R[m, m] q_m and y's is R[m, m+1] q_m + R[m+1, m+1] q_m+1."""
        vals = np.zeros(len(tests))  # stays 0 where x or y is constant
        chosen = [self._nodes(*test) for test in tests]
        freedom = np.array([self.samples - len(rows) if rows is not None else 1 for rows in chosen], dtype=float)
        by_width: Dict[int, List[int]] = {}
        for k, rows in enumerate(chosen):
            if rows is not None:
                by_width.setdefault(len(rows), []).append(k)
        for width, batch in by_width.items():
            if self.samples - width < 1:  # too few samples: tigramite's minimum-norm fit, p-value NaN
                vals[batch] = [self._regressed(chosen[k]) for k in batch]
                continue
            order = np.array([[*chosen[k][2:], chosen[k][0], chosen[k][1]] for k in batch], dtype=np.intp)
            r = np.linalg.qr(self.rows[order].transpose(0, 2, 1), mode="r")
            m = width - 2
            with np.errstate(invalid="ignore", divide="ignore"):
                vals[batch] = np.sign(r[:, m, m]) * r[:, m, m + 1] / np.hypot(r[:, m, m + 1], r[:, m + 1, m + 1])
        vals = np.clip(vals, -1.0, 1.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            t = np.abs(vals) * np.sqrt(freedom / (1.0 - vals * vals))
            p = 2 * stdtr(freedom, -t)
        p = np.where(np.abs(np.abs(vals) - 1.0) <= sys.float_info.min, 0.0, p)
        p = np.where(freedom < 1, np.nan, p)
        constant = np.array([rows is None for rows in chosen], dtype=bool)
        return vals, np.where(constant, 1.0, p)


def _candidates(variables: int, tau_max: int) -> List[Node]:
    """Every lagged link into a variable, in tigramite's order."""
    return [(i, -lag) for i in range(variables) for lag in range(1, tau_max + 1)]


def _parents(tests: _Tests, variables: int, tau_max: int, pc_alpha: float) -> List[List[Node]]:
    """PC1's parents of each variable, strongest first (tigramite's
    ``_run_pc_stable_single`` with ``max_combinations=1``), every variable's
    tests of one condition size at once."""
    parents = [_candidates(variables, tau_max) for _ in range(variables)]
    weakest: List[Dict[Node, float]] = [{} for _ in range(variables)]
    for size in range(variables * tau_max + 1):
        active = [j for j in range(variables) if len(parents[j]) - 1 >= size]
        if not active:
            break
        batch = [(j, parent, [p for p in parents[j] if p != parent][:size]) for j in active for parent in parents[j]]
        vals, pvals = tests.run([(parent, (j, 0), conditions) for j, parent, conditions in batch])
        dropped: Dict[int, List[Node]] = {j: [] for j in active}
        for (j, parent, _), val, pval in zip(batch, vals, pvals):
            weakest[j][parent] = min(np.abs(val), weakest[j].get(parent, float("inf")))
            if not pval <= pc_alpha:  # a NaN p-value (too few samples) drops it too
                dropped[j].append(parent)
        for j in active:
            for parent in dropped[j]:
                del weakest[j][parent]
            parents[j] = sorted(weakest[j], key=weakest[j].get, reverse=True)
    return parents


def run_pcmci(data: np.ndarray, tau_max: int, pc_alpha: float) -> np.ndarray:
    """PCMCI's MCI partial correlations ``[source, target, lag]`` (lag 0 is
    zero) of ``data`` ``[frames, variables]``: tigramite's ``val_matrix`` of
    ``run_pcmci(tau_min=1, tau_max=tau_max, pc_alpha=pc_alpha)`` with
    analytic ParCorr."""
    data = np.asarray(data, dtype=np.float64)
    frames, variables = data.shape
    if tau_max < 1 or frames <= 2 * tau_max:
        raise ValueError(f"tau_max {tau_max}: give 1 <= tau_max < frames / 2 ({frames} frames)")
    tests = _Tests(data, tau_max)
    parents = _parents(tests, variables, tau_max, pc_alpha)
    links, batch = [], []
    for j in range(variables):
        for i, tau in _candidates(variables, tau_max):
            shifted = [(k, tau + lag) for k, lag in parents[i]]
            conditions = [node for node in parents[j] if node != (i, tau)]
            conditions += [node for node in shifted if node not in conditions]
            links.append((i, j, -tau))
            batch.append(((i, tau), (j, 0), conditions))
    val = np.zeros((variables, variables, tau_max + 1))
    val[tuple(np.array(links).T)] = tests.run(batch)[0]
    return val
