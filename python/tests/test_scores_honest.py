"""Scores that cannot be fooled, and the reference table's simple rows:
predictions record the dataset they were made on and evaluate refuses any
other; a file without val predictions is flagged before its numbers; the
path rule and the supervised classifier are methods like any other."""

import json
import os
import shlex
import subprocess
import sys

import numpy as np
import pytest

import causalcity
from causalcity.methods import load_split, make

TOY = {
    "name": "honest-toy",
    "world": "toy",
    "seed": 3,
    "frames": 150,
    "groups": [{"cars": 4, "edge_proportion": 0.5}, {"cars": 8, "edge_proportion": 0.5}],
    "splits": {"train": 8, "val": 3, "test": 4},
}


def cli(*args):
    command = shlex.split(os.environ.get("CAUSALCITY_CLI", "target/release/causalcity"))
    return subprocess.run(command + [str(a) for a in args], capture_output=True, text=True)


def methods(*args):
    return subprocess.run(
        [sys.executable, "-m", "causalcity.methods", *[str(a) for a in args]], capture_output=True, text=True
    )


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = tmp_path_factory.mktemp("honest")
    made = {}
    for name, spec in {
        "toy": TOY,
        "toy_seed4": dict(TOY, seed=4),
        "toy_groups": dict(TOY, groups=[{"cars": 6, "edge_proportion": 0.5}]),
        "city": dict(TOY, world="city", name="honest-city"),
    }.items():
        made[name] = root / name
        causalcity.generate(spec, made[name], images=False, progress=False)
    return made


def test_predictions_made_on_another_dataset_are_refused_naming_both(data, tmp_path):
    pred = tmp_path / "path.npz"
    run = methods("path", data["toy"], "--out", pred, "--quiet")
    assert run.returncode == 0, run.stderr
    assert cli("evaluate", data["toy"], pred).returncode == 0
    # (Other groups: it was told by the first array naming no scenario there.)
    for other, says in (("toy_seed4", "seed 4"), ("city", "city world"), ("toy_groups", "score them against")):
        run = cli("evaluate", data[other], pred)
        assert run.returncode == 2, (other, run.stderr)
        assert "made on honest-toy (toy world, seed 3" in run.stderr and says in run.stderr, run.stderr
        with pytest.raises(causalcity.InputError, match="these predictions were made on"):
            causalcity.evaluate(data[other], pred)


def test_a_file_without_its_dataset_record_or_val_predictions_is_flagged(data, tmp_path):
    test = load_split(data["toy"], "cars04_edges50", "test")
    # Negative distances: a score on no probability scale.
    edges = {folder: -np.abs(np.random.default_rng(1).normal(size=(4, 4))) for folder in test.folders}
    pred = tmp_path / "bare.npz"
    causalcity.save_predictions(pred, edges)
    run = cli("evaluate", data["toy"], pred)
    assert run.returncode == 0, run.stderr
    first, second = run.stdout.splitlines()[:2]
    assert "does not say which dataset" in first, run.stdout
    assert second.startswith("warning: NO VAL PREDICTIONS for cars04_edges50 designed"), run.stdout
    header = next(line for line in run.stdout.splitlines() if line.startswith("graph"))
    assert header.index("AUROC") < header.index("threshold") < header.index("F1"), header
    as_json = json.loads(cli("evaluate", data["toy"], pred, "--json").stdout)
    assert len(as_json["warnings"]) == 2 and as_json["edges"][0]["threshold_from"] == "default"
    with pytest.warns(UserWarning, match="NO VAL PREDICTIONS"):
        causalcity.evaluate(data["toy"], pred)
    # A threshold given, and the file's record: nothing to flag.
    causalcity.save_predictions(pred, edges, dataset=data["toy"])
    assert json.loads(cli("evaluate", data["toy"], pred, "--threshold=-1", "--json").stdout)["warnings"] == []


