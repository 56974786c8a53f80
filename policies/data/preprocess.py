"""One preprocessing pipeline from an observation to the model's input, and from its output back to units:
the same code in training (policies/data/dataset.py, policies/data/frame_cache.py) and at rollout
(policies/rollout/runner.py), saved in the checkpoint JSON ("preprocess") and rebuilt from it.

    pre = Preprocess(Normalizer.fit(...), ImagePath.from_recordings(recs, cameras, size))   # training
    meta["preprocess"] = pre.to_dict();  pre = Preprocess.from_meta(meta)                   # checkpoint
    batch = pre.inputs(state, force, objects, images)        # the one batch assembly (training and rollout)
    actions = pre.actions(z)                                 # model output -> [rad], [m]

Image path. A recorded frame is the camera's RGB JPEG-encoded by the recorder (hardware/recording/
writer_process.py); training decodes it with `decode_resized` (JPEG DCT scaling to the smallest scale still
>= size, then bilinear to size x size: the whole field of view, aspect ratio not kept) into the frame cache,
then crops (RandomResizedCrop, training only). A live frame is the camera's raw RGB: `ImagePath.live`
JPEG-encodes it with the recording's own encoder settings (its quantisation tables and chroma subsampling,
read from the recorded JPEG, so any encoder is reproduced, not only the recorder's quality 85) and sends it
through the same `decode_resized`. The same RGB thus gives the same bytes and the same uint8 input, exactly
(tests/test_policies_preprocess.py, through the real recorder).

Why encode at rollout rather than decode full size in training and resize raw RGB at rollout (measured on
this machine, one camera, PIL 13, libjpeg-turbo; textured 320x240 / 640x480 / 1280x720 frames to 96 px):
  rollout before (resize raw RGB)        0.6 / 1.2 / 3.1 ms per frame
  encode + draft decode (chosen)         1.0 / 2.5 / 7.3 ms per frame at rollout; frame cache unchanged
                                         (draft decode 0.5 / 1.4 / 3.9 ms per frame)
  full decode + resize (the other way)   0.9 / 2.8 / 8.3 ms per frame in the frame cache, and still not
                                         equal: the JPEG loss stays (mean |diff| 1-6 of 255 on a noisy frame)
Only the encode makes the two paths equal; it costs a few ms per camera and chunk (not per control tick),
and it leaves the training data (and so every training run's losses) as they were.
"""

from __future__ import annotations

import io
import os
from concurrent.futures import Executor, ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
import torch

from hardware.errors import ConfigError, UserError
from hardware.features import IMAGES
from policies.data.normalizer import Normalizer

CROP_SCALE = (0.8, 1.0)  # RandomResizedCrop: area share kept
CROP_RATIO = (3 / 4, 4 / 3)  # and aspect ratio range
DECODE = "jpeg-draft-bilinear"  # the one decode: JPEG DCT-scaled decode, then bilinear to size x size


# -- pure image functions ------------------------------------------------------------------------------------
def decode_resized(jpeg: bytes, size: int) -> np.ndarray:
    """A JPEG frame as the model's (size, size, 3) uint8 input: decoded at the smallest DCT scale still
    >= size (JPEG draft mode), then bilinear to size x size (the whole field of view)."""
    from PIL import Image

    im = Image.open(io.BytesIO(jpeg))
    im.draft("RGB", (size, size))  # JPEG DCT scaling: decode at the smallest scale still >= size
    return np.asarray(im.convert("RGB").resize((size, size), Image.BILINEAR))


def jpeg_settings(jpeg: bytes) -> dict:
    """The encoder settings that decide a JPEG's pixels: {"qtables": [[64 ints] per table], "subsampling":
    PIL's code (2 = 4:2:0)}. Encoding the same RGB with them (`encode_jpeg`) gives the same bytes."""
    from PIL import Image, JpegImagePlugin

    im = Image.open(io.BytesIO(jpeg))
    q = getattr(im, "quantization", None)
    if not q:
        raise ValueError("not a JPEG with quantisation tables")
    return {"qtables": [[int(v) for v in q[k]] for k in sorted(q)],
            "subsampling": int(JpegImagePlugin.get_sampling(im))}


def encode_jpeg(rgb: np.ndarray, settings: dict) -> bytes:
    """An (H, W, 3) uint8 RGB frame as a JPEG with the given `jpeg_settings`."""
    from PIL import Image

    buf = io.BytesIO()
    tables = [list(t) for t in settings["qtables"]]
    Image.fromarray(np.ascontiguousarray(rgb, np.uint8)).save(
        buf, format="JPEG", qtables=tables, subsampling=settings["subsampling"])
    return buf.getvalue()


def quality_settings(quality: int) -> dict:
    """The jpeg_settings PIL's encoder uses at `quality` (4:2:0, its default)."""
    from PIL import Image

    buf = io.BytesIO()
    Image.new("RGB", (16, 16)).save(buf, format="JPEG", quality=int(quality))
    return jpeg_settings(buf.getvalue())


