"""A pair's settings (the rig file's [teleop] table, or its pairs.<name> sub-table): what teleop/pair.py's
ArmPair runs with, apart from the per-tick state machine that runs them.

    cfg = PairConfig.from_dict(table, where="teleop")   # ConfigError (one line) on a bad key
"""

from __future__ import annotations

from dataclasses import dataclass, field

from factr2_teleop.teleop.leader_law import LeaderLawConfig
from factr2_teleop.teleop.mapping import JointMapConfig
from factr2_teleop.teleop.soft_start import SoftStartConfig
from factr2_teleop.teleop.takeover import TakeoverConfig
from hardware.errors import ConfigError

DEFAULT_STALE_S = 0.02  # s: a leader/follower sample older than this puts the follower on hold (< 50 ms)


@dataclass
class PairConfig:
    """name: prefix in records ("left"/"right" for bimanual). leader_stale_s / follower_stale_s: data older
    than this holds the follower [s]. estimator_period_s: run the estimator at most this often [s] (0: every
    tick; the paper ran NEXT at 100 Hz). start_timeout_s: wait this long for first data from both arms [s].
    takeover: the leader's following and the hand's takeover during a policy rollout (teleop/takeover.py)."""

    name: str = "arm"
    law: LeaderLawConfig = field(default_factory=LeaderLawConfig)
    mapping: JointMapConfig = field(default_factory=JointMapConfig)
    soft_start: SoftStartConfig = field(default_factory=SoftStartConfig)
    leader_stale_s: float = DEFAULT_STALE_S
    follower_stale_s: float = DEFAULT_STALE_S
    estimator_period_s: float = 0.0
    start_timeout_s: float = 0.5
    takeover: TakeoverConfig = field(default_factory=TakeoverConfig)

    @classmethod
    def from_dict(cls, d: dict, where: str = "pairs") -> PairConfig:
        """From a rig-file table: {name, law: {...}, mapping: {...}, soft_start: {...}, leader_stale_s..}."""
        d = dict(d or {})
        kw: dict = {}
        try:
            if "law" in d:
                kw["law"] = LeaderLawConfig.from_dict(d.pop("law"), where=f"{where}.law")
            if "mapping" in d:
                kw["mapping"] = JointMapConfig(**d.pop("mapping"))
            if "soft_start" in d:
                kw["soft_start"] = SoftStartConfig(**d.pop("soft_start"))
            if "takeover" in d:
                kw["takeover"] = TakeoverConfig(**d.pop("takeover"))
                kw["takeover"].validate(where=f"{where}.takeover")
            return cls(**kw, **d)
        except TypeError as e:
            raise ConfigError(f"bad key: {e}", where=where, fix="see docs/teleop.md") from None
