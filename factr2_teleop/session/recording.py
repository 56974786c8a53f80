"""A session's recording: one MCAP file per session (episodes inside), the per-tick hook of every arm pair,
the rig's cameras at their rate, the twin's ground truth (SIMULATED, labelled) and the loop's timing.

    rec = SessionRecording.open(out_dir, session, pairs, extra_meta={"feedback_mode": "next"})
    rec.start_episode(task="wipe")      # then starts the cameras (start_cameras) unless running
    loop = TeleopLoop(pairs, clock, rate, recorder=rec.on_tick)   # or call rec.on_tick from another hook
    rec.stop_episode("success"); rec.close()  -> RecorderStatus (+ rec.camera_stats)
"""

from __future__ import annotations

import queue
import threading
import time
from pathlib import Path

import numpy as np

from factr2_teleop.teleop.record import TickRecord
from hardware import sim_cpu
from hardware.errors import UserError
from hardware.features import arm_prefix, features_json, rig_features
from hardware.recording.arm_tick import record_arm_tick
from hardware.recording.writer_link import CLOSE_STALL_S, wait_while_progress

TRUTH_EVERY = 5  # ticks between ground-truth samples (each the mean over those ticks): 100 Hz at 500 Hz
TIMING_EVERY = 50  # ticks between loop-timing samples (10 Hz at 500 Hz)
HAND_OVER_EVERY = 50  # ticks kept before a hand-over if no loop calls hand_over() while it sleeps
# s of rig time: simulated time (a lossless recorder) keeps the packer at most this far behind the loop, so
# that a SIGKILL of the app loses no more than this plus the loop's unhanded batch (the writer process
# drains its rings); real time never waits: the backlog is the packer's, unbounded
SIM_BACKLOG_S = 0.05
BACKLOG_POLL_S = 0.0005  # s: how often a lockstep loop looks whether the packer caught up


def session_path(out_dir: str | Path, stem: str) -> Path:
    """A new file name in out_dir (never an existing one): <stem>-<date>-<time>[-k].mcap."""
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UserError(f"cannot create {out}: {e.strerror}", where="recording folder",
                        fix="pick a writable folder") from None
    path = out / f"{stem}-{time.strftime('%Y%m%d-%H%M%S')}.mcap"
    k = 1
    while path.exists():
        path = out / f"{stem}-{time.strftime('%Y%m%d-%H%M%S')}-{k}.mcap"
        k += 1
    return path


