"""The factr2 terminal app: six screens (Rig, Calibrate, Teleop, Episodes, Train, Rollout) over one rig
runtime.

SPACE is the emergency stop on every screen (leaders torque off, followers hold, the running activity ends);
in a text field (note, rig path) space types a space and ctrl+space is the emergency stop. Quitting (q,
ctrl+q, ctrl+c) always stops teleop/calibration and leaves the arms safe before the app exits. Blocking work
(connecting, the doctor, teleop start/stop, calibration, reading recordings) runs in threads; screens poll
thread-safe snapshots a few times a second.
"""

from __future__ import annotations

import asyncio
import threading
from pathlib import Path

from textual.app import App
from textual.binding import Binding
from textual.widgets import Input

from factr2_teleop.tui.calib_ctl import CalibrationRun
from factr2_teleop.tui.calibration import CalibrationScreen
from factr2_teleop.tui.episodes import EpisodesScreen
from factr2_teleop.tui.rig import RigScreen
from factr2_teleop.tui.rollout import RolloutScreen
from factr2_teleop.tui.rollout_ctl import RolloutRun
from factr2_teleop.tui.runtime import RigRuntime
from factr2_teleop.tui.stops import OperatorStop, operator_stop
from factr2_teleop.tui.teleop import TeleopScreen
from factr2_teleop.tui.teleop_ctl import TeleopController
from factr2_teleop.tui.train_ctl import Choices, TrainingRun
from factr2_teleop.tui.training import TrainingScreen


def runs_folder(folder: Path) -> Path:
    """The folder of runs: a run's own folder (`factr2 train --out RUN`) stands for the folder holding it, so
    that the runs trained here go beside it, not inside it."""
    return folder.parent if (folder / "checkpoints" / "last").is_file() else folder


TRAINING_STOP_WAIT_S = 120.0  # quitting waits this long for the training step in flight and its checkpoint


