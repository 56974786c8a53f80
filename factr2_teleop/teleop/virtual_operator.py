"""A scripted 'hand' for twins: drives a simulated leader through a task with human-like compliance.

The hand does not set the leader's position: it applies a joint-space impedance torque toward a scripted
leader trajectory, tau_hand = K (q_ref - q) + D (qd_ref - q_dot), clipped to what a hand can push. So it FEELS
the feedback: when the leader pushes back, the leader lags the script and the hand pushes harder. The twin
applies tau_hand as an external torque on the leader's joints (VirtualOperator.torque is that input function)
and the operator logs what it pushed (the paper's user study measured the applied joint torque).

Script = segments, each a min-jerk move from the previous end pose to q_end [rad, leader joints] over
duration_s, optionally with a sinusoidal oscillation on top (free motion, wiping). make_task_script builds the
standard task: free motion, reach, contact (the target lies beyond the surface so the hand presses), wipe,
release. All of it is pure math; the only state is the log.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from hardware.params import PerJoint, per_joint
from hardware.types import STATUS_COMM_LOST, STATUS_STALE

PHASES = ("free", "reach", "contact", "wipe", "release")
_NOT_READ = STATUS_STALE | STATUS_COMM_LOST
_ENVELOPE_S = 0.3  # s: oscillations fade in/out over this so the reference stays smooth


@dataclass
class Segment:
    """phase: label logged with each sample; duration_s [s]; q_end [rad]; osc_amp_rad (per joint) and
    osc_hz [Hz]: oscillation added on top of the move (zero at both ends)."""

    phase: str
    duration_s: float
    q_end: np.ndarray
    osc_amp_rad: np.ndarray | None = None
    osc_hz: float = 0.5


@dataclass
class OperatorScript:
    q_start: np.ndarray
    segments: list[Segment] = field(default_factory=list)

    @property
    def duration_s(self) -> float:
        return float(sum(s.duration_s for s in self.segments))


def min_jerk(s: float) -> float:
    """Fraction of a min-jerk move done at normalised time s in [0, 1]."""
    s = float(np.clip(s, 0.0, 1.0))
    return s**3 * (10.0 - 15.0 * s + 6.0 * s * s)


def _position(t: float, script: OperatorScript) -> tuple[np.ndarray, str]:
    q0 = np.asarray(script.q_start, dtype=float)
    t_seg = 0.0
    for seg in script.segments:
        if t < t_seg + seg.duration_s or seg is script.segments[-1]:
            tau = float(np.clip(t - t_seg, 0.0, seg.duration_s))
            q = q0 + min_jerk(tau / seg.duration_s) * (np.asarray(seg.q_end, dtype=float) - q0)
            if seg.osc_amp_rad is not None:
                env = min(1.0, tau / _ENVELOPE_S, (seg.duration_s - tau) / _ENVELOPE_S)
                env = min_jerk(max(env, 0.0))
                q = q + env * np.asarray(seg.osc_amp_rad, dtype=float) * np.sin(2 * np.pi * seg.osc_hz * tau)
            return q, seg.phase
        q0 = np.asarray(seg.q_end, dtype=float)
        t_seg += seg.duration_s
    return q0, "done"


def scripted_target(t: float, script: OperatorScript, h: float = 1e-4) -> tuple[np.ndarray, np.ndarray, str]:
    """Reference leader pose q_ref [rad], velocity qd_ref [rad/s] (central difference) and phase at time t [s]
    since the script started."""
    q, phase = _position(t, script)
    qd = (_position(t + h, script)[0] - _position(max(t - h, 0.0), script)[0]) / (t + h - max(t - h, 0.0))
    return q, qd, phase


def hand_torque(q: np.ndarray, q_dot: np.ndarray, q_ref: np.ndarray, qd_ref: np.ndarray, k: np.ndarray,
                d: np.ndarray, tau_max: np.ndarray) -> np.ndarray:
    """Joint-space hand impedance [N*m], clipped per joint to what a hand can push."""
    tau = k * (q_ref - np.asarray(q, dtype=float)) + d * (qd_ref - np.asarray(q_dot, dtype=float))
    return np.clip(np.where(np.isfinite(tau), tau, 0.0), -tau_max, tau_max)


def make_task_script(q_home, q_above, q_press, wipe_amp_rad, free_amp_rad=None, *, free_s: float = 3.0,
                     reach_s: float = 2.0, contact_s: float = 1.5, wipe_s: float = 4.0,
                     release_s: float = 2.0,
                     wipe_hz: float = 0.5, free_hz: float = 0.3) -> OperatorScript:
    """The standard task (leader joints, rad): free motion around q_home, reach q_above, press toward q_press
    (put it beyond the surface: the hand keeps pushing while in contact), wipe around q_press, release to
    q_above then q_home."""
    home, above, press = (np.asarray(x, dtype=float) for x in (q_home, q_above, q_press))
    free_amp = np.full_like(home, 0.2) if free_amp_rad is None else np.asarray(free_amp_rad, dtype=float)
    return OperatorScript(q_start=home, segments=[
        Segment("free", free_s, home, free_amp, free_hz),
        Segment("reach", reach_s, above),
        Segment("contact", contact_s, press),
        Segment("wipe", wipe_s, press, np.asarray(wipe_amp_rad, dtype=float), wipe_hz),
        Segment("release", release_s * 0.5, above),
        Segment("release", release_s * 0.5, home),
    ])


@dataclass
class OperatorSample:
    t: float
    phase: str
    q_ref: np.ndarray
    q: np.ndarray
    tau_hand: np.ndarray  # N*m the hand applied to the leader joints
    press_nm: float  # tau_hand along the press direction (q_press - q_above, unit) [N*m]
    force_n: float  # Cartesian push into the surface [N] (NaN without a Jacobian)


class VirtualOperator:
    """torque(t, q, q_dot) -> tau_hand is the twin's hand input; every call is logged.

    stiffness [N*m/rad], damping [N*m*s/rad], tau_max_nm: per joint (a relaxed human wrist/arm on a small
    leader is about 2-5 N*m/rad). press_dir: joint-space direction of pressing (default from the script's
    contact segment). jacobian_fn(q) -> 6 x n and surface_normal (world, pointing out of the surface) give the
    Cartesian push force: F = pinv(J^T) tau_hand, push = -normal . F[:3]."""

    def __init__(self, script: OperatorScript, stiffness: PerJoint = 3.0, damping: PerJoint = 0.1,
                 tau_max_nm: PerJoint = 2.0, press_dir: np.ndarray | None = None,
                 jacobian_fn: Callable[[np.ndarray], np.ndarray] | None = None,
                 surface_normal: np.ndarray | None = None, t0: float = 0.0, defer_force: bool = False):
        n = len(script.q_start)
        self.script, self.n, self.t0 = script, n, float(t0)
        self.k = per_joint(stiffness, n, "virtual_operator.stiffness", nonneg=True)
        self.d = per_joint(damping, n, "virtual_operator.damping", nonneg=True)
        self.tau_max = per_joint(tau_max_nm, n, "virtual_operator.tau_max_nm", nonneg=True)
        if press_dir is None:
            press_dir = _press_direction(script)
        u = np.asarray(press_dir, dtype=float)
        self.press_dir = u / np.linalg.norm(u) if np.linalg.norm(u) > 0 else u
        self.jacobian_fn, self.normal = jacobian_fn, surface_normal
        self.defer_force = defer_force  # True: force_n is computed in arrays() (batched), not per tick
        self.log: list[OperatorSample] = []
        self._paused_at: float | None = None  # while the follower is on hold: when the task stopped [s]

    def pause(self, t: float) -> None:
        """The follower went on hold at t [s]: a person stops the task and holds the leader where it is
        (phase "hold"), rather than carry on the script and leave the follower behind."""
        if self._paused_at is None:
            self._paused_at = float(t)

    def resume(self, t: float) -> None:
        """The pair tracks again at t [s]: the task goes on from where it stopped."""
        if self._paused_at is not None:
            self.t0 += float(t) - self._paused_at
            self._paused_at = None

    def reference(self, t: float, goal: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, str]:
        """Where the hand wants the leader at t [s]: q_ref [rad], qd_ref [rad/s], phase (see torque)."""
        if goal is not None:
            return np.asarray(goal, dtype=float), np.zeros(self.n), "return"
        if self._paused_at is not None:
            return _position(self._paused_at - self.t0, self.script)[0], np.zeros(self.n), "hold"
        return scripted_target(t - self.t0, self.script)

    def torque(self, t: float, q: np.ndarray, q_dot: np.ndarray, goal: np.ndarray | None = None
               ) -> np.ndarray:
        """The hand's torque [N*m] at t [s] on the leader at q [rad], q_dot [rad/s]. Paused: toward where the
        task stopped, or toward `goal` [rad, leader joints] when given (phase "return": after a refused
        resume a person brings the leader back to the held follower's pose)."""
        q_ref, qd_ref, phase = self.reference(t, goal)
        tau = hand_torque(q, q_dot, q_ref, qd_ref, self.k, self.d, self.tau_max)
        force = float("nan")
        if self.jacobian_fn is not None and self.normal is not None and not self.defer_force:
            J = np.asarray(self.jacobian_fn(np.asarray(q, dtype=float)), dtype=float)
            F = np.linalg.pinv(J.T) @ tau
            force = -float(np.dot(np.asarray(self.normal, dtype=float), F[:3]))
        self.log.append(OperatorSample(t, phase, q_ref, np.asarray(q, dtype=float).copy(), tau,
                                       float(np.dot(tau, self.press_dir)), force))
        return tau

    def done(self, t: float) -> bool:
        return t - self.t0 >= self.script.duration_s

    def arrays(self) -> dict[str, np.ndarray]:
        """The log as arrays: t, phase (str), q_ref, q, tau_hand, press_nm, force_n."""
        L = self.log
        out = {"t": np.array([s.t for s in L]), "phase": np.array([s.phase for s in L]),
               "q_ref": np.array([s.q_ref for s in L]), "q": np.array([s.q for s in L]),
               "tau_hand": np.array([s.tau_hand for s in L]), "press_nm": np.array([s.press_nm for s in L]),
               "force_n": np.array([s.force_n for s in L])}
        if self.defer_force and L and self.jacobian_fn is not None and self.normal is not None:
            if not hasattr(self, "_force_cache") or len(self._force_cache) != len(L):
                Jt = np.array([np.asarray(self.jacobian_fn(q), dtype=float).T for q in out["q"]])
                F = np.einsum("tij,tj->ti", np.linalg.pinv(Jt), out["tau_hand"])  # batched pinv(J^T) tau
                self._force_cache = -(F[:, :3] @ np.asarray(self.normal, dtype=float))
            out["force_n"] = self._force_cache
        return out

    def summary(self) -> dict[str, dict[str, float]]:
        """Per phase: mean ||tau_hand||_1 [N*m] (the user study's 'applied joint torque'), mean press [N*m],
        mean push force [N] and mean tracking error ||q_ref - q||_2 [rad]."""
        a = self.arrays()
        out = {}
        for ph in dict.fromkeys(a["phase"].tolist()):
            m = a["phase"] == ph
            out[ph] = {"tau_l1_nm": float(np.mean(np.sum(np.abs(a["tau_hand"][m]), axis=1))),
                       "press_nm": float(np.mean(a["press_nm"][m])),
                       "force_n": float(np.mean(a["force_n"][m])),
                       "track_err_rad": float(np.mean(np.linalg.norm(a["q_ref"][m] - a["q"][m], axis=1)))}
        return out


def _press_direction(script: OperatorScript) -> np.ndarray:
    prev = np.asarray(script.q_start, dtype=float)
    for seg in script.segments:
        if seg.phase == "contact":
            return np.asarray(seg.q_end, dtype=float) - prev
        prev = np.asarray(seg.q_end, dtype=float)
    return np.zeros(len(script.q_start))


def felt_joints(state, bank) -> tuple[np.ndarray, np.ndarray]:
    """The leader's joints as a simulated hand on it feels them ([rad], [rad/s], NaN velocity as 0): the app's
    reading where it is fresh (the arm to an encoder tick and one loop tick: every lockstep result stays as
    it was), the twin's true joints (bank.true_state(), SIMULATED) where the driver holds a stale sample. A
    Dynamixel chain that stops answering freezes the reading, not the arm: a hand impedance on the frozen
    reading pushed at its clip for the whole gap and flung the leader 1-3 rad (re-coupling was refused)."""
    q, qd = np.asarray(state.q, float), np.nan_to_num(np.asarray(state.q_dot, float))
    stale = (np.asarray(state.status, np.uint32) & np.uint32(_NOT_READ)) != 0
    if not stale.any():
        return q, qd
    q_true, qd_true = bank.true_state()
    n = len(q)
    return np.where(stale, q_true[:n], q), np.where(stale, qd_true[:n], qd)
