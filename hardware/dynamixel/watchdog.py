"""The Dynamixel X-series Bus Watchdog(98): the servo's own fallback when its host stops talking.

What the servo does (ROBOTIS e-Manual, X-series control table, "Bus Watchdog(98)",
emanual.robotis.com/docs/en/dxl/x/xl330-m288/#bus-watchdog; source text
ROBOTIS-GIT/emanual _includes/en/dxl/control_table_buswatchdog.md):
- 0 deactivates the watchdog and clears a Bus Watchdog Error; 1..127 activates it, unit 20 ms; -1 (reads
  0xFF) is the Bus Watchdog Error status.
- It monitors the interval between Instruction Packets ("all the Instruction Packet in the DYNAMIXEL
  Protocol") while Torque Enable(64) is 1. When the interval exceeds the set value the servo stops and
  Bus Watchdog(98) becomes -1.
- While it is -1 the Goal values (Goal PWM(100), Goal Current(102), Goal Velocity(104), Goal
  Position(116)) are read-only: a write of one is answered with a Data Range Error. Writing 0 clears the
  error; a goal written after that is obeyed again.
- Available from firmware v38 (the XL330 series: every firmware).

The e-Manual says "stop" without a per-mode definition (its example, velocity mode, stops with profile
acceleration 0). The twin models it per mode as the output the servo holds: current mode 0 A, position
modes the present position, velocity/PWM modes no torque. The error byte carries no alert bit and Hardware
Error Status(70) is not touched (the manual lists neither).

Pure codec below; `BusWatchdogState` is the emulator's per-servo state machine; `arm_bus_watchdog` /
`BusWatchdogKeeper` are the leader driver's side (set at connect, read back; re-armed after a gap in its own
traffic long enough for the servo to have latched, and wherever the register reads back -1: at the loop's
first goal write and every CHECK_EVERY_S after (one sync read), since a gap the servo saw but the app's
clock did not -- a slow start before the first tick, packets held up in the USB adapter -- leaves no trace
in the app's own sends).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from hardware.dynamixel import protocol as p
from hardware.dynamixel.fast_sync import plain_sync_read_bytes
from hardware.errors import DeviceError

ADDR = p.ADDR_BUS_WATCHDOG  # (98, 1)
UNIT_S = 0.020  # s per unit of Bus Watchdog(98)
MAX_UNITS = 127
ERROR_VALUE = -1  # Bus Watchdog Error (latched): reads 0xFF unsigned
MIN_FIRMWARE = 38  # e-Manual: "Bus Watchdog (98) is available from firmware v38" (not the XL330 note)
GOAL_ADDRESSES = frozenset(  # every byte of the four Goal values
    b for a, n in (p.ADDR_GOAL_PWM, p.ADDR_GOAL_CURRENT, p.ADDR_GOAL_VELOCITY, p.ADDR_GOAL_POSITION)
    for b in range(a, a + n))

# The leader's period. The loop runs at 500 Hz (2 ms) and its own software watchdog zeroes the torque after
# 50 ms (hardware.safety.DEFAULT_WATCHDOG_S) while the app lives; the servo's watchdog is for when it does
# not. 100 ms (5 units) is 50 loop periods, twice the software watchdog and 4x the longest loop period the
# 30-minute soak measured (25.7 ms, docs/faults.md): a live loop never trips it, a dead app leaves the
# operator's hand under the last force-feedback current for at most 100 ms plus one 20 ms unit.
LEADER_PERIOD_S = 0.100

# How often the leader reads Bus Watchdog(98) back from its servos: one sync read (one round trip, 1 byte per
# servo) per 125 ticks of the 500 Hz loop, the only word a latched servo gives (a sync write has no status;
# the status error byte carries no bit for it). A servo latched unseen by the app (its packets delayed in
# the USB adapter, a twin that skipped time) refuses goals for at most this long.
CHECK_EVERY_S = 0.25


def units_for(period_s: float) -> int:
    """Bus Watchdog(98) value for a period [s]: rounded up to whole 20 ms units, 1..127."""
    if not (period_s > 0) or not math.isfinite(period_s):
        raise ValueError(f"bus watchdog period must be > 0 s, got {period_s}")
    return max(1, min(MAX_UNITS, math.ceil(period_s / UNIT_S - 1e-9)))


def period_s(value: int) -> float | None:
    """The period [s] a read-back value means; None for 0 (off) and for -1 (latched error)."""
    v = p.to_signed(int(value), 1)
    return v * UNIT_S if v > 0 else None


def describe(value: int) -> str:
    """A read-back value in words (doctor, warnings)."""
    v = p.to_signed(int(value), 1)
    if v == ERROR_VALUE:
        return "-1: tripped (latched: goals are refused until 0 is written; the leader clears it at connect)"
    if v == 0:
        return "off"
    return f"{v} x 20 ms = {v * UNIT_S * 1e3:.0f} ms"


def supported(model_name: str, firmware: int) -> bool:
    """Whether a servo has Bus Watchdog(98): firmware v38+, any XL330."""
    return model_name.upper().startswith("XL330") or int(firmware) >= MIN_FIRMWARE


# -- the emulated servo --------------------------------------------------------------------------------------
@dataclass
class BusWatchdogState:
    """One emulated servo's watchdog: last instruction time [s of the servo's clock], whether it latched."""

    last_rx_s: float = 0.0
    latched: bool = False
    trips: int = 0
    t_tripped: float | None = None  # when it last latched [s]

    def deadline(self, value: int, torque_on: bool) -> float:
        """When the watchdog expires [s] (inf: off, latched or torque off)."""
        v = p.to_signed(int(value), 1)
        if v <= 0 or not torque_on or self.latched:
            return math.inf
        return self.last_rx_s + v * UNIT_S

    def expire(self, now: float, value: int, torque_on: bool) -> bool:
        """Latch if the interval since the last instruction exceeds the set value; True when it latched now.
        The latch time is the deadline (the servo checks continuously, the emulator when asked)."""
        dl = self.deadline(value, torque_on)
        if now <= dl:
            return False
        self.latched, self.t_tripped = True, dl
        self.trips += 1
        return True


def write_error(value_bytes: bytes, latched: bool, addr: int) -> int:
    """The status error of a write starting at addr (0: allowed) under the watchdog's rules: a goal byte while
    latched, or a watchdog value outside 0..127, is a Data Range Error."""
    end = addr + len(value_bytes)
    if latched and any(b in GOAL_ADDRESSES for b in range(addr, end)):
        return p.ERR_DATA_RANGE
    a = ADDR[0]
    if addr <= a < end and not 0 <= value_bytes[a - addr] <= MAX_UNITS:
        return p.ERR_DATA_RANGE
    return p.ERR_NONE


# -- the driver's side --------------------------------------------------------------------------------
@dataclass
class ArmResult:
    """What arm_bus_watchdog set and read back: per id the value read (None: could not set), and why not."""

    units: int
    read_back: dict[int, int | None] = field(default_factory=dict)
    refused: dict[int, str] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return not self.refused and all(v == self.units for v in self.read_back.values())


def clear_bus_watchdog(bus, ids) -> None:
    """Write 0 to each servo: clears a latched Bus Watchdog Error (a crashed app's) so goals are obeyed."""
    for i in ids:
        bus.write(i, ADDR, 0)


def arm_bus_watchdog(bus, ids, period: float = LEADER_PERIOD_S) -> ArmResult:
    """Clear, then set each servo's Bus Watchdog to period [s] and read it back. A servo that refuses (old
    firmware, access error) or reads back another value is listed in .refused with the reason."""
    units = units_for(period)
    res = ArmResult(units)
    for i in ids:
        try:
            _rearm(bus, i, units)
            got = p.to_signed(bus.read(i, ADDR), 1)
        except DeviceError as e:
            res.read_back[i] = None
            res.refused[i] = e.what
            continue
        res.read_back[i] = got
        if got != units:
            res.refused[i] = f"read back {describe(got)}, wrote {units}"
    return res


def refusal_line(leader: str, res: ArmResult) -> str:
    """The one line a leader whose watchdog cannot be set gets: what it means for the operator."""
    ids = ", ".join(f"id {i} ({why})" for i, why in res.refused.items())
    return (f"leader {leader}: Bus Watchdog not set on servo {ids}: if this app dies (crash, kill, freeze), "
            "that servo keeps applying its last force-feedback current into your hand until its power is cut "
            "-- keep the servo supply's switch within reach, or update the firmware (v38+, Dynamixel Wizard)")


class BusWatchdogKeeper:
    """The driver's view of the servos' watchdog, before each goal write (a latched servo refuses goals):
    re-arms them after a gap in its own traffic long enough for them to latch (an app freeze), and reads the
    register back -- at the first goal write after check_all_next() (the loop's first tick), then every
    CHECK_EVERY_S -- to re-arm what latched on the servo's side only."""

    MARGIN = 0.8  # re-arm after gaps above this share of the period (the clocks differ: re-arm early)

    def __init__(self, ids, units: int | None):
        self.ids, self.units = list(ids), units
        self.last_tx_s: float | None = None
        self.rearms = 0
        self.found = 0  # servos found latched (or off) by a read-back, re-armed
        self._due = False
        self._check_all = False
        self._next_check_s: float | None = None

    def traffic(self, now: float) -> None:
        """The driver sent an instruction at now [s]; notes whether the gap before it may have tripped."""
        last = self.last_tx_s
        if self.units and last is not None and now - last > self.MARGIN * self.units * UNIT_S:
            self._due = True
        self.last_tx_s = now

    def mark_due(self) -> None:
        """Re-arm before the next goal write (a servo was rebooted: its watchdog is off again)."""
        self._due = True

    def check_all_next(self) -> None:
        """Read every servo back at the next goal write (the loop's first tick, however late it comes)."""
        self._check_all = True

    def rearm_if_due(self, bus, now: float) -> bool:
        """Before a goal write: clear and set again where the servos may have latched. True when it did."""
        if not self._due or not self.units:
            return False
        self._due = False
        for i in self.ids:
            try:
                _rearm(bus, i, self.units)
            except DeviceError:
                self._due = True  # try again next tick
                return False
        self.rearms += 1
        self.last_tx_s = now
        return True

    def check_if_due(self, bus, now: float) -> list[int]:
        """Before a goal write: the read-back, when due (check_all_next(), or CHECK_EVERY_S since the last);
        the ids found latched and re-armed."""
        if not self.units or not self.ids:
            return []
        if not self._check_all and self._next_check_s is not None and now < self._next_check_s:
            return []
        self._check_all, self._next_check_s = False, now + CHECK_EVERY_S
        return self.check(bus, now)

    def check(self, bus, now: float, ids=None) -> list[int]:
        """Read Bus Watchdog(98) back (one sync read: all armed servos, or ids); re-arm each that reads -1
        (latched) or anything but the period (0: rebooted or power-cycled), as the e-Manual requires: 0, then
        the period, by sync write. A servo that did not answer is read again at the next check. The ids
        re-armed."""
        ids = self.ids if ids is None else list(ids)
        wait_ms = bus.rx_timeout_ms(plain_sync_read_bytes(len(ids), ADDR[1]), len(ids))
        got = bus.sync_read(bus.make_sync_read(ids, ADDR), ids, wait_ms)
        found = [i for i in ids if i in got and p.to_signed(got[i][0][0], 1) != self.units]
        if found:  # two sync writes, no status to wait for (the loop's tick): the next check confirms them
            group = bus.make_sync_write(found, ADDR)
            for value in (0, self.units):
                bus.sync_write_ints(group, [value] * len(found))
        self.found += len(found)
        if found:
            self.last_tx_s = now
        return found


def _rearm(bus, dxl_id: int, units: int) -> None:
    """Clear a latched Bus Watchdog Error (0), then set the period again."""
    bus.write(dxl_id, ADDR, 0)
    bus.write(dxl_id, ADDR, units)
