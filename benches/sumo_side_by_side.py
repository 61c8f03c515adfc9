"""causalcity's poses-only `gen` side by side with SUMO on the same job, in one
run (`make bench` runs it). Prints figures and a ratio; asserts nothing.

The job: a city scenario of 12 cars on a 2 x 2 grid of signalised
intersections, 150 s simulated in steps of 0.05 s (causalcity's
`world::city::MAX_STEP`), positions written once a second (causalcity's
`poses.csv` and friends; SUMO's FCD output). Both run as whole processes
from the command line, one CPU thread, writing into /dev/shm where there
is one:

- causalcity: `gen --no-images --no-effects -j 1` on `configs/city.json`
  narrowed to its 12-car group, 200 scenarios in one process (as the
  issue measured it), the wall time per scenario written (the fastest of
  three runs), and of it the simulation stage alone (`gen --json`);
- SUMO: one `sumo` process per scenario (SUMO simulates one scenario per
  run), twelve looping cars with randomised start positions and speeds, the
  wall time per process, and beside it SUMO's own "Duration" (its
  simulation loop without start-up and loading) as the stricter figure.

SUMO comes from PyPI (`pip install eclipse-sumo`, which `make bench`
installs into its venv); `$SUMO_BIN` overrides the binary. Without SUMO the
script says so and exits 0.
"""

import json
import os
import random
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# SUMO runs one process per scenario (40 give a steady mean); causalcity
# one process for all of them, as the issue measured it (200 city scenarios).
SCENARIOS = int(os.environ.get("BENCH_SUMO_SCENARIOS", "40"))
OUR_SCENARIOS = int(os.environ.get("BENCH_OUR_SCENARIOS", "200"))
# causalcity's one process is timed this many times, the fastest kept: on a
# shared machine a single run can be slowed by half by disk and neighbours.
OUR_RUNS = int(os.environ.get("BENCH_OUR_RUNS", "3"))
CARS = 12
SECONDS = 150
STEP_S = 0.05  # causalcity's world::city::MAX_STEP
FRAME_INTERVAL_S = 1.0  # configs/city.json's frame_interval
GOAL = 50


def sumo_binary():
    explicit = os.environ.get("SUMO_BIN")
    if explicit:
        return explicit
    beside = Path(sys.executable).parent / "sumo"
    if beside.exists():
        return str(beside)
    return shutil.which("sumo")


def sumo_tool(sumo, name):
    return str(Path(sumo).parent / name)


