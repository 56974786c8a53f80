"""FIRST phase labels (paper Sec. 5): free motion, pre-contact, contact, from the NEXT external torque.

    score  f_t = ||tau_ext_t||_1                       [N*m] (or [A] for a current-unit checkpoint)
    contact: every run of samples above T_low that reaches T_high somewhere (`contact_runs`: hysteresis in
             both directions of time, as offline labels can look ahead; a contact's rise below T_high, before
             the crossing, is contact too, not only its fall)
    onset: a sample in contact whose predecessor is not (sample 0 counts when it is in contact)
    pre-contact: samples within `pre_s` (1 s) before an onset, never a contact sample, clipped at the start
    free: the rest

Default thresholds come from the recordings themselves (`recording_thresholds`): contact only adds large
scores, so the score distribution of an episode set is free-motion noise plus a contact part above it.
With o = Otsu's threshold of log f over every sample of the set (the split into two classes with the largest
between-class variance, i.e. the valley between the noise and the contact): T_low = OTSU_LOW_X * o, T_high =
OTSU_HIGH_X * o, a band around the valley (measured against the twin's truth, docs/first_labels.md: T_low = o
itself cut a contact's weak start and end, recall 79-83 % on peg-insert and press-fit).
Nothing in it is fitted to data; it assumes the set has contact (a set without any is split inside its free
motion: check the figures, or pass thresholds). The former source remains: the NEXT checkpoint's measured
free-motion noise, its validation L1 per joint (metrics["val_l1"]): with s = sum_j val_l1_j (the mean
free-motion score on the calibration replay), T_low = LOW_X * s and T_high = HIGH_X * s; on teleop motion,
far from the replay, it sits well below the free-motion scores (docs/first_labels.md). Both are overridable.
"""

from __future__ import annotations

import numpy as np

FREE, PRE_CONTACT, CONTACT = 0, 1, 2
PHASE_NAMES = ("free", "pre-contact", "contact")
PHASE_SHORT = ("F", "PC", "C")
PRE_CONTACT_S = 1.0  # the paper's pre-contact window before each onset [s]
LOW_X, HIGH_X = 2.0, 3.0  # checkpoint source: thresholds as multiples of the mean free-motion score
# the recording source's band around Otsu's valley o: off at 2/3 o, on at 5/4 o (chosen on the seed-1
# collections against the twin's truth, checked on the seed-9 ones: docs/first_labels.md "Contact runs")
OTSU_LOW_X, OTSU_HIGH_X = 2.0 / 3.0, 1.25
LABEL_RULE = "runs; recording band 2/3:5/4 of Otsu"  # what a run's meta and the benchmark's ledger compare
OTSU_BINS = 256  # histogram of log f for Otsu's threshold
MIN_ERROR_SHARE = 0.005  # min_error_log_threshold: the least share of the samples either class may hold
SPLITS = ("otsu", "min-error")  # how the recording source places its valley o (the default: otsu)


def contact_score(tau_ext: np.ndarray) -> np.ndarray:
    """f_t = sum_j |tau_ext_tj| for tau_ext (N, J); NaN where any joint is NaN (no estimate yet)."""
    tau = np.asarray(tau_ext, dtype=float)
    return np.abs(tau).sum(axis=1) if tau.ndim == 2 else np.abs(tau)


def hysteresis(score: np.ndarray, t_low: float, t_high: float) -> np.ndarray:
    """Contact state (N,) bool: switches on at score >= t_high, off at score <= t_low, else keeps the previous
    state; starts off. NaN scores (no estimate) keep the state."""
    if not t_low <= t_high:
        raise ValueError(f"t_low {t_low} must be <= t_high {t_high}")
    s = np.asarray(score, dtype=float)
    on = s >= t_high
    off = s <= t_low
    # the state after sample i is the last decisive event (on or off) at or before i
    event = np.where(on, 1, np.where(off, 0, -1))
    idx = np.where(event >= 0, np.arange(len(s)), -1)
    last = np.maximum.accumulate(idx) if len(s) else idx
    return np.where(last >= 0, event[np.maximum(last, 0)] == 1, False)


def contact_runs(score: np.ndarray, t_low: float, t_high: float) -> np.ndarray:
    """Offline contact (N,) bool: the samples of every run above t_low that reaches t_high somewhere, i.e.
    `hysteresis` forward in time or backward (a contact rises through t_low before it crosses t_high; the
    causal form, as live feedback must be, starts it only at the crossing). NaN scores keep the state."""
    s = np.asarray(score, dtype=float)
    return hysteresis(s, t_low, t_high) | hysteresis(s[::-1], t_low, t_high)[::-1]


