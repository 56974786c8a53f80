"""LeRobotDataset v3 folders in (hardware/importers/lerobot.py): datasets written by LeRobot 0.6.1 itself
(tests/data/lerobot, made by tests/lerobot/write_datasets.py; regenerated here when the LeRobot environment
is present) train, list and export as a folder of recordings do; our export read back gives the same
training samples as the recordings it came from."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from bench.bring_data_round_trip import digest as first_batch_digest
from factr2_teleop.cli import main
from hardware.importers.lerobot import PHASES_LINE, labels_at, lerobot_recordings, phase_changes
from hardware.recording.reader import Recording
from policies.data.dataset import build_dataset
from policies.data.recordings import load_episodes
from policies.labels.labelling import resolve_thresholds
from policies.training import checkpoint as C
from tests.policy_helpers import write_recording
from tests.test_policies_inputs import FAST, _one_line_error

DATA = Path(__file__).parent / "data" / "lerobot"
LEROBOT_PYTHON = Path(os.environ.get("LEROBOT_PYTHON", "/work/lerobot312/bin/python"))


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("FACTR2_CACHE", str(tmp_path / "cache"))


def _cli(capsys, *args):
    rc = main([*map(str, args)])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def _samples(path, given=(1.0, 3.0)):
    eps, arms = load_episodes([path])
    th = resolve_thresholds(given, None, eps, arms)
    return build_dataset(eps, arms, th=th, observation="state", rate_hz=30.0, chunk=10), th


@pytest.mark.parametrize("flags, given", [(["--thresholds", "1:3"], (1.0, 3.0)), ([], "recording")])
def test_round_trip_recordings_export_train_same_samples(tmp_path, capsys, flags, given):
    """With the default thresholds ("recording") the dataset's own phase column is trained on (labels made
    again from its 30 Hz force differ); given thresholds label both alike."""
    rec = write_recording(tmp_path / "a.mcap", episodes=3, seconds=4.0, cameras=(), objects=3)
    rc, _, err = _cli(capsys, "export", "lerobot", rec, "--out", tmp_path / "ds", *flags)
    assert rc == 0, err
    (a, th_a), (b, th_b) = _samples(rec, given), _samples(tmp_path / "ds", given)
    said = [ln for ln in capsys.readouterr().err.splitlines() if PHASES_LINE in ln]
    assert len(said) == 1 and "unless --thresholds" in said[0]  # the dataset says so, whatever the flags
    assert len(a) == len(b) == 360
    for k in ("state", "force", "action", "mask", "phase", "objects"):
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k), err_msg=k)
    assert first_batch_digest(a) == first_batch_digest(b)
    assert np.bincount(b.phase, minlength=3).min() > 0  # every phase present: the labels are not trivial
    assert th_b.source.key == ("dataset" if given == "recording" else "given")
    assert (th_b.t_low, th_b.t_high) == (th_a.t_low, th_a.t_high)  # the thresholds that made the labels


def test_phase_changes_and_labels_at():
    ph = np.array([0, 0, 1, 1, 2, 2, 2, 0])
    ch = phase_changes(ph)
    assert ch == [[0, 0], [2, 1], [4, 2], [7, 0]]
    np.testing.assert_array_equal(labels_at(ch, np.arange(8)), ph)
    # float rows (force samples' times x fps) go to the nearest row; before the first, the first label
    np.testing.assert_array_equal(labels_at(ch, [-0.3, 1.6, 3.9999999, 7.5, 20.0]), [0, 1, 2, 0, 0])
    assert phase_changes(np.zeros(0, int)) == []


def test_effort_video_first_labels_and_trains(tmp_path, capsys):
    run = tmp_path / "run"
    rc, out, err = _cli(capsys, "train", DATA / "effort_video", "--out", run, "--method", "first", *FAST)
    assert rc == 0, err
    said = [ln for ln in err.splitlines() if "raw observation.effort" in ln]
    assert len(said) == 1 and "not NEXT" in said[0] and "--next" in said[0], err
    assert "phases F/PC/C 50% / 25% / 25%" in out and "cameras wrist" in out, out
    meta = C.read_meta(C.last_checkpoint(run))
    assert meta["method"] == "first" and meta["samples"]["train"] + meta["samples"]["val"] == 120
    assert meta["phase_shares"]["contact"] == pytest.approx(0.25, abs=0.05)


def test_video_frames_come_through(tmp_path):
    (mcap,) = lerobot_recordings(DATA / "effort_video", say=lambda s: None)
    rec = Recording(mcap)
    fr = rec.frames("wrist")
    assert len(fr) == 120 and rec.cameras == ["wrist"]
    for i, k in ((0, 0), (5, 5), (47, 7)):  # episode 1 starts at row 40: frame_image(k) of its k-th row
        img = fr.rgb(i).astype(int)
        assert img.shape == (32, 40, 3)
        x = (k * 2) % 32
        assert img[10:18, x + 2 : x + 6].mean() > 200 and img[24:30].mean() < 100, i


def test_no_force_refuses_first_and_trains_base(tmp_path, capsys):
    rc, _, err = _cli(capsys, "train", DATA / "noforce_video", "--out", tmp_path / "r1", "--method", "first",
                      *FAST)
    _one_line_error(rc, err, "--method first needs FIRST phase labels", "no force-like signal",
                    "--method base")
    assert not (tmp_path / "r1").exists()
    rc, out, err = _cli(capsys, "train", DATA / "noforce_video", "--out", tmp_path / "r2", "--method", "base",
                        *FAST)
    assert rc == 0, err
    assert "phases F/PC/C 100% / 0% / 0%" in out
    assert C.read_meta(C.last_checkpoint(tmp_path / "r2"))["phases"]["source"].startswith("none")
    # a mapping can drop the force-like feature: the effort dataset then trains base only as well
    rc, _, err = _cli(capsys, "train", DATA / "effort_video", "--out", tmp_path / "r3", "--method", "first",
                      "--lerobot-map", "effort=none", *FAST)
    _one_line_error(rc, err, "no force-like signal")


def test_state_only_and_image_features_list_and_export(tmp_path, capsys):
    rc, out, err = _cli(capsys, "episodes", "list", DATA / "state_only")
    assert rc == 0 and "3 episode(s)" in out and "base methods only" in err, err
    rc, out, err = _cli(capsys, "episodes", "list", DATA / "images_png")
    assert rc == 0 and "3 episode(s)" in out, err
    rc, out, err = _cli(capsys, "export", "lerobot", DATA / "images_png", "--out", tmp_path / "x",
                        "--thresholds", "1:3")
    assert rc == 0, err
    info = json.loads((tmp_path / "x" / "meta" / "info.json").read_text())
    assert info["total_episodes"] == 3 and "observation.images.wrist" in info["features"]
    # degrees: state and action scaled to rad
    (deg,) = lerobot_recordings(DATA / "state_only", "angles=deg", say=lambda s: None)
    (rad,) = lerobot_recordings(DATA / "state_only", say=lambda s: None)
    q_deg = Recording(deg).topic("/follower/joint_state").fields["q"]
    q_rad = Recording(rad).topic("/follower/joint_state").fields["q"]
    np.testing.assert_allclose(q_deg, q_rad * np.pi / 180, rtol=1e-6)


def _broken(tmp_path, name, edit) -> Path:
    d = tmp_path / name
    shutil.copytree(DATA / "effort_video", d)
    edit(d)
    return d


@pytest.mark.parametrize("name, edit, words", [
    ("junk", lambda d: (d / "meta" / "info.json").write_text("{"), ["not a readable LeRobotDataset",
                                                                  "meta/info.json"]),
    ("v21", lambda d: (d / "meta" / "info.json").write_text(json.dumps(
        {**json.loads((d / "meta" / "info.json").read_text()), "codebase_version": "v2.1"})), ["v2.1"]),
    ("nodata", lambda d: shutil.rmtree(d / "data"), ["no data/*/*.parquet"]),
    ("badparquet", lambda d: (d / "data" / "chunk-000" / "file-000.parquet").write_bytes(b"PAR1garbage"),
     ["data:"]),
    ("novideo", lambda d: shutil.rmtree(d / "videos"), ["video", "missing"]),
])
def test_garbage_is_one_line(tmp_path, capsys, name, edit, words):
    d = _broken(tmp_path, name, edit)
    rc, _, err = _cli(capsys, "episodes", "list", d)
    _one_line_error(rc, err, *words)


def test_bad_mapping_is_one_line(capsys):
    rc, _, err = _cli(capsys, "episodes", "list", DATA / "effort_video", "--lerobot-map", "effort=obs.nope")
    _one_line_error(rc, err, "no such feature", "observation.effort")
    rc, _, err = _cli(capsys, "episodes", "list", DATA / "effort_video", "--lerobot-map", "torque")
    _one_line_error(rc, err, "bad entry")


@pytest.mark.skipif(not LEROBOT_PYTHON.exists(), reason="no LeRobot environment (LEROBOT_PYTHON)")
def test_lerobot_writer_output_reads_like_the_fixtures(tmp_path):
    """LeRobot's own writer, run now: its datasets convert to the same joint data as the committed ones."""
    script = Path(__file__).parent / "lerobot" / "write_datasets.py"
    subprocess.run([str(LEROBOT_PYTHON), str(script), str(tmp_path / "lr")], check=True, capture_output=True,
                   timeout=600)
    for name in ("effort_video", "state_only"):
        (new,) = lerobot_recordings(tmp_path / "lr" / name, say=lambda s: None)
        (old,) = lerobot_recordings(DATA / name, say=lambda s: None)
        a, b = Recording(new).topic("/follower/joint_state"), Recording(old).topic("/follower/joint_state")
        np.testing.assert_array_equal(a.fields["q"], b.fields["q"])
        np.testing.assert_array_equal(a.fields["tau_m"], b.fields["tau_m"])


def test_next_labels_the_effort_dataset(tmp_path, capsys):
    """With a NEXT checkpoint for the arm (here an official run folder), labels come from NEXT run offline
    over the joint states and the effort, not from the raw effort."""
    from tests.test_next_official import _official_run

    _official_run(tmp_path / "next")
    run = tmp_path / "run"
    rc, out, err = _cli(capsys, "train", DATA / "effort_video", "--out", run, "--method", "first",
                        "--next", tmp_path / "next", *FAST)
    assert rc == 0, err
    meta = C.read_meta(C.last_checkpoint(run))
    assert meta["tau_ext_source"] == "offline" and meta["next_checkpoint"].startswith(str(tmp_path / "next"))
