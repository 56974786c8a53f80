"""Collect NEXT's free-motion data on a rig: move to the start pose, replay a coverage trajectory, record.

    run = collect_free_motion(session, "follower", trajectory, progress=callback)
    save_plain_log("free.npz", **run.arrays())

The follower is commanded through its driver (and so through the safety layer) at the trajectory's rate;
every tick the state is read back and logged (t, q, qd, q_cmd, tau_m, current, and the motor temperature
when the driver reports one: the identified prior corrects the torque constant's drift with it). On a twin
the simulated ground truth (tau_ext_true, contact) is logged too and marked simulated in the log.

Unexpected contact guard: a generalised-momentum observer on the arm description (calibration.baselines,
K_o = 50/s) estimates the external torque from measured q, qd and tau_m; when |r_j| exceeds `contact_frac` x
tau_max_j for `contact_ticks` ticks in a row the follower is put on hold and the run stops (ContactStop). It
is a coarse guard against hitting something, not a force estimate: unmodelled friction sits below the
threshold. Why an observer and not tau_m - RNEA(q, qd, qdd_ref): with the trajectory's acceleration the
residual also holds M (qdd - qdd_ref), and in the fast phase the firmware loop lags (0.24 rad on the Piper
twin) -- the twin's 10-minute replay was stopped at 448 s by a false alarm with no contact in its ground
truth. The observer needs no acceleration.
ContactStop carries what was recorded before the stop (`err.run`), so a long run is not lost to a late graze.

Scripted pushes (twins only, for contact evaluation with ground truth): `pushes=[Push(t_s, link, force_n,
duration_s), ...]` applies each world-frame force through the twin at t_s into the recorded part; the guard
is off in such a run (the contact is intended), and a sample counts as contact while a push or a touch acts.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from enum import Enum

import numpy as np

from calibration.baselines import momentum_observer_step
from calibration.trajectories import Trajectory, ruckig_move
from hardware.errors import DeviceError
from hardware.reasons import Reason, messages
from hardware.types import FollowerCommand


class CollectStop(Enum):
    """Why a free-motion collection stopped early (hardware.reasons)."""

    CONTACT = "contact"  # the contact guard tripped (detail, once the data before it is kept: what, kept_min)
    OPERATOR = "operator"  # the progress callback asked to stop


def _contact_message(what: str = "", kept_min: float | None = None) -> str:
    return "contact" if kept_min is None else f"contact: {what}; kept the {kept_min:.1f} min before it"


messages({CollectStop.CONTACT: _contact_message, CollectStop.OPERATOR: "operator"})


class ContactStop(DeviceError):
    """The arm met something during free-motion calibration; it is holding position. `run`: the data
    recorded before the stop (CollectedRun), or None."""

    run = None


@dataclass
class Push:
    """A scripted push on a twin: world-frame force [N] on `link`'s centre of mass from t_s for duration_s."""

    t_s: float
    link: str
    force_n: tuple[float, float, float]
    duration_s: float


@dataclass
class CollectedRun:
    t: list = field(default_factory=list)
    q: list = field(default_factory=list)
    qd: list = field(default_factory=list)
    q_cmd: list = field(default_factory=list)
    tau_m: list = field(default_factory=list)
    current: list = field(default_factory=list)
    temperature: list = field(default_factory=list)  # [degC] per joint (NaN where not reported)
    tau_ext_true: list = field(default_factory=list)
    contact: list = field(default_factory=list)
    joint_names: list[str] = field(default_factory=list)
    arm: str = ""  # the arm description's name and SHA-256: a log says which arm it comes from
    arm_sha256: str = ""
    stopped: Reason | None = None  # a CollectStop reason when the collection stopped early
    wall_s: float = 0.0

    def arrays(self) -> dict[str, np.ndarray]:
        """Keyword arrays for hardware.recording.plain_log.save_plain_log."""
        out = {k: np.asarray(getattr(self, k), float) for k in ("t", "q", "qd", "q_cmd", "tau_m", "current")}
        temp = np.asarray(self.temperature, float)
        if temp.shape == out["q"].shape and np.all(np.isfinite(temp)):  # only a complete temperature log
            out["temperature"] = temp
        if self.tau_ext_true:
            out["tau_ext_true"] = np.asarray(self.tau_ext_true, float)
            out["contact"] = np.asarray(self.contact, bool)
            out["simulated_ground_truth"] = np.array(True)
        out["joint_names"] = np.array(self.joint_names)
        if self.arm:
            out["arm"], out["arm_sha256"] = np.array(self.arm), np.array(self.arm_sha256)
        return out


class _ContactGuard:
    """Streaming momentum observer -> estimated external torque [N*m] per tick (thin shell around
    calibration.baselines.momentum_observer_step on hardware.arms.dynamics.ArmDynamics)."""

    def __init__(self, dyn, q0: np.ndarray, qd0: np.ndarray, dt_s: float, k_o: float = 50.0):
        self.dyn, self.dt = dyn, dt_s
        self.k_o = np.full(dyn.n, k_o)
        self.p0 = dyn.mass_matrix(q0) @ qd0
        self.integral, self.r = np.zeros(dyn.n), np.zeros(dyn.n)

    def step(self, q, qd, tau_m) -> np.ndarray:
        q, qd, tau_m = (np.asarray(a, float) for a in (q, qd, tau_m))
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(qd)) and np.all(np.isfinite(tau_m))):
            return np.full(self.dyn.n, np.nan)
        beta = self.dyn.gravity(q) - self.dyn.coriolis_matrix(q, qd).T @ qd
        self.integral, self.r = momentum_observer_step(self.integral, self.r, self.dyn.mass_matrix(q) @ qd,
                                                       self.p0, tau_m, beta, self.dt, self.k_o)
        return -self.r


