"""Open a python-can bus with one-line errors; the codec helpers, driver link and emulator wire side shared
by the CAN followers.

open_bus() is the only place the CAN followers (Piper, Damiao) create a bus. Failures become
hardware.errors.DeviceNotFound / DeviceError naming the channel and the fix (bring the link up at 1 Mbit/s,
install the adapter's library, ...). For interface "virtual" it returns a FastVirtualBus
(hardware/can_virtual_bus.py), the twins' cheap in-process bus.
"""

from __future__ import annotations

import errno
import os
import random
from enum import Enum

import can

from hardware.can_virtual_bus import FastVirtualBus
from hardware.errors import DeviceError, DeviceNotFound
from hardware.reasons import Reason, messages

CAN_BITRATE_DEFAULT = 1_000_000  # bit/s: Piper and YAM (Damiao) both run classic CAN at 1 Mbit/s
SYSFS_NET = "/sys/class/net"
_IFF_UP = 0x1  # net_device flags bit: the administrator brought the link up
# bits on the wire of a classic 11-bit data frame with 8 data bytes: 44 overhead + 64 data + 3 interframe,
# before bit stuffing (stuffing adds up to ~20 %)
FRAME_BITS_8B = 111


def bus_load(frames_per_s: float, bitrate: int = CAN_BITRATE_DEFAULT) -> float:
    """Fraction of a classic CAN bus used by this many 8-byte frames per second (no stuffing; real load is
    up to ~20 % higher). Above about 0.7 expect arbitration delays and lost low-priority frames."""
    return frames_per_s * FRAME_BITS_8B / bitrate


def link_up_fix(channel: str, bitrate: int = CAN_BITRATE_DEFAULT) -> str:
    return f"sudo ip link set {channel} up type can bitrate {bitrate}"


class CanLinkProblem(Enum):
    """Why a socketcan channel cannot work (hardware.reasons)."""

    MISSING = "missing"
    DOWN = "down"


messages({CanLinkProblem.MISSING: "no such CAN interface", CanLinkProblem.DOWN: "CAN interface is down"})


def _socketcan_problem(channel: str) -> Reason | None:
    """Why a socketcan channel cannot work, from sysfs (None when it looks fine or sysfs is absent)."""
    if not os.path.isdir(SYSFS_NET):
        return None
    path = os.path.join(SYSFS_NET, channel)
    if not os.path.exists(path):
        return Reason.of(CanLinkProblem.MISSING)
    try:
        with open(os.path.join(path, "flags")) as f:
            flags = int(f.read().strip(), 16)
    except (OSError, ValueError):
        return None
    if not flags & _IFF_UP:
        return Reason.of(CanLinkProblem.DOWN)
    return None


def open_bus(channel: str, interface: str = "socketcan", bitrate: int = CAN_BITRATE_DEFAULT,
             **kwargs) -> can.BusABC:
    """Open a CAN bus. Raises DeviceNotFound (missing channel, link down, adapter library missing) or
    DeviceError (bus opens but refuses to work), each a single line with the fix."""
    where = f"CAN {interface}:{channel}"
    if not channel:
        raise DeviceNotFound("no CAN channel given", where=where,
                             fix="set channel (e.g. can0) in the rig file")
    if interface == "virtual":
        return FastVirtualBus(channel=channel, **kwargs)
    if interface == "pty":  # a twin served by another process (hardware/can_pty.py)
        from hardware.can_pty import PtyCanBus

        try:
            return PtyCanBus(channel)
        except can.CanInitializationError as e:
            raise DeviceNotFound(str(e), where=where, fix="start the twin (factr2 twin --can-pty) and use "
                                 "the channel it prints") from None
    if interface == "socketcan":
        problem = _socketcan_problem(channel)
        if problem is not None:
            fix = link_up_fix(channel, bitrate)
            if problem.kind is CanLinkProblem.MISSING:
                fix = f"plug in the USB-CAN adapter, check `ip link show` for its name, then `{fix}`"
            raise DeviceNotFound(str(problem), where=where, fix=fix)
    try:
        if interface == "socketcan":  # socketcan takes its bitrate from `ip link`, not from python-can
            return can.Bus(interface=interface, channel=channel, **kwargs)
        return can.Bus(interface=interface, channel=channel, bitrate=bitrate, **kwargs)
    except can.CanInterfaceNotImplementedError as e:
        fix = "use interface \"socketcan\" on Linux, or install the adapter's driver"
        raise DeviceNotFound(f"python-can interface not available ({e})", where=where, fix=fix) from None
    except (can.CanError, OSError, ValueError) as e:
        err = getattr(e, "errno", None) or getattr(e, "error_code", None)
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        if err in (errno.ENODEV, errno.ENOENT, errno.EAFNOSUPPORT) or "No such" in msg:
            fix = link_up_fix(channel, bitrate)
            if err == errno.EAFNOSUPPORT:
                fix = "this kernel has no SocketCAN support: `sudo modprobe can can_raw`, or use a Linux host"
            raise DeviceNotFound(f"cannot open CAN channel ({msg})", where=where, fix=fix) from None
        raise DeviceError(f"cannot open CAN channel ({msg})", where=where,
                          fix=f"check the adapter and `{link_up_fix(channel, bitrate)}`") from None


