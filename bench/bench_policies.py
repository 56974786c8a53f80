"""FIRST policy benchmarks (docs/benchmarks.md, "Policies"):

loader     samples/s of the training batch path (cached frames, RandomResizedCrop, normalisation),
           2 cameras, small preset (96 px), batch 128
train      optimiser steps/s x batch = samples/s, both presets, both policies (CPU here; CUDA if present)
latency    one action chunk on one core, small preset, 2 cameras (flow: encode once + 10 Euler steps; and
           its parts: the encoding, one velocity step), wall and the thread's CPU time
phases     validation action loss per phase F / PC / C, `base-torque` vs `first`, same steps and seed
           (needs recordings with contact: --recordings DIR, e.g. from `factr2 collect --task wipe`)

  python -m bench.bench_policies [--only loader,train,latency] [--presets small]
                                 [--recordings DIR --steps 400]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from policies.data.dataset import build_dataset
from policies.data.recordings import load_episodes
from policies.labels.labelling import Thresholds
from policies.models.config import preset
from policies.models.policy import make_policy


def _synthetic(folder: Path, seconds: float = 20.0) -> Path:
    from tests.policy_helpers import write_recording

    return write_recording(folder / "bench.mcap", episodes=4, seconds=seconds, contact_at=(3.0, 9.0, 15.0))


def bench_loader(folder: Path, n_batches: int = 40, batch: int = 128) -> dict:
    eps, arms = load_episodes([folder])
    data = build_dataset(eps, arms, th=Thresholds.given(1.0, 3.0), image_size=96)
    idx = np.flatnonzero(np.ones(len(data), bool))
    gen = torch.Generator().manual_seed(0)
    rng = np.random.default_rng(0)
    data.batch(rng.choice(idx, batch), data.pre.image.draw_crops(batch, gen))  # warm the page cache
    t = time.perf_counter()
    for _ in range(n_batches):
        data.batch(rng.choice(idx, batch), data.pre.image.draw_crops(batch, gen))
    dt = time.perf_counter() - t
    return {
        "samples_per_s": n_batches * batch / dt,
        "cameras": len(data.names.cameras),
        "image_px": 96,
        "batch": batch,
        "threads": torch.get_num_threads(),
    }


def _fake_batch(cfg, b: int) -> dict:
    g = torch.Generator().manual_seed(0)
    s = cfg.image_size
    return {
        "images": torch.randint(0, 256, (b, cfg.n_cameras, s, s, 3), generator=g, dtype=torch.uint8),
        "state": torch.randn(b, cfg.state_dim, generator=g),
        "force": torch.randn(b, cfg.force_dim, generator=g),
        "action": torch.randn(b, cfg.chunk, cfg.action_dim, generator=g),
        "mask": torch.ones(b, cfg.chunk, dtype=torch.bool),
    }


def bench_train(device: torch.device, steps: int = 3, presets=("small", "paper")) -> list[dict]:
    out = []
    sizes = {"small": 32, "paper": 4 if device.type == "cpu" else 128}
    for name, batch in ((n, sizes[n]) for n in presets):
        for policy in ("flow", "act"):
            cfg = preset(name, policy)
            cfg.n_cameras, cfg.state_dim, cfg.force_dim, cfg.action_dim = 2, 7, 6, 7
            torch.manual_seed(0)
            model = make_policy(cfg).to(device)
            opt = torch.optim.AdamW(model.parameters(), lr=3e-4, weight_decay=0.05, betas=(0.9, 0.95))
            b = {k: v.to(device) for k, v in _fake_batch(cfg, batch).items()}
            noise = {
                k: v.to(device) for k, v in type(model).draw_noise(cfg, batch, torch.Generator()).items()
            }
            ac = (
                torch.autocast("cuda", dtype=torch.bfloat16)
                if device.type == "cuda"
                else torch.autocast("cpu", enabled=False)
            )

            def step(model=model, opt=opt, b=b, noise=noise, ac=ac):
                with ac:
                    loss = model(b, noise)[0].float().mean()
                loss.backward()
                opt.step()
                opt.zero_grad(set_to_none=True)

            step()
            if device.type == "cuda":
                torch.cuda.synchronize()
            t = time.perf_counter()
            for _ in range(steps):
                step()
            if device.type == "cuda":
                torch.cuda.synchronize()
            dt = (time.perf_counter() - t) / steps
            out.append(
                {
                    "preset": name,
                    "policy": policy,
                    "batch": batch,
                    "device": str(device),
                    "params_M": sum(p.numel() for p in model.parameters()) / 1e6,
                    "step_s": dt,
                    "samples_per_s": batch / dt,
                }
            )
            print(json.dumps(out[-1]), flush=True)
    return out


def _cpu_ms(fn, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Wall and this thread's CPU time [ms] of n calls (the load of other processes cannot inflate the
    second, only share the core's caches)."""
    ts, cpu = [], []
    for _ in range(n):
        t, c = time.perf_counter(), time.thread_time()
        fn()
        ts.append(time.perf_counter() - t)
        cpu.append(time.thread_time() - c)
    return np.asarray(ts) * 1e3, np.asarray(cpu) * 1e3


