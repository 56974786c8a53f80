"""What every twin task is made of (SIMULATED): objects added to a follower's scene, seeded initial
conditions, and stage detectors that read the MuJoCo state as plain arrays.

    task = get_task("peg-insert")
    model = scene_model(load_arm("piper"), "table", task)   # the rig's scene + the task's objects + cameras
    params = task.reset(model, data, np.random.default_rng(seed))   # initial conditions for one episode
    obs = task.observe(model, data, params)                          # dict of arrays (the "what is where")
    tracker = StageTracker(task.stages); tracker.update(task.detect(obs, params, tracker.memory))

Detectors are pure functions of those arrays (tested on scripted states); only observe() touches MuJoCo.
Stages latch in order: a stage counts once every stage before it has been reached, and the paper's
task-progress metric is the share of stages reached. Success = every stage reached and the final stage's
condition still true at the end of the episode (task.final_ok), so a peg pulled back out is not a success.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np

from hardware.errors import ConfigError

# Scene objects of the plain table scene that a task scene removes (they would sit in the task's workspace).
TABLE_CLUTTER_GEOMS = ("fixed_block",)
TABLE_CLUTTER_BODIES = ("box",)
# Contact settings shared by task objects (why: docs/tasks.md "Contact settings"): a stiff, critically damped
# contact (time constant 2 ms = twice the 1 ms physics step, MuJoCo's stability floor) and an impedance that
# reaches 0.99 within 0.5 mm, so that resting penetration stays a fraction of the 0.5 mm clearance per side.
SOLREF = (0.002, 1.0)
SOLIMP = (0.95, 0.99, 0.0005, 0.5, 2.0)
CONTACT_MARGIN_M = 0.0  # no early contact: a margin would eat the clearance
OBJECT_CONTYPE, OBJECT_CONAFFINITY = 1, 3  # like the table: touched by the arm (contype 2) and by objects


@dataclass
class StageTracker:
    """Latching, ordered stage flags for one episode; memory holds what a detector accumulates (coverage)."""

    stages: tuple[str, ...]
    done: np.ndarray = field(init=False)
    t_done: np.ndarray = field(init=False)
    memory: dict = field(default_factory=dict)

    def __post_init__(self):
        self.done = np.zeros(len(self.stages), dtype=bool)
        self.t_done = np.full(len(self.stages), np.nan)

    def update(self, flags: np.ndarray, t: float = float("nan")) -> list[str]:
        """Latch newly reached stages (in order); returns the names reached by this update."""
        new = latch_stages(self.done, np.asarray(flags, dtype=bool))
        names = [self.stages[i] for i in np.flatnonzero(new & ~self.done)]
        self.t_done[new & ~self.done] = t
        self.done = new
        return names

    @property
    def progress(self) -> float:
        return task_progress(self.done)


def latch_stages(done: np.ndarray, flags: np.ndarray) -> np.ndarray:
    """done | flags, where stage k may only turn on when stages 0..k-1 are done (after this update)."""
    out = np.asarray(done, dtype=bool).copy()
    for k, f in enumerate(np.asarray(flags, dtype=bool)):
        if not out[k] and f and out[:k].all():
            out[k] = True
    return out


def task_progress(done: np.ndarray) -> float:
    """The paper's task-progress metric: the share of stages completed (0..1)."""
    d = np.asarray(done, dtype=bool)
    return float(d.mean()) if d.size else 0.0


