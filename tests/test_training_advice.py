"""The advice a run gives from its own validation curve (policies/training/advice.py): the rule on synthetic
curves, `factr2 train` printing it after a tiny run (and `factr2 train-advice` for the finished run), the
Train screen showing it after a tiny run and for a run it lists."""

from __future__ import annotations

import asyncio
from pathlib import Path

import numpy as np
import pytest
import torch

from policies.training import advice as A
from tests.policy_helpers import write_recording

torch.set_num_threads(1)


def _rows(values, every=500, noise=0.0, seed=0, train_rows=True):
    rng = np.random.default_rng(seed)
    rows = []
    for k, v in enumerate(values):
        step = (k + 1) * every
        if train_rows:  # training-loss rows between the evaluations: ignored by the rule
            rows.append({"step": step - 1, "train/loss": 0.1})
        rows.append({"step": step, "val/loss": float(v) * (1.0 + noise * rng.standard_normal())})
    return rows


def test_a_curve_that_turned_up_says_the_data_limits_and_not_to_train_shorter():
    v = np.r_[np.linspace(1.0, 0.3, 6), np.linspace(0.31, 0.45, 11)]  # bottom at the 6th evaluation
    lines = A.training_advice(_rows(v, noise=0.01), 47, ["cap-screw"], rig="sim-piper")
    assert "turned up after 3.0 k of 8.5 k steps at 47 demonstrations" in lines[0]
    assert "the data, not the training length" in lines[0] and "record more demonstrations" in lines[0]
    # shorter training was measured not to raise success: the advice never suggests it
    assert "--steps" not in lines[0] and "train shorter" not in lines[0]
    sh = A.measured()["shorter_training"]
    assert (f"training shorter did not raise success on the twin (peg-insert + press-fit: {sh['k_short']} / "
            f"{sh['n_short']} at") in lines[0] and "'Choosing the defaults')" in lines[0]
    assert lines[1] == ("no measured data curve for cap-screw on sim-piper: no basis to say how many "
                        "demonstrations would be enough")


FIXTURE = Path(__file__).parent / "data" / "data_curve"  # results-shaped files: 2 seeds pooled, 1 alone


@pytest.fixture(scope="module")
def fixture_curve():
    from bench.data_curve_advice import build

    return build(FIXTURE)


def test_the_measured_curve_pools_the_seeds_present(fixture_curve):
    pf = fixture_curve["tasks"]["press-fit"]
    assert [(p["n"], p["seeds"], p["rollouts"], p["k"], p["episodes"]) for p in pf] == [
        (25, [0, 1], [24], 14, 48), (50, [0, 1], [24], 22, 48), (100, [0], [24], 18, 24)]
    assert pf[0]["wilson"] == [0.1824, 0.4318]  # 14 / 48, 95 % Wilson
    sh = fixture_curve["shorter_training"]  # the steps both curves share, EMA rows only, pooled
    got = [sh[k] for k in ("short_steps", "long_steps", "k_short", "n_short", "k_long", "n_long")]
    assert got == [2000, 8000, 1, 40, 5, 40]
    assert sh["p_one_sided"] == 0.1004  # scipy.stats.fisher_exact([[1, 39], [5, 35]], "less"): 0.10036


