"""Training speed of the policy presets on a state observation (issue #31 item 1): samples per CPU second of
one thread (thread_time: another process on the other core cannot inflate it), and one chunk's inference
(encode + 10 Euler steps), on the peg-insert input sizes (joints + gripper 7, tau_ext 6, PRIVILEGED objects
21, action 7, chunk 30). Candidates: `small` (the image preset's DiT, the old state default), the `state`
preset (MLP flow head) and its neighbours in width and depth.

    python -m bench.bench_state_preset [--steps 40] [--json OUT]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import torch

from bench import harness
from policies.models.config import preset
from policies.models.policy import make_policy

DIMS = dict(observation="state", state_dim=7, force_dim=6, objects_dim=21, action_dim=7)
CANDIDATES = [
    ("small (DiT h256, 2 blocks)", "small", {}),
    ("state: MLP w512 x3 (default)", "state", {}),
    ("MLP w256 x3", "state", {"ff": 256}),
    ("MLP w512 x4", "state", {"dec_layers": 4}),
    ("MLP w1024 x3", "state", {"ff": 1024}),
]


def measure(cfg, batch: int, steps: int, chunks: int = 20) -> dict:
    torch.manual_seed(0)
    model = make_policy(cfg)
    opt = torch.optim.AdamW(model.parameters(), lr=3e-4)
    g = torch.Generator().manual_seed(0)
    b = {"state": torch.randn(batch, 7), "force": torch.randn(batch, 6), "objects": torch.randn(batch, 21),
         "action": torch.randn(batch, cfg.chunk, 7), "mask": torch.ones(batch, cfg.chunk, dtype=torch.bool)}
    for i in range(steps + 5):
        if i == 5:
            c = time.thread_time()
        loss = model.loss(b, type(model).draw_noise(cfg, batch, g))[0].mean()
        loss.backward()
        opt.step()
        opt.zero_grad(set_to_none=True)
    train_cpu = time.thread_time() - c
    model.eval()
    one = {k: v[:1] for k, v in b.items()}
    with torch.inference_mode():
        model.predict(one, type(model).draw_noise(cfg, 1, g))
        c = time.thread_time()
        for _ in range(chunks):
            model.predict(one, type(model).draw_noise(cfg, 1, g))
    return {"batch": batch, "samples_per_cpu_s": batch * steps / train_cpu,
            "chunk_cpu_ms": (time.thread_time() - c) / chunks * 1e3,
            "params_M": sum(p.numel() for p in model.parameters()) / 1e6}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--json", default=None, help="write the rows here (a bench/harness.py record)")
    harness.add_quick(ap, "the default MLP, 2 steps")
    a = ap.parse_args(argv)
    if a.quick:
        a.steps = 2
    torch.set_num_threads(1)
    rows = []
    print("| preset | params [M] | samples / CPU s, batch 64 | batch 256 | one chunk [ms CPU] |\n"
          "|---|---|---|---|---|")
    for label, name, kw in CANDIDATES[1:2] if a.quick else CANDIDATES:  # quick: the default MLP
        cfg = replace(preset(name), **DIMS, **kw)
        steps256 = max(a.steps if a.quick else 10, a.steps // 4)
        chunks = 2 if a.quick else 20
        r64, r256 = measure(cfg, 64, a.steps, chunks), measure(cfg, 256, steps256, chunks)
        rows.append({"preset": label, "b64": r64, "b256": r256})
        print(f"| {label} | {r64['params_M']:.2f} | {r64['samples_per_cpu_s']:.0f} | "
              f"{r256['samples_per_cpu_s']:.0f} | {r64['chunk_cpu_ms']:.1f} |", flush=True)
    if a.json:
        harness.write(a.json, harness.record("state_preset_speed", rows, simulated=False))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
