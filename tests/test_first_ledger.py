"""The FIRST benchmark's ledger (bench/first_ledger.py): finished cells leave OUT for the repository and come
back into a new OUT only when the settings and the demonstrations are the same."""

import json
import shutil
from pathlib import Path

import pytest

from bench.first_config import CELLS
from bench.first_ledger import (
    SAME_SETTINGS,
    _key,
    demos_fingerprint,
    export_cells,
    finished_cells,
    import_cells,
    next_weights_digest,
)

RESULTS = Path(__file__).resolve().parents[1] / "results"
CONFIG = {"obs": "state", "rollouts": 4, "steps": 100, "batch": 8, "policy": "flow",
          "thresholds": "recording", "max_seconds": None, "preset": "", "include_failed": False,
          "actions": "absolute", "eval_seed": 15,
          "demos_from": {"wipe": ["/somewhere"]}}


def _cell(out, task, cell, seed, success, rollout=True, score="l1"):
    run = out / task / cell / f"seed{seed}"
    run.mkdir(parents=True)
    train = {"task": task, "cell": cell, "seed": seed, "cpu_s": 1.0}
    if score != "l1":  # the training's phases record a score other than the default (labelling.py)
        train["phases"] = {"t_low": 0.5, "t_high": 0.9, "score": score}
    (run / "train.json").write_text(json.dumps(train))
    if rollout:
        eps = [{"seed": 1500000 + i, "outcome": "success" if s else "failure"} for i, s in enumerate(success)]
        (run / "rollout.json").write_text(json.dumps({"task": task, "cell": cell, "seed": seed,
                                                      "episodes": eps, "cpu_s": 2.0}))


def _summary(progress=1.0):
    return {"results": [{"seed": 100003, "outcome": "success", "progress": progress, "duration_s": 12.5,
                         "t_start": 1.0, "t_end": 13.5}]}


def test_fingerprint_changes_with_any_episode_or_the_estimator():
    a = demos_fingerprint(_summary(), "abc")
    assert a == demos_fingerprint(_summary(), "abc")
    assert a != demos_fingerprint(_summary(progress=0.75), "abc")
    assert a != demos_fingerprint(_summary(), "abd")


def test_only_cells_with_training_and_rollouts_are_finished(tmp_path):
    _cell(tmp_path, "wipe", "first", 0, [1, 0])
    _cell(tmp_path, "wipe", "first", 1, [], rollout=False)  # trained, not rolled out
    assert [c["rollout"]["seed"] for c in finished_cells(tmp_path)] == [0]


def test_cells_go_to_the_ledger_and_back_when_the_demonstrations_match(tmp_path):
    out, ledger = tmp_path / "s16", tmp_path / "cells.json"
    _cell(out, "wipe", "first", 0, [1, 0, 1])
    _cell(out, "wipe", "base-torque", 0, [0, 0, 1])
    _cell(out, "peg-insert", "first", 0, [1])  # its demonstrations have no fingerprint: not exported
    assert export_cells(out, ledger, {"wipe": "f1"}, CONFIG, session="s16") == 2
    assert export_cells(out, ledger, {"wipe": "f1"}, CONFIG) == 0  # kept once
    new = tmp_path / "s17"
    n, skipped = import_cells(new, ledger, {"wipe": "f1"}, dict(CONFIG, demos_from={"wipe": ["/elsewhere"]}))
    assert n == 2 and not skipped
    got = json.loads((new / "wipe" / "first" / "seed0" / "rollout.json").read_text())
    assert [e["outcome"] for e in got["episodes"]] == ["success", "failure", "success"]
    assert (new / "wipe" / "base-torque" / "seed0" / "train.json").is_file()


def test_other_demonstrations_or_settings_import_nothing(tmp_path):
    out, ledger = tmp_path / "a", tmp_path / "cells.json"
    _cell(out, "wipe", "first", 0, [1])
    export_cells(out, ledger, {"wipe": "f1"}, CONFIG)
    n, skipped = import_cells(tmp_path / "b", ledger, {"wipe": "f2"}, CONFIG)
    assert n == 0 and "other demonstrations" in skipped[0]
    n, skipped = import_cells(tmp_path / "c", ledger, {"wipe": "f1"}, dict(CONFIG, steps=8000))
    assert n == 0 and "other settings" in skipped[0]
    with pytest.raises(SystemExit, match="other settings"):
        export_cells(out, ledger, {"wipe": "f1"}, dict(CONFIG, rollouts=32))


def test_a_cell_already_in_out_is_not_overwritten(tmp_path):
    out, ledger = tmp_path / "a", tmp_path / "cells.json"
    _cell(out, "wipe", "first", 0, [1])
    export_cells(out, ledger, {"wipe": "f1"}, CONFIG)
    new = tmp_path / "b"
    _cell(new, "wipe", "first", 0, [0, 0])
    assert import_cells(new, ledger, {"wipe": "f1"}, CONFIG)[0] == 0
    assert len(json.loads((new / "wipe" / "first" / "seed0" / "rollout.json").read_text())["episodes"]) == 2


