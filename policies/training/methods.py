"""The paper's methods (Sec. 5 baselines), one code path and one flag:

    base         no force input, uniform sampling
    base-torque  tau_ext token, uniform sampling
    first        tau_ext token + FIRST re-sampling (default ratio 1:5:1)
    factr        tau_ext token + Gaussian blur curriculum on the images (FACTR): sigma_n = sigma_0 (1 - n/N),
                 the paper's plain linear schedule (FACTR's own code holds sigma_0 for 2/3 of the run first)
    tavla        tau_ext token + the future tau_ext chunk as an auxiliary prediction target (TA-VLA)

`--force current` swaps the force input for the raw motor current (the paper's current-vs-tau_ext study);
`--ratio` re-samples any method (FIRST without force input: `--method base --ratio 1:5:1`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from policies.data.sampler import DEFAULT_RATIO, RATIO_PRESETS

BLUR_SIGMA0_PX_224 = 5.0  # FACTR's starting blur [px] at 224 px; scaled with the input size


@dataclass(frozen=True)
class Method:
    name: str
    force: bool  # a force token
    ratio: tuple[float, float, float]  # default w_F : w_PC : w_C
    blur: bool = False
    aux_force: bool = False


METHODS = {
    "base": Method("base", False, RATIO_PRESETS["uniform"]),
    "base-torque": Method("base-torque", True, RATIO_PRESETS["uniform"]),
    "first": Method("first", True, DEFAULT_RATIO),
    "factr": Method("factr", True, RATIO_PRESETS["uniform"], blur=True),
    "tavla": Method("tavla", True, RATIO_PRESETS["uniform"], aux_force=True),
}


def blur_sigma(step: int, total: int, sigma0: float) -> float:
    """sigma_n = sigma_0 (1 - n / N) [px]."""
    return max(0.0, sigma0 * (1.0 - step / max(total, 1)))


def gaussian_blur(img: torch.Tensor, sigma: float) -> torch.Tensor:
    """Depthwise Gaussian blur of img (..., 3, H, W), kernel 2 ceil(3 sigma) + 1 (reflect padding);
    identity below 0.1 px."""
    if sigma < 0.1:
        return img
    r = int(math.ceil(3 * sigma))
    r = min(r, img.shape[-1] // 2 - 1, img.shape[-2] // 2 - 1)
    x = torch.arange(-r, r + 1, dtype=img.dtype, device=img.device)
    k = torch.exp(-0.5 * (x / sigma) ** 2)
    k = k / k.sum()
    shape = img.shape
    flat = img.reshape(-1, 1, shape[-2], shape[-1])
    flat = F.conv2d(F.pad(flat, (r, r, 0, 0), mode="reflect"), k.view(1, 1, 1, -1))
    flat = F.conv2d(F.pad(flat, (0, 0, r, r), mode="reflect"), k.view(1, 1, -1, 1))
    return flat.reshape(shape)
