"""ACT (Zhao et al. 2023) as the paper configures it: a CVAE whose encoder (training only) reads the state and
the action chunk into a style latent z; the policy encodes [z, state, force, image tokens] with a transformer
encoder and decodes `chunk` learned queries into absolute joint + gripper targets. Loss: L1 on the valid chunk
steps + kl_weight * KL(q(z | a, s) || N(0, I)); at inference z = 0. TA-VLA: an extra head predicts the future
force chunk (L1, aux_weight).

Randomness (the reparameterisation noise) is drawn by `draw_noise` for a whole global batch and sliced per
rank, so a DDP run and a single process compute the same loss.
"""

from __future__ import annotations

import torch
import torch.nn as nn
import torch.nn.functional as F

from policies.models.config import PolicyConfig
from policies.models.policy import Policy, register
from policies.models.tokens import ObservationTokens, masked_mean, sinusoidal


def _encoder(cfg: PolicyConfig, layers: int) -> nn.TransformerEncoder:
    layer = nn.TransformerEncoderLayer(
        cfg.hidden, cfg.heads, cfg.ff, cfg.dropout, batch_first=True, norm_first=True, activation="gelu"
    )
    return nn.TransformerEncoder(layer, layers, enable_nested_tensor=False)


@register("act")
class ACTPolicy(Policy):
    def __init__(self, cfg: PolicyConfig):
        super().__init__(cfg)
        h = cfg.hidden
        self.obs = ObservationTokens(cfg)
        # CVAE posterior q(z | state, actions)
        self.vae_cls = nn.Parameter(torch.zeros(1, 1, h))
        self.vae_state = nn.Linear(cfg.state_dim, h)
        self.vae_action = nn.Linear(cfg.action_dim, h)
        self.vae_encoder = _encoder(cfg, cfg.enc_layers)
        self.vae_out = nn.Linear(h, 2 * cfg.latent_dim)
        self.latent_in = nn.Linear(cfg.latent_dim, h)
        # policy
        self.encoder = _encoder(cfg, cfg.enc_layers)
        layer = nn.TransformerDecoderLayer(
            h, cfg.heads, cfg.ff, cfg.dropout, batch_first=True, norm_first=True, activation="gelu"
        )
        self.decoder = nn.TransformerDecoder(layer, cfg.dec_layers, norm=nn.LayerNorm(h))
        self.queries = nn.Parameter(torch.zeros(1, cfg.chunk, h))
        nn.init.normal_(self.queries, std=0.02)
        self.head = nn.Linear(h, cfg.action_dim)
        self.aux_head = nn.Linear(h, cfg.force_dim) if cfg.aux_force and cfg.force_dim else None

    @staticmethod
    def draw_noise(cfg: PolicyConfig, batch: int, gen: torch.Generator) -> dict:
        return {"eps": torch.randn(batch, cfg.latent_dim, generator=gen)}

    def _posterior(self, state, action, mask):
        x = torch.cat(
            [
                self.vae_cls.expand(len(state), -1, -1),
                self.vae_state(state)[:, None],
                self.vae_action(action),
            ],
            dim=1,
        )
        x = x + sinusoidal(x.shape[1], x.shape[2]).to(x)[None]
        pad = torch.cat([torch.zeros(len(state), 2, dtype=torch.bool, device=x.device), ~mask], dim=1)
        mu, logvar = self.vae_out(self.vae_encoder(x, src_key_padding_mask=pad)[:, 0]).chunk(2, dim=-1)
        return mu, logvar

    def _decode(self, batch: dict, z: torch.Tensor):
        tokens = self.obs.tokens(batch)
        x = torch.cat([self.latent_in(z)[:, None], tokens], dim=1)
        memory = self.encoder(x + sinusoidal(x.shape[1], x.shape[2]).to(x)[None])
        q = self.queries + sinusoidal(self.cfg.chunk, self.cfg.hidden).to(x)[None]
        out = self.decoder(q.expand(len(x), -1, -1), memory)
        return self.head(out), (self.aux_head(out) if self.aux_head is not None else None)

    def loss(self, batch: dict, noise: dict) -> tuple[torch.Tensor, dict]:
        """Per-sample loss (B,) and its parts (each (B,))."""
        mu, logvar = self._posterior(batch["state"], batch["action"], batch["mask"])
        z = mu + torch.exp(0.5 * logvar) * noise["eps"].to(mu)
        pred, aux = self._decode(batch, z)
        l1 = masked_mean(F.l1_loss(pred, batch["action"], reduction="none"), batch["mask"])
        kl = -0.5 * (1 + logvar - mu.pow(2) - logvar.exp()).sum(-1)
        parts = {"action": l1, "kl": kl}
        total = l1 + self.cfg.kl_weight * kl
        if aux is not None:
            parts["aux_force"] = masked_mean(
                F.l1_loss(aux, batch["force_chunk"], reduction="none"), batch["mask"]
            )
            total = total + self.cfg.aux_weight * parts["aux_force"]
        return total, parts

    @torch.no_grad()
    def predict(self, batch: dict, noise: dict | None = None) -> torch.Tensor:
        """Action chunk (B, chunk, action_dim) in normalised units, z = 0 (the prior's mean)."""
        z = torch.zeros(len(batch["state"]), self.cfg.latent_dim, device=batch["state"].device)
        return self._decode(batch, z)[0]
