"""NEXT training loop: MSE on normalised torque, AdamW (wd 1e-6), grad clip 1.0, best weights restored.

The user waits for it, so it is sized in wall time (issue 23: <= 60 s for 10 minutes of data on 2 cores):

- An "epoch" is `samples_per_epoch` (4096) windows drawn at random from the training blocks (neighbouring
  100 Hz windows are nearly identical, so full passes mostly repeat themselves); the validation loss is
  measured after each, on at most `max_val_windows` (2048) evenly strided windows.
- Stopping, whichever comes first: (1) validation stops paying for the time -- after `warmup` epochs, when
  the best validation loss improved by less than `min_gain` (1 %) over the last `gain_epochs` (5) epochs,
  i.e. less than 1 % per ~20k windows (~15 s on two cores); (2) the wall budget `max_seconds` (60 s,
  evaluation included: the loop keeps room for three validations, timed before training and after every
  epoch); (3) `patience` epochs without any improvement; (4) `max_epochs`.
- Learning rate: one cycle -- linear warm-up from lr to lr_peak over lr_warmup_windows, cosine down to
  lr_final over lr_decay_windows, then constant (lr_at). The schedule advances by windows seen or by the
  share of the wall budget spent, whichever is further, so a slow or busy machine still anneals before the
  budget ends (runs without a budget are deterministic for a seed on CPU).

CPU speed. One training window of the paper's 2x128 LSTM over 50 steps costs ~60 MFLOP (forward +
backward), ~1600 windows/s on two quiet cores with batch 256 (batch 1024 is several times slower per window
with oneDNN's LSTM here); the default 2x64 runs ~7000/s (measured, quiet) and fits the UR5 as well.
Batches are gathered by index from one contiguous array (no DataLoader, no per-batch host sync).
"""

from __future__ import annotations

import math
import os
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace

import numpy as np
import torch
from torch import nn

from calibration.next.data import WindowData, n_inputs, validation_split
from calibration.next.gate import CROSSFIT_SHARE, crossfit_folds, fit_gate, gate_offset
from calibration.next.model import ModelConfig, NextModel
from calibration.next.threads import ThreadProbe  # noqa: F401  (re-exported: tests and older imports)

TRAIN_BUDGET_S = 60.0  # default wall budget of a training the user waits for [s] (issue 23)
GATES = ("crossfit", "heldout", "none")  # TrainConfig.gate (calibration.next.gate)


@dataclass
class TrainConfig:
    arch: str = "lstm"
    history: int = 50
    inputs: str = "q,qd,dq"
    hidden: int = 64  # the paper's 128 fits the UR5 no better (0.216 vs 0.218 A held out after 24k windows)
    # at 2.7x the time per window (37 vs 102 s): in the user's minute the smaller model sees more data
    head_hidden: int = 256
    dropout: float = 0.1
    lr: float = 1e-3  # the paper's AdamW lr: where the warm-up starts (see lr_at)
    lr_peak: float = 5e-3  # one-cycle peak (lr_peak = lr_final = lr and no decay: the paper's constant lr)
    lr_warmup_windows: int = 4096  # linear ramp lr -> lr_peak over this many training windows
    lr_decay_windows: int = 61440  # then cosine lr_peak -> lr_final over this many (0: no decay)
    lr_final: float = 1e-4
    weight_decay: float = 1e-6
    grad_clip: float = 1.0
    batch_size: int = 256
    samples_per_epoch: int = 4096  # training windows between two validations
    max_epochs: int = 400
    patience: int = 20
    warmup: int = 4  # epochs before any stopping rule applies
    min_delta: float = 1e-5
    min_gain: float = 0.01  # stop when the best validation loss gained less than this (relative) ...
    gain_epochs: int = 5  # ... over the last this many epochs (0: rule off)
    max_val_windows: int = 2048
    max_seconds: float = TRAIN_BUDGET_S  # wall budget of the training, evaluation included [s] (inf: none)
    threads: int = 0  # 0: every core this process may use, or 1 when that is faster now (ThreadProbe)
    device: str = "auto"  # "auto": cuda when available, else cpu
    seed: int = 0
    normalize: str = "zscore"  # normaliser of inputs and targets (data.Normalizer.fit): zscore, robust
    input_noise: float = 0.0  # augmentation: Gaussian noise of this std (normalised units) on training inputs
    validation: str = "blocks"  # what early stopping / best weights are chosen on (data.validation_split):
    # blocks of every run; runs = whole held-out runs when the logs have >= 3; auto = runs when there are
    gate: str = "crossfit"  # per-joint scale alpha in [0, 1] of the network's correction, fitted on runs it
    # never saw (calibration.next.gate): crossfit (with >= 3 runs; the UR5's default), heldout (on the
    # validation runs), none. Single-run logs (the twin) get no gate either way.
    prior: str = "none"  # physics prior under the network (calibration.next.prior): none, description,
    # identified, or auto (identified when the arm and a torque signal in N*m are known, else none)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["max_seconds"] = None if math.isinf(self.max_seconds) else self.max_seconds
        return d


