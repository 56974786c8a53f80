"""DynamixelLeader's set-up and tear-down: the port, the servos' ids, models and registers, the first
positions (the power-on turn), the fast-sync-read choice and the round-trip check at connect; torque off at
close.

A mixin of DynamixelLeader (leader.py: the per-tick read and write): it uses the driver's config and state.
It never falls back to a fake device: a missing port, id or wrong model is a UserError.
"""

from __future__ import annotations

import logging

import numpy as np

from hardware.dynamixel import protocol as p
from hardware.dynamixel.bus import DynamixelBus
from hardware.dynamixel.fast_sync import choose_fast_sync_read, fast_sync_read_bytes, plain_sync_read_bytes
from hardware.dynamixel.leader_math import FastReplyDecoder, decode_feedback, wrap_to_offset
from hardware.dynamixel.models import model_name
from hardware.errors import DeviceError, DeviceNotFound
from hardware.serial_ports import latency_timer_advice

PING_TRIES = 3  # pings per id at connect before the id counts as missing

log = logging.getLogger("factr2.dynamixel")


class LeaderSetup:
    """connect() and the close of DynamixelLeader (mixed in; the attributes are the driver's)."""

    def connect(self) -> None:
        c = self.config
        bus = DynamixelBus(c.port, c.baud, where=f"leader {c.name}")
        bus.open()
        self.bus = bus
        try:
            self._setup(bus)
        except BaseException:
            self.bus = None
            bus.close()
            raise

    def _setup(self, bus: DynamixelBus) -> None:
        c = self.config
        advice = latency_timer_advice(c.port, bus.latency_timer_ms)
        if advice:
            self._warn(advice)
        self._check_ids_and_models(bus)
        joint_ids = list(c.ids)
        for i, dxl_id in enumerate(joint_ids):
            bus.write(dxl_id, p.ADDR_TORQUE_ENABLE, 0)  # EEPROM is writable only with torque off
            self._clear_watchdog(bus, dxl_id)  # a crashed app's latched watchdog refuses the goal below
            info = self.servo_info[dxl_id]
            for field, want, key in (
                (p.ADDR_RETURN_DELAY_TIME, 0, "return_delay"),
                (p.ADDR_OPERATING_MODE, p.OP_MODE_CURRENT, "operating_mode"),
            ):
                have = bus.read(dxl_id, field)
                if have != want:
                    log.info("servo %d: %s %d -> %d", dxl_id, key, have, want)
                    bus.write(dxl_id, field, want)
                info[key] = want
            self.limit_units[i] = bus.read(dxl_id, p.ADDR_CURRENT_LIMIT)
            bus.write(dxl_id, p.ADDR_GOAL_CURRENT, 0)
        if c.gripper_id is not None:
            bus.write(c.gripper_id, p.ADDR_TORQUE_ENABLE, 0)  # the trigger is read only, free to move
            delay = bus.read(c.gripper_id, p.ADDR_RETURN_DELAY_TIME)
            if delay:
                bus.write(c.gripper_id, p.ADDR_RETURN_DELAY_TIME, 0)
        self._read_group = bus.make_sync_read(self.read_ids, self.field)
        self._fast_decoder = FastReplyDecoder(self.read_ids, c.read_current)
        self._limit_l = self.limit_units.tolist()  # the goal current's clip, per tick (Current Limit(38))
        self._write_group = bus.make_sync_write(joint_ids, p.ADDR_GOAL_CURRENT)
        m, ln = len(self.read_ids), self.field[1]
        plain_ms, fast_ms = (  # sized for n status packets, or for the one longer fast packet
            bus.rx_timeout_ms(n_bytes, m) if c.rx_timeout_ms is None else c.rx_timeout_ms
            for n_bytes in (plain_sync_read_bytes(m, ln), fast_sync_read_bytes(m, ln))
        )
        self.rx_timeout_ms, self.fast_read = plain_ms, False
        self._init_positions(bus)
        firmware = {i: self.servo_info[i]["firmware"] for i in self.read_ids}
        fast, why = choose_fast_sync_read(c.fast_sync_read, bus, self._read_group, self.read_ids, fast_ms,
                                          firmware)
        if fast:
            self.rx_timeout_ms, self.fast_read = fast_ms, True
        elif c.fast_sync_read is True:
            raise DeviceError(f"fast sync read not supported by {why}", where=f"leader {c.name} {c.port}",
                              fix='update the firmware (Dynamixel Wizard) or set fast_sync_read = "auto"')
        elif why:
            self._warn(f"leader {c.name}: fast sync read not supported by {why}: plain sync read")
        for dxl_id in joint_ids:
            bus.write(dxl_id, p.ADDR_TORQUE_ENABLE, 1)
        self._torque_on = True
        self._arm_watchdog(bus, joint_ids)
        zero = {i: p.le(0, 2) for i in joint_ids}
        self.round_trip_s, complete = bus.measure_round_trip(
            self._read_group, self.read_ids, self.rx_timeout_ms, self._write_group, zero, fast=self.fast_read
        )
        hz = 1.0 / self.round_trip_s if self.round_trip_s > 0 else float("inf")
        if hz < c.loop_hz:
            self._warn(
                f"leader {c.name} on {c.port}: one sync read + write takes {1e3 * self.round_trip_s:.2f} ms "
                f"-> at most {hz:.0f} Hz, below loop_hz {c.loop_hz:.0f} -- fix: baud 4000000 on servos "
                "and rig, return delay 0, USB latency timer 1 ms"
            )
        if complete < 15:
            self._warn(
                f"leader {c.name}: only {complete}/20 sync reads were complete at start-up "
                "(cabling, power or a second program on the port?)"
            )
        self.zero_torque("connected")  # known zero start; also starts the safety layer's rate-limit clock
        if self._wd is not None:  # however late the loop's first tick comes, it reads the servos back
            self._wd.check_all_next()

    def _check_ids_and_models(self, bus: DynamixelBus) -> None:
        c = self.config
        answered: dict[int, tuple[int, int]] = {}
        for dxl_id in self.read_ids:
            for _ in range(PING_TRIES):  # a single lost packet must not fail the start-up
                r = bus.ping(dxl_id)
                if r is not None:
                    answered[dxl_id] = r
                    break
        missing = [i for i in self.read_ids if i not in answered]
        if missing:
            on_bus = bus.broadcast_ping()
            hint = (
                "no servo answered: check the servo supply and that the servos' baud matches"
                if not on_bus
                else "set the rig's ids to the servos' ids (or change the servo ids with Dynamixel Wizard)"
            )
            raise DeviceNotFound(
                f"servo id(s) {missing} did not answer at {c.baud} bit/s; ids that answered: "
                f"{on_bus or 'none'}",
                where=f"leader {c.name} {c.port}",
                fix=hint,
            )
        wrong = []
        expected = dict(zip(c.ids, self.models))
        if c.gripper_id is not None:
            expected[c.gripper_id] = self.gripper_model
        for dxl_id, (number, fw) in answered.items():
            self.servo_info[dxl_id] = {"model_number": number, "model": model_name(number), "firmware": fw}
            if number != expected[dxl_id].model_number:
                wrong.append(
                    f"id {dxl_id} is {model_name(number)} (#{number}), config says "
                    f"{expected[dxl_id].name} (#{expected[dxl_id].model_number})"
                )
        if wrong:
            raise DeviceError(
                "; ".join(wrong),
                where=f"leader {c.name} {c.port}",
                fix="set `model` in the rig file to the servos actually fitted",
            )

    def _init_positions(self, bus: DynamixelBus) -> None:
        for _ in range(10):
            got = bus.sync_read(self._read_group, self.read_ids, max(self.rx_timeout_ms, 20.0))
            if len(got) == len(self.read_ids):
                break
        else:
            raise DeviceError(
                "no complete sync read of the servos' positions in 10 tries",
                where=f"leader {self.config.name} {self.config.port}",
                fix="check cabling and power; run `factr2 doctor --port ...`",
            )
        ticks = np.array([decode_feedback(got[i][0], self.config.read_current)[2] for i in self.read_ids])
        offsets = (
            np.append(self.offsets, 0.5 * (self.config.gripper_open_rad + self.config.gripper_closed_rad))
            if self.config.gripper_id is not None
            else self.offsets
        )
        self._q_servo = wrap_to_offset(p.ticks_to_rad(ticks), offsets)
        self._ticks_prev = ticks

    def _disconnect_bus(self) -> None:
        bus, self.bus = self.bus, None
        if bus is None:
            return
        try:
            for dxl_id in self.config.ids:
                try:
                    bus.write(dxl_id, p.ADDR_TORQUE_ENABLE, 0)
                except DeviceError as e:
                    log.warning("leader %s: torque off failed: %s", self.config.name, e)
            if self._wd is not None:  # after torque off (first, at once): one latched since the last
                try:  # read-back refused the stop's 0 A and would keep its last goal in the register
                    for dxl_id in self._wd.check(bus, self.clock.now()):
                        bus.write(dxl_id, p.ADDR_GOAL_CURRENT, 0)
                        log.warning("leader %s: servo %d's Bus Watchdog had latched: re-armed, 0 A written",
                                    self.config.name, dxl_id)
                except DeviceError as e:
                    log.warning("leader %s: Bus Watchdog read-back at close failed: %s", self.config.name, e)
        finally:
            self._torque_on = False
            bus.close()
