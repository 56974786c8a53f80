"""Per-joint parameters: rig files give a scalar (same on every joint) or one value per joint."""

from __future__ import annotations

from typing import Union

import numpy as np

from hardware.errors import ConfigError

PerJoint = Union[float, list]  # a scalar, or a list with one value per joint


def clamp(x: np.ndarray, lo, hi) -> np.ndarray:
    """np.clip without its Python-level overhead (2-3x faster on small arrays; this runs at 500 Hz)."""
    return np.minimum(np.maximum(x, lo), hi)


def per_joint(value, n: int, where: str, *, positive: bool = False, nonneg: bool = False) -> np.ndarray:
    """Broadcast a scalar or check a per-joint list: (n,) finite floats, or ConfigError naming `where`."""
    try:
        a = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ConfigError(f"{value!r} is not a number or a list of numbers", where=where,
                          fix=f"give one number or {n} numbers") from None
    if a.size == 1:
        a = np.full(n, a[0])
    if a.shape != (n,):
        raise ConfigError(f"has {a.size} values, expected 1 or {n}", where=where,
                          fix=f"give one number or one per joint ({n})")
    if np.any(np.isnan(a) | (a == -np.inf)):  # +inf is allowed: "no limit"
        raise ConfigError("contains NaN or -inf", where=where, fix="use finite numbers")
    if positive and np.any(a <= 0):
        raise ConfigError(f"must be > 0 on every joint, got {a.tolist()}", where=where,
                          fix="use positive values")
    if nonneg and np.any(a < 0):
        raise ConfigError(f"must be >= 0 on every joint, got {a.tolist()}", where=where,
                          fix="use values >= 0")
    return a