def onsets(contact: np.ndarray) -> np.ndarray:
    """Indices where contact starts (a contact sample after a non-contact one; index 0 if in contact)."""
    c = np.asarray(contact, dtype=bool)
    prev = np.concatenate([[False], c[:-1]])
    return np.flatnonzero(c & ~prev)


def label_phases(t: np.ndarray, contact: np.ndarray, pre_s: float = PRE_CONTACT_S) -> np.ndarray:
    """Phase per sample (N,) int8: CONTACT where in contact, PRE_CONTACT for samples with
    t_onset - pre_s <= t < t_onset (any sample rate; clipped at the first sample; never over contact),
    FREE elsewhere. t [s] ascending."""
    t = np.asarray(t, dtype=float)
    c = np.asarray(contact, dtype=bool)
    out = np.full(len(t), FREE, dtype=np.int8)
    for k in onsets(c):
        lo = np.searchsorted(t, t[k] - pre_s, side="left")
        out[lo:k] = PRE_CONTACT
    out[c] = CONTACT
    return out


def phases_from_torque(
    t: np.ndarray, tau_ext: np.ndarray, t_low: float, t_high: float, pre_s: float = PRE_CONTACT_S
) -> np.ndarray:
    """The whole labelling: tau_ext (N, J) at times t [s] -> phase per sample (N,) int8."""
    return label_phases(t, contact_runs(contact_score(tau_ext), t_low, t_high), pre_s)


def phase_shares(phases: np.ndarray) -> np.ndarray:
    """Fraction of samples in each phase (3,); zeros for an empty array."""
    p = np.asarray(phases)
    if len(p) == 0:
        return np.zeros(3)
    return np.bincount(p.astype(np.int64), minlength=3)[:3] / len(p)


def labels_warning(shares) -> str:
    """One line when a set's labelled shares (free, pre-contact, contact) [fractions] look like a contact
    threshold inside the free-motion noise, else "". The sign: more pre-contact than free motion. Pre-contact
    is the PRE_CONTACT_S before each onset, so it outweighs free motion only when onsets come more often than
    about one every 2 s across the whole set, as the noise crossing a threshold does; no measured set with
    sound labels came near it (docs/first_labels.md, 'Otsu with a small contact share')."""
    free, pre = float(shares[FREE]), float(shares[PRE_CONTACT])
    if not pre > free:
        return ""
    return (f"warning: FIRST's labels put more samples in pre-contact ({pre:.0%}) than in free motion "
            f"({free:.0%}): contact onsets come faster than one every ~2 s, as when the contact threshold "
            "sits inside the free-motion noise (docs/first_labels.md, 'Otsu with a small contact share'); "
            "check `factr2 episodes phases` and its figures, or pass --thresholds LOW:HIGH [N*m]")


def default_thresholds(val_l1) -> tuple[float, float]:
    """(T_low, T_high) from a NEXT checkpoint's free-motion validation L1 per joint (see module doc)."""
    s = float(np.sum(np.abs(np.asarray(val_l1, dtype=float))))
    if not np.isfinite(s) or s <= 0:
        raise ValueError("the NEXT checkpoint has no usable free-motion noise (metrics.val_l1)")
    return LOW_X * s, HIGH_X * s


def _log_histogram(score: np.ndarray, bins: int) -> tuple[np.ndarray, np.ndarray]:
    """(p (bins,) probabilities, edges (bins + 1,)) of log(score) over its finite positive samples,
    between the 0.1 and 99.9 percentiles (outliers go to the end bins). ValueError with fewer than 2
    distinct values."""
    s = np.asarray(score, dtype=float).ravel()
    x = np.log(s[np.isfinite(s) & (s > 0)])
    if len(x) < 2 or np.ptp(x) == 0:
        raise ValueError("too few distinct contact scores to split")
    lo, hi = np.percentile(x, [0.1, 99.9])
    if hi <= lo:
        lo, hi = x.min(), x.max()
    h, edges = np.histogram(np.clip(x, lo, hi), bins=bins, range=(lo, hi))
    return h / h.sum(), edges


