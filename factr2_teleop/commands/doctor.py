"""`factr2 doctor`: list serial ports and CAN interfaces; with --port/--ids (or --rig) probe the Dynamixel
servos and CAN devices and say plainly what is wrong. Read-only (nothing is written to any device), but for
--fallbacks, which connects a rig's drivers to set and read back each motor's own timeout.

Exit code: 0 when no check failed, 1 when one did (a missing port, a servo that does not answer, ...).
"""

from __future__ import annotations

import argparse
import sys

from hardware import doctor as dr
from hardware.dynamixel_probe import dynamixel_check
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
    parser.add_argument("--fallbacks", action="store_true",
                        help="with --rig: connect its drivers (a sim rig on its twin; a real rig: torque on, "
                        "motors enabled) and show each motor's own fallback as set and read back (the "
                        "Dynamixel Bus Watchdog, the Damiao command timeout, the Piper's none)")


def run(args) -> int:
    ids = parse_ids(args.ids) if args.ids else list(range(1, 8))
    rig = None
    if args.rig:
        from hardware.rigs import load_rig

        rig = load_rig(args.rig)
    failed = False
    print("serial ports:")
    ports = dr.check_serial_ports(list(args.port) + (dr.rig_serial_ports(rig) if rig else []))
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
    checks = [dynamixel_check(p, args.baud, ids, args.loop_hz, args.model) for p in args.port]
    notes: list[str] = []
    if rig is not None:
        rig_checks, notes = dr.rig_checks(rig, args.loop_hz)
        checks += rig_checks
    if args.fallbacks:
        if rig is None:
            print("error: --fallbacks needs --rig RIG", file=sys.stderr)
            return 2
        checks.append(dr.rig_fallbacks(rig))
    for n in notes:
        print(f"note: {n}")
    for chk in checks:
        print(chk.title)
        for line in chk.details:
            print(f"  {line}")
        for f in chk.findings:
            print(f"  {f.line()}")
        failed |= chk.failed
    for iface in args.can:
        print(f"CAN {iface}:")
        if iface not in {c.name for c in ifaces}:
            print(f"  note: {iface} is not a CAN interface in /sys/class/net")
        for f in dr.run_can_checks(iface):
            print(f"  {f.line()}")
            failed |= f.level == "error"
    if not checks and not args.can and not notes:
        print("(give --port PORT --ids 1-7 [--baud 4000000] to ping servos, --can can0, or --rig RIG)")
    print("doctor: " + ("problems found (see ERROR lines)" if failed else "no errors"))
    return 1 if failed else 0
