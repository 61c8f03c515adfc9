"""The counterfactual task in one picture (docs/counterfactual-task.png):
one test pair of a sweep, its factual and counterfactual runs from the
intervention's frame, and what each reference method predicted.

    python benches/counterfactual_figure.py SWEEP OUT.png cf_copy.npz cf_constant_velocity.npz cf_nri.npz

SWEEP is a `counterfactual --sweep` output; each .npz is a method's
predictions (`python -m causalcity.methods NAME SWEEP --out NAME.npz`).
The pair shown is the first test pair whose stop moved 2 to 4 other cars
(else the first that moved any). Needs matplotlib.
"""

import json
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import causalcity  # noqa: E402

STYLE = {
    "cf_copy": ("nothing changes", "#7f7f7f"),
    "cf_constant_velocity": ("constant velocity", "#9467bd"),
    "cf_nri": ("NRI rollout", "#1f77b4"),
}


def main(sweep: Path, out: Path, predictions: list) -> None:
    pairs = causalcity.open_sweep(sweep)

    def moved(key):
        summary = json.loads((sweep / key.folder / "summary.json").read_text())
        car = summary["intervention"]["car"]
        return summary["intervention"]["do"], sum(c["max_divergence_m"] > 0.5 for c in summary["cars"] if c["id"] != car)

    keys = pairs.keys("test")
    chosen = [k for k in keys if moved(k)[0] == "stop" and 2 <= moved(k)[1] <= 4] or [k for k in keys if moved(k)[1]]
    key = chosen[0]
    pair = pairs.load(key, images=False)
    iv = pair.summary["intervention"]
    f, car = iv["frame"], iv["car"]
    factual, counterfactual = pair.factual.pixels, pair.counterfactual.pixels
    loaded = {Path(p).stem: np.load(p) for p in predictions}
    steps = next(iter(loaded.values()))[f"{key.folder}/counterfactual"].shape[0]
    window = slice(f, f + steps)
    moved_cars = [c["id"] for c in pair.summary["cars"] if c["max_divergence_m"] > 0.5 and c["id"] != car]

    fig, ax = plt.subplots(figsize=(10, 6.6))
    width, height = pair.factual.metadata["camera"]["width"], pair.factual.metadata["camera"]["height"]
    for c in range(pair.factual.cars):
        colour = "#d62728" if c == car else "#ff7f0e" if c in moved_cars else "#bbbbbb"
        ax.plot(*factual[window, c].T, ":", color=colour, lw=1.2)
        on_map = np.abs(pair.counterfactual.position[window, c, 0]) < 5000
        ax.plot(*counterfactual[window, c][on_map].T, "-", color=colour, lw=2.2)
        ax.plot(*factual[f, c], "o", color=colour, ms=5)
        ax.annotate(pair.factual.car_names[c], factual[f, c], xytext=(4, 4), textcoords="offset points", fontsize=8)
    for name, data in loaded.items():
        label, colour = STYLE.get(name, (name, None))
        predicted = data[f"{key.folder}/counterfactual"]
        scores = data[f"{key.folder}/affected"]
        for c in moved_cars:
            ax.plot(*predicted[:, c].T, "--", color=colour, lw=1.4, label=label if c == moved_cars[0] else None)
        called = ", ".join(pair.factual.car_names[c] for c in np.argsort(-scores) if c != car)[:60]
        print(f"{label}: most likely affected first: {called}")
    ax.plot([], [], ":", color="k", label="factual")
    ax.plot([], [], "-", color="k", label="counterfactual (truth)")
    involved = [car] + moved_cars
    shown = np.concatenate([factual[window][:, involved].reshape(-1, 2), counterfactual[window][:, involved].reshape(-1, 2)])
    shown = shown[(shown[:, 0] > -width) & (shown[:, 0] < 2 * width)]
    (x0, y0), (x1, y1) = shown.min(axis=0) - 30, shown.max(axis=0) + 30
    ax.set_xlim(max(x0, 0), min(x1, width))
    ax.set_ylim(min(y1, height), max(y0, 0))
    ax.set_aspect("equal")
    what = f"{iv['do']} {iv['car_name']}" + (f" for {iv['seconds']} s" if iv.get("seconds") else "")
    ax.set_title(
        f"{key.folder}: {what} at frame {f}, the next {steps} frames\nred: the intervened car; orange: the "
        f"cars it moved ({len(moved_cars)}); solid: the counterfactual run,\ndotted: the factual one; "
        "dashed: each method's prediction for the moved cars",
        fontsize=9,
    )
    ax.legend(loc="lower right", fontsize=8)
    ax.set_xlabel("bird's-eye px")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


if __name__ == "__main__":
    if len(sys.argv) < 4:
        sys.exit(__doc__)
    main(Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3:])
