"""A local LeRobotDataset v3 folder -> factr2 recordings, so `factr2 train`, `factr2 episodes` and `factr2
export` read it as they read a folder of recordings.

Layout read (LeRobot's v3.0): meta/info.json (fps, features with dtype / shape / names, data_path and
video_path templates), meta/episodes/*/*.parquet (per episode: length, tasks, data rows, and per video key its
file and from_timestamp), data/*/*.parquet (one row per frame: the features, timestamp, episode_index,
frame_index), videos/<key>/*/*.mp4 (frames of all episodes back to back, decoded with PyAV), image features
stored in the rows (PNG / JPEG bytes).

Features are mapped to the recording by name (MAP_DEFAULT, overridable: `--lerobot-map ROLE=KEY,...`, a KEY
of `none` drops the role):

    state     observation.state      follower joints [rad] (+ the gripper: the element named *gripper*)
    action    action                 the commanded joint targets [rad] (+ gripper), /follower/command
    velocity  observation.velocity   q_dot [rad/s] (absent: differentiated from the state)
    effort    observation.effort     tau_m [N*m]
    current   observation.current    current [A]
    tau_ext   observation.tau_ext, observation.force    external joint torque [N*m] (factr2's own export)
    images    observation.images.*   camera frames (video or image features)
    objects   observation.state.objects, observation.perceived.objects   a twin export's PRIVILEGED object
              state and SIMULATED detector report (factr2's export of twin tasks), back on their topics

plus `angles=deg` when the dataset's joint angles are in degrees (LeRobot's SO-100/101 default), and
`gripper=none` when no state element is a gripper. A force-like feature must have one value per joint (a
6-axis wrist force is not a joint torque: left out with a note).

FIRST labels need tau_ext: a dataset without tau_ext gets its raw effort (else raw current) as the recorded
tau_ext, said in one line (the paper's raw-signal comparison); `--next CKPT` runs NEXT on the joint states
instead. A dataset with none of them has no tau_ext topic: base methods only (policies.training.run refuses
first).

A dataset written by `factr2 export lerobot` carries FIRST's labels (its `phase` feature, marked
hardware.features.FACTR2_PHASES): they go into the recording metadata (IMPORT_PHASES: per
episode the rows where the label changes, and the fps), and policies.labels.labelling trains on them instead
of labelling the 30 Hz force again. Other datasets' `phase` columns are not read.

Converted recordings are cached under cache_home()/lerobot/<key>, the key a hash of the dataset's meta and
data files (size, mtime) and the mapping: a changed dataset or mapping converts again.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import sys
from pathlib import Path

import numpy as np

from hardware.errors import UserError
from hardware.features import FACTR2_PHASES, PHASE_FEATURE
from hardware.importers.write import ImportedEpisode, write_episodes
from hardware.recording.schemas import OBJECT_TOPICS

ROLES = ("state", "action", "velocity", "effort", "current", "tau_ext")
MAP_DEFAULT: dict[str, tuple[str, ...]] = {
    "state": ("observation.state",),
    "action": ("action",),
    "velocity": ("observation.velocity",),
    "effort": ("observation.effort",),
    "current": ("observation.current",),
    "tau_ext": ("observation.tau_ext", "observation.force"),
}
IMAGES = "observation.images."
IMPORT_PHASES = "import_phases"  # recording metadata: a factr2 export's labels (phase_changes, per episode)
CONVERTER_VERSION = 4  # bump when the conversion changes: cached conversions are made again
FIX_MAP = "name the features with --lerobot-map ROLE=KEY,... (docs/bringing_data.md)"


def is_lerobot_dataset(path: Path) -> bool:
    return Path(path).is_dir() and (Path(path) / "meta" / "info.json").is_file()


def parse_map(text: str | None) -> dict[str, str]:
    """'state=observation.state,effort=none,angles=deg' -> dict; a bad entry is one UserError."""
    out: dict[str, str] = {}
    for part in filter(None, (p.strip() for p in (text or "").split(","))):
        role, eq, key = part.partition("=")
        role, key = role.strip(), key.strip()
        ok = eq and key and (role in ROLES or (role == "angles" and key in ("rad", "deg"))
                             or (role == "gripper" and key == "none"))
        if not ok:
            raise UserError(f"--lerobot-map: bad entry {part!r}",
                            fix=f"ROLE=KEY with ROLE one of {', '.join(ROLES)} (KEY `none` drops it), "
                            "angles=rad|deg, gripper=none")
        out[role] = key
    return out


def _bad(root: Path, what: str, fix: str = "pass a LeRobotDataset v3.0 folder (meta/info.json, data/)"):
    return UserError(f"not a readable LeRobotDataset: {what}", where=str(root), fix=fix)


def read_info(root: Path) -> dict:
    try:
        info = json.loads((root / "meta" / "info.json").read_text())
        feats = info["features"]
        fps = float(info["fps"])
        if not isinstance(feats, dict) or not fps > 0:
            raise ValueError("features / fps")
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise _bad(root, f"meta/info.json ({type(e).__name__}: {str(e)[:60]})") from None
    version = str(info.get("codebase_version", ""))
    if not version.startswith("v3"):
        raise _bad(root, f"codebase_version {version or '?'} (this reader knows v3.x)",
                   "convert it with LeRobot's v2.1 -> v3.0 script first")
    return info


def _names(feat: dict) -> list[str] | None:
    names = feat.get("names")
    if isinstance(names, dict):  # {"motors": [...]} in older writers
        names = next(iter(names.values()), None)
    return [str(n) for n in names] if isinstance(names, list) else None


def _width(feat: dict) -> int:
    shape = feat.get("shape") or [1]
    return int(np.prod(shape))


class Mapping:
    """The resolved mapping of one dataset: which key fills each role, the gripper column, the joint
    names, and notes for the user."""

    def __init__(self, info: dict, given: dict[str, str], root: Path):
        feats = info["features"]
        self.keys: dict[str, str] = {}
        self.notes: list[str] = []
        for role in ROLES:
            key = given.get(role)
            if key == "none":
                continue
            cands = (key,) if key else MAP_DEFAULT[role]
            if key and key not in feats:
                raise UserError(f"--lerobot-map {role}={key}: the dataset has no such feature",
                                where=str(root), fix=f"one of {', '.join(sorted(feats))}")
            found = next((k for k in cands if k in feats), None)
            if found:
                self.keys[role] = found
        for role in ("state", "action"):
            if role not in self.keys:
                raise UserError(f"the dataset has no {role} feature ({'/'.join(MAP_DEFAULT[role])})",
                                where=str(root), fix=FIX_MAP)
        st = feats[self.keys["state"]]
        n = _width(st)
        names = _names(st) or [f"joint{i + 1}" for i in range(n)]
        if len(names) != n:
            names = [f"joint{i + 1}" for i in range(n)]
        grip = [i for i, nm in enumerate(names) if "gripper" in nm.lower()]
        self.gripper = None if given.get("gripper") == "none" or not grip else grip[-1]
        self.joints = [i for i in range(n) if i != self.gripper]
        self.joint_names = [_short(names[i]) for i in self.joints]
        self.deg = given.get("angles") == "deg"
        if _width(feats[self.keys["action"]]) != n:
            raise UserError(f"action has {_width(feats[self.keys['action']])} values, state {n}",
                            where=str(root), fix=FIX_MAP)
        for role in ("velocity", "effort", "current", "tau_ext"):
            k = self.keys.get(role)
            if k and _width(feats[k]) not in (n, len(self.joints)):
                self.notes.append(f"{k} has {_width(feats[k])} values for {len(self.joints)} joints: not "
                                  f"used as {role}")
                del self.keys[role]
        self.cameras = sorted(k for k, f in feats.items()
                              if k.startswith(IMAGES) and f.get("dtype") in ("video", "image"))
        self.objects = {k: _names(feats[k]) or [f"v{i}" for i in range(_width(feats[k]))]
                        for k in OBJECT_TOPICS if k in feats}
        self.force = next((r for r in ("tau_ext", "effort", "current") if r in self.keys), "none")
        # factr2's own labels (a factr2 export): the thresholds that made them, else None
        self.phases = (feats.get(PHASE_FEATURE) or {}).get(FACTR2_PHASES) if self.force != "none" else None

    def cols(self, a: np.ndarray, n_state: int) -> np.ndarray:
        """The joint columns of a (N, n_state) or (N, J) array."""
        return a[:, self.joints] if a.shape[1] == n_state else a

    def to_dict(self) -> dict:
        return {"keys": self.keys, "gripper_index": self.gripper, "joint_names": self.joint_names,
                "angles": "deg" if self.deg else "rad", "cameras": self.cameras, "force": self.force}


def _short(name: str) -> str:
    """'follower.joint1' -> 'joint1', 'shoulder_pan.pos' -> 'shoulder_pan'."""
    if name.startswith("follower."):
        name = name[len("follower."):]
    return name[: -len(".pos")] if name.endswith(".pos") else name


def _tables(root: Path, sub: str):
    import pyarrow.parquet as pq

    files = sorted((root / sub).glob("*/*.parquet"))
    if not files:
        raise _bad(root, f"no {sub}/*/*.parquet files")
    try:
        return [pq.read_table(f) for f in files]
    except Exception as e:  # noqa: BLE001 -- pyarrow raises many kinds on a damaged file: one line
        raise _bad(root, f"{sub}: {type(e).__name__}: {str(e)[:80]}") from None


def _column(table, key: str) -> np.ndarray:
    """A column as numpy: a list column (vector feature) as (N, width) float."""
    import pyarrow as pa

    col = table.column(key).combine_chunks()
    ty = col.type
    if pa.types.is_list(ty) or pa.types.is_fixed_size_list(ty) or pa.types.is_large_list(ty):
        flat = np.asarray(col.flatten().to_numpy(zero_copy_only=False), float)
        return flat.reshape(len(col), -1) if len(col) else flat.reshape(0, 0)
    return np.asarray(col.to_numpy(zero_copy_only=False))


def _video_frames(root: Path, info: dict, ep_meta: dict, key: str, n: int, fps: float):
    """The episode's n frames of video `key`, in order (PyAV), from its from_timestamp on."""
    import av

    tmpl = info.get("video_path") or "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
    path = root / tmpl.format(video_key=key, chunk_index=int(ep_meta.get(f"videos/{key}/chunk_index", 0)),
                              file_index=int(ep_meta.get(f"videos/{key}/file_index", 0)))
    start = float(ep_meta.get(f"videos/{key}/from_timestamp", 0.0))
    if not path.is_file():
        raise _bad(root, f"video {path.relative_to(root)} missing")
    got = 0
    with av.open(str(path)) as c:
        stream = c.streams.video[0]
        if start > 0:
            c.seek(int(start / stream.time_base), stream=stream, backward=True, any_frame=False)
        for frame in c.decode(stream):
            if frame.time is None or frame.time < start - 0.5 / fps:
                continue
            yield frame.to_ndarray(format="rgb24")
            got += 1
            if got == n:
                return
    if got < n:
        raise _bad(root, f"video {path.relative_to(root)}: {got} frames for an episode of {n}")


