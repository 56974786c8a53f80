"""Damiao motors in MIT mode over CAN (I2RT YAM style follower): driver, protocol, emulator; its doctor
probe is hardware/can_probe.py.

KIND declares rig `driver = "damiao"` (hardware/registry.py).
"""

from __future__ import annotations

from hardware.damiao.config import DamiaoFollowerConfig
from hardware.registry import DeviceKind, TwinDrive


def make_driver(spec, clock, twin=None):
    from hardware.damiao.follower import DamiaoFollower

    return DamiaoFollower(spec.config, spec.limits(), clock=clock)


KIND = DeviceKind(driver="damiao", role="follower", config=DamiaoFollowerConfig,
                  driver_ref="hardware.damiao:make_driver",
                  twin_drive=lambda c: TwinDrive(motors=None, gripper_motor=c.gripper_motor,
                                                 gripper=c.gripper_id is not None),
                  wire="can", protocol="Damiao MIT-mode CAN",
                  emulator_ref="hardware.damiao.emulator:make_twin_emulator",
                  probe_ref="hardware.can_probe:damiao_checks",
                  bare_probe_ref="hardware.can_probe:damiao_bare")