def test_weights_digest_reads_the_weights_beside_the_json(tmp_path):
    (tmp_path / "next.json").write_text("{}")
    (tmp_path / "next.safetensors").write_bytes(b"w1")
    a = next_weights_digest(tmp_path / "next.json")
    (tmp_path / "next.safetensors").write_bytes(b"w2")
    assert a and a != next_weights_digest(tmp_path / "next.json")
    assert next_weights_digest(tmp_path / "none" / "next.json") == ""


def test_a_mismatch_names_the_mujoco_version_it_was_collected_under(tmp_path):
    out, ledger = tmp_path / "a", tmp_path / "cells.json"
    _cell(out, "wipe", "first", 0, [1])
    export_cells(out, ledger, {"wipe": "f1"}, CONFIG)
    data = json.loads(ledger.read_text())
    assert set(data["cells"][0]["env"]) == {"mujoco", "numpy", "torch"}
    n, skipped = import_cells(tmp_path / "b", ledger, {"wipe": "f2"}, CONFIG)
    assert n == 0 and skipped[0].endswith("runs again")  # same MuJoCo: nothing to add
    data["cells"][0]["env"]["mujoco"] = "0.0.1"
    ledger.write_text(json.dumps(data))
    _, skipped = import_cells(tmp_path / "c", ledger, {"wipe": "f2"}, CONFIG)
    assert "collected under MuJoCo 0.0.1" in skipped[0] and "pip install mujoco==0.0.1" in skipped[0]
    del data["cells"][0]["env"]
    ledger.write_text(json.dumps(data))
    _, skipped = import_cells(tmp_path / "d", ledger, {"wipe": "f2"}, CONFIG)
    assert "MuJoCo version was not recorded" in skipped[0]


def test_a_seed_whose_pair_is_whole_on_another_collection_is_taken(tmp_path):
    out, ledger = tmp_path / "a", tmp_path / "cells.json"
    for cell in ("first", "base-torque"):
        _cell(out, "wipe", cell, 0, [1])
    _cell(out, "wipe", "first", 1, [0])  # seed 1: half a pair
    export_cells(out, ledger, {"wipe": "f1"}, CONFIG)
    needed = {"wipe": ["base-torque", "first"]}
    n, skipped = import_cells(tmp_path / "b", ledger, {"wipe": "f2"}, CONFIG, needed=needed)
    assert n == 2 and (tmp_path / "b" / "wipe" / "base-torque" / "seed0" / "rollout.json").is_file()
    assert not (tmp_path / "b" / "wipe" / "first" / "seed1").exists()  # trains again, beside its partner
    assert sum("runs again" in s for s in skipped) == 1 and sum("pair whole" in s for s in skipped) == 2
    n, _ = import_cells(tmp_path / "c", ledger, {"wipe": "f2"}, CONFIG,
                        needed={"wipe": ["base-torque", "first", "base"]})  # the run needs a third
    assert n == 0


def test_cells_the_run_does_not_train_are_not_listed_as_running_again(tmp_path):
    out, ledger = tmp_path / "a", tmp_path / "cells.json"
    _cell(out, "wipe", "base-torque", 0, [1])
    _cell(out, "peg-insert", "first", 0, [1])
    export_cells(out, ledger, {"wipe": "f1", "peg-insert": "p1"}, CONFIG)
    # a run of the second table on peg-insert, on another collection: wipe and base-torque are not its cells
    n, skipped = import_cells(tmp_path / "b", ledger, {"peg-insert": "p2"}, CONFIG,
                              needed={"peg-insert": ["base", "first"]})
    assert n == 0 and len(skipped) == 1 and skipped[0].startswith("peg-insert first seed 0")
    # on the run's own collection a cell it does not train still comes in, shown beside its table
    n, skipped = import_cells(tmp_path / "c", ledger, {"wipe": "f1"}, CONFIG, needed={"wipe": ["base"]})
    assert n == 1 and skipped == []


def test_an_unrecorded_setting_matches_nothing_recorded(tmp_path):
    out, ledger = tmp_path / "a", tmp_path / "cells.json"
    _cell(out, "wipe", "first", 0, [1])
    export_cells(out, ledger, {"wipe": "f1"}, CONFIG)  # CONFIG has no precision: no default is assumed
    for p in ("fp32", "bf16"):
        n, why = import_cells(tmp_path / p, ledger, {"wipe": "f1"}, {**CONFIG, "precision": p})
        assert n == 0 and "other settings" in why[0]


def test_every_committed_ledger_records_every_setting():
    """So a ledger means what it says, with no default for a setting it lacks (results/README.md)."""
    ledgers = sorted((Path(__file__).resolve().parents[1] / "results").glob("first_cells*.json"))
    assert ledgers
    for p in ledgers:
        settings = json.loads(p.read_text())["settings"]
        assert set(SAME_SETTINGS) <= set(settings), p.name  # null: not recorded then, matches no run


