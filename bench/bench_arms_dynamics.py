"""Microseconds per sample of the arm dynamics helpers (hardware.arms.dynamics), single and batched.

Each helper reuses one pinocchio Data; batches loop in Python over pinocchio's C++ calls. Also times
MuJoCo's mj_step on the arm's table scene (1 kHz physics) for comparison with the twin's budget.

    python -m bench.bench_arms_dynamics --arm piper --samples 5000
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bench import harness
from hardware.arms import load_arm
from hardware.arms.dynamics import ArmDynamics


def _time(fn, reps: int) -> float:
    t0 = time.perf_counter()
    fn()
    return (time.perf_counter() - t0) / reps * 1e6


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arm", default="piper")
    ap.add_argument("--samples", type=int, default=5000)
    harness.add_quick(ap, "50 samples, 100 MuJoCo steps")
    args = ap.parse_args()
    if args.quick:
        args.samples = 50
    arm = load_arm(args.arm)
    dyn = ArmDynamics(arm)
    T, n = args.samples, dyn.n
    rng = np.random.default_rng(0)
    Q = rng.uniform(arm.limits.q_min, arm.limits.q_max, size=(T, n))
    QD, QDD = rng.normal(size=(T, n)), rng.normal(size=(T, n))
    print(f"# {arm.name} (n={n}), {T} samples; {harness.machine_line()}; "
          "timings on a shared machine are noisy")
    rows = {
        "gravity (single)": lambda: [dyn.gravity(q) for q in Q],
        "rnea (single)": lambda: [dyn.rnea(Q[t], QD[t], QDD[t]) for t in range(T)],
        "gravity_batch": lambda: dyn.gravity_batch(Q),
        "rnea_batch": lambda: dyn.rnea_batch(Q, QD, QDD),
        "nonlinear_effects_batch": lambda: dyn.nonlinear_effects_batch(Q, QD),
        "mass_matrix_batch": lambda: dyn.mass_matrix_batch(Q),
        "coriolis_matrix_batch": lambda: dyn.coriolis_matrix_batch(Q, QD),
        "regressor_batch": lambda: dyn.regressor_batch(Q, QD, QDD),
        "fk_batch": lambda: dyn.fk_batch(Q),
        "jacobian_batch": lambda: dyn.jacobian_batch(Q),
    }
    for name, fn in rows.items():
        print(f"{name:28s} {_time(fn, T):8.2f} us/sample")
    if arm.name in ("piper", "yam", "panda"):
        import mujoco

        m = mujoco.MjModel.from_xml_path(str(arm.scene_path()))
        d = mujoco.MjData(m)
        mujoco.mj_resetDataKeyframe(m, d, 0)
        steps = 100 if args.quick else 2000
        us = _time(lambda: [mujoco.mj_step(m, d) for _ in range(steps)], steps)
        print(f"{'mj_step (table scene)':28s} {us:8.2f} us/step")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
