"""Recorded episodes -> policy samples (paper Sec. 5): one sample per tick of the policy rate (default the
camera rate) with

    observation.images.<cam>   the latest frame of each camera at or before the tick (cached uint8, S x S)
    observation.state          follower joint positions [rad] + gripper [m] (per follower arm)
    observation.force          tau_ext [N*m] (NEXT: recorded or offline), or motor current [A], or nothing
    observation.state.objects  PRIVILEGED (twins only, `observation` "state" / "images+state"): the task
                               objects' vector (policies/data/privileged.py) last recorded at or before the
                               tick; "state" reads no frames at all
    observation.perceived.objects  SIMULATED (twins only, "perceived" / "images+perceived"), in its place:
                               the simulated pose detector's vector as recorded live (hardware/sim/
                               perception.py; what the demonstrator's camera gave), held the same way
    action                     the next `chunk` commanded joint targets [rad] + gripper [m]
                               (/follower/command) from this tick on; past the episode end the last one is
                               repeated and masked out; a perturbed collection's ticks: the operator's
                               target (the offset taken off) or masked out (policies/data/perturbed.py)
    phase                      FIRST phase of the tick (policies.labels.phases)
    source                     who made the tick: a demonstration, or in a rollout recording the policy, the
                               pre-intervention window or the operator (hardware/recording/interventions.py)

Validation: whole episodes, a deterministic choice per seed. Normalisation: mean/std of the training samples.
Normalisation, frame decoding and the RandomResizedCrop augmentation (per-sample boxes from the step's
generator) are policies.data.preprocess's, the pipeline a rollout rebuilds from the checkpoint; `batch`
assembles the inputs with it as a rollout does. A tick is a sample by `valid_samples`, the export's rule too.
"""

from __future__ import annotations

from concurrent.futures import Executor
from dataclasses import dataclass, field

import numpy as np
import torch

from hardware.errors import UserError
from hardware.features import IMAGES, policy_names
from hardware.features import size as feature_size
from hardware.recording import schemas as S
from hardware.recording.interventions import SOURCE_DEMO, source_on_grid
from hardware.recording.reader import Episode, interp_linear
from hardware.timeseries import hold_previous
from policies.data.frame_cache import camera_frames
from policies.data.normalizer import Normalizer
from policies.data.perturbed import DEFAULT_PERTURBED, offset_on_grid, perturbed_actions
from policies.data.preprocess import ImagePath, Preprocess, crop_pool, relative_columns, to_frame
from policies.data.privileged import OBSERVATIONS, objects_feature, uses_images
from policies.data.recordings import ArmSet, episode_id, follower_state_action, recording_features
from policies.labels.labelling import NextModel, Thresholds, label_episode

FORCE_SOURCES = ("tau_ext", "current", "none")
STATE_RATE_HZ = 30.0  # Hz: policy rate without cameras (`--obs state` on camera-less recordings): the twin
# rigs' camera rate, so a state policy acts as often as an image policy would


@dataclass
class FeatureNames:
    state: list[str]
    force: list[str]
    action: list[str]
    cameras: list[str]
    objects: list[str] = field(default_factory=list)  # element names of the object vector, [] if unused
    objects_feature: str = S.TASK_OBJECTS_FEATURE  # which: privileged (state) or perceived (SIMULATED)

    def to_dict(self) -> dict:
        out = {
            "observation.state": self.state,
            "observation.force": self.force,
            "action": self.action,
            "observation.images": [f"{IMAGES}{c}" for c in self.cameras],
        }
        if self.objects:
            out[self.objects_feature] = self.objects
        return out


