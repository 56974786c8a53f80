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
