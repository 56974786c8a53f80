"""Recording format, writer and readers (MCAP sessions and plain .npz logs). Lives in hardware/ so that
calibration/ and policies/ can read recordings without depending on the app layer."""
