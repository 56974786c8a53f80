"""Flat feature names (LeRobot style), declared once per rig: the tick record, the recorder, the reader and
the policy's normaliser all use these names and this module's mapping to recording topics.

    name                         shape  unit   what                           topic, field
    follower.joint.pos           (n,)   rad    measured joint positions       /follower/joint_state, q
    follower.joint.vel           (n,)   rad/s  measured joint velocities      /follower/joint_state, q_dot
    follower.joint.tau           (n,)   N*m    measured motor torque          /follower/joint_state, tau_m
    follower.joint.current       (n,)   A      motor current                  /follower/joint_state, current
    follower.joint.tau_ext       (n,)   N*m    estimated external torque      /follower/tau_ext, tau_ext
    follower.gripper.pos         ()     m      gripper stroke               /follower/joint_state, gripper_pos
    leader.joint.pos             (m,)   rad    leader joint positions         /leader/joint_state, q
    leader.gripper.pos           ()     rad    leader trigger                 /leader/joint_state, gripper_pos
    leader.joint.tau_cmd         (m,)   N*m    torque sent to the leader      /leader/tau_cmd, tau
    action.joint.pos             (n,)   rad    follower target after safety   /follower/command, q
    action.gripper.pos           ()     m      follower gripper target        /follower/command, gripper
    follower.joint.tau_ext_true  (n,)   N*m    twin only: PRIVILEGED truth    /follower/ground_truth
    observation.images.<cam>     (H, W, 3) uint8 camera frame                 /camera/<cam>/image

A bimanual rig prefixes each pair's arms with the pair name ("left", "right": the follower's device name less
a trailing "_follower"): `left_follower.joint.pos`, `left_action.joint.pos`, topics `/left_follower/...`.
Single-pair rigs ("arm") have no prefix.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from hardware.recording import schemas as S
from hardware.recording.schemas import ACTION

IMAGES = "observation.images."
# the policy's input and output groups (LeRobot's keys): a checkpoint's "features", the dataset, the export
OBS_STATE, OBS_FORCE, OBS_IMAGES = "observation.state", "observation.force", "observation.images"
# a LeRobot export's FIRST phase column (0 free, 1 pre-contact, 2 contact), and the key in its info.json
# feature that marks it as factr2's own labels (the value: the thresholds that made them, Thresholds.to_dict)
PHASE_FEATURE, FACTR2_PHASES = "phase", "factr2/phases"
JOINT_POS, GRIPPER_POS = "joint.pos", "gripper.pos"
POLICY_STATE = (JOINT_POS, GRIPPER_POS)  # per follower arm: what a policy observes of it, and acts on
FORCE_FEATURE = {"tau_ext": "joint.tau_ext", "current": "joint.current"}  # policy force input -> feature


@dataclass(frozen=True)
class Feature:
    """name: flat feature name; shape: per-sample shape; unit: physical unit ("" for counts/flags, "rgb" for
    images); dtype: numpy dtype name; topic/field: where a recording holds it (field "" for images);
    privileged: only a twin can know it (ground truth), never a policy input on real hardware."""

    name: str
    shape: tuple[int, ...]
    unit: str
    dtype: str
    topic: str
    field: str
    privileged: bool = False
    arm: str = ""  # the recorded arm it belongs to ("follower", "left_follower"; an action: the arm it moves)

    def to_json(self) -> dict:
        return {"shape": list(self.shape), "unit": self.unit, "dtype": self.dtype, "topic": self.topic,
                "field": self.field, "privileged": self.privileged, "arm": self.arm}

    @classmethod
    def from_json(cls, name: str, d: dict) -> Feature:
        return cls(name, tuple(int(x) for x in d["shape"]), str(d["unit"]), str(d["dtype"]), str(d["topic"]),
                   str(d["field"]), bool(d.get("privileged", False)), str(d.get("arm", "")))


def arm_prefix(pair: str, n_pairs: int) -> str:
    """"" for a single-pair rig, else "<pair>_" (the recording's topic prefix)."""
    return "" if n_pairs <= 1 else f"{pair}_"


def _arm(arm: str, n: int, leader: bool) -> list[Feature]:
    js, f = S.joint_state_topic(arm), []

    def add(what, shape, unit, topic, fld):
        f.append(Feature(f"{arm}.{what}", shape, unit, "float32", topic, fld, arm=arm))

    add(JOINT_POS, (n,), "rad", js, "q")
    add("joint.vel", (n,), "rad/s", js, "q_dot")
    if leader:
        add(GRIPPER_POS, (), "rad", js, "gripper_pos")
        add("joint.tau_cmd", (n,), "N*m", S.tau_cmd_topic(arm), "tau")
        return f
    add("joint.tau", (n,), "N*m", js, "tau_m")
    add(FORCE_FEATURE["current"], (n,), "A", js, "current")
    add(FORCE_FEATURE["tau_ext"], (n,), "N*m", S.tau_ext_topic(arm), "tau_ext")
    add(GRIPPER_POS, (), "m", js, "gripper_pos")
    return f


def pair_features(prefix: str, n_leader: int, n_follower: int, simulated: bool) -> list[Feature]:
    """The features of one leader/follower pair (prefix from arm_prefix)."""
    fol, act = f"{prefix}follower", f"{prefix}{ACTION}"
    out = _arm(f"{prefix}leader", n_leader, leader=True) + _arm(fol, n_follower, leader=False)
    cmd = S.command_topic(fol)
    out.append(Feature(f"{act}.{JOINT_POS}", (n_follower,), "rad", "float32", cmd, "q", arm=fol))
    out.append(Feature(f"{act}.{GRIPPER_POS}", (), "m", "float32", cmd, "gripper", arm=fol))
    if simulated:
        out.append(Feature(f"{fol}.joint.tau_ext_true", (n_follower,), "N*m", "float32",
                           S.ground_truth_topic(fol), "tau_ext_true", privileged=True, arm=fol))
    return out


def camera_feature(name: str, height: int, width: int) -> Feature:
    return Feature(f"{IMAGES}{name}", (int(height), int(width), 3), "rgb", "uint8", S.camera_topic(name), "")


def rig_features(rig) -> dict[str, Feature]:
    """Every feature a rig (hardware.rigs.Rig) produces, by name: its pairs' arms, actions and cameras."""
    from hardware.arms import load_arm

    out: dict[str, Feature] = {}
    for pair_name, (lead, fol) in zip(pair_names(rig), rig.pairs):
        n_l = load_arm(rig.device(lead).arm).n_joints
        n_f = load_arm(rig.device(fol).arm).n_joints
        for f in pair_features(arm_prefix(pair_name, len(rig.pairs)), n_l, n_f, rig.simulated):
            out[f.name] = f
    for c in rig.cameras:
        out[f"{IMAGES}{c.name}"] = camera_feature(c.name, c.height, c.width)
    return out


def pair_names(rig) -> list[str]:
    """Pair names: "arm" on a single-pair rig, else each pair's follower name less "_follower" ("left")."""
    if len(rig.pairs) <= 1:
        return ["arm"]
    return [fol[: -len("_follower")] if fol.endswith("_follower") else fol for _lead, fol in rig.pairs]


def rig_arm_names(rig) -> list[tuple[str, str]]:
    """Per pair of a rig: (pair name, the follower's recorded arm name: "follower", "left_follower")."""
    names = pair_names(rig)
    return [(p, f"{arm_prefix(p, len(names))}follower") for p in names]


# -- the schema a recording carries, and what a policy reads of it ------------------------------------
def features_json(features: dict[str, Feature]) -> str:
    """The recording metadata entry "features": every feature's topic, field, shape and unit, by name."""
    return json.dumps({n: f.to_json() for n, f in features.items()})


def recorded_features(meta: dict[str, str], topics) -> dict[str, Feature]:
    """The features a recording declares (its recording metadata "features", written since #36). Older
    recordings: rebuilt from the arms their joint names list (the same pair_features the rig gives), keeping
    the followers whose joint-state topic the file holds."""
    try:
        text = meta.get("features", "")
        if text:
            return {n: Feature.from_json(n, d) for n, d in json.loads(text).items()}
    except (ValueError, KeyError, TypeError):
        pass  # a damaged entry: rebuilt below as for an old recording
    try:
        joints = {str(k): list(v) for k, v in json.loads(meta.get("joint_names", "") or "{}").items()}
    except (ValueError, AttributeError, TypeError):
        joints = {}
    topics = set(topics)
    labels = set(joints) | {t.split("/")[1] for t in topics if t.count("/") == 2}
    out: dict[str, Feature] = {}
    for label in sorted(labels):
        if not label.endswith("follower") or S.joint_state_topic(label) not in topics:
            continue
        prefix = label[: -len("follower")]
        n_l = len(joints.get(f"{prefix}leader", []))
        for f in pair_features(prefix, n_l, len(joints.get(label, [])), simulated=False):
            out[f.name] = f
    return out


def follower_arms(features: dict[str, Feature]) -> list[str]:
    """The follower arms of a feature set, sorted ("follower"; "left_follower", "right_follower")."""
    return sorted({f.arm for n, f in features.items()
                   if f.arm.endswith("follower") and n == f"{f.arm}.{JOINT_POS}"})


def action_of(arm: str) -> str:
    """The action prefix of a follower arm: "follower" -> "action", "left_follower" -> "left_action"."""
    return f"{arm[: -len('follower')]}{ACTION}"


def policy_names(features: dict[str, Feature], arms: list[str], force: str) -> dict[str, list[str]]:
    """The flat names a policy on these follower arms reads and writes, in order: "state" (joint and gripper
    positions per arm), "force" (FORCE_FEATURE[force] per arm; [] for "none") and "action" (the command
    after the safety layer per arm). KeyError names a feature the set lacks."""
    state = [f"{a}.{k}" for a in arms for k in POLICY_STATE]
    force_names = [f"{a}.{FORCE_FEATURE[force]}" for a in arms] if force in FORCE_FEATURE else []
    action = [f"{action_of(a)}.{k}" for a in arms for k in POLICY_STATE]
    for n in state + force_names + action:
        if n not in features:
            raise KeyError(n)
    return {"state": state, "force": force_names, "action": action}


def size(feature: Feature) -> int:
    """Values a sample of the feature flattens to (a scalar: 1)."""
    return int(np.prod(feature.shape)) if feature.shape else 1


def follower_values(features: dict[str, Feature], arm: str, state, tau_ext) -> dict:
    """One follower's observation by feature name, read as the recording holds it: its joint-state fields from
    the JointState `state`, its external torque from the estimator's tau_ext [N*m] (NaN without one)."""
    js = S.joint_state_topic(arm)
    out = {}
    for n, f in features.items():
        if f.arm != arm or f.privileged:
            continue
        if f.topic == js:
            out[n] = getattr(state, f.field)
        elif f.field == "tau_ext":
            out[n] = tau_ext
    return out