# ---- codec helpers shared by the CAN protocols (pure) ------------------------------------------------
def float_to_uint(x: float, lo: float, hi: float, bits: int) -> int:
    """Clamp x into [lo, hi], then int((x - lo) * (2^bits - 1) / span) (truncation, as the vendors do)."""
    x = lo if not x >= lo else hi if x > hi else x  # NaN -> lo
    return int((x - lo) * ((1 << bits) - 1) / (hi - lo))


def uint_to_float(u: int, lo: float, hi: float, bits: int) -> float:
    return u * (hi - lo) / ((1 << bits) - 1) + lo


class RejectCounters:
    """Frames rejected by a decoder, by reason (cumulative)."""

    def __init__(self):
        self.ok = 0
        self.bad_dlc = 0
        self.unknown_id = 0
        self.bad_crc = 0
        self.bad_frame = 0  # extended id, remote or error frame where a data frame is expected

    def as_dict(self) -> dict[str, int]:
        return dict(vars(self))

    @property
    def rejected(self) -> int:
        return self.bad_dlc + self.unknown_id + self.bad_crc + self.bad_frame


def frame_ok(counters: RejectCounters, known: frozenset, arb_id: int, data, is_ext: bool,
             is_special: bool, dlc: int = 8) -> bool:
    """Shared validation: standard 11-bit data frame, known id, expected DLC."""
    if is_ext or is_special:
        counters.bad_frame += 1
        return False
    if arb_id not in known:
        counters.unknown_id += 1
        return False
    if len(data) != dlc:
        counters.bad_dlc += 1
        return False
    return True


def send_error_is_fatal(e: Exception) -> bool:
    """A send error that will not go away by itself (link down, adapter gone) vs. a transient one
    (tx buffer full, ENOBUFS) that the loop counts and survives."""
    return getattr(e, "errno", None) in (errno.ENETDOWN, errno.ENODEV, errno.ENXIO)


WAIT_STEP_S = 1e-3  # s: how far a lockstep clock is advanced per poll while waiting for a reply


