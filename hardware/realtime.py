"""Real-time scheduling for the threads that must answer within a tick: the control loop's thread and, on a
twin, the device emulators that stand in for hardware (a servo answers in microseconds whatever the host is
doing; an emulator thread at normal priority waits behind every other process on a busy machine).

SCHED_FIFO where the OS allows it (Linux with CAP_SYS_NICE or an rtprio limit); otherwise one line saying
why, for the start-up messages. The kernel's RT throttling (95 % of each second by default) keeps a runaway
thread from locking the machine up. FACTR2_NO_RT=1 turns it off (A/B timing runs; hardware/switches.py).
"""

from __future__ import annotations

import os
import struct
import subprocess
import tempfile
import threading
from collections.abc import Callable
from enum import Enum
from pathlib import Path

from hardware.reasons import Reason, messages
from hardware.switches import switches

LOOP_PRIORITY = 40  # the control loop (1-99; below the kernel's IRQ threads at 50)
EMULATOR_PRIORITY = 41  # a twin's device emulators: the loop waits on their answers, so they go first
TWIN_PRIORITY = 39  # a real-time twin's physics thread: ahead of other processes, behind the loop


class RtRefusal(Enum):
    """Why SCHED_FIFO was not set (hardware.reasons). REFUSED is for this one thread (it may have ended, or
    the kernel's RT budget is spent): another thread may still get it; the others hold for every thread."""

    UNAVAILABLE = "unavailable"  # not this OS
    OFF = "off"  # FACTR2_NO_RT
    NOT_PERMITTED = "not permitted"  # no CAP_SYS_NICE / rtprio limit
    REFUSED = "refused"  # this thread (detail: error)


messages({
    RtRefusal.UNAVAILABLE: "real-time scheduling: not available on this OS (normal priority)",
    RtRefusal.OFF: "real-time scheduling: off (FACTR2_NO_RT is set)",
    RtRefusal.NOT_PERMITTED: ("real-time scheduling: not permitted, normal priority (allow it with "
                              "CAP_SYS_NICE or an rtprio limit in /etc/security/limits.conf)"),
    RtRefusal.REFUSED: "real-time scheduling: refused ({error}), normal priority",
})


def set_fifo(priority: int, native_id: int | None = None) -> Reason | None:
    """SCHED_FIFO at `priority` for thread `native_id` (default: the calling thread). None when it was set,
    else why not (an RtRefusal reason; str() is the line to show; the thread keeps normal priority)."""
    if not hasattr(os, "sched_setscheduler"):
        return Reason.of(RtRefusal.UNAVAILABLE)
    if switches().no_rt:
        return Reason.of(RtRefusal.OFF)
    tid = threading.get_native_id() if native_id is None else int(native_id)
    try:
        os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(int(priority)))
    except PermissionError:
        return Reason.of(RtRefusal.NOT_PERMITTED)
    except OSError as e:
        return Reason.of(RtRefusal.REFUSED, error=e.strerror or e)
    return None


