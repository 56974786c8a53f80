"""Joint time series: one type, one resampler, one held-out splitter (numpy only, no torch).

Used by calibration (NEXT's data pipeline), diagnosis and the recording reader, so a run is resampled and
split the same way wherever it is read.

Segment      one contiguous run of joint samples on one clock (t [s], q [rad], qd [rad/s], tau [N*m|A] ...)
resample()   arrays on an irregular clock -> a grid (uniform at rate_hz, or given): float arrays interpolated
             linearly, bool/int arrays held at the previous sample; grid points outside the samples' span are
             NaN (float) or False/0 -- nothing is extrapolated; optionally split where samples are missing
heldout_spans()  which samples are held out, as contiguous spans -- never random samples: neighbouring
             samples of a 100 Hz log are nearly identical, so a random split measures interpolation
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

Span = tuple[int, int, int]  # (series index, start, stop): samples [start, stop) of one series


@dataclass
class Segment:
    """One contiguous run of an arm's joint samples. Per-sample arrays are (N, n) (contact: (N,)); None =
    not logged. rate_hz: the uniform rate of t (0.0: irregular clock, as logged). units: of tau, "N*m"
    (motor torque) or "A" (motor current)."""

    t: np.ndarray  # (N,) s
    q: np.ndarray  # rad
    qd: np.ndarray  # rad/s
    tau: np.ndarray  # N*m or A (units): the measured torque signal, the quantity models predict
    q_cmd: np.ndarray | None = None  # rad, commanded position (NEXT's third input)
    rate_hz: float = 0.0
    name: str = ""
    units: str = "N*m"
    qdd: np.ndarray | None = None  # rad/s^2 (differentiated, see calibration.diagnosis.data)
    qd_logged: np.ndarray | None = None  # rad/s as logged, where qd was replaced by a cleaner estimate
    temperature: np.ndarray | None = None  # degC
    tau_ext_true: np.ndarray | None = None  # N*m, twin ground truth (SIMULATED)
    contact: np.ndarray | None = None  # (N,) bool
    joint_names: tuple[str, ...] = ()
    arm: str = ""  # arm description name ("" = unknown) and the SHA-256 of its file
    arm_sha256: str = ""

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def n(self) -> int:
        """Number of joints."""
        return int(self.q.shape[1])

    @property
    def source(self) -> str:  # NEXT's name for the run a segment came from
        return self.name

    def slice(self, a: int, b: int, name: str | None = None) -> Segment:
        """Samples [a, b) as a new Segment (every per-sample array cut the same way)."""
        n = len(self)
        cut = {f.name: v[a:b] for f in dataclasses.fields(self)
               if isinstance(v := getattr(self, f.name), np.ndarray) and v.ndim >= 1 and v.shape[0] == n}
        return dataclasses.replace(self, **cut, name=self.name if name is None else name)


def interp_linear(t: np.ndarray, y: np.ndarray, t_grid: np.ndarray) -> np.ndarray:
    """Linear interpolation of samples y (N, ...) at increasing times t (N,) onto t_grid (M,); NaN outside
    [t[0], t[-1]]. Inside, exactly numpy.interp per column."""
    t, y, tg = np.asarray(t, float), np.asarray(y, float), np.asarray(t_grid, float)
    out = np.full((tg.shape[0],) + y.shape[1:], np.nan)
    if t.shape[0] == 0:
        return out
    inside = (tg >= t[0]) & (tg <= t[-1])
    flat = y.reshape(t.shape[0], -1)
    vals = np.stack([np.interp(tg[inside], t, flat[:, k]) for k in range(flat.shape[1])], 1)
    out[inside] = vals.reshape((-1,) + y.shape[1:])
    return out


def hold_previous(t: np.ndarray, y: np.ndarray, t_grid: np.ndarray) -> np.ndarray:
    """Previous-value hold of y (N, ...) onto t_grid; before the first sample (or no samples): NaN for float,
    False/0 for bool/int."""
    y = np.asarray(y)
    i = np.searchsorted(np.asarray(t, float), np.asarray(t_grid, float), side="right") - 1
    fill = np.nan if y.dtype.kind == "f" else 0
    out = np.full((len(t_grid),) + y.shape[1:], fill, dtype=y.dtype if y.dtype.kind in "fbiu" else float)
    ok = i >= 0
    if y.shape[0]:
        out[ok] = y[i[ok]]
    return out


def uniform_grid(t0: float, t1: float, rate_hz: float) -> np.ndarray:
    """t0, t0 + 1/rate_hz, ... up to and including t1 when it falls on the grid [s]."""
    return t0 + np.arange(int(np.floor((t1 - t0) * rate_hz)) + 1) / rate_hz


def resample(t: np.ndarray, arrays: dict[str, np.ndarray | None], rate_hz: float | None = None,
             t_grid: np.ndarray | None = None, max_gap_s: float | None = None
             ) -> list[tuple[np.ndarray, dict[str, np.ndarray | None]]]:
    """Arrays sampled at increasing times t [s] -> [(grid, arrays on grid), ...].

    Float arrays are interpolated linearly, bool/int arrays hold the previous sample; None stays None.
    t_grid given: one piece on it (NaN / False outside the samples' span). Else a uniform grid at rate_hz
    from the first sample; with max_gap_s the run is split where consecutive samples are more than
    max_gap_s apart (a gap is not bridged: no grid point lies in it) and each piece gets its own grid
    starting at its first sample. Pieces with fewer than 2 samples are dropped."""
    t = np.asarray(t, float)
    if t_grid is not None:
        pieces = [(0, len(t), np.asarray(t_grid, float))]
    else:
        if not rate_hz:
            raise ValueError("give t_grid or rate_hz")
        breaks = np.flatnonzero(np.diff(t) > max_gap_s) + 1 if max_gap_s is not None else np.zeros(0, int)
        pieces = [(lo, hi, uniform_grid(t[lo], t[hi - 1], rate_hz))
                  for lo, hi in zip(np.r_[0, breaks], np.r_[breaks, len(t)]) if hi - lo >= 2]
    out = []
    for lo, hi, grid in pieces:
        ts = t[lo:hi]
        res = {}
        for k, v in arrays.items():
            if v is None:
                res[k] = None
                continue
            v = np.asarray(v)[lo:hi]
            res[k] = interp_linear(ts, v, grid) if v.dtype.kind in "fc" else hold_previous(ts, v, grid)
        out.append((grid, res))
    return out


def heldout_spans(lengths: Sequence[int], frac: float, block_len: int | None = None, offset: int = 1,
                  min_tail: int = 0) -> tuple[list[Span], list[Span]]:
    """Split series of `lengths` samples into (train, held-out) spans (series index, start, stop).

    Tail (block_len None): the held-out part is the end of the data. Several series: the trailing whole
    series that make up at least `frac` of all samples (the first series always trains). One series: its
    trailing `frac` (cut at int(N * (1 - frac))).
    Blocks (block_len given): every series is cut into contiguous blocks of block_len samples (a last
    partial block shorter than min_tail joins the one before it); block b, counted over all series in
    order, is held out when (b + offset) % k == 0 with k = max(2, round(1 / frac)). Spread over the whole
    run, the held-out part has every phase of a trajectory (a tail would be its last phase only). A series
    shorter than a block is one block."""
    lengths = [int(n) for n in lengths]
    if not lengths:
        return [], []
    if block_len is None:
        if len(lengths) >= 2:
            need, k = frac * sum(lengths), len(lengths) - 1
            while k > 1 and sum(lengths[k:]) < need:
                k -= 1
            return ([(i, 0, n) for i, n in enumerate(lengths[:k])],
                    [(i, 0, n) for i, n in enumerate(lengths) if i >= k])
        cut = int(lengths[0] * (1 - frac))
        return [(0, 0, cut)], [(0, cut, lengths[0])]
    every = max(2, int(round(1.0 / frac)))
    block_len = max(1, int(block_len))
    train: list[Span] = []
    held: list[Span] = []
    b = 0
    for si, n in enumerate(lengths):
        starts = list(range(0, n, block_len))
        if len(starts) > 1 and n - starts[-1] < min_tail:
            starts.pop()
        for lo, hi in zip(starts, starts[1:] + [n]):
            (held if (b + offset) % every == 0 else train).append((si, lo, hi))
            b += 1
    return train, held


def spans_mask(spans: Sequence[Span], lengths: Sequence[int]) -> list[np.ndarray]:
    """Per series, a bool mask (N,) of the samples inside `spans`."""
    masks = [np.zeros(int(n), bool) for n in lengths]
    for si, lo, hi in spans:
        masks[si][lo:hi] = True
    return masks