def draw_crops(batch: int, gen: torch.Generator, scale=CROP_SCALE, ratio=CROP_RATIO) -> torch.Tensor:
    """RandomResizedCrop boxes (B, 4): centre x, centre y, width, height as fractions of the image."""
    u = torch.rand(batch, 4, generator=gen, dtype=torch.float64)
    area = scale[0] + u[:, 0] * (scale[1] - scale[0])
    log_r = np.log(ratio[0]) + u[:, 1] * (np.log(ratio[1]) - np.log(ratio[0]))
    r = torch.exp(log_r)
    w = torch.sqrt(area * r).clamp(max=1.0)
    h = torch.sqrt(area / r).clamp(max=1.0)
    cx = w / 2 + u[:, 2] * (1 - w)
    cy = h / 2 + u[:, 3] * (1 - h)
    return torch.stack([cx, cy, w, h], dim=1)


def crop_pool() -> Executor:
    """Threads for the crops: PIL releases the GIL while it resamples. The caller owns it (shutdown())."""
    return ThreadPoolExecutor(max_workers=min(4, os.cpu_count() or 1), thread_name_prefix="crop")


def resized_crop(img: np.ndarray, boxes: np.ndarray, pool: Executor) -> np.ndarray:
    """Crop each sample's box (the same for all its cameras) and resize it back to the full size, bilinear
    (PIL, one C call per image, on `pool`'s threads (crop_pool): ~10x faster here than grid_sample or fancy
    indexing on the whole batch). img (B, M, H, W, 3) uint8; boxes (B, 4) from draw_crops."""
    from PIL import Image

    b, m, h, w, _ = img.shape
    out = np.empty_like(img)

    def one(i: int) -> None:
        cx, cy, bw, bh = (float(v) for v in boxes[i])
        box = ((cx - bw / 2) * w, (cy - bh / 2) * h, (cx + bw / 2) * w, (cy + bh / 2) * h)
        for k in range(m):
            out[i, k] = np.asarray(Image.fromarray(img[i, k]).resize((w, h), Image.BILINEAR, box=box))

    list(pool.map(one, range(b)))
    return out


# -- the pipeline's parameters ------------------------------------------------------------------------------
@dataclass
class ImagePath:
    """Camera frame -> (size, size, 3) uint8 model input. jpeg: camera -> the recording's jpeg_settings."""

    size: int
    jpeg: dict[str, dict] = field(default_factory=dict)
    crop_scale: tuple = CROP_SCALE
    crop_ratio: tuple = CROP_RATIO
    decode: str = DECODE

    @classmethod
    def from_recordings(cls, recs, cameras: list[str], size: int) -> ImagePath:
        """The encoder settings of each camera, read from its first recorded frame in every recording
        (UserError when two recordings of a camera were encoded differently: one rollout cannot match
        both)."""
        jpeg: dict[str, dict] = {}
        for r in recs:
            for c in cameras:
                frames = r.frames(c)
                if not len(frames):
                    continue
                got = jpeg_settings(frames.jpeg(0))
                if jpeg.setdefault(c, got) != got:
                    raise UserError(f"camera {c}: the recordings were JPEG-encoded with different settings",
                                    where=str(r.path),
                                    fix="train on recordings made with one recorder setting")
        return cls(int(size), jpeg)

    def recorded(self, jpeg: bytes) -> np.ndarray:
        """A recorded frame (the JPEG as stored) as the model's input."""
        return decode_resized(jpeg, self.size)

    def live(self, camera: str, rgb: np.ndarray) -> np.ndarray:
        """A live camera's raw RGB frame as the model's input: encoded as the recording encoded this camera,
        then decoded as training decodes (so the same RGB gives the same input)."""
        return self.recorded(encode_jpeg(rgb, self.jpeg[camera]))

    def draw_crops(self, batch: int, gen: torch.Generator) -> torch.Tensor:
        return draw_crops(batch, gen, self.crop_scale, self.crop_ratio)

    def to_dict(self) -> dict:
        return {"size": self.size, "decode": self.decode, "jpeg": self.jpeg,
                "crop_scale": list(self.crop_scale), "crop_ratio": list(self.crop_ratio)}

    @classmethod
    def from_dict(cls, d: dict) -> ImagePath:
        if d.get("decode", DECODE) != DECODE:
            raise ValueError(f"image decode {d.get('decode')!r}: this version decodes {DECODE!r} only")
        return cls(int(d["size"]), {c: dict(v) for c, v in (d.get("jpeg") or {}).items()},
                   tuple(d.get("crop_scale", CROP_SCALE)), tuple(d.get("crop_ratio", CROP_RATIO)))


ACTION_FRAMES = ("absolute", "relative")  # `factr2 train --actions`: see Preprocess


def relative_columns(action_names: list[str], sizes: dict[str, int]) -> list[bool]:
    """Which action values are joint positions ([rad], ".joint.pos" features), flattened in the names'
    order: in the relative frame these are taken relative to the observed joints; grippers stay absolute."""
    return [n.endswith(".joint.pos") for n in action_names for _ in range(sizes[n])]


