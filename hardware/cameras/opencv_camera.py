"""Real cameras through OpenCV (optional: pip install 'factr2-teleop[opencv]'); cv2 is imported lazily."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hardware.cameras.base import Camera, CameraConfig, CameraError
from hardware.clock import Clock


@dataclass
class OpenCVCameraConfig(CameraConfig):
    """device: a /dev/videoN path or an index (as a string, e.g. "0")."""

    device: str = "0"


def _cv2():
    try:
        import cv2
    except ImportError:
        raise CameraError("OpenCV is not installed", where="opencv camera",
                          fix="pip install 'factr2-teleop[opencv]' (opencv-python-headless)") from None
    return cv2


class OpenCVCamera(Camera):
    def __init__(self, config: OpenCVCameraConfig, clock: Clock | None = None):
        super().__init__(config, clock)
        self._cap = None

    def connect(self) -> None:
        cv2 = _cv2()
        dev = self.config.device
        cap = cv2.VideoCapture(int(dev) if dev.isdigit() else dev)
        if not cap.isOpened():
            raise CameraError("cannot open camera", where=f"camera {self.name} ({dev})",
                              fix="check the device exists (ls /dev/video*) and no other program uses it")
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.config.width)
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.config.height)
        cap.set(cv2.CAP_PROP_FPS, self.config.fps)
        self._cap = cap

    def _grab(self) -> np.ndarray:
        ok, bgr = self._cap.read()
        if not ok or bgr is None:
            raise CameraError("no frame", where=f"camera {self.name} ({self.config.device})",
                              fix="check the cable; the camera stopped delivering frames")
        return np.ascontiguousarray(bgr[:, :, ::-1])

    def disconnect(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None

    @property
    def is_connected(self) -> bool:
        return self._cap is not None
