"""The terminal app opens the command line's folders (issue #32): `--recordings` of `factr2 collect --out`,
`--runs` of `factr2 train --out` (one run folder), key d for another; the Train screen's observation
choice says why a set cannot train; Rollout refuses a task the demonstrations did not come from, in keys
(not CLI flags), unless forced (f)."""

from __future__ import annotations

import asyncio

import pytest
import torch
from tui_helpers import SIZE, make_app, screen_text, wait_for

from factr2_teleop.cli import main
from factr2_teleop.session.task_check import check_task, task_mismatch
from factr2_teleop.tui import rollout_ctl as R
from factr2_teleop.tui.train_ctl import TRYOUT_OVERRIDES, Choices, list_runs
from factr2_teleop.tui.train_inputs import observation_problem
from hardware.errors import UserError
from policies.training.run import RunOptions, run_training
from policies.training.train import Dist, TrainConfig
from tests.policy_helpers import write_recording

torch.set_num_threads(1)


def test_task_check_refuses_another_task_unless_forced():
    meta = {"tasks": {"wipe": 8}}
    assert task_mismatch(meta, "wipe") == "" and task_mismatch(meta, None) == ""
    assert task_mismatch({"tasks": {"push": 2}}, "peg-insert") == ""  # not a twin task: nothing to compare
    assert task_mismatch({}, "peg-insert") == ""  # a run from before the check
    with pytest.raises(UserError, match="trained on wipe demonstrations, not peg-insert.*--force"):
        check_task(meta, "peg-insert")
    assert check_task(meta, "peg-insert", force=True).endswith("(forced)")
    line = R.app_words(str(UserError("trained on wipe", where="--task",
                                     fix="pass --task wipe, or --force to roll out on peg-insert anyway")))
    assert line == "Rollout: trained on wipe -- fix: press t for task wipe, or f (force) to roll out on " \
                   "peg-insert anyway"
    assert "press t to pick a task" in R.app_words("fix: pass --task T on a sim-* rig")


def test_observation_problem_names_the_key():
    a, b = "a.mcap", "b.mcap"
    state_only = {a: (False, True), b: (False, True)}
    assert "2 of 2 recording(s) have no camera frames -- press i for obs state" in observation_problem(
        [a, b], state_only, "images")
    assert observation_problem([a, b], state_only, "state") == ""
    assert "record with cameras" in observation_problem([a], {a: (False, False)}, "images")
    assert "press i for obs images" in observation_problem([a], {a: (True, False)}, "state")


def test_step_keys_run_in_order_of_length():
    c = Choices()  # 20 epochs, here ~300 steps: `[` goes shorter (100), `]` longer (500)
    c.step(-1, 300)
    assert c.steps == 100
    c.steps = 0
    c.step(1, 300)
    assert c.steps == 500


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    """A `collect --no-cameras`-like folder (wipe, object state) and one run trained on it, elsewhere."""
    d = tmp_path_factory.mktemp("folders")
    rec = d / "collected"
    write_recording(rec / "wipe.mcap", episodes=2, seconds=1.0, cameras=(), objects=8, task="wipe")
    run = d / "elsewhere" / "my-run"
    run_training(RunOptions(inputs=[rec], out=run, thresholds=(1.0, 3.0), progress=False, observation="state",
                            overrides=dict(TRYOUT_OVERRIDES), val_fraction=0.0,
                            train=TrainConfig(steps=2, batch=4, warmup=1, threads=1)), Dist())
    return rec, run


def test_cli_refuses_a_missing_folder(tmp_path, capsys):
    rc = main(["tui", "--recordings", str(tmp_path / "nope")])
    err = capsys.readouterr().err
    assert rc == 2 and "--recordings: no such folder" in err and "fix:" in err


def test_app_opens_the_command_lines_folders(folders, tmp_path):
    rec, run = folders
    assert [r.path for r in list_runs(run)] == [run]  # one run's folder lists that run

    async def go():
        app = make_app(tmp_path / "out", recordings_dir=rec, runs_dir=run, train_threads=1)
        async with app.run_test(size=SIZE) as pilot:
            await pilot.press("4")
            assert await wait_for(pilot, lambda: f"recordings in {rec}" in screen_text(app))
            assert await wait_for(pilot, lambda: "wipe" in screen_text(app) and "my-run" in screen_text(app))
            await pilot.press("5")
            no_frames = "cannot train: obs images: 1 of 1 recording(s) have no camera frames -- press i"
            assert await wait_for(pilot, lambda: no_frames in screen_text(app)), screen_text(app)
            await pilot.press("i")
            assert await wait_for(pilot, lambda: "obs state (i)" in screen_text(app))
            assert "cannot train" not in screen_text(app)
            await pilot.press("6")  # the run's folder stands for the folder holding it: new runs go beside it
            assert await wait_for(pilot, lambda: "my-run" in screen_text(app))
            assert app.runs_dir == run.parent
            await pilot.press("t")  # peg-insert: not the demonstrations' task
            mismatch = "trained on wipe demonstrations, not peg-insert"
            assert await wait_for(pilot, lambda: mismatch in screen_text(app), 60), screen_text(app)
            text = screen_text(app)
            assert "press t for task wipe" in text and "f (force)" in text and "--task" not in text
            await pilot.press("g")
            assert app.rollout is None  # refused
            await pilot.press("f")
            warned = "WARNING the policy was " + mismatch
            assert await wait_for(pilot, lambda: warned in screen_text(app), 60), screen_text(app)
            assert "rig check: OK for sim-piper with task peg-insert" in screen_text(app)
            # d opens another folder: an empty one lists nothing, and says how to fill it
            other = tmp_path / "empty"
            other.mkdir()
            await pilot.press("4", "d", *["backspace"] * 200, *str(other), "enter")
            assert await wait_for(pilot, lambda: f"recordings in {other}" in screen_text(app))
            assert await wait_for(pilot, lambda: "`factr2 collect`" in screen_text(app))
            await pilot.press("q")
            await pilot.pause(0.3)

    asyncio.run(go())


def test_cli_rollout_refuses_another_task_in_one_line(folders, capsys):
    _, run = folders
    rc = main(["rollout", "--policy", str(run), "--task", "peg-insert"])
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("factr2 ")]
    assert rc == 2 and len(lines) == 1, err
    assert "trained on wipe demonstrations, not peg-insert" in lines[0] and "--force" in lines[0]


def test_error_lines_are_not_cut():
    """A failed run's whole line reaches the widget (it wraps there), not the first 79 characters."""
    from factr2_teleop.tui.rollout import status_lines
    from factr2_teleop.tui.train_ctl import TrainState
    from factr2_teleop.tui.training import progress_lines

    why = "x.mcap: the recordings have no camera frames -- fix: press i for obs state " * 2
    assert why.strip() in progress_lines(TrainState(status="failed", line=why.strip()))[0]
    assert why.strip() in status_lines(R.RolloutState(status="failed", line=why.strip()))[0]
