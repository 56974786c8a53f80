"""Damiao MIT-mode follower chain (I2RT YAM style) over python-can: the wire side of hardware.roles.Follower.

Start-up: clear errors, read each motor's control mode (register 10, must be MIT) and PMAX/VMAX/TMAX
(registers 21-23, used by the codec from then on), write the motors' own command timeout (register 9) from
config.timeout_ms, enable each motor and wait for its feedback, then hold (damping).
Per command: exactly one MIT frame per motor (joints, then the gripper motor when configured); each motor
answers with exactly one feedback frame, which the next read() drains. JointState.t is the receive time of
the oldest joint feedback; joints without fresh feedback within the watchdog timeout are flagged STATUS_STALE.
Safe state: damping (kp=0, kd=safe.kd, tau=0), re-sent every HOLD_RESEND_S from read() so feedback keeps
flowing and a lost frame cannot leave a stiff command active. Disconnect: damping, then disable.
"""

from __future__ import annotations

import logging

import numpy as np

from hardware.can_bus import CanLink, bus_load, open_bus
from hardware.clock import Clock
from hardware.damiao import protocol as D
from hardware.damiao.config import DamiaoFollowerConfig
from hardware.errors import ConfigError, DeviceError, DeviceNotFound
from hardware.roles import Follower
from hardware.safety import DEFAULT_WATCHDOG_S, SafeFollowerCommand
from hardware.types import STATUS_HOLD, STATUS_STALE, JointLimits, JointState

HOLD_RESEND_S = 0.02  # s: the damping command is repeated this often while on hold
REGISTER_TRIES = 5  # a register read is retried this often before the motor counts as absent
log = logging.getLogger("factr2.damiao")
STARTUP_RIDS = (D.RID_CTRL_MODE, D.RID_PMAX, D.RID_VMAX, D.RID_TMAX)


def default_limits(models: list[str]) -> JointLimits:
    """Placeholder limits from the motor models (+-pi, 3 rad/s, rated torque) until an arm description
    (hardware/arms) supplies the real ones."""
    n = len(models)
    rated = np.array([D.motor_model(m).tau_rated for m in models])
    return JointLimits(q_min=np.full(n, -np.pi), q_max=np.full(n, np.pi), v_max=np.full(n, 3.0),
                       tau_max=rated, tau_rate_max=np.full(n, 100.0), kp_max=np.full(n, D.KP_MAX),
                       kd_max=np.full(n, D.KD_MAX))


