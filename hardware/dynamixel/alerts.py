"""A leader servo with a hardware alert (Hardware Error Status(70): overload, overheating, ...) has dropped
its torque and stays so until rebooted. The driver reboots it once the alert has lasted REBOOT_AFTER_S, and
turns its torque back on when it answers without the alert: teleop resumes without a restart. The
pair holds the follower meanwhile (STATUS_DRIVER_ERROR on that joint).

    reb = AlertRebooter()
    reb.service(leader, alerting_ids, answered_ids)  # each read that saw an alert or has one pending
    reb.notes                                                 # what it did, in words (the driver's warnings)
"""

from __future__ import annotations

from hardware.dynamixel import protocol as p
from hardware.errors import DeviceError

REBOOT_AFTER_S = 0.5  # s: an alert lasts this long before the servo is rebooted (an overload cools a little)
REBOOT_MAX = 3  # reboots per servo while the rig is open; then it stays off (the alert is a real fault)


def alert_names(bits: int) -> str:
    """Hardware Error Status(70) bits in words."""
    return ", ".join(v for b, v in p.HW_ERROR_BITS.items() if bits >> b & 1) or f"0x{bits:02x}"


class AlertRebooter:
    def __init__(self):
        self.since: dict[int, float] = {}  # servo id -> when its alert was first seen [s]
        self.rebooted: set[int] = set()  # rebooted, torque not back on yet
        self.counts: dict[int, int] = {}
        self.notes: list[str] = []

    @property
    def pending(self) -> bool:
        return bool(self.since or self.rebooted)

    def _note(self, text: str) -> None:
        self.notes.append(text)  # the driver says them (its warnings, logged)

    def step(self, bus, t: float, alerting: list[int], answered, torque_on: bool) -> None:
        """t [s]; alerting: ids whose status has the alert bit now; answered: ids that answered this read."""
        for i in alerting:
            self.since.setdefault(i, t)
        for i in [i for i in self.since if i in answered and i not in alerting]:
            del self.since[i]  # cleared without a reboot
        for i, t0 in list(self.since.items()):
            if t - t0 < REBOOT_AFTER_S or self.counts.get(i, 0) >= REBOOT_MAX:
                continue
            try:
                bits = bus.read(i, p.ADDR_HARDWARE_ERROR_STATUS)
                bus.reboot(i)
            except DeviceError as e:
                self._note(f"servo id {i}: reboot failed ({e}); trying again")
                self.since[i] = t
                continue
            self.counts[i] = self.counts.get(i, 0) + 1
            del self.since[i]
            self.rebooted.add(i)
            self._note(f"servo id {i}: hardware alert ({alert_names(bits)}) for {t - t0:.1f} s: rebooted")
        for i in [i for i in self.rebooted if i in answered and i not in alerting]:
            try:
                if torque_on:
                    bus.write(i, p.ADDR_TORQUE_ENABLE, 1)
            except DeviceError as e:
                self._note(f"servo id {i}: torque on after its reboot failed ({e}); trying again")
                continue
            self.rebooted.discard(i)
            self._note(f"servo id {i}: back after its reboot" + (", torque on" if torque_on else ""))

    def service(self, leader, alerting: list[int], answered) -> None:
        """step() for a DynamixelLeader (its bus, clock and torque state); what it did goes to the leader's
        warnings (the loop says them)."""
        seen = len(self.notes)
        self.step(leader.bus, leader.clock.now(), alerting, answered, leader._torque_on)
        for text in self.notes[seen:]:
            leader._warn(f"leader {leader.config.name}: {text}")
