"""Checks on small joint vectors (6-7 floats) as plain Python over .tolist(): the 500 Hz loop's hot path.

A numpy reduction (`.all()`, `.any()`, `count_nonzero`, `bitwise_or.reduce`) on a 6-element array costs
~3-5x a `tolist()` and a builtin over the list (issue #53: ~35 of them per teleop tick). Same answers as
the numpy forms for 1-D arrays: NaN is not finite and differs from itself, as in numpy.
"""

from __future__ import annotations

import math
from functools import reduce
from operator import ne, or_

import numpy as np

__all__ = ["all_finite", "count_changed", "bits_or", "all_within", "abs_sum", "np_max", "np_min",
           "clamp_floats"]


def all_finite(a: np.ndarray) -> bool:
    """np.isfinite(a).all() for a 1-D array: a finite sum has no NaN or inf in it (cheaper than a test per
    value); a sum that is not finite (one, or an overflow) is looked at value by value."""
    x = a.tolist()
    return math.isfinite(sum(x)) or all(map(math.isfinite, x))


def count_changed(a: np.ndarray, b: np.ndarray) -> int:
    """int(np.count_nonzero(a != b)) for two 1-D arrays of one shape (NaN counts as changed)."""
    return sum(map(ne, a.tolist(), b.tolist()))


def bits_or(a: np.ndarray) -> int:
    """int(np.bitwise_or.reduce(a)) for a 1-D integer array (0 when empty)."""
    return reduce(or_, a.tolist(), 0)


def all_within(d: np.ndarray, tol: float) -> bool:
    """(abs(d) <= tol).all() for a 1-D float array and a float tol (NaN is not within)."""
    return all(map(float(tol).__ge__, map(abs, d.tolist())))


def abs_sum(a: np.ndarray) -> float:
    """float(np.abs(a).sum()) for a 1-D float array of fewer than 8 entries, bit for bit: numpy adds fewer
    than 8 in order (its pairwise sum's base case), as this loop does (not sum(): Python 3.12 compensates)."""
    s = 0.0
    for x in a.tolist():
        s += abs(x)
    return s


# numpy's elementwise maximum / minimum on two floats, bit for bit: NaN in either gives NaN (the first
# operand's when both are), and a tie (0.0 and -0.0) gives the SECOND operand (numpy 2: `a > b ? a : b`
# with NaN propagated). Python's max()/min() differ on both. Hot loops inline these same expressions.
def np_max(a: float, b: float) -> float:
    """np.maximum(a, b) on floats."""
    return a if (a > b or a != a) else b


def np_min(a: float, b: float) -> float:
    """np.minimum(a, b) on floats."""
    return a if (a < b or a != a) else b


def clamp_floats(x: list[float], lo: list[float], hi: list[float]) -> list[float]:
    """np.minimum(np.maximum(x, lo), hi) on lists of floats (hardware.params.clamp), bit for bit."""
    out = []
    for v, a, b in zip(x, lo, hi, strict=True):
        v = v if (v > a or v != v) else a
        out.append(v if (v < b or v != v) else b)
    return out
