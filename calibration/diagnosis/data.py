"""Logs as segments (one contiguous run each) and the held-out split.

A Segment (hardware.timeseries, the one time-series type) holds one run: t [s] from the run's start, q [rad],
qd [rad/s] (the cleaner of logged and differenced velocity), qdd [rad/s^2] (differentiated from qd,
smoothed), tau = the quantity the model predicts (motor torque [N*m] or motor current [A], see `units`),
optional temperature [degC], and the arm the log names (arm, arm_sha256; "" when it names none).
Held-out data is always whole runs or contiguous blocks, never random samples (hardware.timeseries.
heldout_spans): neighbouring samples of a 125 Hz log are nearly identical, so a random split would measure
interpolation, not prediction.
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np

from hardware.errors import UserError
from hardware.recording.plain_log import load_plain_log
from hardware.timeseries import Segment, heldout_spans
from hardware.timeseries import resample as resample_arrays


def smooth(x: np.ndarray, width: int) -> np.ndarray:
    """Centred moving average along axis 0 (edges use the available samples)."""
    if width <= 1:
        return x
    k = np.ones(width) / width
    num = np.apply_along_axis(lambda c: np.convolve(c, k, mode="same"), 0, x)
    den = np.convolve(np.ones(len(x)), k, mode="same")
    return num / den[:, None]


def differentiate(t: np.ndarray, x: np.ndarray, smooth_width: int = 7) -> np.ndarray:
    """d/dt of x (N, n) on a possibly irregular clock t, low-passed by a moving average."""
    if len(t) < 3:
        return np.zeros_like(x)
    return smooth(np.gradient(x, t, axis=0), smooth_width)


CONTACT_MARGIN_S = 0.3  # samples this close to a (twin ground-truth) contact are left out
SMOOTHER = 3.0  # how much smoother the differenced position must be to replace the logged velocity


def roughness(x: np.ndarray) -> np.ndarray:
    """Per-column RMS of the second difference along time: ~sqrt(6) * sigma for white noise of std sigma,
    near zero for a smooth motion sampled fast."""
    return np.sqrt(np.mean(np.diff(x, 2, axis=0) ** 2, 0)) if len(x) > 2 else np.zeros(x.shape[1])


def cleaner_velocity(t: np.ndarray, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per joint, the logged velocity or the central difference of the logged position, whichever is less
    noisy -> (velocity [rad/s] (N, n), bool (n,) True where the difference of q was taken). Why: friction-like
    features (sign(qd), Stribeck) are decided at near-zero velocity, where a drive's noisy speed estimate
    flips sign while an encoder that reads 1e-5 rad differentiates cleanly; where the encoder is coarse the
    logged speed wins. The difference must be SMOOTHER x smoother to replace the logged value: roughness is
    also real high-frequency motion, and on the real UR5 logs a 1.5x rule swapped joints whose logged speed
    was the better signal (held-out L1 0.50 -> 0.53 A; 3x: 0.50)."""
    if len(t) < 5:
        return qd, np.zeros(q.shape[1], bool)
    dq = np.gradient(q, t, axis=0)
    use = roughness(dq) * SMOOTHER < roughness(qd)
    return np.where(use[None, :], dq, qd), use


def make_segment(name: str, t, q, qd, y, units: str, temperature=None, joint_names=(), qdd=None,
                 q_cmd=None, qd_logged=None, arm: str = "", arm_sha256: str = "") -> Segment:
    """y: the torque signal [units]. qd_logged: the logged velocity when qd has been processed already
    (resampling); default: qd."""
    t = np.asarray(t, float).ravel()
    q = np.atleast_2d(np.asarray(q, float))
    if q.shape[0] != len(t):
        q = q.T
    qd = differentiate(t, q, 1) if qd is None else np.asarray(qd, float).reshape(q.shape)
    y = np.asarray(y, float).reshape(q.shape)
    keep = np.all(np.isfinite(q), 1) & np.all(np.isfinite(qd), 1) & np.all(np.isfinite(y), 1) & np.isfinite(t)
    if keep.sum() < 20:
        raise UserError(f"only {int(keep.sum())} finite samples", where=name,
                        fix="record a longer run (diagnosis needs at least a few seconds)")
    t, q, qd, y = t[keep], q[keep], qd[keep], y[keep]
    order = np.argsort(t, kind="stable")
    t, q, qd, y = t[order], q[order], qd[order], y[order]
    uniq = np.concatenate([[True], np.diff(t) > 0])
    t, q, qd, y = t[uniq], q[uniq], qd[uniq], y[uniq]
    if q_cmd is not None:
        q_cmd = np.asarray(q_cmd, float).reshape(-1, q.shape[1])[keep][order][uniq]
        if not np.all(np.isfinite(q_cmd)):
            q_cmd = None
    if qd_logged is None:
        qd_logged = qd.copy()
    else:  # given separately (resampling): the same rows as the other arrays
        qd_logged = np.asarray(qd_logged, float).reshape(-1, q.shape[1])[keep][order][uniq]
        if not np.all(np.isfinite(qd_logged)):
            qd_logged = None
    qd, _ = cleaner_velocity(t, q, qd)
    if qdd is None:
        qdd = differentiate(t, qd)
    else:
        qdd = np.asarray(qdd, float)[keep][order][uniq]
    temp = None
    if temperature is not None:
        temp = np.asarray(temperature, float).reshape(-1, q.shape[1])[keep][order][uniq]
        if not np.all(np.isfinite(temp)):
            temp = None
    return Segment(t=t - t[0], q=q, qd=qd, tau=y, q_cmd=q_cmd, name=name, units=units, qdd=qdd,
                   qd_logged=qd_logged, temperature=temp, joint_names=tuple(joint_names), arm=arm,
                   arm_sha256=arm_sha256)


