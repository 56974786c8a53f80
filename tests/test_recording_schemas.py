"""Format details: the hand-written protobuf for foxglove.CompressedImage, JSON payloads, time mapping."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hardware.recording import schemas as S
from hardware.recording.protobuf_wire import (
    compressed_image_descriptor_set,
    decode_compressed_image,
    encode_compressed_image,
)


@pytest.mark.parametrize("stamp", [0, 1, 1_763_780_000_123_456_789, 2**40 + 7])
def test_compressed_image_round_trip(stamp):
    data = bytes(range(256)) * 3
    msg = encode_compressed_image(stamp, data, "jpeg", "wrist")
    stamp_ns, got, fmt, frame_id = decode_compressed_image(msg)
    assert (stamp_ns, bytes(got), fmt, frame_id) == (stamp, data, "jpeg", "wrist")


def test_compressed_image_matches_google_protobuf():
    pb = pytest.importorskip("google.protobuf")  # optional: checks our descriptor against the real library
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    assert pb
    fds = descriptor_pb2.FileDescriptorSet.FromString(compressed_image_descriptor_set())
    pool = descriptor_pool.DescriptorPool()
    for f in fds.file:
        pool.Add(f)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName("foxglove.CompressedImage"))
    m = cls.FromString(encode_compressed_image(1_700_000_000_250_000_000, b"\xff\xd8", "jpeg", "cam"))
    assert (m.timestamp.seconds, m.timestamp.nanos, m.data, m.format, m.frame_id) == (
        1_700_000_000, 250_000_000, b"\xff\xd8", "jpeg", "cam")


def test_garbage_image_payload_raises_value_error_only():
    rng = np.random.default_rng(0)
    for _ in range(200):
        blob = rng.integers(0, 256, int(rng.integers(1, 40)), dtype=np.uint8).tobytes()
        try:
            decode_compressed_image(blob)
        except ValueError:
            pass


def test_numeric_payloads_are_strict_json_with_nulls():
    payload = {"t": 12.5, "tau": [1.0, float("nan"), float("inf"), -float("inf")], "gate": float("nan")}
    text = S.encode_numeric(S.TORQUE_COMMAND, payload)
    d = json.loads(text, parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))
    assert d == {"t": 12.5, "tau": [1.0, None, None, None], "gate": None}
    for schema in S.NUMERIC_SCHEMAS.values():
        js = schema.json_schema()
        assert js["title"] == schema.name and set(js["properties"]) == {"t"} | {f.name for f in schema.fields}


def test_log_time_mapping():
    assert S.log_time_ns(1.5, 1000.0) == 1_001_500_000_000
    assert S.log_time_ns(-5.0, 1.0) == 0
