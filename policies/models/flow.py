"""Flow-matching DiT policy (paper Sec. 5; architecture after MDT / DiT): a velocity field v(x_a, a, o) over
the action chunk. Training: x1 = the (normalised) demonstrated chunk, x0 ~ N(0, I), a ~ Beta(1.0, 1.5),
x_a = (1 - a) x0 + a x1, loss ||v - (x1 - x0)||^2 on the valid chunk steps. Inference: the observation is
encoded once per chunk, then 10 Euler steps from noise (a = 0) to the chunk (a = 1).

Each block: adaLN-Zero modulation from the flow time (DiT), self-attention over the chunk, cross-attention to
the observation tokens, MLP. TA-VLA: a linear head on the last hidden states predicts the future force chunk.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from policies.models.config import PolicyConfig
from policies.models.policy import Policy, register
from policies.models.tokens import ObservationTokens, masked_mean, sinusoidal, timestep_embedding


def _modulate(x, shift, scale1p):
    """adaLN: x * (1 + scale) + shift in one fused op; shift and scale1p = 1 + scale are (B, 1, hidden)."""
    return torch.addcmul(shift, x, scale1p)


class Attention(nn.Module):
    """Multi-head attention on scaled_dot_product_attention. Cross-attention takes the memory's keys and
    values from `kv(memory)`, computed once per chunk and reused by every Euler step."""

    def __init__(self, cfg: PolicyConfig, cross: bool):
        super().__init__()
        h = cfg.hidden
        self.heads, self.cross, self.p = cfg.heads, cross, cfg.dropout
        self.q = nn.Linear(h, h) if cross else None
        self.qkv = nn.Linear(h, 2 * h if cross else 3 * h)  # cross: the memory's k, v
        self.proj = nn.Linear(h, h)

    def _heads(self, x, parts: int):
        """(B, N, parts * hidden) -> `parts` tensors (B, heads, N, hidden / heads), views of one buffer."""
        b, n, d = x.shape
        return x.view(b, n, parts, self.heads, d // (parts * self.heads)).permute(2, 0, 3, 1, 4).unbind(0)

    def kv(self, memory):
        """The memory's keys and values (B, heads, T, hidden / heads): once per chunk at inference."""
        return self._heads(self.qkv(memory), 2)

    def forward(self, x, kv=None):
        if self.cross:
            (q,), (k, v) = self._heads(self.q(x), 1), kv
        else:
            q, k, v = self._heads(self.qkv(x), 3)
        y = F.scaled_dot_product_attention(q, k, v, dropout_p=self.p if self.training else 0.0)
        return self.proj(y.transpose(1, 2).flatten(2))


class DiTBlock(nn.Module):
    def __init__(self, cfg: PolicyConfig):
        super().__init__()
        h = cfg.hidden
        self.norm1 = nn.LayerNorm(h, elementwise_affine=False)
        self.attn = Attention(cfg, cross=False)
        self.norm_x = nn.LayerNorm(h)
        self.cross = Attention(cfg, cross=True)
        self.norm2 = nn.LayerNorm(h, elementwise_affine=False)
        self.mlp = nn.Sequential(
            nn.Linear(h, cfg.ff), nn.GELU(), nn.Dropout(cfg.dropout), nn.Linear(cfg.ff, h)
        )
        self.ada = nn.Sequential(nn.SiLU(), nn.Linear(h, 6 * h))
        nn.init.zeros_(self.ada[1].weight)  # adaLN-Zero: every block starts as the identity
        nn.init.zeros_(self.ada[1].bias)
        self.drop = nn.Dropout(cfg.dropout)

    def forward(self, x, mod, kv):
        """mod: this block's six adaLN terms for the flow time, each (B, 1, hidden): shift, 1 + scale and gate
        of the attention and of the MLP (FlowPolicy.conditioning)."""
        s1, g1, a1, s2, g2, a2 = mod
        x = torch.addcmul(x, a1, self.drop(self.attn(_modulate(self.norm1(x), s1, g1))))
        x = x + self.drop(self.cross(self.norm_x(x), kv))
        return torch.addcmul(x, a2, self.mlp(_modulate(self.norm2(x), s2, g2)))


def flow_matching_loss(model, batch: dict, noise: dict) -> tuple[torch.Tensor, dict]:
    """Per-sample loss (B,) and its parts for either velocity field (FlowPolicy, flow_mlp.FlowMLPPolicy):
    ||v(x_a, a, o) - (x1 - x0)||^2 on the valid chunk steps, plus aux_weight x the future-force MSE when the
    model has TA-VLA's head."""
    x1 = batch["action"]
    x0, a = noise["x0"].to(x1), noise["alpha"].to(x1)
    xa = (1 - a)[:, None, None] * x0 + a[:, None, None] * x1
    v, h = model.velocity(xa, a, model.encode(batch))
    fm = masked_mean(F.mse_loss(v, x1 - x0, reduction="none"), batch["mask"])
    parts, total = {"action": fm}, fm
    if model.aux_head is not None:
        parts["aux_force"] = masked_mean(
            F.mse_loss(model.aux_force(h), batch["force_chunk"], reduction="none"), batch["mask"]
        )
        total = total + model.cfg.aux_weight * parts["aux_force"]
    return total, parts


