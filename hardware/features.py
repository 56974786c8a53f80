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

from dataclasses import dataclass

from hardware.recording import schemas as S
from hardware.recording.schemas import ACTION

IMAGES = "observation.images."


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


def arm_prefix(pair: str, n_pairs: int) -> str:
    """"" for a single-pair rig, else "<pair>_" (the recording's topic prefix)."""
    return "" if n_pairs <= 1 else f"{pair}_"


def _arm(arm: str, n: int, leader: bool) -> list[Feature]:
    js, f = S.joint_state_topic(arm), []
    f.append(Feature(f"{arm}.joint.pos", (n,), "rad", "float32", js, "q"))
    f.append(Feature(f"{arm}.joint.vel", (n,), "rad/s", "float32", js, "q_dot"))
    if leader:
        f.append(Feature(f"{arm}.gripper.pos", (), "rad", "float32", js, "gripper_pos"))
        f.append(Feature(f"{arm}.joint.tau_cmd", (n,), "N*m", "float32", S.tau_cmd_topic(arm), "tau"))
        return f
    f.append(Feature(f"{arm}.joint.tau", (n,), "N*m", "float32", js, "tau_m"))
    f.append(Feature(f"{arm}.joint.current", (n,), "A", "float32", js, "current"))
    f.append(Feature(f"{arm}.joint.tau_ext", (n,), "N*m", "float32", S.tau_ext_topic(arm), "tau_ext"))
    f.append(Feature(f"{arm}.gripper.pos", (), "m", "float32", js, "gripper_pos"))
    return f


def pair_features(prefix: str, n_leader: int, n_follower: int, simulated: bool) -> list[Feature]:
    """The features of one leader/follower pair (prefix from arm_prefix)."""
    fol, act = f"{prefix}follower", f"{prefix}{ACTION}"
    out = _arm(f"{prefix}leader", n_leader, leader=True) + _arm(fol, n_follower, leader=False)
    cmd = S.command_topic(fol)
    out.append(Feature(f"{act}.joint.pos", (n_follower,), "rad", "float32", cmd, "q"))
    out.append(Feature(f"{act}.gripper.pos", (), "m", "float32", cmd, "gripper"))
    if simulated:
        out.append(Feature(f"{fol}.joint.tau_ext_true", (n_follower,), "N*m", "float32",
                           S.ground_truth_topic(fol), "tau_ext_true", privileged=True))
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
