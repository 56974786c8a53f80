"""`factr2 doctor`: list serial ports and CAN interfaces; with --port/--ids (or --rig) probe the Dynamixel
servos and CAN devices and say plainly what is wrong. Read-only: nothing is written to any device.

Exit code: 0 when no check failed, 1 when one did (a missing port, a servo that does not answer, ...).
"""

from __future__ import annotations

import argparse

from hardware import doctor as dr
from hardware.dynamixel.protocol import OP_MODE_NAMES
from hardware.errors import ConfigError

HELP = "list serial ports and CAN interfaces; ping Dynamixel servos and say what is wrong"
DEFAULT_BAUD = 4_000_000


def parse_ids(text: str) -> list[int]:
    """'1-6,9' -> [1, 2, 3, 4, 5, 6, 9]."""
    out: list[int] = []
    try:
        for part in text.split(","):
            part = part.strip()
            if not part:
                continue
            if "-" in part:
                a, b = (int(x) for x in part.split("-", 1))
                out += list(range(a, b + 1))
            else:
                out.append(int(part))
    except ValueError:
        raise ConfigError(f"cannot read ids {text!r}", where="--ids", fix="write e.g. 1-6,9") from None
    if not out or any(not 0 <= i <= 252 for i in out):
        raise ConfigError(f"ids {text!r} must be in 0..252", where="--ids", fix="write e.g. 1-6,9")
    return out


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--port",
        action="append",
        default=[],
        help="serial port (or a twin's pty) to probe; repeat for several",
    )
    parser.add_argument("--baud", type=int, default=DEFAULT_BAUD, help=f"bit/s (default {DEFAULT_BAUD})")
    parser.add_argument("--ids", default="", help="servo ids to ping, e.g. 1-6,7 (default with --port: 1-7)")
    parser.add_argument("--model", default=None, help="expected servo model, e.g. XL330-M288")
    parser.add_argument(
        "--loop-hz", type=float, default=500.0, help="loop rate to check the bus against [Hz]"
    )
    parser.add_argument("--can", action="append", default=[], help="CAN interface to probe (repeatable)")
    parser.add_argument("--rig", default=None, help="probe every device of this rig (name or .toml path)")


def _targets(args) -> tuple[list[dict], list[str], list[str]]:
    """(dynamixel probes, CAN interfaces, notes) from --port/--ids and --rig."""
    ids = parse_ids(args.ids) if args.ids else list(range(1, 8))
    probes = [dict(port=p, baud=args.baud, ids=ids, expect_model=args.model) for p in args.port]
    cans, notes = list(args.can), []
    if args.rig:
        try:
            from hardware.rigs import load_rig
        except ImportError:
            raise ConfigError(
                "rig files are not available in this install", where="--rig", fix="use --port/--ids/--baud"
            ) from None
        rig = load_rig(args.rig)
        for d in rig.leaders + rig.followers:
            c = d.config
            port, channel = getattr(c, "port", None), getattr(c, "channel", None)
            if port == "twin" or channel == "twin" or c is None:
                notes.append(
                    f"{d.name}: simulated by the twin (its pty / virtual bus exists only while the "
                    "twin runs); probe a running twin with --port PTY"
                )
                continue
            if d.driver == "dynamixel":
                rig_ids = list(c.ids) + ([c.gripper_id] if c.gripper_id is not None else [])
                model = c.model if isinstance(c.model, str) else None
                probes.append(dict(port=c.port, baud=c.baud, ids=rig_ids, expect_model=model))
            elif channel:
                cans.append(channel)
    return probes, cans, notes


def run(args) -> int:
    probes, cans, notes = _targets(args)
    failed = False
    print("serial ports:")
    ports = dr.check_serial_ports([p["port"] for p in probes])
    for info in ports:
        lat = "" if info.latency_timer_ms is None else f", latency timer {info.latency_timer_ms} ms"
        desc = f" ({info.description})" if info.description and info.description != "n/a" else ""
        print(f"  {info.path}{desc}{lat}" + ("  [pty]" if info.kind == "pty" else ""))
    if not ports:
        print("  none found (USB adapter unplugged? on Linux: /dev/ttyUSB*, /dev/ttyACM*)")
    print("CAN interfaces:")
    ifaces = dr.check_can_interfaces()
    for c in ifaces:
        print(f"  {c.name}: {'up' if c.up else 'DOWN'} ({c.operstate})")
    if not ifaces:
        print("  none found")
    for n in notes:
        print(f"note: {n}")
    for pr in probes:
        rep = dr.probe_dynamixel(pr["port"], pr["baud"], pr["ids"], args.loop_hz, pr["expect_model"])
        print(f"dynamixel {rep.port} @ {rep.baud} bit/s, ids {pr['ids']}:")
        if rep.latency_timer_ms is not None:
            print(f"  latency timer: {rep.latency_timer_ms} ms")
        if rep.servos:
            print("  id  model        fw  mode                    delay  temp  torque  hw-error")
        for s in rep.servos:
            mode = OP_MODE_NAMES.get(s.operating_mode, str(s.operating_mode))
            print(
                f"  {s.id:<3} {s.model:<12} {s.firmware:<3} {mode:<23} {s.return_delay_us:>4}us "
                f"{s.temperature_c:>3}C  {'on' if s.torque_on else 'off':<6}  {s.hardware_error}"
            )
        if rep.round_trip_s == rep.round_trip_s:
            print(f"  round trip (sync read): {1e3 * rep.round_trip_s:.2f} ms")
        for f in rep.findings:
            print(f"  {f.line()}")
            failed |= f.level == "error"
    for iface in cans:
        print(f"CAN {iface}:")
        if iface not in {c.name for c in ifaces}:
            print(f"  note: {iface} is not a CAN interface in /sys/class/net")
        for f in dr.run_can_checks(iface):
            print(f"  {f.line()}")
            failed |= f.level == "error"
    if not probes and not cans:
        print("(give --port PORT --ids 1-7 [--baud 4000000] to ping servos, --can can0, or --rig RIG)")
    print("doctor: " + ("problems found (see ERROR lines)" if failed else "no errors"))
    return 1 if failed else 0
