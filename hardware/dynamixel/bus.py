"""A thin shell over dynamixel-sdk (PortHandler, PacketHandler 2.0) for one port.

Turns sdk result codes into UserErrors with a fix, recovers a port left busy by Ctrl-C (COMM_PORT_BUSY),
and does sync reads whose per-servo replies are taken one by one so a lost reply only stales that servo.
The two per-tick transactions (sync read, sync write) are framed and parsed by this package's codec
(sync_io.py says why: the sdk's packet layer cost 100+ us per tick); the sdk opens the port and runs every
other transaction. Used by DynamixelLeader and by `factr2 doctor`. No fake fallback: a missing port is an
error. A port named "inproc:..." is a lockstep twin's in-process emulator (hardware/dynamixel/inprocess.py):
the same calls run on an InProcessPortHandler; it exists only in the process that serves it.
"""

from __future__ import annotations

import os
import select
import time

import dynamixel_sdk as sdk
import serial

try:
    import termios  # POSIX: the direct per-tick path below; elsewhere pyserial's calls
except ImportError:  # pragma: no cover -- not POSIX
    termios = None

from hardware.dynamixel import protocol as p
from hardware.dynamixel.inprocess import InProcessPortHandler, is_inprocess
from hardware.dynamixel.sync_io import (
    SyncReadGroup,
    SyncWriteGroup,
    fast_sync_read,
    fast_sync_read_reply,
    plain_sync_read,
    write_only,
)
from hardware.errors import ConfigError, DeviceError, DeviceNotFound
from hardware.serial_ports import read_latency_timer

USB_DEFAULT_LATENCY_MS = 16  # FTDI default, assumed when sysfs cannot be read on a ttyUSB port
WHOLE_READ_BYTES = 32  # a read this long is a whole reply (sync_io), not the sdk's header probe
READ_BLOCK_S = 0.001  # s: longest one sdk readPort() call may block (see open())
RX_MARGIN_MS = 4.0
# A pty is a twin/emulator on this host: its replies come late only when the OS starves a thread, not because
# they were lost, so wait longer before calling them lost.
RX_MARGIN_PTY_MS = 10.0  # ms added to the computed wire + latency time before a reply counts as lost


def _port_fix(port: str) -> str:
    if is_inprocess(port):
        return "an in-process twin port exists only in the process that serves it (use the twin's pty)"
    return (
        f"plug in the U2D2/adapter and check the path (`factr2 doctor` lists ports); "
        f"permission denied means: sudo usermod -aG dialout $USER and log in again ({port})"
    )


