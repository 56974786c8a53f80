"""The recording's packing thread in simulated time: the loop waits for it (at most SIM_BACKLOG_S behind), so
that a SIGKILL of the app loses no more than that; real time never waits (its backlog grows instead)."""

from __future__ import annotations

import time
from types import SimpleNamespace

import numpy as np
import pytest

from factr2_teleop.session.recording import SIM_BACKLOG_S, SessionRecording
from factr2_teleop.teleop.record import TickRecord


class SlowRecorder:
    """A recorder whose hand-over takes 1 ms a tick (a starved writer's ring, a busy machine)."""

    def __init__(self, lossless: bool):
        self.lossless = lossless
        self.batches = 0

    def log_batch(self, items) -> bool:
        time.sleep(0.001)
        self.batches += 1
        return True

    def close(self):
        return None


def _tick(k: int, rate_hz: float) -> TickRecord:
    z = np.zeros(2)
    return TickRecord(t=k / rate_hz, pair="arm", phase="coupled", leader=None, follower=None,
                      leader_tau_cmd=None, tau_ext=z, action_q=None)


class CountingTime:
    """The recording module's `time`, counting the loop's waits for the packer (not the wall time they took:
    a slow or busy machine stretches that, #53)."""

    def __init__(self):
        self.waits = 0

    def __getattr__(self, name):
        return getattr(time, name)

    def sleep(self, s: float) -> None:
        self.waits += 1
        time.sleep(s)


@pytest.mark.parametrize("lossless", [True, False])
def test_simulated_time_keeps_the_packer_close_real_time_never_waits(lossless, monkeypatch):
    import factr2_teleop.session.recording as recording

    clock = CountingTime()
    monkeypatch.setattr(recording, "time", clock)
    rate_hz, n = 500.0, 300
    pair = SimpleNamespace(cfg=SimpleNamespace(name="arm"), follower=SimpleNamespace(n_joints=2))
    session = SimpleNamespace(twin=None, clock=SimpleNamespace(now=lambda: 0.0))
    rec = SessionRecording(SlowRecorder(lossless), session, [pair], rate_hz)
    rec.recording = True
    worst = 0
    for k in range(n):
        rec.on_tick(_tick(k, rate_hz))
        rec.hand_over()  # as the loop goes to sleep
        worst = max(worst, rec._backlog)
    waits = clock.waits
    rec.recording = False
    rec.close()
    assert rec.recorder.batches == n  # every tick packed in the end
    if lossless:
        assert worst <= SIM_BACKLOG_S * rate_hz and waits > 0  # a SIGKILL loses at most SIM_BACKLOG_S
    else:
        assert worst > SIM_BACKLOG_S * rate_hz and waits == 0  # never waited for the packer
