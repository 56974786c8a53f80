"""Training logs: TensorBoard event files, RUN/metrics.jsonl (one JSON line per logged step: what the PNG
and --resume's continuation read), and RUN/curves.png (training loss, validation loss per phase, lr)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np


class RunLog:
    """Rank 0's logger. On resume, lines past the resumed step are dropped (they will be logged again)."""

    def __init__(self, run: Path, resume_step: int = 0):
        from torch.utils.tensorboard import SummaryWriter

        self.run = Path(run)
        self.path = self.run / "metrics.jsonl"
        rows = self.read(self.run) if resume_step else []
        self.rows = [r for r in rows if r["step"] <= resume_step]
        self.path.write_text("".join(json.dumps(r) + "\n" for r in self.rows))
        self.tb = SummaryWriter(
            str(self.run / "tensorboard"), purge_step=resume_step + 1 if resume_step else None
        )

    @staticmethod
    def read(run: Path) -> list[dict]:
        p = Path(run) / "metrics.jsonl"
        return (
            [json.loads(line) for line in p.read_text().splitlines() if line.strip()] if p.is_file() else []
        )

    def log(self, step: int, values: dict[str, float]) -> None:
        for k, v in values.items():
            self.tb.add_scalar(k, v, step)
        row = {"step": step, **{k: float(v) for k, v in values.items()}}
        self.rows.append(row)
        with open(self.path, "a") as f:
            f.write(json.dumps(row) + "\n")

    def close(self) -> None:
        self.tb.flush()
        self.tb.close()
        plot_curves(self.rows, self.run / "curves.png")


def plot_curves(rows: list[dict], path: Path) -> Path | None:
    if not rows:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def series(key):
        pts = [(r["step"], r[key]) for r in rows if key in r and np.isfinite(r[key])]
        return np.array(pts).T if pts else None

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    tr = series("train/loss")
    if tr is not None:
        axes[0].plot(tr[0], tr[1], lw=0.7, color="#999", label="train")
    for key, colour in (
        ("val/loss", "k"),
        ("val/loss_F", "#4c72b0"),
        ("val/loss_PC", "#f5a442"),
        ("val/loss_C", "#e4572e"),
    ):
        s = series(key)
        if s is not None:
            axes[0 if key == "val/loss" else 1].plot(s[0], s[1], "o-", ms=3, color=colour, label=key)
    for a, title in zip(axes[:2], ("loss", "validation loss per phase")):
        a.set_title(title)
        a.set_xlabel("step")
        a.set_yscale("log")
        if a.get_legend_handles_labels()[0]:
            a.legend(fontsize=8)
    lr = series("lr")
    if lr is not None:
        axes[2].plot(lr[0], lr[1])
    axes[2].set_title("learning rate")
    axes[2].set_xlabel("step")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
