"""The records a recording's producer (the control process) hands to its writer process through the byte ring
(hardware/recording/ring.py): compact binary, cheap to pack on the control thread (one numpy concatenate and
struct headers per tick, no JSON, no dict), decoded in the writer process into the payloads that schemas.py
encodes.

Kinds (first byte):
- TOPIC: a topic id and what it carries (a numeric schema, a camera), sent once before the topic's first use;
- NUMERIC: one or more messages (a tick): per message its topic id and vector lengths, then float64
  [t, scalar fields..., vector fields...] of every message in the schemas' field order;
- EVENT: t [s], episode, event kind, value, text;
- FRAME: topic id, t [s], an H x W x 3 uint8 RGB frame (JPEG-encoded in the writer process) or a JPEG;
- NAMES: channel metadata that became known after the start ({arm: names}, e.g. the task objects').
Every value survives bit for bit (float64, ints < 2**53): the JSON written is the same as before the split.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass

import numpy as np

from hardware.recording import schemas as S

TOPIC, NUMERIC, EVENT, FRAME, NAMES = range(5)
SCHEMAS: tuple[S.Schema, ...] = tuple(S.NUMERIC_SCHEMAS.values())
SCHEMA_CODE = {s.name: i for i, s in enumerate(SCHEMAS)}
CAMERA_CODE = 255  # a TOPIC record's code for a camera (the name is the camera's)
RAW, JPEG = 0, 1

_TOPIC = struct.Struct("<BHB")
_NUMS = struct.Struct("<BB")  # kind, messages
_MSG = struct.Struct("<HBB")  # topic id, scalars (t included), vectors
_EVENT = struct.Struct("<BdiBd")
_FRAME = struct.Struct("<BHdBIII")
_LENS: dict[int, struct.Struct] = {}


def _layout(schema: S.Schema) -> tuple[tuple[S.Field, ...], tuple[S.Field, ...]]:
    return (tuple(f for f in schema.fields if not f.vector), tuple(f for f in schema.fields if f.vector))


LAYOUTS = {s.name: _layout(s) for s in SCHEMAS}


def _lens(n: int) -> struct.Struct:
    st = _LENS.get(n)
    if st is None:
        st = _LENS[n] = struct.Struct(f"<{n}I")
    return st


# ---- producer side -------------------------------------------------------------------------------------
def joint_state_fields(state) -> tuple[tuple, tuple]:
    """(scalars, vectors) of a hardware.types.JointState in JOINT_STATE's field order."""
    return ((state.gripper_pos, state.gripper_effort),
            (state.q, state.q_dot, state.tau_m, state.current, state.q_cmd, state.temperature, state.status))


def num(x) -> float:
    """A scalar field's value: None (not given) is NaN, written as null."""
    return float("nan") if x is None else float(x)


def pack_topic(topic_id: int, code: int, name: str) -> bytes:
    return _TOPIC.pack(TOPIC, topic_id, code) + name.encode()


def pack_numerics(items) -> bytes:
    """One record of one or more numeric messages (a whole tick of an arm pair: one concatenate). items:
    (topic id, t [s], scalars, vectors), scalars and vectors in the schema's field order (schemas.py).
    TypeError / ValueError on a value that is not a number or a 1-D vector (None, text, a matrix)."""
    head = [_NUMS.pack(NUMERIC, len(items))]
    parts = []
    for tid, t, scalars, vectors in items:
        lens = [len(v) for v in vectors]
        head.append(_MSG.pack(tid, 1 + len(scalars), len(lens)) + _lens(len(lens)).pack(*lens))
        parts.append((t, *scalars))
        parts.extend(vectors)
    body = np.concatenate(parts, dtype=np.float64, casting="same_kind")
    return b"".join(head) + body.tobytes()


def pack_event(t: float, kind: str, episode: int, text: str, value: float) -> bytes:
    return _EVENT.pack(EVENT, float(t), int(episode), S.EVENT_KINDS.index(kind), float(value)) + text.encode()


