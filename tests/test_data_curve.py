"""bench/data_curve.py's pure parts: the nested subsets, the seeds apart from every other, the queue skipping
what OUT holds, the report's numbers from fake rows, and bad options in one line (its --quick run collects,
trains and rolls out: minutes, run by hand; tests/test_bench_quick.py lists it in SKIP)."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import pytest

from bench import data_curve as dc
from bench import data_curve_queue as Q
from bench import first_config
from bench.data_curve_report import chart, finished_rows, point_dir, summarize, write_results
from bench.first_report import wilson
from factr2_teleop.session.task_episodes import episode_seed
from policies.data.recordings import parse_episode_ids

ROOT = Path(__file__).resolve().parents[1]


def _summary(seed: int, outcomes: str) -> dict:
    return {"seed": seed, "task": "wipe", "wall_s": 1.0, "cpu_s": 1.0,
            "results": [{"index": i, "seed": episode_seed(seed, i),
                         "outcome": "success" if o == "s" else "failure",
                         "progress": 1.0 if o == "s" else 0.5}
                        for i, o in enumerate(outcomes)]}


def test_subsets_are_the_first_successes_in_collection_order_and_nested():
    parts = [("a.mcap", _summary(1, "sfss")), ("b.mcap", _summary(2, "ssfs"))]
    ids = dc.successful_ids(parts)
    assert ids == ["a.mcap#0", "a.mcap#2", "a.mcap#3", "b.mcap#0", "b.mcap#1", "b.mcap#3"]
    assert ids[:2] == ids[:4][:2]  # the smaller point's episodes are in the larger one's
    assert dc.parts_for([3, 3], 3) == 1 and dc.parts_for([3, 3], 4) == 2 and dc.parts_for([3, 3], 7) is None
    assert dc.episode_ranges(ids) == "a.mcap#0,a.mcap#2-3,b.mcap#0-1,b.mcap#3"
    assert parse_episode_ids(dc.episode_ranges(ids)) == tuple(ids)  # what factr2 train --episodes reads back


def _other_seeds() -> set[int]:
    """Every seed constant of bench/first_config.py besides the data curve's, and every evaluation seed a
    committed result pre-registered."""
    own = {n for n in vars(first_config) if n.startswith("DATA_CURVE")}
    seeds = {v for n, v in vars(first_config).items() if n.endswith("_SEED") and n not in own}
    for p in (ROOT / "results").glob("*.json"):
        text = p.read_text()
        if json.loads(text).get("payload", {}).get("seed_set") == "curve":  # the data curve's own results
            continue
        seeds |= {int(x) for x in __import__("re").findall(r'"eval_seed": (\d+)', text)}
    return seeds


def test_data_curve_seeds_are_used_for_nothing_else():
    demo = range(first_config.DATA_CURVE_DEMO_SEED,
                 first_config.DATA_CURVE_DEMO_SEED + first_config.DATA_CURVE_PARTS_MAX)
    others = _other_seeds()
    assert {2, 15, 31} <= others  # the scan sees the evaluation seeds in use
    assert not set(demo) & others and first_config.DATA_CURVE_EVAL_SEED not in others
    assert first_config.DATA_CURVE_EVAL_SEED not in demo
    # episode seeds (S * stride + k) of the collection parts and the rollouts never meet for k < stride
    roll = {episode_seed(first_config.DATA_CURVE_EVAL_SEED, k) for k in range(1000)}
    assert not roll & {episode_seed(s, k) for s in demo for k in range(1000)}


def _cfg(tmp_path: Path, **kw) -> dc.CurveConfig:
    return dc.CurveConfig(**{"out": str(tmp_path), "tasks": ["wipe"], "points": {"wipe": [2, 4]}, "seeds": 1,
                             "rollouts": 2, "part_episodes": 3, **kw})


def _write_part(cfg: dc.CurveConfig, k: int, outcomes: str) -> None:
    summary = Q.part_paths(cfg, "wipe", k)[1]
    summary.parent.mkdir(parents=True, exist_ok=True)
    summary.write_text(json.dumps(_summary(cfg.demo_seed + k, outcomes)))


def _finish(cfg: dc.CurveConfig, n: int, seed: int, outcomes: list[int], rollout: bool = True) -> None:
    run = point_dir(cfg.out, "wipe", n, seed)
    run.mkdir(parents=True, exist_ok=True)
    (run / "train.json").write_text(json.dumps({
        "task": "wipe", "n_demos": n, "seed": seed, "steps": 100, "batch": 256, "epochs": 80.0,
        "val": {"val/loss": 0.5}, "commit": "abc1234", "defaults": "current", "wall_s": 10.0, "cpu_s": 9.0,
        "run": str(run)}))
    if rollout:
        eps = [{"seed": episode_seed(cfg.eval_seed, i), "outcome": "success" if o else "failure",
                "progress": 1.0 if o else 0.25} for i, o in enumerate(outcomes)]
        (run / "rollout.json").write_text(json.dumps({
            "task": "wipe", "n_demos": n, "seed": seed, "success_rate": sum(outcomes) / len(outcomes),
            "mean_progress": sum(e["progress"] for e in eps) / len(eps), "episodes": eps,
            "stage_rates": {"grasp": 1.0, "wipe": sum(outcomes) / len(outcomes)}, "wall_s": 5.0,
            "cpu_s": 4.0}))


def test_the_queue_collects_then_trains_the_points_it_can_and_skips_what_is_finished(tmp_path):
    cfg = _cfg(tmp_path)
    st = Q.State(cfg)
    assert [(k, a) for _, k, a in st.ready(set())] == [("collect", ("wipe", 0)), ("collect", ("wipe", 1))]
    _write_part(cfg, 0, "sfs")  # 2 successes: the 2-point can train, the 4-point waits for part 1
    st = Q.State(cfg)
    jobs = [(k, a[:3]) for _, k, a in st.ready(set())]
    assert jobs == [("train", ("wipe", 2, 0)), ("collect", ("wipe", 1))]
    folders, ids = st.subset("wipe", 2)
    assert ids == ["wipe-sim-piper-seed5601.mcap#0", "wipe-sim-piper-seed5601.mcap#2"]
    assert folders == [Q.part_dir(cfg.out, "wipe", 0)]
    _write_part(cfg, 1, "fff")  # both planned parts in, 2 successes: a third part is planned
    _finish(cfg, 2, 0, [1, 0])  # the 2-point finished: neither trained nor rolled out again
    st = Q.State(cfg)
    assert [(k, a[:3]) for _, k, a in st.ready(set())] == [("collect", ("wipe", 2))]
    _write_part(cfg, 2, "ss")
    _finish(cfg, 4, 0, [], rollout=False)  # trained, not rolled out (an interrupted run)
    st = Q.State(cfg)
    assert [(k, a[:3]) for _, k, a in st.ready(set())] == [("rollout", ("wipe", 4, 0))]
    assert st.ready({("rollout", ("wipe", 4, 0))}) == []  # running already
    train = dc.train_argv(cfg, *st.subset("wipe", 4), 0, Path("RUN"))
    assert train[train.index("--episodes") + 1] == ("wipe-sim-piper-seed5601.mcap#0,wipe-sim-piper-seed5601"
                                                    ".mcap#2,wipe-sim-piper-seed5603.mcap#0-1")
    assert "--steps" not in train  # the current defaults: factr2 train with no options


def test_the_report_pools_the_seeds_and_writes_a_portable_record(tmp_path):
    cfg = _cfg(tmp_path, seeds=2)
    _finish(cfg, 2, 0, [1, 0, 0, 0])
    _finish(cfg, 2, 1, [1, 1, 0, 0])
    _finish(cfg, 4, 0, [1, 1, 1, 1])
    rows = finished_rows(tmp_path)
    assert [(r["n_demos"], r["seed"]) for r in rows] == [(2, 0), (2, 1), (4, 0)]
    s = summarize(rows)["wipe"]
    assert (s[2]["k"], s[2]["episodes"]) == (3, 8) and s[2]["wilson"] == list(wilson(3, 8))
    assert s[2]["per_seed"] == [0.25, 0.5] and s[2]["progress"] == pytest.approx((3 * 1 + 5 * 0.25) / 8)
    assert s[2]["stages"]["wipe"] == pytest.approx(3 / 8) and s[4]["success"] == 1.0
    chart(summarize(rows), tmp_path / "curve.png", "wipe")
    assert (tmp_path / "curve.png").stat().st_size > 1000
    res = dc.build_results(cfg, f"python -m bench.data_curve --out {tmp_path} --report")
    assert res["rows"] == rows and res["summary"]["wipe"]["2"]["k"] == 3
    path = write_results(res, "dc_test", f"python -m bench.data_curve --out {tmp_path} --report", tmp_path,
                         results_dir=tmp_path / "results")
    text = path.read_text()
    assert str(tmp_path) not in text and '"out": "OUT"' in text  # no machine folder in a published result
    rec = json.loads(text)
    assert rec["experiment"] == "dc_test" and rec["simulated"]
    assert rec["payload"]["summary"]["wipe"]["4"]["k"] == 4
    assert rec["command"] == "python -m bench.data_curve --out OUT --report"


@pytest.mark.parametrize("argv, says", [
    (["--points", "25,x"], "--points"), (["--seeds", "0"], "--seeds 0"),
    (["--tasks", "cap-screw"], "no default points for cap-screw"), (["--defaults", "later"], "--defaults"),
    (["--perturb", "amplitude=0.1"], "--perturb"),
    (["--train-args", "--bogus 3"], "factr2 train has no --bogus"),
    (["--train-args", "--steps abc"], "--steps: invalid int value"),
])
def test_bad_options_say_one_thing_and_exit_2(tmp_path, capsys, argv, says):
    with pytest.raises(SystemExit) as e:
        dc.parse_args(["--out", str(tmp_path), *argv])
    assert e.value.code == 2 and says in capsys.readouterr().err


def test_current_defaults_are_factr2_train_with_no_options_but_the_subset_and_seed(tmp_path):
    """What a point trains with, parsed by factr2 train's own flags: the same options as
    `factr2 train DEMOS --obs state --out RUN` except the episodes, the training seed and how it runs."""
    import argparse

    from policies.training.run_config import add_arguments, from_args

    ap = argparse.ArgumentParser()
    add_arguments(ap)
    argv = dc.train_argv(_cfg(tmp_path), [tmp_path / "part00"], ["x.mcap#0", "x.mcap#1"], 1, tmp_path / "run")
    point = asdict(from_args(ap.parse_args(argv + ["--threads", "1", "--no-progress"])))
    plain = asdict(from_args(ap.parse_args([str(tmp_path / "part00"), "--obs", "state", "--out", "RUN"])))
    for d in (point, plain):
        d["train"].update(seed=None, threads=None)
    assert {k for k in point if point[k] != plain[k]} == {"out", "episodes", "progress"}
    assert point["episodes"] == ("x.mcap#0", "x.mcap#1")


def test_train_args_reach_every_point_and_its_recorded_flags(tmp_path):
    cfg, _ = dc.parse_args(["--out", str(tmp_path), "--train-args", "--thresholds 0.6:1.1 --no-tare"])
    assert cfg.train_flags == ["--thresholds", "0.6:1.1", "--no-tare"]
    argv = dc.train_argv(cfg, [tmp_path / "part00"], ["x.mcap#0"], 0, tmp_path / "run")
    assert argv[argv.index("--thresholds") + 1] == "0.6:1.1" and "--no-tare" in argv
    assert "train_flags" in dc.SAME_ON_RESUME  # an OUT is never resumed with other train args


def test_an_out_is_not_resumed_under_other_defaults(tmp_path):
    meta = dc.defaults_meta("current")
    assert (meta["train"]["epochs"], meta["train"]["batch"], meta["observation"]) == (80.0, 256, "state")
    assert dc.defaults_meta("current") == meta  # no seed, thread count or path in it
    cfg = _cfg(tmp_path, defaults_meta=meta)
    (tmp_path / "config.json").write_text(json.dumps(asdict(cfg)))
    first_config.check_resume(cfg, tmp_path, dc.SAME_ON_RESUME)  # the same: resumes
    later = _cfg(tmp_path, defaults_meta={**meta, "train": {**meta["train"], "epochs": 40.0}})
    with pytest.raises(SystemExit, match="defaults_meta"):
        first_config.check_resume(later, tmp_path, dc.SAME_ON_RESUME)


def test_the_registry_seed_ranges_never_meet_and_cover_every_seed():
    """Every *_SEED constant of bench/first_config.py lies in its SEED_RANGES entry, no two ranges share a
    session seed, and so no two share an episode seed (S * stride + k, k below the stride); the development
    seeds also miss every evaluation seed a committed result pre-registered and every page's (below 1001)."""
    ranges = first_config.SEED_RANGES
    for name, value in vars(first_config).items():
        if name.endswith("_SEED"):
            assert any(value in r for r in ranges.values()), name
    names = list(ranges)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            assert not set(ranges[a]) & set(ranges[b]), (a, b)
    eps = {n: {episode_seed(s, k) for s in r for k in (0, 999)} for n, r in ranges.items()}
    assert sum(map(len, eps.values())) == len(set().union(*eps.values()))
    dev = set(ranges["defaults_dev_demo"]) | set(ranges["defaults_dev_eval"])
    assert not dev & _other_seeds() - dev and min(dev) > 1000


