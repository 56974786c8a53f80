"""The recording metadata (hardware/recording/metadata.py) keeps its on-disk record name, so files written
before and after the rename read the same way; the former Python names stay as aliases."""

from __future__ import annotations

from mcap.reader import make_reader

from hardware.recording import Recording, describe_recording, describe_session
from hardware.recording import schemas as S
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
    assert rec.session == rec.info  # the former name
    assert describe_session is describe_recording


def test_the_former_module_still_imports():
    from hardware.recording import metadata
    from hardware.recording.session import describe_session as old
    from hardware.recording.session import software_version

    assert old is metadata.describe_recording and software_version is metadata.software_version
