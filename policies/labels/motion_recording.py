"""The recording side of `--contact-score motion` (policies.labels.motion_residual): the joint velocities at
the force samples' times."""

from __future__ import annotations

import numpy as np

from hardware.recording import schemas as S
from hardware.recording.reader import Episode, interp_linear
from policies.data.recordings import ArmSet


def episode_q_dot(ep: Episode, arms: ArmSet, t: np.ndarray) -> np.ndarray:
    """Joint velocities (N, sum of joints) [rad/s] of every follower at times t [s], in episode_tau_ext's
    joint order (the recorded joint states, interpolated)."""
    parts = []
    for arm in arms.followers:
        js = ep.topic(S.joint_state_topic(arm))
        parts.append(interp_linear(js.t, np.asarray(js.fields["q_dot"], float), t))
    return np.concatenate(parts, axis=1)