def test_dev_mode_uses_its_own_seeds_and_is_never_resumed_as_the_curve(tmp_path):
    curve, _ = dc.parse_args(["--out", str(tmp_path)])
    dev, _ = dc.parse_args(["--out", str(tmp_path), "--dev"])
    assert (curve.demo_seed, curve.eval_seed) == (5601, 5600)
    assert (dev.demo_seed, dev.eval_seed) == (first_config.DEFAULTS_DEV_DEMO_SEED,
                                              first_config.DEFAULTS_DEV_EVAL_SEED) and dev.seed_set == "dev"
    (tmp_path / "config.json").write_text(json.dumps(asdict(curve)))
    with pytest.raises(SystemExit, match="demo_seed"):
        first_config.check_resume(dev, tmp_path, dc.SAME_ON_RESUME)
    assert Q.part_paths(dev, "wipe", 2)[0].name == "wipe-sim-piper-seed5703.mcap"


def test_the_sized_rule_maps_demonstrations_to_factr2_train_flags(tmp_path):
    """Below SIZED_BELOW: noise on the low-dimensional inputs and dropout, parsed by factr2 train's flags;
    from it on: exactly the current defaults; OUT's record of the rule is its flags at every probed size."""
    import argparse

    from bench import data_curve_defaults as D
    from policies.training.run_config import add_arguments, from_args

    ap = argparse.ArgumentParser()
    add_arguments(ap)
    cfg = _cfg(tmp_path, defaults="sized")
    small = from_args(ap.parse_args(dc.train_argv(cfg, [tmp_path], ["x.mcap#0"] * 50, 0, tmp_path / "r")))
    assert small.train.obs_noise == {"state": 0.05, "objects": 0.05, "force": 0.1} and small.dropout == 0.1
    big = dc.train_argv(cfg, [tmp_path], ["x.mcap#0"] * D.SIZED_BELOW, 0, tmp_path / "r")
    assert big == dc.train_argv(_cfg(tmp_path), [tmp_path], ["x.mcap#0"] * D.SIZED_BELOW, 0, tmp_path / "r")
    meta = dc.defaults_meta("sized")
    assert set(meta) == {f"n{n}" for n in D.RULE_PROBE}
    assert meta["n200"] == dc.defaults_meta("current") and meta["n50"]["train"]["obs_noise"]
    assert "obs_noise" not in dc.defaults_meta("current")["train"]  # an OUT from before the option resumes
    for name in D.DEFAULTS:  # every named set parses as factr2 train flags at every probed size
        for n in D.RULE_PROBE:
            from_args(ap.parse_args(["D", "--out", "R", "--obs", "state", *D.defaults_flags(name, n)]))


