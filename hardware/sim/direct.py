"""A follower driven directly on a twin's motor bank, without a wire protocol (SIMULATED ONLY).

Used for arms that have no supported bus in this project (the Franka Panda rig `sim-panda`): the same
Follower role, safety layer and watchdog as a real driver, but commands go straight to the MujocoBank
(position loop for plain targets, the MIT law when gains are given) and read() returns the bank's
firmware-style reading. It refuses to exist outside a twin: there is no hardware behind it.

KIND declares rig `driver = "sim"` (hardware/registry.py): simulated rigs only, no wire, no doctor probe.
"""

from __future__ import annotations

import numpy as np

from hardware.clock import Clock
from hardware.errors import ConfigError
from hardware.registry import DeviceKind, TwinDrive
from hardware.roles import Follower
from hardware.safety import DEFAULT_WATCHDOG_S, SafeFollowerCommand
from hardware.types import STATUS_ENABLED, STATUS_HOLD, JointLimits, JointState


class BankFollower(Follower):
    """Follower on bank motors 0..n-1 (arm joints); motor n is the gripper when the bank has one."""

    simulated = True

    def __init__(self, name: str, bank, limits: JointLimits, clock: Clock | None = None,
                 watchdog_s: float = DEFAULT_WATCHDOG_S):
        super().__init__(name, limits, clock, watchdog_s)
        self.bank = bank
        self._idx = np.arange(limits.n)
        self._connected = False
        self._q_cmd = np.full(limits.n, np.nan)

    @property
    def is_connected(self) -> bool:
        return self._connected

    def connect(self) -> None:
        self._connected = True
        self.bank.enable(np.arange(self.bank.n), True)
        self.read()

    def _disconnect_bus(self) -> None:
        self._connected = False

    def _read(self) -> JointState | None:
        r = self.bank.read()
        n = self.n_joints
        status = np.where(r.enabled[:n], STATUS_ENABLED, 0).astype(np.uint32)
        if self.in_safe_state:
            status |= STATUS_HOLD
        st = JointState(t=self.clock.now(), q=r.q[:n].copy(), q_dot=r.q_dot[:n].copy(),
                        tau_m=r.tau_m[:n].copy(), current=r.current[:n].copy(), q_cmd=self._q_cmd.copy(),
                        temperature=r.temperature[:n].copy(), status=status)
        if self.bank.n > n:
            st.gripper_pos, st.gripper_effort = float(r.q[n]), float(r.tau_m[n])
        return st

    def _send_safe(self, safe: SafeFollowerCommand) -> None:
        self._q_cmd = safe.q.copy()
        if safe.hold or safe.kp is None:  # hold: the position loop keeps the arm where it is
            self.bank.command_position(self._idx, safe.q)
        else:
            self.bank.command_mit(self._idx, safe.q, np.zeros(self.n_joints), safe.kp, safe.kd, safe.tau_ff)
        if safe.gripper is not None and self.bank.n > self.n_joints:
            self.bank.command_position(np.array([self.n_joints]), np.array([float(safe.gripper)]))


SIM_GRIPPER_MOTOR = "piper_gripper"  # hardware/sim/presets.py: gripper drive of arms without a real bus


def make_driver(spec, clock, twin=None) -> BankFollower:
    if twin is None:
        raise ConfigError(f"device {spec.name} has driver 'sim' but no twin runs", where=f"rig {spec.name}",
                          fix="use a simulated rig")
    return BankFollower(spec.name, twin.bank(spec.name), spec.limits(), clock=clock)


KIND = DeviceKind(driver="sim", role="follower", config=None, driver_ref="hardware.sim.direct:make_driver",
                  twin_drive=lambda c: TwinDrive(motors=None, gripper_motor=SIM_GRIPPER_MOTOR, gripper=True),
                  simulated_only=True)
