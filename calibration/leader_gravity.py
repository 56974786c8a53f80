"""Identify a leader arm's gravity terms after building it: hold a few poses, least squares on the regressor.

A GELLO-style leader is 3D-printed: its printed links, servo horns, screws and handle never weigh what the
description says, so the leader law's g(q) (hardware/arms description, pinocchio) leaves a residual at rest
that the operator feels as a joint that sags or floats (i2rt corrects the YAM with per-joint factors 1.0-1.2,
docs/twin_model.md). Here the leader holds each pose under a PD on its own joints (current mode), approached
once from below and once from above so that static friction cancels in the mean, and the torque that holds
it is gravity. Gravity is linear in each link's mass and first moment (m, m c_x, m c_y, m c_z):
g(q) = Y_g(q) p, so p is a least-squares fit, pulled toward the description's values (a Gaussian prior,
PRIOR_MASS_FRAC / PRIOR_COM_M) for the combinations the poses do not pin down. Gravity sees only some
combinations of the parameters (none of a base link turning about a vertical axis, nor a link's mass at its
own joint): the fit is mapped back so that what gravity never sees stays as described
(described_where_unidentified).

Pure math (arrays in, arrays out): hold_poses, hold_torque, gravity_regressor, fit_gravity_params,
gravity_null_space, described_where_unidentified, rest_residual, model_with_params. The thin shell
measure_holds drives a connected Leader (hardware.roles).
The result is a JSON file the leader law loads (factr2_teleop.teleop.leader_law.arm_model_fns): see
docs/teleop.md "Leader gravity identification" for where it lives.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hardware.errors import ConfigError, DeviceError

# prior on the parameters (1 sigma): link mass within 30 % of the description, COM within 2 cm
PRIOR_MASS_FRAC = 0.3
PRIOR_COM_M = 0.02
# N*m: torque noise of one hold's mean (Dynamixel current unit 2.69 mA x ~0.5 N*m/A, + friction left over)
HOLD_SIGMA_NM = 0.005
FORMAT = "factr2.leader_gravity/1"
# poses whose described gravity is at most this share of a joint's torque limit: a true arm up to ~40 %
# heavier (the GELLO magnitudes in hardware/arms/true_body.py stay below) can still be held there
LOAD_FRAC = 0.6
# a hold is kept when the leader came to rest near its pose without touching its torque limit
HOLD_TOL_RAD = 0.15
SATURATED_FRAC = 0.97
# ... and its two approaches (from below, from above) came to rest this close together: near a balanced pose
# (gravity turning over) the PD settles on either side and their mean torque is not gravity (the twin's
# UR5-size GELLO: 0.14 rad and 1.5 N*m apart on J2 at one pose, 0.03 rad where the hold is good)
APPROACH_AGREE_RAD = 0.1


@dataclass(frozen=True)
class HoldGains:
    """PD that holds a leader pose on current control, with the description's gravity as feed-forward. Per
    joint from the description's mass matrix M (armature included) at the pose: kp = max(omega^2 M_jj,
    kp_min) [N*m/rad], kd = 2 zeta sqrt(kp M_jj) [N*m*s/rad] -- a GELLO's J1 sees 0.007-0.023 kg*m^2 and its
    wrist 1e-4, so one gain for all is either underdamped at the shoulder or unstable at the wrist. No
    integrator: the pose need not be reached exactly (the fit uses the measured rest pose), and an integrator
    against stiction hunts (a 1 s, 0.03 rad limit cycle on the twin's GELLO). approach_rad: the offset each
    pose is approached from (below, then above); move_s / settle_s / measure_s: phases of one approach [s]."""

    omega_rad_s: float = 30.0
    zeta: float = 0.9
    kp_min: float = 0.5
    approach_rad: float = 0.05
    move_s: float = 0.8
    settle_s: float = 0.9
    measure_s: float = 0.3

    def gains(self, m_diag: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(kp, kd) per joint for the mass-matrix diagonal m_diag [kg*m^2]."""
        m = np.asarray(m_diag, float)
        kp = np.maximum(self.omega_rad_s ** 2 * m, self.kp_min)
        return kp, 2.0 * self.zeta * np.sqrt(kp * m)


# -- pure math -----------------------------------------------------------------------------------------
def hold_poses(q_min: np.ndarray, q_max: np.ndarray, n: int, seed: int = 0, spread: float = 0.7,
               q_home: np.ndarray | None = None, g_fn=None, tau_max: np.ndarray | None = None,
               load_frac: float = LOAD_FRAC) -> np.ndarray:
    """n poses [rad] (n, joints): q_home first (if given), then uniform draws within the middle `spread` of
    each joint's range (clear of the limits). With g_fn and tau_max: only poses whose described gravity is
    at most load_frac x tau_max on every joint all along the straight line from the first pose (the leader
    travels home -> pose -> home: a weak servo that meets more than its torque on the way drops the arm to
    its end stop, and a heavier true arm must still be holdable)."""
    q_min, q_max = np.asarray(q_min, float), np.asarray(q_max, float)
    mid, half = (q_min + q_max) / 2, spread * (q_max - q_min) / 2
    rng = np.random.default_rng(seed)
    poses = [np.clip(q_home, mid - half, mid + half)] if q_home is not None and n > 0 else []
    for _ in range(200 * max(n, 1)):
        if len(poses) >= n:
            break
        q = mid + half * rng.uniform(-1.0, 1.0, size=len(q_min))
        path = [q] if not poses else [poses[0] + s * (q - poses[0]) for s in np.linspace(0.0, 1.0, 11)]
        cap = None if g_fn is None else load_frac * np.asarray(tau_max, float)
        if g_fn is None or all(np.all(np.abs(g_fn(p)) <= cap) for p in path):
            poses.append(q)
    return np.array(poses[:n])


def hold_torque(g_ff: np.ndarray, q: np.ndarray, q_dot: np.ndarray, q_d: np.ndarray, kp: np.ndarray,
                kd: np.ndarray) -> np.ndarray:
    """One PD tick toward q_d [rad] with gravity feed-forward g_ff [N*m] -> torque [N*m]."""
    return g_ff + kp * (np.asarray(q_d, float) - np.asarray(q, float)) - kd * np.asarray(q_dot, float)


def gravity_columns(n_links: int) -> np.ndarray:
    """Columns of pinocchio's joint-torque regressor (10 per link) gravity uses: m, m c_x, m c_y, m c_z."""
    return (10 * np.arange(n_links)[:, None] + np.arange(4)[None, :]).reshape(-1)


def gravity_regressor(model, Q: np.ndarray) -> np.ndarray:
    """(K, n, 4 L) gravity regressors of a pinocchio model at poses Q (K, n) [rad]: Y_g(q) p = g(q)."""
    import pinocchio as pin

    data, cols = model.createData(), gravity_columns(model.njoints - 1)
    zero = np.zeros(model.nv)
    return np.stack([pin.computeJointTorqueRegressor(model, data, np.asarray(q, float), zero, zero)[:, cols]
                     for q in np.atleast_2d(Q)])


def description_params(model) -> np.ndarray:
    """(L, 4): each link's (m [kg], m c [kg*m]) in the joint frame, from a pinocchio model."""
    return np.array([model.inertias[j].toDynamicParameters()[:4] for j in range(1, model.njoints)])


def fit_gravity_params(Y: np.ndarray, tau: np.ndarray, p0: np.ndarray, sigma_nm: float = HOLD_SIGMA_NM,
                       mass_frac: float = PRIOR_MASS_FRAC, com_m: float = PRIOR_COM_M) -> np.ndarray:
    """MAP fit of the gravity parameters: minimise |Y p - tau|^2 / sigma^2 + |(p - p0) / s|^2 with
    s = (mass_frac m0, m0 com_m x 3) per link. Y (K, n, 4 L), tau (K, n) [N*m], p0 (L, 4). Returns (L, 4)."""
    p0 = np.asarray(p0, float)
    m0 = np.maximum(p0[:, 0], 1e-3)
    s = np.column_stack([mass_frac * m0] + [com_m * m0] * 3).reshape(-1)
    A = np.vstack([np.asarray(Y, float).reshape(-1, p0.size) / sigma_nm, np.diag(1.0 / s)])
    b = np.concatenate([np.asarray(tau, float).reshape(-1) / sigma_nm, p0.reshape(-1) / s])
    p, *_ = np.linalg.lstsq(A, b, rcond=None)
    return p.reshape(p0.shape)


def gravity_null_space(model, q_min: np.ndarray, q_max: np.ndarray, n_poses: int = 64, seed: int = 0,
                       rtol: float = 1e-9) -> np.ndarray:
    """(4 L, k) orthonormal directions of the (m, m c) parameters that gravity never sees (SVD of the
    regressor stacked over n_poses random poses within the limits [rad]): e.g. every parameter of a link
    turning about a vertical axis, a link's mass at its own joint, a distal mass on a parallel axis that a
    proximal first moment stands in for. Holds cannot identify these; only the identifiable (base)
    combinations -- the rest of the space -- are."""
    lo = np.where(np.isfinite(q_min), q_min, -np.pi)
    hi = np.where(np.isfinite(q_max), q_max, np.pi)
    Q = np.random.default_rng(seed).uniform(lo, hi, size=(n_poses, len(lo)))
    a = gravity_regressor(model, Q)
    a = a.reshape(-1, a.shape[-1])
    _, sv, vt = np.linalg.svd(a, full_matrices=True)
    rank = int(np.sum(sv > rtol * sv[0])) if sv.size else 0
    return vt[rank:].T


def described_where_unidentified(params: np.ndarray, p0: np.ndarray, null: np.ndarray,
                                 mass_frac: float = 1e-3 * PRIOR_MASS_FRAC,
                                 com_m: float = PRIOR_COM_M) -> np.ndarray:
    """The fit mapped back to link parameters: among all (L, 4) parameter sets with the same gravity at every
    pose (params + null z, null from gravity_null_space) the one closest to the description p0 with the
    masses held stiffly (prior widths mass_frac m0 and com_m m0): a mass the holds cannot see stays the
    described one -- positive -- and the identifiable change sits in the first moments that carry it. The
    gravity g(q) is the fit's (to rounding), so the residuals of a fit do not change."""
    p, p0 = np.asarray(params, float), np.asarray(p0, float)
    if null.shape[1] == 0:
        return p.copy()
    m0 = np.maximum(p0[:, 0], 1e-3)
    w = 1.0 / np.column_stack([mass_frac * m0] + [com_m * m0] * 3).reshape(-1)
    z = np.linalg.lstsq(w[:, None] * null, -w * (p - p0).reshape(-1), rcond=None)[0]
    return p + (null @ z).reshape(p.shape)


def good_holds(q_rest: np.ndarray, tau: np.ndarray, poses: np.ndarray, tau_max: np.ndarray,
               spread: np.ndarray | None = None) -> np.ndarray:
    """(K,) bool: the hold came to rest within HOLD_TOL_RAD of its pose on every joint, no joint's
    torque reached SATURATED_FRAC of its limit (a saturated hold is not gravity), and (spread given: (K, n)
    |q rest from below - q rest from above| [rad]) its two approaches agree within APPROACH_AGREE_RAD."""
    near = np.all(np.abs(np.asarray(q_rest) - np.asarray(poses)) <= HOLD_TOL_RAD, axis=1)
    free = np.all(np.abs(np.asarray(tau)) < SATURATED_FRAC * np.asarray(tau_max, float), axis=1)
    agree = True if spread is None else np.all(np.asarray(spread) <= APPROACH_AGREE_RAD, axis=1)
    return near & free & agree


def rest_residual(tau_hold: np.ndarray, g_model: np.ndarray) -> dict:
    """Per joint: RMS and max |tau_hold - g_model| [N*m] over the poses, and their means over the joints."""
    r = np.asarray(tau_hold, float) - np.asarray(g_model, float)
    rms, mx = np.sqrt(np.mean(r ** 2, axis=0)), np.max(np.abs(r), axis=0)
    return {"rms_nm": rms.tolist(), "max_nm": mx.tolist(), "rms_mean_nm": float(rms.mean()),
            "max_nm_all": float(mx.max())}


def model_with_params(model, params: np.ndarray):
    """A copy of a pinocchio model whose links have the given (m, m c) (L, 4); rotational inertia about the
    COM kept (gravity does not see it). A non-positive mass is a ConfigError (a broken fit or file)."""
    import pinocchio as pin

    params = np.asarray(params, float)
    if params.shape != (model.njoints - 1, 4) or not np.all(np.isfinite(params)) or np.any(params[:, 0] <= 0):
        raise ConfigError(f"leader gravity parameters of shape {params.shape} are not {model.njoints - 1} "
                          "links of (m > 0, m c)", where="leader gravity",
                          fix="re-run `factr2 leader-gravity`")
    out = pin.Model(model)
    for j in range(1, model.njoints):
        old = model.inertias[j]
        m, mc = params[j - 1, 0], params[j - 1, 1:]
        out.inertias[j] = pin.Inertia(float(m), mc / m, np.array(old.inertia))
    return out


# -- file ---------------------------------------------------------------------------------------------
@dataclass
class LeaderGravity:
    """An identification: params (L, 4) on the description `arm` (its sha256), residuals at rest before (the
    description) and after (the fit) on poses not used in the fit, and where it was measured."""

    arm: str
    arm_sha256: str
    params: np.ndarray
    before: dict
    after: dict
    meta: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"format": FORMAT, "arm": self.arm, "arm_sha256": self.arm_sha256,
                "params_m_mc": np.asarray(self.params).tolist(), "residual_before": self.before,
                "residual_after": self.after, **self.meta}


