"""One MuJoCo world (a follower's scene, or a leader arm) with its motor banks, pushes and ground truth.

step() runs one control tick: every bank writes its motor torques (hardware/sim/mujoco_bank.py), then
`substeps` MuJoCo steps. ground_truth() separates what an estimator must find from what the drives do:
external joint torque from contacts (constraint rows of contact type only; joint-limit rows are reported
apart), pushes (xfrc_applied -> J^T F) and the operator's hand, in the paper's convention
tau_ext = tau_m - tau_free, i.e. the torque the joints exert against the environment.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import mujoco
import numpy as np

from hardware.sim import actuators as act
from hardware.sim.mujoco_bank import MujocoBank

_CONTACT_TYPES = (int(mujoco.mjtConstraint.mjCNSTR_CONTACT_FRICTIONLESS),
                  int(mujoco.mjtConstraint.mjCNSTR_CONTACT_PYRAMIDAL),
                  int(mujoco.mjtConstraint.mjCNSTR_CONTACT_ELLIPTIC))
_LIMIT_TYPES = (int(mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT), int(mujoco.mjtConstraint.mjCNSTR_LIMIT_TENDON))


@dataclass
class GroundTruth:
    """Simulated ground truth for one bank (never visible to an estimator).

    tau_ext [N*m]: external joint torque, paper convention (tau_m - tau_free): contacts + pushes + hand;
    tau_contact / tau_push / tau_hand: its parts; tau_limit: joint-limit constraint torque (not external);
    contact: any arm body touches something; q/q_dot: link-side state; tau_motor: rotor torque;
    tau_friction / tau_load: the drive's internal loads (friction; ripple + hook)."""

    t: float
    tau_ext: np.ndarray
    tau_contact: np.ndarray
    tau_push: np.ndarray
    tau_hand: np.ndarray
    tau_limit: np.ndarray
    contact: bool
    q: np.ndarray
    q_dot: np.ndarray
    tau_motor: np.ndarray
    tau_friction: np.ndarray
    tau_load: np.ndarray


