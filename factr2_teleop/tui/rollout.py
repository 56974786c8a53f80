"""Rollout screen: pick a trained run (checked against the rig: arm, joints, cameras, NEXT checkpoint; every
mismatch said in words), on a twin a task and a number of episodes, recording on or off; start / stop; live
commanded vs actual follower joints, tau_ext bars, the policy's stage and the executed action's age; the
per-episode outcome (judged by the twin task, or marked with s / y / n); who drives (policy or operator), the
takeover count and the hand's torque on the leader against its threshold, o takes over / hands back (the
hand on the leader does too). SPACE is the emergency stop."""

from __future__ import annotations

import numpy as np
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import VerticalScroll
from textual.widgets import Static

from factr2_teleop.session.takeover_switch import TOGGLE_KEY
from factr2_teleop.tui import rollout_ctl as R
from factr2_teleop.tui.base import BaseScreen
from factr2_teleop.tui.stops import OperatorStop, operator_stop
from factr2_teleop.tui.teleop import Q_RANGE, TAU_RANGE
from factr2_teleop.tui.train_ctl import list_runs
from factr2_teleop.tui.widgets import bar, fmt

RUNS_SHOWN = 3


def live_lines(st) -> list[str]:
    """Per joint: commanded target and actual follower position [rad], tau_ext [N*m] (bars + numbers)."""
    q = np.asarray(st.q if st.q is not None else [], float)
    qc = np.asarray(st.q_cmd if st.q_cmd is not None else [], float)
    te = np.asarray(st.tau_ext if st.tau_ext is not None else [], float)
    out = [f"{'j':<2} {'commanded q [rad]':<19} {'actual q [rad]':<19} {'tau_ext [N*m]':<19}"]

    def cell(a, j, rng):
        v = a[j] if j < len(a) else float("nan")
        return f"{bar(v, -rng, rng, 11)}{fmt(v, 7)}"

    for j in range(len(q)):
        out.append(f"{j + 1:<2} {cell(qc, j, Q_RANGE)} {cell(q, j, Q_RANGE)} {cell(te, j, TAU_RANGE)}")
    return out


def status_lines(st) -> list[str]:
    age = "-" if not np.isfinite(st.action_age_s) else f"{1e3 * st.action_age_s:.0f} ms"
    out = [f"rollout {st.status.upper()}: {st.line}"]  # not cut: the widget wraps an error's whole line
    if st.status in ("running", "E-STOPPED", "stopped", "done"):
        out.append(f"episode {min(max(st.episode, 1), st.episodes)}/{st.episodes}  stage {st.stage}  "
                   f"action age {age}  t {fmt(st.t, 6, 1)} s  {'follower HOLD' if st.hold else ''}")
    if st.driver:
        hand = "-" if not np.isfinite(st.hand_nm) else f"{st.hand_nm:.2f}"
        out.append(f"drives: {st.driver.upper()}  takeovers {st.takeovers}  hand {hand} / {st.grab_nm:.2f} "
                   f"N*m {bar(st.hand_nm, 0.0, 2 * st.grab_nm, 11)}  ({TOGGLE_KEY}: take over / hand back)")
    if st.stages:
        out.append("task stages: " + " ".join(f"{s}{'+' if st.reached.get(s) else '-'}" for s in st.stages))
    for idx, outcome, prog, secs in st.results[-3:]:
        out.append(f"  episode {idx}: {outcome.upper()} progress {prog:.2f} in {secs:.1f} s")
    if st.recording:
        out.append(f"recorded: {st.recording}"[:79])
    return out


