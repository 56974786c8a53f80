"""The policy base class and the factory that builds a policy from its config (as LeRobot's `make_policy`):
each policy module registers its classes with `@register(name, head)`; `make_policy(cfg)` builds the one
that cfg.policy and cfg.head name. A new policy is one new file (a `Policy` subclass, registered) plus its
module in POLICY_MODULES.

What the training loop, the checkpoints and the rollout use of a policy is this class's interface:
draw_noise (all randomness of a step, drawn for the whole global batch), loss (per sample), predict (an
action chunk) and action_error. Everything a policy is built with comes from its config at construction.
"""

from __future__ import annotations

from importlib import import_module

import torch
import torch.nn as nn

from policies.models.config import PolicyConfig

# the modules that define policies; importing one registers its classes (the first's is the default policy)
POLICY_MODULES = ("policies.models.flow", "policies.models.flow_mlp", "policies.models.act")
ANY_HEAD = "*"  # a policy with one head registers under this

_REGISTRY: dict[tuple[str, str], type[Policy]] = {}


def register(name: str, head: str = ANY_HEAD):
    """Class decorator: the class is `name` (PolicyConfig.policy) with head `head` (PolicyConfig.head)."""

    def add(cls):
        key = (name, head)
        if key in _REGISTRY and _REGISTRY[key] is not cls:
            raise ValueError(f"policy {name!r} head {head!r} is registered twice")
        _REGISTRY[key] = cls
        return cls

    return add


def registered() -> dict[tuple[str, str], type[Policy]]:
    """(policy, head) -> class, every policy module imported."""
    for module in POLICY_MODULES:
        import_module(module)
    return dict(_REGISTRY)


def policy_names() -> tuple[str, ...]:
    """The registered policies' names (`--policy`'s choices), in POLICY_MODULES order."""
    return tuple(dict.fromkeys(name for name, _ in registered()))


def make_policy(cfg: PolicyConfig) -> Policy:
    """The policy cfg names, built from cfg (ValueError naming the known ones for an unknown name/head)."""
    table = registered()
    cls = table.get((cfg.policy, cfg.head)) or table.get((cfg.policy, ANY_HEAD))
    if cls is None:
        known = ", ".join(sorted(f"{n}" + ("" if h == ANY_HEAD else f" (head {h})") for n, h in table))
        raise ValueError(f"no policy {cfg.policy!r} with head {cfg.head!r}: one of {known}")
    return cls(cfg)


class Policy(nn.Module):
    """A policy over (batch of observations, noise) -> per-sample loss; predict gives the action chunk in
    normalised units. `noise` holds every random draw of a step, so a step is a function of its inputs."""

    def __init__(self, cfg: PolicyConfig):
        super().__init__()
        self.cfg = cfg

    @staticmethod
    def draw_noise(cfg: PolicyConfig, batch: int, gen: torch.Generator) -> dict:
        """Every random draw of a training step for `batch` samples, from `gen` (the loop slices per rank)."""
        raise NotImplementedError

    def loss(self, batch: dict, noise: dict) -> tuple[torch.Tensor, dict]:
        """Per-sample loss (B,) and its parts (each (B,)); parts["action"] is the imitation term."""
        raise NotImplementedError

    def predict(self, batch: dict, noise: dict | None = None) -> torch.Tensor:
        """Action chunk (B, chunk, action_dim) in normalised units."""
        raise NotImplementedError

    def forward(self, batch: dict, noise: dict):
        return self.loss(batch, noise)  # DDP wraps forward: the training step is the loss

    def action_error(self, batch: dict, noise: dict) -> torch.Tensor:
        """Per-sample L1 of the inferred chunk vs the demonstration (valid steps, normalised units) (B,)."""
        from policies.models.tokens import masked_mean

        return masked_mean((self.predict(batch, noise) - batch["action"]).abs(), batch["mask"])