def frame_header(topic_id: int, t: float, encoding: int, shape: tuple[int, int, int]) -> bytes:
    """The header of a FRAME record; the pixels (or JPEG bytes) follow as a second part (no copy)."""
    return _FRAME.pack(FRAME, topic_id, float(t), encoding, *shape)


def pack_names(names: dict[str, list[str]]) -> bytes:
    return bytes([NAMES]) + json.dumps(names).encode()


# ---- writer side ---------------------------------------------------------------------------------------
@dataclass
class Topic:
    code: int
    name: str


@dataclass
class Frame:
    topic_id: int
    t: float
    encoding: int
    shape: tuple[int, int, int]
    data: bytes  # RGB (H x W x C uint8) or JPEG

    def rgb(self) -> np.ndarray:
        return np.frombuffer(self.data, np.uint8).reshape(self.shape)


def unpack(rec: bytes):
    """Like _unpack; any malformed record (short, unknown kind, bad text) is a ValueError."""
    try:
        return _unpack(rec)
    except (struct.error, IndexError, UnicodeDecodeError) as e:
        raise ValueError(f"malformed record ({type(e).__name__}: {e})") from None


def _unpack(rec: bytes):
    """One record -> ("topic", id, Topic) | ("numeric", [(id, values, vector lengths)]) |
    ("event", t, kind, episode,
    text, value) | ("frame", Frame) | ("names", dict). ValueError on a malformed record."""
    if not rec:
        raise ValueError("empty record")
    kind = rec[0]
    if kind == TOPIC:
        _, tid, code = _TOPIC.unpack_from(rec)
        return ("topic", tid, Topic(code, rec[_TOPIC.size:].decode()))
    if kind == NUMERIC:
        _, count = _NUMS.unpack_from(rec)
        at, shapes = _NUMS.size, []
        for _ in range(count):
            tid, nscal, nvec = _MSG.unpack_from(rec, at)
            lens = _lens(nvec).unpack_from(rec, at + _MSG.size)
            shapes.append((tid, nscal, lens))
            at += _MSG.size + 4 * nvec
        values = np.frombuffer(rec, np.float64, offset=at)
        msgs, i = [], 0
        for tid, nscal, lens in shapes:
            n = nscal + sum(lens)
            if i + n > values.size:
                raise ValueError("numeric record shorter than its header")
            msgs.append((tid, values[i: i + n], lens))
            i += n
        return ("numeric", msgs)
    if kind == EVENT:
        _, t, ep, k, value = _EVENT.unpack_from(rec)
        return ("event", t, S.EVENT_KINDS[k], ep, rec[_EVENT.size:].decode(), value)
    if kind == FRAME:
        _, tid, t, enc, h, w, c = _FRAME.unpack_from(rec)
        data = rec[_FRAME.size:]
        if enc == RAW and len(data) != h * w * c:
            raise ValueError(f"frame of {len(data)} bytes for {h} x {w} x {c}")
        return ("frame", Frame(tid, t, enc, (h, w, c), data))
    if kind == NAMES:
        return ("names", json.loads(rec[1:].decode()))
    raise ValueError(f"unknown record kind {kind}")


def numeric_payload(schema: S.Schema, values: np.ndarray, lens) -> dict:
    """The payload dict schemas.encode_numeric takes, from a NUMERIC record's values."""
    scalars, vectors = LAYOUTS[schema.name]
    if len(lens) != len(vectors) or values.size != 1 + len(scalars) + sum(lens):
        raise ValueError(f"{schema.name}: {values.size} values do not match its fields")
    p = {"t": float(values[0])}
    i = 1
    for f in scalars:
        v = values[i]
        p[f.name] = bool(v) if f.kind == "bool" else int(v) if f.kind == "int" else float(v)
        i += 1
    for f, n in zip(vectors, lens):
        v = values[i: i + n]
        p[f.name] = v.astype(np.int64).tolist() if f.kind == "int" else v.tolist()
        i += n
    return p
