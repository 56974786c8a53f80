"""The `state` preset (MLP flow head), EMA weights, the schedule fitted to short runs, the thread choice."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import torch

from policies.models.config import default_preset, preset
from policies.models.flow_mlp import FlowMLPPolicy
from policies.training import checkpoint as C
from policies.training.run import RunOptions, run_training
from policies.training.train import Dist, Ema, TrainConfig, clamp_schedule
from policies.training.train_threads import pick_threads
from tests.policy_helpers import write_recording


@pytest.fixture(scope="module")
def state_recordings(tmp_path_factory):
    d = tmp_path_factory.mktemp("rec_state")
    write_recording(d / "a.mcap", episodes=3, seconds=3.0, objects=5)
    return d


def _cfg(**kw):
    return replace(preset("state"), state_dim=7, force_dim=6, objects_dim=5, action_dim=7, chunk=8, **kw)


def test_default_preset_follows_the_observation():
    assert default_preset("state") == "state" and default_preset("images") == "small"
    cfg = preset("state")
    assert cfg.head == "mlp" and cfg.observation == "state"
    assert preset("state", "act").policy == "act"
    with pytest.raises(ValueError):
        FlowMLPPolicy(replace(_cfg(), observation="images"))


def test_mlp_head_starts_at_zero_velocity_and_overfits_one_batch():
    torch.manual_seed(0)
    cfg = _cfg(ff=128, dec_layers=2)
    m = FlowMLPPolicy(cfg)
    b = {"state": torch.randn(8, 7), "force": torch.randn(8, 6), "objects": torch.randn(8, 5),
         "action": torch.randn(8, cfg.chunk, 7), "mask": torch.ones(8, cfg.chunk, dtype=torch.bool)}
    g = torch.Generator().manual_seed(0)
    noise = FlowMLPPolicy.draw_noise(cfg, 8, g)
    v, _ = m.velocity(torch.randn(8, cfg.chunk, 7), noise["alpha"], m.encode(b))
    assert torch.equal(v, torch.zeros_like(v))  # zero-initialised output: training starts from v = 0
    opt = torch.optim.Adam(m.parameters(), 1e-3)
    first = None
    for _ in range(300):
        loss = m.loss(b, noise)[0].mean()
        first = first if first is not None else float(loss.detach())
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert float(loss.detach()) < first / 10
    out = m.eval().predict(b, noise)
    assert out.shape == (8, cfg.chunk, 7) and torch.isfinite(out).all()


def test_ema_decay_warms_up_and_averages():
    lin = torch.nn.Linear(2, 2)
    ema = Ema(lin, power=0.75, max_decay=0.9999)
    assert ema.decay(0) == 0.0 and 0.99 < ema.decay(1000) < ema.decay(10000) < 0.9999 + 1e-12
    with torch.no_grad():
        lin.weight.fill_(1.0)
    ema.update(lin, 0)  # decay 0: the average is the model
    assert torch.allclose(ema.model.weight, torch.ones(2, 2))
    with torch.no_grad():
        lin.weight.fill_(3.0)
    ema.update(lin, 1)  # decay 1 - 2 ** -0.75 = 0.405: moves 59.5 % of the way
    assert torch.allclose(ema.model.weight, torch.full((2, 2), 1.0 + 2.0 * 2 ** -0.75))


def test_schedule_is_clamped_to_a_short_run_and_says_so():
    cfg, notes = clamp_schedule(TrainConfig(warmup=500, val_every=500, ckpt_every=1000), 400)
    assert (cfg.warmup, cfg.val_every, cfg.ckpt_every) == (40, 50, 100) and len(notes) == 3
    assert "400" in notes[0]
    same, none = clamp_schedule(TrainConfig(), 20000)
    assert same == TrainConfig() and none == []
    # validation 16 times (the advice reads the curve's shape), not shortened below 50 steps, 4 times at least
    got = [clamp_schedule(TrainConfig(), n)[0].val_every for n in (8000, 2000, 600, 100)]
    assert got == [500, 125, 50, 25]
    assert clamp_schedule(TrainConfig(val_every=2), 12)[0].val_every == 2  # a short period asked for stays


def test_thread_choice_leaves_busy_cores_alone(monkeypatch):
    import policies.training.train_threads as T

    monkeypatch.setattr("calibration.next.train.available_cores", lambda: 2)
    monkeypatch.setattr(T.os, "getloadavg", lambda: (1.0, 1.0, 1.0))  # one other CPU-bound process
    assert pick_threads(0, 1)[0] == 1
    monkeypatch.setattr(T.os, "getloadavg", lambda: (0.1, 0.1, 0.1))
    assert pick_threads(0, 1)[0] == 2 and pick_threads(0, 2)[0] == 1
    assert pick_threads(3, 1) == (3, "as asked (--threads)")
    monkeypatch.setattr("calibration.next.train.available_cores", lambda: 16)
    monkeypatch.setattr(T.os, "getloadavg", lambda: (20.0, 20.0, 20.0))
    assert pick_threads(0, 1)[0] == 1


def test_state_run_trains_saves_ema_and_rolls_in(state_recordings, tmp_path):
    torch.set_num_threads(1)
    run = tmp_path / "run"
    opts = RunOptions(inputs=[state_recordings], out=run, policy="flow", thresholds=(1.0, 3.0),
                      progress=False, observation="state", overrides={"chunk": 8, "ff": 64},
                      train=TrainConfig(steps=20, batch=16, log_every=5, threads=1, keep_checkpoints=0))
    run_training(opts, Dist())
    model, meta, _ = C.load_policy(run)
    assert isinstance(model, FlowMLPPolicy) and meta["weights_used"] == "ema"
    assert meta["schedule"] == {"warmup": 2, "val_every": 5, "ckpt_every": 5}  # clamped to 20 steps
    assert meta["train"]["warmup"] == 500  # what was asked stays the run's record (--resume compares it)
    steps = sorted(json.loads(p.read_text())["step"] for p in (run / "checkpoints").glob("step-*.json"))
    assert steps == [5, 10, 15, 20]  # keep_checkpoints 0: every checkpoint kept (a learning curve)
    metrics = meta["metrics"]
    assert np.isfinite(metrics["val/loss"]) and np.isfinite(metrics["val/loss_raw"])


def test_default_length_comes_from_the_learning_curve_for_state():
    from policies.training.run_config import default_length

    assert default_length("state") == (80.0, 256)  # docs/first_training.md: success still rose at 8000 x 256
    assert default_length("images") == (20.0, 128)  # the paper's 20 epochs
    import argparse

    from policies.training import run_config as R

    p = argparse.ArgumentParser()
    R.add_arguments(p)
    o = R.from_args(p.parse_args(["rec", "--out", "run", "--obs", "state"]))
    assert (o.train.epochs, o.train.batch, o.preset) == (80.0, 256, "")
    argv = ["rec", "--out", "run", "--obs", "state", "--batch", "64", "--epochs", "3"]
    o = R.from_args(p.parse_args(argv))
    assert (o.train.epochs, o.train.batch) == (3.0, 64)


def test_relative_actions_train_and_come_back_in_joint_units(state_recordings, tmp_path):
    """--actions relative: the checkpoint keeps the frame; a rollout's chunk is the model's output plus the
    observed joints (grippers absolute), so the same output at another observed pose moves with it."""
    from hardware.recording.schemas import TASK_OBJECTS_FEATURE
    from policies.rollout.runner import PolicyRunner
    from policies.training.run_config import RESUME_KEYS

    torch.set_num_threads(1)
    run = tmp_path / "rel"
    opts = RunOptions(inputs=[state_recordings], out=run, policy="flow", thresholds=(1.0, 3.0),
                      progress=False, observation="state", overrides={"chunk": 8, "ff": 64},
                      actions="relative",
                      train=TrainConfig(steps=10, batch=16, log_every=5, threads=1))
    run_training(opts, Dist())
    runner = PolicyRunner(run)
    assert runner.meta["actions"] == "relative" and "actions" in RESUME_KEYS
    assert runner.pre.action_frame == "relative" and runner.pre.relative == [True] * 6 + [False]
    joints, grip = runner.state_names
    obs = {joints: np.zeros(6, np.float32), grip: np.float32(0.02),
           TASK_OBJECTS_FEATURE: np.zeros(5, np.float32)}
    obs.update({n: np.zeros(6, np.float32) for n in runner.force_names})
    shifted = {**obs, joints: np.full(6, 0.1, np.float32)}
    a = runner.infer(obs, 0.0).actions
    assert a.shape == (8, 7) and np.isfinite(a).all()
    runner.reseed(3)  # an episode's draws repeat whatever was drawn before it
    first = runner.infer(obs, 0.0).actions
    assert not np.allclose(runner.infer(obs, 0.0).actions, first)  # the noise moves on within the episode
    runner.reseed(3)
    assert np.array_equal(runner.infer(obs, 0.0).actions, first)
    z = torch.randn(1, 8, 7)  # one fixed model output, whatever the observation
    runner.model.predict = lambda batch, noise: z
    a, b = runner.infer(obs, 0.0).actions, runner.infer(shifted, 0.0).actions
    assert np.allclose(b[:, :6] - a[:, :6], 0.1, atol=1e-6) and np.allclose(b[:, 6], a[:, 6])
    n = runner.pre.norm
    want = n.denorm("action", z[0].numpy().reshape(-1)).reshape(8, 7)
    assert np.allclose(a, want, atol=1e-5)  # at zero joints the chunk is the denormalised output itself
