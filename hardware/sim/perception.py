"""A simulated camera-based object pose detector (twins only, SIMULATED): what a tag- or model-based pose
estimator behind a calibrated camera would report of a twin task's objects, made from the twin's truth.

    params = perception_params(task.perception | rig_table)      # defaults, then overrides; ConfigError
    det = PoseDetector(params, names=("peg", "hole"))
    det.reset(np.random.default_rng(episode_seed))               # this episode's calibration bias
    seen = det.update(t_s, task.detectables(model, data, p), gripper_pos_m)   # every decision (~100 Hz)
    seen["peg"].pos_m, seen["peg"].rot, seen["peg"].age_s, seen["peg"].visible

Error model (docs/perception.md gives the published numbers behind each default):
- per episode, a camera-to-robot calibration bias common to every object (translation b_cam [m] per axis,
  rotation r_cam [rad] per axis) plus a per-object estimator bias (b_obj, r_obj): a static scene seen by
  one camera gives the same wrong answer frame after frame;
- per frame, white noise on position and rotation (n_p [m], n_r [rad] per axis);
  perceived p = p_true + b_cam + b_obj + n_p;  R = Exp(n_r) Exp(r_obj) Exp(r_cam) R_true  (world frame);
- frames at rate_hz (captured at the first update at or after each frame time), each delivered latency_s
  after its capture; between deliveries the last detection is held (its age grows);
- an object within occlusion_radius_m of the gripper when a frame is captured is not detected in it (the
  hand hides it): the held detection freezes and `visible` turns False; each object's detection is also
  missing from a frame with probability drop_prob (motion blur, a lost track);
- nothing else: no contact state, no velocities, no forces.
The pure pieces (perception_params, perturb_pose, rotvec_exp, seen_vector) are functions on arrays.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, fields, replace

import numpy as np

from hardware.errors import ConfigError

AGE_MAX_S = 2.0  # s: the age a policy's input reports for a detection older than this, or never made
ROT6_NEVER = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0)  # the 6D rotation a never-seen object reports (identity)
T_EPS_S = 1e-6  # s: times this close count as equal (a caller's t = k * dt drifts from a summed frame clock)


@dataclass(frozen=True)
class PerceptionParams:
    """The detector's error model, every field with its unit (defaults: docs/perception.md, sources there)."""

    bias_pos_m: float = 0.003  # std of the per-episode camera-to-robot calibration bias, per axis [m]
    bias_rot_rad: float = math.radians(1.0)  # std of the per-episode camera rotation bias, per axis [rad]
    noise_pos_m: float = 0.001  # per-frame position noise std, per axis [m]
    noise_rot_rad: float = math.radians(0.5)  # per-frame rotation noise std, per axis [rad]
    rate_hz: float = 30.0  # camera / detector rate [Hz]
    latency_s: float = 0.1  # age of a detection when it arrives [s]
    occlusion_radius_m: float = 0.05  # object centre within this of the gripper: not detected [m]
    drop_prob: float = 0.05  # probability that an object's detection is missing from a frame [1]
    object_bias_pos_m: float = 0.002  # std of the per-episode per-object estimator bias, per axis [m]
    object_bias_rot_rad: float = math.radians(1.0)  # std of the per-object rotation bias, per axis [rad]


_LIMITS = {  # field -> (lowest, highest) accepted, inclusive; why: a value outside is a typo, not a camera
    "bias_pos_m": (0.0, 0.1), "bias_rot_rad": (0.0, 0.5), "noise_pos_m": (0.0, 0.1),
    "noise_rot_rad": (0.0, 0.5), "rate_hz": (0.1, 1000.0), "latency_s": (0.0, 5.0),
    "occlusion_radius_m": (0.0, 1.0), "drop_prob": (0.0, 0.99), "object_bias_pos_m": (0.0, 0.1),
    "object_bias_rot_rad": (0.0, 0.5),
}