def _flow_parts(model, b: dict, noise: dict, n: int) -> dict:
    """Where a flow chunk's time goes: the observation, once, then each Euler step (median CPU ms)."""
    mem, k = model.encode(b), model.cfg.flow_steps
    cond = model.conditioning(torch.arange(k, dtype=torch.float32) / k)
    step = [[t[:1] for t in terms] for terms in cond]
    return {
        "encode_cpu_ms": float(np.median(_cpu_ms(lambda: model.encode(b), n)[1])),
        "velocity_step_cpu_ms": float(
            np.median(_cpu_ms(lambda: model.velocity(noise["x0"], None, mem, step), n)[1])
        ),
    }


def bench_latency(n: int = 30) -> list[dict]:
    torch.set_num_threads(1)
    out = []
    for policy in ("flow", "act"):
        cfg = preset("small", policy)
        cfg.n_cameras, cfg.state_dim, cfg.force_dim, cfg.action_dim = 2, 7, 6, 7
        torch.manual_seed(0)
        model = make_policy(cfg).eval()
        b = _fake_batch(cfg, 1)
        noise = type(model).draw_noise(cfg, 1, torch.Generator().manual_seed(0))
        with torch.inference_mode():
            for _ in range(5):
                model.predict(b, noise)
            ms, cpu = _cpu_ms(lambda m=model, b=b, noise=noise: m.predict(b, noise), n)
            part = _flow_parts(model, b, noise, n) if policy == "flow" else {}
        out.append(
            {
                "policy": policy,
                "preset": "small",
                "backbone": cfg.backbone,
                "hidden": cfg.hidden,
                "cameras": 2,
                "threads": 1,
                "median_ms": float(np.median(ms)),
                "p90_ms": float(np.percentile(ms, 90)),
                "min_ms": float(ms.min()),
                "cpu_median_ms": float(np.median(cpu)),
                "cpu_min_ms": float(cpu.min()),
                **part,
            }
        )
        print(json.dumps(out[-1]), flush=True)
    return out


def bench_phases(
    recordings: Path,
    steps: int,
    out_dir: Path,
    thresholds=None,
    nxt=None,
    backbone: str = "convnet-gn",
    batch: int = 32,
) -> dict:
    from policies.training.run import RunOptions, run_training
    from policies.training.train import Dist, TrainConfig

    res = {}
    for method in ("base-torque", "first"):
        run = out_dir / method
        o = RunOptions(
            inputs=[recordings],
            out=run,
            policy="flow",
            method=method,
            thresholds=thresholds,
            next=nxt,
            backbone=backbone,
            progress=False,
            train=TrainConfig(
                steps=steps,
                batch=batch,
                warmup=min(100, steps // 5),
                val_every=steps // 4,
                ckpt_every=steps,
                log_every=10,
                seed=0,
                threads=1,  # on a shared 2-core host one thread per process runs faster than two
            ),
        )
        t = time.perf_counter()
        res[method] = run_training(o, Dist())
        res[method]["train_s"] = time.perf_counter() - t
        print(method, json.dumps(res[method]), flush=True)
    return res


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--only", default="loader,train,latency")
    ap.add_argument("--recordings", type=Path, default=None, help="recordings for the phase comparison")
    ap.add_argument("--thresholds", default=None, help="LOW:HIGH for the phase comparison")
    ap.add_argument("--next", type=Path, default=None)
    ap.add_argument("--steps", type=int, default=400)
    ap.add_argument("--backbone", default="convnet-gn", help="phase comparison's image encoder")
    ap.add_argument("--batch", type=int, default=32, help="phase comparison's batch")
    ap.add_argument("--out", type=Path, default=None, help="write the results as JSON here")
    ap.add_argument("--threads", type=int, default=0, help="torch threads (0: default)")
    ap.add_argument("--presets", default="small,paper", help="presets of the training benchmark")
    a = ap.parse_args()
    if a.threads:
        torch.set_num_threads(a.threads)
    only = set(a.only.split(","))
    results: dict = {"torch": torch.__version__, "cores": torch.get_num_threads()}
    with tempfile.TemporaryDirectory() as tmp:
        if "loader" in only:
            folder = a.recordings or Path(tmp)
            if a.recordings is None:
                _synthetic(folder)
            results["loader"] = bench_loader(folder)
            print(json.dumps(results["loader"]), flush=True)
        if "train" in only:
            dev = torch.device("cuda" if torch.cuda.is_available() else "cpu")
            results["train"] = bench_train(dev, presets=tuple(a.presets.split(",")))
        if "latency" in only:
            results["latency"] = bench_latency()
        if "phases" in only:
            if a.recordings is None:
                sys.exit("--only phases needs --recordings DIR")
            th = tuple(float(x) for x in a.thresholds.split(":")) if a.thresholds else None
            results["phases"] = bench_phases(
                a.recordings, a.steps, Path(tmp) / "runs", th, a.next, a.backbone, a.batch
            )
    if a.out:
        a.out.write_text(json.dumps(results, indent=1))
    print(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
