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
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from hardware.dynamixel import protocol as p
from hardware.dynamixel import watchdog as wd
from hardware.dynamixel.bus import DynamixelBus
from hardware.dynamixel.models import MODELS_BY_NUMBER, model_name
from hardware.errors import UserError
from hardware.registry import device_kind, device_kinds
from hardware.serial_ports import SerialPortInfo, latency_timer_problem, list_serial_ports

SYSFS_NET = "/sys/class/net"
ARPHRD_CAN = 280  # /sys/class/net/<if>/type of a CAN interface
HOT_C = 60  # degC: warn above this servo temperature
SCAN_BAUDS = (57600, 1_000_000, 2_000_000, 3_000_000, 4_000_000, 115200)


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


# -- Dynamixel ---------------------------------------------------------------------------------------
@dataclass
class ServoReport:
    id: int
    model_number: int
    model: str
    firmware: int
    operating_mode: int
    return_delay_us: int
    temperature_c: int
    torque_on: bool
    hardware_error: int
    current_limit_a: float
    bus_watchdog: int | None = None  # Bus Watchdog(98) as read (unsigned byte); None: the servo has none


@dataclass
class DynamixelReport:
    port: str
    baud: int
    latency_timer_ms: int | None = None
    servos: list[ServoReport] = field(default_factory=list)
    round_trip_s: float = float("nan")
    findings: list[Finding] = field(default_factory=list)


def probe_dynamixel(
    port: str,
    baud: int,
    ids: list[int],
    loop_hz: float = 500.0,
    expect_model: str | None = None,
    rounds: int = 50,
) -> DynamixelReport:
    """Ping ids on port and read each servo's state (read-only); measure the per-tick sync read."""
    rep = DynamixelReport(port, baud)
    bus = DynamixelBus(port, baud, where="doctor")
    rep.latency_timer_ms = bus.latency_timer_ms
    prob = latency_timer_problem(port, bus.latency_timer_ms)
    if prob:
        rep.findings.append(Finding("warn", port, *prob))
    try:
        bus.open()
    except UserError as e:
        rep.findings.append(Finding("error", port, e.what, e.fix))
        return rep
    try:
        _probe_servos(bus, rep, ids, expect_model)
        live = [s.id for s in rep.servos]
        if live:
            _measure(bus, rep, live, loop_hz, rounds)
    finally:
        bus.close()
    return rep


def dynamixel_check(port: str, baud: int, ids: list[int], loop_hz: float = 500.0,
                    expect_model: str | None = None) -> DeviceCheck:
    """probe_dynamixel as a DeviceCheck: the servo table as detail lines."""
    rep = probe_dynamixel(port, baud, ids, loop_hz, expect_model)
    chk = DeviceCheck(f"dynamixel {rep.port} @ {rep.baud} bit/s, ids {ids}:", findings=list(rep.findings))
    if rep.latency_timer_ms is not None:
        chk.details.append(f"latency timer: {rep.latency_timer_ms} ms")
    if rep.servos:
        chk.details.append("id  model        fw  mode                    delay  temp  torque  hw-error  "
                           "bus watchdog")
    for s in rep.servos:
        mode = p.OP_MODE_NAMES.get(s.operating_mode, str(s.operating_mode))
        chk.details.append(f"{s.id:<3} {s.model:<12} {s.firmware:<3} {mode:<23} {s.return_delay_us:>4}us "
                           f"{s.temperature_c:>3}C  {'on' if s.torque_on else 'off':<6}  "
                           f"{s.hardware_error:<8}  "
                           f"{'none (firmware)' if s.bus_watchdog is None else wd.describe(s.bus_watchdog)}")
    if rep.round_trip_s == rep.round_trip_s:
        chk.details.append(f"round trip (sync read): {1e3 * rep.round_trip_s:.2f} ms")
    return chk


def dynamixel_checks(config, loop_hz: float) -> list[DeviceCheck]:
    """A rig's Dynamixel leader (its DynamixelLeaderConfig): the joints' and the trigger's servos."""
    ids = list(config.ids) + ([config.gripper_id] if config.gripper_id is not None else [])
    model = config.model if isinstance(config.model, str) else None
    return [dynamixel_check(config.port, int(config.baud), ids, loop_hz, model)]


