"""Export recorded episodes as a LeRobotDataset v3.0 folder, so LeRobot users can train on our recordings:

    meta/info.json            codebase_version "v3.0", fps, features, totals, path templates
    meta/stats.json           mean / std / min / max / count per feature (images: per channel, in [0, 1])
    meta/tasks.parquet        task strings (index) -> task_index
    meta/episodes/chunk-000/file-000.parquet   per episode: length, index range, data and video locations
    data/chunk-000/file-000.parquet            one row per frame (all episodes)
    videos/<camera key>/chunk-000/file-000.mp4 H.264, yuv420p, all episodes back to back

Frames are sampled at `fps` (default: the camera rate, rounded) from each episode's start; every row has
observation.state (follower joints [rad] + gripper [m]), observation.tau_ext [N*m] (recorded or NEXT offline),
action (the commanded joint targets + gripper), phase (FIRST: 0 free, 1 pre-contact, 2 contact), the images
(the latest frame of each camera at the row's time), and LeRobot's timestamp / frame_index / episode_index /
index / task_index. Written to a temporary folder and renamed: never half a dataset.
"""

from __future__ import annotations

import json
import shutil
import tempfile
from fractions import Fraction
from pathlib import Path

import numpy as np

from hardware.errors import UserError
from hardware.recording import schemas as S
from hardware.recording.reader import interp_linear
from policies.dataset import action_prefix, camera_rate
from policies.labelling import label_episode
from policies.phases import PHASE_NAMES
from policies.recordings import follower_state_action

CODEBASE_VERSION = "v3.0"
CHUNKS_SIZE = 1000
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
EPISODES_PATH = "meta/episodes/chunk-000/file-000.parquet"


def _episode_rows(ep, arms, cams, fps, th, next_model):
    js0 = ep.topic(S.joint_state_topic(arms.followers[0]))
    t0 = max([js0.t[0]] + [ep.recording.frames(c).t[0] for c in cams if len(ep.recording.frames(c))])
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
        "observation.tau_ext": np.nan_to_num(interp_linear(lab.t, lab.tau_ext, grid)),
        "phase": lab.at(grid).astype(np.int64),
    }
    frame_idx = {c: np.searchsorted(ep.recording.frames(c).t, grid + 1e-6, side="right") - 1 for c in cams}
    ok = np.isfinite(rows["observation.state"]).all(1) & np.isfinite(rows["action"]).all(1)
    ok &= np.all([frame_idx[c] >= 0 for c in cams], axis=0) if cams else True
    # LeRobot needs timestamps on the fps grid from 0: keep the longest valid run from the start
    first_bad = int(np.argmin(ok)) if not ok.all() else len(ok)
    keep = slice(0, first_bad)
    return {k: v[keep] for k, v in rows.items()}, {c: v[keep] for c, v in frame_idx.items()}


def _even(x: int) -> int:
    return x - (x % 2)


def _video_writer(path: Path, fps: int, width: int, height: int):
    import av

    path.parent.mkdir(parents=True, exist_ok=True)
    out = av.open(str(path), "w")
    st = out.add_stream("libx264", rate=Fraction(fps, 1))
    st.width, st.height, st.pix_fmt = width, height, "yuv420p"
    st.time_base = Fraction(1, fps)
    st.options = {"g": "2", "crf": "23"}  # short GOP: LeRobot seeks to single frames
    return out, st


