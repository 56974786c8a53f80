"""Read-only health probes of the CAN followers for `factr2 doctor`: firmware, status, temperatures, errors,
feedback rates, round trip. They never enable a motor or send a target.

    bus = hardware.can_bus.open_bus(cfg.channel, cfg.interface, cfg.bitrate)
    report = probe_piper(bus, cfg)            # or probe_damiao(bus, cfg, with_feedback=False)
    print("\\n".join(report.lines())); bus.shutdown()

clock: pass the rig's clock (a LockstepClock for a lockstep twin: waiting then advances the twin, and the
round trip is in simulated time, which report.lines() says).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from hardware.can_bus import CanLink
from hardware.clock import Clock
from hardware.damiao import protocol as D
from hardware.damiao.config import DamiaoFollowerConfig
from hardware.piper import protocol as P
from hardware.piper.config import PiperFollowerConfig
from hardware.piper.follower import fallback_line

PIPER_LISTEN_S = 0.25  # s of passive listening to measure feedback rates
PIPER_MIN_HZ = 100.0  # a fast feedback id below this rate is reported (real arm: about 200 Hz)
TEMP_WARN_C = 70.0  # degC: a motor/driver this hot is reported
ARM_STATUS_NAMES = {0: "normal", 1: "emergency stop", 2: "no IK solution", 3: "singularity",
                    4: "target angle over limit", 5: "joint communication error",
                    6: "joint brake not released", 7: "collision", 8: "teach drag overspeed",
                    9: "joint status error", 10: "other error"}
_LOW_SPEED_NAMES = ("undervoltage", "motor overtemperature", "overcurrent", "driver overtemperature",
                    "collision", "driver error", "enabled", "stall")


@dataclass
class ProbeReport:
    """What a probe found. ok: nothing in errors. round_trip_ms: query -> first reply [ms of the clock]."""

    device: str
    where: str
    simulated_time: bool
    ok: bool = True
    firmware: str | None = None
    round_trip_ms: float | None = None
    feedback_hz: dict[str, float] = field(default_factory=dict)
    temperatures_c: list[float] = field(default_factory=list)
    status: dict[str, object] = field(default_factory=dict)
    errors: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def error(self, msg: str) -> None:
        self.errors.append(msg)
        self.ok = False

    def lines(self) -> list[str]:
        clock = " (simulated time)" if self.simulated_time else ""
        out = [f"{self.device} on {self.where}: {'OK' if self.ok else 'PROBLEMS'}"]
        if self.firmware is not None:
            out.append(f"  firmware: {self.firmware}")
        if self.round_trip_ms is not None:
            out.append(f"  round trip: {self.round_trip_ms:.2f} ms{clock}")
        if self.feedback_hz:
            rates = ", ".join(f"{k} {v:.0f} Hz" for k, v in self.feedback_hz.items())
            out.append(f"  feedback: {rates}{clock}")
        if self.temperatures_c:
            out.append("  temperatures [degC]: " + " ".join(f"{t:.0f}" for t in self.temperatures_c))
        out += [f"  {k}: {v}" for k, v in self.status.items()]
        out += [f"  ERROR: {e}" for e in self.errors] + [f"  note: {n}" for n in self.notes]
        return out


def probe_piper(bus, config: PiperFollowerConfig, clock: Clock | None = None,
                listen_s: float = PIPER_LISTEN_S) -> ProbeReport:
    """Listen to the Piper's feedback, then ask for the firmware version and motor 1's limits."""
    clock = clock or Clock()
    link = CanLink(bus, config.channel, config.interface, clock, config.bitrate)
    rep = ProbeReport("AgileX Piper", link.where, simulated_time=not clock.realtime)
    dec = P.PiperFeedbackDecoder()
    counts: dict[int, int] = {}

    def push(msg):
        if dec.push_msg(msg, clock.now()):
            counts[msg.arbitration_id] = counts.get(msg.arbitration_id, 0) + 1

    t0 = clock.now()
    link.wait(lambda: False, listen_s, push)
    span = max(clock.now() - t0, 1e-9)
    if not counts:
        rep.error("no feedback frames at all -- power the arm, check CAN wiring/termination and the bitrate "
                  f"({config.bitrate} bit/s: `ip -details link show {config.channel}`)")
        return rep
    groups = {"status": (P.ID_STATUS,), "joint angles": P.ID_JOINT_FB, "high-speed": P.ID_HIGH_SPEED,
              "low-speed": P.ID_LOW_SPEED, "gripper": (P.ID_GRIPPER_FB,)}
    for name, ids in groups.items():
        rep.feedback_hz[name] = min(counts.get(i, 0) for i in ids) / span
    for name in ("status", "joint angles", "high-speed"):
        if rep.feedback_hz[name] < PIPER_MIN_HZ:
            rep.error(f"{name} feedback at {rep.feedback_hz[name]:.0f} Hz (expected about 200 Hz): bus "
                      "overloaded or frames lost -- check termination and that nothing else floods the bus")
    if dec.counters.rejected:
        rep.error(f"{dec.counters.rejected} malformed frames ({dec.counters.as_dict()})")
    if P.ID_STATUS in dec.latest:
        ctrl, arm, mode, *_, lim, comm = P.decode_status(dec.latest[P.ID_STATUS])
        rep.status["control mode"] = {0: "standby", 1: "CAN command"}.get(ctrl, f"0x{ctrl:02X}")
        rep.status["arm status"] = ARM_STATUS_NAMES.get(arm, f"0x{arm:02X}")
        if arm not in (0,):
            rep.error(f"arm reports '{rep.status['arm status']}'")
        for j in range(6):
            if lim >> j & 1:
                rep.error(f"joint {j + 1} over its angle limit")
            if comm >> j & 1:
                rep.error(f"joint {j + 1} communication error")
    for j, i in enumerate(P.ID_LOW_SPEED):
        if i not in dec.latest:
            continue
        volt, t_drv, t_mot, bits, _ = P.decode_low_speed(dec.latest[i])
        rep.temperatures_c.append(float(max(t_drv, t_mot)))
        rep.status[f"J{j + 1}"] = f"{volt:.1f} V, driver {t_drv} degC, motor {t_mot} degC"
        faults = [n for b, n in enumerate(_LOW_SPEED_NAMES) if bits >> b & 1 and n != "enabled"]
        if faults:
            rep.error(f"joint {j + 1}: {', '.join(faults)}")
        if max(t_drv, t_mot) >= TEMP_WARN_C:
            rep.error(f"joint {j + 1} at {max(t_drv, t_mot)} degC -- let it cool")
    t_q = clock.now()
    link.send(P.ID_FIRMWARE, P.encode_firmware_query())
    first: list[float] = []

    def push_fw(msg):
        push(msg)
        if msg.arbitration_id == P.ID_FIRMWARE and not first:
            first.append(clock.now())

    if link.wait(lambda: P.firmware_complete(bytes(dec.firmware_buf)), 0.2, push_fw):
        rep.firmware = P.parse_firmware(bytes(dec.firmware_buf))
        rep.round_trip_ms = 1e3 * (first[0] - t_q) if first else None
        if rep.firmware and _old_firmware(rep.firmware) and not config.firmware_effort_x4:
            rep.notes.append("firmware <= 1.8-2 reports J1-J3 effort 4x low: set firmware_effort_x4 = true")
    else:
        rep.notes.append("no answer to the firmware query (0x4AF) -- some firmwares do not answer it")
    rep.notes.append(fallback_line(config.name, config.mode))
    return rep


def _old_firmware(text: str) -> bool:
    """True for S-V1.8-2 and older (numbers after 'S-V')."""
    nums = []
    for part in text[3:].replace("-", ".").split("."):
        if not part.isdigit():
            break
        nums.append(int(part))
    return bool(nums) and tuple(nums) <= (1, 8, 2)


def probe_damiao(bus, config: DamiaoFollowerConfig, clock: Clock | None = None,
                 with_feedback: bool = False) -> ProbeReport:
    """Read each motor's registers (mode, PMAX/VMAX/TMAX, timeout) and time the round trip. with_feedback:
    also send each motor a DISABLE frame (it answers with ERR, temperatures): the motors go limp, so only use
    it with the arm resting."""
    clock = clock or Clock()
    link = CanLink(bus, config.channel, config.interface, clock, config.bitrate)
    rep = ProbeReport("Damiao chain", link.where, simulated_time=not clock.realtime)
    slaves = list(config.ids) + ([config.gripper_id] if config.gripper_id is not None else [])
    masters = list(config.master_ids) if config.master_ids else [s + D.MASTER_ID_OFFSET for s in slaves]
    if len(masters) < len(slaves):
        masters += [s + D.MASTER_ID_OFFSET for s in slaves[len(masters):]]
    dec = D.DamiaoFeedbackDecoder(slaves, masters)

    def push(msg):
        dec.push_msg(msg, clock.now())

    trips = []
    for k, sid in enumerate(slaves):
        regs = {}
        for rid in (D.RID_CTRL_MODE, D.RID_PMAX, D.RID_VMAX, D.RID_TMAX, D.RID_TIMEOUT):
            dec.expect_registers, dec.reg_replies[:] = True, []
            t0, w0 = clock.now(), time.perf_counter()
            link.send(D.ID_REGISTER, D.encode_reg_read(sid, rid))
            link.wait(lambda sid=sid, rid=rid: any(s == sid and r == rid for s, r, _ in dec.reg_replies),
                      0.05, push)
            got = [v for s, r, v in dec.reg_replies if s == sid and r == rid]
            if got:
                regs[rid] = got[0]
                trips.append(1e3 * ((clock.now() - t0) if not clock.realtime else time.perf_counter() - w0))
        dec.expect_registers = False
        if not regs:
            rep.error(f"motor id {sid} (feedback id 0x{masters[k]:02X}) does not answer -- check its power, "
                      "its slave/master ids (registers 8/7) and the bitrate")
            continue
        mode = regs.get(D.RID_CTRL_MODE)
        if mode is not None and mode != D.CTRL_MODE_MIT:
            rep.error(f"motor id {sid} in control mode {mode}, not MIT (1) -- set register 10 to 1 and save")
        timeout = regs.get(D.RID_TIMEOUT)
        nan = float("nan")
        text = (f"PMAX {regs.get(D.RID_PMAX, nan):.1f} VMAX {regs.get(D.RID_VMAX, nan):.1f} "
                f"TMAX {regs.get(D.RID_TMAX, nan):.1f}")
        if timeout:
            text += f", timeout {timeout * D.TIMEOUT_UNIT_S * 1e3:.0f} ms"
        elif timeout == 0:  # the follower sets it at connect; a motor left at 0 has no fallback of its own
            text += ", command timeout off (the follower sets it at connect)"
        rep.status[f"id {sid}"] = text
    if trips:
        rep.round_trip_ms = sorted(trips)[len(trips) // 2]
    if with_feedback:
        t0 = clock.now()
        for sid in slaves:
            link.send(sid, D.special_frame(D.CODE_DISABLE))
        link.wait(lambda: all(t >= t0 for t in dec.t_rx), 0.05, push)
        for k, sid in enumerate(slaves):
            d = dec.latest[k]
            if d is None:
                continue
            _, err, *_, t_mos, t_rot = D.decode_feedback(d, D.MODELS["DM4310"].ranges)
            rep.temperatures_c.append(float(max(t_mos, t_rot)))
            if err not in (D.ERR_ENABLED, D.ERR_DISABLED):
                name = D.ERR_NAMES.get(err, f"error 0x{err:X}")
                rep.error(f"motor id {sid}: {name} -- clear it (power cycle or the clear-error frame) after "
                          "fixing the cause")
            if max(t_mos, t_rot) >= TEMP_WARN_C:
                rep.error(f"motor id {sid} at {max(t_mos, t_rot)} degC -- let it cool")
    else:
        rep.notes.append("ERR codes and temperatures need with_feedback=True (disables the motors)")
    return rep


# -- `factr2 doctor` adapters (declared by hardware/piper and hardware/damiao KIND, hardware/registry.py) ----
def _findings(rep: ProbeReport, subject: str) -> list:
    from hardware.doctor import Finding

    lines = rep.lines()
    return [Finding("ok" if rep.ok else "error", subject, lines[0].split(": ", 1)[-1])] + [
        Finding("info", subject, ln.strip()) for ln in lines[1:]]


def _run(probe, cfg, subject: str) -> list:
    from hardware.can_bus import open_bus

    bus = open_bus(cfg.channel, cfg.interface, cfg.bitrate)
    try:
        rep = probe(bus, cfg)
    finally:
        bus.shutdown()
    return _findings(rep, subject)


def _check(probe, kind: str, cfg) -> list:
    from hardware.doctor import DeviceCheck, Finding
    from hardware.errors import UserError

    title = f"CAN {cfg.interface}:{cfg.channel} ({kind} {cfg.name})"
    try:
        return [DeviceCheck(title, findings=_run(probe, cfg, f"{cfg.channel} {kind}"))]
    except UserError as e:
        return [DeviceCheck(title, findings=[Finding("error", f"{cfg.channel} {kind}", e.what, e.fix)])]


def piper_checks(config: PiperFollowerConfig, loop_hz: float) -> list:
    """A rig's Piper, probed with its own config (read-only)."""
    return _check(probe_piper, "piper", config)


def damiao_checks(config: DamiaoFollowerConfig, loop_hz: float) -> list:
    """A rig's Damiao chain, probed with its own ids and motors (read-only)."""
    return _check(probe_damiao, "damiao", config)


def piper_bare(interface: str) -> list:
    """`factr2 doctor --can IFACE`: a Piper with the default config on this interface."""
    return _run(probe_piper, PiperFollowerConfig(channel=interface), f"{interface} piper")


def damiao_bare(interface: str) -> list:
    """`factr2 doctor --can IFACE`: a 6-motor YAM-style Damiao chain (ids 1-6) on this interface."""
    cfg = DamiaoFollowerConfig(channel=interface, ids=[1, 2, 3, 4, 5, 6],
                               motor=["DM4340"] * 3 + ["DM4310"] * 3)
    return _run(probe_damiao, cfg, f"{interface} damiao")
