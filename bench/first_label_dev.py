"""A change to FIRST's contact labels, before and after, on development episodes (SIMULATED).

    python -m bench.first_label_dev --bench OUT --task cap-screw --score motion --rollout-seed 12 --out DEV
    python -m bench.first_label_dev --out DEV --report [--results NAME]   # results/NAME.json, raw episodes

OUT is a `bench_first` results folder (OUT/config.json; its demonstrations and its trained policies). For
each training seed S this trains `first` again on the same demonstrations with the same recipe (steps,
batch, ratio, observation, training seed), only the labels changed (`--contact-score SCORE`), into
DEV/TASK/first-SCORE/seedS, and rolls out that policy and the benchmark's own ones (first, and with
--cells also base-torque, read from OUT, never retrained) on the DEVELOPMENT rollout seed: episodes the
evaluation never uses, so a change is judged before the evaluation sees it. Each rollout set is written to
DEV/TASK/CELL/seedS/rollout.json; both stages resume. The report pairs by episode (bench.first_force):
the new labels against the old (before / after) and, when rolled out, against base-torque.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from bench import first_force as F
from bench import harness
from bench.portable import portable, portable_text


def _write(path: Path, obj) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(obj, indent=1, default=float))
    os.replace(tmp, path)


def train_relabelled(bench: str, task: str, seed: int, score: str, dev: str) -> str:
    """first on OUT's demonstrations with OUT's recipe and the labels' score changed; resumes."""
    import torch

    from bench.first_config import CELLS, BenchConfig
    from bench.first_stages import training_options
    from policies.training.checkpoint import last_checkpoint
    from policies.training.run import run_training
    from policies.training.train import Dist

    cfg = BenchConfig(**json.loads((Path(bench) / "config.json").read_text()))
    run = Path(dev) / task / f"first-{score}" / f"seed{seed}"
    if (run / "train.json").is_file():
        return str(run)
    cell = CELLS["first"]._replace(score=score)  # the benchmark's first, only the labels changed
    opts = training_options(cfg, task, cell, run, seed, cfg.threads or 1,
                            resume=last_checkpoint(run) is not None)
    t = time.perf_counter()
    run_training(opts, Dist(device=torch.device("cpu")))
    _write(run / "train.json", {"task": task, "seed": seed, "score": score,
                                "wall_s": time.perf_counter() - t})
    return str(run)


def dev_rollout(policy: str, task: str, episodes: int, seed: int, dest: str) -> dict:
    """A rollout set of one policy on the development seed, written to DEST (resumes: kept when there)."""
    from factr2_teleop.session.rollout import RolloutOptions, run_rollout

    path = Path(dest)
    if path.is_file():
        return json.loads(path.read_text())
    t, c = time.perf_counter(), time.process_time()
    res = run_rollout(RolloutOptions(rig="sim-piper", policy=Path(policy), task=task, episodes=episodes,
                                     seed=seed, record=None, progress=False)).to_dict()
    out = {"task": task, "policy": Path(policy).name, "rollout_seed": seed,
           "success_rate": res["success_rate"], "mean_progress": res["mean_progress"],
           "stage_rates": res.get("stage_rates"), "episodes": res.get("episodes"),
           "wall_s": time.perf_counter() - t, "cpu_s": time.process_time() - c}
    path.parent.mkdir(parents=True, exist_ok=True)
    _write(path, out)
    return out


