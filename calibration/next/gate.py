"""Per-joint gate on the network's correction over its physics prior (issue 23): tau_f = prior + alpha_j *
network_j, alpha_j in [0, 1], fitted on validation data the network never trained on.

Why: on the real UR5 the learned residual helps on runs like the training data and hurts on unseen
trajectories (extrapolation to new joint configurations). Early stopping alone cannot fix that when what it
validates on is interpolation. With whole held-out runs as validation (calibration.next.data.split_runs),
alpha_j is the least-squares scale of the network's correction c_j that best explains the residual r_j the
prior leaves on those runs: alpha_j = <c_j, r_j> / <c_j, c_j>, clipped to [0, 1]. A correction that is noise
with respect to the held-out residual gets alpha ~ 0 (NEXT falls back to its prior on that joint), a correct
one alpha ~ 1. Clipped, because a scale above 1 or below 0 would be extrapolating the extrapolation.

Where the alpha comes from (TrainConfig.gate):
- "crossfit" (the default with >= 3 runs): the runs are split into CROSSFIT_FOLDS groups; for each, a fold
  model is trained exactly as the final one (block validation) on the other groups' runs and predicts every
  window of the group's runs; alpha is fitted on all those out-of-run predictions pooled -- every run is
  scored once as unseen, so alpha measures how much of the learned correction transfers to a new
  trajectory, not how it does on one run. The final model then trains on every run and gets that alpha.
  (The fold models share the final model's normaliser, fitted on every run: a scale of the inputs and
  targets, not a fit to the held-out runs.)
- "heldout": fitted on the one model's own whole-run validation (validation "runs"); one run's verdict.

The gate acts on the correction in the data's units (N*m or A) -- its mean included -- and is folded into
the network's normalised output: out' = alpha * out + (alpha - 1) * y_mean / y_std, so that
out' * y_std + y_mean = alpha * (out * y_std + y_mean) (gate_offset).
"""

from __future__ import annotations

import numpy as np

from calibration.next.data import MIN_RUNS

MIN_POWER = 1e-12  # a correction of less mean square than this [units^2] keeps alpha = 1 (nothing to scale)


def fit_gate(correction: np.ndarray, residual: np.ndarray) -> np.ndarray:
    """alpha per joint (J,) in [0, 1]: the clipped least-squares scale of `correction` (N, J; the network's
    output in the data's units) that best fits `residual` (N, J; measured torque minus the prior, same units).
    Rows with a non-finite value are ignored; a joint with no usable rows or no correction gets 1."""
    c, r = np.asarray(correction, float), np.asarray(residual, float)
    if c.shape != r.shape or c.ndim != 2:
        raise ValueError(f"correction {c.shape} and residual {r.shape} must both be (N, J)")
    ok = np.all(np.isfinite(c), axis=1) & np.all(np.isfinite(r), axis=1)
    c, r = c[ok], r[ok]
    power = (c * c).mean(0) if len(c) else np.zeros(c.shape[1])
    cross = (c * r).mean(0) if len(c) else np.zeros(c.shape[1])
    alpha = np.where(power > MIN_POWER, cross / np.maximum(power, MIN_POWER), 1.0)
    return np.clip(alpha, 0.0, 1.0)


def gate_offset(alpha: np.ndarray, y_mean: np.ndarray, y_std: np.ndarray) -> np.ndarray:
    """The normalised output offset (alpha - 1) * y_mean / y_std that makes the gate act on the correction in
    the data's units (its training mean included), not only on its deviation from that mean."""
    return (np.asarray(alpha, float) - 1.0) * np.asarray(y_mean, float) / np.asarray(y_std, float)


CROSSFIT_FOLDS = 3  # groups of runs the gate is cross-fitted over (each fold model trains on the others)
CROSSFIT_SHARE = 0.5  # share of the training budget the fold models get together (the final model the rest)


def crossfit_folds(run_index: np.ndarray, train_ends: np.ndarray, val_ends: np.ndarray,
                   k: int = CROSSFIT_FOLDS, min_runs: int = MIN_RUNS
                   ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Folds of whole runs for the cross-fitted gate: run r (run_index: the run of every sample, numbered
    in order) belongs to fold r % k. Per fold (train window ends, validation window ends, held-out window
    ends): the block split's windows of the other folds' runs -- the final model's own procedure on fewer
    runs -- and every window of this fold's runs. [] with fewer than min_runs runs; a fold that would
    leave nothing to train on or to score is left out."""
    run_index = np.asarray(run_index)
    n_runs = int(run_index.max()) + 1 if len(run_index) else 0
    if n_runs < max(min_runs, 2):
        return []
    fold_of = run_index % min(k, n_runs)  # of every sample
    every = np.union1d(train_ends, val_ends)
    out = []
    for f in range(min(k, n_runs)):
        tr, va = (e[fold_of[e] != f] for e in (train_ends, val_ends))
        held = every[fold_of[every] == f]
        if len(tr) and len(held):
            out.append((tr, va, held))
    return out
