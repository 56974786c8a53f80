"""Collection that teaches recovery (DART-style, issue #56): small, bounded, smooth offsets added to the
follower's commanded joint positions during a demonstration, which the operator then corrects.

The pair (teleop/pair.py) adds `Perturbation(t)` to its coupled target before the follower's safety layer
(hardware/safety.py), so the offset is clipped and rate-limited like any command, on a twin and on a real rig
alike; the tick's record carries the offset asked, and the recorder writes it on /<arm>follower/perturb
(hardware/recording/schemas.py PERTURBATION) so training can learn the operator's correction or skip the
perturbed ticks (`factr2 train --perturbed`, policies/data/perturbed.py).

The offsets, as pure functions of (config, seed, time): windows drawn per episode from its seed, each a
random offset per joint, uniform in [-amplitude_rad, amplitude_rad], ramped in and out with a raised cosine
(ramp_s), held for hold_s; zero outside the windows. Bounded by amplitude_rad per joint, continuous with a
continuous first derivative, at most max_rate_rad_s() fast.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from hardware.errors import UserError

PERTURB_STREAM = 0xDA27  # the episode seed's stream for the perturbation windows (independent of the others)


@dataclass(frozen=True)
class PerturbConfig:
    """amplitude_rad: the largest offset of one joint [rad] (0.04 rad: ~2 cm at a Piper's gripper);
    ramp_s / hold_s: each window's raised-cosine ramp in and out and its hold at full offset [s];
    gap_min_s + an exponential gap of mean gap_mean_s: the unperturbed time before each window [s] (the
    operator's correction, and the recovery after a window, show in it); start_s: no window this early in an
    episode [s]; joints: the follower joints perturbed (0-based; empty: every joint)."""

    amplitude_rad: float = 0.04
    ramp_s: float = 0.4
    hold_s: float = 0.8
    gap_min_s: float = 1.5
    gap_mean_s: float = 3.0
    start_s: float = 1.0
    joints: tuple[int, ...] = ()

    def validate(self, n_joints: int, where: str = "--perturb") -> None:
        for name in ("amplitude_rad", "ramp_s", "hold_s", "gap_min_s", "gap_mean_s", "start_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0.0):
                raise UserError(f"{name} {v} must be a finite number >= 0", where=where,
                                fix="e.g. the default")
        if self.ramp_s <= 0.0 or self.gap_mean_s <= 0.0:
            raise UserError("ramp_s and gap_mean_s must be above 0 (a step offset is not smooth)",
                            where=where, fix=f"e.g. ramp_s={PerturbConfig.ramp_s}")
        if any(not 0 <= j < n_joints for j in self.joints):
            raise UserError(f"joints {self.joints} outside 0..{n_joints - 1}", where=where,
                            fix="name follower joints by 0-based index, or none for all")

    @property
    def window_s(self) -> float:
        return 2.0 * self.ramp_s + self.hold_s

    def max_rate_rad_s(self) -> float:
        """The fastest an offset changes [rad/s]: the raised cosine's steepest slope."""
        return self.amplitude_rad * math.pi / (2.0 * self.ramp_s)

    def to_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}


def parse_perturb(text: str) -> PerturbConfig:
    """'amplitude_rad=0.03,hold_s=1' (any subset of PerturbConfig's fields; '' or 'on': the defaults;
    joints as 1+3+5) -> PerturbConfig; UserError with the fix on a bad entry."""
    kw: dict = {}
    for part in (p.strip() for p in text.split(",")):
        if part in ("", "on", "default"):
            continue
        key, _, value = part.partition("=")
        key = key.strip()
        try:
            if key == "joints":
                kw[key] = tuple(int(j) for j in value.split("+") if j.strip())
            elif key in PerturbConfig.__dataclass_fields__:
                kw[key] = float(value)
            else:
                raise KeyError(key)
        except (KeyError, ValueError):
            raise UserError(f"bad perturbation setting {part!r}", where="--perturb",
                            fix="KEY=VALUE,... with KEY in " + ", ".join(PerturbConfig.__dataclass_fields__)
                            + " (joints as 0+1+2)") from None
    return PerturbConfig(**kw)


def draw_windows(cfg: PerturbConfig, seed, n_joints: int, horizon_s: float) -> list[tuple[float, np.ndarray]]:
    """The episode's windows up to horizon_s [s after its start]: (start [s], offset per joint [rad]); the
    same for the same seed."""
    rng = np.random.default_rng([*np.atleast_1d(seed).tolist(), PERTURB_STREAM])
    mask = np.zeros(n_joints, bool)
    mask[list(cfg.joints) if cfg.joints else slice(None)] = True
    out, t = [], cfg.start_s
    while True:
        t += cfg.gap_min_s + rng.exponential(cfg.gap_mean_s)
        amp = rng.uniform(-cfg.amplitude_rad, cfg.amplitude_rad, n_joints) * mask
        if t >= horizon_s:
            return out
        out.append((t, amp))
        t += cfg.window_s


def envelope(tau: np.ndarray, cfg: PerturbConfig) -> np.ndarray:
    """The window's shape in [0, 1] at tau [s] after its start: raised-cosine ramp in, hold, ramp out; 0
    outside."""
    tau = np.asarray(tau, float)
    r, h = cfg.ramp_s, cfg.hold_s
    up = 0.5 - 0.5 * np.cos(np.pi * np.clip(tau / r, 0.0, 1.0))
    down = 0.5 - 0.5 * np.cos(np.pi * np.clip((2.0 * r + h - tau) / r, 0.0, 1.0))
    return np.where((tau <= 0.0) | (tau >= 2.0 * r + h), 0.0, np.minimum(up, down))


def offset_at(windows, cfg: PerturbConfig, t: float, n_joints: int) -> np.ndarray:
    """The offset [rad] per joint at t [s after the episode start] (windows never overlap)."""
    out = np.zeros(n_joints)
    for t0, amp in windows:
        if t0 < t < t0 + cfg.window_s:
            out = out + float(envelope(t - t0, cfg)) * amp
    return out


class Perturbation:
    """One episode's perturbation, called by the pair every coupled tick: offset [rad] at rig time t [s]."""

    def __init__(self, cfg: PerturbConfig, seed, n_joints: int, t_start: float, horizon_s: float):
        self.cfg, self.n, self.t_start = cfg, int(n_joints), float(t_start)
        self.windows = draw_windows(cfg, seed, self.n, horizon_s)

    def __call__(self, t: float) -> np.ndarray:
        return offset_at(self.windows, self.cfg, t - self.t_start, self.n)
