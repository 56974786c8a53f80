"""Force feedback to the leader: contact hysteresis, freshness gate, ramp, per-joint clip, gripper EMA.

Sign convention (project-wide, docs/teleop.md): tau_ext [N*m] = tau_m - tau_free on the follower's joints
(the paper's eq., NEXT's output, the twin's GroundTruth.tau_ext): the torque the follower's joints exert
AGAINST the environment = minus the environment's torque on the follower. The leader gets
tau_fb = -K_f * tau_ext_leader with K_f >= 0, tau_ext_leader = tau_ext mapped onto the leader's joints
(mapping.JointMap.torque_back). So when the operator drives the follower into a wall, the wall pushes the
follower back, and the leader pushes back against the operator on the same joint (tests check it per
joint). The FACTR 2 code writes the same law with negative gains (tau_fb = gains * tau_ext, gains < 0).

Pure functions on numpy arrays; FeedbackGate keeps the few values that carry from tick to tick.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hardware.params import PerJoint, clamp, per_joint
from hardware.small_vec import abs_sum


@dataclass
class FeedbackConfig:
    """enabled: feedback on at all. gain: K_f per leader joint [leader N*m per follower N*m], >= 0.
    t_high_nm / t_low_nm: contact hysteresis on ||tau_ext||_1 over the follower joints [N*m].
    gate_on_contact: False feeds back without waiting for contact (position-position mode).
    max_age_s: an estimate older than this is stale [s] (FACTR 2 code: 0.2 s).
    ramp_in_s / ramp_out_s: time for the gate to go 0 -> 1 / 1 -> 0 [s] (linear, rate-independent).
    clip_nm: per-joint bound of the feedback torque [N*m].
    gripper_gain: leader trigger torque per follower gripper effort [N*m per N or N*m];
    gripper_ema_beta: EMA weight of the previous value (FACTR: 0.95); gripper_clip_nm [N*m]."""

    enabled: bool = True
    gain: PerJoint = 0.03
    t_high_nm: float = 1.0
    t_low_nm: float = 0.5
    gate_on_contact: bool = True
    max_age_s: float = 0.2
    ramp_in_s: float = 0.05
    ramp_out_s: float = 0.05
    clip_nm: PerJoint = 0.5
    gripper_gain: float = 0.0
    gripper_ema_beta: float = 0.95
    gripper_clip_nm: float = 0.3

    def validate(self, n: int, where: str = "feedback") -> None:
        from hardware.errors import ConfigError

        per_joint(self.gain, n, f"{where}.gain", nonneg=True)
        per_joint(self.clip_nm, n, f"{where}.clip_nm", nonneg=True)
        if not (0.0 <= self.t_low_nm <= self.t_high_nm):
            raise ConfigError(f"needs 0 <= t_low_nm <= t_high_nm, got {self.t_low_nm}, {self.t_high_nm}",
                              where=where, fix="set t_low_nm below t_high_nm")
        if not (self.max_age_s > 0 and self.ramp_in_s >= 0 and self.ramp_out_s >= 0):
            raise ConfigError("max_age_s must be > 0 and ramp times >= 0", where=where, fix="fix the values")
        if not 0.0 <= self.gripper_ema_beta < 1.0:
            raise ConfigError(f"gripper_ema_beta {self.gripper_ema_beta} not in [0, 1)", where=where,
                              fix="use e.g. 0.95")


# -- pure functions ---------------------------------------------------------------------------------
def contact_score(tau_ext: np.ndarray) -> float:
    """||tau_ext||_1 [N*m] over the follower joints (the paper's contact score f_t); NaN if any is NaN."""
    a = np.asarray(tau_ext, dtype=float)
    if a.ndim == 1 and a.shape[0] < 8:
        return abs_sum(a)  # the same sum without a numpy reduction (500 Hz)
    return float(np.abs(a).sum())


def contact_hysteresis(score: float, in_contact: bool, t_high: float, t_low: float) -> bool:
    """On when score >= t_high, off when score <= t_low, otherwise unchanged."""
    if score >= t_high:
        return True
    if score <= t_low:
        return False
    return in_contact


def estimate_fresh(now: float, t_est: float, max_age_s: float, fresh_flag: bool = True) -> bool:
    """The estimate may be fed back: flagged fresh and computed from data at most max_age_s old."""
    return bool(fresh_flag) and math.isfinite(t_est) and (now - t_est) <= max_age_s


def ramp_toward(gate: float, target: float, dt_s: float, ramp_in_s: float, ramp_out_s: float) -> float:
    """Move gate in [0, 1] linearly toward target: full scale in ramp_in_s going up, ramp_out_s going down."""
    dt = max(float(dt_s), 0.0) if math.isfinite(dt_s) else 0.0
    if target > gate:
        step = np.inf if ramp_in_s <= 0 else dt / ramp_in_s
        return float(min(target, gate + step))
    step = np.inf if ramp_out_s <= 0 else dt / ramp_out_s
    return float(max(target, gate - step))


def feedback_torque(tau_ext_leader: np.ndarray, gain: np.ndarray, gate: float,
                    clip_nm: np.ndarray) -> np.ndarray:
    """tau_fb = clip(-gate * K_f * tau_ext_leader, +-clip) [N*m] (see the module docstring for the sign)."""
    return clamp(-gate * gain * np.asarray(tau_ext_leader, dtype=float), -clip_nm, clip_nm)


def feedback_torque_floats(tau_ext_leader: list[float], gain: list[float], gate: float,
                           clip_nm: list[float]) -> list[float]:
    """feedback_torque on plain floats, bit for bit (the 500 Hz path; numpy's maximum / minimum written
    out as in hardware.small_vec.np_max)."""
    m = -gate
    # a value strictly inside +-clip is unclipped by numpy's maximum / minimum too; any other the whole way
    return [x if -c < (x := m * k * t) < c else _clip_one(x, c)
            for t, k, c in zip(tau_ext_leader, gain, clip_nm, strict=True)]


def _clip_one(x: float, c: float) -> float:
    """min(max(x, -c), c) as numpy's maximum / minimum give it (NaN wins, a tie gives the second operand)."""
    lo = -c
    x = x if (x > lo or x != x) else lo
    return x if (x < c or x != x) else c


def ema(prev: float, x: float, beta: float) -> float:
    """beta * prev + (1 - beta) * x; a NaN prev restarts from x, a NaN x keeps prev."""
    if not math.isfinite(x):
        return prev
    if not math.isfinite(prev):
        return float(x)
    return float(beta * prev + (1.0 - beta) * x)


# -- the small state that carries over ticks ----------------------------------------------------------
class FeedbackResult:
    """One tick's feedback: tau_fb [N*m] on the leader joints (tau_fb_floats: the same as floats; the array
    is made at its first read: the law sums the floats), gate 0..1, contact, fresh, message (set when
    feedback was turned off for a reason the operator should see), gripper_tau [N*m] on the leader trigger."""

    __slots__ = ("tau_fb_floats", "gate", "contact", "fresh", "message", "gripper_tau", "_tau_fb")

    def __init__(self, tau_fb, gate: float, contact: bool, fresh: bool, message: str | None,
                 gripper_tau: float):
        self.tau_fb_floats = tau_fb if type(tau_fb) is list else np.asarray(tau_fb, dtype=float).tolist()
        self.gate, self.contact, self.fresh, self.message = gate, contact, fresh, message
        self.gripper_tau = gripper_tau
        self._tau_fb = None

    @property
    def tau_fb(self) -> np.ndarray:
        if self._tau_fb is None:
            self._tau_fb = np.array(self.tau_fb_floats, dtype=float)
        return self._tau_fb


class FeedbackGate:
    """Contact hysteresis + freshness gate + ramp for one leader. step() once per loop tick."""

    def __init__(self, cfg: FeedbackConfig, n: int):
        cfg.validate(n)
        self.cfg, self.n = cfg, n
        self.gain = per_joint(cfg.gain, n, "feedback.gain", nonneg=True)
        self.clip = per_joint(cfg.clip_nm, n, "feedback.clip_nm", nonneg=True)
        self._clip_floats = self.clip.tolist()
        self.reset()

    def reset(self) -> None:
        self.gate = 0.0
        self.contact = False
        self.last_tau = np.zeros(self.n)  # last finite leader-mapped estimate, ramped out when stale
        self._last_floats = (None, [])  # (last_tau, its floats) when step() set it
        self._gain_floats = (None, [])  # (gain, its floats)
        self.gripper_effort_ema = float("nan")
        self.nan_events = 0  # ticks with a non-finite estimate
        self._nan_active = False
        self._t_prev = float("nan")

    def step(self, now: float, tau_ext_leader: np.ndarray | None, score_nm: float, t_est: float,
             fresh_flag: bool, gripper_effort: float = float("nan")) -> FeedbackResult:
        """tau_ext_leader: estimate mapped onto the leader joints [N*m] (None: no estimator);
        score_nm: ||tau_ext||_1 on the follower joints; t_est: time of the data it came from [s]."""
        cfg = self.cfg
        dt = now - self._t_prev if math.isfinite(self._t_prev) else 0.0
        self._t_prev = now
        message = None
        self.gripper_effort_ema = ema(self.gripper_effort_ema, gripper_effort, cfg.gripper_ema_beta)
        g_eff = self.gripper_effort_ema if math.isfinite(self.gripper_effort_ema) else 0.0
        gripper_tau = min(max(cfg.gripper_gain * g_eff, -cfg.gripper_clip_nm), cfg.gripper_clip_nm)
        if not cfg.enabled or tau_ext_leader is None:
            self.gate, self.contact = 0.0, False
            return FeedbackResult([0.0] * self.n, 0.0, False, False, None, gripper_tau)
        tau = np.asarray(tau_ext_leader, dtype=float)
        lf = self._last_floats
        if tau is lf[0]:  # the last read-only estimate again (the pair maps each once): its floats, finite
            tl = lf[1]
        else:
            tl = tau.tolist() if tau.shape == (self.n,) else None
        if (tl is None or not (math.isfinite(sum(tl)) or all(map(math.isfinite, tl)))
                or not math.isfinite(score_nm)):  # (a finite sum: every value finite)
            # No value to ramp out with: drop the feedback at once (falling torque is the safe direction).
            self.nan_events += 1
            if not self._nan_active:  # say it once per episode, not every tick
                bad = (np.flatnonzero(~np.isfinite(tau)).tolist() if tau.shape == (self.n,)
                       else f"shape {tau.shape}, expected ({self.n},)")
                message = f"feedback off: estimator returned non-finite torque (leader joints {bad})"
            self._nan_active = True
            self.gate, self.contact, self.last_tau = 0.0, False, np.zeros(self.n)
            return FeedbackResult([0.0] * self.n, 0.0, False, False, message, gripper_tau)
        if self._nan_active:
            self._nan_active = False
            message = "feedback estimate finite again (feedback ramps back in on contact)"
        fresh = estimate_fresh(now, t_est, cfg.max_age_s, fresh_flag)
        if fresh:
            self.last_tau = tau
            if tau is not lf[0]:  # its floats kept for the next ticks when nobody can change it
                self._last_floats = (None, []) if tau.flags.writeable else (tau, tl)
            self.contact = contact_hysteresis(score_nm, self.contact, cfg.t_high_nm, cfg.t_low_nm)
        target = 1.0 if fresh and (self.contact or not cfg.gate_on_contact) else 0.0
        self.gate = ramp_toward(self.gate, target, dt, cfg.ramp_in_s, cfg.ramp_out_s)
        lf = self._last_floats
        last = lf[1] if lf[0] is self.last_tau else self.last_tau.tolist()  # (set from outside: reset)
        gain = self._gain_floats if self._gain_floats[0] is self.gain else (self.gain, self.gain.tolist())
        self._gain_floats = gain  # the floats of the gain array (set from outside: set_rate, the UI's keys)
        tau_fb = feedback_torque_floats(last, gain[1], self.gate, self._clip_floats)
        return FeedbackResult(tau_fb, self.gate, self.contact, fresh, message, gripper_tau)
