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
from recording_helpers import flushed_recorder, joint_state

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
