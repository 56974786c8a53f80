"""The leader's per-tick wire path against its reference: the Fast Sync Read reply decoded straight from its
bytes (leader_math.FastReplyDecoder) against fast_sync.split_fast_status + decode_feedback, on any valid
reply, on corrupted ones and on garbage; the goal-current packet from one struct.pack against
protocol.build_instruction, byte for byte, stuffing included; and the leader's sample by the fast path
against the general path on the same replies, bit for bit."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from test_dynamixel_leader import make

from hardware.dynamixel import protocol as p
from hardware.dynamixel.fast_sync import build_fast_status, split_fast_status
from hardware.dynamixel.leader_math import FastReplyDecoder, decode_feedback
from hardware.dynamixel.sync_io import SyncReadGroup, SyncWriteGroup, fast_sync_read_reply

_I16, _I32 = st.integers(-2**15, 2**15 - 1), st.integers(-2**31, 2**31 - 1)


@st.composite
def replies(draw, errors=True):
    """(ids, with_current, the blocks [(id, error byte, data)], the reply's bytes) of 1-7 servos."""
    rc = draw(st.booleans())
    ids = draw(st.lists(st.integers(0, p.MAX_ID), min_size=1, max_size=7, unique=True))
    blocks = []
    for i in ids:
        err = draw(st.sampled_from([0, 0, 0, p.ERR_ALERT_BIT, p.ERR_DATA_RANGE, 0xFF])) if errors else 0
        data = (p.le(draw(_I16), 2) if rc else b"") + p.le(draw(_I32), 4) + p.le(draw(_I32), 4)
        blocks.append((i, err, data))
    length = p.FEEDBACK_LEN if rc else p.FEEDBACK_NO_CURRENT_LEN
    return ids, rc, blocks, build_fast_status(blocks, length)


def _check_against_reference(dec: FastReplyDecoder, ids, rc, buf) -> bool:
    """fields(buf) is None, or every servo's (error, id, fields) as split_fast_status + decode_feedback give
    them for a CRC-checked reply (all of them present, error 0), and runs(buf) (the leader's tick) is None
    with it or its position, velocity and current runs. True when fields took the reply."""
    v, r = dec.fields(buf), dec.runs(buf)
    if v is None:
        assert r is None
        return False
    assert r == (v[dec.pos::dec.width], v[dec.vel::dec.width], v[dec.cur::dec.width] if rc else None)
    length = p.FEEDBACK_LEN if rc else p.FEEDBACK_NO_CURRENT_LEN
    ref = split_fast_status(bytes(buf), ids, length, crc_checked=True)
    assert sorted(ref) == sorted(ids)
    w = dec.width
    for k, i in enumerate(ids):
        data, err = ref[i]
        cur, vel, pos = decode_feedback(data, rc)
        assert (v[3 + k * w], v[4 + k * w]) == (err, i) == (0, i)
        assert v[dec.vel + k * w] == vel and v[dec.pos + k * w] == pos
        assert not rc or v[dec.cur + k * w] == cur
    return True


@settings(max_examples=300, deadline=None)
@given(replies())
def test_a_valid_reply_decodes_as_the_reference(r):
    ids, rc, blocks, buf = r
    took = _check_against_reference(FastReplyDecoder(ids, rc), ids, rc, buf)
    assert took == all(err == 0 for _, err, _ in blocks)  # an error byte goes the general way


class _ReplyPort:
    """A port whose reply to the next instruction is `reply` (sync_io's side of the wire, in memory)."""

    def __init__(self, reply: bytes):
        self.is_using, self._rx, self._reply = False, bytearray(), reply

    def clearPort(self):  # noqa: N802 -- sdk names
        self._rx.clear()

    def writePort(self, packet):  # noqa: N802
        self._rx += self._reply
        return len(packet)

    def setPacketTimeoutMillis(self, ms):  # noqa: N802
        pass

    def isPacketTimeout(self):  # noqa: N802
        return True

    def readPort(self, n):  # noqa: N802
        out = bytes(self._rx[:n])
        del self._rx[:n]
        return out


@settings(max_examples=300, deadline=None)
@given(replies(errors=False), st.data())
def test_a_corrupted_reply_is_never_taken_whole(r, data):
    """One byte changed, the reply cut short or lengthened: not intact (CRC or length), so never decoded as
    a whole; and whatever the bytes, fields() takes only what the reference decodes the same."""
    ids, rc, _, buf = r
    how = data.draw(st.sampled_from(["flip", "cut", "extra"]))
    bad = bytearray(buf)
    if how == "flip":
        k = data.draw(st.integers(0, len(bad) - 1))
        bad[k] ^= data.draw(st.integers(1, 255))
    elif how == "cut":
        del bad[data.draw(st.integers(0, len(bad) - 1)):]
    else:
        bad += data.draw(st.binary(min_size=1, max_size=8))
    length = p.FEEDBACK_LEN if rc else p.FEEDBACK_NO_CURRENT_LEN
    group = SyncReadGroup(ids, p.FEEDBACK_START if rc else p.FEEDBACK_NO_CURRENT_START, length)
    got, intact = fast_sync_read_reply(_ReplyPort(bytes(bad)), group, 1.0)
    if how != "extra":  # extra bytes after a whole reply are left unread: the reply itself is intact
        assert not intact
    dec = FastReplyDecoder(ids, rc)
    _check_against_reference(dec, ids, rc, bad)  # even unchecked by CRC: a layout it takes is the reference's
    good, intact = fast_sync_read_reply(_ReplyPort(buf), group, 1.0)
    assert intact and bytes(good) == buf and _check_against_reference(dec, ids, rc, good)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.integers(0, p.MAX_ID), min_size=1, max_size=7, unique=True), st.binary(max_size=120))
