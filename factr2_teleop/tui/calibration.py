"""Calibration wizard: checklist, move to start, trajectory replay (progress, ETA, live torque and model
residual), abort on unexpected contact, NEXT training progress, then the report (accuracy against the
baselines, diagnosis summary) and activation of the calibration for the rig."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import VerticalScroll
from textual.widgets import Static

from factr2_teleop.tui.base import BaseScreen
from factr2_teleop.tui.calib_ctl import CalibrationRun
from factr2_teleop.tui.stops import OperatorStop, operator_stop
from factr2_teleop.tui.widgets import eta, progress_bar, sparkline

CHECKLIST = (
    ("w", "workspace clear: nothing and nobody within the arm's reach"),
    ("a", "arm mounted as configured in the rig file (base, table height, gripper)"),
    ("e", "emergency stop at hand (SPACE here; the hardware e-stop within reach)"),
)
STEPS = (
    ("plan", "plan the coverage trajectory"),
    ("to_start", "move to the start pose"),
    ("replay", "replay the free-motion trajectory"),
    ("train", "train NEXT"),
    ("diagnose", "diagnose the residual"),
    ("done", "activate for the rig"),
)
MINUTES_CHOICES = (0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0)


def step_lines(step: str, failed_at: str = "") -> list[str]:
    """[x] done, [>] running, [!] failed/aborted here, [ ] pending."""
    names = [s for s, _ in STEPS]
    broken = step in ("aborted", "failed")
    at = failed_at if broken else step
    cur = names.index(at) if at in names else -1
    out = []
    for i, (_, label) in enumerate(STEPS):
        if step == "done":
            mark = "x"
        elif i == cur:
            mark = "!" if broken else ">"
        else:
            mark = "x" if i < cur else " "
        out.append(f"[{mark}] {label}")
    return out


def report_lines(report: dict | None, diagnosis: dict | None) -> list[str]:
    """Accuracy table (held-out free-motion mean |tau_ext| per method, lower is better) + diagnosis."""
    out = []
    if report:
        u = report.get("units", "")
        out.append(f"held-out free motion, mean |tau_ext| [{u}] (truth 0, lower is better):")
        out.append(f"  {'method':<10} {'free L1':>9} {'contact L1':>11}")
        for m, v in report.get("methods", {}).items():
            free, con = v.get("free_l1_mean"), v.get("contact_l1_mean")
            out.append(
                f"  {m:<10} {'--' if free is None else f'{free:9.4f}':>9} "
                f"{'--' if con is None else f'{con:11.4f}':>11}"
            )
        out.append(
            f"  trained {report.get('epochs', '?')} epochs in {report.get('train_seconds', 0):.0f} s on "
            f"{report.get('data_minutes', 0):.2f} min of data ({report.get('device', '?')})"
        )
    if diagnosis:
        out.append(f"diagnosis: {diagnosis.get('verdict', '')}")
        names = diagnosis.get("joints") or []
        for s in diagnosis.get("steps", [])[1:]:
            a = s.get("added") or {}
            j = a.get("joint")
            jn = names[j] if isinstance(j, int) and j < len(names) else str(j)
            ev = a.get("evidence", {})
            out.append(
                f"  + {a.get('effect', '?')} on {jn}: held-out L1 {ev.get('heldout_l1_joint_before', 0):.3f}"
                f" -> {ev.get('heldout_l1_joint_after', 0):.3f}"
            )
    return out


class CalibrationScreen(BaseScreen):
    BINDINGS = [
        Binding("w", "check('w')", "Workspace"),
        Binding("a", "check('a')", "Mounted"),
        Binding("e", "check('e')", "E-stop"),
        Binding("g", "go", "Go"),
        Binding("x", "abort", "Abort"),
        Binding("left_square_bracket", "minutes(-1)", "Shorter"),
        Binding("right_square_bracket", "minutes(1)", "Longer"),
    ]

    def compose_body(self) -> ComposeResult:
        self.checked: set[str] = set()
        with VerticalScroll(id="body"):
            yield Static(markup=False, id="cal-head")
            yield Static(markup=False, id="cal-steps")
            yield Static(markup=False, id="cal-live")

    @property
    def run(self) -> CalibrationRun | None:
        return self.app.calibration

    def refresh_view(self) -> None:
        app = self.app
        run = self.run
        problem = app.calibration_problem()
        lines = []
        if problem:
            lines.append(f"NEXT calibration unavailable: {problem}")
        lines.append(
            f"replay length {app.cal_minutes:g} min ([ / ]), training up to {app.cal_epochs} epochs, "
            f"output {app.out_dir / 'calibration'}"
        )
        if run is None or run.state.step in ("idle",):
            lines.append("checklist (press the key to tick; all three before g starts):")
            for key, text in CHECKLIST:
                lines.append(f"  {key} [{'x' if key in self.checked else ' '}] {text}")
        self.query_one("#cal-head", Static).update("\n".join(lines))
        if run is None:
            self.query_one("#cal-steps", Static).update("\n".join(step_lines("idle")))
            self.query_one("#cal-live", Static).update("")
            return
        st = run.snapshot()
        steps = step_lines(st.step, st.failed_at)
        if st.step == "done":  # room for the report at 80x24
            steps = ["[x] plan, move to start, replay, train NEXT, diagnose, activate: all done"]
        if st.step in ("aborted", "failed"):
            steps.append(f"!! {st.line}")
        elif st.step != "done":
            steps.append(f"{progress_bar(st.progress, 30)} {eta(st.eta_s)}  {st.line}")
        self.query_one("#cal-steps", Static).update("\n".join(steps))
        live = []
        if st.step in ("replay",) or (st.tau and st.step in ("aborted", "failed")):
            live += self._sparks(st)
        if st.epoch_losses and st.step in ("train",):
            val = [v for _, _, v in st.epoch_losses]
            live.append(f"val loss {sparkline(val, 40)} {val[-1]:.4f}")
        if st.step == "done":  # activation first: it must be visible at 80x24 without scrolling
            live.append(f"ACTIVE for {run.spec.name} (until the app closes; teleop mode 'next'): "
                        f"{st.checkpoint}")
            live.append(f"rig file naming it (use with --rig): {st.rig_file}")
            live += report_lines(st.report, st.diagnosis)
        self.query_one("#cal-live", Static).update("\n".join(live))

    @staticmethod
    def _sparks(st) -> list[str]:
        tau = np.array(st.tau) if st.tau else np.zeros((0, 0))
        res = np.array(st.residual) if st.residual else np.zeros((0, 0))
        if tau.size == 0:
            return []
        out = [f"{'j':<2} {'measured torque [N*m]':<30}      {'model residual [N*m]':<30}"]
        for j in range(tau.shape[1]):
            out.append(
                f"{j + 1:<2} {sparkline(tau[:, j], 28)} {tau[-1, j]:+6.2f} "
                f"{sparkline(res[:, j], 28)} {res[-1, j]:+6.2f}"
            )
        return out

    def action_check(self, key: str) -> None:
        if self.run is not None and self.run.state.step not in ("idle", "done", "aborted", "failed"):
            return
        self.checked ^= {key}

    def action_minutes(self, d: int) -> None:
        app = self.app
        ch = MINUTES_CHOICES
        i = min(range(len(ch)), key=lambda k: abs(ch[k] - app.cal_minutes))
        app.cal_minutes = ch[max(0, min(len(ch) - 1, i + d))]

    def action_go(self) -> None:
        app = self.app
        problem = app.calibration_problem()
        if problem:
            app.say(f"NEXT calibration unavailable: {problem}")
            return
        if self.checked != {k for k, _ in CHECKLIST}:
            app.say("tick every checklist item first (w, a, e)")
            return
        if self.run is not None and self.run.state.step not in ("done", "aborted", "failed"):
            app.say("a calibration is already running")
            return
        out = app.out_dir / "calibration" / time.strftime("%Y%m%d-%H%M%S")
        run = CalibrationRun(
            app.runtime,
            out,
            minutes=app.cal_minutes,
            epochs=app.cal_epochs,
            samples_per_epoch=app.cal_samples_per_epoch,
        )
        app.calibration = run
        self.checked = set()
        app.calibration_thread = threading.Thread(
            target=run.run_all, name="factr2-tui-calibration", daemon=True
        )
        app.calibration_thread.start()
        app.say(f"calibration started ({app.cal_minutes:g} min replay) -> {Path(out)}")

    def action_abort(self) -> None:
        if self.run is not None:
            self.run.abort(operator_stop(OperatorStop.ABORTED))
            self.app.say("calibration abort requested: follower holds")
