"""The FIRST benchmark on the twin's tasks (SIMULATED; paper Sec. 5, issue #20 item 2).

Per task: collect N scripted demonstrations through the full teleop stack (`factr2 collect`'s code path,
lockstep, NEXT feedback, collection seed A), train `base`, `base-torque` and `first` (1:5:1) with S training
seeds each on the SAME demonstrations, roll every policy out R episodes on initial conditions drawn from
seed B (never used for a demonstration, never used to choose anything), and on one task also the paper's
ablation C (1:1:5) and PC+C (1:3:3); PC (1:5:1) is the `first` runs themselves (the same ratio). Reported:
success and task progress (mean and spread over the training seeds) per task, and each run's validation
loss per phase F / PC / C.

    python -m bench.bench_first --quick --out OUT                      # a few-minute smoke run
    python -m bench.bench_first --out OUT --jobs 2                     # the CPU configuration (--obs state)
    python -m bench.bench_first --obs images --out DIR                 # the same code path on camera frames
    python -m bench.bench_first --out OUT --write-docs                 # table + chart into docs/first.md

`--obs state` (default) trains on the PRIVILEGED object state of the twin (policies/data/privileged.py), not
on images: labelled so everywhere; `--obs perceived` on those poses as the simulated camera pose detector
reported them during collection (SIMULATED, docs/perception.md). `--out` is resumable: finished
demonstrations, training runs and rollouts are kept and skipped (an interrupted training run resumes from its
last checkpoint); a resumed run may add tasks, seeds and cells (`--table force-motion` on a `force` run adds
`first-motion`: first with `--contact-score motion` labels).

This module runs the jobs and reports; the cells, tables and BenchConfig are in bench/first_config.py, the
stages (collect, train, roll out) in bench/first_stages.py, the ledger of finished cells in
bench/first_ledger.py.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import asdict
from pathlib import Path

try:
    from bench.first_ledger import (
        demos_fingerprint,
        export_cells,
        finished_cells,
        import_cells,
        next_weights_digest,
    )
except ModuleNotFoundError as e:  # `python bench/bench_first.py`: bench/ is a package now
    if e.name != "bench":
        raise
    print("run it from the repository root as: python -m bench.bench_first ...", file=sys.stderr)
    raise SystemExit(2) from None
from bench import harness
from bench.first_config import (  # the configuration (HEADLINE_CELLS, RIG: imported from here by callers)
    CELL_ORDER,
    EVAL_SEED,
    HEADLINE_CELLS,
    OBS_LABELS,
    QUICK,
    RIG,
    TABLES,
    BenchConfig,
    check_resume,
)
from bench.first_report import aggregate, write_docs, write_report
from bench.first_stages import (  # the three stages, each a job of a worker
    _json,
    collect_demos,
    next_checkpoint,
    recorded_summary,
    rollout_cell,
    task_summaries,
    train_cell,
)
from bench.harness import commit, machine

# what callers import from here (the configuration and stages live in bench/first_config.py, first_stages.py)
__all__ = ["BenchConfig", "EVAL_SEED", "HEADLINE_CELLS", "RIG", "_json", "check_disjoint_seeds", "main",
           "next_checkpoint", "parse_args", "recorded_summary", "run_bench", "run_pipeline"]


# -- orchestration ------------------------------------------------------------------------------------------
def _done(label: str, args: tuple, t0: float) -> None:
    what = " ".join(str(a) for a in args if not str(a).endswith(".json"))
    print(f"  {label} {what}: done ({time.perf_counter() - t0:.0f} s)", flush=True)


def check_disjoint_seeds(demos: dict, rollouts: list[dict]) -> dict:
    """Episode seeds of demonstrations (range A) and rollouts (range B), per task; ValueError on overlap."""
    out = {}
    for task, d in demos.items():
        a = {r["seed"] for r in d.get("results", [])}
        b = {e["seed"] for r in rollouts if r["task"] == task for e in (r.get("episodes") or [])
             if isinstance(e, dict) and "seed" in e}
        if a & b:
            raise ValueError(f"{task}: rollout seeds overlap demonstration seeds: {sorted(a & b)[:5]}")
        out[task] = {"demo_seeds": [min(a), max(a)] if a else None,
                     "rollout_seeds": [min(b), max(b)] if b else None}
    return out


class _Elapsed:
    """Wall time per stage [s], kept in a JSON and summed over invocations (a resumed run adds its own)."""

    def __init__(self, path: Path):
        self.path = path
        self.totals = json.loads(path.read_text()) if path.is_file() else {}

    @contextmanager
    def __call__(self, stage: str):
        t = time.perf_counter()
        try:
            yield
        finally:  # an interrupted invocation's time counts too (main turns SIGTERM into SystemExit)
            self.totals[stage] = self.totals.get(stage, 0.0) + time.perf_counter() - t
            _json(self.path, self.totals)


def run_pipeline(cfg: BenchConfig, ck: str, on_cell=lambda: None) -> tuple[dict, list[dict], list[dict]]:
    """Every job of the benchmark in cfg.jobs workers, each started as soon as what it needs is there: a
    task's training runs when its demonstrations are, a policy's rollouts when its training is (no worker
    idles at a stage boundary: 3 collections on 2 workers left one idle for a whole collection)."""
    # seed by seed across the tasks, so that a run stopped early (a table spans sessions) leaves the paired
    # comparison (same seed, both methods) on every task first
    cells = [(task, cell, s) for s in range(cfg.seeds) for task in cfg.tasks for cell in CELL_ORDER
             if cell in cfg.cells(task)]
    demos, trains, rolls = {}, {}, {}
    t0 = time.perf_counter()
    if cfg.jobs <= 1:
        for task in cfg.tasks:
            demos[task] = collect_demos(cfg, task, ck)
            _done("collect", (task,), t0)
        for c in cells:
            trains[c] = train_cell(cfg, *c)
            _done("train", c, t0)
            rolls[c] = rollout_cell(cfg, *c)
            _done("rollout", c, t0)
            on_cell()
        return demos, [trains[c] for c in cells], [rolls[c] for c in cells]
    import multiprocessing as mp
    from concurrent.futures import FIRST_COMPLETED, wait

    kept = sum((Path(cfg.out) / t / c / f"seed{s}" / "rollout.json").is_file() for t, c, s in cells)
    print(f"{len(cfg.tasks)} collection(s), {len(cells) - kept} training run(s) and as many rollout sets "
          f"on {cfg.jobs} worker(s) ({kept} cell(s) already finished)", flush=True)
    # a queue, not a submit-all: a trained policy's rollouts run before the next training, so a run stopped
    # early leaves whole (policy, rollouts) pairs, the earliest task's first
    pending: list[tuple[str, tuple]] = [("collect", (t,)) for t in cfg.tasks]
    jobs = {"collect": collect_demos, "train": train_cell, "rollout": rollout_cell}
    rank = {("collect", (t,)): -1 for t in cfg.tasks} | {("train", c): i for i, c in enumerate(cells)}
    with ProcessPoolExecutor(cfg.jobs, mp_context=mp.get_context("spawn")) as ex:
        running: dict = {}
        while pending or running:
            while pending and len(running) < cfg.jobs:
                stage, args = pending.pop(0)
                extra = (ck,) if stage == "collect" else ()
                running[ex.submit(jobs[stage], cfg, *args, *extra)] = (stage, args)
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            for f in done:
                stage, args = running.pop(f)
                res = f.result()
                _done(stage, args, t0)
                if stage == "collect":
                    demos[args[0]] = res
                    pending += [("train", c) for c in cells if c[0] == args[0]]
                    pending.sort(key=lambda j: rank.get(j, -2))  # rollouts, collections, then cells' order
                elif stage == "train":
                    trains[args] = res
                    pending.insert(0, ("rollout", args))
                else:
                    rolls[args] = res
                    on_cell()
    return {t: demos[t] for t in cfg.tasks}, [trains[c] for c in cells], [rolls[c] for c in cells]


def fingerprints(cfg: BenchConfig, ck: str) -> dict:
    digest = next_weights_digest(ck)
    return {t: demos_fingerprint(s, digest) for t, s in task_summaries(cfg).items()}


def run_bench(cfg: BenchConfig, report_only: bool = False) -> dict:
    """Run every job not yet done (or, report_only, none) and report what is finished."""
    out = Path(cfg.out)
    check_resume(cfg, out)
    out.mkdir(parents=True, exist_ok=True)
    _json(out / "config.json", asdict(cfg))
    ck = next_checkpoint(cfg)
    config = json.loads(json.dumps(asdict(cfg)))
    if cfg.ledger:
        n, skipped = import_cells(out, Path(cfg.ledger), fingerprints(cfg, ck), config,
                                  needed={t: list(cfg.cells(t)) for t in cfg.tasks})
        print(f"ledger {cfg.ledger}: {n} finished cell(s) taken", *skipped, sep="\n  ", flush=True)

    def on_cell():  # every finished cell goes to the ledger at once: a run may be cut at any moment
        if cfg.ledger:
            export_cells(out, Path(cfg.ledger), fingerprints(cfg, ck), config, session=time.strftime("%F"))

    elapsed = _Elapsed(out / "elapsed.json")  # wall time, summed over resumed invocations
    if report_only:
        demos = task_summaries(cfg)
        cells = finished_cells(out)
        trains, rolls = [c["train"] for c in cells], [c["rollout"] for c in cells]
    else:
        with elapsed("pipeline"):
            demos, trains, rolls = run_pipeline(cfg, ck, on_cell)
    on_cell()
    timing = {f"{k}_wall_s": v for k, v in elapsed.totals.items()}
    timing["total_wall_s"] = sum(elapsed.totals.values())
    timing.update({"collect_cpu_s": sum(d.get("cpu_s", 0.0) for d in demos.values()),
                   "train_cpu_s": sum(r["cpu_s"] for r in trains),
                   "rollout_cpu_s": sum(r["cpu_s"] for r in rolls),
                   "cells_wall_s": sum(r["wall_s"] for r in trains + rolls)})
    results = {
        "simulated": True, "command": " ".join(["python", "-m", "bench.bench_first", *sys.argv[1:]]),
        "observation": cfg.obs + OBS_LABELS.get(cfg.obs, ""),
        "config": asdict(cfg), "next_checkpoint": ck, "next_weights_sha256": next_weights_digest(ck),
        "seeds": check_disjoint_seeds(demos, rolls),
        # harness.machine() (CPU model, versions, commit beside) and the keys the report reads
        "machine": {**machine(), "cpus": os.cpu_count(), "loadavg_end": os.getloadavg()}, "commit": commit(),
        "timing": timing,
        "demos": {k: {x: v[x] for x in ("episodes", "success_rate", "progress_mean", "phase_shares",
                                        "phase_thresholds_nm", "sim_s", "wall_s", "cpu_s", "folders",
                                        "collection_seeds") if x in v}
                  for k, v in demos.items()},
        "train": trains, "rollout": rolls,
    }
    results["summary"] = aggregate(trains, rolls)
    _json(out / "results.json", results)
    write_report(results, out)
    return results


def parse_args(argv=None) -> tuple[BenchConfig, str]:
    """The configuration and what to do: run, report (the finished cells) or docs (write OUT's report)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="bench_first", help="results folder (resumable)")
    ap.add_argument("--obs", choices=("state", "perceived", "images"), default="state",
                    help="state: PRIVILEGED object poses, the CPU configuration; perceived: those poses "
                    "through the simulated camera pose detector (SIMULATED, docs/perception.md); images: "
                    "camera frames (GPU)")
    ap.add_argument("--tasks", default=None, help="comma-separated (default: every task)")
    ap.add_argument("--demos", type=int, default=None)
    ap.add_argument("--seeds", type=int, default=None, help="training seeds per method")
    ap.add_argument("--rollouts", type=int, default=None, help="rollout episodes per trained policy")
    ap.add_argument("--steps", type=int, default=None, help="optimiser steps per training run")
    ap.add_argument("--batch", type=int, default=None)
    ap.add_argument("--policy", choices=("flow", "act"), default="flow")
    ap.add_argument("--preset", default="", help="policy preset (default: the observation's: state / small)")
    ap.add_argument("--table", choices=TABLES, default="all",
                    help="headline: base-torque and first on every task; second: base and the ablation C, "
                    "PC+C on --ablation-task (PC = first); all: both (each sized for 2.5 h on 2 cores); "
                    "force: base, base-torque and first on every task (docs/force.md); force-motion: "
                    "those and first-motion, first with --contact-score motion labels (docs/first_labels.md)")
    ap.add_argument("--cells", default="", metavar="CELL[,CELL...]",
                    help="only these cells of the table (e.g. base: one observation against another on the "
                    "same demonstrations)")
    ap.add_argument("--include-failed", action="store_true", help="train on failed demonstrations too")
    ap.add_argument("--actions", choices=("absolute", "relative"), default="absolute",
                    help="the frame the policy learns its joint targets in (factr2 train --actions)")
    ap.add_argument("--ablation-task", default="", help="task with the C / PC+C ablation (default: first)")
    ap.add_argument("--thresholds", default="recording", metavar="recording|next|LOW:HIGH",
                    help="FIRST label thresholds [N*m] (default: from the demonstrations, as factr2 train)")
    ap.add_argument("--max-seconds", type=float, default=None, help="rollout episode limit [s]")
    ap.add_argument("--demos-from", action="append", default=[], metavar="TASK=DIR[+DIR...]",
                    help="train TASK on these recorded folders (factr2 collect's) instead of collecting")
    ap.add_argument("--eval-seed", type=int, default=EVAL_SEED,
                    help=f"rollout seed (default {EVAL_SEED}); never one a choice was made on")
    ap.add_argument("--precision", choices=("fp32", "bf16", "auto"), default="auto",
                    help="the trainings' matmuls (factr2 train --precision; default auto, as the ledger "
                         "results/first_cells.json: bf16 where the CPU or GPU has it natively)")
    ap.add_argument("--jobs", type=int, default=2, help="worker processes (default 2: both cores here)")
    ap.add_argument("--threads", type=int, default=0,
                    help="torch threads per training run (default: cores / jobs)")
    ap.add_argument("--next", default="", help="NEXT checkpoint (default: the demo's cache)")
    ap.add_argument("--quick", action="store_true", help="a few-minute smoke configuration: " + str(QUICK))
    ap.add_argument("--ledger", default="", metavar="FILE",
                    help="finished cells kept across runs: taken from FILE, each new one added to it "
                    "(results/first_cells.json; bench/first_ledger.py)")
    ap.add_argument("--report", action="store_true",
                    help="run nothing: report the finished cells (a partial table) into OUT")
    ap.add_argument("--write-docs", action="store_true",
                    help="only write OUT's table and chart into docs/first.md / docs/first_bench.png")
    a = ap.parse_args(argv)
    cfg = BenchConfig(out=a.out, obs=a.obs, policy=a.policy, ablation_task=a.ablation_task,
                      max_seconds=a.max_seconds, jobs=max(1, a.jobs), next_checkpoint=a.next, preset=a.preset,
                      table=a.table, include_failed=a.include_failed, actions=a.actions,
                      eval_seed=a.eval_seed, ledger=a.ledger, precision=a.precision,
                      threads=max(0, a.threads))
    for item in a.demos_from:
        task, sep, dirs = item.partition("=")
        folders = [d for d in dirs.split("+") if d]
        if not sep or not folders or any(not Path(d).is_dir() for d in folders):
            ap.error(f"--demos-from {item!r}: TASK=DIR[+DIR...], each DIR a folder factr2 collect wrote")
        cfg.demos_from[task.strip()] = [str(Path(d).resolve()) for d in folders]
    if a.quick:
        cfg.quick = True
        for k, v in QUICK.items():
            setattr(cfg, k, v)
    for k in ("demos", "seeds", "rollouts", "steps", "batch"):
        if getattr(a, k) is not None:
            setattr(cfg, k, getattr(a, k))
    if a.tasks:
        cfg.tasks = harness.names(a.tasks)
    cfg.only_cells = harness.names(a.cells)
    table = [c for c in CELL_ORDER if any(c in cfg.table_cells(t) for t in cfg.tasks)]
    if any(c not in table for c in cfg.only_cells):  # a cell of another table would train nothing, silently
        more = " (first-motion: --table force-motion)" if "first-motion" in cfg.only_cells else ""
        ap.error(f"--cells {a.cells!r}: a comma-separated subset of --table {cfg.table}'s cells, "
                 f"{', '.join(table)}{more}")
    cfg.thresholds = a.thresholds
    if a.thresholds not in ("recording", "next"):
        try:
            lo, hi = (float(x) for x in a.thresholds.split(":"))
        except ValueError:
            ap.error(f"--thresholds {a.thresholds!r}: LOW:HIGH in N*m, e.g. 6:9")
        cfg.thresholds = (lo, hi)
    return cfg, "docs" if a.write_docs else "report" if a.report else "run"


def main(argv=None) -> int:
    cfg, mode = parse_args(argv)
    if mode == "docs":
        results = json.loads((Path(cfg.out) / "results.json").read_text())
        write_docs(results, Path(cfg.out), Path(__file__).resolve().parents[1] / "docs")
        return 0
    from hardware.sim.tasks import get_task

    for task in cfg.tasks:
        get_task(task)  # an unknown task: one line (ConfigError), before anything runs
    import signal

    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # killed: keep the elapsed time (resumable)
    res = run_bench(cfg, report_only=mode == "report")
    print((Path(cfg.out) / "table.md").read_text())
    print(f"wall {res['timing']['total_wall_s']:.0f} s; results {cfg.out}/results.json")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
