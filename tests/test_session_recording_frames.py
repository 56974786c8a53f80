"""A recording whose first episode starts the cameras writes every frame the cameras capture: the episode
opens first, so a frame captured as the cameras start (before the opening returned) lies in the episode. The
other way round, such a frame was counted by the camera stream and not written (`factr2 teleop --record`: 60
frames in the file against 61 counted)."""

from __future__ import annotations

import itertools
from types import SimpleNamespace

import numpy as np

from factr2_teleop.session.recording import SessionRecording


class FakeRecorder:
    lossless = True

    def __init__(self):
        self.episodes, self.images = [], []

    def start_episode(self, t, task=""):
        self.episodes.append((t, task))
        return len(self.episodes) - 1

    def stop_episode(self, t, outcome=None, text=""):
        pass

    def log_image(self, camera, t, rgb):
        self.images.append((camera, t))

    def log_batch(self, items):
        return True

    def close(self):
        return None


def _recording():
    """A SessionRecording on a clock that moves 1 ms each time it is read, whose cameras deliver one frame
    stamped at their start, before start() returns (a twin camera's first snapshot on the stepping thread)."""
    ticks = itertools.count()
    clock = SimpleNamespace(now=lambda: 1e-3 * next(ticks), realtime=True)
    session = SimpleNamespace(twin=None, clock=clock)
    captured = []

    def start_cameras():
        if not captured:  # once: later episodes find them running
            captured.append(clock.now())
            rec.frame("scene", captured[-1], np.zeros((2, 2, 3), np.uint8))
        return []

    rec = SessionRecording(FakeRecorder(), session, [], 500.0, start_cameras=start_cameras)
    return rec, captured


def test_frames_captured_as_the_first_episode_starts_the_cameras_are_written():
    rec, captured = _recording()
    rec.start_episode("teleop")
    rec.frame("scene", rec.session.clock.now(), np.zeros((2, 2, 3), np.uint8))  # a later frame
    rec.close()
    (t0, _), = rec.recorder.episodes
    assert len(captured) == 1 and captured[0] >= t0
    assert [t for _, t in rec.recorder.images] == [captured[0], rec.recorder.images[1][1]]  # both written


def test_frames_between_episodes_are_not_written():
    rec, _ = _recording()
    rec.start_episode("a")
    rec.stop_episode("success")
    rec.frame("scene", rec.session.clock.now(), np.zeros((2, 2, 3), np.uint8))  # between episodes
    rec.start_episode("b")
    rec.close()
    assert len(rec.recorder.images) == 1  # the one captured as the cameras started, in episode a