# the CPUs this process may use, read before any thread is pinned (a pinned thread's own set is one CPU)
PROCESS_CPUS: frozenset[int] = frozenset(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else \
    frozenset()


def _inherits_realtime() -> bool:
    """Whether a process started from the calling thread would inherit a real-time policy or a pinned CPU."""
    if not hasattr(os, "sched_getscheduler"):
        return False
    try:
        pinned = bool(PROCESS_CPUS) and set(os.sched_getaffinity(0)) != set(PROCESS_CPUS)
        return os.sched_getscheduler(0) != os.SCHED_OTHER or pinned
    except OSError:
        return False


def spawn_normal(args: list[str], **popen_kw) -> subprocess.Popen:
    """subprocess.Popen(args, **popen_kw), the child at normal priority on every CPU of the process.

    A new process inherits the policy and the CPU affinity of the thread that starts it. Started from the
    control loop's thread (a NEXT worker restarted after it died, mid-run), a child ran its start-up
    (a Python interpreter importing torch, ~1 s) at the loop's SCHED_FIFO priority on the loop's own CPU,
    where an equal-priority FIFO thread is not preempted: the loop stood still for 1.26 s (measured, the
    fault campaign's next_killed on the twin). So from such a thread the Popen runs on a short-lived thread
    that first drops to normal priority and the process's CPUs (the caller waits for the fork and exec
    only, a few ms); from any other thread it is a plain Popen."""
    if not _inherits_realtime():
        return subprocess.Popen(args, **popen_kw)
    box: dict = {}

    def start() -> None:
        set_normal()
        try:
            if PROCESS_CPUS:
                os.sched_setaffinity(0, PROCESS_CPUS)
        except OSError:
            pass  # a cpuset that changed meanwhile: the policy is what matters most
        try:
            box["proc"] = subprocess.Popen(args, **popen_kw)
        except BaseException as e:  # noqa: BLE001 -- raised again on the caller's thread
            box["error"] = e

    th = threading.Thread(target=start, name="spawn-normal", daemon=True)
    th.start()
    th.join()
    if "error" in box:
        raise box["error"]
    return box["proc"]


def set_normal(native_id: int | None = None) -> None:
    """Back to normal scheduling (a loop that ran on a caller's thread gives it back as it was)."""
    if hasattr(os, "sched_setscheduler"):
        tid = threading.get_native_id() if native_id is None else int(native_id)
        try:
            os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))
        except OSError:
            pass


SERVICE_PRIORITY = 10  # every other Python thread of the loop's process while the loop runs (see below)
ESTIMATOR_PRIORITY = 8  # an estimator's own process (NEXT's worker): feedback goes stale without it
# (at normal priority beside a real-time loop on 2 vCPUs its answers came up to 138 ms late). Below
# SERVICE_PRIORITY: above it, it preempted the loop's own service threads while one held the GIL, and the
# loop waited (measured: "leader data stale (24 ms old)" holds in `factr2 teleop` on the twin)

HelperProcesses = Callable[[], dict[int, int]]
"""The processes working for a loop now, pid -> priority (NEXT's worker: its estimator's helper_processes()):
raised and moved off the loop's CPU with the loop's threads while a real-time loop runs -- below the loop
(an estimate may wait, a tick may not), above other processes. The loop that owns them hands this in;
nothing else changes it."""


def no_helpers() -> dict[int, int]:
    return {}


class ProcessThreads:
    """Raise the other Python threads of this process to SCHED_FIFO at a low priority while a real-time loop
    runs, and give them back afterwards. Why: a thread at normal priority that holds the GIL can be preempted
    by any other process (a browser, a build); the loop then waits for the GIL until that thread gets a core
    again -- several ms on a busy machine, whatever the loop's own priority. At SERVICE_PRIORITY they are
    never preempted by normal processes, yet every tick still preempts them (the loop, the twin and its
    emulators are higher). Threads started later (a camera, a recorder) are raised by the next refresh()."""

    def __init__(self, priority: int = SERVICE_PRIORITY, helpers: HelperProcesses = no_helpers):
        self.priority = int(priority)
        self.helpers = helpers
        self._raised: set[int] = set()
        self.note: Reason | None = None

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
            if why is not None and why.kind is not RtRefusal.REFUSED:
                self.note = why  # not permitted / off: stop trying
                return
            if why is None:
                self._raised.add(tid)
        for pid, prio in self.helpers().items():
            if pid in self._raised:
                continue
            try:
                if os.sched_getscheduler(pid) != os.SCHED_OTHER:
                    continue
            except OSError:
                continue  # ended meanwhile
            if set_fifo(prio, pid) is None:
                self._raised.add(pid)

    def restore(self) -> None:
        for tid in self._raised:
            set_normal(tid)
        self._raised.clear()


CPU_LATENCY_DEVICE = "/dev/cpu_dma_latency"  # Linux PM QoS: the largest wake-up latency allowed [us]


