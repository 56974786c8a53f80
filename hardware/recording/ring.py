"""A byte ring in shared memory: one producer process (its threads behind one lock) hands length-prefixed
records to one consumer process, without a system call or a pickle on the producer's side.

Layout of a ring region (offsets in bytes from the region's start): head u64 at 0 (bytes ever written, the
producer's), tail u64 at 8 (bytes ever consumed, the consumer's), data from RING_HEADER on, `capacity` bytes.
A record is [length u32][crc u32][payload][zero padding to 8 bytes]; a record that does not fit before the
end of the data starts over at 0 behind a WRAP length. Why a CRC: on a CPU that reorders stores (aarch64),
the head may become visible before the record it covers; the CRC (seeded by the record's absolute offset, so
that a complete record from the previous lap never passes) tells the consumer to look again a moment later.
On x86-64 (total store order) it never fires. A record that stays bad for BAD_RECORD_WAIT_S is counted and
the consumer resynchronises at the head (it cannot happen without a bug or memory corruption).

Pure logic over a writable buffer (a memoryview of an mmap here, a bytearray in the tests).
"""

from __future__ import annotations

import struct
import time
import zlib

RING_HEADER = 64  # head, tail, then padding to a cache line
_U64 = struct.Struct("<Q")
_REC = struct.Struct("<II")  # length, crc
WRAP = 0xFFFFFFFF
BAD_RECORD_WAIT_S = 0.05  # how long a record may look torn before it is skipped


def region_size(capacity: int) -> int:
    """Bytes a ring of `capacity` data bytes takes (capacity rounded up to 8)."""
    return RING_HEADER + _round8(capacity)


def _round8(n: int) -> int:
    return (int(n) + 7) & ~7


def _crc(offset: int, parts) -> int:
    c = offset & 0xFFFFFFFF
    for p in parts:
        c = zlib.crc32(p, c)
    return c


class ByteRing:
    """One ring in `buf` (at least region_size(capacity) bytes). The producer calls put(), the consumer
    take(); each side keeps its own counter locally and publishes it through the shared header."""

    def __init__(self, buf, capacity: int):
        self.capacity = _round8(capacity)
        self._mv = memoryview(buf)[: region_size(self.capacity)]
        self._data = self._mv[RING_HEADER:]
        self._head = _U64.unpack_from(self._mv, 0)[0]  # producer's own copy (it alone writes it)
        self._tail = _U64.unpack_from(self._mv, 8)[0]  # consumer's own copy
        self._bad_since: float | None = None
        self.bad_records = 0  # consumer: records skipped as torn

    def release(self) -> None:
        """Let go of the buffer (an mmap can only close once no view of it is left)."""
        self._data.release()
        self._mv.release()

    # -- producer --------------------------------------------------------------------------------------
    def put(self, *parts) -> bool:
        """Append one record made of the byte-like `parts` (concatenated). False when it does not fit in
        the free space (the consumer is behind): nothing is written then."""
        n = sum(len(p) for p in parts)
        need = _REC.size + _round8(n)
        head, cap = self._head, self.capacity
        tail = _U64.unpack_from(self._mv, 8)[0]
        pos = head % cap
        waste = cap - pos if need > cap - pos else 0
        if need > cap or head + waste + need - tail > cap:
            return False
        if waste:
            _REC.pack_into(self._data, pos, WRAP, 0)
            head += waste
            pos = 0
        at = pos + _REC.size
        for p in parts:
            self._data[at: at + len(p)] = p
            at += len(p)
        _REC.pack_into(self._data, pos, n, _crc(head, parts))
        self._head = head + need
        _U64.pack_into(self._mv, 0, self._head)  # publish: the record is complete
        return True

    def used(self) -> int:
        """Bytes written and not yet consumed (either side may ask)."""
        return _U64.unpack_from(self._mv, 0)[0] - _U64.unpack_from(self._mv, 8)[0]

    # -- consumer --------------------------------------------------------------------------------------
    def take(self, max_records: int = 1 << 30, max_bytes: int = 1 << 62) -> list[bytes]:
        """Up to max_records complete records (copies), oldest first; fewer once max_bytes of payload were
        taken. A torn record ends the batch (it is looked at again next time)."""
        out: list[bytes] = []
        head = _U64.unpack_from(self._mv, 0)[0]
        tail, cap, got = self._tail, self.capacity, 0
        while tail < head and len(out) < max_records and got < max_bytes:
            pos = tail % cap
            n, crc = _REC.unpack_from(self._data, pos)
            if n == WRAP:
                tail += cap - pos
                continue
            end = pos + _REC.size + n
            payload = bytes(self._data[pos + _REC.size: end]) if end <= cap else b""
            if end > cap or _crc(tail, (payload,)) != crc:
                now = time.monotonic()
                if self._bad_since is None:
                    self._bad_since = now
                if now - self._bad_since < BAD_RECORD_WAIT_S:
                    break  # not visible yet: look again on the next call
                # torn for good: its length cannot be trusted, so resynchronise at the head (what lies
                # between is dropped and counted as one)
                self.bad_records += 1
                self._bad_since = None
                tail = head
                continue
            self._bad_since = None
            out.append(payload)
            got += n
            tail += _REC.size + _round8(n)
        self._tail = tail
        _U64.pack_into(self._mv, 8, tail)  # publish: the space is free again
        return out
