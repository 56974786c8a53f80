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