class CpuWakeLatency:
    """Ask the kernel (PM QoS, as cyclictest and ros2_control setups do) for 0 us wake-up latency while a
    real-time loop runs: idle cores poll instead of entering idle states (or, in a VM, halting the vCPU),
    whose exit costs hundreds of microseconds on every tick that sleeps. Measured on the 2-vCPU dev VM,
    quiet, teleop recording 20 s: 496-500 Hz, p99 2.9-3.3 ms without; 500.0 Hz, p99 2.4-2.6 ms with. The
    request holds while the file is open and ends with close() (or the process). Costs power: idle cores
    spin. Not permitted (not root): one line saying so, and the loop runs as before."""

    def __init__(self, path: str = CPU_LATENCY_DEVICE):
        self._fd: int | None = None
        self.note: str | None = None
        if switches().no_rt:
            self.note = "CPU wake-up latency request: off (FACTR2_NO_RT is set)"
            return
        try:
            fd = os.open(path, os.O_WRONLY)
        except FileNotFoundError:
            self.note = None  # not Linux or no PM QoS: nothing to ask for
            return
        except OSError as e:
            self.note = (f"CPU wake-up latency request: not permitted ({e.strerror}); idle cores may add "
                         f"latency to ticks (allow write access to {path})")
            return
        try:
            os.write(fd, struct.pack("i", 0))
        except OSError as e:
            os.close(fd)
            self.note = f"CPU wake-up latency request refused ({e.strerror})"
            return
        self._fd = fd

    @property
    def active(self) -> bool:
        return self._fd is not None

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


class LoopCpu:
    """CPU affinity while a real-time loop runs: the loop's thread alone on one CPU (the last it may use),
    every other thread of its process (a twin's physics and emulators, a recorder, cameras) and the helper
    processes (NEXT's worker, a camera renderer) on the others, so they neither take the loop's core nor
    evict its caches. Measured on the 2-vCPU dev VM, `factr2 teleop --rig sim-piper --mode dob`, 20 s,
    quiet: loop's own CPU 0.38-0.40 -> 0.30-0.33 ms per tick, compute p99 0.75-0.96 -> 0.66-0.68 ms; the demo
    (its twin steps on the loop's own thread) unchanged. start() pins, refresh() moves threads and helpers
    started since, restore() gives everything its affinity back. note: one line when it cannot pin."""

    def __init__(self, helpers: HelperProcesses = no_helpers):
        self.helpers = helpers
        self.note: str | None = None
        self.cpu: int | None = None
        self._before: dict[int, set[int]] = {}  # thread or process id -> its affinity before
        self._allowed: set[int] = set()
        self._claim = None  # the file saying which CPU the loop holds (claim_loop_cpu)
        if not hasattr(os, "sched_setaffinity"):
            self.note = "CPU affinity: not available on this OS (threads float)"
        elif switches().no_rt or switches().no_pin:
            self.note = "CPU affinity: off (FACTR2_NO_RT or FACTR2_NO_PIN is set)"
        else:
            self._allowed = set(os.sched_getaffinity(0))
            if len(self._allowed) < 2:
                self.note = "CPU affinity: one CPU available, the loop shares it"

    def _move(self, tid: int, cpus: set[int]) -> bool:
        try:
            before = set(os.sched_getaffinity(tid))
            os.sched_setaffinity(tid, cpus)
        except OSError:
            return False  # ended meanwhile, or not ours to move
        self._before.setdefault(tid, before)
        return True

    def start(self) -> None:
        if self.note is not None:
            return
        self.cpu = max(self._allowed)
        if not self._move(threading.get_native_id(), {self.cpu}):
            self.note, self.cpu = "CPU affinity: refused for the loop's thread (threads float)", None
            return
        self._claim = claim_loop_cpu(self.cpu)  # the app's background jobs keep off it (KeepOffLoopCpus)
        self.refresh()

    def refresh(self) -> None:
        if self.cpu is None:
            return
        rest, me = self._allowed - {self.cpu}, threading.get_native_id()
        for th in threading.enumerate():
            tid = th.native_id
            if tid is not None and tid != me and tid not in self._before and th.is_alive():
                self._move(tid, rest)
        for pid in self.helpers():
            if pid not in self._before:
                self._move(pid, rest)

    def restore(self) -> None:
        for tid, cpus in self._before.items():
            if cpus == {self.cpu} and tid != threading.get_native_id():
                cpus = self._allowed  # born while the loop was pinned (it inherited the loop's CPU)
            try:
                os.sched_setaffinity(tid, cpus)
            except OSError:
                pass  # ended meanwhile
        self._before.clear()
        self.cpu = None
        release_loop_cpu(self._claim)
        self._claim = None


