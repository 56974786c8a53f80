"""Export recorded episodes as a LeRobotDataset v3.0 folder, so LeRobot users can train on our recordings:

    meta/info.json            codebase_version "v3.0", fps, features, totals, path templates
    meta/stats.json           mean / std / min / max / count per feature (images: per channel, in [0, 1])
    meta/tasks.parquet        task strings (index) -> task_index
    meta/episodes/chunk-000/file-000.parquet   per episode: length, index range, data and video locations
    data/chunk-000/file-000.parquet            one row per frame (all episodes)
    videos/<camera key>/chunk-000/file-000.mp4 H.264, yuv420p, all episodes back to back

Rows are sampled at `fps` from each episode's start. Default fps: the first camera's nominal rate from the
rig file, checked against the frame timestamps (a warning when they differ by more than 10 %); without
cameras (`factr2 collect --no-cameras`) the policies' state-only rate, 30 Hz. Every row has
observation.state (follower joints [rad] + gripper [m]), observation.force = tau_ext [N*m] (recorded or NEXT
offline), action (the commanded joint targets + gripper), phase (FIRST: 0 free, 1 pre-contact, 2 contact),
the images (the latest frame of each camera at the row's time; none in a state-only dataset), on twin task
recordings observation.state.objects (PRIVILEGED, SIMULATED: the task objects' state, labelled so in
info.json) and observation.perceived.objects (SIMULATED: the simulated pose detector's report, as recorded
live), and LeRobot's timestamp / frame_index / episode_index / index / task_index. Written to a
temporary folder and renamed: never half a dataset.
"""

from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path

import numpy as np

from hardware.errors import UserError
from hardware.features import FACTR2_PHASES, OBS_FORCE, PHASE_FEATURE, action_of
from hardware.recording import schemas as S
from hardware.recording.reader import interp_linear
from hardware.timeseries import hold_previous
from policies.data.dataset import STATE_RATE_HZ, camera_rate, latest_frame, valid_samples
from policies.data.recordings import follower_state_action
from policies.export.export_video import VIDEO_PATH, CameraVideo
from policies.labels.labelling import label_episode
from policies.labels.phases import PHASE_NAMES

CODEBASE_VERSION = "v3.0"
CHUNKS_SIZE = 1000
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
EPISODES_PATH = "meta/episodes/chunk-000/file-000.parquet"


def _rig_camera_fps(rec, cam: str) -> float | None:
    """The camera's nominal rate [Hz] from the rig file the recording's metadata holds (None: not said)."""
    text = rec.info.get("rig_toml", "")
    if not text:
        return None
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib
    try:
        for c in tomllib.loads(text).get("cameras", []):
            if str(c.get("name", "")) == cam:
                return float(c.get("fps", 30.0))  # the rig loader's default (hardware/rigs/rig.py)
    except (ValueError, AttributeError, TypeError):
        pass
    return None


def nominal_fps(episodes, cams: list[str]) -> tuple[int, str]:
    """The dataset's fps and a one-line warning ("" when none). With cameras: the first camera's nominal rate
    from the rig file, checked against its frame timestamps (a median interval taken as the rate gave 29 fps
    for a 30 Hz camera whose frames were sometimes late); without a rig rate, the measured one rounded.
    Without cameras: the policies' state-only rate."""
    if not cams:
        return int(STATE_RATE_HZ), ""
    measured = camera_rate(episodes, cams)
    nominal = _rig_camera_fps(episodes[0].recording, cams[0])
    if nominal is None:
        return max(1, int(round(measured))), ""
    warn = ""
    if abs(measured - nominal) > 0.1 * nominal:
        warn = (f"camera {cams[0]}: the rig file says {nominal:g} fps but its frames came at "
                f"{measured:.3g} fps (median interval); exporting at {nominal:g} fps, each row holding the "
                "latest frame -- pass --fps to choose another rate")
    return max(1, int(round(nominal))), warn


