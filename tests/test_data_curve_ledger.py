"""bench/data_curve_ledger.py: a committed results file as the other side of --against and as the seed of a
new OUT (--import-results), on tiny synthetic OUT folders and on the rows of results/data_curve_current.json
(no collection, training or rollout runs)."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import pytest

from bench import data_curve as dc
from bench import data_curve_ledger as L
from bench import data_curve_queue as Q
from bench import harness
from bench.data_curve_defaults import defaults_meta
from bench.data_curve_report import finished_rows, point_dir, row, write_results
from bench.first_ledger import demos_fingerprint
from bench.first_report import wilson
from factr2_teleop.session.task_episodes import episode_seed

ROOT = Path(__file__).resolve().parents[1]
CURVE = ROOT / "results" / "data_curve_current.json"


def _summary(seed: int, outcomes: str, duration: float = 10.0) -> dict:
    return {"seed": seed, "task": "wipe", "wall_s": 1.0, "cpu_s": 1.0,
            "results": [{"index": i, "seed": episode_seed(seed, i), "duration_s": duration,
                         "outcome": "success" if o == "s" else "failure",
                         "progress": 1.0 if o == "s" else 0.5} for i, o in enumerate(outcomes)]}


def _cfg(out: Path, **kw) -> dc.CurveConfig:
    cfg = dc.CurveConfig(**{"out": str(out), "tasks": ["wipe"], "points": {"wipe": [2, 4]}, "seeds": 1,
                            "rollouts": 4, "part_episodes": 3, **kw})
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.json").write_text(json.dumps(asdict(cfg)))
    return cfg


def _part(cfg: dc.CurveConfig, k: int, outcomes: str, duration: float = 10.0) -> None:
    p = Q.part_paths(cfg, "wipe", k)[1]
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(json.dumps(_summary(cfg.demo_seed + k, outcomes, duration)))


def _point(cfg: dc.CurveConfig, n: int, outcomes: list[int], commit: str = "abc1234", eval_seed: int = 0,
           episodes: str = "") -> None:
    run = point_dir(cfg.out, "wipe", n, 0)
    run.mkdir(parents=True, exist_ok=True)
    cmd = f"factr2 train P --episodes {episodes} --out R" if episodes else "factr2 train P --out R"
    (run / "train.json").write_text(json.dumps({
        "task": "wipe", "n_demos": n, "seed": 0, "steps": 100, "batch": 256, "epochs": 80.0, "samples": {},
        "val": {"val/loss": 0.5}, "commit": commit, "defaults": "current", "command": cmd, "advice": [],
        "wall_s": 10.0, "cpu_s": 9.0, "run": str(run)}))
    eps = [{"seed": episode_seed(eval_seed or cfg.eval_seed, i), "outcome": "success" if o else "failure",
            "progress": 1.0 if o else 0.25} for i, o in enumerate(outcomes)]
    (run / "rollout.json").write_text(json.dumps({
        "task": "wipe", "n_demos": n, "seed": 0, "success_rate": sum(outcomes) / len(outcomes),
        "mean_progress": sum(e["progress"] for e in eps) / len(eps), "episodes": eps,
        "stage_rates": {"wipe": sum(outcomes) / len(outcomes)}, "wall_s": 5.0, "cpu_s": 4.0}))


def _export(cfg: dc.CurveConfig, tmp_path: Path, name: str = "dc_test") -> Path:
    res = dc.build_results(cfg, "CMD")
    return write_results(res, name, "CMD", Path(cfg.out), results_dir=tmp_path / "results")


def test_a_committed_row_is_rebuilt_into_the_files_it_was_made_from():
    """Every row of the committed curve, written back as train.json + rollout.json, reads back the same."""
    rows = json.loads(CURVE.read_text())["payload"]["rows"]
    assert rows
    for r in rows:
        assert row(*L.point_files(r, Path("RUN"), "results/x.json")) == r
    assert L.selection(rows[0]["command"]).startswith("peg-insert-sim-piper-seed5601.mcap#0-")


def test_against_takes_a_results_file_by_path_or_name_and_says_the_commits(tmp_path, monkeypatch):
    a, b = _cfg(tmp_path / "a", perturb={}), _cfg(tmp_path / "b")
    _point(a, 2, [1, 1, 0, 1], commit="new9999")
    _point(b, 2, [1, 0, 0, 0], commit="old1111")
    path = _export(b, tmp_path)
    monkeypatch.setattr(harness, "RESULTS", tmp_path / "results")
    for spec in (str(path), "dc_test"):
        res = dc.write_outputs(a, chart_too=False, command="CMD", against=spec)
        ag = res["against"]
        assert ag["kind"] == "results" and ag["written_at"] == json.loads(path.read_text())["commit"]
        q = ag["paired"]["wipe"]["2"]
        assert (q["both"], q["only_this"], q["only_other"], q["neither"]) == (1, 2, 0, 1)
        assert q["this"] == [3, 4, *wilson(3, 4)] and q["mcnemar_p"] == pytest.approx(0.5)
        assert q["trained_at"] == [["new9999"], ["old1111"]] and ag["across_commits"]
    md = (Path(a.out) / "data_curve.md").read_text()
    assert "new9999; old1111 (ACROSS COMMITS)" in md
    _point(a, 2, [1, 1, 0, 1], commit="old1111")
    res = dc.write_outputs(a, chart_too=False, command="CMD", against="dc_test")
    assert not res["against"]["across_commits"]


def test_against_refuses_a_point_rolled_out_on_other_episodes(tmp_path, monkeypatch):
    a, b = _cfg(tmp_path / "a"), _cfg(tmp_path / "b")
    _point(a, 2, [1, 1, 0, 1])
    _point(b, 2, [1, 0, 0], eval_seed=5601)  # another rollout seed, another count
    monkeypatch.setattr(harness, "RESULTS", tmp_path / "results")
    _export(b, tmp_path)
    with pytest.raises(SystemExit, match=r"wipe n=2 seed 0 was rolled out on other episodes \(4 episode"):
        dc.write_outputs(a, chart_too=False, command="CMD", against="dc_test")
    with pytest.raises(SystemExit, match="not paired"):
        dc.write_outputs(a, chart_too=False, command="CMD", against=b.out)
    for bad, says in (("nothing_here", "no such file"), (str(tmp_path), "no config.json")):
        with pytest.raises(SystemExit, match=says):
            dc.main(["--out", a.out, "--report", "--against", bad])


def test_against_the_committed_curve_pairs_episode_by_episode():
    """An OUT holding the committed press-fit n=50 points with two outcomes flipped, against the curve by its
    name: the flipped episodes are the discordant pairs."""
    rec = json.loads(CURVE.read_text())["payload"]
    rows = [r for r in rec["rows"] if (r["task"], r["n_demos"]) == ("press-fit", 50)]
    mine = [dict(r) for r in rows]
    mine[0]["successes"] = [1 - mine[0]["successes"][0], *mine[0]["successes"][1:]]
    p = dc.paired_points(mine, L.against_side("data_curve_current")["rows"])["press-fit"][50]
    assert p["pairs"] == sum(len(r["successes"]) for r in rows) and p["only_this"] + p["only_other"] == 1
    assert p["trained_at"] == [sorted({r["commit"] for r in rows})] * 2


def test_export_records_each_parts_fingerprint(tmp_path):
    cfg = _cfg(tmp_path / "a")
    _part(cfg, 0, "sfs")
    _part(cfg, 1, "sss")
    res = dc.build_results(cfg, "CMD")
    digest = L.next_digest(cfg)
    assert res["collection"]["wipe"]["part_fingerprints"] == [
        demos_fingerprint(_summary(cfg.demo_seed + k, o), digest) for k, o in ((0, "sfs"), (1, "sss"))]
    assert res["imported"] is None


def _exported_curve(tmp_path: Path, commit: str = "abc1234") -> tuple[dc.CurveConfig, Path]:
    """An OUT with two parts and its 2-point finished, exported to tmp_path/results/dc_test.json."""
    src = _cfg(tmp_path / "src")
    _part(src, 0, "sfs")
    _part(src, 1, "sss")
    st = Q.State(src)
    _point(src, 2, [1, 0, 1, 1], commit=commit, episodes=dc.episode_ranges(st.subset("wipe", 2)[1]))
    return src, _export(src, tmp_path)


def test_import_seeds_a_new_out_and_the_queue_checks_the_recollection(tmp_path):
    src, path = _exported_curve(tmp_path)
    cfg = _cfg(tmp_path / "new")
    lines = L.import_points(cfg, str(path), here="abc1234")
    assert lines[0].startswith("imported 1 finished point(s)") and "wipe n=2 seed 0" in lines[0]
    assert finished_rows(cfg.out) == finished_rows(src.out)  # the same row, trained nothing
    st = Q.State(cfg)
    assert [(k, a[:3]) for _, k, a in st.ready(set())] == [("collect", ("wipe", 0)), ("collect", ("wipe", 1))]
    _part(cfg, 0, "sfs")  # re-collected the same: the queue goes on to the 4-point
    _part(cfg, 1, "sss")
    assert [(k, a[:3]) for _, k, a in Q.State(cfg).ready(set())] == [("train", ("wipe", 4, 0))]
    assert dc.build_results(cfg, "CMD")["imported"]["points"] == [["wipe", 2, 0, "abc1234"]]
    _part(cfg, 1, "sss", duration=10.5)  # the same outcomes, other demonstrations: refused with the reason
    with pytest.raises(SystemExit, match=r"wipe part 01 \(wipe-sim-piper-seed5602.mcap\): re-collected with"):
        Q.State(cfg).ready(set())
    with pytest.raises(SystemExit, match="wipe part 01"):  # nor reported: the points are not this curve's
        dc.build_results(cfg, "CMD")
    assert L.import_points(cfg, str(path), here="abc1234")[0].startswith("imported 0")  # already there


def test_import_refuses_other_settings_and_other_commits_unless_asked(tmp_path):
    _, path = _exported_curve(tmp_path)
    with pytest.raises(SystemExit, match="other settings.*rollouts: 4 there, 8 here"):
        L.import_points(_cfg(tmp_path / "r", rollouts=8), str(path), here="abc1234")
    with pytest.raises(SystemExit, match="other settings.*defaults_meta"):
        L.import_points(_cfg(tmp_path / "m", defaults_meta=defaults_meta("current")), str(path),
                        here="abc1234")
    with pytest.raises(SystemExit, match="trained at abc1234, this is fff0000: --any-commit"):
        L.import_points(_cfg(tmp_path / "c"), str(path), here="fff0000")
    assert not (tmp_path / "c" / "wipe").exists()  # nothing written when refused
    lines = L.import_points(_cfg(tmp_path / "c"), str(path), any_commit=True, here="fff0000-dirty")
    assert lines[0].startswith("imported 1") and any("spans commits" in x for x in lines)
    L.check_imported(L.read_imported(tmp_path / "c"), "fff0000")  # the queue: asked for, taken
    L.import_points(_cfg(tmp_path / "q"), str(path), here="abc1234")
    with pytest.raises(SystemExit, match="trained at abc1234, this is fff0000"):  # imported for abc1234
        L.check_imported(L.read_imported(tmp_path / "q"), "fff0000")
    L.check_imported(L.read_imported(tmp_path / "q"), "abc1234-dirty")
    assert L.same_commit("abc1234-dirty", "abc1234") and L.same_commit("9573a08", "9573a08c")
    assert not L.same_commit("", "") and not L.same_commit("abc1234", "abd1234")


def _legacy(path: Path) -> Path:
    """The exported file as one written before part fingerprints were recorded."""
    rec = json.loads(path.read_text())
    for c in rec["payload"]["collection"].values():
        del c["part_fingerprints"]
    path.write_text(json.dumps(rec))
    return path


def test_results_without_fingerprints_come_in_only_at_their_commit_with_a_warning(tmp_path):
    _, path = _exported_curve(tmp_path)
    _legacy(path)
    with pytest.raises(SystemExit, match="no fingerprint of their collection recorded"):
        L.import_points(_cfg(tmp_path / "c"), str(path), any_commit=True, here="fff0000")
    cfg = _cfg(tmp_path / "new")
    lines = L.import_points(cfg, str(path), here="abc1234")
    assert lines[0].startswith("imported 1") and any(x.startswith("WARNING wipe: ") for x in lines)
    _part(cfg, 0, "sfs")
    _part(cfg, 1, "sss", duration=10.5)  # no fingerprint to see this by
    Q.State(cfg).ready(set())
    _part(cfg, 0, "ssf")  # its first 2 successful episodes are others: refused
    with pytest.raises(SystemExit, match=r"wipe n=2: this collection's first 2 successful episodes are "
                                         r"wipe-sim-piper-seed5601.mcap#0-1, the point trained on "):
        Q.State(cfg).ready(set())
    with pytest.raises(SystemExit, match="wipe n=2"):
        dc.build_results(cfg, "CMD")
    with pytest.raises(SystemExit, match="no fingerprint"):  # nor run on at another commit
        L.check_imported(L.read_imported(cfg.out), "fff0000")


def _curve_mujoco(monkeypatch) -> str:
    """The MuJoCo version the committed curve was collected under, made this process's: the import refuses
    any other (a new MuJoCo may step the twin differently), and the machine's install is not the test."""
    import mujoco

    was = json.loads(CURVE.read_text())["machine"]["mujoco"]
    monkeypatch.setattr(mujoco, "__version__", was)
    return was