def otsu_log_threshold(score: np.ndarray, bins: int = OTSU_BINS) -> float:
    """Otsu's threshold of log(score) [same unit as score]: the split of the finite positive samples into a
    low and a high class with the largest between-class variance, computed on a histogram of log(score)
    between its 0.1 and 99.9 percentiles (outliers go to the end bins). Where several splits tie (an empty
    gap between the classes), the middle of the tied ones. ValueError with fewer than 2 distinct values."""
    p, edges = _log_histogram(score, bins)
    centre = 0.5 * (edges[1:] + edges[:-1])
    w0, m0 = np.cumsum(p)[:-1], np.cumsum(p * centre)[:-1]  # split after bin k, k = 0 .. bins - 2
    mt = float(np.sum(p * centre))
    with np.errstate(divide="ignore", invalid="ignore"):
        between = np.where((w0 > 0) & (w0 < 1), (mt * w0 - m0) ** 2 / (w0 * (1 - w0)), -np.inf)
    best = np.flatnonzero(between >= between.max() * (1 - 1e-9))
    k = best[len(best) // 2]
    return float(np.exp(edges[k + 1]))


def min_error_log_threshold(score: np.ndarray, bins: int = OTSU_BINS, min_share: float = MIN_ERROR_SHARE
                            ) -> float:
    """Kittler and Illingworth's minimum-error threshold of log(score) [same unit as score], on the same
    histogram as `otsu_log_threshold`: the split whose two classes, each fitted with its own normal
    distribution (own share, mean and variance), best explain the histogram, i.e. the minimum of
    J = w0 ln var0 + w1 ln var1 - 2 (w0 ln w0 + w1 ln w1). Unlike Otsu's (equal variances, and a pull towards
    equal shares) it holds where contact is a small share of the samples and spreads wider than the
    free-motion noise (docs/first_labels.md, "Otsu with a small contact share"). Splits leaving a class under
    `min_share` of the samples or with less variance than one bin's are not considered (J runs to -inf
    there). ValueError with fewer than 2 distinct values or no admissible split."""
    p, edges = _log_histogram(score, bins)
    centre = 0.5 * (edges[1:] + edges[:-1])
    w0 = np.cumsum(p)[:-1]
    m0, s0 = np.cumsum(p * centre)[:-1], np.cumsum(p * centre**2)[:-1]
    mt, st = float(np.sum(p * centre)), float(np.sum(p * centre**2))
    w1 = 1.0 - w0
    floor = (edges[1] - edges[0]) ** 2 / 12.0  # a uniform bin's variance
    with np.errstate(divide="ignore", invalid="ignore"):
        var0 = s0 / w0 - (m0 / w0) ** 2
        var1 = (st - s0) / w1 - ((mt - m0) / w1) ** 2
        j = w0 * np.log(var0) + w1 * np.log(var1) - 2.0 * (w0 * np.log(w0) + w1 * np.log(w1))
    ok = (w0 >= min_share) & (w1 >= min_share) & (var0 > floor) & (var1 > floor) & np.isfinite(j)
    if not ok.any():
        raise ValueError("no split leaves both classes a share and a spread")
    k = int(np.flatnonzero(ok)[np.argmin(j[ok])])
    return float(np.exp(edges[k + 1]))


def valley(score: np.ndarray, split: str = "otsu") -> float:
    """The valley o [score's unit] between free motion and contact in log f, placed by `split` (SPLITS)."""
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}: one of {', '.join(SPLITS)}")
    return otsu_log_threshold(score) if split == "otsu" else min_error_log_threshold(score)


def recording_thresholds(score: np.ndarray, split: str = "otsu") -> tuple[float, float]:
    """(T_low, T_high) from the scores of a whole episode set (see module doc): OTSU_LOW_X and OTSU_HIGH_X
    times the valley o of log f, placed by `split` (SPLITS: Otsu's, the default, or the minimum-error one,
    measured beside it by bench/label_truth.py --split)."""
    o = valley(score, split)
    return OTSU_LOW_X * o, OTSU_HIGH_X * o


def parse_thresholds(text: str) -> tuple[float, float]:
    """'LOW:HIGH' -> (T_low, T_high), 0 <= LOW <= HIGH; ValueError with the reason otherwise."""
    parts = str(text).split(":")
    if len(parts) != 2:
        raise ValueError(f"{text!r} is not LOW:HIGH")
    lo, hi = (float(p) for p in parts)
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 <= lo <= hi):
        raise ValueError(f"{text!r}: need 0 <= LOW <= HIGH")
    return lo, hi
