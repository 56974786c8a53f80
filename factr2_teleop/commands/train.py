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

HELP = "train a FIRST / ACT / flow-matching policy on recorded episodes (one or many processes)"


def add_arguments(p) -> None:
    from policies.training.run_config import add_arguments

    add_arguments(p)  # one flag per field of policies.training.run_config.RunOptions


def _launch(opts) -> int:
    """Check what can be checked once, then run N worker processes under torchrun (standalone), each given
    these options as flags (policies.training.run_config.to_argv)."""
    from policies.training.run import precheck
    from policies.training.run_config import to_argv

    precheck(opts)
    cmd = [
        sys.executable,
        "-m",
        "torch.distributed.run",
        "--standalone",
        f"--nproc_per_node={opts.nproc}",
        "-m",
        "factr2_teleop.cli",
        "train",
    ] + to_argv(opts)
    env = dict(os.environ, OMP_NUM_THREADS=str(max(1, (os.cpu_count() or 1) // opts.nproc)))
    rc = subprocess.call(cmd, env=env)
    return 0 if rc == 0 else 2


def run(args) -> int:
    from policies.training.run_config import from_args

    opts = from_args(args)  # bad values fail here (UserError), before any process starts
    if opts.nproc > 1 and "RANK" not in os.environ:
        return _launch(opts)
    from policies.training.run import run_training
    from policies.training.train import setup_distributed

    d = setup_distributed()
    try:
        metrics = run_training(opts, d)
    finally:
        if d.world > 1:
            import torch.distributed as dist

            dist.destroy_process_group()
    if d.main:
        from policies.training.checkpoint import kept_checkpoint

        shown = ", ".join(f"{k} {v:.4g}" for k, v in metrics.items())
        kept = kept_checkpoint(opts.out)  # --keep val-min: what rollouts load is not the last
        which = f"{kept.stem} kept: the lowest validation loss" if kept and kept.stem.startswith("valmin") \
            else "last"
        print(
            f"done: {opts.out}/checkpoints ({which}), curves {opts.out}/curves.png, "
            f"TensorBoard {opts.out}/tensorboard"
            + (f"; {shown}" if shown else "")
        )
        from policies.training.advice import run_advice

        for line in run_advice(opts.out):  # what more data or training would buy, from the run's own curve
            print(line)
    return 0
