"""Training screen at 80x24 on demonstrations recorded on the sim-piper twin from the Teleop screen: phase
preview, a try-out policy trained to the end, then a run stopped by quitting the app (a checkpoint is kept)
and resumed from the screen in a new app to its end."""

from __future__ import annotations

import asyncio
import json

import numpy as np
import torch
from tui_helpers import SIZE, connect, make_app, screen_text, wait_for

from factr2_teleop.tui import train_ctl as T
from factr2_teleop.tui.training import progress_lines
from factr2_teleop.tui.widgets import text_plot
from policies.training import checkpoint as C

torch.set_num_threads(1)


def test_progress_lines_show_steps_eta_and_phase_losses():
    st = T.TrainState(status="training", step=5, total=20, eta_s=12.0, losses=[1.0, 0.5],
                      val={"val/loss": [0.9], "val/loss_PC": [1.2], "val/loss_C": [0.7]}, line="x")
    text = "\n".join(progress_lines(st))
    assert "step 5/20" in text and "ETA 12s" in text and "train loss" in text
    assert "val PC" in text and "val C" in text and "val F" not in text
    assert all(len(line) <= 80 for line in text.splitlines())


def test_text_plot_shades_pre_contact_and_contact_columns():
    t = np.linspace(0.0, 3.0, 301)
    phases = np.where(t >= 2.0, 2, np.where(t >= 1.0, 1, 0))
    lines = text_plot(t, np.zeros((301, 2)), 30, 3, shade=phases).splitlines()
    row = lines[0].split("|", 1)[1]  # the top row holds no mark: only the shading
    assert row == " " * 10 + "." * 9 + ":" * 11  # a column holding both phases shows the higher


def test_choices_give_the_paper_defaults_and_run_options(tmp_path):
    c = T.Choices()
    assert (c.policy, c.method, c.ratio_weights(), c.size, c.steps) == ("flow", "first", (1.0, 5.0, 1.0),
                                                                         "small", 0)
    c.cycle("ratio", T.form()["ratio"])
    c.size = "tryout"
    o = T.run_options(c, tmp_path, ["a.mcap#0"], tmp_path / "run")
    assert o.ratio == (1.0, 5.0, 1.0) and o.preset == "small" and o.overrides["hidden"] == 64
    assert o.episodes == ("a.mcap#0",) and o.train.batch == T.TRYOUT_BATCH
    # the screen's default filter is `factr2 train`'s: no failed or incomplete episode; "all" keeps them
    assert T.DEFAULT_FILTER == "success+unlabelled" and not (o.include_failed or o.keep_incomplete)
    o = T.run_options(c, tmp_path, ["a.mcap#0"], tmp_path / "run", outcomes="all")
    assert o.include_failed and o.keep_incomplete


def _frames(app) -> int:
    cams = app.teleop.ts.cameras if app.teleop.ts is not None else None
    return 0 if cams is None else sum(st.captured for st in cams.stats().values())


async def record_demos(pilot, app, seconds: float = 1.5) -> None:
    """Two demonstrations through the Teleop screen: the SIMULATED operator, a success and a failure."""
    await connect(pilot, app)
    await pilot.press("3", "v", "t")
    assert await wait_for(pilot, lambda: "phase coupled" in screen_text(app))
    # the twin camera's render process takes a few wall seconds to start: episodes need its frames
    assert await wait_for(pilot, lambda: _frames(app) > 0, 60)
    for key in ("s", "f"):
        await pilot.press("r")
        assert await wait_for(pilot, lambda: app.teleop.recording)
        assert await wait_for(pilot, lambda: app.teleop.rec_state().duration_s > seconds, 60)
        await pilot.press(key)
    await pilot.pause(1.0)  # the twin camera's last frames reach the file before teleop stops
    await pilot.press("t")
    assert await wait_for(pilot, lambda: not app.teleop.running and app.teleop.recorder is None)
    await pilot.press("1", "c")  # disconnect: training needs no rig (and the unpaced twin no CPU)
    assert await wait_for(pilot, lambda: not app.runtime.connected)


