"""NEXT free-space inverse dynamics network f_theta: window of H normalised inputs -> free-space torque.

Paper appendix, Table "NEXT hyperparameters": 2-layer LSTM, hidden 128 (ModelConfig's default; training
uses TrainConfig.hidden, 64 since issue 23: as accurate on the UR5 at 2.7x the windows per second), dropout
0.1 between the LSTM layers; prediction head = 2-layer MLP (hidden 256) on the last time step's hidden state.
The LSTM is stateless over the window: its state starts at zero for every window (no hidden-state drift
over a long run).
Ablation architectures: "gru" (same shape as the LSTM) and "mlp" (flattened window -> 256 -> 256 -> out).
Gate (issue 23, calibration.next.gate): the output is gate * head + gate_offset per joint, fitted after
training on whole held-out runs; None (the default and every older checkpoint) = no gate.
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
    gate: list[float] | None = None  # per output, alpha in [0, 1] (calibration.next.gate.fit_gate)
    gate_offset: list[float] | None = None  # per output, normalised (calibration.next.gate.gate_offset)

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
        # not in the state dict (persistent=False): the gate lives in the config, so weight files and
        # checkpoints written before the gate existed load unchanged
        self.register_buffer("gate_scale", torch.ones(cfg.n_out), persistent=False)
        self.register_buffer("gate_shift", torch.zeros(cfg.n_out), persistent=False)
        self.set_gate(cfg.gate, cfg.gate_offset)

    def set_gate(self, gate, offset) -> None:
        """Set (or, with None, remove) the per-output gate: output = gate * head + offset (normalised)."""
        if (gate is None) != (offset is None):
            raise ValueError("gate and gate_offset go together")
        n = self.cfg.n_out
        if gate is not None and (len(gate) != n or len(offset) != n):
            raise ValueError(f"gate needs {n} values per field, got {len(gate)} and {len(offset)}")
        self.cfg.gate = None if gate is None else [float(g) for g in gate]
        self.cfg.gate_offset = None if offset is None else [float(o) for o in offset]
        self.gate_scale.copy_(torch.ones(n) if gate is None else torch.as_tensor(self.cfg.gate))
        self.gate_shift.copy_(torch.zeros(n) if offset is None else torch.as_tensor(self.cfg.gate_offset))

    def output(self, h: torch.Tensor) -> torch.Tensor:
        """The gated output from the features the head reads (last hidden state, or the flat window)."""
        out = self.head(h)
        return out if self.cfg.gate is None else out * self.gate_scale + self.gate_shift

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.rnn is None:
            return self.output(x.reshape(x.shape[0], -1))
        out, _ = self.rnn(x)  # zero initial state: stateless sliding window
        return self.output(out[:, -1])
