"""GELLO teleop saves -> one factr2 recording (`factr2 episodes import gello DIR --out FILE.mcap`).

GELLO's data collection (its public `run_env.py` / `format_obs.save_frame`) writes one folder per episode
and in it one pickle per control step, named by the step's wall time (`datetime.isoformat()`, some forks
with ':' and '.' as '-', or an integer ns / frame counter), each a dict:

    joint_positions   (J [+1],) rad; with a gripper its last element is the gripper, 0..1 of its stroke
    joint_velocities  (J [+1],) rad/s (not trusted: the UR driver writes the positions there, others a
                      fixed dt; q_dot is differentiated from the positions instead)
    gripper_position  (1,) 0..1 (present with a gripper)
    ee_pos_quat       (7,) (not used)
    control           (J [+1],) the commanded joint targets (+ gripper): the action
    <view>_rgb        (H, W, 3) uint8 camera frames; <view>_depth dropped
    timestamp_ns / monotonic_ns   (some forks) the step's time [ns]: preferred to the file name

Newer GELLO writes an episode as state.npz (the same keys, one row per step, plus timestamp [s]) +
meta.json (task, outcome) + <view>/NNNNNN.jpg: read too. Pickles are read with an allow-list unpickler
(numpy arrays and plain containers only): a pickle that asks for anything else is refused, not run.
"""

from __future__ import annotations

import datetime as dt
import io
import json
import pickle
import re
from pathlib import Path

import numpy as np

from hardware.errors import UserError
from hardware.importers.write import ImportedEpisode, write_episodes

SAFE_GLOBALS = {
    ("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
    ("numpy.core.multiarray", "scalar"), ("numpy._core.multiarray", "scalar"),
    ("numpy", "ndarray"), ("numpy", "dtype"), ("collections", "OrderedDict"),
    ("datetime", "datetime"), ("numpy.core.numeric", "_frombuffer"), ("numpy._core.numeric", "_frombuffer"),
}
IMAGE_SUFFIX, DEPTH_SUFFIX = "_rgb", "_depth"
FIX = "pass GELLO's save folder (one folder per episode of <time>.pkl steps; docs/bringing_data.md)"


class _SafeUnpickler(pickle.Unpickler):
    def find_class(self, module, name):
        if (module, name) in SAFE_GLOBALS:
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"refused: the pickle asks for {module}.{name}")


def load_step(path: Path) -> dict:
    """One step's dict (allow-listed unpickling); ValueError with the reason on anything else."""
    try:
        obj = _SafeUnpickler(io.BytesIO(path.read_bytes())).load()
    except (pickle.UnpicklingError, EOFError, AttributeError, ImportError, IndexError, TypeError,
            ValueError, OSError) as e:
        raise ValueError(f"{type(e).__name__}: {str(e)[:80]}") from None
    if not isinstance(obj, dict):
        raise ValueError(f"a {type(obj).__name__}, not a dict of observations")
    return obj


_ISO_DASHED = re.compile(r"^(\d{4}-\d{2}-\d{2})T(\d{2})-(\d{2})-(\d{2})(?:-(\d+))?$")


def stem_time(stem: str) -> tuple[float | None, str]:
    """A step file's time from its name: (seconds, kind) with kind "wall" (ISO), "ns" or "index"."""
    try:
        return dt.datetime.fromisoformat(stem).timestamp(), "wall"
    except ValueError:
        pass
    m = _ISO_DASHED.match(stem)
    if m:
        frac = m.group(5) or "0"
        t = dt.datetime.fromisoformat(f"{m.group(1)}T{m.group(2)}:{m.group(3)}:{m.group(4)}")
        return t.timestamp() + int(frac) / 10 ** len(frac), "wall"
    if stem.isdigit():
        v = int(stem)
        return (v * 1e-9, "ns") if v > 10**12 else (float(v), "index")
    return None, ""


def _arr(d: dict, key: str) -> np.ndarray | None:
    v = d.get(key)
    return None if v is None else np.asarray(v, float).reshape(-1)


def _split(rows: np.ndarray, gripper: bool) -> tuple[np.ndarray, np.ndarray | None]:
    return (rows[:, :-1], rows[:, -1]) if gripper else (rows, None)


def _episode_from_rows(steps: list[dict], t: np.ndarray, where: str) -> ImportedEpisode:
    for key in ("joint_positions", "control"):
        if any(key not in s for s in steps):
            raise UserError(f"a step has no {key}", where=where, fix=FIX)
    try:
        q_all = np.stack([_arr(s, "joint_positions") for s in steps])
        act_all = np.stack([_arr(s, "control") for s in steps])
    except ValueError:
        raise UserError("steps with different joint counts", where=where, fix=FIX) from None
    if q_all.shape[1] != act_all.shape[1]:
        raise UserError(f"joint_positions has {q_all.shape[1]} values, control {act_all.shape[1]}",
                        where=where, fix=FIX)
    grip = "gripper_position" in steps[0] and q_all.shape[1] > 1
    q, g = _split(q_all, grip)
    a, ag = _split(act_all, grip)
    ep = ImportedEpisode(t=t, q=q, gripper=g, action_q=a, action_gripper=ag)
    views = sorted(k[: -len(IMAGE_SUFFIX)] for k in steps[0] if k.endswith(IMAGE_SUFFIX))
    for v in views:
        frames = [np.asarray(s.get(f"{v}{IMAGE_SUFFIX}"), np.uint8) for s in steps]
        ok = [i for i, f in enumerate(frames) if f.ndim == 3 and f.shape[2] == 3]
        ep.frames[v] = (t[ok], (frames[i] for i in ok))
    return ep