def _probe_servos(bus: DynamixelBus, rep: DynamixelReport, ids: list[int], expect_model: str | None) -> None:
    missing = []
    for i in ids:
        pong = bus.ping(i)
        if pong is None:
            missing.append(i)
            continue
        number, fw = pong
        m = MODELS_BY_NUMBER.get(number)
        try:
            s = ServoReport(
                id=i,
                model_number=number,
                model=model_name(number),
                firmware=fw,
                operating_mode=bus.read(i, p.ADDR_OPERATING_MODE),
                return_delay_us=int(bus.read(i, p.ADDR_RETURN_DELAY_TIME) * p.RETURN_DELAY_UNIT_S * 1e6),
                temperature_c=bus.read(i, p.ADDR_PRESENT_TEMPERATURE),
                torque_on=bool(bus.read(i, p.ADDR_TORQUE_ENABLE)),
                hardware_error=bus.read(i, p.ADDR_HARDWARE_ERROR_STATUS),
                current_limit_a=bus.read(i, p.ADDR_CURRENT_LIMIT) * (m.amps_per_unit if m else float("nan")),
                bus_watchdog=bus.read(i, wd.ADDR) if wd.supported(model_name(number), fw) else None,
            )
        except UserError as e:
            rep.findings.append(Finding("error", f"servo {i}", e.what, e.fix))
            continue
        rep.servos.append(s)
        _judge(s, rep, expect_model)
    if missing:
        found = bus.broadcast_ping()
        if found:
            rep.findings.append(
                Finding(
                    "error",
                    bus.port_name,
                    f"id(s) {missing} did not answer; ids that answered at {bus.baud} bit/s: {found}",
                    "use the ids that answered in the rig file, or re-id the servos (Dynamixel Wizard)",
                )
            )
        else:
            rep.findings.append(_baud_scan(bus, missing))


def _baud_scan(bus: DynamixelBus, missing: list[int]) -> Finding:
    """Nothing answered: look for the servos at the other standard rates."""
    for b in SCAN_BAUDS:
        if b == bus.baud:
            continue
        bus.port.setBaudRate(b)
        found = bus.broadcast_ping()
        if found:
            bus.port.setBaudRate(bus.baud)
            return Finding(
                "error",
                bus.port_name,
                f"no servo answered at {bus.baud} bit/s, but ids {found} answer at {b} bit/s",
                f"set baud = {b} in the rig, or set the servos to {bus.baud} "
                "(Dynamixel Wizard; 4000000 recommended)",
            )
    bus.port.setBaudRate(bus.baud)
    return Finding(
        "error",
        bus.port_name,
        f"no servo answered (ids {missing}) at any standard baud",
        "check the servo power supply (XL330: 5 V) and the TTL cable; is this the right port?",
    )


def _judge(s: ServoReport, rep: DynamixelReport, expect_model: str | None) -> None:
    subj = f"servo {s.id} ({s.model})"
    if s.model_number not in MODELS_BY_NUMBER:
        rep.findings.append(
            Finding(
                "warn",
                subj,
                "model not in hardware/dynamixel/models.py: no torque constant",
                "add it there or use a supported model",
            )
        )
    if expect_model and s.model.upper() != expect_model.upper():
        rep.findings.append(
            Finding("error", subj, f"rig expects {expect_model}", "fix `model` in the rig file")
        )
    if s.return_delay_us:
        rep.findings.append(
            Finding(
                "info",
                subj,
                f"return delay {s.return_delay_us} us (costs that much per reply)",
                "the leader sets it to 0 at connect",
            )
        )
    if s.operating_mode != p.OP_MODE_CURRENT:
        rep.findings.append(
            Finding(
                "info",
                subj,
                f"operating mode {p.OP_MODE_NAMES.get(s.operating_mode, '?')}",
                "the leader switches joints to current mode at connect",
            )
        )
    if s.hardware_error:
        bits = [n for b, n in p.HW_ERROR_BITS.items() if s.hardware_error & (1 << b)]
        rep.findings.append(
            Finding(
                "error",
                subj,
                f"hardware error: {', '.join(bits) or s.hardware_error}",
                "remove the cause, then power-cycle or reboot the servo",
            )
        )
    if s.temperature_c >= HOT_C:
        rep.findings.append(
            Finding("warn", subj, f"temperature {s.temperature_c} degC", "let it cool; lower gains")
        )


def _measure(bus: DynamixelBus, rep: DynamixelReport, ids: list[int], loop_hz: float, rounds: int) -> None:
    field_ = (p.FEEDBACK_START, p.FEEDBACK_LEN)
    delay_s = max(s.return_delay_us for s in rep.servos) * 1e-6
    # generous timeout: the doctor reports replies that are truly lost, not ones a busy host was slow to take
    timeout = max(
        25.0, bus.rx_timeout_ms(len(ids) * (11 + p.FEEDBACK_LEN) + 14 + len(ids), len(ids), delay_s)
    )
    group = bus.make_sync_read(ids, field_)
    t0 = time.perf_counter()
    rep.round_trip_s, complete = bus.measure_round_trip(group, ids, timeout, n=rounds)
    hz = 1.0 / rep.round_trip_s if rep.round_trip_s > 0 else float("inf")
    msg = (
        f"one sync read of {len(ids)} servos: {1e3 * rep.round_trip_s:.2f} ms median -> about {hz:.0f} Hz "
        f"({complete}/{rounds} complete, {time.perf_counter() - t0:.2f} s)"
    )
    if complete < rounds:
        rep.findings.append(
            Finding(
                "warn",
                bus.port_name,
                msg + ": replies were lost",
                "check cabling/power; another program on the port?",
            )
        )
    elif hz < loop_hz:
        rep.findings.append(
            Finding(
                "warn",
                bus.port_name,
                msg + f", below the loop's {loop_hz:.0f} Hz",
                "baud 4000000, return delay 0, USB latency timer 1 ms",
            )
        )
    else:
        rep.findings.append(Finding("ok", bus.port_name, msg))
