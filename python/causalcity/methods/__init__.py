"""Reference methods for the paper's experiments, each scored by
``causalcity evaluate`` the way anyone's method is: they read a dataset
``gen`` wrote, train on its train split, tune on val and write a predictions
file of edge scores and/or predicted trajectories.

======================  ==========  ============  =============================
method                  discovers   predicts      needs (extras)
======================  ==========  ============  =============================
``constant_velocity``   no          yes           numpy (the floor)
``granger``             yes         no            scipy (``[methods]``)
``pcmci``               yes         no            scipy: tigramite's algorithm
                                                  (``backend="tigramite"``: tigramite)
``nri``                 yes         yes           torch (``[methods]``)
``nri_trail``           yes         yes           torch: NRI whose messages
                                                  read the sender's trail
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

Your own method: any class with :class:`Method`'s interface (``discovers``
and/or ``predicts``, ``fit(train, val)``, ``predict(episodes)``), named
``package.module:Class``, runs wherever a reference method's name does
(``python -m causalcity.methods mypkg.models:MyMethod data/toy --out ...``,
``python -m causalcity.paper --method path mypkg.models:MyMethod``). Its
constructor gets those of ``seed``, ``device`` and ``quiet`` it takes.

Trajectories: every predicting method observes frames ``0 .. history`` (100,
the paper's) and predicts the next ``steps`` (20) frames' bird's-eye pixel
positions.
"""

from __future__ import annotations

import importlib
import inspect
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
    "is_user_method",
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


def _nri_trail(**options) -> Method:
    from .nri import Nri

    # (warmed up only where that is few optimiser steps: nri.AUTO_WARMUP_STEPS)
    return Nri(decoder="trail", encoder_input="heading", name="nri_trail", **{"warmup_epochs": "auto", **options})


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
    "nri_trail": _nri_trail,
    "interaction": _interaction,
    "frame0": _frame0,
    "path": _path,
    "supervised": _supervised,
}
"""Every reference method by name; each call makes a fresh, untrained one."""


def is_user_method(name: str) -> bool:
    """Whether ``name`` names a user's class (``package.module:Class``)
    rather than a reference method."""
    return ":" in name


def _takes(target, option: str) -> bool:
    """Whether the constructor ``target`` takes ``option`` (by name, or any
    keyword)."""
    try:
        parameters = inspect.signature(target).parameters
    except (TypeError, ValueError):
        return False
    return option in parameters or any(p.kind == inspect.Parameter.VAR_KEYWORD for p in parameters.values())


def user_method_takes(name: str, option: str) -> bool:
    """Whether a user's class ``package.module:Class`` takes ``option``;
    ``True`` when it cannot be loaded (making it says why)."""
    try:
        return _takes(_user_class(name), option)
    except Exception:  # a user's module may raise anything on import
        return True


def _user_class(name: str):
    """The class ``package.module:Class`` names; every failure is a
    ``ValueError`` naming ``name`` and what is wrong."""
    module_name, _, attribute = name.partition(":")
    if not module_name or not attribute:
        raise ValueError(f"method {name!r}: give a reference method ({', '.join(METHODS)}) or package.module:Class")
    try:
        module = importlib.import_module(module_name)
    except ImportError as e:
        raise ValueError(f"method {name!r}: cannot import {module_name} ({e}); is it on PYTHONPATH?") from None
    target = module
    for part in attribute.split("."):
        if not hasattr(target, part):
            raise ValueError(f"method {name!r}: {module_name} has no {attribute}")
        target = getattr(target, part)
    if not callable(target):
        raise ValueError(f"method {name!r}: {attribute} is not a class")
    return target


def _user_method(name: str, options: dict, task: str = "discovery") -> Method:
    """A fresh instance of the class ``package.module:Class``, given those of
    ``options`` its constructor takes; every failure is a ``ValueError``
    naming ``name`` and what is wrong."""
    target = _user_class(name)
    given = {k: v for k, v in options.items() if _takes(target, k)}
    # A function that is no method's constructor (os:system), or a class
    # needing arguments the command line cannot give, is refused before it
    # is called; an error raised inside a constructor is the user's code's,
    # with its traceback.
    try:
        inspect.signature(target).bind(**given)
    except TypeError as e:
        taking = ", ".join(f"{k}=" for k in given) or "no arguments"
        raise ValueError(f"method {name!r}: cannot be made with {taking}: {e}") from None
    except ValueError:
        pass  # no signature to check (some built-ins): called as it is
    method = target(**given)
    missing = [a for a in ("fit", "predict") if not callable(getattr(method, a, None))]
    if missing:
        raise ValueError(f"method {name!r}: an instance has no {' or '.join(missing)}() (see causalcity.methods.Method)")
    if task == "counterfactual":
        return method
    if not (getattr(method, "discovers", False) or getattr(method, "predicts", False)):
        raise ValueError(
            f"method {name!r}: set discovers = True (it scores edges) and/or predicts = True (it predicts trajectories)"
        )
    return method


def make(name: str, _task: str = "discovery", **options) -> Method:
    """A fresh method by name (see :data:`METHODS`) with its options, or a
    user's class named ``package.module:Class`` (given those of ``seed``,
    ``device`` and ``quiet`` its constructor takes)."""
    if is_user_method(name):
        return _user_method(name, options, _task)
    if name not in METHODS:
        raise ValueError(f"method {name!r} is not one of {', '.join(METHODS)}, nor package.module:Class")
    return METHODS[name](**options)
