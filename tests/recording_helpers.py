"""Helpers shared by the recording tests: a deterministic synthetic session."""

from __future__ import annotations

import numpy as np

from hardware.recording import Recorder
from hardware.types import STATUS_ENABLED, JointState

N_JOINTS = 6
NAMES = [f"joint{i + 1}" for i in range(N_JOINTS)]


def joint_state(k: int, dt: float = 1e-3, phase: float = 0.0) -> JointState:
    t = k * dt
    s = JointState.empty(N_JOINTS, t=t)
    s.q[:] = np.sin(t + phase + np.arange(N_JOINTS))
    s.q_dot[:] = np.cos(t + phase + np.arange(N_JOINTS))
    s.tau_m[:] = 0.1 * np.arange(N_JOINTS) + t
    s.current[:] = 0.05 * k
    s.q_cmd[:] = s.q + 0.01 if k % 2 else np.nan  # NaN must survive (written as null)
    s.temperature[:] = 30.0 + 0.001 * k
    s.status[:] = STATUS_ENABLED
    s.gripper_pos = 0.01 * k
    return s


def flushed_recorder(path, n: int = 200) -> Recorder:
    """A recorder holding n joint samples that its writer has written and flushed to the file (the state a
    test then stops or kills the writer in)."""
    import time

    from machine_speed import budget

    rec = Recorder(path, t0=0.0, flush_interval_s=0.02)
    for k in range(n):
        assert rec.log_joint_state("follower", k * 1e-3, joint_state(k))
    deadline = time.monotonic() + budget(10.0)
    while rec.status().messages_written < n and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(0.2)  # ten flush intervals: the chunk holding them reached the file
    return rec


def stalled_two_episodes(path, copy_to=None):
    """A two-episode file whose writer stalls after episode 1's start and its progress mark (0.5, "reach")
    reached the file and before its stop did (both judged success live): the file is recovered in place, its
    episode 1 "incomplete". copy_to: where to copy the file as it stands while the writer is stopped (a
    truncated file, as a killed session leaves it). Returns the RecorderStatus."""
    import os
    import shutil
    import signal
    import time

    from machine_speed import budget

    rec = Recorder(path, t0=0.0, flush_interval_s=0.02)
    for e in range(2):
        rec.start_episode(e * 0.5)
        if e == 1:
            rec.mark_progress(0.55, 0.5, "reach")
        assert all(rec.log_joint_state("follower", e * 0.5 + k * 1e-3, joint_state(k)) for k in range(100))
        if e == 0:
            rec.stop_episode(0.2, "success")
    deadline = time.monotonic() + budget(10.0)
    while rec.status().messages_written < 200 and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(0.2)  # ten flush intervals: the chunk holding them reached the file
    os.kill(rec._proc.pid, signal.SIGSTOP)
    if copy_to is not None:
        shutil.copyfile(path, copy_to)
    rec.stop_episode(0.7, "success")  # handed over, never written
    st = rec.close(0.5)
    assert st.recovered and "recovered" in st.error
    return st


def gradient_frame(h: int = 48, w: int = 64, shift: int = 0) -> np.ndarray:
    y, x = np.mgrid[0:h, 0:w]
    return np.stack([(x * 4 + shift) % 256, y * 5 % 256, np.full_like(x, 128)], axis=-1).astype(np.uint8)


def record_session(path, n: int = 2000, dt: float = 1e-3, episodes: int = 1, cameras: bool = True,
                   contact: bool = True, **kw) -> Recorder:
    """n ticks per episode: leader/follower state, tau_ext, tau_cmd, ground truth (in contact the first 25
    of every 100 ticks, or never with contact=False), timing, frames, events."""
    rec = Recorder(path, joint_names={"leader": NAMES, "follower": NAMES}, t0=0.0, **kw)
    k = 0
    for e in range(episodes):
        rec.start_episode(k * dt, task=f"task{e}")
        for _ in range(n):
            t = k * dt
            rec.log_joint_state("leader", t, joint_state(k, dt, 0.5))
            rec.log_joint_state("follower", t, joint_state(k, dt))
            rec.log_external_torque("follower", t, np.full(N_JOINTS, 0.2 * (k % 10)), k % 100 < 30)
            rec.log_torque_command("leader", t, -0.01 * np.arange(N_JOINTS), gate=0.5)
            rec.log_ground_truth("follower", t, np.full(N_JOINTS, 0.1), contact and k % 100 < 25,
                                 [1.0, 2.0, 3.0])
            rec.log_loop_timing(t, dt, 2e-4, 0.0, 0)
            if cameras and k % 33 == 0:
                rec.log_image("wrist", t, gradient_frame(shift=k % 256))
            if k % 500 == 250:
                rec.mark_progress(t, 0.5, "halfway")
            k += 1
        rec.note(k * dt, "looked fine")
        rec.stop_episode(k * dt, "success" if e % 2 == 0 else "failure")
        k += 100  # idle time between episodes is recorded too
    return rec
