"""DynamixelLeader: a GELLO-style leader arm of Dynamixel X servos in current mode (dynamixel-sdk only).

Per tick: ONE sync read (a Fast Sync Read where the chain has it: fast_sync.py) of present current/velocity/
position (126..135, 10 bytes; 8 from 128 without current) and ONE sync write of goal current (102).
Joint convention (config): q_joint = sign * (q_servo - offset_rad); joint torque tau = sign * K * current.

Multi-turn: present position restarts within one turn at power-on, so at connect each servo's angle is
moved by the 2*pi multiple that brings it closest to its stored offset (the joint then reads within
+-pi of zero); afterwards the driver integrates tick deltas (wrapped to +-half a turn), which also works
when a servo is in single-turn position mode.

The math (decode, unwrap, torque<->current, trigger mapping) is in pure functions below; the class is the
I/O shell. It never falls back to a fake device: a missing port, id or wrong model is a UserError.
"""

from __future__ import annotations

import functools
import logging
import math
import struct

import numpy as np

from hardware.clock import Clock
from hardware.dynamixel import protocol as p
from hardware.dynamixel import watchdog as wd
from hardware.dynamixel.alerts import AlertRebooter
from hardware.dynamixel.bus import DynamixelBus
from hardware.dynamixel.config import DynamixelLeaderConfig
from hardware.dynamixel.fast_sync import choose_fast_sync_read, fast_sync_read_bytes, plain_sync_read_bytes
from hardware.dynamixel.models import ServoModel, get_model, model_name, resolve_models
from hardware.errors import ConfigError, DeviceError, DeviceNotFound
from hardware.roles import Leader
from hardware.safety import DEFAULT_WATCHDOG_S, SafeLeaderTorque
from hardware.serial_ports import latency_timer_advice
from hardware.types import STATUS_COMM_LOST, STATUS_DRIVER_ERROR, STATUS_ENABLED, STATUS_STALE, JointState

PING_TRIES = 3  # pings per id at connect before the id counts as missing

log = logging.getLogger("factr2.dynamixel")
TWO_PI = 2.0 * math.pi
HALF_TURN_TICKS = p.TICKS_PER_REV // 2
_TICK_MASK = p.TICKS_PER_REV - 1  # TICKS_PER_REV (4096) is a power of two: x & mask == x % TICKS_PER_REV


# -- pure math ---------------------------------------------------------------------------------------
def decode_feedback(data: bytes, with_current: bool) -> tuple[int, int, int]:
    """(current units, velocity units, position ticks), signed, from one servo's sync-read block."""
    cur = p.from_le(data[0:2], True) if with_current else 0
    k = 2 if with_current else 0
    return cur, p.from_le(data[k : k + 4], True), p.from_le(data[k + 4 : k + 8], True)


@functools.lru_cache(maxsize=8)
def _blocks_struct(with_current: bool, m: int) -> struct.Struct:
    """decode_feedback's fields of m servo blocks back to back, flat: (current,) velocity, position each."""
    return struct.Struct("<" + ("hii" if with_current else "ii") * m)


def wrap_to_offset(q_servo_rad: np.ndarray, offset_rad: np.ndarray) -> np.ndarray:
    """q_servo + 2*pi*k with k chosen so the result is closest to offset (resolves power-on turns)."""
    q, off = np.asarray(q_servo_rad, float), np.asarray(offset_rad, float)
    return q + TWO_PI * np.round((off - q) / TWO_PI)


def wrapped_tick_delta(ticks_now: np.ndarray, ticks_prev: np.ndarray) -> np.ndarray:
    """Tick difference wrapped to [-2048, 2048): a servo cannot turn half a revolution in one tick."""
    d = np.asarray(ticks_now, np.int64) - np.asarray(ticks_prev, np.int64)
    return (d + HALF_TURN_TICKS) % p.TICKS_PER_REV - HALF_TURN_TICKS


def servo_to_joint(q_servo_rad, signs, offsets_rad) -> np.ndarray:
    return np.asarray(signs, float) * (np.asarray(q_servo_rad, float) - np.asarray(offsets_rad, float))


