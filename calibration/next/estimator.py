"""Streaming NEXT estimator for the control loop: tau_ext = tau_m - f(last H samples), once per tick.

Exactness vs speed. NEXT's LSTM is stateless over its window: the estimate at tick n is the LSTM run from a
zero state over samples n-H+1..n. Recomputing that run every tick costs H sequential steps of small
matrix-vector products (slow in Python). Instead we keep H runs in flight, staggered by one tick: run r
starts (zero state) at tick r, r+H, r+2H, ...  Every tick all H runs advance by one step on the *same* new
sample -- two small matrix-matrix products (H x 128 @ 128 x 512 and H x 256 @ 256 x 512) -- and the run that
has just seen H samples is exactly the stateless window model; its head output is the estimate, and it
restarts from zero. Same arithmetic as the batch model (float32, differences ~1e-6), no approximation.
The per-step layer-1 input projection is computed once per tick and shared by all runs.

Spreading the work (`defer=True`): of the H runs only the one that completes its window is needed for this
tick's estimate. update() steps that run (and the one that starts) and returns the estimate; the other H-2
runs may be stepped later by work() calls on the control ticks between two samples (a 500 Hz loop with a
100 Hz model has four), so no single tick carries the whole product. update() first finishes whatever is
still pending, so the result is the same arithmetic in any case.

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

from dataclasses import dataclass

import numpy as np
import torch

from calibration.next.checkpoint import NextCheckpoint, weights_numpy
from calibration.next.data import make_inputs
from calibration.next.prior import PriorStream, prior_torque
from calibration.next.train import predict_series

FLAG_OK = 0
FLAG_WARMUP = 1  # fewer than H clean samples since start/restart: estimate is NaN
FLAG_NONFINITE = 2  # an input was NaN/inf: estimate is NaN
FLAG_OOD = 4  # inputs outside the training range: estimate may be unreliable
FLAG_NO_TEMPERATURE = 8  # the prior has a temperature term but no finite temperature came: not corrected


@dataclass
class Estimate:
    tau_ext: np.ndarray  # (J,) external torque [units of the checkpoint]; NaN when not valid
    tau_f: np.ndarray  # (J,) predicted free-space torque
    flags: int

    @property
    def valid(self) -> bool:
        return not (self.flags & (FLAG_WARMUP | FLAG_NONFINITE))

    @property
    def ood(self) -> bool:
        return bool(self.flags & FLAG_OOD)


def _lstm_layer_weights(w: dict[str, np.ndarray], layer: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(W_ih^T, W_hh^T, b) with the gates reordered from torch's (i, f, g, o) to (i, f, o, g) and the cell
    gate g pre-scaled by 2, so one sigmoid over all columns gives every gate: tanh(z) = 2 sigmoid(2 z) - 1.
    (One in-place torch sigmoid over 50x512 floats is ~4x cheaper than numpy's float32 tanh, which is not
    vectorised; the identity is exact up to float32 rounding.)"""
    w_ih, w_hh = w[f"rnn.weight_ih_l{layer}"], w[f"rnn.weight_hh_l{layer}"]
    b = w[f"rnn.bias_ih_l{layer}"] + w[f"rnn.bias_hh_l{layer}"]
    h = w_ih.shape[0] // 4
    order = np.r_[np.arange(0, 2 * h), np.arange(3 * h, 4 * h), np.arange(2 * h, 3 * h)]
    scale = np.r_[np.ones(3 * h), np.full(h, 2.0)].astype(np.float32)
    return ((w_ih[order] * scale[:, None]).T.copy(), (w_hh[order] * scale[:, None]).T.copy(),
            (b[order] * scale).astype(np.float32))


