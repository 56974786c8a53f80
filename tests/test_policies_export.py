"""`factr2 export lerobot`: the LeRobotDataset v3.0 folder re-read with pyarrow / pandas / PyAV."""

from __future__ import annotations

import json

import numpy as np
import pytest

from factr2_teleop.cli import main
from tests.policy_helpers import write_recording


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    d = tmp_path_factory.mktemp("exp")
    write_recording(d / "a.mcap", episodes=2, seconds=4.0)
    rc = main(["export", "lerobot", str(d / "a.mcap"), "--out", str(d / "ds"), "--thresholds", "1:3"])
    assert rc == 0
    return d


def test_layout_info_and_stats(exported):
    ds = exported / "ds"
    info = json.loads((ds / "meta" / "info.json").read_text())
    assert info["codebase_version"] == "v3.0" and info["fps"] == 10 and info["total_episodes"] == 2
    assert info["total_frames"] == 80
    feats = info["features"]
    assert feats["observation.state"]["shape"] == [7] and feats["action"]["shape"] == [7]
    assert feats["observation.force"]["shape"] == [6] and feats["phase"]["dtype"] == "int64"
    assert feats["observation.images.wrist"]["dtype"] == "video"
    assert feats["observation.images.wrist"]["shape"] == [32, 40, 3]
    stats = json.loads((ds / "meta" / "stats.json").read_text())
    assert set(stats) >= {"observation.state", "action", "observation.images.top", "phase"}
    assert np.asarray(stats["observation.images.top"]["mean"]).shape == (3, 1, 1)
    for p in (
        "data/chunk-000/file-000.parquet",
        "meta/episodes/chunk-000/file-000.parquet",
        "meta/tasks.parquet",
        "videos/observation.images.top/chunk-000/file-000.mp4",
    ):
        assert (ds / p).is_file(), p


def test_rows_phases_and_video_frames_read_back(exported):
    import av
    import pandas as pd

    ds = exported / "ds"
    data = pd.read_parquet(ds / "data" / "chunk-000" / "file-000.parquet")
    eps = pd.read_parquet(ds / "meta" / "episodes" / "chunk-000" / "file-000.parquet")
    tasks = pd.read_parquet(ds / "meta" / "tasks.parquet")
    assert len(data) == 80 and list(data["index"]) == list(range(80))
    assert list(eps["length"]) == [40, 40] and list(eps["dataset_from_index"]) == [0, 40]
    assert list(tasks.index) == ["push"] and list(tasks["task_index"]) == [0]
    ep0 = data[data["episode_index"] == 0]
    np.testing.assert_allclose(ep0["timestamp"].to_numpy(), np.arange(40) / 10, atol=1e-6)
    # contact 1.5..2.5 s, pre-contact 0.5..1.5 s of each 4 s episode (10 frames each at 10 fps)
    assert np.bincount(ep0["phase"].to_numpy(), minlength=3).tolist() == [20, 10, 10]
    state = np.stack(ep0["observation.state"].to_numpy())
    assert state.shape == (40, 7)
    with av.open(str(ds / "videos" / "observation.images.top" / "chunk-000" / "file-000.mp4")) as c:
        frames = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
    assert len(frames) == 80 and frames[0].shape == (32, 40, 3)
    from hardware.recording.reader import Recording

    rec = Recording(exported / "a.mcap")
    first_ep1 = rec.frames("top").rgb(
        int(np.searchsorted(rec.frames("top").t, rec.episodes[1].t_start - 1e-6))
    )
    assert np.abs(frames[40].astype(int) - first_ep1.astype(int)).mean() < 6  # H.264 at crf 23


def test_existing_output_is_refused(exported, capsys):
    rc = main(
        ["export", "lerobot", str(exported / "a.mcap"), "--out", str(exported / "ds"), "--thresholds", "1:3"]
    )
    assert rc == 2 and "output folder exists" in capsys.readouterr().err


RIG_30FPS = '[[cameras]]\nname = "top"\nsource = "sim:top"\nfps = 30\n'


def test_state_only_export_with_privileged_objects(tmp_path, capsys):
    """`collect --no-cameras` recordings: a valid dataset without videos, at the state-only rate, with the
    twin's object state as a labelled feature."""
    import pandas as pd

    write_recording(tmp_path / "a.mcap", episodes=2, seconds=2.0, cameras=(), objects=3)
    rc = main(["export", "lerobot", str(tmp_path / "a.mcap"), "--out", str(tmp_path / "ds"), "--thresholds",
               "1:3"])
    out = capsys.readouterr().out
    assert rc == 0 and "state only (no cameras)" in out and "PRIVILEGED" in out, out
    info = json.loads((tmp_path / "ds" / "meta" / "info.json").read_text())
    assert info["fps"] == 30 and info["video_path"] is None
    assert not [k for k, f in info["features"].items() if f["dtype"] == "video"]
    obj = info["features"]["observation.state.objects"]
    assert obj["names"] == ["obj0", "obj1", "obj2"] and "PRIVILEGED" in obj["description"]
    data = pd.read_parquet(tmp_path / "ds" / "data" / "chunk-000" / "file-000.parquet")
    assert len(data) == info["total_frames"] >= 2 * 55  # 2 s at 30 fps each, less the span's ends
    assert np.isfinite(np.stack(data["observation.state.objects"].to_numpy())).all()
    stats = json.loads((tmp_path / "ds" / "meta" / "stats.json").read_text())
    assert "observation.state.objects" in stats and not (tmp_path / "ds" / "videos").exists()


@pytest.mark.parametrize("rig_fps,warned", [(10, False), (30, True)])
def test_fps_is_the_rig_files_checked_against_the_frames(tmp_path, capsys, rig_fps, warned):
    """The nominal camera rate from the rig file, not a median interval rounded down (29 for 30 Hz), and
    a warning when the frames' timestamps disagree with it."""
    rig = RIG_30FPS.replace("30", str(rig_fps))
    write_recording(tmp_path / "a.mcap", episodes=1, seconds=2.0, metadata={"rig_toml": rig})
    rc = main(["export", "lerobot", str(tmp_path / "a.mcap"), "--out", str(tmp_path / "ds"), "--thresholds",
               "1:3"])
    err = capsys.readouterr().err
    assert rc == 0, err
    assert json.loads((tmp_path / "ds" / "meta" / "info.json").read_text())["fps"] == rig_fps
    assert ("rig file says 30 fps but its frames came at 10" in err) == warned, err
