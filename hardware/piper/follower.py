"""AgileX Piper follower over python-can: the wire side of hardware.roles.Follower.

Per command the vendor's order is kept: 0x151 mode is re-sent before every set of targets. read() drains
every pending frame without blocking, keeps the newest frame per id and decodes only those. State timing:
JointState.t is the receive time of the OLDEST of the three joint-angle frames (a sample is only as fresh as
its oldest part), so the Device watchdog trips when any joint's angles stop arriving. Joints whose angle or
high-speed frames are older than the watchdog timeout are flagged STATUS_STALE.

MIT torque: the vendor FAQ says the motor executes 4x the commanded MIT torque. We divide tau_ff [N*m] by
config.mit_torque_gain (4) before encoding, so the joint gets what the safety layer allowed; the wire range
+-8 N*m then covers +-32 N*m at the joint with 8-bit steps of 0.25 N*m. Verify the factor on your firmware
(set mit_torque_gain = 1 if your arm applies the torque as sent).

Safe state (safe.hold): position mode at safe.q (J-mode targets), in either configured mode. While on hold
the hold targets are re-sent every HOLD_RESEND_S from read(), so one lost frame cannot leave an MIT command
active.
The arm is NOT disabled on disconnect: a disabled Piper drops under gravity; it is left holding its pose.
"""

from __future__ import annotations

import struct
from operator import itemgetter

import numpy as np

from hardware.can_bus import CanLink, bus_load, open_bus
from hardware.clock import Clock
from hardware.errors import ConfigError, DeviceError, DeviceNotFound
from hardware.piper import protocol as P
from hardware.piper.config import PiperFollowerConfig
from hardware.roles import Follower
from hardware.safety import DEFAULT_WATCHDOG_S, SafeFollowerCommand
from hardware.types import STATUS_ENABLED, STATUS_HOLD, STATUS_STALE, JointLimits, JointState


def fallback_line(name: str, mode: str) -> str:
    """What a Piper does when its host dies. The vendor's SDK and manual document no command timeout to set
    (0x151's residence-time byte is the SDK's offline-trajectory point dwell, not a watchdog), so nothing is
    configured."""
    if mode == "mit":
        what = ("MIT mode: each joint keeps its last MIT command (gains and feed-forward torque) -- not "
                "documented by the vendor; the twin does that; a feed-forward torque goes on pushing")
    else:
        what = "position mode: the arm holds its last joint target (the vendor's position loop)"
    return (f"follower {name} (Piper): no motor-side command timeout (the firmware offers none to set): if "
            f"this app dies, {what}; stop it with its e-stop or power switch")

STATUS_FIELDS = ("ctrl_mode", "arm_status", "mode_feed", "teach", "motion", "trajectory", "limit_bits",
                 "comm_bits")  # 0x2A1 bytes in order
FRAMES_PER_COMMAND = {"position": 4, "mit": 7}  # 0x151 + targets (the gripper frame only when it changes)
ENABLE_RETRY_S = 0.1  # s: 0x471 is repeated this often until every joint reports enabled
HOLD_RESEND_S = 0.02  # s: hold targets are repeated this often while on hold
GRIPPER_RESEND_S = 0.05  # s: an unchanged gripper command is repeated this often
_FIRST_FEEDBACK_IDS = (*P.ID_JOINT_FB, *P.ID_HIGH_SPEED)
# a sample's frames back to back, for one unpack each (P.S_JOINT_PAIR, P.S_HIGH_SPEED per frame); the getters
# raise KeyError for a frame not yet received
_S_JOINT_ALL = struct.Struct(">" + "ii" * len(P.ID_JOINT_FB))
_S_HIGH_ALL = struct.Struct(">" + "hhi" * len(P.ID_HIGH_SPEED))
_joint_of, _high_of = itemgetter(*P.ID_JOINT_FB), itemgetter(*P.ID_HIGH_SPEED)
_ID_J12, _ID_J34, _ID_J56 = P.ID_JOINT_TARGET


