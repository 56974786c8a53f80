"""`factr2 demo`'s live view (SIMULATED): the demo run on the twin, shown with the Teleop screen's pieces.

    show_demo(run, worker)   # run: factr2_teleop.demo.task.DemoRun; worker: a thread whose target is run.run

commands/demo.py starts the worker first (a real-time DemoRun must run right after it is built: its twin is
not stepped until run() starts); a worker not started yet is started when the app mounts.

Shows per joint leader q, follower q, the follower's tau_ext estimate and the leader's feedback torque (bars +
numbers, tui.teleop.joint_lines), contact, loop rate and p99 period, the feedback mode, the virtual operator's
task phase and elapsed / remaining seconds, all labelled SIMULATED. The run stays in its own thread; the UI
polls run.loop.snapshot() (thread-safe) 5 times a second and never waits on the loop.

Keys: SPACE = emergency stop (the loop ends: leader zero torque, follower hold; if the loop thread does not
answer within WORKER_JOIN_S the safe states are commanded from here too; the view stays, showing the checked
state, until q). q / ctrl+q / ctrl+c = quit (same stop first). A run that ends on its own closes the view
after LINGER_S. show_demo returns one line saying how the run ended (commands/demo.py prints it).
"""

from __future__ import annotations

import asyncio
import threading
import time

import numpy as np
from textual.app import App, ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.widgets import Footer, Static

from factr2_teleop.tui.teleop import joint_lines, record_arrays
from factr2_teleop.tui.widgets import duration, fmt, progress_bar

REFRESH_S = 0.2  # s between screen updates
LINGER_S = 1.5  # s the last frame stays up after the run ends on its own
WORKER_JOIN_S = 2.0  # s to wait for the loop thread to end (it leaves the arms safe) before acting here


def _num(x, prec: int) -> str:
    return "-" if x is None or not np.isfinite(x) else f"{x:.{prec}f}"


def task_phase(run) -> str:
    """The virtual operator's current task phase ('-' before the first tick). Reads the last entry of a list
    the loop thread appends to (atomic in CPython); the warm-up may clear it meanwhile."""
    try:
        return run.operator.log[-1].phase
    except IndexError:
        return "-"


def head_lines(run, snap, elapsed_s: float, stop_line: str | None) -> list[str]:
    """The lines above the joint table, each <= 80 columns."""
    cfg = run.cfg
    rec = (snap.records.get("arm") or next(iter(snap.records.values()), None)) if snap else None
    phase = ", ".join(snap.phases.values()) if snap and snap.phases else "starting"
    contact = "CONTACT" if rec is not None and rec.contact else "free"
    gate = rec.gate if rec is not None else float("nan")
    last = "" if snap is None or snap.running else "last tick: "  # stopped: the arms are safe now
    remaining = max(cfg.seconds - elapsed_s, 0.0) if np.isfinite(elapsed_s) else float("nan")
    frac = elapsed_s / cfg.seconds if np.isfinite(elapsed_s) else 0.0
    lines = [
        f"SIMULATED twin, virtual operator: press + wipe the table | feedback {cfg.mode}",
        f"phase {phase} | task {task_phase(run)} | {last}contact: {contact} | gate {fmt(gate, 4, 2)}",
        f"t {duration(elapsed_s)} of {duration(cfg.seconds)}, {_num(remaining, 1)} s left "
        f"{progress_bar(frac, 20)}",
    ]
    if snap is None:
        lines.append("loop: setting up (warm-up) ...")
    else:
        tm = snap.timing
        clock = "sim clock" if cfg.clock == "lockstep" else "wall clock"
        lines.append(f"loop {_num(tm.rate_hz, 0)} Hz ({clock}), p99 period {_num(tm.period_p99_ms, 2)} ms, "
                     f"{tm.overruns} overruns / {tm.ticks} ticks")
        if snap.error:
            lines.append(f"STOPPED BY {snap.error}"[:80])
    if stop_line:
        lines.append(stop_line)
    return lines


