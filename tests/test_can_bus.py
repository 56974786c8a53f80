"""hardware.can_bus: one-line open errors, the fast virtual bus, CanLink waits on a lockstep clock."""

from __future__ import annotations

import can
import pytest
from can.interfaces.virtual import VirtualBus

from hardware.can_bus import CanLink, float_to_uint, open_bus, uint_to_float
from hardware.can_virtual_bus import FastVirtualBus
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


def _key(m):
    return (m.timestamp, m.arbitration_id, bytes(m.data), m.dlc, m.is_rx, m.is_extended_id, m.channel)


def test_a_burst_reads_the_same_every_way():
    """A send_batch burst is one queue item on a FastVirtualBus receiver: recv(0), recv(timeout), recv with
    filters, take_pending and take_pending_raw all give its frames, in order, as single frames would."""
    clock = LockstepClock(1.5)
    tx = FastVirtualBus("cb-burst", clock=clock.now)
    rxs = [FastVirtualBus("cb-burst") for _ in range(5)]
    try:
        frames = [(0x2A1 + k, bytes([k, 7])) for k in range(4)]
        one = FastVirtualBus("cb-burst-ref", clock=clock.now)
        ref_rx = FastVirtualBus("cb-burst-ref")
        for arb_id, data in frames:
            one.send_fresh(arb_id, data)
        want = [_key(m) for m in ref_rx.take_pending()]
        tx.send_batch(frames)
        tx.send_fresh(0x99, b"\x01")  # a single frame after the burst keeps its place
        want1 = want + [(1.5, 0x99, b"\x01", 1, True, False, "cb-burst")]
        want = [(t, a, d, n, r, e, "cb-burst") for t, a, d, n, r, e, _ in want] + want1[-1:]
        a, b, c, d, e = rxs
        assert [_key(a.recv(0)) for _ in range(5)] == want and a.recv(0) is None
        assert [_key(b.recv(0.01)) for _ in range(5)] == want and b.recv(0.001) is None
        c.set_filters([{"can_id": 0x2A2, "can_mask": 0x7FF}])
        assert _key(c.recv(0.05)) == want[1] and c.recv(0.001) is None  # (recv(0) gives up on a mismatch)
        assert [_key(m) for m in d.take_pending()] == want
        assert e.recv(0) is not None  # the burst's first frame as a Message, the rest raw
        assert e.take_pending_raw() == [(a_, d_, False, False) for a_, d_ in frames[1:]] + [(0x99, b"\x01",
                                                                                           False, False)]
        c.set_filters(None)
        assert c.take_pending_raw() == []
    finally:
        for bus in (tx, one, ref_rx, *rxs):
            bus.shutdown()
