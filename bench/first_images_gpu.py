"""The FIRST benchmark on camera frames where a GPU is lent (SIMULATED; issue #31 item 5).

One task, the benchmark's code paths (bench/bench_first.py's stages), sized for ONE command on the lent
machine (one GPU, 16 CPU cores, a few minutes):

1. collection WITH both twin cameras, split over several collection seeds in parallel processes (collection is
   sequential per seed): seeds 5, 6, ... (never 1, 2 = the evaluation's, 4 = the learning curve's), each a
   few episodes, all into OUT/TASK/demos so that training reads every one of them. Episode seeds are
   seed * 100003 + k (factr2_teleop/session/task_episodes.py): 500015... for seed 5, disjoint from the
   evaluation's 200006... (checked on the recorded seeds, bench_first.check_disjoint_seeds);
2. the recordings' frame caches decoded in parallel (one process per recording), so the training runs start
   on cached frames;
3. training of `base-torque` and `first` (1:5:1), `--obs images`, small preset, on the GPU, the runs side by
   side as processes (policies.training.run.run_training, as `factr2 train`); a wall-clock guard stops a run
   early (checkpoint kept, said in its train.json) so the command ends inside its limit;
4. rollouts of every policy on the evaluation seed (2: episodes 200006...), on the CPU cores: R episodes per
   policy split into contiguous blocks over P processes; a block starting at episode k0 uses the episode
   seeds episode_seed(2, k0 + k) (the same initial conditions as one sequential run; only the arm's state
   carried from the previous episode differs at a block's start);
5. results.json in bench_first's shape, table.md / first_results.json / first_bench.png from
   bench/first_report.py, and timings per stage.

    python -m bench.first_images_gpu --out /tmp/fig --toy          # the local end-to-end check (CPU, minutes)
    python -m bench.first_images_gpu --out $OUT/run                # the GPU machine's configuration

See bench/first_images_gpu.sh for the device command (packages, EGL).
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time
from concurrent.futures import CancelledError, ProcessPoolExecutor
from dataclasses import asdict
from pathlib import Path

from bench import harness
from bench.bench_first import (
    BenchConfig,
    _json,
    check_disjoint_seeds,
)
from bench.first_images_workers import (
    blocks,
    collect_part,
    merge_demos,
    merge_rollouts,
    prewarm,
    rollout_part,
    say,
    train_part,
)
from bench.first_report import aggregate, wilson, write_report

FORBIDDEN_COLLECT_SEEDS = (1, 2, 3, 4)  # 1: bench demos, 2: evaluation, 3: spare, 4: learning curve


def partial(stages: dict, **kw) -> None:
    """What is done so far, to $FIRST_IMAGES_PARTIAL (a command killed at its limit still returns it)."""
    path = os.environ.get("FIRST_IMAGES_PARTIAL")
    if path:
        _json(Path(path), {"stages": stages, **kw})


def machine() -> dict:
    import torch

    m = {**harness.machine(), "cpus": os.cpu_count(), "loadavg_end": os.getloadavg(),
         "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
         "mujoco_gl": os.environ.get("MUJOCO_GL", "")}
    if m["gpu"]:
        m["gpu_mem_gib"] = round(torch.cuda.get_device_properties(0).total_memory / 2**30, 1)
    return m


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--task", default="wipe")
    ap.add_argument("--collect-seeds", default="5-12", help="A-B or a,b,c (never 1-4)")
    ap.add_argument("--demos-per-seed", type=int, default=6)
    ap.add_argument("--cells", default="base-torque,first")
    ap.add_argument("--train-seeds", type=int, default=1)
    ap.add_argument("--steps", type=int, default=1500)
    ap.add_argument("--batch", type=int, default=128)
    ap.add_argument("--train-budget-s", type=float, default=150.0,
                    help="wall time per training run (the probe sizes the steps to it; a guard stops there)")
    ap.add_argument("--probe-steps", type=int, default=30, help="steps of the timing probe (0: none)")
    ap.add_argument("--min-steps", type=int, default=200, help="fewest steps the probe may choose")
    ap.add_argument("--train-threads", type=int, default=4, help="torch threads per training process")
    ap.add_argument("--device", default="auto", help="training device: auto (cuda if there), cuda, cpu")
    ap.add_argument("--rollouts", type=int, default=32, help="episodes per policy")
    ap.add_argument("--rollout-procs", type=int, default=0, help="processes for the rollouts (0: the cores)")
    ap.add_argument("--block", type=int, default=2, help="rollout episodes per process start")
    ap.add_argument("--rollout-budget-s", type=float, default=150.0,
                    help="blocks not started by then are dropped (the running ones finish)")
    ap.add_argument("--collect-procs", type=int, default=0, help="processes for the collection (0: seeds)")
    ap.add_argument("--max-seconds", type=float, default=None, help="rollout episode limit (default task's)")
    ap.add_argument("--next", default="", help="NEXT checkpoint (default: the demo's cache)")
    ap.add_argument("--label", default="", help="machine label for the report (e.g. the device reply's)")
    ap.add_argument("--toy", action="store_true", help="local check: 2 seeds x 1 demo, 10 steps, 1 rollout")
    a = ap.parse_args(argv)
    if a.toy:
        a.collect_seeds, a.demos_per_seed, a.steps, a.batch, a.rollouts = "7-8", 1, 10, 8, 2
        a.rollout_procs, a.max_seconds, a.train_threads = 2, a.max_seconds or 4.0, 1
        a.probe_steps, a.min_steps, a.block = 6, 4, 1
    if "-" in a.collect_seeds:
        lo, hi = (int(x) for x in a.collect_seeds.split("-"))
        a.seeds = list(range(lo, hi + 1))
    else:
        a.seeds = [int(x) for x in a.collect_seeds.split(",")]
    bad = sorted(set(a.seeds) & set(FORBIDDEN_COLLECT_SEEDS))
    if bad:
        ap.error(f"collection seeds {bad}: 1-4 are the benchmark's own (2 evaluation, 4 curve)")
    a.cells = [c.strip() for c in a.cells.split(",") if c.strip()]
    return a


def main(argv=None) -> int:
    a = parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    import multiprocessing as mp

    from bench.bench_first import next_checkpoint
    from policies.models.config import preset

    cores = os.cpu_count() or 1
    ctx = mp.get_context("spawn")
    cfg = BenchConfig(out=str(out), obs="images", tasks=[a.task], demos=len(a.seeds) * a.demos_per_seed,
                      seeds=a.train_seeds, rollouts=a.rollouts, steps=a.steps, batch=a.batch, preset="small",
                      table="headline", max_seconds=a.max_seconds, jobs=a.rollout_procs or cores,
                      next_checkpoint=a.next, quick=a.toy)
    ck = next_checkpoint(cfg)
    stages: dict = {}
    t_all = time.perf_counter()

    # 1. collection, one process per collection seed
    t = time.perf_counter()
    say(f"collect: {a.task}, seeds {a.seeds} x {a.demos_per_seed} episodes with cameras")
    with ProcessPoolExecutor(a.collect_procs or len(a.seeds), mp_context=ctx) as ex:
        demo_parts = list(ex.map(collect_part, *zip(*[(str(out), a.task, s, a.demos_per_seed, ck)
                                                      for s in a.seeds])))
    stages["collect_wall_s"] = time.perf_counter() - t
    sim = sum(p["sim_s"] for p in demo_parts)
    say(f"collect: {sum(p['episodes'] for p in demo_parts)} episodes, {sim:.0f} s simulated, "
        f"{stages['collect_wall_s']:.0f} s wall; CPU {sum(p['cpu_s'] for p in demo_parts):.0f} s "
        f"({sum(p['cpu_s'] for p in demo_parts) / max(sim, 1e-9):.2f} CPU s per simulated s)")

    partial(stages, collect=[{k: v for k, v in p.items() if k != "results"} for p in demo_parts])

    # 2. frame caches, one process per recording
    t = time.perf_counter()
    size = preset("small", "flow").image_size
    with ProcessPoolExecutor(min(cores, len(demo_parts)), mp_context=ctx) as ex:
        warm = list(ex.map(prewarm, [p["recording"] for p in demo_parts], [size] * len(demo_parts)))
    stages["frame_cache_wall_s"] = time.perf_counter() - t
    say(f"frame caches: {sum(w['frames'] for w in warm)} frames at {size} px, "
        f"{stages['frame_cache_wall_s']:.0f} s")

    # 3. training, the runs side by side on the GPU; a probe of the same runs side by side first times a
    # step, and the steps are what fits the budget (at most --steps), so the cosine schedule ends at the end
    runs = [(c, s) for c in a.cells for s in range(a.train_seeds)]
    steps = a.steps
    if a.probe_steps:
        t = time.perf_counter()
        with ProcessPoolExecutor(len(runs), mp_context=ctx) as ex:
            probes = list(ex.map(train_part, *zip(*[(str(out), a.task, c, s, a.probe_steps, a.batch, a.device,
                                                      600.0, a.train_threads, True) for c, s in runs])))
        stages["train_probe_wall_s"] = time.perf_counter() - t
        step_s = max(p["step_s_median"] for p in probes)
        setup_s = max(p["setup_s"] or 0.0 for p in probes)
        fit = int((a.train_budget_s - setup_s) / step_s * 0.85)  # validation and checkpoints: 15 %
        steps = max(a.min_steps, min(a.steps, fit))
        say(f"train probe: {step_s * 1e3:.0f} ms per step with {len(runs)} runs side by side, set-up "
            f"{setup_s:.0f} s -> {steps} steps (budget {a.train_budget_s:.0f} s fits {fit}, "
            f"at most {a.steps})")
    cfg.steps = steps
    t = time.perf_counter()
    say(f"train: {len(runs)} run(s) x {steps} steps x batch {a.batch}, device {a.device}")
    with ProcessPoolExecutor(len(runs), mp_context=ctx) as ex:
        trains = list(ex.map(train_part, *zip(*[(str(out), a.task, c, s, steps, a.batch, a.device,
                                                 a.train_budget_s, a.train_threads) for c, s in runs])))
    stages["train_wall_s"] = time.perf_counter() - t
    for tr in trains:
        say(f"train {tr['cell']} seed {tr['seed']}: {tr['steps']} steps on {tr['device']} "
            f"({tr['gpu'] or 'CPU'}), {tr['wall_s']:.0f} s, {tr['step_s_median'] * 1e3:.0f} ms per step, "
            f"val loss {tr['val'].get('val/loss', float('nan')):.3f}"
            + (" STOPPED EARLY by the guard" if tr["stopped_early"] else ""))

    partial(stages, trains=trains)

    # 4. rollouts on the CPU cores: every policy's episodes in blocks of --block episodes, interleaved over
    # the policies, all in one pool; blocks not started after --rollout-budget-s are dropped (said)
    t = time.perf_counter()
    procs = a.rollout_procs or cores
    bl = blocks(a.rollouts, -(-a.rollouts // max(1, a.block)))
    jobs = [(tr, k0, n) for k0, n in bl for tr in trains]
    say(f"rollout: {len(trains)} policies x {a.rollouts} episodes in {len(jobs)} blocks on {procs} processes")
    parts_of: dict = {}
    with ProcessPoolExecutor(procs, mp_context=ctx) as ex:
        futs = [(tr, ex.submit(rollout_part, tr["run"], a.task, k0, n, a.max_seconds)) for tr, k0, n in jobs]
        guard = threading.Timer(a.rollout_budget_s, lambda: [f.cancel() for _, f in futs])
        guard.daemon = True
        guard.start()
        dropped = 0
        for tr, f in futs:
            try:
                parts_of.setdefault((tr["cell"], tr["seed"]), []).append(f.result())
            except CancelledError:
                dropped += 1
        guard.cancel()
    stages["rollout_wall_s"] = time.perf_counter() - t
    if dropped:
        say(f"rollout: {dropped} block(s) not started inside {a.rollout_budget_s:.0f} s, dropped")
    rolls = []
    for tr in trains:
        r = merge_rollouts(a.task, tr["cell"], tr["seed"], parts_of[(tr["cell"], tr["seed"])],
                           stages["rollout_wall_s"])
        _json(Path(tr["run"]) / "rollout.json", r)
        rolls.append(r)
        k = sum(e["outcome"] == "success" for e in r["episodes"])
        lo, hi = wilson(k, len(r["episodes"]))
        say(f"rollout {tr['cell']} seed {tr['seed']}: {k}/{len(r['episodes'])} success "
            f"(95 % Wilson {100 * lo:.0f}-{100 * hi:.0f} %), progress {r['mean_progress']:.2f}, "
            f"violations {r['timing']['command_violations']}")

    # 5. results and report
    demos = {a.task: merge_demos(a.task, demo_parts, trains)}
    stages["total_wall_s"] = time.perf_counter() - t_all
    timing = dict(stages)
    timing.update({"collect_cpu_s": demos[a.task]["cpu_s"], "train_cpu_s": sum(r["cpu_s"] for r in trains),
                   "rollout_cpu_s": sum(r["cpu_s"] for r in rolls)})
    m = machine()
    m["label"] = a.label
    results = {
        "simulated": True, "command": " ".join(["python", "-m", "bench.first_images_gpu", *sys.argv[1:]]),
        "observation": "images (both twin cameras, 96 px, small preset)", "config": asdict(cfg),
        "next_checkpoint": ck, "seeds": check_disjoint_seeds(demos, rolls), "machine": m, "timing": timing,
        "demos": {k: {x: v for x, v in d.items() if x != "results"} for k, d in demos.items()},
        "demo_seeds_all": sorted(r["seed"] for r in demos[a.task]["results"]),
        "train": trains, "rollout": rolls, "frame_cache": warm,
    }
    results["summary"] = aggregate(trains, rolls)
    _json(out / "results.json", results)
    write_report(results, out)
    say("stages [s]: " + ", ".join(f"{k[:-7]} {v:.0f}" for k, v in stages.items()))
    print((out / "table.md").read_text(), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