class DamiaoFollower(Follower):
    """DamiaoFollower(config, limits=None, clock=None, watchdog_s=0.05). Joints in config.ids order."""

    def __init__(self, config: DamiaoFollowerConfig, limits: JointLimits | None = None,
                 clock: Clock | None = None, watchdog_s: float = DEFAULT_WATCHDOG_S):
        c, where = config, f"follower {config.name}"
        n = len(c.ids)
        if len(c.motor) != n:
            raise ConfigError(f"{len(c.motor)} motor models for {n} ids", where=where, fix="one model per id")
        try:
            models = [D.motor_model(m) for m in c.motor] + ([D.motor_model(c.gripper_motor)]
                                                            if c.gripper_id is not None else [])
        except KeyError as e:
            raise ConfigError(str(e.args[0]), where=where, fix="use DM4310 or DM4340") from None
        slaves = list(c.ids) + ([c.gripper_id] if c.gripper_id is not None else [])
        masters = list(c.master_ids) if c.master_ids is not None else [s + D.MASTER_ID_OFFSET for s in c.ids]
        if c.gripper_id is not None and len(masters) == n:
            masters.append(c.gripper_id + D.MASTER_ID_OFFSET)
        unique = len(set(slaves)) == len(slaves) and len(set(masters)) == len(masters)
        if len(masters) != len(slaves) or not unique:
            raise ConfigError(f"ids {slaves} / master ids {masters} must be unique and one per motor",
                              where=where, fix="list one master id per motor (gripper last), or leave it out")
        if len(c.kp) != n or len(c.kd) != n:
            raise ConfigError(f"kp/kd need {n} entries", where=where, fix="one gain per joint")
        limits = limits or default_limits(list(c.motor))
        if limits.n != n:
            raise ConfigError(f"limits have {limits.n} joints, config {n}", where=where, fix="match the arm")
        super().__init__(c.name, limits, clock, watchdog_s)
        self.config = c
        self.slave_ids, self.master_ids = slaves, masters
        self.n_motors = len(slaves)
        self.ranges = [m.ranges for m in models]  # replaced by registers 21-23 at connect
        self._set_wrap()
        self.kt = np.array([m.torque_constant for m in models])
        self.registers: list[dict[int, float | int]] = [{} for _ in slaves]
        self.decoder = D.DamiaoFeedbackDecoder(slaves, masters)
        self.link: CanLink | None = None
        self._kp, self._kd = np.asarray(c.kp, float), np.asarray(c.kd, float)
        self._q_cmd = np.full(n, np.nan)
        self._grip_target = float("nan")  # motor angle [rad]
        self._hold: SafeFollowerCommand | None = None
        self.fallback: dict[int, float | None] = {}  # slave id -> command timeout read back at connect [s]
        self.warnings: list[str] = []
        self._t_hold_sent = float("nan")

    def _set_wrap(self) -> None:
        """A joint's reading rolls over at +-PMAX (the 16-bit field of a multi-turn count): Device.read puts
        it back on the joint's turn, a period of 2 * PMAX (hardware/wrap.py)."""
        self.wrap_period_rad = np.array([2.0 * r.pmax for r in self.ranges[:self.n_joints]])

    # -- connection --------------------------------------------------------------------------------------
    @property
    def is_connected(self) -> bool:
        return self.link is not None

    def _push(self, msg) -> None:
        self.decoder.push_msg(msg, self.clock.now())

    def connect(self) -> None:
        c = self.config
        self.link = link = CanLink(open_bus(c.channel, c.interface, c.bitrate), c.channel, c.interface,
                                   self.clock, c.bitrate)
        enabling = False
        try:
            for sid in self.slave_ids:
                link.send(sid, D.special_frame(D.CODE_CLEAR_ERROR))
            for k, sid in enumerate(self.slave_ids):
                for rid in STARTUP_RIDS:
                    self.registers[k][rid] = self._read_register(k, rid)
                mode = int(self.registers[k][D.RID_CTRL_MODE])
                if mode != D.CTRL_MODE_MIT:
                    raise DeviceError(f"motor id {sid} is in control mode {mode}, not MIT (1)",
                                      where=link.where,
                                      fix="set register 10 to 1 with the Damiao tool and save it")
                r = self.registers[k]
                self.ranges[k] = D.MotorRanges(float(r[D.RID_PMAX]), float(r[D.RID_VMAX]),
                                               float(r[D.RID_TMAX]))
                self._set_wrap()
                self._set_timeout(k)
            self._say_timeout_refusals()
            t0 = self.clock.now()
            enabling = True
            missing = list(self.slave_ids)
            for _ in range(REGISTER_TRIES):  # enable until every motor answered with a feedback frame
                for sid in missing:
                    link.send(sid, D.special_frame(D.CODE_ENABLE))
                link.wait(lambda: all(t >= t0 for t in self.decoder.t_rx), c.reply_timeout_s, self._push)
                missing = [s for s, t in zip(self.slave_ids, self.decoder.t_rx, strict=True) if not t >= t0]
                if not missing:
                    break
            if missing:
                raise DeviceNotFound(f"motor id(s) {missing} did not answer the enable frame",
                                     where=link.where, fix="check the motors' power and CAN wiring")
            faults = [f"id {sid}: {D.ERR_NAMES.get(err, hex(err))}" for sid, err in self._motor_errors()
                      if err != D.ERR_ENABLED]
            if faults:  # the clear-error frame went out first: these came back or never left
                raise DeviceError(f"motor(s) not enabled after clearing errors ({'; '.join(faults)})",
                                  where=link.where, fix="fix the cause (supply voltage, temperature, load), "
                                                        "power-cycle the motors, then reconnect")
        except Exception:
            if enabling:  # leave the motors damped (their own timeout keeps them so), not stiff or limp
                for k, sid in enumerate(self.slave_ids):
                    link.send(sid, D.encode_mit(0.0, 0.0, 0.0, self.safety.hold_kd, 0.0, self.ranges[k]))
            self._close()
            raise
        st = self._build_state(self.clock.now())
        self._last_state = st
        self.safety.watchdog.feed_feedback(st.t)
        if c.gripper_id is not None:
            self._grip_target = self._grip_q
        self.hold("connect: damping")
        t1 = self.clock.now()  # fresh feedback from every motor (retries above may have aged some)
        for _ in range(REGISTER_TRIES):
            if self.link.wait(lambda: all(t >= t1 for t in self.decoder.t_rx), c.reply_timeout_s, self._push):
                break
            self._to_wire(self._hold)
        self._last_state = self._build_state(self.clock.now())
        self.safety.watchdog.feed_feedback(self._last_state.t)

    # -- the motors' own fallback: the command timeout (register 9) ------------------------------------------
    def _set_timeout(self, k: int) -> None:
        """Write register 9 (config.timeout_ms) and read it back: fallback[sid] is what the motor holds
        [s] (None: no answer)."""
        sid, want = self.slave_ids[k], D.timeout_register(self.config.timeout_ms * 1e-3)
        self._register_round_trip(k, D.encode_reg_write(sid, D.RID_TIMEOUT, want), D.RID_TIMEOUT)
        try:
            got = int(self._read_register(k, D.RID_TIMEOUT))
        except DeviceNotFound:
            got = None
        self.registers[k][D.RID_TIMEOUT] = got
        self.fallback[sid] = None if got is None else got * D.TIMEOUT_UNIT_S

    def _say_timeout_refusals(self) -> None:
        """One line for the motors whose timeout is not what was written: what that means for the operator."""
        want = D.timeout_register(self.config.timeout_ms * 1e-3) * D.TIMEOUT_UNIT_S
        bad = [f"id {sid} ({'no answer' if v is None else 'off' if v == 0 else f'{1e3 * v:.0f} ms'})"
               for sid, v in self.fallback.items() if v is None or abs(v - want) > 1e-9]
        if bad:
            msg = (f"follower {self.config.name}: command timeout (register 9 = {1e3 * want:.0f} ms) not set "
                   f"on motor {', '.join(bad)}: if this app dies, that motor keeps its last MIT command "
                   "(stiff at the last target, with its last torque) until its power is cut -- keep the "
                   "e-stop within reach; check the motor's firmware with the Damiao tool")
            self.warnings.append(msg)
            log.warning(msg)

    def fallback_lines(self) -> list[str]:
        """The motors' own fallback as read back at connect (doctor, start-up summary)."""
        if not self.fallback:
            return [f"follower {self.config.name}: command timeout not set (not connected)"]
        ok = {sid: v for sid, v in self.fallback.items() if v}
        out = [f"follower {self.config.name}: command timeout (register 9) read back "
               + ", ".join(f"id {sid} {1e3 * v:.0f} ms" for sid, v in ok.items())
               + "; a motor without commands that long drops to damping (kp 0, its firmware's kd)"
               ] if ok else []
        return out + [w for w in self.warnings if "command timeout" in w]

    def _motor_errors(self) -> list[tuple[int, int]]:
        """(slave id, ERR nibble) of every motor's latest feedback."""
        return [(sid, d[0] >> 4) for sid, d in zip(self.slave_ids, self.decoder.latest, strict=True)
                if d is not None]

    def _read_register(self, k: int, rid: int) -> float | int:
        sid = self.slave_ids[k]
        for _ in range(REGISTER_TRIES):
            got = self._register_round_trip(k, D.encode_reg_read(sid, rid), rid)
            if got is not None:
                return got
        raise DeviceNotFound(f"Damiao motor id {sid} (feedback id 0x{self.master_ids[k]:02X}) does not "
                             f"answer register {rid}", where=self.link.where,
                             fix="check power, the motor's slave/master ids (registers 8/7) and the bitrate")

    def _write_register(self, k: int, rid: int, value) -> None:
        sid = self.slave_ids[k]
        for _ in range(REGISTER_TRIES):
            got = self._register_round_trip(k, D.encode_reg_write(sid, rid, value), rid)
            if got is not None and got == value:
                self.registers[k][rid] = got
                return
        raise DeviceError(f"motor id {sid} did not confirm register {rid} = {value}", where=self.link.where,
                          fix="check the motor's firmware version supports this register")

    def _register_round_trip(self, k: int, frame: bytes, rid: int):
        dec, sid = self.decoder, self.slave_ids[k]
        dec.expect_registers = True
        dec.reg_replies.clear()
        try:
            self.link.send(D.ID_REGISTER, frame)
            self.link.wait(lambda: any(s == sid and r == rid for s, r, _ in dec.reg_replies),
                           self.config.reply_timeout_s, self._push)
            for s, r, v in dec.reg_replies:
                if s == sid and r == rid:
                    return v
            return None
        finally:
            dec.expect_registers = False

    def _close(self) -> None:
        if self.link is not None:
            self.link.close()
            self.link = None

    def _disconnect_bus(self) -> None:
        if self.link is not None:
            for sid in self.slave_ids:
                self.link.send(sid, D.special_frame(D.CODE_DISABLE))
        self._close()

    # -- feedback ----------------------------------------------------------------------------------------
    @property
    def _grip_q(self) -> float:
        d = self.decoder.latest[-1] if self.config.gripper_id is not None else None
        return D.decode_feedback(d, self.ranges[-1])[2] if d is not None else float("nan")

    def _read(self) -> JointState | None:
        if self.link is None:
            return None
        ok_before = self.decoder.counters.ok
        self.link.drain(self._push)
        due = not self.clock.now() - self._t_hold_sent < HOLD_RESEND_S
        if self._hold is not None and self.in_safe_state and due:
            self._to_wire(self._hold)
        if self.decoder.counters.ok == ok_before:
            return None
        return self._build_state(self.clock.now())

    def _build_state(self, now: float) -> JointState:
        n, dec = self.n_joints, self.decoder
        # a joint that never answered counts as infinitely old, so the watchdog trips (NaN would hide it)
        st = JointState.empty(n, t=min(t if t == t else -np.inf for t in dec.t_rx[:n]))
        stale_before = now - self.safety.watchdog.timeout_s
        hold = STATUS_HOLD if self.in_safe_state else 0
        for i in range(n):
            d = dec.latest[i]
            if d is None:
                st.status[i] = STATUS_STALE | hold
                continue
            _, err, q, v, tau, t_mos, t_rot = D.decode_feedback(d, self.ranges[i])
            st.q[i], st.q_dot[i], st.tau_m[i] = q, v, tau
            st.current[i] = tau / self.kt[i]  # derived: the motor reports torque, not current
            st.temperature[i] = max(t_mos, t_rot)
            st.status[i] = D.err_flags(err) | hold | (STATUS_STALE if dec.t_rx[i] < stale_before else 0)
        st.q_cmd[:] = self._q_cmd
        if self.config.gripper_id is not None and dec.latest[-1] is not None:
            _, _, q, _, tau, _, _ = D.decode_feedback(dec.latest[-1], self.ranges[-1])
            st.gripper_pos, st.gripper_effort = self._rad_to_stroke(q), tau
        return st

    def _stroke_to_rad(self, stroke_m: float) -> float:
        c = self.config
        s = min(max(stroke_m, 0.0), c.gripper_stroke_m) / c.gripper_stroke_m
        return c.gripper_closed_rad + s * (c.gripper_open_rad - c.gripper_closed_rad)

    def _rad_to_stroke(self, q: float) -> float:
        c = self.config
        return (q - c.gripper_closed_rad) / (c.gripper_open_rad - c.gripper_closed_rad) * c.gripper_stroke_m

    def bus_load(self, loop_hz: float) -> float:
        """Expected CAN bus load (fraction) at this command rate: one command + one feedback per motor."""
        return bus_load(2 * self.n_motors * loop_hz, self.config.bitrate)

    # -- commands ----------------------------------------------------------------------------------------
    def _send_safe(self, safe: SafeFollowerCommand) -> None:
        if self.link is None:
            raise DeviceError("Damiao follower is not connected", where=f"follower {self.name}",
                              fix="call connect() first")
        send, rng, n = self.link.send, self.ranges, self.n_joints
        if safe.hold:
            kp, kd, tau = np.zeros(n), safe.kd if safe.kd is not None else np.full(n, 1.0), np.zeros(n)
        else:
            kp = self._kp if safe.kp is None else safe.kp
            kd = self._kd if safe.kd is None else safe.kd
            tau = safe.tau_ff
        q = safe.q
        for i in range(n):
            send(self.slave_ids[i], D.encode_mit(float(q[i]), 0.0, float(kp[i]), float(kd[i]), float(tau[i]),
                                                 rng[i]))
        if self.config.gripper_id is not None:
            c = self.config
            if safe.gripper is not None:
                self._grip_target = self._stroke_to_rad(float(safe.gripper))
            g_q = self._grip_target if np.isfinite(self._grip_target) else self._grip_q
            g_kp = 0.0 if safe.hold or not np.isfinite(g_q) else c.gripper_kp
            g_q = g_q if np.isfinite(g_q) else 0.0
            send(self.slave_ids[-1], D.encode_mit(g_q, 0.0, g_kp, c.gripper_kd, 0.0, rng[-1]))
        self._q_cmd = np.array(q, dtype=float)
        if safe.hold:
            self._hold, self._t_hold_sent = safe, self.clock.now()
        else:
            self._hold = None
