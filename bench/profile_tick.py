"""Where one teleop tick's CPU goes (issue #24 item 1): the demo (sim-piper, dob feedback) in lockstep, each
tick's thread CPU split by owner -- the app's loop (law, estimator, safety, bookkeeping), the leader's driver
and Dynamixel wire (dynamixel-sdk), the follower's driver and CAN wire, the in-process Dynamixel emulator,
the twin's physics and CAN emulator, and the demo's simulated operator and ground truth. SIMULATED.

    python -m bench.profile_tick [--seconds 10] [--root TREE]   # TREE: another checkout (before / after)
    python -m bench.profile_tick --clock realtime --mode next    # as `factr2 demo` runs (NEXT from the cache)

Exclusive CPU time (time.thread_time) of wrapped methods, per tick [us]; a method called inside another is
counted to its own owner only. Lockstep (default): the loop's thread runs everything, so every owner is on one
clock. Real time: the same split at the demo's pace; the twin's physics then runs between ticks and leaves the
caches cold for the app (measured here: the app's owners cost ~25 % more per tick than in lockstep).
"""

from __future__ import annotations

import argparse
import functools
import importlib
import json
import sys
import time
from pathlib import Path

# (module, class, method, owner); missing ones (an older checkout) are skipped
TARGETS = [
    ("factr2_teleop.teleop.pair", "ArmPair", "tick", "app loop: pair tick (mapping, safety, bookkeeping)"),
    ("factr2_teleop.teleop.pair", "ArmPair", "_tick_estimator", "app loop: NEXT / feedback estimator"),
    ("factr2_teleop.teleop.leader_law", "LeaderLaw", "step", "app loop: leader law (gravity, friction)"),
    ("factr2_teleop.teleop.loop", "TeleopLoop", "_tick_all", "app loop: loop shell, hooks, recorder"),
    ("hardware.roles", "Leader", "read", "leader driver + Dynamixel wire (sdk)"),
    ("hardware.roles", "Leader", "command_torque", "leader driver + Dynamixel wire (sdk)"),
    ("hardware.roles", "Follower", "read", "follower driver + CAN wire"),
    ("hardware.roles", "Follower", "command", "follower driver + CAN wire"),
    ("hardware.dynamixel.emulator", "DynamixelEmulator", "serve", "twin: Dynamixel emulator (in-process)"),
    ("hardware.sim.twin", "Twin", "step", "twin: physics + CAN emulator"),
    ("factr2_teleop.demo.task", "DemoRun", "_on_tick", "demo: simulated operator + ground truth"),
]


class Split:
    """Exclusive thread CPU per owner of wrapped methods (a nested call is its own owner's)."""

    def __init__(self):
        self.excl: dict[str, float] = {}
        self.calls: dict[str, int] = {}
        self.stack: list[list] = []  # [owner, t0, child time]

    def wrap(self, cls, name: str, owner) -> None:
        fn = getattr(cls, name)

        @functools.wraps(fn)
        def wrapper(*a, **k):
            own = owner(a[0]) if callable(owner) else owner
            t0 = time.thread_time()
            self.stack.append([own, t0, 0.0])
            try:
                return fn(*a, **k)
            finally:
                own, start, child = self.stack.pop()
                dt = time.thread_time() - start
                self.excl[own] = self.excl.get(own, 0.0) + dt - child
                self.calls[own] = self.calls.get(own, 0) + 1
                if self.stack:
                    self.stack[-1][2] += dt

        setattr(cls, name, wrapper)

    @classmethod
    def of(cls, targets) -> Split:
        """A Split over (module, class, method, owner) targets; ones a checkout lacks are said and skipped."""
        split = cls()
        for mod, name, meth, owner in targets:
            try:
                c = getattr(importlib.import_module(mod), name)
                getattr(c, meth)
            except (ImportError, AttributeError):
                print(f"(not in this checkout: {name}.{meth})")
                continue
            split.wrap(c, meth, owner)
        return split


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--root", default=str(Path(__file__).resolve().parents[1]))
    ap.add_argument("--json", default="")
    ap.add_argument("--clock", choices=("lockstep", "realtime"), default="lockstep")
    ap.add_argument("--mode", choices=("dob", "next"), default="dob",
                    help="feedback estimator (next: the demo's cached NEXT checkpoint, as `factr2 demo`)")
    ap.add_argument("--quick", action="store_true", help="0.5 s (a smoke run; its numbers mean nothing)")
    args = ap.parse_args()
    if args.quick:
        args.seconds = 0.5
    sys.path.insert(0, args.root)
    split = Split.of(TARGETS)
    from factr2_teleop.demo.task import DemoConfig, DemoRun

    next_est = next_path = None
    if args.mode == "next":
        from factr2_teleop.session import next_cache
        from factr2_teleop.session.pairs import load_next
        from hardware.rigs.rig import load_rig

        cached = next_cache.find_checkpoint("sim-piper")
        next_path = cached or next_cache.create_checkpoint("sim-piper", print)
        next_est = load_next(next_path, load_rig("sim-piper").followers[0].arm)
    run = DemoRun(DemoConfig(seconds=args.seconds, clock=args.clock, mode=args.mode), next_source=next_est,
                  next_path=str(next_path) if next_path else None)
    run.run()
    ticks = run.loop.timing.ticks if hasattr(run.loop, "timing") else int(args.seconds * 500)
    rows = sorted(split.excl.items(), key=lambda kv: -kv[1])
    total = sum(v for _, v in rows)
    print(f"{args.root}: {ticks} ticks, {total / ticks * 1e6:.0f} us CPU per tick in the wrapped owners")
    for owner, v in rows:
        print(f"  {v / ticks * 1e6:7.1f} us  {100 * v / total:5.1f} %  {owner}")
    if args.json:
        per_tick = {o: v / ticks * 1e6 for o, v in rows}
        Path(args.json).write_text(json.dumps({"root": args.root, "ticks": ticks, "us_per_tick": per_tick},
                                              indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