class BufferedPortHandler(sdk.PortHandler):
    """dynamixel-sdk's PortHandler whose readPort serves the sdk's many small reads (11 bytes, then the rest,
    per status packet) from one larger read of everything waiting: two syscalls per sync read instead of ~4
    per servo. Bytes and timeouts are unchanged; clearPort() drops the local buffer with the OS one.

    The per-tick calls (write, flush, the whole-reply read) go to the port's file descriptor directly, with
    pyserial's semantics (a non-blocking write returns what the OS took; a read blocks at most READ_BLOCK_S
    per call; a port that is readable but gives no bytes was unplugged: SerialException), without its
    per-call Timeout objects and abort pipe (this app never cancels a read). With the sync write's flush
    gone too (sync_io.write_only), the two per-tick transactions cost the loop 100-135 us of CPU a tick
    instead of 152 against a real-time twin's pty on the dev VM (issue #37; thread CPU of the calls, 10 s
    of `factr2 teleop --rig sim-piper`, two runs after, one before)."""

    def __init__(self, port_name: str):
        super().__init__(port_name)
        self._rx = bytearray()
        self._fd = -1
        # the last transaction was a fast sync read that took its whole, intact reply and left nothing in the
        # local buffer: the next read's input flush (a tcflush syscall on every tick) can go. Any other read,
        # a short write or an error (the sdk's own transactions read through readPort) clears it, so a stale
        # or partial reply is still flushed; bytes that come after a whole reply anyway (line noise) are
        # dropped by the fast read's header search (sync_io.fast_sync_read).
        self.rx_clean = False

    def mark_clean(self) -> None:
        """sync_io: the fast read just took its whole reply; clean unless bytes beyond it are buffered."""
        self.rx_clean = not self._rx

    def setupPort(self, cflag_baud):  # noqa: N802 -- sdk name
        ok = super().setupPort(cflag_baud)
        self._fd = getattr(self.ser, "fd", -1) if termios is not None else -1
        return ok

    def closePort(self):  # noqa: N802 -- sdk name
        self._fd = -1
        super().closePort()

    def readPort(self, length):  # noqa: N802 -- sdk name
        self.rx_clean = False
        if len(self._rx) < length:
            want = length - len(self._rx)
            # a whole reply asked for at once (sync_io: the fast reply's length) needs no in_waiting ioctl;
            # the sdk's small reads (11 bytes, then the rest) take whatever is waiting with them
            if want >= WHOLE_READ_BYTES and self._fd >= 0:
                self._read_fd(want)
            else:
                self._rx += self.ser.read(max(want, self.ser.in_waiting))
        out = bytes(self._rx[:length])
        del self._rx[:length]
        return out

    def _read_fd(self, want: int) -> None:
        """Up to `want` bytes into the buffer, blocking at most READ_BLOCK_S (pyserial's read, direct)."""
        fd, rx = self._fd, self._rx
        end, goal = time.monotonic() + READ_BLOCK_S, len(rx) + want
        while len(rx) < goal:
            left = end - time.monotonic()
            try:
                if not select.select((fd,), (), (), max(left, 0.0))[0]:
                    return  # timed out
                buf = os.read(fd, goal - len(rx))
            except InterruptedError:
                continue
            except BlockingIOError:
                buf = None
            except OSError as e:
                raise serial.SerialException(f"read failed: {e}") from None
            if buf is not None:
                if not buf:  # readable with nothing in it: pyserial's sign of an unplugged device
                    raise serial.SerialException("device reports readiness to read but returned no data "
                                                 "(device disconnected or multiple access on port?)")
                rx += buf
            if left <= 0.0:
                return

    def writePort(self, packet):  # noqa: N802 -- sdk name
        if self._fd < 0:
            return super().writePort(packet)
        try:  # non-blocking (open() sets write_timeout 0): the bytes the OS took; a short count is a failure
            n = os.write(self._fd, packet if isinstance(packet, (bytes, bytearray)) else bytes(packet))
        except (BlockingIOError, InterruptedError):
            self.rx_clean = False
            return 0
        except OSError as e:
            self.rx_clean = False
            raise serial.SerialException(f"write failed: {e}") from None
        if n != len(packet):  # half an instruction out: what answers it must be flushed
            self.rx_clean = False
        return n

    def clearPort(self):  # noqa: N802 -- sdk name
        self._rx.clear()
        if self._fd >= 0:
            termios.tcflush(self._fd, termios.TCIFLUSH)  # pyserial's reset_input_buffer
        else:
            super().clearPort()

    def getBytesAvailable(self):  # noqa: N802 -- sdk name
        return len(self._rx) + self.ser.in_waiting