class Task:
    """One task. Subclasses set name, title, stages, arms, episode_s and implement the four methods."""

    name: str = ""
    title: str = ""
    stages: tuple[str, ...] = ()
    arms: tuple[str, ...] = ("piper",)  # follower arms whose scene can hold the task (reach, gripper size)
    episode_s: float = 30.0  # s: time limit of one demonstration
    scene_camera = "task_scene"  # MJCF camera names the task adds (rendered by the rig's cameras)
    wrist_camera = "wrist"
    # the simulated pose detector's settings for this task (hardware/sim/perception.py PerceptionParams
    # fields), over the defaults and under a rig's [twin.perception]; {}: the defaults
    perception: dict = {}
    # whether `factr2 collect` lets the scripted operator see through the detector by default (--perception
    # / --no-perception decide otherwise); False: it sees the twin's truth
    operator_perception: bool = False
    # the feedback estimator `factr2 collect` gives the scripted operator by default (--mode decides
    # otherwise): None: the rig's (NEXT with a checkpoint, else the disturbance observer); "dob" where the
    # task's band is finer than the NEXT checkpoint resolves (cap-screw, docs/tasks.md)
    operator_feedback: str | None = None

    def add_objects(self, spec: mujoco.MjSpec, arm) -> None:
        raise NotImplementedError

    def reset(self, model, data, rng: np.random.Generator) -> dict:
        """Place the objects for one episode (data is mj_forward'ed by the caller); returns the episode's
        parameters (arrays/floats: targets, offsets) that observe() and detect() need."""
        raise NotImplementedError

    def observe(self, model, data, params: dict) -> dict:
        """The task-relevant state as arrays (the only MuJoCo read)."""
        raise NotImplementedError

    def detect(self, obs: dict, params: dict, memory: dict) -> np.ndarray:
        """Stage conditions now (bool per stage); may accumulate into memory (e.g. wiped cells)."""
        raise NotImplementedError

    def final_ok(self, obs: dict, params: dict, memory: dict) -> bool:
        """Whether the end state still holds the result (default: the last stage's condition now)."""
        return bool(self.detect(obs, params, dict(memory))[-1])

    def detectables(self, model, data, params: dict) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """The TRUE poses (position [m] (3,), rotation (3, 3), world = robot base frame) of the objects a
        camera-based pose estimator could report, by name (hardware/sim/perception.py perturbs them). Only
        poses: no contact state, velocities, forces or hidden parameters. Naming: an object `n` is the one
        that observe() / the episode params hold as `n_pos`, `n_rot` or `n_yaw` (where they do), so that
        what is seen can stand in for them (factr2_teleop/tasks/seen.py)."""
        raise NotImplementedError(f"task {self.name} names no detectable objects (Task.detectables)")

    def check_arm(self, arm_name: str, where: str) -> None:
        if arm_name not in self.arms:
            raise ConfigError(f"task {self.name} does not fit the {arm_name} arm's scene", where=where,
                              fix=f"use a rig whose follower is one of {', '.join(self.arms)} (factr2 tasks)")


def _body_id(model, name: str) -> int:
    return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)


def free_joint_adr(model, body: str) -> tuple[int, int]:
    """(qpos address, dof address) of a body's free joint."""
    j = model.body_jntadr[_body_id(model, body)]
    return int(model.jnt_qposadr[j]), int(model.jnt_dofadr[j])


def set_free_pose(model, data, body: str, pos, yaw: float = 0.0) -> None:
    """Teleport a free body to pos [m] with a yaw [rad] about world z, at rest."""
    qa, da = free_joint_adr(model, body)
    data.qpos[qa:qa + 3] = pos
    data.qpos[qa + 3:qa + 7] = yaw_quat(yaw)
    data.qvel[da:da + 6] = 0.0


def set_static_pos(model, data, body: str, pos, yaw: float = 0.0) -> None:
    """Move a fixed task object (a mocap body: fixed in the physics, placed per episode) to pos [m], yaw
    [rad]. (Writing model.body_pos of a plain static body is not seen by a twin world, which lets resting
    bodies sleep: its pose is not recomputed.)"""
    k = model.body_mocapid[_body_id(model, body)]
    if k < 0:
        raise ValueError(f"task body {body!r} is not a mocap body")
    data.mocap_pos[k] = pos
    data.mocap_quat[k] = yaw_quat(yaw)


def task_perception(task: Task, rig_table: dict | None = None, where: str = "[twin.perception]"):
    """The detector settings of a task on a rig (PerceptionParams): defaults, then the task's own, then the
    rig file's [twin.perception] table; ConfigError (one line) for a bad entry."""
    from hardware.sim.perception import perception_params

    own = perception_params(task.perception, where=f"task {task.name} perception")
    return perception_params(rig_table, base=own, where=where)


def yaw_quat(yaw: float) -> np.ndarray:
    return np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])


def body_pose(model, data, body: str) -> tuple[np.ndarray, np.ndarray]:
    """(position [m], rotation matrix 3x3) of a body in the world."""
    b = _body_id(model, body)
    return data.xpos[b].copy(), data.xmat[b].reshape(3, 3).copy()


def touching(model, data, body_a: str, bodies_b: tuple[str, ...]) -> np.ndarray:
    """For each body in bodies_b: whether it is in contact with body_a now (bool array)."""
    a = _body_id(model, body_a)
    ids = np.array([_body_id(model, b) for b in bodies_b])
    out = np.zeros(len(ids), dtype=bool)
    n = data.ncon
    if n:
        b1 = model.geom_bodyid[data.contact.geom1[:n]]
        b2 = model.geom_bodyid[data.contact.geom2[:n]]
        for k, b in enumerate(ids):
            out[k] = bool(np.any(((b1 == a) & (b2 == b)) | ((b2 == a) & (b1 == b))))
    return out


