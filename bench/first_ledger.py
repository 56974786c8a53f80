"""Finished FIRST benchmark cells, carried across runs (issue #31).

A cell -- (task, cell, training seed, and the contact score its labels split) -- is finished when its
training and its rollouts are; their results are small JSON files in OUT/TASK/CELL/seedN
(bench/bench_first.py). The score is read from what the training recorded: a cell whose score is not the one
its name trains with (bench/first_config.py CELLS: first l1, first-motion motion) is never exported or
taken. A table takes longer than one sitting on two cores, and the scratch folder does not outlive the
machine: the repository does. So:

- `export_cells(out, ledger, ...)` merges the finished cells of OUT into a ledger file in the repository
  (results/first_cells.json), each with the fingerprint of the demonstrations and the NEXT checkpoint it was
  trained on;
- `import_cells(out, ledger, ...)` writes a ledger's cells back into a new OUT, so its queue skips them, when
  the settings that shape a result are the same and the demonstrations are the same (re-collected with the
  same seeds and the same committed NEXT checkpoint: the lockstep collection is deterministic). A cell
  whose demonstrations differ is not imported, and the reason is said.

The fingerprint is a hash of what the collection summaries say of every episode (seed, outcome, progress,
duration, start and end times) and of the checkpoint's weights: two collections with the same fingerprint
are the same scripted runs through the same estimator.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

from bench.first_config import CELLS, trained_score
from bench.portable import portable

LEDGER_VERSION = 1
# settings a kept result depends on, compared between a ledger and a run (folders and checkpoint paths are
# compared through the fingerprint instead: they move between runs and machines)
SAME_SETTINGS = ("obs", "rollouts", "steps", "batch", "policy", "thresholds", "max_seconds", "preset",
                 "include_failed", "actions", "eval_seed", "limit_tol_fraction",
                 "sampler_seeding", "precision", "labels")


def environment() -> dict:
    """The versions a cell's numbers depend on beyond the code: the twin's physics engine above all (MuJoCo
    4.0.0 and 3.17.0 collect other demonstrations from the same seeds: docs/first.md)."""
    import mujoco
    import numpy
    import torch

    return {"mujoco": mujoco.__version__, "numpy": numpy.__version__, "torch": torch.__version__}


def _why_other(c: dict, env: dict) -> str:
    """A hint after 'trained on other demonstrations': the MuJoCo version, when that is what differs."""
    was = (c.get("env") or {}).get("mujoco")
    if was is None:
        return f" (its MuJoCo version was not recorded; this is {env['mujoco']})"
    if was != env["mujoco"]:
        return f" (collected under MuJoCo {was}, this is {env['mujoco']}: `pip install mujoco=={was}`)"
    return ""


def file_digest(path: str | Path) -> str:
    """sha256 of a file's bytes; '' when it cannot be read."""
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return ""


def next_weights_digest(checkpoint: str | Path) -> str:
    """The digest of a NEXT checkpoint's weights (next.safetensors beside next.json; else the JSON itself)."""
    p = Path(checkpoint)
    w = p.with_name("next.safetensors") if p.suffix == ".json" else p
    return file_digest(w if w.is_file() else p)