class EarlyStopping:
    """Stop when the validation loss has not improved by more than `min_delta` for `patience` epochs.
    The first `warmup` epochs never stop training (but they do count towards the best loss)."""

    def __init__(self, patience: int = 20, warmup: int = 10, min_delta: float = 1e-5):
        self.patience, self.warmup, self.min_delta = patience, warmup, min_delta
        self.best = math.inf
        self.best_epoch = -1
        self.bad_epochs = 0

    def step(self, epoch: int, loss: float) -> tuple[bool, bool]:
        """Returns (improved, stop)."""
        improved = loss < self.best - self.min_delta
        if improved:
            self.best, self.best_epoch, self.bad_epochs = loss, epoch, 0
        elif epoch >= self.warmup:
            self.bad_epochs += 1
        return improved, epoch >= self.warmup and self.bad_epochs >= self.patience


def stopped_paying(best_curve: list[float], min_gain: float, gain_epochs: int, warmup: int) -> bool:
    """The validation-gain rule: True when, after `warmup` epochs, the best validation loss so far (one value
    per epoch in best_curve) fell by less than `min_gain` (relative) over the last `gain_epochs` epochs."""
    e = len(best_curve)
    if gain_epochs <= 0 or e < max(warmup, gain_epochs + 1):
        return False
    before, now = best_curve[-gain_epochs - 1], best_curve[-1]
    return before - now < min_gain * before


@dataclass
class Progress:
    """What a progress callback sees after every epoch. Return True from the callback to stop early."""

    epoch: int
    train_loss: float
    val_loss: float
    best_val_loss: float
    elapsed_s: float
    max_epochs: int
    stage: str = ""  # "" for the model that is kept; "gate fold k/K" while the gate's fold models train


@dataclass
class TrainResult:
    model: NextModel
    model_config: ModelConfig
    config: TrainConfig
    device: str
    seconds: float
    epochs: int
    best_epoch: int
    best_val_loss: float
    curve: list[tuple[float, float]] = field(default_factory=list)  # (elapsed s, val loss) per epoch
    val_l1: list[float] = field(default_factory=list)  # per joint, in the data's units
    carried_max_diff: list[float] | None = None  # per joint, data units (carried_state_diff); None: no RNN
    stop_reason: str = ""  # "validation gain", "budget", "patience", "max_epochs", "callback"
    threads: int = 0  # CPU threads the training ended on (ThreadProbe)
    validation: str = "blocks"  # what it validated on: "blocks" or "runs" (whole held-out runs)
    val_runs: list[str] = field(default_factory=list)  # the held-out runs' names (validation "runs")
    gate: list[float] | None = None  # per joint alpha (calibration.next.gate), None: no gate

    @property
    def seconds_to_within_5pct(self) -> float | None:
        """Elapsed training time [s] at the first epoch whose validation loss was within 5 % of the final
        (best, restored) one."""
        return next((t for t, v in self.curve if v <= 1.05 * self.best_val_loss), None)


