"""Twin cameras render in a process of their own: MuJoCo's renderer holds the GIL while it rasterises
(Mesa's llvmpipe on a machine without a GPU takes ~10 ms per 320x240 frame), which stalled a 500 Hz control
loop in the same process by that much (measured: p99 of a 0.5 ms sleep loop 0.65 ms alone, 5.7-7.4 ms
beside a render thread, 35 ms with llvmpipe on the calling thread). Here the control process only copies
the physics state (WorldSnapshot) and waits on a pipe (GIL released) while the render process draws it into
shared memory.

    rp = RenderProcess(pickle.dumps(model), [("scene", "front", 320, 240)])   # starts, loads, opens GL
    rgb = rp.render(0, snapshot)                                 # H x W x 3 uint8 (a copy)
    rp.close()
"""

from __future__ import annotations

import mmap
import os
import pickle
import secrets
import shutil
import subprocess
import sys
import tempfile
import threading
from multiprocessing.connection import Client, Listener

import numpy as np

from hardware.cameras.base import CameraError
from hardware.realtime import spawn_normal

START_TIMEOUT_S = 30.0  # a cold start imports mujoco and opens an OpenGL context
RENDER_TIMEOUT_S = 5.0
RASTER_THREADS = 1  # Mesa llvmpipe threads in the render process (LP_NUM_THREADS)
# The render process runs at normal priority, not niced: a frame needs a fair share against a busy process
# (~10 ms of llvmpipe per 320x240 frame: 30 % of a core at 30 Hz; niced by 10 it got ~10 % beside a busy
# process and dropped frames), and not real time (see RenderProcess).


def _serve(conn) -> None:
    """The render process: one renderer per camera, requests (index, snapshot arrays) -> frame in its
    shared file mapping."""
    import mujoco

    blob, cams, paths = conn.recv()
    model = pickle.loads(blob)
    model.light_castshadow[:] = 0  # this copy only draws: no shadow pass (mujoco_camera.TWIN_MSAA_SAMPLES)
    from hardware.cameras.offscreen_gl import make_renderer

    try:
        data = mujoco.MjData(model)
        renderers, views, maps = [], [], []
        for (_name, _cam, w, h), path in zip(cams, paths):
            r, _backend = make_renderer(model, w, h)
            renderers.append(r)
            with open(path, "r+b") as f:
                maps.append(mmap.mmap(f.fileno(), h * w * 3))
            views.append(np.ndarray((h, w, 3), np.uint8, buffer=maps[-1]))
        conn.send(("ready", ""))
    except Exception as e:  # noqa: BLE001 -- reported to the parent as one line
        conn.send(("error", f"{type(e).__name__}: {e}"))
        return
    while True:
        try:
            req = conn.recv()
        except EOFError:
            break
        if req is None:
            break
        i, qpos, qvel, mocap_pos, mocap_quat = req
        try:
            data.qpos[:], data.qvel[:] = qpos, qvel
            data.mocap_pos[:], data.mocap_quat[:] = mocap_pos, mocap_quat
            mujoco.mj_kinematics(model, data)
            mujoco.mj_camlight(model, data)
            cam = cams[i][1]
            renderers[i].update_scene(data, camera=cam if cam not in ("", "-1") else -1)
            views[i][...] = renderers[i].render()
            conn.send(("ok", ""))
        except Exception as e:  # noqa: BLE001
            conn.send(("error", f"{type(e).__name__}: {e}"))
    for r in renderers:
        r.close()
    views.clear()
    for m in maps:
        m.close()


