"""Issue #56's training levers (policies/training/regularise.py), on tiny state-preset runs: the observation
noise goes into training batches only and only on the named inputs, deterministic under a seed and the same
across ranks; --keep val-min keeps the evaluated weights of the lowest validation loss, rollouts load them,
--resume continues with them; all of it off by default."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import torch

from hardware.errors import UserError
from policies.training import checkpoint as C
from policies.training.regularise import add_obs_noise, format_obs_noise, parse_obs_noise
from policies.training.run import run_training
from policies.training.run_config import RunOptions, TrainConfig
from policies.training.train import Dist
from tests.policy_helpers import write_recording


def test_parse_reads_back_and_refuses_what_is_not_an_input():
    s = parse_obs_noise("state=0.05, objects=0.05,force=0.1")
    assert s == {"state": 0.05, "objects": 0.05, "force": 0.1}
    assert parse_obs_noise(format_obs_noise(s)) == s
    for bad in ("images=0.1", "state", "state=nan", "force=-0.1", "action=0.1"):
        with pytest.raises(ValueError):
            parse_obs_noise(bad)


def _batch(n=8):
    g = torch.Generator().manual_seed(0)
    return {k: torch.randn((n, d), generator=g) for k, d in
            (("state", 7), ("force", 6), ("objects", 5), ("action", 7), ("force_chunk", 6))}


def test_noise_only_on_the_named_inputs_at_its_sigma_and_the_same_split_over_ranks():
    clean = _batch(4096)
    noisy = add_obs_noise({k: v.clone() for k, v in clean.items()}, {"state": 0.5, "objects": 0.0},
                          torch.Generator().manual_seed(3), 4096, np.arange(4096))
    for k in ("force", "objects", "action", "force_chunk"):  # not named, sigma 0, the targets
        assert torch.equal(noisy[k], clean[k]), k
    d = (noisy["state"] - clean["state"]).numpy()
    assert abs(d.std() - 0.5) < 0.02 and abs(d.mean()) < 0.02  # normalised units: sigma of the input's std
    # two ranks keeping their halves of the global batch add what one process adds to the whole
    whole = add_obs_noise(_batch(), {"state": 0.1, "force": 0.2}, torch.Generator().manual_seed(5), 8,
                          np.arange(8))
    halves = [add_obs_noise({k: v[pos] for k, v in _batch().items()}, {"state": 0.1, "force": 0.2},
                            torch.Generator().manual_seed(5), 8, pos)
              for pos in (np.arange(4), np.arange(4, 8))]
    for k in ("state", "force"):
        assert torch.equal(torch.cat([h[k] for h in halves]), whole[k])


@pytest.fixture(scope="module")
def rec(tmp_path_factory):
    d = tmp_path_factory.mktemp("reg")
    write_recording(d / "a.mcap", episodes=4, seconds=3.0, objects=5)
    return d


def _opts(rec, out, **train):
    cfg = dict(steps=12, batch=16, lr=3e-3, warmup=2, log_every=1, val_every=2, ckpt_every=1000, threads=1)
    cfg.update(train)
    return RunOptions(inputs=[rec], out=out, observation="state", thresholds=(1.0, 3.0), progress=False,
                      overrides={"hidden": 32, "ff": 64}, val_fraction=0.25, train=TrainConfig(**cfg))


def _rows(run, key):
    return [(r["step"], r[key]) for r in map(json.loads, (run / "metrics.jsonl").read_text().splitlines())
            if key in r]


NOISE = {"state": 0.5, "objects": 0.5, "force": 0.5}


def test_noise_changes_training_not_validation_and_is_off_by_default(rec, tmp_path):
    """The same seed with and without noise: the training losses part (the flow head starts blind to its
    inputs, so from the first update on); the validation loss the noisy run logged is that of its weights on
    clean inputs, recomputed here."""
    from policies.training.run import prepare
    from policies.training.train import evaluate

    torch.set_num_threads(1)
    assert TrainConfig().obs_noise is None and TrainConfig().keep == "last"
    runs, last = {}, {}
    for name, noise in (("clean", None), ("noisy", NOISE)):
        runs[name] = _opts(rec, tmp_path / name, steps=6, val_every=6, obs_noise=noise)
        last[name] = run_training(runs[name], Dist())
    tr = [np.array([v for _, v in _rows(tmp_path / n, "train/loss")]) for n in ("clean", "noisy")]
    assert len(tr[0]) == 6 and tr[0][0] == tr[1][0] and np.all(tr[0][2:] != tr[1][2:])
    data, pcfg, *_ = prepare(replace(runs["noisy"], resume=True), Dist())
    model, _, _ = C.load_policy(tmp_path / "noisy")
    clean = evaluate(model, data, data.split()[1], pcfg, torch.device("cpu"))
    assert clean["val/loss"] == pytest.approx(last["noisy"]["val/loss"], rel=1e-6)


def test_noise_on_an_input_the_run_lacks_is_refused_before_run_is_written(tmp_path):
    torch.set_num_threads(1)
    write_recording(tmp_path / "rec" / "a.mcap", episodes=2, seconds=2.0)  # no objects
    o = replace(_opts(tmp_path / "rec", tmp_path / "run", obs_noise={"objects": 0.1}), observation="joints")
    with pytest.raises(UserError, match="--obs-noise names objects, not an input of this run"):
        run_training(o, Dist())
    assert not (tmp_path / "run").exists()


def test_noise_is_deterministic_under_a_seed(rec, tmp_path):
    torch.set_num_threads(1)
    losses = {}
    for name, seed in (("a", 0), ("b", 0), ("c", 1)):
        run_training(_opts(rec, tmp_path / name, steps=6, obs_noise=NOISE, seed=seed), Dist())
        losses[name] = _rows(tmp_path / name, "train/loss")
    assert losses["a"] == losses["b"] and losses["a"] != losses["c"]


def test_val_min_keeps_the_lowest_validation_loss_and_resume_continues_it(rec, tmp_path):
    """The kept checkpoint is the evaluated (EMA) weights at the lowest val/loss of the curve; `last` stays
    the end (what --resume continues); a RUN folder loads the kept one; a run stopped and resumed keeps
    the same one as a run straight through (noise on, so the resumed noise is the same too)."""
    torch.set_num_threads(1)
    run = tmp_path / "whole"
    run_training(_opts(rec, run, steps=24, keep="val-min", obs_noise=NOISE, lr=1e-2), Dist())
    val = _rows(run, "val/loss")
    step_min, loss_min = min(val, key=lambda sv: sv[1])
    kept = C.kept_checkpoint(run)
    meta = json.loads(kept.read_text())
    assert kept.name == f"valmin-{step_min:07d}.json" and meta["step"] == step_min
    assert meta["metrics"]["val/loss"] == loss_min and meta["kept"] == "val-min"
    assert len(list((run / "checkpoints").glob("valmin-*.json"))) == 1  # the ones it replaced: removed
    assert json.loads(C.last_checkpoint(run).read_text())["step"] == 24
    model, loaded, _ = C.load_policy(run)
    assert loaded["step"] == step_min and loaded["weights_used"] == "ema"
    from safetensors.torch import load_file

    want = load_file(str(kept.with_name(meta["weights_ema"])))
    assert all(torch.equal(model.state_dict()[k], v) for k, v in want.items())
    # the same run stopped after its step-8 checkpoint and resumed: the same curve, the same kept step
    part = tmp_path / "part"
    o = _opts(rec, part, steps=24, keep="val-min", obs_noise=NOISE, lr=1e-2, ckpt_every=8)
    run_training(o, Dist(), stop_at=8)
    run_training(replace(o, resume=True), Dist())
    assert _rows(part, "val/loss") == val
    assert C.kept_checkpoint(part).name == kept.name


def test_keep_last_writes_no_kept_pointer(rec, tmp_path):
    torch.set_num_threads(1)
    run_training(_opts(rec, tmp_path / "run", steps=4), Dist())
    assert not (tmp_path / "run" / "checkpoints" / "kept").exists()
    assert C.kept_checkpoint(tmp_path / "run") == C.last_checkpoint(tmp_path / "run")


def test_factr2_train_says_which_checkpoint_rollouts_load(rec, tmp_path, capsys):
    from factr2_teleop.cli import main

    argv = ["train", str(rec), "--out", str(tmp_path / "run"), "--obs", "state", "--steps", "8",
            "--batch", "16", "--val-every", "2", "--thresholds", "1:3", "--threads", "1", "--no-progress",
            "--set", "hidden=32", "--obs-noise", "state=0.1,objects=0.1", "--keep", "val-min"]
    assert main(argv) == 0
    kept = C.kept_checkpoint(tmp_path / "run")
    assert f"checkpoints ({kept.stem} kept: the lowest validation loss)" in capsys.readouterr().out
    meta = C.read_meta(tmp_path / "run")
    assert meta["train"]["obs_noise"] == {"state": 0.1, "objects": 0.1} and meta["train"]["keep"] == "val-min"
