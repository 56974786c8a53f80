"""The teleop loop: a thin shell that ticks arm pairs at a fixed rate on a hardware.clock.Clock.

One TeleopLoop runs its pairs in one thread, in order, at one rate (default 500 Hz). Bimanual: two pairs in
one loop (required on a LockstepClock, whose sleep advances the whole twin), or one loop per pair on a real
clock (two threads). Per tick and pair: read leader, read follower, estimator, leader law ->
leader.command_torque, mapping -> follower.command (pair.ArmPair). The loop measures its timing
(timing.LoopTiming), calls an optional recorder with each pair's flat record, and keeps a thread-safe snapshot
for a UI. It always ends safe: stop(), Ctrl-C, an exception in a tick -> every leader zero torque, every
follower on hold.
"""

from __future__ import annotations

import gc
import logging
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from factr2_teleop.teleop.degrade import RateGovernor
from factr2_teleop.teleop.pair import COUPLED, FAULT, HOLD, IDLE, SOFT_START, STOPPED, ArmPair, PairHold
from factr2_teleop.teleop.record import TickRecord
from factr2_teleop.teleop.timing import LoopTiming, TimingStats
from hardware import sim_cpu
from hardware.clock import Clock
from hardware.realtime import LOOP_PRIORITY, CpuWakeLatency, LoopCpu, ProcessThreads, set_fifo, set_normal
from hardware.reasons import Reason
from hardware.threads import limit_threads

log = logging.getLogger("factr2.teleop")

DEFAULT_RATE_HZ = 500.0
# s: a loop that fell behind its schedule by up to this much makes the ticks up (they run back to back until
# it is on time again), so a single late tick (a GC pause, the OS scheduling another process) costs no ticks
# and the rate holds on average; further behind, the schedule restarts from now. Back-to-back ticks are safe:
# the safety layer's rate limits use the real time between commands.
CATCH_UP_S = 0.02
SWITCH_FRACTION = 0.05  # the GIL switch interval while a real-time loop runs, in loop periods
SERVICE_REFRESH_TICKS = 500  # ticks between two looks for new threads to raise (realtime.ProcessThreads)
__all__ = ["TeleopLoop", "TeleopSnapshot", "DEFAULT_RATE_HZ", "SOFT_START", "COUPLED", "HOLD", "FAULT",
           "STOPPED", "IDLE"]


@dataclass(frozen=True)
class TeleopSnapshot:
    """What a UI shows: per-pair latest record (record.TickRecord), phases, timing,
    the last messages (t [s], pair, text), running flag and the error that stopped the loop (if any)."""

    t: float
    running: bool
    phases: dict[str, str]
    records: dict[str, TickRecord]
    timing: TimingStats
    messages: tuple[tuple[float, str, str], ...]
    error: str | None


