"""`make bench-methods`: our NRI on NRI's own benchmark, and its training
speed, measured side by side in one run (prints figures, asserts nothing).

1. Springs (NRI's paper, section 5.1; 5 particles): edge accuracy and AUROC
   on 500 test simulations against the training-set size and epochs, beside
   the paper's figure (99.9 % edge accuracy, from 50,000 training
   simulations and 500 epochs).
2. Training throughput in scenario windows per second on the toy world (8
   cars, 50 % linked, 200 training scenarios), today's code at the paper
   setting's batch of 8, the default 16, and 128 and 512, against the code
   of a git revision before the batched decoder (BENCH_NRI_BEFORE, default
   56aa4cd), run in the same process on the same data: in a steady epoch
   (epochs 2 and 3), and in the first (which also prepares the data).
3. Learning at a large batch against a small one (toy, 8 cars): val loss per
   epoch and test AUROC, so that a faster batch is not bought with worse
   learning.

4. (``epoch``) One epoch at the paper's full size: 4,000 toy training
   scenarios of 8 cars (and 500 val, the val loss included in the epoch),
   at the paper setting's batch of 128 and at 512; target <= 5 s on one
   H100-class GPU at 128.
5. (``toy``) NRI and NRI with trail messages at the toy's full size (4,000
   / 500 / 500, 8 cars, 50 %): test AUROC, F1 at val's best threshold and
   the share of edges whose direction is right, beside the path rule and
   Granger on the same data.
6. (``recipe``) NRI's edges epoch by epoch (AUROC, mean edge probability
   of true and other pairs) under training recipes: the default, and a KL
   weighed against the prediction loss with a cosine learning rate, on val
   scenarios neither train nor the val loss see. About 10 min a recipe on
   2 cores at the default 1,000 training scenarios and 40 epochs.
7. (``pcmci``) PCMCI's numpy backend against tigramite itself on the same
   toy and city scenarios (8 cars): seconds per scenario on every core, the
   ratio, and the largest difference between their scores. About a minute
   and a half on 2 cores.

Environment: BENCH_ONLY (sections, default "throughput,learning,springs,pcmci";
also "epoch", "toy" and "recipe"), BENCH_SPRINGS_TRAIN (default "500,2000"),
BENCH_SPRINGS_EPOCHS (default "10,30"), BENCH_SPRINGS_SECONDS (a time limit
per fit), BENCH_SPRINGS_SETTING ("nri", NRI's springs setting, the default
on a GPU; "default", our default model, the default on a CPU), BENCH_DEVICE (default cpu), BENCH_NRI_BEFORE, BENCH_TOY_TRAIN
(default 4000), BENCH_TOY_SECONDS (time limit per NRI fit, default none),
BENCH_TOY_EPOCHS (default 100), BENCH_TOY_WARMUP (NRI's warm-up epochs, a number or "auto",
default the method's own), BENCH_TOY_METHODS (default
"path,granger,nri,nri_trail"),
BENCH_RECIPE_TRAIN (default 1000), BENCH_RECIPE_EPOCHS (default 40),
BENCH_RECIPES (default "default,kl10-cosine,kl100-cosine": klW-SCHEDULE).
"""

import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Optional

import torch

import causalcity
from causalcity.methods import load_split, make, springs
from causalcity.methods.common import auroc_of, direction_right

ROOT = Path(__file__).resolve().parents[1]
DEVICE = os.environ.get("BENCH_DEVICE", "cpu")
# "nri", NRI's springs setting: the encoder reads each particle's 49 frames
# (NRI's node input), the Markovian MLP decoder predicts 10 frames from its
# own outputs, 256 hidden units, a uniform prior, no warm-up; every
# simulation once per epoch (0.960 edge accuracy from 50,000 simulations on
# an H200). "default": our default model (pair inputs, recurrent decoder),
# which learns faster from the few simulations a CPU can afford but levels
# off near 0.89.
SPRINGS_SETTINGS = {
    "nri": dict(history=49, steps=10, warm=10, pair_every=1, decoder="mlp", encoder_input="nodes", hidden=256,
                prior=0.5, warmup_epochs=0, windows=1),
    "default": dict(history=49, steps=10, warm=10, pair_every=1, window=10, warmup_epochs=2),
}  # fmt: skip