def _episode_rows(ep, arms, cams, fps, th, next_model, objects):
    """objects: the object features to export (PRIVILEGED state, perceived; feature -> names)."""
    js0 = ep.topic(S.joint_state_topic(arms.followers[0]))
    starts = [js0.t[0]] + [ep.recording.frames(c).t[0] for c in cams if len(ep.recording.frames(c))]
    obs = {f: ep.topic(S.OBJECT_TOPICS[f]) for f in objects or ()}
    t0 = max(starts)  # the training grid's (data/dataset.py): a dataset read back trains on the same ticks
    n = int(np.floor((js0.t[-1] - t0) * fps + 1e-9)) + 1
    grid = t0 + np.arange(max(n, 0)) / fps
    state, action = [], []
    for arm in arms.followers:
        st, act = follower_state_action(ep, arm, grid, "export")
        state.append(st)
        action.append(act)
    lab = label_episode(ep, arms, th, next_model)
    rows = {
        "observation.state": np.concatenate(state, 1),
        "action": np.concatenate(action, 1),
        OBS_FORCE: np.nan_to_num(interp_linear(lab.t, lab.tau_ext, grid)),
        PHASE_FEATURE: lab.at(grid).astype(np.int64),
    }
    for f, ob in obs.items():  # the latest vector at or before each row, as a live policy has it
        rows[f] = hold_previous(ob.t, ob.fields["objects"], grid)
    frame_idx = {c: latest_frame(ep.recording.frames(c).t, grid) for c in cams}
    held = np.concatenate([rows[f] for f in obs], axis=1) if obs else None
    ok = valid_samples(rows["observation.state"], rows["action"], held,
                       np.stack([frame_idx[c] for c in cams], axis=1) if cams else None)
    # LeRobot needs timestamps on the fps grid from 0: keep the longest valid run from the first valid row
    # (rows before the first object vector have none: LeRobot rows have no missing values)
    first = int(np.argmax(ok)) if ok.any() else len(ok)
    rest = ok[first:]
    keep = slice(first, first + (int(np.argmin(rest)) if not rest.all() else len(rest)))
    return {k: v[keep] for k, v in rows.items()}, {c: v[keep] for c, v in frame_idx.items()}


def _stats(x: np.ndarray) -> dict:
    x = np.asarray(x, np.float64).reshape(len(x), -1)
    return {
        "mean": x.mean(0).tolist(),
        "std": x.std(0).tolist(),
        "min": x.min(0).tolist(),
        "max": x.max(0).tolist(),
        "count": [int(len(x))],
    }


def _names(arms, objects: dict) -> dict:
    """info.json element names per vector feature."""
    out = {
        "observation.state": [n for a, j in zip(arms.followers, arms.joint_names)
                              for n in [f"{a}.{x}" for x in j] + [f"{a}.gripper"]],
        "action": [n for a, j in zip(arms.followers, arms.joint_names)
                   for n in [f"{action_of(a)}.{x}" for x in j] + [f"{action_of(a)}.gripper"]],
        OBS_FORCE: [f"{a}.{x}" for a, j in zip(arms.followers, arms.joint_names) for x in j],
    }
    out.update({f: list(n) for f, n in (objects or {}).items()})
    return out


def _object_names(recs) -> dict[str, list[str]]:
    """The object vectors to export, feature -> element names: the PRIVILEGED state and the perceived one
    (SIMULATED), each when every recording has the same one."""
    out = {}
    for feature, topic in S.OBJECT_TOPICS.items():
        names = [tuple(r.task_object_names(topic)) if topic in r.topics else () for r in recs]
        if names[0] and len(set(names)) == 1:
            out[feature] = list(names[0])
    return out


