"""How the task contacts were checked (SIMULATED): a peg held by a compliant hand is lowered onto the hole.

The peg keeps the task's geometry and contact settings but hangs on three slide joints (x, y, z) and three
hinges, each servoed by a position actuator: a hand that holds it firmly but can be pushed aside (300 N/m
laterally, 2 N*m/rad in rotation). The hand lowers it at 30 mm/s to 15 mm below the table. Used by
tests/test_tasks_contact.py and quoted in docs/tasks.md; pure set-up + a run, no randomness.
"""

from __future__ import annotations

import mujoco
import numpy as np

from hardware.sim.tasks import base as B
from hardware.sim.tasks import peg_insert as PEG

HAND_KP_N_PER_M = (300.0, 300.0, 500.0)
HAND_KP_NM_PER_RAD = 2.0
LOWER_SPEED_M_S = 0.03


def held_peg_model() -> mujoco.MjModel:
    return _held_model(PEG.PegInsert(), "peg")


def _held_model(task, body: str) -> mujoco.MjModel:
    spec = mujoco.MjSpec()
    spec.option.timestep = 0.001
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.worldbody.add_geom(name="table", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.5, 0.6, 0.025],
                            pos=[0.3, 0, -0.025], solref=[0.004, 1], friction=[0.8, 0.005, 0.0001])
    task.add_objects(spec, None)
    spec.delete(spec.joint(body))
    peg = spec.body(body)
    axes = ([1, 0, 0], [0, 1, 0], [0, 0, 1])
    for k, ax in enumerate(axes):
        peg.add_joint(name=f"slide{k}", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=ax, damping=5.0)
    for k, ax in enumerate(axes):
        peg.add_joint(name=f"hinge{k}", type=mujoco.mjtJoint.mjJNT_HINGE, axis=ax, damping=0.01)
    for k in range(3):
        a = spec.add_actuator(name=f"slide{k}", target=f"slide{k}", trntype=mujoco.mjtTrn.mjTRN_JOINT)
        a.set_to_position(kp=HAND_KP_N_PER_M[k])
    for k in range(3):
        a = spec.add_actuator(name=f"hinge{k}", target=f"hinge{k}", trntype=mujoco.mjtTrn.mjTRN_JOINT)
        a.set_to_position(kp=HAND_KP_NM_PER_RAD)
    return spec.compile()


def lower_held_peg(offset_m: float = 0.0, yaw_rad: float = 0.0, tilt_rad: float = 0.0,
                   seconds: float = 3.0) -> dict:
    """Lower the held peg onto a hole at the origin's side with a lateral offset [m] (along the hole's x),
    a yaw and a tilt [rad]. Returns the peg's final metrics, the detectors' verdict and the deepest
    interpenetration [m] seen during the run."""
    m = held_peg_model()
    d = mujoco.MjData(m)
    hole = np.array([0.3, 0.1, 0.0])
    B.set_static_pos(m, d, "fixture", hole, 0.0)
    p0 = m.body_pos[m.body("peg").id].copy()
    start = hole + [offset_m, 0.0, PEG.DEPTH_M + PEG.PEG_HALF[2] + 0.005]
    ctrl = lambda z: np.array([*(start[:2] - p0[:2]), z - p0[2], tilt_rad, 0.0, yaw_rad])  # noqa: E731
    d.qpos[:6] = ctrl(start[2])
    mujoco.mj_forward(m, d)
    deepest = 0.0
    steps = round(seconds / m.opt.timestep)
    for k in range(steps):
        z = start[2] - min(0.04, LOWER_SPEED_M_S * k * m.opt.timestep)
        d.ctrl[:] = ctrl(z)
        mujoco.mj_step(m, d)
        deepest = max(deepest, B.max_penetration_m(d))
    b = m.body("peg").id
    obs = {"peg_pos": d.xpos[b].copy(), "peg_rot": d.xmat[b].reshape(3, 3).copy(),
           "hole_pos": hole, "hole_yaw": 0.0, "finger_touch": np.array([True, True])}
    met = PEG.peg_metrics(obs["peg_pos"], obs["peg_rot"], hole, 0.0)
    return {"inserted": bool(PEG.detect_peg(obs)[2]), "bottom_z_m": met["bottom_z_m"],
            "max_penetration_m": deepest}


def press_held_block(offset_m: float = 0.0, push_below_m: float = 0.005, seconds: float = 4.0) -> dict:
    """Press a held press-fit block onto the studs (offset [m] along the base's x; the hand's target ends
    push_below_m below seated). Returns the detectors' seat verdict and the deepest interpenetration [m]."""
    from hardware.sim.tasks import press_fit as PF

    m = _held_model(PF.PressFit(), "block")
    d = mujoco.MjData(m)
    base = np.array([0.3, 0.1, 0.0])
    B.set_static_pos(m, d, "base", base, 0.0)
    p0 = m.body_pos[m.body("block").id].copy()
    h = 0.5 * (PF.SKIRT_H_M + PF.CAP_H_M)
    start = base + [offset_m, 0.0, PF.PLATE_TOP_M + 2 * PF.STUD_HALF[2] + h + 0.004]
    end_z = PF.PLATE_TOP_M + h - push_below_m
    ctrl = lambda z: np.array([*(start[:2] - p0[:2]), z - p0[2], 0.0, 0.0, 0.0])  # noqa: E731
    d.qpos[:6] = ctrl(start[2])
    mujoco.mj_forward(m, d)
    deepest = 0.0
    for k in range(round(seconds / m.opt.timestep)):
        d.ctrl[:] = ctrl(max(end_z, start[2] - 0.02 * k * m.opt.timestep))
        mujoco.mj_step(m, d)
        deepest = max(deepest, B.max_penetration_m(d))
    b = m.body("block").id
    obs = {"block_pos": d.xpos[b].copy(), "block_rot": d.xmat[b].reshape(3, 3).copy(), "base_pos": base,
           "base_yaw": 0.0, "finger_touch": np.array([True, True])}
    return {"seated": bool(PF.detect_press(obs)[2]), "max_penetration_m": deepest}
