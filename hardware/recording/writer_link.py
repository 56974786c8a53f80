"""The recorder's link to its writer process, the parent's side (hardware/recording/writer.py's Recorder is
the records' side): start the process over shared memory (the status block and the two rings of
writer_process.py), read its status, and at close wait on its progress, give up on a stall and recover the
file in place. wait_while_progress is also how the session's packer thread is joined
(factr2_teleop/session/recording.py).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass

from hardware.realtime import spawn_normal
from hardware.recording import writer_process as W
from hardware.recording.ring import region_size

CLOSE_STALL_S = 30.0  # s: close() gives up on the writer only after this long without progress (a busy
# machine makes it slow, never lost: a fixed wall-time limit cut recordings' ends at load 12-14)
CLOSE_POLL_S = 0.5  # s: how often close() looks for progress
WRITER_START_S = 120.0  # s: close() waits this long for a writer still starting (a new interpreter and its
# imports: ~0.2 s idle, seconds on a loaded machine) before its stall clock runs; one that never starts is
# given up on then


@dataclass
class RecorderStatus:
    """What the UI shows. error: None while healthy, else one line (what happened, what was kept)."""

    recording: bool
    error: str | None  # fatal: the recorder stopped (disk full, write error)
    warning: str | None  # last non-fatal problem (a malformed sample or frame was skipped)
    messages_written: int
    frames_written: int
    bytes_written: int
    dropped_samples: int
    dropped_frames: int
    queue_depth: int  # records handed over and not yet written
    last_flush_age_s: float
    recovered: bool = False  # close() gave up on a stalled writer and rewrote the file to its last record
    # (what the file holds may then end short of what was logged: an episode without its stop)


def _shared_file(size: int) -> int:
    """A file descriptor of `size` bytes of shared memory that the writer process inherits: an anonymous
    memfd on Linux (no /dev/shm size limit, nothing left behind after a crash), else an unlinked temp file."""
    if hasattr(os, "memfd_create"):
        fd = os.memfd_create("factr2-recorder")
    else:
        fd, name = tempfile.mkstemp(prefix="factr2-recorder-")
        os.unlink(name)
    os.ftruncate(fd, size)
    return fd


def wait_while_progress(ended, mark, stall_s: float, poll_s: float = CLOSE_POLL_S, started=None,
                        start_s: float = float("inf")) -> bool:
    """Wait for something to end while it makes progress: ended(timeout_s) -> True once it has ended (waiting
    up to timeout_s [s]), mark() -> a value that changes while it works. False after stall_s [s] without a
    change (the caller decides what giving up means). started() -> True once it has started: until then the
    stall clock does not run (a start-up is no stall), and the wait for the start ends after start_s [s]."""
    t0 = time.monotonic()
    last, t_last = mark(), t0
    while not ended(min(poll_s, stall_s)):
        now, t = mark(), time.monotonic()
        if started is not None and not started():
            if t - t0 >= start_s:
                return False
            last, t_last = now, t
        elif now != last:
            last, t_last = now, t
        elif t - t_last >= stall_s:
            return False
    return True


class WriterLink:
    """The writer process as the recorder sees it. A base of Recorder, sharing its state: path and _f (the
    open file the writer inherits), _reserve (hardware/recording/space.py), _life (status() against close()),
    _closed, warning, _dropped / _dropped_frames / _put_count (the producer's counts, in the status)."""

    def _start_writer(self, cfg: dict) -> None:
        import mmap

        total = W.STATUS_BYTES + region_size(cfg["samples_bytes"]) + region_size(cfg["frames_bytes"])
        self._shm_fd = _shared_file(total)
        # the writer process faults the pages in (MAP_POPULATE, ~65 ms for 96 MB): here a first touch then
        # only maps a page (a frame's copy that allocated 56 pages held the GIL for ~0.4 ms)
        self._mm = mmap.mmap(self._shm_fd, total)
        self._status = W.SharedStatus(self._mm)
        self._samples, self._frames = W.attach_rings(self._mm, cfg["samples_bytes"], cfg["frames_bytes"])
        cfg.update(shm_fd=self._shm_fd, file_fd=self._f.fileno())
        # A new interpreter (`python -m`), as the twin's render process: multiprocessing's spawn re-runs the
        # user's __main__, a fork would copy the loop's threads. Its own POSIX session: Ctrl-C is the app's.
        self._proc = spawn_normal([sys.executable, "-m", "hardware.recording.writer_process"],
                                      stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                                      stderr=subprocess.DEVNULL,
                                      pass_fds=(self._shm_fd, self._f.fileno()), start_new_session=True)
        self._proc.stdin.write(json.dumps(cfg).encode())
        self._proc.stdin.close()
        # Not waited for: records wait in the rings while it starts (~0.2 s; a twin's unheld leader would
        # sink meanwhile). A writer that cannot start or write says so through status().error.

    def _accepting(self) -> bool:
        return not self._closed and self._status.get(W.W_STATE) in (W.STARTING, W.RUNNING)

    def status(self) -> RecorderStatus:
        with self._life:
            if self._mm is None:
                return self._final
            return self._read_status()

    def _read_status(self) -> RecorderStatus:
        st = self._status
        try:
            size = os.fstat(self._f.fileno()).st_size
        except (OSError, ValueError):
            size = 0
        error = st.text("error")
        live = (W.STARTING, W.RUNNING, W.FULL)
        if error is None and st.get(W.W_STATE) in live and self._proc.poll() is not None:
            # died without a word (killed, out of memory)
            error = (f"recording stopped: its writer process ended unexpectedly "
                     f"(exit {self._proc.returncode}); "
                     f"run `factr2 recover {self.path}`")
            st.set_text("error", error)
            st.set(W.W_STATE, W.FAILED)
        child_warning = st.text("warning")
        flush_ns = st.get(W.W_FLUSH_NS)
        return RecorderStatus(
            self._accepting() and error is None, error, self.warning or child_warning, st.get(W.W_WRITTEN),
            st.get(W.W_FRAMES), size, self._dropped + st.get(W.W_DROP_SAMPLES) + st.get(W.W_BAD),
            self._dropped_frames + st.get(W.W_DROP_FRAMES), max(0, self._put_count - st.get(W.W_CONSUMED)),
            (time.monotonic_ns() - flush_ns) / 1e9 if flush_ns else float("nan"))

    def _progress_mark(self) -> tuple:
        """What changes while the writer works: its counters, flush time, state and the file's size."""
        st = self._status
        try:
            size = os.fstat(self._f.fileno()).st_size
        except (OSError, ValueError):
            size = -1
        return (st.get(W.W_CONSUMED), st.get(W.W_WRITTEN), st.get(W.W_FRAMES), st.get(W.W_FLUSH_NS),
                st.get(W.W_STATE), size)

    def _wait_writer(self, stall_s: float, start_s: float) -> bool:
        """Wait for the writer process to end while it makes progress, its stall clock running once it has
        started; False when it made none for stall_s [s] or did not start in start_s [s] (it is then
        killed)."""
        def ended(timeout_s: float) -> bool:
            try:
                self._proc.wait(timeout_s)
                return True
            except subprocess.TimeoutExpired:
                return False

        if wait_while_progress(ended, self._progress_mark, stall_s, started=self._writer_started,
                               start_s=start_s):
            return True
        self._proc.kill()
        self._proc.wait()
        return False

    def _writer_started(self) -> bool:
        return self._status.get(W.W_STATE) != W.STARTING

    def close(self, stall_s: float = CLOSE_STALL_S, start_s: float = WRITER_START_S) -> RecorderStatus:
        """Let the writer drain the rings, write the summary and close the file: waits as long as the writer
        makes progress (a busy machine), gives up after stall_s [s] without any, then recovers the file
        (hardware/recording/recover.py, as `factr2 recover`) so it reads to its last complete record.
        The stall clock starts when the writer has started (a writer still starting waits up to start_s [s]:
        its start-up is no stall). Safe to call twice."""
        if self._closed:
            return self._final
        self._closed = True
        st = self._status
        st.set(W.W_PARENT_DROP_SAMPLES, self._dropped)
        st.set(W.W_PARENT_DROP_FRAMES, self._dropped_frames)
        st.set(W.W_CLOSING, 1)
        stalled = not self._wait_writer(stall_s, start_s)
        why = (f"the writer made no progress for {stall_s:.0f} s" if self._writer_started() else
               f"the writer did not start in {start_s:.0f} s")
        if stalled and st.text("error") is None:
            st.set_text("error", f"recording stopped: {why}; run `factr2 recover {self.path}`")
        if st.get(W.W_STATE) not in (W.FINISHED, W.FAILED) and st.text("error") is None:
            st.set_text("error", f"recording stopped: the writer process ended ({self._proc.returncode}); "
                                 f"run `factr2 recover {self.path}`")
        self._reserve.release()  # (the writer gave it back already unless it died)
        with self._life:
            self._final = self._read_status()
            self._final.recording = False
            self._release()
        if stalled:
            self._final.error, self._final.recovered = self._recover_after_stall(why)
        return self._final

    def _recover_after_stall(self, why: str) -> tuple[str, bool]:
        """The killed writer's file rewritten in place to its last complete record: (the one-line error,
        whether it was recovered)."""
        from hardware.recording.recover import recover

        try:
            rep = recover(self.path, in_place=True)
        except Exception as e:  # noqa: BLE001 -- said in the one line; the file is left as it was
            return (f"recording stopped: {why} and recovering the file failed ({e}); "
                    f"run `factr2 recover {self.path}`"), False
        return (f"recording stopped: {why}; the file was recovered in place ({rep.messages} messages kept, "
                f"{rep.dropped} damaged dropped)"), True

    def _release(self) -> None:
        if self._mm is not None:
            for ring in (self._samples, self._frames):
                ring.release()
            self._status.mv.release()
            self._samples = self._frames = self._status = None
            self._mm.close()
            self._mm = None
            os.close(self._shm_fd)
        try:
            self._f.close()
        except OSError:
            pass

    def __del__(self):
        # never closed (an exception on the way): let the writer finish the file rather than wait for us
        if not getattr(self, "_closed", True) and getattr(self, "_status", None) is not None:
            self._status.set(W.W_CLOSING, 1)
