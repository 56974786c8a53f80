"""Base types every driver, twin and loop shares: joint state, limits, commands, the Leader/Follower roles.

Units: rad, rad/s, N*m, A, degC, s. Flat feature names follow LeRobot ("joint.pos", "joint.tau_ext").
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# Status flag bits in JointState.status (per joint, uint32). Drivers map vendor bits onto these.
STATUS_ENABLED = 1 << 0
STATUS_OVERTEMP = 1 << 1
STATUS_OVERCURRENT = 1 << 2
STATUS_UNDERVOLTAGE = 1 << 3
STATUS_COMM_LOST = 1 << 4
STATUS_COLLISION = 1 << 5
STATUS_DRIVER_ERROR = 1 << 6
STATUS_STALL = 1 << 7
STATUS_LIMIT = 1 << 8
STATUS_STALE = 1 << 9  # no fresh feedback for this joint within the watchdog timeout
STATUS_HOLD = 1 << 10  # the safety layer put the device on hold
STATUS_IMPLAUSIBLE = 1 << 11  # this sample jumped further than the joint can move: the previous value is held
# a motor reporting one of these is not driven on (the pair holds until the report clears)
STATUS_MOTOR_ERROR = STATUS_OVERTEMP | STATUS_OVERCURRENT | STATUS_DRIVER_ERROR


def _nan(n: int) -> np.ndarray:
    return np.full(n, np.nan)


@dataclass
class JointState:
    """One sample of an arm's joints (the gripper is separate).

    t: host clock time of the sample [s] (clock of the rig: monotonic or simulated).
    q [rad], q_dot [rad/s], tau_m: measured motor torque = current x torque constant [N*m],
    current [A], q_cmd: last commanded joint target [rad] (NaN when none), temperature [degC],
    status: per-joint STATUS_* bit flags. Gripper: position [m of stroke, or rad for a leader trigger],
    effort [N*m or N as the device reports].
    """

    t: float
    q: np.ndarray
    q_dot: np.ndarray
    tau_m: np.ndarray
    current: np.ndarray
    q_cmd: np.ndarray
    temperature: np.ndarray
    status: np.ndarray
    gripper_pos: float = float("nan")
    gripper_effort: float = float("nan")

    @classmethod
    def empty(cls, n: int, t: float = float("nan")) -> JointState:
        return cls(t=t, q=_nan(n), q_dot=_nan(n), tau_m=_nan(n), current=_nan(n), q_cmd=_nan(n),
                   temperature=_nan(n), status=np.zeros(n, dtype=np.uint32))

    @property
    def n(self) -> int:
        return int(self.q.shape[0])

    def features(self, prefix: str = "joint") -> dict[str, np.ndarray | float]:
        """Flat feature dict ("joint.pos", ...) for recording and policies."""
        return {
            f"{prefix}.pos": self.q, f"{prefix}.vel": self.q_dot, f"{prefix}.tau": self.tau_m,
            f"{prefix}.current": self.current, f"{prefix}.pos_cmd": self.q_cmd,
            f"{prefix}.temp": self.temperature, f"{prefix}.status": self.status,
            "gripper.pos": self.gripper_pos, "gripper.effort": self.gripper_effort,
        }


@dataclass(frozen=True)
class JointLimits:
    """Per-joint limits the safety layer enforces (arrays of length n).

    q_min/q_max [rad], v_max [rad/s] (also bounds how fast a position target may move),
    tau_max [N*m] (feed-forward / leader torque), tau_rate_max [N*m/s] (torque slew),
    kp_max [N*m/rad], kd_max [N*m*s/rad] for impedance (MIT) commands.
    """

    q_min: np.ndarray
    q_max: np.ndarray
    v_max: np.ndarray
    tau_max: np.ndarray
    tau_rate_max: np.ndarray
    kp_max: np.ndarray = field(default=None)  # type: ignore[assignment]
    kd_max: np.ndarray = field(default=None)  # type: ignore[assignment]

    def __post_init__(self):
        n = len(self.q_min)
        for name in ("q_min", "q_max", "v_max", "tau_max", "tau_rate_max", "kp_max", "kd_max"):
            v = getattr(self, name)
            if v is None:
                v = np.full(n, {"kp_max": 500.0, "kd_max": 5.0}.get(name, np.inf))
            arr = np.asarray(v, dtype=float).reshape(-1).copy()
            if arr.shape != (n,):
                raise ValueError(f"JointLimits.{name} has {arr.shape[0]} entries, expected {n}")
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        if np.any(self.q_min >= self.q_max):
            raise ValueError("JointLimits: q_min must be below q_max on every joint")
        for name in ("v_max", "tau_max", "tau_rate_max", "kp_max", "kd_max"):
            if np.any(~(getattr(self, name) > 0)):
                raise ValueError(f"JointLimits.{name} must be positive on every joint")

    @property
    def n(self) -> int:
        return int(self.q_min.shape[0])


@dataclass(frozen=True)
class FollowerCommand:
    """What a loop asks of a follower. Raw: it must pass hardware.safety before reaching a motor.

    q [rad] joint targets; tau_ff [N*m] feed-forward (None: zero); kp [N*m/rad] / kd [N*m*s/rad]
    impedance gains for MIT-capable followers (None: the device's position loop);
    gripper [m stroke, None: keep].
    """

    q: np.ndarray
    tau_ff: np.ndarray | None = None
    kp: np.ndarray | None = None
    kd: np.ndarray | None = None
    gripper: float | None = None

    @classmethod
    def targets(cls, q: np.ndarray, gripper: float | None = None) -> FollowerCommand:
        """FollowerCommand(q=q, gripper=gripper): joint targets [rad] alone, built without the frozen
        dataclass's per-field object.__setattr__ (the 500 Hz loop's command; the same value)."""
        c = object.__new__(cls)
        d = c.__dict__
        d["q"], d["tau_ff"], d["kp"], d["kd"], d["gripper"] = q, None, None, None, gripper
        return c
