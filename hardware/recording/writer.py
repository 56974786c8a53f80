"""Recorder: a threaded, crash-safe MCAP writer for everything a session produces.

The control loop calls non-blocking log_* methods; each snapshots its arguments into a bounded queue (a
deque, lock-free under the GIL) and returns True, or False when the queue is full or the recorder stopped
(counted in status().dropped_*). A writer thread encodes JSON, writes small MCAP chunks and flushes the
finished chunks every `flush_interval_s` (0.25 s), so a SIGKILL loses at most ~0.25 s plus the queue.
Camera frames (H x W x 3 uint8 RGB, ownership passes to the recorder) are JPEG-encoded by encoder threads.
A write error (disk full, device gone) stops the recorder cleanly: what was flushed stays readable
(`factr2 recover` adds the summary) and status().error holds a one-line message for the UI.
"""

from __future__ import annotations

import fcntl
import functools
import io
import os
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hardware.errors import UserError
from hardware.recording import schemas as S
from hardware.recording.protobuf_wire import encode_compressed_image
from hardware.recording.session import session_metadata

WRITER_YIELD_EVERY = 32  # messages the writer encodes between two hand-backs of the GIL (a tick waits less)
_FLOAT_FIELDS = ("q", "q_dot", "tau_m", "current", "q_cmd", "temperature")


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
    queue_depth: int
    last_flush_age_s: float


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


def _vec(x) -> list:
    return x.tolist() if isinstance(x, np.ndarray) else [float(v) for v in np.ravel(x)]


def _num(x) -> float:
    return float("nan") if x is None else float(x)


