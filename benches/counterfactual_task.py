"""The counterfactual task's reference table (docs/evaluation.md, "The
counterfactual task"), measured in one run: makes the sweep of
`configs/counterfactual-task.json` (`--kinds stop,remove`, no images),
runs each reference method on it, scores them with `causalcity evaluate`,
and prints the table with the time each took. `make counterfactual-table`
runs it (about 2 minutes on 2 cores; BENCH_DEVICE=cuda trains NRI on a GPU).
Prints, asserts nothing. $CAUSALCITY_CLI is the command that runs the
binary; the sweep and predictions go to a temporary folder unless
BENCH_OUT names one (then the figure is drawn there too).
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
from causalcity.methods.counterfactual import COUNTERFACTUAL_METHODS, run_counterfactual_method

ROOT = Path(__file__).resolve().parents[1]
CLI = shlex.split(os.environ.get("CAUSALCITY_CLI", str(ROOT / "target" / "release" / "causalcity")))
DEVICE = os.environ.get("BENCH_DEVICE", "cpu")
LABELS = {
    "cf_copy": "`cf_copy` (nothing changes)",
    "cf_constant_velocity": "`cf_constant_velocity` (path rule)",
    "cf_nri": "`cf_nri`",
}


def row(report: dict, key: str, split: str = "test") -> dict:
    (found,) = [r for r in report[key] if r["split"] == split]
    return found


def main() -> None:
    out = Path(os.environ["BENCH_OUT"]) if os.environ.get("BENCH_OUT") else Path(tempfile.mkdtemp(prefix="cf-task-"))
    sweep = out / "sweep"
    start = time.monotonic()
    args = ["counterfactual", "--sweep", str(ROOT / "configs" / "counterfactual-task.json"), "--no-images", "--quiet",
            "--kinds", "stop,remove", "--out", str(sweep)]  # fmt: skip
    subprocess.run(CLI + args, check=True, stdout=subprocess.DEVNULL)
    print(f"sweep: {time.monotonic() - start:.1f} s into {sweep}", file=sys.stderr)
    lines = [
        "| method | affected F1 | AUROC | AUPRC | error @5 | @10 | @20 | moved cars @5 | @10 | @20 | seconds |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    predictions = []
    for name, make in COUNTERFACTUAL_METHODS.items():
        options = dict(device=DEVICE, quiet=True) if name == "cf_nri" else {}
        path = out / f"{name}.npz"
        start = time.monotonic()
        run_counterfactual_method(lambda: make(**options), sweep, path, quiet=True)
        seconds = time.monotonic() - start
        predictions.append(path)
        report = causalcity.evaluate(sweep, path)
        affected = [e for e in report["edges"] if e["graph"] == "affected" and e["split"] == "test"][0]
        every, moved = row(report, "counterfactuals"), row(report, "counterfactuals_affected")
        errors = [f"{t['steps'][k - 1]['mse']:.1e}" for t in (every, moved) for k in (5, 10, 20)]
        lines.append(
            f"| {LABELS.get(name, name)} | {affected['f1']:.2f} ± {affected['f1_se']:.2f} | {affected['auroc']:.2f} | "
            f"{affected['auprc']:.2f} | " + " | ".join(errors) + f" | {seconds:.0f} |"
        )
        if name == "cf_copy":
            counts = (affected["scenarios"], affected["pairs"], affected["true_edges"], moved["scenarios"])
    print("test split: {} pairs, {} cars besides the intervened ones, {} of them moved; {} pairs moved some car".format(*counts))
    print("\n".join(lines))
    if os.environ.get("BENCH_OUT"):
        figure = ROOT / "benches" / "counterfactual_figure.py"
        subprocess.run([sys.executable, str(figure), str(sweep), str(out / "counterfactual-task.png")]
                       + [str(p) for p in predictions], check=True)  # fmt: skip
    print(json.dumps({"out": str(out)}), file=sys.stderr)


if __name__ == "__main__":
    main()
