"""causalcity evaluate (and causalcity.evaluate): its metrics agree with
scikit-learn and numpy computed from the dataset's own files, any dtype and
memory order numpy saves is read the same, and bad predictions files are
refused with exit status 2 and nothing written."""

import csv
import io
import json
import os
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from sklearn.metrics import average_precision_score, f1_score, roc_auc_score

import causalcity

DATA = Path(os.environ.get("CAUSALCITY_DATA", "target/python-data"))
TOY = DATA / "toy"
HISTORY = 20  # the test toy has 30 frames
STEPS = 6


def scenarios(split=None):
    for meta_path in sorted(TOY.glob("*/*/*/scenario.json")):
        folder = meta_path.parent
        rel = folder.relative_to(TOY).as_posix()
        if split is None or rel.split("/")[1] == split:
            yield rel, json.loads(meta_path.read_text())


def truth(meta, field="edges"):
    n = len(meta["cars"])
    g = np.zeros((n, n), dtype=bool)
    for a, b in meta[field]:
        g[a, b] = True
    return g


def led(g, s):
    """(Linked pairs a -> b, with b -> a unlinked, scored above their
    reverse, ties half; such pairs), as evaluate's direction counts them."""
    one_way = g & ~g.T
    return float((s > s.T)[one_way].sum() + 0.5 * (s == s.T)[one_way].sum()), int(one_way.sum())


def pixels(rel, meta):
    table = np.loadtxt(TOY / rel / "poses.csv", delimiter=",", skiprows=1, ndmin=2)
    return table[:, [9, 10]].reshape(meta["frames"], len(meta["cars"]), 2)


@pytest.fixture(scope="module")
def predictions(tmp_path_factory):
    """Noisy scores (truth + noise, so every metric is between its extremes)
    and trajectories (truth + noise) for every val and test scenario."""
    if not (TOY / "manifest.json").is_file():
        pytest.skip("needs the test toy dataset (make test-python generates it)")
    rng = np.random.default_rng(11)
    edges, trajectories = {}, {}
    for rel, meta in scenarios():
        if "/train/" in rel:
            continue
        g = truth(meta)
        edges[rel] = g * 0.6 + rng.random(g.shape)
        trajectories[rel] = pixels(rel, meta)[HISTORY : HISTORY + STEPS] + rng.normal(0, 4.0, (STEPS, g.shape[0], 2))
    path = tmp_path_factory.mktemp("evaluate") / "pred.npz"
    causalcity.save_predictions(path, edges, trajectories)
    return path, edges, trajectories


def test_edge_metrics_agree_with_scikit_learn(predictions):
    path, edges, _ = predictions
    report = causalcity.evaluate(TOY, path, graph=["designed", "causal"], history=HISTORY)
    checked = 0
    for row in report["edges"]:
        field = {"designed": "edges", "causal": "causal_edges"}[row["graph"]]
        group, split = row["group"], row["split"]
        rels = [(rel, meta) for rel, meta in scenarios(split) if rel.startswith(group + "/")]
        assert row["scenarios"] == len(rels) > 0
        ys, ss, f1s, shds, right, one_way = [], [], [], [], 0.0, 0
        for rel, meta in rels:
            n = len(meta["cars"])
            off = ~np.eye(n, dtype=bool)
            y, s = truth(meta, field)[off], edges[rel][off]
            called = s > row["threshold"]
            f1s.append(f1_score(y, called, zero_division=1.0))
            shds.append(int((called != y).sum()))
            ys.append(y)
            ss.append(s)
            r, k = led(truth(meta, field), edges[rel])
            right, one_way = right + r, one_way + k
        y, s = np.concatenate(ys), np.concatenate(ss)
        assert row["pairs"] == len(y) and row["true_edges"] == int(y.sum())
        assert row["f1"] == pytest.approx(np.mean(f1s), abs=1e-9)
        if len(f1s) > 1:
            assert row["f1_se"] == pytest.approx(np.std(f1s, ddof=1) / np.sqrt(len(f1s)), abs=1e-9)
        assert row["shd"] == pytest.approx(np.mean(shds), abs=1e-9)
        if 0 < y.sum() < len(y):
            assert row["auroc"] == pytest.approx(roc_auc_score(y, s), abs=1e-9)
            assert row["auprc"] == pytest.approx(average_precision_score(y, s), abs=1e-9)
        else:
            assert row["auroc"] is None
        # who leads: noisy scores get some edges' direction wrong, not all
        assert one_way > 0 and 0.5 < right / one_way <= 1, (right, one_way)
        assert row["direction"] == pytest.approx(right / one_way, abs=1e-12)
        checked += 1
    assert checked == 2 * 2 * 2  # graphs x groups x (val, test)


