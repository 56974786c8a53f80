"""Episodes held as arrays -> one factr2 recording (MCAP), through the real Recorder (lossless: nothing is
late while converting, so a busy writer makes the converter wait instead of dropping).

Each episode becomes a recorded episode of a single follower: its joint states (q [rad], q_dot [rad/s],
tau_m [N*m], current [A], q_cmd [rad] = the commanded target, gripper [m]), the follower command (the
action: joint targets [rad] + gripper [m]), tau_ext [N*m] when the source has it, and camera frames
(JPEG-encoded by the recorder: a re-encoding of what the source stored). Signals the source lacks are NaN,
as a recording of a rig without them would hold.

The last row is held for half a row period (HOLD_TAIL): the policy grid's last tick, t0 + (n - 1) / rate,
can round a hair past the last row's time and be lost; the hold keeps it (no new tick is made from it).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hardware.errors import UserError
from hardware.recording import schemas as S
from hardware.types import STATUS_ENABLED, JointState

HOLD_TAIL = 0.5  # of a row period [1]: the last row's hold (module docstring)
EPISODE_GAP_S = 1.0  # idle time between episodes [s], as a recording has between stop and start


@dataclass
class ImportedEpisode:
    """One episode: t (N,) [s] from the episode's start, strictly increasing; per-row arrays (N, J) or (N,)
    in the units above; None where the source has no such signal. frames: camera -> (t (K,) [s] increasing,
    an iterable of K (H, W, 3) uint8 frames in that order: read as they are written, a video need not be held
    in memory)."""

    t: np.ndarray
    q: np.ndarray
    gripper: np.ndarray | None = None
    action_q: np.ndarray | None = None
    action_gripper: np.ndarray | None = None
    qd: np.ndarray | None = None
    tau_m: np.ndarray | None = None
    current: np.ndarray | None = None
    tau_ext: np.ndarray | None = None
    frames: dict = field(default_factory=dict)
    # a twin's exported object vectors by feature (hardware.recording.schemas.OBJECT_TOPICS: the PRIVILEGED
    # state, the SIMULATED detector's report): feature -> ((N, O) values, O element names)
    objects: dict = field(default_factory=dict)
    # FIRST labels (N,) of a factr2 export's phase column (not written here: the importer puts them in the
    # recording metadata, hardware.importers.lerobot.IMPORT_PHASES)
    phase: np.ndarray | None = None
    task: str = ""
    outcome: str | None = "success"


def _rows(a, n: int, j: int | None, what: str, where: str) -> np.ndarray | None:
    if a is None:
        return None
    a = np.asarray(a, float)
    want = (n,) if j is None else (n, j)
    if a.shape != want:
        raise UserError(f"{what} has shape {a.shape}, expected {want}", where=where,
                        fix="map a feature of the right size (docs/bringing_data.md)")
    return a


def write_episodes(path: Path, episodes: list[ImportedEpisode], joint_names: list[str],
                   metadata: dict[str, str]) -> Path:
    """Write `episodes` (one follower, `joint_names`) to a new recording at `path` (written beside it and
    renamed: never half a file)."""
    from hardware.recording import Recorder

    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{path.stem}.mcap")
    tmp.unlink(missing_ok=True)
    nj = len(joint_names)
    rec = Recorder(tmp, joint_names={"follower": list(joint_names)}, t0=0.0, lossless=True,
                   metadata=dict(metadata, simulated="false"))
    try:
        offset = 0.0
        for e, ep in enumerate(episodes):
            where = f"{path.name} episode {e}"
            t = np.asarray(ep.t, float)
            n = len(t)
            if n < 2 or not np.all(np.diff(t) > 0):
                raise UserError(f"episode {e}: {n} rows, times not increasing", where=where,
                                fix="check the source's timestamps")
            q = _rows(ep.q, n, nj, "joint positions", where)
            cols = {k: _rows(getattr(ep, k), n, nj, k, where) for k in ("action_q", "qd", "tau_m", "current",
                                                                          "tau_ext")}
            grip = _rows(ep.gripper, n, None, "gripper", where)
            agrip = _rows(ep.action_gripper, n, None, "action gripper", where)
            qd = cols["qd"] if cols["qd"] is not None else np.gradient(q, t, axis=0)
            frames = sorted((float(ft), cam, i) for cam, (fts, _) in ep.frames.items()
                            for i, ft in enumerate(np.asarray(fts, float)))
            sources = {cam: iter(seq) for cam, (_, seq) in ep.frames.items()}
            rec.start_episode(offset + t[0], task=ep.task)
            fi = 0
            for k in range(n):
                tk = offset + t[k]
                while fi < len(frames) and frames[fi][0] <= t[k] + 1e-9:
                    ft, cam, i = frames[fi]
                    rgb = next(sources[cam], None)
                    if rgb is None:
                        raise UserError(f"camera {cam}: {i} frames where its timestamps say more",
                                        where=where, fix="check the source's videos")
                    rec.log_image(cam, offset + ft, np.ascontiguousarray(rgb))
                    fi += 1
                _log_row(rec, tk, k, nj, q, qd, cols, grip, agrip)
                for feature, (vals, names) in ep.objects.items():
                    log = rec.log_task_objects if feature == S.TASK_OBJECTS_FEATURE else rec.log_perceived
                    log(tk, np.asarray(vals[k], float), names)
            dt = float(t[-1] - t[-2])
            t_hold = offset + t[-1] + HOLD_TAIL * dt
            _log_row(rec, t_hold, n - 1, nj, q, qd, cols, grip, agrip)
            rec.stop_episode(t_hold, ep.outcome)
            offset = float(np.ceil(t_hold + EPISODE_GAP_S))
    except BaseException:
        rec.close()
        tmp.unlink(missing_ok=True)
        raise
    st = rec.close()
    if st.error or st.dropped_samples or st.dropped_frames:
        tmp.unlink(missing_ok=True)
        raise UserError(f"converting to {path.name} lost data ({st.error or 'dropped records'})",
                        where=str(path), fix="free disk space and run the command again")
    tmp.rename(path)
    return path


def _log_row(rec, tk, k, nj, q, qd, cols, grip, agrip) -> None:
    s = JointState.empty(nj, t=tk)
    s.q[:] = q[k]
    s.q_dot[:] = qd[k]
    for src, dst in (("tau_m", s.tau_m), ("current", s.current), ("action_q", s.q_cmd)):
        if cols[src] is not None:
            dst[:] = cols[src][k]
    s.status[:] = STATUS_ENABLED
    if grip is not None:
        s.gripper_pos = float(grip[k])
    rec.log_joint_state("follower", tk, s)
    if cols["action_q"] is not None:
        rec.log_follower_command("follower", tk, cols["action_q"][k],
                                 gripper=float(agrip[k]) if agrip is not None else float("nan"))
    if cols["tau_ext"] is not None:
        rec.log_external_torque("follower", tk, cols["tau_ext"][k], False)
