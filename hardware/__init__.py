"""Device layer: base roles, the safety layer, wire codecs and drivers, arm descriptions, twins, cameras.

Nothing here imports calibration/, policies/ or factr2_teleop/ (dependencies point one way).
"""
