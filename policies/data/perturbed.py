"""A perturbed collection's marks read back for training (`factr2 collect --perturb`,
factr2_teleop/teleop/perturb.py): the offset the pair added to the operator's follower target on each tick,
recorded on /<arm>follower/perturb before the safety layer.

`factr2 train --perturbed` chooses what training does with them:

- "dart" (default, as DART does): every tick's state is kept, and the action learned is the operator's own
  target, the recorded command minus the offset, so the policy learns the operator's correction from the
  states the perturbation led to;
- "skip": the states are kept as observations, and the perturbed ticks' actions (every step of an action chunk
  that falls on a tick with a non-zero offset) are masked out of the loss.

Recordings without the topic (every recording before it, and collections without --perturb) have no
perturbed tick: both modes leave them as they are.
"""

from __future__ import annotations

import numpy as np

from hardware.recording import schemas as S
from hardware.timeseries import interp_linear

PERTURBED_MODES = ("dart", "skip")
DEFAULT_PERTURBED = "dart"


def offset_on_grid(ep, arm: str, grid: np.ndarray, n_joints: int) -> np.ndarray:
    """The offset [rad] (len(grid), n_joints) on the follower `arm`'s target at the grid times [s]: linear
    between the recorded ticks, 0 where the episode has none."""
    topic = S.perturb_topic(arm)
    out = np.zeros((len(grid), n_joints))
    if topic not in ep.recording.topics:
        return out
    ta = ep.topic(topic)
    if len(ta.t) == 0:
        return out
    off = interp_linear(ta.t, np.asarray(ta.fields["offset"], float), np.asarray(grid, float))
    out[:, : off.shape[1]] = np.nan_to_num(off[:, :n_joints])
    return out


def perturbed_actions(action: np.ndarray, offset: np.ndarray, mode: str) -> tuple[np.ndarray, np.ndarray]:
    """(the actions to learn, perturbed per tick) for one arm's actions (T, J + 1: joints [rad], gripper)
    and offsets (T, J) [rad]: "dart" subtracts the offset from the joint targets, "skip" keeps them (the
    caller masks the perturbed ticks)."""
    if mode not in PERTURBED_MODES:
        raise ValueError(f"perturbed {mode!r}: one of {PERTURBED_MODES}")
    hit = np.any(offset != 0.0, axis=1)
    if mode == "skip" or not hit.any():
        return action, hit
    out = np.array(action, dtype=float, copy=True)
    out[:, : offset.shape[1]] -= offset
    return out, hit

