"""BufferedPortHandler's direct per-tick path (hardware/dynamixel/bus.py) on a real pty: the bytes, the
timeout, a write, and an unplugged device, as pyserial's own read / write behave."""

from __future__ import annotations

import os
import threading
import time

import pytest
import serial

from hardware.dynamixel.bus import READ_BLOCK_S, BufferedPortHandler

pty = pytest.importorskip("pty")


@pytest.fixture
def port():
    master, slave = pty.openpty()
    ph = BufferedPortHandler(os.ttyname(slave))
    ph.baudrate = 1_000_000
    assert ph.openPort()
    ph.ser.timeout, ph.ser.write_timeout = READ_BLOCK_S, 0
    yield ph, master
    ph.closePort()
    for fd in (master, slave):
        try:
            os.close(fd)
        except OSError:
            pass


def test_a_whole_reply_is_read_in_pieces_as_it_arrives(port):
    ph, master = port
    reply = bytes(range(60))

    def answer():
        os.write(master, reply[:25])
        time.sleep(0.0003)
        os.write(master, reply[25:])

    threading.Thread(target=answer).start()
    got = b""
    t_end = time.monotonic() + 0.5
    while len(got) < len(reply) and time.monotonic() < t_end:
        got += ph.readPort(len(reply) - len(got))
    assert got == reply


def test_silence_returns_nothing_after_the_block_time(port):
    ph, _ = port
    t0 = time.monotonic()
    assert ph.readPort(40) == b""
    assert time.monotonic() - t0 < 0.05  # READ_BLOCK_S (1 ms) plus scheduling, never the packet timeout


def test_write_goes_out_whole_and_a_list_of_ints_is_taken(port):
    ph, master = port
    assert ph.writePort(b"\xff\xff\xfd\x00\x01") == 5
    assert ph.writePort([1, 2, 3]) == 3  # the sdk's own transactions pass lists
    time.sleep(0.01)
    assert os.read(master, 100) == b"\xff\xff\xfd\x00\x01\x01\x02\x03"


def test_clear_drops_waiting_bytes(port):
    ph, master = port
    os.write(master, bytes(50))
    time.sleep(0.01)
    ph.clearPort()
    assert ph.readPort(40) == b""


def test_an_unplugged_device_is_a_serial_error_not_silence(port):
    ph, master = port
    os.close(master)  # the adapter goes away: the slave reads EIO (pyserial raises the same class)
    with pytest.raises(serial.SerialException):
        ph.readPort(40)


def _fast_exchange(ph, master, reply: bytes | None, stale: bytes = b"") -> dict:
    """One fast sync read of servos 1, 2 on the pty; the servo side answers `reply` (None: silence) once the
    instruction is in. `stale`: bytes already waiting in the port before the instruction goes out."""
    from hardware.dynamixel.sync_io import SyncReadGroup, fast_sync_read

    if stale:
        os.write(master, stale)
        time.sleep(0.01)
    group = SyncReadGroup([1, 2], 126, 10)

    def servo():
        os.read(master, 100)  # the instruction
        if reply is not None:
            os.write(master, reply)

    t = threading.Thread(target=servo)
    t.start()
    got = fast_sync_read(ph, group, 30.0)
    t.join(1.0)
    return got


def _reply(fill: int) -> bytes:
    from hardware.dynamixel.fast_sync import build_fast_status

    return build_fast_status([(1, 0, bytes([fill]) * 10), (2, 0, bytes([fill + 1]) * 10)], 10)


def test_no_flush_after_a_whole_reply_but_a_stale_reply_after_a_lost_one_is_flushed(port):
    ph, master = port
    flushes = []
    clear = ph.clearPort
    ph.clearPort = lambda: (flushes.append(1), clear())[1]
    assert _fast_exchange(ph, master, _reply(1))[1][0] == bytes([1]) * 10
    assert ph.rx_clean and len(flushes) == 1  # the first read flushes (nothing known about the port)
    assert _fast_exchange(ph, master, _reply(3))[2][0] == bytes([4]) * 10
    assert ph.rx_clean and len(flushes) == 1  # the previous reply came whole: no tcflush
    assert _fast_exchange(ph, master, _reply(5)[:20]) == {}  # cut short: the read times out
    assert not ph.rx_clean
    # the lost reply's servo answers late, whole: without the flush the next read would take its data
    got = _fast_exchange(ph, master, _reply(7), stale=_reply(9))
    assert len(flushes) == 2 and got[1][0] == bytes([7]) * 10 and ph.rx_clean


def test_noise_after_a_whole_reply_is_dropped_by_the_header_search(port):
    ph, master = port
    assert _fast_exchange(ph, master, _reply(1)) and ph.rx_clean
    got = _fast_exchange(ph, master, _reply(3), stale=b"\x00\xff\xff")  # noise, then a header's first bytes
    assert got[1][0] == bytes([3]) * 10 and got[2][0] == bytes([4]) * 10


def test_any_other_read_or_a_short_write_needs_the_flush_again(port):
    ph, master = port
    assert _fast_exchange(ph, master, _reply(1)) and ph.rx_clean
    ph.readPort(11)  # an sdk transaction's read (a ping, a register read)
    assert not ph.rx_clean
    assert _fast_exchange(ph, master, _reply(1)) and ph.rx_clean
