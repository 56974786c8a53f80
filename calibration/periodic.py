"""Position-periodic content of a residual (ripple, cogging, gear meshing): a least-squares periodogram
against joint position and the best period. Shared by the diagnosis loop (calibration/diagnosis/trace.py)
and NEXT's identified prior (calibration/next/prior.py)."""

from __future__ import annotations

import numpy as np


def periodogram(q: np.ndarray, r: np.ndarray, periods: np.ndarray, weights: np.ndarray | None = None
                ) -> np.ndarray:
    """Fraction of sum(w r^2) explained by a*sin(2 pi q / P) + b*cos(2 pi q / P) for each period P [rad].
    A least-squares (Lomb-Scargle-like) periodogram of the residual against joint position: q is irregular
    (it follows the motion), so no FFT; each period gets its own weighted 2-parameter fit."""
    w8 = np.ones_like(r) if weights is None else weights
    rr = float(np.sum(w8 * r * r)) or 1.0
    out = np.empty(len(periods))
    for s in range(0, len(periods), 64):
        w = 2 * np.pi / periods[s:s + 64]
        ph = np.outer(q, w)
        c, sn = np.cos(ph), np.sin(ph)
        wc, ws = w8[:, None] * c, w8[:, None] * sn
        cc, ss, cs = np.sum(wc * c, 0), np.sum(ws * sn, 0), np.sum(wc * sn, 0)
        cr, sr = r @ wc, r @ ws
        det = np.maximum(cc * ss - cs * cs, 1e-12)
        a = (ss * cr - cs * sr) / det
        b = (cc * sr - cs * cr) / det
        out[s:s + 64] = (a * cr + b * sr) / rr
    return out


def bin_by_position(q: np.ndarray, r: np.ndarray, width: float):
    """(bin centres, mean residual, counts) of r in bins of q `width` [rad] wide: a periodic effect in q
    survives the averaging when width << period, and the periodogram gets many times cheaper."""
    k = np.floor((q - q.min()) / width).astype(int)
    counts = np.bincount(k)
    sums = np.bincount(k, weights=r)
    qs = np.bincount(k, weights=q)
    keep = counts > 0
    return qs[keep] / counts[keep], sums[keep] / counts[keep], counts[keep].astype(float)


def find_period(q: np.ndarray, r: np.ndarray, p_min: float = 0.02, p_max: float | None = None):
    """(best period [rad], explained fraction, peak-to-median ratio of the periodogram) or None when the
    joint moved too little for a period to be resolved."""
    span = float(np.ptp(q))
    p_max = min(span / 2.0, np.pi) if p_max is None else p_max
    if p_max <= 2 * p_min:
        return None
    # frequency grid fine enough that neighbouring frequencies differ by a quarter cycle over the span
    f = np.arange(1.0 / p_max, 1.0 / p_min, 1.0 / (4.0 * span))
    qb, rb, wb = bin_by_position(q, r, p_min / 20.0)
    power = periodogram(qb, rb, 1.0 / f, wb)
    k = int(np.argmax(power))
    f_fine = np.linspace(f[max(k - 1, 0)], f[min(k + 1, len(f) - 1)], 41)
    p_fine = periodogram(q, r, 1.0 / f_fine)
    kf = int(np.argmax(p_fine))
    return float(1.0 / f_fine[kf]), float(p_fine[kf]), float(power[k] / max(np.median(power), 1e-12))
