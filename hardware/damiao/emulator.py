"""Simulated Damiao MIT-mode motors on a python-can bus (SIMULATED: the motors are a MotorBank).

    emu = DamiaoEmulator(bus, bank, ids=[1, 2, 3, 4, 5, 6, 7], models=["DM4340"] * 3 + ["DM4310"] * 4)
    each step: emu.poll(); bank.advance(t); emu.emit(t)

bank index i is the motor with slave id ids[i] (feedback on master_ids[i], default id + 0x10), rad and N*m.
poll() answers every pending frame the way the firmware does: exactly one feedback frame per MIT command and
per enable/disable frame, register reads/writes on 0x7FF answered on the master id, clear error, save zero.
emit(t) sends nothing periodic (Damiao motors only answer) but runs each motor's own command timeout
(register 9, units of 50 us; 0 = off): a motor without commands for that long drops to damping
(kp=0, kd=timeout_kd, tau=0) until the next command. Fault injection: drop_prob (each frame in either
direction lost with this probability), silent (answer nothing), err (per-motor ERR code forced into the
feedback, e.g. protocol.ERR_COIL_OVERTEMP; cleared by the clear-error frame), spike_rad (per motor [rad]
added to that motor's next feedback frame only: an encoder glitch; each entry is cleared once sent).
"""

from __future__ import annotations

import can
import numpy as np

from hardware.can_bus import CanEmulatorIO
from hardware.damiao import protocol as D

TIMEOUT_KD = 1.0  # N*m*s/rad: damping the emulated firmware applies after its command timeout
CAN_BAUD_INDEX_1M = 4  # register 35 value reported for 1 Mbit/s (index table not verified)


