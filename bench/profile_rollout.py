"""Where a policy rollout tick's CPU goes (issue #31 item 4): `run_rollout` of a trained policy on sim-piper
in lockstep, as bench/bench_first.py runs it (record=None, no progress lines), each tick's thread CPU split
by owner -- the twin's physics (follower and leader worlds apart), its CAN and Dynamixel emulators, the
follower's driver and CAN wire, the leader's driver and Dynamixel wire, NEXT, the policy (observation,
inference), the chunk schedule, the task's episode bookkeeping and the loop's own shell. SIMULATED.

    python -m bench.profile_rollout --policy RUN --task wipe [--episodes 1] [--max-seconds 10]
    python -m bench.profile_rollout ... --root TREE       # another checkout (before / after)

Exclusive CPU time (time.thread_time) of wrapped methods, per loop tick [us] (every tick of the loop: homing,
settling and the policy's run); a method called inside another is counted to its own owner only. "loop
rest" is the loop's thread CPU outside every wrapped method (timing, the lockstep clock, numpy glue).
Set-up (loading the policy, building the twin) is reported apart, per rollout. The wrappers cost CPU
themselves (~1 us per wrapped call): --plain wraps only the loop (its thread CPU and its tick count) for
the before / after totals.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from bench.profile_tick import Split  # exclusive thread CPU per owner, shared

LOOP = "loop rest (timing, clock, glue)"
# (module, class, method, owner); owner may be a callable(self) -> str. Missing ones are skipped.
TARGETS = [
    ("factr2_teleop.teleop.loop", "TeleopLoop", "run", LOOP),
    ("factr2_teleop.teleop.loop", "TeleopLoop", "_tick_all", "app: loop shell, hooks"),
    ("factr2_teleop.session.rollout_pair", "RolloutPair", "tick", "app: rollout pair (bookkeeping)"),
    ("factr2_teleop.teleop.pair", "ArmPair", "_tick_estimator", "NEXT estimator"),
    ("factr2_teleop.session.rollout_pair", "PolicyTarget", "_target", "app: chunk schedule, homing"),
    ("factr2_teleop.session.rollout_pair", "PolicyTarget", "observation", "policy: observation (+ objects)"),
    ("policies.rollout.runner", "PolicyRunner", "infer", "policy: inference"),
    ("factr2_teleop.session.rollout_episodes", "TwinRollout", "on_tick", "task: episodes, stage detection"),
    ("hardware.roles", "Leader", "read", "leader driver + Dynamixel wire"),
    ("hardware.roles", "Leader", "command_torque", "leader driver + Dynamixel wire"),
    ("hardware.roles", "Follower", "read", "follower driver + CAN wire"),
    ("hardware.roles", "Follower", "command", "follower driver + CAN wire (incl. safety layer)"),
    ("hardware.roles", "Follower", "hold", "follower driver + CAN wire (incl. safety layer)"),
    ("hardware.dynamixel.emulator", "DynamixelEmulator", "serve", "twin: Dynamixel emulator"),
    ("hardware.piper.emulator", "PiperEmulator", "poll", "twin: CAN emulator"),
    ("hardware.piper.emulator", "PiperEmulator", "emit", "twin: CAN emulator"),
    ("hardware.sim.world", "MujocoWorld", "step", lambda w: f"twin: physics, {w.name} world"),
    ("hardware.sim.twin", "Twin", "advance", "twin: stepping shell"),
]




def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--policy", required=True, help="RUN folder (bench_first: OUT/TASK/CELL/seed0)")
    ap.add_argument("--task", default="wipe")
    ap.add_argument("--episodes", type=int, default=1)
    ap.add_argument("--max-seconds", type=float, default=10.0, help="episode limit [s] (a failing episode)")
    ap.add_argument("--seed", type=int, default=2, help="rollout seed (bench_first uses 2)")
    ap.add_argument("--root", default=str(Path(__file__).resolve().parents[1]))
    ap.add_argument("--json", default="")
    ap.add_argument("--plain", action="store_true", help="only the loop's total (no per-owner wrappers)")
    ap.add_argument("--lean", choices=("auto", "on", "off"), default="auto",
                    help="RolloutOptions.lean (auto: the default; a checkout without it ignores this)")
    args = ap.parse_args()
    sys.path.insert(0, args.root)
    split = Split.of(TARGETS[:2] if args.plain else TARGETS)
    from factr2_teleop.session.rollout import RolloutOptions, run_rollout

    kw = {"lean": {"on": True, "off": False}[args.lean]} if args.lean != "auto" else {}
    c0 = time.process_time()
    res = run_rollout(RolloutOptions(rig="sim-piper", policy=Path(args.policy), task=args.task,
                                     episodes=args.episodes, seed=args.seed, max_seconds=args.max_seconds,
                                     record=None, progress=False, **kw)).to_dict()
    cpu_total = time.process_time() - c0
    ticks = split.calls.get("app: loop shell, hooks", 0)
    rows = sorted(split.excl.items(), key=lambda kv: -kv[1])
    loop = sum(v for _, v in rows)
    sim_s = ticks / 500.0
    print(f"{args.root}: {ticks} ticks ({sim_s:.1f} s simulated), {loop / ticks * 1e6:.0f} us thread CPU per "
          f"tick in the loop; process CPU {cpu_total:.2f} s (set-up and other threads "
          f"{cpu_total - loop:.2f} s); success {res['success_rate']:.2f}, "
          f"progress {res['mean_progress']:.2f}, "
          f"commands {res['timing']['commands_sent']}, chunks {res['timing']['chunks']}, "
          f"feedback {res['feedback_mode']}, lean {res.get('lean', '-')}")
    for owner, v in rows if not args.plain else []:
        print(f"  {v / ticks * 1e6:7.1f} us  {100 * v / loop:5.1f} %  {owner}")
    print(f"per 40 s episode at this rate: {loop / sim_s * 40:.1f} s CPU in the loop")
    if args.json:
        Path(args.json).write_text(json.dumps({
            "root": args.root, "ticks": ticks, "loop_cpu_s": loop, "process_cpu_s": cpu_total,
            "us_per_tick": {o: v / ticks * 1e6 for o, v in rows}, "episodes": res["episodes"],
            "commands_sent": res["timing"]["commands_sent"]}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
