"""`factr2 train RECORDING_OR_DIR... --out RUN`: train a FIRST (or baseline) policy on recorded episodes.

Multi-process: `--nproc N` runs N processes on this machine (torchrun underneath); several machines: start the
same command under torchrun on each (docs/policies.md), e.g.
    torchrun --nnodes 2 --node_rank 0 --nproc_per_node 8 --rdzv_backend c10d --rdzv_endpoint HOST:29500 \\
        -m factr2_teleop.cli train DATA --out RUN
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from factr2_teleop.commands.label_args import add_label_arguments, thresholds_arg
from hardware.errors import UserError

HELP = "train a FIRST / ACT / flow-matching policy on recorded episodes (one or many processes)"


def add_arguments(p) -> None:
    from policies.config import POLICIES, PRESETS
    from policies.dataset import FORCE_SOURCES
    from policies.methods import METHODS

    p.add_argument("inputs", type=Path, nargs="+", metavar="RECORDING_OR_DIR")
    p.add_argument("--out", type=Path, required=True, metavar="RUN", help="run folder (checkpoints, logs)")
    p.add_argument("--policy", choices=POLICIES, default="flow")
    p.add_argument(
        "--method",
        choices=list(METHODS),
        default="first",
        help="first (default), base, base-torque, factr, tavla",
    )
    p.add_argument(
        "--ratio",
        default=None,
        metavar="F:PC:C",
        help="re-sampling weights w_F:w_PC:w_C or a preset (C, PC, PC+C, uniform); "
        "default 1:5:1 for first, uniform otherwise",
    )
    p.add_argument(
        "--preset", choices=PRESETS, default=None,
        help="state (low-dimensional inputs, the default with --obs state), small (images on a CPU, the "
        "default otherwise) or paper (the paper's sizes)"
    )
    g = p.add_mutually_exclusive_group()
    g.add_argument("--steps", type=int, default=None, help="optimiser steps")
    g.add_argument("--epochs", type=float, default=None,
                   help="passes over the training samples (default 80 with --obs state, else 20)")
    p.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
    p.add_argument(
        "--include-failed",
        action="store_true",
        help="train on failed demonstrations too (default: they are skipped, counted in one line)",
    )
    p.add_argument(
        "--keep-incomplete",
        action="store_true",
        help="train on episodes cut off by a killed recorder too (default: skipped)",
    )
    p.add_argument(
        "--force",
        choices=[f for f in FORCE_SOURCES if f != "none"],
        default="tau_ext",
        help="force input: NEXT tau_ext (default) or raw motor current",
    )
    add_label_arguments(p)
    from policies.privileged import OBSERVATIONS

    p.add_argument(
        "--obs",
        choices=OBSERVATIONS,
        default="images",
        help="what the policy sees besides joints and force: camera frames (default), or `state`: the twin "
        "task objects' poses, PRIVILEGED and SIMULATED (recorded by `factr2 collect`; no frames read)",
    )
    p.add_argument("--rate", type=float, default=None, help="policy rate [Hz] (default: the camera rate)")
    p.add_argument("--batch", type=int, default=None, help="default 256 with --obs state, else 128")
    p.add_argument("--lr", type=float, default=3e-4)
    p.add_argument("--weight-decay", type=float, default=0.05)
    p.add_argument("--warmup", type=int, default=500)
    p.add_argument("--dropout", type=float, default=None)
    p.add_argument("--image-size", type=int, default=None, help="input size [px] (default: the preset's)")
    p.add_argument(
        "--backbone",
        default="",
        help="resnet18-gn, resnet18-gn-l3 (up to layer3), convnet-gn (small, fast), torchvision:NAME or "
        "timm:NAME (default: the preset's, small resnet18-gn-l3, paper resnet18-gn)",
    )
    p.add_argument("--backbone-weights", default="", metavar="FILE", help="local weights for the backbone")
    p.add_argument(
        "--set",
        action="append",
        default=None,
        metavar="FIELD=VALUE",
        dest="set",
        help="override a policy config field of the preset (policies/config.py), e.g. --set hidden=128",
    )
    p.add_argument("--val-every", type=int, default=500)
    p.add_argument("--ckpt-every", type=int, default=1000)
    p.add_argument("--log-every", type=int, default=10, help="steps between logged training losses")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--threads", type=int, default=0, help="torch threads per process (default: cores / nproc)"
    )
    p.add_argument("--nproc", type=int, default=1, help="processes on this machine (DDP; gloo on CPU)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _options(args):
    from policies.run import RunOptions
    from policies.sampler import parse_ratio
    from policies.train import TrainConfig, default_length

    ratio = None
    if args.ratio is not None:
        try:
            ratio = parse_ratio(args.ratio)
        except ValueError as e:
            raise UserError(f"--ratio: {e}", fix="e.g. --ratio 1:5:1") from None
    thresholds = thresholds_arg(args)
    for name in ("steps", "batch", "val_every", "ckpt_every", "log_every"):
        v = getattr(args, name)
        if v is not None and v < 1:
            raise UserError(f"--{name.replace('_', '-')} must be >= 1, got {v}")
    if args.epochs is not None and not args.epochs > 0:
        raise UserError(f"--epochs must be > 0, got {args.epochs}")
    overrides = _overrides(args.set or [])
    tcfg = TrainConfig(
        steps=args.steps or 0,
        epochs=args.epochs or default_length(args.obs)[0],
        batch=args.batch or default_length(args.obs)[1],
        lr=args.lr,
        weight_decay=args.weight_decay,
        warmup=args.warmup,
        val_every=args.val_every,
        ckpt_every=args.ckpt_every,
        log_every=args.log_every,
        seed=args.seed,
        threads=args.threads,
    )
    return RunOptions(
        inputs=args.inputs,
        out=args.out,
        policy=args.policy,
        method=args.method,
        ratio=ratio,
        preset=args.preset or "",
        force=args.force,
        next=args.next,
        thresholds=thresholds,
        rate_hz=args.rate,
        resume=args.resume,
        backbone=args.backbone,
        backbone_weights=args.backbone_weights,
        dropout=args.dropout,
        image_size=args.image_size,
        progress=not args.no_progress,
        train=tcfg,
        overrides=overrides,
        observation=args.obs,
        include_failed=args.include_failed,
        keep_incomplete=args.keep_incomplete,
    )


def _overrides(items: list[str]) -> dict:
    from dataclasses import fields

    from policies.config import PolicyConfig

    types = {f.name: type(getattr(PolicyConfig(), f.name)) for f in fields(PolicyConfig)}
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if (
            not sep
            or key not in types
            or key in ("policy", "n_cameras", "state_dim", "force_dim", "action_dim")
        ):
            raise UserError(
                f"--set {item!r}: not FIELD=VALUE of a settable policy config field",
                fix="see policies/config.py, e.g. --set hidden=128",
            )
        try:
            out[key] = (value.lower() in ("1", "true", "yes")) if types[key] is bool else types[key](value)
        except ValueError:
            raise UserError(f"--set {item!r}: {value!r} is not a {types[key].__name__}") from None
    return out


def _argv(args) -> list[str]:
    """This command's options back as arguments (for the worker processes), less --nproc."""
    out = ["train", *map(str, args.inputs)]
    flags = {"resume": "--resume", "no_progress": "--no-progress", "include_failed": "--include-failed",
             "keep_incomplete": "--keep-incomplete", "no_tare": "--no-tare"}
    for dest, value in sorted(vars(args).items()):
        if dest in ("inputs", "nproc", "command", "debug", "_run") or value is None or dest.startswith("_"):
            continue
        if dest == "set":
            out += [a for item in value for a in ("--set", item)]
        elif dest in flags:
            out += [flags[dest]] if value else []
        elif dest in (
            "out",
            "policy",
            "method",
            "ratio",
            "preset",
            "steps",
            "epochs",
            "force",
            "next",
            "thresholds",
            "rate",
            "batch",
            "lr",
            "weight_decay",
            "warmup",
            "dropout",
            "image_size",
            "backbone",
            "backbone_weights",
            "obs",
            "val_every",
            "ckpt_every",
            "log_every",
            "seed",
            "threads",
        ):
            out += [f"--{dest.replace('_', '-')}", str(value)]
    return out