class RolloutScreen(BaseScreen):
    BINDINGS = [
        Binding("up,k", "move(-1)", "Run up", show=False),
        Binding("down,j", "move(1)", "Run down", show=False),
        Binding("t", "task", "Task"),
        Binding("e", "episodes", "Episodes"),
        Binding("left_square_bracket", "limit(-1)", "Shorter", show=False),
        Binding("right_square_bracket", "limit(1)", "Longer", show=False),
        Binding("r", "record", "Rec on/off"),
        Binding("f", "force", "Force", show=False),
        Binding("d", "folder", "Folder"),
        Binding("g", "go", "Go"),
        Binding("x", "stop", "Stop"),
        Binding("s", "mark('s')", "Stage", show=False),
        Binding("y", "mark('y')", "Success", show=False),
        Binding("n", "mark('n')", "Failure", show=False),
        Binding(TOGGLE_KEY, "takeover", "Take over"),
        Binding("l", "reload", "Reload", show=False),
    ]

    def compose_body(self) -> ComposeResult:
        self.runs: list = []
        self.selected = 0
        self.check: dict = {}  # (run, rig, task) -> list of problems (None: checking)
        self.summary: dict = {}
        self._status = ""
        with VerticalScroll(id="body"):
            yield Static(markup=False, id="ro-head")
            yield Static(markup=False, id="ro-status")
            yield Static(markup=False, id="ro-live")

    def on_mount(self) -> None:
        super().on_mount()
        self.action_reload()

    def on_screen_resume(self) -> None:
        self.action_reload()

    @property
    def run(self) -> R.RolloutRun | None:
        return self.app.rollout

    def _key(self):
        if not self.runs:
            return None
        return (str(self.runs[self.selected].path), str(self.app.runtime.rig.path), self.app.rollout_task,
                self.app.rollout_force)

    # -- view -----------------------------------------------------------------------------------------------
    def refresh_view(self) -> None:
        app = self.app
        lines = [f"trained runs in {app.runs_dir} (up/down; d: another folder):"]
        if not self.runs:
            lines.append("  (none yet: train one on the Train screen, key 5, or d opens the folder of "
                         "`factr2 train --out`)")
        lo = max(0, min(self.selected - RUNS_SHOWN // 2, len(self.runs) - RUNS_SHOWN))
        for i, r in enumerate(self.runs[lo : lo + RUNS_SHOWN], start=lo):
            state = "final" if r.final else f"stopped at {r.step}"
            lines.append(f"{'>' if i == self.selected else ' '} {r.path.name[:32]:<32} {r.policy}/{r.method} "
                         f"{state}"[:79])
        key = self._key()
        if key is not None:
            lines.append(f"  {self.summary.get(key[0], 'reading ...')}"[:79])
            problems = self.check.get(key)
            if problems is None:
                lines.append("  rig check: checking ...")
            elif not any(p.blocking for p in problems):
                lines.append(f"  rig check: OK for {app.runtime.rig.name}"
                             + (f" with task {app.rollout_task}" if app.rollout_task else ""))
                lines += [f"  {p}" for p in problems]
            else:
                lines += [f"  rig check: {p}" for p in problems]
        limit = "task's" if app.rollout_limit_s is None else f"{app.rollout_limit_s:g} s"
        lines.append(f"task {app.rollout_task or 'none'} (t)  episodes {app.rollout_episodes} (e)  "
                     f"limit {limit} ([ ])  record {'ON' if app.rollout_record else 'off'} (r)"
                     + ("  FORCE (f)" if app.rollout_force else ""))
        if not app.rollout_task:
            lines.append("  no task: you judge each episode -- s stage reached, y success, n failure")
        self.query_one("#ro-head", Static).update("\n".join(lines))
        run = self.run
        st = run.snapshot() if run is not None else None
        self.query_one("#ro-status", Static).update(
            "\n".join(status_lines(st)) if st is not None else "g starts the rollout (SPACE: emergency stop)")
        self.query_one("#ro-live", Static).update("\n".join(live_lines(st)) if st is not None else "")
        if st is not None and st.status != self._status:
            self._status = st.status
        if key is not None and key not in self.check:
            self._check(key)

    def _check(self, key) -> None:
        self.check[key] = None
        run, rig, task, force = key

        def work():
            return R.policy_summary(run), R.rig_problems(run, rig, task, force)

        def done(result) -> None:
            self.summary[run], self.check[key] = result

        self.background(work, "rig check", done)

    # -- keys -----------------------------------------------------------------------------------------------
    def action_reload(self) -> None:
        folder = self.app.runs_dir

        def done(runs) -> None:
            self.runs = runs
            self.selected = min(self.selected, max(len(runs) - 1, 0))
            self.refresh_view()

        self.background(lambda: list_runs(folder), "runs", done)

    def action_move(self, d: int) -> None:
        if self.runs:
            self.selected = max(0, min(len(self.runs) - 1, self.selected + d))
            self.refresh_view()

    def _idle(self) -> bool:
        if self.run is not None and self.run.running:
            self.app.say("a rollout is running (x stops it, SPACE is the emergency stop)")
            return False
        return True

    def action_task(self) -> None:
        from hardware.sim.tasks import TASKS

        if not self._idle():
            return
        if not self.app.runtime.rig.simulated:
            self.app.say("twin tasks exist only on simulated rigs: on a real rig you mark outcomes (s/y/n)")
            return
        options = [None, *TASKS]
        cur = self.app.rollout_task
        self.app.rollout_task = options[(options.index(cur) + 1) % len(options)] if cur in options else None
        self.refresh_view()

    def action_episodes(self) -> None:
        if self._idle():
            ch = R.EPISODE_CHOICES
            cur = self.app.rollout_episodes
            self.app.rollout_episodes = ch[(ch.index(cur) + 1) % len(ch)] if cur in ch else ch[0]
            self.refresh_view()

    def action_limit(self, d: int) -> None:
        if self._idle():
            ch = R.TIME_LIMIT_CHOICES
            i = ch.index(self.app.rollout_limit_s) if self.app.rollout_limit_s in ch else 0
            self.app.rollout_limit_s = ch[max(0, min(len(ch) - 1, i + d))]
            self.refresh_view()

    def action_record(self) -> None:
        if self._idle():
            self.app.rollout_record = not self.app.rollout_record
            self.refresh_view()

    def action_force(self) -> None:
        """Roll out on a task the policy's demonstrations did not come from (a warning, not a refusal)."""
        if self._idle():
            app = self.app
            app.rollout_force = not app.rollout_force
            app.say(f"force {'ON: a task mismatch is only a warning' if app.rollout_force else 'off'}")
            self.refresh_view()

    def action_folder(self) -> None:
        from factr2_teleop.tui.folders import open_folder

        def reopened() -> None:
            self.selected = 0
            self.action_reload()

        open_folder(self, "runs", reopened)

    def action_go(self) -> None:
        app = self.app
        if not self._idle():
            return
        key = self._key()
        if key is None:
            app.say("no trained run: train one on the Train screen (key 5)")
            return
        problems = self.check.get(key)
        if problems is None:
            app.say("still checking the run against the rig: a moment")
            return
        blocking = [p for p in problems if p.blocking]
        if blocking:
            app.say(f"cannot roll out: {blocking[0]}"[:200])
            return
        try:
            app.start_rollout(key[0])
        except Exception as e:  # noqa: BLE001 -- one line
            app.say(f"rollout: {e}")
        self.refresh_view()

    def action_stop(self) -> None:
        if self.run is None or not self.run.running:
            self.app.say("no rollout is running")
            return
        self.run.stop(operator_stop(OperatorStop.USER))
        self.app.say("rollout stop requested: the follower holds")

    def action_mark(self, key: str) -> None:
        if self.run is None or not self.run.running:
            self.app.say("no rollout is running")
            return
        try:
            self.run.mark(key)
        except Exception as e:  # noqa: BLE001
            self.app.say(str(e))

    def action_takeover(self) -> None:
        if self.run is None or not self.run.running:
            self.app.say("no rollout is running")
            return
        try:
            self.run.toggle_takeover()
        except Exception as e:  # noqa: BLE001
            self.app.say(str(e))
