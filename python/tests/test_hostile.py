"""Nothing destroyed by a careless path or a hostile file: predictions files
that lie about their sizes are refused within a memory limit, no command or
function writes into a dataset, onto its input or through a link, and every
bad argument is an error that names it, never a traceback."""

import io
import json
import os
import resource
import shlex
import struct
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

import causalcity

SPEC = {
    "name": "hostile",
    "world": "toy",
    "seed": 3,
    "frames": 30,
    "groups": [{"cars": 4, "edge_proportion": 0.5}],
    "splits": {"train": 2, "val": 1, "test": 1},
}
GROUP = "cars04_edges50"
TEST = f"{GROUP}/test/00000"
MEMORY_LIMIT = 400 << 20
"""Address space the hostile-file runs get (bytes): far below what a
believed declared size would take."""


def cli(*args, limit=None):
    command = shlex.split(os.environ.get("CAUSALCITY_CLI", "target/release/causalcity"))
    if limit is not None:
        # The binary itself, not cargo, under the limit.
        binary = Path("target/release/causalcity")
        assert binary.is_file(), "make test-python builds target/release/causalcity"
        command = [str(binary)]

    def cap():
        if limit is not None:
            resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    return subprocess.run(command + [str(a) for a in args], capture_output=True, text=True, preexec_fn=cap)


def methods(*args):
    return subprocess.run(
        [sys.executable, "-m", "causalcity.methods", *[str(a) for a in args]], capture_output=True, text=True
    )


def tree(root):
    """Every file under root with its bytes: what a refusal must leave alone."""
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(Path(root).rglob("*")) if p.is_file()}


def assert_valid(dataset):
    run = cli("validate", dataset)
    assert run.returncode == 0, run.stdout + run.stderr


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    out = tmp_path_factory.mktemp("hostile") / "toy"
    causalcity.generate(SPEC, out, images=False, progress=False)
    return out


def npy_bytes(array):
    buffer = io.BytesIO()
    np.save(buffer, array)
    return buffer.getvalue()


def scores():
    return np.arange(16, dtype=np.float64).reshape(4, 4) / 16


def lying_zip64(path, declared):
    """A small stored entry whose central directory declares `declared`
    bytes (a zip64 size): what numpy's reader would never write."""
    with zipfile.ZipFile(path, "w", allowZip64=True) as z:
        z.writestr(f"{TEST}.npy", npy_bytes(scores()))
        z.filelist[0].file_size = declared
    assert path.stat().st_size < 8 * 1024


def bomb(path, lie):
    """1 GB of zeros after a valid [4, 4] header, deflated to about 1 MB;
    with `lie`, the directory says the entry holds 128 bytes."""
    header = npy_bytes(scores())[:128]
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as z:
        with z.open(f"{TEST}.npy", "w", force_zip64=True) as f:
            f.write(header)
            zeros = bytes(1 << 20)
            for _ in range(1024):
                f.write(zeros)
        if lie:
            z.filelist[0].file_size = 128
    assert path.stat().st_size < 8 << 20


@pytest.mark.parametrize("declared", [2**62, 2**63, 2**64 - 1])
def test_a_declared_size_is_never_believed(toy, tmp_path, declared):
    path = tmp_path / "declared.npz"
    lying_zip64(path, declared)
    run = cli("evaluate", toy, path, limit=MEMORY_LIMIT)
    assert run.returncode == 2, (run.returncode, run.stderr)
    assert str(path) in run.stderr and TEST in run.stderr and "more than any array" in run.stderr, run.stderr
    # From Python: an InputError, and the interpreter lives on.
    with pytest.raises(causalcity.InputError):
        causalcity.evaluate(toy, path)


@pytest.mark.parametrize("lie", [False, True])
def test_a_zip_bomb_is_refused_within_a_memory_limit(toy, tmp_path, lie):
    path = tmp_path / "bomb.npz"
    bomb(path, lie)
    run = cli("evaluate", toy, path, limit=MEMORY_LIMIT)
    assert run.returncode == 2, (run.returncode, run.stderr)
    assert TEST in run.stderr and "more than any array of its kind" in run.stderr, run.stderr


