"""A MujocoBank's joints in its MuJoCo model (SIMULATED): found by name and checked (1-dof hinge or slide),
the motor parameters the rig leaves open taken from the model, and the model's own friction, damping and
actuators on them switched off, since from then on the bank's motor model is the only drive and friction
on them (hardware/sim/mujoco_bank.py).
"""

from __future__ import annotations

import mujoco
import numpy as np

from hardware.sim import actuators as act

_ONE_DOF_JOINTS = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))


def as_slice(idx: np.ndarray):
    """A slice when the indices are consecutive (cheap numpy views), else the index array."""
    if idx.size and np.all(np.diff(idx) == 1):
        return slice(int(idx[0]), int(idx[-1]) + 1)
    return idx


def bind_joints(m: mujoco.MjModel, joints: list[str], params: act.ActuatorParams,
                name: str) -> tuple[act.ActuatorParams, np.ndarray, np.ndarray]:
    """(the bank's parameters sized to its joints with the open ones filled from the model, qpos addresses,
    dof addresses) of `joints` in model m, which is changed: armature from the parameters, the joints'
    frictionloss and damping zeroed, joint actuators on them inert. Raises ValueError naming bank `name` for
    a joint missing or not 1-dof."""
    ids = []
    for j in joints:
        jid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, j)
        if jid < 0:
            raise ValueError(f"bank {name}: no joint {j!r} in the MuJoCo model")
        if int(m.jnt_type[jid]) not in _ONE_DOF_JOINTS:
            raise ValueError(f"bank {name}: joint {j!r} is not a hinge or slide joint")
        ids.append(jid)
    qadr = np.array([m.jnt_qposadr[j] for j in ids])
    dadr = np.array([m.jnt_dofadr[j] for j in ids])
    p = params.sized(len(joints))
    # The arm's MJCF gives armature / Coulomb / viscous unless the params override them; from here on the
    # bank's friction model is the only friction on these joints, and MJCF actuators on them are inert.
    from_model = (("armature", m.dof_armature), ("coulomb", m.dof_frictionloss),
                  ("viscous", m.dof_damping))
    for fld, src in from_model:
        v = getattr(p, fld)
        v[:] = np.where(np.isnan(v), src[dadr], v)
    m.dof_armature[dadr] = p.armature
    # Drive current limit: NaN -> the joint's actuatorfrcrange (the arm's tau_max) / kt.
    frc = np.where(m.jnt_actfrclimited[ids] > 0, np.abs(m.jnt_actfrcrange[ids]).max(axis=1), 1e3)
    p.i_max[:] = np.where(np.isnan(p.i_max), frc / p.kt, p.i_max)
    m.dof_frictionloss[dadr] = 0.0
    m.dof_damping[dadr] = 0.0
    for a in range(m.nu):
        if int(m.actuator_trntype[a]) == int(mujoco.mjtTrn.mjTRN_JOINT) and m.actuator_trnid[a, 0] in ids:
            m.actuator_gainprm[a, :] = 0.0
            m.actuator_biasprm[a, :] = 0.0
    return p, qadr, dadr