def test_the_overall_row_counts_every_scenario_of_every_group_once(predictions):
    path, edges, _ = predictions
    report = causalcity.evaluate(TOY, path, graph=["designed"], history=HISTORY)
    rows = [r for r in report["edges"] if r["graph"] == "designed"]
    checked = 0
    for overall in report["overall"]:
        if overall["graph"] != "designed":
            continue
        split = overall["split"]
        groups = [r for r in rows if r["split"] == split]
        assert overall["groups"] == len(groups) == 2
        ys, ss, f1s, shds = [], [], [], []
        for row in groups:
            for rel, meta in scenarios(split):
                if not rel.startswith(row["group"] + "/"):
                    continue
                n = len(meta["cars"])
                off = ~np.eye(n, dtype=bool)
                y, sc = truth(meta)[off], edges[rel][off]
                called = sc > row["threshold"]  # each scenario at its own group's threshold
                f1s.append(f1_score(y, called, zero_division=1.0))
                shds.append(int((called != y).sum()))
                ys.append(y)
                ss.append(sc)
        y, sc = np.concatenate(ys), np.concatenate(ss)
        assert overall["scenarios"] == len(f1s) == sum(r["scenarios"] for r in groups)
        assert overall["pairs"] == len(y) and overall["true_edges"] == int(y.sum())
        assert overall["f1"] == pytest.approx(np.mean(f1s), abs=1e-9)
        # Scenario-weighted: the groups' F1s weighed by their scenarios.
        weighted = sum(r["f1"] * r["scenarios"] for r in groups) / sum(r["scenarios"] for r in groups)
        assert overall["f1"] == pytest.approx(weighted, abs=1e-9)
        assert overall["shd"] == pytest.approx(np.mean(shds), abs=1e-9)
        assert overall["auroc"] == pytest.approx(roc_auc_score(y, sc), abs=1e-9)
        checked += 1
    assert checked == 2  # val and test
    text = cli("evaluate", TOY, path, "--history", HISTORY).stdout
    assert "all 2 groups" in text, text


def test_the_threshold_is_the_best_f1_on_val(predictions):
    path, edges, _ = predictions
    report = causalcity.evaluate(TOY, path, history=HISTORY)
    for row in [r for r in report["edges"] if r["split"] == "val"]:
        rels = [(rel, meta) for rel, meta in scenarios("val") if rel.startswith(row["group"] + "/")]
        y = np.concatenate([truth(m)[~np.eye(len(m["cars"]), dtype=bool)] for _, m in rels])
        s = np.concatenate([edges[r][~np.eye(len(m["cars"]), dtype=bool)] for r, m in rels])
        best = max(f1_score(y, s >= t) for t in np.unique(s))
        assert row["threshold_from"] == "val"
        assert f1_score(y, s > row["threshold"]) == pytest.approx(best)


def test_trajectory_error_is_the_normalised_squared_error_per_step(predictions):
    path, _, trajectories = predictions
    report = causalcity.evaluate(TOY, path, history=HISTORY)
    width, height = 1024, 640
    assert report["image_size"] == [width, height]
    rows = report["trajectories"]
    assert len(rows) == 4
    for row in rows:
        rels = [(rel, meta) for rel, meta in scenarios(row["split"]) if rel.startswith(row["group"] + "/")]
        per = np.array(
            [
                ((((trajectories[r] - pixels(r, m)[HISTORY : HISTORY + STEPS]) / [width, height]) ** 2).mean(axis=(1, 2)))
                for r, m in rels
            ]
        )
        assert [s["step"] for s in row["steps"]] == list(range(1, STEPS + 1))
        assert [s["mse"] for s in row["steps"]] == pytest.approx(list(per.mean(axis=0)), rel=1e-9)


