"""Grey-box vs plain NEXT vs grey-box prior + NEXT on 1 and 10 minutes of twin data. SIMULATED.

Data: the shipped `sim-piper` twin (every actuator effect on: friction, Stribeck, backlash, ripple, heating,
K(T)) in lockstep through the real Piper driver, replaying the calibration coverage trajectory, plus one
effect nobody declared, injected only through the twin's undeclared-effect hook: a position-periodic torque
(0.3 N*m, period 0.35 rad) on joint 2. Train: a 1-minute and a 10-minute coverage run (trajectory seeds 0 and
10); held out: a 2-minute run of another trajectory (seed 100). Logs are cached under --data (lockstep runs
are deterministic) so a re-run measures the models only.

Methods, all scored on the same held-out samples (100 Hz grid, after NEXT's first window):
- grey-box: the diagnose loop (pinocchio regressor of the Piper description + traced effects), as
  `factr2 diagnose TRAIN --heldout HELD --arm piper`; its time is the loop's wall time.
- plain NEXT: calibration.next on (q, qd, q_cmd - q), history 50, early stopping, capped at --next-seconds.
- grey-box prior + NEXT: NEXT trained on what the grey box leaves (y - grey-box); time = loop + NEXT.

    python -m bench.bench_diagnosis                              # 1 and 10 minutes, NEXT capped at 240 s
    python -m bench.bench_diagnosis --minutes 1 --next-seconds 30     # quick check

Writes bench/out/bench_diagnosis.json; timings on a shared machine are noisy (the load is printed).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

from calibration.diagnosis.data import load_segment, resample
from calibration.diagnosis.greybox import Design, errors
from calibration.diagnosis.loop import diagnose
from calibration.diagnosis.next_loop import prepare, train_next
from calibration.diagnosis.twin_data import TWIN_CASES, TWIN_DEFAULTS, piper_basis, record

HISTORY = 50
TRAIN_SEEDS = {1: 0, 10: 10}  # minutes -> coverage-trajectory seed
HELD_SEED, HELD_MINUTES = 100, 2.0


def twin_log(folder: Path, name: str, minutes: float, seed: int) -> Path:
    """A cached lockstep recording of the shipped twin with the periodic effect injected through the hook."""
    from hardware.recording.plain_log import save_plain_log

    path = folder / f"{name}.npz"
    if not path.exists():
        t0 = time.perf_counter()
        arrays = record(minutes * 60.0, seed, TWIN_CASES["position_periodic"].make(), TWIN_DEFAULTS,
                        twin_seed=seed)
        folder.mkdir(parents=True, exist_ok=True)
        save_plain_log(path, **arrays)
        print(f"recorded {name}: {minutes} min of twin motion in {time.perf_counter() - t0:.0f} s "
              f"(stopped: {arrays['stopped']!s})", flush=True)
    return path


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=int, nargs="+", default=[1, 10], choices=sorted(TRAIN_SEEDS))
    ap.add_argument("--next-seconds", type=float, default=240.0, help="training time cap per NEXT model")
    ap.add_argument("--threads", type=int, default=2, help="torch CPU threads for NEXT")
    ap.add_argument("--data", default="/tmp/factr2_bench_diagnosis", help="where the twin logs are cached")
    ap.add_argument("--out", default="bench/out/bench_diagnosis.json")
    args = ap.parse_args()
    import torch

    torch.set_num_threads(args.threads)
    data = Path(args.data)
    held_raw = [load_segment(twin_log(data, "heldout", HELD_MINUTES, HELD_SEED))]
    held = prepare(held_raw, 100.0, HISTORY)  # the samples every method is scored on
    y = np.concatenate([s.tau for s in held])
    rows = []
    for minutes in args.minutes:
        train = [load_segment(twin_log(data, f"train_{minutes}min", minutes, TRAIN_SEEDS[minutes]))]
        basis = piper_basis()
        t0 = time.perf_counter()
        dg = diagnose(basis, train, held)
        t_grey = time.perf_counter() - t0
        model = dg.model

        def grey_pred(seg, model=model, basis=basis):
            return model.predict(Design(basis, [seg]))

        plain, t_plain, res_plain = train_next(train, args.next_seconds, history=HISTORY,
                                               threads=args.threads)
        prior, t_prior, res_prior = train_next(train, args.next_seconds, residual_of=grey_pred,
                                               history=HISTORY, threads=args.threads)
        preds = {"grey-box (diagnose loop)": model.predict(Design(basis, held))}
        for name, fn in (("plain NEXT", plain), ("grey-box prior + NEXT", prior)):
            # predict on the full resampled run (NEXT needs its first window), compare after it
            preds[name] = np.concatenate([fn(resample(r, 100.0))[HISTORY - 1:HISTORY - 1 + len(h)]
                                          for r, h in zip(held_raw, held)])
        def how(res, took):
            stop = "early stopping" if res.seconds < args.next_seconds - 1 else "time cap"
            return {"train_s": took, "epochs": res.epochs, "best_epoch": res.best_epoch, "stopped": stop}

        extra = {"grey-box (diagnose loop)": {"train_s": t_grey, "effects": [
                     f"{e.family} j{e.joint}" for e in model.effects]},
                 "plain NEXT": how(res_plain, t_plain),
                 "grey-box prior + NEXT": how(res_prior, t_grey + t_prior)}
        for name, p in preds.items():
            l1 = errors(y, p)[0]
            rows.append({"minutes": minutes, "method": name, "heldout_l1": l1.tolist(),
                         "mean_l1": float(l1.mean()), **extra[name]})
            r = rows[-1]
            print(f"{minutes:>3} min  {name:<26} held-out L1 {np.round(l1, 4)} mean {r['mean_l1']:.4f} N*m  "
                  f"train {r['train_s']:.1f} s {r.get('stopped', '')}", flush=True)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({
        "data": "SIMULATED: sim-piper twin (all effects on) + position_periodic j2 through the hook",
        "machine": f"{platform.node()} {platform.machine()}, {os.cpu_count()} CPUs, load {os.getloadavg()}",
        "next_seconds_cap": args.next_seconds, "threads": args.threads, "rows": rows}, indent=1))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
