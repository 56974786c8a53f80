"""The recording's writer process: it takes the records the control process put into the shared rings
(hardware/recording/ring.py), encodes them (JSON, JPEG, zstd) and writes the MCAP file. Why a process and
not a thread: a writer thread in the control process holds the GIL while it encodes, and the loop's wake-up
waits for it; here the control thread only packs a record into shared memory, and the file survives the
app's death. It runs at normal priority (niced by WRITER_NICE), not as a real-time helper: a real-time
process on the other CPU starved the kernel's normal-priority workers there and the loop waited for its
leader (p99 period 5.1-5.8 ms against 2.1-3.5 ms beside a busy process; docs/recording_performance.md).

Shared block (STATUS_BYTES at the start of the mapping): little-endian u64 words, see the offsets below;
the error and warning texts follow. The rings come after it. The parent (hardware/recording/writer.py)
starts this as `python -m hardware.recording.writer_process` with the file and the mapping as inherited file
descriptors and a JSON configuration on stdin.

Crash safety: chunks are flushed every flush_interval_s (0.25 s) and fsynced every fsync_interval_s. When the
parent dies (SIGKILL, a crash) this process drains the rings and finishes the file with its summary, so
nothing that reached the ring is lost. When both die, what was flushed stays readable (`factr2 recover`).
"""

from __future__ import annotations

import errno
import io
import json
import mmap
import os
import signal
import struct
import sys
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor

from hardware.recording.space import ReserveBackedFile, SpaceReserve

STATUS_BYTES = 4096
STARTING, RUNNING, FINISHED, FAILED, FULL = range(5)  # FULL: the disk filled; what was handed over is written
# u64 word offsets in the status block
(W_STATE, W_CLOSING, W_WRITTEN, W_FRAMES, W_DROP_FRAMES, W_DROP_SAMPLES, W_BAD, W_CONSUMED, W_FLUSH_NS,
 W_ERROR_LEN, W_WARNING_LEN, W_PARENT_DROP_SAMPLES, W_PARENT_DROP_FRAMES) = range(0, 104, 8)
ERROR_AT, WARNING_AT, TEXT_MAX = 128, 1152, 1024
_U64 = struct.Struct("<Q")
IDLE_SLEEP_S = 0.002
FRAMES_PER_PASS = 8
PUBLISH_EVERY = 64  # records: the counters are published this often within a pass (a pass of 4000 records
# on a starved writer can take seconds; the parent's close() waits on this progress)
DISK_FULL_GRACE_S = 0.5  # s: after the disk is found full, the producer is refused at once (W_STATE FULL)
# and everything already in the rings is written from the space reserve (hardware/recording/space.py), however
# far behind the writer was (a lockstep loop runs ahead of it); then, at least this long after, the file is
# finished. A write that fails meanwhile ends it as any write error does.


class SharedStatus:
    """The status block over a buffer: words and two texts, read by the parent, written by the writer."""

    def __init__(self, buf):
        self.mv = memoryview(buf)

    def get(self, word: int) -> int:
        return _U64.unpack_from(self.mv, word)[0]

    def set(self, word: int, value: int) -> None:
        _U64.pack_into(self.mv, word, int(value))

    def text(self, which: str) -> str | None:
        at, w = (ERROR_AT, W_ERROR_LEN) if which == "error" else (WARNING_AT, W_WARNING_LEN)
        n = self.get(w)
        return bytes(self.mv[at: at + min(n, TEXT_MAX)]).decode(errors="replace") if n else None

    def set_text(self, which: str, text: str) -> None:
        at, w = (ERROR_AT, W_ERROR_LEN) if which == "error" else (WARNING_AT, W_WARNING_LEN)
        b = text.encode()[:TEXT_MAX]
        self.set(w, 0)
        self.mv[at: at + len(b)] = b
        self.set(w, len(b))


def _encode_jpeg(frame, quality: int) -> bytes:
    import io

    import numpy as np
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(frame.rgb())).save(buf, format="JPEG", quality=quality)
    return buf.getvalue()