class DynamixelBus:
    """One open serial port speaking Protocol 2.0 through dynamixel-sdk."""

    def __init__(self, port: str, baud: int, where: str = "dynamixel"):
        self.port_name, self.baud, self.where = port, int(baud), where
        self.port: BufferedPortHandler | InProcessPortHandler | None = None
        self.ph = sdk.PacketHandler(2.0)
        self.busy_recoveries = 0
        self.latency_timer_ms = read_latency_timer(port)

    # -- open / close ---------------------------------------------------------------------------------
    def open(self) -> None:
        inproc = is_inprocess(self.port_name)
        if not inproc and not os.path.exists(self.port_name):
            raise DeviceNotFound(
                f"serial port {self.port_name} does not exist",
                where=self.where,
                fix=_port_fix(self.port_name),
            )
        ph = InProcessPortHandler(self.port_name) if inproc else BufferedPortHandler(self.port_name)
        if ph.getCFlagBaud(self.baud) <= 0:
            raise ConfigError(
                f"baud {self.baud} is not a rate dynamixel-sdk can set",
                where=self.where,
                fix="use 57600, 1000000, 2000000, 3000000 or 4000000 (set the servos to match)",
            )
        ph.baudrate = self.baud
        try:
            ok = ph.openPort()
        except (serial.SerialException, OSError) as e:
            raise DeviceNotFound(
                f"cannot open {self.port_name}: {e}", where=self.where, fix=_port_fix(self.port_name)
            ) from None
        if not ok:
            raise DeviceNotFound(
                f"cannot open {self.port_name}", where=self.where, fix=_port_fix(self.port_name)
            )
        # dynamixel-sdk opens the port with timeout=0 and spins on it while waiting for a reply, burning a
        # core the servos' host (or a twin) needs; a short blocking read returns as soon as the bytes the sdk
        # asked for are in, so latency is unchanged and the spin is gone.
        if not inproc:
            ph.ser.timeout = READ_BLOCK_S
            # pyserial's blocking write follows every os.write with a select() until the tty is writable
            # again (a second syscall, ~15 us on the dev VM, twice per tick); non-blocking it returns the
            # bytes written, and a short count (a full tty buffer: a dead adapter) is a failed write
            ph.ser.write_timeout = 0
        self.port = ph

    def close(self) -> None:
        if self.port is not None:
            try:
                self.port.closePort()
            finally:
                self.port = None

    @property
    def is_open(self) -> bool:
        return self.port is not None and self.port.is_open

    def _ready(self) -> sdk.PortHandler:
        if self.port is None:
            raise DeviceError("port is not open", where=self.where, fix="call connect() first")
        if self.port.is_using:  # a Ctrl-C inside an sdk transaction leaves the flag set
            self.port.is_using = False
            self.port.clearPort()
            self.busy_recoveries += 1
        return self.port

    # -- timing ---------------------------------------------------------------------------------------
    def effective_latency_ms(self) -> float:
        if self.latency_timer_ms is not None:
            return float(self.latency_timer_ms)
        return float(USB_DEFAULT_LATENCY_MS) if "ttyUSB" in self.port_name else 0.0

    def rx_timeout_ms(self, n_bytes: int, n_servos: int, return_delay_s: float = 0.0) -> float:
        """Reply wait [ms]: wire time (10 bits/byte) + 2 latency-timer periods + return delays + margin."""
        wire_ms = n_bytes * 10.0 / self.baud * 1e3
        margin = RX_MARGIN_PTY_MS if self.port_name.startswith("/dev/pts/") else RX_MARGIN_MS
        return wire_ms + 2.0 * self.effective_latency_ms() + n_servos * return_delay_s * 1e3 + margin

    # -- single-servo transactions ------------------------------------------------------------------
    def ping(self, dxl_id: int) -> tuple[int, int] | None:
        """(model number, firmware version) or None when the id does not answer."""
        model, res, _err = self.ph.ping(self._ready(), dxl_id)
        if res != sdk.COMM_SUCCESS:
            return None
        fw, res2, _ = self.ph.read1ByteTxRx(self._ready(), dxl_id, p.ADDR_FIRMWARE_VERSION[0])
        return int(model), int(fw) if res2 == sdk.COMM_SUCCESS else -1

    def broadcast_ping(self) -> list[int]:
        """Ids that answer a broadcast ping (takes ~0.8 s: only on error paths and in the doctor)."""
        data, res = self.ph.broadcastPing(self._ready())
        return sorted(int(i) for i in data) if res == sdk.COMM_SUCCESS else []

    def read(self, dxl_id: int, field: tuple[int, int], signed: bool = False) -> int:
        addr, size = field
        data, res, err = self.ph.readTxRx(self._ready(), dxl_id, addr, size)
        self._check(dxl_id, f"read of address {addr}", res, err)
        return p.from_le(bytes(data[:size]), signed)

    def write(self, dxl_id: int, field: tuple[int, int], value: int) -> None:
        addr, size = field
        res, err = self.ph.writeTxRx(self._ready(), dxl_id, addr, size, list(p.le(int(value), size)))
        self._check(dxl_id, f"write of address {addr}", res, err)

    def reboot(self, dxl_id: int) -> None:
        """Reboot instruction: clears Hardware Error Status; the servo comes back with its torque off."""
        res, err = self.ph.reboot(self._ready(), dxl_id)
        self._check(dxl_id, "reboot", res, err & ~p.ERR_ALERT_BIT)

    def _check(self, dxl_id: int, what: str, res: int, err: int) -> None:
        if res != sdk.COMM_SUCCESS:
            raise DeviceError(
                f"servo {dxl_id}: {what} failed ({self.ph.getTxRxResult(res).strip('[]')})",
                where=f"{self.where} {self.port_name}",
                fix="check power, cabling and that no other program uses the port",
            )
        if err & 0x7F:
            fix = (
                "torque must be off to write EEPROM"
                if err & 0x7F == p.ERR_ACCESS
                else "check the value and the servo model"
            )
            raise DeviceError(
                f"servo {dxl_id}: {what} answered {p.describe_error(err)}",
                where=f"{self.where} {self.port_name}",
                fix=fix,
            )

    # -- per-tick group transactions -------------------------------------------------------------------
    def make_sync_read(self, ids: list[int], field: tuple[int, int]) -> SyncReadGroup:
        return SyncReadGroup(list(ids), field[0], field[1])

    def make_sync_write(self, ids: list[int], field: tuple[int, int]) -> SyncWriteGroup:
        return SyncWriteGroup(list(ids), field[0], field[1])

    def sync_read(
        self, group: SyncReadGroup, ids: list[int], timeout_ms: float, fast: bool = False
    ) -> dict[int, tuple[bytes, int]]:
        """One sync read; {id: (data, status error byte)} for the servos that answered in time.

        fast: Fast Sync Read (0x8A, hardware/dynamixel/fast_sync.py). ids must be the group's, in its order.
        A reply that is corrupt or cut short gives the servos whose blocks came intact before the damage,
        garbage gives {} -- never an exception (sync_io.py)."""
        if list(ids) != group.ids:
            raise ValueError(f"sync read ids {list(ids)} are not the group's {group.ids}")
        port = self._ready()
        return (fast_sync_read if fast else plain_sync_read)(port, group, timeout_ms)

    def fast_sync_read_reply(self, group: SyncReadGroup, timeout_ms: float) -> tuple[bytearray, bool]:
        """One Fast Sync Read's raw reply and whether it came whole with its CRC (sync_io.py): the leader
        decodes it straight from the bytes (leader_math.FastReplyDecoder), split_fast_status otherwise."""
        return fast_sync_read_reply(self._ready(), group, timeout_ms)

    def sync_write(self, group: SyncWriteGroup, values: dict[int, bytes]) -> bool:
        return write_only(self._ready(), group.packet(values))

    def sync_write_ints(self, group: SyncWriteGroup, values) -> bool:
        """sync_write of one signed integer per servo in the group's id order."""
        return write_only(self._ready(), group.packet_ints(values))

    def measure_round_trip(
        self,
        read_group: SyncReadGroup,
        ids: list[int],
        timeout_ms: float,
        write_group: SyncWriteGroup | None = None,
        values: dict[int, bytes] | None = None,
        n: int = 20,
        fast: bool = False,
    ) -> tuple[float, int]:
        """Median seconds of one sync read (+ one sync write) over n tries, and how many were complete."""
        times, complete = [], 0
        for _ in range(n):
            t0 = time.perf_counter()
            got = self.sync_read(read_group, ids, timeout_ms, fast)
            if write_group is not None and values is not None:
                self.sync_write(write_group, values)
            times.append(time.perf_counter() - t0)
            complete += len(got) == len(ids)
        times.sort()
        return times[len(times) // 2], complete