@register("flow", head="dit")
class FlowPolicy(Policy):
    def __init__(self, cfg: PolicyConfig):
        super().__init__(cfg)
        h = cfg.hidden
        self.obs = ObservationTokens(cfg)
        self.obs_norm = nn.LayerNorm(h)
        self.x_in = nn.Linear(cfg.action_dim, h)
        self.time = nn.Sequential(nn.Linear(h, h), nn.SiLU(), nn.Linear(h, h))
        self.blocks = nn.ModuleList(DiTBlock(cfg) for _ in range(cfg.dec_layers))
        self.norm_out = nn.LayerNorm(h, elementwise_affine=False)
        self.ada_out = nn.Sequential(nn.SiLU(), nn.Linear(h, 2 * h))
        self.out = nn.Linear(h, cfg.action_dim)
        for m in (self.ada_out[1], self.out):
            nn.init.zeros_(m.weight)
            nn.init.zeros_(m.bias)
        self.aux_head = nn.Linear(h, cfg.force_dim) if cfg.aux_force and cfg.force_dim else None
        # the chunk's position table, made once (not per Euler step); not saved: a function of the config
        self.register_buffer("pos", sinusoidal(cfg.chunk, h)[None], persistent=False)

    @staticmethod
    def draw_noise(cfg: PolicyConfig, batch: int, gen: torch.Generator) -> dict:
        """x0 (B, chunk, A) ~ N(0, I) and a (B,) ~ Beta(a, b), both fixed by the generator's state (torch has
        no seeded Beta sampler: numpy's, seeded from the generator)."""
        x0 = torch.randn(batch, cfg.chunk, cfg.action_dim, generator=gen)
        rng = np.random.default_rng(int(torch.randint(0, 2**62, (1,), generator=gen)))
        alpha = torch.from_numpy(rng.beta(cfg.time_beta_a, cfg.time_beta_b, size=batch).astype(np.float32))
        return {"x0": x0, "alpha": alpha}

    def encode(self, batch: dict) -> list:
        """The observation, once per chunk: each block's cross-attention keys and values of its tokens."""
        memory = self.obs_norm(self.obs.tokens(batch))
        return [blk.cross.kv(memory) for blk in self.blocks]

    def conditioning(self, alpha):
        """Everything the flow time alpha (B,) conditions, each term (B, 1, hidden): per block its six adaLN
        terms (shift, 1 + scale, gate; attention then MLP), then the output's shift and 1 + scale."""
        c = self.time(timestep_embedding(alpha, self.cfg.hidden))
        out = []
        for ada, n in [(blk.ada, 6) for blk in self.blocks] + [(self.ada_out, 2)]:
            terms = list(ada(c)[:, None].chunk(n, dim=-1))
            for i in range(1, n, 3):  # the scales: 1 + scale once here rather than in every step
                terms[i] = terms[i] + 1
            out.append(terms)
        return out

    def velocity(self, x, alpha, memory, cond=None):
        """v (B, chunk, A) and the last hidden states. cond: conditioning(alpha) when already computed."""
        cond = self.conditioning(alpha) if cond is None else cond
        h = self.x_in(x) + self.pos[:, : x.shape[1]]
        for blk, kv, mod in zip(self.blocks, memory, cond):
            h = blk(h, mod, kv)
        shift, scale1p = cond[-1]
        h = _modulate(self.norm_out(h), shift, scale1p)
        return self.out(h), h

    def loss(self, batch: dict, noise: dict) -> tuple[torch.Tensor, dict]:
        return flow_matching_loss(self, batch, noise)

    def aux_force(self, h):
        """TA-VLA's future force chunk (B, chunk, F) from the last hidden states."""
        return self.aux_head(h)

    @torch.no_grad()  # not inference_mode: callers may still modify the chunk in place
    def predict(self, batch: dict, noise: dict) -> torch.Tensor:
        """Action chunk (B, chunk, A), normalised: Euler integration of v from x0 = noise["x0"]. The
        observation is encoded once (each block's cross-attention keys and values), and the Euler times k/n
        are the same for every chunk, so their conditioning is one batched pass; each step then runs only
        the chunk's own layers."""
        memory = self.encode(batch)
        x = noise["x0"].to(memory[0][0])
        n = self.cfg.flow_steps
        cond = self.conditioning(torch.arange(n, device=x.device, dtype=x.dtype) / n)
        for k in range(n):
            step = [[t[k : k + 1] for t in terms] for terms in cond]  # (1, 1, hidden): broadcast over B
            x = torch.add(x, self.velocity(x, None, memory, step)[0], alpha=1.0 / n)
        return x
