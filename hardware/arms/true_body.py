"""The twin's true body: an arm description with the errors a real unit has against its published model.

A real arm never matches its vendor's description (docs/twin_model.md "The true body": each magnitude). The
twin simulates a perturbed copy of the description's MuJoCo model, drawn per twin seed; the app, the
baselines, NEXT's prior and the leader's gravity compensation keep loading the published MJCF
(hardware.arms.load_arm), which this module never changes.

    model_true, err = true_body(model, load_arm("piper"), seed=0, mags=description_errors("piper"))

Per arm link (the body of each arm joint, and rigid bodies fixed to one, e.g. the Panda's hand):
- mass x f_m, f_m ~ U(mass_range); the inertia about the COM scales with it (same shape, denser part);
- COM + d, d ~ U(-com_m, com_m) per body axis [m];
- principal moments x (1 + e_k), e_k ~ U(-inertia_frac, inertia_frac), then the triangle inequality
  (I_a + I_b >= I_c) restored, so the body stays physical;
- joint armature x (1 + e), e ~ U(-armature_frac, armature_frac);
- leaders: a servo horn of U(horn_kg) at each joint (on the joint axis, moving with the child link) and an
  extra U(handle_kg) at the handle (half-way to the end-effector site, where the description lumps it).
Gripper / trigger bodies are left as described. Pure: the input model is not modified.
"""

from __future__ import annotations

import copy
import zlib
from dataclasses import dataclass, field

import numpy as np

# A uniform draw is bounded and its spread easy to state; a draw per (twin seed, arm) is reproducible.
_RNG_TAG = 0x7B0D  # separates these draws from the bank's noise streams drawn from the same seed


@dataclass(frozen=True)
class BodyErrorMagnitudes:
    """How far a real unit is from its description. mass_range: factor range on each link mass; com_m: half
    width of the COM shift per axis [m]; inertia_frac: half width of the relative error per principal moment;
    armature_frac: half width of the relative armature error; horn_kg / handle_kg: (min, max) extra masses of
    a leader's servo horns (each joint) and handle [kg]; source: where the numbers come from
    (docs/twin_model.md)."""

    mass_range: tuple[float, float] = (0.85, 1.15)
    com_m: float = 0.01
    inertia_frac: float = 0.3
    armature_frac: float = 0.3
    horn_kg: tuple[float, float] = (0.0, 0.0)
    handle_kg: tuple[float, float] = (0.0, 0.0)
    source: str = "engineering estimate"


# One source for the per-arm magnitudes (docs/twin_model.md "The true body": the reasoning and citations).
DESCRIPTION_ERRORS: dict[str, BodyErrorMagnitudes] = {
    # FACTR 2 (appendix, Piper free space): with the manufacturer's URDF FILIC errs 0.435 N*m and the observer
    # 0.248 N*m mean L1 vs NEXT 0.018; the vendor URDF's CAD masses sum to 1.15 kg against the 4.2 kg spec
    # (hardware/arms/specs.py), so the per-link split of our re-estimated description is uncertain: +-15 %
    # mass, +-1 cm COM, +-30 % inertia and armature (engineering estimate within that evidence)
    "piper": BodyErrorMagnitudes((0.85, 1.15), 0.010, 0.30, 0.30,
                                 source="FACTR 2 appendix (manufacturer URDF); estimate"),
    # i2rt runs the YAM's gravity compensation on its own description times per-joint factors
    # [1.0, 1.1, 1.1, 1.2, 1.0, 1.0] (reference/prior-art.md): the real arm is up to 20 % heavier in gravity
    "yam": BodyErrorMagnitudes((0.95, 1.20), 0.008, 0.25, 0.20,
                               source="i2rt gravity factors 1.0-1.2; COM/inertia estimate"),
    # the Panda description already carries identified values (Gaz et al., RA-L 2019, as franka_ros
    # publishes them): a smaller residual error, engineering estimate
    "panda": BodyErrorMagnitudes((0.95, 1.05), 0.005, 0.20, 0.20,
                                 source="estimate (description = Gaz et al. 2019 identification)"),
    # GELLO leaders: printed links at another infill / wall count than the 60 g/m assumed, a servo horn and
    # screws (2-4 g, not in the description) at every joint, a handle 10-30 g heavier (grip, cable, trigger
    # servo lead): engineering estimates from the build (hardware/arms/specs.py GELLO section)
    "gello_piper": BodyErrorMagnitudes((0.85, 1.20), 0.005, 0.30, 0.30, (0.002, 0.004), (0.010, 0.030),
                                       source="estimate (printed parts, horns, handle)"),
    "gello_yam": BodyErrorMagnitudes((0.85, 1.20), 0.005, 0.30, 0.30, (0.002, 0.004), (0.010, 0.030),
                                     source="estimate (printed parts, horns, handle)"),
}
LEADER_DEFAULT = DESCRIPTION_ERRORS["gello_piper"]  # a user's leader MJCF
FOLLOWER_DEFAULT = DESCRIPTION_ERRORS["piper"]  # a user's follower MJCF


