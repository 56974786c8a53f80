"""Speed of the MuJoCo twin (SIMULATED rig sim-piper): lockstep throughput and real-time rate holding.

    python -m bench.bench_twin [--seconds 2] [--repeats 5] [--rig sim-piper] [--loops 500,200] [--json F]

Reports simulated seconds per wall second (x real time) and per CPU second of this process
(time.process_time: what a quiet machine approaches when other processes load this one) for:
  (a) twin_emulators   the headline: open_rig(clock="lockstep") with both drivers connected (the follower
                       holding in position mode, the leader in current mode), Twin.advance with the wire
                       emulators in the loop -- the Piper emulator polls commands and emits its full feedback
                       stream (~2,400 frames/s) onto the virtual CAN bus to the driver, the Dynamixel
                       emulator serves the in-process port -- and no client calls in between; median, min and
                       max of --repeats runs. Target >= 20x (50 us per simulated ms).
  (b) replay_<hz>      + the Piper driver reading and commanding every 1/hz s (100 Hz: the calibration
                       replay, the lockstep twin's main data-generation job)
      teleop_<hz>      + the Dynamixel leader driver (sync read + sync write of goal current each loop)
                       through dynamixel-sdk on the in-process port (open_rig's lockstep default)
      teleop_pty_<hz>  the same over the pseudo-terminal (emulator thread), for comparison
  per-call costs (CPU us) of the bank math and mj_step per world, the Piper emulator (per control tick)
  and one transaction of each driver;
  (c) real time: serve_twin alone, and open_rig(clock="realtime") with a 500 Hz driver loop (both drivers;
      leader over the pty -- the real-time default -- and over the in-process port): simulated s per wall
      s, overruns, lag behind wall time, achieved loop rate, late ticks, CPU share of this process.
Physics at the rig's physics_hz (1 kHz); firmware laws and emulators at its control_hz (500 Hz default;
--control-hz overrides). The clients' costs are the drivers' own (b): dynamixel-sdk's pure-Python packet
handling alone is ~200 us per sync read + write. Timings on a shared VM are noisy: hence the repeats.
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

from bench import harness
from hardware.connect import open_rig, serve_twin
from hardware.rigs import Rig, load_rig
from hardware.types import FollowerCommand


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
    """CPU us per call: each world's bank math and mj_step (its substeps) per control tick, the Piper
    emulator's poll + emit per control tick, one transaction of each driver. Motors under their drivers'
    modes (follower position, leader current), as in (a)."""
    costs = {}
    with open_rig(rig, clock="lockstep") as s:
        f, lead, tw = s.follower, s.leader, s.twin
        f.command(FollowerCommand(q=f.read().q))
        lead.command_torque(np.zeros(lead.n_joints))
        s.clock.sleep(0.1)
        for w in tw.worlds:
            b = w.banks[0]
            _, c = _timed(lambda b=b, w=w: [b._apply(w.t, w.dt) for _ in range(n)])
            costs[f"bank_math_{w.name}"] = c / n * 1e6
            _, c = _timed(lambda w=w: [mujoco.mj_step(w.model, w.data, w.substeps) for _ in range(n)])
            costs[f"mj_step_{w.name}"] = c / n * 1e6
        for e in tw.can_emulators:
            t = tw.t
            _, c = _timed(lambda e=e, t=t: [(e.poll(), e.emit(t + tw.dt * (k + 1))) for k in range(n)])
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


def twin_emulators(rig: Rig, seconds: float) -> dict:
    """(a): both drivers connected and commanded once (follower holding in position mode, leader at zero
    current), then the twin advances with its emulators in the loop and no client calls."""
    with open_rig(rig, clock="lockstep") as s:
        s.follower.command(FollowerCommand(q=s.follower.read().q))
        s.leader.command_torque(np.zeros(s.leader.n_joints))
        s.clock.sleep(0.2)
        t0 = s.clock.now()
        return _x(seconds, *_timed(lambda: s.clock.sleep_until(t0 + seconds)))


def _spread(runs: list[dict]) -> dict:
    xs = sorted(r["x_realtime"] for r in runs)
    cpu = sorted(r["x_realtime_per_cpu"] for r in runs)
    return {"x_realtime_median": xs[len(xs) // 2], "x_realtime_min": xs[0], "x_realtime_max": xs[-1],
            "x_realtime_per_cpu_median": cpu[len(cpu) // 2], "runs": len(runs)}


def bench_lockstep(rig: Rig, seconds: float, loops: list[float], repeats: int = 5) -> dict:
    out = {"twin_emulators": _spread([twin_emulators(rig, seconds) for _ in range(repeats)])}
    out["cpu_us_per_call"] = step_costs(rig)
    out["replay_100"] = _spread([_replay(rig, seconds, 100.0) for _ in range(repeats)])
    for hz in loops:
        with open_rig(rig, clock="lockstep") as s:
            _loop(s, 0.1, hz, leader=True)  # warm-up
            if f"replay_{hz:g}" not in out:  # replay_100 is the median of the repeats above
                out[f"replay_{hz:g}"] = _loop(s, seconds, hz, leader=False)
            out[f"teleop_{hz:g}"] = _loop(s, seconds, hz, leader=True)
    with open_rig(rig, clock="lockstep", dynamixel_transport="pty") as s:
        hz = loops[0]
        _loop(s, 0.1, hz, leader=True)
        out[f"teleop_pty_{hz:g}"] = _loop(s, min(seconds, 1.0), hz, leader=True)
    return out


def _replay(rig: Rig, seconds: float, hz: float) -> dict:
    with open_rig(rig, clock="lockstep") as s:
        _loop(s, 0.1, hz, leader=False)  # warm-up
        return _loop(s, seconds, hz, leader=False)


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
        lags.append(twin.lag(time.monotonic()))
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
    ap.add_argument("--repeats", type=int, default=5, help="runs of (a) and replay_100 (median, min, max)")
    ap.add_argument("--control-hz", type=float, default=None,
                    help="override the rig's twin control_hz (physics stays at physics_hz)")
    ap.add_argument("--no-realtime", action="store_true")
    ap.add_argument("--json", default=None, help="also write the results here (a bench/harness.py record)")
    harness.add_quick(ap, "0.2 s lockstep at 500 Hz, once, no real-time run")
    a = ap.parse_args(argv)
    if a.quick:
        a.seconds, a.loops, a.repeats, a.no_realtime = 0.2, "500", 1, True
    rig = load_rig(a.rig)
    if a.control_hz:
        rig = dataclasses.replace(rig, twin=dataclasses.replace(rig.twin, control_hz=a.control_hz))
    loops = [float(x) for x in a.loops.split(",") if x]
    res = {"rig": a.rig, "simulated": True, "physics_hz": rig.twin.physics_hz,
           "control_hz": rig.twin.control_hz, "load_avg_1min": round(os.getloadavg()[0], 2)}
    res["lockstep"] = bench_lockstep(rig, a.seconds, loops, max(1, a.repeats))
    if not a.no_realtime:
        res["realtime"] = bench_realtime(rig, a.seconds)
    res["load_avg_1min_end"] = round(os.getloadavg()[0], 2)
    print(json.dumps(res, indent=2))
    if a.json:
        Path(a.json).parent.mkdir(parents=True, exist_ok=True)
        harness.write(a.json, harness.record("twin_speed", res, simulated=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
