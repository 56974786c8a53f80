"""Flow-matching policy with a residual-MLP velocity field: the `state` preset's head, for low-dimensional
observations (joints + gripper, force, the PRIVILEGED object vector), where a transformer over the chunk's
30 tokens costs ~10x more per sample for nothing it can use (measured: docs/first_training.md).

Same objective and sampling as policies.models.flow.FlowPolicy (x_a = (1 - a) x0 + a x1, a ~ Beta(1, 1.5),
loss
||v - (x1 - x0)||^2 on the valid chunk steps, 10 Euler steps at inference, the same `draw_noise`), so the
training loop, the checkpoints and the rollout treat both alike. The velocity field sees the whole noisy chunk
flattened (chunk * A values); the observation tokens (ObservationTokens, one per input) are concatenated into
one conditioning vector, added to the flow time's embedding, and modulate every residual block (FiLM, as
Diffusion Policy conditions its 1-D U-Net). Widths: cfg.hidden per observation token and for the
conditioning, cfg.ff for the residual stream, cfg.dec_layers residual blocks.
"""

from __future__ import annotations

import torch
import torch.nn as nn

from policies.data.privileged import uses_images
from policies.models.config import PolicyConfig
from policies.models.flow import FlowPolicy, flow_matching_loss
from policies.models.policy import Policy, register
from policies.models.tokens import ObservationTokens, timestep_embedding


class FiLMBlock(nn.Module):
    """h + MLP(LayerNorm(h) * (1 + scale(c)) + shift(c)); the modulation starts at zero (identity block)."""

    def __init__(self, width: int, cond: int, dropout: float):
        super().__init__()
        self.norm = nn.LayerNorm(width, elementwise_affine=False)
        self.film = nn.Linear(cond, 2 * width)
        nn.init.zeros_(self.film.weight)
        nn.init.zeros_(self.film.bias)
        self.mlp = nn.Sequential(nn.Linear(width, width), nn.GELU(), nn.Dropout(dropout),
                                 nn.Linear(width, width))

    def forward(self, h, c):
        shift, scale = self.film(c).chunk(2, dim=-1)
        return h + self.mlp(torch.addcmul(shift, self.norm(h), 1 + scale))


@register("flow", head="mlp")
class FlowMLPPolicy(Policy):
    def __init__(self, cfg: PolicyConfig):
        super().__init__(cfg)
        if uses_images(cfg.observation):
            raise ValueError("the MLP flow head takes low-dimensional inputs only: observation 'state'")
        h, w = cfg.hidden, cfg.ff
        self.obs = ObservationTokens(cfg)
        n_tokens = 1 + (cfg.force_dim > 0) + (cfg.objects_dim > 0)
        self.obs_in = nn.Sequential(nn.LayerNorm(n_tokens * h), nn.Linear(n_tokens * h, h))
        self.time = nn.Sequential(nn.Linear(h, h), nn.SiLU(), nn.Linear(h, h))
        self.cond_act = nn.SiLU()
        self.x_in = nn.Linear(cfg.chunk * cfg.action_dim, w)
        self.blocks = nn.ModuleList(FiLMBlock(w, h, cfg.dropout) for _ in range(cfg.dec_layers))
        self.norm_out = nn.LayerNorm(w)
        self.out = nn.Linear(w, cfg.chunk * cfg.action_dim)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)
        self.aux_head = (nn.Linear(w, cfg.chunk * cfg.force_dim)
                         if cfg.aux_force and cfg.force_dim else None)

    draw_noise = staticmethod(FlowPolicy.draw_noise)

    def encode(self, batch: dict) -> torch.Tensor:
        """The observation as one conditioning vector (B, hidden), once per chunk."""
        return self.obs_in(self.obs.tokens(batch).flatten(1))

    def velocity(self, x, alpha, memory):
        """v (B, chunk, A) and the last hidden state (B, ff) for noisy chunks x at flow times alpha (B,)."""
        c = self.cond_act(memory + self.time(timestep_embedding(alpha, self.cfg.hidden)))
        h = self.x_in(x.flatten(1))
        for blk in self.blocks:
            h = blk(h, c)
        h = self.norm_out(h)
        return self.out(h).view_as(x), h

    def loss(self, batch: dict, noise: dict) -> tuple[torch.Tensor, dict]:
        return flow_matching_loss(self, batch, noise)

    def aux_force(self, h):
        """TA-VLA's future force chunk (B, chunk, F) from the last hidden state (B, ff)."""
        return self.aux_head(h).view(h.shape[0], self.cfg.chunk, self.cfg.force_dim)

    @torch.no_grad()
    def predict(self, batch: dict, noise: dict) -> torch.Tensor:
        """Action chunk (B, chunk, A), normalised: Euler integration of v from x0 = noise["x0"], the
        observation encoded once."""
        memory = self.encode(batch)
        x = noise["x0"].to(memory)
        n = self.cfg.flow_steps
        for k in range(n):
            a = torch.full((x.shape[0],), k / n, dtype=x.dtype, device=x.device)
            x = x + self.velocity(x, a, memory)[0] / n
        return x
