"""NEXT data: plain logs -> fixed-rate segments -> normalised sliding windows.

Pipeline, top to bottom:
  1. resample_log(): irregular timestamps -> uniform grid at `rate_hz` (default 100 Hz, the paper's rate) by
     linear interpolation (hardware.timeseries: the one Segment type and resampler). Gaps longer than
     `max_gap_s` are not bridged: the run is split there into segments, and no window ever spans two.
  2. make_inputs(): per-sample features. "q,qd,dq" = (q [rad], q_dot [rad/s], q_cmd - q [rad]) as in the
     paper; "q" and "q,qd" reproduce the input ablation.
  3. split_blocks(): each segment is cut into contiguous blocks (default 10 s); every k-th block goes to
     validation. Windows are drawn entirely inside one block, so no train window shares a sample with a
     validation window (neighbouring samples are nearly identical: a random split would leak).
     With >= MIN_RUNS runs (segments grouped by their log's name), split_runs() also holds out whole runs:
     what training validates on then (TrainConfig.validation) is a trajectory it never saw -- extrapolation,
     the error that matters on a new task -- instead of blocks of runs it trains on (interpolation).
  4. Normalizer: per-feature mean/std of inputs and targets, fitted on the training blocks only; stored with
     the model (checkpoint metadata) together with the training input range used for the OOD flag.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import numpy as np

from hardware.timeseries import Segment, heldout_spans, resample

INPUT_SETS = ("q", "q,qd", "q,qd,dq")


def resample_log(log, rate_hz: float = 100.0, max_gap_s: float = 0.1) -> list[Segment]:
    """Resample a PlainLog (hardware.recording.plain_log) onto a `rate_hz` grid; split at gaps > max_gap_s.

    Linear interpolation of q, qd, q_cmd (None when not logged), tau (and tau_ext_true, temperature);
    `contact` takes the nearest earlier sample (hardware.timeseries.resample). Samples with any non-finite
    value are dropped first (treated as a gap).
    """
    t = np.asarray(log.t, float)
    arrays = {"q": log.q, "qd": log.qd, "tau": log.tau}
    if log.q_cmd is not None:  # None: not logged (calibration.next.logs; inputs then fall back to q, q_dot)
        arrays["q_cmd"] = log.q_cmd
    if log.tau_ext_true is not None:
        arrays["tau_ext_true"] = log.tau_ext_true
    finite = np.ones(len(t), bool)
    for a in arrays.values():
        finite &= np.all(np.isfinite(a), axis=1)
    temp = getattr(log, "temperature", None)
    if temp is not None and np.all(np.isfinite(np.asarray(temp, float)[finite])):  # partial: not used
        arrays["temperature"] = temp
    arrays = {k: np.asarray(v, float)[finite] for k, v in arrays.items()}
    if log.contact is not None:
        arrays["contact"] = np.asarray(log.contact, bool)[finite]
    meta = {"rate_hz": rate_hz, "name": str(getattr(log, "name", "")), "units": getattr(log, "units", "N*m"),
            "joint_names": tuple(getattr(log, "joint_names", ()) or ()), "arm": getattr(log, "arm", ""),
            "arm_sha256": getattr(log, "arm_sha256", "")}
    return [Segment(t=grid, **res, **meta)
            for grid, res in resample(t[finite], arrays, rate_hz, max_gap_s=max_gap_s)]


def logged_arm(segments) -> str | None:
    """The arm description every segment's log names (plain_log `arm`), or None when a log names none or
    they disagree: logs this app writes say which arm they come from, so --arm is only an override."""
    named = {getattr(s, "arm", "") for s in segments}
    return named.pop() if len(named) == 1 and "" not in named else None


def make_inputs(q: np.ndarray, qd: np.ndarray, q_cmd: np.ndarray, inputs: str = "q,qd,dq") -> np.ndarray:
    """Per-sample network inputs (N, F): q [rad], q_dot [rad/s], q_cmd - q [rad] as `inputs` selects."""
    if inputs not in INPUT_SETS:
        raise ValueError(f"inputs must be one of {INPUT_SETS}, got {inputs!r}")
    parts = [q]
    if inputs in ("q,qd", "q,qd,dq"):
        parts.append(qd)
    if inputs == "q,qd,dq":
        parts.append(q_cmd - q)
    return np.concatenate([np.asarray(p, np.float64) for p in parts], axis=-1)


def n_inputs(n_joints: int, inputs: str) -> int:
    return n_joints * (1 + inputs.count(","))


@dataclass
class Normalizer:
    """z = (x - mean) / std for inputs (x) and targets (y). Stored in checkpoints as plain lists."""

    x_mean: np.ndarray
    x_std: np.ndarray
    y_mean: np.ndarray
    y_std: np.ndarray

    @classmethod
    def fit(cls, x: np.ndarray, y: np.ndarray, eps: float = 1e-6, kind: str = "zscore") -> Normalizer:
        """kind "zscore": mean / standard deviation; "robust": median / (interquartile range / 1.349) (the
        same scale for Gaussian data; a few large samples -- fast runs, spikes -- do not shrink the rest)."""
        if kind == "zscore":
            return cls(x.mean(0), np.maximum(x.std(0), eps), y.mean(0), np.maximum(y.std(0), eps))
        if kind != "robust":
            raise ValueError(f"normaliser kind {kind!r}: use zscore or robust")

        def loc_scale(a):
            q25, q50, q75 = np.percentile(a, [25, 50, 75], axis=0)
            return q50, np.maximum((q75 - q25) / 1.349, eps)

        return cls(*loc_scale(x), *loc_scale(y))

    def norm_x(self, x):
        return (x - self.x_mean) / self.x_std

    def norm_y(self, y):
        return (y - self.y_mean) / self.y_std

    def denorm_y(self, z):
        return z * self.y_std + self.y_mean

    def to_dict(self) -> dict:
        keys = ("x_mean", "x_std", "y_mean", "y_std")
        return {k: np.asarray(getattr(self, k), float).tolist() for k in keys}

    @classmethod
    def from_dict(cls, d: dict) -> Normalizer:
        return cls(*(np.asarray(d[k], float) for k in ("x_mean", "x_std", "y_mean", "y_std")))


def split_blocks(lengths: list[int], block_len: int, val_every: int = 5, offset: int = 2
                 ) -> tuple[list[tuple[int, int, int]], list[tuple[int, int, int]]]:
    """Cut each segment (by length) into contiguous blocks of `block_len` samples; block b of the whole
    sequence goes to validation when (b + offset) % val_every == 0. Returns (train, val) lists of
    (segment index, start, stop). A segment shorter than a block is one block. The last partial block of a
    segment joins the previous one so no tiny block is made (hardware.timeseries.heldout_spans)."""
    train, val = heldout_spans(lengths, 1.0 / val_every, block_len, offset, min_tail=block_len // 2)
    if not train and val:  # a single tiny run: keep something to train on
        train, val = val, []
    return train, val


MIN_RUNS = 3  # fewer runs: holding one out would leave too little to train on, so blocks validate


def split_runs(names: list[str], lengths: list[int], val_every: int = 5, offset: int = 2
               ) -> tuple[list[tuple[int, int, int]], list[tuple[int, int, int]]] | None:
    """Whole-run split: segments are grouped into runs by name (in order of first appearance; "" is one
    run); run r is held out when (r + offset) % val_every == 0 -- the same rule as the blocks', counted in
    runs -- or, when that picks none, the last run. Returns (train, val) lists of whole segments
    (index, 0, length), or None with fewer than MIN_RUNS runs."""
    runs = list(dict.fromkeys(names))
    if len(runs) < MIN_RUNS:
        return None
    held = {r for i, r in enumerate(runs) if (i + offset) % val_every == 0} or {runs[-1]}
    train = [(i, 0, n) for i, (nm, n) in enumerate(zip(names, lengths)) if nm not in held]
    val = [(i, 0, n) for i, (nm, n) in enumerate(zip(names, lengths)) if nm in held]
    return train, val


def window_ends(blocks: list[tuple[int, int, int]], offsets: list[int], history: int) -> np.ndarray:
    """Global indices (into the concatenated segments) of the last sample of every full window that lies
    entirely inside one block. `offsets[si]` is the start of segment si in the concatenation."""
    ends = [offsets[si] + np.arange(lo + history - 1, hi) for si, lo, hi in blocks if hi - lo >= history]
    return np.concatenate(ends) if ends else np.zeros(0, np.int64)


@dataclass
class WindowData:
    """Everything training needs: normalised inputs/targets of all samples concatenated, and window ends."""

    x: np.ndarray  # (N, F) normalised float32
    y: np.ndarray  # (N, J) normalised float32
    train_ends: np.ndarray
    val_ends: np.ndarray
    normalizer: Normalizer
    x_min: np.ndarray  # raw training input range (for the OOD flag)
    x_max: np.ndarray
    history: int
    inputs: str
    data_hash: str
    n_samples: int
    meta: dict = field(default_factory=dict)
    # whole-run split (split_runs; empty arrays / [] when there are fewer than MIN_RUNS runs)
    run_train_ends: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    run_val_ends: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    val_runs: list[str] = field(default_factory=list)
    run_index: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # (N,) run of each sample
    # (runs = segments grouped by name, numbered in order of first appearance)


def data_hash(segments: list[Segment]) -> str:
    h = hashlib.sha256()
    for s in segments:
        for a in (s.q, s.qd, s.q_cmd, s.tau):
            if a is None:
                continue
            h.update(np.ascontiguousarray(a, np.float64).tobytes())
    return h.hexdigest()[:16]


def build_windows(segments: list[Segment], history: int = 50, inputs: str = "q,qd,dq",
                  block_s: float = 10.0, val_every: int = 5, normalize: str = "zscore") -> WindowData:
    """Concatenate segments, split into train/validation blocks, fit the normaliser on the train blocks."""
    if not segments:
        raise ValueError("no data segments to train on")
    rate = segments[0].rate_hz
    x_raw = np.concatenate([make_inputs(s.q, s.qd, s.q_cmd, inputs) for s in segments])
    y_raw = np.concatenate([s.tau for s in segments])
    lengths = [len(s) for s in segments]
    offsets = list(np.r_[0, np.cumsum(lengths)[:-1]].astype(int))
    block_len = max(int(round(block_s * rate)), 2 * history)
    train_b, val_b = split_blocks(lengths, block_len, val_every)
    train_ends = window_ends(train_b, offsets, history)
    val_ends = window_ends(val_b, offsets, history)
    if len(train_ends) == 0:
        raise ValueError(f"not enough data for one window of {history} samples")
    train_rows = np.concatenate([offsets[si] + np.arange(lo, hi) for si, lo, hi in train_b])
    norm = Normalizer.fit(x_raw[train_rows], y_raw[train_rows], kind=normalize)
    names = [getattr(s, "name", "") for s in segments]
    run_no = {nm: i for i, nm in enumerate(dict.fromkeys(names))}
    by_run = split_runs(names, lengths, val_every)
    run_tr, run_val = ((window_ends(b, offsets, history) for b in by_run) if by_run
                       else (np.zeros(0, np.int64), np.zeros(0, np.int64)))
    if len(run_tr) == 0 or len(run_val) == 0:  # a held-out run too short for one window: blocks only
        run_tr, run_val = np.zeros(0, np.int64), np.zeros(0, np.int64)
    val_runs = list(dict.fromkeys(names[si] for si, _, _ in by_run[1])) if len(run_val) else []
    # the normaliser stays the blocks' in either case: a scale of inputs, not a fit to the held-out run
    return WindowData(x=norm.norm_x(x_raw).astype(np.float32), y=norm.norm_y(y_raw).astype(np.float32),
                      train_ends=train_ends, val_ends=val_ends, normalizer=norm,
                      x_min=x_raw[train_rows].min(0), x_max=x_raw[train_rows].max(0), history=history,
                      inputs=inputs, data_hash=data_hash(segments), n_samples=len(x_raw),
                      run_train_ends=run_tr, run_val_ends=run_val, val_runs=val_runs,
                      run_index=np.repeat([run_no[nm] for nm in names], lengths).astype(np.int64))


VALIDATIONS = ("auto", "blocks", "runs")


def validation_split(data: WindowData, validation: str = "auto") -> tuple[np.ndarray, np.ndarray, str]:
    """(train ends, validation ends, "blocks" or "runs") as TrainConfig.validation asks: "auto" = whole
    held-out runs when the data has them (>= MIN_RUNS runs), else blocks; "runs" without them -> blocks."""
    if validation not in VALIDATIONS:
        raise ValueError(f"validation must be one of {VALIDATIONS}, got {validation!r}")
    if validation != "blocks" and len(data.run_val_ends):
        return data.run_train_ends, data.run_val_ends, "runs"
    return data.train_ends, data.val_ends, "blocks"


def gather_windows(x: np.ndarray, ends: np.ndarray, history: int) -> np.ndarray:
    """(B, H, F) windows ending (inclusive) at `ends`."""
    return x[ends[:, None] + np.arange(-history + 1, 1)[None, :]]


def sliding_windows(x: np.ndarray, history: int) -> np.ndarray:
    """All full windows of a (N, F) array: (N - H + 1, H, F) view (no copy)."""
    return np.lib.stride_tricks.sliding_window_view(x, history, axis=0).transpose(0, 2, 1)
