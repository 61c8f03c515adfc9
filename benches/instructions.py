"""Instructions a `gen` job executes, counted by valgrind's callgrind:
the one figure on a shared VM that repeats to the last instruction, where
wall time swings by 30 % from run to run. `make bench-instructions` runs it;
it prints figures and ratios and asserts nothing.

Two jobs, one thread each, on `configs/city.json` narrowed to one group:
- poses only (`--no-images --no-effects`): 20 scenarios of 12 cars
  (22 with val and test), the SUMO side by side's job;
- with effects (`--no-images`): 6 scenarios of 8 cars (8 in all).

`CAUSALCITY_CLI` is the binary measured (default target/release/causalcity);
`BASE_CLI`, when set, is measured beside it with the ratio printed (build an
older revision with `git worktree add` and `cargo build --release
--target-dir ...`). Under valgrind SHA-256 runs without the CPU's SHA
instructions, so the checksums weigh more here than in a real run (about a
fifth of the poses-only job): compare builds with each other, not with wall
time. Without valgrind the script says so and exits 0.
"""

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
JOBS = [
    ("poses only, 12 cars", 12, 20, ["--no-images", "--no-effects"]),
    ("with effects, 8 cars", 8, 6, ["--no-images"]),
]


def spec_for(work, cars, train):
    spec = json.loads((ROOT / "configs" / "city.json").read_text())
    spec["groups"] = [g for g in spec["groups"] if g["cars"] == cars][:1]
    spec["splits"] = {"train": train, "val": 1, "test": 1}
    spec["name"] = f"instructions-{cars}"
    path = work / f"spec{cars}.json"
    path.write_text(json.dumps(spec))
    return path


def instructions(cli, spec, flags, work):
    out = work / "out"
    shutil.rmtree(out, ignore_errors=True)
    log = work / "callgrind.out"
    result = subprocess.run(
        ["valgrind", "--tool=callgrind", f"--callgrind-out-file={log}"]
        + shlex.split(cli)
        + ["gen", "--spec", str(spec), "--out", str(out), "-j", "1", "-q"]
        + flags,
        capture_output=True,
        text=True,
    )
    if result.returncode != 0:
        sys.exit(f"{cli} failed under valgrind:\n{result.stderr[-2000:]}")
    found = re.search(r"Collected : (\d+)", result.stderr)
    if not found:
        sys.exit(f"no instruction count in valgrind's output:\n{result.stderr[-2000:]}")
    return int(found.group(1))


def main():
    if shutil.which("valgrind") is None:
        print("Instruction counts: skipped, no `valgrind` found (apt-get install valgrind)")
        return 0
    cli = os.environ.get("CAUSALCITY_CLI", str(ROOT / "target" / "release" / "causalcity"))
    base = os.environ.get("BASE_CLI")
    shm = Path("/dev/shm")
    scratch = str(shm) if shm.is_dir() and os.access(shm, os.W_OK) else None
    print("Instructions per job (callgrind, one thread; millions):")
    with tempfile.TemporaryDirectory(prefix="causalcity-instructions-", dir=scratch) as tmp:
        work = Path(tmp)
        for name, cars, train, flags in JOBS:
            spec = spec_for(work, cars, train)
            ours = instructions(cli, spec, flags, work)
            line = f"  {name}, {train + 2} scenarios: {ours / 1e6:,.1f} M"
            if base:
                theirs = instructions(base, spec, flags, work)
                line += f" (base {theirs / 1e6:,.1f} M: {100 * (ours - theirs) / theirs:+.1f} %)"
            print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
