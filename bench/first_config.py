"""The FIRST benchmark's configuration (bench/bench_first.py): its seeds, its cells and the tables that group
them, BenchConfig, and what a resumed run must keep.

A cell is a column of a table: a training method, its re-sampling ratio w_F:w_PC:w_C, and the contact score
FIRST's labels split (`--contact-score`: policies/labels/motion_residual.py). Cells are trained per task and
training seed into OUT/TASK/CELL/seedS; the name is the folder and the ledger's key (bench/first_ledger.py,
which also keys by the score the training recorded, so a `first-motion` result is never read as `first`).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import NamedTuple

from policies.labels.phases import LABEL_RULE
from policies.rollout.schedule import LIMIT_TOL_FRACTION

DEMO_SEED = 1  # collection seed: range A (episode seeds follow from it, session/task_episodes.py)
EVAL_SEED = 2  # rollout seed: range B, disjoint from A (checked on the episodes' recorded seeds)
CURVE_SEED = 4  # rollout seed of the learning curve (bench/first_curve.py): never the evaluation's
# the data curve's (bench/data_curve.py, issue #56) and used for nothing else: its collection is made in
# parts, part k from collection seed DATA_CURVE_DEMO_SEED + k (k < DATA_CURVE_PARTS_MAX), and every point's
# policies are rolled out from DATA_CURVE_EVAL_SEED. Episode k of seed S is S * 100003 + k
# (session/task_episodes.py), so these meet no seed above, no evaluation seed the results pre-registered (15,
# 31) and no development seed the pages name (all below 1001): tests/test_data_curve.py checks the first two
DATA_CURVE_DEMO_SEED, DATA_CURVE_PARTS_MAX = 5601, 40  # collection seeds 5601-5640
DATA_CURVE_EVAL_SEED = 5600  # rollout seed
# development seeds for choosing the training defaults (issue #56 item 2: `bench/data_curve.py --dev`, the
# data curve's layout on seeds of its own, so a rule is fitted here and checked on the curve's seeds after)
DEFAULTS_DEV_DEMO_SEED = 5701  # collection part k from 5701 + k: 5701-5740
DEFAULTS_DEV_EVAL_SEED = 5700  # rollout seed
# every session seed registered here, by use; no two ranges meet (tests/test_data_curve.py), and disjoint
# session seeds give disjoint episodes (S * 100003 + k for k < 100003)
SEED_RANGES = {
    "demo": range(DEMO_SEED, DEMO_SEED + 1), "eval": range(EVAL_SEED, EVAL_SEED + 1),
    "curve": range(CURVE_SEED, CURVE_SEED + 1),
    "data_curve_demo": range(DATA_CURVE_DEMO_SEED, DATA_CURVE_DEMO_SEED + DATA_CURVE_PARTS_MAX),
    "data_curve_eval": range(DATA_CURVE_EVAL_SEED, DATA_CURVE_EVAL_SEED + 1),
    "defaults_dev_demo": range(DEFAULTS_DEV_DEMO_SEED, DEFAULTS_DEV_DEMO_SEED + DATA_CURVE_PARTS_MAX),
    "defaults_dev_eval": range(DEFAULTS_DEV_EVAL_SEED, DEFAULTS_DEV_EVAL_SEED + 1),
}
RIG = "sim-piper"
OBS_LABELS = {"state": " (PRIVILEGED twin object state, no images)",
              "perceived": " (SIMULATED camera pose detector's object poses, no images; docs/perception.md)"}


class Cell(NamedTuple):
    """What one cell trains: `factr2 train --method METHOD --ratio RATIO --contact-score SCORE`."""

    method: str
    ratio: tuple | None  # w_F:w_PC:w_C; None: the method's default (uniform)
    score: str = "l1"  # the contact labels' score (policies.labels.motion_residual.CONTACT_SCORES)


# every cell by name, in the order a run trains them within a training seed (new cells go last: a resumed
# run keeps the order of the cells it had)
CELLS = {
    "base": Cell("base", None),
    "base-torque": Cell("base-torque", None),
    "first": Cell("first", (1, 5, 1)),
    "C": Cell("first", (1, 1, 5)),
    "PC+C": Cell("first", (1, 3, 3)),
    # first with the motion-discounted labels (docs/first_labels.md), beside first on the same episodes
    "first-motion": Cell("first", (1, 5, 1), "motion"),
}
CELL_ORDER = tuple(CELLS)


def _sampler_seeding() -> str:
    from policies.rollout.runner import SAMPLER_SEEDING

    return SAMPLER_SEEDING


def trained_score(train: dict) -> str:
    """The contact score a training run's labels split, read from its meta or its train.json: their phases
    record "score" for every score but the default l1 (so runs from before the score read as l1)."""
    return (train.get("phases") or {}).get("score", "l1")


def _cells(*names: str) -> dict[str, Cell]:
    return {n: CELLS[n] for n in names}


# the paper's comparison; the second table: base and the ratio ablation (PC = the first cell)
HEADLINE_CELLS = _cells("base-torque", "first")
SECOND_CELLS = _cells("base", "C", "PC+C")
FORCE_CELLS = _cells("base", "base-torque", "first")  # does force help, does FIRST: on every task
# the force table and first with the motion-discounted labels as a cell of its own (issue #51)
FORCE_MOTION_CELLS = _cells("base", "base-torque", "first", "first-motion")
# which cells a run trains: headline, second and all each sized for 2.5 h on 2 cores
TABLES = ("headline", "second", "all", "force", "force-motion")


@dataclass
class BenchConfig:
    out: str = "bench_first"
    obs: str = "state"
    tasks: list = field(default_factory=lambda: ["peg-insert", "press-fit", "wipe"])
    demos: int = 50
    seeds: int = 3
    rollouts: int = 32  # per policy: 3 seeds x 32 = 96 per cell, a 95 % Wilson interval within +-10 points
    steps: int = 8000  # optimiser steps per training run: from the learning curve (docs/first_training.md)
    batch: int = 256
    policy: str = "flow"
    preset: str = ""  # "": the observation's default (state: the MLP flow head; images: small)
    table: str = "all"  # headline: base-torque and first on every task; second: base, C, PC+C on one task
    include_failed: bool = False  # train on failed demonstrations too (the paper trains on successes)
    actions: str = "absolute"  # the frame joint targets are learned in (factr2 train --actions)
    ablation_task: str = ""  # "" = the first task
    thresholds: tuple | str = "recording"  # FIRST labels: from each task's demonstrations (as `factr2 train`)
    max_seconds: float | None = None  # rollout episode limit [s]; None = the task's own
    jobs: int = 2  # worker processes (each training run then uses cores / jobs torch threads)
    threads: int = 0  # torch threads per training run; 0 = cores / jobs (two runs side by side: pass 1 each)
    next_checkpoint: str = ""  # "" = the demo's cached NEXT for sim-piper (made once when missing)
    quick: bool = False  # the smoke configuration (QUICK): said in the report
    demos_from: dict = field(default_factory=dict)  # task -> recorded folders used instead of a collection
    eval_seed: int = EVAL_SEED  # rollout seed (range B): a run may pre-register a fresh one
    ledger: str = ""  # finished cells kept in the repository across runs (bench/first_ledger.py)
    # the rollouts' rule for chunks beyond a joint limit (policies/rollout/schedule.py), recorded: results of
    # the earlier rule (a fixed 0.15 rad refused: results/first_cells_refuse015.json) are not mixed with these
    limit_tol_fraction: float = LIMIT_TOL_FRACTION
    # the flow noise seeded per episode (policies/rollout/runner.py; read when a config is made: the runner
    # imports torch, and the cells here are read by the ledger and the reports without it)
    sampler_seeding: str = field(default_factory=_sampler_seeding)
    # the training's matmuls (factr2 train --precision): auto, as the current ledger's cells were trained
    # (results/first_cells_fp32_hysteresis.json: fp32 and the earlier labels)
    precision: str = "auto"
    # the contact labeller (policies.labels.phases.LABEL_RULE): cells labelled by an earlier rule are not
    # mixed in
    labels: str = LABEL_RULE
    only_cells: list = field(default_factory=list)  # a subset of the table's cells ([] = all of them)

    def table_cells(self, task: str) -> dict[str, Cell]:
        """Every cell the table has on a task (before --cells)."""
        if self.table == "force":
            return dict(FORCE_CELLS)
        if self.table == "force-motion":
            return dict(FORCE_MOTION_CELLS)
        out = dict(HEADLINE_CELLS) if self.table in ("headline", "all") else {}
        if self.table in ("second", "all") and task == (self.ablation_task or self.tasks[0]):
            out.update(SECOND_CELLS)
            out["first"] = CELLS["first"]  # PC (1:5:1) of the ablation
        return out

    def cells(self, task: str) -> dict[str, Cell]:
        """The cells this run trains on a task: the table's, only those of --cells when given."""
        cells = self.table_cells(task)
        return {k: v for k, v in cells.items() if not self.only_cells or k in self.only_cells}


QUICK = {"tasks": ["wipe"], "demos": 4, "seeds": 1, "rollouts": 2, "steps": 40, "batch": 32}

# what the kept results depend on (tasks and seeds may be added; so may cells: each is its own folder)
SAME_ON_RESUME = ("obs", "demos", "rollouts", "steps", "batch", "policy", "thresholds", "max_seconds",
                  "next_checkpoint", "preset", "include_failed", "demos_from", "eval_seed",
                  "limit_tol_fraction", "sampler_seeding", "precision", "labels")


def check_resume(cfg, out: Path, keys: tuple = SAME_ON_RESUME) -> None:
    """A resumed OUT must have been started with the same settings `keys` of the configuration (a dataclass:
    BenchConfig, bench/data_curve.py's CurveConfig): its kept results were made with them."""
    old_path = out / "config.json"
    if not old_path.is_file():
        return
    old, new = json.loads(old_path.read_text()), json.loads(json.dumps(asdict(cfg)))
    diff = [k for k in keys if old.get(k) != new.get(k)]
    if diff:
        was = ", ".join(f"{k} {old.get(k)}" for k in diff)
        raise SystemExit(f"{out}: its kept results were made with other settings ({was}); "
                         "use another --out or the same options")
