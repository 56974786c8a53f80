"""Demo metrics as pure functions on recorded arrays (no devices, no clock).

Conventions: tau_ext [N*m] = tau_m - tau_free on the follower joints (docs/teleop.md). The leader feedback
torque is tau_fb = -K_f * M^T(tau_ext_est); "mapped back to the follower" means -tau_fb / K_f taken through
the joint map back onto the follower joints, so it has tau_ext's sign and units and is compared with the
twin's true tau_ext directly.
"""

from __future__ import annotations

import numpy as np

MIN_STD_NM = 1e-3  # N*m: a joint whose true torque barely moves during contact has no defined correlation


def feedback_on_follower(tau_fb_leader: np.ndarray, gain: np.ndarray, index: np.ndarray,
                         k: np.ndarray) -> np.ndarray:
    """(T, n_leader) leader feedback torque [N*m] -> (T, n_follower) equivalent follower tau_ext [N*m].

    Inverts tau_fb[:, index[j]] = -K_f[index[j]] * k[j] * tau_ext[:, j] (k = sign * scale,
    JointMap.torque_back
    then the feedback law). Joints with K_f = 0 come out NaN (no feedback there)."""
    fb = np.asarray(tau_fb_leader, dtype=float)
    k = np.asarray(gain, dtype=float)[index] * np.asarray(k, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = -fb[:, index] / np.where(k != 0, k, np.nan)
    return out


def per_joint_corr(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Pearson correlation per column over the rows in mask; NaN where either side is (nearly) constant."""
    a, b = np.asarray(a, dtype=float)[mask], np.asarray(b, dtype=float)[mask]
    out = np.full(a.shape[1], np.nan)
    for j in range(a.shape[1]):
        ok = np.isfinite(a[:, j]) & np.isfinite(b[:, j])
        x, y = a[ok, j], b[ok, j]
        if x.size < 3 or np.std(x) < MIN_STD_NM or np.std(y) < MIN_STD_NM:
            continue
        out[j] = float(np.corrcoef(x, y)[0, 1])
    return out


LAG_SMOOTH_S = 0.005  # s: moving average over the first differences before correlating (see lag_by_xcorr)


def _smoothed_diff(x: np.ndarray, width: int) -> np.ndarray:
    d = np.diff(x, axis=0)
    if width <= 1 or len(d) < width:
        return d
    c = np.cumsum(np.vstack([np.zeros((1, d.shape[1])), d]), axis=0)
    return (c[width:] - c[:-width]) / width


def lag_by_xcorr(est: np.ndarray, true: np.ndarray, dt_s: float, max_lag_s: float = 0.2,
                 smooth_s: float = LAG_SMOOTH_S) -> float:
    """Delay [s] of est behind true (both on a uniform grid of step dt_s): the shift k >= 0 maximising
    sum_j corr(d_est[t+k, j], d_true[t, j]), d = first difference averaged over smooth_s (NaNs as 0).

    Why differences: contact torques in a wipe change over seconds, so the correlation of the levels is
    flat in the shift (on a 20 s lockstep demo it varied by 0.3 % between 0 and 40 ms) and its peak wandered
    between 0 and 24 ms from run to run with the same code; the differences weight the changes (contact on
    and off, pressing harder), which is what a delay delays, and give a defined peak. smooth_s = 0 correlates
    the raw differences. Needs signals that move."""
    width = max(1, int(round(smooth_s / dt_s)))
    e = _smoothed_diff(np.nan_to_num(np.asarray(est, dtype=float)), width)
    g = _smoothed_diff(np.nan_to_num(np.asarray(true, dtype=float)), width)
    e, g = e - e.mean(axis=0), g - g.mean(axis=0)
    n = e.shape[0]
    best_k, best = 0, -np.inf
    for k in range(0, min(int(round(max_lag_s / dt_s)), n - 2) + 1):
        x, y = e[k:], g[: n - k]
        den = np.sqrt(np.sum(x * x, axis=0) * np.sum(y * y, axis=0))
        c = float(np.sum(np.where(den > 0, np.sum(x * y, axis=0) / np.where(den > 0, den, 1.0), 0.0)))
        if c > best:
            best_k, best = k, c
    return best_k * dt_s


def resample(t: np.ndarray, x: np.ndarray, dt_s: float) -> np.ndarray:
    """(T, n) samples at times t [s] (increasing, possibly jittery) -> a uniform grid of step dt_s, linear
    interpolation per column (NaN as 0), so a lag in samples is a lag in seconds."""
    t = np.asarray(t, dtype=float)
    x = np.nan_to_num(np.asarray(x, dtype=float))
    if len(t) < 2:
        return x
    grid = np.arange(t[0], t[-1], dt_s)
    return np.stack([np.interp(grid, t, x[:, j]) for j in range(x.shape[1])], axis=1)


def command_violations(q_cmd: np.ndarray, t: np.ndarray, q_min: np.ndarray, q_max: np.ndarray,
                       v_max: np.ndarray, min_dt_s: float, hold: np.ndarray | None = None,
                       tol: float = 1e-9, t_sent: np.ndarray | None = None) -> int:
    """Follower position commands outside the limits, counted per (command, joint): q outside
    [q_min, q_max], or a step larger than v_max * (the longest time the commands can have been apart +
    min_dt_s). t [s]: when each command was issued (entry to Follower.command); t_sent [s]: when it went on
    the wire. The safety layer reads the clock somewhere in between, so with both the interval it budgeted
    is at most t_sent[k] - t[k-1]: a step beyond v_max times that is a violation whatever the thread's
    scheduling (a thread preempted between the two reads moved its command no faster on the wire). Without
    t_sent the interval is t[k] - t[k-1], and min_dt_s (e.g. one loop period) is the slack for that jitter.
    hold: per command, True for the safe state (target = where the arm is): no rate check into or out of
    it, since a hold stops the arm where it stands rather than moving the target."""
    q = np.asarray(q_cmd, dtype=float)
    if q.size == 0:
        return 0
    bad = (~np.isfinite(q)) | (q < q_min - tol) | (q > q_max + tol)
    n = int(np.sum(bad))
    if len(q) > 1:
        t = np.asarray(t, dtype=float)
        later = t[1:] if t_sent is None else np.asarray(t_sent, dtype=float)[1:]
        dt = (np.maximum(later - t[:-1], 0.0) + min_dt_s)[:, None]
        step = np.abs(np.diff(q, axis=0))
        fast = np.isfinite(v_max) & (step > v_max * dt * 1.05 + 1e-6)
        if hold is not None and len(hold) == len(q):
            h = np.asarray(hold, dtype=bool)
            fast &= ~(h[1:] | h[:-1])[:, None]
        n += int(np.sum(fast))
    return n


def torque_violations(tau: np.ndarray, tau_max: np.ndarray, tol: float = 1e-9) -> int:
    """Leader torque commands outside +-tau_max (or non-finite), counted per (command, joint)."""
    tau = np.asarray(tau, dtype=float)
    if tau.size == 0:
        return 0
    return int(np.sum(~np.isfinite(tau) | (np.abs(tau) > tau_max + tol)))


def l1_mean(tau: np.ndarray, mask: np.ndarray) -> float:
    """Mean over the masked rows of ||tau||_1 [N*m] (NaN rows skipped); NaN if none."""
    x = np.asarray(tau, dtype=float)[mask]
    x = x[np.all(np.isfinite(x), axis=1)]
    return float(np.mean(np.sum(np.abs(x), axis=1))) if len(x) else float("nan")
