"""The force table (bench/first_force.py): pooled success, the paired comparisons and the ablation drop,
computed from a bench_first folder of known rollouts."""
import json

import pytest

from bench.first_force import failing_stage, main, report
from bench.first_report import mcnemar_p, wilson


def _roll(path, outcomes, progress, stages):
    path.parent.mkdir(parents=True, exist_ok=True)
    eps = [{"seed": 3100093 + i, "outcome": "success" if o else "failure", "progress": p}
           for i, (o, p) in enumerate(zip(outcomes, progress))]
    path.write_text(json.dumps({"episodes": eps, "stage_rates": stages}))


def _folder(tmp_path):
    (tmp_path / "config.json").write_text(json.dumps({"obs": "perceived", "eval_seed": 31, "rollouts": 4}))
    st = {"grasp": 1.0, "engage": 0.75, "seat": 0.5, "tight": 0.25}
    for seed in (0, 1):
        run = tmp_path / "cap-screw"
        _roll(run / "base" / f"seed{seed}" / "rollout.json", [0, 0, 0, 1], [0.5, 0.5, 0.75, 1.0], st)
        _roll(run / "base-torque" / f"seed{seed}" / "rollout.json", [1, 1, 0, 1], [1, 1, 0.75, 1], st)
        _roll(run / "first" / f"seed{seed}" / "rollout.json", [1, 1, 1, 1], [1, 1, 1, 1], st)
        _roll(run / "first" / f"seed{seed}" / "rollout-zero.json", [0, 1, 0, 0], [0.5, 1, 0.5, 0.5], st)
    return tmp_path


def test_force_table_pairs_by_seed_and_episode(tmp_path):
    md, data = report(_folder(tmp_path))
    cells, pairs = data["tasks"]["cap-screw"]["cells"], data["tasks"]["cap-screw"]["pairs"]
    assert (cells["base"]["k"], cells["base"]["n"]) == (2, 8)
    assert (cells["first"]["k"], cells["first, force zero"]["k"]) == (8, 2)
    bt = pairs["base-torque vs base"]
    assert (bt["only_a"], bt["only_b"], bt["pairs"]) == (4, 0, 8)
    assert bt["success_diff"] == pytest.approx(0.5) and bt["mcnemar_p"] == pytest.approx(0.125)
    assert bt["progress_diff"] == pytest.approx((0.5 + 0.5 + 0 + 0) / 4)
    drop = pairs["first: live vs force zero"]
    assert (drop["only_a"], drop["only_b"]) == (6, 0) and drop["mcnemar_p"] == pytest.approx(1 / 32)
    assert "first: live vs force shuffle" not in pairs  # no such rollouts
    assert "| cap-screw | first, force zero | 2 | 2 / 8 = 25 %" in md


def test_failing_stage_is_the_largest_drop():
    assert failing_stage({"grasp": 0.9, "engage": 0.85, "seat": 0.3, "tight": 0.25}).startswith("seat")
    assert failing_stage({"grasp": 1.0, "tight": 1.0}) == "-" and failing_stage({}) == "-"


