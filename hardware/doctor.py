"""Hardware checks behind `factr2 doctor`: what is plugged in, and what is wrong with it, in plain words.

Every check is a function returning data plus Findings (level, subject, message, fix); the command only
prints them. Checks never write to a device (the doctor is read-only: a servo's mode, delays and torque
are left as found).

Device probes are declared by each device kind (hardware/registry.py: probe_ref for a rig's device,
bare_probe_ref for `--can IFACE`): rig_checks() probes every device of a rig with its own config,
run_can_checks() runs every kind's bare CAN probe on one interface, plus any probe registered with
register_can_check(name, probe) (probe(interface) -> list[Finding]).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field

from hardware.errors import UserError
from hardware.registry import device_kind, device_kinds
from hardware.serial_ports import SerialPortInfo, list_serial_ports

SYSFS_NET = "/sys/class/net"
ARPHRD_CAN = 280  # /sys/class/net/<if>/type of a CAN interface


@dataclass
class Finding:
    level: str  # "ok" | "info" | "warn" | "error"
    subject: str
    message: str
    fix: str = ""

    def line(self) -> str:
        tag = {"ok": "OK   ", "info": "INFO ", "warn": "WARN ", "error": "ERROR"}.get(self.level, self.level)
        return f"{tag} {self.subject}: {self.message}" + (f" -- fix: {self.fix}" if self.fix else "")


@dataclass
class DeviceCheck:
    """One probed device: a title line, detail lines (e.g. a servo table) and the findings."""

    title: str
    details: list[str] = field(default_factory=list)
    findings: list[Finding] = field(default_factory=list)

    @property
    def failed(self) -> bool:
        return any(f.level == "error" for f in self.findings)


def rig_serial_ports(rig) -> list[str]:
    """The serial ports a rig's real devices name (listed before they are probed)."""
    out = []
    for d in rig.leaders + rig.followers:
        kind = device_kind(d.driver, where=f"{rig.path}: {d.name}")
        port = kind.endpoint_of(d.config) if kind.wire == "serial" and d.config is not None else None
        if port and port != "twin":
            out.append(port)
    return out


def rig_checks(rig, loop_hz: float = 500.0) -> tuple[list[DeviceCheck], list[str]]:
    """Probe every device of a rig with its kind's probe (read-only); (checks, notes). Devices a twin
    simulates (port/channel "twin", or a simulated-only kind) are noted, not probed."""
    checks, notes = [], []
    for d in rig.leaders + rig.followers:
        kind = device_kind(d.driver, where=f"{rig.path}: {d.name}")
        if kind.simulated_only or d.config is None or kind.endpoint_of(d.config) == "twin":
            notes.append(f"{d.name}: simulated by the twin (its pty / virtual bus exists only while the twin "
                         "runs); probe a running twin with --port PTY")
            continue
        checks += kind.doctor_probe(d.config, loop_hz)
    return checks, notes


# -- ports and interfaces ----------------------------------------------------------------------------
def fallback_check(session) -> DeviceCheck:
    """Every connected device's own fallback as its driver set and read it back at connect (the Dynamixel
    Bus Watchdog, the Damiao command timeout; the Piper has none): one line each, and the one line of what a
    device that could not take it means for the operator (a warning)."""
    chk = DeviceCheck("motor-side fallbacks (what each motor does by itself if this app dies):")
    for name, dev in list(session.leaders.items()) + list(session.followers.items()):
        lines = dev.fallback_lines() if hasattr(dev, "fallback_lines") else [
            f"{name}: no motor-side fallback is known for driver {type(dev).__name__}"]
        for ln in lines:
            bad = "not set" in ln or "no motor-side" in ln
            chk.findings.append(Finding("warn" if bad else "ok", name, ln.split(": ", 1)[-1]))
    return chk


def rig_fallbacks(rig, seed: int | None = None) -> DeviceCheck:
    """Connect a rig's drivers (sim rigs: on their twin, lockstep; real rigs: torque on, motors enabled),
    take fallback_check, disconnect. Unlike the rest of the doctor this writes to the devices: it sets each
    motor's own timeout exactly as open_rig's connect does."""
    from hardware.connect import open_rig

    session = open_rig(rig, clock="lockstep" if rig.simulated else "realtime", seed=seed)
    try:
        return fallback_check(session)
    finally:
        session.close()


def check_serial_ports(extra: list[str] | None = None) -> list[SerialPortInfo]:
    return list_serial_ports(extra)


@dataclass
class CanInterface:
    name: str
    operstate: str
    up: bool


def check_can_interfaces(sysfs: str = SYSFS_NET) -> list[CanInterface]:
    """Network interfaces whose type is CAN (280), with their link state."""
    out = []
    try:
        names = sorted(os.listdir(sysfs))
    except OSError:
        return out
    for name in names:
        try:
            with open(os.path.join(sysfs, name, "type")) as f:
                if int(f.read().strip()) != ARPHRD_CAN:
                    continue
        except (OSError, ValueError):
            continue
        state = _read(os.path.join(sysfs, name, "operstate")) or "unknown"
        try:
            up = bool(int(_read(os.path.join(sysfs, name, "flags")) or "0", 16) & 0x1)
        except ValueError:
            up = False
        out.append(CanInterface(name, state, up))
    return out


def _read(path: str) -> str | None:
    try:
        with open(path) as f:
            return f.read().strip()
    except OSError:
        return None


# -- CAN hook ----------------------------------------------------------------------------------------
CanCheck = Callable[[str], list[Finding]]
_CAN_CHECKS: dict[str, CanCheck] = {}


def register_can_check(name: str, probe: CanCheck) -> None:
    """Register an extra CAN probe (the device kinds' own probes need no registration)."""
    _CAN_CHECKS[name] = probe


def run_can_checks(interface: str) -> list[Finding]:
    """Every device kind's bare CAN probe and every registered one on one interface; a probe that raises
    becomes an error finding."""
    probes = {k.driver: k.bare_probe for k in device_kinds() if k.bare_probe_ref} | _CAN_CHECKS
    if not probes:
        return [Finding("info", interface, "no CAN probe is declared (hardware/registry.py)")]
    out: list[Finding] = []
    for name, probe in probes.items():
        try:
            out += probe(interface)
        except UserError as e:
            out.append(Finding("error", f"{interface} {name}", str(e)))
        except Exception as e:  # noqa: BLE001 -- a broken probe must not stop the other checks
            out.append(Finding("error", f"{interface} {name}", f"probe failed: {type(e).__name__}: {e}"))
    return out
