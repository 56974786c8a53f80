"""`factr2 episodes import gello DIR` (hardware/importers/gello.py) on episodes written to GELLO's documented
layout: one folder per episode of per-step pickles named by the step's wall time (format_obs.save_frame),
and the newer state.npz + meta.json + <view>/NNNNNN.jpg episodes."""

from __future__ import annotations

import datetime as dt
import json
import pickle

import numpy as np
import pytest
from PIL import Image

from factr2_teleop.cli import main
from hardware.importers.gello import load_step, stem_time
from hardware.recording.reader import Recording

HZ = 50.0
T0 = dt.datetime(2026, 11, 30, 14, 0, 0)


def _step(k: int, n_joints: int = 6, camera: bool = True) -> dict:
    t = k / HZ
    q = 0.3 * np.sin(t + np.arange(n_joints))
    obs = {"joint_positions": np.r_[q, 0.5 + 0.4 * np.sin(t)],  # + the gripper, 0..1
           "joint_velocities": np.r_[q, 0.0],  # what GELLO's UR driver writes there: the positions
           "ee_pos_quat": np.zeros(7), "gripper_position": np.array([0.5 + 0.4 * np.sin(t)]),
           "control": np.r_[q + 0.01, 0.6]}
    if camera:
        img = np.full((24, 32, 3), 30, np.uint8)
        img[4:12, k % 24 : k % 24 + 8] = 250
        obs["wrist_rgb"], obs["wrist_depth"] = img, np.zeros((24, 32), np.uint16)
    return obs


def write_gello_pickles(folder, n: int = 100, name="iso", camera=True, start=T0):
    folder.mkdir(parents=True)
    for k in range(n):
        ts = start + dt.timedelta(seconds=k / HZ)
        stem = {"iso": ts.isoformat(), "dashed": ts.isoformat().replace(":", "-").replace(".", "-"),
                "index": str(k)}[name]
        (folder / f"{stem}.pkl").write_bytes(pickle.dumps(_step(k, camera=camera)))


def _cli(capsys, *args):
    rc = main([*map(str, args)])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def test_pickled_episodes_become_a_recording(tmp_path, capsys):
    write_gello_pickles(tmp_path / "gello" / "1130_140000", n=100)
    write_gello_pickles(tmp_path / "gello" / "1130_140100", n=60, name="dashed", start=T0 + dt.timedelta(60))
    rc, out, err = _cli(capsys, "episodes", "import", "gello", tmp_path / "gello", "--out",
                        tmp_path / "g.mcap", "--task", "wipe")
    assert rc == 0, err
    assert "2 episode(s)" in out
    rec = Recording(tmp_path / "g.mcap")
    assert [e.task for e in rec.episodes] == ["wipe", "wipe"] and rec.cameras == ["wrist"]
    js = rec.episodes[0].topic("/follower/joint_state")
    t = js.t[:100] - js.t[0]
    np.testing.assert_allclose(t, np.arange(100) / HZ, atol=2e-6)  # from the file names' wall times
    q_ref = np.stack([_step(k)["joint_positions"] for k in range(100)])
    np.testing.assert_allclose(js.fields["q"][:100], q_ref[:, :6], atol=1e-8)
    np.testing.assert_allclose(js.fields["gripper_pos"][:100], q_ref[:, 6], atol=1e-8)
    np.testing.assert_allclose(js.fields["q_dot"][:100], np.gradient(q_ref[:, :6], t, axis=0), atol=1e-6)
    cmd = rec.episodes[0].topic("/follower/command")
    np.testing.assert_allclose(cmd.fields["q"][:100], q_ref[:, :6] + 0.01, atol=1e-8)
    np.testing.assert_allclose(cmd.fields["gripper"][:100], 0.6)
    assert len(rec.frames("wrist")) == 160 and rec.frames("wrist").rgb(5)[6, 5:11].mean() > 200
    assert len(rec.episodes[1].topic("/follower/joint_state")) == 61  # dashed ISO names read too


def test_numbered_steps_need_the_rate(tmp_path, capsys):
    write_gello_pickles(tmp_path / "ep", n=30, name="index", camera=False)
    rc, _, err = _cli(capsys, "episodes", "import", "gello", tmp_path / "ep", "--out", tmp_path / "a.mcap")
    assert rc == 2 and "numbered, not timed" in err and "--rate" in err and "Traceback" not in err
    rc, out, err = _cli(capsys, "episodes", "import", "gello", tmp_path / "ep", "--out", tmp_path / "a.mcap",
                        "--rate", "50")
    assert rc == 0, err
    js = Recording(tmp_path / "a.mcap").episodes[0].topic("/follower/joint_state")
    np.testing.assert_allclose(np.diff(js.t[:30]), 0.02, atol=1e-9)