def test_per_scenario_rows_agree_with_scikit_learn_and_average_to_the_group_rows(predictions, tmp_path):
    path, edges, trajectories = predictions
    out = tmp_path / "scenarios.csv"
    report = causalcity.evaluate(TOY, path, graph=["designed", "causal"], history=HISTORY, per_scenario=out)
    rows = report["scenarios"]
    expected = [(rel, g) for rel, _ in scenarios() if "/train/" not in rel for g in ("causal", "designed")]
    assert [(r["scenario"], r["graph"]) for r in rows] == sorted(expected) and len(rows) == 8
    metas = dict(scenarios())
    for r in rows:
        meta = metas[r["scenario"]]
        n = len(meta["cars"])
        off = ~np.eye(n, dtype=bool)
        y = truth(meta, {"designed": "edges", "causal": "causal_edges"}[r["graph"]])[off]
        s = edges[r["scenario"]][off]
        called = s > r["threshold"]
        assert (r["cars"], r["true_edges"], r["predicted_edges"]) == (n, y.sum(), called.sum())
        assert r["f1"] == pytest.approx(f1_score(y, called, zero_division=1.0), abs=1e-6)
        assert r["shd"] == (y != called).sum()
        assert r["auroc"] == (pytest.approx(roc_auc_score(y, s), abs=1e-6) if 0 < y.sum() < len(y) else None)
        right, one_way = led(truth(meta, {"designed": "edges", "causal": "causal_edges"}[r["graph"]]), edges[r["scenario"]])
        assert r["direction"] == (pytest.approx(right / one_way, abs=1e-6) if one_way else None), r
        steps = (trajectories[r["scenario"]] - pixels(r["scenario"], meta)[HISTORY : HISTORY + STEPS]) / [1024, 640]
        assert r["trajectory_mse"] == pytest.approx(float((steps**2).mean()), rel=1e-5)
    # A group row's F1 is the mean of its scenarios' F1.
    for group_row in report["edges"]:
        mine = [r["f1"] for r in rows if r["graph"] == group_row["graph"] and r["split"] == group_row["split"]
                and r["group"] == group_row["group"]]  # fmt: skip
        assert mine and group_row["f1"] == pytest.approx(np.mean(mine), abs=1e-6)
    # The command line writes the same file.
    again = tmp_path / "again.csv"
    run = cli("evaluate", TOY, path, "--graph", "designed,causal", "--history", HISTORY, "--per-scenario", again)
    assert run.returncode == 0, run.stderr
    assert again.read_bytes() == out.read_bytes()
    header = out.read_text().splitlines()[0]
    assert header.startswith("scenario,group,split,graph,cars,threshold,true_edges,predicted_edges,true_positives")
    assert header.endswith(",counterfactual_mse,direction"), header  # (a new column goes last)
    assert any(r["direction"] is not None for r in rows), rows
    # The table as the version before the direction column wrote it is this
    # command's own, replaced on a rerun (it was refused as someone's text).
    earlier = tmp_path / "earlier.csv"
    earlier.write_text(header.removesuffix(",direction") + "\ncars04_edges50/test/00000,cars04_edges50\n")
    run = cli("evaluate", TOY, path, "--graph", "designed,causal", "--history", HISTORY, "--per-scenario", earlier)
    assert run.returncode == 0 and earlier.read_text().splitlines()[0] == header, run.stderr
    # Never onto the dataset or the same file as --csv.
    run = cli("evaluate", TOY, path, "--per-scenario", TOY / "scenarios.csv")
    assert run.returncode == 2 and not (TOY / "scenarios.csv").exists()
    run = cli("evaluate", TOY, path, "--per-scenario", tmp_path / "x.csv", "--csv", tmp_path / "x.csv")
    assert run.returncode == 2 and "own file" in run.stderr and not (tmp_path / "x.csv").exists()


def test_dtypes_and_memory_order_numpy_saves_are_read_the_same(predictions, tmp_path):
    path, edges, _ = predictions
    base = causalcity.evaluate(TOY, path, history=HISTORY)
    # float32 of the transposed-back transpose (Fortran order on disk), and int scores.
    other = {k: np.asfortranarray(v.astype(np.float32)) for k, v in edges.items()}
    assert not next(iter(other.values())).flags["C_CONTIGUOUS"]
    np.savez(tmp_path / "f32.npz", **other)
    again = causalcity.evaluate(TOY, tmp_path / "f32.npz", history=HISTORY)
    for a, b in zip(base["edges"], again["edges"]):
        assert a["auroc"] == pytest.approx(b["auroc"], abs=1e-6)
    # A transposed array really is transposed: scores of "j leads i" rank worse.
    np.savez(tmp_path / "t.npz", **{k: v.T for k, v in edges.items()})
    flipped = causalcity.evaluate(TOY, tmp_path / "t.npz", history=HISTORY)
    assert all(f["auroc"] < b["auroc"] for f, b in zip(flipped["edges"], base["edges"]))


def cli(*args):
    command = shlex.split(os.environ.get("CAUSALCITY_CLI", "target/release/causalcity"))
    return subprocess.run(command + [str(a) for a in args], capture_output=True, text=True)


def test_the_command_line_prints_the_table_and_writes_the_csv(predictions, tmp_path):
    path, _, _ = predictions
    out = tmp_path / "results.csv"
    run = cli("evaluate", TOY, path, "--history", HISTORY, "--csv", out)
    assert run.returncode == 0, run.stderr
    assert "cars08_edges80" in run.stdout and "F1" in run.stdout and "MSE@1" in run.stdout
    lines = out.read_text().splitlines()
    assert lines[0] == "group,cars,edge_proportion,split,graph,metric,step,value,se,scenarios"
    f1_rows = [l for l in lines if ",f1," in l]
    assert len(f1_rows) == 4
    # the direction right: a row per group and split, and a column of the table
    direction_rows = [l.split(",") for l in lines if ",direction," in l]
    assert len(direction_rows) == 4 and all(0.5 < float(r[7]) <= 1 for r in direction_rows), direction_rows
    header = next(l for l in run.stdout.splitlines() if l.startswith("graph "))
    assert header.split()[6:9] == ["AUROC", "AUPRC", "dir"], header
    row = next(l for l in run.stdout.splitlines() if l.startswith("designed ") and " test " in l)
    assert row.split()[8].endswith("%"), row
    assert len([l for l in lines if ",trajectory_mse," in l]) == 4 * STEPS
    as_json = json.loads(cli("evaluate", TOY, path, "--history", HISTORY, "--json").stdout)
    assert len(as_json["edges"]) == 4