def perception_params(table: dict | None, base: PerceptionParams | None = None,
                      where: str = "[twin.perception]") -> PerceptionParams:
    """`base` (default: PerceptionParams()) with the entries of a task's or rig file's perception table;
    ConfigError (one line: what, where, fix) for an unknown key, a non-number or a value out of range."""
    base = base if base is not None else PerceptionParams()
    if table is None:
        return base
    if not isinstance(table, dict):
        raise ConfigError(f"perception settings must be a table, got {type(table).__name__}", where=where,
                          fix="write [twin.perception] with key = number lines")
    names = [f.name for f in fields(PerceptionParams)]
    kw = {}
    for k, v in table.items():
        if k not in names:
            raise ConfigError(f"unknown perception setting {k!r}", where=where,
                              fix=f"use any of {', '.join(names)}")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
            raise ConfigError(f"perception setting {k} = {v!r} is not a finite number", where=where,
                              fix=f"give {k} a number in {_LIMITS[k][0]:g} .. {_LIMITS[k][1]:g}")
        lo, hi = _LIMITS[k]
        if not lo <= float(v) <= hi:
            raise ConfigError(f"perception setting {k} = {v!r} is out of range", where=where,
                              fix=f"give {k} a number in {lo:g} .. {hi:g} (units in its name)")
        kw[k] = float(v)
    return replace(base, **kw)


def rotvec_exp(w) -> np.ndarray:
    """Rotation matrix of a rotation vector w [rad] (Rodrigues)."""
    w = np.asarray(w, float)
    a = float(np.linalg.norm(w))
    if a < 1e-12:
        return np.eye(3)
    k = w / a
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K  # np's sin: the operator's IK path, as before


def rotvec_log(R) -> np.ndarray:
    """Rotation vector [rad] of a rotation matrix (inverse of rotvec_exp, angles below pi)."""
    R = np.asarray(R, float)
    c = float(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0))
    a = math.acos(c)
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return v * (0.5 if a < 1e-9 else a / (2 * math.sin(a)))


def perturb_pose(pos, rot, dpos, drot) -> tuple[np.ndarray, np.ndarray]:
    """(pos + dpos, Exp(drot) @ rot): a pose [m, 3x3] moved by an error (dpos [m] (3,), drot [rad] (3,),
    world frame)."""
    return np.asarray(pos, float) + np.asarray(dpos, float), rotvec_exp(drot) @ np.asarray(rot, float)


@dataclass(frozen=True)
class Seen:
    """The latest detection of one object available now (SIMULATED)."""

    pos_m: np.ndarray  # (3,) perceived position [m], robot base frame (NaN if never seen)
    rot: np.ndarray  # (3, 3) perceived rotation (NaN if never seen)
    age_s: float  # how old the held detection is [s] (inf if never seen)
    visible: bool  # False while occluded / dropped: the held value is then stale


NEVER = Seen(np.full(3, np.nan), np.full((3, 3), np.nan), math.inf, False)


