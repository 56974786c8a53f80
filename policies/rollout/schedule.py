"""Action-chunk scheduling at rollout, as pure functions on arrays (tested directly), plus ChunkSchedule, the
small stateful shell the control loop asks for a target every tick.

A chunk is the policy's answer to one observation: actions (H, A) in raw units (joint targets [rad] +
gripper [m]), actions[i] meant for t_obs + i * dt, dt = 1 / the policy rate (the rate its training samples
were taken at). The loop runs faster (500 Hz): targets are interpolated linearly between chunk steps, and
the part of a chunk that lies before the current time (the inference latency) is simply never executed.

Two ways to execute chunks (both configurable):
- temporal ensembling (ACT, Zhao et al. 2023): a chunk is requested every policy step; the target at time t
  is the weighted mean of every chunk still covering t, weights exp(-m * i) with i = 0 the OLDEST chunk
  (the original's order and m = 0.01): an old prediction changes slowly what a new one adds.
- receding horizon (flow, Diffusion-Policy style): a chunk is requested every K policy steps and the newest
  one is executed, so the first K steps of each chunk (plus the latency) are what runs.

Age of the executed action [s]: time now minus the observation time of the newest chunk used.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum

import numpy as np

from hardware.reasons import Reason, messages

ACT_ENSEMBLE_M = 0.01  # the original ACT's temporal-ensembling weight constant (per chunk)
STALL_S = 0.2  # s: a chunk this late (after it was due) holds the follower
# A chunk reaching further beyond a joint limit than this share of the joint's range is refused (a model gone
# wrong); closer, the safety layer clamps it to the limit and counts it. Demonstrations work at the limits
# (peg-insert and press-fit: joint 3 at its 0 limit), and a flow policy's samples overshoot such a limit:
# measured 0.15-0.43 rad past joint 3's 0 (range 2.97 rad) in the FIRST headline's rollouts. The fixed
# 0.15 rad used before refused those chunks; a refused chunk empties the schedule and holds the arm, and from
# the held pose the policy asks for the same again: on the curve seed, 3 of 8 peg-insert episodes of one
# policy stood held 11-16 s and never grasped, none with clamping (docs/first_runs.md, "What earlier runs
# taught").
LIMIT_TOL_FRACTION = 0.25


def limit_tolerance(q_min, q_max) -> np.ndarray:
    """Per joint [rad]: how far beyond [q_min, q_max] a chunk may aim before it is refused (the safety layer
    clamps what lies between)."""
    return LIMIT_TOL_FRACTION * (np.asarray(q_max, dtype=float) - np.asarray(q_min, dtype=float))


ENSEMBLE, RECEDING = "ensemble", "receding"


class PolicyHold(Enum):
    """Why a rollout's follower holds (hardware.reasons). The value is the key the pair's `holds` counter
    (and the rollout summary) counts it under."""

    NOT_FINITE = "policy output not finite"  # a chunk refused
    OUTSIDE_LIMITS = "policy target outside the joint limits"  # a chunk refused (detail: joint, q, limit)
    FIRST_CHUNK = "waiting for the policy's first chunk"
    STALLED = "policy stalled"  # detail: ms
    USED_UP = "policy chunks used up"
    FOLLOWER_STALE = "follower data stale"
    FOLLOWER_MOTOR_ERROR = "follower motor error"  # detail: what ("j2 over-current")
    BETWEEN_EPISODES = "waiting"
    NOT_STARTED = "waiting to start"
    NO_POLICY = "no policy attached"

    @property
    def fault(self) -> bool:
        """Whether a hold of this kind is a fault (counted); waiting is not."""
        return self not in (PolicyHold.FIRST_CHUNK, PolicyHold.BETWEEN_EPISODES, PolicyHold.NOT_STARTED)


messages({
    PolicyHold.NOT_FINITE: "policy output not finite",
    PolicyHold.OUTSIDE_LIMITS: ("policy target outside the joint limits (joint {joint}: {q:.3f} rad, "
                                "limit {limit:.3f})"),
    PolicyHold.FIRST_CHUNK: "waiting for the policy's first chunk",
    PolicyHold.STALLED: "policy stalled: no new chunk {ms:.0f} ms after one was due",
    PolicyHold.USED_UP: "policy chunks used up",
    PolicyHold.FOLLOWER_STALE: "follower data stale",
    PolicyHold.FOLLOWER_MOTOR_ERROR: "follower motor error: {what}",
    PolicyHold.BETWEEN_EPISODES: "waiting: between episodes",
    PolicyHold.NOT_STARTED: "waiting to start",
    PolicyHold.NO_POLICY: "no policy attached",
})


@dataclass(frozen=True)
class Chunk:
    """actions (H, A) raw units for t_obs + i * dt [s]; seq: request number; latency_s: inference time
    [s, wall]."""

    t_obs: float
    actions: np.ndarray
    dt: float
    seq: int = 0
    latency_s: float = 0.0

    @property
    def t_end(self) -> float:
        """Time of the last action [s]."""
        return self.t_obs + (len(self.actions) - 1) * self.dt


def ensemble_weights(n: int, m: float = ACT_ENSEMBLE_M) -> np.ndarray:
    """(n,) normalised weights exp(-m * i), i = 0 the oldest of n chunks."""
    w = np.exp(-float(m) * np.arange(n))
    return w / w.sum()


def interp_chunk(actions: np.ndarray, t_obs: float, dt: float, t: float) -> np.ndarray | None:
    """The chunk's target at time t [s], linear between its steps; actions[0] before t_obs; None after its
    last step (the chunk is used up)."""
    u = (t - t_obs) / dt
    h = len(actions)
    if u <= 0:
        return np.asarray(actions[0], dtype=float)
    if u > h - 1:
        return None
    i = min(math.floor(u), h - 2) if h > 1 else 0  # math: a numpy call on a Python float costs ~1 us/tick
    if h == 1:
        return np.asarray(actions[0], dtype=float)
    f = u - i
    return (1.0 - f) * np.asarray(actions[i], dtype=float) + f * np.asarray(actions[i + 1], dtype=float)


def stack_chunks(chunks: list[Chunk]) -> tuple[np.ndarray, np.ndarray, float] | None:
    """(actions (n, H, A), t_obs (n,) [s], dt [s]) of chunks of one length and step, for
    ensembled_stacked; None when they differ (then ensembled_target goes chunk by chunk)."""
    if not chunks:
        return None
    h, dt = chunks[0].actions.shape, chunks[0].dt
    if any(c.actions.shape != h or c.dt != dt for c in chunks):
        return None
    return (np.stack([np.asarray(c.actions, dtype=float) for c in chunks]),
            np.array([c.t_obs for c in chunks], dtype=float), float(dt))


def ensembled_stacked(actions: np.ndarray, t_obs: np.ndarray, dt: float, t: float,
                      m: float = ACT_ENSEMBLE_M) -> tuple[np.ndarray | None, int]:
    """ensembled_target on stacked chunks (stack_chunks): every chunk interpolated at t at once (the loop
    asks every tick, 500 Hz, over up to a chunk's length of chunks: chunk by chunk it cost ~0.3 ms a tick,
    a sixth of a rollout's CPU)."""
    n, h = actions.shape[:2]
    u = (t - t_obs) / dt
    live = np.flatnonzero(u <= h - 1)  # a chunk past its last step is used up
    if not live.size:
        return None, -1
    u = u[live]
    if h == 1:
        vals = actions[live, 0]
    else:
        i = np.clip(np.floor(u), 0, h - 2).astype(np.intp)
        f = np.clip(u - i, 0.0, 1.0)[:, None]  # before t_obs: the first step
        vals = (1.0 - f) * actions[live, i] + f * actions[live, i + 1]
    return np.tensordot(ensemble_weights(live.size, m), vals, axes=1), int(live[-1])


def ensembled_target(chunks: list[Chunk], t: float,
                     m: float = ACT_ENSEMBLE_M) -> tuple[np.ndarray | None, int]:
    """Temporal ensembling at t over the chunks (oldest first) that still cover t: (target, newest index
    used) or (None, -1) when none does."""
    stacked = stack_chunks(chunks)
    if stacked is not None:
        return ensembled_stacked(*stacked, t, m)
    vals, used = [], []
    for k, c in enumerate(chunks):
        a = interp_chunk(c.actions, c.t_obs, c.dt, t)
        if a is not None:
            vals.append(a)
            used.append(k)
    if not vals:
        return None, -1
    w = ensemble_weights(len(vals), m)
    return np.tensordot(w, np.stack(vals), axes=1), used[-1]


def receding_target(chunks: list[Chunk], t: float) -> tuple[np.ndarray | None, int]:
    """Receding horizon at t: the newest chunk's target (target, its index) or (None, -1) when used up."""
    if not chunks:
        return None, -1
    a = interp_chunk(chunks[-1].actions, chunks[-1].t_obs, chunks[-1].dt, t)
    return (a, len(chunks) - 1) if a is not None else (None, -1)


def request_period_s(mode: str, dt: float, k_exec: int) -> float:
    """How often a chunk is requested [s]: every policy step (ensembling) or every K steps (receding)."""
    return dt if mode == ENSEMBLE else max(int(k_exec), 1) * dt


def overdue_s(t: float, t_obs_newest: float, period_s: float) -> float:
    """How late the next chunk is at t [s]: it was due one request period after the newest chunk's
    observation (negative: not due yet)."""
    return t - (t_obs_newest + period_s)


def chunk_problem(actions: np.ndarray, q_min: np.ndarray, q_max: np.ndarray,
                  tol: float = 0.0, steps: int | None = None) -> Reason | None:
    """Why a chunk must not run, or None: non-finite values anywhere (PolicyHold.NOT_FINITE: the model is
    broken), or a joint target of its first `steps` (None: all) outside [q_min - tol, q_max + tol] [rad]
    (OUTSIDE_LIMITS, the first such joint 1-based, its target and the limit [rad]; joints: the first
    len(q_min) columns; the gripper column is clamped, not judged)."""
    a = np.asarray(actions, dtype=float)
    if not np.all(np.isfinite(a)):
        return Reason.of(PolicyHold.NOT_FINITE)
    n = len(q_min)
    q = a[:steps, :n]
    lo, hi = q < np.asarray(q_min) - tol, q > np.asarray(q_max) + tol
    if lo.any() or hi.any():
        step, j = np.argwhere(lo | hi)[0]
        bound = q_min[j] if lo[step, j] else q_max[j]
        return Reason.of(PolicyHold.OUTSIDE_LIMITS, joint=int(j) + 1, q=float(q[step, j]), limit=float(bound))
    return None


@dataclass
class ChunkSchedule:
    """The loop's view of the policy: add() each chunk as it arrives, target(t) every tick.

    mode: ENSEMBLE or RECEDING; m: ensembling constant; k_exec: steps executed per chunk (receding);
    q_min / q_max [rad]: the follower's limits (a chunk more than tol [rad] beyond them is refused; a target
    closer to them is clamped by the safety layer, which a held pose at a limit needs); stall_s: lateness that
    holds. Counters: chunks accepted, refused (non-finite / outside the limits)."""

    mode: str
    dt: float
    q_min: np.ndarray
    q_max: np.ndarray
    m: float = ACT_ENSEMBLE_M
    k_exec: int = 10
    stall_s: float = STALL_S
    tol: float | np.ndarray | None = None  # rad, scalar or per joint; None: limit_tolerance(q_min, q_max)
    chunks: list[Chunk] = field(default_factory=list)
    accepted: int = 0
    nonfinite: int = 0
    outside_limits: int = 0
    problem: Reason | None = None  # the newest chunk's problem: holds until a good chunk arrives
    t_obs_min: float = -math.inf  # s: a chunk observed before this is dropped (restart: a hand-back)
    stale_dropped: int = 0  # chunks dropped for that
    _stacked: tuple | None = field(default=None, repr=False)  # stack_chunks(chunks), made as chunks change

    def __post_init__(self):
        if self.tol is None:
            self.tol = limit_tolerance(self.q_min, self.q_max)

    @property
    def period_s(self) -> float:
        return request_period_s(self.mode, self.dt, self.k_exec)

    def executable_steps(self, horizon: int) -> int:
        """How many of a chunk's first steps can ever run: all of them when ensembling; receding, the
        k_exec steps before the next chunk plus those a late one (up to stall_s) would use. The rest is
        never executed, so it is not judged: a chunk's far end (1 s ahead at 30 Hz) is its least accurate
        part, and a policy working at a joint limit overshoots there first."""
        if self.mode == ENSEMBLE:
            return horizon
        return min(horizon, self.k_exec + int(np.ceil(self.stall_s / self.dt)) + 1)

    def add(self, chunk: Chunk) -> Reason | None:
        """Take a chunk; returns why it was refused (and the schedule holds), or None. A chunk observed before
        the last restart() is dropped without a word (it was asked for before the operator handed back)."""
        if chunk.t_obs < self.t_obs_min:
            self.stale_dropped += 1
            return None
        why = chunk_problem(chunk.actions, self.q_min, self.q_max, self.tol,
                            self.executable_steps(len(chunk.actions)))
        if why is not None:
            if why.kind is PolicyHold.NOT_FINITE:
                self.nonfinite += 1
            else:
                self.outside_limits += 1
            self.problem = why
            self.chunks.clear()  # nothing of a policy gone wrong is executed any more
            self._stacked = None
            return why
        self.problem = None
        self.accepted += 1
        self.chunks.append(chunk)
        keep = int(np.ceil((len(chunk.actions) * chunk.dt) / self.period_s)) + 1
        del self.chunks[:-keep]  # older chunks no longer cover any time ahead
        self._stacked = stack_chunks(self.chunks) if self.mode == ENSEMBLE else None
        return None

    def target(self, t: float) -> tuple[np.ndarray | None, Reason | None, float]:
        """(target (A,) or None, why None (a PolicyHold reason), age of the executed action [s])."""
        if self.problem is not None:
            return None, self.problem, float("nan")
        if not self.chunks:
            return None, Reason.of(PolicyHold.FIRST_CHUNK), float("nan")
        late = overdue_s(t, self.chunks[-1].t_obs, self.period_s)
        if late > self.stall_s:
            return None, Reason.of(PolicyHold.STALLED, ms=1e3 * self.stall_s), float("nan")
        if self.mode == ENSEMBLE and self._stacked is not None:  # once per chunk, not per tick
            a, k = ensembled_stacked(*self._stacked, t, self.m)
        elif self.mode == ENSEMBLE:
            a, k = ensembled_target(self.chunks, t, self.m)
        else:
            a, k = receding_target(self.chunks, t)
        if a is None:
            return None, Reason.of(PolicyHold.USED_UP), float("nan")
        return a, None, t - self.chunks[k].t_obs

    def clear(self) -> None:
        """Forget every chunk (a new episode)."""
        self.chunks.clear()
        self._stacked = None
        self.problem = None

    def restart(self, t_obs_min: float) -> None:
        """Forget every chunk and refuse any observed before t_obs_min [s] (an operator handed back at that
        time: the policy re-plans from the arm's state then, and nothing older is ever executed)."""
        self.clear()
        self.t_obs_min = float(t_obs_min)