class DamiaoEmulator(CanEmulatorIO):
    """DamiaoEmulator(bus, bank, ids, models, *, master_ids=None, drop_prob=0.0, seed=0, timeout_kd=1.0,
    timeout_reg=0, ctrl_mode=1). Counters: rx_frames, tx_frames, dropped, ignored, timeouts,
    decode_errors (garbage: wrong DLC, unknown id, non-data frames)."""

    def __init__(self, bus: can.BusABC, bank, ids: list[int], models: list[str], *,
                 master_ids: list[int] | None = None, drop_prob: float = 0.0, seed: int = 0,
                 timeout_kd: float = TIMEOUT_KD, timeout_reg: int = 0, ctrl_mode: int = D.CTRL_MODE_MIT,
                 read_only_rids: frozenset = frozenset()):
        if len(ids) != bank.n or len(models) != bank.n:
            raise ValueError(f"DamiaoEmulator: {len(ids)} ids / {len(models)} models for a bank of {bank.n}")
        self._init_io(bus, drop_prob, seed)
        self.bank = bank
        self.ids = list(ids)
        self.master_ids = list(master_ids) if master_ids else [i + D.MASTER_ID_OFFSET for i in ids]
        self._index = {sid: k for k, sid in enumerate(self.ids)}
        self.ranges = [D.motor_model(m).ranges for m in models]
        self.registers = [{D.RID_MASTER_ID: self.master_ids[k], D.RID_SLAVE_ID: sid,
                           D.RID_TIMEOUT: timeout_reg, D.RID_CTRL_MODE: ctrl_mode, D.RID_PMAX: r.pmax,
                           D.RID_VMAX: r.vmax, D.RID_TMAX: r.tmax, D.RID_CAN_BAUD: CAN_BAUD_INDEX_1M}
                          for k, (sid, r) in enumerate(zip(self.ids, self.ranges, strict=True))]
        self.timeout_kd = float(timeout_kd)
        n = bank.n
        self.enabled = np.zeros(n, dtype=bool)
        self.err = np.zeros(n, dtype=int)  # forced ERR codes (0: none)
        self.spike_rad: np.ndarray | None = None  # SIMULATED encoder glitch (hardware/sim/faults.py)
        self.zero_offset = np.zeros(n)  # rad, set by the save-zero frame
        self.last_cmd_t = np.full(n, -np.inf)
        self.timed_out = np.zeros(n, dtype=bool)
        self.counters = D.RejectCounters()
        self.timeouts = 0
        self.t_timed_out = np.full(n, np.nan)  # when each motor last fell back to damping [s]
        self.timeout_log: list[tuple[int, float]] = []  # (motor index, its deadline [s]) of every fallback
        self.read_only_rids = frozenset(read_only_rids)  # fault: writes keep the old value (old firmware)

    @property
    def decode_errors(self) -> int:
        return self.counters.rejected

    # -- host -> motors ----------------------------------------------------------------------------------
    def poll(self) -> int:
        """Handle every pending frame; returns how many arrived."""
        recv, n = self.bus.recv, 0
        replies: list[tuple[int, int | None, bytes | None]] = []  # (motor, None, None): feedback
        mit_idx, mit_vals = [], []
        while True:
            msg = recv(0)
            if msg is None:
                break
            n += 1
            if self._lost():
                continue
            data, aid = msg.data, msg.arbitration_id
            if msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame:
                self.counters.bad_frame += 1
                continue
            if len(data) != D.FRAME_DLC:
                self.counters.bad_dlc += 1
                continue
            k = self._index.get(aid)
            if k is not None:
                self.counters.ok += 1
                code = D.special_code(data)
                if code is None:  # MIT command
                    q, v, kp, kd, tau = D.decode_mit(bytes(data), self.ranges[k])
                    if self.enabled[k] and self.registers[k][D.RID_CTRL_MODE] == D.CTRL_MODE_MIT:
                        mit_idx.append(k)
                        mit_vals.append((q + self.zero_offset[k], v, kp, kd, tau))
                    replies.append((k, None, None))
                else:  # commands are applied in arrival order: flush the batched MIT frames first
                    self._flush_mit(mit_idx, mit_vals)
                    if self._special(k, code):
                        replies.append((k, None, None))
            elif aid == D.ID_REGISTER:
                self.counters.ok += 1
                r = self._register(bytes(data))
                if r is not None:
                    replies.append(r)
            else:
                self.counters.unknown_id += 1
        self.rx_frames += n
        self._flush_mit(mit_idx, mit_vals)
        if replies:
            self._answer(replies)
        return n

    def _flush_mit(self, idx: list, vals: list) -> None:
        if idx:
            m = np.array(vals)
            self.bank.command_mit(np.array(idx), m[:, 0], m[:, 1], m[:, 2], m[:, 3], m[:, 4])
            idx.clear()
            vals.clear()

    def _special(self, k: int, code: int) -> bool:
        """Apply a special frame; True when the firmware answers it with a feedback frame."""
        if code in (D.CODE_ENABLE, D.CODE_DISABLE):
            on = code == D.CODE_ENABLE
            self.enabled[k] = on
            self.bank.enable(np.array([k]), on)
            return True
        if code == D.CODE_CLEAR_ERROR:
            self.err[k] = 0
        elif code == D.CODE_SAVE_ZERO:
            self.zero_offset[k] = self.bank.read().q[k]
        return False

    def _register(self, d: bytes):
        sid, op, rid, value = D.decode_reg_request(d)
        k = self._index.get(sid)
        if k is None:
            self.ignored += 1
            return None
        regs = self.registers[k]
        if op == D.REG_SAVE:
            return None  # flash write: no reply modelled
        if rid not in regs:
            self.ignored += 1
            return None
        if op == D.REG_WRITE and rid not in self.read_only_rids:
            regs[rid] = value
            if rid in (D.RID_PMAX, D.RID_VMAX, D.RID_TMAX):
                self.ranges[k] = D.MotorRanges(regs[D.RID_PMAX], regs[D.RID_VMAX], regs[D.RID_TMAX])
        elif op != D.REG_READ:
            self.ignored += 1
            return None
        return k, op, D.encode_reg_reply(sid, op, rid, regs[rid])

    def _answer(self, replies) -> None:
        r = self.bank.read()
        q, v = (r.q - self.zero_offset).tolist(), r.q_dot.tolist()  # Python floats: cheaper to encode
        tau, temp = r.tau_m.tolist(), r.temperature.tolist()
        for k, op, raw in replies:
            if op is None:
                self.last_cmd_t[k] = r.t
                self.timed_out[k] = False
                err = self.err[k] or (D.ERR_ENABLED if self.enabled[k] else D.ERR_DISABLED)
                if self.spike_rad is not None and k < len(self.spike_rad) and self.spike_rad[k]:
                    q[k] += float(self.spike_rad[k])  # one glitched frame, then the encoder reads true
                    self.spike_rad[k] = 0.0
                raw = D.encode_feedback(self.ids[k], int(err), D.reported_position(q[k], self.ranges[k].pmax),
                                        v[k], tau[k], temp[k], temp[k], self.ranges[k])
            self._send(self.master_ids[k], raw)

    # -- firmware timers ---------------------------------------------------------------------------------
    def emit(self, t: float) -> int:
        """Run the motors' command timeout at sim time t [s]; sends nothing (returns 0)."""
        for k in range(len(self.ids)):
            reg = self.registers[k][D.RID_TIMEOUT]
            late = t - self.last_cmd_t[k] > reg * D.TIMEOUT_UNIT_S
            if reg and late and self.enabled[k] and not self.timed_out[k]:
                q = self.bank.read().q[k]
                self.bank.command_mit(np.array([k]), np.array([q]), np.zeros(1), np.zeros(1),
                                      np.array([self.timeout_kd]), np.zeros(1))
                self.timed_out[k] = True
                self.t_timed_out[k] = self.last_cmd_t[k] + reg * D.TIMEOUT_UNIT_S
                self.timeout_log.append((k, float(self.t_timed_out[k])))
                self.timeouts += 1
        return 0