def _image_frames(col) -> object:
    import io

    from PIL import Image

    for v in col:
        b = v.get("bytes") if isinstance(v, dict) else v
        if b is None and isinstance(v, dict) and v.get("path"):
            b = Path(v["path"]).read_bytes()
        yield np.asarray(Image.open(io.BytesIO(b)).convert("RGB"))


def read_episodes(root: Path, m: Mapping, info: dict) -> list[ImportedEpisode]:
    """Every episode of the dataset as arrays (frames read lazily)."""
    import pyarrow as pa

    data = pa.concat_tables(_tables(root, "data"), promote_options="default")
    try:
        metas = pa.concat_tables(_tables(root, "meta/episodes"), promote_options="default").to_pylist()
    except UserError:
        metas = []
    meta_by_ep = {int(d["episode_index"]): d for d in metas if "episode_index" in d}
    fps = float(info["fps"])
    need = ["episode_index", "timestamp", *(m.keys[r] for r in m.keys), *m.objects,
            *([PHASE_FEATURE] if m.phases is not None else [])]
    missing = [k for k in need if k not in data.column_names]
    if missing:
        raise _bad(root, f"data rows lack column(s) {', '.join(missing)}")
    eps = np.asarray(_column(data, "episode_index"), int)
    ts = np.asarray(_column(data, "timestamp"), float)
    frame_idx = np.asarray(_column(data, "frame_index"), int) if "frame_index" in data.column_names else None
    cols = {r: _column(data, k) for r, k in m.keys.items()}
    n_state = cols["state"].shape[1]
    objects = {k: _column(data, k) for k in m.objects}
    phase = np.asarray(_column(data, PHASE_FEATURE), int).reshape(-1) if m.phases is not None else None
    scale = np.pi / 180.0 if m.deg else 1.0
    out = []
    for e in sorted(set(eps.tolist())):
        rows = np.flatnonzero(eps == e)
        order = np.argsort(frame_idx[rows] if frame_idx is not None else ts[rows], kind="stable")
        rows = rows[order]
        # the rows' time on the fps grid (LeRobot's timestamps are frame_index / fps as float32)
        t = (frame_idx[rows] - frame_idx[rows][0]) / fps if frame_idx is not None else ts[rows] - ts[rows][0]
        st, act = cols["state"][rows], cols["action"][rows]
        g = m.gripper
        ep = ImportedEpisode(t=t, q=st[:, m.joints] * scale, action_q=act[:, m.joints] * scale,
                             gripper=None if g is None else st[:, g],
                             action_gripper=None if g is None else act[:, g])
        if "velocity" in cols:
            ep.qd = m.cols(cols["velocity"][rows], n_state) * scale
        if "effort" in cols:
            ep.tau_m = m.cols(cols["effort"][rows], n_state)
        if "current" in cols:
            ep.current = m.cols(cols["current"][rows], n_state)
        force = {"tau_ext": "tau_ext", "effort": "effort", "current": "current"}.get(m.force)
        if force:
            ep.tau_ext = m.cols(cols[force][rows], n_state)
        ep.objects = {k: (v[rows], m.objects[k]) for k, v in objects.items()}
        ep.phase = phase[rows] if phase is not None else None
        meta = meta_by_ep.get(e, {})
        tasks = meta.get("tasks") or []
        ep.task = str(tasks[0]) if len(tasks) else ""
        for cam in m.cameras:
            if info["features"][cam].get("dtype") == "video":
                seq = _video_frames(root, info, meta, cam, len(rows), fps)
            else:
                seq = _image_frames(data.column(cam).take(pa.array(rows)).to_pylist())
            ep.frames[cam[len(IMAGES):]] = (t, seq)  # the camera's name, as a rig names it
        out.append(ep)
    if not out:
        raise _bad(root, "no rows")
    return out


