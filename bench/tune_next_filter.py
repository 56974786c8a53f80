"""Choose the NEXT estimate's adaptive low-pass (calibration/next/prior.py: EST_MIN_HZ, EST_BETA,
EST_DERIV_HZ) on SIMULATED pushed runs that are not the calibration's evaluation.

The calibration scores NEXT on a pushed replay with seed 1 (factr2_teleop/commands/calibrate.py); tuning the
filter on that run would tune on the test. So this records fresh pushed replays with other seeds on a new
twin (default seeds 2 and 3, 120 s each, cold motors), takes the identified prior of a calibration run's
checkpoint, and scores every filter on the grid by the prior's estimate alone (the network adds < 0.01 N*m on
the twin). Rule: among the filters whose free-motion L1 is no worse than the fixed low-pass
(`ACCEL_CUTOFF_HZ`, `FILTER_ORDER`) on the same runs, those within 1 % of the smallest contact L1 (closer
is run-to-run noise); of these, the one with the smallest free-motion L1.

    python -m bench.tune_next_filter --checkpoint cal/next.json [--seeds 2 3] [--seconds 120]

Writes bench/out/tune_next_filter.json. L1 in N*m, mean over the 6 joints.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from calibration.next.checkpoint import load_checkpoint
from calibration.next.data import resample_log
from calibration.next.prior import ACCEL_CUTOFF_HZ, FILTER_ORDER, prior_torque
from hardware.recording.plain_log import load_plain_log, save_plain_log

ROOT = Path(__file__).resolve().parents[1]

GRID_MIN_HZ = (5.0, 8.0, 10.0, 12.0)
GRID_BETA = (1.0, 2.0, 4.0, 6.0)  # Hz per N*m/s
GRID_DERIV_HZ = (3.0, 5.0, 10.0)
CONTACT_TIE = 1.01  # contact L1 within 1 % of the best counts as equal


def record(seeds: list[int], seconds: float, out: Path) -> list[Path]:
    from calibration.pipeline import record_pushed_replay
    from hardware.connect import open_rig
    from hardware.rigs.rig import load_rig

    rig = load_rig("sim-piper")
    paths = []
    for seed in seeds:
        with open_rig(rig, clock="lockstep", seed=seed) as s:
            run = record_pushed_replay(s, rig.followers[0], seconds, 100.0, seed=seed)
        paths.append(save_plain_log(out / f"pushed_seed{seed}.npz", **run.arrays()))
    return paths


def score(prior, segments) -> tuple[float, float]:
    """(free L1, contact L1) of the prior's estimate over the segments."""
    free, con = [], []
    for s in segments:
        est = s.tau - prior_torque(prior, s.t, s.q, s.qd, s.tau, s.temperature)
        err = np.abs(est - s.tau_ext_true)
        c = s.contact.astype(bool)
        free.append(err[~c])
        con.append(err[c])
    return float(np.concatenate(free).mean()), float(np.concatenate(con).mean())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--checkpoint", required=True, help="next.json of a `factr2 calibrate` run with a prior")
    ap.add_argument("--seeds", type=int, nargs="+", default=[2, 3])
    ap.add_argument("--seconds", type=float, default=120.0)
    a = ap.parse_args()
    if 1 in a.seeds:
        print("error: seed 1 is the calibration's evaluation run; tune on other seeds", file=sys.stderr)
        return 2
    ck = load_checkpoint(a.checkpoint)
    if ck.prior is None:
        print(f"error: {a.checkpoint} has no physics prior; use a default `factr2 calibrate` run",
              file=sys.stderr)
        return 2
    out = ROOT / "bench" / "out"
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    paths = record(a.seeds, a.seconds, out)
    segments = [s for p in paths for s in resample_log(load_plain_log(p)) if len(s.t) > 1]
    print(f"recorded {len(paths)} SIMULATED pushed runs in {time.perf_counter() - t0:.0f} s", file=sys.stderr)

    fixed = dataclasses.replace(ck.prior, est_min_hz=ACCEL_CUTOFF_HZ, est_beta=0.0, order=FILTER_ORDER)
    base = score(fixed, segments)
    rows = []
    grid = list(itertools.product(GRID_MIN_HZ, GRID_BETA, GRID_DERIV_HZ))
    for fmin, beta, fd in tqdm(grid, desc="filters", file=sys.stderr):
        p = dataclasses.replace(ck.prior, est_min_hz=fmin, est_beta=beta, est_deriv_hz=fd, order=FILTER_ORDER)
        rows.append({"min_hz": fmin, "beta": beta, "deriv_hz": fd, **dict(zip(("free", "contact"),
                                                                           score(p, segments)))})
    ok = [r for r in rows if r["free"] <= base[0]]
    best = None
    if ok:
        c_min = min(r["contact"] for r in ok)
        best = min((r for r in ok if r["contact"] <= CONTACT_TIE * c_min), key=lambda r: r["free"])
    print(f"fixed {ACCEL_CUTOFF_HZ:g} Hz low-pass: free {base[0]:.4f}  contact {base[1]:.4f} [N*m]")
    for r in sorted(rows, key=lambda r: r["contact"])[:10]:
        mark = "  <- chosen" if r is best else ("" if r["free"] <= base[0] else "  (free worse)")
        print(f"min {r['min_hz']:4.0f} Hz  beta {r['beta']:3.0f}  deriv {r['deriv_hz']:4.0f} Hz: "
              f"free {r['free']:.4f}  contact {r['contact']:.4f}{mark}")
    if best is not None:
        print(f"chosen: EST_MIN_HZ = {best['min_hz']:g}, EST_BETA = {best['beta']:g}, "
              f"EST_DERIV_HZ = {best['deriv_hz']:g}")
    (out / "tune_next_filter.json").write_text(json.dumps(
        {"simulated": True, "seeds": a.seeds, "seconds": a.seconds, "checkpoint": str(a.checkpoint),
         "fixed": {"free": base[0], "contact": base[1]}, "grid": rows, "chosen": best}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