class CanLink:
    """Thin I/O shell around one open bus for a driver: send with counted transient errors, non-blocking
    drain, and a wait that works on real time (blocking recv) and on a LockstepClock (sleep advances the
    twin)."""

    def __init__(self, bus: can.BusABC, channel: str, interface: str, clock,
                 bitrate: int = CAN_BITRATE_DEFAULT):
        self.bus, self.channel, self.clock, self.bitrate = bus, channel, clock, bitrate
        self.where = f"CAN {interface}:{channel}"
        self.tx_frames = 0
        self.tx_errors = 0  # transient send failures (tx buffer full), cumulative
        self.rx_frames = 0
        self._send_fresh = getattr(bus, "send_fresh", None)  # FastVirtualBus shortcuts
        self._take_pending = getattr(bus, "take_pending", None)
        self._take_raw = getattr(bus, "take_pending_raw", None)
        self._send_batch = getattr(bus, "send_batch", None)  # a twin's channel: a command's frames at once
        if hasattr(bus, "set_clock"):  # a virtual bus stamps frames with the driver's clock, not wall time
            bus.set_clock(clock.now)

    def send(self, arb_id: int, data: bytes) -> bool:
        try:
            if self._send_fresh is not None:
                self._send_fresh(arb_id, data)
            else:
                self.bus.send(can.Message(arbitration_id=arb_id, data=data, is_extended_id=False,
                                          check=False))
        except (can.CanError, OSError) as e:
            if send_error_is_fatal(e):
                raise DeviceError(f"CAN send failed ({e})", where=self.where,
                                  fix=link_up_fix(self.channel, self.bitrate)) from None
            self.tx_errors += 1
            return False
        self.tx_frames += 1
        return True

    def send_all(self, frames: list[tuple[int, bytes]]) -> bool:
        """send() each (arb_id, data) of frames, in order; False if any failed. A bus that takes a batch (a
        twin's virtual or pty channel) gets them in one call, stamped with one clock reading (the 500 Hz
        loop's command is 4-5 frames: one call instead of one per frame and receiver); a real bus gets one
        send per frame as before."""
        if self._send_batch is None:
            ok = True
            for arb_id, data in frames:
                ok = self.send(arb_id, data) and ok
            return ok
        try:
            self._send_batch(frames)
        except (can.CanError, OSError) as e:
            if send_error_is_fatal(e):
                raise DeviceError(f"CAN send failed ({e})", where=self.where,
                                  fix=link_up_fix(self.channel, self.bitrate)) from None
            self.tx_errors += len(frames)
            return False
        self.tx_frames += len(frames)
        return True

    def drain(self, push, push_raw=None) -> int:
        """Hand every pending frame to push(msg) without blocking; returns how many. push_raw(frames): the
        same without Message objects, the frames as a list of (arb_id, data, is_extended_id,
        is_remote_or_error), used on a FastVirtualBus (a twin's feedback stream: its bursts are never turned
        into Messages)."""
        if push_raw is not None and self._take_raw is not None:
            frames = self._take_raw()
            if frames is not None:
                push_raw(frames)
                self.rx_frames += len(frames)
                return len(frames)
        if self._take_pending is not None:  # FastVirtualBus: one call for the lot
            msgs = self._take_pending()
            for msg in msgs:
                push(msg)
            self.rx_frames += len(msgs)
            return len(msgs)
        recv, n = self.bus.recv, 0
        while True:
            msg = recv(0)
            if msg is None:
                self.rx_frames += n
                return n
            push(msg)
            n += 1

    def wait(self, done, timeout_s: float, push) -> bool:
        """Drain frames into push until done() is true or timeout_s [s of the clock] passed."""
        clock = self.clock
        t_end = clock.now() + timeout_s
        while True:
            self.drain(push)
            if done():
                return True
            left = t_end - clock.now()
            if left <= 0:
                return False
            if clock.realtime:
                msg = self.bus.recv(timeout=min(WAIT_STEP_S * 5, left))
                if msg is not None:
                    self.rx_frames += 1
                    push(msg)
            else:
                clock.sleep(WAIT_STEP_S)

    def close(self) -> None:
        try:
            self.bus.shutdown()
        except (can.CanError, OSError):
            pass


class CanEmulatorIO:
    """Wire side shared by the CAN emulators (Piper, Damiao): fault injection and counters.

    drop_prob: each frame in either direction is lost with this probability (seeded, deterministic);
    silent: the device sends nothing (a device that stopped answering)."""

    def _init_io(self, bus, drop_prob: float, seed: int) -> None:
        self.bus = bus
        self.drop_prob = float(drop_prob)
        self.silent = False
        self._rng = random.Random(seed)
        self._send_fresh = getattr(bus, "send_fresh", None)  # FastVirtualBus shortcuts (no extra Message)
        self._send_batch = getattr(bus, "send_batch", None)
        self._take_pending = getattr(bus, "take_pending", None)  # None: recv(0) until None
        self.rx_frames = self.tx_frames = self.dropped = self.ignored = 0

    def _lost(self) -> bool:
        """True when the frame at hand is dropped by the injected loss (counted)."""
        if self.drop_prob and self._rng.random() < self.drop_prob:
            self.dropped += 1
            return True
        return False

    def _send(self, arb_id: int, data: bytes) -> None:
        if self.silent or self._lost():
            return
        if self._send_fresh is not None:
            self._send_fresh(arb_id, data)
        else:
            self.bus.send(can.Message(arbitration_id=arb_id, data=data, is_extended_id=False, check=False))
        self.tx_frames += 1

    def _send_all(self, frames: list) -> None:
        """_send each (arb_id, data) of frames in order; one bus call when nothing can be lost or muted."""
        if self._send_batch is None or self.silent or self.drop_prob:
            for arb_id, data in frames:
                self._send(arb_id, data)
            return
        self._send_batch(frames)
        self.tx_frames += len(frames)
