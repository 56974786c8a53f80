"""Recorded episodes -> policy samples (paper Sec. 5): one sample per tick of the policy rate (default the
camera rate) with

    observation.images.<cam>   the latest frame of each camera at or before the tick (cached uint8, S x S)
    observation.state          follower joint positions [rad] + gripper [m] (per follower arm)
    observation.force          tau_ext [N*m] (NEXT: recorded or offline), or motor current [A], or nothing
    action                     the next `chunk` commanded joint targets [rad] + gripper [m]
                               (/follower/command) from this tick on; past the episode end the last one is
                               repeated and masked out
    phase                      FIRST phase of the tick (policies.phases)

Validation: whole episodes, a deterministic choice per seed. Normalisation: mean/std of the training samples.
Augmentation: RandomResizedCrop on the training batches (torch, per-sample boxes from the step's generator).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from hardware.errors import UserError
from hardware.recording import schemas as S
from hardware.recording.reader import Episode, interp_linear
from policies.frame_cache import camera_frames
from policies.labelling import NextModel, Thresholds, label_episode
from policies.normalizer import Normalizer
from policies.recordings import ArmSet, episode_id, follower_state_action

FORCE_SOURCES = ("tau_ext", "current", "none")
CROP_SCALE = (0.8, 1.0)  # RandomResizedCrop: area share kept
CROP_RATIO = (3 / 4, 4 / 3)  # and aspect ratio range


def action_prefix(follower: str) -> str:
    """ "follower" -> "action", "left_follower" -> "left_action" (hardware.features naming)."""
    return follower[: -len("follower")] + "action" if follower.endswith("follower") else f"{follower}_action"


@dataclass
class FeatureNames:
    state: list[str]
    force: list[str]
    action: list[str]
    cameras: list[str]

    def to_dict(self) -> dict:
        return {
            "observation.state": self.state,
            "observation.force": self.force,
            "action": self.action,
            "observation.images": [f"observation.images.{c}" for c in self.cameras],
        }


@dataclass
class PolicyData:
    """All samples of a run, concatenated over episodes. Arrays are raw units; normalise with `norm`."""

    names: FeatureNames
    state: np.ndarray  # (N, S) float32
    force: np.ndarray  # (N, F) float32 (F = 0 without force)
    action: np.ndarray  # (N, chunk, A) float32
    mask: np.ndarray  # (N, chunk) bool
    force_chunk: np.ndarray  # (N, chunk, F) float32: future force (TA-VLA's auxiliary target)
    phase: np.ndarray  # (N,) int8
    episode: np.ndarray  # (N,) int32 index into episode_ids
    frames: list[dict[str, np.ndarray]]  # per recording: camera -> (n, S, S, 3) uint8 (memory-mapped)
    frame_rec: np.ndarray  # (N,) int32 recording of each sample
    frame_idx: np.ndarray  # (N, M) int64 frame per camera
    episode_ids: list[str]
    rate_hz: float
    image_size: int
    norm: Normalizer | None = None
    val_episodes: list[int] = field(default_factory=list)

    def __len__(self) -> int:
        return int(self.state.shape[0])

    def split(self) -> tuple[np.ndarray, np.ndarray]:
        """(train sample indices, validation sample indices)."""
        val = np.isin(self.episode, self.val_episodes)
        return np.flatnonzero(~val), np.flatnonzero(val)

    def images(self, idx: np.ndarray) -> np.ndarray:
        """(B, M, S, S, 3) uint8 frames of samples `idx`."""
        out = np.empty((len(idx), len(self.names.cameras), self.image_size, self.image_size, 3), np.uint8)
        recs = self.frame_rec[idx]
        for r in np.unique(recs):
            rows = np.flatnonzero(recs == r)
            for m, cam in enumerate(self.names.cameras):
                out[rows, m] = self.frames[r][cam][self.frame_idx[idx[rows], m]]
        return out

    def batch(self, idx: np.ndarray, crops: torch.Tensor | None = None) -> dict:
        """Torch batch of samples `idx`: images uint8 (B, M, S, S, 3) (the model converts them), the rest
        normalised float32; crops (B, 4) = RandomResizedCrop boxes (draw_crops) or None."""
        n = self.norm
        img = self.images(idx)
        if crops is not None:
            img = resized_crop(img, crops.numpy())
        out = {"images": torch.from_numpy(img), "state": torch.from_numpy(n.norm("state", self.state[idx])),
               "action": torch.from_numpy(n.norm("action", self.action[idx])),
               "mask": torch.from_numpy(self.mask[idx]),
               "phase": torch.from_numpy(self.phase[idx].astype(np.int64))}
        if self.force.shape[1]:
            out["force"] = torch.from_numpy(n.norm("force", self.force[idx]))
            out["force_chunk"] = torch.from_numpy(n.norm("force", self.force_chunk[idx]))
        return out


def draw_crops(batch: int, gen: torch.Generator) -> torch.Tensor:
    """RandomResizedCrop boxes (B, 4): centre x, centre y, width, height as fractions of the image."""
    u = torch.rand(batch, 4, generator=gen, dtype=torch.float64)
    area = CROP_SCALE[0] + u[:, 0] * (CROP_SCALE[1] - CROP_SCALE[0])
    log_r = np.log(CROP_RATIO[0]) + u[:, 1] * (np.log(CROP_RATIO[1]) - np.log(CROP_RATIO[0]))
    r = torch.exp(log_r)
    w = torch.sqrt(area * r).clamp(max=1.0)
    h = torch.sqrt(area / r).clamp(max=1.0)
    cx = w / 2 + u[:, 2] * (1 - w)
    cy = h / 2 + u[:, 3] * (1 - h)
    return torch.stack([cx, cy, w, h], dim=1)


_POOL = None


def _crop_pool():
    """Threads for the crops: PIL releases the GIL while it resamples."""
    global _POOL
    if _POOL is None:
        import os
        from concurrent.futures import ThreadPoolExecutor

        _POOL = ThreadPoolExecutor(max_workers=min(4, os.cpu_count() or 1), thread_name_prefix="crop")
    return _POOL


def resized_crop(img: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Crop each sample's box (the same for all its cameras) and resize it back to the full size, bilinear
    (PIL, one C call per image, on a few threads: ~10x faster here than grid_sample or fancy indexing on
    the whole batch). img (B, M, H, W, 3) uint8; boxes (B, 4) from draw_crops."""
    from PIL import Image

    b, m, h, w, _ = img.shape
    out = np.empty_like(img)

    def one(i: int) -> None:
        cx, cy, bw, bh = (float(v) for v in boxes[i])
        box = ((cx - bw / 2) * w, (cy - bh / 2) * h, (cx + bw / 2) * w, (cy + bh / 2) * h)
        for k in range(m):
            out[i, k] = np.asarray(Image.fromarray(img[i, k]).resize((w, h), Image.BILINEAR, box=box))

    list(_crop_pool().map(one, range(b)))
    return out