def torque_to_current_units(tau_nm, signs, k_nm_per_a, amps_per_unit, limit_units) -> np.ndarray:
    """Joint torques [N*m] -> servo goal-current units (sign applied, clipped to the Current Limit)."""
    amps = np.asarray(signs, float) * np.asarray(tau_nm, float) / np.asarray(k_nm_per_a, float)
    return p.amps_to_current_units(amps, amps_per_unit, limit_units)


def torque_to_current_ints(tau_nm: list[float], signs: list[float], k_nm_per_a: list[float],
                           amps_per_unit: list[float], limit_units: list[float]) -> list[int]:
    """torque_to_current_units on plain floats, bit for bit (the 500 Hz path): sign * tau / K / amps per
    unit, a non-finite value 0, clipped to +-limit (numpy's maximum / minimum: a NaN limit wins), rounded
    half to even (np.rint; Python's round of a float does the same)."""
    out = []
    isfinite = math.isfinite
    for t, s, k, a, lim in zip(tau_nm, signs, k_nm_per_a, amps_per_unit, limit_units, strict=True):
        u = s * t / k / a
        u = u if isfinite(u) else 0.0
        lo = -lim
        u = u if (u > lo or u != u) else lo
        u = u if (u < lim or u != u) else lim
        out.append(round(u))
    return out


def trigger_fraction(q_servo_rad: float, open_rad: float, closed_rad: float) -> float:
    """Trigger servo angle -> 0 (open) .. 1 (closed), clipped."""
    span = closed_rad - open_rad
    if span == 0 or not math.isfinite(q_servo_rad):
        return float("nan")
    return min(max((float(q_servo_rad) - open_rad) / span, 0.0), 1.0)


