"""Camera frames decoded once into a uint8 array at the model's input size, cached in the user's cache
folder, not beside the recording: derived_dir(RECORDING, "policy-frames")/<camera>-<size>.npy (N, size, size,
3) and its key (the MCAP's size, mtime and head/tail hash, as the array cache uses). Training reads it
memory-mapped: never a JPEG decode per sample.

Frames are decoded by policies.data.preprocess.decode_resized, the one decode a rollout's live frames go
through too (size x size whole: the aspect ratio is not kept, the full field of view stays in the image;
RandomResizedCrop then works on that). Written to a temporary name and renamed: never half a cache.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import numpy as np

from hardware.recording.cache import cache_key, derived_dir
from hardware.recording.reader import Recording
from policies.data.preprocess import decode_resized


def cache_folder(path: Path) -> Path:
    return derived_dir(path, "policy-frames")  # the user's cache folder, not their data folder


def camera_frames(rec: Recording, camera: str, size: int, progress=None) -> np.ndarray:
    """(N, size, size, 3) uint8 frames of `camera` (all of the recording's, in time order), memory-mapped
    from the cache; decoded and cached first when the cache is missing or stale."""
    folder = cache_folder(rec.path)
    arr_path, key_path = folder / f"{camera}-{size}.npy", folder / f"{camera}-{size}.json"
    key = cache_key(rec.path)
    try:
        if json.loads(key_path.read_text()) == key:
            return np.load(arr_path, mmap_mode="r")
    except (OSError, ValueError):
        pass
    frames = rec.frames(camera)
    out = np.empty((len(frames), size, size, 3), np.uint8)
    for i in range(len(frames)):
        out[i] = decode_resized(frames.jpeg(i), size)
        if progress is not None:
            progress(1)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return out  # no cache folder: the frames are decoded anyway, just not kept
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=f".{camera}-{size}.", suffix=".npy")
    try:
        with os.fdopen(fd, "wb") as f:
            np.save(f, out)
        os.replace(tmp, arr_path)
        key_path.write_text(json.dumps(key))
    except OSError:
        Path(tmp).unlink(missing_ok=True)
        return out  # read-only folder: the frames are decoded anyway, just not kept
    return np.load(arr_path, mmap_mode="r")