class MujocoWorld:
    """One MuJoCo world and its motor banks; step() advances one physics step of model.opt.timestep."""

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData | None = None, name: str = "world"):
        self.model, self.name = model, name
        if model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4:
            model.opt.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST  # damping must be implicit
        self.data = data if data is not None else mujoco.MjData(model)
        self.substeps = 1  # physics steps per control tick (the firmware laws' period is dt)
        self.dt = float(model.opt.timestep)
        self.banks: list[MujocoBank] = []
        self.lock = threading.RLock()
        self._push_body, self._push_force, self._push_until = -1, np.zeros(6), -1.0
        self._geom_bank: np.ndarray | None = None
        self.steps = 0
        mujoco.mj_forward(model, self.data)

    @property
    def t(self) -> float:
        return float(self.data.time)

    def add_bank(self, joints: list[str], params: act.ActuatorParams, **kw) -> MujocoBank:
        bank = MujocoBank(self, joints, params, **kw)
        self.banks.append(bank)
        self._geom_bank = None
        return bank

    def set_substeps(self, k: int) -> None:
        """Run the firmware laws (and everything in Python) every k physics steps; MuJoCo integrates the
        implicit damping, friction slope, contacts and limits at every physics step in between."""
        self.substeps = max(1, int(k))
        self.dt = float(self.model.opt.timestep) * self.substeps
        for b in self.banks:
            b.set_control_dt(self.dt)

    def step(self) -> None:
        """One control tick: banks compute torques, then `substeps` physics steps."""
        with self.lock:
            t, dt = self.t, self.dt
            if self._push_until >= 0 and t >= self._push_until:
                self.data.xfrc_applied[self._push_body] = 0.0
                self._push_until = -1.0
            for b in self.banks:
                b._apply(t, dt)
            mujoco.mj_step(self.model, self.data, self.substeps)
            self.steps += 1
            for b in self.banks:
                b._after_step(dt)

    def advance(self, t_target: float) -> int:
        """Step until sim time reaches t_target [s] (to within half a step); returns steps taken."""
        n = 0
        while self.t + 0.5 * self.dt < t_target:
            self.step()
            n += 1
        return n

    def set_qpos(self, bank: MujocoBank, q: np.ndarray) -> None:
        """Teleport a bank's joints (initial pose), zero velocity, motors re-seeded there."""
        with self.lock:
            self.data.qpos[bank.qadr] = q
            self.data.qvel[bank.dadr] = 0.0
            mujoco.mj_forward(self.model, self.data)
            bank.theta = np.asarray(q, float).copy()
            bank.q_d, bank.q_brake = bank.theta.copy(), bank.theta.copy()
            bank._reset_targets(slice(None), bank.theta)

    def push(self, body: str, force: np.ndarray, duration_s: float, torque: np.ndarray | None = None) -> None:
        """Apply a world-frame force [N] (and torque [N*m]) at a body's centre of mass for duration_s [s]."""
        bid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, body)
        if bid < 0:
            raise ValueError(f"{self.name}: no body {body!r} to push")
        with self.lock:
            if self._push_body >= 0:
                self.data.xfrc_applied[self._push_body] = 0.0
            w = np.zeros(6)
            w[:3] = force
            if torque is not None:
                w[3:] = torque
            self._push_body, self._push_force, self._push_until = bid, w, self.t + float(duration_s)
            self.data.xfrc_applied[bid] = w

    def _bank_of_geom(self) -> np.ndarray:
        """geom id -> index of the bank whose joints move it (-1: none)."""
        if self._geom_bank is None:
            m = self.model
            body_bank = np.full(m.nbody, -1)
            for k, b in enumerate(self.banks):
                for jb in m.jnt_bodyid[[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, j)
                                        for j in b.joint_names]]:
                    body_bank[jb] = k
            for bid in range(1, m.nbody):  # children follow parents (bodies are in tree order)
                if body_bank[bid] < 0:
                    body_bank[bid] = body_bank[m.body_parentid[bid]]
            self._geom_bank = body_bank[m.geom_bodyid]
        return self._geom_bank

    def ground_truth(self) -> list[GroundTruth]:
        """Ground truth per bank from the last step's constraint forces and the current pushes."""
        m, d = self.model, self.data
        with self.lock:
            nefc = d.nefc
            etype = d.efc_type[:nefc]
            force = d.efc_force[:nefc]
            is_contact = np.isin(etype, _CONTACT_TYPES)
            qfrc_contact, qfrc_limit = np.zeros(m.nv), np.zeros(m.nv)
            if nefc:
                mujoco.mj_mulJacTVec(m, d, qfrc_contact, np.where(is_contact, force, 0.0))
                mujoco.mj_mulJacTVec(m, d, qfrc_limit, np.where(np.isin(etype, _LIMIT_TYPES), force, 0.0))
            gb = self._bank_of_geom()
            touching = set()
            active = np.unique(d.efc_id[:nefc][is_contact & (np.abs(force) > 1e-9)])
            for c in active:
                g1, g2 = d.contact.geom1[c], d.contact.geom2[c]
                touching.update(int(k) for k in (gb[g1], gb[g2]) if k >= 0)
            qfrc_push = np.zeros(m.nv)
            if self._push_until >= 0:
                jacp, jacr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
                mujoco.mj_jacBodyCom(m, d, jacp, jacr, self._push_body)
                qfrc_push = jacp.T @ self._push_force[:3] + jacr.T @ self._push_force[3:]
            out = []
            for k, b in enumerate(self.banks):
                dd = b.dadr
                tc, tp = -qfrc_contact[dd], -qfrc_push[dd]
                th = -b.tau_hand
                out.append(GroundTruth(t=self.t, tau_ext=tc + tp + th, tau_contact=tc, tau_push=tp,
                                       tau_hand=th,
                                       tau_limit=-qfrc_limit[dd], contact=k in touching,
                                       q=d.qpos[b.qadr].copy(), q_dot=d.qvel[dd].copy(),
                                       tau_motor=b.tau_act.copy(), tau_friction=b.tau_friction,
                                       tau_load=b.tau_load))
            return out
