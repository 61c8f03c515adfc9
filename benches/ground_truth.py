"""Issue 23's figures, measured side by side in one run (`make bench` runs
it last): on `configs/city.json` and `configs/toy.json`, `--limit` scenarios
per group and split (default 200; BENCH_GROUND_TRUTH_LIMIT), poses only:

- how many designed edges an interventional effect backs (`stats`);
- `baseline`'s dynamics score against its frame-0 rule (AUROC);
- the learned classifiers of `causalcity.reference`: frame 0 only against
  the whole trajectory (F1, AUROC, and AUROC among pairs that start in one
  lane one behind the other), the toy world's trajectory F1 beside the
  city's, and whether the paper's trends hold.

Prints the table and the targets beside it; asserts nothing. Needs
scikit-learn (the package's `reference` extra). $CAUSALCITY_CLI is the
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

from causalcity import reference

ROOT = Path(__file__).resolve().parents[1]
LIMIT = os.environ.get("BENCH_GROUND_TRUTH_LIMIT", "200")


def cli(*args):
    command = shlex.split(os.environ.get("CAUSALCITY_CLI", str(ROOT / "target" / "release" / "causalcity")))
    return subprocess.run(command + list(args), capture_output=True, text=True, check=True).stdout


def main():
    with tempfile.TemporaryDirectory(prefix="causalcity-ground-truth-") as tmp:
        for world in ("toy", "city"):
            out = Path(tmp) / world
            start = time.perf_counter()
            cli("gen", "--spec", str(ROOT / "configs" / f"{world}.json"), "--out", str(out), "--limit", LIMIT, "--no-images", "-q")
            made = time.perf_counter() - start
            stats = json.loads(cli("stats", str(out), "--json"))
            backed = {}
            for row in stats["rows"]:
                c = row["causal"]
                b = backed.setdefault(row["group"], [0, 0, 0, 0])
                b[0] += c["designed_with_effect"]
                b[1] += c["designed_edges"]
                b[2] += c["causal_not_designed"]
                b[3] += c["causal_edges"]
            print(f"\n== {world}: configs/{world}.json --limit {LIMIT} --no-images (generated in {made:.0f} s) ==")
            if world == "toy":
                toy = {r.group: r for r in reference.evaluate(out, methods=("trajectory",))}
                for group, (w, d, u, c) in backed.items():
                    print(
                        f"{group:<16} designed edges backed by an effect {w / d:6.1%} (target >= 90 %), "
                        f"causal edges no design explains {u / max(c, 1):6.1%}, learned trajectory F1 {toy[group].f1:.3f}"
                    )
                continue
            base = json.loads(cli("baseline", str(out), "--json"))
            start = time.perf_counter()
            results = reference.evaluate(out)
            learned = time.perf_counter() - start
            by = {(r.group, r.method): r for r in results}
            print(
                f"{'group':<16} {'backed':>7} {'unexpl':>7} {'dyn AUROC':>9} {'f0 AUROC':>9} "
                f"{'f0 F1':>6} {'f0 lane':>7} {'traj F1':>7} {'gain':>6}"
            )
            for dyn, f0 in zip(base["groups"], base["frame0"]):
                g = dyn["group"]
                w, d, u, c = backed[g]
                lf, lt = by[(g, "frame0")], by[(g, "trajectory")]
                lane = "-" if lf.same_lane_auroc is None else f"{lf.same_lane_auroc:.3f}"
                print(
                    f"{g:<16} {w / d:7.1%} {u / max(c, 1):7.1%} {dyn['auroc']:9.3f} {f0['auroc']:9.3f} "
                    f"{lf.f1:6.3f} {lane:>7} {lt.f1:7.3f} {lt.f1 - lf.f1:+6.3f}"
                )
            print(
                f"(learned classifiers {learned:.0f} s) targets: backed >= 90 %; baseline dynamics AUROC above frame0's; "
                "learned frame0 F1 <= 0.5 and its same-lane AUROC (f0 lane) <= 0.7; trajectory F1 >= frame0 F1 + 0.15"
            )
            f1 = {g: by[(g, "trajectory")].f1 for g, _ in by}
            trends = [
                ("falls from 4 to 12 cars at 50 %", "cars04_edges50", "cars12_edges50", lambda a, b: a > b),
                ("rises from 20 % to 80 % at 8 cars", "cars08_edges20", "cars08_edges80", lambda a, b: a < b),
            ]
            for what, a, b, holds in trends:
                if a in f1 and b in f1:
                    verdict = "holds" if holds(f1[a], f1[b]) else "DOES NOT HOLD"
                    print(f"paper's trend, learned trajectory F1 {what}: {f1[a]:.3f} -> {f1[b]:.3f} ({verdict})")
            harder = all(f1[g] < toy[g].f1 for g in f1 if g in toy)
            print(f"city harder than toy (trajectory F1 lower in every group): {'yes' if harder else 'NO'}")


if __name__ == "__main__":
    sys.exit(main())
