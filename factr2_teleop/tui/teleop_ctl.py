"""Teleop + recording behind the Teleop screen (no Textual): a factr2_teleop.session TeleopSession on the
connected rig (the same pairs, estimators and recording as `factr2 teleop` for the same options), its loop
in a thread, episodes in one session file. On twins a per-tick hook moves the virtual hand.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calibration.estimate import describe_flags
from factr2_teleop.session.pairs import TeleopOptions, modes_for
from factr2_teleop.session.teleop import TeleopSession
from factr2_teleop.teleop.feedback import FeedbackConfig
from factr2_teleop.teleop.loop import TeleopLoop, TeleopSnapshot
from factr2_teleop.teleop.record import TickRecord
from factr2_teleop.tui.runtime import RigRuntime
from factr2_teleop.tui.stops import OperatorStop, operator_stop
from hardware.errors import UserError

GAIN_STEP = 0.01  # K_f step per key press [leader N*m per follower N*m]
GAIN_MAX = 0.5


@dataclass
class RecordingState:
    """What the Teleop screen shows about recording. duration_s: current episode so far [s, rig clock]."""

    file: str | None
    recording: bool
    episode: int  # index of the current/last episode in the file (-1: none)
    episodes_done: int  # episodes stopped in this session
    duration_s: float
    last_outcome: str
    error: str | None
    dropped: int


def next_checkpoint_problem(runtime: RigRuntime) -> str | None:
    """Why mode "next" cannot run on this rig (None: a checkpoint is configured and exists)."""
    for f in runtime.rig.followers:
        ck = f.next_checkpoint
        if ck is None:
            return f"follower {f.name} has no next_checkpoint in {runtime.rig.path.name} (calibrate first)"
        if not Path(ck).with_suffix(".json").exists():
            return f"checkpoint {ck} not found (calibrate first)"
    return None


class TeleopController:
    def __init__(
        self,
        runtime: RigRuntime,
        out_dir: str | Path = "recordings",
        rate_hz: float = 500.0,
        mode: str | None = None,
        gain: float | None = None,
    ):
        self.rt = runtime
        self.out_dir = Path(out_dir)
        self.rate_hz = float(rate_hz)
        self.mode = mode or ("dob" if not runtime.simulated else "ground_truth")
        self.gain = FeedbackConfig().gain if gain is None else float(gain)
        self.operator = False  # SIMULATED: a scripted virtual operator drives the leader
        self.loop: TeleopLoop | None = None
        self.ts: TeleopSession | None = None
        self._thread: threading.Thread | None = None
        self.recorder = None
        self._ep_t0 = float("nan")
        self._episodes_done = 0
        self._last_outcome = "-"
        self._lock = threading.RLock()
        self.stop_reason = operator_stop(OperatorStop.TELEOP_STOPPED)  # the recording's closing note
        self._ticks = 0
        self.last_error: str | None = None
        self.last_file: str | None = None
        self.next_flags: dict[str, str] = {}  # follower -> NEXT estimator state (ok / warming up / OOD)

    # -- feedback settings --------------------------------------------------------------------------------
    def modes(self) -> list[str]:
        """Feedback modes offered on this rig (ground_truth only on a twin)."""
        return modes_for(self.rt.rig)

    def cycle_mode(self) -> str:
        if self.running:
            raise UserError(
                "feedback mode cannot change while teleop runs",
                where="Teleop",
                fix="stop teleop (key t), change the mode, start again",
            )
        ms = self.modes()
        self.mode = ms[(ms.index(self.mode) + 1) % len(ms)] if self.mode in ms else ms[0]
        return self.mode

    def set_gain(self, gain: float) -> float:
        """Feedback gain K_f (same on every joint), applied live to the running loop."""
        self.gain = float(np.clip(gain, 0.0, GAIN_MAX))
        if self.loop is not None:
            for p in self.loop.pairs:
                p.law.feedback.gain = np.full(p.law.feedback.n, self.gain)
        return self.gain

    # -- run ------------------------------------------------------------------------------------------------
    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def build(self) -> TeleopSession:
        """The pairs and loop for this screen's mode and gain (UserError when they cannot be built)."""
        if self.mode == "next":
            problem = next_checkpoint_problem(self.rt)
            if problem:
                raise UserError(f"NEXT feedback unavailable: {problem}", where="Teleop",
                                fix="run the Calibration screen, or pick another mode (key m)")
        return TeleopSession(self.rt.session, self.options())

    def options(self) -> TeleopOptions:
        """The session layer's TeleopOptions of this screen's settings."""
        return TeleopOptions(mode=self.mode, rate_hz=self.rate_hz, gain=self.gain)

    def start(self) -> None:
        """Claim the rig and start the loop (UserError when it cannot start; the arms stay safe)."""
        self.rt.claim("teleop")
        try:
            self.ts = self.build()
            self.ts.hooks.append(self._on_tick)
            self.loop = self.ts.loop
            if self.operator:
                self._start_operator()
        except BaseException:
            self.rt.release("teleop")
            raise
        self.last_error = None
        self.stop_reason = operator_stop(OperatorStop.TELEOP_STOPPED)  # the recording's closing note
        self.next_flags.clear()
        self._ticks = 0
        self._thread = threading.Thread(target=self._run, name="factr2-tui-teleop", daemon=True)
        self._thread.start()
        try:  # cameras run with teleop (this is a worker): recording an episode then starts at once
            for line in self.ts.start_cameras():
                self.rt.say(f"recording without it: {line}")
        except Exception as e:  # noqa: BLE001 -- teleop goes on without frames; say why
            self.rt.say(f"cameras unavailable: {e}")
        self.rt.say(f"teleop started: feedback {self.mode}, K_f {self.gain:.2f}, {self.rate_hz:.0f} Hz")

    def _run(self) -> None:
        try:
            self.loop.run()
        except BaseException as e:  # noqa: BLE001 -- shown on screen; the loop already made the arms safe
            self.last_error = f"{type(e).__name__}: {e}"
            self.rt.say(f"teleop stopped: {self.last_error}")
        finally:
            s = self.rt.session
            for name, h in self.rt.hands.items():  # SIMULATED: the hand stays where the operator left it
                h.operator = None
                q = s.leaders[name].last_state.q if s is not None else None
                if q is not None and np.all(np.isfinite(q)) and q.shape == h.q_ref.shape:
                    h.q_ref = np.asarray(q, dtype=float).copy()
            self._close_recording(str(self.stop_reason))
            if self.ts is not None:
                self.ts.stop_cameras()
            self.rt.release("teleop")

    def stop(self) -> None:
        """Stop the loop (arms left safe); a running episode ends (kept, unlabelled) and the file closes."""
        if self.loop is not None:
            self.loop.stop(timeout_s=2.0)
        if self._thread is not None:
            self._thread.join(3.0)
        self._close_recording("teleop stopped")
        self.rt.say("teleop stopped (leader torque off, follower hold)")

    def _close_recording(self, why: str) -> None:
        """End the episode in progress (unlabelled, with a note) and close the session file (one file per
        teleop run, complete with its summary). Never raises."""
        with self._lock:
            r = self.recorder
            if r is None:
                return
            try:
                if self.recording:
                    self._episodes_done += 1
                    self._last_outcome = "unlabelled"
                    self._ep_t0 = float("nan")
                st = self.ts.close_recording(why) if self.ts is not None else r.close(why)
                if st.error:
                    self.rt.say(f"recording closed with an error: {st.error}")
            except Exception as e:  # noqa: BLE001 -- the arms are already safe; say it
                self.rt.say(f"closing the recording failed: {e}")
            finally:
                self.last_file = str(r.path)
                self.recorder = None

    def snapshot(self) -> TeleopSnapshot | None:
        return None if self.loop is None else self.loop.snapshot()

    # -- SIMULATED operator ------------------------------------------------------------------------------
    def _start_operator(self) -> None:
        from factr2_teleop.teleop.virtual_operator import VirtualOperator, make_task_script

        for name, hand in self.rt.hands.items():
            home = hand.q_ref
            delta = np.zeros_like(home)
            delta[1:3] = [0.35, -0.30][: max(0, min(2, home.size - 1))]
            script = make_task_script(
                home,
                home + delta,
                home + 1.6 * delta,
                wipe_amp_rad=np.r_[0.25, np.zeros(home.size - 1)],
                free_s=2.0,
                reach_s=1.5,
                contact_s=1.0,
                wipe_s=2.0,
                release_s=1.5,
            )
            hand.operator = VirtualOperator(script, t0=self.rt.session.clock.now())
            self.rt.say(f"{name}: SIMULATED virtual operator runs a {script.duration_s:.0f} s task script")

    # -- per tick (loop thread) ---------------------------------------------------------------------------
    def _on_tick(self, rec: TickRecord) -> None:
        pair = next((p for p in self.loop.pairs if p.cfg.name == rec.pair), None)
        if pair is not None and pair.leader.name in self.rt.hands:  # SIMULATED hand on the leader
            ls = pair.leader.last_state
            self.rt.hands[pair.leader.name].apply(rec.t, ls.q, ls.q_dot)
        if pair is not None and pair.mode == "next":
            self.next_flags[pair.follower.name] = describe_flags(pair.estimator.flags)

    # -- recording ----------------------------------------------------------------------------------------
    @property
    def recording(self) -> bool:
        return self.recorder is not None and np.isfinite(self._ep_t0)

    def _now(self) -> float:
        return self.rt.session.clock.now() if self.rt.session is not None else float("nan")

    def rec_start(self, task: str = "") -> int:
        """Start an episode (opens the session file on first use). UserError when teleop is not running."""
        if not self.running:
            raise UserError("teleop is not running", where="Teleop", fix="start teleop first (key t)")
        if self.recording:
            raise UserError("already recording an episode", where="Teleop", fix="stop it first (key x)")
        if self.recorder is None:
            meta = {"operator_simulated": str(self.operator)}
            self.recorder = self.ts.record(self.out_dir, extra_meta=meta)
        self._ep_t0 = self._now()
        ep = self.recorder.start_episode(task)
        self.rt.say(f"recording episode {ep} to {self.recorder.path.name}")
        return ep

    def rec_stop(self, outcome: str | None = None) -> None:
        if not self.recording:
            raise UserError("no episode is recording", where="Teleop", fix="start one first (key r)")
        self.recorder.stop_episode(outcome)
        self._ep_t0 = float("nan")
        self._episodes_done += 1
        self._last_outcome = outcome or "unlabelled"
        self.rt.say(f"episode {self.recorder.recorder.episode} stopped ({self._last_outcome})")

    def rec_discard(self) -> None:
        self.rec_stop("discard")

    def mark(self, outcome: str) -> None:
        """Label the current episode (stops it) or else the last one of the open file: success / failure."""
        if self.recording:
            self.rec_stop(outcome)
            return
        if self.recorder is None or self.recorder.recorder.episode < 0:
            raise UserError(
                "no episode to label in an open recording",
                where="Teleop",
                fix="label an episode before stopping teleop, or use `factr2 episodes`",
            )
        w = self.recorder.recorder
        w.label_episode(self._now(), outcome, episode=w.episode)
        self._last_outcome = outcome
        self.rt.say(f"episode {w.episode} marked {outcome}")

    def note(self, text: str) -> None:
        if self.recorder is None:
            raise UserError("no recording to annotate", where="Teleop", fix="record an episode first (key r)")
        self.recorder.recorder.note(self._now(), text)
        self.rt.say(f"note added: {text}")

    def rec_state(self) -> RecordingState:
        r = self.recorder
        st = r.recorder.status() if r is not None else None
        dur = self._now() - self._ep_t0 if self.recording else float("nan")
        return RecordingState(
            str(r.path) if r else self.last_file,
            self.recording,
            r.recorder.episode if r else -1,
            self._episodes_done,
            dur,
            self._last_outcome,
            st.error if st else None,
            (st.dropped_samples + st.dropped_frames) if st else 0,
        )

    def close(self) -> None:
        """Stop teleop and close the recording file (summary written). Never raises."""
        try:
            if self.running or self.loop is not None:
                self.stop()
        finally:
            self._close_recording("app closed")

