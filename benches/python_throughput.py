"""Python package throughput against the command line's, measured side by
side in one run (`make bench` runs it after the Rust benchmarks). Prints
figures and ratios; asserts nothing.

- poses only: city scenarios per second, `gen --no-images` (files written)
  against `causalcity.stream` (numpy arrays, nothing written);
- with images: frame pairs (RGB + mask) per second, `gen` with its PNG
  encoding time taken out, against `stream(images=True)`.

- the DataLoader recipe README recommends (`causalcity.batches`, shuffled
  batches of 8 as torch tensors, `num_workers=0`) against the bare stream on
  the same scenarios, poses only and with images (target >= 80 %); beside
  them, the same batches through 2 DataLoader workers, and the recipe README
  gave before (`DataLoader(stream, batch_size=None, num_workers=2)`).
- a packed scenario's frames read in the process a DataLoader worker sent
  the scenario to: from where the worker found them in the pack, against
  finding them again by the pack's headers.

Same spec, same scenarios, same thread counts, without the interventional
effects on either side. $CAUSALCITY_CLI is the
command that runs the binary.
"""

import json
import os
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import causalcity

ROOT = Path(__file__).resolve().parents[1]
POSES_SPEC = ROOT / "configs" / "city.json"
IMAGES_SPEC = ROOT / "configs" / "ci-city.json"
POSES_LIMIT = int(os.environ.get("BENCH_POSES_LIMIT", "20"))
IMAGES_LIMIT = int(os.environ.get("BENCH_IMAGES_LIMIT", "1"))


def cli_run(spec_path, threads, limit, images):
    command = shlex.split(os.environ.get("CAUSALCITY_CLI", str(ROOT / "target" / "release" / "causalcity")))
    with tempfile.TemporaryDirectory(prefix="causalcity-bench-") as out:
        args = ["gen", "--spec", str(spec_path), "--out", out, "--limit", str(limit), "-j", str(threads), "--json", "-q"]
        # The generation pipeline itself: the effects' re-runs are measured by `BENCH_ONLY=effects`.
        args.append("--no-effects")
        if not images:
            args.append("--no-images")
        result = subprocess.run(command + args, capture_output=True, text=True, check=True)
    return json.loads(result.stdout)


def python_run(spec, threads, limit, images):
    start = time.perf_counter()
    scenarios = frames = 0
    for split in spec.splits:
        for s in causalcity.stream(spec, split, limit=limit, images=images, effects=False, threads=threads):
            scenarios += 1
            frames += s.frames if images else 0
    return scenarios, frames, time.perf_counter() - start


def main():
    cores = os.cpu_count() or 1
    thread_counts = sorted({1, cores})
    spec = causalcity.Spec.load(POSES_SPEC)
    print(f"python package vs CLI, {cores} cores")
    print(f"poses only (city scenarios/s, {POSES_SPEC.relative_to(ROOT)} --limit {POSES_LIMIT}):")
    for threads in thread_counts:
        python_run(spec, threads, 1, False)  # warm up
        cli = cli_run(POSES_SPEC, threads, POSES_LIMIT, False)
        cli_rate = cli["written"] / cli["elapsed"]
        n, _, seconds = python_run(spec, threads, POSES_LIMIT, False)
        rate = n / seconds
        print(
            f"  {threads} thread(s): CLI {cli_rate:.0f}/s, python {rate:.0f}/s, ratio {rate / cli_rate:.0%} ({n} scenarios); "
            f"gen writes at {cli_rate / rate:.0%} of the stream's rate (target >= 50%)"
        )
    spec = causalcity.Spec.load(IMAGES_SPEC)
    print(
        f"with images (frame pairs/s, {IMAGES_SPEC.relative_to(ROOT)} --limit {IMAGES_LIMIT}; "
        "CLI with its PNG encoding taken out):"
    )
    for threads in thread_counts:
        cli = cli_run(IMAGES_SPEC, threads, IMAGES_LIMIT, True)
        encode = cli["stage_seconds"]["encode"] / cli["threads"]
        cli_rate = cli["frame_pairs"] / cli["elapsed"]
        cli_no_encode = cli["frame_pairs"] / max(cli["elapsed"] - encode, 1e-9)
        _, frames, seconds = python_run(spec, threads, IMAGES_LIMIT, True)
        rate = frames / seconds
        print(
            f"  {threads} thread(s): CLI {cli_rate:.0f}/s ({cli_no_encode:.0f}/s without encoding), "
            f"python {rate:.0f}/s, ratio {rate / cli_no_encode:.0%} ({frames} frame pairs)"
        )
    if os.environ.get("BENCH_SKIP_DATALOADER") is None:
        dataloader_side_by_side()
    packed_frames_sent()


