"""Is a camera live? Frame age, judged per frame request (pure; hardware/cameras/stream.py feeds it).

A camera is live while its newest frame is at most STALE_S older than the frame asked for. A frozen camera
(a hung driver handing out its last buffer again, with that buffer's timestamp) and a gone one (unplugged:
reads fail) both age; a repeated timestamp is never passed on as a new frame. The first request at which the
age passes STALE_S is an event ("frozen" / "gone"), the first fresh frame after it another ("back").

    h = CameraHealth("scene", t_start)
    if h.frame(t_req, t_frame): sink(...)       # fresh: pass it on
    h.failed(t_req, "CameraError: ...")          # the read / render failed
    h.take_events()                              # [(t [s], text)] to say and to mark in the recording
"""

from __future__ import annotations

STALE_S = 0.3  # s: newest frame older than this (9 periods at 30 fps): the camera is not live (said)
OK, FROZEN, GONE = "ok", "frozen", "gone"


class CameraHealth:
    def __init__(self, name: str, t_start: float):
        self.name = name
        self.t_good = float(t_start)  # timestamp of the newest fresh frame [s] (the start until one came)
        self._t_last = float("-inf")  # timestamp of the newest frame passed on (any first frame is fresh)
        self.state = OK
        self.stale = 0  # frames not passed on: their timestamp was not newer than the newest one
        self.outages = 0  # times the camera stopped being live
        self._why = ""
        self._events: list[tuple[float, str]] = []

    def frame(self, t_req: float, t_frame: float) -> bool:
        """A frame stamped t_frame [s] came for the request at t_req [s]; True: fresh, pass it on."""
        if t_frame > self._t_last:
            if self.state != OK:
                self._events.append((t_req, f"camera {self.name}: back after {t_req - self.t_good:.2f} s "
                                            f"without new frames ({self.state})"))
                self.state = OK
            self.t_good = self._t_last = t_frame
            return True
        self.stale += 1
        self._age(t_req, FROZEN, f"the same frame again (newest {1e3 * (t_req - self.t_good):.0f} ms old)")
        return False

    def failed(self, t_req: float, why: str) -> None:
        """The request at t_req [s] gave no frame (why: the error)."""
        self._age(t_req, GONE, f"no frames ({why})")

    def _age(self, t_req: float, kind: str, why: str) -> None:
        if self.state == OK and t_req - self.t_good > STALE_S:
            self.state, self._why = kind, why
            self.outages += 1
            self._events.append((t_req, f"camera {self.name}: {kind}: {why}; its frames are not recorded "
                                        "until it is back"))

    def take_events(self) -> list[tuple[float, str]]:
        out, self._events = self._events, []
        return out
