"""Serial ports: listing what is plugged in, and the USB-serial latency timer that throttles Dynamixel loops.

FTDI/USB-serial adapters (U2D2, OpenRB bridge) buffer received bytes for `latency_timer` ms (default 16)
before handing them to the host; at 16 ms a request/reply loop cannot beat ~30 Hz. Linux exposes it at
/sys/bus/usb-serial/devices/ttyUSBn/latency_timer; set it to 1 with a udev rule (persistent) or
`echo 1 | sudo tee .../latency_timer` (until unplug). dynamixel-sdk never touches it.
"""

from __future__ import annotations

import glob
import os
from dataclasses import dataclass

LATENCY_TIMER_GOOD_MS = 1
SYSFS_USB_SERIAL = "/sys/bus/usb-serial/devices"
UDEV_RULE = (
    'ACTION=="add", SUBSYSTEM=="usb-serial", DRIVERS=="ftdi_sio", ATTR{latency_timer}="1"  '
    "(in /etc/udev/rules.d/99-dynamixel-latency.rules, then replug)"
)


@dataclass
class SerialPortInfo:
    path: str
    description: str = ""
    hwid: str = ""
    latency_timer_ms: int | None = None  # None: not a USB-serial adapter (or unreadable)
    kind: str = "serial"  # "serial" or "pty"


def latency_timer_path(port: str) -> str:
    return os.path.join(SYSFS_USB_SERIAL, os.path.basename(os.path.realpath(port)), "latency_timer")


def read_latency_timer(port: str) -> int | None:
    """The adapter's latency timer [ms], or None where the port has none (pty, ACM, not Linux)."""
    try:
        with open(latency_timer_path(port)) as f:
            return int(f.read().strip())
    except (OSError, ValueError):
        return None


def latency_timer_problem(port: str, value_ms: int | None) -> tuple[str, str] | None:
    """(what, fix) when the latency timer is above 1 ms; None when fine or unknown."""
    if value_ms is None or value_ms <= LATENCY_TIMER_GOOD_MS:
        return None
    return (
        f"USB latency timer is {value_ms} ms (limits the loop to about {1000 / (2 * value_ms):.0f} "
        "round trips/s)",
        f"echo 1 | sudo tee {latency_timer_path(port)}  or a udev rule: {UDEV_RULE}",
    )


def latency_timer_advice(port: str, value_ms: int | None) -> str | None:
    """One line saying what to do when the latency timer is above 1 ms; None when fine or unknown."""
    prob = latency_timer_problem(port, value_ms)
    return None if prob is None else f"{port}: {prob[0]} -- fix: {prob[1]}"


def list_serial_ports(extra: list[str] | None = None) -> list[SerialPortInfo]:
    """Ports from pyserial's list_ports plus /dev/ttyUSB*, /dev/ttyACM* and any extra paths (e.g. a twin's
    pty) that exist. Sorted, no duplicates."""
    found: dict[str, SerialPortInfo] = {}
    try:
        from serial.tools import list_ports

        for info in list_ports.comports():
            found[info.device] = SerialPortInfo(info.device, info.description or "", info.hwid or "")
    except Exception:  # noqa: BLE001 -- listing is best effort; the globs below still run
        pass
    for path in sorted(glob.glob("/dev/ttyUSB*") + glob.glob("/dev/ttyACM*")):
        found.setdefault(path, SerialPortInfo(path))
    for path in extra or []:
        if os.path.exists(path):
            kind = "pty" if path.startswith("/dev/pts/") else "serial"
            found.setdefault(path, SerialPortInfo(path, kind=kind))
    for info in found.values():
        info.latency_timer_ms = read_latency_timer(info.path)
    return [found[k] for k in sorted(found)]