def _pickle_episode(folder: Path, files: list[Path], rate_hz: float | None, notes: list[str]):
    steps, times, kinds, bad = [], [], set(), []
    for f in files:
        try:
            s = load_step(f)
        except ValueError as e:
            bad.append(f"{f.name} ({e})")
            continue
        ns = s.get("monotonic_ns", s.get("timestamp_ns"))
        t, kind = (int(ns) * 1e-9, "ns") if ns is not None else stem_time(f.stem)
        if t is None:
            bad.append(f"{f.name} (no time in its name or dict)")
            continue
        steps.append(s)
        times.append(t)
        kinds.add(kind)
    if bad:
        notes.append(f"{folder.name}: skipped {len(bad)} step file(s): {'; '.join(bad[:2])}")
    if len(steps) < 2:
        return None
    order = np.argsort(times, kind="stable")
    steps, t = [steps[i] for i in order], np.asarray(times, float)[order]
    if kinds == {"index"}:
        if rate_hz is None:
            raise UserError("step files are numbered, not timed", where=str(folder),
                            fix="pass --rate HZ (GELLO's control rate, run_env.py --hz)")
        t = t / rate_hz
    keep = np.r_[True, np.diff(t) > 0]  # two steps in one clock tick: the first kept
    if not keep.all():
        notes.append(f"{folder.name}: {int((~keep).sum())} step(s) with a repeated time dropped")
    steps, t = [s for s, k in zip(steps, keep) if k], t[keep]
    ep = _episode_from_rows(steps, t - t[0], str(folder))
    ep.task, ep.outcome = "", None  # the classic saves say neither
    return ep


def _npz_episode(folder: Path) -> ImportedEpisode:
    from PIL import Image

    try:
        with np.load(folder / "state.npz", allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (ValueError, OSError, EOFError) as e:
        raise UserError(f"state.npz unreadable ({type(e).__name__})", where=str(folder), fix=FIX) from None
    try:
        meta = json.loads((folder / "meta.json").read_text())
    except (OSError, ValueError):
        meta = {}
    if "timestamp" not in arrays:
        raise UserError("state.npz has no timestamp", where=str(folder), fix=FIX)
    n = len(arrays["timestamp"])
    steps = [{k: v[i] for k, v in arrays.items() if len(v) == n} for i in range(n)]
    t = np.asarray(arrays["timestamp"], float)
    ep = _episode_from_rows(steps, t - t[0], str(folder))
    for view in meta.get("views", []):
        files = [folder / view / f"{i:06d}.jpg" for i in range(n)]
        ok = [i for i, f in enumerate(files) if f.is_file()]  # dropped frames have no file
        ep.frames[view] = (ep.t[ok], (np.asarray(Image.open(files[i]).convert("RGB")) for i in ok))
    ep.task = str(meta.get("task", ""))
    outcome = meta.get("outcome")
    ep.outcome = outcome if outcome in ("success", "failure") else None
    return ep


def episode_folders(root: Path) -> list[Path]:
    """The episode folders under root: root itself when it holds steps, else its subfolders that do."""
    def is_episode(d: Path) -> bool:
        return (d / "state.npz").is_file() or any(d.glob("*.pkl"))

    if not root.is_dir():
        raise UserError("no such folder", where=str(root), fix=FIX)
    if is_episode(root):
        return [root]
    return sorted(d for d in root.iterdir() if d.is_dir() and is_episode(d))


def import_gello(root: Path, out: Path, rate_hz: float | None = None, task: str = "",
                 say=None) -> tuple[Path, list[str]]:
    """Write every episode under `root` to the recording `out`; returns it and notes for the user."""
    root, out = Path(root), Path(out)
    if out.exists():
        raise UserError("output file exists", where=str(out), fix="name a new --out file")
    folders = episode_folders(root)
    if not folders:
        raise UserError("no GELLO episodes (no folder with .pkl steps or state.npz)", where=str(root),
                        fix=FIX)
    notes: list[str] = []
    episodes, names = [], None
    for d in folders:
        ep = (_npz_episode(d) if (d / "state.npz").is_file()
              else _pickle_episode(d, sorted(d.glob("*.pkl")), rate_hz, notes))
        if ep is None:
            notes.append(f"{d.name}: fewer than 2 readable steps, left out")
            continue
        ep.task = ep.task or task or "gello teleop"
        n = ep.q.shape[1]
        if names is None:
            names = [f"joint{i + 1}" for i in range(n)]
        elif len(names) != n:
            raise UserError(f"episode {d.name} has {n} joints, the first {len(names)}", where=str(d),
                            fix="import one robot's episodes at a time")
        episodes.append(ep)
        if say:
            say(f"{d.name}: {len(ep.t)} steps, {ep.t[-1]:.1f} s, cameras {', '.join(ep.frames) or 'none'}")
    if not episodes:
        raise UserError(f"no readable GELLO episode ({notes[0] if notes else ''})", where=str(root), fix=FIX)
    meta = {"task": episodes[0].task, "import_format": "gello", "import_source": str(root.resolve()),
            "tau_ext_source": "none"}
    out.parent.mkdir(parents=True, exist_ok=True)
    return write_episodes(out, episodes, names, meta), notes
