"""Read-only probe of a Dynamixel chain for `factr2 doctor`: the servos that answer and their state (model,
firmware, mode, delay, temperature, torque, hardware error, Bus Watchdog), a baud scan when ids are missing,
and the per-tick sync read's round trip against the loop rate. Findings and DeviceCheck: hardware/doctor.py.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from hardware.doctor import DeviceCheck, Finding
from hardware.dynamixel import protocol as p
from hardware.dynamixel import watchdog as wd
from hardware.dynamixel.bus import DynamixelBus
from hardware.dynamixel.models import MODELS_BY_NUMBER, model_name
from hardware.errors import UserError
from hardware.serial_ports import latency_timer_problem

HOT_C = 60  # degC: warn above this servo temperature
SCAN_BAUDS = (57600, 1_000_000, 2_000_000, 3_000_000, 4_000_000, 115200)


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
