"""One camera of a LeRobotDataset export: its frames as one H.264 mp4 (every exported frame, episodes back to
back), the per-channel image statistics LeRobot normalises with, and its info.json feature."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import numpy as np

VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"


def _even(x: int) -> int:
    return x - (x % 2)  # yuv420p needs even sides


class CameraVideo:
    """Frames of camera `cam` -> `root`/videos/observation.images.<cam>/chunk-000/file-000.mp4."""

    def __init__(self, root: Path, cam: str, first_rgb: np.ndarray, fps: int):
        import av

        self.cam, self.fps = cam, fps
        self.key = f"observation.images.{cam}"
        self.h, self.w = _even(first_rgb.shape[0]), _even(first_rgb.shape[1])
        path = Path(root) / VIDEO_PATH.format(video_key=self.key, chunk_index=0, file_index=0)
        path.parent.mkdir(parents=True, exist_ok=True)
        self._out = av.open(str(path), "w")
        st = self._out.add_stream("libx264", rate=Fraction(fps, 1))
        st.width, st.height, st.pix_fmt = self.w, self.h, "yuv420p"
        st.time_base = Fraction(1, fps)
        st.options = {"g": "2", "crf": "23"}  # short GOP: LeRobot seeks to single frames
        self._st = st
        self._sum = np.zeros((3, 3))  # per channel: sum, sum of squares, count
        self._min, self._max = np.full(3, np.inf), np.full(3, -np.inf)

    def add(self, frames, frame_idx: np.ndarray, first_pts: int) -> None:
        """Encode the recording's frames frame_idx[k] as video frames first_pts + k (a frame repeated when
        the camera had no newer one)."""
        import av

        last, img = -1, None
        for k, fi in enumerate(frame_idx):
            if fi != last:
                last = int(fi)
                img = frames.rgb(last)[: self.h, : self.w]
                f = img.reshape(-1, 3).astype(np.float64) / 255.0
                self._sum += [f.sum(0), (f * f).sum(0), np.full(3, len(f))]
                self._min, self._max = np.minimum(self._min, f.min(0)), np.maximum(self._max, f.max(0))
            vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="rgb24")
            vf.pts = first_pts + k
            for pkt in self._st.encode(vf):
                self._out.mux(pkt)

    def close(self) -> None:
        for pkt in self._st.encode():
            self._out.mux(pkt)
        self._out.close()

    def episode_columns(self, t_from: float, n: int) -> dict:
        """meta/episodes columns locating an episode of n frames starting at t_from [s] in the video."""
        k = self.key
        return {f"videos/{k}/chunk_index": 0, f"videos/{k}/file_index": 0,
                f"videos/{k}/from_timestamp": t_from, f"videos/{k}/to_timestamp": t_from + n / self.fps}

    def feature(self) -> dict:
        return {
            "dtype": "video",
            "shape": [self.h, self.w, 3],
            "names": ["height", "width", "channels"],
            "info": {
                "video.height": self.h,
                "video.width": self.w,
                "video.codec": "h264",
                "video.pix_fmt": "yuv420p",
                "video.is_depth_map": False,
                "video.fps": self.fps,
                "video.channels": 3,
                "has_audio": False,
            },
        }

    def stats(self) -> dict:
        s, ss, cnt = self._sum
        mean = s / np.maximum(cnt, 1)
        std = np.sqrt(np.maximum(ss / np.maximum(cnt, 1) - mean**2, 0))

        def col(v):  # LeRobot's (3, 1, 1) per channel
            return [[[float(x)]] for x in v]

        return {"mean": col(mean), "std": col(std), "min": col(self._min), "max": col(self._max),
                "count": [int(cnt[0])]}