def test_the_committed_curve_imports_at_its_commit_and_the_queue_trains_only_the_200_points(tmp_path,
                                                                                          monkeypatch):
    """The aim: at the curve's commit, the 200-demonstration points of peg-insert and press-fit run without
    training the 25/50/100 ones again; under another MuJoCo nothing is imported."""
    import mujoco

    rec = json.loads(CURVE.read_text())["payload"]
    cfg, _ = dc.parse_args(["--out", str(tmp_path), "--tasks", "peg-insert,press-fit",
                            "--points", "25,50,100,200"])
    cfg.defaults_meta = defaults_meta("current")
    was = _curve_mujoco(monkeypatch)
    monkeypatch.setattr(mujoco, "__version__", was + ".other")
    with pytest.raises(SystemExit, match=f"collected under MuJoCo {was}, this is {was}.other"):
        L.import_points(cfg, "data_curve_current", here=rec["rows"][0]["commit"])
    _curve_mujoco(monkeypatch)
    lines = L.import_points(cfg, "data_curve_current", here=rec["rows"][0]["commit"])
    assert lines[0].startswith("imported 12 finished point(s) from results/data_curve_current.json")
    st = Q.State(cfg)
    assert sorted(st.rolled) == sorted((t, n, s) for t in cfg.tasks for n in (25, 50, 100) for s in (0, 1))
    assert {k for _, k, _ in st.ready(set())} == {"collect"}  # the 200 points wait on their collection


