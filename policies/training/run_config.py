"""The training configuration, in one place (nanoGPT style): RunOptions, what a run learns from and how big
its model is, with its TrainConfig, the optimiser and the schedule. Every other form of it is generated from
these fields' metadata (policies.training.flags.option):

- `factr2 train`'s flags, their help, choices, units and bounds (add_arguments), and the options parsed back
  (from_args);
- the torchrun relaunch's argv (to_argv: parsed back, the same options);
- what `--resume` requires to be unchanged (RESUME_KEYS: each field names the meta entry that checks it);
- the checkpoint meta's configuration entries (to_meta) and the options read back from a run's meta
  (from_meta: older runs' meta too), which the terminal app resumes with;
- the terminal app's choices (form_choices).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

from hardware.errors import UserError
from policies.data.dataset import FORCE_SOURCES
from policies.data.perturbed import DEFAULT_PERTURBED, PERTURBED_MODES
from policies.data.preprocess import ACTION_FRAMES
from policies.data.privileged import OBSERVATIONS, low_dimensional
from policies.data.sampler import DEFAULT_SOURCE_WEIGHTS
from policies.labels.label_flags import NEXT_HELP
from policies.labels.labelling import LabelChoice, ThresholdSource, source_kind
from policies.models.config import PRESETS, PolicyConfig, default_preset, preset, settable
from policies.models.policy import policy_names
from policies.training import flags as F
from policies.training.flag_kinds import (
    EpisodesFlag,
    ObsNoiseFlag,
    OverridesFlag,
    RatioFlag,
    SourceWeightsFlag,
    ThresholdsFlag,
)
from policies.training.flags import Flag, Switch, option
from policies.training.methods import METHODS
from policies.training.regularise import KEEP_CHOICES

# the state preset's defaults: the learning curve (docs/first_training.md) still
# rose at 8000 steps x 256 on 47 peg-insert demonstrations (~82 passes); images keep 20 passes at 128
STATE_EPOCHS, STATE_BATCH = 80.0, 256


def default_length(observation: str) -> tuple[float, int]:
    """(epochs, batch) of a run that names neither: from the learning curve for a state observation."""
    return (STATE_EPOCHS, STATE_BATCH) if low_dimensional(observation) else (20.0, 128)


def _train(name: str, **kw):
    """A TrainConfig field that must match on --resume (its meta entry train.NAME)."""
    return option(resume=f"train.{name}", **kw)


@dataclass
class TrainConfig:
    """The optimiser and the schedule (policies.training.train's loop)."""

    steps: int = _train("steps", default=0, flag=Flag(  # 0: from epochs
        "--steps", "optimiser steps", type=int, optional=True, at_least=1, group="length"))
    epochs: float = _train("epochs", default=20.0, flag=Flag(  # draws per epoch = training samples
        "--epochs", "passes over the training samples (default 80 with --obs state, else 20)", type=float,
        optional=True, above=0, group="length"))
    batch: int = _train("batch", default=128, flag=Flag(  # global batch (all ranks together)
        "--batch", "default 256 with --obs state, else 128", type=int, optional=True, at_least=1))
    lr: float = _train("lr", default=3e-4, flag=Flag("--lr", "peak learning rate (AdamW)", type=float))
    weight_decay: float = _train("weight_decay", default=0.05, flag=Flag(
        "--weight-decay", "AdamW weight decay of the weight matrices", type=float))
    betas: tuple[float, float] = _train("betas", default=(0.9, 0.95))
    warmup: int = _train("warmup", default=500, flag=Flag(
        "--warmup", "linear warm-up of the learning rate", type=int, unit="steps"))
    grad_clip: float = _train("grad_clip", default=1.0)
    # the matmuls' precision (policies.training.train.pick_precision): auto = bf16 autocast where the hardware
    # has it
    precision: str = _train("precision", default="auto", flag=Flag(
        "--precision", "bf16 autocast or fp32 (auto: bf16 on a GPU or a CPU with native bf16)",
        choices=("auto", "bf16", "fp32")))
    val_every: int = option(500, flag=Flag("--val-every", "steps between validations", type=int, at_least=1))
    ckpt_every: int = option(1000, flag=Flag("--ckpt-every", "steps between checkpoints", type=int,
                                             at_least=1))
    log_every: int = option(10, flag=Flag("--log-every", "steps between logged training losses", type=int,
                                          at_least=1))
    val_max: int = 1024  # validation samples per evaluation (evenly spaced over the validation episodes)
    seed: int = _train("seed", default=0, flag=Flag("--seed", "seed of the weights, batches and noise",
                                                    type=int))
    # torch threads per process (0: chosen from the free cores, policies.training.train_threads.pick_threads)
    threads: int = option(0, flag=Flag("--threads", "torch threads per process (default: cores / nproc)",
                                       type=int))
    # keep an exponential moving average of the weights (ema_power, ema_max): validation and rollouts use it
    ema: bool = _train("ema", default=True, flag=Switch(
        "--no-ema", "evaluate and roll out the trained weights, no moving average of them"))
    # issue #56's levers, off by default (policies/training/regularise.py)
    obs_noise: dict | None = _train("obs_noise", default=None, flag=ObsNoiseFlag(
        "--obs-noise", "Gaussian noise added to these low-dimensional inputs in training only (not "
        "validation, not rollouts), sigma in each input's standard deviations over the training data "
        "(state: joints and grippers, force, objects: the PRIVILEGED or perceived vector)",
        metavar="NAME=SIGMA,...", unit="normalised units"))
    keep: str = _train("keep", default="last", flag=Flag(
        "--keep", "the checkpoint rollouts load from RUN: last (default), or val-min: the evaluated weights "
        "at the lowest validation loss (RUN/checkpoints/kept names it; --resume continues from the last)",
        choices=KEEP_CHOICES))
    ema_power: float = 0.75  # EMA decay at step s: min(ema_max, 1 - (1 + s) ** -ema_power) (Diffusion Policy)
    ema_max: float = 0.9999
    keep_checkpoints: int = 2  # periodic checkpoints kept (the final one always stays); 0: every one

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> TrainConfig:
        """From a run's meta["train"] (older runs' extra entries, e.g. method, ratio, force, left out)."""
        known = {f.name for f in fields(cls)}
        kw = {k: v for k, v in d.items() if k in known}
        if "betas" in kw:
            kw["betas"] = tuple(kw["betas"])
        return cls(**kw)


@dataclass
class RunOptions:
    """One training run: its data, method, model and schedule (the `resume` of each field:
    policies.training.flags)."""

    inputs: list = option(resume="data_hash", flag=Flag("inputs", type=Path, metavar="RECORDING_OR_DIR"))
    out: Path = option(flag=Flag("--out", "run folder (checkpoints, logs)", type=Path, metavar="RUN",
                                 required=True))
    policy: str = option("flow", resume="policy", flag=Flag(
        "--policy", "the policy (policies.models.policy registers them)", choices=policy_names()))
    method: str = option("first", resume="method", flag=Flag(
        "--method", "first (default), base, base-torque, factr, tavla", choices=tuple(METHODS)))
    ratio: tuple | None = option(None, resume="ratio", flag=RatioFlag(  # None: the method's default
        "--ratio", f"re-sampling weights w_F:w_PC:w_C or a preset ({', '.join(RatioFlag.presets)}); "
        "default 1:5:1 for first, uniform otherwise", metavar="F:PC:C"))
    source_weights: tuple | None = option(None, resume="ratio", flag=SourceWeightsFlag(
        "--source-weights", "rollout recordings with interventions (factr2 rollout --takeover --record): "
        "sampling weight per source, multiplied with the phase ratio (default demo=1,policy=1,pre=0.25,"
        "operator=2; pre: the seconds of policy control before each takeover)", metavar="NAME=W,..."))
    preset: str = option("", resume="policy", flag=Flag(  # "": models/config.py default_preset(observation)
        "--preset", "state (low-dimensional inputs, the default with --obs state), small (images on a CPU, "
        "the default otherwise) or paper (the paper's sizes)", choices=PRESETS))
    force: str = option("tau_ext", resume="force", flag=Flag(
        "--force", "force input: NEXT tau_ext (default) or raw motor current",
        choices=tuple(f for f in FORCE_SOURCES if f != "none")))
    next: Path | None = option(None, resume="phases", flag=Flag("--next", NEXT_HELP, type=Path,
                                                                metavar="CKPT"))
    thresholds: object = option(None, resume="phases", flag=ThresholdsFlag("--thresholds"))
    lerobot_map: str = option("", resume="data_hash", flag=Flag(
        "--lerobot-map", "LeRobotDataset inputs: ROLE=KEY,... over the default feature names (state, "
        "action, velocity, effort, current, tau_ext; KEY none drops one; angles=deg; docs/bringing_data.md)",
        metavar="ROLE=KEY,..."))
    rate_hz: float | None = option(None, resume="rate_hz", flag=Flag(
        "--rate", "policy rate (default: the camera rate)", type=float, unit="Hz"))
    resume: bool = option(False, flag=Switch("--resume",
                                             "continue the run in --out from its last checkpoint"))
    backbone: str = option("", resume="policy", flag=Flag(  # "": the preset's
        "--backbone", "resnet18-gn, resnet18-gn-l3 (up to layer3), convnet-gn (small, fast), "
        "torchvision:NAME or timm:NAME (default: the preset's, small resnet18-gn-l3, paper resnet18-gn)"))
    backbone_weights: str = option("", resume="policy", flag=Flag(
        "--backbone-weights", "local weights for the backbone", metavar="FILE"))
    dropout: float | None = option(None, resume="policy", flag=Flag(
        "--dropout", "dropout (default: the preset's)", type=float))
    image_size: int | None = option(None, resume="policy", flag=Flag(
        "--image-size", "input size (default: the preset's)", type=int, unit="px"))
    val_fraction: float = 0.1
    progress: bool = option(True, flag=Switch("--no-progress", "no progress bar"))
    train: TrainConfig = option(factory=TrainConfig, nested=TrainConfig)
    overrides: dict | None = option(None, resume="policy", flag=OverridesFlag(  # over the preset
        "--set", "override a policy config field of the preset (policies/models/config.py), e.g. "
        "--set hidden=128"))
    observation: str = option("images", resume="observation", flag=Flag(
        "--obs", "what the policy sees besides joints and force: camera frames (default), or `state`: the "
        "twin task objects' poses, PRIVILEGED and SIMULATED (recorded by `factr2 collect`; no frames read), "
        "or `perceived`: those poses as a simulated camera pose detector reports them (bias, noise, latency, "
        "occlusion; SIMULATED, docs/perception.md), or `joints`: nothing besides (a blind policy, any rig)",
        choices=OBSERVATIONS))
    actions: str = option("absolute", resume="actions", flag=Flag(
        "--actions", "the frame the policy learns its joint targets in: absolute (default) or relative to "
        "the "
        "joints at each observation (grippers absolute; policies.data.preprocess.Preprocess)",
        choices=ACTION_FRAMES))
    perturbed: str = option(DEFAULT_PERTURBED, resume="perturbed", flag=Flag(
        "--perturbed", "a perturbed collection's ticks (factr2 collect --perturb): dart (default) learns the "
        "operator's target, the offset taken off, from the states the perturbation led to; skip masks the "
        "perturbed ticks' actions out of the loss (policies/data/perturbed.py)", choices=PERTURBED_MODES))
    episodes: tuple | None = option(None, resume="data_hash", flag=EpisodesFlag(  # None: every usable one
        "--episodes", "train on these episodes only: FILE.mcap#N or FILE.mcap#N-M (inclusive), "
        "comma-separated (`factr2 episodes list` names them)", metavar="FILE#N-M,..."))
    include_failed: bool = option(False, resume="data_hash", flag=Switch(
        "--include-failed",
        "train on failed demonstrations too (default: they are skipped, counted in one line)"))
    keep_incomplete: bool = option(False, resume="data_hash", flag=Switch(
        "--keep-incomplete", "train on episodes cut off by a killed recorder too (default: skipped)"))
    nproc: int = option(1, flag=Flag("--nproc", "processes on this machine (DDP; gloo on CPU)", type=int,
                                     at_least=1, relaunch=False))

    def resolved(self) -> RunOptions:
        """These options with each "the default" spelled out as the run uses it: the method's ratio, force
        "none" for a method without a force input, the observation's preset, and the model fields the preset
        fills (backbone, dropout, image size; the overrides that change something)."""
        m = METHODS[self.method]
        name = self.preset or default_preset(self.observation)
        base = _preset(name, self.policy, self.observation)
        ov = dict(self.overrides or {})
        own = {"backbone": ov.pop("backbone", self.backbone or base.backbone),
               "backbone_weights": ov.pop("backbone_weights", self.backbone_weights),
               "dropout": ov.pop("dropout", base.dropout if self.dropout is None else self.dropout),
               "image_size": ov.pop("image_size",
                                    int(self.image_size) if self.image_size else base.image_size)}
        ov = {k: v for k, v in ov.items() if v != getattr(base, k)}
        return replace(self, ratio=tuple(self.ratio) if self.ratio is not None else m.ratio,
                       source_weights=tuple(self.source_weights or DEFAULT_SOURCE_WEIGHTS),
                       force=self.force if m.force else "none", preset=name, overrides=ov or None, **own)

    def policy_config(self) -> PolicyConfig:
        """The model's config before the data fills its input and output sizes: the preset, then the flags,
        then the overrides; the observation and the method's auxiliary force head."""
        r = self.resolved()
        pcfg = replace(_preset(r.preset, r.policy, r.observation), backbone=r.backbone,
                       backbone_weights=r.backbone_weights, dropout=r.dropout, image_size=r.image_size)
        return replace(pcfg, **(r.overrides or {}), observation=r.observation,
                       aux_force=METHODS[r.method].aux_force)

    def to_meta(self, pcfg: PolicyConfig | None = None) -> dict:
        """The checkpoint meta's configuration entries (pcfg: the model's, sizes filled from the data)."""
        r = self.resolved()
        return {"policy": (pcfg or self.policy_config()).to_dict(), "preset": r.preset, "method": r.method,
                "ratio": list(r.ratio), "source_weights": list(r.source_weights), "force": r.force,
                "observation": r.observation,
                "include_failed": r.include_failed, "keep_incomplete": r.keep_incomplete,
                "rate_hz": r.rate_hz, "train": r.train.to_dict(), "actions": r.actions,
                "perturbed": r.perturbed}

    @classmethod
    def from_meta(cls, meta: dict, inputs: list, out: Path, **kw) -> RunOptions:
        """The resolved options of the run whose checkpoint meta this is, on recordings `inputs`; kw: fields
        to set (resume, progress, ...). Older runs' meta: no preset (then all `small`), no observation
        (images), no outcome filter (every outcome trained)."""
        pol = meta["policy"]
        name = meta.get("preset", "small")
        observation = meta.get("observation", "images")
        base = _preset(name, pol["policy"], observation)
        own = {k: pol.get(k, getattr(base, k))
               for k in ("backbone", "backbone_weights", "dropout", "image_size")}
        kinds = settable()
        ov = {k: v for k, v in pol.items() if k in kinds and k not in own and v != getattr(base, k)}
        ph = meta.get("phases", {})
        kind = source_kind(ph)  # typed (policies.labels.labelling.ThresholdSource), never the message parsed
        given = ((ph["t_low"], ph["t_high"]) if kind is ThresholdSource.GIVEN
                 else "recording" if kind in (ThresholdSource.RECORDING, ThresholdSource.DATASET) else None)
        opts = cls(inputs=list(inputs), out=Path(out), policy=pol["policy"], method=meta["method"],
                   ratio=tuple(meta["ratio"]), preset=name, force=meta["force"],
                   source_weights=tuple(meta.get("source_weights", DEFAULT_SOURCE_WEIGHTS)),
                   thresholds=LabelChoice(given, ph.get("tare", "off"), ph.get("score", "l1")),
                   rate_hz=meta.get("rate_hz"),
                   train=TrainConfig.from_dict(meta["train"]), overrides=ov or None, observation=observation,
                   actions=meta.get("actions", "absolute"),
                   perturbed=meta.get("perturbed", DEFAULT_PERTURBED),
                   episodes=tuple(meta["episodes"]) if "episodes" in meta else None,
                   include_failed=bool(meta.get("include_failed", True)),
                   keep_incomplete=bool(meta.get("keep_incomplete", True)), **own)
        return replace(opts, **kw)


def _preset(name: str, policy: str, observation: str) -> PolicyConfig:
    if name == "state" and not low_dimensional(observation):
        raise UserError(f"preset state takes no images, the observation is {observation}",
                        where="--preset state",
                        fix="train with --obs state or perceived, or --preset small|paper")
    if policy not in policy_names():
        raise UserError(f"unknown policy {policy!r}", where="--policy",
                        fix=f"one of {', '.join(policy_names())}")
    return preset(name, policy)


RESUME_KEYS = tuple(F.resume_keys(RunOptions))  # meta entries that must be unchanged for --resume


def add_arguments(p) -> None:
    """`factr2 train`'s flags, one per field (policies.training.flags)."""
    F.add_arguments(p, RunOptions)


def from_args(ns) -> RunOptions:
    """The options of parsed flags; epochs and batch not given: the observation's (default_length)."""
    o = F.from_args(RunOptions, ns)
    epochs, batch = default_length(o.observation)
    return replace(o, train=replace(o.train, epochs=o.train.epochs if F.given(ns, "train.epochs") else epochs,
                                    batch=o.train.batch if F.given(ns, "train.batch") else batch))


def to_argv(o: RunOptions) -> list[str]:
    """The flags that give `o` back through from_args (less --nproc: for the processes torchrun starts)."""
    return F.to_argv(o)


def form_choices() -> dict[str, tuple]:
    """The choices of the fields the terminal app's Train screen cycles through (its form), by field name:
    the flags' choices; the ratio's "default" (the method's own, None) then its presets."""
    flag = {f.name: f.metadata.get("flag") for f in fields(RunOptions)}
    out = {name: tuple(flag[name].choices) for name in ("policy", "method", "observation")}
    return out | {"ratio": ("default", *flag["ratio"].presets)}
