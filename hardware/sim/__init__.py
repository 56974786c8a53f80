"""Simulated hardware: the MuJoCo twin behind the real wire protocols (everything here is SIMULATED).

serve_twin(rig) runs a rig's twin in real time; open_rig(rig, clock=...) connects the rig's real drivers
(to the twin for sim-* rigs, to the hardware otherwise). See docs/twin.md. The names are imported lazily
so that hardware.rigs can use hardware.sim.actuators without an import cycle.
"""

from __future__ import annotations

__all__ = ["RigSession", "TwinServer", "open_rig", "serve_twin"]


def __getattr__(name: str):
    if name in __all__:
        from hardware.sim import serve

        return getattr(serve, name)
    raise AttributeError(f"module 'hardware.sim' has no attribute {name!r}")
