"""Training: a tiny model overfits, checkpoints round-trip, --resume continues exactly, 2-process gloo DDP
matches one process on the same global batch, TensorBoard logs read back."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from policies.training import checkpoint as C
from policies.training.run import RunOptions, run_training
from policies.training.train import Dist, TrainConfig
from tests.policy_helpers import write_recording

TINY = dict(
    hidden=64, heads=2, enc_layers=1, dec_layers=2, ff=128, backbone="convnet-gn", image_size=32, dropout=0.0
)


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    d = tmp_path_factory.mktemp("rec")
    write_recording(d / "a.mcap", episodes=3, seconds=3.0)
    return d


def _opts(rec, out, policy="act", steps=20, **kw):
    train = dict(
        steps=steps, batch=16, lr=1e-3, warmup=10, log_every=1, val_every=1000, ckpt_every=1000, threads=1
    )
    train.update(kw.pop("train", {}))
    return RunOptions(
        inputs=[rec],
        out=out,
        policy=policy,
        thresholds=(1.0, 3.0),
        progress=False,
        overrides=dict(TINY),
        train=TrainConfig(**train),
        **kw,
    )


def _series(run, key):
    return [r[key] for r in map(json.loads, (run / "metrics.jsonl").read_text().splitlines()) if key in r]


def _losses(run):
    return _series(run, "train/loss")


@pytest.mark.parametrize("policy,steps", [("act", 100), ("flow", 150)])
def test_tiny_model_overfits_a_few_episodes(tmp_path, policy, steps):
    """The imitation term (ACT: L1 of the chunk; flow: the velocity MSE) falls 10x on one 3 s episode (30
    samples): more steps on fewer samples and a higher lr than the other tests. ACT's total loss is not
    used: its KL term starts at ~60 and collapses by itself (measured: action term 18x; flow 24x at 150
    steps, 50x at 200)."""
    torch.set_num_threads(1)
    write_recording(tmp_path / "rec" / "a.mcap", episodes=1, seconds=3.0)
    run = tmp_path / "run"
    run_training(
        _opts(tmp_path / "rec", run, policy, steps=steps, val_fraction=0.0, train=dict(lr=2e-3)), Dist()
    )
    loss = _series(run, "train/action")
    first, last = np.mean(loss[:3]), np.mean(loss[-10:])
    assert len(loss) == steps and first / last > 10, (first, last)


def test_checkpoint_round_trip_and_tensorboard(recordings, tmp_path):
    torch.set_num_threads(1)
    run = tmp_path / "run"
    run_training(_opts(recordings, run, "flow", steps=6, train={"val_every": 3}), Dist())
    model, meta, pre = C.load_policy(run)
    assert meta["step"] == 6 and meta["final"] and meta["method"] == "first" and meta["ratio"] == [1, 5, 1]
    assert meta["features"]["action"] == ["action.joint.pos", "action.gripper.pos"]
    assert meta["phases"]["t_high"] == 3.0 and len(meta["data_hash"]) == 16
    assert set(pre.norm.mean) == {"state", "action", "force"}
    from safetensors.torch import load_file

    assert meta["weights_used"] == "ema"  # the moving average is what rollouts get by default
    saved = load_file(str(run / "checkpoints" / meta["weights_ema"]))
    for k, v in model.state_dict().items():
        assert torch.equal(saved[k], v), k
    trained, meta_t, _ = C.load_policy(run, ema=False)
    saved = load_file(str(run / "checkpoints" / meta_t["weights"]))
    assert meta_t["weights_used"] == "trained"
    assert all(torch.equal(saved[k], v) for k, v in trained.state_dict().items())
    assert any(not torch.equal(v, trained.state_dict()[k]) for k, v in model.state_dict().items())
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(run / "tensorboard"))
    acc.Reload()
    tags = set(acc.Tags()["scalars"])
    assert {"train/loss", "lr", "samples_per_s", "val/loss"} <= tags
    assert len(acc.Scalars("train/loss")) == 6
    assert (run / "curves.png").stat().st_size > 10_000


def test_the_run_ends_the_crop_threads_it_started(recordings, tmp_path, monkeypatch):
    import threading
    from concurrent.futures import ThreadPoolExecutor

    from policies.data import dataset

    started = []
    monkeypatch.setattr(dataset, "crop_pool", lambda: started.append(ThreadPoolExecutor(
        2, thread_name_prefix="test-crop")) or started[-1])
    run_training(_opts(recordings, tmp_path / "run", "act", steps=2), Dist())
    assert len(started) == 1  # the data started its crop threads once, for the first cropped batch ...
    assert not [t.name for t in threading.enumerate() if t.name.startswith("test-crop")]  # ... and ended them


def test_resume_reproduces_the_uninterrupted_loss_curve(recordings, tmp_path):
    torch.set_num_threads(1)
    whole = tmp_path / "whole"
    run_training(_opts(recordings, whole, "act", steps=12, train={"ckpt_every": 6}), Dist())
    part = tmp_path / "part"
    opts = _opts(recordings, part, "act", steps=12, train={"ckpt_every": 6})
    run_training(opts, Dist(), stop_at=6)
    assert C.read_meta(part)["step"] == 6
    opts.resume = True
    run_training(opts, Dist())
    a, b = _losses(whole), _losses(part)
    assert len(a) == len(b) == 12
    np.testing.assert_allclose(b, a, rtol=1e-5, atol=1e-6)


def _cli_args(rec, out, extra=()):
    tiny = [
        a
        for k, v in TINY.items()
        if k not in ("backbone", "image_size", "dropout")
        for a in ("--set", f"{k}={v}")
    ]
    return [
        "train",
        str(rec),
        "--out",
        str(out),
        "--policy",
        "flow",
        "--steps",
        "4",
        "--batch",
        "8",
        "--warmup",
        "2",
        "--log-every",
        "1",
        "--thresholds",
        "1:3",
        "--backbone",
        "convnet-gn",
        "--image-size",
        "32",
        "--dropout",
        "0",
        "--no-progress",
        *tiny,
        *extra,
    ]


def test_two_process_gloo_ddp_matches_one_process(recordings, tmp_path):
    from factr2_teleop.cli import main

    # fp32: the DDP arithmetic is what is compared (bf16 rounds each rank's half-batch apart)
    fp32 = ["--threads", "1", "--precision", "fp32"]
    assert main(_cli_args(recordings, tmp_path / "one", fp32)) == 0
    assert main(_cli_args(recordings, tmp_path / "two", ["--nproc", "2", *fp32])) == 0
    one, two = _losses(tmp_path / "one"), _losses(tmp_path / "two")
    assert len(one) == len(two) == 4
    np.testing.assert_allclose(two, one, rtol=2e-4)
    assert C.read_meta(tmp_path / "two")["world_size"] == 2
    w1 = C.load_policy(tmp_path / "one")[0].state_dict()
    w2 = C.load_policy(tmp_path / "two")[0].state_dict()
    assert max(float((w1[k] - w2[k]).abs().max()) for k in w1) < 1e-4


@pytest.mark.parametrize(
    "method,force,check",
    [
        ("base", "tau_ext", lambda m, rows: m["policy"]["force_dim"] == 0 and m["force"] == "none"),
        (
            "base-torque",
            "current",
            lambda m, rows: m["features"]["observation.force"] == ["follower.joint.current"],
        ),
        ("factr", "tau_ext", lambda m, rows: m["ratio"] == [1, 1, 1]),
        (
            "tavla",
            "tau_ext",
            lambda m, rows: m["policy"]["aux_force"] and any("train/aux_force" in r for r in rows),
        ),
    ],
)
def test_every_method_trains_through_one_code_path(recordings, tmp_path, method, force, check):
    torch.set_num_threads(1)
    run = tmp_path / "run"
    run_training(_opts(recordings, run, "act", steps=2, method=method, force=force), Dist())
    meta = C.read_meta(run)
    rows = [json.loads(x) for x in (run / "metrics.jsonl").read_text().splitlines()]
    assert meta["method"] == method and check(meta, rows)


def test_factr_blur_schedule_and_kernel():
    from policies.training.methods import blur_sigma, gaussian_blur

    assert (
        blur_sigma(0, 100, 5.0) == 5.0 and blur_sigma(50, 100, 5.0) == 2.5 and blur_sigma(100, 100, 5.0) == 0
    )
    img = torch.zeros(1, 3, 32, 32)
    img[..., 16, 16] = 1.0
    out = gaussian_blur(img, 2.0)
    assert out.sum().item() == pytest.approx(3.0, rel=1e-4)  # mass kept per channel
    assert out[0, 0, 16, 16] < 0.05 and out[0, 0, 16, 18] > 0.01
    assert torch.equal(gaussian_blur(img, 0.05), img)


def test_precision_auto_uses_bf16_only_where_the_hardware_has_it(monkeypatch):
    import torch

    from policies.training.train import pick_precision

    cpu = torch.device("cpu")
    assert pick_precision("fp32", cpu)[0] == "fp32"
    monkeypatch.setattr(torch.ops.mkldnn, "_is_mkldnn_bf16_supported", lambda: False)
    assert pick_precision("auto", cpu)[0] == "fp32"
    p, why = pick_precision("bf16", cpu)
    assert p == "bf16" and "slower than fp32" in why
    monkeypatch.setattr(torch.ops.mkldnn, "_is_mkldnn_bf16_supported", lambda: True)
    assert pick_precision("auto", cpu)[0] == "bf16"
    assert pick_precision("auto", torch.device("cuda"))[0] == "bf16"
