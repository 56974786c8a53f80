"""Published results name no folder of the machine they ran on (bench/portable.py): the pure functions, the
FIRST ledger's export and import through them, and every committed result and TUI capture."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench.portable import fix, ledger_cell, machine_paths, portable, portable_path, portable_text

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("path,want", [
    ("/scratch/run1", "OUT"),
    ("/scratch/run1/peg-insert/PC+C/seed0", "OUT/peg-insert/PC+C/seed0"),
    ("/scratch/run1/demos/state", "DEMOS/state"),  # the longer root first
    (str(REPO / "docs" / "first_cells.json"), "docs/first_cells.json"),
    ("/work/fb/e1/run/checkpoints/step-0008000.json", "SCRATCH/fb/e1/run/checkpoints/step-0008000.json"),
    ("/tmp", "SCRATCH"),
    ("/dev/ttyUSB0", "/dev/ttyUSB0"),  # a device: the same on every machine
    ("results/first_cells.json", "results/first_cells.json"),  # relative: portable already
])
def test_portable_path(path, want):
    assert portable_path(path, {"OUT": "/scratch/run1", "DEMOS": "/scratch/run1/demos"}) == want


def test_portable_text_finds_every_path_and_nothing_else():
    cmd = ("python -m bench.bench_first --out /scratch/run1 --demos-from peg-insert=/d/peg1+/d/peg9 "
           "--ledger results/first_cells.json (5 / 32, p/s, https://example.org/a, root@vm:/work/x)")
    assert portable_text(cmd, {"OUT": "/scratch/run1"}) == (
        "python -m bench.bench_first --out OUT --demos-from peg-insert=SCRATCH/peg1+SCRATCH/peg9 "
        "--ledger results/first_cells.json (5 / 32, p/s, https://example.org/a, root@vm:SCRATCH/x)")
    assert machine_paths(cmd) == ["/scratch/run1", "/d/peg1", "/d/peg9", "/work/x"]
    assert machine_paths(portable_text(cmd)) == []


def test_portable_keeps_the_shape_and_everything_not_a_path():
    data = {"out": "/scratch/run1", "n": [1, 2.5, None, True], "demos_from": {"wipe": ["/scratch/run1/w"]}}
    assert portable(data, {"OUT": "/scratch/run1"}) == {"out": "OUT", "n": [1, 2.5, None, True],
                                                        "demos_from": {"wipe": ["OUT/w"]}}
    assert fix(data) == portable(data, {"OUT": "/scratch/run1"})  # a result's own `out` is its OUT


def test_a_ledger_cell_names_its_run_from_its_own_out():
    cell = {"train": {"run": "/a/out_w/wipe/first/seed1"}, "rollout": {"policy": "/a/out_w/wipe/first/seed1"}}
    assert ledger_cell(cell) == {"train": {"run": "OUT/wipe/first/seed1"},
                                 "rollout": {"policy": "OUT/wipe/first/seed1"}}


def test_the_ledger_exports_portable_runs_and_imports_them_into_the_new_out(tmp_path, monkeypatch):
    import bench.first_ledger as L

    monkeypatch.setattr(L, "environment", lambda: {"mujoco": "x"})
    out, out2, ledger = tmp_path / "out", tmp_path / "again", tmp_path / "cells.json"
    run = out / "wipe" / "first" / "seed0"
    run.mkdir(parents=True)
    (run / "train.json").write_text(json.dumps({"task": "wipe", "run": str(run)}))
    (run / "rollout.json").write_text(json.dumps({"task": "wipe", "cell": "first", "seed": 0}))
    assert L.export_cells(out, ledger, {"wipe": "fp"}, {}) == 1
    text = ledger.read_text()
    assert machine_paths(text) == []
    assert json.loads(text)["cells"][0]["train"]["run"] == "OUT/wipe/first/seed0"
    assert L.import_cells(out2, ledger, {"wipe": "fp"}, {}) == (1, [])
    again = json.loads((out2 / "wipe" / "first" / "seed0" / "train.json").read_text())
    assert again["run"] == str(out2 / "wipe" / "first" / "seed0")  # the folder it is in now


def _files():
    results = sorted((REPO / "results").glob("*.json"))
    return [*results, *sorted((REPO / "docs" / "tui_captures").glob("*.txt"))]


@pytest.mark.parametrize("path", _files(), ids=lambda p: p.name)
def test_no_committed_result_or_capture_names_a_machine_folder(path):
    """The TUI captures keep the scratch folders their scripts make in /tmp (docs/tui_captures/*.sh set them:
    the same on every machine that runs the script); nothing else. A result with one: `python -m
    bench.portable --fix FILE`."""
    left = machine_paths(path.read_text())
    if path.suffix == ".txt":
        left = [p for p in left if not p.startswith("/tmp/")]
    assert left == [], f"{path.name}: {sorted(set(left))[:5]}"