def _dataset_key(root: Path, given: dict) -> str:
    h = hashlib.sha256(json.dumps([CONVERTER_VERSION, sorted(given.items())]).encode())
    for f in sorted(p for sub in ("meta", "data", "videos") for p in (root / sub).rglob("*") if p.is_file()):
        st = f.stat()
        h.update(f"{f.relative_to(root)}:{st.st_size}:{st.st_mtime_ns}".encode())
    return h.hexdigest()[:20]


def phase_changes(phase: np.ndarray) -> list[list[int]]:
    """Per-row labels (N,) -> [[row, label], ...] at the first row and wherever the label changes."""
    phase = np.asarray(phase, int).reshape(-1)
    rows = np.flatnonzero(np.r_[True, phase[1:] != phase[:-1]]) if len(phase) else np.zeros(0, int)
    return [[int(r), int(phase[r])] for r in rows]


def labels_at(changes: list, rows: np.ndarray) -> np.ndarray:
    """The label of each row index (float rows rounded to the nearest) from phase_changes' list; rows
    before the first change take the first label."""
    ch = np.asarray(changes, int).reshape(-1, 2)
    i = np.searchsorted(ch[:, 0], np.rint(np.asarray(rows, float)), side="right") - 1
    return ch[np.clip(i, 0, None), 1].astype(np.int8)