def test_demos_from_trains_on_another_outs_collection_and_collects_nothing(tmp_path):
    src = _cfg(tmp_path / "src")
    _write_part(src, 0, "sss")
    _write_part(src, 1, "sss")
    (tmp_path / "src" / "config.json").write_text(json.dumps(asdict(src)))
    cfg = _cfg(tmp_path / "dst", demos_from=str(tmp_path / "src"), defaults="noise")
    dc.check_demos_from(cfg)
    st = Q.State(cfg)
    jobs = [(k, a[:3]) for _, k, a in st.ready(set())]
    assert jobs == [("train", ("wipe", 2, 0)), ("train", ("wipe", 4, 0))]
    assert st.subset("wipe", 4)[0] == [Q.part_dir(tmp_path / "src", "wipe", 0),
                                       Q.part_dir(tmp_path / "src", "wipe", 1)]
    with pytest.raises(SystemExit, match="demo_seed"):
        dc.check_demos_from(_cfg(tmp_path / "dst", demos_from=str(tmp_path / "src"), demo_seed=5701))


def test_perturb_collects_every_part_perturbed_and_trains_with_perturbed_dart(tmp_path, monkeypatch):
    """--perturb SPEC: factr2 collect's PerturbConfig reaches every part's collection, on the curve's seeds
    (paired with its points), and `--perturbed dart` is in the recorded train flags and factr2 train's
    options."""
    import argparse

    import factr2_teleop.tasks.run as task_run
    from bench.data_curve_config import QUICK
    from factr2_teleop.teleop.perturb import PerturbConfig
    from policies.training.run_config import add_arguments, from_args

    cfg, _ = dc.parse_args(["--out", str(tmp_path), "--tasks", "wipe", "--points", "2",
                            "--perturb", "amplitude_rad=0.03,joints=0+1"])
    assert cfg.perturb == PerturbConfig(amplitude_rad=0.03, joints=(0, 1)).to_dict()
    assert (cfg.demo_seed, cfg.eval_seed) == (first_config.DATA_CURVE_DEMO_SEED,
                                              first_config.DATA_CURVE_EVAL_SEED)
    assert cfg.train_flags == ["--perturbed", "dart"]
    assert dc.parse_args(["--out", str(tmp_path), "--perturb"])[0].perturb == PerturbConfig().to_dict()
    quick, _ = dc.parse_args(["--out", str(tmp_path), "--quick", "--perturb"])
    assert quick.train_flags == [*QUICK["train_flags"], "--perturbed", "dart"]
    assert "--perturbed" not in QUICK["train_flags"]  # QUICK's own list is left alone
    seen = []
    monkeypatch.setattr(task_run, "collect", lambda cc, progress=False: seen.append(cc) or {"results": []})
    dc.collect_part(cfg, "wipe", 1)
    assert seen[0].perturb == PerturbConfig(amplitude_rad=0.03, joints=(0, 1))
    assert seen[0].seed == first_config.DATA_CURVE_DEMO_SEED + 1 and seen[0].task == "wipe"
    dc.collect_part(dc.parse_args(["--out", str(tmp_path / "plain"), "--tasks", "wipe", "--points", "2"])[0],
                    "wipe", 1)
    assert seen[1].perturb is None
    ap = argparse.ArgumentParser()
    add_arguments(ap)
    argv = dc.train_argv(cfg, [tmp_path], ["x.mcap#0"], 0, tmp_path / "run")
    assert argv[argv.index("--perturbed") + 1] == "dart"
    assert from_args(ap.parse_args(argv)).perturbed == "dart"
    assert dc.build_results(cfg, "CMD")["train_flags"]["2"] == ["--perturbed", "dart"]