class _Writer:
    def __init__(self, cfg: dict, status: SharedStatus, samples, frames, f, reserve, full):
        from hardware.recording import wire_records as R
        from hardware.recording.mcap_sink import McapSink

        self.R, self.cfg, self.status = R, cfg, status
        self.samples, self.frames = samples, frames
        self.path = cfg["path"]
        self.sink = McapSink(f, joint_names=cfg["joint_names"], metadata=cfg["metadata"],
                             clock_offset_s=cfg["clock_offset_s"], compression=cfg["compression"],
                             chunk_size=cfg["chunk_size"])
        self.topics: dict[int, object] = {}
        self.pending: deque = deque()  # (camera, t, future) in arrival order
        self.pool = ThreadPoolExecutor(max(1, int(cfg["encoder_threads"])), thread_name_prefix="factr2-jpeg")
        self.consumed = self.drop_samples = self.drop_frames = 0
        self.reserve, self.full = reserve, full  # full: a write found the disk full (ReserveBackedFile)

    def warn(self, text: str) -> None:
        self.status.set_text("warning", text)

    def handle(self, rec: bytes) -> None:
        R = self.R
        try:
            msg = R.unpack(rec)
            kind = msg[0]
            if kind == "topic":
                self.topics[msg[1]] = msg[2]
            elif kind == "numeric":
                for tid, values, lens in msg[1]:
                    top = self.topics[tid]
                    schema = R.SCHEMAS[top.code]
                    self.sink.numeric(schema, top.name, R.numeric_payload(schema, values, lens))
            elif kind == "event":
                self.sink.event(*msg[1:])
            elif kind == "names":
                for k, v in msg[1].items():
                    self.sink.joint_names.setdefault(k, list(v))
            elif kind == "frame":
                fr = msg[1]
                camera = self.topics[fr.topic_id].name
                if fr.encoding == R.JPEG:
                    self.pending.append((camera, fr.t, None, fr.data))
                else:
                    job = self.pool.submit(_encode_jpeg, fr, self.cfg["jpeg_quality"])
                    self.pending.append((camera, fr.t, job, None))
        except (ValueError, KeyError, IndexError, UnicodeDecodeError, struct.error) as e:
            is_frame = bool(rec) and rec[0] == R.FRAME
            if is_frame:
                self.drop_frames += 1
            else:
                self.drop_samples += 1
            what = "frame" if is_frame else "sample"
            self.warn(f"a malformed {what} was skipped ({type(e).__name__}: {e})")

    def write_encoded(self, wait: bool) -> None:
        while self.pending and (wait or self.pending[0][2] is None or self.pending[0][2].done()):
            camera, t, fut, jpeg = self.pending.popleft()
            if fut is not None:
                try:
                    jpeg = fut.result()
                except Exception as e:  # noqa: BLE001 -- a bad frame must not stop the recording
                    self.drop_frames += 1
                    self.warn(f"camera {camera}: frame not encodable, skipped ({e})")
                    continue
            self.sink.image(camera, t, jpeg)
            self.publish()

    def publish(self) -> None:
        st = self.status
        st.set(W_WRITTEN, self.sink.messages)
        st.set(W_FRAMES, self.sink.frames)
        st.set(W_DROP_FRAMES, self.drop_frames)
        st.set(W_DROP_SAMPLES, self.drop_samples)
        st.set(W_BAD, self.samples.bad_records + self.frames.bad_records)
        st.set(W_CONSUMED, self.consumed)

    def run(self) -> str:
        """Until the parent closes (or dies) and the rings are empty. Returns how it ended."""
        cfg, st = self.cfg, self.status
        parent = cfg["parent_pid"]
        flush_every, sync_every = cfg["flush_interval_s"], cfg["fsync_interval_s"]
        last_flush = last_sync = time.monotonic()
        full_at, free = None, 0  # when the disk was found (nearly) full [s, monotonic]
        st.set(W_FLUSH_NS, time.monotonic_ns())
        while True:
            recs = self.samples.take(max_records=4000)
            frames = self.frames.take(max_records=FRAMES_PER_PASS)
            if full_at is None and (recs or frames or self.full.is_set()):  # before writing them
                free = self.reserve.low()
                if free is not None or self.full.is_set():  # (nearly) full: what the rings hold is written
                    # into what is left, and the reserve is given back only by the write that meets ENOSPC
                    # (ReserveBackedFile): held till then, another process still filling the disk cannot
                    # take it before that write
                    free = free if free is not None else 0
                    full_at = time.monotonic()
                    st.set(W_STATE, FULL)  # the producer stops handing over: what is in the rings is older
                    st.set_text("warning", "the disk is full: writing what was handed over, then stopping")
            self.consumed += len(recs) + len(frames)
            for i, r in enumerate(recs + frames, 1):
                self.handle(r)
                if cfg.get("handle_delay_s"):  # tests: a writer slowed (a busy machine, a slow disk)
                    time.sleep(cfg["handle_delay_s"])
                if i % PUBLISH_EVERY == 0:  # progress the closing parent sees (writer.Recorder.close)
                    self.publish()
            self.write_encoded(wait=False)
            now = time.monotonic()
            drained = not recs and not frames and not self.samples.used() and not self.frames.used()
            closing = st.get(W_CLOSING) or os.getppid() != parent
            if full_at is not None and drained and (now - full_at >= DISK_FULL_GRACE_S or closing):
                self.write_encoded(wait=True)
                st.set_text("error", f"recording stopped: the disk is full ({free >> 10} KiB free) at "
                                     f"{self.path}; everything up to then was written and the file is "
                                     "complete")
                return "disk full"
            if now - last_flush >= flush_every:
                sync = now - last_sync >= sync_every
                self.sink.flush(fsync=sync)
                last_flush = now
                last_sync = now if sync else last_sync
                st.set(W_FLUSH_NS, time.monotonic_ns())
            self.publish()
            if not recs and not frames:
                if closing and not self.samples.used() and not self.frames.used():
                    return "closed" if st.get(W_CLOSING) else "producer ended without closing"
                time.sleep(IDLE_SLEEP_S)

    def finish(self, ended: str) -> None:
        self.write_encoded(wait=True)
        self.pool.shutdown(wait=True)
        self.publish()
        st = self.status
        self.sink.finish({"messages": str(self.sink.messages), "frames": str(self.sink.frames),
                          "dropped_samples": str(st.get(W_PARENT_DROP_SAMPLES) + self.drop_samples),
                          "dropped_frames": str(st.get(W_PARENT_DROP_FRAMES) + self.drop_frames),
                          "ended": ended})