class Recorder:
    """Record one session to `path` (.mcap). Arguments:

    joint_names: {"leader": [...], "follower": [...]} stored in the channels' metadata.
    metadata: extra session metadata (str -> str), merged over session_metadata()'s defaults; see
      hardware.recording.session.session_metadata for the rig/arm/NEXT/operator fields.
    t0: rig clock time [s] now (Clock.now()); log_time = wall time of the start + (t - t0).
    jpeg_quality: 1-95. queue_size: max pending samples; frame_queue_size: max pending raw frames (120: ~1 s
      of 4 cameras at 30 Hz, ~110 MB at 640x480).
    compression: "zstd" (default), "lz4" or "" (none).
    """

    def __init__(self, path: str | Path, *, joint_names: dict[str, list[str]] | None = None,
                 metadata: dict[str, str] | None = None, t0: float | None = None, jpeg_quality: int = 85,
                 queue_size: int = 200_000, frame_queue_size: int = 120, encoder_threads: int = 2,
                 flush_interval_s: float = 0.25, chunk_size: int = 256 * 1024, compression: str = "zstd",
                 fsync_interval_s: float = 5.0, overwrite: bool = False, stream=None):
        from mcap.writer import CompressionType, Writer

        self.path = Path(path)
        self._joint_names = {k: list(v) for k, v in (joint_names or {}).items()}
        t0 = time.monotonic() if t0 is None else float(t0)
        self.clock_offset_s = time.time() - t0
        self._jpeg_quality = int(jpeg_quality)
        self._qmax, self._fqmax = int(queue_size), int(frame_queue_size)
        self._flush_interval = float(flush_interval_s)
        self._fsync_interval = float(fsync_interval_s)
        self._q: deque = deque()
        self._frames: deque = deque()
        self._frames_cv = threading.Condition()
        self._stop = False
        self._accepting = True
        self.error: str | None = None
        self.warning: str | None = None
        self._written = self._frames_written = self._dropped = self._dropped_frames = 0
        self._episode = -1
        self._size = 0
        self._last_t = float("nan")
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self._last_flush = time.monotonic()
        if stream is None:
            if self.path.exists() and not overwrite:
                raise UserError("recording file already exists", where=str(self.path),
                                fix="choose a new name (recordings are never overwritten)")
            try:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                stream = open(self.path, "wb")
                fcntl.flock(stream.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)  # episodes tools refuse it
            except OSError as e:
                raise UserError(f"cannot create recording ({e.strerror or e})", where=str(self.path),
                                fix="check the folder exists, is writable and has free space") from None
        self._f = stream
        comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                "": CompressionType.NONE}[compression]
        self._w = Writer(stream, chunk_size=chunk_size, compression=comp)
        meta = session_metadata(clock_offset_s=self.clock_offset_s, joint_names=self._joint_names)
        meta.update({k: str(v) for k, v in (metadata or {}).items()})
        try:
            self._w.start(profile=S.PROFILE, library=f"factr2-recorder {meta.get('software_version', '')}")
            self._w.add_metadata(S.SESSION_METADATA, meta)
            self._w.flush()
        except OSError as e:
            raise UserError(f"cannot write recording ({e.strerror or e})", where=str(self.path),
                            fix="free disk space or choose another folder") from None
        self._threads = [threading.Thread(target=self._run, name="factr2-recorder", daemon=True)]
        self._threads += [threading.Thread(target=self._encode_frames, name=f"factr2-jpeg{i}", daemon=True)
                          for i in range(max(1, int(encoder_threads)))]
        for th in self._threads:
            th.start()

    # ---- non-blocking API for the control loop and the UI --------------------------------------------
    def _put(self, item) -> bool:
        if not self._accepting or len(self._q) >= self._qmax:
            self._dropped += 1
            return False
        self._q.append(item)
        return True

    @_never_raises
    def log_joint_state(self, topic_or_arm: str, t: float, state) -> bool:
        """A hardware.types.JointState of arm "leader"/"follower" (or a full topic name) at time t [s]."""
        topic = topic_or_arm if topic_or_arm.startswith("/") else S.joint_state_topic(topic_or_arm)
        p = {"t": float(t), "q": _vec(state.q), "q_dot": _vec(state.q_dot), "tau_m": _vec(state.tau_m),
             "current": _vec(state.current), "q_cmd": _vec(state.q_cmd),
             "temperature": _vec(state.temperature),
             "status": np.asarray(state.status).astype(np.int64).tolist(),
             "gripper_pos": float(state.gripper_pos), "gripper_effort": float(state.gripper_effort)}
        return self._put((S.JOINT_STATE, topic, p))

    @_never_raises
    def log_external_torque(self, arm: str, t: float, tau_ext, contact: bool) -> bool:
        """Estimated external torque [N*m] per joint and the contact state of `arm`."""
        return self._put((S.EXTERNAL_TORQUE, S.tau_ext_topic(arm),
                          {"t": float(t), "tau_ext": _vec(tau_ext), "contact": bool(contact)}))

    @_never_raises
    def log_torque_command(self, arm: str, t: float, tau, gate: float | None = None) -> bool:
        """Torque commanded to `arm` [N*m] (the leader's force feedback), optional feedback gate [0, 1]."""
        return self._put((S.TORQUE_COMMAND, S.tau_cmd_topic(arm),
                          {"t": float(t), "tau": _vec(tau), "gate": _num(gate)}))

    @_never_raises
    def log_follower_command(self, arm: str, t: float, q, gripper: float = float("nan"),
                             hold: bool = False) -> bool:
        """The position target [rad] and gripper target [m] a follower was sent after the safety layer (the
        policy's action), and whether the layer turned it into a hold."""
        return self._put((S.FOLLOWER_COMMAND, S.command_topic(arm),
                          {"t": float(t), "q": _vec(q), "gripper": _num(gripper), "hold": bool(hold)}))

    @_never_raises
    def log_ground_truth(self, arm: str, t: float, tau_ext_true, contact: bool, force=None) -> bool:
        """Twin only: true external torque [N*m], contact flag, net contact force [N] (x, y, z)."""
        f = _vec(force) if force is not None else [float("nan")] * 3
        return self._put((S.GROUND_TRUTH, S.ground_truth_topic(arm),
                          {"t": float(t), "tau_ext_true": _vec(tau_ext_true), "contact": bool(contact),
                           "force": f}))

    @_never_raises
    def log_task_objects(self, t: float, values, names) -> bool:
        """PRIVILEGED (twin only): the task objects' state vector (policies/privileged.py); `names` (one per
        element, fixed for the session) go into the channel's metadata on first use."""
        self._joint_names.setdefault(S.TOPIC_TASK_OBJECTS.split("/")[1], [str(n) for n in names])
        return self._put((S.TASK_OBJECTS, S.TOPIC_TASK_OBJECTS, {"t": float(t), "objects": _vec(values)}))

    @_never_raises
    def log_loop_timing(self, t: float, period_s: float, busy_s: float, late_s: float, overruns: int) -> bool:
        return self._put((S.LOOP_TIMING, S.TOPIC_LOOP, {"t": float(t), "period_s": float(period_s),
                                                        "busy_s": float(busy_s), "late_s": float(late_s),
                                                        "overruns": int(overruns)}))

    @_never_raises
    def log_image(self, camera: str, t: float, rgb: np.ndarray) -> bool:
        """An H x W x 3 uint8 RGB frame; JPEG-encoded off this thread. Do not modify `rgb` afterwards."""
        if not self._accepting or len(self._frames) >= self._fqmax:
            self._dropped_frames += 1
            return False
        with self._frames_cv:
            self._frames.append((camera, float(t), rgb))
            self._frames_cv.notify()
        return True

    @_never_raises
    def log_jpeg(self, camera: str, t: float, jpeg: bytes) -> bool:
        """An already-encoded JPEG frame (e.g. from an MJPEG camera)."""
        return self._put(("image", camera, float(t), bytes(jpeg)))

    def log_event(self, t: float, kind: str, text: str = "", value: float = float("nan"),
                  episode: int | None = None) -> bool:
        if kind not in S.EVENT_KINDS:
            raise ValueError(f"event kind {kind!r} not in {S.EVENT_KINDS}")
        ep = self._episode if episode is None else int(episode)
        return self._put(("event", float(t), kind, ep, str(text), float(value)))

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

    def status(self) -> RecorderStatus:
        try:
            self._size = os.fstat(self._f.fileno()).st_size
        except (OSError, ValueError, io.UnsupportedOperation, AttributeError):
            pass  # closed: keep the last size seen
        size = self._size
        return RecorderStatus(self._accepting and self.error is None, self.error, self.warning, self._written,
                              self._frames_written, size, self._dropped, self._dropped_frames,
                              len(self._q) + len(self._frames), time.monotonic() - self._last_flush)

    def close(self, timeout_s: float = 30.0) -> RecorderStatus:
        """Drain the queues, write the MCAP summary and close the file. Safe to call twice."""
        self._accepting = False
        self._stop = True
        with self._frames_cv:
            self._frames_cv.notify_all()
        for th in self._threads:
            th.join(timeout_s)
        return self.status()

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ---- worker threads ------------------------------------------------------------------------------
    def _encode_frames(self) -> None:
        from PIL import Image

        while True:
            with self._frames_cv:
                while not self._frames and not self._stop:
                    self._frames_cv.wait(0.1)
                if not self._frames:
                    if self._stop:
                        return
                    continue
                camera, t, rgb = self._frames.popleft()
            try:
                buf = io.BytesIO()
                img = Image.fromarray(np.ascontiguousarray(rgb))
                img.save(buf, format="JPEG", quality=self._jpeg_quality)
                self._q.append(("image", camera, t, buf.getvalue()))  # may pass the bound: never dropped here
            except Exception as e:  # a bad frame must not kill the encoder
                self._dropped_frames += 1
                self.warning = f"camera {camera}: frame not encodable, skipped ({e})"

    def _channel(self, topic: str, schema_name: str, encoding: str, schema_enc: str, data, meta) -> int:
        """Channel id of topic, registered on first use (data and meta are callables: built once)."""
        cid = self._channels.get(topic)
        if cid is None:
            sid = self._schemas.get(schema_name)
            if sid is None:
                sid = self._schemas[schema_name] = self._w.register_schema(schema_name, schema_enc, data())
            meta = meta()
            cid = self._channels[topic] = self._w.register_channel(topic, encoding, sid, meta)
        return cid

    def _write(self, item) -> None:
        kind = item[0]
        if kind == "image":
            _, camera, t, jpeg = item
            topic = S.camera_topic(camera)
            cid = self._channel(topic, S.IMAGE_SCHEMA_NAME, "protobuf", "protobuf",
                                lambda: S.image_schema()[2], lambda: {"camera": camera})
            ns = S.log_time_ns(t, self.clock_offset_s)
            self._w.add_message(cid, ns, encode_compressed_image(ns, jpeg, "jpeg", camera), ns)
            self._frames_written += 1
        elif kind == "event":
            _, t, ev, ep, text, value = item
            cid = self._channel(S.TOPIC_EVENTS, S.EVENT_SCHEMA_NAME, "json", "jsonschema",
                                S.event_json_schema, dict)
            ns = S.log_time_ns(t, self.clock_offset_s)
            self._w.add_message(cid, ns, S.encode_event(t, ev, ep, text, value), ns)
        else:
            schema, topic, payload = item
            cid = self._channels.get(topic)
            if cid is None:
                arm = topic.split("/")[1]
                cid = self._channel(topic, schema.name, "json", "jsonschema", schema.schema_bytes,
                                    lambda: {"arm": arm,
                                             "joint_names": ",".join(self._joint_names.get(arm, []))})
            ns = S.log_time_ns(payload["t"], self.clock_offset_s)
            self._w.add_message(cid, ns, S.encode_numeric(schema, payload), ns)
        self._written += 1

    def _run(self) -> None:
        last_sync = time.monotonic()
        try:
            while True:
                n = 0
                while self._q and n < 2000:
                    self._write(self._q.popleft())
                    n += 1
                    if n % WRITER_YIELD_EVERY == 0:
                        time.sleep(0)  # hand the GIL back so the control loop's wake-up is not delayed
                now = time.monotonic()
                if now - self._last_flush >= self._flush_interval:
                    self._w.flush()  # closes the chunk in progress and flushes the file
                    self._last_flush = now
                    if now - last_sync >= self._fsync_interval and hasattr(self._f, "fileno"):
                        os.fsync(self._f.fileno())
                        last_sync = now
                if n == 0:
                    if self._stop and not self._frames and all(not t.is_alive() for t in self._threads[1:]):
                        if not self._q:
                            break
                    time.sleep(0.003)
            self._w.add_metadata(S.STATS_METADATA, {
                "messages": str(self._written), "frames": str(self._frames_written),
                "dropped_samples": str(self._dropped), "dropped_frames": str(self._dropped_frames)})
            self._w.finish()
            self._f.flush()
            if hasattr(self._f, "fileno"):
                os.fsync(self._f.fileno())
        except Exception as e:  # disk full, device removed, ...: stop cleanly, keep what was flushed
            self._accepting = False
            why = getattr(e, "strerror", None) or str(e) or type(e).__name__
            self.error = (f"recording stopped: {why} while writing {self.path}; data up to the last flush "
                          "was "
                          f"kept -- free space, then run `factr2 recover {self.path}`")
            self._q.clear()
            self._frames.clear()
        finally:
            self.status()
            try:
                self._f.close()
            except Exception:
                pass
