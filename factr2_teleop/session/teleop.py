"""A teleop session on an open rig: its pairs (session.pairs), the loop, per-tick hooks and the recording.
The CLI (`factr2 teleop`), the terminal app's Teleop screen, the demo and task collection all run this.

    ts = TeleopSession(rig_session, TeleopOptions(mode="next"))
    ts.hooks.append(fn)                         # fn(TickRecord) each tick, e.g. a virtual operator's hand
    rec = ts.record("recordings")               # optional: SessionRecording (cameras, truth, timing)
    ts.loop.start()
    rec.start_episode("wipe")                   # opens the episode, then starts the cameras unless running
    ...; ts.loop.stop()
    ts.close_recording()                        # stops the cameras too; ts.camera_stats()
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from calibration.next.ident import NextId, format_ids
from factr2_teleop.session.pairs import TeleopOptions, build_pairs, follower_checkpoint, loop_rate_hz
from factr2_teleop.session.recording import SessionRecording
from factr2_teleop.teleop.loop import TeleopLoop
from factr2_teleop.teleop.record import TickRecord

HEALTH_EVERY_TICKS = 25  # the recording's and the cameras' health is looked at every this many ticks (0.1 s
# at 250 Hz): a recording that stopped (disk full) and a camera frozen, gone or back are said and marked


class TeleopSession:
    def __init__(self, session, opts: TeleopOptions | None = None, *, clock=None,
                 next_estimators: dict | None = None, next_paths: dict | None = None, pair_class=None):
        """session: an open rig (hardware open_rig); clock: the loop's clock (default the session's; the demo
        passes one that steps its twin); next_estimators / next_paths: per follower, an already loaded NEXT
        estimator and the checkpoint it came from (the demo's cache); pair_class: see build_pairs."""
        self.session, self.opts = session, opts or TeleopOptions()
        self.rate_hz = loop_rate_hz(session.rig, self.opts)
        self.pairs = build_pairs(session, self.opts, next_estimators,
                                 **({"pair_class": pair_class} if pair_class else {}))
        self.hooks: list[Callable[[TickRecord], None]] = []
        self.recording: SessionRecording | None = None
        self.cameras = None  # hardware.cameras.stream.CameraStream while it runs
        self._camera_stats: dict = {}
        self._next_paths = dict(next_paths or {})
        self.loop = TeleopLoop(self.pairs, clock or session.clock, self.rate_hz, recorder=self._on_tick)
        self.loop.idle.append(self._idle)
        self.loop.on_rate_change.append(self._rate_changed)
        if session.twin is not None:  # SIMULATED: the hand that held a real-time twin's leaders lets go
            self.loop.on_begin.append(session.twin.release_start_hold)  # (hardware.sim.twin)
        self._idle_ticks = 0
        self._recording_error_said = False

    # -- what runs ---------------------------------------------------------------------------------------
    @property
    def modes(self) -> dict[str, str]:
        """Pair name -> feedback mode."""
        return {p.cfg.name: p.mode for p in self.pairs}

    def next_checkpoint_id(self) -> str:
        """The NEXT checkpoints the pairs run, in the one string form of calibration.next.ident (several:
        comma-separated; "" for none)."""
        ids = []
        for p in self.pairs:
            if p.mode != "next":
                continue
            spec = self.session.rig.device(p.follower.name)
            path = self._next_paths.get(p.follower.name) or follower_checkpoint(spec, self.opts) or "?"
            ids.append(NextId.of(path))
        return format_ids(ids)

    def describe(self) -> list[str]:
        twin = self.session.twin
        sim = " (SIMULATED twin)" if twin is not None else ""
        lines = [f"{p.cfg.name}: {p.leader.name} -> {p.follower.name}, feedback {p.mode}{sim}"
                 for p in self.pairs]
        note = getattr(twin, "realtime_note", None)  # the twin's emulators at normal priority: say why
        return lines + ([f"twin: {note}"] if note else [])

    # -- recording ---------------------------------------------------------------------------------------
    def record(self, out: str | Path, *, stem: str | None = None, extra_meta: dict | None = None,
               task: str = "", cameras: bool = True, path: str | Path | None = None) -> SessionRecording:
        """Open this session's recording (one file; episodes are started on it). UserError when it cannot."""
        meta = {"feedback_mode": ",".join(sorted(set(self.modes.values())))}
        gains = {str(list(p.law.feedback.gain)) for p in self.pairs}
        meta["feedback_gain"] = ",".join(sorted(gains))
        meta.update(extra_meta or {})
        self._recording_error_said = False  # a new recording's error is said again
        self.recording = SessionRecording.open(
            out, self.session, self.pairs, self.rate_hz, stem=stem, extra_meta=meta,
            next_checkpoint=self.next_checkpoint_id(), task=task, path=path,
            start_cameras=self.start_cameras if cameras and self.session.cameras else None)
        return self.recording

    def close_recording(self, why: str = ""):
        """Stop the cameras and close the recording (an open episode ends unlabelled, with `why` as a note);
        its status or None. The recording's camera_stats hold the stream's counts."""
        stats = self.stop_cameras()  # first: the frames still being rendered go to the recording
        rec, self.recording = self.recording, None
        if rec is None:
            return None
        rec.camera_stats = stats
        status = rec.close(why)
        err = getattr(status, "error", None)
        # a writer starved by other work can report after the loop's last health check: said here instead
        if err and not self._recording_error_said:
            self._recording_error_said = True
            self.loop.say("recording", f"{err} -- found as the recording closed")
        return status

    # -- cameras -----------------------------------------------------------------------------------------
    def start_cameras(self) -> list[str]:
        """Capture the rig's cameras beside the loop (a second or so to open: call it from a worker, or
        after the loop started); frames go to the recording while an episode records. Returns one line per
        camera that could not start (teleop goes on without it). If running: only those lines."""
        if not self.session.cameras:
            return []
        if self.cameras is not None:
            return self.cameras.problems()
        from hardware.cameras.stream import CameraStream

        self.cameras = CameraStream(self.session.cameras, self.session.clock, sink=self._frame,
                                    twin=self.session.twin)
        self.cameras.start()
        return self.cameras.problems()

    def stop_cameras(self) -> dict:
        """Stop capturing; the per-camera counts (hardware.cameras.stream.CameraStats)."""
        if self.cameras is not None:
            self.cameras.stop()
            self._camera_stats = self.cameras.stats()
            self.cameras = None
        return dict(self._camera_stats)

    def _frame(self, camera: str, t: float, rgb) -> None:
        rec = self.recording
        if rec is not None:
            rec.frame(camera, t, rgb)

    # -- per tick ----------------------------------------------------------------------------------------
    def _idle(self) -> None:
        rec = self.recording
        if rec is not None:
            rec.hand_over()  # this tick's records to the recording's packing thread, as the loop sleeps
        self._idle_ticks += 1
        if self._idle_ticks % HEALTH_EVERY_TICKS == 0:
            self._check_health(rec)

    def _check_health(self, rec) -> None:
        """Say (and mark in the recording) a recording that stopped and cameras that froze, went or came back.
        Reads only: the arms' commands do not depend on it."""
        if rec is not None and not self._recording_error_said:
            err = rec.recorder.status().error
            if err:  # e.g. the disk is full: what was flushed stays readable; the arms go on
                self._recording_error_said = True
                self.loop.say("recording", f"{err} -- teleop goes on without recording")
        cams = self.cameras
        if cams is not None:
            for t, _name, text in cams.take_events():
                self.loop.say("cameras", text, t)  # when the camera was asked (its thread may lag)
                if rec is not None:
                    rec.recorder.note(t, text)

    def _rate_changed(self, t: float, line: str) -> None:
        """The loop runs at a lower rate from now on (teleop/degrade.py): the recording notes when and why
        (its /loop/timing periods show the new rate)."""
        rec = self.recording
        if rec is not None:
            rec.recorder.note(t, line)

    def _on_tick(self, r: TickRecord) -> None:
        for h in self.hooks:
            h(r)
        rec = self.recording
        if rec is not None:
            rec.on_tick(r)


def message_lines(messages, most: int = 20) -> list[str]:
    """The loop's messages (t [s], who, text) as lines for a summary: holds, faults and recoveries, the first
    `most` of them and how many more."""
    lines = [f"{t:9.3f} s  {who}: {text}" for t, who, text in list(messages)[:most]]
    more = len(messages) - most
    return lines + ([f"... and {more} more messages"] if more > 0 else [])
