"""What a run does beyond fitting its demonstrations (issue #56 item 2): the moving average of the weights,
Gaussian noise on the low-dimensional inputs during training, and which checkpoint the run keeps for use.

The noise and the val-min checkpoint are off by default: today's defaults stay until a rule using them is
measured on rollouts (docs/data_curve.md, "Choosing the defaults"; the validation loss alone is not a safe
signal: on peg-insert success rose with steps while it rose too, docs/first_training.md).
"""

from __future__ import annotations

import copy
import math

import numpy as np
import torch

# the model inputs the noise may be added to: the low-dimensional ones, normalised (mean 0, std 1 over the
# training data, policies/data/normalizer.py); images have their own augmentation (crops, blur)
NOISE_INPUTS = ("state", "force", "objects")
# the checkpoint a run keeps for rollouts: `last` (the end of training) or `val-min` (the evaluated weights
# at the lowest validation loss, saved as RUN/checkpoints/valmin-*; `kept` names it)
KEEP_CHOICES = ("last", "val-min")


class Ema:
    """Exponential moving average of a model's weights (buffers copied): the weights that are evaluated and
    rolled out. Decay at step s: min(ema_max, 1 - (1 + s) ** -power), Diffusion Policy's warm-up, so early
    steps follow the model closely and the average lengthens as training settles."""

    def __init__(self, model: torch.nn.Module, power: float, max_decay: float):
        self.model = copy.deepcopy(model).eval().requires_grad_(False)
        self.power, self.max_decay = power, max_decay

    def decay(self, step: int) -> float:
        return min(self.max_decay, 1.0 - (1.0 + step) ** -self.power)

    @torch.no_grad()
    def update(self, model: torch.nn.Module, step: int) -> None:
        d = self.decay(step)
        ema_p = [p for p in self.model.parameters()]
        torch._foreach_lerp_(ema_p, [p.detach() for p in model.parameters()], 1.0 - d)
        for b_ema, b in zip(self.model.buffers(), model.buffers()):
            b_ema.copy_(b)


def parse_obs_noise(text: str) -> dict[str, float]:
    """"state=0.05,objects=0.05,force=0.1" -> {input: sigma}, sigma in normalised units (the input's
    standard deviations over the training data), each >= 0; ValueError naming what is wrong."""
    out: dict[str, float] = {}
    for item in (t.strip() for t in text.split(",")):
        name, sep, value = item.partition("=")
        if not sep or name.strip() not in NOISE_INPUTS:
            raise ValueError(f"{item!r} is not NAME=SIGMA with NAME one of {', '.join(NOISE_INPUTS)}")
        try:
            sigma = float(value)
        except ValueError:
            raise ValueError(f"{item!r}: {value!r} is not a number") from None
        if not (math.isfinite(sigma) and sigma >= 0):
            raise ValueError(f"{item!r}: sigma must be finite and >= 0")
        out[name.strip()] = sigma
    return out


def format_obs_noise(sigmas: dict[str, float]) -> str:
    """The text parse_obs_noise reads back to `sigmas`."""
    return ",".join(f"{k}={float(v)}" for k, v in sigmas.items())


def add_obs_noise(batch: dict, sigmas: dict[str, float], gen: torch.Generator, n_global: int,
                  pos: np.ndarray) -> dict:
    """Gaussian noise N(0, sigma^2) in normalised units added to the named inputs of a TRAINING batch (never
    validation or rollouts, which do not call this), in place; drawn for the whole global batch of
    n_global samples from `gen` in NOISE_INPUTS order, each rank keeping its positions `pos` (so N processes
    add the noise one process would). An input the batch lacks is left out (run.prepare refuses naming one
    the run has not); the targets (action, force_chunk) are never touched."""
    keep = torch.from_numpy(np.asarray(pos))
    for name in NOISE_INPUTS:
        sigma = float(sigmas.get(name, 0.0))
        if sigma > 0 and name in batch:
            x = batch[name]
            z = torch.randn((n_global, *x.shape[1:]), generator=gen, dtype=torch.float32)[keep]
            batch[name] = x + sigma * z.to(x.dtype)
    return batch


def run_inputs(data) -> set[str]:
    """The low-dimensional inputs a dataset gives its model (policies.data.preprocess.Preprocess.inputs)."""
    out = {"state"}
    if data.force.shape[1]:
        out.add("force")
    if data.objects is not None:
        out.add("objects")
    return out
