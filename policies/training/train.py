"""The training loop (nanoGPT style: one config, one loop). AdamW (lr 3e-4, wd 0.05, betas 0.9/0.95), batch
128, linear warm-up for 500 steps then cosine decay to 0 (the paper's values). Runs alone or under torchrun
(DDP: gloo on CPU, NCCL on CUDA; bf16 autocast on CUDA).

Exactness: global step s fixes everything random in it: the sampler's global batch (policies.data.sampler),
the flow noise / CVAE noise and the crop boxes (drawn for the whole global batch from a generator seeded by
(seed, s), each rank keeping its positions), and dropout (torch seeded by (seed, s, rank)). So `--resume`
continues the uninterrupted run exactly, and N processes compute the gradient of the same global batch as one
(GroupNorm and per-sample losses make the batch split irrelevant; with dropout 0 the loss curves agree to
float rounding).
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from policies.data.dataset import PolicyData
from policies.data.sampler import FirstSampler
from policies.labels.phases import PHASE_SHORT
from policies.models.config import PolicyConfig
from policies.models.policy import make_policy
from policies.training import checkpoint as C
from policies.training.curves import RunLog
from policies.training.methods import BLUR_SIGMA0_PX_224, METHODS, blur_sigma
from policies.training.regularise import Ema, add_obs_noise
from policies.training.run_config import RunOptions, TrainConfig
from policies.training.train_threads import TrainCpu


@dataclass
class Dist:
    rank: int = 0
    world: int = 1
    local_rank: int = 0
    device: torch.device = field(default_factory=lambda: torch.device("cpu"))

    @property
    def main(self) -> bool:
        return self.rank == 0


def setup_distributed() -> Dist:
    """From torchrun's environment (RANK, WORLD_SIZE, LOCAL_RANK); a single process without it."""
    cuda = torch.cuda.is_available()
    if "RANK" not in os.environ or int(os.environ.get("WORLD_SIZE", "1")) <= 1:
        return Dist(device=torch.device("cuda" if cuda else "cpu"))
    import torch.distributed as dist

    rank, world, local = (int(os.environ[k]) for k in ("RANK", "WORLD_SIZE", "LOCAL_RANK"))
    if cuda:
        torch.cuda.set_device(local)
    dist.init_process_group("nccl" if cuda else "gloo")
    return Dist(rank, world, local, torch.device(f"cuda:{local}" if cuda else "cpu"))


def barrier(d: Dist) -> None:
    if d.world > 1:
        import torch.distributed as dist

        dist.barrier()


def lr_at(step: int, cfg: TrainConfig, total: int) -> float:
    """Linear warm-up over cfg.warmup steps, then cosine from cfg.lr to 0 at `total`."""
    if step < cfg.warmup:
        return cfg.lr * (step + 1) / cfg.warmup
    frac = (step - cfg.warmup) / max(1, total - cfg.warmup)
    return cfg.lr * 0.5 * (1.0 + math.cos(math.pi * min(1.0, frac)))


VAL_POINTS = 16  # evaluations a run's curve gets at least (8000 steps at the default 500 have 16)
VAL_EVERY_FLOOR = 50  # [steps] the period that rule shortens no further (an evaluation: ~1 step's time)


