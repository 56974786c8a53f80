"""A simulated AgileX Piper on a python-can bus (SIMULATED: the arm is a MotorBank, not hardware).

    emu = PiperEmulator(bus, bank)  # bus: open python-can bus, e.g. hardware.can_bus.open_bus(ch, "virtual")
    each step: emu.poll(); bank.advance(t); emu.emit(t)

bank: hardware.sim.motors.MotorBank with 6 joint motors (indices 0-5, rad) and optionally the gripper at
index 6 (prismatic, m). poll() handles every pending command frame; emit(t) sends the feedback frames due at
sim time t [s] at the real arm's rates (about 200 Hz per id for status, joint angles, gripper, high-speed,
end pose when fk is given; 40 Hz for low-speed). Behaviour modelled on the vendor documentation:
- targets and MIT frames act only on enabled motors (0x471) while 0x151 selects CAN control; joint targets
  need the J move mode with mit_mode 0x00, MIT frames need mit_mode 0xAD;
- MIT torque: the motor executes mit_torque_gain (4) x the commanded torque (vendor FAQ);
- reported current is the bank's measured current (old_firmware_effort=True reports J1-J3 4x low, like
  firmware <= 1.8-2); the speed % of 0x151 goes to bank.set_speed() when the bank has one;
- 0x472 parameter queries and 0x4AF firmware queries are answered.
Fault injection: drop_prob (each frame in either direction is lost with this probability), silent (send
nothing), fault_flags (per-joint hardware.types STATUS_* flags reported in the low-speed status byte),
arm_status (0x2A1 byte 1, e.g. protocol.ARM_STATUS_ESTOP), spike_rad (6 values [rad] added to the joint
angles of the next feedback only: an encoder glitch; then cleared).
"""

from __future__ import annotations

from collections.abc import Callable

import can
import numpy as np

from hardware.can_bus import CanEmulatorIO
from hardware.piper import protocol as P
from hardware.piper.command_decoder import PiperCommandDecoder

FAST_HZ = 200.0  # Hz per feedback id: status, joint angles, gripper, high-speed, end pose
SLOW_HZ = 40.0  # Hz per low-speed id
SUPPLY_V = 24.0  # V reported in the low-speed frames
MAX_JOINT_SPEED_RAD_S = 3.0  # reported by the 0x473 parameter reply
MAX_JOINT_ACC_RAD_S2 = 10.0  # reported by the 0x47C parameter reply
GRIPPER_ENABLED_BIT = 0x40  # 0x2A8 status byte bit we set while the gripper is enabled (our assumption)
# made-up version texts, marked SIM: the old one is <= 1.8-2 (J1-J3 effort reported 4x low)
SIM_FIRMWARE, SIM_FIRMWARE_OLD = "S-V1.8-3-SIM", "S-V1.6-3-SIM"