class NextEstimator:
    def __init__(self, ck: NextCheckpoint, ema_alpha: float | None = None, ood_margin: float = 0.1,
                 defer: bool = False, parts: int = 4):
        """ema_alpha: optional smoothing of tau_ext, y <- y + alpha (x - y), alpha in (0, 1]. defer: leave
        the runs this tick's estimate does not need to work() (each call steps 1/parts of them)."""
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
        if self._fast:
            w = weights_numpy(ck.model)
            self._wih1, self._whh1, self._b1 = _lstm_layer_weights(w, 0)
            wih2, whh2, self._b2 = _lstm_layer_weights(w, 1)
            self._w2 = np.concatenate([wih2, whh2], axis=0)  # [h1, h2] @ W2 in one product
            self._hw1, self._hb1 = w["head.0.weight"].T.copy(), w["head.0.bias"]
            self._hw2, self._hb2 = w["head.3.weight"].T.copy(), w["head.3.bias"]
            hid = self.cfg.hidden
            self._hh = np.zeros((self.H, 2 * hid), np.float32)  # [h1 | h2] of every run
            self._c1 = np.zeros((self.H, hid), np.float32)
            self._c2 = np.zeros((self.H, hid), np.float32)
            self._z = np.empty((self.H, 4 * hid), np.float32)
            self._tmp = np.empty((self.H, hid), np.float32)
            self._z_t, self._tmp_t = torch.from_numpy(self._z), torch.from_numpy(self._tmp)  # shared memory
            self._g1 = np.zeros(4 * hid, np.float32)  # input projection of the sample the pending runs need
            self._pending: list[int] = []  # runs not yet stepped on the latest sample (oldest first)
            self.defer, self._chunk = defer, max(1, -(-(self.H - 2) // max(1, parts)))
        else:
            self._buf = np.zeros((self.H, self.cfg.n_in), np.float32)
        self._prior = PriorStream(ck.prior, ck.rate_hz) if ck.prior is not None else None
        self.reset()

    def reset(self) -> None:
        """Forget the history (e.g. after a pause or a gap in the data)."""
        self._n = 0  # clean samples since (re)start
        self._ema = None
        if self._prior is not None:
            self._prior.reset()
        if self._fast:
            self._hh[:] = 0.0
            self._c1[:] = 0.0
            self._c2[:] = 0.0
            self._pending = []

    def _nan(self, flags: int) -> Estimate:
        nan = np.full(self.n_j, np.nan)
        return Estimate(nan, nan.copy(), flags)

    def _step_lstm(self, x: np.ndarray) -> np.ndarray | None:
        self.work(all_pending=True)  # every run must have seen the previous sample
        hid, H = self.cfg.hidden, self.H
        r = self._n % H  # run r starts now from a zero state
        self._hh[r] = 0.0
        self._c1[r] = 0.0
        self._c2[r] = 0.0
        np.add(x @ self._wih1, self._b1, out=self._g1)  # shared input projection of the new sample
        self._n += 1
        done = (r + 1) % H  # the run that started H-1 ticks ago completes its window with this sample
        if self._n < H:  # warm-up: no window complete yet, step every run now
            self._pending = [(r + 1 + k) % H for k in range(H)]
            self.work(all_pending=True)
            return None
        others = [(done + k) % H for k in range(1, H)]  # every run but `done`, r last
        if self.defer:
            self._steps([done])
            if r != done:
                self._steps([r])
            self._pending = others[:-1] if r != done else others  # consecutive runs done+1 .. r-1
        else:
            self._pending = [done] + others
            self.work(all_pending=True)
        a = np.maximum(self._hh[done, hid:] @ self._hw1 + self._hb1, 0.0)
        return a @ self._hw2 + self._hb2

    def work(self, all_pending: bool = False) -> None:
        """Step pending runs on the latest sample: 1/parts of them, or all. Cheap no-op when none."""
        if not self._fast or not self._pending:
            return
        k = len(self._pending) if all_pending else self._chunk
        todo, self._pending = self._pending[:k], self._pending[k:]
        self._steps(todo)

    def _steps(self, runs: list[int]) -> None:
        """One LSTM step of the given runs (row indices, consecutive modulo H) on the latest sample."""
        a = runs[0]
        for lo, n in ((a, min(len(runs), self.H - a)), (0, len(runs) - min(len(runs), self.H - a))):
            if n > 0:
                self._rows(lo, lo + n)

    def _rows(self, lo: int, hi: int) -> None:
        hid = self.cfg.hidden
        hh, z = self._hh[lo:hi], self._z[lo:hi]
        h1, h2 = hh[:, :hid], hh[:, hid:]
        np.dot(h1, self._whh1, out=z)
        z += self._g1
        self._cell(self._c1[lo:hi], h1, lo, hi)
        np.dot(hh, self._w2, out=z)
        z += self._b2
        self._cell(self._c2[lo:hi], h2, lo, hi)

    def _cell(self, c: np.ndarray, h_out: np.ndarray, lo: int, hi: int) -> None:
        """LSTM cell on the pre-activations in rows lo:hi of self._z (gate order i, f, o, g; g pre-scaled
        by 2)."""
        hid, z, tmp = c.shape[1], self._z[lo:hi], self._tmp[lo:hi]
        self._z_t[lo:hi].sigmoid_()  # in place on self._z
        g = z[:, 3 * hid:]
        g *= 2.0
        g -= 1.0  # tanh of the unscaled g pre-activation
        c *= z[:, hid:2 * hid]
        np.multiply(z[:, :hid], g, out=tmp)
        c += tmp
        np.multiply(c, 2.0, out=tmp)
        self._tmp_t[lo:hi].sigmoid_()
        tmp *= 2.0
        tmp -= 1.0  # tanh(c)
        np.multiply(z[:, 2 * hid:3 * hid], tmp, out=h_out)

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
            x_raw = make_inputs(np.asarray(q, float), np.asarray(q_dot, float), np.asarray(q_cmd, float),
                                self.ck.inputs)
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
        out = self._step_lstm(x) if self._fast else self._step_torch(x)
        if out is None:
            return self._nan(flags | FLAG_WARMUP)
        tau_f = out.astype(np.float64) * self._y_std + self._y_mean + prior
        if flags & FLAG_NONFINITE:
            return Estimate(np.full(self.n_j, np.nan), tau_f, flags)
        ext = tau - tau_f
        if self.ema_alpha is not None:
            self._ema = ext if self._ema is None else self._ema + self.ema_alpha * (ext - self._ema)
            ext = self._ema.copy()
        return Estimate(ext, tau_f, flags)


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
