"""Offscreen MuJoCo camera for twins, headless on CPU.

OpenGL backend: MUJOCO_GL if set, else EGL, then OSMesa (Mesa's software renderers work without a GPU or
display). The backend is chosen per renderer, so it works even when mujoco was imported before. With no
usable GL the camera fails with one CameraError line naming the Debian packages to install.
Thread rule: read() renders from the attached MjData; call it from the thread that steps the simulation
(between steps), never concurrently with mj_step.
"""

from __future__ import annotations

import importlib
import os
from dataclasses import dataclass

import numpy as np

from hardware.cameras.base import Camera, CameraConfig, CameraError
from hardware.clock import Clock

GL_PACKAGES = "sudo apt-get install -y libegl1 libgl1 libgles2 (EGL, Mesa) or libosmesa6 (OSMesa)"


@dataclass
class MujocoCameraConfig(CameraConfig):
    """camera: name of an MJCF <camera> ("" or -1: the free default camera)."""

    camera: str = ""


def gl_backends() -> list[str]:
    explicit = os.environ.get("MUJOCO_GL", "").strip().lower()
    return [explicit] if explicit in ("egl", "osmesa", "glfw") else ["egl", "osmesa"]


def _gl_context_module():
    try:
        return importlib.import_module("mujoco.rendering.classic.gl_context")
    except ImportError:
        return importlib.import_module("mujoco.gl_context")


def make_renderer(model, width: int, height: int):
    """-> (mujoco.Renderer, backend name). Tries gl_backends() in order; CameraError when none works."""
    try:
        import mujoco

        glc = _gl_context_module()
    except Exception as e:  # e.g. MUJOCO_GL=osmesa without libOSMesa breaks `import mujoco` itself
        raise CameraError(f"MuJoCo cannot load its OpenGL backend ({type(e).__name__}: {e})",
                          where=f"MUJOCO_GL={os.environ.get('MUJOCO_GL', '')}", fix=GL_PACKAGES) from None
    errors = []
    for backend in gl_backends():
        saved = getattr(glc, "GLContext", None)
        try:
            glc.GLContext = importlib.import_module(f"mujoco.{backend}").GLContext
            renderer = mujoco.Renderer(model, height=height, width=width)
            return renderer, backend
        except Exception as e:  # ImportError, OSError, mujoco.FatalError, RuntimeError from GL loaders
            errors.append(f"{backend}: {str(e).splitlines()[0] if str(e) else type(e).__name__}")
        finally:
            glc.GLContext = saved
    raise CameraError(f"no OpenGL for offscreen rendering ({'; '.join(errors)})", where="MuJoCo camera",
                      fix=f"{GL_PACKAGES}, then set MUJOCO_GL=egl or MUJOCO_GL=osmesa")


class MujocoCamera(Camera):
    """Renders `config.camera` of a MuJoCo model from `data` (an MjData the caller keeps stepping)."""

    def __init__(self, config: MujocoCameraConfig, model, data, clock: Clock | None = None):
        super().__init__(config, clock)
        self.model, self.data = model, data
        self._renderer = None
        self.backend = ""

    def connect(self) -> None:
        if self._renderer is not None:
            return
        cam = self.config.camera
        if cam not in ("", "-1"):
            import mujoco

            if mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_CAMERA, cam) < 0:
                raise CameraError(f"model has no camera {cam!r}", where=f"camera {self.name}",
                                  fix="use a <camera name=...> from the MJCF or '' for the free camera")
        w, h = self.config.width, self.config.height
        if w > self.model.vis.global_.offwidth or h > self.model.vis.global_.offheight:
            self.model.vis.global_.offwidth = max(w, self.model.vis.global_.offwidth)
            self.model.vis.global_.offheight = max(h, self.model.vis.global_.offheight)
        self._renderer, self.backend = make_renderer(self.model, w, h)

    def _grab(self) -> np.ndarray:
        cam = self.config.camera
        self._renderer.update_scene(self.data, camera=cam if cam not in ("", "-1") else -1)
        return self._renderer.render()  # a new H x W x 3 uint8 array

    def disconnect(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    @property
    def is_connected(self) -> bool:
        return self._renderer is not None
