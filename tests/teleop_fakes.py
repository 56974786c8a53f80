"""In-test Leader/Follower over hardware.sim.motors.IdealMotorBank (tests only; never a shipped fallback)."""

from __future__ import annotations

import numpy as np

from factr2_teleop.teleop.pair import ArmPair, PairConfig
from hardware.clock import LockstepClock
from hardware.roles import Follower, Leader
from hardware.sim.motors import IdealMotorBank
from hardware.types import STATUS_ENABLED, JointLimits, JointState

N = 3


def limits(n: int = N, tau_max: float = 5.0) -> JointLimits:
    return JointLimits(q_min=np.full(n, -2.0), q_max=np.full(n, 2.0), v_max=np.full(n, 10.0),
                       tau_max=np.full(n, tau_max), tau_rate_max=np.full(n, 1e4))


class _BankDevice:
    def _init_bank(self, bank: IdealMotorBank):
        self.bank, self.silent, self._conn = bank, False, False
        self.sent: list = []  # every Safe* the wire saw

    def connect(self) -> None:
        self._conn = True

    def _disconnect_bus(self) -> None:
        self._conn = False

    @property
    def is_connected(self) -> bool:
        return self._conn

    def _read(self) -> JointState | None:
        if self.silent:  # a device that stopped answering
            return None
        r = self.bank.read()
        n = self.bank.n
        return JointState(t=r.t, q=r.q, q_dot=r.q_dot, tau_m=r.tau_m, current=r.current,
                          q_cmd=np.full(n, np.nan),
                          temperature=r.temperature, status=np.full(n, STATUS_ENABLED, dtype=np.uint32),
                          gripper_pos=0.5, gripper_effort=0.0)


class BankLeader(_BankDevice, Leader):
    def __init__(self, bank: IdealMotorBank, clock, lim: JointLimits | None = None):
        Leader.__init__(self, "leader", lim or limits(bank.n), clock)
        self._init_bank(bank)

    def _send_torque_safe(self, safe) -> None:
        self.sent.append(safe)
        self.bank.command_current(np.arange(self.bank.n), safe.tau / self.bank.torque_constant)


class BankFollower(_BankDevice, Follower):
    def __init__(self, bank: IdealMotorBank, clock, lim: JointLimits | None = None):
        Follower.__init__(self, "follower", lim or limits(bank.n), clock)
        self._init_bank(bank)

    def _send_safe(self, safe) -> None:
        self.sent.append(safe)
        self.bank.command_position(np.arange(self.bank.n), safe.q)


class Rig:
    """Lockstep clock + leader bank + follower bank (+ an optional wall on the follower)."""

    def __init__(self, n: int = N, q_leader=None, q_follower=None, dt: float = 1e-3):
        self.clock = LockstepClock()
        self.lb = IdealMotorBank(n, dt_s=dt, q0=q_leader, damping=0.05)
        self.fb = IdealMotorBank(n, dt_s=dt, q0=q_follower, kp_fw=200.0, kd_fw=3.0, inertia=0.01)
        self.leader, self.follower = BankLeader(self.lb, self.clock), BankFollower(self.fb, self.clock)
        self.leader.connect()
        self.follower.connect()
        self.hand = None  # callable(t, q, q_dot) -> tau on the leader joints
        self.wall = None  # (joint, q_wall, direction +1/-1, stiffness N*m/rad) on the follower
        self.clock.attach(self._advance)

    def follower_env_torque(self) -> np.ndarray:
        tau = np.zeros(self.fb.n)
        if self.wall is not None:
            j, q_wall, direction, k = self.wall
            pen = direction * (self.fb.q[j] - q_wall)
            if pen > 0:
                tau[j] = -direction * k * pen
        return tau

    def follower_tau_ext(self) -> np.ndarray:
        """Ground truth in the project convention: tau_ext = tau_m - tau_free = -(environment on follower)."""
        return -self.follower_env_torque()

    def _advance(self, t: float) -> None:
        while self.lb.t + 0.5 * self.lb.dt_s < t:
            self.fb.tau_external = self.follower_env_torque()
            if self.hand is not None:
                self.lb.tau_external = self.hand(self.lb.t, self.lb.q, self.lb.q_dot)
            t_next = self.lb.t + self.lb.dt_s
            self.lb.advance(t_next)
            self.fb.advance(t_next)

    def pair(self, cfg: PairConfig | None = None, estimator=None, rate_hz: float = 500.0, **kw) -> ArmPair:
        return ArmPair(self.leader, self.follower, cfg or no_model_cfg(), 1.0 / rate_hz, estimator=estimator,
                       **kw)


def no_model_cfg(**kw) -> PairConfig:
    """Pair config without a gravity model (the ideal banks have no gravity) and without dither."""
    cfg = PairConfig(**kw)
    cfg.law.gravity.enabled = False
    cfg.law.friction.mode = "off"
    return cfg
