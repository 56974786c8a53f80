"""SIMULATED camera faults on a twin camera (needs OpenGL, as every twin camera test): a frozen camera
repeats one frame, a gone one fails its renders and renders again once it is back."""

from __future__ import annotations

import numpy as np
import pytest

from hardware.cameras.base import CameraError
from hardware.connect import open_rig
from hardware.sim.faults import parse_fault


@pytest.fixture()
def rig():
    s = open_rig("sim-piper", clock="lockstep", faults=[parse_fault("camera_freeze@0.1:0.1"),
                                                        parse_fault("camera_gone@0.3:0.1")])
    cam = s.cameras["scene"]
    try:
        cam.connect()
    except CameraError as e:
        s.close()
        pytest.skip(f"no OpenGL here: {e}")
    yield s, cam
    s.close()


def _frame(s, cam):
    return cam.render(cam.snapshot(s.clock.now()))


def test_freeze_repeats_one_frame_and_gone_fails_until_back(rig):
    s, cam = rig
    arm = s.followers["follower"]
    arm.hold()
    push = np.array([0.0, 0.0, -60.0])

    def moving(t_s):  # a push keeps the arm moving: consecutive free frames differ
        s.twin.push("link3", push, t_s)
        s.clock.sleep(t_s)

    f0 = _frame(s, cam)
    moving(0.05)
    assert not np.array_equal(f0, _frame(s, cam))  # the push shows: frames of a moving arm differ
    moving(0.07)  # inside the freeze
    f1 = _frame(s, cam)
    moving(0.05)
    f2 = _frame(s, cam)
    assert np.array_equal(f1, f2)
    moving(0.15)  # 0.32 s: gone
    with pytest.raises(CameraError, match="gone"):
        _frame(s, cam)
    moving(0.15)  # 0.47 s: back
    f3 = _frame(s, cam)
    assert f3.shape == f1.shape and not np.array_equal(f3, f1)
    events = [(e["kind"], e["event"]) for e in s.twin.faults.log]
    assert events == [("camera_freeze", "start"), ("camera_freeze", "end"),
                      ("camera_gone", "start"), ("camera_gone", "end")]


def test_frozen_and_gone_camera_are_said_marked_and_used_again_when_back(tmp_path):
    """A teleop run that records with its camera: a freeze and an unplug are detected by frame age (said in
    the loop's messages and noted in the recording), no repeated frame is recorded, and the camera is used
    again once it is back (no restart)."""
    from factr2_teleop.demo.fault_run import run_with_faults
    from hardware.cameras.health import STALE_S

    try:
        out = run_with_faults([parse_fault("camera_freeze@0.4:0.5"), parse_fault("camera_gone@1.1:0.45")],
                              seconds=1.9, record_dir=tmp_path, cameras=True)
    except CameraError as e:  # pragma: no cover
        pytest.skip(f"no OpenGL here: {e}")
    assert out.error is None and out.violations == 0 and out.safe_at_end
    said = [(t, text) for t, who, text in out.messages if who == "cameras"]
    kinds = [text.split(": ")[1] for _, text in said]
    assert [k.split(" ")[0] for k in kinds] == ["frozen", "back", "gone", "back"], said
    assert kinds[1].endswith("(frozen)") and kinds[3].endswith("(gone)")
    assert said[0][0] <= 0.4 + STALE_S + 0.05 and said[2][0] <= 1.1 + STALE_S + 0.05  # within the age bound
    rc = out.recording
    assert rc.opens and rc.lost_before_fault == 0
    assert [n for n in rc.notes if n.startswith("camera")] == [text for _, text in said]
    from hardware.recording.reader import Recording

    rec = Recording(rc.path, use_cache=False, write_cache=False)
    (cam,) = rec.cameras
    t = rec.frames(cam).t
    assert np.all(np.diff(t) > 0)  # no frame twice
    assert t[-1] > 1.6  # frames again after the unplug


def test_camera_health_by_frame_age_is_pure():
    from hardware.cameras.health import STALE_S, CameraHealth

    h = CameraHealth("c", 0.0)
    assert h.frame(0.0, 0.0) and h.frame(0.1, 0.1)  # the first frame at the start time is fresh
    assert not h.frame(0.2, 0.1) and h.take_events() == []  # a repeat: not passed on, not yet stale
    assert not h.frame(0.1 + STALE_S + 0.01, 0.1)
    (ev,) = h.take_events()
    assert ev[0] == 0.1 + STALE_S + 0.01 and "frozen" in ev[1] and h.state == "frozen"
    assert h.frame(0.6, 0.6) and "back after 0.50 s" in h.take_events()[0][1]
    h.failed(0.7, "CameraError: x")
    h.failed(0.6 + STALE_S + 0.01, "CameraError: x")
    assert h.state == "gone" and h.outages == 2 and h.stale == 2
