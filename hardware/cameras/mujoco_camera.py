"""Offscreen MuJoCo camera for twins, headless on CPU.

OpenGL: offscreen_gl.make_renderer (MUJOCO_GL if set, else EGL, then OSMesa; one CameraError line without).
Thread rule: read() renders from the attached MjData; call it from the thread that steps the simulation
(between steps), never concurrently with mj_step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hardware.cameras.base import Camera, CameraConfig, CameraError
from hardware.cameras.offscreen_gl import make_renderer
from hardware.clock import Clock

# Twin cameras render on the CPU (Mesa llvmpipe) where there is no GPU: with the MJCF's 4096 px shadow map
# and 4x MSAA a 320x240 frame took 80 ms on the 2-core dev VM, 1024 px shadows and no MSAA 11 ms, no shadows
# and no MSAA 4 ms. Twin cameras draw without either (the render process turns shadows off in its model
# copy), so task collection with two cameras stays faster than real time beside another busy process.
TWIN_MSAA_SAMPLES = 0


@dataclass
class MujocoCameraConfig(CameraConfig):
    """camera: name of an MJCF <camera> ("" or -1: the free default camera)."""

    camera: str = ""


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
        self._check_camera()
        self._renderer, self.backend = make_renderer(self.model, self.config.width, self.config.height)

    def _check_camera(self) -> None:
        """CameraError when the MJCF has no such camera; grows the offscreen buffer to the frame size."""
        cam = self.config.camera
        if cam not in ("", "-1"):
            import mujoco

            if mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_CAMERA, cam) < 0:
                raise CameraError(f"model has no camera {cam!r}", where=f"camera {self.name}",
                                  fix="use a <camera name=...> from the MJCF or '' for the free camera")
        g = self.model.vis.global_
        g.offwidth, g.offheight = max(self.config.width, g.offwidth), max(self.config.height, g.offheight)

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


@dataclass
class WorldSnapshot:
    """The physics state a frame shows: copied under the world's lock (microseconds), rendered later on the
    camera's own thread. t: rig clock time of the state [s]."""

    t: float
    qpos: np.ndarray
    qvel: np.ndarray
    mocap_pos: np.ndarray
    mocap_quat: np.ndarray
    gone: bool = False  # SIMULATED: the camera is unplugged; rendering it fails


class TwinCamera(MujocoCamera):
    """A camera on a twin world, rendered in a process of its own (render_process.py: MuJoCo's renderer holds
    the GIL while it draws). snapshot(t) copies the physics state (the stepping thread, microseconds);
    render(snapshot) draws it there; read() does both now (for a UI)."""

    def __init__(self, config: MujocoCameraConfig, world, clock: Clock | None = None):
        super().__init__(config, world.model, world.data, clock)
        self.world = world
        self._proc = None
        self._frozen: WorldSnapshot | None = None  # the state a frozen camera keeps showing
        q = world.model.vis.quality  # visual only: physics does not read it
        q.offsamples = min(int(q.offsamples), TWIN_MSAA_SAMPLES)

    def connect(self) -> None:
        if self._proc is not None:
            return
        import pickle

        from hardware.cameras.render_process import RenderProcess

        self._check_camera()
        cam = self.config.camera

        with self.world.lock:  # a consistent copy (~1 ms); the process starts without the lock
            blob = pickle.dumps(self.model)
        self._proc = RenderProcess(blob, [(self.name, cam, self.config.width, self.config.height)])
        self.backend = "process"

    def disconnect(self) -> None:
        if self._proc is not None:
            self._proc.close()
            self._proc = None

    @property
    def is_connected(self) -> bool:
        return self._proc is not None

    def _grab(self) -> np.ndarray:
        return self.render(self.snapshot(self.clock.now()))

    def snapshot(self, t: float) -> WorldSnapshot:
        """The state the frame at t shows. The twin's camera faults (world.camera_fault): "freeze" hands
        out the frame the freeze began with again, its timestamp included (a hung driver's last buffer),
        "gone" marks the snapshot so that render() fails."""
        d, fault = self.world.data, self.world.camera_fault
        if fault == "freeze" and self._frozen is not None:
            return self._frozen
        with self.world.lock:
            snap = WorldSnapshot(float(t), d.qpos.copy(), d.qvel.copy(), d.mocap_pos.copy(),
                                 d.mocap_quat.copy(), gone=fault == "gone")
        self._frozen = snap if fault == "freeze" else None
        return snap

    def render(self, snap: WorldSnapshot) -> np.ndarray:
        """An H x W x 3 uint8 frame of a snapshot (call from one thread at a time)."""
        if snap.gone:
            raise CameraError("no frame: the camera is gone (SIMULATED unplug)", where=f"camera {self.name}",
                              fix="check the camera's cable; it is used again when it answers")
        return self._proc.render(0, snap)
