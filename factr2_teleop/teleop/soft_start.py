"""Before coupling, bring the follower to the leader's mapped pose: refuse a large mismatch, else a
jerk-limited (ruckig) move that tracks the leader if it moves meanwhile. Plus the coupled-phase rate limit.

GELLO refuses to start beyond 1 rad of leader-follower difference; we do the same per joint and say which.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import ruckig

from hardware.errors import UserError
from hardware.params import PerJoint, per_joint

DEFAULT_MAX_MISMATCH_RAD = 1.0


@dataclass
class SoftStartConfig:
    """max_mismatch_rad: refuse to start when any follower joint is further than this from the leader's mapped
    pose [rad]. v/a/j_max: limits of the soft-start move [rad/s, rad/s^2, rad/s^3]. done_tol_rad: coupling
    starts once the move is within this of the (moving) goal on every joint [rad].
    rate_limit_rad_s: coupled-phase limit on how fast the follower target may move [rad/s].
    resume_direct_rad: after a hold, re-couple at once (the coupled rate limit closes the gap) when every
    follower joint is within this of the leader's mapped pose [rad]; the soft-start move cannot catch a leader
    that keeps moving faster than v_max_rad_s (wiping) and cannot end in contact. 0 disables it."""

    max_mismatch_rad: PerJoint = DEFAULT_MAX_MISMATCH_RAD
    v_max_rad_s: PerJoint = 0.5
    a_max_rad_s2: PerJoint = 2.0
    j_max_rad_s3: PerJoint = 10.0
    done_tol_rad: float = 0.02
    rate_limit_rad_s: PerJoint = 3.0
    resume_direct_rad: float = 0.25


def start_mismatch(q_follower: np.ndarray, q_goal: np.ndarray) -> np.ndarray:
    """|q_goal - q_follower| per joint [rad]; NaN stays NaN (an unread joint counts as too far)."""
    return np.abs(np.asarray(q_goal, dtype=float) - np.asarray(q_follower, dtype=float))


def mismatch_error(q_follower: np.ndarray, q_goal: np.ndarray, max_rad: np.ndarray,
                   where: str = "teleop") -> UserError | None:
    """A UserError listing the joints that are too far apart, or None when the start is allowed."""
    d = start_mismatch(q_follower, q_goal)
    bad = np.flatnonzero(~(d <= max_rad))
    if bad.size == 0:
        return None
    parts = ", ".join(f"j{i + 1} {d[i]:.2f} rad" for i in bad)
    return UserError(f"leader and follower differ too much to start ({parts}; limit "
                     f"{float(np.min(max_rad[bad])):.2f} rad)", where=where,
                     fix="move the leader to match the follower's pose (or check the joint offsets/signs "
                     "in the rig file) and start again")


def rate_limit(q_target: np.ndarray, q_prev: np.ndarray, v_max: np.ndarray, dt_s: float) -> np.ndarray:
    """q_target moved at most v_max*dt from q_prev [rad]; non-finite targets keep q_prev."""
    q, p = np.asarray(q_target, dtype=float), np.asarray(q_prev, dtype=float)
    v = np.asarray(v_max, dtype=float)
    if v.shape != q.shape:  # a scalar speed
        v = np.broadcast_to(v, q.shape)
    return np.array(rate_limit_floats(q.tolist(), p.tolist(), v.tolist(), max(float(dt_s), 0.0)))


def rate_limit_floats(q: list[float], q_prev: list[float], v_max: list[float], dt_s: float) -> list[float]:
    """rate_limit's math on plain floats [rad, rad/s, s], bit for bit its numpy form
    clip(where(isfinite(q), q, q_prev), q_prev - v_max dt, q_prev + v_max dt) (numpy's maximum / minimum
    written out as in hardware.small_vec.np_max; tests/test_law_floats.py). dt_s >= 0 (or NaN)."""
    for x, p, v in zip(q, q_prev, v_max, strict=True):
        step = v * dt_s
        if not p - step < x < p + step:
            break
    else:  # the usual tick: every target strictly inside its step (so finite): q itself, bit for bit
        return list(q)
    out = []
    isfinite = math.isfinite
    for x, p, v in zip(q, q_prev, v_max, strict=True):
        x = x if isfinite(x) else p
        step = v * dt_s
        lo, hi = p - step, p + step
        x = x if (x > lo or x != x) else lo
        out.append(x if (x < hi or x != x) else hi)
    return out


class SoftStart:
    """Online ruckig move toward a goal that may move (the leader is in a human hand). step() per tick."""

    def __init__(self, cfg: SoftStartConfig, n: int, dt_s: float):
        self.cfg, self.n, self.dt_s = cfg, n, float(dt_s)
        self.max_mismatch = per_joint(cfg.max_mismatch_rad, n, "soft_start.max_mismatch_rad", positive=True)
        self.v = per_joint(cfg.v_max_rad_s, n, "soft_start.v_max_rad_s", positive=True)
        self.a = per_joint(cfg.a_max_rad_s2, n, "soft_start.a_max_rad_s2", positive=True)
        self.j = per_joint(cfg.j_max_rad_s3, n, "soft_start.j_max_rad_s3", positive=True)
        self.rate = per_joint(cfg.rate_limit_rad_s, n, "soft_start.rate_limit_rad_s", positive=True)
        self._otg = ruckig.Ruckig(n, self.dt_s)
        self._inp = ruckig.InputParameter(n)
        self._out = ruckig.OutputParameter(n)
        self.q = np.full(n, np.nan)
        self._rate_floats: tuple = (None, [])  # (rate, its floats): coupled_step's
        self._last_step: tuple = (None, [])  # (coupled_step's last target, its floats)

    def coupled_step(self, q_goal: np.ndarray, q_prev: np.ndarray, dt_s: float) -> np.ndarray:
        """rate_limit(q_goal, q_prev, self.rate, dt_s) [rad], the same values: the coupled pair's target every
        tick, with the rate's floats kept while self.rate is the same array."""
        c = self._rate_floats
        if c[0] is not self.rate:  # (n,) per joint, as q_goal
            c = self._rate_floats = (self.rate, np.asarray(self.rate, dtype=float).tolist())
        qa = np.asarray(q_goal, dtype=float)
        q, last = qa.tolist(), self._last_step
        # q_prev is usually the target this returned last tick (read-only): its floats kept with it
        p = last[1] if q_prev is last[0] else np.asarray(q_prev, dtype=float).tolist()
        dt = max(float(dt_s), 0.0)
        for x, pj, v in zip(q, p, c[1], strict=True):  # rate_limit_floats' usual tick written out
            step = v * dt
            if not pj - step < x < pj + step:
                fl = rate_limit_floats(q, p, c[1], dt)
                break
        else:  # every target strictly inside its step: q_goal's floats as they are
            fl = q
        # q_goal copied: the same float64 values np.array(list(q)) gave, bit for bit
        out = qa.copy() if fl is q and qa.ndim == 1 else np.array(fl)
        out.flags.writeable = False  # its floats are kept for the next tick
        self._last_step = (out, fl)
        return out

    def reset(self, q_now: np.ndarray) -> None:
        """Start from the follower's measured position, at rest."""
        self.q = np.asarray(q_now, dtype=float).copy()
        inp = self._inp
        inp.current_position, inp.current_velocity = self.q.tolist(), [0.0] * self.n
        inp.current_acceleration = [0.0] * self.n
        inp.target_velocity, inp.target_acceleration = [0.0] * self.n, [0.0] * self.n
        inp.max_velocity, inp.max_acceleration = self.v.tolist(), self.a.tolist()
        inp.max_jerk = self.j.tolist()

    def _update(self):
        """One ruckig update; a rejected input (RuckigError: not a RuntimeError) is retried once from the
        same position with the velocity just inside its limit and no acceleration (the rejections seen: a
        joint at exactly v_max, the fault campaign's collect sessions), then from rest at the last target.
        None when it still fails: the caller keeps the last target and tries again next tick."""
        inp = self._inp
        for attempt in range(3):
            try:
                return self._otg.update(inp, self._out)
            except (RuntimeError, ruckig.RuckigError):
                n = self.n
                v = np.clip(np.asarray(inp.current_velocity, float), -0.99 * self.v, 0.99 * self.v)
                if np.all(np.isfinite(self.q)):
                    inp.current_position = self.q.tolist()
                inp.current_velocity = (v if attempt == 0 else np.zeros(n)).tolist()
                inp.current_acceleration = [0.0] * n
        return None

    def step(self, q_goal: np.ndarray) -> tuple[np.ndarray, bool]:
        """Next follower target [rad] toward q_goal, and whether it is there (within done_tol_rad, slow)."""
        goal = np.asarray(q_goal, dtype=float)
        if not np.all(np.isfinite(goal)):
            return self.q.copy(), False  # no valid goal this tick: hold where the move is
        self._inp.target_position = goal.tolist()
        res = self._update()
        if res not in (ruckig.Result.Working, ruckig.Result.Finished):
            return self.q.copy(), False
        self._out.pass_to_input(self._inp)
        self.q = np.asarray(self._out.new_position, dtype=float)
        near = bool(np.all(np.abs(goal - self.q) <= self.cfg.done_tol_rad))
        slow = bool(np.all(np.abs(np.asarray(self._out.new_velocity)) <= self.v * 0.5))
        return self.q.copy(), near and slow
