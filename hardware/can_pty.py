"""A CAN bus between processes on a pseudo-terminal: python-can interface "pty" (SIMULATED wire).

python-can's "virtual" channels live inside one process, so a twin served by another process (`factr2 twin
--can-pty`, hardware/process_twin.py) cannot reach a driver through one. A pty can: the twin holds the
master side (`PtyCanBus.serve()`), a driver opens the slave path as a rig's channel with interface = "pty"
(hardware.can_bus.open_bus). Both ends carry fixed 17-byte records, one per frame:

    C4 4E | uint32 big-endian arbitration id (bit 31 extended, bit 30 remote, bit 29 error frame) | uint8 DLC
    | 8 data | uint16 big-endian CRC-32 & 0xFFFF of the 13 bytes before it

A pty may take part of a write when its buffer is full: the reader then finds the next sync bytes and a good
checksum (a frame cut so is lost, as a corrupted frame on a bus is).

A side whose reader stops (a killed or stopped app) loses the frames that overflow the kernel's pty buffer,
as a CAN controller's receive queue would; writes never block. No bit timing is modelled.
"""

from __future__ import annotations

import os
import select
import struct
import time
import tty
import zlib

import can

RECORD = struct.Struct(">2sIB8sH")
SYNC = b"\xc4\x4e"
_BODY = struct.Struct(">IB8s")
FLAG_EXT, FLAG_RTR, FLAG_ERR = 1 << 31, 1 << 30, 1 << 29
ID_MASK = 0x1FFFFFFF


def encode(arb_id: int, data: bytes, ext: bool = False, rtr: bool = False, err: bool = False) -> bytes:
    """One frame as its 13-byte record."""
    flags = (FLAG_EXT if ext else 0) | (FLAG_RTR if rtr else 0) | (FLAG_ERR if err else 0)
    d = bytes(data)[:8]
    body = _BODY.pack((arb_id & ID_MASK) | flags, len(d), d.ljust(8, b"\0"))
    return SYNC + body + struct.pack(">H", zlib.crc32(body) & 0xFFFF)


def decode(buf: bytes | bytearray) -> tuple[list[tuple[int, bytes, bool, bool]], int]:
    """Whole good records in buf -> ([(arb_id, data, is_extended, is_remote_or_error)], bytes used); bytes
    that are not a good record are skipped up to the next sync."""
    out, i, n, size = [], 0, len(buf), RECORD.size
    while n - i >= size:
        if buf[i:i + 2] != SYNC:
            j = buf.find(SYNC, i + 1)
            i = j if j >= 0 else n - 1
            continue
        _, a, dlc, d, crc = RECORD.unpack_from(buf, i)
        if zlib.crc32(bytes(buf[i + 2:i + 15])) & 0xFFFF != crc:
            i += 1
            continue
        out.append((a & ID_MASK, d[:min(dlc, 8)], bool(a & FLAG_EXT), bool(a & (FLAG_RTR | FLAG_ERR))))
        i += size
    return out, i


class PtyCanBus(can.BusABC):
    """One end of a pty CAN link. PtyCanBus(path) opens the slave (a driver's side); PtyCanBus.serve() makes
    a new pty and returns the master side, whose .channel_info is the slave path to hand out."""

    def __init__(self, channel: str, fd: int | None = None, keep_fd: int | None = None, **kwargs):
        if fd is None:
            try:
                fd = os.open(channel, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
            except OSError as e:
                msg = f"cannot open pty CAN channel {channel}: {e.strerror}"
                raise can.CanInitializationError(msg) from None
            tty.setraw(fd)
        os.set_blocking(fd, False)
        self._fd, self._keep = fd, keep_fd  # keep: the slave a serving side holds open (no EIO when apps go)
        self._buf = bytearray()
        self.channel_info = channel
        self.tx_dropped = 0  # frames a full pty did not take (the other side is not reading)
        super().__init__(channel=channel, **kwargs)

    @classmethod
    def serve(cls) -> PtyCanBus:
        master, slave = os.openpty()
        tty.setraw(slave)
        return cls(os.ttyname(slave), fd=master, keep_fd=slave)

    # -- send ----------------------------------------------------------------------------------------------
    def _write(self, data: bytes) -> None:
        try:
            n = os.write(self._fd, data)
        except (BlockingIOError, InterruptedError):
            n = 0
        except OSError:  # the other side is gone (EIO): the frames are lost, as on an unplugged bus
            n = 0
        if n < len(data):
            self.tx_dropped += (len(data) - n + RECORD.size - 1) // RECORD.size

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._write(encode(msg.arbitration_id, msg.data, msg.is_extended_id, msg.is_remote_frame,
                           msg.is_error_frame))

    def send_fresh(self, arb_id: int, data: bytes) -> None:
        self._write(encode(arb_id, data))

    def send_batch(self, frames) -> None:
        self._write(b"".join(encode(a, d) for a, d in frames))

    # -- receive -------------------------------------------------------------------------------------------
    def _fill(self) -> None:
        while True:
            try:
                chunk = os.read(self._fd, 65536)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:  # EIO: no process holds the other side
                return
            if not chunk:
                return
            self._buf += chunk

    def take_pending_raw(self) -> list[tuple[int, bytes, bool, bool]]:
        """Every whole frame that arrived, without Message objects."""
        self._fill()
        frames, used = decode(self._buf)
        del self._buf[:used]
        return frames

    def take_pending(self) -> list[can.Message]:
        now = time.monotonic()
        return [can.Message(timestamp=now, arbitration_id=a, data=d, is_extended_id=e, is_remote_frame=r,
                            check=False) for a, d, e, r in self.take_pending_raw()]

    def _recv_internal(self, timeout: float | None):
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            if len(self._buf) < RECORD.size:
                self._fill()
            frames, used = [], 0
            if len(self._buf) >= RECORD.size:  # a window holding at most one record
                frames, used = decode(self._buf[:2 * RECORD.size - 1])
            if used:
                del self._buf[:used]
            if frames:
                (a, d, e, r), = frames[:1]
                return can.Message(timestamp=time.monotonic(), arbitration_id=a, data=d, is_extended_id=e,
                                   is_remote_frame=r, check=False), False
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0:
                return None, False
            select.select([self._fd], [], [], left if left is not None else 0.1)

    def shutdown(self) -> None:
        for fd in (self._fd, self._keep):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._fd, self._keep = -1, None
        super().shutdown()
