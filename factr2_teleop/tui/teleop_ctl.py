"""Teleop + recording behind the Teleop screen (no Textual): builds the arm pairs of the connected rig, runs
the bilateral loop (factr2_teleop.teleop.loop.TeleopLoop) in a thread, and records episodes with
hardware.recording.Recorder. The loop's per-tick callback records and, on twins, moves the virtual hand.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from factr2_teleop.teleop.estimators import ESTIMATOR_MODES, make_estimator
from factr2_teleop.teleop.feedback import FeedbackConfig
from factr2_teleop.teleop.leader_law import arm_model_fns
from factr2_teleop.teleop.loop import TeleopLoop, TeleopSnapshot
from factr2_teleop.teleop.pair import ArmPair, PairConfig
from factr2_teleop.tui.runtime import RigRuntime
from hardware.errors import ConfigError, UserError

GAIN_STEP = 0.01  # K_f step per key press [leader N*m per follower N*m]
GAIN_MAX = 0.5
TIMING_LOG_EVERY = 50  # ticks between loop-timing records (10 Hz at 500 Hz)


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
        self._thread: threading.Thread | None = None
        self.recorder = None
        self._ep_t0 = float("nan")
        self._episodes_done = 0
        self._last_outcome = "-"
        self._lock = threading.RLock()
        self.stop_reason = "teleop stopped"
        self._ticks = 0
        self.last_error: str | None = None
        self.last_file: str | None = None
        self.next_flags: dict[str, str] = {}  # follower -> NEXT estimator state (ok / warming up / OOD)

    # -- feedback settings --------------------------------------------------------------------------------
    def modes(self) -> list[str]:
        """Feedback modes offered on this rig (ground_truth only on a twin)."""
        return [m for m in ESTIMATOR_MODES if m != "ground_truth" or self.rt.simulated]

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

    def _estimator(self, follower_spec, follower, twin):
        n = follower.n_joints
        kw: dict = {"follower_arm": follower_spec.arm, "pp_stiffness_nm_per_rad": 20.0}
        if self.mode == "ground_truth" and twin is not None:
            name = follower_spec.name
            period = 1.0 / self.rate_hz
            kw["truth"] = lambda: twin.device_ground_truth(name, period).tau_ext[:n]
        if self.mode == "next":
            problem = next_checkpoint_problem(self.rt)
            if problem:
                raise UserError(
                    f"NEXT feedback unavailable: {problem}",
                    where="Teleop",
                    fix="run the Calibration screen, or pick another mode (key m)",
                )
            kw["next_source"] = _next_source(follower_spec, self.next_flags)
        return make_estimator(self.mode, n, **kw)

    def build_pairs(self) -> list[ArmPair]:
        """One ArmPair per rig pair, with the rig's [teleop] law settings (factr2 teleop's pair_configs)
        and this screen's feedback mode and gain on top."""
        from factr2_teleop.commands.teleop import pair_configs

        s = self.rt.session
        tables, _ = pair_configs(s.rig)
        pairs = []
        dt = 1.0 / self.rate_hz
        for lname, fname in s.rig.pairs:
            leader, follower = s.leaders[lname], s.followers[fname]
            name = fname if len(s.rig.pairs) > 1 else "arm"
            cfg = PairConfig.from_dict(dict(tables.get(name, {"name": name})), where=f"teleop.pairs.{name}")
            fb = cfg.law.feedback
            fb.gain, fb.gate_on_contact, fb.enabled = self.gain, self.mode != "pp", self.mode != "none"
            grav, jac = arm_model_fns(s.rig.device(lname).arm)
            est = self._estimator(s.rig.device(fname), follower, s.twin)
            pairs.append(ArmPair(leader, follower, cfg, dt, gravity_fn=grav, jacobian_fn=jac, estimator=est))
        if not pairs:
            raise ConfigError(
                "the rig pairs no leader with a follower",
                where=str(s.rig.path),
                fix="add a [[pairs]] table or a leader",
            )
        return pairs

    def start(self) -> None:
        """Claim the rig and start the loop (UserError when it cannot start; the arms stay safe)."""
        self.rt.claim("teleop")
        try:
            pairs = self.build_pairs()
            self.loop = TeleopLoop(pairs, self.rt.session.clock, self.rate_hz, recorder=self._on_tick)
            if self.operator:
                self._start_operator()
        except BaseException:
            self.rt.release("teleop")
            raise
        self.last_error = None
        self.stop_reason = "teleop stopped"
        self.next_flags.clear()
        self._ticks = 0
        self._thread = threading.Thread(target=self._run, name="factr2-tui-teleop", daemon=True)
        self._thread.start()
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
            self._close_recording(self.stop_reason)
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
                    r.note(self._now(), why)
                    self.rec_stop()
                st = r.close()
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
    def _on_tick(self, rec: dict) -> None:
        s = self.rt.session
        pair = next((p for p in self.loop.pairs if p.cfg.name == rec["pair"]), None)
        if pair is not None and pair.leader.name in self.rt.hands:
            ls = pair.leader.last_state
            self.rt.hands[pair.leader.name].apply(rec["t"], ls.q, ls.q_dot)
        r = self.recorder
        if r is None or not np.isfinite(self._ep_t0) or pair is None:
            return
        t = rec["t"]
        prefix = "" if len(self.loop.pairs) == 1 else f"{rec['pair']}_"
        r.log_joint_state(f"{prefix}leader", t, pair.leader.last_state)
        r.log_joint_state(f"{prefix}follower", t, pair.follower.last_state)
        r.log_external_torque(f"{prefix}follower", t, rec["follower.joint.tau_ext"], rec["feedback.contact"])
        r.log_torque_command(f"{prefix}leader", t, rec["leader.joint.tau_cmd"], rec["feedback.gate"])
        if s.twin is not None:
            gt = s.twin.device_ground_truth(pair.follower.name, 1.0 / self.rate_hz)  # mean over the tick
            n = pair.follower.n_joints
            r.log_ground_truth(f"{prefix}follower", t, gt.tau_ext[:n], gt.contact)
        self._ticks += 1
        if self._ticks % TIMING_LOG_EVERY == 0:
            st = self.loop.timing.stats()
            r.log_loop_timing(t, st.period_p50_ms * 1e-3, st.compute_p99_ms * 1e-3, 0.0, st.overruns)

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
            from hardware.recording.session import describe_session
            from hardware.recording.writer import Recorder

            s = self.rt.session
            path = self.out_dir / f"{self.rt.rig.name}-{time.strftime('%Y%m%d-%H%M%S')}.mcap"
            k = 1
            while path.exists():
                path = path.with_name(f"{path.stem}-{k}.mcap")
                k += 1
            ck = next((f.next_checkpoint for f in s.rig.followers if f.next_checkpoint), "")
            meta = describe_session(
                rig_path=self.rt.rig.path,
                twin=s.twin is not None,
                next_checkpoint=ck if self.mode == "next" else "",
            )
            meta.update({"feedback_mode": self.mode, "feedback_gain": f"{self.gain:g}"})
            self.recorder = Recorder(path, t0=self._now(), metadata=meta)
        self._ep_t0 = self._now()
        ep = self.recorder.start_episode(self._ep_t0, task)
        self.rt.say(f"recording episode {ep} to {self.recorder.path.name}")
        return ep

    def rec_stop(self, outcome: str | None = None) -> None:
        if not self.recording:
            raise UserError("no episode is recording", where="Teleop", fix="start one first (key r)")
        t = self._now()
        self.recorder.stop_episode(t, outcome)
        self._ep_t0 = float("nan")
        self._episodes_done += 1
        self._last_outcome = outcome or "unlabelled"
        self.rt.say(f"episode {self.recorder.episode} stopped ({self._last_outcome})")

    def rec_discard(self) -> None:
        self.rec_stop("discard")

    def mark(self, outcome: str) -> None:
        """Label the current episode (stops it) or else the last one of the open file: success / failure."""
        if self.recording:
            self.rec_stop(outcome)
            return
        if self.recorder is None or self.recorder.episode < 0:
            raise UserError(
                "no episode to label in an open recording",
                where="Teleop",
                fix="label an episode before stopping teleop, or use `factr2 episodes`",
            )
        self.recorder.label_episode(self._now(), outcome, episode=self.recorder.episode)
        self._last_outcome = outcome
        self.rt.say(f"episode {self.recorder.episode} marked {outcome}")

    def note(self, text: str) -> None:
        if self.recorder is None:
            raise UserError("no recording to annotate", where="Teleop", fix="record an episode first (key r)")
        self.recorder.note(self._now(), text)
        self.rt.say(f"note added: {text}")

    def rec_state(self) -> RecordingState:
        r = self.recorder
        st = r.status() if r is not None else None
        dur = self._now() - self._ep_t0 if self.recording else float("nan")
        return RecordingState(
            str(r.path) if r else self.last_file,
            self.recording,
            r.episode if r else -1,
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


def _next_source(follower_spec, flags_out: dict):
    """NEXT tau_ext source for estimators.CallableEstimator, from the follower's configured checkpoint."""
    from calibration.next.checkpoint import load_checkpoint
    from calibration.next.estimator import NextEstimator

    ck = load_checkpoint(follower_spec.next_checkpoint, arm=follower_spec.arm)
    est = NextEstimator(ck)
    period = 1.0 / ck.rate_hz
    state = {"t": -np.inf}

    def source(inp):
        st = inp.follower
        if st.t - state["t"] < period - 1e-9:
            return None
        state["t"] = st.t
        q_cmd = inp.q_target_f if inp.q_target_f is not None else st.q
        e = est.update(st.q, st.q_dot, q_cmd, st.tau_m, temperature=st.temperature)
        flags_out[follower_spec.name] = (
            "out of training range (OOD)" if e.ood else ("warming up" if not e.valid else "ok")
        )
        return e.tau_ext, st.t, e.valid

    return source
