"""FIRST's learning curve on one twin task (SIMULATED, issue #31 item 1): success against optimiser steps.

One policy is trained on the benchmark's demonstrations (bench/bench_first.py's OUT/TASK/demos, collected
there first) with every checkpoint kept; chosen checkpoints are rolled out R episodes each, with the moving
average of the weights (EMA, what rollouts use) and with the trained weights, on the CURVE seed: initial
conditions that neither a demonstration nor the benchmark's evaluation uses. The benchmark's default step
count is read off this curve; nothing here is chosen on the evaluation seed.

    python -m bench.first_curve --bench-out /work/fb/state --task peg-insert --out /work/fb/curve \\
        --steps 8000 --at 500,1000,2000,4000,8000 --rollouts 20 --jobs 2

Resumable: a finished training or rollout set leaves its JSON and is skipped. Writes OUT/curve.json and
OUT/first_curve.png (success with 95 % Wilson intervals, and task progress, against steps).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path

# CURVE_SEED: the curve's rollout seed range, disjoint from demonstrations (1) and evaluation (2)
from bench.first_config import CURVE_SEED, RIG
from bench.first_report import wilson
from bench.first_stages import _json


def train_curve(a: dict) -> dict:
    from policies.training.checkpoint import last_checkpoint
    from policies.training.run import RunOptions, run_training
    from policies.training.train import Dist, TrainConfig

    run = Path(a["out"]) / "run"
    done = run / "train.json"
    if done.is_file():
        return json.loads(done.read_text())
    every = min(a["at"])
    tc = TrainConfig(steps=a["steps"], batch=a["batch"], seed=a["seed"], threads=1, ckpt_every=every,
                     val_every=every, keep_checkpoints=0)
    opts = RunOptions(inputs=[Path(a["bench_out"]) / a["task"] / "demos"], out=run, policy="flow",
                      method=a["method"], observation="state", progress=False, train=tc,
                      thresholds="recording",  # as factr2 train (the curves of 2026-11-26 ran with "next")
                      actions=a.get("actions", "absolute"), resume=last_checkpoint(run) is not None)
    t, c = time.perf_counter(), time.process_time()
    run_training(opts, Dist())
    out = {"wall_s": time.perf_counter() - t, "cpu_s": time.process_time() - c, "run": str(run)}
    _json(done, out)
    return out


def rollout_checkpoint(a: dict, step: int, ema: bool) -> dict:
    from factr2_teleop.session.rollout import RolloutOptions, run_rollout

    ck = Path(a["out"]) / "run" / "checkpoints" / f"step-{step:07d}.json"
    done = Path(a["out"]) / f"rollout-{step}-{'ema' if ema else 'raw'}.json"
    if done.is_file():
        return json.loads(done.read_text())
    c = time.process_time()
    res = run_rollout(RolloutOptions(rig=RIG, policy=ck, task=a["task"], episodes=a["rollouts"],
                                     seed=CURVE_SEED, record=None, progress=False, ema=ema)).to_dict()
    eps = res.get("episodes") or []
    out = {"step": step, "ema": ema, "success": [int(e.get("outcome") == "success") for e in eps],
           "progress": [float(e.get("progress", 0.0)) for e in eps], "stage_rates": res.get("stage_rates"),
           "success_rate": res["success_rate"], "cpu_s": time.process_time() - c}
    _json(done, out)
    return out


def chart(rows: list[dict], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(9, 3.4))
    for ema, style in ((True, "o-"), (False, "s--")):
        pts = sorted((r["step"], r) for r in rows if r["ema"] == ema)
        if not pts:
            continue
        x = [p[0] for p in pts]
        k = [sum(p[1]["success"]) for p in pts]
        n = [len(p[1]["success"]) for p in pts]
        m = [ki / max(ni, 1) for ki, ni in zip(k, n)]
        lo_hi = [wilson(ki, ni) for ki, ni in zip(k, n)]
        err = [[mi - lh[0] for mi, lh in zip(m, lo_hi)], [lh[1] - mi for mi, lh in zip(m, lo_hi)]]
        label = "EMA weights" if ema else "trained weights"
        ax.errorbar(x, [100 * v for v in m], yerr=[[100 * e for e in err[0]], [100 * e for e in err[1]]],
                    fmt=style, capsize=3, label=label)
        bx.plot(x, [sum(p[1]["progress"]) / max(len(p[1]["progress"]), 1) for p in pts], style, label=label)
    steps = sorted({r["step"] for r in rows})
    for a_, yl in ((ax, "success [%] (95 % Wilson)"), (bx, "task progress")):
        log_axis(a_, steps, "optimiser steps", yl)
    save(fig, path, title)


def log_axis(ax, ticks: list, xlabel: str, ylabel: str) -> None:
    """A log x axis labelled at `ticks` (the points measured), a grid and the legend."""
    ax.set_xscale("log")
    ax.set_xticks(ticks, [str(x) for x in ticks])
    ax.minorticks_off()
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)


def save(fig, path: Path, title: str) -> None:
    import matplotlib.pyplot as plt

    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def replot(out: Path) -> None:
    """OUT/first_curve.png again from OUT/curve.json."""
    res = json.loads((out / "curve.json").read_text())
    a = res["config"]
    chart(res["rows"], out / "first_curve.png",
          f"{a['task']}, {a['method']}, {a['rollouts']} rollouts per point (SIMULATED, PRIVILEGED state)")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bench-out", required=True, help="bench_first.py's OUT (its TASK/demos are used)")
    ap.add_argument("--task", default="peg-insert")
    ap.add_argument("--method", default="first")
    ap.add_argument("--out", required=True)
    ap.add_argument("--steps", type=int, default=8000)
    ap.add_argument("--batch", type=int, default=256)
    ap.add_argument("--seed", type=int, default=0, help="training seed")
    ap.add_argument("--at", default="500,1000,2000,4000,8000", help="checkpoints rolled out (steps)")
    ap.add_argument("--raw-at", default=None, help="checkpoints also rolled out with the trained weights "
                    "(default: all of --at)")
    ap.add_argument("--rollouts", type=int, default=20)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--actions", choices=("absolute", "relative"), default="absolute",
                    help="the frame the policy learns its joint targets in (factr2 train --actions)")
    a = vars(ap.parse_args(argv))
    a["at"] = sorted(int(x) for x in a["at"].split(","))
    raw_at = a["at"] if a["raw_at"] is None else sorted(int(x) for x in a["raw_at"].split(",") if x)
    if a["steps"] % min(a["at"]) or any(s % min(a["at"]) or s > a["steps"] for s in a["at"]):
        ap.error("--at: multiples of the smallest one, at most --steps")
    out = Path(a["out"])
    out.mkdir(parents=True, exist_ok=True)
    _json(out / "config.json", a)
    todo = [(s, True) for s in a["at"]] + [(s, False) for s in raw_at]
    rows, t0 = [], time.perf_counter()
    with ProcessPoolExecutor(a["jobs"], mp_context=mp.get_context("spawn")) as ex:
        running = {ex.submit(train_curve, a): ("train", None)}
        while running or todo:
            for s, ema in list(todo):  # a checkpoint's rollouts start as soon as it is written
                ck = out / "run" / "checkpoints" / f"step-{s:07d}.json"
                if ck.is_file():
                    todo.remove((s, ema))
                    running[ex.submit(rollout_checkpoint, a, s, ema)] = ("rollout", (s, ema))
            if not running:
                raise SystemExit(f"checkpoints missing: {todo}")
            done, _ = wait(running, timeout=5.0, return_when=FIRST_COMPLETED)
            for f in done:
                kind, what = running.pop(f)
                r = f.result()
                if kind == "rollout":
                    rows.append(r)
                    print(f"  step {what[0]} {'EMA' if what[1] else 'raw'}: success {sum(r['success'])}/"
                          f"{len(r['success'])} ({time.perf_counter() - t0:.0f} s)", flush=True)
                else:
                    print(f"  trained ({r['wall_s']:.0f} s)", flush=True)
    res = {"simulated": True, "observation": "state (PRIVILEGED twin object state)", "config": a,
           "curve_seed": CURVE_SEED, "rows": sorted(rows, key=lambda r: (r["step"], not r["ema"])),
           "wall_s": time.perf_counter() - t0}
    _json(out / "curve.json", res)
    chart(res["rows"], out / "first_curve.png",
          f"{a['task']}, {a['method']}, {a['rollouts']} rollouts per point (SIMULATED, PRIVILEGED state)")
    for r in res["rows"]:
        lo, hi = wilson(sum(r["success"]), len(r["success"]))
        prog = sum(r["progress"]) / max(len(r["progress"]), 1)
        print(f"step {r['step']:6d} {'EMA' if r['ema'] else 'raw'}: {100 * r['success_rate']:.0f} % "
              f"[{100 * lo:.0f}, {100 * hi:.0f}]  progress {prog:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
