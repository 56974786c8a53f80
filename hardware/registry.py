"""Device kinds: what a rig file's `driver = "..."` means, declared once by each device folder.

    from hardware.registry import device_kind, device_kinds
    k = device_kind("piper", where="rig followers[0].driver")   # ConfigError naming the choices if unknown
    k.config            # the rig table's dataclass (PiperFollowerConfig); None: arm and name only
    k.make_driver(spec, clock, twin)        # the connected role object's constructor (not connected)
    k.make_emulator(ctx)                    # a twin's emulator of it (EmulatorContext -> TwinEndpoint)
    k.doctor_probe(config, loop_hz)         # `factr2 doctor --rig`: list[hardware.doctor.DeviceCheck]

A device folder declares its kind in its package __init__ (KIND = DeviceKind(...)); KIND_MODULES below
lists those modules. The rig loader (hardware/rigs), the twin (hardware/sim/twin.py), hardware/connect.py
and the doctor ask this registry instead of switching on driver names.

Why names ("module:function") and not imported functions: the constructors pull in python-can, the
dynamixel sdk, MuJoCo; loading a rig file must not, and a device folder must not import the twin, the
doctor or the loader that use it (hardware/ has no import cycle: tests/test_architecture.py). The registry
imports a kind's implementation only when it is called; tests/test_rigs.py resolves every declared name.
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache

from hardware.errors import ConfigError

# the modules whose KIND declares a device kind (a new device folder adds itself here)
KIND_MODULES = ("hardware.dynamixel", "hardware.piper", "hardware.damiao", "hardware.sim.direct")
ROLES = ("leader", "follower")
WIRES = ("serial", "can", None)  # what a twin serves a kind on: a serial port, a CAN channel, nothing


@dataclass(frozen=True)
class TwinDrive:
    """How a twin builds a device's motor bank. motors: motor preset per arm joint (None: the arm's
    default, hardware/sim/presets.py); gripper_motor: the gripper's preset; gripper: the device drives
    the arm's gripper joint (when the arm has one)."""

    motors: list[str] | None
    gripper_motor: str
    gripper: bool


@dataclass
class EmulatorContext:
    """What a twin hands a kind's emulator constructor. spec: the rig's DeviceSpec; bank: the device's
    MotorBank (arm joints, then the gripper when drive.gripper); world: its MujocoWorld (lock, model);
    seed: this device's noise seed; twin_seed: the twin's; channel: a fresh CAN channel name for wire
    "can"; dynamixel_transport: "pty" | "inprocess"; now: the rig clock [s] (frame and tick timestamps:
    a lockstep run must not read the wall clock)."""

    spec: object
    bank: object
    world: object
    with_gripper: bool
    seed: int
    twin_seed: int
    channel: str
    dynamixel_transport: str
    now: Callable[[], float]


@dataclass
class TwinEndpoint:
    """A running emulator and where clients reach it. endpoint: pty path, in-process port or CAN channel.
    bus: the emulator's CAN bus (closed with it); the twin polls/emits CAN emulators every step and
    drains serial ones before stepping."""

    emulator: object
    endpoint: str
    bus: object | None = None


def _resolve(ref: str) -> Callable:
    mod, _, attr = ref.partition(":")
    return getattr(importlib.import_module(mod), attr)


@dataclass(frozen=True)
class DeviceKind:
    """One driver name of the rig files. driver_ref / emulator_ref / probe_ref / bare_probe_ref:
    "module:callable" names, imported on first call (see module doc):
      driver_ref(spec, clock, twin) -> hardware.roles Leader/Follower (twin: the Twin or None)
      emulator_ref(EmulatorContext) -> TwinEndpoint                      (None: the twin needs no wire)
      probe_ref(config, loop_hz) -> list[hardware.doctor.DeviceCheck]    (None: nothing to probe)
      bare_probe_ref(interface) -> list[hardware.doctor.Finding]         (`factr2 doctor --can IFACE`)
    wire: "serial" (config.port), "can" (config.channel + interface) or None; twin_drive(config) ->
    TwinDrive; protocol: its wire protocol in words; simulated_only: only a twin has this device (rig
    [rig] simulated = true)."""

    driver: str
    role: str
    config: type | None
    driver_ref: str
    twin_drive: Callable[[object], TwinDrive]
    wire: str | None = None
    protocol: str = ""  # what it speaks on its wire, in words ("Dynamixel Protocol 2.0")
    emulator_ref: str | None = None
    probe_ref: str | None = None
    bare_probe_ref: str | None = None
    simulated_only: bool = False

    def __post_init__(self):
        wired = self.emulator_ref is not None
        if self.role not in ROLES or self.wire not in WIRES or (self.wire is not None) != wired:
            raise ValueError(f"device kind {self.driver!r}: role {self.role!r}, wire {self.wire!r}, "
                             f"emulator {self.emulator_ref!r} do not fit")

    def make_driver(self, spec, clock, twin=None):
        return _resolve(self.driver_ref)(spec, clock, twin)

    def make_emulator(self, ctx: EmulatorContext) -> TwinEndpoint:
        return _resolve(self.emulator_ref)(ctx)

    def doctor_probe(self, config, loop_hz: float) -> list:
        return [] if self.probe_ref is None else _resolve(self.probe_ref)(config, loop_hz)

    def bare_probe(self, interface: str) -> list:
        return [] if self.bare_probe_ref is None else _resolve(self.bare_probe_ref)(interface)

    def with_endpoint(self, config, endpoint: str):
        """A copy of config that reaches a twin's endpoint (pty / in-process port, virtual CAN channel)."""
        if self.wire == "serial":
            return dataclasses.replace(config, port=endpoint)
        if self.wire == "can":
            return dataclasses.replace(config, channel=endpoint, interface="virtual")
        return config

    def endpoint_of(self, config) -> str | None:
        """The port or channel a config names (None for a kind without a wire)."""
        return getattr(config, {"serial": "port", "can": "channel"}.get(self.wire, ""), None)


@cache
def _all() -> dict[str, DeviceKind]:
    out: dict[str, DeviceKind] = {}
    for mod in KIND_MODULES:
        k = importlib.import_module(mod).KIND
        if k.driver in out:
            raise ValueError(f"device kind {k.driver!r} declared twice ({mod})")
        out[k.driver] = k
    return out


def device_kinds(role: str | None = None) -> list[DeviceKind]:
    """Every declared kind (of one role), in KIND_MODULES order."""
    return [k for k in _all().values() if role is None or k.role == role]


def device_kind(driver: str, role: str | None = None, where: str = "rig") -> DeviceKind:
    """The kind a driver name declares; ConfigError naming the choices when unknown (for this role)."""
    k = _all().get(driver)
    if k is None or (role is not None and k.role != role):
        names = sorted(x.driver for x in device_kinds(role))
        raise ConfigError(f"unknown driver {driver!r}" + (f" for a {role}" if role else ""), where=where,
                          fix=f"use one of {names}")
    return k
