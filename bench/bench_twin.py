"""Speed of the MuJoCo twin (SIMULATED rig sim-piper): lockstep throughput and real-time rate holding.

    python bench/bench_twin.py [--seconds 2] [--rig sim-piper] [--loops 500,200] [--json out.json]

Reports simulated seconds per wall second (x real time) and per CPU second of this process
(time.process_time: what a quiet machine approaches when other processes load this one) for:
  (a) twin_only        Twin.advance with the wire emulators polling/emitting, no driver traffic
  (b) follower_<hz>    + the Piper driver reading and commanding every 1/hz s through virtual CAN
      full_<hz>        + the Dynamixel leader driver (sync read + sync write of goal current each loop)
                       through dynamixel-sdk on the lockstep twin's in-process port (open_rig's default)
      full_pty_<hz>    the same over the pseudo-terminal (emulator thread), for comparison
  per-step costs (CPU us per simulated ms) of the bank math, mj_step per world, the Piper emulator and
  one driver transaction each;
  (c) real time: serve_twin alone, and open_rig(clock="realtime") with a 500 Hz driver loop (both drivers;
      leader over the pty -- the real-time default -- and over the in-process port): simulated s per wall
      s, overruns, lag behind wall time, achieved loop rate, late ticks, CPU share of this process.
Physics 1 kHz (the rig's physics_hz; --control-hz decimates the firmware laws only). Target: >= 20x real
time for full_500 (50 us wall per simulated ms). Timings on a shared machine are noisy: say so.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hardware.rigs import Rig, load_rig  # noqa: E402
from hardware.sim import open_rig, serve_twin  # noqa: E402
from hardware.sim.twin import Twin  # noqa: E402
from hardware.types import FollowerCommand  # noqa: E402


def _timed(fn) -> tuple[float, float]:
    t0, c0 = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - t0, time.process_time() - c0


def _x(sim_s: float, wall: float, cpu: float) -> dict:
    return {"x_realtime": round(sim_s / wall, 2), "x_realtime_per_cpu": round(sim_s / max(cpu, 1e-9), 2)}


def _loop(s, seconds: float, loop_hz: float, leader: bool) -> dict:
    f = s.follower
    lead = s.leader if leader else None
    q0 = f.read().q.copy()
    dt = 1.0 / loop_hz
    n = int(round(seconds * loop_hz))
    zero = np.zeros(lead.n_joints) if lead is not None else None
    lost0 = lead.lost_reads if lead is not None else 0

    def run():
        for k in range(n):
            f.read()
            f.command(FollowerCommand(q=q0 + 0.3 * np.sin(2 * np.pi * 0.5 * k * dt)))
            if lead is not None:
                lead.read()
                lead.command_torque(zero)
            s.clock.sleep(dt)

    wall, cpu = _timed(run)
    assert np.all(np.isfinite(f.read().q))
    out = _x(n * dt, wall, cpu)
    if lead is not None:
        out["leader_lost_reads"] = lead.lost_reads - lost0
    return out


def step_costs(rig: Rig, n: int = 500) -> dict:
    """CPU us per call of each part of one 1 ms tick, and of one driver transaction."""
    costs = {}
    with Twin(rig, dynamixel_transport="inprocess") as tw:
        tw.advance(0.1)
        for w in tw.worlds:
            b = w.banks[0]
            _, c = _timed(lambda b=b, w=w: [b._apply(w.t, w.dt) for _ in range(n)])
            costs[f"bank_math_{w.name}"] = c / n * 1e6
            _, c = _timed(lambda w=w: [mujoco.mj_step(w.model, w.data, w.substeps) for _ in range(n)])
            costs[f"mj_step_{w.name}"] = c / n * 1e6
        for e in tw._can_emus:
            t = tw.t
            _, c = _timed(lambda e=e, t=t: [(e.poll(), e.emit(t + 1e-3 * (k + 1))) for k in range(n)])
            costs[f"{type(e).__name__}_poll_emit"] = c / n * 1e6
    with open_rig(rig, clock="lockstep") as s:
        f, lead = s.follower, s.leader
        q = f.read().q.copy()
        _, c = _timed(lambda: [(f.read(), f.command(FollowerCommand(q=q))) for _ in range(n)])
        costs["piper_driver_read_command"] = c / n * 1e6
        z = np.zeros(lead.n_joints)
        _, c = _timed(lambda: [(lead.read(), lead.command_torque(z)) for _ in range(n)])
        costs["dynamixel_driver_read_write_inprocess"] = c / n * 1e6
    return {k: round(v, 1) for k, v in costs.items()}


def bench_lockstep(rig: Rig, seconds: float, loops: list[float]) -> dict:
    out = {}
    with Twin(rig, dynamixel_transport="inprocess") as tw:
        tw.advance(0.2)
        out["twin_only"] = _x(seconds, *_timed(lambda: tw.advance(0.2 + seconds)))
    out["cpu_us_per_call"] = step_costs(rig)
    for hz in loops:
        tag = f"{hz:g}"
        with open_rig(rig, clock="lockstep") as s:
            _loop(s, 0.1, hz, leader=True)  # warm-up
            out[f"follower_{tag}"] = _loop(s, seconds, hz, leader=False)
            out[f"full_{tag}"] = _loop(s, seconds, hz, leader=True)
    with open_rig(rig, clock="lockstep", dynamixel_transport="pty") as s:
        hz = loops[0]
        _loop(s, 0.1, hz, leader=True)
        out[f"full_pty_{hz:g}"] = _loop(s, min(seconds, 1.0), hz, leader=True)
    return out


def _lag_probe(twin, seconds: float, body=None) -> dict:
    """Run body (or sleep 10 ms) repeatedly for `seconds`; sample how far the twin's physics is behind wall
    time (lag = wall - sim - the twin's offset, so catching up after a skip is not counted as ahead)."""
    lags, t_wall0, t_sim0 = [], time.monotonic(), twin.t
    c0 = time.process_time()
    end = t_wall0 + seconds
    while time.monotonic() < end:
        if body is None:
            time.sleep(0.01)
        else:
            body()
        lags.append(time.monotonic() - twin._t_offset - twin.t)
    wall, cpu = time.monotonic() - t_wall0, time.process_time() - c0
    return {"sim_per_wall": round((twin.t - t_sim0) / wall, 4), "worst_lag_ms": round(1e3 * max(lags), 2),
            "median_lag_ms": round(1e3 * float(np.median(lags)), 2), "cpu_share": round(cpu / wall, 2)}


def bench_realtime(rig: Rig, seconds: float, loop_hz: float = 500.0) -> dict:
    out = {}
    srv = serve_twin(rig)
    try:
        out["twin_only"] = _lag_probe(srv.twin, seconds)
        out["twin_only"]["overruns"] = srv.twin.overruns
    finally:
        srv.stop()
    for transport in ("pty", "inprocess"):
        out[f"with_drivers_{loop_hz:g}_{transport}"] = _realtime_loop(rig, seconds, loop_hz, transport)
    return out


def _realtime_loop(rig: Rig, seconds: float, loop_hz: float, transport: str) -> dict:
    with open_rig(rig, clock="realtime", dynamixel_transport=transport) as s:
        f, lead, clk = s.follower, s.leader, s.clock
        q0, z = f.read().q.copy(), np.zeros(s.leader.n_joints)
        dt, state = 1.0 / loop_hz, {"k": 0, "late": 0, "next": clk.now()}

        def tick():
            f.read()
            f.command(FollowerCommand(q=q0))
            lead.read()
            lead.command_torque(z)
            state["k"] += 1
            state["next"] += dt
            if clk.now() > state["next"]:
                state["late"] += 1
            clk.sleep_until(state["next"])

        r = _lag_probe(s.twin, seconds, tick)
        r.update(loop_hz_target=loop_hz, loop_hz_achieved=round(state["k"] / seconds, 1),
                 late_ticks=state["late"], overruns=s.twin.overruns, watchdog_holds=f.safety.holds - 1,
                 leader_lost_reads=lead.lost_reads)
        return r


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rig", default="sim-piper")
    ap.add_argument("--seconds", type=float, default=2.0, help="simulated seconds per lockstep measurement")
    ap.add_argument("--loops", default="500,200", help="driver loop rates [Hz], comma separated")
    ap.add_argument("--control-hz", type=float, default=None,
                    help="override the rig's twin control_hz (physics stays at physics_hz)")
    ap.add_argument("--no-realtime", action="store_true")
    ap.add_argument("--json", default=None, help="also write the results here")
    a = ap.parse_args(argv)
    rig = load_rig(a.rig)
    if a.control_hz:
        rig = dataclasses.replace(rig, twin=dataclasses.replace(rig.twin, control_hz=a.control_hz))
    loops = [float(x) for x in a.loops.split(",") if x]
    res = {"rig": a.rig, "simulated": True, "physics_hz": rig.twin.physics_hz,
           "control_hz": rig.twin.control_hz,
           "cpus": os.cpu_count(), "load_avg_1min": round(os.getloadavg()[0], 2)}
    res["lockstep"] = bench_lockstep(rig, a.seconds, loops)
    if not a.no_realtime:
        res["realtime"] = bench_realtime(rig, a.seconds)
    res["load_avg_1min_end"] = round(os.getloadavg()[0], 2)
    print(json.dumps(res, indent=2))
    if a.json:
        Path(a.json).parent.mkdir(parents=True, exist_ok=True)
        Path(a.json).write_text(json.dumps(res, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