@dataclass
class PolicyData:
    """All samples of a run, concatenated over episodes. Arrays are raw units; `batch` normalises them."""

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
    pre: Preprocess | None = None  # normaliser (fitted on the training samples) and image path: saved with
    # the policy (build_dataset sets it)
    val_episodes: list[int] = field(default_factory=list)
    objects: np.ndarray | None = None  # (N, O) float32 privileged object vector, None when not observed
    source: np.ndarray | None = None  # (N,) int8 sample source (hardware/recording/interventions.py
    # SOURCE_NAMES), None when every sample is a demonstration's
    perturbed: np.ndarray | None = None  # (N,) bool: the tick's target was perturbed (policies/data/
    # perturbed.py), None when no tick was
    _crop_pool: Executor | None = field(default=None, init=False, repr=False, compare=False)

    def __len__(self) -> int:
        return int(self.state.shape[0])

    def _crops(self) -> Executor:
        """The crop threads, started with the first cropped batch; close() ends them."""
        if self._crop_pool is None:
            self._crop_pool = crop_pool()
        return self._crop_pool

    def close(self) -> None:
        """End the crop threads (the data stays usable: a later cropped batch starts them again)."""
        if self._crop_pool is not None:
            self._crop_pool.shutdown()
            self._crop_pool = None

    def __enter__(self) -> PolicyData:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def split(self) -> tuple[np.ndarray, np.ndarray]:
        """(train sample indices, validation sample indices)."""
        val = np.isin(self.episode, self.val_episodes)
        return np.flatnonzero(~val), np.flatnonzero(val)

    def images(self, idx: np.ndarray) -> np.ndarray:
        """(B, M, S, S, 3) uint8 frames of samples `idx`."""
        size = self.pre.image.size
        out = np.empty((len(idx), len(self.names.cameras), size, size, 3), np.uint8)
        recs = self.frame_rec[idx]
        for r in np.unique(recs):
            rows = np.flatnonzero(recs == r)
            for m, cam in enumerate(self.names.cameras):
                out[rows, m] = self.frames[r][cam][self.frame_idx[idx[rows], m]]
        return out

    def batch(self, idx: np.ndarray, crops: torch.Tensor | None = None) -> dict:
        """Torch batch of samples `idx`: the model's inputs as a rollout builds them (Preprocess.inputs:
        images uint8 (B, M, S, S, 3), the rest normalised float32) plus the normalised targets; crops (B, 4)
        = RandomResizedCrop boxes (ImagePath.draw_crops) or None."""
        n = self.pre.norm
        out = self.pre.inputs(self.state[idx], self.force[idx],
                              self.objects[idx] if self.objects is not None else None,
                              self.images(idx) if self.names.cameras else None, crops,
                              self._crops() if crops is not None else None)
        out.update(action=torch.from_numpy(self.pre.targets(self.action[idx], self.state[idx])),
                   mask=torch.from_numpy(self.mask[idx]),
                   phase=torch.from_numpy(self.phase[idx].astype(np.int64)))
        if self.force.shape[1]:
            out["force_chunk"] = torch.from_numpy(n.norm("force", self.force_chunk[idx]))
        return out