class GripperTransmission:
    """MotorBank view whose last motor is a rotary gripper motor driving the bank's linear finger joint:
    angle theta [rad] = closed_rad + s * x [m], s = (open_rad - closed_rad) / stroke_m, so theta_closed at
    x = 0 and theta_open at the finger's full travel. Forces map by power (F = s * tau), gains by s^2."""

    def __init__(self, bank, closed_rad: float, open_rad: float, stroke_m: float):
        self.bank, self.n, self.g = bank, bank.n, bank.n - 1
        self.c, self.s = float(closed_rad), (float(open_rad) - float(closed_rad)) / float(stroke_m)
        self.torque_constant = bank.torque_constant

    def __getattr__(self, name):  # set_speed etc. pass through
        return getattr(self.bank, name)

    def _split(self, idx, *vals):
        idx = np.atleast_1d(np.asarray(idx, dtype=int))
        return idx, [np.array(np.broadcast_to(np.asarray(v, dtype=float), idx.shape)) for v in vals]

    def read(self):
        r = self.bank.read()
        g, s = self.g, self.s
        r.q[g], r.q_dot[g] = self.c + s * r.q[g], s * r.q_dot[g]
        r.tau_m[g] = r.tau_m[g] / s
        r.current[g] = r.tau_m[g] / self.torque_constant[g]
        return r

    def command_position(self, idx, q) -> None:
        idx, (q,) = self._split(idx, q)
        q[idx == self.g] = (q[idx == self.g] - self.c) / self.s
        self.bank.command_position(idx, q)

    def command_mit(self, idx, q, v, kp, kd, tau_ff) -> None:
        idx, (q, v, kp, kd, tau) = self._split(idx, q, v, kp, kd, tau_ff)
        m, s = idx == self.g, self.s
        q[m], v[m], tau[m] = (q[m] - self.c) / s, v[m] / s, tau[m] * s
        kp[m], kd[m] = kp[m] * s * s, kd[m] * s * s
        self.bank.command_mit(idx, q, v, kp, kd, tau)

    def command_current(self, idx, current_a) -> None:
        idx, (i,) = self._split(idx, current_a)
        i[idx == self.g] *= self.s  # joint force per amp = s * K
        self.bank.command_current(idx, i)

    def enable(self, idx, on: bool) -> None:
        self.bank.enable(idx, on)


def make_twin_emulator(ctx):
    """A twin's Damiao chain (hardware.registry EmulatorContext -> TwinEndpoint) on a fresh virtual CAN
    channel; the gripper motor turns (rad) while the MJCF finger slides (m): GripperTransmission maps them."""
    import mujoco

    from hardware.can_bus import open_bus
    from hardware.registry import TwinEndpoint

    cfg, g = ctx.spec.config, ctx.with_gripper
    ids = list(cfg.ids) + ([cfg.gripper_id] if g else [])
    motors = list(cfg.motor) + ([cfg.gripper_motor] if g else [])
    bank = ctx.bank
    if g:
        m = ctx.world.model
        lo, hi = m.jnt_range[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, bank.joint_names[-1])]
        bank = GripperTransmission(bank, cfg.gripper_closed_rad, cfg.gripper_open_rad, float(hi - lo))
    master = cfg.master_ids and (list(cfg.master_ids) + ([cfg.gripper_id + 0x10] if g else []))
    bus = open_bus(ctx.channel, "virtual", clock=ctx.now)
    try:
        emu = DamiaoEmulator(bus, bank, ids, motors, master_ids=master, seed=ctx.seed)
    except BaseException:
        bus.shutdown()
        raise
    return TwinEndpoint(emulator=emu, endpoint=ctx.channel, bus=bus)
