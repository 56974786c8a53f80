"""The leader arm's torque law (FACTR-style), as pure functions plus a thin stateful wrapper.

tau_leader = cap( gravity + friction + barrier + null_space + damping + feedback )
  gravity     gain * g(q)                                   g from a callable (pinocchio RNEA in production)
  friction    dither: +-gain*|g(q)| (at least min_nm), sign flipped every tick while |q_dot| < v_thr
              coulomb: tau_c * sign(q_dot) once |q_dot| >= v_thr (zero below: no chatter at rest)
  barrier     -kp (q - q_edge) - kd q_dot outside [q_min + margin, q_max - margin]
  null_space  N (-kp (q - q_ns) - kd q_dot), N = I - pinv(J) J (redundant leaders; J from a callable)
  damping     -kd q_dot
  feedback    feedback.FeedbackGate (contact hysteresis, freshness, ramp, clip)
  cap         per-joint clip of the sum to tau_total_max_nm (the safety layer then applies the device limits)
All torques in N*m on the leader's joints, q in rad, q_dot in rad/s. Every gain is per joint (scalar or list).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from factr2_teleop.teleop.feedback import FeedbackConfig, FeedbackGate
from factr2_teleop.teleop.law_floats import (
    LawTerms,
    barrier_floats,
    friction_coulomb_floats,
    friction_dither_floats,
    law_joint_params,
    law_tau_floats,
    scaled,
    sum_cap,
)
from factr2_teleop.teleop.mapping import JointMap
from hardware.errors import ConfigError
from hardware.params import PerJoint, clamp, per_joint
from hardware.small_vec import count_changed
from hardware.types import JointLimits

FRICTION_MODES = ("off", "dither", "coulomb")
TERM_NAMES = ("gravity", "friction", "barrier", "null_space", "damping", "feedback")  # LeaderOutput.terms


@dataclass
class GravityConfig:
    """gain per joint on g(q) (FACTR: 0.85; i2rt: 1.0-1.2 to correct per-joint model bias)."""

    enabled: bool = True
    gain: PerJoint = 0.85


@dataclass
class FrictionConfig:
    """mode: "off" | "dither" | "coulomb". dither_gain: fraction of |g(q)| (FACTR 0.6); dither_min_nm: floor
    of the dither amplitude so joints without gravity load get some [N*m]; vel_threshold_rad_s: dither below,
    Coulomb above (FACTR 0.9); coulomb_nm: Coulomb compensation magnitude [N*m]."""

    mode: str = "dither"
    dither_gain: PerJoint = 0.6
    dither_min_nm: PerJoint = 0.0
    vel_threshold_rad_s: PerJoint = 0.9
    coulomb_nm: PerJoint = 0.0


@dataclass
class BarrierConfig:
    """Joint-limit barrier (FACTR: kp 1.0356 N*m/rad, kd 0.04315 N*m*s/rad, margin 0.1 rad)."""

    enabled: bool = True
    kp: PerJoint = 1.0356
    kd: PerJoint = 0.04315
    margin_rad: PerJoint = 0.1


@dataclass
class NullSpaceConfig:
    """Null-space regulation for redundant leaders (FACTR: kp 0.1, kd 0.01). q_ns [rad]: rest posture
    (None: the pose at the start of teleop)."""

    enabled: bool = False
    kp: PerJoint = 0.1
    kd: PerJoint = 0.01
    q_ns: list[float] | None = None


@dataclass
class LeaderLawConfig:
    """Everything a rig file sets for one leader. damping_kd [N*m*s/rad]; tau_total_max_nm: per-joint cap on
    the summed torque (None: the leader's JointLimits.tau_max)."""

    gravity: GravityConfig = field(default_factory=GravityConfig)
    friction: FrictionConfig = field(default_factory=FrictionConfig)
    barrier: BarrierConfig = field(default_factory=BarrierConfig)
    null_space: NullSpaceConfig = field(default_factory=NullSpaceConfig)
    feedback: FeedbackConfig = field(default_factory=FeedbackConfig)
    damping_kd: PerJoint = 0.0
    tau_total_max_nm: PerJoint | None = None

    @classmethod
    def from_dict(cls, d: dict, where: str = "leader_law") -> LeaderLawConfig:
        """Build from a rig file table ({"gravity": {...}, "feedback": {...}, "damping_kd": ...})."""
        sub = {"gravity": GravityConfig, "friction": FrictionConfig, "barrier": BarrierConfig,
               "null_space": NullSpaceConfig, "feedback": FeedbackConfig}
        kw = {}
        for key, val in (d or {}).items():
            try:
                kw[key] = sub[key](**val) if key in sub else val
            except TypeError as e:
                raise ConfigError(f"bad key: {e}", where=f"{where}.{key}", fix="see docs/teleop.md") from None
        try:
            return cls(**kw)
        except TypeError as e:
            raise ConfigError(f"bad key: {e}", where=where, fix="see docs/teleop.md") from None


# -- pure terms --------------------------------------------------------------------------------------
def gravity_term(g: np.ndarray, gain: np.ndarray) -> np.ndarray:
    return gain * np.asarray(g, dtype=float)


def friction_dither(g: np.ndarray, q_dot: np.ndarray, gain: np.ndarray, min_nm: np.ndarray,
                    v_thr: np.ndarray, sign: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Static-friction dither: sign * max(gain |g|, min) on joints slower than v_thr.
    Returns (tau, next sign)."""
    amp = np.maximum(gain * np.abs(g), min_nm)
    tau = np.where(np.abs(q_dot) < v_thr, sign * amp, 0.0)
    return tau, -sign


def friction_coulomb(q_dot: np.ndarray, tau_c: np.ndarray, v_thr: np.ndarray) -> np.ndarray:
    """Coulomb compensation in the direction of motion, only once |q_dot| >= v_thr."""
    return np.where(np.abs(q_dot) >= v_thr, tau_c * np.sign(q_dot), 0.0)


def joint_limit_barrier(q: np.ndarray, q_dot: np.ndarray, q_min: np.ndarray, q_max: np.ndarray,
                        margin: np.ndarray, kp: np.ndarray, kd: np.ndarray) -> np.ndarray:
    """Spring-damper pushing back inside [q_min + margin, q_max - margin]; zero inside."""
    lo, hi = q_min + margin, q_max - margin
    below, above = q < lo, q > hi
    if not (any(below.tolist()) or any(above.tolist())):
        return np.zeros_like(q)
    edge = np.where(below, lo, hi)
    return np.where(below | above, -kp * (q - edge) - kd * q_dot, 0.0)


def null_space_projector(J: np.ndarray) -> np.ndarray:
    """N = I - pinv(J) J (n x n) for a task Jacobian J (m x n)."""
    J = np.asarray(J, dtype=float)
    return np.eye(J.shape[1]) - np.linalg.pinv(J) @ J


def null_space_term(q: np.ndarray, q_dot: np.ndarray, J: np.ndarray, q_ns: np.ndarray, kp: np.ndarray,
                    kd: np.ndarray) -> np.ndarray:
    """N (-kp (q - q_ns) - kd q_dot): posture regulation that does not move the task (J N = 0)."""
    return null_space_projector(J) @ (-kp * (q - q_ns) - kd * q_dot)


def damping_term(q_dot: np.ndarray, kd: np.ndarray) -> np.ndarray:
    return -kd * q_dot


def cap_total(tau: np.ndarray, cap: np.ndarray) -> tuple[np.ndarray, int]:
    """Per-joint clip of the summed torque; returns (capped, number of joints clipped)."""
    out = clamp(tau, -cap, cap)
    return out, count_changed(out, tau)


# -- the stateful wrapper the loop calls ------------------------------------------------------------
@dataclass
class LeaderInputs:
    """One tick's inputs. tau_ext_leader: the estimate mapped onto the leader joints [N*m] (None: no
    estimator); contact_score_nm: ||tau_ext||_1 on the follower joints; est_t: time of the data the estimate
    used [s]; est_fresh: the estimator's own freshness flag; gripper_effort: follower gripper effort."""

    t: float
    q: np.ndarray
    q_dot: np.ndarray
    tau_ext_leader: np.ndarray | None = None
    contact_score_nm: float = 0.0
    est_t: float = float("nan")
    est_fresh: bool = False
    gripper_effort: float = float("nan")


@dataclass
class LeaderOutput:
    tau: np.ndarray  # N*m, summed and capped
    terms: Mapping[str, np.ndarray]  # each term before the cap, for the UI (read-only; law_floats.LawTerms)
    gate: float
    contact: bool
    fresh: bool
    capped: int
    gripper_tau: float
    message: str | None


class LeaderLaw:
    """Holds the resolved per-joint gains, the dither sign and the feedback gate of one leader.

    gravity_fn(q_model) -> g [N*m] and jacobian_fn(q_model) -> J (m x n) work in the leader MODEL's joint
    frame; model_map (leader joints -> model joints, None = identity) converts q and maps torques back.
    """

    def __init__(self, cfg: LeaderLawConfig, limits: JointLimits,
                 gravity_fn: Callable[[np.ndarray], np.ndarray] | None = None,
                 jacobian_fn: Callable[[np.ndarray], np.ndarray] | None = None,
                 model_map: JointMap | None = None):
        n = limits.n
        self.cfg, self.limits, self.n = cfg, limits, n
        if cfg.gravity.enabled and gravity_fn is None:
            raise ConfigError("gravity compensation is on but no gravity model was given",
                              where="leader_law.gravity", fix="load the leader's arm description, or set "
                              "gravity.enabled = false")
        if cfg.null_space.enabled and jacobian_fn is None:
            raise ConfigError("null-space regulation is on but no Jacobian was given",
                              where="leader_law.null_space", fix="give the leader's arm description's "
                              "Jacobian, or set null_space.enabled = false")
        if cfg.friction.mode not in FRICTION_MODES:
            raise ConfigError(f"unknown mode {cfg.friction.mode!r}", where="leader_law.friction.mode",
                              fix=f"use one of {', '.join(FRICTION_MODES)}")
        self.gravity_fn, self.jacobian_fn = gravity_fn, jacobian_fn
        self.model_map = model_map or JointMap.identity(n)
        self._g_floats: tuple = (None, None)  # (gravity_fn, its floats form or None): gravity_floats
        g, f, b, ns = cfg.gravity, cfg.friction, cfg.barrier, cfg.null_space
        pj = per_joint
        self.g_gain = pj(g.gain, n, "leader_law.gravity.gain")
        self.dither_gain = pj(f.dither_gain, n, "leader_law.friction.dither_gain", nonneg=True)
        self.dither_min = pj(f.dither_min_nm, n, "leader_law.friction.dither_min_nm", nonneg=True)
        self.v_thr = pj(f.vel_threshold_rad_s, n, "leader_law.friction.vel_threshold_rad_s", nonneg=True)
        self.coulomb = pj(f.coulomb_nm, n, "leader_law.friction.coulomb_nm", nonneg=True)
        self.b_kp = pj(b.kp, n, "leader_law.barrier.kp", nonneg=True)
        self.b_kd = pj(b.kd, n, "leader_law.barrier.kd", nonneg=True)
        self.b_margin = pj(b.margin_rad, n, "leader_law.barrier.margin_rad", nonneg=True)
        self.ns_kp = pj(ns.kp, n, "leader_law.null_space.kp", nonneg=True)
        self.ns_kd = pj(ns.kd, n, "leader_law.null_space.kd", nonneg=True)
        self.damp = pj(cfg.damping_kd, n, "leader_law.damping_kd", nonneg=True)
        cap = limits.tau_max if cfg.tau_total_max_nm is None else cfg.tau_total_max_nm
        self.cap = pj(cap, n, "leader_law.tau_total_max_nm", positive=True)
        self.feedback = FeedbackGate(cfg.feedback, n)
        self.q_ns = None if ns.q_ns is None else pj(ns.q_ns, n, "leader_law.null_space.q_ns")
        self._signs = ([1.0] * n, [-1.0] * n)
        self._dither_sign = self._signs[0]  # +-1 per joint, flipped every tick (friction_dither)
        # the per-joint parameters as floats for step() (law_floats.py), made once: the arrays above are set
        # here only; b_lo / b_hi / neg_* are the numpy terms' own intermediate values
        self._floats = {k: np.asarray(v, dtype=float).tolist() for k, v in {
            "g_gain": self.g_gain, "dither_gain": self.dither_gain, "dither_min": self.dither_min,
            "v_thr": self.v_thr, "coulomb": self.coulomb, "b_lo": limits.q_min + self.b_margin,
            "b_hi": limits.q_max - self.b_margin, "neg_b_kp": -self.b_kp, "b_kd": self.b_kd,
            "neg_damp": -self.damp, "cap": self.cap}.items()}
        self._floats["joints"] = law_joint_params(self._floats)  # one tuple per joint (law_tau_floats)

    def reset(self, q_now: np.ndarray | None = None) -> None:
        """Before coupling: feedback off, dither restarted, null-space posture = q_now if not configured."""
        self.feedback.reset()
        self._dither_sign = self._signs[0]
        if self.cfg.null_space.q_ns is None and q_now is not None:
            self.q_ns = np.asarray(q_now, dtype=float).copy()

    def gravity(self, q: np.ndarray) -> np.ndarray:
        """g(q) on the leader joints [N*m] (model frame mapped back)."""
        return self.model_map.torque_back(self.gravity_fn(self.model_map.forward(q)))

    def gravity_floats(self, q: np.ndarray) -> list[float]:
        """gravity(q).tolist(); with a unit map (torque_back: a copy) and an ArmDynamics' own gravity (the
        usual rig), the floats of pinocchio's result itself: the same values, two copies fewer."""
        fn, c = self.gravity_fn, self._g_floats
        if c[0] is not fn:  # (gravity_fn set again: looked at again)
            owner = getattr(fn, "__self__", None)
            fast = (self.model_map._unit and callable(getattr(owner, "gravity_floats", None))
                    and getattr(fn, "__func__", None) is getattr(type(owner), "gravity", None))
            c = self._g_floats = (fn, owner.gravity_floats if fast else None)
        return self.gravity(q).tolist() if c[1] is None else c[1](self.model_map.forward(q))

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """J on the leader joints: J_model @ dq_model/dq_leader."""
        J = np.asarray(self.jacobian_fn(self.model_map.forward(q)), dtype=float)
        dqm_dq = np.zeros((self.model_map.n_b, self.n))
        dqm_dq[np.arange(self.model_map.n_b), self.model_map.index] = self.model_map.k
        return J @ dqm_dq

    def step(self, inp: LeaderInputs, feedback_on: bool = True,
             extra: dict[str, np.ndarray] | None = None) -> LeaderOutput:
        """One tick. feedback_on=False (soft start, holds) keeps the feedback gate closed. extra: further
        named terms [N*m] summed under the same cap (a rollout's following spring, teleop/takeover.py)."""
        n, cfg, f = self.n, self.cfg, self._floats
        q = np.asarray(inp.q, dtype=float)
        qd = np.asarray(inp.q_dot, dtype=float)
        qdl = qd.tolist()
        if not (math.isfinite(sum(qdl)) or all(map(math.isfinite, qdl))):  # (a finite sum: all finite)
            qd = np.where(np.isfinite(qd), qd, 0.0)
            qdl = qd.tolist()
        gl = self.gravity_floats(q) if cfg.gravity.enabled else None
        mode = cfg.friction.mode
        sign = self._dither_sign
        if mode == "dither":  # the sign flips every tick: the two lists made once, swapped
            pos, neg = self._signs
            self._dither_sign = neg if sign is pos else pos if sign is neg else [-x for x in sign]
        ql = q.tolist() if cfg.barrier.enabled else None
        ns = (null_space_term(q, qd, self.jacobian(q), self.q_ns, self.ns_kp, self.ns_kd).tolist()
              if cfg.null_space.enabled and self.q_ns is not None else None)
        fb = self.feedback.step(inp.t, inp.tau_ext_leader if feedback_on else None, inp.contact_score_nm,
                                inp.est_t, inp.est_fresh, inp.gripper_effort)

        def raw() -> dict:  # the terms as the float kernels give them (law_floats.py), made when read
            zeros = [0.0] * n
            gl0 = zeros if gl is None else gl
            fric = (friction_dither_floats(gl0, qdl, f["dither_gain"], f["dither_min"], f["v_thr"], sign)
                    if mode == "dither" else friction_coulomb_floats(qdl, f["coulomb"], f["v_thr"])
                    if mode == "coulomb" else zeros)
            barrier = (None if ql is None else
                       barrier_floats(ql, qdl, f["b_lo"], f["b_hi"], f["neg_b_kp"], f["b_kd"]))
            return {"gravity": zeros if gl is None else scaled(f["g_gain"], gl), "friction": fric,
                    "barrier": zeros if barrier is None else barrier,
                    "null_space": zeros if ns is None else ns,
                    "damping": scaled(f["neg_damp"], qdl), "feedback": fb.tau_fb_floats}

        if extra:  # a rollout's further terms: the term lists summed in order (sum_cap)
            terms = {**raw(), **extra}
            _, tau, capped = sum_cap([np.asarray(v, dtype=float).tolist() for v in terms.values()], f["cap"])
            terms = LawTerms(terms)
        else:  # the usual tick: one pass over the joints, the same operations in the same order
            tau, capped = law_tau_floats(gl, f["g_gain"], qdl, ql, mode == "dither", mode == "coulomb", sign,
                                         f, ns, fb.tau_fb_floats)
            terms = LawTerms(raw, TERM_NAMES)  # arrays only when read (law_floats.LawTerms)
        # positional, in the field order (tau, terms, gate, contact, fresh, capped, gripper_tau, message)
        return LeaderOutput(np.array(tau), terms, fb.gate, fb.contact, fb.fresh, capped, fb.gripper_tau,
                            fb.message)


def pinocchio_gravity(model) -> Callable[[np.ndarray], np.ndarray]:
    """g(q) = RNEA(q, 0, 0) on a pinocchio model (leader description); q beyond the model's joints is cut,
    missing model joints (a gripper in the model) are held at their neutral value."""
    import pinocchio as pin

    data = model.createData()
    q0 = pin.neutral(model)

    def g(q: np.ndarray) -> np.ndarray:
        qm = q0.copy()
        k = min(len(q), model.nq)
        qm[:k] = np.asarray(q, dtype=float)[:k]
        tau = pin.computeGeneralizedGravity(model, data, qm)
        return np.asarray(tau[: len(q)], dtype=float)

    return g


def pinocchio_jacobian(model, frame: str) -> Callable[[np.ndarray], np.ndarray]:
    """6 x n Jacobian of `frame` (LOCAL_WORLD_ALIGNED) on a pinocchio model, first n joints only."""
    import pinocchio as pin

    if not model.existFrame(frame):
        raise ConfigError(f"frame {frame!r} not in the leader model", where="leader_law.null_space",
                          fix="name the end-effector frame of the leader's description")
    data, fid, q0 = model.createData(), model.getFrameId(frame), pin.neutral(model)

    def jac(q: np.ndarray) -> np.ndarray:
        qm = q0.copy()
        k = min(len(q), model.nq)
        qm[:k] = np.asarray(q, dtype=float)[:k]
        J = pin.computeFrameJacobian(model, data, qm, fid, pin.LOCAL_WORLD_ALIGNED)
        return np.asarray(J[:, : len(q)], dtype=float)

    return jac


def arm_model_fns(arm, gravity_file=None) -> tuple[Callable[[np.ndarray], np.ndarray],
                                                  Callable[[np.ndarray], np.ndarray]]:
    """(gravity_fn, jacobian_fn) of an arm description (hardware.arms name or ArmDescription), each on its own
    pinocchio Data (hardware.arms.dynamics.ArmDynamics): hand them to LeaderLaw / ArmPair. The loop thread is
    the only caller while teleop runs. gravity_file: a leader gravity identification (`factr2 leader-gravity`,
    calibration/leader_gravity.py) whose fitted link masses and first moments replace the description's in
    g(q); ConfigError if it was made for another description."""
    from hardware.arms.dynamics import ArmDynamics

    dyn = ArmDynamics(arm)
    if gravity_file is None:
        return dyn.gravity, dyn.jacobian
    from calibration import leader_gravity

    params = leader_gravity.load(gravity_file, dyn.arm)
    return pinocchio_gravity(leader_gravity.model_with_params(dyn.model, params)), dyn.jacobian


def leader_gravity_path(rig, leader: str) -> Path:
    """Where `factr2 leader-gravity` writes a leader's identification and teleop reads it: $FACTR2_CACHE
    (default ~/.cache/factr2, beside the demo's NEXT cache) / leader-gravity / <rig> / <leader>.json. A
    twin's true body comes from the rig file's [twin] seed (hardware/arms/true_body.py), so a twin's file
    names it (<leader>-seed<N>.json; -exact when the rig turns description_error off)."""
    from hardware.recording.cache import cache_home

    name = leader
    if rig.simulated:
        name += f"-seed{rig.twin.seed}" + ("" if getattr(rig.twin, "description_error", True) else "-exact")
    return cache_home() / "leader-gravity" / Path(str(rig.name)).stem / f"{name}.json"


def leader_gravity_file(rig, leader: str) -> Path | None:
    """The identification teleop uses for this leader (None: none made yet; g(q) is the description's)."""
    p = leader_gravity_path(rig, leader)
    return p if p.is_file() else None
