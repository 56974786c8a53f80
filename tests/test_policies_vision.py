"""The image encoder's layer3 variant (the small preset's) and the flow policy's inference path: the same
values as the plain computations they replace."""

from __future__ import annotations

import torch
import torch.nn.functional as F

from policies.models.config import PolicyConfig, preset
from policies.models.flow import FlowPolicy
from policies.models.vision import ResNet18GN, load_weights_file, make_backbone


def test_layer3_variant_is_the_first_three_stages_and_loads_full_weights(tmp_path):
    from safetensors.torch import save_file

    torch.manual_seed(0)
    full = ResNet18GN().eval()
    path = tmp_path / "r18.safetensors"
    save_file({k: v.contiguous() for k, v in full.state_dict().items()}, str(path))
    l3 = make_backbone("resnet18-gn-l3").eval()
    missing, unexpected = load_weights_file(l3, path)
    assert l3.out_channels == 256 and not missing
    assert unexpected and all(k.startswith("layer4") for k in unexpected)
    x = torch.randn(2, 3, 96, 96)
    with torch.no_grad():
        stem = F.max_pool2d(full.relu(full.bn1(full.conv1(x))), 3, 2, 1)  # NCHW pooling, the plain way
        expect = full.layer3(full.layer2(full.layer1(stem)))
        got = l3(x)
        assert got.shape == (2, 256, 6, 6)  # 36 tokens per camera at 96 px
        torch.testing.assert_close(got, expect, rtol=0, atol=1e-5)
        assert full(x).shape == (2, 512, 3, 3)


def test_small_preset_sizes():
    flow, act = preset("small", "flow"), preset("small", "act")
    assert (flow.hidden, flow.ff, flow.dec_layers, flow.image_size) == (256, 512, 2, 96)
    assert (act.enc_layers, act.dec_layers) == (2, 3) and flow.backbone == act.backbone == "resnet18-gn-l3"
    assert preset("paper", "flow").backbone == "resnet18-gn"


def test_flow_predict_is_plain_euler_on_the_velocity_field():
    """predict (observation encoded once, the Euler times' conditioning in one batched pass) equals Euler
    steps that condition on each time afresh, as training does."""
    cfg = PolicyConfig(hidden=32, heads=2, dec_layers=2, ff=64, backbone="convnet-gn", image_size=32,
                       n_cameras=2, dropout=0.0)
    torch.manual_seed(0)
    model = FlowPolicy(cfg).eval()
    for p in model.parameters():  # adaLN-Zero starts as the identity: give every path a say
        torch.nn.init.normal_(p, std=0.1)
    g = torch.Generator().manual_seed(1)
    batch = {
        "images": torch.randint(0, 256, (3, 2, 32, 32, 3), generator=g, dtype=torch.uint8),
        "state": torch.randn(3, cfg.state_dim, generator=g),
        "force": torch.randn(3, cfg.force_dim, generator=g),
    }
    noise = FlowPolicy.draw_noise(cfg, 3, g)
    with torch.no_grad():
        memory, x, n = model.encode(batch), noise["x0"].clone(), cfg.flow_steps
        for k in range(n):
            x = x + model.velocity(x, torch.full((3,), k / n), memory)[0] / n
        torch.testing.assert_close(model.predict(batch, noise), x, rtol=0, atol=1e-5)
