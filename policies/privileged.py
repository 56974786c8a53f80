"""The PRIVILEGED state observation (twins only, SIMULATED): a twin task's object state as one flat float
vector, a policy input in place of (or beside) camera frames (`factr2 train --obs state`).

Order (fixed per task, recorded with the data as the /task/objects channel's `names`): every entry of
`task.observe(model, data, params)` in its dict order, then every entry of the episode's `params` that
observe() does not already hold, in their dict order; each entry flattened row-major, booleans as 0 / 1.
For the built-in tasks (positions [m], rotation-matrix entries [1], yaws [rad], contacts 0/1, force [N]):

    peg-insert (25)  peg_pos 3, peg_rot 9, hole_pos 3, hole_yaw 1, finger_touch 2, peg_to_hole 4, peg_start 3
    press-fit  (25)  block_pos 3, block_rot 9, base_pos 3, base_yaw 1, finger_touch 2, block_to_base 4,
                     block_start 3
    wipe        (8)  tip_pos 3, force_n 1, area_pos 3, area_yaw 1

Why the params too: wipe's observe() reads only the fingertip and the pressing force, so without the mark's
pose (a parameter) a policy could not know where to wipe. Real hardware has no such vector: a policy trained
on it runs on twins only, and its results are labelled so.

    vec = task_state_vector(task, model, data, params)        # live, at rollout: float32 (D,)
    batch["objects"] = torch.from_numpy(normaliser.norm("objects", vec[None]))   # the policy's (1, D) input
"""

from __future__ import annotations

import numpy as np

OBSERVATIONS = ("images", "state", "images+state")  # PolicyConfig.observation / `factr2 train --obs`


def uses_images(observation: str) -> bool:
    return "images" in observation.split("+")


def uses_objects(observation: str) -> bool:
    return "state" in observation.split("+")


def _entries(obs: dict, params: dict) -> list[tuple[str, np.ndarray]]:
    out = [(k, np.asarray(v, dtype=float).ravel()) for k, v in obs.items()]
    out += [(k, np.asarray(v, dtype=float).ravel()) for k, v in params.items() if k not in obs]
    return out


def objects_vector(obs: dict, params: dict) -> tuple[np.ndarray, list[str]]:
    """(vector float32 (D,), element names ("peg_pos.0", ...)) from observe()'s dict and the episode's
    params (pure)."""
    entries = _entries(obs, params)
    names = [f"{k}.{i}" for k, v in entries for i in range(v.size)]
    vec = np.concatenate([v for _, v in entries]) if entries else np.zeros(0)
    return vec.astype(np.float32), names


def task_state_vector(task, model, data, params: dict) -> np.ndarray:
    """The privileged vector of a live twin task now (float32 (D,)), in the order the recordings hold
    (objects_vector). Call it on the thread that steps the physics, or under the world's lock."""
    return objects_vector(task.observe(model, data, params), params)[0]