def _stats(x: np.ndarray) -> dict:
    x = np.asarray(x, np.float64).reshape(len(x), -1)
    return {
        "mean": x.mean(0).tolist(),
        "std": x.std(0).tolist(),
        "min": x.min(0).tolist(),
        "max": x.max(0).tolist(),
        "count": [int(len(x))],
    }


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
    """Write the dataset to `out` (must not exist); returns info.json's dict."""
    import av
    import pandas as pd
    import pyarrow as pa
    import pyarrow.parquet as pq

    out = Path(out)
    if out.exists():
        raise UserError("output folder exists", where=str(out), fix="name a new --out folder")
    recs = list(dict.fromkeys(ep.recording for ep in episodes))
    cams = sorted(set.intersection(*(set(r.cameras) for r in recs)))
    if not cams:
        raise UserError(
            "the recordings have no camera frames", where=str(recs[0].path), fix="record with cameras"
        )
    fps = int(fps or round(camera_rate(episodes, cams)))
    tmp = Path(tempfile.mkdtemp(dir=out.parent if out.parent.exists() else None, prefix=f".{out.name}.tmp-"))
    try:
        sizes = {}
        for c in cams:
            h, w = recs[0].frames(c).rgb(0).shape[:2]
            sizes[c] = (_even(h), _even(w))
        writers = {
            c: _video_writer(
                tmp / VIDEO_PATH.format(video_key=f"observation.images.{c}", chunk_index=0, file_index=0),
                fps,
                sizes[c][1],
                sizes[c][0],
            )
            for c in cams
        }
        img_sum = {c: np.zeros((3, 3)) for c in cams}  # per channel: sum, sum of squares, count
        img_min = {c: np.full(3, np.inf) for c in cams}
        img_max = {c: np.full(3, -np.inf) for c in cams}
        tasks: dict[str, int] = {}
        columns: dict[str, list] = {}
        ep_rows = []
        index = 0
        for ep in episodes:
            rows, fidx = _episode_rows(ep, arms, cams, fps, th, next_model)
            n = len(rows["phase"])
            if n == 0:
                continue
            task = ep.task or ep.recording.session.get("task", "") or "factr2 teleop"
            t_idx = tasks.setdefault(task, len(tasks))
            t_from = index / fps  # each video holds every exported frame, episodes back to back
            for c in cams:
                frames, (h, w) = ep.recording.frames(c), sizes[c]
                last, img = -1, None
                for k in range(n):
                    if fidx[c][k] != last:
                        last = int(fidx[c][k])
                        img = frames.rgb(last)[:h, :w]
                        f = img.reshape(-1, 3).astype(np.float64) / 255.0
                        img_sum[c] += [f.sum(0), (f * f).sum(0), np.full(3, len(f))]
                        img_min[c] = np.minimum(img_min[c], f.min(0))
                        img_max[c] = np.maximum(img_max[c], f.max(0))
                    vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="rgb24")
                    vf.pts = index + k
                    for pkt in writers[c][1].encode(vf):
                        writers[c][0].mux(pkt)
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
            for c in cams:
                key = f"observation.images.{c}"
                rec.update(
                    {
                        f"videos/{key}/chunk_index": 0,
                        f"videos/{key}/file_index": 0,
                        f"videos/{key}/from_timestamp": t_from,
                        f"videos/{key}/to_timestamp": t_from + n / fps,
                    }
                )
            ep_rows.append(rec)
            index += n
        if not ep_rows:
            raise UserError(
                "no frames to export (no episode has joint states, commands and frames together)",
                where=str(recs[0].path),
                fix="check the recordings with `factr2 episodes show`",
            )
        for c in cams:
            out_c, st = writers[c]
            for pkt in st.encode():
                out_c.mux(pkt)
            out_c.close()
        cat = {k: np.concatenate(v) for k, v in columns.items()}
        arrays, features = {}, {}
        names = {
            "observation.state": [
                n
                for a, j in zip(arms.followers, arms.joint_names)
                for n in [f"{a}.{x}" for x in j] + [f"{a}.gripper"]
            ],
            "action": [
                n
                for a, j in zip(arms.followers, arms.joint_names)
                for n in [f"{action_prefix(a)}.{x}" for x in j] + [f"{action_prefix(a)}.gripper"]
            ],
            "observation.tau_ext": [f"{a}.{x}" for a, j in zip(arms.followers, arms.joint_names) for x in j],
        }
        for k in ("observation.state", "observation.tau_ext", "action"):
            v = cat[k].astype(np.float32)
            arrays[k] = pa.FixedSizeListArray.from_arrays(pa.array(v.reshape(-1)), v.shape[1])
            features[k] = {"dtype": "float32", "shape": [v.shape[1]], "names": names[k]}
        features["phase"] = {
            "dtype": "int64",
            "shape": [1],
            "names": None,
            "description": ", ".join(f"{i}: {p}" for i, p in enumerate(PHASE_NAMES)),
        }
        for c in cams:
            h, w = sizes[c]
            features[f"observation.images.{c}"] = {
                "dtype": "video",
                "shape": [h, w, 3],
                "names": ["height", "width", "channels"],
                "info": {
                    "video.height": h,
                    "video.width": w,
                    "video.codec": "h264",
                    "video.pix_fmt": "yuv420p",
                    "video.is_depth_map": False,
                    "video.fps": fps,
                    "video.channels": 3,
                    "has_audio": False,
                },
            }
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
        stats = {
            k: _stats(cat[k])
            for k in (
                "observation.state",
                "observation.tau_ext",
                "action",
                "phase",
                "timestamp",
                "frame_index",
                "episode_index",
                "index",
                "task_index",
            )
        }
        for c in cams:
            s, ss, cnt = img_sum[c]
            mean = s / cnt
            std = np.sqrt(np.maximum(ss / cnt - mean**2, 0))
            col = lambda v: [[[float(x)]] for x in v]  # noqa: E731  (LeRobot's (3, 1, 1) per channel)
            stats[f"observation.images.{c}"] = {
                "mean": col(mean),
                "std": col(std),
                "min": col(img_min[c]),
                "max": col(img_max[c]),
                "count": [int(cnt[0])],
            }
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
            "video_path": VIDEO_PATH,
            "features": features,
        }
        (tmp / "meta" / "info.json").write_text(json.dumps(info, indent=4))
        (tmp / "meta" / "stats.json").write_text(json.dumps(stats, indent=4))
        tmp.rename(out)
        return info
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
