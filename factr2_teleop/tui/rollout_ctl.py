"""Policy rollout behind the Rollout screen (no Textual): `factr2_teleop.session.rollout.run_rollout` (the
same rollout as `factr2 rollout`, no second copy) in a worker thread, with its on_start hook giving this
controller the running session for the live view, the operator's marks and the stop / emergency stop.

The rollout opens the rig itself (on a twin task: the task's scene), so the app's own connection is closed
first. Emergency stop: the loop is told to stop, the follower holds and the leader goes to zero torque at
once from the calling thread (each attempted even if the other fails); the loop then ends safe.
"""

from __future__ import annotations

import queue
import re
import threading
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from calibration.next.ident import parse_ids
from factr2_teleop.tui.stops import STOPPED, OperatorStop
from hardware.errors import UserError
from hardware.reasons import Reason

TIME_LIMIT_CHOICES = (None, 2.0, 5.0, 10.0, 30.0, 60.0)  # [s] per episode; None: the task's own
EPISODE_CHOICES = (1, 2, 5, 10, 20)
MARK_KEYS = ("s", "y", "n")  # operator marks (MarkedRollout): next stage reached, success, failure


# the command line's options -> this screen's keys, for the session layer's check messages (which name the
# CLI's flags: "pass --task T" means nothing in the app)
APP_WORDS = (
    (re.compile(r"pass --task ([a-z][\w-]*)"), r"press t for task \1"),
    (re.compile(r"pass --task T\b"), "press t to pick a task"),
    (re.compile(r"--force\b"), "f (force)"),
    (re.compile(r"^--task: "), "Rollout: "),
    (re.compile(r"^--policy: "), "Rollout: "),
    (re.compile(r"^--episodes: "), "Rollout: "),
)


def app_words(text: str) -> str:
    """A check's one line with the command line's flags replaced by this screen's keys."""
    for pattern, repl in APP_WORDS:
        text = pattern.sub(repl, text)
    return text


@dataclass(frozen=True)
class RigProblem:
    """One finding of the rig check: text (in this screen's words); blocking: the rollout may not start
    (else a warning shown beside "OK")."""

    text: str
    blocking: bool = True

    def __str__(self) -> str:
        return self.text


def rig_problems(run: Path, rig: str, task: str | None, force: bool = False) -> list[RigProblem]:
    """What stands between the trained run and this rig (arm model, joint names, cameras, the NEXT checkpoint
    it was trained with; a task other than its demonstrations' unless forced), in words with this screen's
    keys; [] when nothing does. The session layer's own checks, run before any device opens. Blocking (loads
    the policy): a worker."""
    from factr2_teleop.session import rollout as R
    from factr2_teleop.session.task_check import task_mismatch
    from policies.rollout.runner import PolicyRunner

    out = []
    try:
        runner = PolicyRunner(run)
        R.check_options(R.RolloutOptions(rig=rig, policy=Path(run), task=task, force=force), runner)
    except UserError as e:
        return [RigProblem(app_words(str(e)))]
    if force and task_mismatch(runner.meta, task):
        why = task_mismatch(runner.meta, task)
        out.append(RigProblem(f"WARNING {why}: rolled out anyway (f: force is on)", blocking=False))
    try:
        _, note = R.resolve_next(runner.meta, None)
        if note is not None:
            out.append(RigProblem(str(note), blocking=False))
    except UserError as e:
        out.append(RigProblem(app_words(str(e))))
    return out


def policy_summary(run: Path) -> str:
    """One line: policy/method, steps, the arm and joints it was trained on, its NEXT checkpoint."""
    from policies.training import checkpoint as C

    m = C.read_meta(run)
    arms = m.get("arms", {})
    joints = arms.get("joint_names", [[]])[0]
    model = (arms.get("arm_models") or ["?"])[0] or "?"
    ids = parse_ids(m.get("next_checkpoint"))
    nxt = ", ".join(i.short for i in ids) if ids else "none (recorded tau_ext)"
    return (f"{m['policy']['policy']}/{m['method']} step {m['step']}, arm {model} ({len(joints)} joints), "
            f"NEXT {nxt}")


