"""The folders the app reads and writes: recordings (Episodes, Train; teleop and rollout recordings go
there too) and training runs (Train writes new runs there, Rollout lists them). `factr2 tui --recordings
DIR --runs DIR` opens a `factr2 collect --out` or `factr2 train --out` folder (a run's folder stands for the
folder holding it: app.runs_folder); key d on Episodes, Train and
Rollout opens another one while the app runs."""

from __future__ import annotations

from pathlib import Path

from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.screen import ModalScreen
from textual.widgets import Input, Static

from hardware.errors import UserError

KINDS = {"recordings": "recordings folder (.mcap files, e.g. `factr2 collect --out`)",
         "runs": "runs folder (training runs, or one `factr2 train --out` run)"}


def check_folder(text: str, kind: str, where: str) -> Path:
    """The folder a user typed, expanded; UserError (one line) when it is not an existing folder."""
    p = Path(text.strip()).expanduser()
    if not text.strip() or not p.is_dir():
        raise UserError(f"no such folder: {text.strip() or '(empty)'}", where=where,
                        fix=f"give an existing {KINDS[kind]}")
    return p


class FolderDialog(ModalScreen[str | None]):
    """Type a folder path (the current one prefilled). Enter opens it, Escape cancels."""

    BINDINGS = [Binding("escape", "cancel", "Cancel")]

    def __init__(self, kind: str, current: Path):
        super().__init__()
        self.kind, self.current = kind, current

    def compose(self) -> ComposeResult:
        with Vertical(id="picker"):
            yield Static(f"Open another {KINDS[self.kind]}. Enter: open, Escape: cancel", markup=False)
            yield Input(value=str(self.current), id="folder")

    def on_input_submitted(self, ev: Input.Submitted) -> None:
        self.dismiss(ev.value)

    def action_cancel(self) -> None:
        self.dismiss(None)


def open_folder(screen, kind: str, then) -> None:
    """Ask for another folder of `kind` ("recordings" / "runs"), set it on the app, then call then()."""
    app = screen.app
    current = app.recordings_dir if kind == "recordings" else app.runs_dir

    def done(text: str | None) -> None:
        if text is None:
            return
        try:
            folder = check_folder(text, kind, where=type(screen).__name__.replace("Screen", ""))
        except UserError as e:
            app.say(str(e))
            return
        app.set_folder(kind, folder)
        app.say(f"{kind}: {folder}")
        then()

    app.push_screen(FolderDialog(kind, current), done)
