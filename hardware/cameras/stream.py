"""Camera capture beside a control loop: every camera of a session at its rate, on threads of its own, each
frame handed to sink(camera, t [s, rig clock], rgb). The control loop never waits for a camera.

- Real cameras: one thread per camera grabs on the rig clock's schedule (k / fps from the start); a grab that
  fails or comes back later than half a period is counted.
- Twin cameras (hardware.cameras.mujoco_camera.TwinCamera): the twin's stepping path
  (Twin.add_step_observer) copies the physics state when a frame is due (microseconds, lock held by the
  stepper), and the camera's thread renders the copy on a private MjData: MuJoCo never renders on the control
  thread, and the frame shows the state at exactly its timestamp. In lockstep the stepper waits for a free
  slot (no real time to keep: no frame is dropped and a run stays deterministic); in real time a full queue
  drops the frame and counts it.

    stream = CameraStream(session.cameras, session.clock, sink=recorder.log_image, twin=session.twin)
    stream.start(); ...; stream.stop(); stream.stats()   # {camera: CameraStats}
    stream.take_events()   # [(t, camera, text)]: a camera frozen, gone, back (hardware/cameras/health.py)

A frame whose timestamp is not newer than the camera's newest (a frozen camera) is not passed on.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from hardware.cameras.base import Camera, CameraError
from hardware.cameras.health import CameraHealth
from hardware.clock import Clock

QUEUE_FRAMES = 15  # snapshots waiting per twin camera (0.5 s at 30 Hz: a render burst is absorbed)
MAX_FAILURES = 10  # failed renders in a row (other than CameraError: no frame now) after which a camera
# is given up (the loop goes on without it); a camera that says it has no frame (unplugged) is asked again
LATE_FRACTION = 0.5  # a real camera's grab later than this many periods counts as late


@dataclass
class CameraStats:
    """expected: frames due since start (elapsed rig time x fps); captured: handed to the sink; dropped: due
    but not taken (queue full, real time); failed: grabs/renders that raised; late: real grabs > half a
    period late. error: the last failure's message."""

    expected: int = 0
    captured: int = 0
    dropped: int = 0
    failed: int = 0
    late: int = 0
    error: str = ""

    @property
    def ratio(self) -> float:
        return self.captured / self.expected if self.expected else float("nan")


