"""``python -m causalcity.methods``: train a reference method on a dataset
and write its predictions file for ``causalcity evaluate``."""

from __future__ import annotations

import argparse
import sys
from typing import Optional, Sequence

from . import METHODS, make
from .common import run_method


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m causalcity.methods",
        description="Fit a reference method per group on the train split of a dataset gen wrote, and write its "
        "predictions (edge scores and/or trajectories for val and test) as an .npz for causalcity evaluate.",
    )
    parser.add_argument("method", choices=list(METHODS))
    parser.add_argument("dataset", help="a dataset folder gen wrote (the one holding manifest.json)")
    parser.add_argument("--out", required=True, help="the predictions .npz to write")
    parser.add_argument("--group", nargs="+", help="only these groups")
    parser.add_argument("--split", nargs="+", default=["val", "test"], choices=["train", "val", "test"])
    parser.add_argument("--epochs", type=int, help="nri, interaction: training epochs (default 30)")
    parser.add_argument("--device", default="auto", help="nri, interaction: cpu, cuda or auto (default)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--quiet", action="store_true", help="no progress lines")
    args = parser.parse_args(argv)
    options = {}
    if args.method in ("nri", "interaction"):
        options.update(device=args.device, seed=args.seed, quiet=args.quiet)
        if args.epochs is not None:
            options["epochs"] = args.epochs
    elif args.method in ("granger", "pcmci"):
        options["quiet"] = args.quiet
    elif args.method == "frame0":
        options["seed"] = args.seed
    try:
        out = run_method(lambda: make(args.method, **options), args.dataset, args.out, args.group, args.split, args.quiet)
    except (ValueError, FileNotFoundError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
