"""DynamixelLeader's use of the servos' own fallback, the Bus Watchdog(98) (hardware/dynamixel/watchdog.py):
cleared at connect (a crashed app's latch), armed and read back, kept armed before goal writes (re-armed after
a gap or a reboot, a latch found by read-back said once), and the lines that report it.

A mixin of DynamixelLeader (leader.py); the attributes are the driver's.
"""

from __future__ import annotations

import logging

from hardware.dynamixel import protocol as p
from hardware.dynamixel import watchdog as wd
from hardware.dynamixel.bus import DynamixelBus
from hardware.errors import DeviceError

log = logging.getLogger("factr2.dynamixel")


class LeaderWatchdog:
    """The Bus Watchdog handling of DynamixelLeader (mixed in)."""

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

    def _rest_fallback(self) -> None:
        """Leader.rest(), after its 0 A: the servos will hear nothing until the next command, which their
        Bus Watchdog would take for a dead host and latch -- harmless at 0 A, but reported as lost force
        feedback at the end. Stood down (0: off) here, each servo after a 0 A goal it acknowledged (the
        sync write has no status: a lost one must not leave a current unwatched); the next goal write arms
        it again (_keep_watchdog: 0, then the period) before its current lands. A servo that refuses either
        stays armed, and latches at 0 A."""
        k, bus = self._wd, self.bus
        if k is None or bus is None:
            return
        for i in k.ids:
            try:
                bus.write(i, p.ADDR_GOAL_CURRENT, 0)
                bus.write(i, wd.ADDR, 0)
            except DeviceError as e:
                log.info("leader %s: Bus Watchdog of servo %d not stood down for the rest: %s",
                         self.config.name, i, e)
        k.mark_due()

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