def bad_files(predictions, tmp_path):
    _, edges, trajectories = predictions
    one = sorted(edges)[0]
    n = edges[one].shape[0]
    cases = {}

    def save(name, arrays):
        p = tmp_path / f"{name}.npz"
        np.savez(p, **arrays)
        cases[name] = p

    save("shape", {**edges, one: np.zeros((n + 1, n))})
    save("nan", {**edges, one: np.where(np.eye(n) == 0, np.nan, 0.0)})
    # one of the two train scenarios of a group: a split scored in part
    train, meta = next(scenarios("train"))
    save("missing", {**edges, train: np.zeros((len(meta["cars"]),) * 2)})
    save("unknown", {**edges, "cars99_edges50/test/00000": np.zeros((n, n))})
    save("trajectory", {**edges, one + "/trajectory": np.zeros((STEPS, n, 3))})
    save("horizon", {**edges, **{k + "/trajectory": np.zeros((40, edges[k].shape[0], 2)) for k in edges}})
    save("frames_toy", {**edges, one + "/frames": np.zeros((30, n, n))})
    save("empty", {})
    p = tmp_path / "text.npz"
    p.write_text("not a zip")
    cases["text"] = p
    return cases, one


@pytest.mark.parametrize(
    "case, says",
    [
        ("shape", "has shape"),
        ("nan", "NaN"),
        ("missing", "missing 1"),
        ("unknown", "names no scenario"),
        ("trajectory", "[steps,"),
        # 40 steps of a 30-frame scenario: no history fits, so only the steps are advised.
        ("horizon", "predict at most 10 steps"),
        ("frames_toy", "only the city world"),
        ("empty", "holds no arrays"),
        ("text", "not an .npz"),
    ],
)
def test_bad_predictions_exit_2_naming_the_file_and_write_nothing(predictions, tmp_path, case, says):
    cases, one = bad_files(predictions, tmp_path)
    out = tmp_path / "results.csv"
    run = cli("evaluate", TOY, cases[case], "--history", HISTORY, "--csv", out)
    assert run.returncode == 2, (run.returncode, run.stderr)
    assert str(cases[case]) in run.stderr and says in run.stderr, run.stderr
    assert run.stdout == "" and not out.exists()
    if case in ("shape", "nan"):
        assert one in run.stderr
    with pytest.raises(causalcity.InputError):
        causalcity.evaluate(TOY, cases[case], history=HISTORY)


CITY = DATA / "city"
SWEEP = DATA / "sweep"


def binding(folder, frames, cars):
    """[t, i, j] = True when interactions.csv says car i bound car j at frame t."""
    g = np.zeros((frames, cars, cars), dtype=bool)
    with open(folder / "interactions.csv", newline="") as f:
        for row in csv.DictReader(f):
            if row["other_car"] != "":
                g[int(row["frame"]), int(row["other_car"]), int(row["car"])] = True
    return g


def test_per_frame_scores_are_scored_against_interactions(tmp_path):
    if not (CITY / "manifest.json").is_file():
        pytest.skip("needs the test city dataset (make test-python generates it)")
    rng = np.random.default_rng(5)
    truths, frames = {}, {}
    for meta_path in sorted(CITY.glob("*/*/*/scenario.json")):
        rel = meta_path.parent.relative_to(CITY).as_posix()
        meta = json.loads(meta_path.read_text())
        g = binding(meta_path.parent, meta["frames"], len(meta["cars"]))
        truths[rel] = g
        frames[rel] = g * 0.5 + rng.random(g.shape)
    assert sum(int(g.sum()) for g in truths.values()) > 0, "the test city has no car binding another"
    path = tmp_path / "frames.npz"
    causalcity.save_predictions(path, frames=frames)
    report = causalcity.evaluate(CITY, path, history=HISTORY)
    rows = [r for r in report["edges"] if r["graph"] == "per-frame"]
    assert len(rows) == 3 and report["trajectories"] == []
    for row in rows:
        rels = [r for r in truths if r.split("/")[1] == row["split"]]
        ys, ss, f1s, shds = [], [], [], []
        for rel in rels:
            t, n, _ = truths[rel].shape
            off = np.broadcast_to(~np.eye(n, dtype=bool), (t, n, n))
            y, s = truths[rel][off], frames[rel][off]
            called = s > row["threshold"]
            f1s.append(f1_score(y, called, zero_division=1.0))
            shds.append((called != y).sum() / t)
            ys.append(y)
            ss.append(s)
        y, s = np.concatenate(ys), np.concatenate(ss)
        assert row["pairs"] == len(y) and row["true_edges"] == int(y.sum())
        assert row["f1"] == pytest.approx(np.mean(f1s), abs=1e-9)
        assert row["shd"] == pytest.approx(np.mean(shds), abs=1e-9)
        if 0 < y.sum() < len(y):
            assert row["auroc"] == pytest.approx(roc_auc_score(y, s), abs=1e-9)
            assert row["auprc"] == pytest.approx(average_precision_score(y, s), abs=1e-9)
    # Receiver-first (car_graph's [t, j, i]) really is the other orientation.
    flipped = {k: v.transpose(0, 2, 1) for k, v in frames.items()}
    causalcity.save_predictions(tmp_path / "flipped.npz", frames=flipped)
    worse = causalcity.evaluate(CITY, tmp_path / "flipped.npz", history=HISTORY)
    test = [r for r in report["edges"] if r["split"] == "test"][0]
    assert [r for r in worse["edges"] if r["split"] == "test"][0]["auroc"] < test["auroc"]


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    """A sweep long enough for interventions to move other cars."""
    spec = json.loads((Path(__file__).resolve().parents[2] / "tests" / "python" / "city.json").read_text())
    spec.update(frames=120, splits={"train": 2, "val": 4, "test": 6})
    folder = tmp_path_factory.mktemp("sweep")
    (folder / "spec.json").write_text(json.dumps(spec))
    run = cli("counterfactual", "--sweep", folder / "spec.json", "--no-images", "--quiet", "--kinds", "stop,remove",
              "--out", folder / "sweep")  # fmt: skip
    assert run.returncode == 0, run.stderr
    return folder / "sweep"