def test_an_npy_header_that_declares_a_huge_shape_is_refused(toy, tmp_path):
    path = tmp_path / "shape.npz"
    header = "{'descr': '<f8', 'fortran_order': False, 'shape': (4294967296, 4294967296), }"
    body = b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header.encode()
    with zipfile.ZipFile(path, "w") as z:
        z.writestr(f"{TEST}.npy", body)
    run = cli("evaluate", toy, path, limit=MEMORY_LIMIT)
    assert run.returncode == 2 and "declares shape" in run.stderr, run.stderr


@pytest.mark.filterwarnings("ignore:Duplicate name")
def test_duplicate_names_truncated_data_and_float16(toy, tmp_path):
    dup = tmp_path / "dup.npz"
    with zipfile.ZipFile(dup, "w") as z:
        for value in (0.0, 1.0):
            z.writestr(f"{TEST}.npy", npy_bytes(np.full((4, 4), value)))
    run = cli("evaluate", toy, dup)
    assert run.returncode == 2 and "twice" in run.stderr and TEST in run.stderr, run.stderr

    cut = tmp_path / "cut.npz"
    with zipfile.ZipFile(cut, "w") as z:
        z.writestr(f"{TEST}.npy", npy_bytes(scores())[:-20])
    run = cli("evaluate", toy, cut)
    assert run.returncode == 2 and "is truncated" in run.stderr, run.stderr
    assert "fill whole buffer" not in run.stderr

    # float16 holds k/16 exactly: the same report as float64.
    half, full = tmp_path / "half.npz", tmp_path / "full.npz"
    np.savez(half, **{TEST: scores().astype(np.float16)})
    np.savez(full, **{TEST: scores()})
    assert causalcity.evaluate(toy, half)["edges"] == causalcity.evaluate(toy, full)["edges"]


def test_evaluate_csv_and_save_predictions_never_write_into_the_dataset_or_onto_the_input(toy, tmp_path):
    pred = tmp_path / "pred.npz"
    causalcity.save_predictions(pred, {TEST: scores()})
    before, pred_bytes = tree(toy), pred.read_bytes()
    for target in (toy / "manifest.json", toy / "extra.csv", pred):
        with pytest.raises(causalcity.InputError):
            causalcity.evaluate(toy, pred, csv=target)
    with pytest.raises(causalcity.InputError, match="inside a gen dataset"):
        causalcity.save_predictions(toy / GROUP / "pred.npz", {TEST: scores()})
    assert tree(toy) == before and pred.read_bytes() == pred_bytes
    assert_valid(toy)
    out = tmp_path / "report.csv"
    causalcity.evaluate(toy, pred, csv=out)
    assert GROUP in out.read_text()


def test_methods_out_is_checked_before_any_work_and_bad_input_exits_2(toy, tmp_path):
    before = tree(toy)
    pixels = toy / TEST / "pixels.npy"
    a_file = tmp_path / "a-file"
    a_file.write_text("x")
    for out, says in [
        (toy / "manifest.json", "inside a gen dataset"),
        (pixels, "inside a gen dataset"),
        (tmp_path, "is a folder"),
        (a_file / "pred.npz", "is a file"),
    ]:
        run = methods("constant_velocity", toy, "--out", out)
        assert run.returncode == 2, (out, run.stderr)
        assert says in run.stderr and "Traceback" not in run.stderr, run.stderr
    for args, says in [
        (["nri", "--device", "bogus"], "device='bogus'"),
        (["nri", "--epochs", "-1"], "use 1 or more"),
        (["nri", "--epochs", "0"], "use 1 or more"),
        (["nri_trail", "--decoder", "rnn"], "give those to nri instead"),
        (["granger", "--split", "test", "--group", "cars99_edges50"], "cars99_edges50"),
    ]:
        run = methods(args[0], toy, "--out", tmp_path / "p.npz", *args[1:])
        assert run.returncode == 2, (args, run.returncode, run.stderr)
        assert says in run.stderr and "Traceback" not in run.stderr, run.stderr
    assert not (tmp_path / "p.npz").exists()
    assert tree(toy) == before
    assert_valid(toy)


