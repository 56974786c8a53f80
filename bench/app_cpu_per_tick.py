"""The teleop app's own CPU per tick, the same work tick for tick (issue #53 item 1): the thread CPU of
`TeleopLoop._tick_all` minus what the twin charged on that thread (hardware/sim_cpu.py), on the sim-piper
twin in lockstep (dob feedback). Thread CPU time moves less with other load than wall time, but not nothing on
a shared VM: alternate the checkouts (--root) and compare medians. SIMULATED.

    python bench/app_cpu_per_tick.py [--ticks 2000] [--root CHECKOUT]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ticks", type=int, default=2000)
    ap.add_argument("--root", default=str(Path(__file__).resolve().parents[1]))
    a = ap.parse_args()
    sys.path.insert(0, a.root)
    import numpy as np

    from factr2_teleop.session.pairs import TeleopOptions
    from factr2_teleop.session.teleop import TeleopSession
    from hardware import sim_cpu
    from hardware.connect import open_rig

    with open_rig("sim-piper", clock="lockstep") as s:
        ts = TeleopSession(s, TeleopOptions(mode="dob"))
        loop = ts.loop
        ts.pairs[0].begin(s.clock)
        for _ in range(300):  # past the soft start
            s.clock.sleep(loop.period_s)
            loop._tick_all(s.clock.now())
        app = np.empty(a.ticks)
        for k in range(a.ticks):
            s.clock.sleep(loop.period_s)
            c, sim = time.thread_time(), sim_cpu.charged()
            loop._tick_all(s.clock.now())
            app[k] = (time.thread_time() - c) - (sim_cpu.charged() - sim)
    us = app * 1e6
    print(f"{a.root}: app CPU per tick median {np.median(us):.1f} us, mean {us.mean():.1f} us, "
          f"p10 {np.percentile(us, 10):.1f} us ({a.ticks} ticks, lockstep, dob)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
