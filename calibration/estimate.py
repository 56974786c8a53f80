"""One external-torque estimate type and its flags, torch-free, for every estimator (NEXT, observer,
position-position, a twin's truth) and every consumer (teleop feedback, recording, policies).

Convention: tau_ext [N*m] = tau_m - tau_free on the follower joints = minus the environment's torque on the
follower (the paper's, NEXT's and the twin's GroundTruth.tau_ext).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

FLAG_OK = 0
FLAG_WARMUP = 1  # fewer samples than the estimator needs since start/restart: estimate is NaN
FLAG_NONFINITE = 2  # an input was NaN/inf: estimate is NaN
FLAG_OOD = 4  # inputs outside the training range: estimate may be unreliable
FLAG_NO_TEMPERATURE = 8  # the prior has a temperature term but no finite temperature came: not corrected
FLAG_UNVERIFIED = 16  # carried-state estimate while the exact windows refill after a failed audit
FLAG_UNCONVERGED = 32  # an observer's first samples: its integral has not settled yet
_INVALID = FLAG_WARMUP | FLAG_NONFINITE | FLAG_UNCONVERGED


@dataclass
class Estimate:
    """tau_ext: (J,) external torque [N*m, or the checkpoint's units], NaN when not valid; t: time of the
    data it used [s] (NaN: not stamped); flags: FLAG_* bits; tau_f: (J,) predicted free-space torque when
    the source has one (NEXT), else None."""

    tau_ext: np.ndarray
    t: float = float("nan")
    flags: int = FLAG_OK
    tau_f: np.ndarray | None = None

    @property
    def valid(self) -> bool:
        """Usable for feedback and labels (not warming up, finite inputs, converged)."""
        return not (self.flags & _INVALID)

    @property
    def ood(self) -> bool:
        return bool(self.flags & FLAG_OOD)

    @property
    def warming_up(self) -> bool:
        return bool(self.flags & FLAG_WARMUP)


def describe_flags(flags: int) -> str:
    """A short word for a UI: "ok", "warming up", "bad input", "out of training range (OOD)", ..."""
    if flags & FLAG_WARMUP:
        return "warming up"
    if flags & FLAG_NONFINITE:
        return "bad input"
    if flags & FLAG_UNCONVERGED:
        return "converging"
    if flags & FLAG_OOD:
        return "out of training range (OOD)"
    return "ok"