def _from_plain_log(path: Path) -> Segment:
    return _segment_of(load_plain_log(path), path.stem)


def _segment_of(log, name: str) -> Segment:
    """A PlainLog as a Segment. Where the log carries the true external torque (twin logs), it is
    subtracted: diagnosis models the free-space dynamics."""
    y = log.tau if log.tau_ext_true is None or log.units != "N*m" else log.tau - log.tau_ext_true
    return make_segment(name, log.t, log.q, log.qd, y, log.units, log.temperature, log.joint_names,
                        q_cmd=log.q_cmd, arm=getattr(log, "arm", ""),
                        arm_sha256=getattr(log, "arm_sha256", ""))


def free_runs(t: np.ndarray, contact: np.ndarray | None, margin_s: float = CONTACT_MARGIN_S,
              min_samples: int = 20) -> list[tuple[int, int]]:
    """[lo, hi) index ranges of t [s] farther than margin_s from every contact sample, min_samples or
    longer. Subtracting the true external torque is not enough around a touch: the contact torque is
    sampled at the log's instants while the motor current answers it through the position loop, so
    spikes of several N*m are left (a 5-sample graze of the table moved a joint's held-out L1 by 30 %)."""
    n = len(t)
    if contact is None or not np.any(contact) or np.any(np.diff(t) < 0):
        return [(0, n)] if n >= min_samples else []
    tc = t[np.asarray(contact, bool)]
    i = np.searchsorted(tc, t)
    before, after = tc[np.clip(i - 1, 0, len(tc) - 1)], tc[np.clip(i, 0, len(tc) - 1)]
    gap = np.minimum(np.abs(t - before), np.abs(after - t))
    near = gap <= margin_s
    edges = np.flatnonzero(np.diff(np.r_[0, (~near).astype(int), 0]))
    return [(int(lo), int(hi)) for lo, hi in zip(edges[::2], edges[1::2]) if hi - lo >= min_samples]


def _segments_of(log, name: str) -> list[Segment]:
    """The contact-free stretches of a PlainLog as Segments (all of it when it has no contact flag)."""
    runs = free_runs(np.asarray(log.t, float), log.contact)
    if runs == [(0, len(log.t))]:
        return [_segment_of(log, name)]
    out = []
    for i, (lo, hi) in enumerate(runs):
        part = copy.copy(log)
        for f in ("t", "q", "qd", "q_cmd", "tau", "temperature", "tau_ext_true", "force", "contact"):
            v = getattr(log, f, None)
            if v is not None:
                setattr(part, f, v[lo:hi])
        out.append(_segment_of(part, f"{name}#{i}"))
    return out


def load_segments(path: str | Path, arm: str = "follower") -> list[Segment]:
    """Runs in a file: a plain .npz log is one run; an MCAP recording (hardware.recording) gives one run per
    episode of `arm`. Episodes with contact and no ground truth to subtract bias a free-space model: diagnose
    free-motion recordings (calibration replays), or twin recordings."""
    path = Path(path)
    if path.suffix != ".mcap":
        if path.suffix == ".npz" and path.exists():
            try:
                return _segments_of(load_plain_log(path), path.stem)
            except UserError:
                pass  # not a full plain log: load_segment's lenient reader says what is wrong
        return [load_segment(path)]
    from hardware.recording.reader import Recording

    if not path.exists():
        raise UserError("file not found", where=str(path), fix="give the path of a recording (.mcap)")
    from hardware.recording.metadata import recorded_arm

    try:
        rec = Recording(path)
        logs = [(ep.index, ep.to_plain(arm)) for ep in rec.episodes]
    except (ValueError, KeyError, OSError) as e:
        raise UserError(f"cannot read the {arm} joint states ({str(e)[:80]})", where=str(path),
                        fix="pass a factr2 recording (teleop/demo --record) or a plain .npz log") from None
    named = recorded_arm(rec.info, arm)  # the recording metadata says which arm (describe_recording)
    for _, log in logs:
        log.arm, log.arm_sha256 = named.get("arm", ""), named.get("arm_sha256", "")
    segs = [seg for i, log in logs if len(log.t) >= 20 for seg in _segments_of(log, f"{path.stem}#ep{i}")]
    if not segs:
        raise UserError(f"no episode with {arm} joint states", where=str(path),
                        fix="record at least a few seconds of motion")
    return segs


