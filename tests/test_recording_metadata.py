"""The recording metadata (hardware/recording/metadata.py) keeps its on-disk record name, so files written
before and after the rename read the same way; a file without episode events reads as one UNMARKED episode."""

from __future__ import annotations

from mcap.reader import make_reader

from hardware.recording import Recording, describe_recording
from hardware.recording import schemas as S
from hardware.recording.reader import UNMARKED
from tests.recording_helpers import record_session


def test_the_record_keeps_its_name_and_reads_as_info(tmp_path):
    path = tmp_path / "r.mcap"
    meta = describe_recording(task="wipe", operator="ada", twin=True)
    record_session(path, n=50, cameras=False, metadata=meta).close()
    with path.open("rb") as f:
        names = [m.name for m in make_reader(f).iter_metadata()]
    assert S.RECORDING_METADATA == "factr2.session" and S.RECORDING_METADATA in names
    rec = Recording(path, use_cache=False)
    assert rec.info["task"] == "wipe" and rec.info["operator"] == "ada" and rec.info["simulated"] == "true"


def test_a_recording_without_episode_events_is_one_unmarked_episode(tmp_path):
    from hardware.recording import Recorder
    from tests.recording_helpers import NAMES, joint_state

    path = tmp_path / "plain.mcap"
    rec = Recorder(path, joint_names={"follower": NAMES}, t0=0.0)
    for k in range(20):
        rec.log_joint_state("follower", k * 1e-3, joint_state(k, 1e-3))
    rec.close()
    eps = Recording(path, use_cache=False).episodes
    assert [(e.index, e.outcome) for e in eps] == [(0, UNMARKED)] and UNMARKED == "unmarked"
