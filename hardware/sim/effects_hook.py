"""The undeclared-effect hook: a user function whose torque the twin's followers feel inside their drives.

    factr2 twin --rig sim-piper --twin-effect mypkg.effects:sticky_j2
    serve_twin("sim-piper", effect="mypkg.effects:sticky_j2")   # or effect=<callable>

f(t [s], q [rad], q_dot [rad/s]) -> tau [N*m] per arm joint is added to the drive's internal load (like
friction): it shows in the measured current / tau_m, never in a configuration an estimator reads, and
never in the ground-truth external torque. It tests whether NEXT learns effects nobody declared.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable

import numpy as np

from hardware.errors import ConfigError

HookFn = Callable[[float, np.ndarray, np.ndarray], np.ndarray]


def load_hook(spec: str | HookFn, n_check: int | None = None) -> HookFn:
    """Resolve "MODULE:FUNCTION" (or pass a callable through). With n_check, call it once on zeros and
    check it returns n_check finite values. Any problem is a one-line ConfigError."""
    where = "--twin-effect"
    if callable(spec):
        fn = spec
        label = getattr(spec, "__name__", repr(spec))
    else:
        label = str(spec)
        mod_name, sep, fn_name = label.partition(":")
        if not sep or not mod_name or not fn_name:
            raise ConfigError(f"effect {label!r} is not MODULE:FUNCTION", where=where,
                              fix="write it like mypkg.effects:my_torque")
        try:
            mod = importlib.import_module(mod_name)
        except Exception as e:  # ImportError, or the module itself failing to import
            raise ConfigError(f"cannot import module {mod_name!r} ({type(e).__name__}: {e})", where=where,
                              fix="check the module name and that it is on PYTHONPATH") from None
        fn = mod
        for part in fn_name.split("."):
            fn = getattr(fn, part, None)
            if fn is None:
                raise ConfigError(f"module {mod_name!r} has no {fn_name!r}", where=where,
                                  fix="check the function name after the colon") from None
        if not callable(fn):
            raise ConfigError(f"{label!r} is not callable", where=where, fix="point at a function")
    if n_check is not None:
        try:
            tau = np.asarray(fn(0.0, np.zeros(n_check), np.zeros(n_check)), dtype=float).reshape(-1)
        except Exception as e:
            raise ConfigError(f"effect {label!r} failed on a test call ({type(e).__name__}: {e})",
                              where=where, fix="f(t, q, q_dot) must accept floats and numpy arrays") from None
        if tau.shape != (n_check,) or not np.all(np.isfinite(tau)):
            raise ConfigError(f"effect {label!r} returned shape {tau.shape}, expected ({n_check},) finite",
                              where=where, fix="return one torque [N*m] per arm joint")
    return fn


def call_hook(fn: HookFn, t: float, q: np.ndarray, v: np.ndarray, k: int,
              n: int) -> tuple[np.ndarray, str | None]:
    """The hook's load on the first k of n joints at (t [s], q [rad], v [rad/s]) -> (tau [N*m] (n,), None),
    or (zeros, why) when it raises or returns a wrong shape or non-finite values: a broken effect must not
    stop the physics (the bank counts and shows it)."""
    try:
        tau = np.asarray(fn(t, q[:k].copy(), v[:k].copy()), dtype=float).reshape(-1)
        if tau.shape == (k,) and np.all(np.isfinite(tau)):
            return (tau if k == n else np.concatenate([tau, np.zeros(n - k)])), None
        why = f"returned shape {tau.shape} or non-finite values"
    except Exception as e:
        why = f"{type(e).__name__}: {e}"
    return np.zeros(n), why
