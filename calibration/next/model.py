"""NEXT free-space inverse dynamics network f_theta: window of H normalised inputs -> free-space torque.

Paper appendix, Table "NEXT hyperparameters": 2-layer LSTM, hidden 128 (ModelConfig's default; training
uses TrainConfig.hidden, 64 since issue 23: as accurate on the UR5 at 2.7x the windows per second), dropout
0.1 between the LSTM layers; prediction head = 2-layer MLP (hidden 256) on the last time step's hidden state.
The LSTM is stateless over the window: its state starts at zero for every window (no hidden-state drift
over a long run).
Ablation architectures: "gru" (same shape as the LSTM) and "mlp" (flattened window -> 256 -> 256 -> out).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from torch import nn

ARCHS = ("lstm", "gru", "mlp")


@dataclass
class ModelConfig:
    n_in: int
    n_out: int
    history: int = 50
    arch: str = "lstm"
    hidden: int = 128
    layers: int = 2
    head_hidden: int = 256
    dropout: float = 0.1

    def to_dict(self) -> dict:
        return asdict(self)


class NextModel(nn.Module):
    """Input (B, H, n_in) normalised; output (B, n_out) normalised free-space torque at the window's end."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        if cfg.arch not in ARCHS:
            raise ValueError(f"arch must be one of {ARCHS}, got {cfg.arch!r}")
        self.cfg = cfg
        if cfg.arch == "mlp":
            self.rnn = None
            feat = cfg.n_in * cfg.history
            self.head = nn.Sequential(
                nn.Linear(feat, cfg.head_hidden), nn.ReLU(), nn.Dropout(cfg.dropout),
                nn.Linear(cfg.head_hidden, cfg.head_hidden), nn.ReLU(), nn.Dropout(cfg.dropout),
                nn.Linear(cfg.head_hidden, cfg.n_out))
        else:
            rnn_cls = nn.LSTM if cfg.arch == "lstm" else nn.GRU
            self.rnn = rnn_cls(cfg.n_in, cfg.hidden, num_layers=cfg.layers, batch_first=True,
                               dropout=cfg.dropout if cfg.layers > 1 else 0.0)
            self.head = nn.Sequential(
                nn.Linear(cfg.hidden, cfg.head_hidden), nn.ReLU(), nn.Dropout(cfg.dropout),
                nn.Linear(cfg.head_hidden, cfg.n_out))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.rnn is None:
            return self.head(x.reshape(x.shape[0], -1))
        out, _ = self.rnn(x)  # zero initial state: stateless sliding window
        return self.head(out[:, -1])