class Factr2App(App):
    CSS_PATH = "factr2.tcss"
    TITLE = "factr2"
    ENABLE_COMMAND_PALETTE = False
    MODES = {
        "rig": RigScreen,
        "calibration": CalibrationScreen,
        "teleop": TeleopScreen,
        "episodes": EpisodesScreen,
        "training": TrainingScreen,
        "rollout": RolloutScreen,
    }
    DEFAULT_MODE = "rig"
    BINDINGS = [
        Binding("space", "estop", "E-STOP", priority=True),
        Binding("ctrl+space,ctrl+@", "estop_always", "E-STOP", show=False, priority=True),
        Binding("1", "switch_mode('rig')", "Rig", show=False),
        Binding("2", "switch_mode('calibration')", "Calibrate", show=False),
        Binding("3", "switch_mode('teleop')", "Teleop", show=False),
        Binding("4", "switch_mode('episodes')", "Episodes", show=False),
        Binding("5", "switch_mode('training')", "Train", show=False),
        Binding("6", "switch_mode('rollout')", "Rollout", show=False),
        Binding("q", "quit_safe", "Quit", show=False),
        Binding("ctrl+q,ctrl+c", "quit_safe", "Quit", show=False, priority=True),
    ]

    def __init__(
        self,
        runtime: RigRuntime,
        out_dir: str | Path = "factr2_out",
        rate_hz: float = 500.0,
        cal_minutes: float = 10.0,
        cal_epochs: int = 400,
        cal_samples_per_epoch: int = 16384,
        connect: bool = False,
        mode: str | None = None,
        light: bool = False,
        train_threads: int = 0,
        recordings_dir: str | Path | None = None,
        runs_dir: str | Path | None = None,
    ):
        super().__init__()
        if light:
            self.theme = "textual-light"
        self.runtime = runtime
        self.out_dir = Path(out_dir)
        # read by Episodes and Train, written by teleop and rollout recordings / new training runs;
        # `--recordings` / `--runs` or key d (tui/folders.py) open others
        self.recordings_dir = Path(recordings_dir) if recordings_dir else self.out_dir / "recordings"
        self.runs_dir = runs_folder(Path(runs_dir)) if runs_dir else self.out_dir / "runs"
        self.teleop = TeleopController(runtime, self.recordings_dir, rate_hz=rate_hz, mode=mode)
        self.calibration: CalibrationRun | None = None
        self.calibration_thread: threading.Thread | None = None
        self.cal_minutes, self.cal_epochs = float(cal_minutes), int(cal_epochs)
        self.cal_samples_per_epoch = int(cal_samples_per_epoch)
        self.training: TrainingRun | None = None
        self.train_choices = Choices()
        self.train_threads = int(train_threads)  # torch threads for training (0: every core)
        self.rollout: RolloutRun | None = None
        self.rollout_task: str | None = None  # a twin task, or None: the operator marks episodes
        self.rollout_episodes = 1
        self.rollout_limit_s: float | None = None  # [s] per episode; None: the task's own
        self.rollout_record = True  # into the recordings folder, listed by the Episodes screen
        self.rollout_force = False  # roll out on a task the policy's demonstrations did not come from
        self._connect_on_start = connect
        self._closed = False

    def on_mount(self) -> None:
        self.say(
            f"rig {self.runtime.rig.name}: press c on this screen to connect"
            if not self._connect_on_start
            else f"connecting to {self.runtime.rig.name} ..."
        )
        if self._connect_on_start:
            self.run_worker(self._connect, thread=True, name="connect")

    def _connect(self) -> None:
        try:
            self.runtime.connect()
        except Exception as e:  # noqa: BLE001 -- one line on screen
            self.call_from_thread(self.say, f"connect: {e}")

    # -- shared helpers ------------------------------------------------------------------------------------
    def say(self, text: str) -> None:
        self.runtime.say(text)

    def set_folder(self, kind: str, folder: Path) -> None:
        """Open another recordings or runs folder; teleop records into the new recordings folder from its
        next file on (an open recording stays where it is)."""
        if kind == "recordings":
            self.recordings_dir = Path(folder)
            self.teleop.out_dir = Path(folder)
        else:
            self.runs_dir = runs_folder(Path(folder))

    def calibration_problem(self) -> str | None:
        """Why a NEXT calibration cannot run now (None: it can)."""
        rt = self.runtime
        if not rt.connected:
            return "no rig connected (Rig screen, key c)"
        if rt.activity == "teleop":
            return "teleop is running (stop it on the Teleop screen, key t)"
        try:
            import calibration.report  # noqa: F401
            import calibration.trajectories  # noqa: F401
        except ImportError as e:
            return f"calibration pipeline not installed ({e})"
        return None

    def stop_activities(self) -> None:
        """End teleop and calibration (each leaves the arms safe) and training (a checkpoint is kept).
        Never raises."""
        if self.training is not None and self.training.running:
            self.training.stop(operator_stop(OperatorStop.APP_CLOSING))
        if self.rollout is not None and self.rollout.running:
            self.rollout.stop(operator_stop(OperatorStop.APP_CLOSING))
            self.rollout.join(10.0)
        if self.teleop.running:
            try:
                self.teleop.stop()
            except Exception as e:  # noqa: BLE001
                self.say(f"teleop stop: {e}")
        if self.calibration is not None:
            self.calibration.abort(operator_stop(OperatorStop.STOPPED))
        if self.calibration_thread is not None:
            self.calibration_thread.join(10.0)
        if self.training is not None:
            self.training.join(TRAINING_STOP_WAIT_S)

    def start_rollout(self, run: str) -> None:
        """Roll the trained `run` out on this rig (session.rollout.run_rollout opens the rig itself, so the
        app's connection is closed first, in the worker). UserError when something else holds the rig."""
        from factr2_teleop.session.rollout import RolloutOptions

        rt = self.runtime
        rt.claim("rollout", need_connection=False)
        opts = RolloutOptions(
            rig=str(rt.rig.path),
            policy=Path(run),
            task=self.rollout_task,
            episodes=self.rollout_episodes,
            max_seconds=self.rollout_limit_s,
            record=self.recordings_dir if self.rollout_record else None,
            force=self.rollout_force,
            takeover=True,  # the leader follows, the hand or the key takes over (session/rollout_takeover.py)
        )
        def after() -> None:
            rt.release("rollout")
            self.say("rollout over: the rig is free (c on the Rig screen connects the app again)")

        ro = RolloutRun(opts, say=self.say, before=rt.disconnect, after=after)
        self.rollout = ro
        ro.start()
        self.say(f"rollout of {Path(run).name} on {rt.rig.name}"
                 + (f", task {self.rollout_task}" if self.rollout_task else ", you mark the outcome (s/y/n)"))

    # -- emergency stop -------------------------------------------------------------------------------------
    def check_action(self, action: str, parameters: tuple) -> bool | None:
        if action == "estop" and isinstance(self.focused, Input):
            return False  # typing: space is a space here; ctrl+space is the e-stop
        return True

    def action_estop_always(self) -> None:
        self.action_estop()

    def action_estop(self) -> None:
        def stop_activity() -> None:
            if self.teleop.loop is not None:
                self.teleop.stop_reason = operator_stop(OperatorStop.ESTOP)
                self.teleop.loop.stop(timeout_s=0.0)  # non-blocking: the loop ends safe on its next tick
            if self.calibration is not None:
                self.calibration.abort(operator_stop(OperatorStop.ESTOP))

        if self.rollout is not None and self.rollout.running:  # the rollout holds the rig, not the runtime
            self.runtime.estopped = True
            problems = self.rollout.estop()
            line = "E-STOP: rollout ended, follower HOLD, leader torque OFF" + (
                f" -- PROBLEMS: {problems}" if problems else "")
            self.say(line)
        else:
            line = self.runtime.estop(stop_activity)
        self.notify(line, title="EMERGENCY STOP", severity="error", timeout=4)

    # -- quitting -------------------------------------------------------------------------------------------
    def shutdown_all(self) -> None:
        """Stop everything, close the recording, leave the arms safe, close the rig. Idempotent."""
        if self._closed:
            return
        self._closed = True
        self.stop_activities()
        try:
            self.teleop.close()
        except Exception as e:  # noqa: BLE001
            self.say(f"closing the recording: {e}")
        self.runtime.shutdown()
        # drop the loop's ruckig objects now, not at interpreter exit (nanobind then reports "leaks")
        self.teleop.loop = None
        self.teleop.ts = None  # its pairs hold the soft start's ruckig objects too
        self.calibration = None
        self.rollout = None
        import gc

        gc.collect()

    async def action_quit_safe(self) -> None:
        self.say("quitting: stopping and leaving the arms safe ...")
        await asyncio.to_thread(self.shutdown_all)
        self.exit()

    def on_unmount(self) -> None:
        self.shutdown_all()
