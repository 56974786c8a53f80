"""Arm descriptions: one MJCF file per arm, read by MuJoCo (the twin) and pinocchio (dynamics).

    from hardware.arms import load_arm, list_arms
    arm = load_arm("piper")            # or a path to an MJCF file following docs/arms.md
    arm.limits                         # hardware.types.JointLimits (rad, rad/s, N*m, N*m/s)
    arm.mujoco_model()                 # mujoco.MjModel of the arm alone (cached)
    arm.pinocchio_model()              # pinocchio.Model, arm joints only, gripper locked (cached)
    arm.scene_path("table")            # hardware/arms/scenes/piper_table.xml

Dynamics helpers on these models: hardware.arms.dynamics. The files are generated from
hardware/arms/specs.py (`python -m hardware.arms.generate`); the conventions the loader checks are listed
in hardware/arms/generate.py and docs/arms.md.
"""

from __future__ import annotations

import hashlib
import threading
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hardware.errors import ConfigError
from hardware.types import JointLimits

ARMS_DIR = Path(__file__).resolve().parent
SCENES_DIR = ARMS_DIR / "scenes"
FIX_HINT = "see docs/arms.md (the factr2.* custom fields every arm MJCF needs)"
_LOCK = threading.Lock()
_CACHE: dict[tuple[str, str], ArmDescription] = {}


@dataclass(frozen=True, eq=False)
class ArmDescription:
    """What the rest of the project knows about an arm (everything from its MJCF file).

    joint_names: arm joints in order (the order of every q/qd/tau array); gripper_joints: the gripper's
    joints (first one actuated), locked in the pinocchio model. limits [rad, rad/s, N*m, N*m/s];
    armature [kg*m^2] per arm joint; q_home [rad]; ee_site: end-effector site (MuJoCo) = frame (pinocchio);
    role: "follower", "leader" or "sim"; sha256 of the file's bytes. gripper_range: (min, max) of the first
    (actuated) gripper joint [m per finger, or rad for a leader trigger]; gripper_stroke_gain: stroke per unit
    of that joint (2.0 for a parallel gripper whose mirror finger follows it: stroke = 2 x finger travel [m];
    1.0 otherwise), so JointState.gripper_pos = gain * q_gripper.
    """

    name: str
    mjcf_path: Path
    joint_names: tuple[str, ...]
    gripper_joints: tuple[str, ...]
    limits: JointLimits
    sha256: str
    role: str
    ee_site: str
    armature: np.ndarray
    q_home: np.ndarray
    gripper_range: tuple[float, float] = (0.0, 0.0)
    gripper_stroke_gain: float = 1.0
    motors: tuple[str, ...] = ()  # the twin's motor presets per joint (factr2.motors; imported arms)
    _cache: dict = field(default_factory=dict, repr=False)

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    def mujoco_model(self):
        """mujoco.MjModel of the arm alone (cached; treat as read-only, copy before changing it)."""
        with _LOCK:
            if "mj" not in self._cache:
                self._cache["mj"] = _compile_mujoco(self.mjcf_path)
            return self._cache["mj"]

    def pinocchio_model(self):
        """pinocchio.Model with the arm joints only (gripper joints locked closed, at 0), cached.

        Includes the joints' armature (so crba / rnea add armature, as MuJoCo's qM does); no damping or
        friction terms (MuJoCo's passive forces are not in pinocchio's dynamics).
        """
        with _LOCK:
            if "pin" not in self._cache:
                self._cache["pin"] = _build_pinocchio(self)
            return self._cache["pin"]

    def scene_path(self, scene: str = "table") -> Path:
        """MuJoCo scene file that includes this arm (hardware/arms/scenes/<name>_<scene>.xml)."""
        path = self.mjcf_path.parent / "scenes" / f"{self.name}_{scene}.xml"
        if not path.is_file():
            have = sorted(p.name for p in (self.mjcf_path.parent / "scenes").glob(f"{self.name}_*.xml"))
            raise ConfigError(f"no scene '{scene}' for arm '{self.name}'", where=str(path),
                              fix=f"use one of {have or 'none'}, or add the scene (docs/arms.md)")
        return path

    def mujoco_indices(self, model) -> tuple[np.ndarray, np.ndarray]:
        """(qpos addresses, dof addresses) of the arm joints in `model` (the arm file or a scene with it)."""
        import mujoco

        qadr, dadr = [], []
        for jn in self.joint_names:
            jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, jn)
            if jid < 0:
                raise ConfigError(f"joint '{jn}' of arm '{self.name}' not in this MuJoCo model",
                                  where=self.name, fix="load a scene that includes this arm's MJCF")
            qadr.append(int(model.jnt_qposadr[jid]))
            dadr.append(int(model.jnt_dofadr[jid]))
        return np.asarray(qadr), np.asarray(dadr)


