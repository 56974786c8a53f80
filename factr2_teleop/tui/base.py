"""What every screen shares: the top status line (rig, simulated/real, connection, activity, E-STOP state),
the bottom message line, the footer of keys, and running blocking work off the UI thread."""

from __future__ import annotations

from collections.abc import Callable

from textual.app import ComposeResult
from textual.screen import Screen
from textual.widgets import Footer, Static

from hardware.errors import UserError

SCREEN_KEYS = " 1 Rig  2 Calibrate  3 Teleop  4 Episodes  5 Train  6 Rollout | q quit (arms left safe)"


class StatusBar(Static):
    """One line: factr2 | rig [SIMULATED|REAL] | connected? | activity | E-STOP state."""

    def status_text(self) -> str:
        app = self.app
        rt = app.runtime
        kind = "SIM" if rt.simulated else "REAL"
        conn = "connected" if rt.connected else "disconnected"
        act = rt.activity or "idle"
        stop = "  ** E-STOPPED **" if rt.estopped else ""
        return f" factr2 | {rt.rig.name} [{kind}] | {conn} | {act}{stop} | SPACE=E-STOP"

    def on_mount(self) -> None:
        self.update(self.status_text())
        self.set_interval(0.25, lambda: self.update(self.status_text()))


class MessageLine(Static):
    """The last message of the rig runtime (what happened, in words)."""

    def on_mount(self) -> None:
        self.set_interval(0.25, self._tick)

    def _tick(self) -> None:
        msgs = self.app.runtime.messages
        self.update(msgs[-1] if msgs else "")


class BaseScreen(Screen):
    """Status bar + body (compose_body) + message line + footer. refresh_view() runs 5 times a second."""

    REFRESH_S = 0.2

    def compose(self) -> ComposeResult:
        yield StatusBar(markup=False, id="statusbar")
        yield Static(SCREEN_KEYS, markup=False, id="keysline")
        yield from self.compose_body()
        yield MessageLine(markup=False, id="msgline")
        yield Footer(compact=True, show_command_palette=False)

    def compose_body(self) -> ComposeResult:  # pragma: no cover - overridden
        yield Static("", markup=False)

    def on_mount(self) -> None:
        self.refresh_view()
        self.set_interval(self.REFRESH_S, self.refresh_view)

    def refresh_view(self) -> None:
        pass

    def background(
        self, fn: Callable[[], object], label: str, done: Callable[[object], None] | None = None
    ) -> None:
        """Run fn() in a thread worker; a UserError/any error becomes one message line, never a crash."""
        app = self.app

        def work():
            try:
                result = fn()
            except UserError as e:
                app.call_from_thread(app.say, f"{label}: {e}")
                return
            except Exception as e:  # noqa: BLE001 -- the UI shows it and keeps running
                app.call_from_thread(app.say, f"{label} failed: {type(e).__name__}: {e}")
                return
            if done is not None:
                app.call_from_thread(done, result)

        self.run_worker(work, thread=True, name=label, group=label)