def test_cells_labelled_by_the_earlier_rule_are_not_mixed_with_contact_runs(tmp_path):
    from policies.labels.phases import LABEL_RULE

    out, ledger = tmp_path / "a", tmp_path / "cells.json"
    _cell(out, "wipe", "first", 0, [1])
    export_cells(out, ledger, {"wipe": "f1"}, CONFIG)  # CONFIG has no labels: a ledger from before the rule
    n, why = import_cells(tmp_path / "b", ledger, {"wipe": "f1"}, {**CONFIG, "labels": LABEL_RULE})
    assert n == 0 and "other settings" in why[0]
    with pytest.raises(SystemExit, match="another ledger"):
        export_cells(out, ledger, {"wipe": "f1"}, {**CONFIG, "labels": LABEL_RULE})


def test_first_motion_is_its_own_cell_beside_first(tmp_path):
    out, ledger = tmp_path / "a", tmp_path / "cells.json"
    _cell(out, "cap-screw", "first", 0, [1, 0])
    _cell(out, "cap-screw", "first-motion", 0, [0, 0, 1], score="motion")
    assert export_cells(out, ledger, {"cap-screw": "f1"}, CONFIG) == 2
    keys = {(c["rollout"]["cell"], _key(c)[3]) for c in json.loads(ledger.read_text())["cells"]}
    assert keys == {("first", "l1"), ("first-motion", "motion")}
    new = tmp_path / "b"
    n, skipped = import_cells(new, ledger, {"cap-screw": "f1"}, CONFIG,
                              needed={"cap-screw": ["base-torque", "first", "first-motion"]})
    assert n == 2 and not skipped
    got = {c: len(json.loads((new / "cap-screw" / c / "seed0" / "rollout.json").read_text())["episodes"])
           for c in ("first", "first-motion")}
    assert got == {"first": 2, "first-motion": 3}
    # a motion-labelled cell is never a first cell, a first cell never a first-motion one
    _cell(tmp_path / "c", "cap-screw", "first", 1, [1], score="motion")
    with pytest.raises(SystemExit, match="contact score motion, the cell's is l1"):
        export_cells(tmp_path / "c", ledger, {"cap-screw": "f1"}, CONFIG)


def test_a_ledger_cell_whose_score_is_not_its_names_is_not_taken(tmp_path):
    out, ledger = tmp_path / "a", tmp_path / "cells.json"
    _cell(out, "cap-screw", "first", 0, [1])
    _cell(out, "cap-screw", "base-torque", 0, [1])
    export_cells(out, ledger, {"cap-screw": "f1"}, CONFIG)
    data = json.loads(ledger.read_text())
    data["cells"][1]["train"]["phases"] = {"score": "motion"}  # first, as if trained on the motion labels
    ledger.write_text(json.dumps(data))
    needed = {"cap-screw": ["base-torque", "first"]}
    n, skipped = import_cells(tmp_path / "b", ledger, {"cap-screw": "f1"}, CONFIG, needed=needed)
    assert n == 1 and skipped == ["cap-screw first seed 0: trained with contact score motion, the cell's "
                                  "is l1: not taken"]
    # nor does it make its seed's pair whole on another collection
    n, skipped = import_cells(tmp_path / "c", ledger, {"cap-screw": "f2"}, CONFIG, needed=needed)
    assert n == 0 and sum("runs again" in s for s in skipped) == 1


@pytest.mark.parametrize("name", [p.name for p in sorted(RESULTS.glob("first_cells*.json"))])
def test_committed_ledgers_load_their_cells_as_before(tmp_path, name):
    """Every cell of every committed ledger (a copy: the running benchmark writes them) comes back into a
    new OUT on its own demonstrations, keyed with the score its cell trains with (first-motion: motion, every
    other: l1), and a ledger written back is the same."""
    ledger = tmp_path / name
    shutil.copy(RESULTS / name, ledger)
    data = json.loads(ledger.read_text())
    groups: dict = {}
    for c in data["cells"]:
        assert c["rollout"]["cell"] in CELLS and _key(c)[3] == CELLS[c["rollout"]["cell"]].score
        groups.setdefault((c["rollout"]["task"], c["demos_fingerprint"]), []).append(c)
    for i, ((task, fp), cells) in enumerate(sorted(groups.items())):
        out = tmp_path / f"out{i}"
        n, skipped = import_cells(out, ledger, {task: fp}, data["settings"], needed={task: []})
        assert n == len(cells), skipped
        for c in cells:
            run = out / task / c["rollout"]["cell"] / f"seed{c['rollout']['seed']}"
            assert json.loads((run / "rollout.json").read_text()) == c["rollout"]
        before = ledger.read_bytes()
        assert export_cells(out, ledger, {task: fp}, data["settings"]) == 0
        assert json.loads(ledger.read_bytes()) == json.loads(before)
