"""A chain of Dynamixel X servos (Protocol 2.0) on a pseudo-terminal (or in-process), driven by a MotorBank.

SIMULATED DEVICE. dynamixel-sdk (and so DynamixelLeader and `factr2 doctor`) talk to `port_path`
exactly as to /dev/ttyUSB0. Each servo has its own control table (EEPROM below address 64, RAM above);
present current/velocity/position/temperature come from bank.read() at the moment a read is answered;
goal current (torque on, current mode) goes to bank.command_current, goal position (position modes) to
bank.command_position, torque off to bank.enable(False).

Physical assembly: servo i drives bank motor indices[i] with servo_angle = sign*q_joint + offset_rad
(the same convention as DynamixelLeaderConfig), so a twin passes the rig's signs/offsets and the leader
reads back joint angles. Present position counts turns from power-on like a real servo (it starts in
[0, 4096) and is unwrapped afterwards); reboot() resets that.

Threading: one daemon thread reads the pty master, parses with protocol.PacketParser and answers.
bank methods are called from that thread; pass bank_lock if the bank is stepped from another thread.
drain(timeout) returns once every byte written to the port so far has been read and handled -- a lockstep
twin calls it before stepping physics so that a sync write has landed.

transport="inprocess": no pty and no thread; `port_path` is an "inproc:..." name that DynamixelBus opens
with hardware.dynamixel.inprocess.InProcessPortHandler, whose writes call serve() on the caller's thread
(lockstep twins: deterministic, no syscalls or thread hand-offs per packet).

Faults: drop_prob ignores each instruction packet with that probability (no reply, no effect);
set_silent(True) (or silent_ids) makes servos ignore everything, as if unpowered; corrupt_prob flips one
byte of each status packet with that probability (a noisy line: the host sees CRC errors); spike_rad (per
bank motor, rad) is added to the present position of the next read only (an encoder glitch), then cleared.
"""

from __future__ import annotations

import math
import os
import select
import termios
import threading
import time
import tty
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from hardware.dynamixel import protocol as p
from hardware.dynamixel.emulator_instructions import EmulatorInstructions
from hardware.dynamixel.emulator_watchdog import EmulatorWatchdog
from hardware.dynamixel.models import resolve_models
from hardware.dynamixel.servo_table import FIRMWARE_VERSION, ServoTable

if TYPE_CHECKING:  # the contract only: a device folder does not import the twin (no import cycle)
    from hardware.sim.motors import MotorBank

SEEN_PACKETS_MAX = 16  # in-process: recent clean writes whose parse is reused (a parse is a pure function)
PARTIAL_TIMEOUT_S = 0.05  # an incomplete packet older than this is dropped (the servo's rx timeout)
IDLE_WAKE_S = 0.02  # the thread's longest wait for bytes [s]: partial-packet timeouts are checked this often
# The thread's shortest wait for a watchdog deadline [s of wall time]. The deadline is on the servos' clock (a
# twin's sim time), the wait on the wall clock: a clock frozen at or just before the deadline (a paused twin,
# or its physics thread starved by this one, which runs SCHED_FIFO above it) would otherwise make the wait ~0
# and the thread spin. A servo then latches at most this late: 5 % of one 20 ms watchdog unit.
WAKE_MIN_S = 1e-3
# termios speed constant -> bit/s, to see the rate the client set on the port (baud mismatch = no answer)
_TERMIOS_RATES = {
    getattr(termios, f"B{r}"): r
    for r in (9600, 57600, 115200, 1_000_000, 2_000_000, 3_000_000, 4_000_000)
    if hasattr(termios, f"B{r}")
}