def contact_force_between(model, data, body_a: str, bodies_b: tuple[str, ...]) -> float:
    """Sum of the normal contact forces [N] between body_a and any of bodies_b now."""
    a = _body_id(model, body_a)
    ids = {_body_id(model, b) for b in bodies_b}
    f6, total = np.zeros(6), 0.0
    for i in range(data.ncon):
        c = data.contact[i]
        b1, b2 = model.geom_bodyid[c.geom1], model.geom_bodyid[c.geom2]
        if (b1 == a and b2 in ids) or (b2 == a and b1 in ids):
            mujoco.mj_contactForce(model, data, i, f6)
            total += abs(f6[0])
    return total


def max_penetration_m(data, geoms: set[int] | None = None) -> float:
    """Deepest interpenetration [m] among current contacts (optionally only those touching `geoms`)."""
    n = data.ncon
    if not n:
        return 0.0
    dist = data.contact.dist[:n]
    if geoms is not None:
        g1, g2 = data.contact.geom1[:n], data.contact.geom2[:n]
        keep = np.isin(g1, list(geoms)) | np.isin(g2, list(geoms))
        dist = dist[keep]
    return float(max(0.0, -dist.min())) if dist.size else 0.0


def add_box(body, name: str, half, pos=(0, 0, 0), rgba=(0.6, 0.6, 0.6, 1), mass: float | None = None,
            friction=(0.8, 0.005, 0.0001), collide: bool = True):
    g = body.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_BOX, size=list(half), pos=list(pos),
                      rgba=list(rgba), friction=list(friction), solref=list(SOLREF), solimp=list(SOLIMP),
                      margin=CONTACT_MARGIN_M)
    if mass is not None:
        g.mass = mass
    if collide:
        g.contype, g.conaffinity = OBJECT_CONTYPE, OBJECT_CONAFFINITY
    else:
        g.contype = g.conaffinity = 0
    return g


def scene_model(arm, scene: str, task: Task | None) -> mujoco.MjModel:
    """The follower world's model: the arm's scene file, plus (with a task) the task's objects and cameras,
    the table clutter removed. A task's scene is built in memory (MjSpec), never written to disk."""
    path = str(arm.scene_path(scene))
    if task is None:
        return mujoco.MjModel.from_xml_path(path)
    task.check_arm(arm.name, where=f"scene {scene}")
    spec = mujoco.MjSpec.from_file(path)
    for g in TABLE_CLUTTER_GEOMS:
        if spec.geom(g) is not None:
            spec.delete(spec.geom(g))
    for b in TABLE_CLUTTER_BODIES:
        if spec.body(b) is not None:
            spec.delete(spec.body(b))
    for k in list(spec.keys):  # keyframes list the removed objects' qpos
        spec.delete(k)
    task.add_objects(spec, arm)
    return spec.compile()


def look_at_xyaxes(pos, target) -> list[float]:
    """MJCF camera xyaxes for a camera at pos looking at target [m] with the image's up toward world +z."""
    f = np.asarray(target, float) - np.asarray(pos, float)
    f /= np.linalg.norm(f)
    x = np.cross(f, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(x, f)
    return [*x, *y]


def add_cameras(task: Task, spec: mujoco.MjSpec, look_at, wrist_body: str = "link6") -> None:
    """A scene camera in front of and above the workspace looking at `look_at` [m], and a wrist camera on the
    follower's last link looking along its approach axis (+z of the link), the fingers in view."""
    pos = np.asarray(look_at, float) + np.array([0.42, 0.0, 0.32])
    spec.worldbody.add_camera(name=task.scene_camera, pos=list(pos), quat=list(xyaxes_quat(
        look_at_xyaxes(pos, look_at))), fovy=50.0)
    body = spec.body(wrist_body)
    if body is not None:  # view axis (-z of the camera) along the link's +z, tilted 20 deg toward the fingers
        a = np.deg2rad(20.0)
        spec_x, spec_y = [0.0, -1.0, 0.0], [-np.cos(a), 0.0, -np.sin(a)]
        body.add_camera(name=task.wrist_camera, pos=[0.065, 0.0, 0.07],
                        quat=list(xyaxes_quat(spec_x + spec_y)), fovy=80.0)


def xyaxes_quat(xyaxes) -> np.ndarray:
    """Quaternion (w x y z) of a frame given its x and y axes (MJCF xyaxes convention)."""
    x = np.asarray(xyaxes[:3], float)
    x /= np.linalg.norm(x)
    y = np.asarray(xyaxes[3:], float)
    y -= x * np.dot(x, y)
    y /= np.linalg.norm(y)
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.column_stack([x, y, np.cross(x, y)]).ravel())
    return q