def run(args) -> None:
    bench, dev = Path(args.bench), Path(args.out)
    cfg = json.loads((bench / "config.json").read_text())
    if args.rollout_seed == cfg.get("eval_seed"):
        raise SystemExit(f"--rollout-seed {args.rollout_seed} is OUT's evaluation seed: pick a development "
                         "one")
    dev.mkdir(parents=True, exist_ok=True)
    _write(dev / "config.json", {"bench": str(bench), "task": args.task, "score": args.score,
                                 "rollout_seed": args.rollout_seed, "rollouts": args.rollouts,
                                 "seeds": args.seeds, "cells": args.cells, "eval_seed": cfg.get("eval_seed")})
    new = f"first-{args.score}"
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:  # the trainings first: the longest path
        trains = [(s, pool.submit(train_relabelled, str(bench), args.task, s, args.score, str(dev)))
                  for s in args.seeds]
        olds = [(c, s, pool.submit(dev_rollout, str(bench / args.task / c / f"seed{s}"), args.task,
                                   args.rollouts, args.rollout_seed,
                                   str(dev / args.task / c / f"seed{s}" / "rollout.json")))
                for s in args.seeds for c in args.cells]
        for s, fut in trains:
            runp = fut.result()
            print(f"  train {new} seed {s}: done", flush=True)
            dev_rollout(runp, args.task, args.rollouts, args.rollout_seed,
                        str(dev / args.task / new / f"seed{s}" / "rollout.json"))
            print(f"  rollout {new} seed {s}: done", flush=True)
        for c, s, fut in olds:
            fut.result()
            print(f"  rollout {c} seed {s}: done", flush=True)


def report(dev: Path) -> dict:
    cfg = json.loads((dev / "config.json").read_text())
    task, new = cfg["task"], f"first-{cfg['score']}"
    runs = F.load_runs(dev)
    cells = {c: F.cell_summary(runs, task, c) for c in [new, *cfg["cells"]]}
    pairs = {f"{new} vs {c}": F.paired(runs, task, (new, "live"), (c, "live")) for c in cfg["cells"]}
    raw = {c: {str(s): r.get("episodes") for (t, cc, s, h), r in runs.items() if (t, cc) == (task, c)}
           for c in cells}  # every rollout's per-episode outcome and progress, as the benchmark keeps them
    out = {"config": cfg, "cells": cells, "pairs": pairs, "episodes": raw}
    for c, s in cells.items():
        if s:
            print(f"{c:<14} {s['k']:>3} / {s['n']:<3} = {100 * s['success']:4.0f} % "
                  f"[{100 * s['wilson'][0]:.0f}, {100 * s['wilson'][1]:.0f}]  progress {s['progress']:.2f}  "
                  f"fails at {s['failing_stage']}")
    for name, p in pairs.items():
        if p:
            print(f"{name}: {p['only_a']} / {p['only_b']} discordant, McNemar p {p['mcnemar_p']:.3f}, "
                  f"progress {p['progress_diff']:+.3f} "
                  f"[{p['progress_ci'][0]:+.3f}, {p['progress_ci'][1]:+.3f}]")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", required=True, help="the development results folder DEV")
    ap.add_argument("--bench", help="the bench_first folder OUT whose demonstrations and policies are used")
    ap.add_argument("--task", default="cap-screw")
    ap.add_argument("--score", default="motion", help="the labels' --contact-score to try")
    ap.add_argument("--seeds", type=lambda s: [int(x) for x in harness.names(s)], default=[0])
    ap.add_argument("--cells", type=harness.names, default=["first"],
                    help="OUT's policies to roll out beside")
    ap.add_argument("--rollout-seed", type=int, default=12, help="a development seed, never the evaluation's")
    ap.add_argument("--rollouts", type=int, default=32)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--report", action="store_true", help="only the report of what DEV holds")
    ap.add_argument("--results", default="", help="also write results/NAME.json (raw episodes included)")
    args = ap.parse_args(argv)
    if not args.report:
        if not args.bench:
            ap.error("--bench OUT is needed to run (or --report)")
        run(args)
    data = report(Path(args.out))
    _write(Path(args.out) / "report.json", data | {"cmd": harness.command(None, "bench.first_label_dev"),
                                                   "machine": harness.machine()})
    if args.results:  # DEV and OUT are scratch folders: named, not the machine's paths
        roots = {"DEV": Path(args.out).resolve(), "OUT": Path(data["config"]["bench"]).resolve()}
        cmd = harness.command(None, "bench.first_label_dev").replace(args.out, "DEV")
        print(harness.write(harness.RESULTS / f"{args.results}.json",
                            harness.record(args.results, portable(data, roots), simulated=True,
                                           cmd=portable_text(cmd, roots))))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
