"""`make bench-methods`: our NRI on NRI's own benchmark, and its training
speed, measured side by side in one run (prints figures, asserts nothing).

1. Springs (NRI's paper, section 5.1; 5 particles): edge accuracy and AUROC
   on 500 test simulations against the training-set size and epochs, beside
   the paper's figure (99.9 % edge accuracy, from 50,000 training
   simulations and 500 epochs).
2. Training throughput in scenario windows per second on the toy world (8
   cars, 50 % linked, 200 training scenarios), today's code at the paper
   setting's batch of 8 and the default 16, against the code of a git
   revision before the batched decoder (BENCH_NRI_BEFORE, default 56aa4cd),
   run in the same process on the same data.
3. Learning at a large batch against a small one (toy, 8 cars): val loss per
   epoch and test AUROC, so that a faster batch is not bought with worse
   learning.

Environment: BENCH_SPRINGS_TRAIN (default "500,2000"), BENCH_SPRINGS_EPOCHS
(default "10,30"), BENCH_DEVICE (default cpu), BENCH_NRI_BEFORE.
"""

import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

import causalcity
from causalcity.methods import load_split, make, springs
from causalcity.methods.common import auroc_of, direction_right

ROOT = Path(__file__).resolve().parents[1]
DEVICE = os.environ.get("BENCH_DEVICE", "cpu")
SPRINGS_OPTIONS = dict(history=49, steps=10, warm=10, pair_every=1, window=10, warmup_epochs=2)


def springs_figure() -> None:
    sizes = [int(v) for v in os.environ.get("BENCH_SPRINGS_TRAIN", "500,2000").split(",")]
    epochs_grid = [int(v) for v in os.environ.get("BENCH_SPRINGS_EPOCHS", "10,30").split(",")]
    val = springs.episodes(200, frames=69, seed=2, split="val")
    test = springs.episodes(500, frames=69, seed=3, split="test")
    print("== springs, 5 particles (NRI paper: 99.9 % edge accuracy, 50,000 train simulations, 500 epochs) ==")
    print(f"{'train sims':>10} {'epochs':>6} {'batch':>5} {'edge acc':>8} {'AUROC':>6} {'fit s':>6}")
    for size in sizes:
        train = springs.episodes(size, frames=69, seed=1)
        for epochs in epochs_grid:
            batch = 64
            nri = make("nri", epochs=epochs, batch_size=batch, lr=2e-3, device=DEVICE, quiet=True, **SPRINGS_OPTIONS)
            start = time.perf_counter()
            nri.fit(train, val)
            seconds = time.perf_counter() - start
            scores = nri.predict(test).edges
            auroc = auroc_of(scores, test.graph)
            print(
                f"{size:>10} {epochs:>6} {batch:>5} {springs.edge_accuracy(scores, test.graph):8.3f} "
                f"{max(auroc, 1 - auroc):6.3f} {seconds:6.0f}",
                flush=True,
            )
    print("target: edge accuracy >= 0.95 with no more data and epochs than the paper")


def toy_dataset(folder: Path, train: int, test: int = 0) -> Path:
    raw = json.loads((ROOT / "configs" / "toy.json").read_text())
    raw["groups"] = [g for g in raw["groups"] if g["cars"] == 8 and g["edge_proportion"] == 0.5]
    raw["splits"] = {"train": train, "val": max(test // 2, 1), "test": max(test, 1)}
    raw["name"] = f"bench-nri-{train}-{test}"
    causalcity.generate(raw, folder, images=False, effects=False, progress=False)
    return folder


def before_module():
    """causalcity/methods/nri.py as it was at BENCH_NRI_BEFORE, imported
    beside today's (None outside a git checkout)."""
    revision = os.environ.get("BENCH_NRI_BEFORE", "56aa4cd")
    try:
        source = subprocess.run(
            ["git", "-C", str(ROOT), "show", f"{revision}:python/causalcity/methods/nri.py"],
            capture_output=True, text=True, check=True,
        ).stdout  # fmt: skip
    except (OSError, subprocess.CalledProcessError):
        return None, revision
    path = Path(tempfile.mkdtemp()) / "nri_before.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location("causalcity.methods._nri_before", path)
    module = importlib.util.module_from_spec(spec)
    module.__package__ = "causalcity.methods"
    spec.loader.exec_module(module)
    return module, revision


def throughput(tmp: Path) -> None:
    train = load_split(toy_dataset(tmp / "speed", 200), "cars08_edges50", "train")
    old, revision = before_module()
    print(f"\n== NRI training throughput, toy 8 cars, {len(train)} train scenarios, {DEVICE}, "
          f"{torch.get_num_threads()} threads ==")  # fmt: skip
    rows = []
    runs = [("today", None, b) for b in (8, 16, 128, 512)]
    if old is not None:
        runs = [(f"before ({revision})", old.Nri, b) for b in (8, 16)] + runs
    for label, cls, batch in runs:
        options = dict(epochs=1, batch_size=batch, device=DEVICE, quiet=True, warmup_epochs=0)
        nri = cls(**options) if cls is not None else make("nri", **options)
        start = time.perf_counter()
        nri.fit(train, None)
        seconds = time.perf_counter() - start
        rate = len(train) * nri.windows / seconds
        rows.append((label, batch, rate))
        print(f"{label:<20} batch {batch:>4}: {rate:8.1f} windows/s, {seconds:5.1f} s per epoch", flush=True)
    if old is not None:
        base = rows[0][2]
        best = max(r for label, _, r in rows if label == "today")
        print(f"today's best against before at the paper's batch 8: {best / base:.1f}x (target >= 10x on this CPU)")


def learning(tmp: Path) -> None:
    folder = toy_dataset(tmp / "learn", 200, 40)
    train, val, test = (load_split(folder, "cars08_edges50", s) for s in ("train", "val", "test"))
    print("\n== learning at a large batch against a small one (toy, 8 cars, 200 train, 20 epochs) ==")
    for batch, lr in ((8, 1e-3), (128, 3e-3)):
        nri = make("nri", epochs=20, batch_size=batch, lr=lr, device=DEVICE, quiet=True, seed=0)
        start = time.perf_counter()
        nri.fit(train, val)
        seconds = time.perf_counter() - start
        scores = nri.predict(test).edges
        curve = " ".join(f"{v:.0f}" for _, _, v in nri.losses)
        direction = direction_right(scores, test.graph)
        print(f"batch {batch:>4} lr {lr:g}: test AUROC {auroc_of(scores, test.graph):.3f}, direction right "
              f"{direction:.0%}, {seconds:.0f} s; val loss per epoch: {curve}", flush=True)  # fmt: skip


def main() -> int:
    torch.manual_seed(0)
    with tempfile.TemporaryDirectory(prefix="causalcity-bench-nri-") as tmp:
        throughput(Path(tmp))
        learning(Path(tmp))
        springs_figure()
    return 0


if __name__ == "__main__":
    sys.exit(main())
