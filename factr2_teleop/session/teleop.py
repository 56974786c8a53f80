"""A teleop session on an open rig: its pairs (session.pairs), the loop, per-tick hooks and the recording.
The CLI (`factr2 teleop`), the terminal app's Teleop screen, the demo and task collection all run this.

    ts = TeleopSession(rig_session, TeleopOptions(mode="next"))
    ts.hooks.append(fn)                         # fn(TickRecord) each tick, e.g. a virtual operator's hand
    rec = ts.record("recordings")               # optional: SessionRecording (cameras, truth, timing)
    rec.start_episode("wipe")
    ts.loop.run(duration_s=60)                  # or ts.loop.start() / ts.loop.stop()
    ts.close_recording()
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from factr2_teleop.session.pairs import TeleopOptions, build_pairs, follower_checkpoint, loop_rate_hz
from factr2_teleop.session.recording import SessionRecording
from factr2_teleop.teleop.loop import TeleopLoop
from factr2_teleop.teleop.record import TickRecord


class TeleopSession:
    def __init__(self, session, opts: TeleopOptions | None = None, *, clock=None,
                 next_estimators: dict | None = None, next_paths: dict | None = None):
        """session: an open rig (hardware open_rig); clock: the loop's clock (default the session's; the demo
        passes one that steps its twin); next_estimators / next_paths: per follower, an already loaded NEXT
        estimator and the checkpoint it came from (the demo's cache)."""
        self.session, self.opts = session, opts or TeleopOptions()
        self.rate_hz = loop_rate_hz(session.rig, self.opts)
        self.pairs = build_pairs(session, self.opts, next_estimators)
        self.hooks: list[Callable[[TickRecord], None]] = []
        self.recording: SessionRecording | None = None
        self._next_paths = dict(next_paths or {})
        self.loop = TeleopLoop(self.pairs, clock or session.clock, self.rate_hz, recorder=self._on_tick)

    # -- what runs ---------------------------------------------------------------------------------------
    @property
    def modes(self) -> dict[str, str]:
        """Pair name -> feedback mode."""
        return {p.cfg.name: p.mode for p in self.pairs}

    def next_checkpoint_id(self) -> str:
        """The NEXT checkpoints the pairs run (comma-separated paths with their data hash; "" for none)."""
        ids = []
        for p in self.pairs:
            if p.mode != "next":
                continue
            spec = self.session.rig.device(p.follower.name)
            path = self._next_paths.get(p.follower.name) or follower_checkpoint(spec, self.opts) or "?"
            ck = getattr(getattr(p.estimator, "next", None), "ck", None)
            h = getattr(ck, "data_hash", "")
            ids.append(f"{path}" + (f"#{h[:12]}" if h else ""))
        return ",".join(ids)

    def describe(self) -> list[str]:
        sim = " (SIMULATED twin)" if self.session.twin is not None else ""
        return [f"{p.cfg.name}: {p.leader.name} -> {p.follower.name}, feedback {p.mode}{sim}"
                for p in self.pairs]

    # -- recording ---------------------------------------------------------------------------------------
    def record(self, out: str | Path, *, stem: str | None = None, extra_meta: dict | None = None,
               task: str = "", cameras: bool = True, path: str | Path | None = None) -> SessionRecording:
        """Open this session's recording (one file; episodes are started on it). UserError when it cannot."""
        meta = {"feedback_mode": ",".join(sorted(set(self.modes.values())))}
        gains = {str(list(p.law.feedback.gain)) for p in self.pairs}
        meta["feedback_gain"] = ",".join(sorted(gains))
        meta.update(extra_meta or {})
        self.recording = SessionRecording.open(out, self.session, self.pairs, self.rate_hz, stem=stem,
                                               extra_meta=meta, next_checkpoint=self.next_checkpoint_id(),
                                               task=task, cameras=cameras, path=path)
        return self.recording

    def close_recording(self, why: str = ""):
        """Close the recording (an open episode ends unlabelled, with `why` as a note); its status or None."""
        rec, self.recording = self.recording, None
        return None if rec is None else rec.close(why)

    # -- per tick ----------------------------------------------------------------------------------------
    def _on_tick(self, r: TickRecord) -> None:
        for h in self.hooks:
            h(r)
        rec = self.recording
        if rec is not None:
            rec.on_tick(r)
