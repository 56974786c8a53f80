"""A contact score that discounts motion: FIRST's `--contact-score motion`.

FIRST's default score is ||tau_ext||_1. It assumes the estimate is near zero in free motion. An estimator
whose free-motion error follows the motion breaks that: the disturbance observer on cap-screw reads up to
+0.13 N*m on the wrist while it turns and more on the shoulder and elbow while the open hand swings back
between strokes, so the recording's Otsu split labelled 58 % of the truly free samples contact
(docs/force.md). This score removes the part of tau_ext that the joint velocities explain, fitted on the
recording itself, without any truth:

    features  x_t = [1, sign(q_dot_t), q_dot_t]                 (1 + 2J,) all joints of the set
    fit       tau_ext_t ~ x_t @ W   on the samples most likely free: the KEEP_FRACTION of the set with the
              lowest score (||tau_ext||_1 on the first pass, the residual score after), PASSES times
              (a trimmed least squares: contact is what the fit must not explain)
    scale     s_j = median |r_tj| over those samples      [N*m]: each joint's free-motion residual
    score     f_t = sum_j |tau_ext_tj - x_t @ W_j| / s_j      (dimensionless: multiples of the free noise)
    labels    the centred mean of f over SMOOTH_S (offline labels may look ahead): a joint velocity's
              noise reaches f unfiltered, and the raw f crosses the thresholds back and forth inside one
              contact (cap-screw: 3,130 labelled onsets against 488 true ones unsmoothed, 327 smoothed)

Coulomb and viscous terms per joint, with every joint's velocity in every joint's fit (the swing of one
joint shows in another's estimate through the model's inertia and coupling errors). Contact is rarely
explained by velocity alone (a push is at rest or slow), so it stays in the residual. What it cannot
remove: an error that follows position or acceleration (a held load: the tare does that first), and a
set where contact is more than half the samples in every pass (tight-insert, truth 70 %: recall stays
low with either score). The thresholds are then Otsu's band on this score, as for the default one.
Measured against the twin's truth: docs/first_labels.md "Motion-discounted score".
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

KEEP_FRACTION = 0.5  # share of the set's samples the fit treats as free, lowest score first
PASSES = 3  # trimmed fits: the first on ||tau_ext||_1, the next on the previous fit's residual score
SCALE_FLOOR_NM = 1e-6  # a joint whose free residual is below this is scaled by it [N*m]
SMOOTH_S = 0.025  # the labels' moving mean of the score [s] (chosen on cap-screw / peg-insert, module doc)
CONTACT_SCORES = ("l1", "motion")  # --contact-score words: the paper's ||tau_ext||_1, or this module's


def motion_features(q_dot: np.ndarray) -> np.ndarray:
    """(N, 1 + 2J) features [1, sign(q_dot), q_dot] of joint velocities q_dot (N, J) [rad/s]."""
    qd = np.asarray(q_dot, dtype=float)
    return np.concatenate([np.ones((len(qd), 1)), np.sign(qd), qd], axis=1)


@dataclass(frozen=True)
class MotionResidual:
    """The part of tau_ext the motion explains: weights (1 + 2J, J) [N*m per feature], scale (J,) [N*m]."""

    weights: np.ndarray
    scale: np.ndarray

    def to_dict(self) -> dict:
        return {"weights": np.asarray(self.weights).tolist(), "scale": np.asarray(self.scale).tolist(),
                "keep": KEEP_FRACTION, "passes": PASSES}

    @classmethod
    def from_dict(cls, d: dict) -> MotionResidual:
        return cls(np.asarray(d["weights"], float), np.asarray(d["scale"], float))


def residual_score(model: MotionResidual, tau_ext: np.ndarray, q_dot: np.ndarray) -> np.ndarray:
    """f_t (N,) of tau_ext (N, J) [N*m] at joint velocities q_dot (N, J) [rad/s]; NaN where either is."""
    tau = np.asarray(tau_ext, dtype=float)
    with np.errstate(invalid="ignore", over="ignore"):  # a NaN or inf row scores NaN or inf, as documented
        r = tau - motion_features(q_dot) @ model.weights
    return (np.abs(r) / model.scale).sum(axis=1)


def fit_motion_residual(tau_ext: np.ndarray, q_dot: np.ndarray, keep: float = KEEP_FRACTION,
                        passes: int = PASSES) -> MotionResidual:
    """The trimmed fit of the module doc over a set's samples tau_ext (N, J) [N*m], q_dot (N, J) [rad/s].
    Non-finite rows are left out. ValueError when fewer finite samples than 4 per feature remain."""
    tau, qd = np.asarray(tau_ext, dtype=float), np.asarray(q_dot, dtype=float)
    if tau.shape != qd.shape or tau.ndim != 2:
        raise ValueError(f"tau_ext {tau.shape} and q_dot {qd.shape} must both be (N, J)")
    ok = np.isfinite(tau).all(axis=1) & np.isfinite(qd).all(axis=1)
    tau, x = tau[ok], motion_features(qd[ok])
    if len(tau) < 4 * x.shape[1]:
        raise ValueError(f"{len(tau)} finite samples: too few to fit the motion's part of tau_ext")
    score = np.abs(tau).sum(axis=1)
    for _ in range(max(1, int(passes))):
        free = score <= np.quantile(score, keep)
        w = np.linalg.lstsq(x[free], tau[free], rcond=None)[0]
        r = np.abs(tau - x @ w)
        scale = np.maximum(np.median(r[free], axis=0), SCALE_FLOOR_NM)
        score = (r / scale).sum(axis=1)
    return MotionResidual(w, scale)


def smooth_score(t: np.ndarray, score: np.ndarray, window_s: float = SMOOTH_S) -> np.ndarray:
    """The centred mean of score (N,) over window_s [s] at times t (N,) [s] ascending, any sample rate;
    NaN samples are left out of each mean (NaN where a window holds none)."""
    t, f = np.asarray(t, dtype=float), np.asarray(score, dtype=float)
    ok = np.isfinite(f)
    csum = np.concatenate([[0.0], np.cumsum(np.where(ok, f, 0.0))])
    cnt = np.concatenate([[0], np.cumsum(ok)])
    lo = np.searchsorted(t, t - window_s / 2, side="left")
    hi = np.searchsorted(t, t + window_s / 2, side="right")
    n = cnt[hi] - cnt[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, (csum[hi] - csum[lo]) / np.maximum(n, 1), np.nan)