def test_the_path_rule_finds_the_toy_edges_and_learns_its_lag_on_train(data):
    rule = make("path")
    train = load_split(data["toy"], "cars08_edges50", "train")
    test = load_split(data["toy"], "cars08_edges50", "test")
    rule.fit(train, None)
    assert rule.lag_s in rule.LAGS_S and rule.aurocs[rule.lag_s] == max(rule.aurocs.values())
    scores = rule.predict(test).edges
    off = ~np.eye(8, dtype=bool)
    linked, unlinked = scores[:, off][test.graph[:, off] == 1], scores[:, off][test.graph[:, off] == 0]
    # In the toy world a follower drives exactly its leader's path: every link outranks every non-link.
    assert linked.size and unlinked.size and linked.min() > unlinked.max()


def test_the_path_rule_and_the_supervised_classifier_are_rows_evaluate_scores(data, tmp_path):
    scored = {}
    for name in ("path", "supervised", "frame0"):
        pred = tmp_path / f"{name}.npz"
        run = methods(name, data["city"], "--out", pred, "--quiet")
        assert run.returncode == 0, run.stderr
        report = causalcity.evaluate(data["city"], pred)
        assert report["warnings"] == []
        scored[name] = {e["group"]: e["auroc"] for e in report["edges"] if e["split"] == "test"}
    for group in ("cars04_edges50", "cars08_edges50"):
        assert scored["path"][group] > 0.7, scored
        assert scored["supervised"][group] > 0.6, scored


def test_a_group_whose_val_holds_no_link_takes_the_pooled_val_threshold_not_a_false_warning(tmp_path):
    # Val predictions of a group without links (edge_proportion 0) were
    # told "NO VAL PREDICTIONS" and called at a fixed 0.5, which for
    # scores on no probability scale (negative distances) calls nothing.
    spec = dict(TOY, name="unlinked", groups=[{"cars": 4, "edge_proportion": 0.5}, {"cars": 4, "edge_proportion": 0.0}])
    data = tmp_path / "data"
    causalcity.generate(spec, data, images=False, progress=False)
    rng = np.random.default_rng(2)
    edges = {}
    for group in ("cars04_edges50", "cars04_edges00"):
        for split in ("val", "test"):
            part = load_split(data, group, split)
            for folder, graph in zip(part.folders, part.graph):
                # Negative distances: linked pairs from -0.6 to -0.5, the
                # others from -2 to -1.
                edges[folder] = np.where(graph == 1, -0.5 - 0.1 * rng.random((4, 4)), -1.0 - rng.random((4, 4)))
    pred = tmp_path / "scores.npz"
    causalcity.save_predictions(pred, edges, dataset=data)
    report = json.loads(cli("evaluate", data, pred, "--json").stdout)
    rows = {(r["group"], r["split"]): r for r in report["edges"]}
    assert rows[("cars04_edges50", "test")]["threshold_from"] == "val"
    unlinked = rows[("cars04_edges00", "test")]
    assert unlinked["threshold_from"] == "pooled", unlinked
    # The best F1 on both groups' val together: between the linked and
    # the unlinked scores, so nothing of the unlinked group is called.
    assert -1.0 <= unlinked["threshold"] <= -0.6 and unlinked["predicted_edges"] == 0, unlinked
    assert not any("NO VAL PREDICTIONS" in w for w in report["warnings"]), report["warnings"]
    assert any("no true link in val for cars04_edges00 designed" in w for w in report["warnings"]), report["warnings"]
    # No group's val with a link: 0.5, and said so (not "no val predictions").
    only = tmp_path / "only-unlinked.npz"
    causalcity.save_predictions(only, {k: v for k, v in edges.items() if "edges00" in k}, dataset=data)
    report = json.loads(cli("evaluate", data, only, "--json").stdout)
    row = next(r for r in report["edges"] if r["split"] == "test")
    assert row["threshold_from"] == "default" and row["threshold"] == 0.5, row
    assert [w for w in report["warnings"] if "NO TRUE LINK IN VAL for cars04_edges00 designed" in w], report["warnings"]
    assert not any("NO VAL PREDICTIONS" in w for w in report["warnings"]), report["warnings"]