def _lenient_npz(path: Path) -> Segment:
    """Fallback for .npz logs without q_cmd (t, q, [qd], tau_m or current, [temperature], [joint_names])."""
    try:
        d = np.load(path, allow_pickle=False)
    except Exception as e:  # noqa: BLE001 - any unreadable file is one user-facing line
        raise UserError(f"cannot read ({type(e).__name__})", where=str(path),
                        fix="pass a .npz written by numpy.savez") from None
    keys = set(d.files)
    if not {"t", "q"} <= keys or not ({"tau_m", "current"} & keys):
        raise UserError(f"missing arrays (has {', '.join(sorted(keys))})", where=str(path),
                        fix="a plain log needs t, q and tau_m [N*m] or current [A]")
    units = "N*m" if "tau_m" in keys else "A"
    y = d["tau_m"] if units == "N*m" else d["current"]
    names = tuple(str(x) for x in d["joint_names"]) if "joint_names" in keys else ()
    try:
        return make_segment(path.stem, d["t"], d["q"], d["qd"] if "qd" in keys else None, y, units,
                            d["temperature"] if "temperature" in keys else None, names,
                            q_cmd=d["q_cmd"] if "q_cmd" in keys else None)
    except ValueError as e:
        raise UserError(f"inconsistent array shapes ({e})", where=str(path),
                        fix="t is (N,), q, qd, tau_m/current are (N, n_joints)") from None


def load_segment(path: str | Path) -> Segment:
    """One run: a plain .npz log (see hardware/recording/plain_log.py) -> Segment."""
    path = Path(path)
    if not path.exists():
        raise UserError("file not found", where=str(path), fix="give the path of a plain .npz log")
    if path.suffix != ".npz":
        raise UserError("not a plain .npz log", where=str(path),
                        fix="export the recording as a plain log (t, q, qd, q_cmd, tau_m or current)")
    try:
        return _from_plain_log(path)
    except UserError:  # e.g. no q_cmd: diagnosis does not need it
        return _lenient_npz(path)


def resample(seg: Segment, rate_hz: float) -> Segment:
    """The segment on a uniform `rate_hz` grid (hardware.timeseries.resample: linear interpolation; qd
    re-cleaned and qdd re-differentiated on the new clock)."""
    arrays = {k: getattr(seg, k) for k in ("q", "qd", "tau", "temperature", "q_cmd", "qd_logged")}
    grid, r = resample_arrays(seg.t, arrays, rate_hz)[0]
    return make_segment(seg.name, grid, r["q"], r["qd"], r["tau"], seg.units, r["temperature"],
                        seg.joint_names, q_cmd=r["q_cmd"], qd_logged=r["qd_logged"], arm=seg.arm,
                        arm_sha256=seg.arm_sha256)


def split_heldout(runs: list[list[Segment]], heldout: list[Segment] | None, frac: float = 0.25):
    """(train, heldout) segments from `runs` (one list of segments per input file: a log whose contacts were
    cut out is several segments). Given held-out segments win; else the last file is held out when there
    are several (a different run); one file's segments are split by hardware.timeseries.heldout_spans's
    tail rule: its trailing segments, at least `frac` of its samples, or the contiguous trailing `frac` of
    a single segment."""
    segments = [s for run in runs for s in run]
    if heldout:
        return segments, list(heldout)
    runs = [run for run in runs if run]
    if len(runs) >= 2:
        return [s for run in runs[:-1] for s in run], list(runs[-1])
    train, held = heldout_spans([len(s) for s in segments], frac)

    def take(spans, tag):
        whole = [(0, len(s)) for s in segments]
        return [segments[i] if (lo, hi) == whole[i] else segments[i].slice(lo, hi, segments[i].name + tag)
                for i, lo, hi in spans]

    return take(train, "[train]"), take(held, "[heldout]")