def test_the_counterfactual_task_is_scored_from_the_intervention_on_with_the_affected_cars(sweep, tmp_path):
    steps = 12
    rng = np.random.default_rng(3)
    predicted, affected, expected, expected_affected, removed_cars, removed_alone = {}, {}, {}, {}, 0, 0
    truth_of, start_of = {}, {}
    for summary_path in sorted(sweep.glob("*/*/*/summary.json")):
        rel = summary_path.parent.relative_to(sweep).as_posix()
        summary = json.loads(summary_path.read_text())
        start, car = summary["intervention"]["frame"], summary["intervention"]["car"]
        meta = json.loads((summary_path.parent / "factual" / "scenario.json").read_text())
        n = len(meta["cars"])
        table = np.loadtxt(summary_path.parent / "counterfactual" / "poses.csv", delimiter=",", skiprows=1)
        xy = table[:, [3, 4]].reshape(meta["frames"], n, 2)[start : start + steps]
        truth = table[:, [9, 10]].reshape(meta["frames"], n, 2)[start : start + steps]
        guess = truth + rng.normal(0, 3.0, truth.shape)
        on_map = xy[..., 0] < 5000  # removed cars are parked 10 km away
        removed_cars += int((~on_map).any(axis=0).sum())
        guess[~on_map] = 0.0
        predicted[rel] = guess
        err = (((guess - truth) / [1024, 640]) ** 2).mean(axis=2)
        expected[rel] = np.array([err[k][on_map[k]].mean() for k in range(steps)])
        moved = np.array([c["max_divergence_m"] > 0.5 for c in summary["cars"]])
        # A step with no affected car on the map has no error (a removed
        # intervened car alone scored a perfect 0 whatever was predicted).
        per_step = np.array([err[k][on_map[k] & moved].mean() if (on_map[k] & moved).any() else np.nan
                             for k in range(steps)])  # fmt: skip
        if moved.any() and not np.isnan(per_step).all():
            expected_affected[rel] = per_step
        elif moved.any():
            removed_alone += 1
        affected[rel] = moved * 1.0 + rng.normal(0, 0.6, n)
        truth_of[rel] = (moved, car)
        start_of[rel] = (start, meta["frames"])
    assert removed_cars > 0
    others = [m[np.arange(len(m)) != c] for rel, (m, c) in truth_of.items() if "/test/" in rel]
    assert sum(o.sum() for o in others) > 0, "some test intervention should move another car"
    causalcity.save_predictions(tmp_path / "cf.npz", counterfactuals=predicted, affected=affected)
    report = causalcity.evaluate(sweep, tmp_path / "cf.npz", per_scenario=tmp_path / "pairs.csv")
    for key, want_of in (("counterfactuals", expected), ("counterfactuals_affected", expected_affected)):
        rows = report[key]
        assert {r["split"] for r in rows} == {"train", "val", "test"} or key == "counterfactuals_affected"
        assert rows
        for row in rows:
            rels = [r for r in want_of if r.split("/")[1] == row["split"]]
            table = np.array([want_of[r] for r in rels])
            want = {k + 1: np.nanmean(table[:, k]) for k in range(steps) if not np.isnan(table[:, k]).all()}
            assert {s["step"]: s["mse"] for s in row["steps"]} == pytest.approx(want, rel=1e-9)
    assert removed_alone > 0, "a removal that moved no other car should be in the sweep (its pair is not scored)"
    (test_row,) = [e for e in report["edges"] if e["graph"] == "affected" and e["split"] == "test"]
    y = np.concatenate(others)
    s = np.concatenate([affected[rel][np.arange(len(m)) != c] for rel, (m, c) in truth_of.items() if "/test/" in rel])
    assert test_row["auroc"] == pytest.approx(roc_auc_score(y, s), abs=1e-9)
    assert test_row["pairs"] == len(y) and test_row["true_edges"] == y.sum()
    # The intervened car's own score is ignored, as documented, so a NaN
    # there is taken (it was refused).
    ignored = {rel: np.where(np.arange(len(a)) == truth_of[rel][1], np.nan, a) for rel, a in affected.items()}
    causalcity.save_predictions(tmp_path / "nan.npz", counterfactuals=predicted, affected=ignored)
    again = causalcity.evaluate(sweep, tmp_path / "nan.npz")
    assert [e for e in again["edges"] if e["graph"] == "affected"] == [e for e in report["edges"] if e["graph"] == "affected"]
    rows = list(csv.DictReader(open(tmp_path / "pairs.csv")))
    assert {r["graph"] for r in rows} == {"affected"} and len(rows) == len(predicted)
    run = cli("evaluate", sweep, tmp_path / "cf.npz")
    assert run.returncode == 0 and "counterfactual trajectories of the affected cars" in run.stdout, run.stderr
    # A counterfactual that runs past the pair's last frame is refused, naming the frame it starts at.
    rel = next(iter(predicted))
    too_long = dict(predicted)
    too_long[rel] = np.zeros((120, predicted[rel].shape[1], 2))
    causalcity.save_predictions(tmp_path / "long.npz", counterfactuals=too_long)
    run = cli("evaluate", sweep, tmp_path / "long.npz")
    assert run.returncode == 2 and "from the intervention's frame" in run.stderr, run.stderr
    # Every pair of a split predicts the same steps, fewer only where its run ends: one cut short (it
    # dropped out of the later steps' means) or one predicting further (scored alone there) is refused.
    room = [r for r in predicted if "/test/" in r and start_of[r][0] + steps + 2 <= start_of[r][1]]
    assert len(room) >= 2
    for length in (steps - 4, steps + 2):
        uneven = dict(predicted)
        uneven[room[1]] = np.zeros((length, predicted[room[1]].shape[1], 2))
        causalcity.save_predictions(tmp_path / "uneven.npz", counterfactuals=uneven)
        run = cli("evaluate", sweep, tmp_path / "uneven.npz")
        assert run.returncode == 2 and room[1] in run.stderr and f" {length}" in run.stderr, run.stderr
        assert "predict the same steps for every pair" in run.stderr, run.stderr
    # A damaged summary.json (fewer cars than its runs) is a failure naming it, not a crash.
    import shutil

    damaged = tmp_path / "damaged"
    shutil.copytree(sweep, damaged)
    summary_path = damaged / rel / "summary.json"
    summary = json.loads(summary_path.read_text())
    summary["cars"] = summary["cars"][:2]
    summary_path.write_text(json.dumps(summary))
    run = cli("evaluate", damaged, tmp_path / "cf.npz")
    # A damaged dataset is bad input (it exited 1).
    assert run.returncode == 2 and "summary.json: names 2 cars" in run.stderr, run.stderr
    assert "is damaged: `causalcity validate" in run.stderr, run.stderr
    # On a gen dataset (no re-simulated runs), counterfactual and affected arrays are refused.
    for suffix in ("/counterfactual", "/affected"):
        np.savez(tmp_path / "wrong.npz", **{"cars08_edges50/test/00000" + suffix: np.zeros((3, 8, 2))})
        run = cli("evaluate", CITY, tmp_path / "wrong.npz")
        assert run.returncode == 2 and "counterfactual --sweep" in run.stderr, run.stderr


