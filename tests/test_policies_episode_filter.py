"""Which episodes train: failed demonstrations and episodes cut off by a killed recorder are skipped by
default, said in one line and recorded in the run's meta; --include-failed / --keep-incomplete keep them;
episodes without a verdict (teleop without a task) train."""

from __future__ import annotations

import pytest

from factr2_teleop.cli import main
from policies.data.recordings import load_episodes, skipped_line, training_episodes
from policies.training import checkpoint as C
from tests.policy_helpers import write_recording
from tests.test_policies_inputs import FAST, _one_line_error


@pytest.fixture(scope="module")
def mixed(tmp_path_factory):
    d = tmp_path_factory.mktemp("mixed")
    # the incomplete episode last: it ends at the file's last sample, as a killed recorder's does
    outcomes = ["success", "failure", None, "incomplete"]
    write_recording(d / "a.mcap", episodes=4, seconds=2.0, outcomes=outcomes)
    return d


def test_failed_and_incomplete_are_skipped_unless_asked(mixed):
    eps, _ = load_episodes([mixed])
    assert [e.outcome for e in eps] == ["success", "failure", "unlabelled", "incomplete"]
    kept, skipped = training_episodes(eps)
    assert [e.outcome for e in kept] == ["success", "unlabelled"]
    assert skipped == [{"episode": "a.mcap#1", "why": "failed"}, {"episode": "a.mcap#3", "why": "incomplete"}]
    line = skipped_line(skipped)
    assert line == ("skipped 1 failed episode (--include-failed keeps them), 1 incomplete episode "
                    "(recording cut off; --keep-incomplete keeps them)")
    assert len(training_episodes(eps, include_failed=True)[0]) == 3
    assert len(training_episodes(eps, include_failed=True, keep_incomplete=True)[0]) == 4
    assert skipped_line([]) == ""


def _train(capsys, *args):
    rc = main(["train", *map(str, args)])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def test_train_says_what_it_skipped_and_records_it(mixed, tmp_path, capsys):
    run = tmp_path / "run"
    rc, out, err = _train(capsys, mixed, "--out", run, "--thresholds", "1:3", *FAST)
    assert rc == 0, err
    said = [ln for ln in out.splitlines() if ln.startswith("skipped ")]
    assert len(said) == 1 and "1 failed" in said[0] and "1 incomplete" in said[0], out
    meta = C.read_meta(C.last_checkpoint(run))
    assert sorted(meta["episodes"]) == ["a.mcap#0", "a.mcap#2"]
    assert meta["skipped_episodes"] == [{"episode": "a.mcap#1", "why": "failed"},
                                        {"episode": "a.mcap#3", "why": "incomplete"}]
    assert meta["include_failed"] is False and meta["keep_incomplete"] is False

    run2 = tmp_path / "run2"
    rc, out, err = _train(capsys, mixed, "--out", run2, "--thresholds", "1:3", "--include-failed",
                          "--keep-incomplete", *FAST)
    assert rc == 0, err
    assert not [ln for ln in out.splitlines() if ln.startswith("skipped ")]
    meta = C.read_meta(C.last_checkpoint(run2))
    assert len(meta["episodes"]) == 4 and meta["skipped_episodes"] == []


def test_only_failed_demonstrations_is_one_line_naming_the_flag(tmp_path, capsys):
    write_recording(tmp_path / "rec" / "f.mcap", episodes=2, seconds=1.0, outcomes=["failure", "failure"])
    rc, _, err = _train(capsys, tmp_path / "rec", "--out", tmp_path / "run", "--thresholds", "1:3", *FAST)
    _one_line_error(rc, err, "no episode to train on", "2 failed episodes", "--include-failed")
    assert not (tmp_path / "run").exists()
