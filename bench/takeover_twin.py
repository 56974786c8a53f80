"""Operator takeover on the twin in real time (issue #33, SIMULATED): loop rate and p99 with the leader
following, command violations, the leader's tracking error, and the takeover latency (hand torque over the
threshold -> the switch -> the follower's target on the leader).

    python -m bench.takeover_twin --policy RUN [--task wipe] [--seconds 8] [--grab-at 3] [--smooth]
                                  [--json OUT]

A scripted hand grabs the leader at --grab-at s into the episode (pulls joint 1 by 0.3 rad), holds it still
1 s later, and lets go once the policy drives again. --smooth replaces the policy's chunks by a slow sine
about the first observed pose (<= 0.45 rad/s), as a trained policy moves: the takeover machinery is timed,
not the policy. The machine is the shared dev VM: say so with the numbers.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np


def main() -> int:
    from factr2_teleop.session.rollout import RolloutHooks, RolloutOptions, run_rollout
    from factr2_teleop.teleop.takeover import POLICY

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--policy", type=Path, required=True)
    ap.add_argument("--task", default="wipe")
    ap.add_argument("--seconds", type=float, default=8.0)
    ap.add_argument("--grab-at", type=float, default=3.0)
    ap.add_argument("--smooth", action="store_true")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--baseline", action="store_true", help="the same rollout without takeover (no hand)")
    a = ap.parse_args()
    if a.smooth:
        from tests.rollout_helpers import install_smooth_policy

        install_smooth_policy(call_real=True)
    box: dict = {}

    def on_start(ts, target, eps):
        pair, tk = ts.pairs[0], target.takeover
        if tk is None:
            return
        bank = ts.session.twin.bank(pair.leader.name)
        box["t0"] = None

        def hook(r):
            if target.state != "run":
                return
            t0 = box["t0"] = box["t0"] if box["t0"] is not None else r.t
            t = r.t - t0
            tau = None
            if a.grab_at <= t and not (t >= a.grab_at + 1.0 and tk.driver == POLICY and not tk.pending):
                key = "q" if t < a.grab_at + 1.0 else "rest"
                ref = box.setdefault(key, np.asarray(r.leader.q, float)
                                     + (np.r_[0.3, np.zeros(len(r.leader.q) - 1)] if key == "q" else 0.0))
                k = 8.0 if key == "q" else 3.0
                tau = np.r_[np.clip(k * (ref - r.leader.q) - 0.12 * np.nan_to_num(r.leader.q_dot), -0.8, 0.8),
                            0.0]
            bank.set_hand_torque(tau if tau is not None else np.zeros(pair.leader.n_joints + 1))

        ts.hooks.append(hook)

    t_wall = time.perf_counter()
    out = run_rollout(RolloutOptions(rig="sim-piper", policy=a.policy, task=a.task, episodes=1, seed=7,
                                     max_seconds=a.seconds, realtime=True, takeover=not a.baseline,
                                     progress=False), RolloutHooks(on_start=on_start)).to_dict()
    t = out["timing"]
    res = {"simulated": True, "smooth_reference": a.smooth, "takeover_on": not a.baseline,
           "wall_s": time.perf_counter() - t_wall,
           "loop_rate_hz": t["loop_rate_hz"], "period_p99_ms": t["period_p99_ms"],
           "period_max_ms": t["period_max_ms"], "overruns": t["overruns"], "ticks": t["ticks"],
           "command_violations": t["command_violations"], "commands_sent": t["commands_sent"],
           "takeover": out["takeover"]}
    print(json.dumps(res, indent=1, default=float))
    if a.json:
        a.json.write_text(json.dumps(res, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
