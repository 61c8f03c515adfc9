"""NRI's own benchmark, the springs simulation (Kipf et al. 2018, section
5.1), written from the paper and its published data-generator constants, so
that our NRI can be checked where the original reported near-perfect edge
accuracy before it is trusted on causalcity's worlds.

``particles`` balls move in a 2-D box (walls at +-:data:`BOX`, elastic); each
pair is joined by a spring with probability 1/2 (both ways alike); a spring
pulls with force ``-SPRING * (x_i - x_j)``; start positions are normal with
standard deviation :data:`LOC_STD`, start velocities point anywhere with
norm :data:`VEL_NORM`; leapfrog steps of :data:`DT`, every
:data:`SAMPLE_EVERY`-th kept (one frame = 0.1 time units).

:func:`episodes` hands the simulations to any :class:`~causalcity.methods.Method`
as :class:`~causalcity.methods.common.Episodes` (positions as "pixels" in
a 10 x 10 "image"), and :func:`edge_accuracy` scores edge scores the way
the NRI paper does.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional, Tuple

import numpy as np

from .common import Episodes

BOX = 5.0
"""Half the box's side: walls at -5 and +5."""
LOC_STD = 0.5
VEL_NORM = 0.5
SPRING = 0.1
"""Spring constant (NRI's ``interaction_strength``)."""
DT = 0.001
SAMPLE_EVERY = 100


def simulate(
    sims: int, particles: int = 5, frames: int = 49, seed: int = 0, device: Optional[str] = None
) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``sims`` simulations at once: positions ``[sims, frames, particles, 2]``,
    velocities alike, and the springs ``[sims, particles, particles]``
    (symmetric 0/1, empty diagonal). ``device`` (a PyTorch device, e.g.
    ``cuda``) integrates there in float64, from the same draws: NRI's
    50,000 simulations take minutes in NumPy, seconds on a GPU."""
    rng = np.random.default_rng(seed)
    upper = np.triu(rng.random((sims, particles, particles)) < 0.5, k=1)
    edges = (upper | upper.transpose(0, 2, 1)).astype(np.float64)
    loc = rng.normal(0.0, LOC_STD, (sims, particles, 2))
    vel = rng.normal(size=(sims, particles, 2))
    vel *= VEL_NORM / np.linalg.norm(vel, axis=-1, keepdims=True)
    if device is not None:
        return _simulate_torch(loc, vel, edges, frames, device) + (edges.astype(np.uint8),)
    positions = np.empty((sims, frames, particles, 2))
    velocities = np.empty_like(positions)

    def force(loc: np.ndarray) -> np.ndarray:
        # sum over j of -k e_ij (x_i - x_j)
        diff = loc[:, :, None, :] - loc[:, None, :, :]
        return -SPRING * (edges[..., None] * diff).sum(axis=2)

    def clamp(loc: np.ndarray, vel: np.ndarray) -> None:
        # elastic walls: reflect the position and flip the velocity
        over, under = loc > BOX, loc < -BOX
        loc[over] = 2 * BOX - loc[over]
        vel[over] = -np.abs(vel[over])
        loc[under] = -2 * BOX - loc[under]
        vel[under] = np.abs(vel[under])

    acc = force(loc)
    for frame in range(frames):
        positions[:, frame], velocities[:, frame] = loc, vel
        for _ in range(SAMPLE_EVERY):
            # leapfrog (kick-drift-kick)
            vel += 0.5 * DT * acc
            loc += DT * vel
            clamp(loc, vel)
            acc = force(loc)
            vel += 0.5 * DT * acc
    return positions, velocities, edges.astype(np.uint8)


def _simulate_torch(loc: np.ndarray, vel: np.ndarray, edges: np.ndarray, frames: int, device: str):
    """:func:`simulate`'s leapfrog loop in PyTorch on ``device``."""
    import torch

    loc_t, vel_t = (torch.as_tensor(a, dtype=torch.float64, device=device) for a in (loc, vel))
    e = torch.as_tensor(edges, dtype=torch.float64, device=device)
    degree = e.sum(dim=-1, keepdim=True)

    def force(x):
        # sum over j of -k e_ij (x_i - x_j) = -k (degree_i x_i - (E x)_i)
        return -SPRING * (degree * x - e @ x)

    positions = torch.empty((loc.shape[0], frames) + loc.shape[1:], dtype=torch.float64, device=device)
    velocities = torch.empty_like(positions)
    acc = force(loc_t)
    for frame in range(frames):
        positions[:, frame], velocities[:, frame] = loc_t, vel_t
        for _ in range(SAMPLE_EVERY):
            vel_t = vel_t + 0.5 * DT * acc
            loc_t = loc_t + DT * vel_t
            over, under = loc_t > BOX, loc_t < -BOX
            loc_t = torch.where(over, 2 * BOX - loc_t, torch.where(under, -2 * BOX - loc_t, loc_t))
            vel_t = torch.where(over, -vel_t.abs(), torch.where(under, vel_t.abs(), vel_t))
            acc = force(loc_t)
            vel_t = vel_t + 0.5 * DT * acc
    return positions.cpu().numpy(), velocities.cpu().numpy()


def episodes(
    sims: int, particles: int = 5, frames: int = 49, seed: int = 0, split: str = "train", device: Optional[str] = None
) -> Episodes:
    """Simulations as :class:`Episodes` a method can fit or predict
    (``device``: see :func:`simulate`)."""
    positions, velocities, edges = simulate(sims, particles, frames, seed, device)
    speed = np.linalg.norm(velocities, axis=-1)
    metres = np.concatenate([positions, np.zeros_like(speed)[..., None], speed[..., None]], axis=-1)
    return Episodes(
        dataset=Path("springs"),
        group=f"springs{particles}",
        split=split,
        folders=[f"springs{particles}/{split}/{k:05d}" for k in range(sims)],
        pixels=positions + BOX,
        metres=metres,
        graph=edges,
        image_size=(int(2 * BOX), int(2 * BOX)),
        frame_interval=DT * SAMPLE_EVERY,
    )


def energy(positions: np.ndarray, velocities: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Total energy ``[sims, frames]``: kinetic (unit masses) plus each
    spring's ``SPRING / 2 * length^2``, which the simulation conserves."""
    kinetic = 0.5 * (velocities**2).sum(axis=(-1, -2))
    d2 = ((positions[:, :, :, None] - positions[:, :, None, :]) ** 2).sum(axis=-1)
    potential = 0.25 * SPRING * (edges[:, None] * d2).sum(axis=(-1, -2))  # each spring counted twice
    return kinetic + potential


def edge_accuracy(scores: np.ndarray, graph: np.ndarray) -> float:
    """NRI's edge accuracy: the share of ordered pairs (off the diagonal)
    whose score is on the right side of 0.5, with the edge types' labels
    taken whichever way round fits better (an unsupervised encoder may name
    "spring" either type)."""
    n = graph.shape[-1]
    off = ~np.eye(n, dtype=bool)
    called = scores[:, off] > 0.5
    right = float((called == graph[:, off].astype(bool)).mean())
    return max(right, 1.0 - right)