def test_cli_refuses_a_folder_that_is_not_a_run(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        main(["--out", str(tmp_path)])
    assert e.value.code == 2 and "not a bench_first results folder" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--out", str(_folder(tmp_path)), "--ablate", "noise"])
    assert main(["--out", str(tmp_path), "--report"]) == 0 and (tmp_path / "force_table.md").is_file()


def test_against_pairs_another_observation_on_the_same_episodes(tmp_path):
    (tmp_path / "perceived").mkdir()
    out = _folder(tmp_path / "perceived")
    other = tmp_path / "state"
    other.mkdir()
    (other / "config.json").write_text(json.dumps({"obs": "state", "eval_seed": 31, "rollouts": 4}))
    st = {"grasp": 1.0, "engage": 1.0, "seat": 1.0, "tight": 1.0}
    _roll(other / "cap-screw" / "base" / "seed0" / "rollout.json", [1, 1, 0, 1], [1, 1, 0.75, 1], st)
    md, data = report(out, other)
    d = data["tasks"]["cap-screw"]
    assert (d["cells"]["base, PRIVILEGED state observation"]["k"], d["cells"]["base"]["k"]) == (3, 2)
    p = d["pairs"]["base: perceived vs PRIVILEGED state observation"]
    assert (p["pairs"], p["only_a"], p["only_b"], p["seeds"]) == (4, 0, 2, [0])  # seed 1 has no state run
    assert "base, PRIVILEGED state observation" in md
    (other / "config.json").write_text(json.dumps({"obs": "state", "eval_seed": 32, "rollouts": 4}))
    with pytest.raises(SystemExit, match="would not pair"):
        report(out, other)


def test_first_motion_is_its_own_row_paired_against_base_torque_and_first(tmp_path):
    out = _folder(tmp_path)
    _, without = report(out)
    assert not any("first-motion" in k for t in without["tasks"].values() for k in [*t["cells"], *t["pairs"]])
    st = {"grasp": 1.0, "engage": 1.0, "seat": 0.5, "tight": 0.5}
    for seed in (0, 1):  # seed 0 and 1 alike: 2 of 4 succeed, episodes 3100093 and 3100095
        _roll(out / "cap-screw" / "first-motion" / f"seed{seed}" / "rollout.json", [1, 0, 1, 0],
              [1, 0.5, 1, 0.75], st)
    md, data = report(out)
    d = data["tasks"]["cap-screw"]
    fm = d["cells"]["first-motion"]
    assert (fm["k"], fm["n"], fm["seeds"], fm["per_seed"]) == (4, 8, [0, 1], [0.5, 0.5])
    assert fm["wilson"] == pytest.approx(wilson(4, 8)) and fm["progress"] == pytest.approx(0.8125)
    assert fm["failing_stage"].startswith("seat")
    bt = d["pairs"]["first-motion vs base-torque"]  # base-torque: 1 1 0 1, progress 1 1 0.75 1
    assert (bt["pairs"], bt["only_a"], bt["only_b"]) == (8, 2, 4)
    assert bt["mcnemar_p"] == pytest.approx(mcnemar_p(2, 4))
    assert bt["progress_diff"] == pytest.approx((0 - 0.5 + 0.25 - 0.25) / 4)
    lo, hi = bt["progress_ci"]
    assert lo < bt["progress_diff"] < hi
    first = d["pairs"]["first-motion vs first"]  # first: 1 1 1 1
    assert (first["only_a"], first["only_b"], first["success_diff"]) == (0, 4, -0.5)
    assert "first-motion vs base" in d["pairs"]
    # every row and comparison of the table without first-motion is there unchanged, in its order
    before = without["tasks"]["cap-screw"]
    assert {k: v for k, v in d["cells"].items() if k != "first-motion"} == before["cells"]
    assert list(d["cells"]) == [*before["cells"], "first-motion"]
    assert {k: v for k, v in d["pairs"].items() if "first-motion" not in k} == before["pairs"]
    assert "| cap-screw | first-motion | 2 | 4 / 8 = 50 %" in md
    assert "| cap-screw | first-motion vs first | 8 (seeds 0,1) | 0 / 4 |" in md


def test_keep_rebuilds_the_committed_table_from_its_raw_rows_alone(tmp_path):
    """An empty run folder with --keep force_perceived gives back every cell and comparison the committed
    results file holds: nothing of the table lives only in a run folder."""
    from bench import harness

    path = harness.RESULTS / "force_perceived.json"
    payload = json.loads(path.read_text())["payload"]
    (tmp_path / "config.json").write_text(json.dumps({"obs": payload["observation"],
                                                      "eval_seed": payload["eval_seed"], "rollouts": 32}))
    _, data = report(tmp_path, keep=payload)
    for task, d in payload["tasks"].items():
        got = data["tasks"][task]
        assert set(got["cells"]) == set(d["cells"]) and set(got["pairs"]) == set(d["pairs"]), task
        for name, cell in d["cells"].items():
            for key in ("k", "n", "seeds", "per_seed", "failing_stage"):
                assert got["cells"][name][key] == cell[key], (task, name, key)
            assert got["cells"][name]["progress"] == pytest.approx(cell["progress"])
            assert got["cells"][name]["stages"] == pytest.approx(cell["stages"])
        for name, pair in d["pairs"].items():
            for key in ("pairs", "only_a", "only_b", "seeds"):
                assert got["pairs"][name][key] == pair[key], (task, name, key)
            assert got["pairs"][name]["progress_ci"] == pytest.approx(pair["progress_ci"])
        assert got["raw"] == d["raw"]


def test_keep_takes_only_what_the_run_lacks_and_refuses_other_episodes(tmp_path):
    out = _folder(tmp_path)
    _, first = report(out)
    st = {"grasp": 1.0, "engage": 0.5, "seat": 0.5, "tight": 0.5}  # a kept cell that OUT lacks
    first["tasks"]["cap-screw"]["raw"]["base/state"] = {"0": [[3100093, 1, 1.0], [3100094, 0, 0.5]]}
    first["tasks"]["cap-screw"]["cells"]["base, PRIVILEGED state observation"] = {"stages": st}
    first["tasks"]["cap-screw"]["raw"]["first/live"]["0"] = [[3100093, 0, 0.0]]  # OUT has it: not taken
    first["tasks"]["cap-screw"]["raw"]["first/live"]["2"] = [[3100093, 0, 0.0]]  # a seed OUT lacks: taken
    _, data = report(out, keep=first)
    d = data["tasks"]["cap-screw"]
    first_cell = d["cells"]["first"]
    assert (first_cell["k"], first_cell["n"], first_cell["seeds"]) == (8, 9, [0, 1, 2])
    kept = d["cells"]["base, PRIVILEGED state observation"]
    assert (kept["k"], kept["n"], kept["stages"]) == (1, 2, st)
    assert d["pairs"]["base: perceived vs PRIVILEGED state observation"]["pairs"] == 2
    with pytest.raises(SystemExit, match="would not pair"):
        report(out, keep={**first, "eval_seed": 32})
