"""Speed of the MuJoCo twin (SIMULATED rig sim-piper): lockstep throughput and real-time rate holding.

    python bench/bench_twin.py [--seconds 2] [--rig sim-piper] [--json bench/out/twin.json]

Reports simulated seconds per wall second and per CPU second (x real time; the CPU figure is what a
quiet machine approaches) for:
  twin_only            Twin.advance with the wire emulators polling/emitting, no driver traffic
  follower_loop        + the Piper driver reading and commanding at loop_hz through virtual CAN
  full_loop            + the Dynamixel leader driver reading and writing goal currents over the pty
and per-step costs (us wall per simulated ms) of the bank math, mj_step per world and the emulators;
then real-time mode: simulated time gained over wall time, overruns, worst lag. Target: >= 20x real time
for full_loop (about 50 us wall per simulated ms). Timings on a shared machine are noisy: say so when
reporting them.
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


def _loop(s, seconds: float, loop_hz: float, leader: bool) -> tuple[float, float]:
    f = s.follower
    lead = s.leader if leader else None
    q = f.read().q.copy()
    dt = 1.0 / loop_hz
    n = int(seconds * loop_hz)
    t0, c0 = time.perf_counter(), time.process_time()
    for k in range(n):
        st = f.read()
        f.command(FollowerCommand(q=q + 0.3 * np.sin(2 * np.pi * 0.5 * k * dt)))
        if lead is not None:
            lead.read()
            lead.command_torque(np.zeros(lead.n_joints))
        s.clock.sleep(dt)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    assert np.all(np.isfinite(st.q))
    return seconds / wall, seconds / cpu


def bench_lockstep(rig: Rig, seconds: float, loop_hz: float) -> dict:
    out = {}
    tw = Twin(rig)
    tw.advance(0.2)
    t0, c0 = time.perf_counter(), time.process_time()
    tw.advance(0.2 + seconds)
    out["twin_only_x_realtime"] = seconds / (time.perf_counter() - t0)
    out["twin_only_x_realtime_per_cpu"] = seconds / (time.process_time() - c0)
    # per-step breakdown (us per simulated ms)
    n = 500
    costs = {}
    for w in tw.worlds:
        b = w.banks[0]
        c0 = time.process_time()
        for _ in range(n):
            b._apply(w.t, w.dt)
        costs[f"bank_apply_{w.name}_cpu_us"] = (time.process_time() - c0) / n * 1e6
        c0 = time.process_time()
        for _ in range(n):
            mujoco.mj_step(w.model, w.data)
        costs[f"mj_step_{w.name}_cpu_us"] = (time.process_time() - c0) / n * 1e6
    for e in tw._can_emus:
        c0 = time.process_time()
        for k in range(n):
            e.poll()
            e.emit(tw.t + 1e-3 * (k + 1))
        costs[f"{type(e).__name__}_poll_emit_cpu_us"] = (time.process_time() - c0) / n * 1e6
    tw.close()
    out["per_step_costs"] = {k: round(v, 1) for k, v in costs.items()}
    with open_rig(rig, clock="lockstep") as s:
        _loop(s, 0.1, loop_hz, leader=False)
        out["follower_loop_x_realtime"], out["follower_loop_x_realtime_per_cpu"] = \
            _loop(s, seconds, loop_hz, leader=False)
        out["full_loop_x_realtime"], out["full_loop_x_realtime_per_cpu"] = \
            _loop(s, seconds, loop_hz, leader=True)
    return out


def bench_realtime(rig: Rig, seconds: float) -> dict:
    srv = serve_twin(rig)
    try:
        lags = []
        t_wall0, t_sim0 = time.monotonic(), srv.sim_time
        end = t_wall0 + seconds
        while time.monotonic() < end:
            time.sleep(0.01)
            lags.append((time.monotonic() - t_wall0) - (srv.sim_time - t_sim0))
        wall = time.monotonic() - t_wall0
        sim = srv.sim_time - t_sim0
        return {"realtime_sim_per_wall": sim / wall, "realtime_overruns": srv.twin.overruns,
                "realtime_worst_lag_ms": 1e3 * max(lags),
                "realtime_median_lag_ms": 1e3 * float(np.median(lags))}
    finally:
        srv.stop()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rig", default="sim-piper")
    ap.add_argument("--seconds", type=float, default=2.0, help="simulated seconds per lockstep measurement")
    ap.add_argument("--loop-hz", type=float, default=500.0)
    ap.add_argument("--control-hz", type=float, default=None,
                    help="override the rig's twin control_hz (physics stays at physics_hz)")
    ap.add_argument("--json", default=None, help="also write the results here")
    a = ap.parse_args(argv)
    rig = load_rig(a.rig)
    if a.control_hz:
        rig = dataclasses.replace(rig, twin=dataclasses.replace(rig.twin, control_hz=a.control_hz))
    res = {"rig": a.rig, "loop_hz": a.loop_hz, "physics_hz": rig.twin.physics_hz,
           "control_hz": rig.twin.control_hz,
           "cpus": os.cpu_count(), "load_avg_1min": os.getloadavg()[0], "simulated": True}
    res.update(bench_lockstep(rig, a.seconds, a.loop_hz))
    res.update(bench_realtime(rig, a.seconds))
    print(json.dumps(res, indent=2))
    if a.json:
        Path(a.json).parent.mkdir(parents=True, exist_ok=True)
        Path(a.json).write_text(json.dumps(res, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
