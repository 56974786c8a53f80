"""Cameras: offscreen MuJoCo rendering (headless EGL/OSMesa), the one-line no-GL error, OpenCV lazily."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from hardware.cameras import CameraConfig, CameraError, offscreen_gl
from hardware.cameras import mujoco_camera as mc
from hardware.cameras.opencv_camera import OpenCVCamera, OpenCVCameraConfig
from hardware.clock import LockstepClock
from hardware.recording import Recorder, Recording

SCENE = """<mujoco><visual><global offwidth="64" offheight="48"/></visual><worldbody>
<light pos="0 0 3"/><camera name="top" pos="0 0 1"/>
<geom type="sphere" size=".2" rgba="1 0 0 1"/></worldbody></mujoco>"""


@pytest.fixture
def sim():
    mujoco = pytest.importorskip("mujoco")
    m = mujoco.MjModel.from_xml_string(SCENE)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    return m, d


def _camera(sim, **kw):
    m, d = sim
    cam = mc.MujocoCamera(mc.MujocoCameraConfig("top", width=64, height=48, camera="top", **kw), m, d,
                          clock=LockstepClock(2.5))
    try:
        cam.connect()
    except CameraError as e:  # the only reason to skip: this machine has no GL at all
        pytest.skip(f"no offscreen OpenGL here: {e}")
    return cam


def test_mujoco_camera_renders_the_scene(sim):
    cam = _camera(sim)
    try:
        f = cam.read()
        assert f.camera == "top" and f.t == 2.5 and f.rgb.shape == (48, 64, 3) and f.rgb.dtype == np.uint8
        r, g, b = f.rgb[24, 32].astype(int)
        assert r > 100 and r > 2 * g and r > 2 * b  # the red sphere under the camera
        assert f.rgb[0, 0].max() < r  # corners see the dark background
        assert cam.backend in ("egl", "osmesa", "glfw")
    finally:
        cam.disconnect()
    assert not cam.is_connected


def test_rendered_frames_record_and_read_back(sim, tmp_path):
    cam = _camera(sim)
    path = tmp_path / "cam.mcap"
    rec = Recorder(path, t0=0.0)
    frames = [cam.read() for _ in range(3)]
    for i, f in enumerate(frames):
        rec.log_image(f.camera, i / 30, f.rgb)
    assert rec.close().frames_written == 3
    cam.disconnect()
    got = Recording(path).frames("top")
    assert len(got) == 3
    assert np.abs(got.rgb(2).astype(int) - frames[2].rgb).mean() < 4


def test_no_gl_is_one_clear_line(sim, monkeypatch):
    m, d = sim
    monkeypatch.setattr(offscreen_gl, "gl_backends", lambda: ["no_such_gl"])
    cam = mc.MujocoCamera(mc.MujocoCameraConfig("x", width=64, height=48), m, d)
    with pytest.raises(CameraError) as err:
        cam.connect()
    msg = str(err.value)
    assert "no OpenGL" in msg and "apt-get install" in msg and "MUJOCO_GL" in msg and "\n" not in msg


def test_unknown_mjcf_camera(sim):
    m, d = sim
    with pytest.raises(CameraError, match="no camera 'nope'"):
        mc.MujocoCamera(mc.MujocoCameraConfig("x", camera="nope"), m, d).connect()


def test_config_validation_and_read_before_connect(sim):
    with pytest.raises(ValueError):
        CameraConfig("a/b")
    with pytest.raises(ValueError):
        CameraConfig("a", width=0)
    m, d = sim
    with pytest.raises(CameraError, match="not connected"):
        mc.MujocoCamera(mc.MujocoCameraConfig("x"), m, d).read()


def test_opencv_missing_is_a_camera_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "cv2", None)  # import cv2 -> ImportError
    with pytest.raises(CameraError, match="OpenCV is not installed"):
        OpenCVCamera(OpenCVCameraConfig("webcam", device="0")).connect()
