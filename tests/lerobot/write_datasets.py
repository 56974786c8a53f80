"""Write small LeRobotDataset v3 folders with LeRobot's own writer (LeRobotDataset.create / add_frame /
save_episode / finalize), for tests/test_import_lerobot.py. Run with the Python that has LeRobot 0.6.x
(a separate 3.12 environment): `python write_datasets.py OUT_DIR`. Not imported by the test suite.

    effort_video/   a 6-joint arm + gripper (names "joint1.pos" ... "gripper.pos", radians), action,
                    observation.effort (7, N*m), one camera as a video feature; contact pushes in the effort
    noforce_video/  the same without effort (no force-like feature)
    state_only/     state and action only (no images, no force)
    images_png/     effort and one camera stored as images (use_videos=False)
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from lerobot.datasets.lerobot_dataset import LeRobotDataset

FPS = 10
NAMES = [f"joint{i + 1}.pos" for i in range(6)] + ["gripper.pos"]
H, W = 32, 40


def frame_image(k: int) -> np.ndarray:
    img = np.full((H, W, 3), 60, np.uint8)
    x = (k * 2) % (W - 8)
    img[8:20, x : x + 8] = 240  # a bright square that moves with the frame index
    return img


def write(root: Path, *, effort: bool, camera: str | None, episodes: int = 3, seconds: float = 4.0) -> None:
    features = {
        "observation.state": {"dtype": "float32", "shape": (7,), "names": NAMES},
        "action": {"dtype": "float32", "shape": (7,), "names": NAMES},
    }
    if effort:
        features["observation.effort"] = {"dtype": "float32", "shape": (7,), "names": NAMES}
    if camera:
        features["observation.images.wrist"] = {"dtype": camera, "shape": (H, W, 3),
                                                "names": ["height", "width", "channels"]}
    ds = LeRobotDataset.create("local/test", fps=FPS, features=features, root=root, robot_type="piper",
                               use_videos=camera == "video")
    rng = np.random.default_rng(0)
    for e in range(episodes):
        n = int(seconds * FPS)
        for k in range(n):
            t = k / FPS
            q = 0.4 * np.sin(0.9 * t + e + np.arange(6))
            state = np.r_[q, 0.02 + 0.01 * np.sin(t)].astype(np.float32)
            q_next = 0.4 * np.sin(0.9 * (t + 1 / FPS) + e + np.arange(6))
            frame = {"observation.state": state,
                     "action": np.r_[q_next, 0.02 + 0.01 * np.sin(t + 1 / FPS)].astype(np.float32),
                     "task": "push the block"}
            if effort:
                push = 3.0 if 1.5 <= t < 2.5 else 0.0  # a contact of 1 s in every episode [N*m]
                frame["observation.effort"] = np.r_[0.2 * q + push + rng.normal(0, 0.01, 6), 0.1].astype(
                    np.float32)
            if camera:
                frame["observation.images.wrist"] = frame_image(k)
            ds.add_frame(frame)
        ds.save_episode()
    ds.finalize()


def main(out: str) -> None:
    out = Path(out)
    write(out / "effort_video", effort=True, camera="video")
    write(out / "noforce_video", effort=False, camera="video")
    write(out / "state_only", effort=False, camera=None)
    write(out / "images_png", effort=True, camera="image")


if __name__ == "__main__":
    main(sys.argv[1])