def export_lerobot(
    episodes,
    arms,
    out: Path,
    th,
    next_model=None,
    fps: int | None = None,
    robot_type: str = "",
    progress=None,
) -> dict:
    """Write the dataset to `out` (must not exist); returns info.json's dict, with "factr2/warnings" (lines
    for the user, not written to info.json). Recordings without cameras give a state-only dataset."""
    import pandas as pd
    import pyarrow as pa
    import pyarrow.parquet as pq

    out = Path(out)
    if out.exists():
        raise UserError("output folder exists", where=str(out), fix="name a new --out folder")
    recs = list(dict.fromkeys(ep.recording for ep in episodes))
    cams = sorted(set.intersection(*(set(r.cameras) for r in recs)))
    objects = _object_names(recs)
    warns = []
    if fps is None:
        fps, warn = nominal_fps(episodes, cams)
        warns += [warn] if warn else []
    tmp = Path(tempfile.mkdtemp(dir=out.parent if out.parent.exists() else None, prefix=f".{out.name}.tmp-"))
    try:
        videos = [CameraVideo(tmp, c, recs[0].frames(c).rgb(0), fps) for c in cams]
        tasks: dict[str, int] = {}
        columns: dict[str, list] = {}
        ep_rows = []
        index = 0
        for ep in episodes:
            rows, fidx = _episode_rows(ep, arms, cams, fps, th, next_model, objects)
            n = len(rows["phase"])
            if n == 0:
                continue
            task = ep.task or ep.recording.info.get("task", "") or "factr2 teleop"
            t_idx = tasks.setdefault(task, len(tasks))
            for v in videos:  # each video holds every exported frame, episodes back to back
                v.add(ep.recording.frames(v.cam), fidx[v.cam], index)
            if progress:
                progress(n)
            row_cols = dict(
                rows,
                timestamp=np.arange(n, dtype=np.float32) / fps,
                frame_index=np.arange(n),
                episode_index=np.full(n, len(ep_rows)),
                index=index + np.arange(n),
                task_index=np.full(n, t_idx),
            )
            for k, v in row_cols.items():
                columns.setdefault(k, []).append(v)
            rec = {
                "episode_index": len(ep_rows),
                "tasks": [task],
                "length": n,
                "data/chunk_index": 0,
                "data/file_index": 0,
                "dataset_from_index": index,
                "dataset_to_index": index + n,
                "meta/episodes/chunk_index": 0,
                "meta/episodes/file_index": 0,
                "factr2/source": f"{ep.recording.path.name}#{ep.index}",
            }
            for v in videos:
                rec.update(v.episode_columns(index / fps, n))
            ep_rows.append(rec)
            index += n
        if not ep_rows:
            what = "joint states, commands and frames" if cams else "joint states and commands"
            raise UserError(
                f"nothing to export (no episode has {what} together)",
                where=str(recs[0].path),
                fix="check the recordings with `factr2 episodes show`",
            )
        for v in videos:
            v.close()
        cat = {k: np.concatenate(v) for k, v in columns.items()}
        arrays, features = {}, {}
        names = _names(arms, objects)
        for k in names:
            v = cat[k].astype(np.float32)
            arrays[k] = pa.FixedSizeListArray.from_arrays(pa.array(v.reshape(-1)), v.shape[1])
            features[k] = {"dtype": "float32", "shape": [v.shape[1]], "names": names[k]}
        if S.TASK_OBJECTS_FEATURE in objects:
            features[S.TASK_OBJECTS_FEATURE]["description"] = (
                "PRIVILEGED, SIMULATED: the twin task objects' state (policies/data/privileged.py); a real "
                "robot has no such input")
        if S.PERCEIVED_FEATURE in objects:
            features[S.PERCEIVED_FEATURE]["description"] = (
                "SIMULATED: the twin task objects as a simulated camera pose detector reports them "
                "(hardware/sim/perception.py, docs/perception.md): per object position [m], rotation's first "
                "two columns, visible 0/1, age [s]; a real robot's camera pose estimator gives the like")
        features[PHASE_FEATURE] = {
            "dtype": "int64",
            "shape": [1],
            "names": None,
            "description": ", ".join(f"{i}: {p}" for i, p in enumerate(PHASE_NAMES)),
            FACTR2_PHASES: th.to_dict(),  # factr2's own labels: an import trains on them (importers.lerobot)
        }
        for v in videos:
            features[v.key] = v.feature()
        arrays["phase"] = pa.array(cat["phase"].astype(np.int64))
        arrays["timestamp"] = pa.array(cat["timestamp"].astype(np.float32))
        for k in ("frame_index", "episode_index", "index", "task_index"):
            arrays[k] = pa.array(cat[k].astype(np.int64))
        for k, dt in (
            ("timestamp", "float32"),
            ("frame_index", "int64"),
            ("episode_index", "int64"),
            ("index", "int64"),
            ("task_index", "int64"),
        ):
            features[k] = {"dtype": dt, "shape": [1], "names": None}
        data_path = tmp / DATA_PATH.format(chunk_index=0, file_index=0)
        data_path.parent.mkdir(parents=True)
        pq.write_table(pa.table(arrays), data_path)
        (tmp / EPISODES_PATH).parent.mkdir(parents=True)
        pd.DataFrame(ep_rows).to_parquet(tmp / EPISODES_PATH, index=False)
        pd.DataFrame(
            {"task_index": list(tasks.values())}, index=pd.Index(list(tasks), name="task")
        ).to_parquet(tmp / "meta" / "tasks.parquet")
        stats = {k: _stats(cat[k]) for k in [*names, "phase", "timestamp", "frame_index", "episode_index",
                                             "index", "task_index"]}
        for v in videos:
            stats[v.key] = v.stats()
        info = {
            "codebase_version": CODEBASE_VERSION,
            "robot_type": robot_type or "factr2",
            "total_episodes": len(ep_rows),
            "total_frames": int(index),
            "total_tasks": len(tasks),
            "chunks_size": CHUNKS_SIZE,
            "data_files_size_in_mb": 100,
            "video_files_size_in_mb": 500,
            "fps": fps,
            "splits": {"train": f"0:{len(ep_rows)}"},
            "data_path": DATA_PATH,
            "video_path": VIDEO_PATH if videos else None,
            "features": features,
        }
        (tmp / "meta" / "info.json").write_text(json.dumps(info, indent=4))
        (tmp / "meta" / "stats.json").write_text(json.dumps(stats, indent=4))
        tmp.rename(out)
        return dict(info, **{"factr2/warnings": warns})
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
