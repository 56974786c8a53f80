"""Free-motion calibration trajectories for NEXT (paper appendix, "Free-Space Data Collection Guidelines"):

  1. "single": each joint alone across its range (others at home), medium speed;
  2. "multi": multi-joint motions -- every joint moves at once to random targets, time-synchronised by ruckig
     so the arm follows a straight line in joint space (not a Cartesian line: no IK is involved);
  3. "slow" and "fast": the same kind of multi-joint motions at low and at full speed (velocity-dependent
     friction and actuator effects).

Every piece is a jerk-limited ruckig profile from rest to rest within the position (shrunk by `margin`),
velocity, acceleration and jerk limits, sampled at `rate_hz`. With a MuJoCo scene (the arm on its table,
hardware.arms) every candidate move is checked for self-collision and collision with the table/objects
and rejected when it collides; without one, `collision_checked` is False and the caller must say so.
Default length 10 minutes (the paper's amount of free-space data).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import ruckig

PHASES = ("single", "multi", "slow", "fast")
PHASE_SPEED = {"single": 0.5, "multi": 0.6, "slow": 0.2, "fast": 1.0}  # fraction of v_max / a_max
PHASE_SHARE = {"multi": 0.4, "slow": 0.3, "fast": 0.3}  # of the time left after the single-joint sweeps
# Extra clearance [m] at full speed (|qd_j| = v_max_j), scaled per sample by the path's speed: the follower's
# position loop lags its command in proportion to velocity (the Piper twin's shoulder by 0.12 rad in the fast
# phase, ~6 cm at the gripper), so a fast stretch needs more room than a slow one. With 5 cm everywhere the
# 10-minute replay touched the table 52 times (twin ground truth).
LAG_CLEARANCE_M = 0.08
# The lag outlasts the motion: the arm is still settling (0.15 rad behind on the shoulder) when a fast move's
# command has stopped, so each sample gets the allowance of the fastest sample in the preceding LAG_SETTLE_S.
LAG_SETTLE_S = 0.5


def lag_speed(qd: np.ndarray, v_max: np.ndarray, window: int) -> np.ndarray:
    """Per sample of a path: the largest max_j |qd_j| / v_max_j over that sample and the `window` - 1 before
    it (0 before the path starts: a move starts from rest, where the previous move's end was checked)."""
    s = np.max(np.abs(qd) / v_max, axis=1)
    w = max(int(window), 1)
    return np.lib.stride_tricks.sliding_window_view(np.r_[np.zeros(w - 1), s], w).max(axis=1)


@dataclass
class Trajectory:
    t: np.ndarray  # (N,) s, uniform
    q: np.ndarray  # (N, n) rad
    qd: np.ndarray  # (N, n) rad/s
    qdd: np.ndarray  # (N, n) rad/s^2
    phase: np.ndarray  # (N,) index into PHASES
    rate_hz: float
    joint_names: list[str]
    arm: str = ""
    collision_checked: bool = False

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0]) if len(self.t) else 0.0

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        np.savez(path, t=self.t, q=self.q, qd=self.qd, qdd=self.qdd, phase=self.phase,
                 phase_names=np.array(PHASES), rate_hz=self.rate_hz, joint_names=np.array(self.joint_names),
                 arm=np.array(self.arm), collision_checked=self.collision_checked)
        return path

    @classmethod
    def load(cls, path: str | Path) -> Trajectory:
        from hardware.errors import ConfigError

        try:
            with np.load(path, allow_pickle=False) as z:
                return cls(t=z["t"], q=z["q"], qd=z["qd"], qdd=z["qdd"], phase=z["phase"],
                           rate_hz=float(z["rate_hz"]), joint_names=[str(s) for s in z["joint_names"]],
                           arm=str(z["arm"]), collision_checked=bool(z["collision_checked"]))
        except (OSError, KeyError, ValueError) as e:
            raise ConfigError(f"not a calibration trajectory file ({type(e).__name__})", where=str(path),
                              fix="generate one with calibration.trajectories.coverage_trajectory") from None


