"""The former name of hardware/recording/metadata.py, kept for callers outside hardware/ that still import it
(policies/training/run.py). New code imports hardware.recording.metadata."""

from hardware.recording import metadata as _m

arm_metadata, recorded_arm, software_version = _m.arm_metadata, _m.recorded_arm, _m.software_version
describe_recording, default_metadata = _m.describe_recording, _m.default_metadata
describe_session, session_metadata = _m.describe_recording, _m.default_metadata  # the former names
