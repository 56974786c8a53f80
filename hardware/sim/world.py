"""One MuJoCo world (a follower's scene, or a leader arm) with its motor banks, pushes and ground truth.

step() runs one control tick: every bank writes its motor torques (hardware/sim/mujoco_bank.py), then
`substeps` MuJoCo steps. ground_truth() separates what an estimator must find from what the drives do:
external joint torque from contacts (constraint rows of contact type only; joint-limit rows are reported
apart), pushes (xfrc_applied -> J^T F) and the operator's hand, in the paper's convention
tau_ext = tau_m - tau_free, i.e. the torque the joints exert against the environment.

Sampling. A stiff contact is a train of impacts a few physics steps long (a wrist pushed onto the table hops:
~4 ms pulses of 100-800 N every ~10 ms). One physics step's constraint force, read every 10 ms, aliases that
train into isolated spikes of tens of N*m; a drive, an F/T sensor's anti-alias filter and every estimator see
its mean. So every physics step's external torque is kept (GT_HISTORY_S; from the first averaged read on,
`keep_truth`, ~5 us per physics step), and ground_truth(average_s=T) returns the mean over the physics steps
of the last T seconds: a recorder sampling every T seconds passes T (the mean over its sample period, like an
integrating sensor); average_s=0 is the state now.
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass

import mujoco
import numpy as np

from hardware.sim import actuators as act
from hardware.sim.mujoco_bank import MujocoBank

_CONTACT_TYPES = (int(mujoco.mjtConstraint.mjCNSTR_CONTACT_FRICTIONLESS),
                  int(mujoco.mjtConstraint.mjCNSTR_CONTACT_PYRAMIDAL),
                  int(mujoco.mjtConstraint.mjCNSTR_CONTACT_ELLIPTIC))
_LIMIT_TYPES = (int(mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT), int(mujoco.mjtConstraint.mjCNSTR_LIMIT_TENDON))
_IS_CONTACT = np.isin(np.arange(64), _CONTACT_TYPES)  # constraint type -> is a contact row
_IS_LIMIT = np.isin(np.arange(64), _LIMIT_TYPES)
GT_HISTORY_S = 0.1  # s: physics steps of ground truth kept for ground_truth(average_s=...)


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
        # SIMULATED camera fault on this world's cameras (hardware/sim/faults.py): None, "freeze" (they show
        # the state the freeze began with) or "gone" (their renders fail, as an unplugged camera's reads do)
        self.camera_fault: str | None = None
        mujoco.mj_forward(model, self.data)
        # per physics step: (t, contact, limit, push [N*m, model dofs], hand per bank, banks touching); kept
        # from the first averaged read on (keep_truth), so a world nobody asks costs nothing extra per step
        self.keep_truth = False
        self._truth: deque = deque(maxlen=max(1, round(GT_HISTORY_S / float(model.opt.timestep))))

    @property
    def t(self) -> float:
        return float(self.data.time)

    def add_bank(self, joints: list[str], params: act.ActuatorParams, **kw) -> MujocoBank:
        bank = MujocoBank(self, joints, params, **kw)
        self.banks.append(bank)
        self._geom_bank = None
        self._truth.clear()  # entries carry one hand torque per bank
        return bank

    def set_substeps(self, k: int) -> None:
        """Run the firmware laws (and everything in Python) every k physics steps; MuJoCo integrates the
        implicit damping, friction slope, contacts and limits at every physics step in between."""
        self.substeps = max(1, int(k))
        self.dt = float(self.model.opt.timestep) * self.substeps
        for b in self.banks:
            b.set_control_dt(self.dt)

    def step(self) -> None:
        """One control tick: banks compute torques, then `substeps` physics steps (truth kept for each)."""
        with self.lock:
            t, dt = self.t, self.dt
            if self._push_until >= 0 and t >= self._push_until:
                self.data.xfrc_applied[self._push_body] = 0.0
                self._push_until = -1.0
            for b in self.banks:
                b._apply(t, dt)
            if self.keep_truth:
                hands = self._hands()  # the hand torques hold over the tick
                for _ in range(self.substeps):
                    mujoco.mj_step(self.model, self.data)
                    self._truth.append(self._instant_truth(hands))
            else:
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

    def _hands(self) -> tuple:
        return tuple(b.tau_hand.copy() if np.count_nonzero(b.tau_hand) else None for b in self.banks)

    def _instant_truth(self, hands: tuple | None = None) -> tuple:
        """This physics step's external joint torques (model dofs) from its constraint forces and push:
        (t, contact, limit, push, hand per bank, banks touching); None for a part that is zero (most steps,
        so the per-step cost stays small: MuJoCo's contact and limit counts first)."""
        m, d = self.model, self.data
        contact = limit = push = None
        touching: tuple = ()
        ncon = d.ncon
        gb = self._bank_of_geom() if ncon else None  # physics steps without contacts skip even this
        # a contact between two bodies no bank moves (an object resting on the table) loads no bank joint
        if ncon and np.count_nonzero(gb[d.contact.geom[:ncon]] >= 0):
            nefc = d.nefc
            is_contact, force = _IS_CONTACT[d.efc_type[:nefc]], d.efc_force[:nefc]
            contact = np.zeros(m.nv)
            mujoco.mj_mulJacTVec(m, d, contact, np.where(is_contact, force, 0.0))
            active = np.unique(d.efc_id[:nefc][is_contact & (np.abs(force) > 1e-9)])
            touching = tuple({int(k) for c in active
                              for k in (gb[d.contact.geom1[c]], gb[d.contact.geom2[c]]) if k >= 0})
        if d.nl:  # joint or tendon limit rows
            nefc = d.nefc
            limit = np.zeros(m.nv)
            mujoco.mj_mulJacTVec(m, d, limit, np.where(_IS_LIMIT[d.efc_type[:nefc]], d.efc_force[:nefc], 0.0))
        if self._push_until >= 0:
            jacp, jacr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
            mujoco.mj_jacBodyCom(m, d, jacp, jacr, self._push_body)
            push = jacp.T @ self._push_force[:3] + jacr.T @ self._push_force[3:]
        return (d.time, contact, limit, push, self._hands() if hands is None else hands, touching)

    def ground_truth(self, average_s: float = 0.0) -> list[GroundTruth]:
        """Ground truth per bank: the mean over the physics steps of the last average_s seconds (at least the
        state now; up to GT_HISTORY_S) of the external torques; q, q_dot and drive torques as of now. The
        first call with average_s > 0 starts the per-step history (keep_truth): read once before a run."""
        with self.lock:
            if average_s > 0 and not self.keep_truth:
                self.keep_truth = True
                self._truth.clear()
            t_from = self.t - average_s + 0.5 * float(self.model.opt.timestep)  # steps ending in (t - T, t]
            recent = [s for s in self._truth if s[0] > t_from] if average_s > 0 else []
            recent = recent or [self._instant_truth()]  # the state now (and a push or hand set since)
            nv = self.model.nv

            def mean(parts) -> np.ndarray:
                return sum((x for x in parts if x is not None), np.zeros(nv)) / len(recent)

            qfrc_contact, qfrc_limit, qfrc_push = (mean(s[k] for s in recent) for k in (1, 2, 3))
            touching = set().union(*(s[5] for s in recent))
            out = []
            for k, b in enumerate(self.banks):
                dd = b.dadr
                tc, tp = -qfrc_contact[dd], -qfrc_push[dd]
                th = -sum((s[4][k] for s in recent if s[4][k] is not None), np.zeros(b.n)) / len(recent)
                out.append(GroundTruth(t=self.t, tau_ext=tc + tp + th, tau_contact=tc, tau_push=tp,
                                       tau_hand=th,
                                       tau_limit=-qfrc_limit[dd], contact=k in touching,
                                       q=self.data.qpos[b.qadr].copy(), q_dot=self.data.qvel[dd].copy(),
                                       tau_motor=b.tau_act.copy(), tau_friction=b.tau_friction,
                                       tau_load=b.tau_load))
            return out