def test_hostile_and_broken_pickles(tmp_path, capsys):
    class Boom:
        def __reduce__(self):
            return (print, ("ran code",))

    write_gello_pickles(tmp_path / "ep", n=20, camera=False)
    bad = tmp_path / "ep" / f"{(T0 + dt.timedelta(seconds=5)).isoformat()}.pkl"
    bad.write_bytes(pickle.dumps({"joint_positions": Boom()}))
    (tmp_path / "ep" / f"{(T0 + dt.timedelta(seconds=6)).isoformat()}.pkl").write_bytes(b"\x80\x04garbage")
    with pytest.raises(ValueError, match="refused: the pickle asks for builtins.print"):
        load_step(bad)
    rc, out, err = _cli(capsys, "episodes", "import", "gello", tmp_path / "ep", "--out", tmp_path / "a.mcap")
    assert rc == 0 and "ran code" not in out + err, err
    assert "skipped 2 step file(s)" in out and "1 episode(s)" in out
    rc, _, err = _cli(capsys, "episodes", "import", "gello", tmp_path / "nothing", "--out",
                      tmp_path / "b.mcap")
    assert rc == 2 and "no such folder" in err


def test_npz_episodes(tmp_path, capsys):
    d = tmp_path / "wipe" / "20261130_140000"
    (d / "base").mkdir(parents=True)
    steps = [_step(k, camera=False) for k in range(40)]
    arrays = {k: np.stack([s[k] for s in steps]) for k in steps[0]}
    arrays["timestamp"] = np.arange(40) / 30.0
    np.savez_compressed(d / "state.npz", **arrays)
    for k in range(40):
        if k != 7:  # a dropped frame: no file
            Image.fromarray(np.full((16, 16, 3), k * 5, np.uint8)).save(d / "base" / f"{k:06d}.jpg")
    meta = {"task": "wipe the table", "outcome": "failure", "views": ["base"]}
    (d / "meta.json").write_text(json.dumps(meta))
    rc, out, err = _cli(capsys, "episodes", "import", "gello", tmp_path / "wipe", "--out",
                        tmp_path / "n.mcap")
    assert rc == 0, err
    rec = Recording(tmp_path / "n.mcap")
    assert rec.episodes[0].outcome == "failure" and rec.episodes[0].task == "wipe the table"
    assert len(rec.frames("base")) == 39


def test_stem_times():
    assert stem_time("2026-11-30T14:00:00.020000") == (T0.timestamp() + 0.02, "wall")
    assert stem_time("2026-11-30T14-00-00-020000") == (pytest.approx(T0.timestamp() + 0.02), "wall")
    assert stem_time("1764511200000000000") == (pytest.approx(1764511200.0), "ns")
    assert stem_time("17") == (17.0, "index") and stem_time("junk") == (None, "")


def test_imported_gello_trains_base_only(tmp_path, capsys):
    from tests.test_next_official import _official_run
    from tests.test_policies_inputs import FAST, _one_line_error

    write_gello_pickles(tmp_path / "gello" / "a", n=60)
    write_gello_pickles(tmp_path / "gello" / "b", n=60, start=T0 + dt.timedelta(60))
    rc, _, err = _cli(capsys, "episodes", "import", "gello", tmp_path / "gello", "--out", tmp_path / "g.mcap")
    assert rc == 0, err
    rc, _, err = _cli(capsys, "train", tmp_path / "g.mcap", "--out", tmp_path / "r1", "--method", "first",
                      *FAST)
    _one_line_error(rc, err, "no force-like signal", "--method base")
    _official_run(tmp_path / "next")  # a NEXT checkpoint for 6 joints: nothing to run it on
    rc, _, err = _cli(capsys, "train", tmp_path / "g.mcap", "--out", tmp_path / "r2", "--method", "base",
                      "--next", tmp_path / "next", *FAST)
    _one_line_error(rc, err, "--next runs NEXT over the logged motor torque", "have none")
    rc, out, err = _cli(capsys, "train", tmp_path / "g.mcap", "--out", tmp_path / "r3", "--method", "base",
                        *FAST)
    assert rc == 0 and "cameras wrist" in out, err
