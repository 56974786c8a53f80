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
last checkpoint).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, fields
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
from bench.first_report import aggregate, write_docs, write_report
from bench.harness import commit, machine
from policies.labels.phases import LABEL_RULE
from policies.rollout.runner import SAMPLER_SEEDING
from policies.rollout.schedule import LIMIT_TOL_FRACTION

DEMO_SEED = 1  # collection seed: range A (episode seeds follow from it, session/task_episodes.py)
EVAL_SEED = 2  # rollout seed: range B, disjoint from A (checked on the episodes' recorded seeds)
CURVE_SEED = 4  # rollout seed of the learning curve (bench/first_curve.py): never the evaluation's
# the paper's comparison; the second table: base and the ratio ablation (PC = the first cell)
HEADLINE_CELLS = {"base-torque": ("base-torque", None), "first": ("first", (1, 5, 1))}
SECOND_CELLS = {"base": ("base", None), "C": ("first", (1, 1, 5)), "PC+C": ("first", (1, 3, 3))}
FORCE_CELLS = {"base": ("base", None), **HEADLINE_CELLS}  # does force help, does FIRST: on every task
TABLES = ("headline", "second", "all", "force")  # which cells a run trains: each sized for 2.5 h on 2 cores
RIG = "sim-piper"
OBS_LABELS = {"state": " (PRIVILEGED twin object state, no images)",
              "perceived": " (SIMULATED camera pose detector's object poses, no images; docs/perception.md)"}


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
    sampler_seeding: str = SAMPLER_SEEDING  # the flow noise seeded per episode (policies/rollout/runner.py)
    # the training's matmuls (factr2 train --precision): auto, as the current ledger's cells were trained
    # (results/first_cells_fp32_hysteresis.json: fp32 and the earlier labels)
    precision: str = "auto"
    # the contact labeller (policies.labels.phases.LABEL_RULE): cells labelled by an earlier rule are not
    # mixed in
    labels: str = LABEL_RULE
    only_cells: list = field(default_factory=list)  # a subset of the table's cells ([] = all of them)

    def cells(self, task: str) -> dict:
        if self.table == "force":
            out = dict(FORCE_CELLS)
        else:
            out = dict(HEADLINE_CELLS) if self.table in ("headline", "all") else {}
            if self.table in ("second", "all") and task == (self.ablation_task or self.tasks[0]):
                out.update(SECOND_CELLS)
                out["first"] = HEADLINE_CELLS["first"]  # PC (1:5:1) of the ablation
        return {k: v for k, v in out.items() if not self.only_cells or k in self.only_cells}


QUICK = {"tasks": ["wipe"], "demos": 4, "seeds": 1, "rollouts": 2, "steps": 40, "batch": 32}
CELL_ORDER = ("base", "base-torque", "first", "C", "PC+C")


# -- the three stages (each a job: a function of picklable arguments, its result kept as JSON) -------------
def _json(path: Path, obj) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(obj, indent=1, default=float))
    os.replace(tmp, path)  # written whole or not at all: a killed run leaves no half result


def demo_folders(cfg: BenchConfig, task: str) -> list[Path]:
    """Where a task's demonstrations are: the folders the run was given, or its own collection."""
    return [Path(d) for d in cfg.demos_from.get(task, [])] or [Path(cfg.out) / task / "demos"]


def recorded_summary(task: str, folders: list[Path]) -> dict:
    """The collection summaries (`factr2 collect`'s JSON) of given folders, merged into one."""
    parts = [json.loads(f.read_text()) for d in folders for f in sorted(d.glob("*.json"))]
    parts = [p for p in parts if isinstance(p, dict) and p.get("results")]
    if not parts or any(p.get("task") != task for p in parts):
        raise SystemExit(f"--demos-from {task}: {', '.join(map(str, folders))} hold no {task} collection "
                         "summary (the JSON `factr2 collect` writes beside its recording)")
    results = [r for p in parts for r in p["results"]]
    n = len(results)
    return {"episodes": n, "success_rate": sum(r.get("outcome") == "success" for r in results) / n,
            "progress_mean": sum(r.get("progress", 0.0) for r in results) / n,
            "sim_s": sum(p.get("sim_s", 0.0) for p in parts),
            "wall_s": sum(p.get("wall_s", 0.0) for p in parts),
            "cpu_s": 0.0,  # not this run's work
            "folders": [str(d) for d in folders], "collection_seeds": [p.get("seed") for p in parts],
            "results": results}


def collect_demos(cfg: BenchConfig, task: str, checkpoint: str) -> dict:
    """The task's demonstrations (factr2 collect's function), kept in OUT/TASK/demos, or those the run was
    given (--demos-from)."""
    from factr2_teleop.tasks.run import CollectConfig, collect, output_paths

    if task in cfg.demos_from:
        return recorded_summary(task, demo_folders(cfg, task))
    folder = Path(cfg.out) / task / "demos"
    # mode None: the task's demonstrator feedback (Task.operator_feedback), else NEXT from `checkpoint`
    cc = CollectConfig(rig=RIG, task=task, episodes=cfg.demos, out=str(folder), seed=DEMO_SEED, mode=None,
                       checkpoint=checkpoint, cameras=cfg.obs == "images")
    mcap, summary = output_paths(cc, RIG)
    if summary.is_file():
        return json.loads(summary.read_text())
    shutil.rmtree(folder, ignore_errors=True)  # an interrupted collection: start it again
    return collect(cc, progress=False)


