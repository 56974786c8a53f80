"""Image encoders: a ResNet-18 with GroupNorm (default, from scratch), or any torchvision/timm backbone, with
weights only from a local file the user names (nothing is fetched at run time).

The ResNet-18 is written here rather than taken from torchvision: torchvision's PyPI wheels are built against
CUDA torch and do not import next to the CPU torch this project installs. Parameter names follow
torchvision's resnet18 (conv1, bn1, layer1.0.conv1, ...), so a torchvision ResNet-18 state dict file loads
into it (BatchNorm running statistics are dropped: GroupNorm has none). Output: a feature map (B, C, h, w);
the policy turns each cell into a token.
"""

from __future__ import annotations

from pathlib import Path

import torch
import torch.nn as nn

from hardware.errors import UserError

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


def _gn(c: int) -> nn.GroupNorm:
    return nn.GroupNorm(min(32, c // 4), c)  # 16 groups at 64 channels, 32 from 128 on


class BasicBlock(nn.Module):
    def __init__(self, cin: int, cout: int, stride: int):
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride, 1, bias=False)
        self.bn1 = _gn(cout)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1, bias=False)
        self.bn2 = _gn(cout)
        self.relu = nn.ReLU(inplace=True)
        self.downsample = None
        if stride != 1 or cin != cout:
            self.downsample = nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False), _gn(cout))

    def forward(self, x):
        y = self.relu(self.bn1(self.conv1(x)))
        y = self.bn2(self.conv2(y))
        return self.relu(y + (x if self.downsample is None else self.downsample(x)))


class ResNet18GN(nn.Module):
    """ResNet-18 with GroupNorm, torchvision's layout and names. stages = 3 stops after layer3 (256 channels,
    1/16 of the input): at the small preset's 96 px the fourth stage works on a 3 x 3 map, where most of its
    3 x 3 taps read padding, yet holds 8.4 M of the 11.2 M weights (34 MB to stream per chunk at batch 1);
    layer3's 6 x 6 map gives 36 tokens per camera instead of 9."""

    def __init__(self, stages: int = 4):
        super().__init__()
        self.conv1 = nn.Conv2d(3, 64, 7, 2, 3, bias=False)
        self.bn1 = _gn(64)
        self.relu = nn.ReLU(inplace=True)
        self.maxpool = nn.MaxPool2d(3, 2, 1)
        chans = [64, 64, 128, 256, 512]
        self.stages = stages
        self.out_channels = chans[stages]
        for i in range(stages):
            stride = 1 if i == 0 else 2
            setattr(
                self,
                f"layer{i + 1}",
                nn.Sequential(
                    BasicBlock(chans[i], chans[i + 1], stride), BasicBlock(chans[i + 1], chans[i + 1], 1)
                ),
            )

    def forward(self, x):
        x = self.relu(self.bn1(self.conv1(x)))
        if x.device.type == "cpu":
            # CPU max pooling is ~15x faster channels-last (0.15 vs 2.3 ms on 2 x 64 x 48 x 48, one core);
            # the convolutions are faster in NCHW, so only the pooling changes layout (same values)
            x = self.maxpool(x.contiguous(memory_format=torch.channels_last)).contiguous()
        else:
            x = self.maxpool(x)
        for i in range(self.stages):
            x = getattr(self, f"layer{i + 1}")(x)
        return x


class ConvNetGN(nn.Module):
    """A small encoder for quick CPU experiments and tests: four stride-2 3x3 conv + GroupNorm + ReLU stages
    (32, 64, 128, 128 channels), feature map at 1/16 of the input."""

    out_channels = 128

    def __init__(self):
        super().__init__()
        chans, layers = [3, 32, 64, 128, 128], []
        for cin, cout in zip(chans[:-1], chans[1:]):
            layers += [nn.Conv2d(cin, cout, 3, 2, 1, bias=False), _gn(cout), nn.ReLU(inplace=True)]
        self.body = nn.Sequential(*layers)

    def forward(self, x):
        return self.body(x)


BACKBONES = {
    "resnet18-gn": ResNet18GN,
    "resnet18-gn-l3": lambda: ResNet18GN(stages=3),  # the small preset's (see ResNet18GN)
    "convnet-gn": ConvNetGN,
}


class _Features(nn.Module):
    """A third-party backbone's last feature map."""

    def __init__(self, body: nn.Module, channels: int):
        super().__init__()
        self.body, self.out_channels = body, channels

    def forward(self, x):
        y = self.body(x)
        return y[-1] if isinstance(y, (list, tuple)) else y


def _third_party(spec: str) -> nn.Module:
    lib, _, name = spec.partition(":")
    if lib not in ("timm", "torchvision") or not name:
        raise UserError(
            f"unknown backbone {spec!r}",
            fix=f"use one of {', '.join(BACKBONES)}, torchvision:NAME or timm:NAME",
        )
    try:
        if lib == "timm":
            import timm

            m = timm.create_model(name, pretrained=False, features_only=True)
            return _Features(m, m.feature_info.channels()[-1])
        import torchvision

        m = getattr(torchvision.models, name)(weights=None)
        body = nn.Sequential(*list(m.children())[:-2])  # drop pooling + classifier
        with torch.no_grad():
            c = body(torch.zeros(1, 3, 64, 64)).shape[1]
        return _Features(body, c)
    except Exception as e:  # import errors, unknown names: one line for the user
        raise UserError(
            f"backbone {spec!r} unavailable ({type(e).__name__}: {str(e)[:80]})",
            fix="use --backbone resnet18-gn, or install a working torchvision/timm",
        ) from None


def load_weights_file(module: nn.Module, path: str | Path) -> tuple[list[str], list[str]]:
    """Load a local state dict (.safetensors, or a torch file holding a state dict) into `module`, matching
    names and shapes; returns (missing, unexpected). Nothing matching is a UserError."""
    p = Path(path)
    if not p.is_file():
        raise UserError("backbone weights file not found", where=str(p), fix="name a local weights file")
    try:
        if p.suffix == ".safetensors":
            from safetensors.torch import load_file

            sd = load_file(str(p))
        else:
            sd = torch.load(str(p), map_location="cpu", weights_only=True)
            sd = sd.get("state_dict", sd) if isinstance(sd, dict) else sd
    except Exception as e:
        raise UserError(
            f"unreadable weights file ({type(e).__name__})",
            where=str(p),
            fix="pass a .safetensors or torch state-dict file",
        ) from None
    own = module.state_dict()
    ok = {k: v for k, v in sd.items() if k in own and tuple(v.shape) == tuple(own[k].shape)}
    if not ok:
        raise UserError(
            "no tensor in the weights file matches the backbone",
            where=str(p),
            fix="use weights of the same architecture as --backbone",
        )
    module.load_state_dict(ok, strict=False)
    return sorted(set(own) - set(ok)), sorted(set(sd) - set(ok))


def make_backbone(spec: str = "resnet18-gn", weights: str = "") -> nn.Module:
    """The image encoder for `spec` with `out_channels`; weights from a local file when named."""
    own = spec in BACKBONES
    m = BACKBONES[spec]() if own else _third_party(spec)
    if weights:
        load_weights_file(m if own else m.body, weights)
    return m
