"""The safety layer: every command to a motor passes here, and only its output types reach a wire.

Pure functions (limit_position_target, limit_torque, limit_gains) do the math on numpy arrays;
SafetyLayer is the stateful shell (previous safe command, watchdog, counters). Drivers accept only
SafeFollowerCommand / SafeLeaderTorque, which nothing outside this module can construct, so there is no
path from a loop to a motor that skips the limits (tests/test_safety.py checks that, hypothesis tries to
break the limits).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

import numpy as np

from hardware.reasons import Reason, messages
from hardware.small_vec import all_finite
from hardware.types import FollowerCommand, JointLimits

DEFAULT_WATCHDOG_S = 0.05  # s: commands or feedback older than this put the device in its safe state
MAX_RATE_DT_S = DEFAULT_WATCHDOG_S  # s: a pause longer than this does not buy a larger target step
HOLD_KD = 1.0  # N*m*s/rad: damping gain of the safe state for impedance (MIT) followers
# an encoder sample further than PLAUSIBLE_JUMP_RAD + PLAUSIBLE_SPEED_RAD_S * dt from the last accepted one
# is a glitch, not motion: no arm here moves a joint faster than 20 rad/s (Piper 3 rad/s, XL330 leader
# servos ~10 rad/s unloaded); 0.2 rad covers noise and quantisation with a wide margin
PLAUSIBLE_SPEED_RAD_S = 20.0
PLAUSIBLE_JUMP_RAD = 0.2
_TOKEN = object()  # only this module can build Safe* values


class DeviceHold(Enum):
    """Why the shared device code put a device in its safe state (hardware.reasons)."""

    NO_COMMAND = "no command"  # the watchdog: the last command is older than its timeout
    NO_FEEDBACK = "no feedback"  # the watchdog: the last feedback is older than its timeout
    WATCHDOG = "watchdog"  # the device went safe on one of the two above (detail: stale)
    DISCONNECT = "disconnect"


messages({
    DeviceHold.NO_COMMAND: "no command for {ms:.0f} ms",
    DeviceHold.NO_FEEDBACK: "no feedback for {ms:.0f} ms",
    DeviceHold.WATCHDOG: "watchdog: {stale}",
    DeviceHold.DISCONNECT: "disconnect",
})


def limit_position_target(q_target: np.ndarray, q_prev: np.ndarray, dt_s: float,
                          lim: JointLimits) -> tuple[np.ndarray, int]:
    """Position target inside [q_min, q_max], moving at most v_max*dt from q_prev [rad].

    Non-finite entries keep q_prev (the joint holds). q_prev must be finite and inside the limits.
    Returns (safe target, number of joints that were changed).
    """
    raw = np.asarray(q_target, dtype=float)
    out, c = limit_position_floats(raw.tolist(), np.asarray(q_prev, dtype=float).tolist(), _rate_dt(dt_s),
                                   lim.v_max.tolist(), lim.q_min.tolist(), lim.q_max.tolist())
    return np.array(out), c


def implausible_jump(q: np.ndarray, q_prev: np.ndarray, dt_s) -> np.ndarray:
    """Per joint: True where q [rad] lies further from q_prev (the last accepted sample) than the joint can
    move in dt_s [s, scalar or per joint]. Non-finite values are never implausible (other checks see them)."""
    step = PLAUSIBLE_JUMP_RAD + PLAUSIBLE_SPEED_RAD_S * np.maximum(dt_s, 0.0)
    with np.errstate(invalid="ignore"):
        return np.abs(np.asarray(q, dtype=float) - q_prev) > step


def _rate_dt(dt_s: float) -> float:
    """dt [s] for rate limits: non-finite or negative -> 0, capped at MAX_RATE_DT_S."""
    return min(max(dt_s, 0.0), MAX_RATE_DT_S) if math.isfinite(dt_s) else 0.0


def limit_torque(tau: np.ndarray, tau_prev: np.ndarray, dt_s: float,
                 lim: JointLimits) -> tuple[np.ndarray, int]:
    """Torque [N*m] within +-tau_max whose magnitude grows at most tau_rate_max*dt per call.

    Falling towards zero is never slowed (zero torque is the safe direction). Non-finite entries become 0.
    Returns (safe torque, number of joints changed).
    """
    raw = np.asarray(tau, dtype=float)
    out, c = limit_torque_floats(raw.tolist(), np.asarray(tau_prev, dtype=float).tolist(), _rate_dt(dt_s),
                                 lim.tau_rate_max.tolist(), lim.tau_max.tolist())
    return np.array(out), c


def limit_torque_floats(raw: list[float], tau_prev: list[float], r_dt: float, rate: list[float],
                        tau_max: list[float]) -> tuple[list[float], int]:
    """limit_torque's math on plain floats (the 500 Hz path: the ~15 numpy calls it took on 6 values cost
    more than this loop), bit for bit the numpy form lo = max(min(prev - r, min(prev, 0)), -tau_max),
    hi = min(max(prev + r, max(prev, 0)), tau_max), out = min(max(tau, lo), hi) (tests/test_safety_floats.py):
    numpy's maximum/minimum written out (NaN wins, a tie gives the second operand: small_vec.np_max).
    raw [N*m] as given (a non-finite entry becomes 0), tau_prev [N*m], r_dt: _rate_dt(dt) [s],
    rate: tau_rate_max [N*m/s], tau_max [N*m].
    Returns (safe torque, number of joints changed)."""
    out: list[float] = []
    append = out.append
    changed = 0
    for x0, p, rr, m in zip(raw, tau_prev, rate, tau_max, strict=True):
        r = rr * r_dt
        if p - r < x0 < p + r and -m < x0 < m:
            # the usual joint: strictly inside its slew and its +-tau_max (so every value here is finite):
            # lo below and hi above it by numpy's maximum / minimum too, the torque passes unchanged
            append(x0)
            continue
        x = x0 if math.isfinite(x0) else 0.0
        a, b = p - r, (p if (p < 0.0 or p != p) else 0.0)
        lo = a if (a < b or a != a) else b
        nm = -m
        lo = lo if (lo > nm or lo != lo) else nm
        a, b = p + r, (p if (p > 0.0 or p != p) else 0.0)
        hi = a if (a > b or a != a) else b
        hi = hi if (hi < m or hi != hi) else m
        y = x if (x > lo or x != x) else lo
        y = y if (y < hi or y != y) else hi
        append(y)
        changed += y != x0
    return out, changed


def limit_position_floats(raw: list[float], q_prev: list[float], r_dt: float, v_max: list[float],
                          q_min: list[float], q_max: list[float]) -> tuple[list[float], int]:
    """limit_position_target's math on plain floats, bit for bit the numpy form lo = max(prev - step, q_min),
    hi = min(prev + step, q_max), out = min(max(q, lo), hi) (as limit_torque_floats): a non-finite target
    keeps q_prev [rad] (q_prev is inside the limits, so lo <= hi); r_dt: _rate_dt(dt) [s]; v_max [rad/s].
    Returns (safe target, joints changed)."""
    out: list[float] = []
    append = out.append
    changed = 0
    for x0, p, v, qa, qb in zip(raw, q_prev, v_max, q_min, q_max, strict=True):
        step = v * r_dt
        lo, hi = p - step, p + step
        if lo < x0 < hi and qa < x0 < qb:  # the usual joint: strictly inside its step and its limits
            append(x0)
            continue
        x = x0 if math.isfinite(x0) else p
        lo = lo if (lo > qa or lo != lo) else qa
        hi = hi if (hi < qb or hi != hi) else qb
        y = x if (x > lo or x != x) else lo
        y = y if (y < hi or y != y) else hi
        append(y)
        changed += y != x0
    return out, changed


def limit_gains(kp: np.ndarray, kd: np.ndarray, lim: JointLimits) -> tuple[np.ndarray, np.ndarray, int]:
    """Impedance gains in [0, kp_max] / [0, kd_max]; non-finite kp -> 0 (no stiffness), kd -> HOLD_KD."""
    kp_raw, kd_raw = np.asarray(kp, dtype=float), np.asarray(kd, dtype=float)
    kp_o = np.clip(np.where(np.isfinite(kp_raw), kp_raw, 0.0), 0.0, lim.kp_max)
    kd_o = np.clip(np.where(np.isfinite(kd_raw), kd_raw, HOLD_KD), 0.0, lim.kd_max)
    changed = int(np.count_nonzero(kp_o != kp_raw) + np.count_nonzero(kd_o != kd_raw))
    return kp_o, kd_o, changed


def safe_start_target(q_meas: np.ndarray, lim: JointLimits) -> np.ndarray:
    """A finite target inside the limits near the measured position (where holding starts) [rad]."""
    q = np.asarray(q_meas, dtype=float)
    mid = 0.5 * (lim.q_min + lim.q_max)
    return np.clip(np.where(np.isfinite(q), q, mid), lim.q_min, lim.q_max)


@dataclass(frozen=True)
class SafeFollowerCommand:
    """A follower command that passed the limits. Only SafetyLayer makes these."""

    q: np.ndarray
    tau_ff: np.ndarray
    kp: np.ndarray | None
    kd: np.ndarray | None
    gripper: float | None
    hold: bool
    _token: object

    def __post_init__(self):
        if self._token is not _TOKEN:
            raise TypeError("SafeFollowerCommand can only be made by hardware.safety.SafetyLayer")


@dataclass(frozen=True)
class SafeLeaderTorque:
    """Leader joint torques [N*m] that passed the limits. Only SafetyLayer makes these."""

    tau: np.ndarray
    _token: object

    def __post_init__(self):
        if self._token is not _TOKEN:
            raise TypeError("SafeLeaderTorque can only be made by hardware.safety.SafetyLayer")


class Watchdog:
    """Commands and feedback must both be fresher than timeout_s [s] (device clock)."""

    def __init__(self, timeout_s: float = DEFAULT_WATCHDOG_S):
        self.timeout_s = float(timeout_s)
        self.last_command_t = float("nan")
        self.last_feedback_t = float("nan")

    def feed_command(self, t: float) -> None:
        self.last_command_t = t

    def feed_feedback(self, t: float) -> None:
        self.last_feedback_t = t

    def stale(self, now: float) -> Reason | None:
        """Why the device must go safe now (DeviceHold.NO_COMMAND / NO_FEEDBACK, with its age in ms), or
        None. Nothing fed yet is not stale (not started)."""
        if now - self.last_command_t <= self.timeout_s and now - self.last_feedback_t <= self.timeout_s:
            return None  # the usual tick: both fed and fresh (NaN, or a time never fed, goes the way below)
        if math.isfinite(self.last_command_t) and now - self.last_command_t > self.timeout_s:
            return Reason.of(DeviceHold.NO_COMMAND, ms=1e3 * (now - self.last_command_t))
        if math.isfinite(self.last_feedback_t) and now - self.last_feedback_t > self.timeout_s:
            return Reason.of(DeviceHold.NO_FEEDBACK, ms=1e3 * (now - self.last_feedback_t))
        return None


class SafetyLayer:
    """Stateful shell around the pure limits for one device.

    Keeps the previous safe command (for rate limits), a watchdog and counters the UI and recordings show.
    """

    def __init__(self, limits: JointLimits, watchdog_s: float = DEFAULT_WATCHDOG_S,
                 hold_kd: float = HOLD_KD):
        self.limits = limits
        self.watchdog = Watchdog(watchdog_s)
        self.hold_kd = float(hold_kd)
        self._q_prev: np.ndarray | None = None
        self._tau_prev = np.zeros(limits.n)
        self._prev_floats: tuple = (None, None)  # (_q_prev, its tolist()) and below the same of _tau_prev
        self._zeros = np.zeros(limits.n)  # the feed-forward of every command without one [N*m], read-only
        self._zeros.flags.writeable = False
        self._tau_prev_floats: tuple = (None, None)
        self._t_prev = float("nan")
        self.clipped = 0  # joints changed by a limit, cumulative
        self.rejected = 0  # non-finite values replaced, cumulative
        self.holds = 0  # times the safe state was entered
        self.jumps_rejected = 0  # joint samples held: implausible jumps (Device.read), cumulative
        self.last_fault: Reason | str | None = None  # the last safe state's reason (or a caller's note)
        self._floats_of: JointLimits | None = None
        self._lim_floats: tuple[list[float], ...] = ()

    def _dt(self, now: float) -> float:
        dt = now - self._t_prev if math.isfinite(self._t_prev) else 0.0
        self._t_prev = now
        return dt

    def follower(self, cmd: FollowerCommand, now: float, q_meas: np.ndarray) -> SafeFollowerCommand:
        """Limit a raw follower command. q_meas [rad] seeds the rate limit on the first command."""
        lim, n = self.limits, self.limits.n
        if self._q_prev is None:
            self._q_prev = safe_start_target(q_meas, lim)
        dt = self._dt(now)
        qv = _vec(cmd.q, n)
        raw = qv.tolist()
        lf = self._floats()
        q, c1 = limit_position_floats(raw, _as_floats(self._q_prev, self._prev_floats), _rate_dt(dt), lf[2],
                                      lf[3], lf[4])
        self._prev_floats = (q_arr := np.array(q)), q  # the next call's q_prev as floats, without a tolist
        q = q_arr
        bad = 0 if math.isfinite(sum(raw)) or all(map(math.isfinite, raw)) else _n_bad(qv)  # (a finite sum:
        # no NaN or inf in it; an overflowing one is looked at value by value)
        if cmd.tau_ff is None:  # no feed-forward: zero passes every torque limit unchanged (falling is free)
            tau, c2 = self._zeros, 0
        else:
            tv = _vec(cmd.tau_ff, n, 0.0)
            tau, c2 = limit_torque(tv, self._tau_prev, dt, lim)
            bad += _n_bad(tv)
        kp = kd = None
        c3 = 0
        if cmd.kp is not None or cmd.kd is not None:
            kpv, kdv = _vec(cmd.kp, n, 0.0), _vec(cmd.kd, n, self.hold_kd)
            kp, kd, c3 = limit_gains(kpv, kdv, lim)
            bad += _n_bad(kpv) + _n_bad(kdv)
        self.rejected += bad
        grip = cmd.gripper if cmd.gripper is None or math.isfinite(cmd.gripper) else None
        self.clipped += c1 + c2 + c3
        self._q_prev, self._tau_prev = q, tau
        self.watchdog.feed_command(now)
        v = _new(SafeFollowerCommand)  # built by the layer (_new)
        d = v.__dict__
        d["q"], d["tau_ff"], d["kp"], d["kd"], d["gripper"] = q, tau, kp, kd, grip
        d["hold"], d["_token"] = False, _TOKEN
        return v

    def follower_hold(self, now: float, q_meas: np.ndarray, reason: Reason | str) -> SafeFollowerCommand:
        """The safe state: hold the measured position (clipped into the limits), no feed-forward,
        damping only for impedance followers (kp=0, kd=hold_kd) -- the driver picks which it sends."""
        q = safe_start_target(q_meas if self._q_prev is None else
                              np.where(np.isfinite(q_meas), q_meas, self._q_prev), self.limits)
        self._q_prev, self._tau_prev, self._t_prev = q, np.zeros(self.limits.n), now
        self.holds += 1
        self.last_fault = reason
        n = self.limits.n
        return SafeFollowerCommand(q=q, tau_ff=np.zeros(n), kp=np.zeros(n),
                                   kd=np.minimum(np.full(n, self.hold_kd), self.limits.kd_max),
                                   gripper=None, hold=True, _token=_TOKEN)

    def leader(self, tau: np.ndarray, now: float) -> SafeLeaderTorque:
        """Limit leader joint torques [N*m]."""
        dt = self._dt(now)
        tv = _vec(tau, self.limits.n, 0.0)
        raw = tv.tolist()
        if not (math.isfinite(sum(raw)) or all(map(math.isfinite, raw))):  # (as in follower())
            self.rejected += _n_bad(tv)
        lf = self._floats()
        out, c = limit_torque_floats(raw, _as_floats(self._tau_prev, self._tau_prev_floats), _rate_dt(dt),
                                     lf[0], lf[1])
        self.clipped += c
        self._tau_prev = arr = np.array(out)
        self._tau_prev_floats = arr, out
        self.watchdog.feed_command(now)
        v = _new(SafeLeaderTorque)  # built by the layer (_new)
        d = v.__dict__
        d["tau"], d["_token"] = arr, _TOKEN
        return v

    def _floats(self) -> tuple[list[float], ...]:
        """The limits as lists for the float kernels (tau_rate_max, tau_max, v_max, q_min, q_max), made once
        per JointLimits object."""
        lim = self.limits
        if self._floats_of is not lim:
            self._floats_of = lim
            self._lim_floats = tuple(a.tolist() for a in (lim.tau_rate_max, lim.tau_max, lim.v_max, lim.q_min,
                                                          lim.q_max))
        return self._lim_floats

    def leader_zero(self, now: float, reason: Reason | str) -> SafeLeaderTorque:
        """The leader's safe state: zero torque."""
        self._tau_prev, self._t_prev = np.zeros(self.limits.n), now
        self.holds += 1
        self.last_fault = reason
        return SafeLeaderTorque(tau=np.zeros(self.limits.n), _token=_TOKEN)


_new = object.__new__  # the layer builds its Safe* values with this and their __dict__ (the token set, as
# __post_init__ demands of anyone else), without the frozen dataclass's per-field object.__setattr__ (500 Hz)


def _as_floats(a: np.ndarray, cached: tuple) -> list[float]:
    """a.tolist(), or the list the layer made `a` from (cached = (a, its floats)) when it is that array."""
    return cached[1] if cached[0] is a else a.tolist()


def _vec(x, n: int, fill: float = np.nan) -> np.ndarray:
    """Shape a user value to (n,) floats; wrong shapes become all-NaN (rejected), never an exception."""
    if x is None:
        return np.full(n, fill)
    if type(x) is np.ndarray and x.dtype == np.float64 and x.shape == (n,):
        return x  # the hot path: already the right array
    try:
        a = np.asarray(x, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        return np.full(n, np.nan)
    return a if a.shape == (n,) else np.full(n, np.nan)


def _n_bad(a: np.ndarray) -> int:
    """Number of non-finite entries."""
    return 0 if all_finite(a) else int(np.count_nonzero(~np.isfinite(a)))