def springs_figure() -> None:
    sizes = [int(v) for v in os.environ.get("BENCH_SPRINGS_TRAIN", "500,2000").split(",")]
    epochs_grid = [int(v) for v in os.environ.get("BENCH_SPRINGS_EPOCHS", "10,30").split(",")]
    limit = float(os.environ["BENCH_SPRINGS_SECONDS"]) if os.environ.get("BENCH_SPRINGS_SECONDS") else None
    setting = os.environ.get("BENCH_SPRINGS_SETTING", "default" if DEVICE == "cpu" else "nri")
    if setting not in SPRINGS_SETTINGS:
        raise SystemExit(f"BENCH_SPRINGS_SETTING={setting}: use {' or '.join(SPRINGS_SETTINGS)}")
    chosen = {"batch_size": 128, "lr": 1e-3} if setting == "nri" else {"batch_size": 64, "lr": 2e-3}
    if os.environ.get("BENCH_SPRINGS_BATCH"):
        chosen["batch_size"] = int(os.environ["BENCH_SPRINGS_BATCH"])
    if os.environ.get("BENCH_SPRINGS_LR"):
        chosen["lr"] = float(os.environ["BENCH_SPRINGS_LR"])
    sim_device = DEVICE if DEVICE != "cpu" else None
    val = springs.episodes(500, frames=69, seed=2, split="val", device=sim_device)
    test = springs.episodes(1000, frames=69, seed=3, split="test", device=sim_device)
    print("== springs, 5 particles (NRI paper: 99.9 % edge accuracy, 50,000 train simulations, 500 epochs), "
          f"setting {setting!r}, {device_name()} ==")  # fmt: skip
    print(f"{'train sims':>10} {'epochs':>6} {'batch':>5} {'edge acc':>8} {'AUROC':>6} {'fit s':>6}  val loss by epoch")
    for size in sizes:
        train = springs.episodes(size, frames=69, seed=1, device=sim_device)
        for epochs in epochs_grid:
            options = {**SPRINGS_SETTINGS[setting], **chosen}
            nri = make("nri", epochs=epochs, device=DEVICE, quiet=True, time_limit_s=limit, **options)
            start = time.perf_counter()
            nri.fit(train, val)
            seconds = time.perf_counter() - start
            scores = nri.predict(test).edges
            auroc = auroc_of(scores, test.graph)
            curve = " ".join(f"{v:.0f}" for _, _, v in nri.losses[:: max(len(nri.losses) // 10, 1)])
            print(
                f"{size:>10} {len(nri.losses):>6} {options['batch_size']:>5} {springs.edge_accuracy(scores, test.graph):8.3f} "
                f"{max(auroc, 1 - auroc):6.3f} {seconds:6.0f}  {curve}",
                flush=True,
            )
    print("target: edge accuracy >= 0.95 with no more data and epochs than the paper")


def toy_dataset(folder: Path, train: int, test: int = 0, val: Optional[int] = None) -> Path:
    raw = json.loads((ROOT / "configs" / "toy.json").read_text())
    raw["groups"] = [g for g in raw["groups"] if g["cars"] == 8 and g["edge_proportion"] == 0.5]
    raw["splits"] = {"train": train, "val": max(test // 2 if val is None else val, 1), "test": max(test, 1)}
    raw["name"] = f"bench-nri-{train}-{test}"
    if (folder / "manifest.json").is_file():
        return folder  # made by an earlier section of this run
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
    """Windows per second in a steady epoch: each configuration is fitted
    for 1 and for 3 epochs from the same start, and the 2 epochs between
    are timed (a first epoch also pays for preparing the data and building
    the model: at batch 512 it is 1.6 batches of this set, so its rate says
    more about the set-up than about training). The first epoch's rate is
    printed beside it."""
    train = load_split(toy_dataset(tmp / "speed", 200), "cars08_edges50", "train")
    old, revision = before_module()
    print(f"\n== NRI training throughput, toy 8 cars, {len(train)} train scenarios, {DEVICE}, "
          f"{torch.get_num_threads()} threads: windows/s in a steady epoch (the first epoch's) ==")  # fmt: skip
    rows = []
    runs = [("today", None, b) for b in (8, 16, 128, 512)]
    if old is not None:
        runs = [(f"before ({revision})", old.Nri, b) for b in (8, 16)] + runs

    def fit_seconds(cls, batch: int, epochs: int):
        options = dict(epochs=epochs, batch_size=batch, device=DEVICE, quiet=True, warmup_epochs=0, seed=0)
        nri = cls(**options) if cls is not None else make("nri", **options)
        start = time.perf_counter()
        nri.fit(train, None)
        return time.perf_counter() - start, nri.windows

    for label, cls, batch in runs:
        first, windows = fit_seconds(cls, batch, 1)
        three, _ = fit_seconds(cls, batch, 3)
        steady = max(three - first, 1e-9) / 2
        rate, first_rate = len(train) * windows / steady, len(train) * windows / first
        rows.append((label, batch, rate, first_rate))
        print(f"{label:<20} batch {batch:>4}: {rate:8.1f} windows/s ({first_rate:6.1f} in the first epoch), "
              f"{steady:5.1f} s per steady epoch", flush=True)  # fmt: skip
    if old is not None:
        base, base_first = rows[0][2], rows[0][3]
        best = max(r for label, _, r, _ in rows if label == "today")
        best_first = max(r for label, _, _, r in rows if label == "today")
        print(f"today's best against before at the paper's batch 8: {best / base:.1f}x in a steady epoch, "
              f"{best_first / base_first:.1f}x in the first (target >= 10x on this CPU)")  # fmt: skip


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


def epoch_time(tmp: Path) -> None:
    size = int(os.environ.get("BENCH_TOY_TRAIN", "4000"))
    folder = toy_dataset(tmp / "epoch", size, 500, val=500)
    train, val = (load_split(folder, "cars08_edges50", s) for s in ("train", "val"))
    print(f"\n== one NRI epoch, toy 8 cars, {len(train)} train + {len(val)} val scenarios, {device_name()} ==")
    runs = ((128, 3e-3, False), (128, 3e-3, True), (512, 6e-3, True))
    if not DEVICE.startswith("cuda"):
        runs = runs[1:]  # (CUDA graphs are for CUDA only)
    for batch, lr, graphs in runs:
        # two epochs: the first pays for the device's warm-up and the capture
        nri = make("nri", epochs=2, batch_size=batch, lr=lr, device=DEVICE, quiet=True, warmup_epochs=0,
                   cuda_graphs=graphs)  # fmt: skip
        nri.fit(train, val)
        seconds = nri.epoch_seconds[-1]
        rate = len(train) * nri.windows / seconds
        how = "CUDA graphs" if graphs and DEVICE.startswith("cuda") else "eager"
        print(f"batch {batch:>4}, {how:<11}: {seconds:6.2f} s per epoch ({rate:,.0f} windows/s; first epoch "
              f"{nri.epoch_seconds[0]:.1f} s); val loss by epoch {' '.join(f'{v:.0f}' for _, _, v in nri.losses)}",
              flush=True)  # fmt: skip
    print("target: <= 5 s per epoch at batch 128 on one H100-class GPU")


def toy_full(tmp: Path) -> None:
    """NRI and Granger on the toy at full size, scored by `evaluate`."""
    from causalcity.methods.common import run_method

    size = int(os.environ.get("BENCH_TOY_TRAIN", "4000"))
    limit = float(os.environ["BENCH_TOY_SECONDS"]) if os.environ.get("BENCH_TOY_SECONDS") else None
    epochs = int(os.environ.get("BENCH_TOY_EPOCHS", "100"))
    folder = toy_dataset(tmp / "epoch", size, 500, val=500)
    group = "cars08_edges50"
    test = load_split(folder, group, "test")
    print(f"\n== toy at full size: 8 cars, 50 %, {size}/500/500, {device_name()} ==")
    wanted = os.environ.get("BENCH_TOY_METHODS", "path,granger,nri,nri_trail").split(",")
    neural = dict(epochs=epochs, batch_size=128, lr=3e-3, time_limit_s=limit, device=DEVICE, quiet=True)
    if os.environ.get("BENCH_TOY_WARMUP"):
        warmup = os.environ["BENCH_TOY_WARMUP"]
        if warmup != "auto" and not warmup.isdigit():
            raise SystemExit(f"BENCH_TOY_WARMUP={warmup!r}: use a whole number of epochs, or auto")
        neural["warmup_epochs"] = warmup if warmup == "auto" else int(warmup)
    runs = [("path", dict()), ("granger", dict(quiet=True)), ("nri", neural), ("nri_trail", neural)]
    for k, (name, options) in enumerate(r for r in runs if r[0] in wanted):
        predictions = tmp / f"toy-{k}.npz"
        start = time.perf_counter()
        kept = {}

        def build(name=name, options=options):
            kept["method"] = make(name, **options)
            return kept["method"]

        run_method(build, folder, predictions, groups=[group], quiet=True)
        seconds = time.perf_counter() - start
        report = causalcity.evaluate(folder, predictions, graph="designed")
        row = next(e for e in report["edges"] if e["split"] == "test")
        scores = kept["method"].predict(test).edges
        label = name + "".join(f" {k}={v}" for k, v in options.items() if k in ("decoder", "encoder_input", "warmup_epochs"))
        epochs_run = len(getattr(kept["method"], "losses", [])) or "-"
        print(f"{label:<18} test F1 {row['f1']:.3f} AUROC {row['auroc']:.3f} direction right "
              f"{direction_right(scores, test.graph):.0%}  epochs {epochs_run}, {seconds:.0f} s", flush=True)  # fmt: skip


def _traced(options: dict, scored):
    """An NRI that prints, after each epoch, the edge AUROC on ``scored``
    and the mean edge probability of true and other pairs."""
    import numpy as np

    nri = make("nri", **options)
    real = nri._evaluate_loss

    def traced(*args, **kwargs):
        loss = real(*args, **kwargs)
        epoch = nri.epoch
        edges = nri.predict(scored).edges
        nri.epoch = epoch  # (predict marks the model trained)
        nri._train_mode(True)
        truth = scored.graph.astype(bool)
        other = ~truth & ~np.swapaxes(truth, 1, 2) & ~np.eye(edges.shape[1], dtype=bool)[None]
        print(f"  epoch {epoch + 1:3d} lr {nri.epoch_lrs[-1]:.2g} val loss {loss:7.1f}  AUROC "
              f"{auroc_of(edges, scored.graph):.3f}  p(edge) true {edges[truth].mean():.3g} other "
              f"{edges[other].mean():.3g}", flush=True)  # fmt: skip
        return loss

    nri._evaluate_loss = traced
    return nri


def recipes(tmp: Path) -> None:
    """NRI's edges over training at a larger size than the quick setting's:
    with the default recipe the encoder switches its edges off and the val
    loss keeps a late epoch; a KL weighed against the prediction loss with
    a cosine learning rate keeps them. Scored on val scenarios that neither
    train nor the val loss see (the test split is left alone)."""
    size = int(os.environ.get("BENCH_RECIPE_TRAIN", "1000"))
    epochs = int(os.environ.get("BENCH_RECIPE_EPOCHS", "40"))
    folder = toy_dataset(tmp / f"recipe-{size}", size, 1, val=500)
    group = "cars08_edges50"
    train, val = load_split(folder, group, "train"), load_split(folder, group, "val")

    val, scored = val.part(slice(0, 200)), val.part(slice(200, None))
    chosen = os.environ.get("BENCH_RECIPES", "default,kl10-cosine,kl100-cosine").split(",")
    print(f"\n== NRI's edges over training: toy 8 cars, 50 %, {size} train, 200 val for the loss, "
          f"{len(scored)} val scored, {epochs} epochs at batch 128, lr 3e-3, {device_name()} ==")  # fmt: skip
    for name in chosen:
        weight, schedule = 1.0, "constant"
        if name != "default":
            kl, _, schedule = name.partition("-")
            weight = float(kl.removeprefix("kl"))
        print(f"{name}: kl_weight {weight:g}, lr_schedule {schedule}", flush=True)
        options = dict(epochs=epochs, batch_size=128, lr=3e-3, kl_weight=weight, lr_schedule=schedule,
                       device=DEVICE, quiet=True, seed=0)  # fmt: skip
        nri = _traced(options, scored)
        start = time.perf_counter()
        nri.fit(train, val)
        edges = nri.predict(scored).edges
        print(f"{name}: kept (best val loss) AUROC {auroc_of(edges, scored.graph):.3f}, direction right "
              f"{direction_right(edges, scored.graph):.0%}, {time.perf_counter() - start:.0f} s", flush=True)  # fmt: skip


def device_name() -> str:
    if DEVICE.startswith("cuda") and torch.cuda.is_available():
        return torch.cuda.get_device_name()
    return f"cpu, {torch.get_num_threads()} threads"


def pcmci_backends(tmp: Path) -> None:
    import numpy as np

    print("\n== PCMCI: the numpy backend against tigramite, 8 cars, 50 % linked, every core ==")
    try:
        import tigramite  # noqa: F401
    except ImportError:
        print("tigramite is not installed: nothing to compare with")
        return
    for world in ("toy", "city"):
        raw = json.loads((ROOT / "configs" / f"{world}.json").read_text())
        raw["groups"] = [g for g in raw["groups"] if g["cars"] == 8 and g["edge_proportion"] == 0.5]
        raw.update(name=f"bench-pcmci-{world}", splits={"train": 1, "val": 1, "test": 40})
        causalcity.generate(raw, tmp / f"pcmci-{world}", images=False, effects=False, progress=False)
        test = load_split(tmp / f"pcmci-{world}", "cars08_edges50", "test")
        few = test.part(slice(0, 8))
        rows = {}
        for backend, data in (("tigramite", few), ("numpy", test)):
            start = time.perf_counter()
            edges = make("pcmci", quiet=True, backend=backend).predict(data).edges
            rows[backend] = ((time.perf_counter() - start) / len(data), edges[: len(few)])
        (slow, reference), (fast, ours) = rows["tigramite"], rows["numpy"]
        print(f"{world}: tigramite {slow:.3f} s per scenario ({len(few)} scenarios), numpy {fast:.3f} s ({len(test)}): "
              f"{slow / fast:.0f}x; largest score difference {np.abs(reference - ours).max():.1e}", flush=True)


SECTIONS = {"throughput": throughput, "learning": learning, "springs": springs_figure, "epoch": epoch_time,
            "toy": toy_full, "recipe": recipes, "pcmci": pcmci_backends}  # fmt: skip


def main() -> int:
    torch.manual_seed(0)
    chosen = os.environ.get("BENCH_ONLY", "throughput,learning,springs,pcmci").split(",")
    unknown = [c for c in chosen if c not in SECTIONS]
    if unknown:
        print(f"BENCH_ONLY: {', '.join(unknown)} is not a section: use {', '.join(SECTIONS)}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="causalcity-bench-nri-") as tmp:
        for name in chosen:
            section = SECTIONS[name]
            section() if name == "springs" else section(Path(tmp))
    return 0


if __name__ == "__main__":
    sys.exit(main())