def list_arms() -> list[str]:
    """Names of the arm descriptions shipped in hardware/arms/ (load_arm accepts each)."""
    return sorted(p.stem for p in ARMS_DIR.glob("*.xml"))


def user_arms() -> list[str]:
    """Names of the arms imported into the user's arm folder (`factr2 arm import`; docs/arms_import.md)."""
    from hardware.switches import switches

    return sorted(p.stem for p in switches().arms.glob("*.xml"))


def load_arm(name_or_path: str | Path) -> ArmDescription:
    """Load an arm by name (built-in: "piper", "yam", "panda", "gello_piper", "gello_yam"; then the arms
    imported into the user's arm folder, $FACTR2_ARMS) or MJCF path.

    Raises ConfigError (one line: which file/field, how to fix) for an unknown name or a malformed file.
    """
    path = _resolve(name_or_path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"cannot read arm description ({exc.strerror})", where=str(path),
                          fix="check the path and its permissions") from None
    sha = hashlib.sha256(data).hexdigest()
    key = (str(path), sha)
    with _LOCK:
        if key in _CACHE:
            return _CACHE[key]
    desc = _parse(path, sha)
    with _LOCK:
        _CACHE[key] = desc
    return desc


def _resolve(name_or_path: str | Path) -> Path:
    s = str(name_or_path)
    if s in list_arms():
        return ARMS_DIR / f"{s}.xml"
    if "/" not in s and not s.endswith(".xml"):
        from hardware.switches import switches

        user = switches().arms / f"{s}.xml"
        if user.is_file():
            return user.resolve()
    p = Path(s).expanduser()
    if p.suffix.lower() == ".xml" or p.exists() or "/" in s:
        if not p.is_file():
            raise ConfigError("arm description file not found", where=str(p),
                              fix=f"give an existing MJCF path or one of: {', '.join(list_arms())}")
        return p.resolve()
    raise ConfigError(f"unknown arm '{s}'", where="arm",
                      fix=f"use one of: {', '.join(list_arms() + user_arms())}, a path to an MJCF file, or "
                          "import its URDF (factr2 arm import FILE.urdf --name NAME)")


def _compile_mujoco(path: Path):
    import mujoco

    try:
        return mujoco.MjModel.from_xml_path(str(path))
    except Exception as exc:  # mujoco raises ValueError with the XML error; keep the first line
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ConfigError(f"MJCF does not compile: {msg}", where=str(path),
                          fix="fix the XML (or regenerate it: python -m hardware.arms.generate)") from None


def _custom_text(model, name: str, path: Path) -> str:
    import mujoco

    tid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TEXT, name)
    if tid < 0:
        raise ConfigError(f"missing <custom><text name=\"{name}\">", where=str(path), fix=FIX_HINT)
    adr, size = int(model.text_adr[tid]), int(model.text_size[tid])
    return bytes(model.text_data[adr:adr + size]).split(b"\0")[0].decode()


def _custom_numeric(model, name: str, n: int, path: Path) -> np.ndarray:
    import mujoco

    nid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_NUMERIC, name)
    if nid < 0:
        raise ConfigError(f"missing <custom><numeric name=\"{name}\">", where=str(path), fix=FIX_HINT)
    adr, size = int(model.numeric_adr[nid]), int(model.numeric_size[nid])
    vals = np.array(model.numeric_data[adr:adr + size], dtype=float)
    if vals.shape != (n,) or not np.all(np.isfinite(vals)):
        raise ConfigError(f"numeric \"{name}\" has {size} values (or a non-finite one), expected {n}",
                          where=str(path), fix="give one finite value per arm joint, in joint order")
    return vals