def description_errors(arm_name: str, role: str = "follower") -> BodyErrorMagnitudes:
    """The magnitudes for an arm (by description name); an unknown arm gets its role's default."""
    if arm_name in DESCRIPTION_ERRORS:
        return DESCRIPTION_ERRORS[arm_name]
    return LEADER_DEFAULT if role == "leader" else FOLLOWER_DEFAULT


@dataclass
class BodyError:
    """What was drawn (for tests, docs and the twin's report). Per arm link, in arm-joint order: mass
    [kg] described / true, COM shift [m, body frame], principal-moment factors, armature factors, horn
    mass [kg]; handle_kg: the handle's extra mass."""

    arm: str
    seed: int
    bodies: list[str] = field(default_factory=list)
    mass_desc: np.ndarray = field(default_factory=lambda: np.zeros(0))
    mass_true: np.ndarray = field(default_factory=lambda: np.zeros(0))
    com_shift: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    inertia_factor: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    armature_factor: np.ndarray = field(default_factory=lambda: np.zeros(0))
    horn_kg: np.ndarray = field(default_factory=lambda: np.zeros(0))
    handle_kg: float = 0.0


# -- pure rigid-body arithmetic ------------------------------------------------------------------------
def triangle_inertia(moments: np.ndarray) -> np.ndarray:
    """Principal moments [kg*m^2] made physical: each at most the sum of the other two."""
    m = np.asarray(moments, float).copy()
    for _ in range(3):
        for k in range(3):
            others = m.sum() - m[k]
            m[k] = min(m[k], others)
    return m


def combine_point_masses(mass: float, com: np.ndarray, inertia: np.ndarray,
                         points: list[tuple[float, np.ndarray]]) -> tuple[float, np.ndarray, np.ndarray]:
    """A body (mass [kg], com [m], 3x3 inertia about the com) plus point masses (kg, position [m]) in the
    same frame -> (mass, com, 3x3 inertia about the new com) by the parallel-axis theorem."""
    parts = [(mass, np.asarray(com, float), np.asarray(inertia, float))]
    parts += [(float(m), np.asarray(p, float), np.zeros((3, 3))) for m, p in points if m > 0]
    total = sum(p[0] for p in parts)
    c = sum(p[0] * p[1] for p in parts) / total
    out = np.zeros((3, 3))
    for m, p, inertia_own in parts:
        d = p - c
        out += inertia_own + m * (float(d @ d) * np.eye(3) - np.outer(d, d))
    return total, c, out


def _principal(inertia: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """3x3 inertia -> (principal moments, quaternion w x y z of the principal frame, det +1)."""
    import mujoco

    vals, vecs = np.linalg.eigh(0.5 * (inertia + inertia.T))
    if np.linalg.det(vecs) < 0:
        vecs[:, 2] = -vecs[:, 2]
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(vecs).reshape(-1))
    return np.maximum(vals, 1e-12), quat


def _full_inertia(moments: np.ndarray, iquat: np.ndarray) -> np.ndarray:
    import mujoco

    r = np.zeros(9)
    mujoco.mju_quat2Mat(r, np.asarray(iquat, float))
    r = r.reshape(3, 3)
    return r @ np.diag(moments) @ r.T


def _arm_bodies(model, arm) -> tuple[list[int], list[int]]:
    """(body ids of the arm joints, dof ids) in arm-joint order; bodies welded to an arm link without a
    joint of their own (a hand flange) follow their link."""
    import mujoco

    bodies, dofs = [], []
    for jn in arm.joint_names:
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, jn)
        bodies.append(int(model.jnt_bodyid[jid]))
        dofs.append(int(model.jnt_dofadr[jid]))
    return bodies, dofs


