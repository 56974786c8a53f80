"""What a policy rollout reports (factr2_teleop/session/rollout.py): the wire check on every follower, the
loop's timing, and the typed result the CLI, the terminal app and the benchmarks read.

    res = run_rollout(opts)               # RolloutResult
    res.success_rate, res.timing["command_violations"], res.to_dict()   # to_dict(): the summary JSON
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from factr2_teleop.session.read_back import episode_rates, read_back

EPISODE_KEYS = ("index", "seed", "outcome", "progress", "stages", "duration_s")  # of each EpisodeResult


class WireCheck:
    """Command observers at the wire (after the safety layer): follower commands sent, those with a joint
    target outside the limits or not finite (an independent check of the layer: should stay 0), the times
    the follower went on hold [s], and the last command of each arm (Ctrl-C must end on a follower hold and
    a zero leader torque)."""

    def __init__(self, limits):
        self.q_min, self.q_max = np.asarray(limits.q_min), np.asarray(limits.q_max)
        self._lo, self._hi = self.q_min - 1e-9, self.q_max + 1e-9
        self.sent = self.violations = 0
        self.hold_times: list[float] = []  # t_sent of each hold entered
        self.last_hold = False
        self.leader_tau = None

    def __call__(self, t_issued, t_sent, safe) -> None:
        q = np.asarray(safe.q, dtype=float)
        self.sent += 1
        if not ((q >= self._lo) & (q <= self._hi)).all():  # NaN fails both comparisons, +-inf one of them
            self.violations += 1
        if safe.hold and not self.last_hold:
            self.hold_times.append(float(t_sent))
        self.last_hold = bool(safe.hold)

    def leader(self, t_issued, t_sent, safe) -> None:
        self.leader_tau = np.asarray(safe.tau, dtype=float)


def _pct(x, p: float) -> float:
    return float(np.percentile(x, p)) if len(x) else float("nan")


def timing_summary(periods_s, latencies_s, ages_s, realtime: bool, target_hz: float) -> dict:
    """Loop rate [Hz] and period p99 / max [ms] over the policy's run ticks, chunk latency and action age
    mean / p99 [ms]. In lockstep, periods and ages are simulated time (latency is wall time)."""
    p = np.asarray([x for x in periods_s if np.isfinite(x)])
    lat, age = np.asarray(latencies_s) * 1e3, np.asarray(ages_s) * 1e3
    return {"clock": "real time" if realtime else "lockstep (simulated time; latency is wall time)",
            "loop_target_hz": target_hz, "loop_rate_hz": float(1.0 / p.mean()) if len(p) else float("nan"),
            "period_p99_ms": _pct(p * 1e3, 99),
            "period_max_ms": float(p.max() * 1e3) if len(p) else float("nan"),
            "overruns": int(np.sum(p > 1.5 / target_hz)), "ticks": int(len(p)),
            "chunks": int(len(lat)), "chunk_latency_mean_ms": float(lat.mean()) if len(lat) else float("nan"),
            "chunk_latency_p99_ms": _pct(lat, 99),
            "action_age_mean_ms": float(age.mean()) if len(age) else float("nan"),
            "action_age_p99_ms": _pct(age, 99)}


def wire_summary(checks: list[WireCheck]) -> dict:
    """Every follower's wire check in one: commands sent, violations, holds entered [s] (sorted), whether
    every follower ended on hold, the largest last leader torque [N*m] (None: no leader command seen)."""
    taus = [np.max(np.abs(w.leader_tau)) for w in checks if w.leader_tau is not None]
    return {"commands_sent": sum(w.sent for w in checks),
            "command_violations": sum(w.violations for w in checks),
            "end_follower_held": all(w.last_hold for w in checks),
            "end_leader_tau_max_nm": float(max(taus)) if taus else None,
            "hold_times_s": sorted(t for w in checks for t in w.hold_times)[:100]}


def episode_summary(results, stages: tuple, recording: str | None, status) -> dict:
    """The RolloutResult's episode fields from the episodes' EpisodeResults: episodes (EPISODE_KEYS of
    each), success_rate, mean_progress, stage_rates, and with a recording what its closed file holds
    (session/read_back.py read_back, `status` its RecorderStatus): each episode's outcome, progress and stages
    as the file holds them (a writer that stalled leaves the last one "incomplete", later ones "missing"), the
    live verdict kept as outcome_judged (progress_judged, stages_judged), the rates over the episodes the file
    holds (episode_rates). as_recorded: the EpisodeResults with those outcomes (the takeover summary's)."""
    episodes = [{k: v for k, v in asdict(r).items() if k in EPISODE_KEYS} for r in results]
    in_file = read_back(episodes, Path(recording), status) if recording else {}
    out = {"episodes": episodes, **episode_rates(episodes, stages), **in_file}
    out["as_recorded"] = [replace(r, outcome=e["outcome"]) for r, e in zip(results, episodes)]
    return out


@dataclass
class RolloutResult:
    """A rollout's summary. episodes: per episode index, seed, outcome, progress, stages, duration_s;
    stage_rates: share of episodes reaching each stage (with a recording: of those its file holds); timing:
    timing_summary plus the wire check, refused chunks, holds by reason, clamped targets and the safe end
    (docs/rollout.md)."""

    simulated: bool
    rig: str
    task: str | None
    policy: str
    policy_kind: str
    method: str | None
    schedule: str
    k_exec: int | None
    ensemble_m: float | None
    seed: int
    feedback_mode: str
    next: str | None
    note: str
    lean: bool
    interrupted: bool
    wall_s: float
    episodes: list[dict]
    success_rate: float
    mean_progress: float
    stage_rates: dict[str, float]
    recording: str | None
    arms: list[str] = field(default_factory=list)  # the follower arms the policy drove
    timing: dict = field(default_factory=dict)
    takeover: dict = field(default_factory=dict)  # session/takeover_switch.py takeover_summary ({}: off)
    messages: list = field(default_factory=list)  # the loop's (t [s], who, text): holds, faults, recoveries
    faults: list = field(default_factory=list)  # the twin's log of what it injected (sim/faults.py)
    force_input: str = "live"  # the policy's force input: live or an ablation (policies/rollout/runner.py)
    # what the recording's file holds where it differs from the live verdicts (episode_summary)
    recording_error: str | None = None  # the recorder's one line (a stall: "... recovered in place ...")
    recording_recovered: bool = False  # the writer stalled and the file was recovered in place
    episodes_not_as_judged: list = field(default_factory=list)  # indices whose outcome is the file's
    episodes_in_file: int | None = None  # episodes the file holds, the rates' denominator (None: not read)
    recording_unread: str | None = None  # why the file could not be read back (outcomes as judged)

    def to_dict(self) -> dict:
        return asdict(self)
