"""`make bench-original-nri`: NRI's own code (Kipf et al.'s public
repository) against causalcity's NRI, on the same data and for about the
same time (prints figures, asserts nothing).

The original is not part of causalcity. Give a checkout of it:

    git clone https://github.com/ethanfetaya/NRI /path/to/NRI
    NRI_CHECKOUT=/path/to/NRI make bench-original-nri

Its code was written for PyTorch 0.3 and NumPy 1.13; two constructs that
today's versions refuse are rewritten in a temporary copy, and nothing else:
``loss.data[0]`` becomes ``loss.item()`` and ``np.float(x)`` becomes
``float(x)`` (the counts are printed). Everything else runs unchanged, with the settings of its README (MLP
encoder and decoder, 256 hidden units, batch 128, learning rate 5e-4), on
the CPU.

Data, the same for both:
1. springs, 5 particles (:mod:`causalcity.methods.springs`), 49 frames for
   both the encoder and the decoder, as NRI's own loader expects;
2. the toy world, 8 cars, 50 % linked, through ``causalcity export nri
   --layout nri --directed`` (the original reads every frame: 150).

Each is scored on its test split by NRI's edge accuracy (types named
whichever way fits better, as an unsupervised encoder may swap them) and,
for causalcity's NRI, AUROC and the share of true edges whose direction it
gets right.

Environment: NRI_CHECKOUT (required; a work tree or a bare git directory),
BENCH_ORIGINAL_EPOCHS ("springs,toy" epochs of the original, default
"10,30"), BENCH_OURS_EPOCHS (default "30,60"), BENCH_SPRINGS_TRAIN (default
2000), BENCH_TOY_TRAIN (default 200).
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from causalcity.methods import load_split, make, springs
from causalcity.methods.common import auroc_of, direction_right
from nri_methods import toy_dataset  # benches/nri_methods.py, beside this script

ROOT = Path(__file__).resolve().parents[1]
CLI = shlex.split(os.environ.get("CAUSALCITY_CLI", str(ROOT / "target" / "release" / "causalcity")))


def original_copy(into: Path) -> Path:
    """A copy of the original's code with the one PyTorch-0.3 construct
    rewritten; ``into/NRI``."""
    source = Path(os.environ["NRI_CHECKOUT"])
    code = into / "NRI"
    if (source / "train.py").is_file():
        shutil.copytree(source, code, ignore=shutil.ignore_patterns(".git", "data", "logs"))
    else:  # a bare git directory
        code.mkdir()
        archive = subprocess.run(["git", "--git-dir", str(source), "archive", "HEAD"], capture_output=True, check=True)
        subprocess.run(["tar", "-x", "-C", str(code)], input=archive.stdout, check=True)
    for name, pattern, replacement in (("train.py", r"\.data\[0\]", ".item()"), ("utils.py", r"np\.float\(", "float(")):
        path = code / name
        patched, count = re.subn(pattern, replacement, path.read_text())
        path.write_text(patched)
        print(f"original NRI: {name}: {count} x {pattern.replace(chr(92), '')} -> {replacement}")
    (code / "data").mkdir(exist_ok=True)
    return code


def write_nri_arrays(folder: Path, split: str, suffix: str, episodes) -> None:
    """NRI's layout: loc/vel [S, T, 2, N], edges [S, N, N] with edges[i, j] = 1
    when j acts on i (NRI's receiver/sender order)."""
    loc = episodes.pixels.transpose(0, 1, 3, 2)
    vel = np.concatenate([loc[:, 1:2] - loc[:, :1], np.diff(loc, axis=1)], axis=1)
    np.save(folder / f"loc_{split}{suffix}.npy", loc.astype(np.float32))
    np.save(folder / f"vel_{split}{suffix}.npy", vel.astype(np.float32))
    np.save(folder / f"edges_{split}{suffix}.npy", episodes.graph.transpose(0, 2, 1).astype(np.int64))


# Run in the original's folder after training: its best encoder (as its own
# test() loads it) on its own test loader, edge probabilities to a file.
ORIGINAL_SCORES = """
import glob, pickle, sys, numpy as np, torch
from modules import MLPEncoder
from utils import load_data, encode_onehot
folder = sorted(glob.glob('logs/exp*/'))[-1]
args = pickle.load(open(folder + 'metadata.pkl', 'rb'))['args']
encoder = MLPEncoder(args.timesteps * args.dims, args.encoder_hidden, args.edge_types, 0.0, args.factor)
encoder.load_state_dict(torch.load(folder + 'encoder.pt'))
encoder.eval()
off = np.ones([args.num_atoms] * 2) - np.eye(args.num_atoms)
rec = torch.FloatTensor(np.array(encode_onehot(np.where(off)[0]), dtype=np.float32))
send = torch.FloatTensor(np.array(encode_onehot(np.where(off)[1]), dtype=np.float32))
_, _, test, *_ = load_data(args.batch_size, args.suffix)
with torch.no_grad():
    probs = [torch.softmax(encoder(d[:, :, : args.timesteps].contiguous(), rec, send), -1)[..., 1] for d, _ in test]
np.save(sys.argv[1], torch.cat(probs).numpy())
"""


def run_original(code: Path, suffix: str, atoms: int, timesteps: int, epochs: int, graph: np.ndarray) -> tuple:
    """(test edge accuracy, AUROC, direction right, seconds), the scores from
    the original's best encoder on the test split's first ``timesteps`` frames."""
    command = [
        sys.executable, "train.py", "--no-cuda", "--epochs", str(epochs), "--suffix", suffix,
        "--num-atoms", str(atoms), "--timesteps", str(timesteps), "--save-folder", "logs",
    ]  # fmt: skip
    (code / "logs").mkdir(exist_ok=True)
    start = time.perf_counter()
    done = subprocess.run(command, cwd=code, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if done.returncode != 0:
        print(done.stdout[-2000:], done.stderr[-4000:])
        raise SystemExit(f"the original NRI failed (exit {done.returncode})")
    if not re.search(r"acc_test: ([0-9.]+)", done.stdout):
        raise SystemExit("the original NRI printed no acc_test:\n" + done.stdout[-2000:])
    subprocess.run([sys.executable, "-c", ORIGINAL_SCORES, "scores.npy"], cwd=code, check=True)
    # [S, E] in NRI's off-diagonal order (receiver i, sender j) -> scores[s, j, i] = P(j acts on i)
    flat = np.load(code / "scores.npy")
    scores = np.zeros((len(flat), atoms, atoms))
    receivers, senders = np.where(~np.eye(atoms, dtype=bool))
    scores[:, senders, receivers] = flat
    return (*scores_summary(scores, graph), seconds)


def scores_summary(scores: np.ndarray, graph: np.ndarray) -> tuple:
    """(edge accuracy, AUROC, share of true edges scored above their reverse),
    with the edge types named whichever way fits better."""
    auroc = auroc_of(scores, graph)
    if auroc < 0.5:
        scores, auroc = 1 - scores, 1 - auroc
    direction = direction_right(scores, graph)
    return springs.edge_accuracy(scores, graph), auroc, direction


def run_ours(train, val, test, epochs: int, **options) -> tuple:
    nri = make("nri", epochs=epochs, device="cpu", quiet=True, **options)
    start = time.perf_counter()
    nri.fit(train, val)
    seconds = time.perf_counter() - start
    return (*scores_summary(nri.predict(test).edges, test.graph), seconds)


def row(label: str, accuracy: float, auroc: float, direction: float, seconds: float, directed: bool = True) -> None:
    """One line; ``directed=False`` (springs pull both ways) leaves direction out."""
    turned = f"direction right {direction:4.0%}" if directed else "direction n/a (springs pull both ways)"
    print(f"  {label:<26} edge accuracy {accuracy:.3f}  AUROC {auroc:.3f}  {turned}  {seconds:6.0f} s", flush=True)


def main() -> int:
    if "NRI_CHECKOUT" not in os.environ:
        print(__doc__)
        print("NRI_CHECKOUT is not set: nothing to compare against.")
        return 2
    original_epochs = [int(v) for v in os.environ.get("BENCH_ORIGINAL_EPOCHS", "10,30").split(",")]
    ours_epochs = [int(v) for v in os.environ.get("BENCH_OURS_EPOCHS", "30,60").split(",")]
    with tempfile.TemporaryDirectory(prefix="causalcity-bench-original-nri-") as tmp:
        code = original_copy(Path(tmp))

        # The original's test() encodes a test simulation's first T frames and
        # decodes its last T, so its test split holds 2T frames (NRI's own
        # springs test set: 100 frames against 49 for training).
        size = int(os.environ.get("BENCH_SPRINGS_TRAIN", 2000))
        sets = {
            "train": springs.episodes(size, frames=49, seed=1),
            "valid": springs.episodes(200, frames=49, seed=2, split="val"),
            "test": springs.episodes(500, frames=98, seed=3, split="test"),
        }
        for split, episodes in sets.items():
            write_nri_arrays(code / "data", split, "_springs5", episodes)
        print(f"\n== springs, 5 particles, {size} train simulations of 49 frames ==")
        graph = sets["test"].graph
        original = run_original(code, "_springs5", 5, 49, original_epochs[0], graph)
        row(f"original, {original_epochs[0]} epochs", *original, directed=False)
        ours = run_ours(
            sets["train"], sets["valid"], sets["test"], ours_epochs[0], batch_size=128, lr=2e-3, prior=0.5,
            history=39, steps=10, warm=10, pair_every=1, window=10, warmup_epochs=2,
        )  # fmt: skip
        row(f"causalcity, {ours_epochs[0]} epochs", *ours, directed=False)

        toy = int(os.environ.get("BENCH_TOY_TRAIN", 200))
        dataset = toy_dataset(Path(tmp) / "toy", toy, 100)
        export = Path(tmp) / "toy-nri"
        subprocess.run([*CLI, "export", "nri", str(dataset), "--out", str(export), "--layout", "nri", "--directed",
                        "--suffix", "_toy", "--quiet"], check=True)  # fmt: skip
        # 150 frames a scenario: train and valid cut to their first 75, so
        # that the test split holds the 2T the original's test() needs.
        train, val, test = (load_split(dataset, "cars08_edges50", s) for s in ("train", "val", "test"))
        half = test.frames // 2
        for path in (export / "cars08_edges50").iterdir():
            array = np.load(path)
            if path.name.startswith(("loc_", "vel_")) and not path.name.startswith(("loc_test", "vel_test")):
                array = array[:, :half]
            np.save(code / "data" / path.name, array)
        print(f"\n== toy world, 8 cars, 50 % linked, {toy} train scenarios (export nri --layout nri --directed); "
              f"both encoders read the first {half} frames ==")  # fmt: skip
        # (the export may order cars its own way: the original is scored on the export's edges)
        exported = np.load(code / "data" / "edges_test_toy.npy").transpose(0, 2, 1)
        row(f"original, {original_epochs[1]} epochs", *run_original(code, "_toy", 8, half, original_epochs[1], exported))
        ours = run_ours(train, val, test, ours_epochs[1], batch_size=128, lr=3e-3, history=half)
        row(f"causalcity, {ours_epochs[1]} epochs", *ours)
    return 0


if __name__ == "__main__":
    sys.exit(main())