def _read_only(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False  # shared by the samples until the frames it is from change
    return a


def default_limits() -> JointLimits:
    """Vendor joint ranges; speed/torque bounds are conservative placeholders until an arm description
    (hardware/arms) supplies the real ones."""
    lo, hi = np.radians(np.array(P.JOINT_LIMITS_DEG)).T
    return JointLimits(q_min=lo, q_max=hi, v_max=np.full(6, 3.0), tau_max=np.array([8.0, 8, 8, 4, 4, 4]),
                       tau_rate_max=np.full(6, 100.0), kp_max=np.full(6, P.MIT_KP_MAX),
                       kd_max=np.full(6, P.MIT_KD_MAX))


class PiperFollower(Follower):
    """PiperFollower(config, limits=None, clock=None, watchdog_s=0.05). Joints J1..J6; gripper separate."""

    def __init__(self, config: PiperFollowerConfig, limits: JointLimits | None = None,
                 clock: Clock | None = None, watchdog_s: float = DEFAULT_WATCHDOG_S):
        limits = limits or default_limits()
        if limits.n != P.N_JOINTS:
            raise ConfigError(f"Piper has 6 joints, limits have {limits.n}", where=f"follower {config.name}",
                              fix="use the piper arm description")
        if config.mode not in ("position", "mit"):
            raise ConfigError(f"unknown mode {config.mode!r}", where=f"follower {config.name}",
                              fix='mode = "position" or "mit"')
        super().__init__(config.name, limits, clock, watchdog_s)
        self.config = config
        self.decoder = P.PiperFeedbackDecoder()
        self.link: CanLink | None = None
        self._k_effort = np.array(P.effort_per_amp(config.firmware_effort_x4))
        self._mit_kp = np.asarray(config.mit_kp, float)
        self._mit_kd = np.asarray(config.mit_kd, float)
        self._q_cmd = np.full(6, np.nan)
        self._flags_of: dict[int, int] = {}  # vendor status byte -> STATUS_* flags (P.low_speed_flags), memo
        self._hold: SafeFollowerCommand | None = None
        self._t_hold_sent = float("nan")
        self._grip_sent, self._t_grip_sent = float("nan"), float("nan")
        self._mode_pos = P.encode_mode(P.MOVE_J, config.speed_pct, P.MIT_MODE_POSVEL)
        self._mode_mit = P.encode_mode(P.MOVE_MIT, config.speed_pct, P.MIT_MODE_MIT)
        self.status_info: dict[str, int] = {}  # last 0x2A1 fields (ctrl_mode, arm_status, ...)
        self._status_frame: bytes | None = None  # the 0x2A1 bytes status_info and _status_flags are from
        self._status_flags: list[int] = []  # P.status_flags of them, per joint
        self._slow_part: tuple | None = None  # (frames and hold, temperature, status) of the last sample

    # -- connection --------------------------------------------------------------------------------------
    @property
    def is_connected(self) -> bool:
        return self.link is not None

    def connect(self) -> None:
        c = self.config
        bus = open_bus(c.channel, c.interface, c.bitrate)
        self.link = link = CanLink(bus, c.channel, c.interface, self.clock, c.bitrate)
        t_enable = self.clock.now()
        link.send(P.ID_ENABLE, P.encode_enable(True))
        link.send(P.ID_MODE, self._mode_pos)
        ok = link.wait(lambda: all(i in self.decoder.latest for i in _FIRST_FEEDBACK_IDS),
                       c.connect_timeout_s, self._push)
        if not ok:
            missing = [f"0x{i:03X}" for i in _FIRST_FEEDBACK_IDS if i not in self.decoder.latest]
            self._close()
            raise DeviceNotFound(f"no feedback from the Piper within {c.connect_timeout_s:.1f} s "
                                 f"(missing {', '.join(missing)})", where=link.where,
                                 fix="power the arm, check CAN wiring/termination and that the link runs at "
                                     f"{c.bitrate} bit/s (`ip -details link show {c.channel}`)")
        self._build_state(self.clock.now())  # fills status_info from 0x2A1
        if self.status_info.get("arm_status") == P.ARM_STATUS_ESTOP:
            self._close()
            raise DeviceError("the Piper reports an emergency stop", where=link.where,
                              fix="release the e-stop, power-cycle the arm, then reconnect")
        self._wait_enabled(t_enable)
        st = self._build_state(self.clock.now())
        self._last_state = st
        self.safety.watchdog.feed_feedback(st.t)
        self.hold("connect: hold the measured pose")
        self._last_state = self._build_state(self.clock.now()) or st  # now flagged STATUS_HOLD

    def _enabled_joints(self, since: float) -> list[bool]:
        """Per joint: a low-speed frame received after `since` reports the driver enabled."""
        lat, t_rx = self.decoder.latest, self.decoder.t_rx
        return [i in lat and t_rx[i] >= since and bool(P.low_speed_flags(P.decode_low_speed(lat[i])[3])
                                                       & STATUS_ENABLED) for i in P.ID_LOW_SPEED]

    def _wait_enabled(self, since: float) -> None:
        """Like the vendor demos: repeat 0x471 until every joint's low-speed status says enabled."""
        link, timeout = self.link, self.config.connect_timeout_s
        t_end = self.clock.now() + timeout
        while not link.wait(lambda: all(self._enabled_joints(since)), ENABLE_RETRY_S, self._push):
            if self.clock.now() >= t_end:
                off = [j + 1 for j, on in enumerate(self._enabled_joints(since)) if not on]
                self._close()
                raise DeviceError(f"Piper joint(s) {off} did not enable within {timeout:.1f} s",
                                  where=link.where,
                                  fix="check the e-stop and the arm's power, power-cycle to clear driver "
                                      "errors, then reconnect")
            link.send(P.ID_ENABLE, P.encode_enable(True))

    def _close(self) -> None:
        if self.link is not None:
            self.link.close()
            self.link = None

    def fallback_lines(self) -> list[str]:
        """The arm's own fallback when this app dies: the firmware offers none (docs/safety.md)."""
        return [fallback_line(self.config.name, self.config.mode)]

    def _disconnect_bus(self) -> None:
        self._close()

    # -- feedback ----------------------------------------------------------------------------------------
    def _push(self, msg) -> None:
        self.decoder.push_msg(msg, self.clock.now())

    def _push_raw(self, frames) -> None:
        self.decoder.push_frames(frames, self.clock.now())  # one drain's frames: all here by now

    def _read(self) -> JointState | None:
        if self.link is None:
            return None
        now = self.clock.now()
        ok_before = self.decoder.counters.ok
        self.link.drain(self._push, self._push_raw)
        if self._hold is not None and self.in_safe_state and not now - self._t_hold_sent < HOLD_RESEND_S:
            self._to_wire(self._hold)
        if self.decoder.counters.ok == ok_before:
            return None
        return self._build_state(now)

    def _build_state(self, now: float) -> JointState | None:
        """The sample from the newest frames. The usual one (every joint-angle and high-speed frame there,
        none stale) in one unpack per kind of frame, its low-speed and status part (temperature, flags: what
        changes at 40 Hz or rarely) decoded when those frames' bytes change; anything else the general way
        (_build_state_general): the same values, bit for bit (tests/test_piper_fast_state.py)."""
        latest, t_rx = self.decoder.latest, self.decoder.t_rx
        try:
            joint, high = _joint_of(latest), _high_of(latest)
            t, t_high = min(_joint_of(t_rx)), min(_high_of(t_rx))
        except KeyError:
            return self._build_state_general(now)
        stale_before = now - self.safety.watchdog.timeout_s
        # a min that is NaN (its first time NaN) or stale: the general way sees each time as it is
        if not (t >= stale_before and t_high >= stale_before):
            return self._build_state_general(now)
        hold = self.in_safe_state
        key = (tuple(map(latest.get, P.ID_LOW_SPEED)), latest.get(P.ID_STATUS), hold)
        memo = self._slow_part
        if memo is None or memo[0] != key:
            status, temp = [STATUS_HOLD if hold else 0] * 6, [float("nan")] * 6
            self._low_speed_and_status(latest, status, temp)
            memo = self._slow_part = (key, _read_only(np.array(temp, dtype=float)),
                                      _read_only(np.array(status, dtype=np.uint32)))
        mdeg, milli = P.MDEG_PER_RAD, P.MILLI
        h = _S_HIGH_ALL.unpack(b"".join(high))
        current = np.array([c * milli for c in h[1::3]])
        g_pos = g_eff = float("nan")
        d = latest.get(P.ID_GRIPPER_FB)
        if d is not None:
            g_pos, g_eff, _ = P.decode_gripper_fb(d)
        return JointState(t, np.array([a / mdeg for a in _S_JOINT_ALL.unpack(b"".join(joint))]),
                          np.array([x * milli for x in h[0::3]]), current * self._k_effort, current,
                          self._q_cmd.copy(), memo[1], memo[2], g_pos, g_eff)

    def _low_speed_and_status(self, latest: dict, status: list[int], temp: list[float]) -> None:
        """The low-speed frames' temperatures into temp, their flags and the arm status's into status."""
        low, flags_of = P.S_LOW_SPEED.unpack, self._flags_of
        for j, i in enumerate(P.ID_LOW_SPEED):
            d = latest.get(i)
            if d is not None:
                _, _, temp[j], bits, _ = low(d)
                flags = flags_of.get(bits)
                if flags is None:  # a few distinct bytes in a run: the bit-by-bit mapping once each
                    flags = flags_of[bits] = P.low_speed_flags(bits)
                status[j] |= flags
        d = latest.get(P.ID_STATUS)
        if d is not None:
            if d != self._status_frame:  # the arm's status changes rarely: decoded when its bytes do
                f = P.decode_status(d)
                self.status_info = dict(zip(STATUS_FIELDS, f, strict=True))
                self._status_frame, self._status_flags = bytes(d), P.status_flags(f[1], f[6], f[7])
            for j, flags in enumerate(self._status_flags):
                status[j] |= flags

    def _build_state_general(self, now: float) -> JointState | None:
        latest, t_rx = self.decoder.latest, self.decoder.t_rx
        self._slow_part = None  # status_info may change here: the usual path decodes its part again
        if not all(map(latest.__contains__, P.ID_JOINT_FB)):
            return None
        nan = float("nan")
        stale_before = now - self.safety.watchdog.timeout_s
        q: list[float] = []
        status = [STATUS_HOLD if self.in_safe_state else 0] * 6
        # the frames' unpacks written out (decode_joint_pair, decode_high_speed, decode_low_speed: the same
        # operations on the same fields), a sample's ~15 decode calls fewer
        pair, mdeg, milli = P.S_JOINT_PAIR.unpack, P.MDEG_PER_RAD, P.MILLI
        for k, i in enumerate(P.ID_JOINT_FB):
            a, b = pair(latest[i])
            q += (a / mdeg, b / mdeg)
            if t_rx[i] < stale_before:
                status[2 * k] |= STATUS_STALE
                status[2 * k + 1] |= STATUS_STALE
        v, cur, temp = [nan] * 6, [nan] * 6, [nan] * 6
        high = P.S_HIGH_SPEED.unpack
        for j, i in enumerate(P.ID_HIGH_SPEED):
            d = latest.get(i)
            if d is None or t_rx[i] < stale_before:
                status[j] |= STATUS_STALE
            if d is not None:
                x, c, _ = high(d)
                v[j], cur[j] = x * milli, c * milli
        self._low_speed_and_status(latest, status, temp)
        current = np.array(cur)
        g_pos = g_eff = nan
        d = latest.get(P.ID_GRIPPER_FB)
        if d is not None:
            g_pos, g_eff, _ = P.decode_gripper_fb(d)
        # positional, in JointState's field order (t, q, q_dot, tau_m, current, q_cmd, temperature, status,
        # gripper_pos, gripper_effort): a third cheaper than by keyword
        return JointState(min([t_rx[i] for i in P.ID_JOINT_FB]), np.array(q), np.array(v),
                          current * self._k_effort, current, self._q_cmd.copy(), np.array(temp, dtype=float),
                          np.array(status, dtype=np.uint32), g_pos, g_eff)

    # -- commands ----------------------------------------------------------------------------------------
    def _send_safe(self, safe: SafeFollowerCommand) -> None:
        if self.link is None:
            raise DeviceError("Piper follower is not connected", where=f"follower {self.name}",
                              fix="call connect() first")
        # the command's frames in order, handed to the link at once (CanLink.send_all)
        if safe.hold or self.config.mode == "position":
            j12, j34, j56 = P.encode_joint_targets(safe.q)
            frames = [(P.ID_MODE, self._mode_pos), (_ID_J12, j12), (_ID_J34, j34), (_ID_J56, j56)]
        else:
            frames = [(P.ID_MODE, self._mode_mit)]
            kp = self._mit_kp if safe.kp is None else safe.kp
            kd = self._mit_kd if safe.kd is None else safe.kd
            gain = self.config.mit_torque_gain
            for j in range(6):
                frames.append((P.ID_MIT[j], P.encode_mit(float(safe.q[j]), 0.0, float(kp[j]), float(kd[j]),
                                                         float(safe.tau_ff[j]) / gain)))
        if safe.gripper is not None:  # sent when it changes, else as a keep-alive (saves bus load)
            stroke = min(max(float(safe.gripper), 0.0), self.config.gripper_stroke_max_m)
            now = self.clock.now()
            if stroke != self._grip_sent or not now - self._t_grip_sent < GRIPPER_RESEND_S:
                effort = self.config.gripper_effort_nm
                frames.append((P.ID_GRIPPER_CMD, P.encode_gripper(stroke, effort, P.GRIPPER_ENABLE)))
                self._grip_sent, self._t_grip_sent = stroke, now
        self.link.send_all(frames)
        self._q_cmd = safe.q  # the safety layer's own new array, never written; a sample gets a copy
        if safe.hold:
            self._hold, self._t_hold_sent = safe, self.clock.now()
        else:
            self._hold = None

    def end_pose(self) -> tuple[float, ...] | None:
        """The arm's own forward kinematics from 0x2A2-0x2A4: (x, y, z [m], rx, ry, rz [rad]); None until
        all three frames arrived. Updated by read()."""
        lat = self.decoder.latest
        if not all(i in lat for i in P.ID_END_POSE):
            return None
        return P.decode_end_pose([lat[i] for i in P.ID_END_POSE])

    def bus_load(self, loop_hz: float) -> float:
        """Expected CAN bus load (fraction) at this command rate: e.g. position 1 kHz ~0.78, MIT 1 kHz ~1.1
        (over capacity: run MIT at <= 400 Hz)."""
        frames = P.ARM_FEEDBACK_FRAMES_S + FRAMES_PER_COMMAND[self.config.mode] * loop_hz
        return bus_load(frames, self.config.bitrate)

    # -- queries (used by can_probe / doctor) ------------------------------------------------------------
    def query_firmware(self, timeout_s: float = 0.2) -> str | None:
        """Ask 0x4AF for the firmware text; None when the arm does not answer in timeout_s."""
        if self.link is None:
            return None
        self.decoder.firmware_buf.clear()
        self.link.send(P.ID_FIRMWARE, P.encode_firmware_query())
        self.link.wait(lambda: P.firmware_complete(bytes(self.decoder.firmware_buf)), timeout_s, self._push)
        return P.parse_firmware(bytes(self.decoder.firmware_buf))
