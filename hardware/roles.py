"""The two roles a device plays: Leader (human-driven, torque-commanded) and Follower (tracks targets).

The public command methods are implemented here, once, and always go through the device's SafetyLayer;
a driver only implements the wire side (_send_safe / _send_torque_safe), which accepts nothing but the
safety layer's output types. Every safe command reaches it through one method, _to_wire (drivers re-send
a hold through it too), where command observers see it: add_command_observer(fn) calls
fn(t_issued [s], t_sent [s], safe) with the SafeFollowerCommand / SafeLeaderTorque about to be sent (for
logs and recordings of what was really commanded). Watchdog: every read() and command call checks it;
real-time rigs also run WatchdogThread so a frozen loop still leaves the device safe.
"""

from __future__ import annotations

import abc
import dataclasses
import math
import threading
from operator import sub

import numpy as np

from hardware.clock import Clock
from hardware.reasons import Reason
from hardware.safety import (
    DEFAULT_WATCHDOG_S,
    PLAUSIBLE_JUMP_RAD,
    DeviceHold,
    SafeFollowerCommand,
    SafeLeaderTorque,
    SafetyLayer,
    implausible_jump,
)
from hardware.types import STATUS_IMPLAUSIBLE, STATUS_STALE, FollowerCommand, JointLimits, JointState
from hardware.wrap import unwrap_reading


