"""Mean/std normalisation per feature group ("state", "force", "action"), stored in the checkpoint JSON.
A dimension that never moves (std < STD_FLOOR, e.g. an arm without a gripper) keeps std 1: centred only."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

STD_FLOOR = 1e-6


@dataclass
class Normalizer:
    mean: dict[str, np.ndarray]
    std: dict[str, np.ndarray]

    @classmethod
    def fit(cls, groups: dict[str, np.ndarray]) -> Normalizer:
        mean, std = {}, {}
        for k, x in groups.items():
            x = np.asarray(x, np.float64).reshape(len(x), -1)
            m = x.mean(0) if len(x) else np.zeros(x.shape[1])
            s = x.std(0) if len(x) else np.ones(x.shape[1])
            mean[k], std[k] = m.astype(np.float32), np.where(s < STD_FLOOR, 1.0, s).astype(np.float32)
        return cls(mean, std)

    def norm(self, key: str, x: np.ndarray) -> np.ndarray:
        return ((np.asarray(x, np.float32) - self.mean[key]) / self.std[key]).astype(np.float32)

    def denorm(self, key: str, z):
        return z * self.std[key] + self.mean[key]

    def to_dict(self) -> dict:
        return {k: {"mean": self.mean[k].tolist(), "std": self.std[k].tolist()} for k in self.mean}

    @classmethod
    def from_dict(cls, d: dict) -> Normalizer:
        return cls(
            {k: np.asarray(v["mean"], np.float32) for k, v in d.items()},
            {k: np.asarray(v["std"], np.float32) for k, v in d.items()},
        )
