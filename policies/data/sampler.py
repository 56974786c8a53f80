"""FIRST re-sampling (paper Sec. 5): each training sample is drawn with probability proportional to its
phase's weight, w_F : w_PC : w_C (default 1:5:1), with replacement. Rollout recordings with an operator's
interventions (issue #33, hardware/recording/interventions.py) add a weight per sample source, multiplied in:
p_i ~ w_phase(i) * w_source(i), sources demo / policy / pre (the pre-intervention window) / operator
(intervention up-weighted, pre-intervention down-weighted or dropped, as in Sirius).

Determinism: an epoch's draws are a function of (seed, epoch) alone, so `--resume` continues from the same
position. Distributed: every rank computes the same global sequence and takes positions rank, rank + world,
... (disjoint by construction); global batch k is positions [kB, (k+1)B) on every world size, so one process
and N processes see the same samples per optimiser step.
"""

from __future__ import annotations

import numpy as np

from policies.labels.phases import PHASE_SHORT

# the paper's ablation (Sec. 5, Table "upsampling"): which phases are up-sampled, as w_F : w_PC : w_C
RATIO_PRESETS = {
    "uniform": (1.0, 1.0, 1.0),
    "C": (1.0, 1.0, 5.0),
    "PC": (1.0, 5.0, 1.0),
    "PC+C": (1.0, 3.0, 3.0),
    "first": (1.0, 5.0, 1.0),
}
DEFAULT_RATIO = RATIO_PRESETS["first"]
# demo : policy : pre : operator (hardware.recording.interventions.SOURCE_NAMES order): Sirius keeps the
# policy's own samples, up-weights the intervention and down-weights the seconds before it
DEFAULT_SOURCE_WEIGHTS = (1.0, 1.0, 0.25, 2.0)


def parse_source_weights(text: str) -> tuple[float, float, float, float]:
    """'demo=1,policy=1,pre=0,operator=3' (any subset; the rest keep DEFAULT_SOURCE_WEIGHTS) -> the four
    weights; ValueError otherwise."""
    from hardware.recording.interventions import SOURCE_NAMES

    w = dict(zip(SOURCE_NAMES, DEFAULT_SOURCE_WEIGHTS))
    for part in filter(None, (p.strip() for p in str(text).split(","))):
        name, _, val = part.partition("=")
        try:
            x = float(val)
        except ValueError:
            x = float("nan")
        if name.strip() not in w or not (np.isfinite(x) and x >= 0):
            raise ValueError(f"source weight {part!r} is not NAME=WEIGHT with NAME one of "
                             f"{', '.join(SOURCE_NAMES)} and WEIGHT >= 0")
        w[name.strip()] = x
    return tuple(w[n] for n in SOURCE_NAMES)  # type: ignore[return-value]


def parse_ratio(text: str) -> tuple[float, float, float]:
    """'1:5:1' or a preset name (uniform, C, PC, PC+C, first) -> (w_F, w_PC, w_C); ValueError otherwise."""
    key = str(text).strip()
    if key in RATIO_PRESETS:
        return RATIO_PRESETS[key]
    parts = key.split(":")
    try:
        w = tuple(float(p) for p in parts)
    except ValueError:
        w = ()
    if len(w) != 3 or not all(np.isfinite(x) and x >= 0 for x in w) or sum(w) <= 0:
        raise ValueError(
            f"ratio {text!r} is not three non-negative numbers w_F:w_PC:w_C with a positive sum "
            f"(or one of {', '.join(RATIO_PRESETS)})"
        )
    return w  # type: ignore[return-value]


def format_ratio(w) -> str:
    return ":".join(f"{x:g}" for x in w)