def test_predictions_made_on_one_sweep_are_refused_on_a_sweep_of_other_kinds(sweep, tmp_path):
    # The same spec swept with the kinds in another order intervenes otherwise on every pair.
    other = tmp_path / "other"
    run = cli("counterfactual", "--sweep", sweep.parent / "spec.json", "--no-images", "--quiet", "--kinds",
              "remove,stop", "--out", other)  # fmt: skip
    assert run.returncode == 0, run.stderr
    interventions = lambda root: [json.loads(p.read_text())["intervention"] for p in sorted(root.glob("*/*/*/summary.json"))]
    assert interventions(other) != interventions(sweep)
    affected = {
        p.parent.relative_to(sweep).as_posix(): np.linspace(0, 1, len(json.loads(p.read_text())["cars"]))
        for p in sweep.glob("*/*/*/summary.json")
    }
    causalcity.save_predictions(tmp_path / "made.npz", affected=affected, dataset=sweep)
    assert cli("evaluate", sweep, tmp_path / "made.npz").returncode == 0
    run = cli("evaluate", other, tmp_path / "made.npz")
    assert run.returncode == 2, run.stderr
    assert "--kinds stop,remove" in run.stderr and "--kinds remove,stop" in run.stderr, run.stderr
    # A record written before sweeps gave their kinds still scores.
    arrays = dict(np.load(tmp_path / "made.npz"))
    record = json.loads(arrays["causalcity-dataset"].tobytes())
    assert record.pop("kinds") == ["stop", "remove"]
    arrays["causalcity-dataset"] = np.frombuffer(json.dumps(record).encode(), dtype=np.uint8)
    np.savez(tmp_path / "older.npz", **arrays)
    assert cli("evaluate", other, tmp_path / "older.npz").returncode == 0
    # A kind named twice would record a sweep no other spelling matches: refused, nothing written.
    run = cli("counterfactual", "--sweep", sweep.parent / "spec.json", "--no-images", "--quiet", "--kinds",
              "stop,remove,stop", "--out", tmp_path / "twice")  # fmt: skip
    assert run.returncode == 2 and "stop is given twice" in run.stderr, run.stderr
    assert not (tmp_path / "twice").exists()