def test_record_train_quit_mid_training_then_resume(tmp_path):
    async def first_app():
        app = make_app(tmp_path, rate_hz=250.0, train_threads=1)
        async with app.run_test(size=SIZE) as pilot:
            await record_demos(pilot, app)
            await pilot.press("5")
            # default: successful and unlabelled demonstrations, as `factr2 train`: the failure is left out
            assert await wait_for(pilot, lambda: "1 of 1 usable episodes chosen" in screen_text(app))
            await pilot.press("o")  # all: the failure joins
            assert await wait_for(pilot, lambda: "2 of 2 usable episodes chosen" in screen_text(app))
            await pilot.press("o")  # success only
            assert await wait_for(pilot, lambda: "1 of 1 usable episodes chosen" in screen_text(app))
            await pilot.press("o", "o")  # back to all: the run then keeps the failure (include_failed)
            assert await wait_for(pilot, lambda: "2 of 2 usable" in screen_text(app))
            # default: thresholds from the recordings' own contact scores (factr2 train's default); these
            # demonstrations (ground-truth feedback, no contact) hold no scores to split: the preview says so
            assert await wait_for(pilot, lambda: "contact thresholds from the recordings" in screen_text(app))
            ask = "press h and set LOW:HIGH"
            assert await wait_for(pilot, lambda: ask in screen_text(app)), screen_text(app)
            await pilot.press("h", *"0.5:1", "enter")
            assert await wait_for(pilot, lambda: "shading: '.' pre-contact" in screen_text(app), 30)
            assert "free/pre/contact" in screen_text(app) and " %" in screen_text(app)
            await pilot.press("z", "z")  # small -> paper -> tryout
            await pilot.press(*["left_square_bracket"] * 5)  # the shortest: 20 steps (lengths in order)
            assert "size tryout" in screen_text(app) and "20 steps" in screen_text(app)
            assert "ratio 1:5:1" in screen_text(app) and "paper: flow or ACT" in screen_text(app)
            await pilot.press("g")
            assert await wait_for(pilot, lambda: app.training.snapshot().status in ("done", "failed"), 120)
            st = app.training.snapshot()
            assert st.status == "done", st.line
            assert await wait_for(pilot, lambda: "final" in screen_text(app))  # listed under runs
            text = screen_text(app)
            assert "step 20/20" in text and "train loss" in text and "val all" in text, text
            done_run = app.training.opts.out
            # a longer run, then quit while it trains
            for _ in range(6):
                await pilot.press("right_square_bracket")  # 10000 steps: it will not end by itself
            await pilot.press("g")
            assert await wait_for(pilot, lambda: app.training.snapshot().step >= 3, 120)
            assert "ETA" in screen_text(app)
            stopped_run = app.training.opts.out
            await pilot.press("q")
            await pilot.pause(0.5)
        return done_run, stopped_run

    done_run, stopped_run = asyncio.run(first_app())
    meta = C.read_meta(done_run)
    assert meta["final"] and meta["step"] == 20 and meta["method"] == "first"
    assert meta["phases"]["source"] == "given" and len(meta["episodes"]) == 2
    kept = C.read_meta(stopped_run)
    assert not kept["final"] and 3 <= kept["step"] < 10000 and kept["total_steps"] == 10000
    losses = [json.loads(x) for x in (stopped_run / "metrics.jsonl").read_text().splitlines()]
    assert np.isfinite([r["train/loss"] for r in losses if "train/loss" in r]).all()

    async def second_app():
        app = make_app(tmp_path, train_threads=1)
        async with app.run_test(size=SIZE) as pilot:
            await pilot.press("5")
            assert await wait_for(pilot, lambda: ": u resumes" in screen_text(app))
            await pilot.press("u")
            assert await wait_for(pilot, lambda: app.training.snapshot().step > kept["step"], 120), (
                app.training.snapshot().line)
            assert app.training.opts.out == stopped_run and app.training.snapshot().start == kept["step"]
            await pilot.press("x")  # stop again: a second checkpoint, later than the first
            assert await wait_for(pilot, lambda: app.training.snapshot().status == "stopped", 60)
            await pilot.press("q")
            await pilot.pause(0.5)

    asyncio.run(second_app())
    assert C.read_meta(stopped_run)["step"] > kept["step"]