# -- a live loop's CPU, kept clear by this app's background jobs -----------------------------------------
# LoopCpu keeps the loop's own process off its CPU; a training started beside it (the operator collects the
# next demonstrations while the last ones train) is another process that floats onto that CPU whenever the
# loop sleeps and evicts its caches. Measured on the 2-vCPU dev VM, `bench/bench_teleop_record.py`, 30 s
# with recording beside `factr2 train --obs state --threads 1`: loop CPU 0.52 ms a tick (26 %) once with the
# training floating, 0.34 ms (17 %) with it kept on the other CPU (quiet: 0.27 ms; later runs floating were
# 0.33-0.38 ms: the cost comes and goes with where the scheduler puts it). So a pinned loop claims
# its CPU in a file, and the app's background jobs (policies.training.train) keep their threads off claimed
# CPUs.
def _claims_dir() -> Path:
    base = os.environ.get("XDG_RUNTIME_DIR") or tempfile.gettempdir()
    return Path(base) / f"factr2-{os.getuid() if hasattr(os, 'getuid') else 0}" / "loop-cpus"


def claim_loop_cpu(cpu: int) -> Path | None:
    """Say that this process's real-time loop runs alone on `cpu`; returns the claim (release_loop_cpu)."""
    try:
        d = _claims_dir()
        d.mkdir(parents=True, exist_ok=True)
        path = d / str(os.getpid())
        path.write_text(str(int(cpu)))
        return path
    except OSError:
        return None  # no writable runtime folder: background jobs just float, as before


def release_loop_cpu(claim: Path | None) -> None:
    if claim is not None:
        try:
            claim.unlink()
        except OSError:
            pass


def claimed_loop_cpus() -> set[int]:
    """CPUs that live loops of this user claim (a claim whose process has ended is removed)."""
    out: set[int] = set()
    try:
        files = list(_claims_dir().iterdir())
    except OSError:
        return out
    for f in files:
        try:
            pid, cpu = int(f.name), int(f.read_text().strip())
        except (OSError, ValueError):
            continue
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            release_loop_cpu(f)  # the loop's process died without releasing (SIGKILL)
            continue
        except OSError:
            pass  # alive, another user's
        out.add(cpu)
    return out


class KeepOffLoopCpus:
    """For a background job (a training): every thread of this process off the CPUs live loops claim, checked
    at most every `every_s` (loops start and stop while a training runs). Never leaves a job without a CPU:
    when every CPU it may use is claimed, it keeps them all."""

    def __init__(self, every_s: float = 2.0):
        self.every_s, self._next = every_s, 0.0
        self._allowed = set(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else set()
        self._current = set(self._allowed)
        self.off = not self._allowed or switches().no_pin

    def refresh(self, now: float) -> set[int]:
        """The CPUs this process's threads may use now (moved there if that changed)."""
        if self.off or now < self._next:
            return self._current
        self._next = now + self.every_s
        want = (self._allowed - claimed_loop_cpus()) or self._allowed
        if want != self._current:
            for tid in _own_threads():
                try:
                    os.sched_setaffinity(tid, want)
                except OSError:
                    pass  # ended meanwhile
            self._current = want
        return self._current


def _own_threads() -> list[int]:
    try:
        return [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        return [0]