def test_a_packed_sweep_is_a_few_tar_files_read_scored_and_validated_as_its_folders(sweep, tmp_path):
    import tarfile

    from causalcity.methods.__main__ import main

    packed = tmp_path / "packed"
    args = ["counterfactual", "--sweep", sweep.parent / "spec.json", "--no-images", "--quiet", "--kinds", "stop,remove"]
    run = cli(*args, "--format", "tar", "--scenarios-per-tar", 4, "--out", packed)
    assert run.returncode == 0, run.stderr
    groups = causalcity.open_sweep(sweep).spec.groups
    # 2 train, 4 val and 6 test pairs per group: 1 + 1 + 2 tar files.
    tars = sorted(packed.rglob("*.tar"))
    assert len(tars) == 4 * len(groups)
    assert sorted(p for p in packed.rglob("*") if p.is_file()) == sorted(tars + [packed / "sweep.json"])
    folder_files = {p.relative_to(sweep).as_posix(): p.read_bytes() for p in sweep.rglob("*") if p.is_file()}
    assert len(folder_files) > 10 * (len(tars) + 1)
    # `tar -xf` of every pack gives the pair folders, byte for byte.
    unpacked = {}
    for path in tars:
        with tarfile.open(path) as tar:
            for member in tar:
                unpacked[member.name] = tar.extractfile(member).read()
    del folder_files["sweep.json"]
    assert unpacked.keys() == folder_files.keys()
    assert all(unpacked[name] == folder_files[name] for name in folder_files)
    # `pack` makes the same packs from the pair folders, byte for byte.
    repacked = tmp_path / "repacked"
    run = cli("pack", sweep, "--out", repacked, "--scenarios-per-tar", 4, "--quiet")
    assert run.returncode == 0 and f"into {len(tars)} tar files" in run.stdout, run.stdout + run.stderr
    mine = sorted(p.relative_to(packed) for p in packed.rglob("*") if p.is_file())
    assert mine == sorted(p.relative_to(repacked) for p in repacked.rglob("*") if p.is_file())
    assert all((packed / p).read_bytes() == (repacked / p).read_bytes() for p in mine)
    # The reader gives the same pairs.
    folders, packs = causalcity.open_sweep(sweep), causalcity.open_sweep(packed)
    assert packs.scenarios_per_tar == 4 and folders.scenarios_per_tar is None
    assert packs.keys() == folders.keys() and len(packs.keys()) == 12 * len(groups)
    for key in packs.keys():
        a, b = folders.load(key), packs.load(key)
        assert a.summary == b.summary and np.array_equal(a.divergence, b.divergence)
        for run_a, run_b in ((a.factual, b.factual), (a.counterfactual, b.counterfactual)):
            assert np.array_equal(run_a.position, run_b.position) and np.array_equal(run_a.pixels, run_b.pixels)
    # A reference method predicts the same from either, and evaluate scores both alike.
    reports = []
    for source in (sweep, packed):
        out = tmp_path / f"{source.name}.npz"
        assert main(["cf_constant_velocity", str(source), "--out", str(out), "--quiet"]) == 0
        reports.append(causalcity.evaluate(source, out))
    with np.load(tmp_path / f"{sweep.name}.npz") as a, np.load(tmp_path / "packed.npz") as b:
        assert sorted(a.files) == sorted(b.files) and all(np.array_equal(a[k], b[k]) for k in a.files)
    for kind in ("edges", "counterfactuals"):
        assert reports[0][kind] and reports[0][kind] == reports[1][kind], kind
    # validate reads the packs: clean, then a changed member named in its pack.
    run = cli("validate", packed)
    assert run.returncode == 0 and "valid" in run.stdout, run.stdout + run.stderr
    damaged = tars[0]
    with tarfile.open(damaged) as tar:
        members = [(m, tar.extractfile(m).read()) for m in tar]
    with tarfile.open(damaged, "w") as tar:
        for member, data in members:
            if member.name.endswith("/factual/poses.csv"):
                data = data.replace(b"0", b"1", 1)
            tar.addfile(member, io.BytesIO(data))
    run = cli("validate", packed)
    assert run.returncode == 1, run.stdout + run.stderr
    assert damaged.name in run.stdout and "factual/poses.csv: checksum mismatch" in run.stdout, run.stdout
    # A rerun writes that pack again and keeps the others; folders into it are refused.
    run = cli(*args, "--format", "tar", "--scenarios-per-tar", 4, "--out", packed)
    assert run.returncode == 0 and "writing the pack again" in run.stderr, run.stderr
    rewritten = len({member.name.split("/")[2] for member, _ in members})
    assert f"{rewritten} written now, {12 * len(groups) - rewritten} kept" in run.stdout, run.stdout
    assert cli("validate", packed).returncode == 0
    run = cli(*args, "--out", packed)
    assert run.returncode == 2 and "--format tar --scenarios-per-tar 4" in run.stderr, run.stderr


