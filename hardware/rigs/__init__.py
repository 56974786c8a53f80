"""Rig files (TOML): which leaders, followers and cameras a setup has. See rig.py and docs/twin.md."""

from hardware.rigs.rig import DEFAULT_RIG, CameraSpec, DeviceSpec, Rig, TwinSpec, list_rigs, load_rig

__all__ = ["DEFAULT_RIG", "CameraSpec", "DeviceSpec", "Rig", "TwinSpec", "list_rigs", "load_rig"]
