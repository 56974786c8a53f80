"""Dynamixel X servos (Protocol 2.0): the GELLO-style leader driver, its emulator and its doctor probe.

KIND declares rig `driver = "dynamixel"` (hardware/registry.py): a leader on a serial port.
"""

from __future__ import annotations

from hardware.dynamixel.config import DynamixelLeaderConfig
from hardware.registry import DeviceKind, TwinDrive, TwinEndpoint


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


def make_twin_emulator(ctx):
    """A twin's leader (hardware.registry EmulatorContext -> TwinEndpoint): the rig's servos, current
    mode, return delay 0 (the leader sets it anyway), on a pty or an in-process port."""
    from hardware.dynamixel import protocol as p
    from hardware.dynamixel.emulator import DynamixelEmulator

    cfg = ctx.spec.config
    g = ctx.with_gripper
    models, trigger = servo_models(cfg)  # the trigger servo comes after the joints
    offsets = [float(o) for o in cfg.offsets_rad] + ([float(cfg.gripper_open_rad)] if g else [])
    emu = DynamixelEmulator(ctx.bank, list(cfg.ids) + ([cfg.gripper_id] if g else []),
                            models + ([trigger] if g else []),
                            signs=[float(s) for s in cfg.signs] + ([1.0] if g else []), offsets_rad=offsets,
                            return_delay=0, operating_mode=p.OP_MODE_CURRENT, baud=int(cfg.baud),
                            bank_lock=ctx.world.lock, seed=ctx.twin_seed, emulate_return_delay=False,
                            transport=ctx.dynamixel_transport, clock=ctx.now)
    return TwinEndpoint(emulator=emu, endpoint=emu.port_path)


KIND = DeviceKind(driver="dynamixel", role="leader", config=DynamixelLeaderConfig,
                  driver_ref="hardware.dynamixel:make_driver", twin_drive=_twin_drive, wire="serial",
                  protocol="Dynamixel Protocol 2.0",
                  emulator_ref="hardware.dynamixel:make_twin_emulator",
                  probe_ref="hardware.dynamixel_probe:dynamixel_checks")
