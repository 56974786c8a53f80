"""External-torque estimators behind one protocol (the paper's comparison modes), below the app so that
teleop, rollout and labelling share them.

    est.update(inp) -> Estimate | None     a new estimate from this tick's data (None: nothing new yet)
    est.refresh(inp) -> Estimate | None    a control tick between two model samples (default: None)
    est.idle() -> None                     a tick without a sample: spread deferred work (default: nothing)
    est.period_s                           run update() at most this often [s] (0: every tick)

Modes (FEEDBACK_MODES):
  none          no estimator, no feedback (GELLO-style)
  dob           momentum disturbance observer on the follower model (MomentumObserver)
  pp            position-position: tau_ext ~ K (q_leader_mapped - q_follower) (PositionPositionEstimator)
  next          NEXT (calibration.next NextEstimator, via NextAdapter): its tau_m - tau_f_hat
  ground_truth  a twin's true contact torque (GroundTruthEstimator; simulated, label it so)
Estimates are calibration.estimate.Estimate (tau_ext [N*m] = tau_m - tau_free on the follower joints).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from calibration.baselines import momentum_observer_step_floats
from calibration.estimate import FLAG_OK, FLAG_UNCONVERGED, Estimate
from hardware.params import PerJoint, per_joint
from hardware.small_vec import all_finite
from hardware.types import JointState

FEEDBACK_MODES = ("none", "dob", "pp", "next", "ground_truth")
SIMULATED_ONLY_MODES = ("ground_truth",)
PP_STIFFNESS_NM_PER_RAD = 40.0  # position-position coupling stiffness (follower N*m per rad of lag)
DOB_GAIN_PER_S = 50.0  # momentum observer gain K_o [1/s]


@dataclass
class EstimatorInput:
    """t: loop time [s]; follower: latest follower state; q_leader_f: leader pose mapped onto the follower
    joints [rad]; q_target_f: the follower target sent last tick [rad] (None before the first)."""

    t: float
    follower: JointState
    q_leader_f: np.ndarray
    q_target_f: np.ndarray | None = None


class Estimator:
    """Base class: subclasses implement update(); refresh() and idle() are optional (no-op defaults)."""

    period_s: float = 0.0

    def update(self, inp: EstimatorInput) -> Estimate | None:
        raise NotImplementedError

    def refresh(self, inp: EstimatorInput) -> Estimate | None:
        return None

    def idle(self) -> None:
        return None

    def helper_processes(self) -> dict[int, int]:
        """Processes that work for this estimator now, pid -> SCHED_FIFO priority (hardware.realtime): the
        loop raises them and moves them off its CPU with its own threads while it runs real time."""
        return {}


class PositionPositionEstimator(Estimator):
    """Bilateral position-position coupling expressed as an external torque: when the follower lags the leader
    (blocked by a wall), its position loop pushes against the wall with about K * lag, which is tau_ext.
    Use with gate_on_contact=False."""

    def __init__(self, stiffness_nm_per_rad: PerJoint, n: int):
        self.k = per_joint(stiffness_nm_per_rad, n, "estimator.pp.stiffness_nm_per_rad", nonneg=True)

    def update(self, inp: EstimatorInput) -> Estimate:
        lag = np.asarray(inp.q_leader_f, dtype=float) - inp.follower.q
        return Estimate(tau_ext=self.k * lag, t=inp.follower.t)


class GroundTruthEstimator(Estimator):
    """A twin's true external torque: truth() -> tau_ext [N*m] (GroundTruth.tau_ext). Simulated only.
    n: keep the first n entries (the twin's bank appends the gripper after the arm joints)."""

    def __init__(self, truth: Callable[[], np.ndarray], n: int | None = None):
        self.truth, self.n = truth, n

    def update(self, inp: EstimatorInput) -> Estimate:
        tau = np.asarray(self.truth(), dtype=float).reshape(-1)
        return Estimate(tau_ext=tau if self.n is None else tau[: self.n], t=inp.follower.t)


def next_period_s(rate_hz: float | None, loop_period_s: float) -> float:
    """How often a loop runs NEXT [s]: the checkpoint's sample period, a quarter tick early (a model period
    that is a whole number of ticks must not slip by one tick); 0 (every tick) without a rate."""
    rate = float(rate_hz or 0.0)
    return max(0.0, 1.0 / rate - 0.25 * loop_period_s) if rate > 0 else 0.0


def refresh_with(tau_f: np.ndarray | None, follower: JointState) -> Estimate | None:
    """tau_ext = the follower's measured torque now - tau_f, the newest predicted free torque [N*m] (NEXT
    between its samples; NextAdapter and the worker's NextWorker); None without a usable tau_f or tau_m."""
    tau_m = np.asarray(follower.tau_m, dtype=float)
    if tau_f is None or tau_m.shape != tau_f.shape or not all_finite(tau_m):
        return None
    return Estimate(tau_ext=tau_m - tau_f, t=follower.t, tau_f=tau_f)


class NextAdapter(Estimator):
    """Drives calibration.next.estimator.NextEstimator from the loop at the checkpoint's rate (period_s). Its
    output is already tau_m - tau_f_hat. q_cmd: the follower's reported target (JointState.q_cmd) when it has
    one, else the target the loop sent last. Warm-up (no estimate yet) returns None, so feedback waits; a NaN
    estimate goes through (feedback off with a message); an out-of-range input (ood) is counted, not gated:
    in contact q_cmd - q leaves the free-motion training range by design. flags: the last estimate's flags."""

    def __init__(self, next_estimator, loop_period_s: float = 0.0):
        self.next = next_estimator
        ck = getattr(next_estimator, "ck", None)
        self.period_s = next_period_s(getattr(ck, "rate_hz", 0.0), loop_period_s)
        self.ood_count = 0
        self.flags = FLAG_OK
        self._tau_f: np.ndarray | None = None  # free-space torque of the last valid estimate [N*m]

    def update(self, inp: EstimatorInput) -> Estimate | None:
        st = inp.follower
        q_cmd = st.q_cmd
        if not np.all(np.isfinite(q_cmd)):
            q_cmd = inp.q_target_f if inp.q_target_f is not None else st.q
        e = self.next.update(st.q, st.q_dot, q_cmd, st.tau_m, temperature=st.temperature)
        self.flags = e.flags
        if e.warming_up:
            self._tau_f = None
            return None  # warming up (or restarting after a bad sample): no estimate yet
        self.ood_count += int(e.ood)
        self._tau_f = np.asarray(e.tau_f, dtype=float) if e.valid and e.tau_f is not None else None
        return Estimate(tau_ext=np.asarray(e.tau_ext, dtype=float), t=st.t, flags=e.flags, tau_f=self._tau_f)

    def refresh(self, inp: EstimatorInput) -> Estimate | None:
        """A control tick between two model samples: tau_ext = this tick's tau_m - the last predicted free
        torque. The free torque changes slowly; contact shows in tau_m at once, so feedback does not wait up
        to a model period (10 ms at 100 Hz) for it. None when there is no valid prediction to use."""
        return refresh_with(self._tau_f, inp.follower)

    def idle(self) -> None:
        """A control tick without a new sample: let a deferring estimator step some of its pending runs."""
        self.next.work()


class MomentumObserver(Estimator):
    """Disturbance-observer estimator on the follower's dynamics model (callables in the follower's joint
    frame): mass(q) -> M, coriolis(q, q_dot) -> C, gravity(q) -> g. k_o: observer gain [1/s] per joint.
    Uses the follower's measured motor torque tau_m (current x torque constant). Returns tau_ext = -r."""

    def __init__(self, mass: Callable, coriolis: Callable, gravity: Callable, k_o: PerJoint, n: int):
        self.mass, self.coriolis, self.gravity = mass, coriolis, gravity
        self.k_o = per_joint(k_o, n, "estimator.dob.k_o", positive=True)
        self.n = n
        self.reset()

    @classmethod
    def from_pinocchio(cls, model, k_o: PerJoint = 50.0, n: int | None = None) -> MomentumObserver:
        import pinocchio as pin

        n = n or model.nv
        data, q0 = model.createData(), pin.neutral(model)

        def full(q):
            qm = q0.copy()
            qm[:n] = q
            return qm

        def mass(q):
            M = pin.crba(model, data, full(q))
            M = np.triu(M) + np.triu(M, 1).T  # pinocchio fills the upper triangle
            return M[:n, :n]

        def coriolis(q, qd):
            v = np.zeros(model.nv)
            v[:n] = qd
            return pin.computeCoriolisMatrix(model, data, full(q), v)[:n, :n].copy()

        def gravity(q):
            return pin.computeGeneralizedGravity(model, data, full(q))[:n].copy()

        return cls(mass, coriolis, gravity, k_o, n)

    @classmethod
    def from_arm(cls, arm, k_o: PerJoint = 50.0) -> MomentumObserver:
        """On a hardware.arms description (name or ArmDescription) of the FOLLOWER, own pinocchio Data."""
        from hardware.arms.dynamics import ArmDynamics

        dyn = ArmDynamics(arm)
        return cls(dyn.mass_matrix, dyn.coriolis_matrix, dyn.gravity, k_o, dyn.n)

    def reset(self) -> None:
        self._integral = [0.0] * self.n  # the observer's state as floats (momentum_observer_step_floats)
        self._r = [0.0] * self.n
        self._p0: list[float] | None = None
        self._t_prev = float("nan")
        self._used = None  # the follower sample of the last update that passed its checks
        self._k_floats = self.k_o.tolist()
        self._tau_ext = self._negated()

    def _negated(self) -> np.ndarray:
        """tau_ext = -r [N*m], one read-only array per new sample: the ticks between follower samples hand
        out the same one (nothing writes an estimate in place; read-only makes sure)."""
        a = np.array([-x for x in self._r])
        a.setflags(write=False)
        return a

    def update(self, inp: EstimatorInput) -> Estimate | None:
        st = inp.follower
        if st is self._used:  # the sample the last update took (the ticks between follower samples): what
            # the checks below give it again (finite, dt = 0): the same estimate and data time
            return Estimate(self._tau_ext, self._t_prev)
        q, qd, tau_m = st.q, st.q_dot, st.tau_m
        if not (all_finite(q) and all_finite(qd) and all_finite(tau_m)):
            return None
        self._used = st if st.t == st.t else None  # (a NaN stamp goes the whole way, as before)
        if self._p0 is None:
            self._p0, self._t_prev = (self.mass(q) @ qd).tolist(), st.t
            return Estimate(tau_ext=self._tau_ext, t=st.t, flags=FLAG_UNCONVERGED)  # not converged yet
        dt = st.t - self._t_prev
        if dt <= 0:  # no new follower sample: same estimate, same data time (M(q) not needed)
            return Estimate(tau_ext=self._tau_ext, t=self._t_prev)
        self._t_prev = st.t
        # the products through numpy as before (the same BLAS calls on the same layouts: bit for bit), the
        # observer's element-wise step on floats
        p = (self.mass(q) @ qd).tolist()
        ctq = (self.coriolis(q, qd).T @ qd).tolist()
        self._integral, self._r = momentum_observer_step_floats(
            self._integral, self._r, p, self._p0, np.asarray(tau_m, dtype=float).tolist(),
            self.gravity(q).tolist(), ctq, dt, self._k_floats)
        self._tau_ext = self._negated()
        return Estimate(tau_ext=self._tau_ext, t=st.t)


def make_estimator(mode: str, n: int, *, follower_arm=None, dob_gain: PerJoint = DOB_GAIN_PER_S,
                   pp_stiffness_nm_per_rad: PerJoint = PP_STIFFNESS_NM_PER_RAD,
                   next_estimator=None, loop_period_s: float = 0.0,
                   truth: Callable[[], np.ndarray] | None = None) -> Estimator | None:
    """The estimator for a feedback mode (FEEDBACK_MODES); None for "none". ConfigError when the mode's
    ingredient is missing: follower_arm (hardware.arms name or ArmDescription, "dob"), next_estimator (a
    calibration.next NextEstimator, "next"; loop_period_s: the control period it runs in), truth (the twin's
    contact torque, "ground_truth")."""
    from hardware.errors import ConfigError

    need = {"dob": follower_arm, "pp": pp_stiffness_nm_per_rad, "next": next_estimator, "ground_truth": truth}
    if mode not in FEEDBACK_MODES:
        raise ConfigError(f"unknown feedback mode {mode!r}", where="teleop.feedback_mode",
                          fix=f"use one of {', '.join(FEEDBACK_MODES)}")
    if mode == "none":
        return None
    if need[mode] is None:
        what = {"dob": "the follower's dynamics model", "pp": "a position-position stiffness",
                "next": "a trained NEXT model",
                "ground_truth": "a twin (ground truth exists only in simulation)"}
        raise ConfigError(f"feedback mode {mode!r} needs {what[mode]}", where="teleop.feedback_mode",
                          fix="provide it, or pick another mode")
    if mode == "dob":
        return MomentumObserver.from_arm(follower_arm, k_o=dob_gain)
    if mode == "pp":
        return PositionPositionEstimator(pp_stiffness_nm_per_rad, n)
    if mode == "next":
        return NextAdapter(next_estimator, loop_period_s)
    return GroundTruthEstimator(truth, n)
