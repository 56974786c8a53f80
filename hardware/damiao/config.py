"""Config of a Damiao-motor follower chain in MIT mode (I2RT YAM style)."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class DamiaoFollowerConfig:
    """channel/interface: python-can bus. ids: slave ids per joint; master_ids: feedback ids (default
    slave + 0x10). motor: model per joint ("DM4340", "DM4310"). kp/kd: default MIT gains per joint
    [N*m/rad, N*m*s/rad] for position tracking. gripper_id: gripper motor id or None. timeout_ms: the
    motors' own command timeout (register 9) set at start-up, after which firmware drops to damping.
    gripper_motor: the gripper's motor model. gripper_kp / gripper_kd: its MIT gains. The gripper command
    [m of stroke, 0 = closed] maps linearly onto the motor angle: gripper_closed_rad at 0,
    gripper_open_rad at gripper_stroke_m (calibrate both angles on your gripper; the defaults are not
    measured).
    reply_timeout_s: how long a register read waits for its reply at start-up [s]."""

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
    gripper_motor: str = "DM4310"
    gripper_kp: float = 10.0
    gripper_kd: float = 0.5
    gripper_closed_rad: float = 0.0
    gripper_open_rad: float = -2.5
    gripper_stroke_m: float = 0.08
    reply_timeout_s: float = 0.05