def clamp_schedule(cfg: TrainConfig, total: int) -> tuple[TrainConfig, list[str]]:
    """The warm-up, validation and checkpoint periods fitted to a run of `total` steps, and one note per
    change: warm-up at most a tenth of the run (a 400-step run would otherwise train entirely in the 500-step
    warm-up), validation and checkpoints at least 4 times per run (one point at the end is no curve), and
    validation VAL_POINTS times down to a period of VAL_EVERY_FLOOR steps: the run's advice reads the curve's
    shape (policies/training/advice.py needs 5 points; 2,000 steps at every 500 gave 4, and no advice)."""
    from dataclasses import replace

    quarter = max(1, total // 4)
    val_every = min(cfg.val_every, quarter, max(total // VAL_POINTS, VAL_EVERY_FLOOR))
    new = replace(cfg, warmup=min(cfg.warmup, max(1, total // 10)), val_every=val_every,
                  ckpt_every=min(cfg.ckpt_every, quarter))
    notes = [f"{name.replace('_', ' ')} {getattr(cfg, name)} -> {getattr(new, name)} steps (run of {total})"
             for name in ("warmup", "val_every", "ckpt_every") if getattr(new, name) != getattr(cfg, name)]
    return new, notes


def _seed(*parts: int) -> int:
    return int(np.random.SeedSequence([int(p) for p in parts]).generate_state(1, np.uint64)[0] >> 1)


def total_steps(cfg: TrainConfig, sampler: FirstSampler) -> int:
    return cfg.steps or max(1, int(round(cfg.epochs * sampler.steps_per_epoch(cfg.batch))))


def _global_means(d: Dist, values: list[torch.Tensor]) -> list[float]:
    """Means over the ranks of per-rank batch means (equal shares: the global batch's mean)."""
    t = torch.stack([v.float() for v in values])
    if d.world > 1:
        import torch.distributed as dist

        dist.all_reduce(t)
        t /= d.world
    return t.cpu().tolist()


def _to(batch: dict, device) -> dict:
    return {k: v.to(device, non_blocking=True) for k, v in batch.items()}


@torch.no_grad()
def evaluate(
    model, data: PolicyData, idx: np.ndarray, pcfg: PolicyConfig, device, max_n: int = 1024, chunk: int = 64
) -> dict[str, float]:
    """Validation action loss (the objective's action term: L1 for ACT, velocity MSE for flow; fixed noise,
    no augmentation) over all validation samples and per phase (the paper's phase-wise validation loss)."""
    if not len(idx):
        return {}
    if len(idx) > max_n:
        idx = idx[np.linspace(0, len(idx) - 1, max_n).round().astype(int)]
    was = model.training
    model.eval()
    gen = torch.Generator().manual_seed(1234)
    noise = type(model).draw_noise(pcfg, len(idx), gen)
    losses = []
    for lo in range(0, len(idx), chunk):
        b = _to(data.batch(idx[lo : lo + chunk]), device)
        n = {k: v[lo : lo + chunk].to(device) for k, v in noise.items()}
        # fp32 on a CPU whatever the training's precision: validation losses compare across precisions
        with _autocast(device, "bf16" if device.type == "cuda" else "fp32"):
            losses.append(model.loss(b, n)[1]["action"].float().cpu())
    model.train(was)
    loss = torch.cat(losses).numpy()
    ph = data.phase[idx]
    out = {"val/loss": float(loss.mean())}
    for p, name in enumerate(PHASE_SHORT):
        if (ph == p).any():
            out[f"val/loss_{name}"] = float(loss[ph == p].mean())
    return out


def _say(bar, text: str) -> None:
    if bar is not None:
        bar.write(text)
    else:
        print(text, flush=True)


def pick_precision(asked: str, device) -> tuple[str, str]:
    """(the matmuls' precision, "bf16" or "fp32"; why). auto: bf16 autocast (weights, optimiser and EMA stay
    fp32) on a GPU and on a CPU with native bf16 (AVX512-BF16 / AMX: 2.8x a state-preset forward+backward on
    the 2-vCPU EPYC VM, docs/first.md), fp32 elsewhere (emulated bf16 is slower than fp32)."""
    if asked == "fp32":
        return "fp32", "fp32 (as asked)"
    if device.type == "cuda":
        return "bf16", f"bf16 autocast on the GPU ({'as asked' if asked == 'bf16' else 'auto'})"
    native = bool(torch.backends.mkldnn.is_available() and torch.ops.mkldnn._is_mkldnn_bf16_supported())
    if asked == "bf16":
        return "bf16", "bf16 autocast (as asked)" + ("" if native else
                                                     ": this CPU has no native bf16, slower than fp32")
    if native:
        return "bf16", "bf16 autocast (auto: this CPU has native bf16; --precision fp32 to train in fp32)"
    return "fp32", "fp32 (auto: this CPU has no native bf16)"


def _autocast(device, precision: str):
    kind = "cuda" if device.type == "cuda" else "cpu"
    return torch.autocast(kind, dtype=torch.bfloat16, enabled=precision == "bf16")


@dataclass
class TrainHooks:
    """What drives one training process from outside (the terminal app, a test, a benchmark). stop_at: leave
    the loop after that many steps (an interruption, as a kill after a checkpoint would be); on_progress(row)
    after every step on rank 0, row = {"step", "total", "start"} plus the logged losses / validation metrics
    of that step; stop: when set, the loop ends after the current step and writes a checkpoint there (kept
    for --resume)."""

    stop_at: int | None = None
    on_progress: Callable[[dict], None] | None = None
    stop: threading.Event | None = None


def train(data: PolicyData, pcfg: PolicyConfig, o: RunOptions, meta: dict, d: Dist,
          resume_from: Path | None = None, hooks: TrainHooks | None = None) -> dict:
    """Train the run `o` (its train config, method, ratio, source weights, out folder, progress) on `data`;
    checkpoints and logs in o.out (rank 0 writes). Returns the final validation metrics. The CPU side
    (threads, the teleop loop's CPU, cost lines) is policies/training/train_threads.py's."""
    hooks = hooks if hooks is not None else TrainHooks()
    cpu = TrainCpu(o.train.threads, d.world)
    train_idx, val_idx = data.split()
    sampler = _sampler(data, train_idx, o, d)
    total = total_steps(o.train, sampler)
    cfg, notes = clamp_schedule(o.train, total)
    if cfg.keep == "val-min" and not len(val_idx):
        notes.append("--keep val-min: no validation split, the last checkpoint is kept")
    precision, why_precision = pick_precision(cfg.precision, d.device)
    meta["precision_used"] = precision
    if d.main and o.progress:
        print(f"torch threads: {cpu.why}; {why_precision}" + "".join(f"; {n}" for n in notes), flush=True)
    spe = sampler.steps_per_epoch(cfg.batch)
    model, opt, ema = _model_and_optimiser(pcfg, cfg, d)
    start = _resume(resume_from, model, ema, opt)
    net = _distributed(model, d)
    eval_model = ema.model if ema is not None else model
    method = METHODS[o.method]
    sigma0 = BLUR_SIGMA0_PX_224 * pcfg.image_size / 224.0
    run = Path(o.out)
    log = RunLog(run, start) if d.main else None
    meta = dict(meta, train=o.train.to_dict(), total_steps=total, steps_per_epoch=spe,
                schedule={k: getattr(cfg, k) for k in ("warmup", "val_every", "ckpt_every")})
    bar = _bar(total, start, f"{pcfg.policy}/{method.name}") if d.main and o.progress else None
    if d.main:
        cpu.watch(start, lambda text: _say(bar, text), cost=o.progress, steps_left=total - start,
                  observation=pcfg.observation, device=d.device.type, batch=cfg.batch)
    t_last, n_last, last_val = time.perf_counter(), 0, {}
    best = C.kept_loss(run) if start else float("inf")  # --keep val-min: the lowest validation loss so far

    def save(step: int, final: bool = False) -> None:  # rank 0: weights, EMA, optimiser, meta
        C.save(run / "checkpoints", step, model, opt, dict(meta, metrics=last_val), final=final,
               ema=ema.model if ema is not None else None, keep=cfg.keep_checkpoints)

    model.train()
    for s in range(start, min(total, hooks.stop_at or total)):
        cpu.before_step(s)
        batch, noise = _step_inputs(data, sampler, train_idx, type(model), pcfg, cfg, s, d)
        if method.blur:  # a step's input, as its crops: the model reads it from the batch
            batch["blur_sigma"] = blur_sigma(s, total, sigma0)
        torch.manual_seed(_seed(cfg.seed, s, d.rank))  # dropout
        lr = lr_at(s, cfg, total)
        for g in opt.param_groups:
            g["lr"] = lr
        with _autocast(d.device, precision):
            loss_ps, parts = net(batch, noise)
        loss = loss_ps.float().mean()
        loss.backward()
        gnorm = torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
        opt.step()
        opt.zero_grad(set_to_none=True)
        if ema is not None:
            ema.update(model, s)
        done = s + 1
        cpu.after_step(done, time.perf_counter())
        n_last += cfg.batch
        if bar is not None:
            bar.update(1)
        logging = done % cfg.log_every == 0 or done == total
        validating = done % cfg.val_every == 0 or done == total
        if logging:  # every rank: the means are reduced over the ranks
            logged = _global_means(d, [loss.detach()] + [v.detach().float().mean() for v in parts.values()])
        if d.main and logging:
            now = time.perf_counter()
            row = {"train/loss": logged[0], "lr": lr, "train/grad_norm": float(gnorm),
                   "samples_per_s": n_last / max(now - t_last, 1e-9)}
            row.update({f"train/{k}": v for k, v in zip(parts, logged[1:])})
            log.log(done, row)
            t_last, n_last = now, 0
            if bar is not None:
                bar.set_postfix(loss=f"{row['train/loss']:.4f}", sps=f"{row['samples_per_s']:.0f}")
            cpu.speed(row["samples_per_s"], done)
        if d.main and validating:
            last_val = _validate(eval_model, model if ema is not None else None, data, val_idx, pcfg, d, cfg)
            if last_val:
                log.log(done, last_val)
            if cfg.keep == "val-min" and last_val.get("val/loss", best) < best:  # the evaluated weights
                best = last_val["val/loss"]
                C.save_kept(run / "checkpoints", done, model, dict(meta, metrics=last_val),
                            ema=ema.model if ema is not None else None)
        if d.main and (done % cfg.ckpt_every == 0 or done == total):
            save(done, final=done == total)
        if done % cfg.ckpt_every == 0:
            barrier(d)  # the others wait while rank 0 writes, so a killed run has a consistent checkpoint
        if d.main and hooks.on_progress is not None:
            hooks.on_progress({"step": done, "total": total, "start": start, **(row if logging else {}),
                               **(last_val if validating else {})})
        if hooks.stop is not None and hooks.stop.is_set() and done < total:
            if d.main and done % cfg.ckpt_every:
                save(done)
            break
    if bar is not None:
        bar.close()
    if log is not None:
        log.close()
    barrier(d)
    return last_val


# -- the pieces of train(), in the order it calls them --------------------------------------------------
def _sampler(data: PolicyData, train_idx: np.ndarray, o: RunOptions, d: Dist) -> FirstSampler:
    """The FIRST sampler over the training samples: the phase ratio, and per source where the data holds
    rollout samples and the run weighs them."""
    src = data.source[train_idx] if data.source is not None and o.source_weights is not None else None
    return FirstSampler(data.phase[train_idx], o.ratio, o.train.seed, rank=d.rank, world=d.world, sources=src,
                        source_weights=o.source_weights if src is not None else None)


def _model_and_optimiser(pcfg: PolicyConfig, cfg: TrainConfig, d: Dist):
    """(model, AdamW, Ema or None): identical initial weights on every rank (seeded), weight decay on the
    matrices only."""
    torch.manual_seed(cfg.seed)  # identical initial weights on every rank
    model = make_policy(pcfg).to(d.device)
    decay = [p for n, p in model.named_parameters() if p.ndim >= 2]
    no_decay = [p for n, p in model.named_parameters() if p.ndim < 2]
    opt = torch.optim.AdamW(
        [{"params": decay, "weight_decay": cfg.weight_decay}, {"params": no_decay, "weight_decay": 0.0}],
        lr=cfg.lr,
        betas=cfg.betas,
        # one kernel for every parameter on CPU too: 7.6 -> 1.9 ms a step for 6 x 512^2 weights, ~6 % of a
        # state-preset step (differs from the per-tensor loop by rounding only, ~3e-8 after 60 steps)
        fused=True,
    )
    ema = Ema(model, cfg.ema_power, cfg.ema_max) if cfg.ema else None
    return model, opt, ema


def _resume(resume_from: Path | None, model, ema: Ema | None, opt) -> int:
    """The step to start at: 0, or the checkpoint's after loading its weights, EMA and optimiser."""
    if resume_from is None:
        return 0
    from safetensors.torch import load_file

    old = C.read_meta(resume_from)
    model.load_state_dict(load_file(str(Path(old["_path"]).with_name(old["weights"]))))
    if ema is not None and old.get("weights_ema"):
        ema.model.load_state_dict(load_file(str(Path(old["_path"]).with_name(old["weights_ema"]))))
    C.load_optimizer(opt, Path(old["_path"]))
    return int(old["step"])


def _distributed(model, d: Dist):
    """The module the loop calls: DDP over the ranks, the model itself in one process."""
    if d.world <= 1:
        return model
    from torch.nn.parallel import DistributedDataParallel as DDP

    return DDP(model, device_ids=[d.local_rank] if d.device.type == "cuda" else None)


def _bar(total: int, start: int, desc: str):
    from tqdm import tqdm

    return tqdm(total=total, initial=start, unit="step", dynamic_ncols=True, desc=desc)


def _step_inputs(data: PolicyData, sampler: FirstSampler, train_idx: np.ndarray, model_type,
                 pcfg: PolicyConfig, cfg: TrainConfig, s: int, d: Dist) -> tuple[dict, dict]:
    """Global step s's batch and noise on this rank: the sampler's global batch, the noise, the crop boxes and
    the observation noise drawn for the whole global batch from a generator seeded by (seed, s), this rank
    keeping its positions."""
    epoch, k = divmod(s, sampler.steps_per_epoch(cfg.batch))
    idx, pos = sampler.batch(epoch, k, cfg.batch)
    gen = torch.Generator().manual_seed(_seed(cfg.seed, s))
    noise = {key: v[torch.from_numpy(pos)] for key, v in model_type.draw_noise(pcfg, cfg.batch, gen).items()}
    crops = data.pre.image.draw_crops(cfg.batch, gen)[torch.from_numpy(pos)]
    batch = data.batch(train_idx[idx], crops)
    if cfg.obs_noise:  # drawn after the rest: a run without it draws what it always did
        add_obs_noise(batch, cfg.obs_noise, gen, cfg.batch, pos)
    return _to(batch, d.device), _to(noise, d.device)


def _validate(eval_model, raw_model, data: PolicyData, val_idx: np.ndarray, pcfg: PolicyConfig, d: Dist,
              cfg: TrainConfig) -> dict[str, float]:
    """The validation metrics of the evaluated weights (EMA where kept), and of the raw ones as *_raw."""
    out = evaluate(eval_model, data, val_idx, pcfg, d.device, cfg.val_max)
    if raw_model is not None and out:
        raw = evaluate(raw_model, data, val_idx, pcfg, d.device, cfg.val_max)
        out.update({f"{k}_raw": v for k, v in raw.items()})
    return out
