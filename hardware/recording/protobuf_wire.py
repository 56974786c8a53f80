"""Minimal protobuf wire codec for foxglove.CompressedImage, written by hand so recordings need no protobuf
package. Foxglove Studio decodes these messages with the FileDescriptorSet below (schema encoding
"protobuf"); `tests/test_recording_schemas.py` checks both against google.protobuf when it is installed.

foxglove.CompressedImage (proto3): timestamp=1 (google.protobuf.Timestamp: seconds=1 int64, nanos=2 int32),
data=2 bytes, format=3 string ("jpeg"), frame_id=4 string.
"""

from __future__ import annotations

# Wire types and descriptor enums (google/protobuf/descriptor.proto).
_VARINT, _LEN = 0, 2
_LABEL_OPTIONAL = 1
_TYPE_INT64, _TYPE_INT32, _TYPE_MESSAGE, _TYPE_STRING, _TYPE_BYTES = 3, 5, 11, 9, 12

IMAGE_SCHEMA_NAME = "foxglove.CompressedImage"


def _varint(n: int) -> bytes:
    if n < 0:
        n &= (1 << 64) - 1  # two's complement for negative int64, as protobuf does
    out = bytearray()
    while True:
        b = n & 0x7F
        n >>= 7
        if n:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def _key(field: int, wire: int) -> bytes:
    return _varint(field << 3 | wire)


def _len_field(field: int, data: bytes) -> bytes:
    return _key(field, _LEN) + _varint(len(data)) + data


def _int_field(field: int, n: int) -> bytes:
    return _key(field, _VARINT) + _varint(n) if n else b""


def _str_field(field: int, s: str) -> bytes:
    return _len_field(field, s.encode()) if s else b""


def encode_compressed_image(stamp_ns: int, data: bytes, fmt: str = "jpeg", frame_id: str = "") -> bytes:
    """One foxglove.CompressedImage message; stamp_ns [ns since the Unix epoch]."""
    sec, nanos = divmod(int(stamp_ns), 1_000_000_000)
    stamp = _int_field(1, sec) + _int_field(2, nanos)
    return (_len_field(1, stamp) + _len_field(2, bytes(data)) + _str_field(3, fmt)
            + _str_field(4, frame_id))


def _read_varint(buf, pos: int) -> tuple[int, int]:
    result = shift = 0
    while True:
        if pos >= len(buf) or shift > 63:
            raise ValueError("truncated or overlong varint")
        b = buf[pos]
        pos += 1
        result |= (b & 0x7F) << shift
        if not b & 0x80:
            return result, pos
        shift += 7


def _fields(buf) -> dict[int, object]:
    """field number -> last value (int for varints, memoryview for length-delimited). Skips 32/64-bit."""
    mv = memoryview(buf)
    out: dict[int, object] = {}
    pos = 0
    while pos < len(mv):
        key, pos = _read_varint(mv, pos)
        field, wire = key >> 3, key & 7
        if wire == _VARINT:
            out[field], pos = _read_varint(mv, pos)
        elif wire == _LEN:
            n, pos = _read_varint(mv, pos)
            if pos + n > len(mv):
                raise ValueError("length-delimited field runs past the message")
            out[field] = mv[pos:pos + n]
            pos += n
        elif wire == 1:
            pos += 8
        elif wire == 5:
            pos += 4
        else:
            raise ValueError(f"unsupported wire type {wire}")
    return out


def decode_compressed_image(buf) -> tuple[int, memoryview, str, str]:
    """-> (stamp_ns, data, format, frame_id). Raises ValueError on malformed input."""
    f = _fields(buf)
    stamp = _fields(f[1]) if 1 in f else {}
    sec = int(stamp.get(1, 0))
    if sec >= 1 << 63:
        sec -= 1 << 64
    stamp_ns = sec * 1_000_000_000 + int(stamp.get(2, 0))
    data = f.get(2, memoryview(b""))
    fmt = bytes(f.get(3, b"")).decode(errors="replace")
    frame_id = bytes(f.get(4, b"")).decode(errors="replace")
    return stamp_ns, data, fmt, frame_id  # type: ignore[return-value]


def _field_desc(name: str, number: int, ftype: int, type_name: str = "", json_name: str = "") -> bytes:
    return (_str_field(1, name) + _int_field(3, number) + _int_field(4, _LABEL_OPTIONAL)
            + _int_field(5, ftype) + _str_field(6, type_name) + _str_field(10, json_name or name))


def _file_desc(name: str, package: str, deps: list[str], msg_name: str, fields: list[bytes]) -> bytes:
    msg = _str_field(1, msg_name) + b"".join(_len_field(2, f) for f in fields)
    return (_str_field(1, name) + _str_field(2, package) + b"".join(_str_field(3, d) for d in deps)
            + _len_field(4, msg) + _str_field(12, "proto3"))


def compressed_image_descriptor_set() -> bytes:
    """google.protobuf.FileDescriptorSet for foxglove.CompressedImage (the MCAP schema data)."""
    timestamp = _file_desc("google/protobuf/timestamp.proto", "google.protobuf", [], "Timestamp", [
        _field_desc("seconds", 1, _TYPE_INT64), _field_desc("nanos", 2, _TYPE_INT32)])
    image = _file_desc("foxglove/CompressedImage.proto", "foxglove", ["google/protobuf/timestamp.proto"],
                       "CompressedImage", [
                           _field_desc("timestamp", 1, _TYPE_MESSAGE, ".google.protobuf.Timestamp"),
                           _field_desc("frame_id", 4, _TYPE_STRING, json_name="frameId"),
                           _field_desc("data", 2, _TYPE_BYTES), _field_desc("format", 3, _TYPE_STRING)])
    return _len_field(1, timestamp) + _len_field(1, image)
