"""The workers of bench/first_images_gpu.py (SIMULATED; issue #31 item 5): collection of one seed's part,
the frame-cache prewarm, one training run under a wall-clock guard, one block of rollouts on shifted episode
seeds, and the merges of the parts into bench_first's shapes. Top-level functions, because the spawned
worker processes pickle them by name.
"""

from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path

from bench.bench_first import EVAL_SEED, HEADLINE_CELLS, RIG, _json


def say(msg: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", flush=True)


# -- workers (top-level functions: spawn pickles them by name) ---------------------------------------------
def collect_part(out: str, task: str, seed: int, episodes: int, ck: str) -> dict:
    from factr2_teleop.tasks.run import CollectConfig, collect, output_paths

    cc = CollectConfig(rig=RIG, task=task, episodes=episodes, out=str(Path(out) / task / "demos"), seed=seed,
                       mode="next", checkpoint=ck, cameras=True)
    mcap, summary = output_paths(cc, RIG)
    if summary.is_file():
        return json.loads(summary.read_text())
    for p in (mcap, summary):  # an interrupted collection of this seed: start it again
        p.unlink(missing_ok=True)
    return collect(cc, progress=False)


def prewarm(mcap: str, size: int) -> dict:
    """The recording's episode arrays and its frame caches at `size` px (what training reads)."""
    from policies.data.frame_cache import camera_frames
    from policies.data.recordings import load_episodes

    t = time.perf_counter()
    episodes, _ = load_episodes([mcap])
    n = 0
    for rec in dict.fromkeys(ep.recording for ep in episodes):
        for cam in rec.cameras:
            n += len(camera_frames(rec, cam, size))
    return {"recording": mcap, "frames": n, "wall_s": time.perf_counter() - t}


def train_part(out: str, task: str, cell: str, seed: int, steps: int, batch: int, device: str,
               budget_s: float, threads: int, probe: bool = False) -> dict:
    """One training run on `device` (bench_first.train_cell with the device and a wall-clock guard: the loop
    ends after the current step once budget_s have passed, its checkpoint kept, said in the result). probe: a
    short run in OUT/probe/ to time a step (nothing of it is reported as a result)."""
    import numpy as np
    import torch

    from policies.training.checkpoint import read_meta
    from policies.training.run import RunOptions, run_training
    from policies.training.train import Dist, TrainConfig

    run = Path(out) / ("probe" if probe else task) / cell / f"seed{seed}"
    done = run / "train.json"
    if done.is_file():
        return json.loads(done.read_text())
    if probe:
        import shutil

        shutil.rmtree(run, ignore_errors=True)
    method, ratio = HEADLINE_CELLS[cell].method, HEADLINE_CELLS[cell].ratio  # the default (l1) labels
    dev = torch.device("cuda" if device == "auto" and torch.cuda.is_available() else
                       ("cpu" if device == "auto" else device))
    tc = TrainConfig(steps=steps, batch=batch, log_every=10, seed=seed, threads=threads)
    opts = RunOptions(inputs=[Path(out) / task / "demos"], out=run, policy="flow", method=method, ratio=ratio,
                      preset="small", thresholds="recording", observation="images", progress=False, train=tc)
    stop = threading.Event()
    t, c = time.perf_counter(), time.process_time()
    timer = threading.Timer(budget_s, stop.set)  # the guard: the loop ends after the current step
    timer.daemon = True
    timer.start()
    ticks: list[float] = []  # clock after every step (validation steps included: the median leaves them out)

    def on_progress(row):
        ticks.append(time.perf_counter())

    try:
        run_training(opts, Dist(device=dev), on_progress=on_progress, stop=stop)
    finally:
        timer.cancel()
    meta = read_meta(run)
    wall = time.perf_counter() - t
    step_s = float(np.median(np.diff(ticks[2:]))) if len(ticks) > 4 else float("nan")
    out_ = {"task": task, "cell": cell, "method": method, "ratio": meta["ratio"], "seed": seed,
            "val": meta.get("metrics", {}), "samples": meta["samples"], "steps": meta["step"],
            "steps_asked": steps, "stopped_early": bool(meta["step"] < steps), "phases": meta["phases"],
            "wall_s": wall, "cpu_s": time.process_time() - c, "device": str(dev),
            "gpu": torch.cuda.get_device_name(0) if dev.type == "cuda" else None,
            "step_s_median": step_s, "setup_s": (ticks[0] - t) if ticks else None,
            "torch_threads": torch.get_num_threads(), "run": str(run)}
    _json(done, out_)
    return out_


def shift_episode_seeds(k0: int):
    """Episode k of a session now uses the seed of episode k0 + k (task_episodes.episode_seed, which the
    rollout's episodes call): a block starting at k0 meets the initial conditions of one sequential run. The
    pool reuses its processes, so the shift is always from the module's own function, never on top of an
    earlier block's (the first GPU run stacked them). Returns the unshifted function."""
    import factr2_teleop.session.task_episodes as tc

    base = tc.__dict__.setdefault("_episode_seed_unshifted", tc.episode_seed)
    tc.episode_seed = lambda seed, k: base(seed, k + k0)
    return base


def rollout_part(run: str, task: str, k0: int, n: int, max_seconds: float | None) -> dict:
    """Episodes k0 .. k0+n-1 of the evaluation seed for the policy in `run`, on the CPU."""
    os.environ["CUDA_VISIBLE_DEVICES"] = ""  # the policy runs on this process's CPU core (as on a robot PC)
    from factr2_teleop.session.rollout import RolloutOptions, run_rollout

    base = shift_episode_seeds(k0)
    t, c = time.perf_counter(), time.process_time()
    res = run_rollout(RolloutOptions(rig=RIG, policy=Path(run), task=task, episodes=n, seed=EVAL_SEED,
                                     record=None, progress=False, max_seconds=max_seconds)).to_dict()
    for e in res["episodes"]:
        e["index"] = int(e["index"]) + k0
        want = base(EVAL_SEED, e["index"])
        if e["seed"] != want:
            raise RuntimeError(f"episode {e['index']} ran seed {e['seed']}, not {want}")
    res["wall_s_part"], res["cpu_s_part"], res["k0"] = time.perf_counter() - t, time.process_time() - c, k0
    return res


# -- orchestration -------------------------------------------------------------------------------------------
def blocks(total: int, parts: int) -> list[tuple[int, int]]:
    """[(k0, n)]: `total` episodes in at most `parts` contiguous blocks whose sizes differ by at most one."""
    parts = max(1, min(parts, total))
    q, r = divmod(total, parts)
    out, k = [], 0
    for i in range(parts):
        n = q + (i < r)
        out.append((k, n))
        k += n
    return out


def merge_rollouts(task: str, cell: str, seed: int, parts: list[dict], wall_s: float) -> dict:
    """One rollout.json (bench_first.rollout_cell's shape) from the blocks of one policy."""
    import numpy as np

    parts = sorted(parts, key=lambda p: p["k0"])
    eps = [e for p in parts for e in p["episodes"]]
    stages = list(parts[0]["stage_rates"])
    tim = [p["timing"] for p in parts]
    timing = {k: int(sum(t.get(k) or 0 for t in tim))
              for k in ("commands_sent", "command_violations", "refused_nonfinite", "refused_outside_limits",
                        "targets_clamped", "safety_clipped")}
    w = [t.get("chunks") or 0 for t in tim]
    if sum(w):  # chunk latency (wall time of one policy call on the CPU), weighted by the blocks' chunks
        means = [t.get("chunk_latency_mean_ms") or 0.0 for t in tim]
        timing["chunk_latency_mean_ms"] = float(np.dot(w, means) / sum(w))
        timing["chunk_latency_p99_ms_max"] = float(max(t.get("chunk_latency_p99_ms") or 0.0 for t in tim))
    return {"task": task, "cell": cell, "seed": seed,
            "success_rate": float(np.mean([e["outcome"] == "success" for e in eps])),
            "mean_progress": float(np.mean([e["progress"] for e in eps])),
            "stage_rates": {s: float(np.mean([e["stages"].get(s) is not None for e in eps])) for s in stages},
            "episodes": eps, "timing": timing, "blocks": [[p["k0"], len(p["episodes"])] for p in parts],
            "timing_blocks": tim, "wall_s": wall_s, "cpu_s": float(sum(p["cpu_s_part"] for p in parts))}


def merge_demos(task: str, parts: list[dict], trains: list[dict]) -> dict:
    """The task's demonstrations as one entry (phase shares: the per-seed shares weighted by simulated time;
    thresholds: the ones training used, Otsu over every demonstration)."""
    import numpy as np

    w = np.array([p.get("sim_s") or 0.0 for p in parts], float)
    res = [r for p in parts for r in p["results"]]
    shares = None
    sh = [p.get("phase_shares") for p in parts]
    if all(sh) and w.sum() > 0:
        shares = {k: float(np.dot(w, [s[k] for s in sh]) / w.sum())
                  for k in ("free", "pre_contact", "contact")}
    th = next((t["phases"] for t in trains if t.get("phases")), {})
    return {"episodes": len(res), "success_rate": float(np.mean([r["outcome"] == "success" for r in res])),
            "progress_mean": float(np.mean([r["progress"] for r in res])), "phase_shares": shares,
            "phase_thresholds_nm": [th.get("t_low"), th.get("t_high")] if th else None,
            "collect_seeds": [p["seed"] for p in parts], "sim_s": float(w.sum()),
            "wall_s": max(p["wall_s"] for p in parts), "cpu_s": float(sum(p["cpu_s"] for p in parts)),
            "frames_written": int(sum(p.get("frames_written") or 0 for p in parts)),
            "frames_dropped": int(sum(p.get("frames_dropped") or 0 for p in parts)), "results": res}
