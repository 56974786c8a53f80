"""MuJoCo's offscreen renderer with a working OpenGL backend, for twin cameras (mujoco_camera.py) and their
render process (render_process.py), which both import it from here.

Backend: MUJOCO_GL if set, else EGL, then OSMesa (Mesa's software renderers work without a GPU or display).
It is chosen per renderer, so it works even when mujoco was imported before. With no usable GL,
make_renderer fails with one CameraError line naming the Debian packages to install.
"""

from __future__ import annotations

import importlib
import os

from hardware.cameras.base import CameraError

GL_PACKAGES = "sudo apt-get install -y libegl1 libgl1 libgles2 (EGL, Mesa) or libosmesa6 (OSMesa)"


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