def _parse(path: Path, sha: str) -> ArmDescription:
    import mujoco

    m = _compile_mujoco(path)
    joints = tuple(_custom_text(m, "factr2.arm_joints", path).split())
    gripper = (tuple(_custom_text(m, "factr2.gripper_joints", path).split())
               if mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_TEXT, "factr2.gripper_joints") >= 0 else ())
    role = _custom_text(m, "factr2.role", path).strip() or "follower"
    ee = _custom_text(m, "factr2.ee_site", path).strip()
    if not joints:
        raise ConfigError("factr2.arm_joints lists no joints", where=str(path), fix=FIX_HINT)
    if mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, ee) < 0:
        raise ConfigError(f"end-effector site '{ee}' (factr2.ee_site) not found", where=str(path),
                          fix="add the <site> or correct factr2.ee_site")
    n = len(joints)
    q_min, q_max, tau_max, armature = (np.zeros(n) for _ in range(4))
    for i, jn in enumerate(joints + gripper):
        jid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, jn)
        if jid < 0:
            raise ConfigError(f"joint '{jn}' named in factr2.*_joints does not exist", where=str(path),
                              fix="name joints that exist in the file")
        if i >= n:
            continue
        if m.jnt_type[jid] != mujoco.mjtJoint.mjJNT_HINGE or not m.jnt_limited[jid]:
            raise ConfigError(f"arm joint '{jn}' must be a hinge with a range", where=str(path),
                              fix="set type=\"hinge\" and range=\"lo hi\" [rad]")
        lo, hi = m.jnt_actfrcrange[jid]
        if not m.jnt_actfrclimited[jid] or not (hi > 0 and lo < 0):
            raise ConfigError(f"arm joint '{jn}' needs actuatorfrcrange=\"-tau_max tau_max\" [N*m]",
                              where=str(path), fix="add the torque limit to the joint")
        q_min[i], q_max[i] = m.jnt_range[jid]
        tau_max[i] = min(-lo, hi)
        armature[i] = m.dof_armature[m.jnt_dofadr[jid]]
    v_max = _custom_numeric(m, "factr2.v_max", n, path)
    rate = _custom_numeric(m, "factr2.tau_rate_max", n, path)
    q_home = _custom_numeric(m, "factr2.q_home", n, path)
    extra = {}
    for key in ("kp_max", "kd_max"):
        if mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_NUMERIC, f"factr2.{key}") >= 0:
            extra[key] = _custom_numeric(m, f"factr2.{key}", n, path)
    try:
        limits = JointLimits(q_min=q_min, q_max=q_max, v_max=v_max, tau_max=tau_max, tau_rate_max=rate,
                             **extra)
    except ValueError as exc:
        raise ConfigError(f"invalid limits: {exc}", where=str(path), fix=FIX_HINT) from None
    if np.any(q_home < q_min) or np.any(q_home > q_max):
        raise ConfigError("factr2.q_home lies outside the joint ranges", where=str(path),
                          fix="pick a home pose inside every joint's range")
    for a in (armature, q_home):
        a.setflags(write=False)
    g_range, gain = (0.0, 0.0), 1.0
    if gripper:
        gids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, g) for g in gripper]
        g_range = (float(m.jnt_range[gids[0]][0]), float(m.jnt_range[gids[0]][1]))
        slides = [g for g in gids if m.jnt_type[g] == mujoco.mjtJoint.mjJNT_SLIDE]
        gain = 2.0 if len(slides) == 2 else 1.0
    motors = ()
    if mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_TEXT, "factr2.motors") >= 0:
        motors = tuple(_custom_text(m, "factr2.motors", path).split())
        if len(motors) != n:
            raise ConfigError(f"factr2.motors lists {len(motors)} motor types for {n} joints",
                              where=str(path),
                              fix="list one motor preset per arm joint (hardware/sim/presets.py)")
    desc = ArmDescription(name=path.stem, mjcf_path=path, joint_names=joints, gripper_joints=gripper,
                          limits=limits, sha256=sha, role=role, ee_site=ee, armature=armature, q_home=q_home,
                          gripper_range=g_range, gripper_stroke_gain=gain, motors=motors)
    desc._cache["mj"] = m
    return desc


def _build_pinocchio(desc: ArmDescription):
    import pinocchio as pin

    try:
        full = pin.buildModelFromMJCF(str(desc.mjcf_path))
    except Exception as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ConfigError(f"pinocchio cannot read the MJCF: {first}", where=str(desc.mjcf_path),
                          fix="keep to hinge/slide joints and quat frames (no euler)") from None
    keep = set(desc.joint_names)
    lock = [full.getJointId(nm) for nm in full.names[1:] if nm not in keep]
    model = pin.buildReducedModel(full, lock, pin.neutral(full)) if lock else full
    if tuple(model.names[1:]) != desc.joint_names:
        raise ConfigError(f"pinocchio joint order {tuple(model.names[1:])} differs from factr2.arm_joints",
                          where=str(desc.mjcf_path), fix="list the arm joints in kinematic order")
    if not model.existFrame(desc.ee_site):
        raise ConfigError(f"pinocchio model has no frame '{desc.ee_site}'", where=str(desc.mjcf_path),
                          fix="put the end-effector <site> on an arm link")
    model.name = desc.name
    return model


__all__ = ["ArmDescription", "list_arms", "load_arm", "user_arms", "ARMS_DIR", "SCENES_DIR"]
