"""bench_first's --demos-from, --eval-seed, --table and --cells: recorded collections merged into one summary,
bad folders said in one line, a cell's contact score reaching its training run (bench/bench_first.py,
bench/first_config.py, bench/first_stages.py)."""

import json

import pytest

from bench.bench_first import EVAL_SEED, parse_args, recorded_summary


def _summary(folder, task, seed, outcomes):
    folder.mkdir(parents=True)
    res = [{"seed": seed * 100000 + i, "outcome": o, "progress": 1.0 if o == "success" else 0.5}
           for i, o in enumerate(outcomes)]
    (folder / f"{task}-sim-piper-seed{seed}.json").write_text(json.dumps(
        {"task": task, "seed": seed, "sim_s": 10.0, "wall_s": 12.0, "results": res}))


def test_recorded_collections_merge(tmp_path):
    _summary(tmp_path / "a", "wipe", 1, ["success", "failure"])
    _summary(tmp_path / "b", "wipe", 8, ["success", "success"])
    (tmp_path / "b" / "notes.json").write_text("[1, 2]")  # another JSON beside it is not a summary
    s = recorded_summary("wipe", [tmp_path / "a", tmp_path / "b"])
    assert s["episodes"] == 4 and s["success_rate"] == 0.75 and s["progress_mean"] == pytest.approx(0.875)
    assert s["collection_seeds"] == [1, 8] and s["sim_s"] == 20.0
    assert sorted(r["seed"] for r in s["results"]) == [100000, 100001, 800000, 800001]


def test_wrong_task_or_empty_folder_is_one_line(tmp_path):
    _summary(tmp_path / "a", "wipe", 1, ["success"])
    with pytest.raises(SystemExit, match="hold no peg-insert collection"):
        recorded_summary("peg-insert", [tmp_path / "a"])
    (tmp_path / "empty").mkdir()
    with pytest.raises(SystemExit, match="hold no wipe"):
        recorded_summary("wipe", [tmp_path / "empty"])


def test_cli_options(tmp_path, capsys):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    both = f"wipe={tmp_path / 'a'}+{tmp_path / 'b'}"
    cfg, _ = parse_args(["--out", str(tmp_path / "o"), "--demos-from", both, "--eval-seed", "15"])
    assert cfg.demos_from == {"wipe": [str(tmp_path / "a"), str(tmp_path / "b")]} and cfg.eval_seed == 15
    assert parse_args(["--out", "x"])[0].eval_seed == EVAL_SEED
    with pytest.raises(SystemExit):
        parse_args(["--demos-from", f"wipe={tmp_path / 'missing'}"])
    assert "TASK=DIR" in capsys.readouterr().err


def test_first_motion_is_asked_for_by_its_table(capsys):
    cfg, _ = parse_args(["--table", "force-motion", "--cells", "first,first-motion", "--tasks", "cap-screw"])
    assert list(cfg.cells("cap-screw")) == ["first", "first-motion"]
    with pytest.raises(SystemExit) as e:  # not a cell of the force table: it would train nothing
        parse_args(["--table", "force", "--cells", "first-motion", "--tasks", "cap-screw"])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "base, base-torque, first" in err and "--table force-motion" in err


def test_a_cells_score_reaches_its_training_run(tmp_path):
    from bench.first_config import CELLS, BenchConfig
    from bench.first_stages import training_options
    from policies.labels.labelling import TARE_DEFAULT, LabelChoice
    from policies.training.run_config import to_argv

    cfg = BenchConfig(out=str(tmp_path), obs="perceived", steps=40, batch=8)
    kw = {"task": "cap-screw", "run": tmp_path / "r", "seed": 1, "threads": 1, "resume": False}
    first = training_options(cfg, cell=CELLS["first"], **kw)
    assert first.thresholds == "recording" and "--contact-score" not in to_argv(first)  # as before
    motion = training_options(cfg, cell=CELLS["first-motion"], **kw)
    assert motion.thresholds == LabelChoice("recording", TARE_DEFAULT, "motion")
    assert (motion.method, motion.ratio) == (first.method, first.ratio) == ("first", (1, 5, 1))
    argv = to_argv(motion)
    assert argv[argv.index("--contact-score") + 1] == "motion"