def test_a_perturbed_out_is_never_resumed_as_an_unperturbed_one_nor_back(tmp_path):
    plain, _ = dc.parse_args(["--out", str(tmp_path)])
    pert, _ = dc.parse_args(["--out", str(tmp_path), "--perturb"])
    (tmp_path / "config.json").write_text(json.dumps(asdict(plain)))
    with pytest.raises(SystemExit, match="perturb"):
        first_config.check_resume(pert, tmp_path, dc.SAME_ON_RESUME)
    (tmp_path / "config.json").write_text(json.dumps(asdict(pert)))
    with pytest.raises(SystemExit, match="perturb"):
        first_config.check_resume(plain, tmp_path, dc.SAME_ON_RESUME)
    first_config.check_resume(pert, tmp_path, dc.SAME_ON_RESUME)  # the same: resumes
    old = {k: v for k, v in asdict(plain).items() if k != "perturb"}  # an OUT from before the option
    (tmp_path / "config.json").write_text(json.dumps(old))
    first_config.check_resume(plain, tmp_path, dc.SAME_ON_RESUME)
    src = _cfg(tmp_path / "src")
    (tmp_path / "src").mkdir()
    (tmp_path / "src" / "config.json").write_text(json.dumps(asdict(src)))
    with pytest.raises(SystemExit, match="perturb"):  # nor trained on an unperturbed collection
        dc.check_demos_from(_cfg(tmp_path / "dst", demos_from=str(tmp_path / "src"), perturb={"x": 1}))


