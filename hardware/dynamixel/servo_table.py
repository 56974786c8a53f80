"""The control table of one emulated Dynamixel X servo (used by hardware.dynamixel.emulator).

Addresses and sizes come from hardware.dynamixel.protocol; initial values are the e-manual's factory values
except where the emulator's constructor says otherwise. Values are stored little-endian as on the servo.
"""

from __future__ import annotations

import struct
import time

from hardware.dynamixel import protocol as p
from hardware.dynamixel import watchdog as wd
from hardware.dynamixel.models import ServoModel

FIRMWARE_VERSION = 52  # default Firmware Version(6) of an emulated servo (>= 45: has Fast Sync Read)
_U16 = struct.Struct("<H")
_POS_VEL = struct.Struct("<II")  # Present Velocity(128) then Present Position(132): adjacent
_PRESENT_VEL, _PRESENT_CUR = p.ADDR_PRESENT_VELOCITY[0], p.ADDR_PRESENT_CURRENT[0]
_PRESENT_TEMP, _MOVING = p.ADDR_PRESENT_TEMPERATURE[0], p.ADDR_MOVING[0]
_REALTIME_TICK = p.ADDR_REALTIME_TICK[0]
assert p.ADDR_PRESENT_POSITION[0] == _PRESENT_VEL + 4
READ_ONLY = (
    {p.ADDR_MODEL_NUMBER[0], p.ADDR_MODEL_NUMBER[0] + 1, p.ADDR_FIRMWARE_VERSION[0]}
    | set(range(p.ADDR_HARDWARE_ERROR_STATUS[0], p.ADDR_HARDWARE_ERROR_STATUS[0] + 1))
    | set(range(p.ADDR_REALTIME_TICK[0], p.CONTROL_TABLE_SIZE))
)


class ServoTable:
    """One servo's control table (EEPROM below address 64, RAM above) and its link to a bank motor."""

    def __init__(
        self,
        dxl_id: int,
        model: ServoModel,
        index: int,
        sign: float,
        offset_rad: float,
        return_delay: int,
        operating_mode: int,
        baud_code: int,
        firmware: int = FIRMWARE_VERSION,
    ):
        self.model, self.index, self.sign, self.offset_rad = model, index, sign, offset_rad
        t = bytearray(p.CONTROL_TABLE_SIZE)
        self.table = t
        self._put(p.ADDR_MODEL_NUMBER, model.model_number)
        self._put(p.ADDR_FIRMWARE_VERSION, firmware)
        self._put(p.ADDR_ID, dxl_id)
        self.id = dxl_id  # cached: looked up on every packet
        self._put(p.ADDR_BAUD_RATE, baud_code)
        self._put(p.ADDR_RETURN_DELAY_TIME, return_delay)
        self._put(p.ADDR_OPERATING_MODE, operating_mode)
        self._put(p.ADDR_PROTOCOL_TYPE, 2)
        self._put(p.ADDR_TEMPERATURE_LIMIT, 70)
        self._put(p.ADDR_CURRENT_LIMIT, model.current_limit_units)
        self._put(p.ADDR_MAX_POSITION_LIMIT, 4095)
        self._put(p.ADDR_STATUS_RETURN_LEVEL, 2)
        self.turn_base: int | None = None  # ticks added to the raw angle so power-on reads [0, 4096)
        self.watchdog = wd.BusWatchdogState()  # Bus Watchdog(98): hardware/dynamixel/watchdog.py
        self.has_watchdog = wd.supported(model.name, firmware)

    def get(self, field: tuple[int, int], signed: bool = False) -> int:
        a, n = field
        return p.from_le(self.table[a : a + n], signed)

    def _put(self, field: tuple[int, int], value: int) -> None:
        a, n = field
        self.table[a : a + n] = p.le(int(value), n)

    @property
    def alert(self) -> int:
        """The status error byte's alert bit while Hardware Error Status(70) is set."""
        return p.ERR_ALERT_BIT if self.table[p.ADDR_HARDWARE_ERROR_STATUS[0]] else 0

    @property
    def torque_on(self) -> bool:
        return self.get(p.ADDR_TORQUE_ENABLE) == 1

    def servo_ticks(self, raw: int) -> int:
        """Present position from the raw encoder count [ticks]: turns counted from power-on."""
        if self.turn_base is None:
            self.turn_base = -(raw // p.TICKS_PER_REV) * p.TICKS_PER_REV
        return raw + self.turn_base

    def joint_angle(self, ticks: int) -> float:
        base = self.turn_base or 0
        return float(self.sign * (p.ticks_to_rad(ticks - base) - self.offset_rad))

    def refresh(self, raw_ticks: int, vel_units: int, cur_units: int, temp_c: int, moving: bool,
                tick_ms: int | None = None) -> None:
        """Latch present values (raw encoder ticks, 0.229 rpm units, current units, degC; tick_ms: Realtime
        Tick, default now)."""
        # one C call per field (this runs for every servo on every read); same bytes as _put
        t = self.table
        if self.turn_base is None:
            self.servo_ticks(raw_ticks)
        _POS_VEL.pack_into(t, _PRESENT_VEL, vel_units & 0xFFFFFFFF, (raw_ticks + self.turn_base) & 0xFFFFFFFF)
        _U16.pack_into(t, _PRESENT_CUR, max(-32768, min(32767, cur_units)) & 0xFFFF)
        t[_PRESENT_TEMP] = max(0, min(255, temp_c))
        t[_MOVING] = 1 if moving else 0
        if tick_ms is None:
            tick_ms = int(time.monotonic() * 1e3) % 32768
        _U16.pack_into(t, _REALTIME_TICK, tick_ms)

    def check_write(self, addr: int, data: bytes) -> int:
        """The status error a write would get (0: allowed): read-only or out of the table, EEPROM with
        torque on (access error 7), goal current beyond Current Limit(38) (data range error)."""
        end = addr + len(data)
        if end > p.CONTROL_TABLE_SIZE or any(a in READ_ONLY for a in range(addr, end)):
            return p.ERR_ACCESS
        if addr < p.EEPROM_END and self.torque_on:
            return p.ERR_ACCESS
        if addr <= wd.ADDR[0] < end and not self.has_watchdog:
            return p.ERR_ACCESS  # firmware before v38: no Bus Watchdog(98)
        err = wd.write_error(data, self.watchdog.latched, addr)
        if err:
            return err
        g = p.ADDR_GOAL_CURRENT[0]
        if addr <= g and g + 2 <= end:
            if abs(p.from_le(data[g - addr : g - addr + 2], True)) > self.get(p.ADDR_CURRENT_LIMIT):
                return p.ERR_DATA_RANGE
        return p.ERR_NONE

    def store(self, addr: int, data: bytes) -> None:
        self.table[addr : addr + len(data)] = data
        self.id = self.table[p.ADDR_ID[0]]
