"""DynamixelLeader: a GELLO-style leader arm of Dynamixel X servos in current mode (dynamixel-sdk only).

Per tick: ONE sync read (a Fast Sync Read where the chain has it: fast_sync.py) of present current/velocity/
position (126..135, 10 bytes; 8 from 128 without current) and ONE sync write of goal current (102).
Joint convention (config): q_joint = sign * (q_servo - offset_rad); joint torque tau = sign * K * current.

Multi-turn: present position restarts within one turn at power-on, so at connect each servo's angle is
moved by the 2*pi multiple that brings it closest to its stored offset (the joint then reads within
+-pi of zero); afterwards the driver integrates tick deltas (wrapped to +-half a turn), which also works
when a servo is in single-turn position mode.

Files: the math (decode, unwrap, torque<->current, trigger mapping) as pure functions in leader_math.py;
connect and close in leader_setup.py, the servos' Bus Watchdog in leader_watchdog.py (mixins of the class
here); this file is the per-tick read and write. It never falls back to a fake device: a missing port, id
or wrong model is a UserError.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from hardware.clock import Clock
from hardware.dynamixel import protocol as p
from hardware.dynamixel import watchdog as wd
from hardware.dynamixel.alerts import AlertRebooter
from hardware.dynamixel.bus import DynamixelBus
from hardware.dynamixel.config import DynamixelLeaderConfig
from hardware.dynamixel.fast_sync import split_fast_status
from hardware.dynamixel.leader_math import (
    _TICK_MASK,
    HALF_TURN_TICKS,
    TWO_PI,
    FastReplyDecoder,
    _blocks_struct,
    decode_feedback,
    servo_to_joint,
    torque_to_current_ints,
    trigger_fraction,
    wrapped_tick_delta,
)
from hardware.dynamixel.leader_setup import LeaderSetup
from hardware.dynamixel.leader_watchdog import LeaderWatchdog
from hardware.dynamixel.models import ServoModel, get_model, resolve_models
from hardware.errors import ConfigError, DeviceError
from hardware.roles import Leader
from hardware.safety import DEFAULT_WATCHDOG_S, SafeLeaderTorque
from hardware.types import STATUS_COMM_LOST, STATUS_DRIVER_ERROR, STATUS_ENABLED, STATUS_STALE, JointState

log = logging.getLogger("factr2.dynamixel")


# -- driver ----------------------------------------------------------------------------------------
class DynamixelLeader(LeaderSetup, LeaderWatchdog, Leader):
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
        self._nan_ro = np.full(n, np.nan)  # a fresh sample's q_cmd and temperature (none: a leader has
        self._nan_ro.flags.writeable = False  # neither), one read-only array shared, as safety's zeros are
        self._status_zero = np.zeros(n, np.uint32)  # a fresh sample's status without an alert: one of these
        self._status_enabled = np.full(n, STATUS_ENABLED, np.uint32)  # two, shared read-only (copied to mark)
        self._status_zero.flags.writeable = self._status_enabled.flags.writeable = False
        self.offsets = np.array(c.offsets_rad, float)
        self.amps_per_unit = np.array([m.amps_per_unit for m in self.models])
        self.limit_units = np.array([m.current_limit_units for m in self.models], float)
        self._amps_l = self.amps_per_unit.tolist()
        # sign * unit scale per joint (a sign is +-1: the product is exact, and sign * (x * r) is x * (sign *
        # r) bit for bit, IEEE rounding being symmetric): velocity and current arrays in one numpy product
        self._sign_rad_s = np.array([s * p.RAD_S_PER_VELOCITY_UNIT for s in self._signs_l])
        self._sign_amps = np.array([s * a for s, a in zip(self._signs_l, self._amps_l, strict=True)])
        self._vel_cur_scale = np.concatenate([self._sign_rad_s, self._sign_amps])  # both in one product
        self._grip_k_a = (self.gripper_model.torque_constant, self.gripper_model.amps_per_unit)
        self._limit_l = self.limit_units.tolist()  # again at connect, where the servos' Current Limit is read
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
        self._q_servo: np.ndarray | list[float] | None = None  # a list after a tick where all answered
        self._fast_decoder: FastReplyDecoder | None = None  # made at connect, for the ids and fields read
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





    # -- per tick ------------------------------------------------------------------------------------
    def _read(self) -> JointState | None:
        bus = self.bus
        if bus is None or self._q_servo is None:
            raise DeviceError(
                "leader is not connected", where=f"leader {self.config.name}", fix="call connect() first"
            )
        n, rc = self.n_joints, self.config.read_current
        if self.fast_read:
            buf, intact = bus.fast_sync_read_reply(self._read_group, self.rx_timeout_ms)
            r = self._fast_decoder.runs(buf) if intact else None
            if r is not None:  # the usual tick: the fields straight from the reply's bytes
                t = self.clock.now()
                if self._wd is not None:
                    self._wd.traffic(t)  # the servos heard this tick
                return self._state_of(t, r[0], r[1], r[2], None)
            got = split_fast_status(bytes(buf), self._read_group.ids, self._read_group.length, intact)
        else:
            got = bus.sync_read(self._read_group, self.read_ids, self.rx_timeout_ms)
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
        self._q_servo = np.asarray(self._q_servo, float) + delta * p.RAD_PER_TICK  # a list after a fresh tick
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
        """Every servo answered (a plain sync read, or a fast one with an alert bit): their blocks' fields
        in one struct unpack, then _state_of."""
        rc, ids = self.config.read_current, self.read_ids
        blocks = [got[i] for i in ids]
        vals = _blocks_struct(rc, len(ids)).unpack(b"".join([b[0] for b in blocks]))
        w = 3 if rc else 2  # (current,) velocity, position per servo
        return self._state_of(self.clock.now(), vals[w - 1::w], vals[w - 2::w], vals[0::w] if rc else None,
                              [b[1] for b in blocks])

    def _state_of(self, t: float, ticks, vel, cur_units, errs) -> JointState:
        """The sample of a tick where every servo answered, from its raw fields in read_ids order: position
        ticks, velocity units, current units (None without current), error bytes (None: all 0). Whole new
        arrays from plain floats (the loop's hot path: the same values as the general path in _read, bit for
        bit -- the tick delta unwrapped inline, each value the numpy decode's float64 operations in order)."""
        n, prev = self.n_joints, self._last_state
        tp = self._ticks_prev.tolist() if isinstance(self._ticks_prev, np.ndarray) else self._ticks_prev
        qs0 = self._q_servo.tolist() if isinstance(self._q_servo, np.ndarray) else self._q_servo
        h, nh, mask, rad = HALF_TURN_TICKS, -HALF_TURN_TICKS, _TICK_MASK, p.RAD_PER_TICK
        # wrapped_tick_delta: & (TICKS_PER_REV - 1) is its % (a power-of-two turn, negatives too), and a delta
        # already in [-h, h) is its own wrap. One value per servo read in each (zip without strict=: its
        # keyword costs the tick more than the rest of a servo's delta)
        qs = [q + (d if nh <= (d := x - x0) < h else ((d + h) & mask) - h) * rad
              for q, x, x0 in zip(qs0, ticks, tp)]
        self._q_servo, self._ticks_prev = qs, ticks
        signs = self._signs_l
        if cur_units is not None:  # velocity and current: one array of the units (ints, exact as floats)
            # times one of the scales, the sample's two arrays views of it: (sign * c) * r and (sign * c) * a
            # of the numpy decode, bit for bit (a third fewer instructions than an array and a product each)
            vc = self._vel_cur_scale * np.array(vel[:n] + cur_units[:n], float)
            qd, cur = vc[:n], vc[n:]
            tau = self.k * cur
        else:
            qd = self._sign_rad_s * np.array(vel[:n], float)
            cur, tau = prev.current.copy(), prev.tau_m.copy()
        status = self._status_enabled if self._torque_on else self._status_zero
        if errs is not None or self.alerts.pending:
            status = status.copy()
            self._alert_bits(status, [0] * len(qs) if errs is None else errs)
        if len(qs) > n:  # the trigger servo: its angle in _q_servo, its current after the joints' -- _trigger
            # written out (trigger_fraction's operations on the float angle, then K * units * amps per unit)
            c, qt = self.config, qs[n]
            lo, span = c.gripper_open_rad, c.gripper_closed_rad - c.gripper_open_rad
            if span == 0 or not math.isfinite(qt):
                grip_pos = math.nan
            else:  # a fraction strictly inside 0..1 is what min(max(f, 0.0), 1.0) gives it
                f = (qt - lo) / span
                grip_pos = f if 0.0 < f < 1.0 else min(max(f, 0.0), 1.0)
            k_a = self._grip_k_a
            grip_effort = math.nan if cur_units is None else k_a[0] * cur_units[n] * k_a[1]
        else:
            grip_pos, grip_effort = prev.gripper_pos, prev.gripper_effort
        nan = self._nan_ro
        # positional: in JointState's field order (t, q, q_dot, tau_m, current, q_cmd, temperature, status,
        # gripper_pos, gripper_effort), a third cheaper than by keyword at 500 Hz; velocity and current as one
        # numpy product (above): cheaper than 6 float products and the array made of them
        return JointState(t, np.array([s * (x - o) for s, x, o in zip(signs, qs, self._offsets_l)]), qd, tau,
                          cur, nan, nan, status, grip_pos, grip_effort)

    def _alert_bits(self, status: np.ndarray, errs) -> None:
        """A joint servo whose status has the alert bit: STATUS_DRIVER_ERROR; the rebooter told (alerts.py)"""
        n, ids, alert = self.n_joints, self.read_ids, p.ERR_ALERT_BIT
        if not (self.alerts.pending or any(e & alert for e in errs)):
            return
        if any(e & alert for e in errs[:n]):
            status[np.array([bool(e & alert) for e in errs[:n]])] |= np.uint32(STATUS_DRIVER_ERROR)
        alerting = [i for i, e in zip(ids, errs, strict=True) if e & alert]
        self.alerts.service(self, alerting, set(ids))

    def _trigger(self, current_units: int) -> tuple[float, float]:
        """(gripper_pos, gripper_effort [N*m]) of the trigger servo just read (its angle in _q_servo)."""
        c = self.config
        pos = trigger_fraction(float(self._q_servo[self.n_joints]), c.gripper_open_rad, c.gripper_closed_rad)
        if not c.read_current:
            return pos, float("nan")
        k, a = self._grip_k_a  # the model's K made once (K * units: the same product as K * float(units))
        return pos, k * current_units * a

    def _send_torque_safe(self, safe: SafeLeaderTorque) -> None:
        if self.bus is None:
            raise DeviceError(
                "leader is not connected", where=f"leader {self.config.name}", fix="call connect() first"
            )
        if self._wd is not None:
            self._keep_watchdog()
        units = torque_to_current_ints(safe.tau.tolist(), self._signs_l, self._k_l, self._amps_l,
                                       self._limit_l)  # the limit is read at connect
        if not self.bus.sync_write_ints(self._write_group, units):
            self.failed_writes += 1