class Device(abc.ABC):
    """Shared shell: connect/disconnect as a context manager, read() that feeds the watchdog."""

    # rad: the period a joint reading can be off by (a single-turn encoder: a full turn; hardware/wrap.py);
    # inf: the driver's reading is absolute. A driver whose readings wrap sets it (scalar or per joint).
    wrap_period_rad: float | np.ndarray = math.inf

    def __init__(self, name: str, limits: JointLimits, clock: Clock | None = None,
                 watchdog_s: float = DEFAULT_WATCHDOG_S):
        self.name = name
        self.clock = clock or Clock()
        self.safety = SafetyLayer(limits, watchdog_s=watchdog_s)
        self.n_joints = limits.n
        self._last_state = JointState.empty(limits.n)
        self._lock = threading.RLock()  # one bus transaction at a time (loop vs watchdog thread)
        self.in_safe_state = False
        self._observers: list = []
        self._q_ok: np.ndarray | None = None  # per joint: the last accepted position [rad] and its time [s]
        self._t_q_ok = np.full(limits.n, -math.inf)
        self._ok_floats: tuple | None = None  # (accepted q as floats, its time [s]) newer than the two above
        self.turns_unwrapped = 0  # joint samples read a whole turn off and put back on theirs, cumulative

    def add_command_observer(self, fn) -> None:
        """fn(t_issued, t_sent, safe) for every safe command before it goes on the wire, on the sending
        thread with the device lock held (keep it short: the teleop loop runs at 500 Hz). t_issued: when
        the command was asked for (clock read on entry, before the lock), t_sent: when it reached the wire
        side; a re-sent hold has t_issued == t_sent."""
        self._observers.append(fn)

    def remove_command_observer(self, fn) -> None:
        if fn in self._observers:
            self._observers.remove(fn)

    def _observe(self, safe, t_issued: float | None) -> None:
        t_sent = self.clock.now()
        for fn in self._observers:
            fn(t_sent if t_issued is None else t_issued, t_sent, safe)

    # -- wire side, per driver ---------------------------------------------------------------------
    @abc.abstractmethod
    def connect(self) -> None: ...

    @abc.abstractmethod
    def _disconnect_bus(self) -> None:
        """Release the port/bus (the safe state was already commanded)."""

    @abc.abstractmethod
    def _read(self) -> JointState | None:
        """One bus read; None when no fresh data arrived (the previous state stays)."""

    @property
    @abc.abstractmethod
    def is_connected(self) -> bool: ...

    @abc.abstractmethod
    def _go_safe(self, reason: Reason | str) -> None:
        """Command the device's safe state (through the safety layer)."""

    # -- shared logic ------------------------------------------------------------------------------
    def read(self) -> JointState:
        with self._lock:
            st = self._read()
            if st is not None:
                st = self._plausible(st)
                self._last_state = st
                self.safety.watchdog.feed_feedback(st.t)
            self.check_watchdog()
            return self._last_state

    def _plausible(self, st: JointState) -> JointState:
        """A joint whose sample jumped further than it can move since its last accepted sample (an encoder
        glitch) keeps that accepted value, flagged STATUS_IMPLAUSIBLE | STATUS_STALE (the pair then neither
        follows it nor counts the sample as fresh) and counted in safety.jumps_rejected."""
        q = np.asarray(st.q, dtype=float)
        if self._q_ok is None or q.shape != self._q_ok.shape or not math.isfinite(st.t):
            st, q = self._on_turn(st, q, None)  # a (re)start in another turn reads the same pose
            self._q_ok, self._t_q_ok, self._ok_floats = q.copy(), np.full(q.shape, st.t), None
            return st
        # the common case first, on floats: no joint moved more than a glitch-free step can in no time at all
        # (NaN fails the test and goes the full way, where it is never implausible); the accepted values kept
        # as the sample's floats and its time, put into the arrays when the full way needs them
        ql, ok = q.tolist(), self._ok_floats
        if all(map(PLAUSIBLE_JUMP_RAD.__ge__, map(abs, map(sub, ql, self._q_ok.tolist() if ok is None
                                                               else ok[0])))):
            self._ok_floats = (ql, st.t)
            return st
        if ok is not None:
            self._q_ok, self._t_q_ok, self._ok_floats = np.array(ok[0]), np.full(q.shape, ok[1]), None
        st, q = self._on_turn(st, q, self._q_ok)  # a reading a turn off is not a jump (hardware/wrap.py)
        bad = implausible_jump(q, self._q_ok, st.t - self._t_q_ok)
        if not bad.any():
            np.copyto(self._q_ok, q)
            self._t_q_ok.fill(st.t)
            return st
        good = ~bad
        self._q_ok[good], self._t_q_ok[good] = q[good], st.t
        self.safety.jumps_rejected += int(bad.sum())
        status = np.asarray(st.status, dtype=np.uint32).copy()
        status[bad] |= np.uint32(STATUS_IMPLAUSIBLE | STATUS_STALE)
        return dataclasses.replace(st, q=np.where(bad, self._q_ok, q), status=status)

    def _on_turn(self, st: JointState, q: np.ndarray, q_ref: np.ndarray | None
                 ) -> tuple[JointState, np.ndarray]:
        """The sample with each wrapping joint on its turn (inside the limits, nearest q_ref: the last
        accepted value), counted in turns_unwrapped; unchanged for a driver whose readings do not wrap."""
        if not np.any(np.isfinite(self.wrap_period_rad)):
            return st, q
        lim = self.safety.limits
        qu = unwrap_reading(q, q_ref, self.wrap_period_rad, lim.q_min, lim.q_max)
        moved = int(np.count_nonzero(np.isfinite(q) & (qu != q)))
        if not moved:
            return st, q
        self.turns_unwrapped += moved
        return dataclasses.replace(st, q=qu), qu

    @property
    def last_state(self) -> JointState:
        return self._last_state

    def check_watchdog(self) -> Reason | None:
        """Go safe if commands or feedback are stale; returns the reason (None when fine)."""
        reason = self.safety.watchdog.stale(self.clock.now())
        if reason is not None and not self.in_safe_state:
            with self._lock:  # looked at again under the lock: the app may have put it down meanwhile (a
                # loop ending late on a slowed core disconnected the leader while this thread waited here)
                if self.in_safe_state or not self.is_connected:
                    return reason
                self._go_safe(Reason.of(DeviceHold.WATCHDOG, stale=reason))
                self.in_safe_state = True
        return reason

    def disconnect(self) -> None:
        with self._lock:
            if self.is_connected:
                try:
                    self._go_safe(Reason.of(DeviceHold.DISCONNECT))
                finally:
                    self.in_safe_state = True
                    self._disconnect_bus()

    def __enter__(self):
        self.connect()
        return self

    def __exit__(self, *exc):
        self.disconnect()
        return False


