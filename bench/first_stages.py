"""The FIRST benchmark's three stages (bench/bench_first.py): collect a task's demonstrations, train one cell
on them, roll the trained policy out. Each is a job -- a function of picklable arguments run in a worker --
whose result is kept as a small JSON in OUT, so a run resumes by skipping what is there."""

from __future__ import annotations

import json
import os
import shutil
import time
from dataclasses import fields
from pathlib import Path

from bench.first_config import DEMO_SEED, RIG, BenchConfig, Cell, trained_score


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
    if task in cfg.demos_from:
        return recorded_summary(task, demo_folders(cfg, task))
    return collect_run(task, Path(cfg.out) / task / "demos", cfg.demos, DEMO_SEED, checkpoint,
                       cameras=cfg.obs == "images")


def collect_run(task: str, folder: Path, episodes: int, seed: int, checkpoint: str,
                cameras: bool = False, perturb=None) -> dict:
    """One collection of `episodes` scripted demonstrations from collection seed `seed` into `folder`
    (factr2 collect's function; perturb: its --perturb, a teleop.perturb.PerturbConfig or None): its
    summary, kept when it is there (an interrupted one starts again)."""
    from factr2_teleop.tasks.run import CollectConfig, collect, output_paths

    # mode None: the task's demonstrator feedback (Task.operator_feedback), else NEXT from `checkpoint`
    cc = CollectConfig(rig=RIG, task=task, episodes=episodes, out=str(folder), seed=seed, mode=None,
                       checkpoint=checkpoint, cameras=cameras, perturb=perturb)
    summary = output_paths(cc, RIG)[1]
    if summary.is_file():
        return json.loads(summary.read_text())
    shutil.rmtree(folder, ignore_errors=True)  # an interrupted collection: start it again
    return collect(cc, progress=False)


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


def label_choice(thresholds, score: str):
    """RunOptions.thresholds for a cell: the run's --thresholds as given for the default score (what every
    l1 cell was trained with), a LabelChoice carrying the score otherwise (factr2 train --contact-score)."""
    if score == "l1":
        return thresholds
    from policies.labels.labelling import LabelChoice

    return LabelChoice(thresholds, score=score)


def training_options(cfg: BenchConfig, task: str, cell: Cell, run: Path, seed: int, threads: int,
                     resume: bool):
    """The RunOptions (`factr2 train`'s) of one cell's training run on the task's demonstrations."""
    from policies.training.run import RunOptions
    from policies.training.train import TrainConfig

    # the warm-up / validation / checkpoint periods: fitted to the run's length by the loop
    tc = TrainConfig(steps=cfg.steps, batch=cfg.batch, log_every=10, seed=seed, threads=threads,
                     precision=cfg.precision)
    return RunOptions(inputs=demo_folders(cfg, task), out=run, policy=cfg.policy, method=cell.method,
                      ratio=cell.ratio, preset=cfg.preset,
                      thresholds=label_choice(cfg.thresholds, cell.score), observation=cfg.obs,
                      progress=False, train=tc, resume=resume,
                      include_failed=cfg.include_failed, actions=cfg.actions)


def train_cell(cfg: BenchConfig, task: str, cell: str, seed: int) -> dict:
    """One training run (policies.training.run, as `factr2 train`), resumed from its checkpoint if
    interrupted."""
    import torch

    from policies.training.checkpoint import last_checkpoint, read_meta
    from policies.training.run import run_training
    from policies.training.train import Dist

    run = Path(cfg.out) / task / cell / f"seed{seed}"
    done = run / "train.json"
    if done.is_file():
        return json.loads(done.read_text())
    spec = cfg.cells(task)[cell]
    last = last_checkpoint(run)
    if last is None:
        shutil.rmtree(run, ignore_errors=True)
    threads = cfg.threads or max(1, (os.cpu_count() or 1) // cfg.jobs)
    opts = training_options(cfg, task, spec, run, seed, threads, resume=last is not None)
    t, c = time.perf_counter(), time.process_time()
    run_training(opts, Dist(device=torch.device("cuda" if torch.cuda.is_available() else "cpu")))
    meta = read_meta(run)
    if trained_score(meta) != spec.score:  # the cell's name promises its labels: never a silent other score
        raise RuntimeError(f"{run}: trained with contact score {trained_score(meta)}, "
                           f"the cell's is {spec.score}")
    # phases records the score the labels split ("score": "motion"; nothing for l1: bench/first_ledger.py)
    out = {"task": task, "cell": cell, "method": spec.method, "ratio": meta["ratio"], "seed": seed,
           "val": meta.get("metrics", {}), "samples": meta["samples"], "steps": meta["step"],
           "phases": meta["phases"], "phase_shares": meta.get("phase_shares"),
           "wall_s": time.perf_counter() - t, "cpu_s": time.process_time() - c,
           "torch_threads": torch.get_num_threads(), "run": str(run)}
    _json(done, out)
    return out


def rollout_cell(cfg: BenchConfig, task: str, cell: str, seed: int) -> dict:
    """R rollouts of one trained policy on the evaluation seed (factr2 rollout's function)."""
    run = Path(cfg.out) / task / cell / f"seed{seed}"
    return rollout_run(run, task, cfg.rollouts, cfg.eval_seed, {"cell": cell, "seed": seed}, cfg.max_seconds)


def rollout_run(run: Path, task: str, episodes: int, eval_seed: int, keys: dict,
                max_seconds: float | None = None) -> dict:
    """`episodes` rollouts of the policy trained in `run` from rollout seed `eval_seed` (factr2 rollout's
    function), kept in RUN/rollout.json (with `keys` beside the results) and skipped when it is there."""
    from factr2_teleop.session.rollout import RolloutOptions, run_rollout

    done = run / "rollout.json"
    if done.is_file():
        return json.loads(done.read_text())
    kw = {"rig": RIG, "policy": str(run), "task": task, "episodes": episodes, "seed": eval_seed,
          "record": None, "progress": False}
    if max_seconds is not None and "max_seconds" in {f.name for f in fields(RolloutOptions)}:
        kw["max_seconds"] = max_seconds
    t, c = time.perf_counter(), time.process_time()
    res = run_rollout(RolloutOptions(**kw)).to_dict()
    out = {"task": task, **keys, "success_rate": res["success_rate"],
           "mean_progress": res["mean_progress"], "stage_rates": res.get("stage_rates"),
           "episodes": res.get("episodes"), "timing": res.get("timing"),
           "wall_s": time.perf_counter() - t, "cpu_s": time.process_time() - c}
    _json(done, out)
    return out


def next_checkpoint(cfg: BenchConfig) -> str:
    """The NEXT checkpoint the demonstrations' feedback and labels use (the demo's cache, made if missing)."""
    from factr2_teleop.session.next_cache import create_checkpoint, find_checkpoint

    ck = find_checkpoint(RIG, cfg.next_checkpoint or None)
    if ck is None:
        ck = create_checkpoint(RIG, say=print)
    return str(ck)