@pytest.mark.parametrize("damage", ["scenario.json", "poses.csv"])
def test_a_damaged_dataset_file_is_named_with_exit_1(toy, tmp_path, damage):
    copy = tmp_path / "copy"
    for rel, data in tree(toy).items():
        (copy / rel).parent.mkdir(parents=True, exist_ok=True)
        (copy / rel).write_bytes(data)
    damaged = copy / GROUP / "train" / "00001" / damage
    damaged.write_text("{ not json" if damage == "scenario.json" else "")
    run = methods("constant_velocity", copy, "--out", tmp_path / "p.npz")
    assert run.returncode == 2, (run.returncode, run.stderr)  # a damaged dataset is bad input
    assert str(damaged) in run.stderr and "Traceback" not in run.stderr, run.stderr


def test_generate_into_an_empty_path_is_refused_like_out_dot(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine.txt").write_text("the user's")
    with pytest.raises(causalcity.InputError, match="empty path"):
        causalcity.generate(SPEC, "", images=False, progress=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine.txt"]


def test_bad_loader_arguments_are_input_errors_naming_them():
    with pytest.raises(causalcity.InputError, match="split=None"):
        causalcity.batches(SPEC, None, 2)
    with pytest.raises(causalcity.InputError, match="groups='cars04_edges50' is one string"):
        causalcity.batches(SPEC, "train", 2, groups=GROUP)
    with pytest.raises(causalcity.InputError, match="item 0 is None"):
        causalcity.collate([None])
    with pytest.raises(causalcity.InputError, match="at least one"):
        causalcity.collate([])


def test_set_epoch_reaches_persistent_workers():
    torch = pytest.importorskip("torch")
    spec = dict(SPEC, splits={"train": 12, "val": 1, "test": 1})

    def epochs(**loader):
        batches = causalcity.batches(spec, "train", 2, seed=4)
        data = torch.utils.data.DataLoader(batches, batch_size=None, **loader)
        seen = []
        for epoch in range(3):
            batches.set_epoch(epoch)
            seen.append(sorted(tuple(b["key"][0]) + tuple(b["key"][1]) for b in data))
        return seen

    reference = epochs(num_workers=0)
    assert reference[0] != reference[1] != reference[2], "each epoch its own batches"
    assert epochs(num_workers=2, persistent_workers=True) == reference


def test_a_scenario_folder_missing_from_a_complete_dataset_is_named_not_skipped(toy, tmp_path):
    copy = tmp_path / "copy"
    for rel, data in tree(toy).items():
        (copy / rel).parent.mkdir(parents=True, exist_ok=True)
        (copy / rel).write_bytes(data)
    split = copy / GROUP / "val"
    gone = sorted(p for p in split.iterdir())[0]
    for f in gone.iterdir():
        f.unlink()
    gone.rmdir()
    run = methods("path", copy, "--out", tmp_path / "p.npz")
    assert run.returncode == 2, (run.returncode, run.stderr)
    assert str(split) in run.stderr and "manifest.json lists" in run.stderr and "Traceback" not in run.stderr
    assert not (tmp_path / "p.npz").exists()
    # A scenario still being written (hidden) is not one of the finished.
    gone.with_name(".partial-" + gone.name).mkdir()
    from causalcity.methods import load_split

    with pytest.raises(RuntimeError, match="manifest.json lists"):
        load_split(copy, GROUP, "val")
    with pytest.raises(causalcity.InputError, match="'training' is not one of train, val, test"):
        load_split(toy, GROUP, "training")
