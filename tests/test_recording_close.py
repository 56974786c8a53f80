"""Closing a recording on a busy machine: the recorder waits for its writer as long as it makes progress
(a fixed 30 s cut the end off a press-fit collection at load 12-14), gives up only on a writer that makes
none, says so in one line and recovers the file in place so that it reads to its last complete record."""

from __future__ import annotations

import os
import signal
import time
import warnings

import numpy as np
from machine_speed import budget
from recording_helpers import flushed_recorder, joint_state, stalled_two_episodes

from hardware.recording import Recorder, Recording


def test_a_slow_writer_is_waited_for_and_the_file_is_complete(tmp_path):
    """The writer sleeps 6 ms per record (test hook): draining 1000 records takes >= 6 s, several times the
    stall limit, yet it progresses all along, so nothing is cut."""
    rec = Recorder(tmp_path / "slow.mcap", t0=0.0, lossless=True, writer_delay_s=0.006)
    rec.start_episode(0.0)
    deadline = time.monotonic() + budget(20.0)
    while rec.status().messages_written < 1 and time.monotonic() < deadline:
        time.sleep(0.01)  # the writer has started (its imports are no progress to wait on)
    n = 1000
    assert all(rec.log_joint_state("follower", k * 1e-3, joint_state(k)) for k in range(n))
    rec.stop_episode(n * 1e-3, "success")
    t = time.monotonic()
    st = rec.close(1.0)
    assert time.monotonic() - t >= 1.5  # it did wait past the stall limit
    assert st.error is None, st.error
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a truncated file warns
        got = Recording(tmp_path / "slow.mcap", use_cache=False)
        assert len(got.topic("/follower/joint_state")) == n
        assert [e.outcome for e in got.episodes] == ["success"]


def test_a_stalled_writer_is_given_up_on_and_the_file_recovered(tmp_path):
    """A writer that makes no progress at all (stopped): close() gives up after the stall limit, says so in
    one line, and the file is recovered in place (valid, indexed, what was flushed kept)."""
    rec = flushed_recorder(tmp_path / "stuck.mcap")
    os.kill(rec._proc.pid, signal.SIGSTOP)
    t = time.monotonic()
    st = rec.close(0.5)
    assert time.monotonic() - t < budget(5.0)
    assert st.error and "\n" not in st.error and "no progress for" in st.error and "recovered" in st.error
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = Recording(tmp_path / "stuck.mcap", use_cache=False).topic("/follower/joint_state")
    assert len(got) >= 150 and np.all(np.diff(got.t) > 0)


def _stopped_while_starting(path) -> Recorder:
    """A recorder whose writer process is stopped before it has started (its state still STARTING)."""
    import pytest

    from hardware.recording import writer_process as W

    rec = Recorder(path, t0=0.0, flush_interval_s=0.02)
    os.kill(rec._proc.pid, signal.SIGSTOP)  # microseconds after the spawn; its start-up takes >= tens of ms
    if rec._status.get(W.W_STATE) != W.STARTING:
        os.kill(rec._proc.pid, signal.SIGCONT)
        rec.close()
        pytest.skip("the writer started before it could be stopped")
    return rec


def test_the_stall_clock_starts_when_the_writer_has_started(tmp_path):
    """A writer still starting at close (a new interpreter's imports on a loaded machine) is waited for: its
    start-up is no stall. Stopped for 1.5 s before it started, three times the stall limit, it is not cut."""
    import threading

    rec = _stopped_while_starting(tmp_path / "late.mcap")
    n = 100
    rec.start_episode(0.0)
    assert all(rec.log_joint_state("follower", k * 1e-3, joint_state(k)) for k in range(n))
    rec.stop_episode(n * 1e-3, "success")
    threading.Timer(1.5, os.kill, (rec._proc.pid, signal.SIGCONT)).start()
    t = time.monotonic()
    st = rec.close(0.5)
    assert time.monotonic() - t >= 1.4
    assert st.error is None and not st.recovered, st.error
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = Recording(tmp_path / "late.mcap", use_cache=False)
        assert len(got.topic("/follower/joint_state")) == n
        assert [e.outcome for e in got.episodes] == ["success"]


def test_a_writer_that_never_starts_is_given_up_on_after_the_start_limit(tmp_path):
    rec = _stopped_while_starting(tmp_path / "never.mcap")
    t = time.monotonic()
    st = rec.close(0.3, start_s=1.0)
    assert 1.0 <= time.monotonic() - t < budget(5.0)
    assert st.error and "\n" not in st.error and "did not start in 1 s" in st.error and not st.recovered


def test_the_collection_summary_says_what_the_recovered_file_holds(tmp_path):
    """The writer stalls before episode 1's stop reached the file: the file's episode 1 reads "incomplete";
    the collection summary's outcome for it says so (the live verdict kept as outcome_judged), and the
    summary's lines say it."""
    from factr2_teleop.session.read_back import agree_with_file, file_episodes
    from factr2_teleop.tasks.run import summary_lines

    path = tmp_path / "two.mcap"
    st = stalled_two_episodes(path)
    results = [{"index": 0, "outcome": "success"}, {"index": 1, "outcome": "success"}]
    recorded = file_episodes(path)
    assert {i: e.outcome for i, e in recorded.items()} == {0: "success", 1: "incomplete"}
    assert agree_with_file(results, recorded) == [1]
    assert results == [{"index": 0, "outcome": "success"},
                       {"index": 1, "outcome": "incomplete", "outcome_judged": "success"}]
    assert agree_with_file([{"index": 2, "outcome": "failure"}], recorded) == [2]  # never reached the file
    out = {"task": "wipe", "rig": "sim-piper", "mode": "next", "seed": 0, "episodes": 2, "success_rate": 0.5,
           "progress_mean": 1.0, "episode_s_mean": 1.0, "episode_s_min": 1.0, "episode_s_max": 1.0,
           "retries_mean": 0.0, "phase_shares": None, "wall_s": 1.0, "sim_s": 1.0, "x_realtime": 1.0,
           "recording": str(path), "frames_written": 0, "samples_dropped": 0, "recording_error": st.error,
           "results": results, "episodes_not_as_judged": [1]}
    assert any("episode 1 incomplete (judged success)" in ln for ln in summary_lines(out))