def routes(seed):
    """Twelve cars on the grid's inner ring, six each way, looping for the
    whole run (as causalcity's cars stay on its map)."""
    rng = random.Random(seed)
    clockwise = ["A0A1", "A1B1", "B1B0", "B0A0"]
    anticlockwise = ["A0B0", "B0B1", "B1A1", "A1A0"]
    lines = [
        "<routes>",
        '  <vType id="car" accel="2.6" decel="4.5" sigma="0.5" length="4.5" maxSpeed="13.9" carFollowModel="IDM"/>',
    ]
    for k in range(4):
        for name, ring in (("cw", clockwise), ("ccw", anticlockwise)):
            lines.append(f'  <route id="{name}{k}" edges="{" ".join(ring[k:] + ring[:k])}" repeat="40"/>')
    for i in range(CARS):
        route = ("cw" if i % 2 == 0 else "ccw") + str((i // 2) % 4)
        position = 4 + 18 * (i // 8) + rng.uniform(0, 3)
        lines.append(
            f'  <vehicle id="car{i}" type="car" route="{route}" depart="0" '
            f'departPos="{position:.2f}" departSpeed="{rng.uniform(0, 4):.2f}"/>'
        )
    lines.append("</routes>")
    return "\n".join(lines) + "\n"


def run_sumo(sumo, work):
    net = work / "net.xml"
    subprocess.run(
        [
            sumo_tool(sumo, "netgenerate"),
            "--grid",
            "--grid.x-number", "2",
            "--grid.y-number", "2",
            "--grid.length", "48",
            "--grid.attach-length", "40",
            "--default-junction-type", "traffic_light",
            "-o", str(net),
        ],
        check=True,
        capture_output=True,
    )
    walls, durations, inserted = [], [], []
    for k in range(SCENARIOS):
        route_file = work / f"routes{k}.xml"
        route_file.write_text(routes(k))
        fcd = work / f"fcd{k}.xml"
        start = time.perf_counter()
        result = subprocess.run(
            [
                sumo,
                "-n", str(net),
                "-r", str(route_file),
                "--step-length", str(STEP_S),
                "--end", str(SECONDS),
                "--fcd-output", str(fcd),
                "--device.fcd.period", str(FRAME_INTERVAL_S),
                "--threads", "1",
                "--no-step-log",
                "--no-warnings",
                "--duration-log.statistics",
            ],
            check=True,
            capture_output=True,
            text=True,
        )
        walls.append(time.perf_counter() - start)
        duration = re.search(r"Duration: ([0-9.]+)s", result.stdout)
        durations.append(float(duration.group(1)) if duration else float("nan"))
        count = re.search(r"Inserted: (\d+)", result.stdout)
        inserted.append(int(count.group(1)) if count else 0)
        fcd.unlink()
    return walls, durations, inserted


def run_causalcity(work):
    spec = json.loads((ROOT / "configs" / "city.json").read_text())
    spec["groups"] = [g for g in spec["groups"] if g["cars"] == CARS][:1]
    spec["splits"] = {"train": OUR_SCENARIOS, "val": 1, "test": 1}
    spec["name"] = "bench-sumo"
    spec_path = work / "spec.json"
    spec_path.write_text(json.dumps(spec))
    command = shlex.split(os.environ.get("CAUSALCITY_CLI", str(ROOT / "target" / "release" / "causalcity")))
    best = None
    for _ in range(max(1, OUR_RUNS)):
        out = work / "out"
        shutil.rmtree(out, ignore_errors=True)
        start = time.perf_counter()
        result = subprocess.run(
            command
            + ["gen", "--spec", str(spec_path), "--out", str(out), "--no-images", "--no-effects"]
            + ["-j", "1", "--json", "-q"],
            check=True,
            capture_output=True,
            text=True,
        )
        wall = time.perf_counter() - start
        report = json.loads(result.stdout)
        if best is None or wall < best[1]:
            best = (report["written"], wall, report["stage_seconds"])
    return best


def main():
    sumo = sumo_binary()
    if sumo is None:
        print("SUMO side by side: skipped, no `sumo` found (pip install eclipse-sumo, or set SUMO_BIN)")
        return 0
    version = subprocess.run([sumo, "--version"], capture_output=True, text=True).stdout.splitlines()[0]
    # Both tools write into memory where the machine has it (/dev/shm), as
    # `make bench`'s other figures do, so that disk noise decides nothing.
    shm = Path("/dev/shm")
    scratch = str(shm) if shm.is_dir() and os.access(shm, os.W_OK) else None
    with tempfile.TemporaryDirectory(prefix="causalcity-sumo-", dir=scratch) as tmp:
        work = Path(tmp)
        written, wall, stages = run_causalcity(work)
        walls, durations, inserted = run_sumo(sumo, work)
    ours = wall / written
    sumo_wall = sum(walls) / len(walls)
    sumo_loop = sum(durations) / len(durations)
    print(
        f"SUMO side by side ({version}; scenarios of {CARS} cars, {SECONDS} s in {STEP_S} s steps, "
        f"positions every {FRAME_INTERVAL_S} s, 1 thread, whole processes):"
    )
    print(
        f"  causalcity gen --no-images: {ours * 1000:.1f} ms per scenario ({written} scenarios in {wall:.2f} s, "
        f"fastest of {max(1, OUR_RUNS)} runs; of which simulating {stages['simulate'] / written * 1000:.1f} ms, "
        f"writing {stages['write'] / written * 1000:.1f} ms)"
    )
    print(
        f"  sumo --fcd-output: {sumo_wall * 1000:.1f} ms per scenario, one process each ({SCENARIOS} runs; "
        f"its simulation loop alone: {sumo_loop * 1000:.1f} ms; cars inserted {min(inserted)}-{max(inserted)} of {CARS})"
    )
    print(
        f"  causalcity is {sumo_wall / ours:.0f}x faster per scenario (goal >= {GOAL}x); "
        f"{sumo_loop / ours:.1f}x against SUMO's loop alone; its loop against our simulation stage alone: "
        f"{sumo_loop / (stages['simulate'] / written):.1f}x"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