class DemoApp(App):
    """The live view; returns (app.run()) a line saying how the run ended."""

    CSS_PATH = "factr2.tcss"
    TITLE = "factr2 demo"
    ENABLE_COMMAND_PALETTE = False
    BINDINGS = [
        Binding("space", "estop", "E-STOP", priority=True),
        Binding("q", "quit_safe", "Quit"),
        Binding("ctrl+q,ctrl+c", "quit_safe", "Quit", show=False, priority=True),
    ]

    def __init__(self, run, worker: threading.Thread, linger_s: float = LINGER_S):
        super().__init__()
        self.demo, self.worker, self.linger_s = run, worker, float(linger_s)
        self.estopped = False
        self.stop_line: str | None = None  # e-stop / quit progress shown under the timing line
        self.outcome = "finished"
        self._t_first = float("nan")  # loop time of the first tick [s]
        self._ended_at: float | None = None
        self._stopping = False

    def compose(self) -> ComposeResult:
        yield Static(markup=False, id="statusbar")
        with Vertical(id="body"):
            yield Static(markup=False, id="tele-head")
            yield Static(markup=False, id="joints")
        yield Static(markup=False, id="msgline")
        yield Footer(compact=True, show_command_palette=False)

    def on_mount(self) -> None:
        self.refresh_view()
        self.set_interval(REFRESH_S, self.refresh_view)
        if self.worker.ident is None:
            self._start_worker()

    def _start_worker(self) -> None:
        if self.worker.ident is None and not self._stopping and not self.estopped:
            self.worker.start()

    # -- the poll ----------------------------------------------------------------------------------------
    def elapsed_s(self, snap) -> float:
        if snap is None or not snap.records:
            return float("nan")
        if not np.isfinite(self._t_first):  # the log was cleared after warm-up: entry 0 is the first tick
            try:
                self._t_first = float(self.demo.operator.log[0].t)
            except IndexError:
                return float("nan")
        return max(snap.t - self._t_first, 0.0)

    def refresh_view(self) -> None:
        snap = self.demo.loop.snapshot()
        started = bool(snap.records) or snap.running
        snap = snap if started else None
        alive, unstarted = self.worker.is_alive(), self.worker.ident is None
        state = ("E-STOPPED" if self.estopped else "RUNNING" if alive else "STARTING" if unstarted
                 else "ENDED")
        self.query_one("#statusbar", Static).update(
            f" factr2 demo | {self.demo.cfg.rig} [SIMULATED] | {state} | SPACE=E-STOP  q quit")
        self.query_one("#tele-head", Static).update(
            "\n".join(head_lines(self.demo, snap, self.elapsed_s(snap), self.stop_line)))
        rec = next(iter(snap.records.values()), None) if snap else None
        table = "\n".join(joint_lines(*record_arrays(rec))) if rec else "no data yet: the loop is starting"
        if snap is not None and not snap.running:
            safe = self.demo.leader.in_safe_state and self.demo.follower.in_safe_state
            table += "\nloop stopped, last tick shown | arms: " + (
                "leader torque OFF, follower HOLD" if safe else "safe state NOT confirmed")
        self.query_one("#joints", Static).update(table)
        msgs = snap.messages if snap else ()
        self.query_one("#msgline", Static).update(f"{msgs[-1][1]}: {msgs[-1][2]}"[:80] if msgs else "")
        if alive or unstarted or self.estopped or self._stopping:
            return
        if self._ended_at is None:  # ended on its own (or by a fault): show the last frame, then return
            self._ended_at = time.monotonic()
            self.outcome = "run stopped by an error" if snap and snap.error else "finished"
        elif time.monotonic() - self._ended_at >= self.linger_s:
            self.exit(self.outcome)

    # -- stopping ----------------------------------------------------------------------------------------
    def _stop_and_check(self, reason: str) -> str:
        """Thread side: let the loop end (it commands the safe states), else command them here; then say
        what the arms are doing. Never raises."""
        self.demo.loop.stop(timeout_s=0.0)
        if self.worker.ident is not None:
            self.worker.join(WORKER_JOIN_S)
        how = ""
        if self.worker.is_alive():  # loop thread stuck in a driver call: the safe states from here too
            self.demo.pair.make_safe(f"{reason} (loop thread not answering)")
            how = " (commanded from the UI: loop thread not answering)"
        lead, fol = self.demo.leader, self.demo.follower
        if lead.in_safe_state and fol.in_safe_state:
            return f"{reason}: leader torque OFF, follower HOLD{how}"
        bad = [d.name for d in (lead, fol) if not d.in_safe_state]
        return f"{reason}: NOT CONFIRMED SAFE: {', '.join(bad)}{how}"

    def action_estop(self) -> None:
        if self.estopped:
            return
        self.estopped = True
        self.outcome = "emergency stop"
        self.demo.loop.stop(timeout_s=0.0)  # non-blocking: the loop ends safe on its next tick
        self.stop_line = "E-STOP: stopping the loop ..."
        self.refresh_view()

        def work() -> None:
            line = self._stop_and_check("E-STOP")
            try:
                self.call_from_thread(self._estop_done, line)
            except RuntimeError:  # the app closed meanwhile (q right after SPACE): the arms are safe anyway
                pass

        self.run_worker(work, thread=True, name="estop", group="estop")

    def _estop_done(self, line: str) -> None:
        self.stop_line = f"** {line} ** | q: summary"
        self.outcome = f"emergency stop: {line.removeprefix('E-STOP: ')}"
        self.notify(line, title="EMERGENCY STOP", severity="error", timeout=4)
        self.refresh_view()

    async def action_quit_safe(self) -> None:
        if self._stopping:
            return
        self._stopping = True
        if self.worker.ident is None:
            self.outcome = "closed before the run started"
        elif self.worker.is_alive():
            self.stop_line = "quitting: stopping the loop, leaving the arms safe ..."
            self.refresh_view()
            line = await asyncio.to_thread(self._stop_and_check, "quit")
            self.outcome = f"stopped by the user, {line.removeprefix('quit: ')}"
        self.exit(self.outcome)


def show_demo(run, worker: threading.Thread, linger_s: float = LINGER_S) -> str:
    """Show DemoRun `run` live while thread `worker` runs it (started at mount if it was not yet); return
    when the run ends or the user quits, with one line saying how it ended. A quit stops the loop (arms safe)
    before this returns; worker.ident stays None if the view closed before the start."""
    app = DemoApp(run, worker, linger_s=linger_s)
    try:
        out = app.run()
    except BaseException:  # the app died (Ctrl-C outside it, a crash): never leave the loop running
        run.loop.stop(timeout_s=0.0)
        if worker.ident is not None:
            worker.join(WORKER_JOIN_S)
        raise
    return out or app.outcome
