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
    spec = mujoco.MjSpec()
    spec.option.timestep = 0.001
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.worldbody.add_geom(name="table", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.5, 0.6, 0.025],
                            pos=[0.3, 0, -0.025], solref=[0.004, 1], friction=[0.8, 0.005, 0.0001])
    PEG.PegInsert().add_objects(spec, None)
    spec.delete(spec.joint("peg"))
    peg = spec.body("peg")
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
    B.set_static_pos(m, "fixture", hole, 0.0)
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
    obs = {"peg_pos": d.xpos[m.body("peg").id].copy(), "peg_rot": d.xmat[m.body("peg").id].reshape(3, 3).copy(),
           "hole_pos": hole, "hole_yaw": 0.0, "finger_touch": np.array([True, True])}
    met = PEG.peg_metrics(obs["peg_pos"], obs["peg_rot"], hole, 0.0)
    return {"inserted": bool(PEG.detect_peg(obs)[2]), "bottom_z_m": met["bottom_z_m"],
            "max_penetration_m": deepest}
