"""The streaming estimator's LSTM arithmetic: runs of the checkpoint's 2-layer LSTM (rows of one float32
state array) stepped together on one shared new sample, and two ways to get NEXT's window output from them.

NEXT's LSTM is stateless over its window: the estimate at tick n is the LSTM run from a zero state over
samples n-H+1..n.

- `ExactWindows`: H runs in flight, staggered by one tick; every tick all of them advance one step on the
  same new sample and the run that has now seen exactly H samples gives the output and restarts. The batch
  model's arithmetic (float32; ~4e-8 from torch.nn.LSTM), H LSTM steps per tick.
- `CarriedRun`: one run that never restarts (its state carries across ticks), one LSTM step per tick.
  It equals the window output only for a model with fading memory: one whose output no longer depends on
  samples more than H ticks old. `calibration.next.train.carried_state_diff` measures that on the
  validation data when the model is trained, and a few audit runs here keep checking it online: audit k
  restarts from zero every H ticks, staggered by H/audits, so every H/audits ticks one of them has just
  seen exactly H samples -- the exact window output -- and is compared with the carried run.

Gates: torch's order (i, f, g, o) is reordered to (i, f, o, g) and g pre-scaled by 2, so one in-place
sigmoid over all columns gives every gate (tanh(z) = 2 sigmoid(2 z) - 1; numpy's float32 tanh is not
vectorised, one torch sigmoid_ on the same memory is ~4x cheaper).
"""

from __future__ import annotations

import numpy as np
import torch


