"""Config of an AgileX Piper follower."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class PiperFollowerConfig:
    """channel: CAN channel ("can0", or a twin's virtual channel); interface: python-can interface
    ("socketcan" on Linux hardware, "virtual" for the twin). mode: "position" (0x151 joint mode + 0x155-0x157
    targets, the vendor's position loop) or "mit" (0x15A-0x15F per-joint impedance). speed_pct: the
    firmware's speed rate 0-100. firmware_effort_x4: old firmware (<= 1.8-2) reports J1-J3 effort 4x low.
    arm: arm description name (limits come from it)."""

    channel: str
    interface: str = "socketcan"
    bitrate: int = 1_000_000
    mode: str = "position"
    speed_pct: int = 100
    firmware_effort_x4: bool = False
    arm: str = "piper"
    name: str = "follower"
