"""Config of an AgileX Piper follower."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class PiperFollowerConfig:
    """channel: CAN channel ("can0", or a twin's virtual channel); interface: python-can interface
    ("socketcan" on Linux hardware, "virtual" for the twin). mode: "position" (0x151 joint mode + 0x155-0x157
    targets, the vendor's position loop) or "mit" (0x15A-0x15F per-joint impedance). speed_pct: the
    firmware's speed rate 0-100. firmware_effort_x4: old firmware (<= 1.8-2) reports J1-J3 effort 4x low.
    arm: arm description name (limits come from it).
    mit_kp / mit_kd: per-joint MIT gains [N*m/rad, N*m*s/rad] used when a command carries none.
    mit_torque_gain: the firmware multiplies the MIT torque by this (vendor FAQ: 4); the driver divides by it.
    gripper_effort_nm: gripping effort sent with 0x159 (0-5 N*m). gripper_stroke_max_m: commands are clipped
    to [0, this] [m]. connect_timeout_s: how long connect() waits for the first full feedback [s]."""

    channel: str
    interface: str = "socketcan"
    bitrate: int = 1_000_000
    mode: str = "position"
    speed_pct: int = 100
    firmware_effort_x4: bool = False
    arm: str = "piper"
    name: str = "follower"
    mit_kp: list[float] = field(default_factory=lambda: [10.0, 10.0, 10.0, 4.0, 4.0, 4.0])
    mit_kd: list[float] = field(default_factory=lambda: [0.8, 0.8, 0.8, 0.3, 0.3, 0.3])
    mit_torque_gain: float = 4.0
    gripper_effort_nm: float = 1.0
    gripper_stroke_max_m: float = 0.07
    connect_timeout_s: float = 1.0