class SessionRecording:
    def __init__(self, recorder, session, pairs, rate_hz: float, start_cameras=None):
        """start_cameras: called as the first episode opens (the session's camera stream; frames come back
        through frame()), or None to record no frames."""
        self.recorder, self.session, self.rate_hz = recorder, session, float(rate_hz)
        n = len(pairs)
        self._pairs = {p.cfg.name: (p, arm_prefix(p.cfg.name, n)) for p in pairs}
        self._start_cameras = start_cameras
        self.camera_stats: dict = {}  # filled at close by the owner of the stream
        self._ticks = 0
        self._lock = threading.Lock()  # two loops (bimanual, real time) may share one file
        self._count_lock = threading.Lock()  # the backlog count: the loop adds, the packer takes away
        self.recording = False  # an episode is open
        # [t_start, t_stop] of every episode [s, rig clock]: a frame belongs to an episode by its timestamp,
        # not by when its render finished (a twin camera renders behind the lockstep stepper)
        self._spans: list[list[float]] = []
        # The loop's thread only collects each tick's record (a list append) and hands the tick's list to
        # the packing thread as it goes to sleep (hand_over(), TeleopLoop.idle); packing them into the
        # recorder's ring costs 50-90 us of cold-cache Python a tick on the dev VM, which the loop's thread
        # paid before (issue #37). Woken from the tick itself, the packer took the GIL mid-tick and the loop
        # waited for it. A record's arrays are never modified after its tick (every driver and law builds
        # new ones; tests/test_recording_process.py compares lockstep records with copies taken at the tick).
        self._batch: list = []
        self._pending: queue.SimpleQueue = queue.SimpleQueue()
        self._backlog = 0  # ticks handed over and not yet packed (the packer's count; read by the loop)
        self._max_backlog = max(1, int(SIM_BACKLOG_S * self.rate_hz)) if getattr(recorder, "lossless",
                                                                                  False) else None
        self._packer = threading.Thread(target=self._pack_ticks, name="factr2-record-ticks", daemon=True)
        self._packer.start()

    @classmethod
    def open(cls, out: str | Path, session, pairs, rate_hz: float, *, stem: str | None = None,
             extra_meta: dict | None = None, next_checkpoint: str = "", task: str = "",
             start_cameras=None, path: str | Path | None = None) -> SessionRecording:
        """A new recording in folder `out` (or exactly `path`). UserError when it cannot be written."""
        from hardware.arms import load_arm
        from hardware.recording.metadata import describe_recording
        from hardware.recording.writer import Recorder

        rig = session.rig
        p = Path(path) if path is not None else session_path(out, stem or rig.name)
        names, arms = {}, []
        for pair in pairs:
            pre = arm_prefix(pair.cfg.name, len(pairs))
            for role, dev in (("leader", pair.leader), ("follower", pair.follower)):
                arm = load_arm(rig.device(dev.name).arm)
                names[f"{pre}{role}"] = list(arm.joint_names)
                arms.append(arm.mjcf_path)
        meta = describe_recording(rig_path=rig.path, arm_files=arms, next_checkpoint=next_checkpoint,
                                  task=task, twin=session.twin is not None)
        meta["features"] = features_json(rig_features(rig))  # the one schema: what the file holds, by name
        meta.update({k: str(v) for k, v in (extra_meta or {}).items()})
        if session.cameras and start_cameras is not None:
            meta["cameras"] = ",".join(session.cameras)
        # simulated time waits for a starved writer rather than dropping (Recorder's lossless)
        rec = Recorder(p, joint_names=names, metadata=meta, t0=session.clock.now(),
                       lossless=not session.clock.realtime)
        faults = getattr(session.twin, "faults", None)
        if faults is not None:  # SIMULATED disk_full fills this recording's filesystem (sim/faults.py)
            faults.recording_dir = p.parent
        return cls(rec, session, pairs, rate_hz, start_cameras=start_cameras)

    @property
    def path(self) -> Path:
        return self.recorder.path

    # -- episodes ----------------------------------------------------------------------------------------
    def start_episode(self, task: str = "") -> int:
        """Open an episode at now, then start the cameras if they are not running: a frame they capture as
        they start is stamped after the episode's start and written (started first, the frames captured
        between the two were counted by the stream and not written)."""
        t = self.session.clock.now()
        ep = self.recorder.start_episode(t, task)
        self._spans.append([t, float("inf")])
        self.recording = True
        if self._start_cameras is not None:
            self._start_cameras()  # no-op once running
        return ep

    def stop_episode(self, outcome: str | None = None, text: str = "") -> None:
        t = self.session.clock.now()
        self.recorder.stop_episode(t, outcome, text)
        if self._spans:
            self._spans[-1][1] = t
        self.recording = False

    def frame(self, camera: str, t: float, rgb: np.ndarray) -> None:
        """A camera frame (the camera stream's thread) taken at t [s]: written when t lies in an episode,
        even if it arrives after that episode stopped (the file is still open). A recording opened without
        cameras (start_cameras None: `--no-cameras`) takes none, whoever else runs the stream."""
        if self._start_cameras is not None and any(t0 <= t <= t1 for t0, t1 in reversed(self._spans)):
            self.recorder.log_image(camera, t, rgb)

    # -- per tick (the loop's thread) --------------------------------------------------------------------
    def on_tick(self, r: TickRecord) -> None:
        if not self.recording:
            return
        pair, pre = self._pairs[r.pair]
        gt = None
        with self._lock:  # two loops (bimanual, real time) may share one file
            self._ticks += 1
            ticks = self._ticks
            twin = self.session.twin
            if twin is not None and ticks % TRUTH_EVERY == 0:  # SIMULATED: the twin's truth, at the tick
                with sim_cpu.simulated():  # privileged twin work, not the app's CPU (hardware/sim_cpu.py)
                    gt = twin.device_ground_truth(pair.follower.name, TRUTH_EVERY / self.rate_hz)
            timing = ticks % TIMING_EVERY == 0 and np.isfinite(r.loop_period_s)
            self._batch.append((r, pre, gt, pair.follower.n_joints, timing))
            if len(self._batch) >= HAND_OVER_EVERY:
                self._hand_over_locked()

    def hand_over(self) -> None:
        """The ticks collected so far to the packing thread (the loop calls it as it goes to sleep)."""
        if self._batch:
            with self._lock:
                self._hand_over_locked()

    def _hand_over_locked(self) -> None:
        if self._batch:
            with self._count_lock:
                self._backlog += len(self._batch)
            self._pending.put(self._batch)
            self._batch = []
            if self._max_backlog is not None:  # simulated time: nothing is late by waiting for the packer
                while self._backlog > self._max_backlog and self._packer.is_alive():
                    time.sleep(BACKLOG_POLL_S)

    def _pack_ticks(self) -> None:
        rec = self.recorder
        while (batch := self._pending.get()) is not None:
            for r, pre, gt, n, timing in batch:
                record_arm_tick(rec, pre, r.t, leader=r.leader, follower=r.follower, tau_ext=r.tau_ext,
                                contact=r.contact, leader_tau_cmd=r.leader_tau_cmd, gate=r.gate,
                                action_q=r.action_q, action_gripper=r.action_gripper,
                                action_hold=r.action_hold, perturb_q=r.perturb_q)
                if gt is not None:  # SIMULATED ground truth: hardware has none to record
                    rec.log_ground_truth(f"{pre}follower", r.t, gt.tau_ext[:n], gt.contact)
                if timing:
                    rec.log_loop_timing(r.t, r.loop_period_s, r.loop_busy_s, r.loop_late_s, r.loop_overruns)
            with self._count_lock:
                self._backlog -= len(batch)

    # -- end -----------------------------------------------------------------------------------------------
    def close(self, why: str = ""):
        """End an open episode (kept, unlabelled, with a note), write the summary. Returns the
        RecorderStatus. Never raises."""
        if self.recording:
            if why:
                self.recorder.note(self.session.clock.now(), why)
            self.stop_episode(None)
        self.hand_over()
        self._pending.put(None)  # the packer writes what it holds, then ends
        self._join_packer(CLOSE_STALL_S)
        return self.recorder.close()

    def _join_packer(self, stall_s: float) -> None:
        """Wait for the packer while its backlog shrinks (a busy machine: slow, not lost); stop waiting after
        stall_s [s] without progress (the recorder's close then says what was kept)."""
        def ended(timeout_s: float) -> bool:
            self._packer.join(timeout_s)
            return not self._packer.is_alive()

        wait_while_progress(ended, lambda: self._backlog, stall_s)
