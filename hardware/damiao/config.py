"""Config of a Damiao-motor follower chain in MIT mode (I2RT YAM style)."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class DamiaoFollowerConfig:
    """channel/interface: python-can bus. ids: slave ids per joint; master_ids: feedback ids (default
    slave + 0x10). motor: model per joint ("DM4340", "DM4310"). kp/kd: default MIT gains per joint
    [N*m/rad, N*m*s/rad] for position tracking. gripper_id: gripper motor id or None. timeout_ms: the
    motors' own command timeout (register 9) set at start-up, after which firmware drops to damping."""

    channel: str
    ids: list[int]
    motor: list[str]
    interface: str = "socketcan"
    bitrate: int = 1_000_000
    master_ids: list[int] | None = None
    kp: list[float] = field(default_factory=lambda: [80.0, 80.0, 80.0, 10.0, 10.0, 10.0])
    kd: list[float] = field(default_factory=lambda: [5.0, 5.0, 5.0, 1.5, 1.5, 1.5])
    gripper_id: int | None = 7
    timeout_ms: float = 50.0
    arm: str = "yam"
    name: str = "follower"
