"""How the tight-insert contacts were checked (SIMULATED): the pin, held by contact_check's compliant hand
(300 N/m sideways, 500 N/m down, 2 N*m/rad), is lowered onto the bore or pressed and slid across its mouth.

lower_held_pin: lowered at 30 mm/s from 4 mm above the fixture to a target 2 mm below the bore's floor (a
push of ~1 N once seated), with a lateral offset and a tilt. slide_held_pin: pressed onto the fixture top
beside the bore, then dragged across it at a search speed: the pin must drop when its tip crosses the chamfer.
Both report the detectors' verdict (the twin's truth), the deepest interpenetration of the task's contacts
(pin against fixture) and of the pin against the table (the scene's softer contact), and the pin's jitter
(std of its position over the last 0.5 s, held still). Used by tests/test_tight_insert.py, quoted in
docs/tasks.md.
"""

from __future__ import annotations

import mujoco
import numpy as np

from hardware.sim.tasks import base as B
from hardware.sim.tasks import tight_insert as TI
from hardware.sim.tasks.contact_check import _held_model

HOLE = np.array([0.3, 0.1, 0.0])  # m: where the fixture stands in these checks
PUSH_BELOW_M = 0.002  # m: the hand's final target under the bore's floor


def _setup():
    m = _held_model(TI.TightInsert(), "pin")
    d = mujoco.MjData(m)
    B.set_static_pos(m, d, "fixture", HOLE, 0.0)
    fixture = {g for g in range(m.ngeom) if m.geom(g).name.startswith("fixture")}
    return m, d, m.body_pos[m.body("pin").id].copy(), fixture, m.geom("table").id


def _run(m, d, ctrl_at, seconds: float, fixture: set, table: int) -> dict:
    """Step with ctrl_at(t) -> 6 hand targets; the verdict, the deepest penetrations [m], the jitter [m]."""
    deep_fix = deep_table = 0.0
    b = m.body("pin").id
    steps = round(seconds / m.opt.timestep)
    tail = []
    for k in range(steps):
        d.ctrl[:] = ctrl_at(k * m.opt.timestep)
        mujoco.mj_step(m, d)
        deep_fix = max(deep_fix, B.max_penetration_m(d, fixture))
        deep_table = max(deep_table, B.max_penetration_m(d, {table}))
        if k >= steps - 500:
            tail.append(d.xpos[b].copy())
    obs = {"pin_pos": d.xpos[b].copy(), "pin_rot": d.xmat[b].reshape(3, 3).copy(), "hole_pos": HOLE,
           "hole_yaw": 0.0, "finger_touch": np.array([True, True])}
    met = TI.pin_metrics(obs["pin_pos"], obs["pin_rot"], HOLE)
    return {"stages": TI.detect_tight(obs), "tip_z_m": met["tip_z_m"], "radial_m": met["radial_m"],
            "pen_fixture_m": deep_fix, "pen_table_m": deep_table,
            "jitter_m": float(np.max(np.std(np.asarray(tail), axis=0)))}


def lower_held_pin(offset_m: float = 0.0, tilt_rad: float = 0.0, seconds: float = 2.5) -> dict:
    """Lower the held pin onto the bore, its tip offset_m [m] off the axis (along x), tilted tilt_rad [rad]
    about x."""
    m, d, p0, fixture, table = _setup()
    start = HOLE + [offset_m, 0.0, TI.DEPTH_M + 0.004]
    end_z = HOLE[2] - PUSH_BELOW_M

    def ctrl(t):
        z = max(end_z, start[2] - 0.03 * t)
        return np.array([*(start[:2] - p0[:2]), z - p0[2], tilt_rad, 0.0, 0.0])

    d.qpos[:6] = ctrl(0.0)
    mujoco.mj_forward(m, d)
    return _run(m, d, ctrl, seconds, fixture, table)


def slide_held_pin(from_m: float = 0.004, speed_m_s: float = 0.01, press_m: float = TI.CHAMFER_M + 0.002,
                   seconds: float = 2.0) -> dict:
    """Press the held pin onto the fixture top from_m [m] beside the axis (the hand's target press_m below
    the top, 2 mm below the chamfer's lower edge: ~2 N on the top) and drag it across the bore at speed_m_s
    [m/s] toward and past the axis."""
    m, d, p0, fixture, table = _setup()
    z_press = HOLE[2] + TI.DEPTH_M - press_m

    def ctrl(t):
        x = HOLE[0] + from_m - min(2 * from_m, speed_m_s * max(0.0, t - 0.3))
        z = max(z_press, HOLE[2] + TI.DEPTH_M + 0.002 - 0.03 * t)
        return np.array([x - p0[0], HOLE[1] - p0[1], z - p0[2], 0.0, 0.0, 0.0])

    d.qpos[:6] = ctrl(0.0)
    mujoco.mj_forward(m, d)
    return _run(m, d, ctrl, seconds, fixture, table)
