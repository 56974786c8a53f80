"""Recorder: a crash-safe MCAP recording whose encoding and writing run in a process of their own.

The control loop calls non-blocking log_* methods; each packs its arguments into a compact binary record
(hardware/recording/wire_records.py: one numpy concatenate, a few microseconds, no JSON) and puts it into a
shared-memory ring (hardware/recording/ring.py); it returns True, or False when the ring is full or the
recorder stopped (counted in status().dropped_*). The writer process (hardware/recording/writer_process.py)
encodes JSON and JPEG, writes small zstd MCAP chunks and flushes them every `flush_interval_s` (0.25 s).
Why a process: the encoding no longer holds this process's GIL, so the loop's wake-up never waits for it.
Camera frames (H x W x 3 uint8 RGB) are copied into a second ring and JPEG-encoded by the writer's threads.
A write error (disk full, device gone) stops the writer cleanly: what was flushed stays readable
(`factr2 recover` adds the summary) and status().error holds a one-line message for the UI. If this process
dies (SIGKILL, a crash), the writer drains the rings and finishes the file; if both die, at most the last
flush interval is lost. Starting the writer, reading its status and closing (waiting on its progress, the
recovery after a stall) are the Recorder's base, WriterLink (hardware/recording/writer_link.py).
"""

from __future__ import annotations

import fcntl
import functools
import itertools
import os
import threading
import time
from pathlib import Path

import numpy as np

from hardware.errors import UserError
from hardware.recording import schemas as S
from hardware.recording import wire_records as R
from hardware.recording.metadata import default_metadata
from hardware.recording.ring import ByteRing
from hardware.recording.space import SpaceReserve
from hardware.recording.writer_link import WriterLink

SAMPLES_BUFFER_BYTES = 32 << 20  # ~50 s of a bimanual 500 Hz run if the writer stalls (a slow disk)
JPEG_QUALITY = 85  # camera frames' JPEG quality (PIL, 4:2:0); policies read the settings back from the frames
LOSSLESS_WAIT_S = 10.0  # s: a lossless recorder's longest wait for room in a ring (then: dropped, counted)
LOSSLESS_POLL_S = 0.0005  # s: how often it looks
FRAMES_BUFFER_BYTES = 64 << 20  # ~9 s of one 320x240 camera at 30 Hz, ~1.2 s of four 640x480 ones


def _never_raises(fn):
    """A malformed sample is counted and skipped, never raised into the control loop."""

    @functools.wraps(fn)
    def wrapper(self, *args, **kwargs):
        try:
            return fn(self, *args, **kwargs)
        except (TypeError, ValueError, AttributeError, IndexError) as e:
            self._dropped += 1
            self.warning = f"{fn.__name__}: malformed input skipped ({type(e).__name__}: {e})"
            return False

    return wrapper


