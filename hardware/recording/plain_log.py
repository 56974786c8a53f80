"""The plain log format for imported data (any arm's logs): one .npz per run.

Required arrays (N samples, n joints):
  t [s] (strictly increasing after dropping duplicates; irregular spacing allowed), q [rad], qd [rad/s],
  q_cmd [rad], and either tau_m [N*m] (measured motor torque) or current [A].
Optional: torque_constant [N*m/A] (n,) -- turns current into tau_m; temperature [degC] (N, n);
  tau_ext_true [N*m] (N, n) ground-truth external torque; force (N, k);
  contact (N,) bool;
  joint_names (n,) str; arm () str, the arm description's name (hardware.arms), and arm_sha256 () str, the
  SHA-256 of its file when the log was written: which arm the log comes from, so that diagnosis and
  calibration need no --arm. Other keys are kept in `extra`.
With current and no torque constant the torque signal stays in A (`units == "A"`): estimates made
from it are in current units.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hardware.errors import ConfigError

REQUIRED = ("t", "q", "qd", "q_cmd")
OPTIONAL = ("torque_constant", "temperature", "tau_ext_true", "force", "contact", "joint_names", "arm",
            "arm_sha256")


@dataclass
class PlainLog:
    """One run. `tau` is the measured torque signal in `units` ("N*m" or "A")."""

    path: Path
    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    q_cmd: np.ndarray
    tau: np.ndarray
    units: str
    joint_names: list[str]
    temperature: np.ndarray | None = None
    tau_ext_true: np.ndarray | None = None
    force: np.ndarray | None = None
    contact: np.ndarray | None = None
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    arm: str = ""  # arm description name ("" = not recorded)
    arm_sha256: str = ""  # SHA-256 of that description's file when the log was written

    @property
    def n_joints(self) -> int:
        return int(self.q.shape[1])

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0]) if len(self.t) > 1 else 0.0

    @property
    def name(self) -> str:
        return self.path.stem


def _bad(path: Path, what: str, fix: str) -> ConfigError:
    return ConfigError(what, where=str(path), fix=fix)


def load_plain_log(path: str | Path) -> PlainLog:
    """Read and validate one plain .npz log. Any problem is a ConfigError naming the file, key and fix."""
    path = Path(path)
    if not path.exists():
        raise _bad(path, "file not found", "check the path")
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except (zipfile.BadZipFile, ValueError, OSError, EOFError) as e:
        raise _bad(path, f"not a readable .npz file ({type(e).__name__})",
                   "pass a NumPy .npz log (see docs/recording.md, plain log format)") from None
    missing = [k for k in REQUIRED if k not in data]
    if "tau_m" not in data and "current" not in data:
        missing.append("tau_m or current")
    if missing:
        raise _bad(path, f"missing array(s): {', '.join(missing)}",
                   "a plain log needs t, q, qd, q_cmd and tau_m [N*m] or current [A]")
    t = np.asarray(data["t"], dtype=float).reshape(-1)
    n_samples = t.shape[0]
    if n_samples < 2:
        raise _bad(path, f"only {n_samples} sample(s)", "a log needs at least 2 samples")
    q = np.asarray(data["q"], dtype=float)
    if q.ndim != 2 or q.shape[0] != n_samples:
        raise _bad(path, f"q has shape {q.shape}, expected ({n_samples}, n_joints)", "store q as (N, n) rad")
    n = q.shape[1]

    def arr2(key: str) -> np.ndarray:
        a = np.asarray(data[key], dtype=float)
        if a.shape != (n_samples, n):
            raise _bad(path, f"{key} has shape {a.shape}, expected {(n_samples, n)}",
                       f"store {key} with one row per sample of t and one column per joint")
        return a

    qd, q_cmd = arr2("qd"), arr2("q_cmd")
    if "tau_m" in data:
        tau, units = arr2("tau_m"), "N*m"
    else:
        tau, units = arr2("current"), "A"
        if "torque_constant" in data:
            k = np.asarray(data["torque_constant"], dtype=float).reshape(-1)
            if k.shape != (n,):
                raise _bad(path, f"torque_constant has {k.shape[0]} entries, expected {n}",
                           "one N*m/A value per joint")
            tau, units = tau * k, "N*m"
    names = ([str(s) for s in np.asarray(data["joint_names"]).reshape(-1)] if "joint_names" in data
             else [f"joint{i + 1}" for i in range(n)])
    if len(names) != n:
        raise _bad(path, f"joint_names has {len(names)} names for {n} joints", "one name per column of q")
    # Drop non-increasing timestamps (duplicates in logged data) rather than failing.
    keep = np.concatenate([[True], np.diff(t) > 0])
    if not np.all(np.isfinite(t)):
        raise _bad(path, "t contains NaN or inf", "timestamps must be finite seconds")
    opt = {k: data[k] for k in ("temperature", "tau_ext_true") if k in data}
    log = PlainLog(path=path, t=t[keep], q=q[keep], qd=qd[keep], q_cmd=q_cmd[keep], tau=tau[keep],
                   units=units, joint_names=names,
                   temperature=arr2("temperature")[keep] if "temperature" in opt else None,
                   tau_ext_true=arr2("tau_ext_true")[keep] if "tau_ext_true" in opt else None)
    if "force" in data:
        f = np.asarray(data["force"], dtype=float)
        if f.shape[0] != n_samples:
            raise _bad(path, f"force has {f.shape[0]} rows for {n_samples} samples", "one row per sample")
        log.force = f[keep]
    if "contact" in data:
        c = np.asarray(data["contact"]).reshape(-1)
        if c.shape[0] != n_samples:
            raise _bad(path, f"contact has {c.shape[0]} entries for {n_samples} samples", "one per sample")
        log.contact = c[keep].astype(bool)
    for key in ("arm", "arm_sha256"):
        if key in data:
            v = np.asarray(data[key])
            if v.ndim != 0 or v.dtype.kind not in "US":
                raise _bad(path, f"{key} is {v.dtype} of shape {v.shape}, expected one string",
                           f"store {key} as np.array('...')")
            setattr(log, key, str(v))
    known = set(REQUIRED) | set(OPTIONAL) | {"tau_m", "current"}
    log.extra = {k: v[keep] if (v.ndim >= 1 and v.shape[0] == n_samples) else v
                 for k, v in data.items() if k not in known}
    return log


def save_plain_log(path: str | Path, **arrays) -> Path:
    """Write a plain log (the inverse of load_plain_log); validates by reading it back."""
    path = Path(path)
    np.savez(path, **{k: np.asarray(v) for k, v in arrays.items() if v is not None})
    load_plain_log(path)
    return path