class PoseDetector:
    """The detector of one episode after another: reset() per episode, update() at every decision (the
    caller's clock t_s [s] must not go backwards within an episode). Not thread-safe: one caller."""

    def __init__(self, params: PerceptionParams, names: tuple[str, ...]):
        if not isinstance(params, PerceptionParams):
            raise TypeError("params must be a PerceptionParams (perception_params() makes one)")
        self.params, self.names = params, tuple(names)
        self._rng = np.random.default_rng(0)
        self.reset(self._rng)

    def reset(self, rng: np.random.Generator) -> None:
        """A new episode: draw its biases from rng (camera: common; per object), forget every detection."""
        p, n = self.params, len(self.names)
        self._rng = rng
        cam_p, cam_r = rng.normal(0.0, p.bias_pos_m, 3), rng.normal(0.0, p.bias_rot_rad, 3)
        obj_p = rng.normal(0.0, p.object_bias_pos_m, (n, 3))
        obj_r = rng.normal(0.0, p.object_bias_rot_rad, (n, 3))
        self.bias_pos_m = cam_p + obj_p  # (n, 3): each object's total position bias this episode
        # the rotation bias as one matrix per object: Exp(r_obj) Exp(r_cam)
        self.bias_rot = np.stack([rotvec_exp(obj_r[i]) @ rotvec_exp(cam_r) for i in range(n)])
        self._t_next = -math.inf  # capture time of the next frame [s] (the first update captures)
        self._pending: deque = deque()  # (arrival t [s], capture t [s], {name: (pos, rot) or None})
        self._held = {k: NEVER for k in self.names}
        self._t_held = {k: math.nan for k in self.names}  # capture time of each held detection [s]
        self._last_frame_had = {k: False for k in self.names}
        self.frames = 0  # frames captured this episode

    def _capture(self, t_s: float, truth: dict, gripper_pos_m) -> None:
        p, rng = self.params, self._rng
        g = np.asarray(gripper_pos_m, float)
        det = {}
        for i, k in enumerate(self.names):
            pos, rot = truth[k]
            occluded = float(np.linalg.norm(np.asarray(pos, float) - g)) < p.occlusion_radius_m
            dropped = rng.random() < p.drop_prob  # drawn always: the stream does not depend on occlusion
            noise_p, noise_r = rng.normal(0.0, p.noise_pos_m, 3), rng.normal(0.0, p.noise_rot_rad, 3)
            if occluded or dropped:
                det[k] = None
                continue
            det[k] = perturb_pose(np.asarray(pos, float) + self.bias_pos_m[i], self.bias_rot[i] @ rot,
                                  noise_p, noise_r)
        self._pending.append((t_s + p.latency_s, t_s, det))
        self.frames += 1

    def update(self, t_s: float, truth: dict[str, tuple[np.ndarray, np.ndarray]],
               gripper_pos_m: np.ndarray) -> dict[str, Seen]:
        """Capture a frame if one is due at t_s (truth: name -> (position [m], rotation 3x3), base frame,
        now), deliver every frame whose latency has passed, and return the latest detection of every name."""
        t_s = float(t_s)
        if t_s >= self._t_next - T_EPS_S:
            self._capture(t_s, truth, gripper_pos_m)
            period = 1.0 / self.params.rate_hz
            # the camera's own clock: frames at t0 + k * period (a late update does not shift it), one
            # frame per update at most (slots an update skipped are lost, as frames a slow reader misses)
            self._t_next = t_s + period if not math.isfinite(self._t_next) else self._t_next + period
            while self._t_next <= t_s + T_EPS_S:
                self._t_next += period
        while self._pending and self._pending[0][0] <= t_s + T_EPS_S:
            _, t_cap, det = self._pending.popleft()
            for k, d in det.items():
                self._last_frame_had[k] = d is not None
                if d is not None:
                    self._held[k] = Seen(d[0], d[1], 0.0, True)
                    self._t_held[k] = t_cap
        out = {}
        for k in self.names:
            h = self._held[k]
            if math.isnan(self._t_held[k]):
                out[k] = NEVER
            else:
                out[k] = Seen(h.pos_m, h.rot, t_s - self._t_held[k], self._last_frame_had[k])
        return out


def seen_names(names: tuple[str, ...]) -> list[str]:
    """Element names of seen_vector for these objects ("peg.pos_m.0", "peg.rot6.0", ..., "peg.visible",
    "peg.age_s")."""
    out = []
    for k in names:
        out += [f"{k}.pos_m.{i}" for i in range(3)] + [f"{k}.rot6.{i}" for i in range(6)]
        out += [f"{k}.visible", f"{k}.age_s"]
    return out


def seen_vector(seen: dict[str, Seen], names: tuple[str, ...]) -> np.ndarray:
    """The detections as one finite float32 vector (11 per object, in `names` order): position [m] (3),
    rotation as its first two columns (6, the continuous 6D form), visible (0/1), age [s] clipped to
    AGE_MAX_S. A never-seen object reports position 0, identity rotation, visible 0, age AGE_MAX_S."""
    out = []
    for k in names:
        s = seen[k]
        if not np.all(np.isfinite(s.pos_m)):
            out += [0.0, 0.0, 0.0, *ROT6_NEVER, 0.0, AGE_MAX_S]
            continue
        R = np.asarray(s.rot, float)
        out += [*np.asarray(s.pos_m, float), *R[:, 0], *R[:, 1], float(s.visible), min(s.age_s, AGE_MAX_S)]
    return np.asarray(out, dtype=np.float32)
