"""Small synthetic teleop recordings for the policy tests: follower joint states, the follower command (the
action), estimated tau_ext with contact bursts, and camera frames, written with the real Recorder."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hardware.recording import Recorder
from hardware.types import STATUS_ENABLED, JointState

N_JOINTS = 6
NAMES = [f"joint{i + 1}" for i in range(N_JOINTS)]
RATE_HZ = 100.0  # joint states, tau_ext, command
CAMERA_HZ = 10.0


def _frame(k: int, cam: int, h: int = 32, w: int = 40) -> np.ndarray:
    """A bright square whose position encodes the time step (so images carry the state)."""
    img = np.full((h, w, 3), 40 + 60 * cam, np.uint8)
    x = (k // 3) % (w - 8)
    img[8:16, x : x + 8] = 250
    return img


def write_recording(
    path,
    *,
    episodes: int = 2,
    seconds: float = 4.0,
    cameras=("wrist", "top"),
    tau_ext: bool = True,
    contact_at=(1.5,),
    contact_s: float = 1.0,
    seed: int = 0,
    n_joints: int = N_JOINTS,
    joint_names=None,
    simulated: bool = True,
    metadata: dict | None = None,
    outcomes=None,
    objects: int = 0,
    task: str = "push",
) -> Path:
    """`episodes` episodes of `seconds` each; in each, tau_ext rises to 2 N*m per joint for `contact_s`
    at every time in `contact_at` (seconds into the episode) and is 0.01 N*m noise elsewhere.
    outcomes: one per episode ("success" default, "failure", None: stopped unlabelled, "incomplete": never
    stopped, as when the recorder is killed). objects: that many PRIVILEGED object values ("obj0", ...) per
    tick on /task/objects, as `factr2 collect` writes on a twin."""
    outcomes = list(outcomes or ["success"] * episodes)
    path = Path(path)
    names = list(joint_names or NAMES[:n_joints])
    rng = np.random.default_rng(seed)
    meta = {"simulated": "true" if simulated else "false", "task": "synthetic", **(metadata or {})}
    rec = Recorder(path, joint_names={"follower": names, "leader": names}, t0=0.0, metadata=meta)
    dt = 1.0 / RATE_HZ
    t = 0.0
    for e in range(episodes):
        t0 = t
        rec.start_episode(t, task=task)
        n = int(seconds * RATE_HZ)
        phase = rng.uniform(0, 2 * np.pi)
        for k in range(n):
            tk = t0 + k * dt
            q = 0.5 * np.sin(0.8 * k * dt + phase + np.arange(n_joints))
            s = JointState.empty(n_joints, t=tk)
            s.q[:] = q
            s.q_dot[:] = 0.4 * np.cos(0.8 * k * dt + phase + np.arange(n_joints))
            s.tau_m[:] = 0.1 * q
            s.current[:] = 0.05 * q
            s.q_cmd[:] = q
            s.temperature[:] = 30.0
            s.status[:] = STATUS_ENABLED
            s.gripper_pos = 0.02 + 0.01 * np.sin(k * dt)
            rec.log_joint_state("follower", tk, s)
            rec.log_joint_state("leader", tk, s)
            q_next = 0.5 * np.sin(0.8 * (k + 1) * dt + phase + np.arange(n_joints))
            rec.log_follower_command("follower", tk, q_next, gripper=0.02 + 0.01 * np.sin((k + 1) * dt))
            if tau_ext:
                in_contact = any(c <= k * dt < c + contact_s for c in contact_at)
                tau = np.full(n_joints, 2.0) if in_contact else rng.normal(0, 0.01, n_joints)
                rec.log_external_torque("follower", tk, tau, in_contact)
            if objects:
                names_o = [f"obj{i}" for i in range(objects)]
                rec.log_task_objects(tk, q[0] + np.arange(objects, dtype=float), names_o)
            if k % int(RATE_HZ / CAMERA_HZ) == 0:
                for ci, cam in enumerate(cameras):
                    rec.log_image(cam, tk, _frame(k, ci))
        t = t0 + n * dt
        if outcomes[e] != "incomplete":
            rec.stop_episode(t, outcomes[e])
        t += 0.5
    rec.close()
    return path


def train_tiny(demos: Path, run: Path, observation: str):
    """A 3-step training of a tiny policy on `demos` (the observation's plumbing, not learning): its
    (model, meta, preprocessing)."""
    from policies.training.checkpoint import load_policy
    from policies.training.run import RunOptions, run_training
    from policies.training.train import Dist, TrainConfig

    tiny = {"hidden": 32, "heads": 2, "dec_layers": 1, "enc_layers": 1, "ff": 64, "chunk": 8, "dropout": 0.0}
    opts = RunOptions(inputs=[demos], out=run, observation=observation, thresholds=(0.5, 1.0),
                      val_fraction=0.0, progress=False, overrides=tiny,
                      train=TrainConfig(steps=3, batch=8, warmup=1, val_every=3, ckpt_every=3, threads=1))
    run_training(opts, Dist())
    return load_policy(run)