def save(path: Path, lg: LeaderGravity) -> Path:
    """Write atomically (a temp file renamed): a half-written file never replaces a good one."""
    path = Path(path).expanduser()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(lg.to_json(), indent=1))
    tmp.replace(path)
    return path


def load(path: Path, arm) -> np.ndarray:
    """The params (L, 4) of a saved identification for `arm` (hardware.arms.ArmDescription); ConfigError
    (one line) for an unreadable file or one made for another description."""
    path = Path(path).expanduser()
    fix = f"re-run `factr2 leader-gravity` for this leader, or delete {path}"
    try:
        d = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ConfigError(f"cannot read leader gravity file ({exc})", where=str(path), fix=fix) from None
    if d.get("format") != FORMAT:
        raise ConfigError(f"not a {FORMAT} file", where=str(path), fix=fix)
    if d.get("arm") != arm.name or d.get("arm_sha256") != arm.sha256:
        raise ConfigError(f"identified on description {d.get('arm')!r} ({str(d.get('arm_sha256'))[:8]}), "
                          f"not on {arm.name!r} ({arm.sha256[:8]})", where=str(path), fix=fix)
    return np.asarray(d["params_m_mc"], float)


# -- the shell on a connected leader ---------------------------------------------------------------------
def measure_holds(leader, clock, poses: np.ndarray, g_desc, m_diag, rate_hz: float = 250.0,
                  gains: HoldGains = HoldGains(), progress=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Hold each pose on `leader` (hardware.roles.Leader, current mode), going there from the first pose
    (home) and approaching it from below then from above. Returns (q at rest (K, n) [rad], holding torque
    (K, n) [N*m], each the mean of the two approaches' last measure_s, and |difference of the two rests|
    (K, n) [rad]). g_desc(q): the description's gravity
    (feed-forward); m_diag(q): its mass-matrix diagonal (the gains). The leader is left at zero torque.
    progress(k, K) after each pose."""
    dt = 1.0 / rate_hz
    q_prev = np.asarray(leader.read().q, float)
    q_out, tau_out, spread = [], [], []
    try:
        for k, pose in enumerate(np.atleast_2d(poses)):
            kp, kd = gains.gains(m_diag(pose))
            qs, taus = [], []
            for side in (-1.0, 1.0):
                start = pose + side * gains.approach_rad
                if side < 0 and k > 0:  # back home first: the checked path (hold_poses)
                    _track(leader, clock, q_prev, poses[0], gains.move_s, 0.0, dt, g_desc, kp, kd, 0.0)
                    q_prev = poses[0]
                _track(leader, clock, q_prev, start, gains.move_s, 0.0, dt, g_desc, kp, kd, gains.measure_s)
                q_m, tau_m = _track(leader, clock, start, pose, gains.move_s / 4, gains.settle_s, dt, g_desc,
                                    kp, kd, gains.measure_s)
                qs.append(q_m)
                taus.append(tau_m)
                q_prev = pose
            q_out.append(np.mean(qs, axis=0))
            spread.append(np.abs(qs[0] - qs[1]))
            tau_out.append(np.mean(taus, axis=0))
            if progress is not None:
                progress(k + 1, len(poses))
    finally:
        leader.zero_torque("leader gravity identification done")
    return np.array(q_out), np.array(tau_out), np.array(spread)


def _track(leader, clock, q_from, q_to, move_s, settle_s, dt, g_desc, kp, kd, measure_s):
    """Ramp the target from q_from to q_to over move_s (smooth step), hold settle_s; returns (mean q, mean
    commanded torque) over the last measure_s of the hold (None, None without a hold)."""
    steps_move, steps_hold = max(1, round(move_s / dt)), round(settle_s / dt)
    n_meas = min(steps_hold, max(1, round(measure_s / dt)))
    q_from, q_to = np.asarray(q_from, float), np.asarray(q_to, float)
    qs, taus = [], []
    t_next = clock.now()
    for i in range(steps_move + steps_hold):
        s = min(1.0, (i + 1) / steps_move)
        q_d = q_from + (q_to - q_from) * (3 * s * s - 2 * s ** 3)  # no kick at either end
        st = leader.read()
        sent = leader.command_torque(hold_torque(g_desc(st.q), st.q, st.q_dot, q_d, kp, kd))
        if i >= steps_move + steps_hold - n_meas:
            qs.append(np.asarray(st.q, float))
            taus.append(np.asarray(sent, float))
        t_next += dt
        clock.sleep(max(0.0, t_next - clock.now()))
    return (np.mean(qs, axis=0), np.mean(taus, axis=0)) if qs else (None, None)


def identify(leader, clock, arm, n_fit: int = 12, n_check: int = 6, seed: int = 0, rate_hz: float = 250.0,
             gains: HoldGains = HoldGains(), progress=None) -> LeaderGravity:
    """Hold n_fit + n_check poses, fit on the first n_fit, report the residual at rest on the other n_check
    before (description) and after (fit). arm: the leader's hardware.arms.ArmDescription."""
    import pinocchio as pin

    model = arm.pinocchio_model()
    data = model.createData()

    def g_desc(q):
        return pin.computeGeneralizedGravity(model, data, np.asarray(q, float)).copy()

    def m_diag(q):
        return np.diag(pin.crba(model, data, np.asarray(q, float))).copy()  # armature included

    lim = leader.safety.limits
    poses = hold_poses(lim.q_min, lim.q_max, n_fit + n_check, seed=seed, q_home=arm.q_home, g_fn=g_desc,
                       tau_max=lim.tau_max)
    t0, c0 = time.monotonic(), clock.now()
    q, tau, spread = measure_holds(leader, clock, poses, g_desc, m_diag, rate_hz, gains, progress)
    ok = good_holds(q, tau, poses, lim.tau_max, spread)
    fit, check = ok & (np.arange(len(q)) < n_fit), ok & (np.arange(len(q)) >= n_fit)
    if fit.sum() < 3 or check.sum() < 1:
        raise DeviceError(f"only {int(ok.sum())} of {len(q)} poses could be held", where=arm.name,
                          fix="check the leader's torque limits and offsets, then run it again")
    p0 = description_params(model)
    Y = gravity_regressor(model, q)
    null = gravity_null_space(model, lim.q_min, lim.q_max, seed=seed)
    params = described_where_unidentified(fit_gravity_params(Y[fit], tau[fit], p0), p0, null)
    fitted = model_with_params(model, params)
    fdata = fitted.createData()
    g_fit = np.array([pin.computeGeneralizedGravity(fitted, fdata, qq) for qq in q[check]])
    g_d = np.array([g_desc(qq) for qq in q[check]])
    before, after = rest_residual(tau[check], g_d), rest_residual(tau[check], g_fit)
    meta = {"poses_fit": int(fit.sum()), "poses_check": int(check.sum()), "poses_dropped": int((~ok).sum()),
            "seed": seed, "rate_hz": rate_hz, "wall_s": round(time.monotonic() - t0, 2),
            "clock_s": round(clock.now() - c0, 2),
            "q_rest": q.tolist(), "tau_hold": tau.tolist()}
    return LeaderGravity(arm=arm.name, arm_sha256=arm.sha256, params=params, before=before, after=after,
                         meta=meta)
