"""The recorder's shared-memory ring and its binary records (hardware/recording/ring.py, wire_records.py):
pure functions over buffers, driven with random sizes, wraps and torn records."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hardware.recording import schemas as S
from hardware.recording import wire_records as R
from hardware.recording.ring import RING_HEADER, ByteRing, region_size


def _ring(capacity: int) -> tuple[ByteRing, ByteRing, bytearray]:
    """A producer and a consumer view of one ring in one buffer (as the two processes have)."""
    buf = bytearray(region_size(capacity))
    return ByteRing(buf, capacity), ByteRing(buf, capacity), buf


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.binary(min_size=0, max_size=300), st.booleans()), min_size=1, max_size=200),
       st.sampled_from([256, 512, 1000, 4096]))
def test_records_come_out_whole_and_in_order_across_wraps(ops, capacity):
    """Random puts and takes: every accepted record comes out once, unchanged, in order; a full ring refuses
    (never overwrites); take() frees the space."""
    prod, cons, _ = _ring(capacity)
    sent, got = [], []
    for payload, take in ops:
        if prod.put(payload):
            sent.append(payload)
        if take:
            got += cons.take()
    got += cons.take()
    assert got == sent and cons.used() == 0 and cons.bad_records == 0


def test_a_full_ring_refuses_and_parts_are_concatenated():
    prod, cons, _ = _ring(256)
    assert not prod.put(b"x" * 300)  # larger than the ring
    n = 0
    while prod.put(b"ab", b"cd" * 10):
        n += 1
    assert n > 0 and prod.used() <= 256
    assert cons.take(max_records=2) == [b"ab" + b"cd" * 10] * 2
    assert prod.put(b"ab", b"cd" * 10)  # space came back


def test_a_torn_record_waits_then_is_skipped(monkeypatch):
    """A record whose bytes are not visible yet (the CRC does not match) is looked at again; one that stays
    bad past BAD_RECORD_WAIT_S is counted and the consumer resynchronises at the head."""
    import hardware.recording.ring as ring

    prod, cons, buf = _ring(1024)
    assert prod.put(b"first") and prod.put(b"second")
    buf[RING_HEADER + 8] ^= 0xFF  # corrupt the first payload's first byte
    assert cons.take() == []  # not yet: could be a store not yet visible
    monkeypatch.setattr(ring, "BAD_RECORD_WAIT_S", 0.0)
    assert cons.take() == [] and cons.bad_records == 1 and cons.used() == 0
    assert prod.put(b"third") and cons.take() == [b"third"]


def test_a_record_from_the_previous_lap_is_not_taken_as_new():
    """The CRC is seeded with the record's absolute offset: a complete old record at the same place in the
    ring (what a consumer sees if the head became visible before the new bytes) does not pass."""
    prod, cons, buf = _ring(64)
    assert prod.put(b"A" * 8)  # 16 bytes at offset 0
    assert cons.take() == [b"A" * 8]
    for _ in range(3):  # fill the rest of the lap
        assert prod.put(b"B" * 8)
    assert len(cons.take()) == 3
    old = bytes(buf[RING_HEADER: RING_HEADER + 16])
    assert prod.put(b"C" * 8)  # the next lap, at offset 0 again
    buf[RING_HEADER: RING_HEADER + 16] = old  # as if the new bytes were not visible yet
    assert cons.take() == []


def _state(n=6, seed=0):
    from hardware.types import JointState

    rng = np.random.default_rng(seed)
    s = JointState.empty(n, t=0.1)
    for f in ("q", "q_dot", "tau_m", "current", "q_cmd", "temperature"):
        getattr(s, f)[:] = rng.normal(size=n)
    s.q_cmd[2] = np.nan
    s.status[:] = rng.integers(0, 2**31, size=n)
    s.gripper_pos, s.gripper_effort = 0.031, float("nan")
    return s


def test_numeric_records_give_the_same_json_as_the_payload_they_came_from():
    """A tick of five messages packed in one record decodes into payloads whose JSON is byte for byte what
    schemas.encode_numeric writes for the original values (NaN, ints, bools included)."""
    s = _state()
    z = np.array([0.5, -1e-9, 3e8, np.inf, -np.inf, np.nan])
    items = [(0, 1.25, *R.joint_state_fields(s)), (1, 1.25, (True,), (z,)), (2, 1.25, (float("nan"),), (z,)),
             (3, 1.25, (0.02, False), (z,)), (4, 1.25, (True,), (z, np.array([1.0, 2.0, 3.0])))]
    schemas = [S.JOINT_STATE, S.EXTERNAL_TORQUE, S.TORQUE_COMMAND, S.FOLLOWER_COMMAND, S.GROUND_TRUTH]
    kind, msgs = R.unpack(R.pack_numerics(items))
    assert kind == "numeric" and [m[0] for m in msgs] == [0, 1, 2, 3, 4]
    expect = [
        {"t": 1.25, "q": s.q.tolist(), "q_dot": s.q_dot.tolist(), "tau_m": s.tau_m.tolist(),
         "current": s.current.tolist(), "q_cmd": s.q_cmd.tolist(), "temperature": s.temperature.tolist(),
         "status": s.status.astype(np.int64).tolist(), "gripper_pos": 0.031, "gripper_effort": float("nan")},
        {"t": 1.25, "tau_ext": z.tolist(), "contact": True},
        {"t": 1.25, "tau": z.tolist(), "gate": float("nan")},
        {"t": 1.25, "q": z.tolist(), "gripper": 0.02, "hold": False},
        {"t": 1.25, "tau_ext_true": z.tolist(), "contact": True, "force": [1.0, 2.0, 3.0]}]
    for (_, values, lens), schema, want in zip(msgs, schemas, expect):
        got = R.numeric_payload(schema, values, lens)
        assert S.encode_numeric(schema, got) == S.encode_numeric(schema, want)


def test_other_records_round_trip_and_garbage_is_a_value_error():
    topic = "/left_follower/tau_ext"
    assert R.unpack(R.pack_topic(7, 2, topic)) == ("topic", 7, R.Topic(2, topic))
    ev = R.unpack(R.pack_event(3.5, "note", 2, "héllo", float("nan")))
    assert ev[:5] == ("event", 3.5, "note", 2, "héllo")
    assert R.unpack(R.pack_names({"task": ["a", "b"]})) == ("names", {"task": ["a", "b"]})
    rgb = np.arange(2 * 3 * 3, dtype=np.uint8).reshape(2, 3, 3)
    kind, fr = R.unpack(R.frame_header(1, 0.5, R.RAW, rgb.shape) + rgb.tobytes())
    assert kind == "frame" and np.array_equal(fr.rgb(), rgb) and fr.t == 0.5
    for bad in (b"", b"\x09abc", R.frame_header(1, 0.5, R.RAW, (4, 4, 3)) + b"short",
                R.pack_numerics([(0, 1.0, (), (np.zeros(3),))])[:-8]):
        with pytest.raises(ValueError):
            kind, msgs = R.unpack(bad)
            for _tid, values, lens in msgs:
                R.numeric_payload(S.TASK_OBJECTS, values, lens)
    with pytest.raises(TypeError):
        R.pack_numerics([(0, 1.0, (), (None,))])


@settings(max_examples=40, deadline=None)
@given(st.binary(min_size=0, max_size=200))
def test_unpack_survives_garbage(data):
    """Any bytes: a record or a ValueError, nothing else (the writer counts it and goes on)."""
    try:
        R.unpack(data)
    except ValueError:
        pass
