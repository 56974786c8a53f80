"""Operator takeover during a policy rollout (issue #33): pure functions on arrays, and the rig-file config.

While the policy drives, the leader FOLLOWS the follower: a weak spring-damper toward the follower's measured
pose mapped onto the leader's joints, on top of teleop's own leader law (gravity, friction, barrier, force
feedback), so the hand feels the policy's motion and its contacts and can overpower the spring at any time:

    tau_follow = cap( kp (q_goal - q) + kd (qd_goal - qd) + drag qd_goal, +-follow_tau_max_nm )
                                                                          [N*m, leader joints]
(drag qd_goal: a feed-forward of the back-driven servo gearbox's drag, so the spring is not what moves it)

What the spring holds against is the hand, and two things that are not one:
- the leader's uncompensated load, a slow function of the pose (measured on the twin's GELLO leader: the
  spring held 0.3 N*m on j2 and 0.2 N*m on j3 at rest, its gravity model against its servos' torque
  constants and friction): a baseline, the spring torque low-passed over hand_baseline_s while no hand is
  sensed (hand_baseline_step), is taken off;
- the leader's lag behind a moving follower (it cannot accelerate as fast: a small servo's torque, a
  back-driven gearbox), which outlasts the motion by a few tenths of a second: an allowance lag_j |qd_goal_j|
  that decays over follow_lag_hold_s once the follower slows (lag_allowance).
  hand_torque_nm = max_j (|s_j - baseline_j| - allowance_j), s = kp (q_goal - q) [N*m], the spring's torque
  before its cap. With the velocity-only allowance and no baseline, a peg-insert policy on the twin
  "took over" every few seconds with no hand on the leader (docs/takeover.md, "Sensing the hand").

Takeover (detect_step): the hand torque at or above grab_nm for grab_min_s (hysteresis: the timer keeps
running while it stays above release_nm, and restarts below it); hand-back: the hand torque at most release_nm
and the leader within rest_tol_rad of where it came to rest, for rest_s (a position window, not a speed: the
leader's reported velocity chatters with its friction dither while it stands still). A key does either at
once (the shell's business).

The switch of the follower's target between policy and leader (handover_target) never steps: at the switch
the gap between the last command and the new source is carried as an offset that fades to zero over blend_s,
and the result is rate-limited like every coupled teleop tick (soft_start.rate_limit: at most
rate_limit_rad_s * dt per tick), so the commanded target moves by at most what one tick of teleop would.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from factr2_teleop.teleop.soft_start import rate_limit
from hardware.params import PerJoint, clamp

POLICY, OPERATOR = "policy", "operator"  # who drives the follower
TAKEOVER, HANDBACK = "takeover", "handback"  # detect_step's events (and the recording's marks)
_T_EPS_S = 1e-9  # s: tick times are sums of floats; a duration of exactly N ticks counts as reached
# N*m: the hand baseline adapts only while some joint's lag allowance is above this (the arm moved in the
# last second or so): the leader's load changes with its pose; a hand on a leader at rest is never absorbed
BASELINE_ADAPT_NM = 0.05


@dataclass
class TakeoverConfig:
    """The rig file's [teleop.takeover] table (every pair's; one pair's: [teleop.pairs.<pair>.takeover]).

    follow_kp_nm_rad [N*m/rad] / follow_kd_nm_s_rad [N*m*s/rad]: the leader's following spring and damper
    (low: a hand overpowers it); follow_tau_max_nm [N*m]: its per-joint cap (a few N*m at most; the leader's
    JointLimits.tau_max and its safety layer bound it further); follow_drag_nm_s_rad [N*m*s/rad]: the
    velocity feed-forward of the leader's own drag (the twin's GELLO leader lags ~0.4 rad at 3 rad/s without);
    follow_lag_nm_s_rad [N*m*s/rad]: spring torque per follower speed that is the leader's lag, not a hand;
    follow_lag_hold_s [s]: how long that allowance outlasts the speed (decay time constant);
    hand_baseline_s [s]: time constant of the spring-torque baseline (the leader's slow uncompensated load).
    grab_nm / release_nm [N*m]: hand-torque thresholds of the hysteresis; grab_min_s [s]: how long above
    grab before the hand drives; grab_max_speed_rad_s [rad/s]: the hand is not sensed while the follower moves
    faster (the leader's lag is no hand: the key takes over); rest_s [s] and rest_tol_rad [rad]: the hand at
    rest (the leader within this of one pose) this long hands back;
    blend_s [s]: how long the gap between the two sources fades at a switch; pre_window_s [s]: the seconds
    of policy control before a takeover the recording marks as the pre-intervention window (Sirius)."""

    follow_kp_nm_rad: PerJoint = 4.0
    follow_kd_nm_s_rad: PerJoint = 0.1
    follow_tau_max_nm: PerJoint = 1.5
    follow_drag_nm_s_rad: PerJoint = 0.2
    follow_lag_nm_s_rad: PerJoint = 0.6
    follow_lag_hold_s: float = 0.5
    hand_baseline_s: float = 0.7
    grab_nm: float = 0.3
    release_nm: float = 0.15
    grab_min_s: float = 0.1
    grab_max_speed_rad_s: float = 1.5
    rest_s: float = 1.0
    rest_tol_rad: float = 0.03
    blend_s: float = 0.2
    pre_window_s: float = 2.0

    def validate(self, where: str = "takeover") -> None:
        from hardware.errors import ConfigError

        if not 0.0 <= self.release_nm <= self.grab_nm:
            raise ConfigError(f"needs 0 <= release_nm <= grab_nm, got {self.release_nm}, {self.grab_nm}",
                              where=where, fix="set release_nm below grab_nm")
        for name in ("grab_min_s", "grab_max_speed_rad_s", "rest_s", "rest_tol_rad", "blend_s",
                     "pre_window_s", "follow_lag_hold_s", "hand_baseline_s"):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"{name} must be >= 0", where=f"{where}.{name}", fix="fix the value")


# -- the leader follows the follower --------------------------------------------------------------------
def leader_goal(q_follower_on_leader: np.ndarray, q_leader: np.ndarray) -> np.ndarray:
    """The follower's pose on the leader's joints [rad] (JointMap.backward); a leader joint no follower joint
    depends on (NaN there) is its own goal: no spring on it."""
    g = np.asarray(q_follower_on_leader, dtype=float)
    return np.where(np.isfinite(g), g, np.asarray(q_leader, dtype=float))


def follow_torque(q: np.ndarray, qd: np.ndarray, q_goal: np.ndarray, qd_goal: np.ndarray, kp: np.ndarray,
                  kd: np.ndarray, drag: np.ndarray, cap_nm: np.ndarray) -> np.ndarray:
    """kp (q_goal - q) + kd (qd_goal - qd) + drag qd_goal, clipped per joint to +-cap_nm [N*m]; non-finite
    terms give 0."""
    qd_goal = np.nan_to_num(np.asarray(qd_goal, dtype=float))
    qd_err = qd_goal - np.nan_to_num(np.asarray(qd, dtype=float))
    tau = kp * (np.asarray(q_goal, dtype=float) - np.asarray(q, dtype=float)) + kd * qd_err + drag * qd_goal
    return clamp(np.where(np.isfinite(tau), tau, 0.0), -cap_nm, cap_nm)


def spring_torque_nm(q: np.ndarray, q_goal: np.ndarray, kp: np.ndarray) -> np.ndarray:
    """kp (q_goal - q) [N*m] per leader joint, before the cap (NaN where a joint is not finite)."""
    return kp * (np.asarray(q_goal, dtype=float) - np.asarray(q, dtype=float))


def lag_allowance(prev_nm: np.ndarray, qd_goal: np.ndarray, lag: np.ndarray, dt_s: float,
                  hold_s: float) -> np.ndarray:
    """The spring torque the leader's lag may explain [N*m]: lag |qd_goal| now, or the previous allowance
    decayed by exp(-dt/hold_s), whichever is larger (the lag outlasts the follower's motion)."""
    now = lag * np.abs(np.nan_to_num(np.asarray(qd_goal, dtype=float)))
    decay = math.exp(-dt_s / hold_s) if hold_s > 0 else 0.0
    return np.maximum(now, np.asarray(prev_nm, dtype=float) * decay)


def hand_baseline_step(baseline_nm: np.ndarray, spring_nm: np.ndarray, dt_s: float,
                       tau_s: float) -> np.ndarray:
    """One step of the spring-torque baseline [N*m]: a first-order low-pass with time constant tau_s (the
    caller freezes it while a hand is sensed); non-finite readings leave it as it was."""
    s = np.asarray(spring_nm, dtype=float)
    a = min(1.0, dt_s / tau_s) if tau_s > 0 else 1.0
    return np.where(np.isfinite(s), baseline_nm + a * (s - baseline_nm), baseline_nm)


def hand_torque_nm(spring_nm: np.ndarray, baseline_nm: np.ndarray, allowance_nm: np.ndarray,
                   qd_goal: np.ndarray, max_speed_rad_s: float = np.inf) -> float:
    """The torque the following spring holds against beyond the leader's load and lag [N*m]: max over joints
    of |spring - baseline| - allowance (at least 0; 0 when no joint is finite, and 0 while the follower moves
    faster than max_speed_rad_s on some joint: a leader that cannot keep up is no hand, and the key takes
    over then)."""
    qd = np.abs(np.nan_to_num(np.asarray(qd_goal, dtype=float)))
    if qd.size and float(qd.max()) > max_speed_rad_s:
        return 0.0
    t = np.abs(np.asarray(spring_nm, dtype=float) - baseline_nm) - allowance_nm
    t = np.maximum(t[np.isfinite(t)], 0.0)
    return float(t.max()) if t.size else 0.0


# -- who drives --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class DetectorState:
    """driver: POLICY or OPERATOR; t_above [s]: since when the hand torque has stayed above release_nm after
    reaching grab_nm (NaN: not); t_rest [s]: since when the hand has been at rest (NaN: not), at the leader
    pose q_rest [rad]."""

    driver: str = POLICY
    t_above: float = math.nan
    t_rest: float = math.nan
    q_rest: np.ndarray | None = None


def detect_step(st: DetectorState, t: float, hand_nm: float, q_leader: np.ndarray, cfg: TakeoverConfig
                ) -> tuple[DetectorState, str | None]:
    """One tick of the hand detector at time t [s] (hand_nm [N*m]; q_leader: every leader's joints [rad]):
    (new state, TAKEOVER / HANDBACK / None)."""
    if st.driver == POLICY:
        above = st.t_above
        if hand_nm >= cfg.grab_nm and not math.isfinite(above):
            above = t
        elif hand_nm < cfg.release_nm:
            above = math.nan
        if math.isfinite(above) and t - above >= cfg.grab_min_s - _T_EPS_S:
            return DetectorState(OPERATOR, math.nan, math.nan), TAKEOVER
        return DetectorState(POLICY, above, math.nan), None
    q = np.asarray(q_leader, dtype=float)
    rest, anchor = st.t_rest, st.q_rest
    near = anchor is not None and bool(np.all(np.abs(q - anchor) <= cfg.rest_tol_rad))
    if hand_nm > cfg.release_nm or not np.isfinite(q).all():
        rest, anchor = math.nan, None
    elif not near:  # comes to rest here (or moved on): the window starts again at this pose
        rest, anchor = t, q.copy()
    if math.isfinite(rest) and t - rest >= cfg.rest_s - _T_EPS_S:
        return DetectorState(POLICY, math.nan, math.nan), HANDBACK
    return DetectorState(OPERATOR, math.nan, rest, anchor), None


def switched(driver: str) -> DetectorState:
    """The detector's state right after a key switched to `driver` (its timers restart)."""
    return DetectorState(driver, math.nan, math.nan)


# -- the follower's target across a switch -------------------------------------------------------------
def blend_weight(t_since_s: float, blend_s: float) -> float:
    """How much of the new source the target is, t_since_s [s] after a switch: 0 -> 1 linearly over
    blend_s (1 at once when blend_s is 0)."""
    if blend_s <= 0 or t_since_s >= blend_s:
        return 1.0
    return max(0.0, float(t_since_s) / blend_s)


def handover_target(q_source: np.ndarray, offset: np.ndarray, w: float, q_prev: np.ndarray,
                    v_max_rad_s: np.ndarray, dt_s: float) -> np.ndarray:
    """The follower's target [rad]: the new source plus the switch's remaining gap (1 - w) * offset
    (offset = last command - source at the switch), rate-limited from q_prev (at most v_max * dt a tick)."""
    q = np.asarray(q_source, dtype=float) + (1.0 - w) * np.asarray(offset, dtype=float)
    return rate_limit(q, np.asarray(q_prev, dtype=float), v_max_rad_s, dt_s)


def blend_gripper(g_source: float | None, g_offset: float, w: float) -> float | None:
    """The gripper target [m] across a switch: the source plus (1 - w) of the gap at the switch."""
    if g_source is None:
        return None
    return float(g_source + (1.0 - w) * g_offset)


GRIP_CATCH_M = 0.0005  # m: the trigger's gripper target this close to the held command has picked it up
GRIP_MOVE_M = 0.002  # m: the trigger moved this far since the takeover: the hand works it


def gripper_pickup(g_held: float, g_leader: float | None, pick: tuple[float, float] | None
                   ) -> tuple[float, bool, tuple[float, float] | None]:
    """The follower's gripper target [m] after an operator takeover, until the trigger picks up the command
    the policy left (a soft takeover, as a mixing desk's fader picks up a value): (target, picked, pick).
    pick: (the trigger's first target after the takeover, the side it started on: sign of g_leader - g_held),
    None before the first reading. The target stays g_held until the trigger's target g_leader comes within
    GRIP_CATCH_M of it, crosses it, or moves GRIP_MOVE_M from where it was (the hand works the trigger: to
    open, too). Why: the trigger is not driven during a rollout, so at a takeover it sits wherever the hand
    left it; fading the gripper to it released an object the policy squeezed (its command lies past the
    object's width, a resting trigger at it)."""
    if g_leader is None or not math.isfinite(g_leader):
        return g_held, False, pick
    d = g_leader - g_held
    if pick is None:
        pick = (g_leader, math.copysign(1.0, d) if d != 0.0 else 0.0)
    g0, side = pick
    if abs(d) <= GRIP_CATCH_M or d * side < 0.0 or abs(g_leader - g0) >= GRIP_MOVE_M:
        return g_leader, True, pick
    return g_held, False, pick
