"""AgileX Piper follower over CAN: driver, protocol, emulator; its doctor probe is hardware/can_probe.py.

KIND declares rig `driver = "piper"` (hardware/registry.py).
"""

from __future__ import annotations

from hardware.piper.config import PiperFollowerConfig
from hardware.registry import DeviceKind, TwinDrive

PIPER_GRIPPER_MOTOR = "piper_gripper"  # hardware/sim/presets.py: the Piper's gripper drive


def make_driver(spec, clock, twin=None):
    from hardware.piper.follower import PiperFollower

    return PiperFollower(spec.config, spec.limits(), clock=clock)


KIND = DeviceKind(driver="piper", role="follower", config=PiperFollowerConfig,
                  driver_ref="hardware.piper:make_driver",
                  twin_drive=lambda c: TwinDrive(None, gripper_motor=PIPER_GRIPPER_MOTOR, gripper=True),
                  wire="can", protocol="AgileX Piper CAN",
                  emulator_ref="hardware.piper.emulator:make_twin_emulator",
                  probe_ref="hardware.can_probe:piper_checks", bare_probe_ref="hardware.can_probe:piper_bare")