def sample_probabilities(phases: np.ndarray, ratio, sources: np.ndarray | None = None,
                         source_weights=None) -> np.ndarray:
    """p_i = w_{phase_i} / sum_j w_{phase_j} over the samples (N,); with sources (N,) (codes of
    interventions.SOURCE_NAMES) and source_weights, p_i ~ w_{phase_i} * w_{source_i}. A ratio that zeroes
    every sample is a ValueError (nothing could be drawn)."""
    w = np.asarray(ratio, dtype=float)[np.asarray(phases, dtype=np.int64)]
    if sources is not None and source_weights is not None:
        w = w * np.asarray(source_weights, dtype=float)[np.asarray(sources, dtype=np.int64)]
    total = w.sum()
    if not total > 0:
        present = sorted({PHASE_SHORT[int(p)] for p in np.unique(phases)})
        raise ValueError(f"ratio {format_ratio(ratio)} gives zero weight to every phase present ({present})")
    return w / total


def expected_source_shares(phases: np.ndarray, ratio, sources: np.ndarray, source_weights) -> np.ndarray:
    """Expected fraction of draws per source (4,): sum of p_i over each source's samples."""
    p = sample_probabilities(phases, ratio, sources, source_weights)
    return np.bincount(np.asarray(sources, dtype=np.int64), weights=p, minlength=4)[:4]


def expected_shares(phases: np.ndarray, ratio) -> np.ndarray:
    """Expected fraction of draws per phase: w_p n_p / sum_q w_q n_q (3,)."""
    n = np.bincount(np.asarray(phases, dtype=np.int64), minlength=3)[:3].astype(float)
    wn = np.asarray(ratio, dtype=float) * n
    return wn / wn.sum()


class FirstSampler:
    """Weighted draws with replacement. samples_per_epoch defaults to the number of samples (an epoch sees
    as many draws as there are samples). epoch_indices(epoch) -> this rank's indices, in order."""

    def __init__(
        self,
        phases: np.ndarray,
        ratio=DEFAULT_RATIO,
        seed: int = 0,
        samples_per_epoch: int | None = None,
        rank: int = 0,
        world: int = 1,
        sources: np.ndarray | None = None,
        source_weights=None,
    ):
        if not 0 <= rank < world:
            raise ValueError(f"rank {rank} outside world {world}")
        self.p = sample_probabilities(phases, ratio, sources, source_weights)
        self.ratio = tuple(float(x) for x in ratio)
        self.seed, self.rank, self.world = int(seed), int(rank), int(world)
        self.samples_per_epoch = int(samples_per_epoch or len(self.p))
        self._drawn: tuple | None = None  # ((epoch, size), the epoch's draws, read-only)

    def global_indices(self, epoch: int, at_least: int = 0) -> np.ndarray:
        """Every rank's draws for `epoch` together (samples_per_epoch,), the same on every rank; at_least:
        draw that many when an epoch is shorter (a global batch larger than the data: draws are with
        replacement, so the batch just repeats samples)."""
        size = max(self.samples_per_epoch, at_least)
        if self._drawn is not None and self._drawn[0] == (int(epoch), size):
            return self._drawn[1]
        rng = np.random.default_rng([self.seed, int(epoch), 0x51F57])
        draws = rng.choice(len(self.p), size=size, replace=True, p=self.p)
        # kept for the epoch's next batches: the draw is ~4 ms for 60k samples, ~5 % of a state-preset step
        draws.setflags(write=False)
        self._drawn = ((int(epoch), size), draws)
        return draws

    def epoch_indices(self, epoch: int) -> np.ndarray:
        return self.global_indices(epoch)[self.rank :: self.world]

    def batch(self, epoch: int, step_in_epoch: int, global_batch: int) -> tuple[np.ndarray, np.ndarray]:
        """(indices, positions) of this rank's share of global batch `step_in_epoch` of `epoch`: positions
        [kB, (k+1)B) of the global sequence taken with stride `world` from `rank`."""
        if global_batch % self.world:
            raise ValueError(f"global batch {global_batch} is not a multiple of the world size {self.world}")
        lo = step_in_epoch * global_batch
        pos = np.arange(lo + self.rank, lo + global_batch, self.world)
        return self.global_indices(epoch, lo + global_batch)[pos], pos - lo

    def steps_per_epoch(self, global_batch: int) -> int:
        """Whole global batches per epoch (the tail that does not fill one is dropped)."""
        return max(1, self.samples_per_epoch // global_batch)
