"""The teleop app's own CPU per tick, the same work tick for tick (issue #53 item 1): the thread CPU of
`TeleopLoop._tick_all` minus what the twin charged on that thread (hardware/sim_cpu.py), on the sim-piper
twin in lockstep (dob feedback). --transport inprocess (default): the leader's Dynamixel emulator answers
inline, as in `factr2 demo`; pty: the leader's packets cross a pseudo-terminal to the emulator's own thread,
as in `factr2 teleop` on a twin (the real serial path: termios, select, read/write syscalls). Thread CPU
time moves less with other load than wall time, but not nothing on a shared VM: repeat (--repeat), alternate
the checkouts (--root) and compare medians. --calls also counts the Python and C calls one tick makes
(sys.setprofile; deterministic, unlike the CPU time). SIMULATED.

    python bench/app_cpu_per_tick.py [--ticks 2000] [--transport inprocess|pty] [--repeat 3] [--root CHECKOUT]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path


def measure(ticks: int, transport: str, calls: bool) -> tuple[list[float], float]:
    """Per-tick app CPU [s] over `ticks` lockstep ticks after the soft start; mean calls per tick (or nan)."""
    from factr2_teleop.session.pairs import TeleopOptions
    from factr2_teleop.session.teleop import TeleopSession
    from hardware import sim_cpu
    from hardware.connect import open_rig

    kw = {} if transport == "inprocess" else {"dynamixel_transport": transport}
    with open_rig("sim-piper", clock="lockstep", **kw) as s:
        ts = TeleopSession(s, TeleopOptions(mode="dob"))
        loop = ts.loop
        ts.pairs[0].begin(s.clock)
        for _ in range(300):  # past the soft start
            s.clock.sleep(loop.period_s)
            loop._tick_all(s.clock.now())
        app = []
        for _ in range(ticks):
            s.clock.sleep(loop.period_s)
            c, sim = time.thread_time(), sim_cpu.charged()
            loop._tick_all(s.clock.now())
            app.append((time.thread_time() - c) - (sim_cpu.charged() - sim))
        n = float("nan")
        if calls:  # counted apart: the profiler hook would inflate the CPU time above
            count = [0]

            def hook(frame, event, arg):
                if event in ("call", "c_call"):
                    count[0] += 1

            k = 200
            for _ in range(k):
                s.clock.sleep(loop.period_s)
                sys.setprofile(hook)
                loop._tick_all(s.clock.now())
                sys.setprofile(None)
            n = count[0] / k
    return app, n


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ticks", type=int, default=2000)
    ap.add_argument("--transport", choices=("inprocess", "pty"), default="inprocess")
    ap.add_argument("--repeat", type=int, default=1, help="runs in this process (each a fresh twin)")
    ap.add_argument("--calls", action="store_true", help="also count the calls per tick (200 more ticks)")
    ap.add_argument("--root", default=str(Path(__file__).resolve().parents[1]))
    a = ap.parse_args()
    sys.path.insert(0, a.root)
    import numpy as np

    medians = []
    for _ in range(a.repeat):
        app, n = measure(a.ticks, a.transport, a.calls)
        us = np.asarray(app) * 1e6
        medians.append(float(np.median(us)))
        more = f", {n:.0f} calls per tick" if a.calls else ""
        print(f"{a.root}: app CPU per tick median {np.median(us):.1f} us, mean {us.mean():.1f} us, "
              f"p10 {np.percentile(us, 10):.1f} us ({a.ticks} ticks, lockstep, dob, {a.transport}){more}",
              flush=True)
    if a.repeat > 1:
        print(f"median of {a.repeat} medians {np.median(medians):.1f} us (min {min(medians):.1f}, "
              f"max {max(medians):.1f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