# -- driver ----------------------------------------------------------------------------------------
class DynamixelLeader(Leader):
    """Leader role over a Dynamixel chain. warnings: start-up problems found by connect() (also logged)."""

    wrap_period_rad = TWO_PI  # single-turn encoders: the turn is inferred, so a reading can be one off

    def __init__(
        self,
        config: DynamixelLeaderConfig,
        limits,
        clock: Clock | None = None,
        watchdog_s: float = DEFAULT_WATCHDOG_S,
    ):
        super().__init__(config.name, limits, clock, watchdog_s)
        c, n = config, limits.n
        for field_name in ("ids", "signs", "offsets_rad"):
            if len(getattr(c, field_name)) != n:
                raise ConfigError(
                    f"{field_name} has {len(getattr(c, field_name))} entries, the arm has {n} joints",
                    where=f"leader {c.name}",
                    fix=f"give one {field_name} entry per joint",
                )
        if not (c.fast_sync_read is True or c.fast_sync_read is False or c.fast_sync_read == "auto"):
            raise ConfigError(f"fast_sync_read is {c.fast_sync_read!r}", where=f"leader {c.name}",
                              fix='use "auto", true or false')
        if any(s not in (1, -1) for s in c.signs):
            raise ConfigError("signs must be +1 or -1", where=f"leader {c.name}", fix="fix the signs list")
        all_ids = list(c.ids) + ([c.gripper_id] if c.gripper_id is not None else [])
        if len(set(all_ids)) != len(all_ids):
            raise ConfigError(
                f"servo ids repeat: {all_ids}", where=f"leader {c.name}", fix="ids must be unique"
            )
        self.config = c
        self.models: list[ServoModel] = resolve_models(c.model, n)
        self.gripper_model = get_model(c.gripper_model) if c.gripper_model else self.models[0]
        self.k = np.array(
            c.torque_constant_nm_per_a
            if c.torque_constant_nm_per_a is not None
            else [m.torque_constant for m in self.models],
            float,
        )
        if self.k.shape != (n,) or np.any(~(self.k > 0)):
            raise ConfigError(
                "torque_constant_nm_per_a needs one positive value per joint",
                where=f"leader {c.name}",
                fix="fix or remove torque_constant_nm_per_a",
            )
        self.signs = np.array(c.signs, float)
        self._signs_l, self._k_l = self.signs.tolist(), self.k.tolist()  # the per-tick float paths' copies
        self._nan_n = np.full(n, np.nan)  # per-tick templates (copied: a copy is 5x cheaper than np.full)
        self._status_zero = np.zeros(n, np.uint32)
        self._status_enabled = np.full(n, STATUS_ENABLED, np.uint32)
        self.offsets = np.array(c.offsets_rad, float)
        self.amps_per_unit = np.array([m.amps_per_unit for m in self.models])
        self.limit_units = np.array([m.current_limit_units for m in self.models], float)
        self._amps_l = self.amps_per_unit.tolist()
        self.read_ids = all_ids
        self.field = (
            (p.FEEDBACK_START, p.FEEDBACK_LEN)
            if c.read_current
            else (p.FEEDBACK_NO_CURRENT_START, p.FEEDBACK_NO_CURRENT_LEN)
        )
        self.bus: DynamixelBus | None = None
        self.warnings: list[str] = []
        self.round_trip_s = float("nan")
        self.rx_timeout_ms = float("nan")
        self.fast_read = False  # Fast Sync Read in use (chosen at connect, see config.fast_sync_read)
        self.servo_info: dict[int, dict] = {}
        self.lost_reads = 0  # sync reads where at least one servo did not answer
        self.failed_writes = 0
        self._ticks_prev: np.ndarray | None = None
        self._q_servo: np.ndarray | None = None
        self._torque_on = False
        self.alerts = AlertRebooter()  # reboots a servo whose hardware alert lasts (dynamixel/alerts.py)
        self.fallback: wd.ArmResult | None = None  # the servos' Bus Watchdog as set and read back at connect
        self._wd: wd.BusWatchdogKeeper | None = None
        self._wd_reboots = 0  # servo reboots seen by the keeper (a reboot turns the watchdog off)

    # -- connect -------------------------------------------------------------------------------------
    @property
    def is_connected(self) -> bool:
        return self.bus is not None and self.bus.is_open

    def _warn(self, msg: str) -> None:
        self.warnings.append(msg)
        log.warning(msg)

    @property
    def offsets(self) -> np.ndarray:
        """Calibration offsets per servo [rad] (the servo angle at the joint's zero). Setting them (a
        restart's stored offsets, a recalibration) also refreshes the 500 Hz decode's float copy: a stale
        copy would read every sample a turn off."""
        return self._offsets

    @offsets.setter
    def offsets(self, value) -> None:
        self._offsets = np.array(value, float)
        self._offsets_l = self._offsets.tolist()

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

    # -- per tick ------------------------------------------------------------------------------------
    def _read(self) -> JointState | None:
        if self.bus is None or self._q_servo is None:
            raise DeviceError(
                "leader is not connected", where=f"leader {self.config.name}", fix="call connect() first"
            )
        n, rc = self.n_joints, self.config.read_current
        got = self.bus.sync_read(self._read_group, self.read_ids, self.rx_timeout_ms, self.fast_read)
        if len(got) == len(self.read_ids):
            if self._wd is not None:
                self._wd.traffic(self.clock.now())  # the servos heard this tick
            return self._state_all_fresh(got)
        prev = self._last_state  # some servos did not answer: they keep the previous sample, flagged stale
        m = len(self.read_ids)  # joints, then the trigger (if any)
        st = JointState(t=self.clock.now(), q=prev.q.copy(), q_dot=prev.q_dot.copy(), tau_m=prev.tau_m.copy(),
                        current=prev.current.copy(), q_cmd=np.full(n, np.nan), temperature=np.full(n, np.nan),
                        status=np.zeros(n, np.uint32), gripper_pos=prev.gripper_pos,
                        gripper_effort=prev.gripper_effort)
        fresh = np.zeros(m, bool)
        raw = np.zeros((m, 3), np.int64)  # current units, velocity units, position ticks
        alert = np.zeros(m, bool)
        for k, dxl_id in enumerate(self.read_ids):
            if dxl_id in got:
                data, err = got[dxl_id]
                raw[k] = decode_feedback(data, rc)
                fresh[k], alert[k] = True, bool(err & p.ERR_ALERT_BIT)
        delta = np.where(fresh, wrapped_tick_delta(raw[:, 2], self._ticks_prev), 0)
        self._ticks_prev = np.where(fresh, raw[:, 2], self._ticks_prev)
        self._q_servo += delta * p.RAD_PER_TICK
        j = fresh[:n]
        q = servo_to_joint(self._q_servo[:n], self.signs, self.offsets)
        qd = self.signs * p.velocity_units_to_rad_s(raw[:n, 1])
        st.q[j], st.q_dot[j] = q[j], qd[j]
        if rc:
            cur = self.signs * raw[:n, 0] * self.amps_per_unit
            st.current[j], st.tau_m[j] = cur[j], (self.k * cur)[j]
        st.status[~j] |= np.uint32(STATUS_STALE | STATUS_COMM_LOST)
        if alert.any():
            st.status[alert[:n]] |= np.uint32(STATUS_DRIVER_ERROR)
        if alert.any() or self.alerts.pending:
            ids = self.read_ids
            self.alerts.service(self, [ids[k] for k in range(m) if alert[k]],
                                 {ids[k] for k in range(m) if fresh[k]})
        if m > n and fresh[n]:
            st.gripper_pos, st.gripper_effort = self._trigger(int(raw[n, 0]))
        if self._torque_on:
            st.status |= np.uint32(STATUS_ENABLED)
        self.lost_reads += 1
        self._last_state = st  # fresh where not flagged stale; the watchdog is not fed
        return None

    def _state_all_fresh(self, got: dict[int, tuple[bytes, int]]) -> JointState:
        """The usual tick: every servo answered. Whole new arrays, decoded at once (the loop's hot path:
        the same values as the general path in _read, bit for bit, with as few small-array operations as
        it takes: the fields read from one structured view, the tick delta unwrapped inline)."""
        n, rc, ids, prev = self.n_joints, self.config.read_current, self.read_ids, self._last_state
        t = self.clock.now()
        blocks = [got[i] for i in ids]
        vals = _blocks_struct(rc, len(ids)).unpack(b"".join([b[0] for b in blocks]))
        w = 3 if rc else 2  # (current,) velocity, position per servo
        tp = self._ticks_prev if type(self._ticks_prev) is list else self._ticks_prev.tolist()
        ticks = list(vals[w - 1::w])
        qs = self._q_servo.tolist()
        for j, (x, x0) in enumerate(zip(ticks, tp, strict=True)):
            # wrapped_tick_delta: & (TICKS_PER_REV - 1) is its % (a power-of-two turn, negatives too)
            qs[j] += (((x - x0 + HALF_TURN_TICKS) & _TICK_MASK) - HALF_TURN_TICKS) * p.RAD_PER_TICK
        self._q_servo, self._ticks_prev = np.array(qs), ticks
        signs, vel = self._signs_l, vals[w - 2::w]
        if rc:
            cur_l = [s * c * a for s, c, a in zip(signs, vals[0:w * n:w], self._amps_l)]
            cur, tau = np.array(cur_l), np.array([k * c for k, c in zip(self._k_l, cur_l)])
        else:
            cur, tau = prev.current.copy(), prev.tau_m.copy()
        status = (self._status_enabled if self._torque_on else self._status_zero).copy()
        alert = p.ERR_ALERT_BIT
        if self.alerts.pending or any(b[1] & alert for b in blocks):
            errs = [b[1] for b in blocks]
            if any(e & alert for e in errs[:n]):
                status[np.array([bool(e & alert) for e in errs[:n]])] |= np.uint32(STATUS_DRIVER_ERROR)
            alerting = [i for i, e in zip(ids, errs, strict=True) if e & alert]
            self.alerts.service(self, alerting, set(ids))
        grip_pos, grip_effort = self._trigger(vals[w * n] if rc else 0) if len(ids) > n else (
            prev.gripper_pos, prev.gripper_effort)
        nan = self._nan_n
        r = p.RAD_S_PER_VELOCITY_UNIT
        return JointState(t=t, q=np.array([s * (x - o) for s, x, o in zip(signs, qs, self._offsets_l)]),
                          q_dot=np.array([s * (v * r) for s, v in zip(signs, vel)]), tau_m=tau,
                          current=cur, q_cmd=nan.copy(), temperature=nan.copy(), status=status,
                          gripper_pos=grip_pos, gripper_effort=grip_effort)

    def _trigger(self, current_units: int) -> tuple[float, float]:
        """(gripper_pos, gripper_effort [N*m]) of the trigger servo just read (its angle in _q_servo)."""
        c, g = self.config, self.gripper_model
        pos = trigger_fraction(float(self._q_servo[self.n_joints]), c.gripper_open_rad, c.gripper_closed_rad)
        if not c.read_current:
            return pos, float("nan")
        return pos, g.torque_constant * float(current_units) * g.amps_per_unit

    def _send_torque_safe(self, safe: SafeLeaderTorque) -> None:
        if self.bus is None:
            raise DeviceError(
                "leader is not connected", where=f"leader {self.config.name}", fix="call connect() first"
            )
        if self._wd is not None:
            self._keep_watchdog()
        units = torque_to_current_ints(safe.tau.tolist(), self._signs_l, self._k_l, self._amps_l,
                                       self.limit_units.tolist())  # the limit is read at connect
        if not self.bus.sync_write_ints(self._write_group, units):
            self.failed_writes += 1

    # -- the servos' own fallback: Bus Watchdog(98) (hardware/dynamixel/watchdog.py) -------------------------
    def _clear_watchdog(self, bus: DynamixelBus, dxl_id: int) -> None:
        """Clear a Bus Watchdog Error a previous app left latched (its goals would be refused); a servo
        without the register is reported by _arm_watchdog."""
        if wd.supported(self.servo_info[dxl_id]["model"], self.servo_info[dxl_id]["firmware"]):
            try:
                bus.write(dxl_id, wd.ADDR, 0)
            except DeviceError:
                pass  # refused: said once by _arm_watchdog

    def _arm_watchdog(self, bus: DynamixelBus, joint_ids: list[int]) -> None:
        """Set every joint servo's Bus Watchdog (wd.LEADER_PERIOD_S), read it back; a servo that refuses
        gets the one-line warning of what that means for the operator."""
        res = wd.arm_bus_watchdog(bus, joint_ids, wd.LEADER_PERIOD_S)
        self.fallback = res
        if res.refused:
            self._warn(wd.refusal_line(self.config.name, res))
        armed = [i for i in joint_ids if i not in res.refused]
        self._wd = wd.BusWatchdogKeeper(armed, res.units) if armed else None
        if self._wd is not None:
            self._wd.traffic(self.clock.now())

    def _keep_watchdog(self) -> None:
        """Before a goal write: re-arm the servos after a gap long enough for them to have latched (an app
        freeze, a silent chain), or after a reboot (it turns the watchdog off); and where the register reads
        back latched (a gap only the servo saw: a slow start before the first tick), said once."""
        k, now = self._wd, self.clock.now()
        reboots = sum(self.alerts.counts.values())
        if reboots != self._wd_reboots and not self.alerts.rebooted:
            self._wd_reboots = reboots
            k.mark_due()
        if k.rearm_if_due(self.bus, now):
            log.info("leader %s: Bus Watchdog re-armed (%d)", self.config.name, k.rearms)
        elif found := k.check_if_due(self.bus, now):
            said = k.found > len(found)  # once in the log as a warning; later ones at info
            (log.info if said else self._warn)(
                f"leader {self.config.name}: Bus Watchdog had latched on servo ids {found} (they refused "
                "every goal current: no force feedback) -- re-armed; a host that stalls over "
                f"{1e3 * wd.LEADER_PERIOD_S:.0f} ms trips it again")

    def fallback_lines(self) -> list[str]:
        """The servos' own fallback as read back at connect (doctor, start-up summary)."""
        res = self.fallback
        if res is None:
            return [f"leader {self.config.name}: Bus Watchdog not set (not connected)"]
        ok = {i: v for i, v in res.read_back.items() if i not in res.refused}
        out = []
        if ok:
            out.append(f"leader {self.config.name}: Bus Watchdog(98) read back on servo ids "
                       f"{sorted(ok)}: {wd.describe(res.units)} (set {res.units}); the servo stops "
                       "(0 current) when the app is silent that long")
        if res.refused:
            out.append(wd.refusal_line(self.config.name, res))
        return out

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