def _layer(w: dict[str, np.ndarray], layer: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(W_ih^T, W_hh^T, b) of one layer, gates reordered to (i, f, o, g) with g scaled by 2."""
    w_ih, w_hh = w[f"rnn.weight_ih_l{layer}"], w[f"rnn.weight_hh_l{layer}"]
    b = w[f"rnn.bias_ih_l{layer}"] + w[f"rnn.bias_hh_l{layer}"]
    h = w_ih.shape[0] // 4
    order = np.r_[np.arange(0, 2 * h), np.arange(3 * h, 4 * h), np.arange(2 * h, 3 * h)]
    scale = np.r_[np.ones(3 * h), np.full(h, 2.0)].astype(np.float32)
    return ((w_ih[order] * scale[:, None]).T.copy(), (w_hh[order] * scale[:, None]).T.copy(),
            (b[order] * scale).astype(np.float32))


class LstmWeights:
    """The 2-layer LSTM + 2-layer MLP head of a NextModel (weights_numpy dict) as float32 numpy arrays."""

    def __init__(self, w: dict[str, np.ndarray], gate=None, gate_offset=None):
        """gate, gate_offset: the model's per-output gate (ModelConfig; None: none), folded into the head's
        last layer -- output = gate * (h @ W + b) + offset -- so the gate costs nothing per tick."""
        self.wih1, self.whh1, self.b1 = _layer(w, 0)
        wih2, whh2, self.b2 = _layer(w, 1)
        self.w2 = np.concatenate([wih2, whh2], axis=0)  # [h1, h2] @ W2 in one product
        self.hidden = self.whh1.shape[0]
        self.hw1, self.hb1 = w["head.0.weight"].T.copy(), w["head.0.bias"]
        self.hw2, self.hb2 = w["head.3.weight"].T.copy(), w["head.3.bias"]
        if gate is not None:
            g = np.asarray(gate, np.float32)
            self.hw2 = (self.hw2 * g[None, :]).astype(np.float32)
            self.hb2 = (self.hb2 * g + np.asarray(gate_offset, np.float32)).astype(np.float32)

    def project(self, x: np.ndarray, out: np.ndarray) -> np.ndarray:
        """Layer 1's input projection of one normalised sample (shared by every run)."""
        return np.add(x @ self.wih1, self.b1, out=out)

    def head(self, h2: np.ndarray) -> np.ndarray:
        """Normalised network output from layer 2's hidden state."""
        return np.maximum(h2 @ self.hw1 + self.hb1, 0.0) @ self.hw2 + self.hb2


class LstmRuns:
    """State ([h1 | h2], c1, c2) of `rows` independent runs; step() advances consecutive rows by one step."""

    def __init__(self, wt: LstmWeights, rows: int):
        hid = wt.hidden
        self.wt, self.rows = wt, rows
        self.hh = np.zeros((rows, 2 * hid), np.float32)
        self.c1 = np.zeros((rows, hid), np.float32)
        self.c2 = np.zeros((rows, hid), np.float32)
        self._z = np.empty((rows, 4 * hid), np.float32)
        self._tmp = np.empty((rows, hid), np.float32)
        self._z_t, self._tmp_t = torch.from_numpy(self._z), torch.from_numpy(self._tmp)  # shared memory

    def zero(self, row: int | slice = slice(None)) -> None:
        """Zero the state of one row (a run restarts), or of all."""
        self.hh[row] = 0.0
        self.c1[row] = 0.0
        self.c2[row] = 0.0

    def h2(self, row: int) -> np.ndarray:
        return self.hh[row, self.wt.hidden:]

    def step(self, lo: int, hi: int, g1: np.ndarray) -> None:
        """One LSTM step of rows lo:hi on the sample whose layer-1 projection is g1."""
        wt, hid = self.wt, self.wt.hidden
        hh, z = self.hh[lo:hi], self._z[lo:hi]
        np.dot(hh[:, :hid], wt.whh1, out=z)
        z += g1
        self._cell(self.c1[lo:hi], hh[:, :hid], lo, hi)
        np.dot(hh, wt.w2, out=z)
        z += wt.b2
        self._cell(self.c2[lo:hi], hh[:, hid:], lo, hi)

    def _cell(self, c: np.ndarray, h_out: np.ndarray, lo: int, hi: int) -> None:
        """LSTM cell on the pre-activations in rows lo:hi (gate order i, f, o, g; g pre-scaled by 2)."""
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


class ExactWindows:
    """H staggered runs: run r starts (zero state) at ticks r, r+H, ...; the one that has just seen H samples
    is the window model. defer=True: push() steps only that run (and the one that starts); work() calls
    between samples step 1/parts of the rest, push() finishes whatever is still pending first."""

    def __init__(self, wt: LstmWeights, history: int, defer: bool = False, parts: int = 4):
        self.wt, self.H = wt, history
        self.runs = LstmRuns(wt, history)
        self.defer, self._chunk = defer, max(1, -(-(history - 2) // max(1, parts)))
        self._g1 = np.zeros(4 * wt.hidden, np.float32)
        self.reset()

    def reset(self) -> None:
        self.n = 0  # samples since (re)start
        self.runs.zero()
        self._pending: list[int] = []  # runs not yet stepped on the latest sample (oldest first)

    def push(self, x: np.ndarray) -> np.ndarray | None:
        """Feed one normalised sample; the window output (normalised) once H samples are in, else None."""
        self.work(all_pending=True)  # every run must have seen the previous sample
        H = self.H
        r = self.n % H  # run r starts now from a zero state
        self.runs.zero(r)
        self.wt.project(x, self._g1)
        self.n += 1
        done = (r + 1) % H  # the run that started H-1 ticks ago completes its window with this sample
        if self.n < H:  # warm-up: no window complete yet, step every run now
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
        return self.wt.head(self.runs.h2(done))

    def work(self, all_pending: bool = False) -> None:
        """Step pending runs on the latest sample: 1/parts of them, or all. Cheap no-op when none."""
        if not self._pending:
            return
        k = len(self._pending) if all_pending else self._chunk
        todo, self._pending = self._pending[:k], self._pending[k:]
        self._steps(todo)

    def _steps(self, runs: list[int]) -> None:
        """Step the given runs (row indices, consecutive modulo H) on the latest sample."""
        a = runs[0]
        first = min(len(runs), self.H - a)
        self.runs.step(a, a + first, self._g1)
        if len(runs) > first:
            self.runs.step(0, len(runs) - first, self._g1)


class CarriedRun:
    """One run carried across ticks (row 0) and `audits` exact window runs (rows 1..) checking it."""

    def __init__(self, wt: LstmWeights, history: int, audits: int = 3):
        if not 1 <= audits <= history:
            raise ValueError(f"audits must be in 1..{history}")
        self.wt, self.H, self.audits = wt, history, audits
        self.starts = [k * history // audits for k in range(audits)]  # tick (mod H) each audit restarts
        self.runs = LstmRuns(wt, 1 + audits)
        self._g1 = np.zeros(4 * wt.hidden, np.float32)
        self.reset()

    def reset(self) -> None:
        self.n = 0
        self.runs.zero()

    def push(self, x: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Feed one normalised sample: (carried output, exact window output of an audit that completed its
        window now or None); (None, None) until H samples are in."""
        n, H = self.n, self.H
        for k, s in enumerate(self.starts):
            if n % H == s:
                self.runs.zero(1 + k)
        self.runs.step(0, 1 + self.audits, self.wt.project(x, self._g1))
        self.n += 1
        if self.n < H:
            return None, None
        out = self.wt.head(self.runs.h2(0))
        for k, s in enumerate(self.starts):
            if (n - s) % H == H - 1:
                return out, self.wt.head(self.runs.h2(1 + k))
        return out, None
