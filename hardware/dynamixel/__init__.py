"""Dynamixel X servos (Protocol 2.0): the GELLO-style leader driver, its emulator and its doctor probe.

KIND declares rig `driver = "dynamixel"` (hardware/registry.py): a leader on a serial port.
"""

from __future__ import annotations

from hardware.dynamixel.config import DynamixelLeaderConfig
from hardware.registry import DeviceKind, TwinDrive


def servo_models(config: DynamixelLeaderConfig) -> tuple[list[str], str]:
    """The servo model per joint and of the trigger, as the config names them (trigger: gripper_model,
    else the last joint's model)."""
    m = config.model
    models = [m] * len(config.ids) if isinstance(m, str) else list(m)
    return models, config.gripper_model or models[-1]


def _twin_drive(config: DynamixelLeaderConfig) -> TwinDrive:
    models, trigger = servo_models(config)  # the servos the rig declares (and the emulator reports)
    return TwinDrive(motors=models, gripper_motor=trigger, gripper=config.gripper_id is not None)


def make_driver(spec, clock, twin=None):
    from hardware.dynamixel.leader import DynamixelLeader

    return DynamixelLeader(spec.config, spec.limits(), clock=clock)


KIND = DeviceKind(driver="dynamixel", role="leader", config=DynamixelLeaderConfig,
                  driver_ref="hardware.dynamixel:make_driver", twin_drive=_twin_drive, wire="serial",
                  protocol="Dynamixel Protocol 2.0",
                  emulator_ref="hardware.dynamixel.emulator:make_twin_emulator",
                  probe_ref="hardware.doctor:dynamixel_checks")
