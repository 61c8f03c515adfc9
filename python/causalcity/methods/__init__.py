"""Reference methods for the paper's experiments, each scored by
``causalcity evaluate`` the way anyone's method is: they read a dataset
``gen`` wrote, train on its train split, tune on val and write a predictions
file of edge scores and/or predicted trajectories.

======================  ==========  ============  =============================
method                  discovers   predicts      needs (extras)
======================  ==========  ============  =============================
``constant_velocity``   no          yes           numpy (the floor)
``granger``             yes         no            scipy (``[methods]``)
``pcmci``               yes         no            tigramite (``[methods]``)
``nri``                 yes         yes           torch (``[methods]``)
``interaction``         no          yes           torch: NRI's decoder on the
                                                  complete graph (NS-DR's role)
``frame0``              yes         no            scikit-learn: the leak row
``path``                yes         no            numpy: the simple rule
                                                  (``baseline``'s following score)
``supervised``          yes         no            scikit-learn: trained on train
                                                  labels, the upper bound
======================  ==========  ============  =============================

From the command line::

    python -m causalcity.methods nri data/toy --out predictions/nri.npz
    causalcity evaluate data/toy predictions/nri.npz

Trajectories: every predicting method observes frames ``0 .. history`` (100,
the paper's) and predicts the next ``steps`` (20) frames' bird's-eye pixel
positions.
"""

from __future__ import annotations

from typing import Callable, Dict

from .common import HISTORY, STEPS, Episodes, Method, Predicted, load_split, run_method, write_predictions

__all__ = [
    "HISTORY",
    "STEPS",
    "Episodes",
    "Method",
    "Predicted",
    "METHODS",
    "make",
    "load_split",
    "run_method",
    "write_predictions",
]


def _constant_velocity(**options) -> Method:
    from .classical import ConstantVelocity

    return ConstantVelocity(**options)


def _granger(**options) -> Method:
    from .classical import Granger

    return Granger(**options)


def _pcmci(**options) -> Method:
    from .classical import Pcmci

    return Pcmci(**options)


def _nri(**options) -> Method:
    from .nri import Nri

    return Nri(**options)


def _interaction(**options) -> Method:
    from .nri import Nri

    return Nri(discover=False, **options)


def _frame0(**options) -> Method:
    from .classical import Frame0

    return Frame0(**options)


def _path(**options) -> Method:
    from .classical import PathFollowing

    return PathFollowing(**options)


def _supervised(**options) -> Method:
    from .classical import Supervised

    return Supervised(**options)


METHODS: Dict[str, Callable[..., Method]] = {
    "constant_velocity": _constant_velocity,
    "granger": _granger,
    "pcmci": _pcmci,
    "nri": _nri,
    "interaction": _interaction,
    "frame0": _frame0,
    "path": _path,
    "supervised": _supervised,
}
"""Every reference method by name; each call makes a fresh, untrained one."""


def make(name: str, **options) -> Method:
    """A fresh method by name (see :data:`METHODS`), with its options."""
    if name not in METHODS:
        raise ValueError(f"method {name!r} is not one of {', '.join(METHODS)}")
    return METHODS[name](**options)
