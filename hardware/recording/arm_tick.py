"""One arm pair's tick into a recording, for every producer (teleop, demo, task collection, policy rollout):
the same topics and fields whoever records (hardware.features names them)."""

from __future__ import annotations

import numpy as np

from hardware.types import JointState


def record_arm_tick(rec, prefix: str, t: float, *, leader: JointState | None = None,
                    follower: JointState | None = None, tau_ext=None, contact: bool = False,
                    leader_tau_cmd=None, gate: float | None = None, action_q=None,
                    action_gripper: float = float("nan"), action_hold: bool = False) -> None:
    """Log what one pair did at t [s, rig clock] into a hardware.recording.Recorder (non-blocking).
    prefix: hardware.features.arm_prefix of the pair. action_q [rad] / action_gripper [m]: the follower
    target after the safety layer (NaN or None: nothing sent this tick; hold: the layer held)."""
    if leader is not None:
        rec.log_joint_state(f"{prefix}leader", t, leader)
    if follower is not None:
        rec.log_joint_state(f"{prefix}follower", t, follower)
    if tau_ext is not None:
        rec.log_external_torque(f"{prefix}follower", t, tau_ext, contact)
    if leader_tau_cmd is not None:
        rec.log_torque_command(f"{prefix}leader", t, leader_tau_cmd, gate)
    if action_q is not None and (action_hold or np.all(np.isfinite(action_q))):
        rec.log_follower_command(f"{prefix}follower", t, action_q, action_gripper, action_hold)
