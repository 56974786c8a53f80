"""Training screen: choose recorded episodes (outcome filter, include/exclude), preview their FIRST phase
labels (shares per episode, tau_ext of the selected one with the phases shaded), choose policy, method,
ratio, size and length (defaults preselected, the paper's values shown), then train in a worker thread with
live steps, ETA, loss and per-phase validation loss; stop keeps a checkpoint, u resumes the newest stopped
run."""

from __future__ import annotations

import time

import numpy as np
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical, VerticalScroll
from textual.screen import ModalScreen
from textual.widgets import Input, Static

from factr2_teleop.tui import train_ctl as T
from factr2_teleop.tui.base import BaseScreen
from factr2_teleop.tui.episodes import short_name
from factr2_teleop.tui.stops import OperatorStop, operator_stop
from factr2_teleop.tui.train_inputs import observation_problem, recording_inputs
from factr2_teleop.tui.widgets import eta, progress_bar, sparkline, text_plot

ROWS_SHOWN = 5


def choice_rows(rows, chosen: set[str], selected: int, preview) -> list[str]:
    """Episode rows around the selection: [x] chosen for training, phase shares when labelled."""
    out = [f"    {'#':>2} {'file':<26} {'ep':>2} {'outcome':<10} {'dur':>6}  free/pre/contact"]
    if not rows:
        return out + ["  (no episodes: record some on the Teleop screen, key 3)"]
    lo = max(0, min(selected - ROWS_SHOWN // 2, len(rows) - ROWS_SHOWN))
    for i, r in enumerate(rows[lo : lo + ROWS_SHOWN], start=lo):
        key = T.episode_key(r)
        mark = "x" if key in chosen else " "
        lab = preview.labels.get(key) if preview is not None else None
        shares = "-" if lab is None else "/".join(f"{100 * x:.0f}" for x in lab.shares()) + " %"
        dur = "-" if not np.isfinite(r.duration_s) else f"{r.duration_s:.1f}s"
        out.append(
            f"{'>' if i == selected else ' '}[{mark}] {i:>2} {short_name(r.file.name):<26} {r.index:>2} "
            f"{r.outcome[:10]:<10} {dur:>6}  {shares}"[:79]
        )
    return out


def phase_lines(lab, th, width: int = 60) -> list[str]:
    """The selected episode's tau_ext per joint with the phases shaded, and the thresholds."""
    t = lab.t - lab.t[0]
    plot = text_plot(t, lab.tau_ext, width, 5, f"{lab.episode}: follower tau_ext [N*m], marks = joints",
                     "N*m", shade=lab.phases)
    sh = lab.shares()
    return plot.splitlines() + [
        f"shading: '.' pre-contact {100 * sh[1]:.0f}%, ':' contact {100 * sh[2]:.0f}%, "
        f"free {100 * sh[0]:.0f}%",
        f"contact on at ||tau_ext||_1 >= {th.t_high:.3g}, off at <= {th.t_low:.3g} N*m ({th.source})"[:79],
    ]


def progress_lines(st) -> list[str]:
    """Status, steps with ETA, the training loss and the validation loss per phase as sparkline charts."""
    out = [f"run {st.status.upper()}: {st.line}"]  # not cut: the widget wraps an error's whole line
    if st.total:
        out.append(f"step {st.step}/{st.total} {progress_bar(st.step / st.total, 30)} {eta(st.eta_s)}")
    if st.losses:
        out.append(f"train loss {sparkline(st.losses, 40)} {st.losses[-1]:.4f}")
    for key, name in (("val/loss", "all"), ("val/loss_F", "F"), ("val/loss_PC", "PC"), ("val/loss_C", "C")):
        v = st.val.get(key)
        if v:
            out.append(f"val {name:<3}    {sparkline(v, 40)} {v[-1]:.4f}")
    return out + list(st.advice)  # a finished run: what more data or training would buy (wrapped)


class ThresholdDialog(ModalScreen[str | None]):
    """Contact thresholds LOW:HIGH [N*m] on ||tau_ext||_1 (empty: from the recordings' own scores; "next":
    from their NEXT checkpoint)."""

    BINDINGS = [Binding("escape", "cancel", "Cancel")]

    def compose(self) -> ComposeResult:
        with Vertical(id="picker"):
            yield Static("Contact thresholds LOW:HIGH [N*m] (empty: from the recordings; next: from NEXT). "
                         "Enter: set, Escape: cancel", markup=False)
            yield Input(placeholder="e.g. 1.5:2.5", id="thresholds")

    def on_input_submitted(self, ev: Input.Submitted) -> None:
        self.dismiss(ev.value.strip())

    def action_cancel(self) -> None:
        self.dismiss(None)


class TrainingScreen(BaseScreen):
    BINDINGS = [
        Binding("up,k", "move(-1)", "Up", show=False),
        Binding("down,j", "move(1)", "Down", show=False),
        Binding("enter", "toggle", "In/out"),
        Binding("o", "filter", "Outcomes"),
        Binding("h", "thresholds", "Thresh"),
        Binding("p", "cycle('policy')", "Policy"),
        Binding("m", "cycle('method')", "Method"),
        Binding("r", "cycle('ratio')", "Ratio"),
        Binding("z", "cycle('size')", "Size"),
        Binding("i", "cycle('observation')", "Obs"),
        Binding("left_square_bracket", "steps(-1)", "Shorter", show=False),
        Binding("right_square_bracket", "steps(1)", "Longer", show=False),
        Binding("g", "go", "Train"),
        Binding("x", "stop", "Stop"),
        Binding("u", "resume", "Resume"),
        Binding("d", "folder", "Folder"),
        Binding("l", "reload", "Reload", show=False),
    ]

    def compose_body(self) -> ComposeResult:
        self.rows: list = []
        self.chosen: set[str] = set()
        self.selected = 0
        self.outcomes = T.DEFAULT_FILTER
        self.preview = None
        self.preview_error = ""
        self._preview_key = None
        self._run_status = ""
        self.runs: list = []
        self.runs_advice: list[str] = []  # the first listed run's advice (T.listed_advice)
        self.inputs: dict = {}  # recording file -> (camera frames?, twin object state?)
        with VerticalScroll(id="body"):
            yield Static(markup=False, id="tr-head")
            yield Static(markup=False, id="tr-table")
            yield Static(markup=False, id="tr-choices")
            yield Static(markup=False, id="tr-progress")
            yield Static(markup=False, id="tr-phases")

    def on_mount(self) -> None:
        super().on_mount()
        self.action_reload()

    def on_screen_resume(self) -> None:
        self.action_reload()

    @property
    def folder(self):
        return self.app.recordings_dir

    @property
    def run(self) -> T.TrainingRun | None:
        return self.app.training

    # -- view -----------------------------------------------------------------------------------------------
    def refresh_view(self) -> None:
        n_ok = sum(T.usable(r, self.outcomes) for r in self.rows)
        self.query_one("#tr-head", Static).update(
            f"{len(self.chosen)} of {n_ok} usable episodes chosen (outcomes {self.outcomes}: o; "
            f"enter: in/out) in {self.folder} (d)"
        )
        self.query_one("#tr-table", Static).update(
            "\n".join(choice_rows(self.rows, self.chosen, self.selected, self.preview))
        )
        c = self.app.train_choices
        th = ("from the recordings" if c.thresholds == "recording" else "from NEXT"
              if c.thresholds in (None, "next") else f"{c.thresholds[0]:g}:{c.thresholds[1]:g} N*m")
        problem = self.observation_problem()
        self.query_one("#tr-choices", Static).update(
            "\n".join([c.describe(T.epoch_steps(self.rows, self.chosen, c)), f"contact thresholds {th} (h)",
                       *([f"cannot train: {problem}"] if problem else []), T.PAPER_CHOICES])
        )
        run = self.run
        status = run.snapshot().status if run is not None else ""
        if status != self._run_status:
            self._run_status = status
            if status in ("done", "stopped", "failed"):
                self.action_reload()  # the run's folder joins the list of runs
        self.query_one("#tr-progress", Static).update(
            "\n".join(progress_lines(run.snapshot()) + ["runs:"] + T.run_lines(self.runs, 3))
            if run is not None else "\n".join(["runs (g trains a new one):", *T.run_lines(self.runs, 3),
                                                *self.runs_advice])
        )
        self.query_one("#tr-phases", Static).update("\n".join(self._phase_view()))
        self._maybe_preview()

    def _phase_view(self) -> list[str]:
        if self.preview_error:
            return [f"phase labels: {self.preview_error}"[:240]]
        if self.preview is None or not self.rows:
            return ["phase labels: " + ("labelling ..." if self.chosen else "choose episodes (enter)")]
        key = T.episode_key(self.rows[self.selected])
        lab = self.preview.labels.get(key)
        if lab is None:
            return [f"phase labels: {key} is not chosen (enter includes it)"]
        return phase_lines(lab, self.preview.thresholds)

    def _maybe_preview(self) -> None:
        """Label the chosen episodes in a worker when the choice or the thresholds changed."""
        key = (tuple(sorted(self.chosen)), self.app.train_choices.thresholds)
        if key == self._preview_key or not self.chosen:
            return
        self._preview_key = key
        folder, chosen, th = self.folder, sorted(self.chosen), self.app.train_choices.thresholds

        def done(preview) -> None:
            if self._preview_key == key:
                self.preview, self.preview_error = preview, ""

        def work():
            try:
                return T.label_preview(folder, chosen, th)
            except Exception as e:  # noqa: BLE001 -- one line on screen, with the fix
                msg = str(e).splitlines()[0]
                self.app.call_from_thread(self._preview_failed, key, msg)
                return None

        self.background(work, "phase labels", lambda p: p is not None and done(p))

    def _preview_failed(self, key, msg: str) -> None:
        if self._preview_key == key:
            self.preview, self.preview_error = None, msg

    # -- keys -------------------------------------------------------------------------------------------
    def action_reload(self) -> None:
        from hardware.recording.episodes import list_episodes

        folder, runs = self.folder, self.app.runs_dir

        def load():
            rows = list_episodes(folder) if folder.exists() else []
            inputs = recording_inputs(r.file for r in rows if not r.error and r.file.suffix == ".mcap")
            listed = T.list_runs(runs)
            return rows, listed, T.listed_advice(listed), inputs

        def done(result) -> None:
            rows, self.runs, self.runs_advice, self.inputs = result
            known = {T.episode_key(r) for r in self.rows}
            self.rows = rows
            for r in rows:  # new usable episodes start chosen; the user's exclusions stay
                if T.usable(r, self.outcomes) and T.episode_key(r) not in known:
                    self.chosen.add(T.episode_key(r))
            self._apply_filter()

        self.background(load, "episodes", done)

    def _apply_filter(self) -> None:
        ok = {T.episode_key(r) for r in self.rows if T.usable(r, self.outcomes)}
        self.chosen &= ok
        self.selected = min(self.selected, max(len(self.rows) - 1, 0))
        self.refresh_view()

    def action_move(self, d: int) -> None:
        if self.rows:
            self.selected = max(0, min(len(self.rows) - 1, self.selected + d))
            self.refresh_view()

    def action_toggle(self) -> None:
        if not self.rows:
            return
        r = self.rows[self.selected]
        if not T.usable(r, self.outcomes):
            self.app.say(f"episode {T.episode_key(r)} ({r.outcome}) is not in the filter {self.outcomes} (o)")
            return
        self.chosen ^= {T.episode_key(r)}
        self.refresh_view()

    def action_filter(self) -> None:
        names = list(T.OUTCOME_FILTERS)
        self.outcomes = names[(names.index(self.outcomes) + 1) % len(names)]
        self.chosen |= {T.episode_key(r) for r in self.rows if T.usable(r, self.outcomes)}
        self._apply_filter()

    def action_cycle(self, name: str) -> None:
        value = self.app.train_choices.cycle(name, T.form()[name])
        if name == "size" and value == "tryout":
            self.app.say("size tryout: a tiny model to try the workflow (not a usable policy)")
        self.refresh_view()

    def action_steps(self, d: int) -> None:
        c = self.app.train_choices
        c.step(d, T.epoch_steps(self.rows, self.chosen, c))
        self.refresh_view()

    def observation_problem(self) -> str:
        """Why the chosen episodes' recordings cannot train with the observation chosen ("" when they can)."""
        files = [r.file for r in self.rows if T.episode_key(r) in self.chosen]
        return observation_problem(files, self.inputs, self.app.train_choices.observation)

    def action_folder(self) -> None:
        from factr2_teleop.tui.folders import open_folder

        def reopened() -> None:
            self.rows, self.chosen, self.preview, self._preview_key = [], set(), None, None
            self.action_reload()

        open_folder(self, "recordings", reopened)

    def action_thresholds(self) -> None:
        from policies.labels.phases import parse_thresholds

        def done(text: str | None) -> None:
            if text is None:
                return
            try:
                text = text.strip()
                self.app.train_choices.thresholds = (parse_thresholds(text) if text not in ("", "next")
                                                     else text or "recording")
            except ValueError as e:
                self.app.say(f"thresholds {e}: give LOW:HIGH in N*m, e.g. 1.5:2.5")
                return
            self.preview_error = ""
            self.refresh_view()

        self.app.push_screen(ThresholdDialog(), done)

    def _busy(self) -> bool:
        if self.run is not None and self.run.running:
            self.app.say("a training run is going on (x stops it, keeping a checkpoint)")
            return True
        return False

    def action_go(self) -> None:
        if self._busy():
            return
        if not self.chosen:
            self.app.say("no episodes chosen: record some on the Teleop screen (3), include them (enter)")
            return
        problem = self.observation_problem()
        if problem:
            self.app.say(f"cannot train: {problem}")
            return
        c = self.app.train_choices
        out = self.app.runs_dir / f"{c.policy}-{c.method}-{time.strftime('%Y%m%d-%H%M%S')}"
        opts = T.run_options(c, self.folder, sorted(self.chosen), out, self.app.train_threads, self.outcomes)
        self._start(opts, f"training {c.policy}/{c.method} on {len(self.chosen)} episode(s) -> {out}")

    def action_resume(self) -> None:
        if self._busy():
            return
        stopped = [r for r in T.list_runs(self.app.runs_dir) if not r.final]
        if not stopped:
            self.app.say("no stopped run to resume (a run stopped with x, or by quitting, can be)")
            return
        try:
            opts = T.resume_options(stopped[0].path, self.folder, self.app.train_threads)
        except Exception as e:  # noqa: BLE001 -- one line
            self.app.say(f"resume {stopped[0].path.name}: {e}")
            return
        self._start(opts, f"resuming {stopped[0].path.name} at step {stopped[0].step}")

    def _start(self, opts, line: str) -> None:
        run = T.TrainingRun(opts, say=self.app.say)
        self.app.training = run
        run.start()
        self.app.say(line)
        self.refresh_view()

    def action_stop(self) -> None:
        if self.run is None or not self.run.running:
            self.app.say("no training run is going on")
            return
        self.run.stop(operator_stop(OperatorStop.USER))
        self.background(self.run.join, "training stop", lambda _: self.action_reload())