def _launch(args, opts) -> int:
    """Check what can be checked once, then run N worker processes under torchrun (standalone)."""
    from policies.run import precheck

    precheck(opts)
    cmd = [
        sys.executable,
        "-m",
        "torch.distributed.run",
        "--standalone",
        f"--nproc_per_node={args.nproc}",
        "-m",
        "factr2_teleop.cli",
    ] + _argv(args)
    env = dict(os.environ, OMP_NUM_THREADS=str(max(1, (os.cpu_count() or 1) // args.nproc)))
    rc = subprocess.call(cmd, env=env)
    return 0 if rc == 0 else 2


def run(args) -> int:
    opts = _options(args)  # bad values fail here, before any process starts
    if args.nproc < 1:
        raise UserError(f"--nproc must be >= 1, got {args.nproc}")
    if args.nproc > 1 and "RANK" not in os.environ:
        return _launch(args, opts)
    from policies.run import run_training
    from policies.train import setup_distributed

    d = setup_distributed()
    try:
        metrics = run_training(opts, d)
    finally:
        if d.world > 1:
            import torch.distributed as dist

            dist.destroy_process_group()
    if d.main:
        shown = ", ".join(f"{k} {v:.4g}" for k, v in metrics.items())
        print(
            f"done: {args.out}/checkpoints (last), curves {args.out}/curves.png, "
            f"TensorBoard {args.out}/tensorboard"
            + (f"; {shown}" if shown else "")
        )
    return 0