class RenderProcess:
    """cams: (name, MJCF camera, width, height) per camera; render(i, snapshot) from ONE thread at a time."""

    def __init__(self, model_pickle: bytes, cams: list[tuple[str, str, int, int]]):
        self.cams = list(cams)
        # Frames come back through a file mapping both processes share (tmpfs where there is one): no
        # multiprocessing.shared_memory, whose resource tracker needs a real stderr (a terminal UI has none)
        base = "/dev/shm" if os.path.isdir("/dev/shm") and os.access("/dev/shm", os.W_OK) else None
        self._dir = tempfile.mkdtemp(prefix="factr2-render-", dir=base)
        self._paths, self._maps, self._views = [], [], []
        for k, (_n, _c, w, h) in enumerate(self.cams):
            path = os.path.join(self._dir, f"frame{k}")
            with open(path, "w+b") as f:
                f.truncate(h * w * 3)
                self._maps.append(mmap.mmap(f.fileno(), h * w * 3))
            self._paths.append(path)
            self._views.append(np.ndarray((h, w, 3), np.uint8, buffer=self._maps[-1]))
        # A new interpreter (`python -m`), not multiprocessing's spawn: spawn re-runs the user's __main__
        # script in the child, and a fork would copy threads and GL state. A Unix socket with a one-time key.
        addr, key = os.path.join(self._dir, "sock"), secrets.token_bytes(16)
        self._conn = self._proc = self._log = None
        listener = Listener(addr, family="AF_UNIX", authkey=key)
        try:
            # Below the control loop: a frame may wait (it carries the time of the state it shows), a tick
            # may not. One rasteriser thread: llvmpipe's default (one per core) took the loop's core.
            env = dict(os.environ, FACTR2_RENDER_ADDR=addr, FACTR2_RENDER_KEY=key.hex(),
                       LP_NUM_THREADS=os.environ.get("LP_NUM_THREADS", str(RASTER_THREADS)))
            # its output goes to a log file (the caller's stdout/stderr may be no real file: a terminal UI)
            self._log = open(os.path.join(self._dir, "render.log"), "wb")  # noqa: SIM115 (closed in close())
            self._proc = spawn_normal([sys.executable, "-m", "hardware.cameras.render_process"], env=env,
                                          stdin=subprocess.DEVNULL, stdout=self._log, stderr=self._log,
                                          close_fds=True)
            # Not raised to real time with the loop (it was, as a helper): a real-time process that renders
            # for ~10 ms on the other CPU starves the kernel's normal-priority workers there (the tty work
            # behind the leader's serial port among them) and the loop waited for its leader. Measured on
            # the 2-vCPU VM, teleop recording + scene camera, 30 s: p99 period 4.0 / 6.5 / 8.3 ms raised
            # (quiet / beside a busy process / beside a training) against 2.2 / 2.5 / 2.4 ms at normal
            # priority, frames 98.0-97.8 % against 97.3-96.5 % (docs/benchmarks.md, issue #37).
            box: dict = {}
            th = threading.Thread(target=lambda: box.setdefault("conn", listener.accept()), daemon=True)
            th.start()
            th.join(START_TIMEOUT_S)
            listener.close()
            if "conn" not in box:
                raise CameraError(f"the render process did not start ({self._log_tail()})",
                                  where="twin cameras",
                                  fix="check that `python -m hardware.cameras.render_process` runs")
            self._conn = box["conn"]
            self._conn.send((model_pickle, self.cams, self._paths))
            if not self._conn.poll(START_TIMEOUT_S):
                raise CameraError("the render process did not start", where="twin cameras",
                                  fix="check that MuJoCo can render offscreen (MUJOCO_GL=egl or osmesa)")
            kind, msg = self._conn.recv()
            if kind != "ready":
                raise CameraError(f"twin cameras cannot render: {msg}", where="twin cameras",
                                  fix="install EGL or OSMesa (libegl1 / libosmesa6) and set MUJOCO_GL")
        except BaseException:
            self.close()
            raise

    def _log_tail(self) -> str:
        try:
            text = open(os.path.join(self._dir, "render.log"), errors="replace").read().strip()
        except OSError:
            return "no log"
        return text.splitlines()[-1] if text else "no output"

    def render(self, i: int, snap) -> np.ndarray:
        self._conn.send((i, snap.qpos, snap.qvel, snap.mocap_pos, snap.mocap_quat))
        if not self._conn.poll(RENDER_TIMEOUT_S):
            raise CameraError("the render process stopped answering", where=f"camera {self.cams[i][0]}",
                              fix="close the rig and open it again (restart the app)")
        kind, msg = self._conn.recv()
        if kind != "ok":
            raise CameraError(f"render failed: {msg}", where=f"camera {self.cams[i][0]}",
                              fix="see the message")
        return self._views[i].copy()

    def close(self) -> None:
        try:
            if self._conn is not None:
                self._conn.send(None)
            if self._proc is not None:
                try:
                    self._proc.wait(2.0)
                except subprocess.TimeoutExpired:
                    self._proc.kill()
        except Exception:  # noqa: BLE001 -- closing must reach the shared memory
            if self._proc is not None:
                self._proc.kill()
        self._conn = self._proc = None
        self._views = []
        for m in self._maps:
            m.close()
        self._maps = []
        if self._log is not None:
            self._log.close()
        shutil.rmtree(self._dir, ignore_errors=True)


if __name__ == "__main__":  # the render process (RenderProcess starts it)
    _serve(Client(os.environ["FACTR2_RENDER_ADDR"], family="AF_UNIX",
                  authkey=bytes.fromhex(os.environ["FACTR2_RENDER_KEY"])))
