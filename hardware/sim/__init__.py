"""Simulated hardware: the MuJoCo twin behind the real wire protocols (everything here is SIMULATED).

Twin (twin.py) builds a rig's worlds, motor banks and emulators; TwinDrivenClock lets a caller's thread
step it. Opening a rig (real or twin) and serving a twin live above this package, in hardware/connect.py
(`from hardware.connect import open_rig, serve_twin`); see docs/twin.md.
"""

from __future__ import annotations


def open_rig(*args, **kwargs):
    """Alias of hardware.connect.open_rig for callers not yet moved (imported in the body: hardware.connect
    imports this package, so a module-level import here would be a cycle)."""
    from hardware.connect import open_rig as _open_rig

    return _open_rig(*args, **kwargs)


def serve_twin(*args, **kwargs):
    """Alias of hardware.connect.serve_twin (see open_rig)."""
    from hardware.connect import serve_twin as _serve_twin

    return _serve_twin(*args, **kwargs)
