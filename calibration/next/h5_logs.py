"""The official NEXT free-motion H5 files (`factr2_next_h5_v1`, the paper's ROS 2 stack) read as NEXT logs.

Schema (the official recorder's, read from its published writer and record config): root attribute
`schema = "factr2_next_h5_v1"` (plus session_name, created_at); one group per episode `ep_NNNN`; in it one
group per recorded key holding `data` (rows x joints, float32) and `timestamps` (rows, int64 ns, the same
stamp for every key of a row). Keys are set by the record config, one arm or several by prefix:

    key (per arm: "<arm>_<key>" or "<key>")   read as        unit
    joint_pos                                  q              rad
    joint_vel                                  qd             rad/s   (absent: differentiated from q)
    joint_cmd                                  q_cmd          rad     (absent: inputs fall back to q, q_dot)
    measured_joint_torque / joint_effort       tau_m          N*m
    joint_current                              current        A       (when no torque key)

Every episode is one run (episodes of unequal length are fine); t [s] = (timestamps - the episode's first)
x 1e-9, subtracted in int64 first so that 10^18 ns stamps keep their ns. A key whose rows differ from
joint_pos's is aligned on the timestamps both have (a note says how many rows were dropped); an episode
without joint_pos or a torque key is skipped with a note. A file with several arms is read for the one named
as FILE.h5::ARM (or the only one). Anything that is not this schema is one ConfigError naming what is
missing. Joint names: the root attribute `joint_names` when present, else joint1..n.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hardware.errors import ConfigError

SCHEMA = "factr2_next_h5_v1"
KEYS = {"joint_pos": "q", "joint_vel": "qd", "joint_cmd": "q_cmd", "measured_joint_torque": "tau_m",
        "joint_effort": "tau_m", "joint_current": "current"}  # the record config's names -> plain-log arrays
H5_SUFFIXES = (".h5", ".hdf5")
FIX = "pass an H5 file written by the official NEXT recorder (factr2_next_h5_v1; docs/bringing_data.md)"


def split_arm(path: str | Path) -> tuple[Path, str | None]:
    """'run.h5::left' -> (Path('run.h5'), 'left'); a path without '::' -> (path, None)."""
    text = str(path)
    if "::" in text:
        p, arm = text.rsplit("::", 1)
        return Path(p), arm or None
    return Path(text), None


def _bad(path, what: str) -> ConfigError:
    return ConfigError(f"not a NEXT H5 file ({SCHEMA}): {what}", where=str(path), fix=FIX)


def _arms(keys: set[str]) -> list[str]:
    """The arm prefixes of an episode's keys: '' for unprefixed keys, 'left' for left_joint_pos, ..."""
    return sorted({k[: -len("joint_pos")].rstrip("_") for k in keys if k.endswith("joint_pos")})


def _read_key(group, key: str, path) -> tuple[np.ndarray, np.ndarray]:
    g = group[key]
    if not hasattr(g, "keys") or "data" not in g or "timestamps" not in g:
        raise _bad(path, f"{group.name}/{key} lacks data or timestamps")
    data = np.asarray(g["data"][()], float)
    ts = np.asarray(g["timestamps"][()])
    if ts.dtype.kind not in "iu":
        raise _bad(path, f"{group.name}/{key}/timestamps are {ts.dtype}, expected int64 ns")
    data = data.reshape(len(data), -1) if data.ndim != 2 else data
    if len(data) != len(ts):
        n = min(len(data), len(ts))
        data, ts = data[:n], ts[:n]
    return data, ts.astype(np.int64)


