"""Streaming NEXT estimator for the control loop: tau_ext = tau_m - f(last H samples), once per tick.

Two ways to run the LSTM (calibration.next.lstm_runs), chosen per checkpoint:
- exact windows (the default): NEXT's LSTM is stateless over its window, so H runs are kept in flight,
  staggered by one tick, all advanced one step per sample; the one that has seen H samples is the batch
  model's output (float32, ~4e-8 from torch.nn.LSTM). H LSTM steps per tick. `defer=True` leaves the runs
  this tick does not need to work() calls on the control ticks between two samples; update() finishes
  what is pending first, so the arithmetic is the same.
- carried state (when the checkpoint's training measured fading memory, `carried_allowed`): one run that
  never restarts, one LSTM step per tick, plus `audits` exact window runs; every H/audits ticks one of them
  completes a window and is compared with the carried output. Above the tolerance (1 % of the network's
  validation L1 per joint) the estimator switches to the exact windows for good: that tick returns the
  audit's window output, and until the exact windows have filled (H - 2 ticks) the carried estimate comes
  with FLAG_UNVERIFIED. `mode` says which is running.

Gate (checkpoints whose ModelConfig has `gate`, calibration.next.gate): the network's correction is scaled
per joint by alpha in [0, 1], folded into the head's last layer (LstmWeights) or applied by the model (torch
path): the same arithmetic as batch_tau_f.

Physics prior (checkpoints trained with `prior`, calibration.next.prior): tau_f = prior part + network; the
prior runs one sample at a time (PriorStream: the same midpoint acceleration as training, and the
checkpoint's low-pass of the residual measured - predicted torque) and restarts with the window. It needs
tau_m, and the motor temperature when it has a temperature term (without one it uses the reference
temperature and sets FLAG_NO_TEMPERATURE).

GRU/MLP checkpoints (ablation architectures) are evaluated with torch on a rolling buffer (exact, slower).

Guards (never raise in the loop): non-finite q/q_dot/q_cmd -> NaN estimate, FLAG_NONFINITE, and the window
restarts (FLAG_WARMUP until H clean samples are in); non-finite tau_m -> NaN estimate, FLAG_NONFINITE, window
kept (the prior's filters restart, and tau_f is NaN for that tick when there is a prior). FLAG_OOD when an
input leaves the training range widened by `ood_margin` x its span.
The estimator assumes one update per sample at the checkpoint's rate (ck.rate_hz, default 100 Hz).
"""

from __future__ import annotations

import numpy as np
import torch

from calibration.estimate import (  # noqa: F401  (re-exported: the flags of NEXT estimates)
    FLAG_NO_TEMPERATURE,
    FLAG_NONFINITE,
    FLAG_OK,
    FLAG_OOD,
    FLAG_UNVERIFIED,
    FLAG_WARMUP,
    Estimate,
)
from calibration.next.checkpoint import NextCheckpoint, weights_numpy
from calibration.next.data import make_inputs
from calibration.next.lstm_runs import CarriedRun, ExactWindows, LstmWeights
from calibration.next.prior import prior_torque
from calibration.next.priors import make_stream
from calibration.next.train import predict_series

CARRIED_TOL = 0.01  # the carried state may move the network output by <= 1 % of its validation L1, per joint


def carried_allowed(ck: NextCheckpoint) -> bool:
    """Whether the checkpoint's network has fading memory enough for the carried state: measured at training
    (metrics["carried_max_diff"], calibration.next.train.carried_state_diff) within CARRIED_TOL of its own
    validation L1 on every joint. Checkpoints without the measurement use the exact windows."""
    tol = carried_tolerance(ck)
    diff = (ck.metrics or {}).get("carried_max_diff")
    if tol is None or diff is None or len(diff) != len(tol):
        return False
    return bool(np.all(np.asarray(diff, float) <= tol))


def carried_tolerance(ck: NextCheckpoint) -> np.ndarray | None:
    """Per-joint tolerance [checkpoint units] for carried vs window outputs: CARRIED_TOL x validation L1."""
    l1 = (ck.metrics or {}).get("val_l1")
    if not l1 or len(l1) != ck.model.cfg.n_out or not np.all(np.isfinite(l1)):
        return None
    return CARRIED_TOL * np.asarray(l1, float)


