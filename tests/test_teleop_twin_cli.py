"""`factr2 teleop` on the twin (SIMULATED, real time, 1 s): runs, ends safe, prints timing; bad input."""

from __future__ import annotations

import re

import numpy as np

from factr2_teleop.cli import main
from factr2_teleop.session.pairs import rig_tables
from hardware.rigs.rig import load_rig


def test_teleop_runs_on_the_twin_and_reports_timing(capsys):
    assert main(["teleop", "--rig", "sim-piper", "--seconds", "1", "--mode", "dob"]) == 0
    out = capsys.readouterr()
    assert "Hz (target 500)" in out.out and "feedback dob (SIMULATED twin)" in out.err


def test_bimanual_rig_gets_one_pair_config_per_pair():
    cfgs, _ = rig_tables(load_rig("sim-bimanual-piper"))
    assert list(cfgs) == ["left", "right"]


def test_teleop_ground_truth_on_real_rig_is_refused(capsys):
    assert main(["teleop", "--rig", "piper", "--mode", "ground_truth", "--seconds", "0.1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "only on simulated rigs" in err[0]


def test_teleop_record_no_cameras_records_no_frames(tmp_path, capsys, monkeypatch):
    """`--record DIR --no-cameras`: the samples, no camera frame (the rig has a scene camera); with the
    cameras, every frame the camera captured, including one delivered the moment capture starts (the episode
    opens before the cameras; opened after them, such a frame was counted and not written). Counted against
    what this machine did (#53): the ticks the loop ran, the frames the camera captured -- not a number of a
    fast core."""
    from hardware.cameras.stream import CameraStream
    from hardware.recording.reader import Recording

    start = CameraStream.start

    def start_with_a_frame_at_once(self):
        start(self)
        name, cam = next(iter(self.cameras.items()))
        t = self.clock.now()
        self._deliver(name, t, np.zeros((cam.config.height, cam.config.width, 3), np.uint8), t)

    monkeypatch.setattr(CameraStream, "start", start_with_a_frame_at_once)
    counts, ticks, captured = {}, {}, {}
    for name, extra in (("without", ["--no-cameras"]), ("with", [])):
        out = tmp_path / name
        assert main(["teleop", "--rig", "sim-piper", "--seconds", "3", "--mode", "dob", "--record",
                     str(out), *extra]) == 0
        printed = capsys.readouterr()
        ticks[name] = int(re.search(r"/ (\d+) ticks", printed.out).group(1))
        cam = re.search(r"camera scene: (\d+) / \d+ frames", printed.err)
        captured[name] = int(cam.group(1)) if cam else 0
        (path,) = out.glob("*.mcap")
        rec = Recording(path, use_cache=False, write_cache=False)
        n_frames = sum(len(rec.frames(c)) for c in rec.cameras)
        n_samples = len(rec.topic("/follower/joint_state").t) if "/follower/joint_state" in rec.topics else 0
        counts[name] = (n_samples, n_frames)
    assert ticks["without"] > 100, ticks
    assert counts["without"][0] >= 0.98 * ticks["without"] and counts["without"][1] == 0, (counts, ticks)
    assert captured["without"] == 0
    assert counts["with"][1] == captured["with"], (counts, captured)  # every captured frame is in the file