class PiperEmulator(CanEmulatorIO):
    """PiperEmulator(bus, bank, *, fk=None, old_firmware_effort=False, mit_torque_gain=4.0, drop_prob=0.0,
    seed=0, firmware=None, joint_limits_rad=None). firmware: version text answered on 0x4AF (default: a
    made-up SIM version consistent with old_firmware_effort).

    fk(q6 [rad]) -> (x, y, z [m], rx, ry, rz [rad]) enables the end-pose frames. joint_limits_rad: (6, 2)
    array for the 0x2A1 limit bits and the 0x473 reply (default: the vendor ranges). Counters: rx_frames,
    tx_frames, dropped, ignored (valid frames the arm's current mode ignores), decoder.counters (rejected
    garbage)."""

    def __init__(self, bus: can.BusABC, bank, *, fk: Callable | None = None,
                 old_firmware_effort: bool = False, mit_torque_gain: float = P.MIT_TORQUE_GAIN,
                 drop_prob: float = 0.0, seed: int = 0,
                 firmware: str | None = None, joint_limits_rad=None):
        if bank.n < 6:
            raise ValueError(f"PiperEmulator needs a bank with >= 6 motors, got {bank.n}")
        self._init_io(bus, drop_prob, seed)
        self.bank, self.fk = bank, fk
        self.has_gripper = bank.n > 6
        self.mit_torque_gain = float(mit_torque_gain)
        self.firmware = firmware or (SIM_FIRMWARE_OLD if old_firmware_effort else SIM_FIRMWARE)
        self.decoder = PiperCommandDecoder()
        scale = np.ones(6)
        if old_firmware_effort:
            scale = 1.0 / np.array(P.OLD_FIRMWARE_EFFORT_X4)
        self._current_scale = scale
        if joint_limits_rad is None:
            joint_limits_rad = np.radians(np.array(P.JOINT_LIMITS_DEG))
        self.joint_limits_rad = np.asarray(joint_limits_rad, float)
        self.enabled = np.zeros(6, dtype=bool)
        self.gripper_enabled = False
        self.ctrl_mode, self.move_mode, self.mit_mode, self.speed_pct = P.CTRL_STANDBY, P.MOVE_J, 0, 100
        self.arm_status = 0
        self.fault_flags = np.zeros(6, dtype=np.int64)
        self.spike_rad: np.ndarray | None = None
        self._q_target = np.full(7, np.nan)  # J1..J6 [rad], gripper stroke [m]
        self._mit = np.zeros((6, 5))
        self._all6 = np.arange(6)
        self._pos_dirty = self._mit_dirty = 0  # bit masks of joints with a batched command
        self._idx_cache: dict[int, np.ndarray] = {}  # joint bit mask -> index array (_dirty_joints)
        self._next_fast = self._next_slow = -np.inf

    # -- host -> arm -------------------------------------------------------------------------------------
    def poll(self) -> int:
        """Handle every pending command frame; returns how many arrived."""
        decode, n, lossy = self.decoder.decode, 0, bool(self.drop_prob)  # (as _lost: no draw at 0)
        take = self._take_pending
        for msg in take() if take is not None else iter(lambda: self.bus.recv(0), None):
            n += 1
            if lossy and self._lost():
                continue
            r = decode(msg.arbitration_id, msg.data, msg.is_extended_id,
                       msg.is_remote_frame or msg.is_error_frame)
            if r is None:
                continue
            kind, val = r
            if kind == "joint":
                k, pair = val
                if self._accepts_targets():
                    self._q_target[2 * k:2 * k + 2] = pair
                    self._pos_dirty |= 0b11 << (2 * k)
                else:
                    self.ignored += 1
            elif kind == "mit":
                j, (q, v, kp, kd, t) = val
                if self.ctrl_mode == P.CTRL_CAN and self.mit_mode == P.MIT_MODE_MIT:
                    self._mit[j] = (q, v, kp, kd, t * self.mit_torque_gain)
                    self._mit_dirty |= 1 << j
                else:
                    self.ignored += 1
            elif kind == "mode":
                self._flush()  # targets act in arrival order relative to mode and enable frames
                self._on_mode(val)
            elif kind == "enable":
                self._flush()
                self._on_enable(*val)
            elif kind == "gripper":
                self._on_gripper(*val)
            elif kind == "query":
                self._on_query(*val)
            elif kind == "firmware":
                for chunk in P.encode_firmware_reply(self.firmware):
                    self._send(P.ID_FIRMWARE, chunk)
        self.rx_frames += n
        self._flush()
        return n

    def _flush(self) -> None:
        """Push the joint targets / MIT commands batched since the last flush to the bank (one call each)."""
        if self._pos_dirty:
            idx = self._dirty_joints(self._pos_dirty)
            if idx is not None:
                self.bank.command_position(idx.copy(), self._q_target[idx])
            self._pos_dirty = 0
        if self._mit_dirty:
            idx = self._dirty_joints(self._mit_dirty)
            if idx is not None:
                m = self._mit[idx]
                self.bank.command_mit(idx.copy(), m[:, 0], m[:, 1], m[:, 2], m[:, 3], m[:, 4])
            self._mit_dirty = 0

    def _dirty_joints(self, dirty: int) -> np.ndarray | None:
        """Indices of the enabled joints among the bit mask `dirty` (bit 6: the gripper, set only while it is
        enabled); None: none. Cached per mask (the same one or two masks come every tick)."""
        en = self.enabled.tolist()
        mask = sum(1 << j for j in range(6) if dirty >> j & 1 and en[j]) | (dirty & 1 << 6)
        if not mask:
            return None
        idx = self._idx_cache.get(mask)
        if idx is None:
            idx = self._idx_cache[mask] = np.array([j for j in range(7) if mask >> j & 1])
        return idx

    def _accepts_targets(self) -> bool:
        return (self.ctrl_mode == P.CTRL_CAN and self.mit_mode == P.MIT_MODE_POSVEL
                and self.move_mode == P.MOVE_J)

    def _on_mode(self, val) -> None:
        ctrl, move, speed, mit, _, _ = val
        self.ctrl_mode, self.move_mode, self.mit_mode = ctrl, move, mit
        if speed != self.speed_pct:
            self.speed_pct = speed
            set_speed = getattr(self.bank, "set_speed", None)
            if set_speed is not None:
                set_speed(self._all6, max(speed, 1) / 100.0)

    def _on_enable(self, motor: int, on: bool | None) -> None:
        if on is None or not 1 <= motor <= P.MOTOR_ALL:
            self.ignored += 1
            return
        idx = self._all6 if motor == P.MOTOR_ALL else np.array([motor - 1])
        self.enabled[idx] = on
        self.bank.enable(idx, on)

    def _on_gripper(self, stroke_m: float, effort_nm: float, code: int, set_zero: int) -> None:
        if not self.has_gripper:
            self.ignored += 1
            return
        on = code in (P.GRIPPER_ENABLE, P.GRIPPER_ENABLE_CLEAR)
        if on != self.gripper_enabled:
            self._flush()  # a batched stroke goes to the gripper before it is switched
            self.bank.enable(np.array([6]), on)
            self.gripper_enabled = on
        if on:  # batched with the joint targets (one bank call a tick instead of two; same bank state)
            self._q_target[6] = stroke_m
            self._pos_dirty |= 1 << 6

    def _on_query(self, motor: int, kind: int) -> None:
        if not 1 <= motor <= 6:
            self.ignored += 1
            return
        if kind == 1:
            lo, hi = self.joint_limits_rad[motor - 1]
            self._send(P.ID_PARAM_REPLY_LIMITS, P.encode_param_limits(motor, hi, lo, MAX_JOINT_SPEED_RAD_S))
        elif kind == 2:
            self._send(P.ID_PARAM_REPLY_ACC, P.encode_param_acc(motor, MAX_JOINT_ACC_RAD_S2))
        else:
            self.ignored += 1

    # -- arm -> host -------------------------------------------------------------------------------------
    def emit(self, t: float) -> int:
        """Send the feedback frames due at sim time t [s]; returns how many were due."""
        fast, slow = t >= self._next_fast, t >= self._next_slow
        if not (fast or slow):
            return 0
        r = self.bank.read()
        out = []  # (id, data) in sending order: one batch onto the bus
        send = out.append
        q = r.q.tolist()  # Python floats: the codec's round() is ~20x slower on numpy scalars
        if fast:
            self._next_fast = _next_tick(self._next_fast, t, 1.0 / FAST_HZ)
            if self.spike_rad is not None:  # one glitched feedback, then the encoders read true again
                q[:6] = (np.asarray(q[:6]) + self.spike_rad).tolist()
                self.spike_rad = None
            lim = self.joint_limits_rad.tolist()  # Python float compares, as numpy's (NaN: not over)
            limit_bits = sum(1 << j for j in range(6) if q[j] < lim[j][0] or q[j] > lim[j][1])
            status = P.encode_status(self.ctrl_mode, self.arm_status, self.move_mode, limit_bits, 0)
            send((P.ID_STATUS, status))
            for k in range(3):
                send((P.ID_JOINT_FB[k], P.encode_joint_pair(q[2 * k], q[2 * k + 1])))
            cur, v = (r.current[:6] * self._current_scale).tolist(), r.q_dot.tolist()
            for j in range(6):
                send((P.ID_HIGH_SPEED[j], P.encode_high_speed(v[j], cur[j], q[j])))
            if self.has_gripper:
                g_status = GRIPPER_ENABLED_BIT if self.gripper_enabled else 0
                send((P.ID_GRIPPER_FB, P.encode_gripper_fb(q[6], float(r.tau_m[6]), g_status)))
            if self.fk is not None:
                out.extend(zip(P.ID_END_POSE, P.encode_end_pose(self.fk(r.q[:6])), strict=True))
        if slow:
            self._next_slow = _next_tick(self._next_slow, t, 1.0 / SLOW_HZ)
            temp, cur, en = r.temperature.tolist(), np.abs(r.current).tolist(), r.enabled.tolist()
            flags = self.fault_flags.tolist()
            for j in range(6):
                bits = P.flags_to_low_speed(flags[j], en[j])
                send((P.ID_LOW_SPEED[j], P.encode_low_speed(SUPPLY_V, temp[j], temp[j], bits, cur[j])))
        self._send_all(out)
        return len(out)


def _next_tick(prev: float, t: float, period: float) -> float:
    """Next due time on a fixed grid; after a long pause restart from t instead of bursting."""
    nxt = prev + period
    return nxt if nxt > t else t + period


def make_twin_emulator(ctx):
    """A twin's Piper (hardware.registry EmulatorContext -> TwinEndpoint) on a fresh virtual CAN channel,
    with the rig's joint limits and firmware generation; frames carry the rig clock's time."""
    from hardware.can_bus import open_bus
    from hardware.registry import TwinEndpoint

    bus = open_bus(ctx.channel, "virtual", clock=ctx.now)
    try:
        lim = ctx.spec.limits()
        emu = PiperEmulator(bus, ctx.bank, seed=ctx.seed,
                            old_firmware_effort=bool(ctx.spec.config.firmware_effort_x4),
                            joint_limits_rad=np.stack([lim.q_min, lim.q_max], axis=1))
    except BaseException:
        bus.shutdown()
        raise
    return TwinEndpoint(emulator=emu, endpoint=ctx.channel, bus=bus)