PHASES_LINE = "FIRST labels from the dataset's phase column (factr2 export), not re-made from its force"


def force_line(root: Path, m: Mapping) -> str:
    """The one line that says where tau_ext (FIRST's labels, the force input) comes from."""
    if m.force == "tau_ext":
        return f"{root.name}: tau_ext from {m.keys['tau_ext']} [N*m]"
    if m.force == "none":
        return (f"{root.name}: no force-like feature (effort, current, tau_ext): base methods only "
                "(--method base)")
    unit = "N*m" if m.force == "effort" else "A"
    return (f"{root.name}: FIRST labels and the force input from raw {m.keys[m.force]} [{unit}], not NEXT, "
            "unless --next CKPT (a NEXT calibration of this arm) runs NEXT on the joint states")


def lerobot_recordings(root: Path, map_text: str | None = None, say=None) -> list[Path]:
    """The dataset's converted recording (made now, or the cached one) as a one-file list."""
    from hardware.recording.cache import cache_home

    root = Path(root)
    say = say or (lambda s: print(s, file=sys.stderr))
    given = parse_map(map_text)
    info = read_info(root)
    m = Mapping(info, given, root)
    dest = cache_home() / "lerobot" / _dataset_key(root, given)
    out = dest / f"{root.name}.mcap"
    for n in m.notes:
        say(f"{root.name}: {n}")
    say(force_line(root, m))
    if m.phases is not None:
        say(f"{root.name}: {PHASES_LINE}, unless --thresholds LOW:HIGH|next or --next CKPT labels it again")
    if out.is_file():
        return [out]
    episodes = read_episodes(root, m, info)
    shutil.rmtree(dest, ignore_errors=True)
    dest.mkdir(parents=True)
    meta = {"task": episodes[0].task, "import_format": "lerobot", "import_source": str(root.resolve()),
            "import_mapping": json.dumps(m.to_dict()), "robot_type": str(info.get("robot_type", "")),
            "tau_ext_source": m.force}
    if m.phases is not None:
        meta[IMPORT_PHASES] = json.dumps({"fps": float(info["fps"]), "thresholds": m.phases,
                                          "episodes": [phase_changes(ep.phase) for ep in episodes]})
    say(f"{root.name}: converting {len(episodes)} episodes to a recording ({out})")
    return [write_episodes(out, episodes, m.joint_names, meta)]
