"""The teleop app's own CPU per tick, the same work tick for tick (issue #53 item 1): the thread CPU of
`TeleopLoop._tick_all` minus what the twin charged on that thread (hardware/sim_cpu.py), on the sim-piper
twin in lockstep (dob feedback). --transport inprocess (default): the leader's Dynamixel emulator answers
inline, as in `factr2 demo`; pty: the leader's packets cross a pseudo-terminal to the emulator's own thread,
as in `factr2 teleop` on a twin (the real serial path: termios, select, read/write syscalls). Thread CPU
time moves less with other load than wall time, but not nothing on a shared VM: repeat (--repeat), alternate
the checkouts (--root) and compare medians. --calls also counts the Python and C calls one tick makes
(sys.setprofile; deterministic, unlike the CPU time). SIMULATED.

--ab BEFORE AFTER: the two checkouts side by side, each in its own process with its own twin, taking turns
every --block ticks (--rounds turns each, the order alternating): both see the same load minute by minute,
so the ratio of their medians holds on a shared machine where one checkout's run and the other's minutes
apart do not (their medians moved 1.5-2x between runs of the same code at load 5-9).

    python bench/app_cpu_per_tick.py [--ticks 2000] [--transport inprocess|pty] [--repeat 3] [--root CHECKOUT]
    python bench/app_cpu_per_tick.py --ab BEFORE AFTER [--rounds 20] [--block 200] [--transport pty]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path


def _session(transport: str):
    """(rig session, teleop loop) of sim-piper in lockstep, dob, past the soft start."""
    from factr2_teleop.session.pairs import TeleopOptions
    from factr2_teleop.session.teleop import TeleopSession
    from hardware.connect import open_rig

    kw = {} if transport == "inprocess" else {"dynamixel_transport": transport}
    s = open_rig("sim-piper", clock="lockstep", **kw)
    ts = TeleopSession(s, TeleopOptions(mode="dob"))
    loop = ts.loop
    ts.pairs[0].begin(s.clock)
    for _ in range(300):  # past the soft start
        s.clock.sleep(loop.period_s)
        loop._tick_all(s.clock.now())
    return s, loop


def _ticks(s, loop, ticks: int) -> list[float]:
    """The app's CPU [s] of each of `ticks` more ticks."""
    from hardware import sim_cpu

    app = []
    for _ in range(ticks):
        s.clock.sleep(loop.period_s)
        c, sim = time.thread_time(), sim_cpu.charged()
        loop._tick_all(s.clock.now())
        app.append((time.thread_time() - c) - (sim_cpu.charged() - sim))
    return app


def measure(ticks: int, transport: str, calls: bool) -> tuple[list[float], float]:
    """Per-tick app CPU [s] over `ticks` lockstep ticks after the soft start; mean calls per tick (or nan)."""
    s, loop = _session(transport)
    with s:
        app = _ticks(s, loop, ticks)
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
    ap.add_argument("--ab", nargs=2, metavar=("BEFORE", "AFTER"), help="two checkouts, taking turns")
    ap.add_argument("--rounds", type=int, default=20)
    ap.add_argument("--block", type=int, default=200, help="ticks per turn (--ab)")
    ap.add_argument("--serve", action="store_true", help=argparse.SUPPRESS)  # one side of --ab
    a = ap.parse_args()
    if a.ab:
        return ab(a.ab, a.transport, a.rounds, a.block)
    sys.path.insert(0, a.root)
    if a.serve:
        return serve(a.transport)
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


def serve(transport: str) -> int:
    """One side of --ab: a session; each line "N" on stdin runs N ticks and answers their CPU [us] as JSON."""
    s, loop = _session(transport)
    with s:
        print("ready", flush=True)
        for line in sys.stdin:
            print(json.dumps([x * 1e6 for x in _ticks(s, loop, int(line))]), flush=True)
    return 0


def ab(roots: list[str], transport: str, rounds: int, block: int) -> int:
    """Both checkouts in turns of `block` ticks; medians, their ratio, and the spread of per-round ratios."""
    import numpy as np

    procs = [subprocess.Popen([sys.executable, __file__, "--serve", "--root", r, "--transport", transport],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True) for r in roots]
    try:
        for pr in procs:
            if pr.stdout.readline().strip() != "ready":
                raise SystemExit(f"a side did not start: {pr.args}")
        got: list[list[float]] = [[], []]
        per_round = []
        for k in range(rounds):
            med = [0.0, 0.0]
            for i in ((0, 1) if k % 2 == 0 else (1, 0)):
                procs[i].stdin.write(f"{block}\n")
                procs[i].stdin.flush()
                us = json.loads(procs[i].stdout.readline())
                got[i] += us
                med[i] = float(np.median(us))
            per_round.append(med[1] / med[0])
    finally:
        for pr in procs:
            pr.stdin.close()
            pr.wait(timeout=60)
    m = [float(np.median(g)) for g in got]
    r = np.asarray(per_round)
    for root, g, mi in zip(roots, got, m, strict=True):
        print(f"{root}: app CPU per tick median {mi:.1f} us, p10 {np.percentile(g, 10):.1f}, "
              f"p90 {np.percentile(g, 90):.1f} ({len(g)} ticks, lockstep, dob, {transport})")
    print(f"after / before: {m[1] / m[0]:.3f} (medians); per round ({rounds} x {block} ticks each side, "
          f"alternating): median {np.median(r):.3f}, p10-p90 {np.percentile(r, 10):.3f}-"
          f"{np.percentile(r, 90):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