def fail_text(path: str, e: BaseException) -> str:
    if getattr(e, "errno", None) == errno.ENOSPC:  # the space held to finish the file was taken as well
        why = "the disk is full and the space held to finish the file was taken too"
    else:
        why = getattr(e, "strerror", None) or str(e) or type(e).__name__
    return (f"recording stopped: {why} while writing {path}; data up to the last flush was kept -- free "
            f"space, then run `factr2 recover {path}`")


def attach_rings(buf, samples_bytes: int, frames_bytes: int):
    """The (samples, frames) rings that follow the status block in the shared mapping `buf`."""
    from hardware.recording.ring import ByteRing, region_size

    with memoryview(buf) as mv:
        return (ByteRing(mv[STATUS_BYTES:], samples_bytes),
                ByteRing(mv[STATUS_BYTES + region_size(samples_bytes):], frames_bytes))


WRITER_NICE = 5  # below the app's other work; see the module's docstring for why not real-time


def serve(cfg: dict) -> int:
    from hardware.recording.ring import region_size

    for sig in ("SIGINT", "SIGXFSZ"):  # Ctrl-C is the parent's to handle; a size limit is an OSError here
        if hasattr(signal, sig):
            signal.signal(getattr(signal, sig), signal.SIG_IGN)
    try:
        os.nice(WRITER_NICE)
    except OSError:
        pass
    if cfg.get("max_file_bytes"):
        import resource

        n = int(cfg["max_file_bytes"])
        resource.setrlimit(resource.RLIMIT_FSIZE, (n, n))
    total = STATUS_BYTES + region_size(cfg["samples_bytes"]) + region_size(cfg["frames_bytes"])
    mm = mmap.mmap(cfg["shm_fd"], total, flags=mmap.MAP_SHARED | getattr(mmap, "MAP_POPULATE", 0))
    st = SharedStatus(mm)
    samples, frames = attach_rings(mm, cfg["samples_bytes"], cfg["frames_bytes"])
    reserve = SpaceReserve(cfg["path"], create=False)  # the Recorder's: to end the file complete
    raw = ReserveBackedFile(cfg["file_fd"], reserve)
    f = io.BufferedWriter(raw)
    w = None
    try:
        w = _Writer(cfg, st, samples, frames, f, reserve, raw.full)
        st.set(W_STATE, RUNNING)
        ended = w.run()
        w.finish(ended)
        st.set(W_STATE, FINISHED)
        if ended == "disk full":
            _drain_until_closed(cfg, st, samples, frames)
        return 0
    except Exception as e:  # noqa: BLE001 -- disk full, device gone: said to the parent in one line
        st.set_text("error", fail_text(cfg["path"], e))
        st.set(W_STATE, FAILED)
        if w is not None:
            w.reserve.release()
            _drain_until_closed(cfg, st, samples, frames)
        return 1
    finally:
        if w is not None:
            w.reserve.release()
        try:
            f.close()
        except OSError:
            pass


def _drain_until_closed(cfg: dict, st, samples, frames) -> None:
    """Keep the rings moving (dropping what comes) until the parent closes, so that it never waits on us."""
    while not st.get(W_CLOSING) and os.getppid() == cfg["parent_pid"]:
        samples.take()
        frames.take()
        time.sleep(0.01)


if __name__ == "__main__":
    sys.exit(serve(json.loads(sys.stdin.buffer.read())))
