"""Reading any reasonable log for NEXT: plain .npz logs (hardware/recording/plain_log.py) and MCAP
recordings, with the defects real logs have, each handled and said once (`LogRead.notes`):

- no q_cmd (a velocity-controlled arm logs no commanded position): the log is read with q_cmd = None and the
  network's inputs fall back to (q, q_dot) (`fallback_inputs`); no qd: differentiated from q.
- corrupt rows: NaN/inf in t, q, qd, q_cmd or the torque signal, and times out of order. The rows kept are
  the largest set whose times increase (a longest increasing subsequence: a single wild timestamp costs one
  row, a clock that jumps back costs the overlapping stretch, never the rest of the log); the others are
  dropped with a note saying how many and where.
- irregular sample times (e.g. 2-30 ms steps at ~100 Hz): kept as logged; calibration.next.data.resample_log
  puts every log on the one rate with hardware.timeseries.resample, so logs of different rates and lengths
  train together. The note gives the logged steps.
- current without a torque constant: trained and scored in A (`units`), said in the note.
"""

from __future__ import annotations

import bisect
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hardware.errors import ConfigError
from hardware.recording.plain_log import PlainLog

NOTE_MAX_PLACES = 4  # how many places a note lists before "..."


@dataclass
class LogRead:
    """One run read for NEXT: the log (q_cmd None when not logged) and what was done to it."""

    name: str
    log: PlainLog
    notes: list[str] = field(default_factory=list)
    dropped: int = 0  # corrupt rows dropped

    @property
    def has_q_cmd(self) -> bool:
        return self.log.q_cmd is not None


def increasing_rows(t: np.ndarray) -> np.ndarray:
    """(N,) bool: the largest set of rows of finite t [s] whose times strictly increase (longest increasing
    subsequence, O(N log N)); non-finite times are never kept."""
    t = np.asarray(t, float)
    tails: list[float] = []  # smallest last time of an increasing run of each length
    tail_idx: list[int] = []
    parent = np.full(len(t), -1)
    for i, v in enumerate(t):
        if not np.isfinite(v):
            continue
        k = bisect.bisect_left(tails, v)
        parent[i] = tail_idx[k - 1] if k else -1
        if k == len(tails):
            tails.append(v)
            tail_idx.append(i)
        else:
            tails[k], tail_idx[k] = v, i
    keep = np.zeros(len(t), bool)
    i = tail_idx[-1] if tail_idx else -1
    while i >= 0:
        keep[i] = True
        i = parent[i]
    return keep


def places(rows: np.ndarray, t: np.ndarray) -> str:
    """'rows 10-12 (t 0.10 s), 400 (t 4.00 s), ...': where the given row indices are, grouped in runs."""
    rows = np.asarray(rows, int)
    if len(rows) == 0:
        return ""
    runs = np.split(rows, np.flatnonzero(np.diff(rows) != 1) + 1)
    out = []
    for r in runs[:NOTE_MAX_PLACES]:
        at = t[r[0]] if np.isfinite(t[r[0]]) else np.nan
        span = f"{r[0]}" if len(r) == 1 else f"{r[0]}-{r[-1]}"
        out.append(f"{span} (t {at:.2f} s)" if np.isfinite(at) else f"{span} (t not finite)")
    more = ", ..." if len(runs) > NOTE_MAX_PLACES else ""
    return "rows " + ", ".join(out) + more


def clean_rows(t: np.ndarray, arrays: dict[str, np.ndarray | None]) -> tuple[np.ndarray, str]:
    """Rows to keep (N,) bool and a note ('' when nothing is dropped): rows with a non-finite value in t or
    any of `arrays` (each (N, ...)), then rows out of time order (increasing_rows)."""
    t = np.asarray(t, float)
    finite = np.isfinite(t)
    for a in arrays.values():
        if a is not None:
            finite &= np.all(np.isfinite(np.asarray(a, float).reshape(len(t), -1)), axis=1)
    keep = np.zeros(len(t), bool)
    keep[finite] = increasing_rows(t[finite])
    bad, order = np.flatnonzero(~finite), np.flatnonzero(finite & ~keep)
    parts = []
    if len(bad):
        parts.append(f"{len(bad)} with NaN/inf values at {places(bad, t)}")
    if len(order):
        parts.append(f"{len(order)} with time out of order at {places(order, t)}")
    note = f"dropped {len(bad) + len(order)} corrupt row(s) of {len(t)}: " + "; ".join(parts) if parts else ""
    return keep, note