def test_against_pairs_each_point_with_the_other_outs_on_the_same_episodes(tmp_path):
    from bench.data_curve_report import paired_points

    a, b = _cfg(tmp_path / "a", perturb={}), _cfg(tmp_path / "b")
    _finish(a, 2, 0, [1, 1, 0, 1])
    _finish(b, 2, 0, [1, 0, 0, 0])
    _finish(b, 4, 0, [1, 1, 1, 1])  # no such point in a: not paired
    (Path(b.out) / "config.json").write_text(json.dumps(asdict(b)))  # a data_curve OUT
    p = paired_points(finished_rows(a.out), finished_rows(b.out))
    assert list(p) == ["wipe"] and list(p["wipe"]) == [2]
    q = p["wipe"][2]
    assert (q["both"], q["only_this"], q["only_other"], q["neither"], q["pairs"]) == (1, 2, 0, 1, 4)
    assert q["this"] == [3, 4, *wilson(3, 4)] and q["other"] == [1, 4, *wilson(1, 4)]
    assert q["mcnemar_p"] == pytest.approx(0.5)  # 2 discordant pairs, both one way: 2 * (1/2)^2
    res = dc.write_outputs(a, chart_too=False, command="CMD", against=b.out)
    assert res["against"]["paired"]["wipe"]["2"]["only_this"] == 2
    md = (Path(a.out) / "data_curve.md").read_text()
    assert "exact McNemar p" in md and "| wipe | 2 | 4 |" in md