class TeleopLoop:
    """TeleopLoop(pairs, clock, rate_hz=500, recorder=None, max_messages=100).

    recorder: callable(record: TickRecord) per pair per tick (an exception in it stops recording with a
    message, never the arms). idle: callables run on the loop's thread after each tick, just before it
    sleeps: hand-overs that wake another thread do it here, so that the woken thread takes the GIL while
    the loop sleeps rather than in the middle of a tick (a recording's tick records). run() blocks (until
    stop(), duration_s or max_ticks); start() runs it in a
    thread. snapshot() may be called from any thread.
    """

    def __init__(self, pairs: list[ArmPair], clock: Clock, rate_hz: float = DEFAULT_RATE_HZ,
                 recorder: Callable[[TickRecord], None] | None = None, max_messages: int = 100):
        if not pairs:
            raise ValueError("TeleopLoop needs at least one arm pair")
        names = [p.cfg.name for p in pairs]
        if len(set(names)) != len(names):
            raise ValueError(f"arm pair names must differ, got {names}")
        if not rate_hz > 0:
            raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
        self.pairs, self.clock, self.rate_hz = pairs, clock, float(rate_hz)
        self.period_s = 1.0 / self.rate_hz
        self.recorder = recorder
        self.degrade = True  # real time: a rate the machine cannot hold drops to one it can (degrade.py)
        self.on_rate_change: list[Callable[[float, str], None]] = []  # fn(t [s], line) then (loop thread)
        self.idle: list[Callable[[], None]] = []
        self.on_begin: list[Callable[[], None]] = []  # fn() once every pair has begun (loop thread)
        # fn() on the loop's thread when it ends, right after its arms were made safe: an app that ends with
        # its loop puts the arms down here (session.disconnect_arms), not after a hand-off to another thread
        self.on_end: list[Callable[[], None]] = []
        self.timing = LoopTiming(self.rate_hz)
        self.error: BaseException | None = None
        self.recorder_errors = 0
        self._messages: deque[tuple[float, str, str]] = deque(maxlen=max_messages)
        # device name -> its warnings said so far (those of its start-up were said by whoever connected it)
        self._notes_seen = {d.name: len(getattr(d, "warnings", None) or ()) for p in pairs
                            for d in (p.leader, p.follower)}
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._running = False
        self._thread: threading.Thread | None = None
        self._t_pub = float("nan")
        self._t_last_start = float("nan")
        self._busy_s = self._late_s = float("nan")  # the last tick's time inside it, this tick's lateness [s]
        self._phases: dict[str, str] = {}
        self._records: dict[str, TickRecord] = {}
        self._publish(float("nan"))

    # -- public ---------------------------------------------------------------------------------------
    def run(self, duration_s: float | None = None, max_ticks: int | None = None, *,
            _keep_stop_request: bool = False) -> None:
        """Start every pair (UserError on a refused start, both arms left safe), then tick until stopped.
        Always leaves every arm safe; re-raises a tick's exception after making them safe."""
        if not _keep_stop_request:  # start() clears it before the thread exists, so an early stop() counts
            self._stop.clear()
        self.error = None
        self._running = True
        # One BLAS thread while the loop runs (process-wide for OpenBLAS): the NEXT estimator's products are
        # small (50x256 @ 256x512), and a thread pool's hand-offs and spinning threads cost more than they
        # give next to the loop and the twin -- 0.66 vs 2.4 ms per estimate on the 2-core dev VM under load.
        blas = limit_threads(1, blas=True)
        # Python hands the GIL to a waiting thread only every switch interval (5 ms by default): a recorder,
        # camera or twin thread holding it could delay a tick by that much. A quarter period bounds it.
        switch = sys.getswitchinterval()
        services = ProcessThreads(helpers=self.helper_processes)
        pin = LoopCpu(helpers=self.helper_processes)
        wake = None
        if self.clock.realtime:
            # Python's full collection holds the GIL while it walks every tracked object: ~200k after start-up
            # (numpy, torch, MuJoCo, the rig), 50-130 ms on the dev VM, a stall of the loop whichever thread
            # triggers it. Frozen out of every later collection (gc.freeze, O(1)), a full collection in a long
            # session walks only what the session made. Not collected first: that took 0.2 s with the GIL
            # held at every start; start-up's garbage waits for the unfreeze at the end instead.
            gc.freeze()
            sys.setswitchinterval(min(switch, SWITCH_FRACTION * self.period_s))
            why = set_fifo(LOOP_PRIORITY)
            if why is not None:
                self._message(self.clock.now(), "loop", str(why))
            else:
                services.refresh()
            pin.start()  # the loop's thread alone on one CPU, the rest of the process on the others
            if pin.note:
                self._message(self.clock.now(), "loop", pin.note)
            wake = CpuWakeLatency()
            if wake.note:
                self._message(self.clock.now(), "loop", wake.note)
        try:
            for p in self.pairs:
                p.begin(self.clock)
            for fn in self.on_begin:
                fn()
            self._note_messages()
            # a clock that drives a simulation between ticks (demo.task.TwinDrivenClock) brings it up to now
            # here, so the first tick does not see samples as old as the start-up; no-op on other clocks
            self.clock.sleep_until(self.clock.now())
            t0 = self.clock.now()
            next_t, ticks = t0, 0
            governor = RateGovernor(self.rate_hz) if self.clock.realtime and self.degrade else None
            while not self._stop.is_set():
                t_start, cpu0, sim0 = self.clock.now(), time.thread_time(), sim_cpu.charged()
                self._late_s = t_start - next_t  # this tick's start after its deadline (the records carry it)
                self._tick_all(t_start)
                ticks += 1
                cpu, sim = time.thread_time() - cpu0, sim_cpu.charged() - sim0
                self._busy_s = self.clock.now() - t_start  # the next tick's records carry it
                with self._lock:  # the loop's own CPU: what a twin did on this thread is kept apart (sim_cpu)
                    self.timing.record(t_start, self._busy_s, cpu - sim, sim)
                self._publish(t_start)
                if governor is not None:
                    verdict = governor.tick(t_start, self._busy_s)
                    if verdict is not None and verdict.new_rate_hz is not None:
                        self._set_rate(verdict.new_rate_hz, verdict.line)
                if (max_ticks is not None and ticks >= max_ticks) or \
                        (duration_s is not None and t_start - t0 + 1.5 * self.period_s >= duration_s):
                    break
                if ticks % SERVICE_REFRESH_TICKS == 0 and self.clock.realtime:
                    services.refresh()  # threads started since (cameras, a recorder): off normal priority
                    pin.refresh()  # ... and off the loop's CPU
                next_t += self.period_s
                now = self.clock.now()
                if now > next_t + CATCH_UP_S:  # too far behind to make up: restart the schedule from now
                    next_t = now
                for fn in self.idle:
                    fn()
                self.clock.sleep_until(next_t)
        except BaseException as e:
            self.error = e
            self._message(self.clock.now(), "loop", f"stopped by {type(e).__name__}: {e}")
            raise
        finally:
            # the arms first, right after the last tick, then the thread's own settings: on a slowed core
            # (bench/slow_core.py) the restores and the hand-off to the thread that stops the rig took over
            # 100 ms, and a leader's Bus Watchdog latched before the stop reached it (issue #53)
            self._running = False
            fault = isinstance(self.error, Exception)
            self._make_safe(Reason.of(PairHold.LOOP_FAULT if fault else PairHold.LOOP_STOPPED),
                            FAULT if fault else STOPPED)
            for fn in self.on_end:
                try:
                    fn()
                except Exception as e:  # noqa: BLE001 -- the thread's settings are restored whatever it did
                    self._message(self.clock.now(), "loop", f"end hook failed ({type(e).__name__}: {e})")
            blas.close()
            sys.setswitchinterval(switch)
            if self.clock.realtime:
                set_normal()
                services.restore()
                pin.restore()
                gc.unfreeze()  # a long-lived app (the terminal app) runs many sessions: collect theirs again
                if wake is not None:
                    wake.close()
            self._publish(self.clock.now())

    def start(self, duration_s: float | None = None) -> threading.Thread:
        """Run in a daemon thread (real-time clocks only; a LockstepClock is driven by run() itself)."""
        if self._thread is not None and self._thread.is_alive():
            raise RuntimeError("teleop loop already running")

        def target():
            try:
                self.run(duration_s=duration_s, _keep_stop_request=True)
            except BaseException:  # noqa: BLE001 -- kept in self.error, shown by snapshot()
                log.exception("teleop loop stopped")

        self._stop.clear()
        self._thread = threading.Thread(target=target, name="factr2-teleop", daemon=True)
        self._thread.start()
        return self._thread

    def stop(self, timeout_s: float = 1.0) -> None:
        """Ask the loop to end; it leaves leaders at zero torque, followers on hold. Safe from any thread."""
        self._stop.set()
        t = self._thread
        if t is not None and t is not threading.current_thread():
            t.join(timeout_s)
            if t.is_alive():  # stuck in a driver call: command the safe states from here too
                self._make_safe(Reason.of(PairHold.LOOP_NOT_ANSWERING), STOPPED)

    @property
    def running(self) -> bool:
        return self._running

    def helper_processes(self) -> dict[int, int]:
        """The processes working for this loop's pairs now (their estimators': NEXT's worker), pid ->
        priority: raised and pinned with the loop's threads while it runs real time (hardware.realtime)."""
        out: dict[int, int] = {}
        for p in self.pairs:
            if p.estimator is not None:
                out.update(p.estimator.helper_processes())
        return out

    @property
    def alive(self) -> bool:
        """The thread of start() still runs (stopping included)."""
        return self._thread is not None and self._thread.is_alive()

    def snapshot(self) -> TeleopSnapshot:
        with self._lock:
            return TeleopSnapshot(
                t=self._t_pub, running=self._running, phases=dict(self._phases), records=dict(self._records),
                timing=self.timing.stats(), messages=tuple(self._messages),
                error=None if self.error is None else f"{type(self.error).__name__}: {self.error}")

    # -- internals ------------------------------------------------------------------------------------
    def _tick_all(self, t_start: float) -> None:
        period = t_start - self._t_last_start if np.isfinite(self._t_last_start) else float("nan")
        self._t_last_start = t_start
        for p in self.pairs:
            rec = p.tick(self.clock.now())
            rec.loop_period_s, rec.loop_overruns = period, self.timing.overruns
            rec.loop_busy_s, rec.loop_late_s = self._busy_s, self._late_s
            if self.recorder is not None:
                try:
                    self.recorder(rec)
                except Exception as e:  # noqa: BLE001 -- recording must never stop the arms
                    self.recorder_errors += 1
                    self.recorder = None
                    self._message(t_start, p.cfg.name, f"recording stopped: recorder failed ({e})")
        self._note_messages()

    def _note_messages(self) -> None:
        now = None  # the clock read only when there is something to stamp (most ticks: nothing)
        for p in self.pairs:
            if p.messages:
                now = self.clock.now()
                for m in p.messages:
                    self._message(now, p.cfg.name, m)
                p.messages.clear()
            for dev in (p.leader, p.follower):  # what a driver did by itself (a servo rebooted), said once
                notes = getattr(dev, "warnings", None)
                seen = self._notes_seen.get(dev.name, 0)
                if notes is not None and len(notes) > seen:
                    now = self.clock.now() if now is None else now
                    for m in notes[seen:]:
                        self._message(now, dev.name, m)
                    self._notes_seen[dev.name] = len(notes)

    def say(self, who: str, text: str, t: float | None = None) -> None:
        """A message from beside the pairs (the recording, a camera) into the loop's list, stamped t [s]
        (default now)."""
        self._message(self.clock.now() if t is None else t, who, text)

    def _message(self, t: float, who: str, text: str) -> None:
        with self._lock:
            self._messages.append((t, who, text))

    def _set_rate(self, rate_hz: float, line: str) -> None:
        """Run at rate_hz from the next tick on (degrade.py): the schedule, the timing's target (the rate
        recorded: TimingStats.target_hz, the timing line, the demo's JSON), every pair's period and gains."""
        self.rate_hz, self.period_s = float(rate_hz), 1.0 / float(rate_hz)
        with self._lock:
            self.timing.target_hz = self.rate_hz
        for p in self.pairs:
            p.set_rate(self.rate_hz)
        t = self.clock.now()
        self._message(t, "loop", line)  # said once: the CLI and the app show the messages
        for fn in self.on_rate_change:  # e.g. a recording notes it (session/teleop.py)
            fn(t, line)

    def _make_safe(self, reason: Reason, phase: str) -> None:
        for p in self.pairs:
            p.make_safe(reason)
            p.phase = phase

    def _publish(self, t: float) -> None:
        phases = {p.cfg.name: p.phase for p in self.pairs}
        # each tick builds a new record: no copy needed
        records = {p.cfg.name: p.last for p in self.pairs if p.last is not None}
        with self._lock:
            self._t_pub, self._phases, self._records = t, phases, records
