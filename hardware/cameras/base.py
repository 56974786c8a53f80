"""Camera interface (LeRobot-like): one config dataclass, connect / read / disconnect, RGB frames."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from hardware.clock import Clock
from hardware.errors import DeviceError


class CameraError(DeviceError):
    """A camera cannot be opened or stopped delivering frames (one line: what, where, fix)."""


@dataclass
class CameraConfig:
    """name: label in recordings (topic /camera/<name>/image); width x height [px]; fps [Hz] target rate."""

    name: str
    width: int = 640
    height: int = 480
    fps: float = 30.0

    def __post_init__(self):
        if not self.name or "/" in self.name:
            raise ValueError(f"camera name {self.name!r} must be non-empty without '/'")
        if self.width <= 0 or self.height <= 0 or self.fps <= 0:
            raise ValueError(f"camera {self.name}: width, height and fps must be positive")


@dataclass
class Frame:
    """t: rig clock time of the capture [s]; rgb: H x W x 3 uint8 (a new array per frame)."""

    camera: str
    t: float
    rgb: np.ndarray


class Camera(ABC):
    def __init__(self, config: CameraConfig, clock: Clock | None = None):
        self.config = config
        self.clock = clock or Clock()

    @property
    def name(self) -> str:
        return self.config.name

    @abstractmethod
    def connect(self) -> None:
        """Open the device (or GL context); raises CameraError with a fix."""

    @abstractmethod
    def _grab(self) -> np.ndarray:
        """One H x W x 3 uint8 RGB frame."""

    @abstractmethod
    def disconnect(self) -> None: ...

    @property
    @abstractmethod
    def is_connected(self) -> bool: ...

    def read(self) -> Frame:
        """Capture one frame now, stamped with the rig clock."""
        if not self.is_connected:
            raise CameraError(f"camera {self.name} is not connected", fix="call connect() first")
        t = self.clock.now()
        return Frame(self.name, t, self._grab())

    def __enter__(self) -> Camera:
        self.connect()
        return self

    def __exit__(self, *exc) -> None:
        self.disconnect()
