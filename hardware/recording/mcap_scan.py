"""A tolerant, fast MCAP record scanner (our own; the `mcap` package is used for writing).

It walks the file front to back (no summary needed), so it reads files cut off by a crash: it yields every
complete record, checks each chunk's CRC, and reports where and why it stopped instead of raising.
A file that does not start with the MCAP magic, or is empty, raises RecordingError (a UserError).
"""

from __future__ import annotations

import mmap
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from hardware.errors import UserError

MAGIC = b"\x89MCAP0\r\n"
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06
OP_METADATA, OP_DATA_END = 0x0C, 0x0F

_U16, _U32, _U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")
_MSG_HEAD = struct.Struct("<HIQQ")  # channel_id, sequence, log_time, publish_time
_CHUNK_HEAD = struct.Struct("<QQQI")  # start, end, uncompressed_size, uncompressed_crc


class RecordingError(UserError):
    """A recording file is missing, empty, corrupt or not a factr2 recording."""


@dataclass
class SchemaRec:
    id: int
    name: str
    encoding: str
    data: bytes


@dataclass
class ChannelRec:
    id: int
    schema_id: int
    topic: str
    encoding: str
    metadata: dict[str, str]


@dataclass
class MessageRec:
    """data: a view valid until the next record. loc: (chunk_offset or -1, data_offset, length), where
    data_offset is inside the decompressed chunk records (or the file when chunk_offset is -1)."""

    channel_id: int
    sequence: int
    log_time: int
    publish_time: int
    data: memoryview
    loc: tuple[int, int, int]


@dataclass
class MetadataRec:
    name: str
    metadata: dict[str, str]


@dataclass
class ScanState:
    """Filled while scanning: header, whether the file ended cleanly, and warnings."""

    profile: str = ""
    library: str = ""
    complete: bool = False  # a footer was reached
    valid_bytes: int = 0  # end of the last complete record
    size: int = 0
    warnings: list[str] = field(default_factory=list)

    @property
    def truncated(self) -> bool:
        return not self.complete


def _string(buf, pos: int) -> tuple[str, int]:
    (n,) = _U32.unpack_from(buf, pos)
    pos += 4
    if pos + n > len(buf):
        raise ValueError("string runs past the record")
    return bytes(buf[pos:pos + n]).decode("utf-8", errors="replace"), pos + n


def _str_map(buf, pos: int) -> tuple[dict[str, str], int]:
    (n,) = _U32.unpack_from(buf, pos)
    pos += 4
    end = pos + n
    out = {}
    while pos < end:
        k, pos = _string(buf, pos)
        v, pos = _string(buf, pos)
        out[k] = v
    return out, end


def decompress(compression: str, data, size: int) -> bytes:
    if compression == "":
        return bytes(data)
    if compression == "zstd":
        import zstandard

        return zstandard.ZstdDecompressor().decompress(bytes(data), max_output_size=size)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.decompress(bytes(data))
    raise ValueError(f"unknown chunk compression {compression!r}")


def parse_chunk(buf, pos: int, end: int) -> tuple[str, int, int, int, int]:
    """-> (compression, records_offset, records_length, uncompressed_size, uncompressed_crc)."""
    _, _, usize, ucrc = _CHUNK_HEAD.unpack_from(buf, pos)
    compression, p = _string(buf, pos + _CHUNK_HEAD.size)
    (rlen,) = _U64.unpack_from(buf, p)
    p += 8
    if p + rlen > end:
        raise ValueError("chunk records run past the chunk")
    return compression, p, rlen, usize, ucrc


def _records(buf, start: int, end: int, chunk_offset: int, state: ScanState | None):
    """Yield parsed records in buf[start:end]. Stops at the first incomplete record."""
    pos = start
    while pos + 9 <= end:
        op = buf[pos]
        (length,) = _U64.unpack_from(buf, pos + 1)
        body = pos + 9
        if length > end - body:
            return  # truncated record: everything before it was complete
        rend = body + length
        try:
            if op == OP_MESSAGE:
                ch, seq, lt, pt = _MSG_HEAD.unpack_from(buf, body)
                d0 = body + _MSG_HEAD.size
                yield MessageRec(ch, seq, lt, pt, buf[d0:rend], (chunk_offset, d0, rend - d0))
            elif op == OP_CHUNK:
                yield ("chunk", pos, body, rend)
            elif op == OP_SCHEMA:
                (sid,) = _U16.unpack_from(buf, body)
                name, p = _string(buf, body + 2)
                enc, p = _string(buf, p)
                (n,) = _U32.unpack_from(buf, p)
                yield SchemaRec(sid, name, enc, bytes(buf[p + 4:p + 4 + n]))
            elif op == OP_CHANNEL:
                cid, sid = struct.unpack_from("<HH", buf, body)
                topic, p = _string(buf, body + 4)
                enc, p = _string(buf, p)
                meta, p = _str_map(buf, p)
                yield ChannelRec(cid, sid, topic, enc, meta)
            elif op == OP_METADATA:
                name, p = _string(buf, body)
                meta, p = _str_map(buf, p)
                yield MetadataRec(name, meta)
            elif op == OP_HEADER:
                profile, p = _string(buf, body)
                library, p = _string(buf, p)
                yield ("header", profile, library)
            elif op == OP_FOOTER:
                yield ("footer",)
        except (struct.error, ValueError) as e:
            if state is not None:
                state.warnings.append(f"malformed record (opcode 0x{op:02x}) at byte {pos}: {e}; skipped")
        pos = rend
        if state is not None and chunk_offset < 0:
            state.valid_bytes = pos


