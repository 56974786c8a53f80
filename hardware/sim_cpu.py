"""CPU time that simulated devices spend on the calling thread (SIMULATED rigs only).

An in-process emulator (hardware/dynamixel/inprocess.py: the twin's Dynamixel leader answering the
driver's packet inline) runs on the thread that talks to it: the control loop's. With a real arm that work
happens in the servos, so the loop's own CPU per tick (factr2_teleop/teleop/timing.py, issue #24 item 2) is
its thread's CPU minus what simulated devices charged here
(factr2_teleop/teleop/loop.py). Per thread, so a twin's other threads and other
loops are not mixed in. Units: seconds of thread CPU time (time.thread_time).
"""

from __future__ import annotations

import threading
import time

_local = threading.local()


def charge(seconds: float) -> None:
    """Add `seconds` of this thread's CPU time as spent inside a simulated device."""
    _local.s = getattr(_local, "s", 0.0) + seconds


def charged() -> float:
    """Total CPU time [s] charged to simulated devices on this thread so far."""
    return getattr(_local, "s", 0.0)


class simulated:  # noqa: N801 -- used as a context manager: `with sim_cpu.simulated():`
    """Charge the CPU time of the block to simulated devices (a twin's virtual operator, its ground truth):
    work a real rig does not do on the loop's thread. Not nested (the inner block would count twice)."""

    __slots__ = ("_t0",)

    def __enter__(self):
        self._t0 = time.thread_time()
        return self

    def __exit__(self, *exc) -> None:
        charge(time.thread_time() - self._t0)