def lr_at(cfg: TrainConfig, windows_seen: int, elapsed_s: float = 0.0) -> float:
    """Learning rate after `windows_seen` training windows and `elapsed_s` of the wall budget: linear
    warm-up lr -> lr_peak, cosine decay lr_peak -> lr_final, then constant lr_final. Counted in windows (not
    steps) so it does not depend on the batch size; with a finite max_seconds the position is the further of
    the windows seen and the budget's share spent (90 % of the budget = the schedule's end)."""
    w = windows_seen
    if math.isfinite(cfg.max_seconds) and cfg.max_seconds > 0:
        span = cfg.lr_warmup_windows + cfg.lr_decay_windows
        w = max(w, int(span * elapsed_s / (0.9 * cfg.max_seconds)))
    if w < cfg.lr_warmup_windows:
        return cfg.lr + (cfg.lr_peak - cfg.lr) * w / cfg.lr_warmup_windows
    w -= cfg.lr_warmup_windows
    if cfg.lr_decay_windows <= 0:
        return cfg.lr_peak
    if w >= cfg.lr_decay_windows:
        return cfg.lr_final
    cos = 0.5 * (1 + math.cos(math.pi * w / cfg.lr_decay_windows))
    return cfg.lr_final + (cfg.lr_peak - cfg.lr_final) * cos


def pick_device(device: str = "auto") -> torch.device:
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(device)


def available_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


@torch.no_grad()
def predict_windows(model: NextModel, x: torch.Tensor, ends: np.ndarray, history: int,
                    batch: int = 4096) -> torch.Tensor:
    """Normalised predictions for the windows ending at `ends` (x: (N, F) tensor on the model's device)."""
    model.eval()
    outs = []
    offs = torch.arange(-history + 1, 1, device=x.device)
    for i in range(0, len(ends), batch):
        e = torch.as_tensor(ends[i:i + batch], device=x.device)
        outs.append(model(x[e[:, None] + offs[None, :]]))
    return torch.cat(outs) if outs else torch.zeros(0, model.cfg.n_out, device=x.device)


def train(data: WindowData, cfg: TrainConfig | None = None,
          callback: Callable[[Progress], bool | None] | None = None, progress_bar: bool | None = None
          ) -> TrainResult:
    """Train NEXT on `data` (calibration.next.data.build_windows). Deterministic for a given seed on CPU
    without a budget. With gate "crossfit" and >= 3 runs: first the fold models of the gate (CROSSFIT_SHARE
    of the budget together; calibration.next.gate), then the final model on every run in the rest (at
    least a quarter of the budget); seconds and curve count from the start of the first."""
    cfg = cfg or TrainConfig()
    if cfg.gate not in GATES:
        raise ValueError(f"gate must be one of {GATES}, got {cfg.gate!r}")
    t0 = time.perf_counter()
    folds = crossfit_folds(data.run_index, data.train_ends, data.val_ends) if cfg.gate == "crossfit" else []
    alpha = _crossfit_alpha(data, cfg, folds, callback, progress_bar) if folds else None
    spent = time.perf_counter() - t0
    final = replace(cfg, max_seconds=max(cfg.max_seconds - spent, 0.25 * cfg.max_seconds))
    res = _train(data, final, *validation_split(data, cfg.validation), callback, progress_bar, alpha)
    res.config, res.seconds = cfg, res.seconds + spent
    res.curve = [(t + spent, v) for t, v in res.curve]
    return res


def _crossfit_alpha(data: WindowData, cfg: TrainConfig, folds, callback=None, progress_bar=None
                    ) -> np.ndarray | None:
    """The cross-fitted gate: each fold model (the final model's procedure on the other folds' runs, its
    share of the budget) predicts every window of its held-out runs (at most 2 x max_val_windows, evenly
    strided); alpha per joint from all of them pooled, in the data's units. The callback sees the fold
    models' epochs too (Progress.stage); None (no gate) when it asked to stop."""
    fold_cfg = replace(cfg, max_seconds=cfg.max_seconds * CROSSFIT_SHARE / len(folds), gate="none")
    ym, ys = data.normalizer.y_mean, data.normalizer.y_std
    x = torch.as_tensor(data.x)
    corr, resid = [], []
    for k, (tr, va, held) in enumerate(folds):
        fold = _train(data, fold_cfg, tr, va, "blocks", callback, progress_bar, None, memory=False,
                      stage=f"gate fold {k + 1}/{len(folds)}")
        if fold.stop_reason == "callback":
            return None
        model = fold.model
        held = held[np.linspace(0, len(held) - 1, min(len(held), 2 * cfg.max_val_windows)).astype(int)]
        corr.append(predict_windows(model, x, held, cfg.history).numpy() * ys + ym)
        resid.append(data.y[held] * ys + ym)
    return fit_gate(np.concatenate(corr), np.concatenate(resid))