def ruckig_move(q0: np.ndarray, q1: np.ndarray, v_max, a_max, j_max, rate_hz: float
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rest-to-rest jerk-limited move q0 -> q1 sampled at rate_hz (first sample q0, last sample q1)."""
    n = len(q0)
    otg, inp, traj = ruckig.Ruckig(n), ruckig.InputParameter(n), ruckig.Trajectory(n)
    inp.current_position, inp.target_position = list(map(float, q0)), list(map(float, q1))
    inp.current_velocity = inp.current_acceleration = [0.0] * n
    inp.target_velocity = inp.target_acceleration = [0.0] * n
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = (list(map(float, a))
                                                            for a in (v_max, a_max, j_max))
    try:
        res = otg.calculate(inp, traj)
    except ruckig.RuckigError as e:  # (an Exception, not a RuntimeError): said as the result is
        raise ValueError(f"ruckig could not plan the move ({str(e).strip().splitlines()[0]})") from None
    if res not in (ruckig.Result.Working, ruckig.Result.Finished):
        raise ValueError(f"ruckig could not plan the move ({res})")
    ts = np.arange(int(np.ceil(traj.duration * rate_hz)) + 1) / rate_hz
    ts[-1] = min(ts[-1], traj.duration)
    samples = [traj.at_time(float(t)) for t in ts]
    return tuple(np.array([s[i] for s in samples]) for i in range(3))


class CollisionChecker:
    """Arm bodies closer than `clearance_m` to each other or to the scene at a joint configuration.
    The clearance covers the follower's tracking lag (a replayed path that only grazes the table on paper
    does touch it on the arm). Pairs already that close at the home pose are allowed."""

    def __init__(self, arm, scene: str = "table", clearance_m: float = 0.05,
                 max_extra_m: float = LAG_CLEARANCE_M):
        import mujoco

        self._mj = mujoco
        self.base = clearance_m
        self.model = mujoco.MjModel.from_xml_path(str(arm.scene_path(scene)))
        self.data = mujoco.MjData(self.model)
        self.qadr, _ = arm.mujoco_indices(self.model)
        # The gripper is not on the path but its fingers can stand anywhere in their travel (the twin's Piper
        # fingers hang open at ~3 cm and touched the table where the closed-finger check saw room): check the
        # arm with the fingers closed and fully open.
        self.rest_poses = [self.model.qpos0.copy() for _ in range(2)]
        for g in arm.gripper_joints:
            jid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_JOINT, g)
            adr = self.model.jnt_qposadr[jid]
            for pose, end in zip(self.rest_poses, self.model.jnt_range[jid]):
                pose[adr] = end
        moving = {int(self.model.jnt_bodyid[mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_JOINT, j)])
                  for j in arm.joint_names}
        self.arm_bodies = set()
        for b in range(self.model.nbody):  # every body below a moving arm joint
            a = b
            while a > 0 and a not in moving:
                a = int(self.model.body_parentid[a])
            if a in moving:
                self.arm_bodies.add(b)
        self.allowed: set[tuple[int, int]] = set()
        self._set_clearance(clearance_m + max_extra_m)  # pairs that close at home stay allowed at any speed
        self.allowed = set(self.pairs(np.asarray(arm.q_home, float)))
        self._set_clearance(clearance_m)

    def _set_clearance(self, clearance_m: float) -> None:
        self.clearance = clearance_m
        self.model.geom_margin[:] = clearance_m  # report pairs within the clearance, not just touching

    def pairs(self, q: np.ndarray) -> list[tuple[int, int]]:
        """(geom, geom) pairs closer than the clearance at arm pose q [rad], fingers closed or open."""
        out: list[tuple[int, int]] = []
        for rest in self.rest_poses:
            self.data.qpos[:] = rest
            self.data.qpos[self.qadr] = q
            self._mj.mj_forward(self.model, self.data)
            for c in self.data.contact[: self.data.ncon]:
                b1, b2 = int(self.model.geom_bodyid[c.geom1]), int(self.model.geom_bodyid[c.geom2])
                if (b1 in self.arm_bodies or b2 in self.arm_bodies) and c.dist < self.clearance:
                    pair = (min(c.geom1, c.geom2), max(c.geom1, c.geom2))
                    if pair not in self.allowed and pair not in out:
                        out.append(pair)
        return out

    def collides(self, q_path: np.ndarray, stride: int = 5, extra_m=0.0) -> bool:
        """Any sampled configuration closer than the clearance + extra_m [m] (the lag allowance: a scalar,
        or one value per sample of q_path)."""
        extra = np.broadcast_to(np.asarray(extra_m, float), (len(q_path),))
        idx = np.r_[np.arange(0, len(q_path), stride), len(q_path) - 1]
        try:
            for i in idx:
                self._set_clearance(self.base + extra[i])
                if self.pairs(q_path[i]):
                    return True
            return False
        finally:
            self._set_clearance(self.base)


def coverage_trajectory(q_min, q_max, v_max, q_home, minutes: float = 10.0, rate_hz: float = 100.0,
                        a_max=None, j_max=None, margin: float = 0.1, seed: int = 0,
                        checker: CollisionChecker | None = None, joint_names=None, arm: str = "",
                        max_tries: int = 50) -> Trajectory:
    """The paper's coverage recipe (module docstring) lasting about `minutes`, within the limits:
    q in [q_min + margin*span, q_max - margin*span] [rad], |qd| <= v_max [rad/s], |qdd| <= a_max
    (default 2 v_max) [rad/s^2], jerk <= j_max (default 10 a_max) [rad/s^3]."""
    q_min, q_max, v_max, home = (np.asarray(a, float) for a in (q_min, q_max, v_max, q_home))
    n = len(q_min)
    a_max = 2.0 * v_max if a_max is None else np.asarray(a_max, float)
    j_max = 10.0 * a_max if j_max is None else np.asarray(j_max, float)
    span = q_max - q_min
    lo, hi = q_min + margin * span, q_max - margin * span
    home = np.clip(home, lo, hi)
    rng = np.random.default_rng(seed)
    pieces: list[tuple[np.ndarray, np.ndarray, np.ndarray, int]] = []
    state = {"q": home, "time": 0.0}

    def move_to(target: np.ndarray, phase: str) -> bool:
        s = PHASE_SPEED[phase]
        q, qd, qdd = ruckig_move(state["q"], target, s * v_max, s * a_max, s * j_max, rate_hz)
        if checker is not None and checker.collides(
                q, extra_m=LAG_CLEARANCE_M * lag_speed(qd, v_max, int(LAG_SETTLE_S * rate_hz))):
            return False
        pieces.append((q[1:], qd[1:], qdd[1:], PHASES.index(phase)))
        state["q"], state["time"] = target, state["time"] + (len(q) - 1) / rate_hz
        return True

    for j in range(n):  # 1. each joint alone across its range
        for end in (lo[j], hi[j], home[j]):
            target = state["q"].copy()
            target[j] = end
            if not move_to(target, "single"):  # blocked: go as far as is free
                for frac in (0.75, 0.5, 0.25):
                    target[j] = home[j] + frac * (end - home[j])
                    if move_to(target, "single"):
                        break
    left = max(minutes * 60.0 - state["time"], 0.0)
    for phase in ("multi", "slow", "fast"):  # 2./3. multi-joint, then slow, then fast
        phase_end = state["time"] + PHASE_SHARE[phase] * left
        while state["time"] < phase_end:
            for _ in range(max_tries):
                if move_to(rng.uniform(lo, hi), phase):
                    break
            else:  # boxed in (near the table, every fast path needs more room): back home slowly, go on
                if np.allclose(state["q"], home) or not move_to(home, "slow"):
                    raise ValueError(f"no collision-free {phase} move found in {max_tries} tries")
    if not np.allclose(state["q"], home):
        move_to(home, "slow")
    q = np.concatenate([home[None]] + [p[0] for p in pieces])
    qd = np.concatenate([np.zeros((1, n))] + [p[1] for p in pieces])
    qdd = np.concatenate([np.zeros((1, n))] + [p[2] for p in pieces])
    phase = np.concatenate([[0]] + [np.full(len(p[0]), p[3]) for p in pieces]).astype(np.int8)
    return Trajectory(t=np.arange(len(q)) / rate_hz, q=q, qd=qd, qdd=qdd, phase=phase, rate_hz=rate_hz,
                      joint_names=list(joint_names or [f"joint{i + 1}" for i in range(n)]), arm=arm,
                      collision_checked=checker is not None)


def arm_coverage_trajectory(arm_name: str, minutes: float = 10.0, rate_hz: float = 100.0, seed: int = 0,
                            scene: str | None = "table") -> Trajectory:
    """coverage_trajectory for an arm of hardware.arms, collision-checked on its MuJoCo scene when
    `scene` is given (scene=None skips the check: collision_checked=False)."""
    from hardware.arms import load_arm

    arm = load_arm(arm_name)
    checker = CollisionChecker(arm, scene) if scene else None
    lim = arm.limits
    return coverage_trajectory(lim.q_min, lim.q_max, lim.v_max, arm.q_home, minutes, rate_hz, seed=seed,
                               checker=checker, joint_names=list(arm.joint_names), arm=arm.name)
