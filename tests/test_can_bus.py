"""hardware.can_bus: one-line open errors, the fast virtual bus, CanLink waits on a lockstep clock."""

from __future__ import annotations

import can
import pytest
from can.interfaces.virtual import VirtualBus

from hardware.can_bus import CanLink, FastVirtualBus, float_to_uint, open_bus, uint_to_float
from hardware.clock import LockstepClock
from hardware.errors import DeviceNotFound


@pytest.mark.parametrize("kw, words", [
    (dict(channel="can_nope3", interface="socketcan"), ["can_nope3", "ip link set can_nope3 up type can"]),
    (dict(channel="x", interface="no_such_interface"), ["not available", "fix:"]),
    (dict(channel="", interface="socketcan"), ["no CAN channel", "fix:"]),
])
def test_open_errors_are_one_line(kw, words):
    with pytest.raises(DeviceNotFound) as e:
        open_bus(**kw)
    msg = str(e.value)
    assert "\n" not in msg and all(w in msg for w in words)


def test_fast_virtual_bus_interoperates_with_python_can_virtual():
    fast, plain, other = open_bus("cb-1", "virtual"), VirtualBus("cb-1"), FastVirtualBus("cb-1")
    try:
        fast.send(can.Message(arbitration_id=0x123, data=b"\x01\x02", is_extended_id=False))
        assert plain.recv(0.1).data == b"\x01\x02" and other.recv(0).arbitration_id == 0x123
        assert fast.recv(0) is None  # no own messages
        plain.send(can.Message(arbitration_id=0x7, data=bytes(8), is_extended_id=False))
        assert fast.recv(0).arbitration_id == 0x7 and other.recv(0.01).arbitration_id == 0x7
        buf = bytearray(b"\xaa" * 8)
        fast.send_fresh(0x55, bytes(buf))
        buf[0] = 0  # the sender reusing its buffer does not change what was sent
        assert plain.recv(0.1).data[0] == 0xAA and other.recv(0).dlc == 8
    finally:
        for b in (fast, plain, other):
            b.shutdown()


def test_canlink_wait_advances_lockstep_clock():
    clock, seen = LockstepClock(), []
    bus = open_bus("cb-2", "virtual")
    peer = open_bus("cb-2", "virtual")
    clock.attach(lambda t: peer.send_fresh(0x1, b"\x00") if t >= 0.0105 else None)
    link = CanLink(bus, "cb-2", "virtual", clock)
    assert link.wait(lambda: bool(seen), 0.1, seen.append)
    assert 0.0105 <= clock.now() <= 0.012
    assert not link.wait(lambda: False, 0.005, seen.append) and clock.now() >= 0.0155
    bus.shutdown()
    peer.shutdown()


def test_uint_mapping_clamps_and_handles_nan():
    assert float_to_uint(float("nan"), -1, 1, 12) == 0
    assert float_to_uint(5, -1, 1, 12) == 4095 and float_to_uint(-5, -1, 1, 12) == 0
    assert uint_to_float(4095, -1, 1, 12) == 1.0 and uint_to_float(0, -1, 1, 12) == -1.0


def test_send_batch_and_take_pending_match_one_frame_at_a_time():
    """A feedback burst sent with send_batch reaches every other bus on the channel exactly as the same
    frames sent one by one (ids, data, order), and take_pending drains what recv(0) would return."""
    tx, rx_a, rx_b = FastVirtualBus("cb-batch"), FastVirtualBus("cb-batch"), VirtualBus("cb-batch")
    try:
        frames = [(0x2A1 + k, bytes([k, 255 - k, 7])) for k in range(5)]
        tx.send_batch(frames)
        for arb_id, data in frames:
            tx.send_fresh(arb_id, data)
        got = rx_a.take_pending()
        assert [(m.arbitration_id, bytes(m.data)) for m in got] == frames + frames
        assert all(not m.is_extended_id and m.is_rx for m in got)
        plain = [rx_b.recv(0) for _ in range(10)]
        assert [(m.arbitration_id, bytes(m.data)) for m in plain] == frames + frames
        assert rx_a.take_pending() == [] and rx_b.recv(0) is None
        assert tx.take_pending() == []  # own frames are not received (receive_own_messages off)
    finally:
        for b in (tx, rx_a, rx_b):
            b.shutdown()