class NextEstimator:
    def __init__(self, ck: NextCheckpoint, ema_alpha: float | None = None, ood_margin: float = 0.1,
                 defer: bool = False, parts: int = 4, carried: bool | None = None, audits: int = 3,
                 audit_tol: np.ndarray | float | None = None, source: tuple[str, str] | None = None):
        """ema_alpha: optional smoothing of tau_ext, y <- y + alpha (x - y), alpha in (0, 1]. defer: leave
        the exact runs this tick's estimate does not need to work() (each call steps 1/parts of them).
        carried: None = when the checkpoint measured fading memory (carried_allowed), True/False to force;
        audits: exact window runs checking the carried one (one completes every H/audits ticks);
        audit_tol: per-joint tolerance of that check [checkpoint units] (default carried_tolerance);
        source: (checkpoint path, arm) it was loaded from -- what a worker process loads the same estimator
        from (calibration/next/worker.py), None when built from a checkpoint in memory."""
        self.source = source
        if ema_alpha is not None and not 0.0 < ema_alpha <= 1.0:
            raise ValueError("ema_alpha must be in (0, 1]")
        self.ck = ck
        self.cfg = ck.model.cfg
        self.H = self.cfg.history
        self.n_j = self.cfg.n_out
        self.ema_alpha = ema_alpha
        norm = ck.normalizer
        self._x_mean = norm.x_mean.astype(np.float64)
        self._x_inv_std = 1.0 / norm.x_std.astype(np.float64)
        self._y_mean, self._y_std = norm.y_mean.astype(np.float64), norm.y_std.astype(np.float64)
        span = np.maximum(ck.x_max - ck.x_min, 1e-9)
        self._lo, self._hi = ck.x_min - ood_margin * span, ck.x_max + ood_margin * span
        self._fast = self.cfg.arch == "lstm" and self.cfg.layers == 2
        self.defer, self._parts = defer, parts
        use_carried = carried_allowed(ck) if carried is None else carried
        self._carried = self._exact = None
        self.audit_max_diff = np.zeros(self.n_j)  # largest |carried - window| an audit saw [ck units]
        self.audits_done = 0
        self.audit_failed = False
        if self._fast:
            self._wt = LstmWeights(weights_numpy(ck.model), ck.model.cfg.gate, ck.model.cfg.gate_offset)
            if use_carried:
                tol = carried_tolerance(ck) if audit_tol is None else np.broadcast_to(audit_tol, (self.n_j,))
                if tol is None:
                    raise ValueError("carried=True needs audit_tol: the checkpoint has no validation L1")
                self._tol = np.asarray(tol, float)
                self._carried = CarriedRun(self._wt, self.H, audits)
            else:
                self._exact = ExactWindows(self._wt, self.H, defer, parts)
        elif carried:
            raise ValueError("the carried state needs a 2-layer LSTM checkpoint")
        else:
            self._buf = np.zeros((self.H, self.cfg.n_in), np.float32)
        self._prior = make_stream(ck.prior, ck.rate_hz) if ck.prior is not None else None
        self.reset()

    @property
    def mode(self) -> str:
        """"exact" (H runs in flight), "carried" (audited carried state), "refilling" (an audit failed: the
        exact windows fill while the carried state is used, FLAG_UNVERIFIED) or "torch" (GRU/MLP)."""
        if not self._fast:
            return "torch"
        if self._carried is None:
            return "exact"
        return "refilling" if self._exact is not None else "carried"

    def reset(self) -> None:
        """Forget the history (e.g. after a pause or a gap in the data)."""
        self._n = 0  # clean samples since (re)start
        self._ema = None
        if self._prior is not None:
            self._prior.reset()
        if self._fast and self.audit_failed:  # memory was longer than measured: exact from now on
            self._carried = None
        if self._carried is not None:
            self._carried.reset()
        if self._exact is not None:
            self._exact.reset()

    def _nan(self, flags: int) -> Estimate:
        nan = np.full(self.n_j, np.nan)
        return Estimate(nan, flags=flags, tau_f=nan.copy())

    def work(self) -> None:
        """Between samples (defer=True): step 1/parts of the exact runs still pending. Cheap no-op else."""
        if self._exact is not None:
            self._exact.work()

    def _step_lstm(self, x: np.ndarray) -> tuple[np.ndarray | None, int]:
        """Normalised network output for this sample (None in warm-up) and flags to add."""
        if self._carried is None:
            return self._exact.push(x), FLAG_OK
        out, audit = self._carried.push(x)
        if self._exact is not None:  # refilling after a failed audit
            exact = self._exact.push(x)
            if exact is not None:
                self._carried = None
                return exact, FLAG_OK
            return out, (FLAG_UNVERIFIED if out is not None else FLAG_OK)
        if audit is None:
            return out, FLAG_OK
        diff = np.abs(out - audit) * self._y_std
        np.maximum(self.audit_max_diff, diff, out=self.audit_max_diff)
        self.audits_done += 1
        if np.any(diff > self._tol):  # this input's memory is longer than H: switch to the exact windows
            self.audit_failed = True
            self._exact = ExactWindows(self._wt, self.H, self.defer, self._parts)
            self._exact.push(x)
            return audit, FLAG_OK
        return out, FLAG_OK

    def _step_torch(self, x: np.ndarray) -> np.ndarray | None:
        self._buf = np.roll(self._buf, -1, axis=0)
        self._buf[-1] = x
        self._n += 1
        if self._n < self.H:
            return None
        with torch.no_grad():
            return self.ck.model(torch.from_numpy(self._buf[None]))[0].numpy()

    def update(self, q, q_dot, q_cmd, tau_m, temperature=None) -> Estimate:
        """One control tick. q [rad], q_dot [rad/s], q_cmd [rad], tau_m [N*m or A as the checkpoint],
        temperature [degC] per joint (used by a prior with a temperature term)."""
        try:
            x_raw = make_inputs(np.asarray(q, float), np.asarray(q_dot, float),
                                None if q_cmd is None else np.asarray(q_cmd, float), self.ck.inputs)
            tau = np.asarray(tau_m, float).reshape(self.n_j)
        except (ValueError, TypeError):
            self.reset()
            return self._nan(FLAG_NONFINITE)
        if x_raw.shape != (self.cfg.n_in,) or not np.all(np.isfinite(x_raw)):
            self.reset()
            return self._nan(FLAG_NONFINITE)
        flags = FLAG_OOD if np.any((x_raw < self._lo) | (x_raw > self._hi)) else FLAG_OK
        if not np.all(np.isfinite(tau)):
            flags |= FLAG_NONFINITE
        x = ((x_raw - self._x_mean) * self._x_inv_std).astype(np.float32)
        prior = 0.0
        if self._prior is not None:
            if flags & FLAG_NONFINITE:
                self._prior.reset()
                prior = np.full(self.n_j, np.nan)
            else:
                self._prior.missing_temperature = False
                prior = self._prior.update(np.asarray(q, float), np.asarray(q_dot, float), tau, temperature)
                if self._prior.missing_temperature:
                    flags |= FLAG_NO_TEMPERATURE
        out, more = self._step_lstm(x) if self._fast else (self._step_torch(x), FLAG_OK)
        flags |= more
        if out is None:
            return self._nan(flags | FLAG_WARMUP)
        tau_f = out.astype(np.float64) * self._y_std + self._y_mean + prior
        if flags & FLAG_NONFINITE:
            return Estimate(np.full(self.n_j, np.nan), flags=flags, tau_f=tau_f)
        ext = tau - tau_f
        if self.ema_alpha is not None:
            self._ema = ext if self._ema is None else self._ema + self.ema_alpha * (ext - self._ema)
            ext = self._ema.copy()
        return Estimate(ext, flags=flags, tau_f=tau_f)


def batch_tau_f(ck: NextCheckpoint, q, qd, q_cmd, tau=None, temperature=None,
                prior_tau: np.ndarray | None = None) -> np.ndarray:
    """Offline: predicted free-space torque for every sample of one uniformly sampled stretch at ck.rate_hz
    (N, J); the first H-1 rows are NaN (no full window yet). A checkpoint with a prior needs tau (and
    temperature when the prior uses it), or prior_tau: the prior's part on these samples when the caller has
    it already (calibration.next.prior.prior_torque)."""
    x = ck.normalizer.norm_x(make_inputs(q, qd, q_cmd, ck.inputs))
    tau_f = ck.normalizer.denorm_y(predict_series(ck.model, x, ck.history).astype(np.float64))
    if ck.prior is not None:
        if prior_tau is None:
            if tau is None:
                raise ValueError("this checkpoint has a physics prior: batch_tau_f needs tau")
            prior_tau = prior_torque(ck.prior, np.arange(len(x)) / ck.rate_hz, np.asarray(q, float),
                                     np.asarray(qd, float), np.asarray(tau, float), temperature)
        tau_f += prior_tau
    return tau_f