@dataclass
class RolloutState:
    """What the screen shows. status: starting | running | done | stopped | E-STOPPED | failed; stage: the
    policy target's phase (home / settle / run / idle); action_age_s: age of the executed action [s]."""

    status: str = "starting"
    line: str = ""
    t: float = float("nan")
    stage: str = "-"
    episode: int = 0
    episodes: int = 0
    q: np.ndarray | None = None  # follower joints [rad]
    q_cmd: np.ndarray | None = None  # last follower target sent, after the safety layer [rad]
    tau_ext: np.ndarray | None = None  # [N*m]
    hold: bool = False
    action_age_s: float = float("nan")
    stages: tuple = ()
    reached: dict = field(default_factory=dict)
    results: list = field(default_factory=list)  # per finished episode: (index, outcome, progress, seconds)
    recording: str | None = None
    held_at_estop: bool | None = None  # the follower reported its safe state right after the e-stop
    driver: str = ""  # who drives the follower (policy / operator; "" without takeover)
    takeovers: int = 0
    hand_nm: float = float("nan")  # the hand's torque on the leader [N*m]
    grab_nm: float = float("nan")  # the takeover threshold [N*m]


class RolloutRun:
    """One rollout (run_rollout's options) in a worker thread; snapshot() for the screen."""

    def __init__(self, opts, say=None, before=None, after=None):
        """before(): in the worker, before the rollout opens the rig (the app closes its connection);
        after(): in the worker when it has ended, however it ended."""
        from factr2_teleop.session.rollout_plan import RolloutHooks

        self.opts = replace(opts, progress=False)
        self.hooks = RolloutHooks(marks=queue.SimpleQueue(), on_start=self._attach)
        self.say = say or (lambda text: None)
        self._before, self._after = before, after
        self.state = RolloutState(episodes=int(opts.episodes))
        self.result = None  # the RolloutResult once it has run
        self._lock = threading.Lock()
        self._ts = self._target = self._eps = None
        self._stop_why: Reason | None = None  # an OperatorStop reason once asked to stop
        self.thread: threading.Thread | None = None

    @property
    def running(self) -> bool:
        return self.thread is not None and self.thread.is_alive()

    def start(self) -> None:
        self.thread = threading.Thread(target=self._run, name="factr2-tui-rollout", daemon=True)
        self.thread.start()

    def join(self, timeout_s: float | None = None) -> None:
        if self.thread is not None:
            self.thread.join(timeout_s)

    def _run(self) -> None:
        try:
            self._rollout()
        finally:
            self._ts = self._target = self._eps = None  # the closed session (its ruckig objects) goes now
            if self._after is not None:
                self._after()

    def _rollout(self) -> None:
        from factr2_teleop.session.rollout import run_rollout

        try:
            if self._before is not None:
                self._before()
            self.result = run_rollout(self.opts, self.hooks)
        except UserError as e:
            self._end("failed", str(e))
            return
        except Exception as e:  # noqa: BLE001 -- shown on screen; the rollout left the arms safe
            self._end("failed", f"{type(e).__name__}: {e}")
            return
        r = self.result
        with self._lock:
            self.state.recording = r.recording
        if self._stop_why is not None:
            self._end("E-STOPPED" if self._stop_why.kind is OperatorStop.ESTOP else "stopped",
                      f"{self._stop_why}: follower held, leader torque off")
        else:
            self._end("done", f"{len(r.episodes)} episode(s), success rate {r.success_rate:.0%}")

    def _end(self, status: str, line: str) -> None:
        with self._lock:
            self.state.status, self.state.line = status, line
        self.say(f"rollout {status.lower()}: {line}")

    # -- the running session (run_rollout's on_start hook, then the loop thread's tick hook) ------------
    def _attach(self, ts, target, eps) -> None:
        self._ts, self._target, self._eps = ts, target, eps
        stages = tuple(getattr(getattr(eps, "task", None), "stages", ()) or getattr(eps, "stages", ()))
        with self._lock:
            self.state.status, self.state.stages = "running", stages
            self.state.line = "homing, then the policy runs"
        ts.hooks.append(self._on_tick)

    def _on_tick(self, r) -> None:
        target, eps = self._target, self._eps
        if target is None:
            return
        if self._stop_why is not None:  # asked while starting (the loop's run() forgets an earlier stop)
            self._ts.loop.stop(timeout_s=0.0)
        tracker = getattr(eps, "tracker", None)
        reached = {}
        if tracker is not None:
            reached = {s: bool(d) for s, d in zip(self.state.stages, np.asarray(tracker.done).reshape(-1))}
        elif hasattr(eps, "reached"):
            reached = {s: s in eps.reached for s in self.state.stages}
        results = [(x.index, x.outcome, x.progress, x.duration_s) for x in eps.results]
        with self._lock:
            s = self.state
            s.t, s.stage = r.t, target.state
            s.q, s.tau_ext = r.follower.q, r.tau_ext
            if np.all(np.isfinite(r.action_q)):  # a hold tick sends no target: show the last one sent
                s.q_cmd = r.action_q
            s.hold = bool(r.action_hold)
            s.action_age_s = target.ages_s[-1] if target.ages_s and target.state == "run" else float("nan")
            s.reached, s.results = reached, results
            s.episode = len(results) + (1 if target.state != "idle" else 0)
            tk = target.takeover
            if tk is not None:
                s.driver = tk.driver + (" (handing back)" if tk.pending else "") + (
                    " HELD (fault in a handover)" if tk.held else "")
                s.takeovers, s.hand_nm, s.grab_nm = tk.count, tk.hand_max_nm, tk.cfg.grab_nm

    def snapshot(self) -> RolloutState:
        with self._lock:
            return replace(self.state, reached=dict(self.state.reached), results=list(self.state.results))

    # -- operator --------------------------------------------------------------------------------------------
    def mark(self, key: str) -> None:
        """s: next stage reached, y: success, n: failure (episodes the operator judges: no twin task)."""
        if self.opts.task:
            raise UserError("the twin task judges its episodes itself", where="Rollout",
                            fix="marks are for rollouts without a task (or on a real rig)")
        self.hooks.marks.put(key)

    def toggle_takeover(self) -> None:
        """Take over (the leader drives) or hand back to the policy: the key's (or pedal's) press."""
        target = self._target
        if target is None or target.takeover is None:
            raise UserError("this rollout runs without takeover", where="Rollout",
                            fix="start a rollout on a rig with a leader")
        target.takeover.press()

    def stop(self, why: Reason = STOPPED) -> None:
        """End the rollout (why: an OperatorStop reason): the loop stops after its tick and leaves the arms
        safe."""
        self._stop_why = self._stop_why or why
        if self._ts is not None and self._ts.loop is not None:
            self._ts.loop.stop(timeout_s=0.0)

    def estop(self) -> list[str]:
        """EMERGENCY STOP from any thread: stop the loop, follower hold, leader zero torque, now."""
        self._stop_why = Reason.of(OperatorStop.ESTOP)
        problems = []
        ts = self._ts
        if ts is None:
            return problems
        ts.loop.stop(timeout_s=0.0)
        for pair in ts.pairs:
            for dev, act in ((pair.follower, "hold"), (pair.leader, "zero_torque")):
                try:
                    getattr(dev, act)(self._stop_why)
                except Exception as e:  # noqa: BLE001 -- the other arm must still be made safe
                    problems.append(f"{dev.name}: {e}")
        with self._lock:
            self.state.held_at_estop = all(p.follower.in_safe_state for p in ts.pairs)
        return problems
