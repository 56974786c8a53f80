"""Teleop loop timing: CPU cost of one tick of the loop shell + laws, and a real-time 500 Hz run.

Devices are IdealMotorBank-backed fakes from tests/teleop_fakes.py (no wire, no MuJoCo), so this measures
the teleop code itself (read/law/map/safety/command), not a driver or the twin. Timings on a shared
machine are noisy: rerun on a quiet one before quoting.

    python -m bench.teleop_loop_timing [--seconds 3] [--rate 500] [--pairs 1]
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from bench import harness
from calibration.estimators import PositionPositionEstimator
from factr2_teleop.teleop.leader_law import arm_model_fns
from factr2_teleop.teleop.loop import TeleopLoop
from factr2_teleop.teleop.pair import ArmPair, PairConfig
from hardware.clock import Clock
from hardware.sim.motors import IdealMotorBank
from tests.teleop_fakes import BankFollower, BankLeader, Rig

N = 6


def _cfg(name: str) -> PairConfig:
    cfg = PairConfig(name=name)  # full law: gravity (pinocchio on gello_piper), dither, barrier, feedback
    cfg.law.feedback.gate_on_contact = False
    return cfg


def tick_cost(n_ticks: int = 3000) -> float:
    """Mean wall time of ArmPair.tick [us] in lockstep (the plant stepping is excluded)."""
    rig = Rig(n=N)
    g, j = arm_model_fns("gello_piper")
    pair = ArmPair(rig.leader, rig.follower, _cfg("arm"), 1 / 500, gravity_fn=g, jacobian_fn=j,
                   estimator=PositionPositionEstimator(20.0, N))
    pair.begin()
    spent = 0.0
    for _ in range(n_ticks):
        t0 = time.perf_counter()
        pair.tick(rig.clock.now())
        spent += time.perf_counter() - t0
        rig.clock.sleep(0.002)
    return spent / n_ticks * 1e6


class _RealtimeBank(IdealMotorBank):
    """Advances itself to wall time on every read (the loop thread drives the plant)."""

    def __init__(self, clock: Clock, **kw):
        super().__init__(N, dt_s=2e-3, **kw)  # one plant step per tick: time the loop, not the plant
        self.clock, self.t = clock, clock.now()  # plant time = the loop's clock

    def read(self):
        self.advance(self.clock.now())
        return super().read()


def realtime(seconds: float, rate: float, n_pairs: int) -> str:
    clock = Clock()
    g, j = arm_model_fns("gello_piper")
    pairs = []
    for k in range(n_pairs):
        lead = BankLeader(_RealtimeBank(clock), clock)
        fol = BankFollower(_RealtimeBank(clock, kp_fw=200.0, kd_fw=3.0), clock)
        lead.connect()
        fol.connect()
        pairs.append(ArmPair(lead, fol, _cfg(f"arm{k}"), 1 / rate, gravity_fn=g, jacobian_fn=j,
                             estimator=PositionPositionEstimator(20.0, N)))
    loop = TeleopLoop(pairs, clock, rate_hz=rate)
    loop.run(duration_s=seconds)
    return loop.snapshot().timing.line()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--rate", type=float, default=500.0)
    ap.add_argument("--pairs", type=int, default=1)
    harness.add_quick(ap, "200 ticks, 0.3 s real time")
    a = ap.parse_args()
    if a.quick:
        a.seconds = 0.3
    np.seterr(all="ignore")
    print(harness.machine_line())
    us = tick_cost(200 if a.quick else 3000)
    print(f"tick cost (1 pair, full law, lockstep, plant excluded): {us:.0f} us")
    print(f"real time, {a.pairs} pair(s), {a.seconds:.0f} s: {realtime(a.seconds, a.rate, a.pairs)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
