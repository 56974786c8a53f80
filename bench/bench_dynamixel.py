"""Round trips per second of a 7-servo Dynamixel leader: one sync read + one sync write per tick.

The leader (DynamixelLeader through dynamixel-sdk) talks Protocol 2.0 over a pseudo-terminal to the
SIMULATED servo chain (hardware.dynamixel.emulator on an IdealMotorBank). By default the emulator is a thread
of this process, as in the MuJoCo twin; --separate-process runs it in its own process, as real servos are
separate hardware (on a loaded 2-core machine the cross-process wake-ups cost more). Target: >= 1000/s.

    python -m bench.bench_dynamixel --seconds 5
"""

from __future__ import annotations

import argparse
import logging
import multiprocessing as mp
import resource
import sys
import time

import numpy as np

from bench import harness
from hardware.dynamixel.config import DynamixelLeaderConfig
from hardware.dynamixel.emulator import DynamixelEmulator
from hardware.dynamixel.leader import DynamixelLeader
from hardware.sim.motors import IdealMotorBank
from hardware.types import JointLimits

N_SERVOS = 7
IDS = list(range(1, N_SERVOS + 1))


def _make_emulator() -> DynamixelEmulator:
    bank = IdealMotorBank(N_SERVOS, torque_constant=0.354)
    return DynamixelEmulator(bank, IDS, "XL330-M288", return_delay=0)


def _serve(conn, stop) -> None:
    emu = _make_emulator()
    conn.send(emu.port_path)
    stop.wait()
    emu.close()


def run(seconds: float, in_process: bool) -> dict:
    ctx = mp.get_context("fork")
    stop, proc, emu = None, None, None
    if in_process:
        emu = _make_emulator()
        path = emu.port_path
    else:
        parent, child = ctx.Pipe()
        stop = ctx.Event()
        proc = ctx.Process(target=_serve, args=(child, stop), daemon=True)
        proc.start()
        path = parent.recv()
    n = N_SERVOS
    cfg = DynamixelLeaderConfig(port=path, ids=IDS, signs=[1] * n, offsets_rad=[0.0] * n, loop_hz=1000.0)
    lim = JointLimits(
        q_min=np.full(n, -10.0),
        q_max=np.full(n, 10.0),
        v_max=np.full(n, 10.0),
        tau_max=np.full(n, 0.3),
        tau_rate_max=np.full(n, 1e3),
    )
    leader = DynamixelLeader(cfg, lim)
    try:
        leader.connect()
        tau = np.full(n, 0.05)
        count, t0, cpu0 = 0, time.perf_counter(), time.process_time()
        lat = []
        while (now := time.perf_counter()) - t0 < seconds:
            leader.read()
            leader.command_torque(tau)
            lat.append(time.perf_counter() - now)
            count += 1
        dt = time.perf_counter() - t0
        cpu_leader = time.process_time() - cpu0
        lat_ms = 1e3 * np.array(lat)
        return {
            "round_trips_per_s": count / dt,
            "count": count,
            "cpu_us_per_rt": 1e6 * cpu_leader / max(count, 1),
            "lost_reads": leader.lost_reads,
            "p50_ms": float(np.percentile(lat_ms, 50)),
            "p99_ms": float(np.percentile(lat_ms, 99)),
            "warnings": leader.warnings,
        }
    finally:
        leader.disconnect()
        if emu is not None:
            emu.close()
        if proc is not None:
            stop.set()
            proc.join(timeout=2)


def _child_cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=5.0, help="how long to run [s]")
    ap.add_argument("--separate-process", action="store_true", help="run the emulator in its own process")
    harness.add_quick(ap, "0.5 s")
    a = ap.parse_args(argv)
    if a.quick:
        a.seconds = 0.5
    logging.getLogger("factr2.dynamixel").setLevel(logging.ERROR)  # start-up warnings are printed below
    c0 = _child_cpu_s()
    in_process = not a.separate_process
    r = run(a.seconds, in_process)
    # CPU per round trip depends far less on other load than the rate does: it bounds the idle-machine rate
    # (the emulator process's CPU includes its start and stop, a small overestimate).
    cpu_us = r["cpu_us_per_rt"] + 1e6 * (_child_cpu_s() - c0) / max(r["count"], 1)
    where = "emulator thread in-process" if in_process else "emulator in a separate process"
    print(
        f"bench_dynamixel: {r['round_trips_per_s']:.0f} round trips/s (1 sync read of 10 B x "
        f"{N_SERVOS} servos + 1 sync write of goal current), {r['count']} in {a.seconds:.1f} s, "
        f"p50 {r['p50_ms']:.3f} ms, "
        f"p99 {r['p99_ms']:.3f} ms, incomplete reads {r['lost_reads']} -- SIMULATED servos over a pty, "
        f"{where}"
    )
    who = "leader + emulator thread" if in_process else "leader + emulator process"
    print(
        f"CPU per round trip ({who}): {cpu_us:.0f} us -> CPU-bound ceiling about {1e6 / cpu_us:.0f}/s "
        "on an idle machine (rates here are noisy when other jobs share the CPUs)"
    )
    for w in r["warnings"]:
        print(f"note (leader start-up check): {w}")
    print(f"machine: {harness.machine_line()}")
    print(f"target >= 1000/s: {'met' if r['round_trips_per_s'] >= 1000 else 'NOT met'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