def clock_note(t: np.ndarray, rate_hz: float) -> str:
    """What the log's clock looks like and that it is resampled ('' when already uniform at rate_hz)."""
    dt = np.diff(np.asarray(t, float))
    if len(dt) == 0:
        return ""
    lo, med, hi = np.percentile(dt, [1, 50, 99]) * 1e3
    if hi - lo < 0.05 * med and abs(1e3 / med - rate_hz) < 1e-3 * rate_hz:
        return ""
    kind = "irregular clock" if hi - lo >= 0.05 * med else "uniform clock"
    return (f"{kind} at ~{1e3 / med:.0f} Hz (steps {lo:.1f}-{hi:.1f} ms, median {med:.1f} ms): "
            f"resampled to {rate_hz:g} Hz (gaps over 0.1 s split the run)")


def _bad(path: Path, what: str, fix: str) -> ConfigError:
    return ConfigError(what, where=str(path), fix=fix)


def _read_npz(path: Path) -> dict[str, np.ndarray]:
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except (zipfile.BadZipFile, ValueError, OSError, EOFError) as e:
        raise _bad(path, f"not a readable .npz file ({type(e).__name__})",
                   "pass a NumPy .npz log (see docs/recording.md, plain log format)") from None


def log_from_arrays(path: Path, data: dict[str, np.ndarray], rate_hz: float = 100.0) -> LogRead:
    """A plain log's arrays -> LogRead, tolerant of the defects in the module docstring; anything else
    wrong (missing t/q/torque, wrong shapes) is one ConfigError naming the file and the key."""
    missing = [k for k in ("t", "q") if k not in data]
    if "tau_m" not in data and "current" not in data:
        missing.append("tau_m or current")
    if missing:
        raise _bad(path, f"missing array(s): {', '.join(missing)}",
                   "a log needs t [s], q [rad] and tau_m [N*m] or current [A] (qd, q_cmd optional)")
    t = np.asarray(data["t"], float).reshape(-1)
    n_rows = len(t)
    q = np.asarray(data["q"], float)
    if q.ndim != 2 or q.shape[0] != n_rows:
        raise _bad(path, f"q has shape {q.shape}, expected ({n_rows}, n_joints)", "store q as (N, n) rad")
    n = q.shape[1]

    def per_sample(key: str) -> np.ndarray | None:
        if key not in data:
            return None
        a = np.asarray(data[key], float)
        if a.shape != (n_rows, n):
            raise _bad(path, f"{key} has shape {a.shape}, expected {(n_rows, n)}",
                       f"store {key} with one row per sample of t and one column per joint")
        return a

    notes = []
    torque_key = "tau_m" if "tau_m" in data else "current"
    tau, units = per_sample(torque_key), "N*m" if torque_key == "tau_m" else "A"
    if units == "A" and "torque_constant" in data:
        k = np.asarray(data["torque_constant"], float).reshape(-1)
        if k.shape != (n,) or not np.all(np.isfinite(k)):
            raise _bad(path, f"torque_constant has {k.size} entries or non-finite values, expected {n}",
                       "one N*m/A value per joint")
        tau, units = tau * k, "N*m"
    elif units == "A":
        notes.append("current without a torque constant: trained and scored in A")
    qd, q_cmd = per_sample("qd"), per_sample("q_cmd")
    if q_cmd is None:
        notes.append("no q_cmd: the network's inputs fall back to (q, q_dot)")
    keep, note = clean_rows(t, {"q": q, "qd": qd, "q_cmd": q_cmd, "tau": tau})
    if note:
        notes.append(note)
    if keep.sum() < 2:
        raise _bad(path, f"only {int(keep.sum())} usable row(s) of {n_rows}", "check the log's t and values")
    t, q, tau = t[keep], q[keep], tau[keep]
    q_cmd = None if q_cmd is None else q_cmd[keep]
    if qd is None:
        qd = np.gradient(q, t, axis=0)
        notes.append("no qd: differentiated from q")
    else:
        qd = qd[keep]
    names = ([str(s) for s in np.asarray(data["joint_names"]).reshape(-1)] if "joint_names" in data
             else [f"joint{i + 1}" for i in range(n)])
    if len(names) != n:
        raise _bad(path, f"joint_names has {len(names)} names for {n} joints", "one name per column of q")
    log = PlainLog(path=path, t=t, q=q, qd=qd, q_cmd=q_cmd, tau=tau, units=units, joint_names=names)
    for key in ("temperature", "tau_ext_true"):
        a = per_sample(key)
        setattr(log, key, None if a is None else a[keep])
    if "contact" in data:
        c = np.asarray(data["contact"]).reshape(-1)
        if c.shape[0] != n_rows:
            raise _bad(path, f"contact has {c.shape[0]} entries for {n_rows} samples", "one per sample")
        log.contact = c[keep].astype(bool)
    for key in ("arm", "arm_sha256"):
        if key in data and np.asarray(data[key]).ndim == 0:
            setattr(log, key, str(data[key]))
    if note := clock_note(t, rate_hz):
        notes.append(note)
    return LogRead(path.stem, log, notes, int((~keep).sum()))