def _live(n: int, stages: dict) -> list:
    """n episodes judged success live (progress 1), each reaching `stages` (stage -> s from its start)."""
    from factr2_teleop.session.task_episodes import EpisodeResult

    return [EpisodeResult(index=e, seed=e, outcome="success", progress=1.0, stages=dict(stages),
                          duration_s=0.2, retries=0, felt=0, gave_up=False, t_start=0.5 * e,
                          t_end=0.5 * e + 0.2) for e in range(n)]


def _rollout_lines(path, eps: dict) -> list[str]:
    """The printed summary of a rollout whose episode fields are `eps` (episode_summary), recorded in path."""
    from factr2_teleop.commands.rollout import summary_lines
    from factr2_teleop.session.rollout_report import RolloutResult, timing_summary

    timing = timing_summary([0.002], [], [], False, 500.0)
    timing.update(commands_sent=0, command_violations=0, refused_nonfinite=0, refused_outside_limits=0,
                  holds={})
    return summary_lines(RolloutResult(
        simulated=True, rig="sim-piper", task="wipe", policy="RUN", policy_kind="act", method=None,
        schedule="receding", k_exec=10, ensemble_m=None, seed=0, feedback_mode="next", next=None, note="",
        lean=False, interrupted=False, wall_s=1.0, recording=str(path), timing=timing, **eps))


def test_the_rollout_summary_says_what_the_recovered_file_holds(tmp_path):
    """The same stalled file under a policy rollout: the rollout's episodes, success rate (over what the file
    holds), takeover count and printed summary say episode 1 is "incomplete", judged success live."""
    from factr2_teleop.session.rollout_report import episode_summary

    path = tmp_path / "two.mcap"
    st = stalled_two_episodes(path)
    live = _live(2, {"reach": 0.1})
    eps = episode_summary(live, ("reach",), str(path), st)
    assert [r.outcome for r in eps.pop("as_recorded")] == ["success", "incomplete"]
    assert eps["success_rate"] == 0.5 and eps["stage_rates"] == {"reach": 1.0}
    assert eps["episodes_not_as_judged"] == [1] and eps["recording_recovered"]
    assert eps["recording_unread"] is None and "recovered" in eps["recording_error"]
    assert [(e["outcome"], e.get("outcome_judged")) for e in eps["episodes"]] == [("success", None),
                                                                                  ("incomplete", "success")]
    assert episode_summary(live, (), None, None)["success_rate"] == 1.0  # nothing recorded: as judged
    lines = _rollout_lines(path, eps)
    assert any("1 / 2 = 50.0 %" in ln for ln in lines)
    assert any("episode 1 incomplete (judged success): counted as the file holds them" in ln for ln in lines)


def test_the_summary_rates_are_over_what_the_recovered_file_holds(tmp_path):
    """Three episodes judged success live, each through both stages (progress 1): the stalled file holds
    episode 0 whole, episode 1 to its "reach" mark (progress 0.5, "incomplete") and not episode 2 ("missing").
    The rollout summary's success rate, mean progress and stage rates are over the two episodes the file
    holds, each as the file holds it (what `factr2 episodes` shows), the live verdict kept beside it; the
    collection's rates come from the same function."""
    from factr2_teleop.session.read_back import episode_rates
    from factr2_teleop.session.rollout_report import episode_summary

    path = tmp_path / "two.mcap"
    st = stalled_two_episodes(path)
    live = _live(3, {"reach": 0.1, "grasp": 0.15})
    eps = episode_summary(live, ("reach", "grasp"), str(path), st)
    eps.pop("as_recorded")
    assert eps["success_rate"] == 0.5 and eps["mean_progress"] == 0.75
    assert eps["stage_rates"] == {"reach": 1.0, "grasp": 0.5} and eps["episodes_in_file"] == 2
    assert eps["episodes_not_as_judged"] == [1, 2]
    got = [(e["outcome"], e["progress"], e["stages"]) for e in eps["episodes"]]
    assert got == [("success", 1.0, {"reach": 0.1, "grasp": 0.15}),
                   ("incomplete", 0.5, {"reach": 0.05, "grasp": None}),
                   ("missing", 0.0, {"reach": None, "grasp": None})]
    assert [(e.get("progress_judged"), e.get("stages_judged")) for e in eps["episodes"]][1:] == \
        [(1.0, {"reach": 0.1, "grasp": 0.15})] * 2
    assert episode_rates(eps["episodes"])["mean_progress"] == 0.75  # collect's progress_mean
    nothing = episode_summary(live, ("reach", "grasp"), None, None)  # nothing recorded: as judged
    assert (nothing["success_rate"], nothing["mean_progress"], nothing["stage_rates"]) == \
        (1.0, 1.0, {"reach": 1.0, "grasp": 1.0})
    lines = _rollout_lines(path, eps)
    assert any("3  (2 in the file: the rates are over those)" in ln for ln in lines)
    assert any("1 / 2 = 50.0 %" in ln for ln in lines) and any("0.75" in ln for ln in lines)