class Leader(Device):
    """A human-driven arm given joint torques [N*m] (current control)."""

    @abc.abstractmethod
    def _send_torque_safe(self, safe: SafeLeaderTorque) -> None:
        """Write the currents for these (already limited) torques."""

    def _to_wire(self, safe: SafeLeaderTorque, t_issued: float | None = None) -> None:
        """The one way a safe torque reaches the driver (observers first; none: one list check)."""
        if self._observers:
            self._observe(safe, t_issued)
        self._send_torque_safe(safe)

    def command_torque(self, tau: np.ndarray) -> np.ndarray:
        """Ask for joint torques [N*m]; returns the torques actually sent after the limits."""
        now = self.clock.now()  # the time the command is issued (read before waiting for the device lock)
        with self._lock:
            safe = self.safety.leader(tau, now)
            self._to_wire(safe, now)
            self.in_safe_state = False
            return safe.tau

    def zero_torque(self, reason: Reason | str = "requested") -> None:
        now = self.clock.now()
        with self._lock:
            self._to_wire(self.safety.leader_zero(now, reason), now)
            self.in_safe_state = True

    def rest(self, reason: Reason | str = "resting") -> None:
        """Zero torque for a leader that will be neither commanded nor read for a while (a lean rollout's
        passive leader), then stand down what the device would take that silence for: a dead host (the
        Dynamixel Bus Watchdog latches and its latch reads as lost force feedback). The next command arms
        it again before its torque lands; the end's zero torque is such a command."""
        with self._lock:  # one transaction: no command lands between the zero torque and the stand-down
            self.zero_torque(reason)
            self._rest_fallback()

    def _rest_fallback(self) -> None:
        """rest(), after its zero torque: stand down a fallback that watches for the host's silence (none
        in general)."""

    def _go_safe(self, reason: Reason | str) -> None:
        now = self.clock.now()
        self._to_wire(self.safety.leader_zero(now, reason), now)


class Follower(Device):
    """A robot arm that tracks joint position targets (optionally with feed-forward torque / MIT gains)."""

    @abc.abstractmethod
    def _send_safe(self, safe: SafeFollowerCommand) -> None:
        """Encode and send an (already limited) command; safe.hold means the device's hold/damping state."""

    def _to_wire(self, safe: SafeFollowerCommand, t_issued: float | None = None) -> None:
        """The one way a safe command reaches the driver (observers first; none: one list check). Drivers
        re-send their hold through here too."""
        if self._observers:
            self._observe(safe, t_issued)
        self._send_safe(safe)

    def command(self, cmd: FollowerCommand) -> SafeFollowerCommand:
        """Send a command through the limits; returns what was actually sent."""
        now = self.clock.now()  # the time the command is issued (read before waiting for the device lock)
        with self._lock:
            safe = self.safety.follower(cmd, now, self._last_state.q)
            self._to_wire(safe, now)
            self.in_safe_state = False
            return safe

    def hold(self, reason: Reason | str = "requested") -> None:
        with self._lock:
            self._go_safe(reason)
            self.in_safe_state = True

    def _go_safe(self, reason: Reason | str) -> None:
        now = self.clock.now()
        self._to_wire(self.safety.follower_hold(now, self._last_state.q, reason), now)


def make_safe(leaders, followers, reason: Reason | str) -> list[str]:
    """The safe state of every arm given: each leader at zero torque, each follower on hold (its safe
    state), every one attempted even when another fails. Returns one line per arm that failed ("" none)."""
    problems = []
    for act, devices in (("zero_torque", leaders), ("hold", followers)):
        for d in devices:
            try:
                getattr(d, act)(reason)
            except Exception as e:  # noqa: BLE001 -- the other arms must still be made safe
                problems.append(f"{d.name}: {e}")
    return problems


class WatchdogThread(threading.Thread):
    """Checks devices' watchdogs every period_s [s] of wall time (real-time rigs only)."""

    def __init__(self, devices: list[Device], period_s: float = 0.005):
        super().__init__(name="factr2-watchdog", daemon=True)
        self.devices, self.period_s = devices, period_s
        self._stop_evt = threading.Event()

    def run(self) -> None:
        while not self._stop_evt.wait(self.period_s):
            for d in self.devices:
                if d.is_connected:
                    d.check_watchdog()

    def stop(self) -> None:
        self._stop_evt.set()
