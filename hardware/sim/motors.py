"""The contract between wire emulators and simulated motors, plus a minimal plant for driver tests.

A MotorBank is what a device emulator (Piper/Damiao on CAN, Dynamixel on a pty) sees of its motors:
per-motor arrays indexed 0..n-1 (the emulator maps bus ids to indices). The MuJoCo twin implements it with
full physics and actuator effects (hardware/sim/twin.py); IdealMotorBank below is a small stand-alone plant
(unit-inertia joints, no gravity) so drivers and emulators can be tested without MuJoCo.

Each motor is in the mode of its latest command: "position" (the firmware's own position loop),
"mit" (tau = kp (q_d - q) + kd (v_d - q_dot) + tau_ff), "current" (current control) or disabled.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

MODE_DISABLED, MODE_POSITION, MODE_MIT, MODE_CURRENT = 0, 1, 2, 3


@dataclass
class MotorReading:
    """Measured values as the motors' firmware reports them (noise and quantisation included).

    t [s] sim time, q [rad] (m for prismatic grippers), q_dot [rad/s], current [A], tau_m = K*current
    [N*m], temperature [degC], enabled (bool per motor)."""

    t: float
    q: np.ndarray
    q_dot: np.ndarray
    current: np.ndarray
    tau_m: np.ndarray
    temperature: np.ndarray
    enabled: np.ndarray


class MotorBank(Protocol):
    n: int
    torque_constant: np.ndarray  # N*m/A per motor, output side

    def read(self) -> MotorReading: ...

    def command_position(self, idx: np.ndarray, q: np.ndarray) -> None: ...

    def command_mit(self, idx: np.ndarray, q: np.ndarray, v: np.ndarray, kp: np.ndarray,
                    kd: np.ndarray, tau_ff: np.ndarray) -> None: ...

    def command_current(self, idx: np.ndarray, current_a: np.ndarray) -> None: ...

    def enable(self, idx: np.ndarray, on: bool) -> None: ...


class IdealMotorBank:
    """n unit-inertia joints with viscous damping, no gravity, exact sensors: a test plant.

    advance(t) integrates to sim time t [s] at dt_s. Position mode is a stiff PD inside the 'firmware'.
    """

    def __init__(self, n: int, torque_constant: np.ndarray | float = 1.0, dt_s: float = 1e-3,
                 inertia: float = 0.01, damping: float = 0.05, kp_fw: float = 40.0, kd_fw: float = 1.0,
                 tau_max: float = 10.0, q0: np.ndarray | None = None):
        self.n, self.dt_s = n, dt_s
        self.torque_constant = np.broadcast_to(np.asarray(torque_constant, float), (n,)).copy()
        self.inertia, self.damping = inertia, damping
        self.kp_fw, self.kd_fw, self.tau_max = kp_fw, kd_fw, tau_max
        self.t = 0.0
        self.q = np.zeros(n) if q0 is None else np.asarray(q0, float).copy()
        self.q_dot = np.zeros(n)
        self.mode = np.zeros(n, dtype=int)
        self.q_d = self.q.copy()
        self.v_d = np.zeros(n)
        self.kp = np.zeros(n)
        self.kd = np.zeros(n)
        self.tau_ff = np.zeros(n)
        self.current_cmd = np.zeros(n)
        self.tau_motor = np.zeros(n)
        self.tau_external = np.zeros(n)  # N*m, set by tests to push the joints

    def read(self) -> MotorReading:
        cur = self.tau_motor / self.torque_constant
        return MotorReading(t=self.t, q=self.q.copy(), q_dot=self.q_dot.copy(), current=cur,
                            tau_m=self.tau_motor.copy(), temperature=np.full(self.n, 30.0),
                            enabled=self.mode != MODE_DISABLED)

    def command_position(self, idx, q) -> None:
        idx = np.asarray(idx)
        self.mode[idx], self.q_d[idx] = MODE_POSITION, q

    def command_mit(self, idx, q, v, kp, kd, tau_ff) -> None:
        idx = np.asarray(idx)
        self.mode[idx] = MODE_MIT
        self.q_d[idx], self.v_d[idx], self.kp[idx], self.kd[idx], self.tau_ff[idx] = q, v, kp, kd, tau_ff

    def command_current(self, idx, current_a) -> None:
        idx = np.asarray(idx)
        self.mode[idx], self.current_cmd[idx] = MODE_CURRENT, current_a

    def enable(self, idx, on: bool) -> None:
        idx = np.asarray(idx)
        if on:
            self.mode[idx] = np.where(self.mode[idx] == MODE_DISABLED, MODE_POSITION, self.mode[idx])
            self.q_d[idx] = self.q[idx]
        else:
            self.mode[idx] = MODE_DISABLED

    def _motor_torque(self) -> np.ndarray:
        tau = np.zeros(self.n)
        m = self.mode
        pos, mit, cur = m == MODE_POSITION, m == MODE_MIT, m == MODE_CURRENT
        tau[pos] = self.kp_fw * (self.q_d - self.q)[pos] - self.kd_fw * self.q_dot[pos]
        tau[mit] = (self.kp * (self.q_d - self.q) + self.kd * (self.v_d - self.q_dot) + self.tau_ff)[mit]
        tau[cur] = (self.current_cmd * self.torque_constant)[cur]
        return np.clip(tau, -self.tau_max, self.tau_max)

    def advance(self, t_target: float) -> None:
        while self.t + 0.5 * self.dt_s < t_target:
            self.tau_motor = self._motor_torque()
            acc = (self.tau_motor + self.tau_external - self.damping * self.q_dot) / self.inertia
            self.q_dot = self.q_dot + acc * self.dt_s
            self.q = self.q + self.q_dot * self.dt_s
            self.t += self.dt_s
