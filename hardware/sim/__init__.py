"""Simulated hardware: the MuJoCo twin behind the real wire protocols (everything here is SIMULATED).

Twin (twin.py; its devices: twin_devices.py) builds a rig's worlds, motor banks and emulators;
TwinDrivenClock (twin_driven_clock.py) lets a caller's thread step it. Opening a rig (real or twin) and
serving a twin live above this package, in hardware/connect.py (`from hardware.connect import open_rig,
serve_twin`); see docs/twin.md.
"""
