"""Config of a GELLO-style Dynamixel leader (one dataclass per device, filled from the rig file)."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class DynamixelLeaderConfig:
    """port: serial device path (/dev/ttyUSB0, or a twin's pty). baud: bit/s (4_000_000 recommended).
    ids: servo ids of the arm joints in joint order; signs: +1/-1 per joint; offsets_rad: assembly offsets
    [rad] so that q_joint = sign * (q_servo - offset). model: servo model name per joint (or one for all),
    e.g. "XL330-M288", "XC330-M288", "XM430-W350". gripper_id: trigger servo id (None: no trigger);
    gripper_open_rad / gripper_closed_rad: trigger positions mapped to 0..1. read_current: add present
    current to the sync read. loop_hz: the rate the loop wants (start-up check warns below it).
    arm: name of the leader's arm description (hardware/arms).
    torque_constant_nm_per_a: per-joint K override [N*m/A] (None: the model's stall torque / stall current,
    see hardware/dynamixel/models.py). gripper_model: trigger servo model (None: the first joint's model).
    rx_timeout_ms: how long one sync read waits for replies (None: 2 x USB latency timer + wire time
    + 4 ms; + 10 ms on a pty, i.e. a twin). fast_sync_read: read the chain with Fast Sync Read (0x8A, one
    status packet for all servos, firmware v45+; less CPU per tick): "auto" tries it at connect and falls
    back to plain sync read with one start-up warning, true requires it (else connect fails), false never."""

    port: str
    ids: list[int]
    signs: list[int]
    offsets_rad: list[float]
    model: str | list[str] = "XL330-M288"
    baud: int = 4_000_000
    gripper_id: int | None = None
    gripper_open_rad: float = 0.0
    gripper_closed_rad: float = 1.0
    read_current: bool = True
    loop_hz: float = 500.0
    arm: str = "gello_piper"
    name: str = "leader"
    torque_constant_nm_per_a: list[float] | None = None
    gripper_model: str | None = None
    rx_timeout_ms: float | None = None
    fast_sync_read: bool | str = "auto"
    extra: dict = field(default_factory=dict)
