"""``python -m causalcity.methods``: train a reference method on a dataset
and write its predictions file for ``causalcity evaluate``."""

from __future__ import annotations

import argparse
import sys
import traceback
from pathlib import Path
from typing import Optional, Sequence

from .. import GenerationError, InputError
from . import METHODS, is_user_method, make, user_method_takes
from .counterfactual import COUNTERFACTUAL_METHODS, is_sweep, run_counterfactual_method
from .classical import Pcmci
from .common import (
    DatasetError,
    MethodFailed,
    non_negative_float,
    positive_float,
    positive_int as _positive,
    run_method,
    warmup_epochs_arg,
)


# The flags that set up one method or another, and the reference methods
# each applies to (a user's class takes --device when its constructor does);
# --seed and --quiet apply to every method.
_TRAINING = ("epochs", "device", "batch_size", "lr", "time_limit", "lr_schedule")
_TAKES = {
    "nri": (*_TRAINING, "decoder", "encoder_input", "kl_weight", "warmup_epochs"),
    "nri_trail": (*_TRAINING, "kl_weight", "warmup_epochs"),
    "interaction": (*_TRAINING, "decoder"),
    "pcmci": ("backend",),
    "cf_nri": ("epochs", "device"),
}
_FLAGS = (*_TRAINING, "decoder", "encoder_input", "kl_weight", "warmup_epochs", "backend")