def test_a_held_out_test_split_is_marked_out_of_distribution_beside_the_in_distribution_rows(tmp_path):
    spec = json.loads((Path(__file__).resolve().parents[2] / "configs" / "ood-towns.json").read_text())
    spec["splits"] = {"train": 2, "val": 3, "test": 3}
    spec["frames"] = 20
    spec_file = tmp_path / "ood.json"
    spec_file.write_text(json.dumps(spec))
    data = tmp_path / "ood"
    generated = cli("gen", "--spec", str(spec_file), "--out", str(data), "--no-images", "--quiet")
    assert generated.returncode == 0, generated.stderr
    # The path rule's scores, written as any method's.
    methods = subprocess.run(
        [sys.executable, "-m", "causalcity.methods", "path", str(data), "--out", str(tmp_path / "p.npz"), "--quiet"],
        capture_output=True,
        text=True,
    )
    assert methods.returncode == 0, methods.stderr
    report = causalcity.evaluate(data, tmp_path / "p.npz")
    rows = {(r["graph"], r["split"]): r for r in report["edges"]}
    assert rows[("designed", "test")]["held_out"] is True
    assert "held_out" not in rows[("designed", "val")]
    text = cli("evaluate", str(data), str(tmp_path / "p.npz")).stdout
    assert "test* " in text and "held out from train" in text, text
    assert "val* " not in text
    towns = {json.loads(p.read_text())["town"] for p in data.glob("*/test/*/scenario.json")}
    assert towns == {"grid-4x4"}


def test_constant_scores_for_every_edge_are_scored_as_every_edge_called(tmp_path):
    # The best cut on val called every pair linked; the threshold then lay
    # below a positive score (F1 0, nothing called), above a negative one.
    data = causalcity.open_dataset(TOY, images=False)
    results = {}
    for value in (1.0, -1.0):
        edges = {k.folder: np.full((data.load(k).cars,) * 2, value) for k in data.keys() if k.split != "train"}
        path = tmp_path / f"const{value}.npz"
        causalcity.save_predictions(path, edges=edges, dataset=TOY)
        report = causalcity.evaluate(TOY, path)
        rows = report["scenarios"]
        results[value] = {r["scenario"]: (r["predicted_edges"], r["f1"]) for r in rows if r["split"] == "test"}
        # a score that cannot tell a -> b from b -> a is right half the time
        assert [e["direction"] for e in report["edges"]] == [0.5] * len(report["edges"]), report["edges"]
    assert results[1.0] and results[1.0] == results[-1.0], results
    assert all(predicted > 0 for predicted, _ in results[1.0].values()), results


def test_save_predictions_takes_keys_or_folders_and_refuses_what_it_would_change(tmp_path):
    data = causalcity.open_dataset(TOY, images=False)
    key = data.keys("test")[0]
    cars = data.load(key).cars
    by_key = tmp_path / "by-key.npz"
    causalcity.save_predictions(by_key, edges={key: np.eye(cars)})
    assert list(np.load(by_key).keys()) == [key.folder]
    for edges, says in [
        ({key.folder: np.eye(cars) * (1 + 1j)}, "complex numbers"),
        ({"causalcity-dataset": np.eye(cars)}, "is not a scenario folder"),
        ({3: np.eye(cars)}, "is not a scenario folder"),
        # Ragged rows: it raised numpy's ValueError.
        ({key.folder: [[0.1, 0.2], [0.3]]}, "is not an array of numbers"),
        # Names that are no folder, and dates, were written as given.
        ({"": np.eye(cars)}, "is not a scenario folder"),
        ({"../../etc/x": np.eye(cars)}, "is not a scenario folder"),
        ({"../test/00000": np.eye(cars)}, "is not a scenario folder"),
        ({key.folder + "/extra": np.eye(cars)}, "is not a scenario folder"),
        ({key.folder: np.full((cars, cars), "2020-01-01", dtype="datetime64[D]")}, "holds datetime64"),
        ({key.folder: np.ones((cars, cars)).astype("timedelta64[s]")}, "holds timedelta64"),
        ({key.folder: np.full((cars, cars), "0.5")}, "holds <U3"),
    ]:
        with pytest.raises(causalcity.InputError, match=says):
            causalcity.save_predictions(tmp_path / "bad.npz", edges=edges)
    assert not (tmp_path / "bad.npz").exists()