def camera_rate(episodes: list[Episode], cameras: list[str]) -> float:
    """Median frame rate [Hz] of the first camera over the episodes."""
    dts = [np.diff(ep.frames(cameras[0]).t) for ep in episodes]
    dts = np.concatenate([d for d in dts if len(d)]) if any(len(d) for d in dts) else np.array([])
    if not len(dts) or np.median(dts) <= 0:
        raise UserError(f"camera {cameras[0]} has too few frames to find its rate", fix="pass --rate HZ")
    return float(1.0 / np.median(dts))


def _chunks(x: np.ndarray, chunk: int) -> tuple[np.ndarray, np.ndarray]:
    """x (N, D) -> (N, chunk, D) windows x[k : k + chunk], padded with the last row, and the valid mask."""
    n = len(x)
    idx = np.arange(n)[:, None] + np.arange(chunk)[None]
    return x[np.minimum(idx, n - 1)], idx < n


def _episode_samples(
    ep: Episode,
    arms: ArmSet,
    cams: list[str],
    rec_frames_t: dict,
    rate: float,
    chunk: int,
    force: str,
    th: Thresholds,
    next_model: NextModel | None,
) -> dict | None:
    js0 = ep.topic(S.joint_state_topic(arms.followers[0]))
    t0 = max([js0.t[0]] + [rec_frames_t[c][0] for c in cams if len(rec_frames_t[c])])
    if t0 >= js0.t[-1]:
        return None
    grid = t0 + np.arange(int(np.floor((js0.t[-1] - t0) * rate)) + 1) / rate
    state, action, force_parts = [], [], []
    for arm in arms.followers:
        js = ep.topic(S.joint_state_topic(arm))
        st, act = follower_state_action(ep, arm, grid, "learn")
        state.append(st)
        action.append(act)
        if force == "current":
            force_parts.append(interp_linear(js.t, js.fields["current"], grid))
    labels = label_episode(ep, arms, th, next_model)
    if force == "tau_ext":
        force_parts.append(interp_linear(labels.t, labels.tau_ext, grid))
    state, action = np.concatenate(state, axis=1), np.concatenate(action, axis=1)
    fvals = np.concatenate(force_parts, axis=1) if force_parts else np.zeros((len(grid), 0))
    fvals = np.nan_to_num(fvals)  # NEXT's first window (offline) has no estimate yet: 0 N*m
    ok = np.isfinite(state).all(1) & np.isfinite(action).all(1)
    fidx = (
        np.stack([np.searchsorted(rec_frames_t[c], grid + 1e-6, side="right") - 1 for c in cams], axis=1)
        if cams
        else np.zeros((len(grid), 0), np.int64)
    )
    ok &= (fidx >= 0).all(1)
    if ok.sum() < 1:
        return None
    keep = np.flatnonzero(ok)
    a, m = _chunks(action[keep], chunk)
    fc, _ = _chunks(fvals[keep], chunk)
    return {
        "state": state[keep],
        "force": fvals[keep],
        "action": a,
        "mask": m,
        "force_chunk": fc,
        "phase": labels.at(grid[keep]),
        "frame_idx": fidx[keep],
    }