def open_buffer(path: str | Path):
    """mmap a recording read-only -> (buffer, closer). Empty or non-MCAP files raise RecordingError."""
    path = Path(path)
    if not path.is_file():
        raise RecordingError("file not found", where=str(path), fix="check the path")
    size = path.stat().st_size
    if size == 0:
        raise RecordingError("empty file (0 bytes): the recorder was killed before its first flush, "
                             "nothing to read", where=str(path), fix="delete it")
    with open(path, "rb") as f:
        head = f.read(len(MAGIC))
        if head != MAGIC:
            what = ("too short to be an MCAP file" if MAGIC.startswith(head)
                    else "not an MCAP file (bad magic bytes)")
            raise RecordingError(what, where=str(path),
                                 fix="pass a .mcap recording made by factr2 (or a plain .npz log)")
        mm = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)

    def close() -> None:
        try:
            mm.close()
        except BufferError:  # a caller still holds a view of it: the mapping goes with the last reference
            pass

    return mm, close


def iter_records(buf, state: ScanState) -> Iterator[object]:
    """Every complete record of an MCAP buffer, chunks expanded (MessageRec/SchemaRec/ChannelRec/
    MetadataRec). Fills `state`; never raises on a damaged file (damage becomes state.warnings)."""
    state.size = len(buf)
    mv = memoryview(buf)
    for rec in _records(mv, len(MAGIC), len(mv), -1, state):
        if isinstance(rec, tuple):
            if rec[0] == "chunk":
                _, cpos, body, rend = rec
                try:
                    comp, roff, rlen, usize, ucrc = parse_chunk(mv, body, rend)
                    inner = decompress(comp, mv[roff:roff + rlen], usize)
                    if ucrc and zlib.crc32(inner) != ucrc:
                        raise ValueError("CRC mismatch")
                except Exception as e:  # any damage in one chunk must not stop the rest of the file
                    state.warnings.append(f"corrupt chunk at byte {cpos} ({e}); its messages are skipped")
                    continue
                # Uncompressed chunks are parsed in place so message locations are file offsets.
                src, lo, hi = (memoryview(inner), 0, len(inner)) if comp else (mv, roff, roff + rlen)
                for r in _records(src, lo, hi, cpos, None):
                    if not isinstance(r, tuple):
                        yield r
            elif rec[0] == "header":
                state.profile, state.library = rec[1], rec[2]
            elif rec[0] == "footer":
                state.complete = True
            continue
        yield rec
    if not state.complete:
        lost = state.size - state.valid_bytes
        state.warnings.append(f"file is truncated (no MCAP footer; last {lost} bytes incomplete): it was not "
                              "closed cleanly; read what was complete")


def read_header(buf) -> tuple[str, str]:
    """(profile, library) of the MCAP header record; ("", "") when it is missing or damaged."""
    mv = memoryview(buf)
    for rec in _records(mv, len(MAGIC), min(len(mv), len(MAGIC) + 9 + 65536), -1, None):
        if isinstance(rec, tuple) and rec[0] == "header":
            return rec[1], rec[2]
        break
    return "", ""


def read_message_data(buf, loc: tuple[int, int, int], chunk_cache: dict | None = None) -> bytes:
    """Bytes of one message from its loc (see MessageRec). chunk_cache keeps the last decompressed chunk."""
    chunk_offset, off, n = (int(x) for x in loc)
    if chunk_offset < 0:
        return bytes(buf[off:off + n])
    mv = memoryview(buf)
    (length,) = _U64.unpack_from(mv, chunk_offset + 1)
    comp, roff, rlen, usize, _ = parse_chunk(mv, chunk_offset + 9, chunk_offset + 9 + length)
    if comp == "":
        return bytes(mv[off:off + n])
    if chunk_cache is not None and chunk_cache.get("offset") == chunk_offset:
        inner = chunk_cache["data"]
    else:
        inner = decompress(comp, mv[roff:roff + rlen], usize)
        if chunk_cache is not None:
            chunk_cache.update(offset=chunk_offset, data=inner)
    return bytes(inner[off:off + n])
