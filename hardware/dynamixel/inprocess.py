"""In-process Dynamixel transport for lockstep twins: a dynamixel-sdk PortHandler wired to an emulator.

SIMULATED. A lockstep twin (open_rig(..., clock="lockstep")) serves its Dynamixel leaders on a port named
"inproc:<name>" instead of a pseudo-terminal. DynamixelBus opens such a name with InProcessPortHandler:
writePort() hands the instruction packet to the emulator's parser on the caller's thread and the status
packets it answers are what readPort() returns next. The sdk's PacketHandler / GroupSyncRead /
GroupSyncWrite run unchanged on it, so the same bytes are built, checksummed and parsed as on a wire;
only the pty, the emulator thread and the GIL hand-offs per packet are gone, and the leader becomes as
deterministic as the CAN followers. The driver sees only the port object.

The pty stays the transport of real-time twins, serve_twin / `factr2 twin` and third-party clients (other
processes cannot reach an in-process port). Like python-can's virtual channels, an in-process port exists
only inside the process that serves it.
"""

from __future__ import annotations

import itertools
import threading
import weakref

import dynamixel_sdk as sdk
import serial

from hardware import sim_cpu

INPROC_PREFIX = "inproc:"
_lock = threading.Lock()
_ports: weakref.WeakValueDictionary = weakref.WeakValueDictionary()
_serial = itertools.count()


def is_inprocess(port_name: str) -> bool:
    return str(port_name).startswith(INPROC_PREFIX)


def register(emulator, name: str | None = None) -> str:
    """Serve `emulator` (a DynamixelEmulator with transport "inprocess") under a fresh port name."""
    with _lock:
        path = f"{INPROC_PREFIX}{name or 'dxl'}-{next(_serial)}"
        _ports[path] = emulator
        return path


def unregister(path: str) -> None:
    with _lock:
        _ports.pop(path, None)


def lookup(path: str):
    """The emulator serving `path`, or None."""
    with _lock:
        return _ports.get(path)


class InProcessPortHandler(sdk.PortHandler):
    """sdk PortHandler whose bytes go to an in-process DynamixelEmulator synchronously.

    The emulator has answered by the time writePort returns, so a reply that is not in the buffer will
    never come: isPacketTimeout() is true at once (a silent servo costs no wall time; the sdk reports
    COMM_RX_TIMEOUT exactly as after a wire timeout). The baud rate set on the port is the line rate the
    emulated servos compare with their Baud Rate(8), as the pty's termios rate is."""

    def __init__(self, port_name: str):
        super().__init__(port_name)
        self._rx = bytearray()
        self._emu = None

    def setupPort(self, cflag_baud):  # noqa: N802 -- sdk name
        emu = lookup(self.port_name)
        if emu is None:
            raise serial.SerialException(f"no in-process Dynamixel port {self.port_name} in this process")
        self._emu, self.is_open = emu, True
        self._rx.clear()
        self.tx_time_per_byte = (1000.0 / self.baudrate) * 10.0
        return True

    def closePort(self):  # noqa: N802 -- sdk name
        self._emu, self.is_open = None, False
        self._rx.clear()

    def clearPort(self):  # noqa: N802 -- sdk name
        self._rx.clear()

    def getBytesAvailable(self):  # noqa: N802 -- sdk name
        return len(self._rx)

    def readPort(self, length):  # noqa: N802 -- sdk name
        out = bytes(self._rx[:length])
        del self._rx[:length]
        return out

    def writePort(self, packet):  # noqa: N802 -- sdk name
        emu = self._emu
        if emu is None or emu.closed:
            return 0  # like a port whose device went away: the sdk reports COMM_TX_FAIL
        with sim_cpu.simulated():  # the servos' work, not the app's (hardware/sim_cpu.py)
            self._rx += emu.serve(bytes(packet), self.baudrate)
        return len(packet)

    def setPacketTimeoutMillis(self, msec):  # noqa: N802 -- sdk name
        # no start time: isPacketTimeout below never waits (the sdk's reads the wall clock, a time.time and a
        # round, every tick's sync read)
        self.packet_timeout = msec

    def isPacketTimeout(self):  # noqa: N802 -- sdk name
        self.packet_timeout = 0
        return True