def _fixed_children(model, body: int) -> list[int]:
    return [b for b in range(1, model.nbody)
            if model.body_parentid[b] == body and model.body_jntnum[b] == 0 and model.body_mass[b] > 0]


def true_body(model, arm, seed: int, mags: BodyErrorMagnitudes):
    """(perturbed copy of `model`, BodyError). model: a compiled mujoco.MjModel holding `arm` (its file or a
    scene with it); arm: hardware.arms.ArmDescription; seed: the twin's device seed. Deterministic."""
    import mujoco

    out = copy.deepcopy(model)
    rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, zlib.crc32(arm.name.encode()), _RNG_TAG])
    bodies, dofs = _arm_bodies(out, arm)
    n = len(bodies)
    err = BodyError(arm=arm.name, seed=int(seed), bodies=[mujoco.mj_id2name(out, mujoco.mjtObj.mjOBJ_BODY, b)
                                                          for b in bodies])
    err.mass_desc = np.array([out.body_mass[b] for b in bodies])
    # all draws up front, in a fixed order, so a magnitude set to zero changes no other draw
    f_m = rng.uniform(*mags.mass_range, size=n)
    d_com = rng.uniform(-mags.com_m, mags.com_m, size=(n, 3))
    e_in = rng.uniform(-mags.inertia_frac, mags.inertia_frac, size=(n, 3))
    e_arm = rng.uniform(-mags.armature_frac, mags.armature_frac, size=n)
    horns = rng.uniform(*mags.horn_kg, size=n)
    handle = float(rng.uniform(*mags.handle_kg))
    handle_at = _handle_point(out, arm, bodies[-1])
    for k, b in enumerate(bodies):
        for bb in [b] + _fixed_children(out, b):  # the hand flange scales with its link
            moments = out.body_inertia[bb] * f_m[k] * (1.0 + e_in[k])
            out.body_inertia[bb] = triangle_inertia(moments)
            out.body_mass[bb] *= f_m[k]
            out.body_ipos[bb] += d_com[k]
        # a joint's horn turns with its link, on the joint axis (the body origin: the MJCFs put joints there)
        points = [(horns[k], np.zeros(3))] if horns[k] > 0 else []
        if k == n - 1 and handle > 0:
            points.append((handle, handle_at))
        if points:
            full = _full_inertia(out.body_inertia[b], out.body_iquat[b])
            m, c, inertia = combine_point_masses(out.body_mass[b], out.body_ipos[b], full, points)
            out.body_mass[b], out.body_ipos[b] = m, c
            out.body_inertia[b], out.body_iquat[b] = _principal(inertia)
        out.dof_armature[dofs[k]] *= 1.0 + e_arm[k]
    err.mass_true = np.array([out.body_mass[b] for b in bodies])
    err.com_shift, err.inertia_factor = d_com, 1.0 + e_in
    err.armature_factor, err.horn_kg, err.handle_kg = 1.0 + e_arm, horns, handle
    mujoco.mj_setConst(out, mujoco.MjData(out))  # derived constants (subtree masses, solver weights)
    return out, err


def _handle_point(model, arm, last_body: int) -> np.ndarray:
    """Where a leader's handle sits in the last link's frame: half-way to the end-effector site (the
    description's handle is lumped there, hardware/arms/specs.py gello_from); the origin if no such site."""
    import mujoco

    sid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, arm.ee_site)
    if sid < 0 or model.site_bodyid[sid] != last_body:
        return np.zeros(3)
    return 0.5 * np.asarray(model.site_pos[sid], float)


def gravity_torque(model, arm, q: np.ndarray) -> np.ndarray:
    """Gravity torque [N*m] on the arm joints at q [rad] on a MuJoCo model (the true body or the
    description), other joints at their reference pose: MuJoCo's bias force at zero velocity."""
    import mujoco

    data = mujoco.MjData(model)
    qadr, dadr = arm.mujoco_indices(model)
    data.qpos[qadr] = np.asarray(q, float)
    mujoco.mj_forward(model, data)
    return data.qfrc_bias[dadr].copy()


__all__ = ["BodyErrorMagnitudes", "BodyError", "DESCRIPTION_ERRORS", "description_errors", "true_body",
           "triangle_inertia", "combine_point_masses", "gravity_torque"]