def rate_of(items, count):
    """Scenarios per second while iterating ``items``; ``count`` gives the
    scenarios in one item."""
    start = time.perf_counter()
    n = sum(count(item) for item in items)
    return n, n / (time.perf_counter() - start)


def dataloader_side_by_side():
    import torch

    print("DataLoader recipe vs the bare stream (scenarios/s, all cores, without effects):")
    for label, spec_path, limit, images in (
        ("poses only", POSES_SPEC, 10 * POSES_LIMIT, False),
        ("with images", IMAGES_SPEC, max(IMAGES_LIMIT, 2), True),
    ):
        spec = causalcity.Spec.load(spec_path)
        split = "train"
        _, bare = rate_of(causalcity.stream(spec, split, limit=limit, images=images, effects=False), lambda s: 1)

        def recipe(workers):
            batches = causalcity.batches(spec, split, 8, seed=0, limit=limit, images=images, effects=False)
            loader = torch.utils.data.DataLoader(batches, batch_size=None, num_workers=workers)
            return rate_of(loader, lambda b: len(b["key"]))

        n, fast = recipe(0)
        _, workers = recipe(2)
        old = torch.utils.data.DataLoader(
            causalcity.stream(spec, split, limit=limit, images=images, effects=False), batch_size=None, num_workers=2
        )
        _, before = rate_of(old, lambda s: 1)
        print(
            f"  {label} ({spec_path.relative_to(ROOT)}, {n} scenarios): stream {bare:.1f}/s, "
            f"batches + DataLoader {fast:.1f}/s = {fast / bare:.0%} of the stream (target >= 80%); "
            f"with 2 workers {workers:.1f}/s ({workers / bare:.0%}); "
            f"old recipe (Scenario objects through 2 workers) {before:.1f}/s ({before / bare:.0%})"
        )


def packed_frames_sent():
    """A packed scenario's frames read in the process a DataLoader worker
    sent the scenario to (README's recipe with ``batch_size=None``): read
    from where the worker found them in the pack, against finding them by
    the pack's headers (the fallback for a pack written again, and the only
    way before), beside reading them in the worker itself."""
    import pickle

    raw = json.loads(IMAGES_SPEC.read_text())
    raw.update(name="bench-packed-frames", frames=150, image={"width": 256, "height": 160})
    raw["groups"] = [{"cars": 4, "edge_proportion": 0.5}]
    raw["splits"] = {"train": 64, "val": 1, "test": 1}
    with tempfile.TemporaryDirectory() as tmp:
        causalcity.generate(raw, Path(tmp) / "packed", effects=False, progress=False, format="tar")
        data = causalcity.open_dataset(Path(tmp) / "packed", "train")
        print(f"packed frames sent to another process (one pack of {len(data)} scenarios, rgb + mask of 150 frames, "
              "seconds per scenario):")  # fmt: skip
        for position in (0, len(data) // 2, len(data) - 1):
            start = time.perf_counter()
            here = data[position]
            rgb, mask = here.rgb[:], here.mask[:]
            worker = time.perf_counter() - start
            sent = pickle.dumps(here)
            timed = []
            for located in (True, False):
                received = pickle.loads(sent)
                if not located:
                    received.rgb._located = received.mask._located = None
                start = time.perf_counter()
                assert (received.rgb[:] == rgb).all() and (received.mask[:] == mask).all()
                timed.append(time.perf_counter() - start)
            print(f"  scenario {position}: read where the worker found it {timed[0]:.3f} s, found by the pack's "
                  f"headers {timed[1]:.3f} s ({timed[1] / timed[0]:.1f}x); in the worker {worker:.3f} s")  # fmt: skip


if __name__ == "__main__":
    sys.exit(main())
