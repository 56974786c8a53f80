"""Cameras: a small base class (connect / read / disconnect), an offscreen MuJoCo renderer for twins and an
optional OpenCV backend for real cameras. Frames are H x W x 3 uint8 RGB; Recorder.log_image() takes them."""

from hardware.cameras.base import Camera, CameraConfig, CameraError, Frame

__all__ = ["Camera", "CameraConfig", "CameraError", "Frame"]