def test_garbage_is_rejected_or_the_reference(ids, junk):
    for rc in (True, False):
        dec = FastReplyDecoder(ids, rc)
        length = p.FEEDBACK_LEN if rc else p.FEEDBACK_NO_CURRENT_LEN
        header = build_fast_status([(i, 0, b"") for i in ids], length)[:8]  # this chain's header, then junk
        for buf in (junk, header + junk, (header + junk * dec.struct.size)[:dec.struct.size]):
            _check_against_reference(dec, ids, rc, buf)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.integers(0, p.MAX_ID), min_size=1, max_size=7, unique=True), st.sampled_from([1, 2, 4]),
       st.data())
def test_goal_packet_is_build_instructions_bytes(ids, length, data):
    """Byte for byte protocol.build_instruction's sync write, stuffing included (a 4-byte value 0xFDFFFF..
    puts FF FF FD in the body)."""
    bits = 8 * length
    edges = [-1, -(2 ** (bits - 1)), 2 ** (bits - 1) - 1] + ([-0x02000001] if length == 4 else [])
    special = st.sampled_from(edges)
    values = data.draw(st.lists(st.one_of(st.integers(-2 ** (bits - 1), 2 ** (bits - 1) - 1), special),
                                min_size=len(ids), max_size=len(ids)))
    group = SyncWriteGroup(list(ids), p.ADDR_GOAL_CURRENT[0], length)
    ref = p.build_instruction(p.BROADCAST_ID, p.INST_SYNC_WRITE, p.sync_write_params(
        group.address, length, {i: p.le(x, length) for i, x in zip(ids, values, strict=True)}))
    assert group.packet_ints(values) == ref
    assert group.packet_ints(values) == ref  # the template, used again, is unchanged


def test_the_fast_path_sample_is_the_general_paths():
    """The leader's sample from a reply decoded straight from its bytes equals the one split_fast_status +
    _state_all_fresh make of the same reply, bit for bit, over moving joints and both reply kinds."""
    bank, emu, leader = make(gripper=True)
    leader.connect()
    try:
        assert leader.fast_read
        fast_decoder = leader._fast_decoder

        class Refuse:  # sends every reply the general way
            width = fast_decoder.width

            @staticmethod
            def fields(buf):
                return None

            runs = fields

        for k in range(20):
            bank.q[: leader.n_joints] += 0.41 * (k % 3 - 1)  # a third of a turn, both ways: the unwrap
            saved = (list(leader._q_servo), list(leader._ticks_prev), leader._last_state)
            leader._fast_decoder = fast_decoder
            a = leader._read()
            leader._q_servo, leader._ticks_prev, leader._last_state = list(saved[0]), list(saved[1]), saved[2]
            leader._fast_decoder = Refuse()
            b = leader._read()
            leader._fast_decoder = fast_decoder
            assert a is not None and b is not None
            for name in ("q", "q_dot", "tau_m", "current", "q_cmd", "temperature", "status"):
                x, y = getattr(a, name), getattr(b, name)
                assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), name
            assert np.float64(a.gripper_pos).tobytes() == np.float64(b.gripper_pos).tobytes()
            assert np.float64(a.gripper_effort).tobytes() == np.float64(b.gripper_effort).tobytes()
    finally:
        leader.disconnect()
        emu.close()