def _read_mcap(path: Path, arm: str, rate_hz: float) -> list[LogRead]:
    """One LogRead per episode of `arm` in a factr2 recording (hardware.recording)."""
    from hardware.recording.metadata import recorded_arm
    from hardware.recording.reader import Recording

    try:
        rec = Recording(path)
        logs = [(ep.index, ep.to_plain(arm)) for ep in rec.episodes]
    except (ValueError, KeyError, OSError) as e:
        raise _bad(path, f"cannot read the {arm} joint states ({str(e)[:80]})",
                   "pass a factr2 recording (.mcap) or a plain .npz log") from None
    named = recorded_arm(rec.info, arm)
    out = []
    for i, log in logs:
        arrays = {k: getattr(log, k) for k in ("t", "q", "qd", "q_cmd", "temperature", "tau_ext_true",
                                                "contact")
                  if getattr(log, k) is not None}
        arrays["tau_m"], arrays["joint_names"] = log.tau, np.array(log.joint_names)
        if np.all(~np.isfinite(arrays["q_cmd"])):  # a recorder that never commanded a position
            del arrays["q_cmd"]
        if arrays.get("temperature") is not None and not np.all(np.isfinite(arrays["temperature"])):
            del arrays["temperature"]
        arrays.update({k: np.array(v) for k, v in named.items() if k in ("arm", "arm_sha256")})
        r = log_from_arrays(path, arrays, rate_hz)
        r.name = f"{path.stem}_ep{i}"
        out.append(r)
    if not out:
        raise _bad(path, f"no episode with {arm} joint states", "record at least a few seconds of motion")
    return out


def read_logs(path: str | Path, rate_hz: float = 100.0, arm: str = "follower") -> list[LogRead]:
    """Every run in a file: a plain .npz log is one run, an MCAP recording one run per episode of `arm`, an
    official NEXT H5 file one run per episode (calibration.next.h5_logs; FILE.h5::ARM names its arm)."""
    from calibration.next.h5_logs import H5_SUFFIXES, read_h5, split_arm

    h5, h5_arm = split_arm(path)
    if h5.suffix.lower() in H5_SUFFIXES:
        if not h5.is_file():
            raise _bad(h5, "file not found", "check the path")
        runs = []
        for name, arrays, notes in read_h5(h5, h5_arm):
            r = log_from_arrays(h5, arrays, rate_hz)
            r.name, r.notes = name, notes + r.notes
            runs.append(r)
        return runs
    path = Path(path)
    if not path.is_file():
        raise _bad(path, "file not found", "check the path")
    if path.suffix == ".mcap":
        return _read_mcap(path, arm, rate_hz)
    return [log_from_arrays(path, _read_npz(path), rate_hz)]
