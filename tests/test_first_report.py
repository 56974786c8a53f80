"""The FIRST benchmark's statistics (bench/first_report.py): Wilson intervals, the paired comparison, the raw
per-rollout JSON, and which cells a table trains (bench/bench_first.py)."""

from __future__ import annotations

import pytest

from bench.bench_first import BenchConfig
from bench.first_report import _labels, mcnemar_p, paired, pooled_stages, raw_results, wilson


def test_wilson_matches_the_textbook_values():
    lo, hi = wilson(8, 10)  # Agresti & Coull's example: 0.490 .. 0.943
    assert lo == pytest.approx(0.4902, abs=1e-3) and hi == pytest.approx(0.9433, abs=1e-3)
    assert wilson(0, 20)[0] == 0.0 and wilson(20, 20)[1] == 1.0 and wilson(0, 0) == (0.0, 1.0)
    lo, hi = wilson(48, 96)  # 96 rollouts at 50 %: the benchmark's sizing, half-width <= 10 points
    assert hi - lo <= 0.20


def test_mcnemar_exact():
    assert mcnemar_p(0, 0) == 1.0
    assert mcnemar_p(5, 5) == 1.0
    assert mcnemar_p(0, 6) == pytest.approx(2 / 64)  # all six discordant pairs one way
    assert mcnemar_p(10, 0) < 0.01 and mcnemar_p(1, 9) == mcnemar_p(9, 1)


def _roll(cell, seed, outcomes):
    eps = [{"seed": 200006 + i, "outcome": "success" if o else "failure", "progress": float(o)}
           for i, o in enumerate(outcomes)]
    return {"task": "wipe", "cell": cell, "seed": seed, "episodes": eps, "success_rate": sum(outcomes) / 4,
            "stage_rates": {}}


def test_paired_comparison_and_raw_json():
    rolls = [_roll("first", 0, [1, 1, 0, 0]), _roll("base-torque", 0, [1, 0, 0, 1]),
             _roll("first", 1, [1, 1, 1, 0]), _roll("base-torque", 1, [0, 0, 1, 0])]
    results = {"rollout": rolls, "observation": "state", "machine": {}, "config": {}, "timing": {}}
    p = paired(results, "wipe")
    assert p["seeds"] == [0, 1] and p["diff_per_seed"] == [0.0, 0.5]
    assert (p["both"], p["only_a"], p["only_b"], p["neither"]) == (2, 3, 1, 2)
    raw = raw_results(results)
    assert raw["wipe"]["first"]["seeds"][1] == {
        "seed": 1, "success": [1, 1, 1, 0], "progress": [1.0, 1.0, 1.0, 0.0],
        "episode_seeds": [200006, 200007, 200008, 200009], "stage_rates": {}}
    assert raw["config"]["simulated"] is True


def test_tables_choose_their_cells():
    cfg = BenchConfig(tasks=["peg-insert", "wipe"], table="headline")
    assert list(cfg.cells("peg-insert")) == ["base-torque", "first"] == list(cfg.cells("wipe"))
    cfg.table = "second"
    assert set(cfg.cells("peg-insert")) == {"base", "C", "PC+C", "first"} and cfg.cells("wipe") == {}
    cfg.table = "all"
    assert set(cfg.cells("peg-insert")) == {"base", "base-torque", "first", "C", "PC+C"}
    cfg.table = "force"  # as it trained before cells carried their contact score
    assert cfg.cells("wipe") == {"base": ("base", None, "l1"), "base-torque": ("base-torque", None, "l1"),
                                 "first": ("first", (1, 5, 1), "l1")}
    cfg.table = "force-motion"  # the force table and first on the motion-discounted labels
    assert list(cfg.cells("wipe")) == ["base", "base-torque", "first", "first-motion"]
    assert cfg.cells("wipe")["first-motion"] == ("first", (1, 5, 1), "motion")
    cfg.only_cells = ["first-motion"]
    assert list(cfg.cells("peg-insert")) == ["first-motion"]


def test_stages_pool_over_the_episodes_of_every_seed():
    a = {"episodes": [{}] * 4, "stage_rates": {"grasp": 1.0, "align": 0.5, "seat": 0.25}}
    b = {"episodes": [{}] * 12, "stage_rates": {"grasp": 0.75, "align": 0.5, "seat": 0.0}}
    got = pooled_stages([a, b])
    assert list(got) == ["grasp", "align", "seat"]  # the task's order, where episodes stop
    assert got == pytest.approx({"grasp": 13 / 16, "align": 0.5, "seat": 1 / 16})
    assert pooled_stages([]) == {} and pooled_stages([{"episodes": [], "stage_rates": {}}]) == {}


def test_the_tables_label_thresholds_in_n_m_are_the_default_scores():
    motion = {"task": "wipe", "phases": {"t_low": 15.3, "t_high": 28.7, "score": "motion"},
              "phase_shares": {"free": 0.35}}
    l1 = {"task": "wipe", "phases": {"t_low": 0.7, "t_high": 1.3}, "phase_shares": {"free": 0.28}}
    demos = {"wipe": {"phase_thresholds_nm": [0.6, 1.2], "phase_shares": {}}}
    assert _labels({"train": [motion, l1], "demos": demos}, "wipe") == (0.7, 1.3, {"free": 0.28})
    assert _labels({"train": [motion], "demos": demos}, "wipe")[:2] == (0.6, 1.2)  # a first-motion-only run
