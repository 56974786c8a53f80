"""Real-time scheduling for the threads that must answer within a tick: the control loop's thread and, on a
twin, the device emulators that stand in for hardware (a servo answers in microseconds whatever the host is
doing; an emulator thread at normal priority waits behind every other process on a busy machine).

SCHED_FIFO where the OS allows it (Linux with CAP_SYS_NICE or an rtprio limit); otherwise one line saying
why, for the start-up messages. The kernel's RT throttling (95 % of each second by default) keeps a runaway
thread from locking the machine up. FACTR2_NO_RT=1 turns it off (A/B timing runs).
"""

from __future__ import annotations

import os
import threading

LOOP_PRIORITY = 40  # the control loop (1-99; below the kernel's IRQ threads at 50)
EMULATOR_PRIORITY = 41  # a twin's device emulators: the loop waits on their answers, so they go first
TWIN_PRIORITY = 39  # a real-time twin's physics thread: ahead of other processes, behind the loop


def set_fifo(priority: int, native_id: int | None = None) -> str | None:
    """SCHED_FIFO at `priority` for thread `native_id` (default: the calling thread). None when it was set,
    else one line saying why not (the thread keeps normal priority)."""
    if not hasattr(os, "sched_setscheduler"):
        return "real-time scheduling: not available on this OS (normal priority)"
    if os.environ.get("FACTR2_NO_RT"):
        return "real-time scheduling: off (FACTR2_NO_RT is set)"
    tid = threading.get_native_id() if native_id is None else int(native_id)
    try:
        os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(int(priority)))
    except PermissionError:
        return ("real-time scheduling: not permitted, normal priority (allow it with CAP_SYS_NICE or an "
                "rtprio limit in /etc/security/limits.conf)")
    except OSError as e:
        return f"real-time scheduling: refused ({e.strerror or e}), normal priority"
    return None


def set_normal(native_id: int | None = None) -> None:
    """Back to normal scheduling (a loop that ran on a caller's thread gives it back as it was)."""
    if hasattr(os, "sched_setscheduler"):
        tid = threading.get_native_id() if native_id is None else int(native_id)
        try:
            os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))
        except OSError:
            pass


SERVICE_PRIORITY = 10  # every other Python thread of the loop's process while the loop runs (see below)


class ProcessThreads:
    """Raise the other Python threads of this process to SCHED_FIFO at a low priority while a real-time loop
    runs, and give them back afterwards. Why: a thread at normal priority that holds the GIL can be preempted
    by any other process (a browser, a build); the loop then waits for the GIL until that thread gets a core
    again -- several ms on a busy machine, whatever the loop's own priority. At SERVICE_PRIORITY they are
    never preempted by normal processes, yet every tick still preempts them (the loop, the twin and its
    emulators are higher). Threads started later (a camera, a recorder) are raised by the next refresh()."""

    def __init__(self, priority: int = SERVICE_PRIORITY):
        self.priority = int(priority)
        self._raised: set[int] = set()
        self.note: str | None = None

    def refresh(self) -> None:
        if self.note is not None or not hasattr(os, "sched_getscheduler"):
            return
        me = threading.get_native_id()
        for th in threading.enumerate():
            tid = th.native_id
            if tid is None or tid == me or tid in self._raised or not th.is_alive():
                continue
            try:
                if os.sched_getscheduler(tid) != os.SCHED_OTHER:
                    continue  # already real-time (the twin, an emulator): keep its own priority
            except OSError:
                continue  # ended meanwhile
            why = set_fifo(self.priority, tid)
            if why is not None and "refused" not in why:
                self.note = why  # not permitted / off: stop trying
                return
            if why is None:
                self._raised.add(tid)

    def restore(self) -> None:
        for tid in self._raised:
            set_normal(tid)
        self._raised.clear()