def demos_fingerprint(summary: dict, next_digest: str) -> str:
    """A task's demonstrations as one hash: every episode of its collection summary (factr2 collect's JSON,
    several merged in order) and the NEXT checkpoint's weights."""
    eps = [[r.get("seed"), r.get("outcome"), round(float(r.get("progress", 0.0)), 9),
            round(float(r.get("duration_s", 0.0)), 9), round(float(r.get("t_start", 0.0)), 9),
            round(float(r.get("t_end", 0.0)), 9)] for r in summary.get("results") or []]
    blob = json.dumps({"episodes": eps, "next": next_digest}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def finished_cells(out: Path) -> list[dict]:
    """{"train", "rollout"} of every cell of OUT whose training and rollouts are both done."""
    cells = []
    for roll in sorted(Path(out).glob("*/*/seed*/rollout.json")):
        train = roll.with_name("train.json")
        if train.is_file():
            cells.append({"train": json.loads(train.read_text()), "rollout": json.loads(roll.read_text())})
    return cells


def _key(c: dict) -> tuple:
    """(task, cell, training seed, contact score): the score is the one the training recorded, so a cell
    trained on other labels (first-motion) is never taken for one of the same name on the default labels."""
    return c["rollout"]["task"], c["rollout"]["cell"], int(c["rollout"]["seed"]), trained_score(c["train"])


def _not_its_cell(c: dict) -> str:
    """Why a finished cell is not the benchmark's cell of its name ('' when it is): an unknown name, or a
    contact score other than the one that name trains with (bench/first_config.py CELLS)."""
    task, cell, seed, score = _key(c)
    if cell not in CELLS:
        return f"{task} {cell} seed {seed}: no such cell (the benchmark's: {', '.join(CELLS)})"
    if score != CELLS[cell].score:
        return (f"{task} {cell} seed {seed}: trained with contact score {score}, the cell's is "
                f"{CELLS[cell].score}")
    return ""


def read_ledger(ledger: Path) -> dict:
    if not Path(ledger).is_file():
        return {"version": LEDGER_VERSION, "cells": []}
    data = json.loads(Path(ledger).read_text())
    if data.get("version") != LEDGER_VERSION:
        raise SystemExit(f"{ledger}: ledger version {data.get('version')}, this code reads {LEDGER_VERSION}")
    return data


def _settings(config: dict) -> dict:
    """The settings a ledger's cells depend on; one a ledger or run does not record is None, and matches
    nothing recorded (every committed ledger records all of them: tests/test_first_ledger.py)."""
    return {k: config.get(k) for k in SAME_SETTINGS}


def export_cells(out: Path, ledger: Path, fingerprints: dict, config: dict, session: str = "") -> int:
    """Merge OUT's finished cells into the ledger (a cell already there is kept as it was); returns how many
    were added. fingerprints: task -> demos_fingerprint of the demonstrations OUT trained on."""
    data = read_ledger(ledger)
    if data["cells"] and _settings(data.get("settings") or {}) != _settings(config):
        raise SystemExit(f"{ledger}: its cells were made with other settings ({data.get('settings')}); "
                         "export to another ledger")
    data["settings"] = _settings(config)
    have = {_key(c) for c in data["cells"]}
    added, env = 0, environment()
    for c in finished_cells(out):
        k = _key(c)
        if k in have or k[0] not in fingerprints:
            continue
        if _not_its_cell(c):  # train_cell refuses to make one: a folder put into OUT by hand
            raise SystemExit(f"{out}: {_not_its_cell(c)}; not exported to {ledger}")
        c["demos_fingerprint"] = fingerprints[k[0]]
        c["session"] = session
        c["env"] = env
        data["cells"].append(portable(c, {"OUT": Path(out).resolve()}))  # no machine folder in the repository
        added += 1
    data["cells"].sort(key=_key)
    tmp = Path(ledger).with_name(f".{Path(ledger).name}.tmp")
    tmp.write_text(json.dumps(data, indent=1, default=float))
    os.replace(tmp, ledger)
    return added


def _whole_seed_groups(cells: list[dict], needed: dict) -> set:
    """(task, seed, fingerprint) of every training seed whose cells the run needs are all in the ledger,
    trained on one collection: a paired comparison complete on its own demonstrations."""
    have: dict = {}
    for c in cells:
        task, cell, seed, _ = _key(c)
        if not _not_its_cell(c):
            have.setdefault((task, seed, c.get("demos_fingerprint")), set()).add(cell)
    return {k for k, got in have.items() if needed.get(k[0]) and set(needed[k[0]]) <= got}


def import_cells(out: Path, ledger: Path, fingerprints: dict, config: dict,
                 needed: dict | None = None) -> tuple[int, list[str]]:
    """Write the ledger's cells into OUT where OUT lacks them; returns (imported, one line per cell left out
    or taken from another collection, and why).

    A cell comes in when its demonstrations match the run's. needed (task -> the cells the run trains for
    it): a cell trained on another collection of the same seeds comes in too when every needed cell of its
    task and training seed is in the ledger on that same collection -- the seed's paired comparison is
    whole on its own demonstrations. Re-collections are not bit-identical across machines or MuJoCo
    versions (measured: docs/first.md), so a table spread over several runs pairs methods within a
    seed on one collection, and its seeds may come from different collections of the same seeds (said
    per cell). A cell the run does not train comes in only on the run's own demonstrations (shown beside
    its table), and is not listed otherwise."""
    data = read_ledger(ledger)
    if not data["cells"]:
        return 0, []
    if _settings(data.get("settings") or {}) != _settings(config):
        return 0, [f"{ledger}: made with other settings ({data.get('settings')}): nothing imported"]
    whole = _whole_seed_groups(data["cells"], needed or {})
    n, skipped, env = 0, [], environment()
    for c in data["cells"]:
        task, cell, seed, _ = _key(c)
        run = Path(out) / task / cell / f"seed{seed}"
        if (run / "rollout.json").is_file():
            continue
        if _not_its_cell(c):
            skipped.append(f"{_not_its_cell(c)}: not taken")
            continue
        fp = c.get("demos_fingerprint")
        if fingerprints.get(task) != fp and needed is not None and cell not in needed.get(task, ()):
            continue  # a cell this run does not train, on other demonstrations: nothing to take or say
        if fingerprints.get(task) != fp:
            if (task, seed, fp) not in whole:
                skipped.append(f"{task} {cell} seed {seed}: trained on other demonstrations "
                               f"({fp} vs {fingerprints.get(task)}): runs again{_why_other(c, env)}")
                continue
            skipped.append(f"{task} {cell} seed {seed}: taken, its seed's pair whole on collection {fp} "
                           f"(this run's: {fingerprints.get(task)})")
        run.mkdir(parents=True, exist_ok=True)
        for name in ("train", "rollout"):  # the train's run folder is this OUT's (the ledger keeps OUT/...)
            part = {**c[name], "run": str(run)} if "run" in c[name] else c[name]
            (run / f"{name}.json").write_text(json.dumps(part, indent=1, default=float))
        n += 1
    return n, skipped