def _episode(path, group, prefix: str, joint_names) -> tuple[tuple | None, str]:
    """One episode as (run name, plain-log arrays, notes), or None and why it was skipped."""
    keys = set(group.keys())
    found = {k: f"{prefix}_{k}" if prefix else k for k in KEYS}
    found = {k: v for k, v in found.items() if v in keys}
    torque = next((k for k in ("measured_joint_torque", "joint_effort", "joint_current") if k in found), None)
    missing = [k for k, ok in (("joint_pos", "joint_pos" in found), ("a torque key", torque)) if not ok]
    if missing:
        return None, f"{group.name}: no {' or '.join(missing)} (has {', '.join(sorted(keys)) or 'nothing'})"
    q, ts = _read_key(group, found["joint_pos"], path)
    arrays, notes = {"q": q}, []
    for k in ("joint_vel", "joint_cmd", torque):
        if k not in found:
            continue
        a, t_k = _read_key(group, found[k], path)
        if a.shape[1] != q.shape[1]:
            raise _bad(path, f"{group.name}/{found[k]} has {a.shape[1]} columns, joint_pos {q.shape[1]}")
        if len(t_k) != len(ts) or not np.array_equal(t_k, ts):
            common, ia, ib = np.intersect1d(ts, t_k, return_indices=True)
            notes.append(f"{found[k]} has {len(t_k)} rows, joint_pos {len(ts)}: kept the {len(common)} rows "
                         "with the same timestamps")
            ts, arrays = common, {n: v[ia] for n, v in arrays.items()}
            a = a[ib]
        arrays[KEYS[k]] = a
    if len(ts) < 2:
        return None, f"{group.name}: {len(ts)} row(s)"
    arrays["t"] = (ts - ts[0]).astype(np.float64) * 1e-9
    if joint_names is not None and len(joint_names) == q.shape[1]:
        arrays["joint_names"] = np.asarray(joint_names)
    name = f"{Path(path).stem}_{group.name.strip('/')}" + (f"_{prefix}" if prefix else "")
    return (name, arrays, notes), ""


def read_h5(path: str | Path, arm: str | None = None) -> list[tuple[str, dict, list[str]]]:
    """Every episode of one arm of an official NEXT H5 file as (run name, plain-log arrays: t [s], q [rad],
    qd [rad/s], q_cmd [rad], tau_m [N*m] or current [A], notes) -- calibration.next.logs makes the runs of
    them (module docstring)."""
    try:
        import h5py
    except ModuleNotFoundError:
        raise ConfigError("reading H5 files needs h5py", where=str(path),
                          fix="pip install 'factr2-teleop[h5]' (or pip install h5py)") from None
    path = Path(path)
    try:
        f = h5py.File(path, "r")
    except OSError as e:
        raise _bad(path, f"cannot open as HDF5 ({str(e)[:60]})") from None
    with f:
        schema = f.attrs.get("schema")
        schema = schema.decode() if isinstance(schema, bytes) else schema
        if schema is not None and str(schema) != SCHEMA:
            raise _bad(path, f"root attribute schema is {schema!r}")
        eps = sorted(k for k in f.keys() if k.startswith("ep_") and hasattr(f[k], "keys"))
        if not eps:
            has = ", ".join(sorted(f.keys())) or "nothing"
            raise _bad(path, f"no ep_NNNN episode groups (root has {has})")
        arms = sorted({a for e in eps for a in _arms(set(f[e].keys()))})
        if not arms:
            raise _bad(path, "no joint_pos key in any episode")
        if arm is None and len(arms) > 1:
            raise ConfigError(f"the H5 file holds arms {', '.join(arms)}", where=str(path),
                              fix=f"name one: {path}::{arms[0]}")
        prefix = arms[0] if arm is None else arm
        if prefix not in arms:
            has = ", ".join(a or "(unprefixed)" for a in arms)
            raise ConfigError(f"no arm {prefix!r} in the H5 file (it has {has})", where=str(path),
                              fix=f"name one: {path}::{arms[0]}")
        names = f.attrs.get("joint_names")
        names = None if names is None else [n.decode() if isinstance(n, bytes) else str(n) for n in names]
        out, skipped = [], []
        for e in eps:
            r, why = _episode(path, f[e], prefix, names)
            (out.append(r) if r is not None else skipped.append(why))
    if not out:
        raise _bad(path, "no usable episode: " + "; ".join(skipped[:3]))
    if schema is None:
        out[0][2].insert(0, f"no root attribute schema: read as {SCHEMA}")
    if skipped:
        out[0][2].insert(0, f"skipped {len(skipped)} episode(s): " + "; ".join(skipped[:3]))
    return out