def test_import_for_another_checkouts_queue_writes_the_out_and_stops(tmp_path, capsys, monkeypatch):
    """At HEAD, for the frozen tree's queue: the committed wipe points imported and OUT/config.json written
    (what that tree's `python -m bench.data_curve --out OUT ...` resumes), nothing run."""
    import signal

    monkeypatch.setattr(signal, "signal", lambda *a: None)  # main's SIGTERM handler: not in pytest's process
    _curve_mujoco(monkeypatch)
    at = json.loads(CURVE.read_text())["payload"]["rows"][0]["commit"]
    argv = ["--out", str(tmp_path), "--tasks", "wipe", "--points", "25,50", "--import-results",
            "data_curve_current"]
    assert dc.main([*argv, "--import-for-commit", at]) == 0
    assert "imported 4 finished point(s)" in capsys.readouterr().out
    assert len(finished_rows(tmp_path)) == 4 and (tmp_path / "config.json").is_file()
    assert not (tmp_path / "wipe" / "demos").exists()  # nothing collected
    with pytest.raises(SystemExit, match=f"trained at another commit than .* \\(wipe at {at}\\)"):
        L.check_imported(L.read_imported(tmp_path), "fff0000")


def test_import_results_is_refused_with_report(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        dc.parse_args(["--out", str(tmp_path), "--report", "--import-results", "data_curve_current"])
    assert e.value.code == 2 and "--import-results with --report" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        dc.parse_args(["--out", str(tmp_path), "--any-commit"])
    assert "go with --import-results" in capsys.readouterr().err
    with pytest.raises(SystemExit, match="no such file"):
        L.import_points(_cfg(tmp_path / "x"), "no_such_results")
