"""Grey-box vs plain NEXT vs grey-box prior + NEXT on 1 and 10 minutes of training data.

Data (SIMULATED): calibration.diagnosis.synthetic.analytic_arm -- a geared planar 3R arm, 60 s runs at
100 Hz with effects nobody declared to the models: Coulomb friction on every joint, a position-periodic
torque (amplitude 0.4 N*m, period 0.2 rad) on joint 1, and a drift over each run's time (0.5 N*m/min) on
joint 2 (the twin with --twin-effect is not used here: it needs a running MuJoCo rig per run). Held-out: two
runs with other seeds. All three models are scored on the same samples (100 Hz grid, after NEXT's first
window).

    python bench/bench_diagnosis.py                      # 1 and 10 minutes, NEXT capped at 120 s each
    python bench/bench_diagnosis.py --minutes 1 --next-seconds 20     # quick check

Timings on a shared machine are noisy. Writes bench/out/bench_diagnosis.json.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from calibration.diagnosis.basis import DataBasis  # noqa: E402
from calibration.diagnosis.data import differentiate, make_segment, resample  # noqa: E402
from calibration.diagnosis.greybox import Design, errors  # noqa: E402
from calibration.diagnosis.loop import diagnose  # noqa: E402
from calibration.diagnosis.next_loop import prepare, train_next  # noqa: E402
from calibration.diagnosis.synthetic import analytic_torque, inject, trajectory  # noqa: E402


def run_log(seed: int, seconds: float = 60.0, noise: float = 0.05):
    t, q = trajectory(seconds, 100.0, 3, seed)
    qd = differentiate(t, q, 1)
    qdd = differentiate(t, qd, 1)
    tau = analytic_torque(q, qdd)
    for j in range(3):
        tau = inject("coulomb_friction", j, t, q, qd, tau, fc=0.5)
    tau = inject("position_periodic", 1, t, q, qd, tau, amplitude=0.4, period_rad=0.2)
    tau = inject("drift", 2, t, q, qd, tau, rate_per_min=0.5)
    tau += noise * np.random.default_rng(seed + 7).standard_normal(tau.shape)
    return make_segment(f"sim{seed}", t, q, qd, tau, "N*m", qdd=qdd)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=int, nargs="+", default=[1, 10])
    ap.add_argument("--next-seconds", type=float, default=120.0, help="training time cap per NEXT model")
    ap.add_argument("--out", default="bench/out/bench_diagnosis.json")
    args = ap.parse_args()
    import torch

    torch.set_num_threads(1)
    history = 50
    held_raw = [run_log(1000 + k) for k in range(2)]
    held = prepare(held_raw, 100.0, history)
    rows = []
    for minutes in args.minutes:
        train = [run_log(k) for k in range(minutes)]
        basis = DataBasis(3)
        t0 = time.perf_counter()
        dg = diagnose(basis, train, held)
        t_grey = time.perf_counter() - t0
        model = dg.model
        d_held = Design(basis, held)
        grey_l1 = errors(d_held.y, model.predict(d_held))[0]

        def grey_pred(seg, model=model, basis=basis):
            return model.predict(Design(basis, [seg]))

        plain, t_plain, _ = train_next(train, args.next_seconds, history=history)
        prior, t_prior, _ = train_next(train, args.next_seconds, residual_of=grey_pred, history=history)
        y = np.concatenate([s.y for s in held])
        full = [prepare([r], 100.0, history)[0] for r in held_raw]
        res = {}
        for name, fn in (("plain NEXT", plain), ("grey-box prior + NEXT", prior)):
            # predict on the full resampled run (NEXT needs its first window), compare after it
            p = np.concatenate([fn(resample(r, 100.0))[history - 1:history - 1 + len(f)]
                                for r, f in zip(held_raw, full)])
            res[name] = errors(y, p)[0]
        rows += [{"minutes": minutes, "method": "grey-box (diagnose loop)", "heldout_l1": grey_l1.tolist(),
                  "mean_l1": float(grey_l1.mean()), "train_s": t_grey,
                  "effects": [(e.family, e.joint) for e in model.effects]},
                 {"minutes": minutes, "method": "plain NEXT", "heldout_l1": res["plain NEXT"].tolist(),
                  "mean_l1": float(res["plain NEXT"].mean()), "train_s": t_plain},
                 {"minutes": minutes, "method": "grey-box prior + NEXT",
                  "heldout_l1": res["grey-box prior + NEXT"].tolist(),
                  "mean_l1": float(res["grey-box prior + NEXT"].mean()), "train_s": t_grey + t_prior}]
        for r in rows[-3:]:
            print(f"{minutes:>3} min  {r['method']:<26} held-out L1 {np.round(r['heldout_l1'], 4)} "
                  f"mean {r['mean_l1']:.4f} N*m   train {r['train_s']:.1f} s", flush=True)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"data": "simulated analytic arm (see docstring)", "next_seconds_cap":
                               args.next_seconds, "rows": rows}, indent=1))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