def _flag_not_taken(args: argparse.Namespace) -> Optional[str]:
    """Why a flag given does nothing for ``args.method`` (it was ignored
    silently: ``path --epochs 5`` ran as ``path``), or ``None``."""
    if args.method not in METHODS and args.method not in COUNTERFACTUAL_METHODS and not is_user_method(args.method):
        return None  # an unknown method is named as such further on
    if is_user_method(args.method):
        # --device is given to a user's class whose constructor takes it.
        takes = ("device",) if user_method_takes(args.method, "device") else ()
    else:
        takes = _TAKES.get(args.method, ())
    for flag in _FLAGS:
        if getattr(args, flag) is not None and flag not in takes:
            option = "--" + flag.replace("_", "-")
            if flag == "backend":
                return f"{option} {args.backend}: only pcmci has backends, not {args.method}"
            which = [m for m, t in _TAKES.items() if flag in t]
            which += ["a class of yours whose constructor takes device"] if flag == "device" else []
            return f"{option} does nothing for {args.method}: it sets up {', '.join(which)} only"
    return None


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m causalcity.methods",
        description="Fit a reference method per group on the train split of a dataset gen wrote, and write its "
        "predictions (edge scores and/or trajectories for val and test) as an .npz for causalcity evaluate.",
    )
    parser.add_argument(
        "method",
        metavar="method",
        help=f"a reference method ({', '.join(METHODS)}; on a sweep {', '.join(COUNTERFACTUAL_METHODS)}) or your own "
        "class as package.module:Class",
    )
    parser.add_argument(
        "dataset",
        help="a dataset folder gen wrote (the one holding manifest.json), or a counterfactual --sweep output (sweep.json) "
        "for the counterfactual task",
    )
    parser.add_argument("--out", required=True, help="the predictions .npz to write")
    parser.add_argument("--group", nargs="+", help="only these groups")
    # (extend: `--split val --split test` kept only test)
    parser.add_argument("--split", nargs="+", action="extend", choices=["train", "val", "test"],
                        help="the splits to predict (default: val test)")  # fmt: skip
    parser.add_argument("--epochs", type=_positive, help="nri, nri_trail, interaction: training epochs, at least 1 (default 30)")
    parser.add_argument("--device", help="nri, interaction, cf_nri, your own class: cpu, cuda or auto (default)")
    parser.add_argument("--batch-size", type=_positive, help="nri, interaction: windows per batch (default 16; use 128 or more on a GPU)")
    parser.add_argument("--lr", type=positive_float, help="nri, interaction: Adam's learning rate (default 1e-3)")
    parser.add_argument("--decoder", choices=["rnn", "mlp", "trail"],
                        help="nri, interaction: rnn (default, with memory), mlp (NRI's Markovian springs decoder) or "
                             "trail (a message says what the sender did where the receiver is now; nri_trail's)")
    parser.add_argument("--encoder-input", choices=["pairs", "nodes", "both", "heading"],
                        help="nri: pairs (default), nodes (NRI's: each car's own states), both, or heading (each "
                             "pair's relative positions in the receiver's heading frame; nri_trail's)")
    parser.add_argument("--time-limit", type=positive_float, metavar="SECONDS",
                        help="nri, interaction: stop training after the epoch that reaches this many seconds")
    parser.add_argument("--lr-schedule", choices=["constant", "cosine"],
                        help="nri, interaction: the learning rate over the epochs (see causalcity.methods.nri)")
    parser.add_argument("--kl-weight", type=non_negative_float, metavar="W",
                        help="nri: the weight of the KL to the sparse prior against the prediction loss")
    parser.add_argument("--warmup-epochs", type=warmup_epochs_arg, metavar="N|auto",
                        help="nri, nri_trail: first epochs that train the decoder alone, with no edges (nri: default "
                             "5; nri_trail: default auto, 5 where those are at most 100 optimiser steps and 0 above: "
                             "longer, its encoder switched every true edge off; see docs/evaluation.md)")
    parser.add_argument("--backend", choices=Pcmci.BACKENDS,
                        help="pcmci: numpy (default: tigramite's algorithm without its per-test overhead, about 50x "
                             "faster, the same scores to 1e-10) or tigramite itself")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--quiet", action="store_true", help="no progress lines")
    args = parser.parse_args(argv)
    args.split = list(dict.fromkeys(args.split or ["val", "test"]))
    options = {}
    if args.method == "nri_trail" and (args.decoder or args.encoder_input):
        print("error: nri_trail is nri with --decoder trail --encoder-input heading: give those to nri instead",
              file=sys.stderr)  # fmt: skip
        return 2
    not_taken = _flag_not_taken(args)
    if not_taken:
        print(f"error: {not_taken}", file=sys.stderr)
        return 2
    args.device = args.device or "auto"
    # (An empty path names the working folder, which then held --out.)
    if not args.dataset or not Path(args.dataset).is_dir():
        what = "an empty path" if not args.dataset else "no such folder" if not Path(args.dataset).exists() else "a file"
        print(f"error: dataset {args.dataset!r}: {what}: give the folder gen (or counterfactual --sweep) wrote",
              file=sys.stderr)  # fmt: skip
        return 2
    if is_user_method(args.method):
        options.update(device=args.device, seed=args.seed, quiet=args.quiet)
    elif args.method in ("nri", "interaction", "nri_trail"):
        options.update(device=args.device, seed=args.seed, quiet=args.quiet)
        given = dict(epochs=args.epochs, batch_size=args.batch_size, lr=args.lr, decoder=args.decoder,
                     time_limit_s=args.time_limit, lr_schedule=args.lr_schedule)  # fmt: skip
        if args.method == "nri_trail":
            given.update(decoder=None, kl_weight=args.kl_weight, warmup_epochs=args.warmup_epochs)
        if args.method == "nri":
            given.update(encoder_input=args.encoder_input, kl_weight=args.kl_weight, warmup_epochs=args.warmup_epochs)
        options.update({k: v for k, v in given.items() if v is not None})
    elif args.method in ("granger", "pcmci"):
        options["quiet"] = args.quiet
        if args.backend is not None:
            options["backend"] = args.backend
    elif args.method == "frame0":
        options["seed"] = args.seed
    elif args.method == "supervised":
        options.update(seed=args.seed, quiet=args.quiet)
    try:
        if is_sweep(args.dataset) or args.method in COUNTERFACTUAL_METHODS:
            out = _counterfactual(args)
        else:
            # Made once up front, so that a bad option is refused before any reading.
            make(args.method, **options)
            out = run_method(lambda: make(args.method, **options), args.dataset, args.out, args.group, args.split, args.quiet)
    except MethodFailed as e:
        # the method's own traceback: the bug is in its code
        traceback.print_exception(e.__cause__, file=sys.stderr)
        print(f"error: {e}; nothing was written", file=sys.stderr)
        return 1
    except (InputError, ValueError, FileNotFoundError, NotADirectoryError, DatasetError) as e:
        # (a damaged dataset is bad input, as for causalcity's readers)
        print(f"error: {e}", file=sys.stderr)
        return 2
    except (GenerationError, OSError, RuntimeError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted: nothing was written", file=sys.stderr)
        return 130
    print(f"wrote {out}")
    return 0


def _counterfactual(args: argparse.Namespace):
    """The counterfactual task on a sweep: a reference method of
    :data:`COUNTERFACTUAL_METHODS` or a user's class."""
    if not is_sweep(args.dataset):
        raise ValueError(
            f"{args.method} predicts counterfactuals: give a counterfactual --sweep output (holding sweep.json), "
            f"and {args.dataset} is none"
        )
    options = dict(seed=args.seed, device=args.device, quiet=args.quiet)
    if args.method in COUNTERFACTUAL_METHODS:
        if args.method != "cf_nri":
            options = {}
        elif args.epochs is not None:
            options["epochs"] = args.epochs

        def fresh():
            return COUNTERFACTUAL_METHODS[args.method](**options)

    elif is_user_method(args.method):

        def fresh():
            return make(args.method, _task="counterfactual", **options)

    else:
        raise ValueError(
            f"{args.method} is not a method of the counterfactual task: {', '.join(COUNTERFACTUAL_METHODS)}, or "
            "package.module:Class"
        )
    fresh()  # refused before any reading
    return run_counterfactual_method(fresh, args.dataset, args.out, args.group, args.split, args.quiet)


if __name__ == "__main__":
    sys.exit(main())
