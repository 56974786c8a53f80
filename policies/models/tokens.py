"""Observation tokens shared by both policies (paper appendix): image features per camera (one token per
feature-map cell of the shared backbone, plus a learned camera embedding), one MLP token for joints + gripper,
one MLP token for the force input (tau_ext or current; absent for `base`). Sinusoidal positions.
With `observation = "state"` (PRIVILEGED, twins only: policies/data/privileged.py) one MLP token for the task
objects' vector replaces the image tokens (no backbone at all); "images+state" has both."""

from __future__ import annotations

import math

import torch
import torch.nn as nn

from policies.data.privileged import uses_images, uses_objects
from policies.models.config import PolicyConfig
from policies.models.vision import IMAGENET_MEAN, IMAGENET_STD, make_backbone
from policies.training.methods import gaussian_blur


def sinusoidal(n: int, dim: int) -> torch.Tensor:
    """(n, dim) fixed sinusoidal position table (Vaswani et al.)."""
    pos = torch.arange(n, dtype=torch.float32)[:, None]
    freq = torch.exp(torch.arange(0, dim, 2, dtype=torch.float32) * (-math.log(10000.0) / dim))
    out = torch.zeros(n, dim)
    out[:, 0::2] = torch.sin(pos * freq)
    out[:, 1::2] = torch.cos(pos * freq[: dim // 2])
    return out


def timestep_embedding(t: torch.Tensor, dim: int, scale: float = 1000.0) -> torch.Tensor:
    """(B,) flow times in [0, 1] -> (B, dim) sinusoidal features."""
    half = dim // 2
    freq = torch.exp(-math.log(10000.0) * torch.arange(half, dtype=torch.float32, device=t.device) / half)
    arg = scale * t.float()[:, None] * freq[None]
    return torch.cat([torch.sin(arg), torch.cos(arg)], dim=-1)


def mlp(din: int, dout: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(din, dout), nn.GELU(), nn.Linear(dout, dout))


class ObservationTokens(nn.Module):
    """(images (B, M, H, W, 3) uint8 or None, state (B, S), force (B, F) or None, objects (B, O) or None)
    -> tokens (B, T, hidden): [state, force?, objects?, image cells...].
    A batch's "blur_sigma" [px], in training only: FACTR's Gaussian blur of the frames
    (policies.training.methods), a step's input like its crops (the loop puts it in the batch; nothing is set
    on the model from outside)."""

    def __init__(self, cfg: PolicyConfig):
        super().__init__()
        self.cfg = cfg
        images = uses_images(cfg.observation)
        self.backbone = make_backbone(cfg.backbone, cfg.backbone_weights) if images else None
        if self.backbone is not None:
            self.proj = nn.Conv2d(self.backbone.out_channels, cfg.hidden, 1)
            self.camera = nn.Embedding(max(cfg.n_cameras, 1), cfg.hidden)
        self.state = mlp(cfg.state_dim, cfg.hidden)
        self.force = mlp(cfg.force_dim, cfg.hidden) if cfg.force_dim > 0 else None
        self.objects = mlp(cfg.objects_dim, cfg.hidden) if uses_objects(cfg.observation) else None
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)

    def image_tokens(self, images: torch.Tensor, blur_sigma: float = 0.0) -> torch.Tensor:
        b, m = images.shape[:2]
        # NCHW contiguous: the CPU convolutions run ~2x faster on it than on the channels-last view
        x = images.flatten(0, 1).permute(0, 3, 1, 2).contiguous().float() / 255.0
        if self.training and blur_sigma > 0:
            x = gaussian_blur(x, blur_sigma)
        x = (x - self.mean) / self.std
        f = self.proj(self.backbone(x))  # (B*M, hidden, h, w)
        f = f.flatten(2).transpose(1, 2)  # (B*M, h*w, hidden)
        f = f + sinusoidal(f.shape[1], f.shape[2]).to(f)[None]
        f = f.view(b, m, -1, f.shape[-1]) + self.camera.weight[:m].view(1, m, 1, -1)
        return f.flatten(1, 2)

    def tokens(self, batch: dict) -> torch.Tensor:
        """The tokens of a policy batch (keys images, state, force, objects: those the config uses; and
        blur_sigma [px] in training, FACTR's)."""
        return self(batch.get("images"), batch["state"], batch.get("force"), batch.get("objects"),
                    batch.get("blur_sigma", 0.0))

    def forward(self, images, state, force=None, objects=None, blur_sigma: float = 0.0) -> torch.Tensor:
        toks = [self.state(state)[:, None]]
        if self.force is not None:
            toks.append(self.force(force)[:, None])
        if self.objects is not None:
            if objects is None:
                raise ValueError("this policy observes the privileged object state: batch['objects'] missing")
            toks.append(self.objects(objects)[:, None])
        if self.backbone is not None:
            toks.append(self.image_tokens(images, blur_sigma))
        return torch.cat(toks, dim=1)


def masked_mean(err: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Per-sample mean of err (B, chunk, D) over the valid chunk steps (mask (B, chunk)) -> (B,)."""
    m = mask.to(err.dtype)[..., None]
    return (err * m).sum(dim=(1, 2)) / (m.sum(dim=(1, 2)) * err.shape[-1]).clamp_min(1.0)
