"""SIMULATED faults of the app's own process and machine (hardware/sim/faults.py PROCESS_KINDS): what the
injector does to play them. Each returns the log's detail; one that finds nothing to act on says so in a
detail starting "not played" (counted as not injected by the campaign).

    kill_next_workers()          # SIGKILL this process's NEXT worker children
    fill_disk(folder)            # fill the (small) filesystem holding folder until ENOSPC; free_disk(folder)
    step_wall_clock(+3600.0)     # time.time() jumps; restore_wall_clock() undoes it (the twin's close)
"""

from __future__ import annotations

import errno
import os
import shutil
import signal
import time
from pathlib import Path

NEXT_WORKER_MODULE = b"calibration.next.worker"  # the NEXT worker's command line names this module
FILL_NAME = ".factr2-fault-disk-full"  # the filler file disk_full writes beside the recording
FILL_MAX_FREE_BYTES = 512 << 20  # refuse to fill a filesystem with more free space: a test's small tmpfs only
FILL_CHUNK_BYTES = 64 << 10

_REAL_TIME = time.time
_wall_offset_s = 0.0


def _children() -> list[int]:
    """Pids of this process's children (Linux /proc)."""
    me, out = os.getpid(), []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            if ppid == me:
                out.append(int(d.name))
    return out


def kill_next_workers() -> str:
    """SIGKILL every NEXT worker this process started (calibration/next/worker.py)."""
    killed = []
    for pid in _children():
        try:
            if NEXT_WORKER_MODULE in Path(f"/proc/{pid}/cmdline").read_bytes():
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
        except OSError:
            continue
    return f"killed NEXT worker pid {', '.join(map(str, killed))}" if killed else "not played: no NEXT worker"


def fill_disk(folder) -> str:
    """Write a filler file into folder until its filesystem is full (ENOSPC). Refused on a filesystem with
    more than FILL_MAX_FREE_BYTES free: this plays a small test filesystem filling, never a real disk."""
    if folder is None:
        return "not played: nothing records"
    free = shutil.disk_usage(folder).free  # bytes an unprivileged writer may take (f_bavail)
    if free > FILL_MAX_FREE_BYTES:
        return f"not played: {free >> 20} MiB free at {folder} (only a small test filesystem is filled)"
    n, chunk = 0, b"\0" * FILL_CHUNK_BYTES
    try:
        with open(Path(folder) / FILL_NAME, "ab", buffering=0) as f:
            n = _take_at_once(f.fileno(), folder)
            while True:  # the last pages (or all of it where fallocate is refused)
                try:
                    n += f.write(chunk)
                except OSError as e:
                    if e.errno != errno.ENOSPC:
                        raise
                    if len(chunk) == 1:
                        break
                    chunk = chunk[: len(chunk) // 2]  # the last pages, down to a byte
    except OSError as e:
        return f"not played: {e.strerror} at {folder}"
    return f"filled {n} bytes at {folder}"


def _take_at_once(fd: int, folder) -> int:
    """Allocate the free space in one call, as another process writing a big file would (a filler writing
    chunk by chunk would go on taking space the recorder frees meanwhile: a race the fault does not mean to
    play). Returns the bytes taken; 0 where the filesystem refuses (then the chunks take it)."""
    for _ in range(3):  # the recorder wrote meanwhile: the space is smaller, try again
        free = shutil.disk_usage(folder).free
        if free <= 0:
            return 0
        try:
            os.posix_fallocate(fd, 0, free)
            return free
        except OSError as e:
            if e.errno != errno.ENOSPC:
                return 0
    return 0


def free_disk(folder) -> str:
    if folder is None:
        return ""
    try:
        (Path(folder) / FILL_NAME).unlink()
    except OSError:
        return ""
    return f"freed {folder}"


def signal_app(sig: int) -> str:
    """Send this process sig (SIGTERM: the app's handler stops safely; SIGKILL: nothing of it runs)."""
    os.kill(os.getpid(), sig)
    return f"sent {signal.Signals(sig).name}"


def freeze_app(seconds: float) -> str:
    """SIGSTOP this process for seconds [s] of wall time, then SIGCONT (a laptop lid, a debugger, a stalled
    host): a helper shell outside the process sends the SIGCONT. Everything of the process stops, an
    in-process twin too: only a twin in a process of its own (hardware/process_twin.py) sees the motors
    fall back meanwhile."""
    import subprocess

    subprocess.Popen(["/bin/sh", "-c", f"sleep {float(seconds):.3f}; kill -CONT {os.getpid()}"],
                     start_new_session=True)
    os.kill(os.getpid(), signal.SIGSTOP)
    return f"stopped {seconds:g} s (SIGSTOP, then SIGCONT)"


def _stepped_time() -> float:
    return _REAL_TIME() + _wall_offset_s


def step_wall_clock(dt_s: float) -> str:
    """time.time() jumps by dt_s [s] from now on, for everything in this process that calls it (the loop and
    the recording's timing must not: they use the monotonic clock)."""
    global _wall_offset_s
    _wall_offset_s += float(dt_s)
    time.time = _stepped_time
    return f"wall clock {dt_s:+g} s"


def restore_wall_clock() -> None:
    global _wall_offset_s
    _wall_offset_s = 0.0
    time.time = _REAL_TIME