def test_the_measured_line_says_the_curve_its_basis_and_where_the_run_lies(fixture_curve):
    m = fixture_curve
    line = A.data_line({"press-fit": 47}, "sim-piper", m)
    assert line == ("measured on the twin's press-fit (SIMULATED, PRIVILEGED state): 25 -> 50 -> 100 "
                    "demonstrations gave 29 -> 46 -> 75 % success (95 % intervals 18-43, 33-60, 55-88 %), "
                    "training seeds x rollouts 2 x 24, 2 x 24, 1 x 24; this run's 47 lie between the "
                    "measured 25 and 50; the next above is 50 (46 %) (docs/policies.md, 'The data curve')")
    lines = {n: A.data_line({"press-fit": n}, "sim-piper", m) for n in (12, 50, 100, 250)}
    where = {n: line[line.index("this run's"):] for n, line in lines.items()}
    assert where[12].startswith("this run's 12 lie below the measured range; its first point is 25 (29 %)")
    assert where[50].startswith("this run's 50 is a measured point; the next above is 100 (75 %)")
    assert where[100].startswith("this run's 100 is the largest point measured, nothing above it")
    assert where[250].startswith("this run's 250 lie above the measured range (up to 100): no basis beyond")
    wipe = A.data_line({"wipe": 30}, "sim-piper", m)
    assert "1 training seed x 4 rollouts each" in wipe and "75 -> 100 % success" in wipe
    # another task, another rig (a real one), or no rig named: no basis, said so
    for tasks, rig in (({"cap-screw": 50}, "sim-piper"), ({"press-fit": 50}, "piper"), ({"wipe": 5}, "")):
        assert A.data_line(tasks, rig, m).startswith(f"no measured data curve for {next(iter(tasks))} on "
                                                     f"{rig or 'this rig'}: no basis")
    flat = A.training_advice(_rows(np.r_[np.linspace(1.0, 0.3, 5), np.full(10, 0.3)]), 47, ["press-fit"],
                             rig="sim-piper", m=m)
    assert flat[1] == line


def test_the_package_copy_is_what_results_hold():
    """The installed app reads policies/training/data_curve_points.json (results/ is not in the wheel):
    regenerated from results/ by `python -m bench.data_curve_advice`, never edited by hand."""
    from bench.data_curve_advice import PACKAGE_COPY, build, main, text

    assert PACKAGE_COPY.read_text() == text(build()), "run `python -m bench.data_curve_advice` and commit it"
    assert A.measured() == build()
    assert main(["--check"]) == 0


def test_a_curve_still_falling_says_train_longer():
    c = A.read_curve(_rows(np.exp(-np.linspace(0, 3, 12)), noise=0.005))
    assert c.kind == "falling" and c.step_end == 6000
    line = A.training_advice(_rows(np.exp(-np.linspace(0, 3, 12))), 20)[0]
    assert "still falling" in line and "train longer" in line


def test_a_flat_end_within_noise_is_flat_not_a_turn():
    v = np.r_[np.linspace(1.0, 0.3, 5), np.full(10, 0.3)]
    kinds = [A.read_curve(_rows(v, noise=0.02, seed=seed)).kind for seed in range(300)]  # 2 % noise
    assert kinds.count("flat") == 299, kinds.count("flat")  # docs/policies.md states these counts
    up = np.r_[np.linspace(1.0, 0.3, 6), np.linspace(0.31, 0.45, 11)]
    assert all(A.read_curve(_rows(up, noise=0.02, seed=seed)).kind == "up" for seed in range(300))
    assert "flat" in A.training_advice(_rows(v), 30)[0]


def test_one_outlier_evaluation_makes_no_turn():
    v = np.r_[np.linspace(1.0, 0.3, 8), [0.3, 0.3, 0.9, 0.3, 0.3]]  # one bad evaluation near the end
    assert A.read_curve(_rows(v)).kind == "flat"


def test_no_validation_or_too_few_points_gives_no_basis():
    assert A.training_advice([{"step": 10, "train/loss": 0.2}], 1) == [
        "advice: no validation split: no basis for advice (validation holds out whole episodes: record at "
        "least 2)"]
    line = A.training_advice(_rows([1.0, 0.5, 0.4, 0.6]), 10)[0]
    assert "4 validation points, 5 needed" in line and "no basis" in line
    nan = [{"step": 5 * k, "val/loss": float("nan")} for k in range(1, 9)]
    assert "no validation split" in A.training_advice(nan, 3)[0]


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    d = tmp_path_factory.mktemp("rec")
    write_recording(d / "a.mcap", episodes=3, seconds=3.0)
    return d