class CameraStream:
    def __init__(self, cameras: dict[str, Camera], clock: Clock,
                 sink: Callable[[str, float, np.ndarray], object], twin=None):
        self.cameras, self.clock, self.sink, self.twin = dict(cameras), clock, sink, twin
        self._stats = {n: CameraStats() for n in self.cameras}
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._queues: dict[str, queue.Queue] = {}
        self._due: dict[str, float] = {}
        self._t_start: dict[str, float] = {}  # when each camera's capture began [s, rig clock]
        self._t0 = float("nan")
        self._t_last = float("nan")
        self._lock = threading.Lock()
        self._observer = None
        self.health: dict[str, CameraHealth] = {}
        self.answered_t: dict[str, float] = {}  # per twin camera: newest snapshot rendered or failed [s]
        self._fails_in_row: dict[str, int] = {}

    # -- lifecycle ------------------------------------------------------------------------------------
    def start(self) -> None:
        """Connect every camera on its own thread and start capturing (frames due from now on)."""
        if self._threads:
            return
        self._stop.clear()
        self._t0 = self._t_last = self.clock.now()
        self.health = {name: CameraHealth(name, self._t0) for name in self.cameras}
        ready = []
        for name, cam in self.cameras.items():
            snap = self.twin is not None and hasattr(cam, "snapshot")
            if snap:
                self._queues[name] = queue.Queue(QUEUE_FRAMES)
                self._due[name] = self._t0
            ev = threading.Event()
            ready.append(ev)
            target = self._render_loop if snap else self._grab_loop
            th = threading.Thread(target=target, args=(name, cam, ev), name=f"factr2-camera-{name}",
                                  daemon=True)
            th.start()
            self._threads.append(th)
        for ev in ready:  # a GL context or device opens in a second or so; capture starts once all are up
            ev.wait(10.0)
        self._t_start = dict.fromkeys(self.cameras, self._t0)  # a real camera grabs from t0 on
        if self._queues:
            # a twin camera's frames are due from now, when capture starts, not from the call: the second
            # its renderer took to open was counted as ~30 frames "dropped" (96.5-97.3 % in a 30 s
            # teleop recording; issue #37)
            now = self.clock.now()
            for name in self._queues:
                self._due[name] = self._t_start[name] = now
                self.health[name].t_good = now
            self._observer = self._on_step
            self.twin.add_step_observer(self._observer)

    def stop(self) -> None:
        if self._observer is not None:
            self.twin.remove_step_observer(self._observer)
            self._observer = None
        self._t_last = self.clock.now()
        self._stop.set()
        for th in self._threads:
            th.join(10.0)
        self._threads = []
        for cam in self.cameras.values():
            try:
                cam.disconnect()
            except Exception:  # noqa: BLE001 -- stopping must reach every camera
                pass

    def problems(self) -> list[str]:
        """One line per camera that failed (for the shells to say)."""
        return [f"camera {n}: {s.failed} failure(s), last: {s.error}" for n, s in self.stats().items()
                if s.failed]

    def take_events(self) -> list[tuple[float, str, str]]:
        """(t [s, rig clock], camera, text): each camera that went frozen / gone / back since last asked."""
        with self._lock:
            return [(t, n, text) for n, h in self.health.items() for t, text in h.take_events()]

    def stats(self) -> dict[str, CameraStats]:
        """Per camera, with `expected` counted up to now (or the stop)."""
        t_end = self.clock.now() if self._threads else self._t_last
        with self._lock:
            out = {}
            for name, st in self._stats.items():
                fps = self.cameras[name].config.fps
                t0 = self._t_start.get(name, self._t0)
                exp = int(np.floor((t_end - t0) * fps + 1e-9)) + 1 if np.isfinite(t0) and t_end >= t0 else 0
                out[name] = CameraStats(exp, st.captured, st.dropped, st.failed, st.late, st.error)
            return out

    # -- twin cameras -----------------------------------------------------------------------------------
    def _on_step(self, t: float) -> None:
        """On the twin's stepping thread after each advance: snapshot every camera whose frame is due."""
        for name, q in list(self._queues.items()):
            due = self._due[name]
            if t + 1e-9 < due:
                continue
            cam = self.cameras[name]
            late = int((t - due) * cam.config.fps + 1e-9)  # whole frame periods missed (a stalled stepper)
            self._due[name] = due + (late + 1) / cam.config.fps
            if late:
                with self._lock:
                    self._stats[name].dropped += late
            snap = (t, cam.snapshot(t))  # (asked at, what the camera gives: a frozen one repeats its t)
            if self.clock.realtime:
                try:
                    q.put_nowait(snap)
                except queue.Full:
                    with self._lock:
                        self._stats[name].dropped += 1
            else:
                while not self._stop.is_set() and name in self._queues:  # lockstep: wait for the renderer
                    try:
                        q.put(snap, timeout=0.5)
                        break
                    except queue.Full:
                        continue

    def _render_loop(self, name: str, cam, ready: threading.Event) -> None:
        q = self._queues[name]
        try:
            cam.connect()
        except Exception as e:  # noqa: BLE001 -- reported in stats; the loop goes on without this camera
            self._fail(name, e)
            self._queues.pop(name, None)  # no more snapshots for it (lockstep would wait for them)
            ready.set()
            return
        ready.set()
        while True:  # until stopped and drained: snapshots taken before the stop are still rendered
            try:
                snap = q.get(timeout=0.1)
            except queue.Empty:
                if self._stop.is_set():
                    break
                continue
            if snap is None:
                break
            t_req, snap = snap
            try:
                rgb = cam.render(snap)
            except Exception as e:  # noqa: BLE001 -- a dead render process: stop asking this camera
                self._fail(name, e, t_req)
                self.answered_t[name] = t_req
                if not cam.is_connected or self._fails_in_row.get(name, 0) >= MAX_FAILURES:
                    self._queues.pop(name, None)
                    break
                continue
            self._deliver(name, snap.t, rgb, t_req)
            self.answered_t[name] = t_req
        cam.disconnect()

    # -- real cameras -----------------------------------------------------------------------------------
    def _grab_loop(self, name: str, cam: Camera, ready: threading.Event) -> None:
        try:
            cam.connect()
        except Exception as e:  # noqa: BLE001
            self._fail(name, e)
            ready.set()
            return
        ready.set()
        period = 1.0 / cam.config.fps
        k = 0
        while not self._stop.is_set():
            due = self._t0 + k * period
            now = self.clock.now()
            if now < due:
                self._stop.wait(min(due - now, 0.1)) if self.clock.realtime else time.sleep(0.001)
                continue
            try:
                frame = cam.read()
            except Exception as e:  # noqa: BLE001
                self._fail(name, e, due)
                k += 1
                continue
            if frame.t - due > LATE_FRACTION * period:
                with self._lock:
                    self._stats[name].late += 1
            self._deliver(name, frame.t, frame.rgb, due)
            k = max(k + 1, int((self.clock.now() - self._t0) / period))  # skip frames that are past

    def _deliver(self, name: str, t: float, rgb: np.ndarray, t_req: float) -> None:
        """A frame stamped t for the request at t_req: to the sink when it is newer than the last one."""
        with self._lock:
            self._fails_in_row[name] = 0
            fresh = self.health[name].frame(t_req, t)
        if not fresh:
            return
        try:
            self.sink(name, t, rgb)
        except Exception as e:  # noqa: BLE001 -- a sink error costs the frame, not the stream
            self._fail(name, e)
            return
        with self._lock:
            self._stats[name].captured += 1

    def _fail(self, name: str, e: BaseException, t_req: float | None = None) -> None:
        with self._lock:
            st = self._stats[name]
            st.failed += 1
            st.error = f"{type(e).__name__}: {e}"
            if t_req is not None:
                self.health[name].failed(t_req, st.error)
                # a camera that says it has no frame now (unplugged) is asked again; other errors add up
                self._fails_in_row[name] = 0 if isinstance(e, CameraError) else \
                    self._fails_in_row.get(name, 0) + 1
