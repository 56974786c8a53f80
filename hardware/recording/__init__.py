"""Recording format, writer and readers (MCAP recordings and plain .npz logs). Lives in hardware/ so that
calibration/ and policies/ can read recordings without depending on the app layer.

    from hardware.recording import Recorder, Recording, describe_recording
"""

from hardware.recording.mcap_scan import RecordingError
from hardware.recording.metadata import describe_recording
from hardware.recording.reader import Episode, Frames, Recording, hold_previous, interp_linear
from hardware.recording.writer import Recorder
from hardware.recording.writer_link import RecorderStatus

__all__ = ["Episode", "Frames", "Recorder", "RecorderStatus", "Recording", "RecordingError",
           "describe_recording",
           "hold_previous", "interp_linear"]