def train_cell(cfg: BenchConfig, task: str, cell: str, seed: int) -> dict:
    """One training run (policies.training.run, as `factr2 train`), resumed from its checkpoint if
    interrupted."""
    import torch

    from policies.training.checkpoint import last_checkpoint, read_meta
    from policies.training.run import RunOptions, run_training
    from policies.training.train import Dist, TrainConfig

    run = Path(cfg.out) / task / cell / f"seed{seed}"
    done = run / "train.json"
    if done.is_file():
        return json.loads(done.read_text())
    method, ratio = cfg.cells(task)[cell]
    last = last_checkpoint(run)
    if last is None:
        shutil.rmtree(run, ignore_errors=True)
    # the warm-up / validation / checkpoint periods: fitted to the run's length by the loop
    tc = TrainConfig(steps=cfg.steps, batch=cfg.batch, log_every=10, seed=seed,
                     threads=cfg.threads or max(1, (os.cpu_count() or 1) // cfg.jobs),
                     precision=cfg.precision)
    opts = RunOptions(inputs=demo_folders(cfg, task), out=run, policy=cfg.policy, method=method,
                      ratio=ratio, preset=cfg.preset, thresholds=cfg.thresholds, observation=cfg.obs,
                      progress=False, train=tc, resume=last is not None, include_failed=cfg.include_failed,
                      actions=cfg.actions)
    t, c = time.perf_counter(), time.process_time()
    run_training(opts, Dist(device=torch.device("cuda" if torch.cuda.is_available() else "cpu")))
    meta = read_meta(run)
    out = {"task": task, "cell": cell, "method": method, "ratio": meta["ratio"], "seed": seed,
           "val": meta.get("metrics", {}), "samples": meta["samples"], "steps": meta["step"],
           "phases": meta["phases"], "phase_shares": meta.get("phase_shares"),
           "wall_s": time.perf_counter() - t, "cpu_s": time.process_time() - c,
           "torch_threads": torch.get_num_threads(), "run": str(run)}
    _json(done, out)
    return out


def rollout_cell(cfg: BenchConfig, task: str, cell: str, seed: int) -> dict:
    """R rollouts of one trained policy on the evaluation seed (factr2 rollout's function)."""
    from factr2_teleop.session.rollout import RolloutOptions, run_rollout

    run = Path(cfg.out) / task / cell / f"seed{seed}"
    done = run / "rollout.json"
    if done.is_file():
        return json.loads(done.read_text())
    kw = {"rig": RIG, "policy": str(run), "task": task, "episodes": cfg.rollouts, "seed": cfg.eval_seed,
          "record": None, "progress": False}
    if cfg.max_seconds is not None and "max_seconds" in {f.name for f in fields(RolloutOptions)}:
        kw["max_seconds"] = cfg.max_seconds
    t, c = time.perf_counter(), time.process_time()
    res = run_rollout(RolloutOptions(**kw)).to_dict()
    out = {"task": task, "cell": cell, "seed": seed, "success_rate": res["success_rate"],
           "mean_progress": res["mean_progress"], "stage_rates": res.get("stage_rates"),
           "episodes": res.get("episodes"), "timing": res.get("timing"),
           "wall_s": time.perf_counter() - t, "cpu_s": time.process_time() - c}
    _json(done, out)
    return out


# -- orchestration ------------------------------------------------------------------------------------------
def next_checkpoint(cfg: BenchConfig) -> str:
    """The NEXT checkpoint the demonstrations' feedback and labels use (the demo's cache, made if missing)."""
    from factr2_teleop.session.next_cache import create_checkpoint, find_checkpoint

    ck = find_checkpoint(RIG, cfg.next_checkpoint or None)
    if ck is None:
        ck = create_checkpoint(RIG, say=print)
    return str(ck)


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


# what the kept results depend on (tasks and seeds may be added)
SAME_ON_RESUME = ("obs", "demos", "rollouts", "steps", "batch", "policy", "thresholds", "max_seconds",
                  "next_checkpoint", "preset", "include_failed", "demos_from", "eval_seed",
                  "limit_tol_fraction", "sampler_seeding", "precision", "labels")


def check_resume(cfg: BenchConfig, out: Path) -> None:
    """A resumed OUT must have been started with the same settings (its kept results were made with them)."""
    old_path = out / "config.json"
    if not old_path.is_file():
        return
    old, new = json.loads(old_path.read_text()), json.loads(json.dumps(asdict(cfg)))
    diff = [k for k in SAME_ON_RESUME if old.get(k) != new.get(k)]
    if diff:
        was = ", ".join(f"{k} {old.get(k)}" for k in diff)
        raise SystemExit(f"{out}: its kept results were made with other settings ({was}); "
                         "use another --out or the same options")


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


def task_summaries(cfg: BenchConfig) -> dict:
    """The collection summary of every task whose demonstrations are there (given or collected earlier)."""
    from factr2_teleop.tasks.run import CollectConfig, output_paths

    out = {}
    for task in cfg.tasks:
        if task in cfg.demos_from:
            out[task] = recorded_summary(task, demo_folders(cfg, task))
            continue
        cc = CollectConfig(rig=RIG, task=task, episodes=cfg.demos, out=str(Path(cfg.out) / task / "demos"),
                           seed=DEMO_SEED)
        summary = output_paths(cc, RIG)[1]
        if summary.is_file():
            out[task] = json.loads(summary.read_text())
    return out


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
                    "force: base, base-torque and first on every task (docs/force.md)")
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
    if any(c not in CELL_ORDER for c in cfg.only_cells):
        ap.error(f"--cells {a.cells!r}: a comma-separated subset of {', '.join(CELL_ORDER)}")
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
