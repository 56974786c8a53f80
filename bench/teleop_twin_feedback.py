"""SIMULATED: feedback modes compared on the sim-piper twin (real wire protocols, lockstep) with the
virtual operator pressing the follower into the table and wiping.

Per mode: where the leader's shoulder (joint 2) ends up vs the follower's, the feedback torque on it, and
the hand's applied joint torque per phase (the paper's user-study measure). Also shows the wiring the CLI
needs: open_rig -> ArmPair(gravity from the leader description, estimator) -> TeleopLoop.

    python -m bench.teleop_twin_feedback [--modes none ground_truth pp dob] [--seconds-scale 1.0]
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from bench import harness
from calibration.estimators import make_estimator
from factr2_teleop.teleop.leader_law import arm_model_fns
from factr2_teleop.teleop.loop import TeleopLoop
from factr2_teleop.teleop.pair import ArmPair, PairConfig
from factr2_teleop.teleop.virtual_operator import VirtualOperator, make_task_script
from hardware.connect import open_rig

PIPER_GAINS = [0.06, 0.08, 0.08, 0.03, 0.03, 0.02]  # leader N*m per follower N*m (FACTR 2 code's magnitudes)
ABOVE = np.array([0, 1.6, -1.0, 0, 0.6, 0])  # rad, leader joints: above the table
PRESS = np.array([0, 2.1, -1.0, 0, 0.6, 0])  # beyond the table surface (the follower stops near 1.9)


def run_mode(mode: str, scale: float) -> dict:
    s = open_rig("sim-piper", clock="lockstep", seed=0)
    try:
        lead, fol = s.pairs[0]
        g, jac = arm_model_fns(s.rig.leaders[0].arm)
        cfg = PairConfig(name="arm")
        cfg.law.feedback.gain = PIPER_GAINS
        cfg.law.feedback.t_high_nm, cfg.law.feedback.t_low_nm = 2.0, 1.0
        if mode == "pp":
            cfg.law.feedback.gate_on_contact = False
        fspec = s.rig.followers[0]
        est = make_estimator(mode, fol.n_joints, follower_arm=fspec.arm, pp_stiffness_nm_per_rad=40.0,
                             truth=lambda: s.twin.device_ground_truth(fspec.name, 1 / 500).tau_ext)
        pair = ArmPair(lead, fol, cfg, 1 / 500, gravity_fn=g, jacobian_fn=jac, estimator=est)
        q0 = lead.read().q
        script = make_task_script(q0, ABOVE, PRESS, [0.3, 0, 0, 0, 0, 0], free_s=1 * scale,
                                  reach_s=2.5 * scale, contact_s=1.5 * scale, wipe_s=3 * scale,
                                  release_s=2 * scale)
        op = VirtualOperator(script, stiffness=3.0, damping=0.1, tau_max_nm=2.0, t0=s.clock.now())
        recs: list[dict] = []

        def hand(rec: dict) -> None:  # the twin applies the hand torque on the leader until the next tick
            recs.append(rec)
            st = lead.last_state
            s.twin.apply_leader_hand_torque(op.torque(rec.t, st.q, np.nan_to_num(st.q_dot)))

        loop = TeleopLoop([pair], s.clock, recorder=hand)
        t0 = time.perf_counter()
        loop.run(duration_s=script.duration_s)
        wall = time.perf_counter() - t0
        wipe = [r for r, smp in zip(recs, op.log) if smp.phase == "wipe"]
        summ = op.summary()
        return {"mode": mode, "wall_s": wall, "ticks": loop.timing.ticks,
                "leader_j2": np.mean([r.leader.q[1] for r in wipe]),
                "follower_j2": np.mean([r.follower.q[1] for r in wipe]),
                "fb_j2": np.mean([r.tau_feedback[1] for r in wipe]),
                "hand_wipe": summ["wipe"]["tau_l1_nm"], "hand_free": summ["free"]["tau_l1_nm"]}
    finally:
        s.close()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--modes", nargs="+", default=["none", "ground_truth"])
    ap.add_argument("--seconds-scale", type=float, default=1.0, help="stretch every phase of the script")
    harness.add_quick(ap, "mode none, the script at a tenth of its length")
    a = ap.parse_args()
    if a.quick:
        a.modes, a.seconds_scale = ["none"], 0.1
    print(harness.machine_line())
    print("SIMULATED (sim-piper twin). Means over the wipe phase; hand = ||tau_hand||_1 [N*m].")
    print(f"{'mode':14s} {'leader j2':>9s} {'follower j2':>11s} {'fb j2':>7s} {'hand wipe':>9s} "
          f"{'hand free':>9s} {'wall s':>7s}")
    for m in a.modes:
        r = run_mode(m, a.seconds_scale)
        print(f"{m:14s} {r['leader_j2']:9.3f} {r['follower_j2']:11.3f} {r['fb_j2']:7.3f} "
              f"{r['hand_wipe']:9.3f} {r['hand_free']:9.3f} {r['wall_s']:7.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