def build_dataset(
    episodes: list[Episode],
    arms: ArmSet,
    *,
    th: Thresholds,
    chunk: int = 30,
    image_size: int = 96,
    force: str = "tau_ext",
    rate_hz: float | None = None,
    next_model: NextModel | None = None,
    val_fraction: float = 0.1,
    seed: int = 0,
    cameras: list[str] | None = None,
    progress=None,
) -> PolicyData:
    if force not in FORCE_SOURCES:
        raise ValueError(f"force {force!r}: one of {FORCE_SOURCES}")
    recs = list(dict.fromkeys(ep.recording for ep in episodes))
    cams = cameras if cameras is not None else sorted(set.intersection(*(set(r.cameras) for r in recs)))
    if not cams:
        raise UserError(
            "the recordings have no camera frames (or no camera in all of them); both presets need images",
            where=str(recs[0].path),
            fix="record with cameras (`factr2 teleop --record` on a rig with [[cameras]])",
        )
    rate = rate_hz or camera_rate(episodes, cams)
    frames = [{c: camera_frames(r, c, image_size, progress) for c in cams} for r in recs]
    frames_t = [{c: r.frames(c).t for c in cams} for r in recs]
    parts, ids = [], []
    for ep in episodes:
        ri = recs.index(ep.recording)
        got = _episode_samples(ep, arms, cams, frames_t[ri], rate, chunk, force, th, next_model)
        if got is None:
            continue
        got["episode"] = np.full(len(got["state"]), len(ids), np.int32)
        got["rec"] = np.full(len(got["state"]), ri, np.int32)
        parts.append(got)
        ids.append(episode_id(ep))
    if not parts:
        raise UserError(
            "no samples: no episode has joint states, commands and frames together",
            where=str(recs[0].path),
            fix="check the recordings with `factr2 episodes show`",
        )
    cat = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    n_f = cat["force"].shape[1]
    names = FeatureNames(
        state=[n for a in arms.followers for n in (f"{a}.joint.pos", f"{a}.gripper.pos")],
        force=(
            [f"{a}.joint.tau_ext" for a in arms.followers]
            if force == "tau_ext"
            else [f"{a}.joint.current" for a in arms.followers]
            if force == "current"
            else []
        ),
        action=[
            n
            for a in arms.followers
            for n in (f"{action_prefix(a)}.joint.pos", f"{action_prefix(a)}.gripper.pos")
        ],
        cameras=list(cams),
    )
    n_val = int(round(val_fraction * len(ids))) if len(ids) >= 2 else 0
    n_val = min(max(n_val, 1 if val_fraction > 0 and len(ids) >= 2 else 0), len(ids) - 1)
    val = sorted(np.random.default_rng([seed, 0xE915]).permutation(len(ids))[:n_val].tolist())
    data = PolicyData(
        names,
        cat["state"].astype(np.float32),
        cat["force"].astype(np.float32).reshape(len(cat["state"]), n_f),
        cat["action"].astype(np.float32),
        cat["mask"],
        cat["force_chunk"].astype(np.float32),
        cat["phase"].astype(np.int8),
        cat["episode"],
        frames,
        cat["rec"],
        cat["frame_idx"],
        ids,
        float(rate),
        int(image_size),
        val_episodes=val,
    )
    train_idx, _ = data.split()
    data.norm = Normalizer.fit(
        {
            "state": data.state[train_idx],
            "action": data.action[train_idx][:, 0],
            "force": data.force[train_idx],
        }
    )
    return data
