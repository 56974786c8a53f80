"""The force table (bench/first_force.py): pooled success, the paired comparisons and the ablation drop,
computed from a bench_first folder of known rollouts."""
import json

import pytest

from bench.first_force import failing_stage, main, report


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
