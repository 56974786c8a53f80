"""One arm pair's tick into a recording, for every producer (teleop, demo, task collection, policy rollout):
the same topics and fields whoever records (hardware.features names them)."""

from __future__ import annotations

import numpy as np

from hardware.recording import schemas as S
from hardware.recording.wire_records import joint_state_fields, num
from hardware.types import JointState


def record_arm_tick(rec, prefix: str, t: float, *, leader: JointState | None = None,
                    follower: JointState | None = None, tau_ext=None, contact: bool = False,
                    leader_tau_cmd=None, gate: float | None = None, action_q=None,
                    action_gripper: float = float("nan"), action_hold: bool = False,
                    perturb_q=None) -> None:
    """Log what one pair did at t [s, rig clock] into a hardware.recording.Recorder (non-blocking).
    prefix: hardware.features.arm_prefix of the pair. action_q [rad] / action_gripper [m]: the follower
    target after the safety layer (NaN or None: nothing sent this tick; hold: the layer held); perturb_q
    [rad]: a perturbed collection's offset on that target (None: not a perturbed collection)."""
    items = []  # one record for the whole tick (one pack and one hand-over on the loop's thread)
    if leader is not None:
        items.append((S.JOINT_STATE, S.joint_state_topic(f"{prefix}leader"), t, *joint_state_fields(leader)))
    if follower is not None:
        items.append((S.JOINT_STATE, S.joint_state_topic(f"{prefix}follower"), t,
                      *joint_state_fields(follower)))
    if tau_ext is not None:
        items.append((S.EXTERNAL_TORQUE, S.tau_ext_topic(f"{prefix}follower"), t, (bool(contact),),
                      (tau_ext,)))
    if leader_tau_cmd is not None:
        items.append((S.TORQUE_COMMAND, S.tau_cmd_topic(f"{prefix}leader"), t,
                      (num(gate),), (leader_tau_cmd,)))
    if action_q is not None and (action_hold or np.all(np.isfinite(action_q))):
        items.append((S.FOLLOWER_COMMAND, S.command_topic(f"{prefix}follower"), t,
                      (float(action_gripper), bool(action_hold)), (action_q,)))
    if perturb_q is not None:
        items.append((S.PERTURBATION, S.perturb_topic(f"{prefix}follower"), t, (), (perturb_q,)))
    if items:
        rec.log_batch(items)
