"""`factr2 recover FILE` by hand makes a session summary beside FILE say what the rewritten file holds, as the
session's own read-back does (session/read_back.py); bad input gets one line, exit 2, and nothing changed."""

from __future__ import annotations

import json
import shutil

import pytest
from recording_helpers import stalled_two_episodes

from factr2_teleop.cli import main as cli_main

STAGES = {"reach": 0.1, "grasp": 0.15}


@pytest.fixture(scope="module")
def killed(tmp_path_factory):
    """A two-episode file as a killed session leaves it (truncated: copied while its writer was stopped):
    episode 0 whole, episode 1 to its "reach" mark, without its stop."""
    folder = tmp_path_factory.mktemp("killed")
    stalled_two_episodes(folder / "session.mcap", copy_to=folder / "killed.mcap")
    return folder / "killed.mcap"


def _live(n: int = 3) -> list[dict]:
    """n episodes judged success live, each through both stages."""
    return [{"index": e, "seed": e, "outcome": "success", "progress": 1.0, "stages": dict(STAGES),
             "duration_s": 0.2} for e in range(n)]


def _session(tmp_path, killed):
    """The killed file in a folder of its own, collect's summary beside it (its stem + .json) and a rollout's
    --json naming it (from another working folder), both written with the live verdicts."""
    mcap = tmp_path / "wipe-sim-piper-seed0.mcap"
    shutil.copyfile(killed, mcap)
    collect = {"task": "wipe", "episodes": 3, "success_rate": 1.0, "progress_mean": 1.0,
               "recording": f"demos/{mcap.name}", "recording_error": None, "results": _live()}
    rollout = {"success_rate": 1.0, "mean_progress": 1.0, "stage_rates": {"reach": 1.0, "grasp": 1.0},
               "recording": str(mcap), "episodes": _live(), "takeover": {"per_episode": [0, 1, 0],
                                                                         "autonomous_successes": 2}}
    paths = mcap.with_suffix(".json"), tmp_path / "rollout.json"
    for path, summary in zip(paths, (collect, rollout)):
        path.write_text(json.dumps(summary))
    (tmp_path / "other.json").write_text("[1, 2")  # not a summary of it: left alone
    return mcap, paths


def test_recover_updates_the_summaries_beside_the_file(tmp_path, killed, capsys):
    """Before, `factr2 recover` left a summary beside the file saying what was judged live; it now says what
    the recovered file holds, as the session's read-back would have (the rates over the two episodes the file
    holds, episode 1 incomplete at its mark, episode 2 missing), in one line per summary; again: unchanged."""
    mcap, (collect, rollout) = _session(tmp_path, killed)
    assert cli_main(["recover", str(mcap), "--in-place"]) == 0
    out = capsys.readouterr().out
    assert (f"summary {collect}: episode 1 incomplete (judged success), 2 missing (judged success); "
            "success rate 1.00 -> 0.50; task progress 1.00 -> 0.75") in out
    c, r = json.loads(collect.read_text()), json.loads(rollout.read_text())
    assert (c["success_rate"], c["progress_mean"], c["episodes_in_file"]) == (0.5, 0.75, 2)
    assert c["recording_recovered"] and c["episodes_not_as_judged"] == [1, 2]
    assert [(e["outcome"], e["progress"], e.get("outcome_judged")) for e in c["results"]] == [
        ("success", 1.0, None), ("incomplete", 0.5, "success"), ("missing", 0.0, "success")]
    assert c["results"][1]["stages"] == {"reach": 0.05, "grasp": None}
    assert c["results"][1]["stages_judged"] == STAGES and c["results"][1]["progress_judged"] == 1.0
    assert (r["success_rate"], r["mean_progress"]) == (0.5, 0.75)
    assert r["stage_rates"] == {"reach": 1.0, "grasp": 0.5} and r["takeover"]["autonomous_successes"] == 1
    assert r["episodes"] == c["results"]
    assert (tmp_path / "other.json").read_text() == "[1, 2"
    assert cli_main(["recover", str(mcap), "--in-place"]) == 0  # read back again: the live verdict stays
    assert f"summary {collect}: already said what the file holds" in capsys.readouterr().out
    assert json.loads(collect.read_text()) == c


def test_a_recovered_copy_is_what_the_summary_then_names(tmp_path, killed, capsys):
    mcap, (collect, _rollout) = _session(tmp_path, killed)
    assert cli_main(["recover", str(mcap), "--summary", str(collect)]) == 0
    c = json.loads(collect.read_text())
    assert c["recording"] == "demos/wipe-sim-piper-seed0.recovered.mcap" and c["success_rate"] == 0.5
    assert mcap.read_bytes() == killed.read_bytes()  # the damaged file stays as it was
    assert "recording -> demos/wipe-sim-piper-seed0.recovered.mcap" in capsys.readouterr().out


@pytest.mark.parametrize("case, message", [
    ("named summary missing", "cannot read the summary"),
    ("summary not JSON", "the summary is not JSON"),
    ("not a session summary", "not a session summary"),
    ("garbage recording", "not an MCAP file"),
])
def test_bad_input_is_one_line_and_changes_nothing(tmp_path, killed, capsys, case, message):
    mcap, (collect, _rollout) = _session(tmp_path, killed)
    argv = ["recover", str(mcap), "--in-place"]
    if case == "named summary missing":
        argv += ["--summary", str(tmp_path / "nope.json")]
    elif case == "summary not JSON":
        collect.write_text('{"results": [')
    elif case == "not a session summary":
        collect.write_text(json.dumps({"recording": mcap.name, "results": [{"index": "a"}]}))
    else:
        mcap.write_bytes(b"hello, not a recording at all")
    before = {p: p.read_bytes() for p in tmp_path.iterdir()}
    assert cli_main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and "Traceback" not in err
    assert {p: p.read_bytes() for p in tmp_path.iterdir()} == before  # the recording and summaries kept


def test_without_a_summary_the_file_alone_is_recovered(tmp_path, killed, capsys):
    mcap = tmp_path / "alone.mcap"
    shutil.copyfile(killed, mcap)
    assert cli_main(["recover", str(mcap), "--in-place"]) == 0
    assert f"no session summary beside {mcap} names it: none updated" in capsys.readouterr().out
    mcap2, (collect, _rollout) = _session(tmp_path, killed)
    kept = collect.read_bytes()
    assert cli_main(["recover", str(mcap2), "--in-place", "--no-summary"]) == 0
    assert collect.read_bytes() == kept