class Recorder(WriterLink):
    """Record one run to `path` (.mcap). Arguments:

    joint_names: {"leader": [...], "follower": [...]} stored in the channels' metadata.
    metadata: extra recording metadata (str -> str), merged over default_metadata()'s defaults; see
      hardware.recording.metadata.describe_recording for the rig/arm/NEXT/operator fields.
    t0: rig clock time [s] now (Clock.now()); log_time = wall time of the start + (t - t0).
    jpeg_quality: 1-95 (JPEG_QUALITY). buffer_bytes / frame_buffer_bytes: the shared rings for samples and
      raw frames (what waits while the writer is behind; beyond them records are dropped and counted).
    compression: "zstd" (default), "lz4" or "" (none). max_file_bytes: stop writing at this size (the
      writer's RLIMIT_FSIZE), as a full disk would.
    lossless: a full ring makes the producer wait for the writer (up to LOSSLESS_WAIT_S, then the record is
      dropped and counted) instead of dropping at once: for simulated time (a lockstep twin), where nothing
      is late by waiting, and a writer starved by a busy machine would otherwise lose whole seconds.
    """

    def __init__(self, path: str | Path, *, joint_names: dict[str, list[str]] | None = None,
                 metadata: dict[str, str] | None = None, t0: float | None = None,
                 jpeg_quality: int = JPEG_QUALITY,
                 buffer_bytes: int = SAMPLES_BUFFER_BYTES, frame_buffer_bytes: int = FRAMES_BUFFER_BYTES,
                 encoder_threads: int = 2, flush_interval_s: float = 0.25, chunk_size: int = 256 * 1024,
                 compression: str = "zstd", fsync_interval_s: float = 5.0, overwrite: bool = False,
                 max_file_bytes: int | None = None, lossless: bool = False, writer_delay_s: float = 0.0):
        if compression not in ("zstd", "lz4", ""):
            raise ValueError(f"compression {compression!r}: use zstd, lz4 or an empty string")
        self.path = Path(path)
        self._joint_names = {k: list(v) for k, v in (joint_names or {}).items()}
        t0 = time.monotonic() if t0 is None else float(t0)
        self.clock_offset_s = time.time() - t0
        self.warning: str | None = None
        self._dropped = self._dropped_frames = 0
        self.lossless = bool(lossless)
        self._episode = -1
        self._topics: dict[str, int] = {}
        self._lock = threading.Lock()  # the samples ring: the loop(s) and the UI
        self._frame_lock = threading.Lock()  # the frame ring: camera threads
        self._life = threading.RLock()  # status() (a UI thread) against close() releasing the shared memory
        self._ids = itertools.count()  # topic ids, shared by both rings (next() is atomic under the GIL)
        self._put_count = 0
        self._closed = False
        self._proc = self._mm = self._final = None
        if self.path.exists() and not overwrite:
            raise UserError("recording file already exists", where=str(self.path),
                            fix="choose a new name (recordings are never overwritten)")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._f = open(self.path, "wb")  # noqa: SIM115 -- the writer process inherits it; closed in close()
            fcntl.flock(self._f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)  # episodes tools refuse it
        except OSError as e:
            raise UserError(f"cannot create recording ({e.strerror or e})", where=str(self.path),
                            fix="check the folder exists, is writable and has free space") from None
        self._reserve = SpaceReserve(self.path)  # before the writer starts: a disk that fills meanwhile
        meta = default_metadata(clock_offset_s=self.clock_offset_s, joint_names=self._joint_names)
        meta.update({k: str(v) for k, v in (metadata or {}).items()})
        self._start_writer(dict(
            path=str(self.path), joint_names=self._joint_names, metadata=meta,
            clock_offset_s=self.clock_offset_s,
            compression=compression, chunk_size=int(chunk_size), jpeg_quality=int(jpeg_quality),
            encoder_threads=int(encoder_threads), flush_interval_s=float(flush_interval_s),
            fsync_interval_s=float(fsync_interval_s), samples_bytes=int(buffer_bytes),
            frames_bytes=int(frame_buffer_bytes), max_file_bytes=max_file_bytes, parent_pid=os.getpid(),
            handle_delay_s=float(writer_delay_s)))

    # ---- non-blocking API for the control loop and the UI --------------------------------------------
    def _topic(self, name: str, code: int, ring: ByteRing) -> int:
        """The id of a topic, announced to the writer on first use in the ring its records go through (so
        that the writer always reads the announcement first). Called under that ring's lock."""
        tid = self._topics.get(name)
        if tid is None:
            tid = self._topics[name] = next(self._ids)
            if not self._ring_put(ring, R.pack_topic(tid, code, name)):
                del self._topics[name]
                return -1
            self._put_count += 1
        return tid

    def _ring_put(self, ring: ByteRing, *parts) -> bool:
        """ring.put(*parts); lossless: while the ring is full and the writer alive, wait for it to drain."""
        if ring.put(*parts):
            return True
        if not self.lossless or sum(len(p) for p in parts) > ring.capacity // 2:
            return False
        deadline = time.monotonic() + LOSSLESS_WAIT_S
        while time.monotonic() < deadline and self._accepting() and self._proc.poll() is None:
            time.sleep(LOSSLESS_POLL_S)
            if ring.put(*parts):
                return True
        return False

    def _put(self, record: bytes) -> bool:
        if not self._accepting() or not self._ring_put(self._samples, record):
            self._dropped += 1
            return False
        self._put_count += 1
        return True

    def _numeric(self, schema: S.Schema, topic: str, t: float, scalars, vectors) -> bool:
        return self.log_batch([(schema, topic, t, scalars, vectors)])

    @_never_raises
    def log_batch(self, items) -> bool:
        """Several numeric messages as one record (an arm pair's tick: hardware/recording/arm_tick.py).
        items: (schema, topic, t [s], scalars, vectors), in the schema's field order."""
        with self._lock:
            packed = []
            for schema, topic, t, scalars, vectors in items:
                tid = self._topic(topic, R.SCHEMA_CODE[schema.name], self._samples)
                if tid < 0:
                    self._dropped += len(items)
                    return False
                packed.append((tid, float(t), scalars, vectors))
            if self._put(R.pack_numerics(packed)):
                return True
            self._dropped += len(items) - 1  # _put counted one
            return False

    @_never_raises
    def log_joint_state(self, topic_or_arm: str, t: float, state) -> bool:
        """A hardware.types.JointState of arm "leader"/"follower" (or a full topic name) at time t [s]."""
        topic = topic_or_arm if topic_or_arm.startswith("/") else S.joint_state_topic(topic_or_arm)
        return self._numeric(S.JOINT_STATE, topic, t, *R.joint_state_fields(state))

    @_never_raises
    def log_external_torque(self, arm: str, t: float, tau_ext, contact: bool) -> bool:
        """Estimated external torque [N*m] per joint and the contact state of `arm`."""
        return self._numeric(S.EXTERNAL_TORQUE, S.tau_ext_topic(arm), t, (bool(contact),), (tau_ext,))

    @_never_raises
    def log_torque_command(self, arm: str, t: float, tau, gate: float | None = None) -> bool:
        """Torque commanded to `arm` [N*m] (the leader's force feedback), optional feedback gate [0, 1]."""
        return self._numeric(S.TORQUE_COMMAND, S.tau_cmd_topic(arm), t, (R.num(gate),), (tau,))

    @_never_raises
    def log_follower_command(self, arm: str, t: float, q, gripper: float = float("nan"),
                             hold: bool = False) -> bool:
        """The position target [rad] and gripper target [m] a follower was sent after the safety layer (the
        policy's action), and whether the layer turned it into a hold."""
        return self._numeric(S.FOLLOWER_COMMAND, S.command_topic(arm), t, (R.num(gripper), bool(hold)), (q,))

    @_never_raises
    def log_ground_truth(self, arm: str, t: float, tau_ext_true, contact: bool, force=None) -> bool:
        """Twin only: true external torque [N*m], contact flag, net contact force [N] (x, y, z)."""
        f = np.full(3, np.nan) if force is None else force
        return self._numeric(S.GROUND_TRUTH, S.ground_truth_topic(arm), t, (bool(contact),),
                             (tau_ext_true, f))

    @_never_raises
    def log_task_objects(self, t: float, values, names) -> bool:
        """PRIVILEGED (twin only): the task objects' state vector (policies/data/privileged.py); `names` (one
        per element, fixed for the recording) go into the channel's metadata on first use."""
        return self._named_vector(S.TASK_OBJECTS, S.TOPIC_TASK_OBJECTS, t, values, names)

    @_never_raises
    def log_perceived(self, t: float, values, names) -> bool:
        """SIMULATED (twin only): the task objects as the simulated pose detector reports them
        (hardware/sim/perception.py seen_vector); `names` as for log_task_objects."""
        return self._named_vector(S.PERCEIVED_OBJECTS, S.TOPIC_PERCEIVED, t, values, names)

    def _named_vector(self, schema: S.Schema, topic: str, t: float, values, names) -> bool:
        arm = topic.split("/")[1]
        if arm not in self._joint_names:
            self._joint_names[arm] = [str(n) for n in names]
            with self._lock:
                self._put(R.pack_names({arm: self._joint_names[arm]}))
        return self._numeric(schema, topic, t, (), (values,))

    @_never_raises
    def log_driver(self, t: float, driver: int, hand_nm: float = float("nan")) -> bool:
        """Who drives the follower from t [s] on (schemas.DRIVER_POLICY / DRIVER_OPERATOR), on a change only;
        hand_nm: the hand's torque on the leader then [N*m]."""
        return self._numeric(S.ROLLOUT_DRIVER, S.TOPIC_ROLLOUT_DRIVER, t, (int(driver), R.num(hand_nm)), ())

    @_never_raises
    def log_loop_timing(self, t: float, period_s: float, busy_s: float, late_s: float, overruns: int) -> bool:
        return self._numeric(S.LOOP_TIMING, S.TOPIC_LOOP, t,
                             (float(period_s), float(busy_s), float(late_s), int(overruns)), ())

    def _frame(self, camera: str, t: float, encoding: int, data, shape: tuple[int, int, int]) -> bool:
        with self._frame_lock:  # not the samples' lock: a frame's copy must not delay the loop's records
            tid = self._topic(camera, R.CAMERA_CODE, self._frames)
            ok = tid >= 0 and self._accepting() and self._ring_put(
                self._frames, R.frame_header(tid, t, encoding, shape), data)
            self._put_count += ok
        if not ok:
            self._dropped_frames += 1
        return ok

    @_never_raises
    def log_image(self, camera: str, t: float, rgb: np.ndarray) -> bool:
        """An H x W x 3 uint8 RGB frame; copied into the frame ring and JPEG-encoded by the writer process."""
        a = np.ascontiguousarray(rgb, dtype=np.uint8)
        shape = a.shape + (1,) * (3 - a.ndim) if a.ndim < 3 else a.shape
        if len(shape) != 3:
            raise ValueError(f"frame of shape {a.shape}: expected H x W x 3")
        return self._frame(camera, float(t), R.RAW, memoryview(a).cast("B"), shape)

    @_never_raises
    def log_jpeg(self, camera: str, t: float, jpeg: bytes) -> bool:
        """An already-encoded JPEG frame (e.g. from an MJPEG camera)."""
        return self._frame(camera, float(t), R.JPEG, bytes(jpeg), (0, 0, 0))

    def log_event(self, t: float, kind: str, text: str = "", value: float = float("nan"),
                  episode: int | None = None) -> bool:
        if kind not in S.EVENT_KINDS:
            raise ValueError(f"event kind {kind!r} not in {S.EVENT_KINDS}")
        ep = self._episode if episode is None else int(episode)
        with self._lock:
            return self._put(R.pack_event(float(t), kind, ep, str(text), float(value)))

    def start_episode(self, t: float, task: str = "") -> int:
        """Start a new episode at t [s]; returns its index (0, 1, ... within this file)."""
        self._episode += 1
        self.log_event(t, "start", task)
        return self._episode

    def stop_episode(self, t: float, outcome: str | None = None, text: str = "") -> None:
        """Stop the current episode; outcome "success"/"failure"/"discard" labels it (may also come later
        through label_episode)."""
        self.log_event(t, "stop", text)
        if outcome:
            self.label_episode(t, outcome)

    def label_episode(self, t: float, outcome: str, episode: int | None = None, text: str = "") -> None:
        if outcome not in S.OUTCOME_KINDS:
            raise ValueError(f"outcome {outcome!r} not in {S.OUTCOME_KINDS}")
        self.log_event(t, outcome, text, episode=episode)

    def mark_progress(self, t: float, value: float, label: str = "") -> None:
        self.log_event(t, "progress", label, value)

    def note(self, t: float, text: str) -> None:
        self.log_event(t, "note", text)

    @property
    def episode(self) -> int:
        """Index of the last started episode (-1: none yet)."""
        return self._episode

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