class DynamixelEmulator(EmulatorInstructions, EmulatorWatchdog):
    """Serve Protocol 2.0 for servos `ids` (one per bank motor in `indices`, default 0..n-1) on a pty.

    models: one name for all or one per id. signs/offsets_rad: servo_angle = sign*q_joint + offset.
    return_delay / operating_mode / baud: initial EEPROM values (factory: 250 = 500 us, 3 = position,
    57600; the default baud is the rig's 4 Mbit/s). A servo ignores packets when the rate the client set on
    the pty (termios) differs from its Baud Rate(8), as garbage on a real wire would be.
    emulate_return_delay: sleep Return Delay Time(9) before each reply, like the firmware.
    firmware: Firmware Version(6), one for all or one per id (default 52); below v45 a servo does not know
    Fast Sync Read (0x8A) and stays silent in it, as old firmware does.
    clock: () -> s for the servos' Realtime Tick (default the wall clock; a twin passes the rig clock so
    that a lockstep run reads no wall time).
    """

    def __init__(
        self,
        bank: MotorBank,
        ids: list[int],
        models: str | list[str] = "XL330-M288",
        *,
        indices: list[int] | None = None,
        signs: list[float] | None = None,
        offsets_rad: list[float] | None = None,
        return_delay: int = 250,
        operating_mode: int = p.OP_MODE_POSITION,
        baud: int = 4_000_000,
        drop_prob: float = 0.0,
        silent_ids: set[int] | None = None,
        emulate_return_delay: bool = True,
        bank_lock: threading.Lock | None = None,
        seed: int | None = None,
        transport: str = "pty",
        clock: Callable[[], float] | None = None,
        firmware: int | list[int] = FIRMWARE_VERSION,
    ):
        if transport not in ("pty", "inprocess"):
            raise ValueError(f"transport must be 'pty' or 'inprocess', got {transport!r}")
        n = len(ids)
        self.bank = bank
        self.drop_prob = float(drop_prob)
        self.silent_ids: set[int] = set(silent_ids or ())
        self.silent = False
        self.corrupt_prob = 0.0
        self._corrupt_rng = np.random.default_rng(None if seed is None else seed + 1)  # apart: no-fault draws
        self.spike_rad: np.ndarray | None = None
        self.emulate_return_delay = emulate_return_delay
        self._bank_lock = bank_lock or threading.Lock()
        self._rng = np.random.default_rng(seed)
        baud_code = {v: k for k, v in p.BAUD_CODES.items()}.get(baud, 1)
        mods = resolve_models(models, n)
        indices = list(range(n)) if indices is None else list(indices)
        signs = [1.0] * n if signs is None else list(signs)
        offsets = [0.0] * n if offsets_rad is None else list(offsets_rad)
        fws = [int(firmware)] * n if isinstance(firmware, int) else [int(f) for f in firmware]
        self.servos: list[ServoTable] = [
            ServoTable(i, m, idx, float(s), float(o), return_delay, operating_mode, baud_code, fw)
            for i, m, idx, s, o, fw in zip(ids, mods, indices, signs, offsets, fws)
        ]
        self.parser = p.PacketParser()
        self.dropped = self.replies = self.instructions = self.write_overflows = 0
        self.transport, self.closed = transport, False
        self._reply_buf: list[bytes] | None = None  # in-process: replies of the packet being served
        self._seen: dict[bytes, list] = {}  # in-process: bytes served recently -> their parsed packets
        self._pending_current: list[tuple[int, float]] | None = None
        self._line_rate: int | None = None
        self._cv = threading.Condition()
        self._busy = False
        self._stop = threading.Event()
        self._last_rx = time.monotonic()  # pty thread only (a real-time transport): partial-packet timeout
        self._tick_clock = clock or time.monotonic
        self._wd_armed = False  # some servo has Bus Watchdog(98) > 0 and torque on (_watchdog_* below)
        self._wd_due = math.inf  # the earliest deadline [s of the clock]: nothing can expire before it
        self._wd_min_period = math.inf  # the shortest armed period [s]
        # (servo id, its deadline, when the emulator stopped it [s of the clock]: later by the thread's wake)
        self.watchdog_trips: list[tuple[int, float, float]] = []
        self._refresh()  # power-on: latch each servo's turn base
        self._thread: threading.Thread | None = None
        if transport == "inprocess":
            from hardware.dynamixel import inprocess

            self._path = inprocess.register(self)
            return
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self._path = os.ttyname(self._slave)
        self._thread = threading.Thread(target=self._run, name="dxl-emulator", daemon=True)
        self._thread.start()

    # -- public --------------------------------------------------------------------------------------
    def set_realtime(self, priority: int):
        """SCHED_FIFO for the serving thread (a real-time twin: servos answer in bounded time). None when set
        (or nothing to set: in-process transport), else why not (hardware.realtime.set_fifo)."""
        from hardware.realtime import set_fifo

        th = self._thread
        return None if th is None or th.native_id is None else set_fifo(priority, th.native_id)

    @property
    def port_path(self) -> str:
        return self._path

    def servo(self, dxl_id: int) -> ServoTable:
        return next(s for s in self.servos if s.id == dxl_id)

    def set_silent(self, on: bool = True) -> None:
        self.silent = bool(on)

    def set_hardware_error(self, dxl_id: int, bits: int) -> None:
        """Fault injection: Hardware Error Status(70) bits (e.g. 1 << 5 overload). Like the firmware, the
        servo drops torque and flags the alert bit in every status until rebooted."""
        s = self.servo(dxl_id)
        s.table[p.ADDR_HARDWARE_ERROR_STATUS[0]] = bits & 0xFF
        if bits:
            self._write(s, p.ADDR_TORQUE_ENABLE[0], b"\x00")

    def serve(self, data: bytes, line_rate: int | None = None) -> bytes:
        """In-process transport: handle these bytes from the host (at line_rate bit/s) now; returns the
        status packets the servos answer, back to back as the wire would carry them."""
        self._line_rate = line_rate
        self._reply_buf = out = []
        try:
            parser = self.parser
            pkts = self._seen.get(data) if not parser.buf else None
            if pkts is not None:  # the per-tick sync read (and an unchanged sync write) repeat byte for byte
                parser.packets += len(pkts)
            else:
                bad = parser.errors + parser.garbage_bytes
                pkts = parser.feed(data)
                if not parser.buf and parser.errors + parser.garbage_bytes == bad:  # parsed cleanly
                    if len(self._seen) >= SEEN_PACKETS_MAX:
                        self._seen.clear()
                    self._seen[data] = pkts
            for pkt in pkts:
                self._handle(pkt)
        finally:
            self._reply_buf = None
        return b"".join(out)

    def drain(self, timeout: float = 1.0) -> bool:
        """True once every byte written to the port so far was read and handled; False on timeout [s]."""
        if self._thread is None:
            return True  # in-process: every write was handled before it returned
        deadline = time.monotonic() + timeout
        poller = select.poll()
        poller.register(self._master, select.POLLIN)
        with self._cv:
            while True:
                if not self._busy and not poller.poll(0):
                    return True  # poll() also flushes the tty layer's pending work, so this is exact
                left = deadline - time.monotonic()
                if left <= 0 or not self._thread.is_alive():
                    return False
                self._cv.wait(min(left, 0.002))

    def close(self) -> None:
        self.closed = True
        self._stop.set()
        if self._thread is None:
            from hardware.dynamixel import inprocess

            inprocess.unregister(self._path)
            return
        self._thread.join(timeout=1.0)
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # -- thread --------------------------------------------------------------------------------------
    def _run(self) -> None:
        while not self._stop.is_set():
            wait = IDLE_WAKE_S
            if self._wd_armed:  # wake at the next watchdog deadline: the servo stops on time (WAKE_MIN_S)
                wait = min(wait, max(WAKE_MIN_S, self._wd_due - self._tick_clock()))
            try:
                ready, _, _ = select.select([self._master], [], [], wait)
            except (OSError, ValueError):
                return
            with self._cv:
                self._busy = True
            try:
                self._service(bool(ready))
            except OSError:
                pass  # the port went away (closed): keep going until stopped
            finally:
                with self._cv:
                    self._busy = False
                    self._cv.notify_all()

    def _service(self, ready: bool) -> None:
        now = time.monotonic()
        data = b""
        if ready:
            try:
                data = os.read(self._master, 65536)
            except BlockingIOError:
                data = b""
        if data:
            self._last_rx = now
            try:
                self._line_rate = _TERMIOS_RATES.get(termios.tcgetattr(self._slave)[4])
            except termios.error:
                self._line_rate = None
            for pkt in self.parser.feed(data):
                self._handle(pkt)
        elif self.parser.buf and now - self._last_rx > PARTIAL_TIMEOUT_S:
            self.parser.discard_partial()
        if self._wd_armed:
            self.poll_watchdogs()

    def _send(self, servo: ServoTable, pkt: bytes) -> None:
        if self.corrupt_prob and self._corrupt_rng.random() < self.corrupt_prob:
            k = int(self._corrupt_rng.integers(len(pkt)))
            pkt = pkt[:k] + bytes([pkt[k] ^ 0x5A]) + pkt[k + 1:]
        if self.emulate_return_delay:
            delay = servo.get(p.ADDR_RETURN_DELAY_TIME) * p.RETURN_DELAY_UNIT_S
            if delay > 0:
                time.sleep(delay)
        if self._reply_buf is not None:
            self._reply_buf.append(pkt)
            self.replies += 1
            return
        try:
            n = os.write(self._master, pkt)
            if n < len(pkt):
                self.write_overflows += 1
        except BlockingIOError:
            self.write_overflows += 1
        self.replies += 1

    def _live(self, dxl_id: int) -> list[ServoTable]:
        if self.silent:
            return []
        rate = self._line_rate
        return [
            s
            for s in self.servos
            if (dxl_id == p.BROADCAST_ID or s.id == dxl_id)
            and s.id not in self.silent_ids
            and (rate is None or p.BAUD_CODES.get(s.table[p.ADDR_BAUD_RATE[0]]) == rate)
        ]

    def _refresh(self, servos: list[ServoTable] | None = None) -> None:
        """Latch present values of these servos from one bank.read(). This runs on every read: per servo in
        Python floats (a handful of servos costs less so than ~30 small numpy calls); the rounding is
        half-to-even like protocol's numpy converters, and non-finite values latch 0."""
        servos = self.servos if servos is None else servos
        with self._bank_lock:
            r = self.bank.read()
        q, qd, cur, temp = r.q.tolist(), r.q_dot.tolist(), r.current.tolist(), r.temperature.tolist()
        if self.spike_rad is not None:  # one glitched sample, then the encoder reads true again
            q = (np.asarray(q) + self.spike_rad).tolist()
            self.spike_rad = None
        tick = int(self._tick_clock() * 1e3) % 32768
        rad_tick, rad_s_unit = p.RAD_PER_TICK, p.RAD_S_PER_VELOCITY_UNIT
        for s in servos:
            i, sg = s.index, s.sign
            s.refresh(_rint((sg * q[i] + s.offset_rad) / rad_tick), _rint(sg * qd[i] / rad_s_unit),
                      _rint(sg * cur[i] / s.model.amps_per_unit), _rint(temp[i]), abs(qd[i]) > 0.01, tick)


def _rint(x: float) -> int:
    """Nearest integer, halves to even (= numpy.rint); 0 for NaN / inf."""
    return round(x) if math.isfinite(x) else 0