@pytest.fixture(scope="module")
def cli_run(recordings, tmp_path_factory):
    """A 12-step `factr2 train` run validating every 2 steps: (its folder, what it printed)."""
    import contextlib
    import io

    from factr2_teleop.cli import main
    from tests.test_policies_train import _cli_args

    out = tmp_path_factory.mktemp("runs") / "run"
    args = _cli_args(recordings, out, ["--val-every", "2", "--ckpt-every", "100"])
    args[args.index("--steps") + 1] = "12"
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        assert main(args) == 0
    return out, printed.getvalue().splitlines()


def test_factr2_train_prints_the_advice_of_its_own_curve(cli_run, tmp_path, capsys):
    from factr2_teleop.cli import main
    from policies.training.curves import RunLog

    out, printed = cli_run
    got = [line for line in printed if line.startswith("advice:") or line.startswith("no measured")]
    rows = RunLog.read(out)
    assert sum("val/loss" in r for r in rows) == 6
    assert got == A.training_advice(rows, 3, ["push"]) and got[0].startswith("advice: validation loss")

    # a finished run's advice again, without training: the same lines
    assert main(["train-advice", str(out)]) == 0
    assert capsys.readouterr().out.splitlines() == got
    # not a run, or a damaged one: one line, exit 2
    import shutil

    bad = tmp_path / "bad"
    shutil.copytree(out, bad)
    (bad / "metrics.jsonl").write_text('{"step": 1, "val/lo')
    for folder, why in ((tmp_path, "not a training run"), (bad, "unreadable run")):
        assert main(["train-advice", str(folder)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and why in err[0] and "fix:" in err[0]
    # several: each run's lines under its name, a bad one said without stopping the rest, exit 2
    assert main(["train-advice", str(tmp_path), str(out)]) == 2
    got_both = capsys.readouterr()
    assert got_both.out.splitlines() == [f"{out}:", *got] and "not a training run" in got_both.err


def test_the_train_screen_shows_the_advice_of_the_run_it_lists_first(cli_run, tmp_path):
    """`factr2 tui --runs RUN` on a `factr2 train` run: the Train screen shows its advice before training."""
    from tui_helpers import SIZE, make_app, screen_text, wait_for

    out, _ = cli_run
    lines = A.run_advice(out)

    async def go():
        app = make_app(tmp_path, runs_dir=out, train_threads=1)
        async with app.run_test(size=SIZE) as pilot:
            await pilot.press("5")
            shown = await wait_for(pilot, lambda: "advice of run, the first run listed:" in screen_text(app))
            text = screen_text(app)
            await pilot.press("q")
        return shown, text

    shown, text = asyncio.run(go())
    assert shown and lines[0].startswith("advice: validation loss")
    flat = " ".join(text.split())
    assert all(" ".join(line.split()) in flat for line in lines)  # wrapped at the screen's width


def test_the_train_screen_shows_the_advice_after_a_run(tmp_path):
    from tui_helpers import SIZE, make_app, screen_text, wait_for

    write_recording(tmp_path / "recordings" / "a.mcap", episodes=3, seconds=3.0)

    async def go():
        app = make_app(tmp_path, train_threads=1)
        async with app.run_test(size=SIZE) as pilot:
            await pilot.press("5")
            assert await wait_for(pilot, lambda: "3 of 3 usable episodes chosen" in screen_text(app))
            await pilot.press("h", *"1:3", "enter")
            await pilot.press("z", "z", *["left_square_bracket"] * 5)  # tryout, 20 steps
            await pilot.press("g")
            assert await wait_for(pilot, lambda: app.training.snapshot().status in ("done", "failed"), 120)
            assert app.training.snapshot().status == "done", app.training.snapshot().line
            assert await wait_for(pilot, lambda: "advice:" in screen_text(app))
            text = screen_text(app)
            await pilot.press("q")
        return app.training.snapshot().advice, text

    advice, text = asyncio.run(go())
    # 20 steps validate every 5: four points, too few to read a curve, and the screen says so
    assert advice == ["advice: 4 validation points, 5 needed to read the curve: no basis for advice"]
    assert "4 validation points" in text