def _train(data: WindowData, cfg: TrainConfig, train_ends: np.ndarray, val_all: np.ndarray, used: str,
           callback, progress_bar: bool | None, gate: np.ndarray | None, memory: bool = True,
           stage: str = "") -> TrainResult:
    """One training on the given window ends (used: "blocks" or "runs", what val_all is); gate: alpha to
    apply to the best weights (None: none, or fitted here on the validation runs with cfg.gate "heldout");
    memory: measure the carried state's fading memory afterwards."""
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    dev = pick_device(cfg.device)
    if dev.type == "cpu":
        torch.set_num_threads(cfg.threads or available_cores())
    probe = ThreadProbe(available_cores() if dev.type == "cpu" and cfg.threads == 0 else 1)
    n_j = data.y.shape[1]
    mcfg = ModelConfig(n_in=n_inputs(n_j, cfg.inputs), n_out=n_j, history=cfg.history, arch=cfg.arch,
                       hidden=cfg.hidden, head_hidden=cfg.head_hidden, dropout=cfg.dropout)
    if data.x.shape[1] != mcfg.n_in or data.history != cfg.history:
        raise ValueError("WindowData was built with other inputs/history than the TrainConfig asks for")
    model = NextModel(mcfg).to(dev)
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    loss_fn = nn.MSELoss()
    x = torch.as_tensor(data.x, device=dev)
    y = torch.as_tensor(data.y, device=dev)
    offs = torch.arange(-cfg.history + 1, 1, device=dev)
    val_all = val_all if len(val_all) else train_ends
    val_ends = val_all
    if len(val_ends) > cfg.max_val_windows:
        val_ends = val_ends[np.linspace(0, len(val_ends) - 1, cfg.max_val_windows).astype(int)]
    val_y = y[torch.as_tensor(val_ends, device=dev)]
    stopper = EarlyStopping(cfg.patience, cfg.warmup, cfg.min_delta)
    best_state = {k: v.detach().clone() for k, v in model.state_dict().items()}
    best_curve: list[float] = []
    reason = "max_epochs"
    show = sys.stderr.isatty() if progress_bar is None else progress_bar
    from tqdm import tqdm  # local import: only training needs it

    desc = f"NEXT training ({stage})" if stage else "NEXT training"
    bar = tqdm(total=cfg.max_epochs, disable=not show, desc=desc, unit="epoch", leave=False)
    curve: list[tuple[float, float]] = []
    t0 = time.perf_counter()
    predict_windows(model, x, val_ends, cfg.history)  # timed once untrained: the budget's reserve below
    eval_s = time.perf_counter() - t0  # a validation's duration [s]: the budget keeps room for three (the
    # epoch's own, the final pass and the fading-memory measurement after the loop), re-measured every epoch
    epoch = 0
    seen = 0
    for epoch in range(cfg.max_epochs):  # noqa: B007 -- epoch is reported after the loop
        model.train()
        n = min(cfg.samples_per_epoch, len(train_ends))
        ends = rng.choice(train_ends, size=n, replace=False)
        total = torch.zeros((), device=dev)  # summed on the device: no host sync per batch
        for i in range(0, n, cfg.batch_size):
            if time.perf_counter() - t0 + 3 * eval_s > cfg.max_seconds:  # room left for the last evaluations
                n = max(i, 1)
                break
            probe.before(epoch, i // cfg.batch_size)
            e = torch.as_tensor(ends[i:i + cfg.batch_size], device=dev)
            for group in opt.param_groups:
                group["lr"] = lr_at(cfg, seen, time.perf_counter() - t0)
            xb = x[e[:, None] + offs[None, :]]
            if cfg.input_noise > 0:  # augmentation (off by default): a model robust to sensor noise
                xb = xb + cfg.input_noise * torch.randn_like(xb)
            pred = model(xb)
            loss = loss_fn(pred, y[e])
            opt.zero_grad(set_to_none=True)
            loss.backward()
            nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
            opt.step()
            total += loss.detach() * len(e)
            seen += len(e)
            probe.after()
        total = float(total)
        t_eval = time.perf_counter()
        val_loss = loss_fn(predict_windows(model, x, val_ends, cfg.history), val_y).item()
        elapsed = time.perf_counter() - t0
        eval_s = elapsed - (t_eval - t0)
        curve.append((elapsed, val_loss))
        improved, stop = stopper.step(epoch, val_loss)
        best_curve.append(stopper.best)
        if improved:
            best_state = {k: v.detach().clone() for k, v in model.state_dict().items()}
        bar.update(1)
        bar.set_postfix(train=f"{total / n:.4f}", val=f"{val_loss:.4f}", best=f"{stopper.best:.4f}")
        if callback is not None and callback(Progress(epoch, total / n, val_loss, stopper.best, elapsed,
                                                      cfg.max_epochs, stage)):
            reason = "callback"
            break
        out_of_time = elapsed + 3 * eval_s > cfg.max_seconds
        reason = ("patience" if stop else "budget" if out_of_time else "validation gain"
                  if stopped_paying(best_curve, cfg.min_gain, cfg.gain_epochs, cfg.warmup) else "")
        if reason:
            break
        reason = "max_epochs"
    bar.close()
    model.load_state_dict(best_state)
    model.eval()
    pred = predict_windows(model, x, val_ends, cfg.history)
    ym, ys = data.normalizer.y_mean, data.normalizer.y_std
    if gate is None and used == "runs" and cfg.gate == "heldout":  # fitted on the runs it never saw
        gate = fit_gate(pred.cpu().numpy() * ys + ym, val_y.cpu().numpy() * ys + ym)
    if gate is not None:
        model.set_gate(gate.tolist(), gate_offset(gate, ym, ys).tolist())
        pred = pred * model.gate_scale + model.gate_shift  # the gated model's output, without a new pass
    l1 = ((pred - val_y).abs().mean(0).cpu().numpy() * data.normalizer.y_std).tolist()
    seconds = time.perf_counter() - t0
    carried = None
    if model.rnn is not None and memory:  # not training time: measured once on the trained model
        ends = val_all[:2 * cfg.max_val_windows]  # bounded
        carried = (carried_state_diff(model, x, ends, cfg.history) * data.normalizer.y_std).tolist()
    return TrainResult(model=model.cpu(), model_config=mcfg, config=cfg, device=str(dev),
                       seconds=seconds, epochs=epoch + 1, best_epoch=stopper.best_epoch,
                       best_val_loss=stopper.best, curve=curve, val_l1=l1, carried_max_diff=carried,
                       stop_reason=reason, threads=probe.threads, validation=used,
                       val_runs=data.val_runs if used == "runs" else [],
                       gate=None if gate is None else gate.tolist())


@torch.no_grad()
def carried_state_diff(model: NextModel, x: torch.Tensor, ends: np.ndarray, history: int) -> np.ndarray:
    """Fading memory of a recurrent NEXT model: per output, the largest |carried - window| (normalised) over
    the windows ending at `ends`, where `window` is the model's stateless output and `carried` the output of
    one run carried from the start of the contiguous stretch of window ends it belongs to (runs of
    consecutive `ends`, e.g. the validation blocks). Small: the model forgets within H samples, so the
    streaming estimator may carry its state (calibration.next.lstm_runs.CarriedRun)."""
    model.eval()
    ends = np.asarray(ends)
    worst = torch.zeros(model.cfg.n_out, device=x.device)
    for run in np.split(ends, np.flatnonzero(np.diff(ends) != 1) + 1):
        if len(run) == 0:
            continue
        start = int(run[0]) - history + 1
        out, _ = model.rnn(x[start:int(run[-1]) + 1][None])
        carried = model.output(out[0, history - 1:])
        window = predict_windows(model, x, run, history)
        worst = torch.maximum(worst, (carried - window).abs().amax(0))
    return worst.cpu().numpy()


@torch.no_grad()
def predict_series(model: NextModel, x_norm: np.ndarray, history: int, batch: int = 4096) -> np.ndarray:
    """Normalised predictions for every sample of one segment (N, F); the first H-1 rows are NaN."""
    model.eval()
    x = torch.as_tensor(np.asarray(x_norm, np.float32))
    out = np.full((len(x_norm), model.cfg.n_out), np.nan, np.float32)
    if len(x_norm) >= history:
        ends = np.arange(history - 1, len(x_norm))
        out[history - 1:] = predict_windows(model, x, ends, history, batch).numpy()
    return out