def latest_frame(frame_t: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Index of each tick's latest frame at or before it (1 us tolerance: frame times come from ns log
    times), -1 before the first frame."""
    return np.searchsorted(frame_t, grid + 1e-6, side="right") - 1


def valid_samples(state: np.ndarray, action: np.ndarray, objects: np.ndarray | None = None,
                  frame_idx: np.ndarray | None = None) -> np.ndarray:
    """The one rule for a usable tick (training samples and exported rows): finite state and action,
    finite PRIVILEGED objects when observed, and a frame of every camera (frame_idx (N, M) >= 0)."""
    ok = np.isfinite(state).all(1) & np.isfinite(action).all(1)
    if objects is not None:
        ok &= np.isfinite(objects).all(1)
    if frame_idx is not None:
        ok &= (frame_idx >= 0).all(1)
    return ok


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
    objects: str | None = None,
    perturbed: str = DEFAULT_PERTURBED,
) -> dict | None:
    """One episode's samples; objects: the topic of the object vector to hold onto the ticks (None: none);
    perturbed: what a perturbed collection's ticks teach (policies/data/perturbed.py)."""
    js0 = ep.topic(S.joint_state_topic(arms.followers[0]))
    t0 = max([js0.t[0]] + [rec_frames_t[c][0] for c in cams if len(rec_frames_t[c])])
    if t0 >= js0.t[-1]:
        return None
    grid = t0 + np.arange(int(np.floor((js0.t[-1] - t0) * rate)) + 1) / rate
    state, action, force_parts, hits = [], [], [], []
    for arm in arms.followers:
        js = ep.topic(S.joint_state_topic(arm))
        st, act = follower_state_action(ep, arm, grid, "learn")
        act, hit = perturbed_actions(act, offset_on_grid(ep, arm, grid, act.shape[1] - 1), perturbed)
        hits.append(hit)
        state.append(st)
        action.append(act)
        if force == "current":
            force_parts.append(interp_linear(js.t, js.fields["current"], grid))
    labels = label_episode(ep, arms, th, next_model) if th is not None else None  # None: no force at all
    if force == "tau_ext":
        force_parts.append(interp_linear(labels.t, labels.tau_ext, grid))
    state, action = np.concatenate(state, axis=1), np.concatenate(action, axis=1)
    fvals = np.concatenate(force_parts, axis=1) if force_parts else np.zeros((len(grid), 0))
    fvals = np.nan_to_num(fvals)  # NEXT's first window (offline) has no estimate yet: 0 N*m
    ovals = None
    if objects:  # the latest vector at or before each tick, as a live policy has it (NaN before the first)
        ob = ep.topic(objects)
        ovals = hold_previous(ob.t, ob.fields["objects"], grid)  # all NaN when the episode has none
    fidx = (
        np.stack([latest_frame(rec_frames_t[c], grid) for c in cams], axis=1)
        if cams
        else np.zeros((len(grid), 0), np.int64)
    )
    ok = valid_samples(state, action, ovals, fidx)
    if ok.sum() < 1:
        return None
    keep = np.flatnonzero(ok)
    a, m = _chunks(action[keep], chunk)
    hit = np.any(hits, axis=0)[keep]
    if perturbed == "skip":  # the perturbed ticks' actions leave the loss; their states stay observations
        m = m & ~_chunks(hit[:, None], chunk)[0][..., 0]
    fc, _ = _chunks(fvals[keep], chunk)
    return {
        "state": state[keep],
        "force": fvals[keep],
        "action": a,
        "mask": m,
        "force_chunk": fc,
        "phase": labels.at(grid[keep]) if labels is not None else np.zeros(len(keep), np.int8),
        "source": source_on_grid(ep, grid[keep]),
        "perturbed": hit,
        "frame_idx": fidx[keep],
        **({"objects": ovals[keep]} if objects else {}),
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
    observation: str = "images",
    action_frame: str = "absolute",
    perturbed: str = DEFAULT_PERTURBED,
) -> PolicyData:
    """observation: "images" (camera frames), "state" (the PRIVILEGED task-object vector, no frames read),
    "perceived" (the SIMULATED detector's vector instead) or either with images ("images+state",
    policies/data/privileged.py); action_frame: "absolute" or "relative" (Preprocess); perturbed: "dart" or
    "skip", what a perturbed collection's ticks teach (policies/data/perturbed.py)."""
    if force not in FORCE_SOURCES:
        raise ValueError(f"force {force!r}: one of {FORCE_SOURCES}")
    if observation not in OBSERVATIONS:
        raise ValueError(f"observation {observation!r}: one of {OBSERVATIONS}")
    recs = list(dict.fromkeys(ep.recording for ep in episodes))
    common = sorted(set.intersection(*(set(r.cameras) for r in recs)))
    cams = (cameras if cameras is not None else common) if uses_images(observation) else []
    if uses_images(observation) and not cams:
        raise UserError(
            "the recordings have no camera frames (or no camera in all of them); both presets need images",
            where=str(recs[0].path),
            fix="record with cameras (`factr2 teleop --record` on a rig with [[cameras]]), or train on the "
            "twin's privileged object state with --obs state (task recordings of `factr2 collect`)",
        )
    feature = objects_feature(observation)
    object_names = _object_names(recs, feature) if feature else []
    rate = rate_hz or (camera_rate(episodes, cams or common) if (cams or common) else STATE_RATE_HZ)
    image = ImagePath.from_recordings(recs, cams, image_size)  # the frames' encoding: rollout repeats it
    frames = [{c: camera_frames(r, c, image.size, progress) for c in cams} for r in recs]
    frames_t = [{c: r.frames(c).t for c in cams} for r in recs]
    parts, ids = [], []
    for ep in episodes:
        ri = recs.index(ep.recording)
        got = _episode_samples(ep, arms, cams, frames_t[ri], rate, chunk, force, th, next_model,
                               S.OBJECT_TOPICS[feature] if object_names else None, perturbed)
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
    features = recording_features(recs[0])
    io = policy_names(features, list(arms.followers), force)  # the one schema's names
    names = FeatureNames(state=io["state"], force=io["force"], action=io["action"], cameras=list(cams),
                         objects=object_names, objects_feature=feature or S.TASK_OBJECTS_FEATURE)
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
        val_episodes=val,
        objects=cat["objects"].astype(np.float32) if object_names else None,
        source=cat["source"] if bool((cat["source"] != SOURCE_DEMO).any()) else None,
        perturbed=cat["perturbed"] if bool(cat["perturbed"].any()) else None,
    )
    train_idx, _ = data.split()
    relative = relative_columns(io["action"], {n: feature_size(features[n]) for n in io["action"]})
    if action_frame == "absolute":  # per value, over the chunks' first steps
        action = data.action[train_idx][:, 0]
    else:  # per chunk step and value (Preprocess)
        action = to_frame(data.action[train_idx], data.state[train_idx], np.asarray(relative))
        action = action.reshape(len(action), -1)
    groups = {"state": data.state[train_idx], "action": action, "force": data.force[train_idx]}
    if data.objects is not None:
        groups["objects"] = data.objects[train_idx]
    data.pre = Preprocess(Normalizer.fit(groups), image, action_frame,
                          relative if action_frame != "absolute" else [])
    return data


def _object_names(recs, feature: str = S.TASK_OBJECTS_FEATURE) -> list[str]:
    """The object vector's element names (PRIVILEGED or perceived, by its feature), the same in every
    recording (UserError otherwise)."""
    names = None
    topic = S.OBJECT_TOPICS[feature]
    what = "perceived objects" if feature == S.PERCEIVED_FEATURE else "privileged object state"
    obs = "perceived" if feature == S.PERCEIVED_FEATURE else "state"
    for r in recs:
        got = r.task_object_names(topic) if topic in r.topics else []
        if not got:
            raise UserError(
                f"no {what} ({topic}) in this recording: --obs {obs} needs twin task demonstrations",
                where=str(r.path),
                fix="record them with `factr2 collect --rig sim-piper --task T`, or train on images",
            )
        if names is not None and got != names:
            raise UserError(
                f"recordings of different tasks: object vectors {len(names)} and {len(got)} long",
                where=str(r.path),
                fix="train on one task's recordings",
            )
        names = got
    return names or []