def to_frame(action: np.ndarray, state: np.ndarray, relative: np.ndarray) -> np.ndarray:
    """Action chunks (N, H, A) [rad, m] -> the learned frame: the `relative` columns (A,) bool minus the
    state at the observation (N, S; its first A columns are the action's: hardware.features.policy_names)."""
    offset = np.where(relative, state[:, : action.shape[2]], 0.0)
    return (action - offset[:, None, :]).astype(np.float32)


def from_frame(action: np.ndarray, state: np.ndarray, relative: np.ndarray) -> np.ndarray:
    """to_frame's inverse: (..., H, A) chunks in the learned frame + the observed state (..., S) ->
    [rad, m]."""
    offset = np.where(relative, np.asarray(state)[..., : action.shape[-1]], 0.0)
    return action + offset[..., None, :]


@dataclass
class Preprocess:
    """Normalisation and the image path: what training applied, and so what a rollout must apply.

    Actions are learned in one of two frames (ACTION_FRAMES). "absolute": joint targets [rad] as commanded,
    normalised per value over the training samples. "relative": each chunk's joint targets minus the joints
    observed at its tick (grippers absolute), normalised per chunk step and value, so the first steps' small
    corrections are on the same scale as the chunk's end: a millimetre of alignment at 0.4 m reach is 0.0025
    rad, <1 % of the absolute targets' spread, a whole unit of the early steps' (docs/first_training.md)."""

    norm: Normalizer
    image: ImagePath
    action_frame: str = "absolute"
    relative: list[bool] = field(default_factory=list)  # per action value: relative in that frame

    def targets(self, action: np.ndarray, state: np.ndarray) -> np.ndarray:
        """Training targets: action chunks (B, H, A) [rad, m] with the state at their ticks (B, S) ->
        normalised, in the learned frame."""
        if self.action_frame == "absolute":
            return self.norm.norm("action", action)
        z = to_frame(action, state, np.asarray(self.relative))
        return self.norm.norm("action", z.reshape(len(z), -1)).reshape(z.shape)

    def inputs(self, state: np.ndarray, force: np.ndarray | None = None, objects: np.ndarray | None = None,
               images: np.ndarray | None = None, crops: torch.Tensor | None = None,
               pool: Executor | None = None) -> dict:
        """The model's input batch (training and rollout alike): state (B, S) [rad, m]; force (B, F) [N*m] or
        [A], NaN (no estimate yet) as 0; objects (B, O) PRIVILEGED vector; images (B, M, size, size, 3)
        uint8 from `recorded` / `live` (the model converts them); crops (B, 4) training's RandomResizedCrop
        boxes (ImagePath.draw_crops) or None, cropped on `pool` (crop_pool; its owner shuts it down)."""
        n = self.norm
        out = {"state": torch.from_numpy(n.norm("state", state))}
        if images is not None:
            img = resized_crop(images, crops.numpy(), pool) if crops is not None else images
            out["images"] = torch.from_numpy(img)
        if objects is not None:
            out["objects"] = torch.from_numpy(n.norm("objects", objects))
        if force is not None and force.shape[1]:
            out["force"] = torch.from_numpy(n.norm("force", np.nan_to_num(force)))
        return out

    def actions(self, z, state=None):
        """Normalised model output (H, A) -> actions in their units ([rad], [m]); state (S,): the
        observation's joints and grippers, needed in the relative frame."""
        if self.action_frame == "absolute":
            return self.norm.denorm("action", z)
        z = np.asarray(z)
        a = self.norm.denorm("action", z.reshape(*z.shape[:-2], -1)).reshape(z.shape)
        return from_frame(a, state, np.asarray(self.relative))

    def to_dict(self) -> dict:
        out = {"normalizer": self.norm.to_dict(), "image": self.image.to_dict()}
        if self.action_frame != "absolute":  # absent: absolute, as every checkpoint before the choice
            out |= {"action_frame": self.action_frame, "relative": list(self.relative)}
        return out

    @classmethod
    def from_meta(cls, meta: dict) -> Preprocess:
        """From a checkpoint's JSON. Checkpoints written before the pipeline was saved hold only the
        normaliser: their frames came from the recorder at its one quality (JPEG_QUALITY), 4:2:0."""
        try:
            if "preprocess" in meta:
                d = meta["preprocess"]
                frame = d.get("action_frame", "absolute")
                if frame not in ACTION_FRAMES:
                    raise ValueError(f"action frame {frame!r}")
                return cls(Normalizer.from_dict(d["normalizer"]), ImagePath.from_dict(d["image"]), frame,
                           [bool(v) for v in d.get("relative", [])])
            from hardware.recording.writer import JPEG_QUALITY

            cams = [n[len(IMAGES):] for n in meta["features"].get("observation.images") or []]
            old = quality_settings(JPEG_QUALITY)
            return cls(Normalizer.from_dict(meta["normalizer"]),
                       ImagePath(int(meta["policy"]["image_size"]), {c: old for c in cams}))
        except (KeyError, TypeError, ValueError) as e:
            raise ConfigError(f"preprocessing unreadable ({type(e).__name__}: {str(e)[:80]})",
                              where=str(meta.get("_path", "checkpoint")),
                              fix="pass a checkpoint written by factr2 train") from None
