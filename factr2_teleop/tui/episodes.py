"""Episodes screen: the recorded episodes in the output folder (duration, outcome, contact share; policy
rollouts too), a text plot of the selected one (follower joint positions and estimated external torque), and
the training runs (OUT/runs: step, final or stopped, validation loss)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import VerticalScroll
from textual.widgets import Static

from factr2_teleop.tui.base import BaseScreen
from factr2_teleop.tui.train_ctl import list_runs, run_lines

ROWS_SHOWN = 6


def short_name(name: str, width: int = 26) -> str:
    """A recording's file name in `width` characters: its start (rig or rollout task) and its end (time)."""
    name = name.removesuffix(".mcap")
    if len(name) <= width:
        return name
    head = (width - 1) // 2
    return name[:head] + "~" + name[-(width - 1 - head):]


def episode_table(rows, selected: int) -> list[str]:
    """The episode rows around the selection ('>' marks it)."""
    out = [f"  {'#':>2} {'file':<26} {'ep':>2} {'outcome':<10} {'duration':>8} {'contact':>7}  task"]
    if not rows:
        return out + ["  (no episodes yet: record some on the Teleop screen, or d opens a folder of "
                      "`factr2 collect`)"]
    lo = max(0, min(selected - ROWS_SHOWN // 2, len(rows) - ROWS_SHOWN))
    for i, r in enumerate(rows[lo : lo + ROWS_SHOWN], start=lo):
        mark = ">" if i == selected else " "
        if r.error:
            out.append(f"{mark} {i:>2} {short_name(r.file.name):<26} {'-':>2} {r.outcome:<10} {r.error}"[:79])
            continue
        contact = "-" if not np.isfinite(r.contact_share) else f"{100 * r.contact_share:.0f}%"
        dur = "-" if not np.isfinite(r.duration_s) else f"{r.duration_s:.2f}s"
        out.append(
            f"{mark} {i:>2} {short_name(r.file.name):<26} {r.index:>2} {r.outcome:<10} {dur:>8} "
            f"{contact:>7}  "
            f"{r.task}"[:79]
        )
    total = sum(r.duration_s for r in rows if not r.error and np.isfinite(r.duration_s))
    out.append(
        f"  {len(rows)} episode(s), {total:.1f} s total, "
        f"{sum(r.outcome == 'success' for r in rows)} success, "
        f"{sum(r.outcome == 'failure' for r in rows)} failure"
    )
    return out


def episode_plot(row, width: int = 60, height: int = 6) -> str:
    """Text plots of one episode: follower q [rad] and follower tau_ext [N*m] (marks 1..n = joints)."""
    from factr2_teleop.tui.widgets import text_plot
    from hardware.recording import schemas as S
    from hardware.recording.reader import Recording

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rec = Recording(row.file)
    ep = next(e for e in rec.episodes if e.index == row.index)
    parts = []
    for arm in ("follower", "leader"):
        if S.joint_state_topic(arm) in rec.topics:
            js = ep.topic(S.joint_state_topic(arm))
            parts.append(
                text_plot(
                    js.t - ep.t_start, js.fields["q"], width, height, f"{arm} q [rad] (marks = joints)", "rad"
                )
            )
            break
    if S.tau_ext_topic("follower") in rec.topics:
        te = ep.topic(S.tau_ext_topic("follower"))
        parts.append(
            text_plot(
                te.t - ep.t_start,
                te.fields["tau_ext"],
                width,
                height,
                "follower tau_ext estimate [N*m]",
                "N*m",
            )
        )
    return "\n".join(parts) if parts else "(no joint data in this episode)"


class EpisodesScreen(BaseScreen):
    BINDINGS = [
        Binding("l", "reload", "Reload"),
        Binding("up,k", "move(-1)", "Up"),
        Binding("down,j", "move(1)", "Down"),
        Binding("enter,v", "plot", "Plot"),
        Binding("d", "folder", "Folder"),
    ]

    def compose_body(self) -> ComposeResult:
        self.rows: list = []
        self.runs: list = []
        self.selected = 0
        with VerticalScroll(id="body"):
            yield Static(markup=False, id="ep-head")
            yield Static(markup=False, id="ep-table")
            yield Static(markup=False, id="ep-runs")
            yield Static(markup=False, id="ep-plot")

    def on_mount(self) -> None:
        super().on_mount()
        self.action_reload()

    def on_screen_resume(self) -> None:
        self.action_reload()

    @property
    def folder(self) -> Path:
        return self.app.recordings_dir

    def refresh_view(self) -> None:
        self.query_one("#ep-head", Static).update(
            f"recordings in {self.folder}   keys: up/down select, enter plot, l reload, d folder"
        )
        self.query_one("#ep-table", Static).update("\n".join(episode_table(self.rows, self.selected)))
        head = f"training runs in {self.app.runs_dir} (Train screen, key 5):"
        self.query_one("#ep-runs", Static).update("\n".join([head, *run_lines(self.runs)]))

    def action_reload(self) -> None:
        from hardware.recording.episodes import list_episodes

        folder = self.folder

        runs = self.app.runs_dir

        def load():
            return (list_episodes(folder) if folder.exists() else []), list_runs(runs)

        def done(result) -> None:
            rows, self.runs = result
            self.rows = rows
            self.selected = min(self.selected, max(len(rows) - 1, 0))
            self.refresh_view()

        self.background(load, "episodes", done)

    def action_folder(self) -> None:
        from factr2_teleop.tui.folders import open_folder

        open_folder(self, "recordings", self.action_reload)

    def action_move(self, d: int) -> None:
        if self.rows:
            self.selected = max(0, min(len(self.rows) - 1, self.selected + d))
            self.refresh_view()

    def action_plot(self) -> None:
        if not self.rows:
            return
        row = self.rows[self.selected]
        if row.error or row.index < 0:
            self.app.say(f"episode not readable: {row.error}")
            return
        widget = self.query_one("#ep-plot", Static)
        widget.update("plotting ...")
        self.background(lambda: episode_plot(row), "plot", widget.update)
