"""Streamed position targets as servo drives interpolate them (cyclic position mode), per joint of a bank.

A target that comes interp_max_s [s] or less after the previous one is reached linearly over that measured
period, starting from where the target path is now; a first target, or one after a longer pause, applies at
once (the firmware's velocity ramp, in hardware/sim/mujoco_bank.py, still limits the move). So a 100 Hz
stream gives a smooth setpoint rather than a staircase. The path is q_goal - irate * max(t_end - t, 0) [rad].
"""

from __future__ import annotations

import numpy as np


class TargetPath:
    """Interpolated target path of n joints starting at q0 [rad]; interp_max_s [s] per joint (the bank's
    ActuatorParams.pos_interp_max_s array: read at every target)."""

    def __init__(self, q0: np.ndarray, interp_max_s: np.ndarray):
        n = len(q0)
        self.q_goal = np.array(q0, dtype=float)
        self.interp_max_s = interp_max_s
        self.t_last_cmd = np.full(n, -np.inf)  # s: time of each joint's latest target
        self.irate, self.t_end, self.t_end_max = np.zeros(n), np.zeros(n), -np.inf

    def at(self, t: float) -> np.ndarray:
        """Where the path is at time t [s] (q_goal itself once every joint got there: do not modify)."""
        if t >= self.t_end_max:
            return self.q_goal
        x = self.t_end - t  # in place from here (7-vectors: numpy calls, not arithmetic, cost the time)
        np.maximum(x, 0.0, out=x)
        x *= self.irate
        return np.subtract(self.q_goal, x, out=x)

    def new(self, sel, q, now: float) -> None:
        """Targets q [rad] for joints sel (slice or index array) arriving at time now [s]."""
        period = now - self.t_last_cmd[sel]
        stream = period > 0
        stream &= period <= self.interp_max_s[sel]
        start = self.at(now)[sel]  # where the target path is now
        if np.count_nonzero(stream) == stream.size:  # the steady stream: np.where would pick `period`
            self.irate[sel] = (q - start) / period
            self.t_end[sel] = now + period
        else:
            span = np.where(stream, period, 1.0)
            self.irate[sel] = np.where(stream, (q - start) / span, 0.0)
            self.t_end[sel] = np.where(stream, now + span, now)
        self.t_end_max = max(self.t_end.tolist())  # (Python's max of floats: cheaper than ndarray.max)
        self.t_last_cmd[sel] = now
        self.q_goal[sel] = q

    def reset(self, idx, q, forget: bool = False) -> None:
        """Targets of joints idx jump to q [rad] (no interpolation in progress); forget: the next target of
        these joints counts as a first one."""
        self.q_goal[idx] = q
        self.irate[idx] = 0.0
        if forget:
            self.t_last_cmd[idx] = -np.inf