def residual_exceeds(r: np.ndarray, tau_max: np.ndarray, frac: float) -> bool:
    """True when any joint's rigid-body residual [N*m] is above frac x its torque limit."""
    return bool(np.any(np.abs(r) > frac * tau_max))


def collect_free_motion(session, follower_name: str, traj: Trajectory, *, move_speed: float = 0.3,
                        contact_frac: float = 0.3, contact_ticks: int = 5,
                        progress: Callable[[float, float], bool | None] | None = None,
                        pushes: list[Push] | None = None, recorder=None) -> CollectedRun:
    """Replay `traj` on the session's follower (RigSession of hardware.connect.open_rig). progress(done_s,
    total_s) is called every tick; returning True stops the run (operator stop). Raises ContactStop (with
    the partial run attached) unless `pushes` are given (twin only; guard off). recorder: a
    hardware.recording Recorder; every recorded sample also goes to it, under the follower's name (its joint
    state with q_cmd = the target sent, and the twin's ground truth), as teleop records."""
    from hardware.arms import load_arm
    from hardware.arms.dynamics import ArmDynamics

    spec = session.rig.device(follower_name)
    arm = load_arm(spec.arm)
    if list(arm.joint_names) != list(traj.joint_names):
        raise DeviceError(f"trajectory joints {traj.joint_names} are not the arm's {list(arm.joint_names)}",
                          where=follower_name, fix="generate the trajectory for this arm")
    follower = session.followers[follower_name]
    limits = spec.limits()
    clock, dt = session.clock, 1.0 / traj.rate_hz
    run = CollectedRun(joint_names=list(arm.joint_names), arm=arm.name, arm_sha256=arm.sha256)
    truth = session.twin.device_ground_truth if session.twin is not None else None
    if pushes and session.twin is None:
        raise DeviceError("scripted pushes need a simulated rig", where=follower_name, fix="use a sim-* rig")
    todo = sorted(pushes or [], key=lambda p: p.t_s)
    if truth is not None:
        truth(follower_name, average_s=dt)  # starts the twin's per-step history: every sample gets its mean

    st = follower.read()
    s = move_speed
    q0, _, _ = ruckig_move(st.q, traj.q[0], s * limits.v_max, 2 * s * limits.v_max, 20 * s * limits.v_max,
                           traj.rate_hz)
    plan = [(q, False) for q in q0] + [(traj.q[k], True) for k in range(len(traj.t))]
    over = 0
    guard = _ContactGuard(ArmDynamics(arm), st.q, st.q_dot, dt)
    t_start = time.monotonic()
    n_move = len(q0)
    for k, (q_ref, record) in enumerate(plan):
        while todo and record and (k - n_move) * dt >= todo[0].t_s:
            p = todo.pop(0)
            session.twin.push(p.link, np.asarray(p.force_n, float), p.duration_s, follower_name)
        follower.command(FollowerCommand(q=q_ref))
        clock.sleep(dt)
        st = follower.read()
        r = guard.step(st.q, st.q_dot, st.tau_m)
        over = over + 1 if np.all(np.isfinite(r)) and residual_exceeds(r, limits.tau_max, contact_frac) else 0
        if over >= contact_ticks and not pushes:
            follower.hold("unexpected contact during calibration")
            run.stopped = Reason.of(CollectStop.CONTACT)
            run.wall_s = time.monotonic() - t_start
            err = ContactStop(f"unexpected contact at t={k * dt:.1f} s (residual {np.abs(r).max():.1f} N*m)",
                              where=follower_name, fix="clear the workspace (or lower the speed) and rerun")
            err.run = run
            raise err
        if record:
            run.t.append(st.t)
            run.q.append(st.q)
            run.qd.append(st.q_dot)
            run.q_cmd.append(q_ref)  # what was sent (the device's own q_cmd may lag a tick)
            run.tau_m.append(st.tau_m)
            run.current.append(st.current)
            run.temperature.append(np.asarray(st.temperature, float)[: arm.n_joints])
            if truth is not None:
                gt = truth(follower_name, average_s=dt)  # the mean over this sample period
                run.tau_ext_true.append(np.asarray(gt.tau_ext)[: arm.n_joints])
                run.contact.append(bool(gt.contact) or bool(np.any(np.asarray(gt.tau_push) != 0.0)))
            if recorder is not None:
                recorder.log_joint_state(follower_name, st.t, replace(st, q_cmd=np.asarray(q_ref, float)))
                if truth is not None:
                    recorder.log_ground_truth(follower_name, st.t, run.tau_ext_true[-1], run.contact[-1])
        if progress is not None and progress((k + 1) * dt, len(plan) * dt):
            follower.hold("operator stop")
            run.stopped = Reason.of(CollectStop.OPERATOR)
            break
    run.wall_s = time.monotonic() - t_start
    return run
