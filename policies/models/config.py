"""One config dataclass for both policies (ACT, flow-matching DiT), with the paper's and a CPU-sized preset.

Paper (appendix, policy table): ACT 4 encoder / 6 decoder layers, flow 6 decoder layers; 8 heads, hidden 768,
FF 3072, dropout 0.1, sinusoidal positions, chunk 30; flow: 10 Euler steps, time ~ Beta(1, 1.5). The paper's
image encoder is DINOv3-Base, whose weights cannot be fetched here: both presets default to a ResNet-18 with
GroupNorm trained from scratch (policies.models.vision), 224 px for `paper`, 96 px for `small` (there up to
layer3). The flow model has no observation transformer: its observation tokens (backbone cells, state and
force MLP tokens) are the cross-attention memory of its decoder blocks directly (enc_layers is ACT's).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields, replace

PRESETS = ("state", "small", "paper")


# a field the run fills itself (from the data, --policy, --obs or --method): not settable with `--set`
FILLED = {"filled": True}


@dataclass
class PolicyConfig:
    policy: str = field(default="flow", metadata=FILLED)  # "flow" (DiT, velocity objective) or "act" (CVAE)
    head: str = "dit"  # flow: "dit" (transformer over the chunk) or "mlp" (models/flow_mlp.py, state only)
    # transformer
    hidden: int = 768
    heads: int = 8
    enc_layers: int = 4  # ACT: observation encoder and CVAE encoder layers (the flow model has none)
    dec_layers: int = 6
    ff: int = 3072
    dropout: float = 0.1
    chunk: int = 30  # actions predicted per observation
    # inputs / outputs (filled from the data)
    # "images", "state" (PRIVILEGED twin object vector, no frames) or both
    observation: str = field(default="images", metadata=FILLED)
    # length of the privileged object vector (policies/data/privileged.py); 0: none
    objects_dim: int = field(default=0, metadata=FILLED)
    n_cameras: int = field(default=1, metadata=FILLED)
    image_size: int = 224  # square input [px], frames are cached at this size
    state_dim: int = field(default=7, metadata=FILLED)  # follower joints + gripper
    force_dim: int = field(default=6, metadata=FILLED)  # tau_ext (or current) per joint; 0: no force token
    action_dim: int = field(default=7, metadata=FILLED)
    aux_force: bool = field(default=False, metadata=FILLED)  # TA-VLA (--method tavla): the force chunk too
    # vision
    backbone: str = "resnet18-gn"  # or "torchvision:NAME" / "timm:NAME" (weights from a local file only)
    backbone_weights: str = ""  # local file (.safetensors / .pt state dict), "" = from scratch
    # ACT
    latent_dim: int = 32
    kl_weight: float = 10.0
    # flow matching
    flow_steps: int = 10
    time_beta_a: float = 1.0
    time_beta_b: float = 1.5
    aux_weight: float = 1.0  # TA-VLA auxiliary loss weight

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> PolicyConfig:
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in known})


def settable() -> dict[str, type]:
    """The fields `--set FIELD=VALUE` (and a resumed run's overrides) may set, with their types: all but those
    the run fills itself (FILLED)."""
    base = PolicyConfig()
    return {f.name: type(getattr(base, f.name)) for f in fields(PolicyConfig) if not f.metadata.get("filled")}


def preset(name: str, policy: str = "flow") -> PolicyConfig:
    """The `paper` sizes; `small`: sized for a laptop CPU, a flow chunk (encode once + 10 Euler steps) in
    <= 30 ms on one core with 2 cameras (docs/benchmarks.md): hidden 256, FF 512 (2x, not 4x), 4 heads, ACT
    2 + 3 layers, flow 2; 96 px through the ResNet-18 GN up to layer3 (policies.models.vision.ResNet18GN: its
    fourth stage would see a 3 x 3 map). With 3 flow layers and the whole ResNet-18 a chunk took 47 ms: 17.7
    ms of backbone, 10 x 2.3 ms of velocity steps (docs/policies.md: why, and the training comparison).
    `state`: for low-dimensional observations (`--obs state`), no images: the flow policy's velocity field is
    a residual MLP over the flattened chunk (policies.models.flow_mlp), 128-wide observation tokens, a
    512-wide stream, 3 FiLM blocks, no dropout (EMA weights smooth instead): 1500 samples/s on one core at
    batch 64, 3800 at batch 256, against 180 for `small`'s DiT on the same input (docs/first_training.md)."""
    if name not in PRESETS:
        raise ValueError(f"preset {name!r}: one of {', '.join(PRESETS)}")
    cfg = PolicyConfig(policy=policy)  # an unregistered policy is refused by models/policy.py make_policy
    if name == "small":
        layers = 2 if policy == "flow" else 3  # flow: DiT blocks, run 10x per chunk; ACT: decoder layers
        cfg = replace(cfg, hidden=256, heads=4, enc_layers=2, dec_layers=layers, ff=512, image_size=96,
                      backbone="resnet18-gn-l3")
    elif name == "state":
        if policy == "flow":
            cfg = replace(cfg, head="mlp", hidden=128, ff=512, dec_layers=3, dropout=0.0, observation="state")
        else:  # ACT keeps its transformer, at the width of the flow head's tokens
            cfg = replace(cfg, hidden=128, heads=4, enc_layers=2, dec_layers=3, ff=512, observation="state")
    return cfg


def default_preset(observation: str) -> str:
    """The preset `factr2 train` uses when none is named: `state` for an observation without images (state
    or perceived), else `small` (images on a CPU; `paper` on a GPU is the user's choice)."""
    from policies.data.privileged import low_dimensional

    return "state" if low_dimensional(observation) else "small"
