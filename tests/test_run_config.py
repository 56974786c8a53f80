"""One training configuration (policies/training/run_config.py): the CLI flags, the torchrun relaunch's argv,
the checkpoint meta, the resume check and the terminal app's choices are all generated from its fields; the
policy factory builds every registered policy, a new one by registration alone."""

from __future__ import annotations

import argparse
import json
from dataclasses import fields, replace
from pathlib import Path

import pytest
import torch

from hardware.errors import UserError
from policies.labels.labelling import LabelChoice
from policies.models import policy as P
from policies.models.config import PolicyConfig, settable
from policies.training import checkpoint as C
from policies.training import flags as F
from policies.training import run_config as R
from policies.training.run import run_training
from policies.training.train import Dist
from tests.policy_helpers import write_recording

# `factr2 train`'s flags before the one config (docs and scripts use them): every one stays
FLAGS_BEFORE = """--out --policy --method --ratio --preset --steps --epochs --resume --include-failed
    --keep-incomplete --force --next --thresholds --no-tare --obs --rate --batch --lr --weight-decay --warmup
    --dropout --image-size --backbone --backbone-weights --set --val-every --ckpt-every --log-every --seed
    --threads --nproc --no-progress""".split()


def _parser():
    from factr2_teleop.commands import train as cmd

    p = argparse.ArgumentParser(prog="factr2 train")
    cmd.add_arguments(p)
    return p


def _parse(argv):
    return R.from_args(_parser().parse_args(argv))


def test_every_flag_is_a_field_and_keeps_its_name_and_default():
    p = _parser()
    options = {s for a in p._actions for s in a.option_strings} - {"-h", "--help"}
    assert options == set(F.flag_names(R.RunOptions)) - {"inputs"}
    assert set(FLAGS_BEFORE) <= options
    o = _parse(["rec", "--out", "run"])
    assert o == R.RunOptions(inputs=[Path("rec")], out=Path("run"), thresholds=LabelChoice("recording"))
    t = o.train
    assert (t.lr, t.warmup, t.log_every, t.epochs, t.batch, o.policy, o.method) == (
        3e-4, 500, 10, 20.0, 128, "flow", "first")


def test_bad_values_are_one_line_errors():
    for argv, why in [(["--steps", "0"], "--steps must be >= 1, got 0"), (["--ratio", "1:2"], "--ratio"),
                      (["--epochs", "0"], "--epochs must be > 0"), (["--nproc", "0"], "--nproc must be >= 1"),
                      (["--episodes", "a.mcap#3-1"], "--episodes: 'a.mcap#3-1': the range ends before"),
                      (["--episodes", "a.mcap#x"], "not FILE.mcap#N or FILE.mcap#N-M"),
                      (["--episodes", "#2"], "not FILE.mcap#N"),
                      (["--obs-noise", "images=0.1"], "--obs-noise: 'images=0.1' is not NAME=SIGMA"),
                      (["--obs-noise", "state=-1"], "sigma must be finite and >= 0"),
                      (["--obs-noise", "state=x"], "'x' is not a number")]:
        with pytest.raises(UserError, match=why):
            _parse(["rec", "--out", "run", *argv])
    # one list of what the run fills itself (PolicyConfig's FILLED fields): --set refuses them all
    for name in ("policy", "n_cameras", "state_dim", "force_dim", "action_dim", "aux_force", "observation"):
        with pytest.raises(UserError, match="not FIELD=VALUE of a settable"):
            _parse(["rec", "--out", "run", "--set", f"{name}=1"])
    assert "hidden" in settable() and "aux_force" not in settable()


@pytest.mark.parametrize("argv", [
    "rec --out run",
    "rec rec2 --out run --obs state --policy act --method tavla --ratio PC+C --steps 40 --batch 128 "
    "--lr 0.001 --seed 3 --threads 2 --no-progress --thresholds 1.5:2.5 --no-tare --set hidden=64 "
    "--set kl_weight=2.5 --rate 15 --include-failed --keep-incomplete --resume --next ck.json --preset state",
    "rec --out run --epochs 3.5 --backbone convnet-gn --image-size 32 --dropout 0 --thresholds next "
    "--force current --method base --val-every 7 --nproc 2",
    "rec --out run --episodes a.mcap#0-2,b.mcap#5",
    "rec --out run --obs state --obs-noise state=0.05,objects=0.05,force=0.1 --keep val-min --no-ema",
])
def test_argv_parses_back_to_the_same_options(argv):
    """The torchrun relaunch: options -> argv -> parse -> the same options (less --nproc, the launcher's)."""
    o = _parse(argv.split())
    assert _parse(R.to_argv(o)) == replace(o, nproc=1)
    assert "--nproc" not in R.to_argv(o)


def test_episodes_names_ids_and_ranges():
    from policies.data.recordings import parse_episode_ids

    assert _parse(["rec", "--out", "run"]).episodes is None
    assert _parse(["rec", "--out", "run", "--episodes", "a.mcap#0-2, b.c.mcap#7,a.mcap#1"]).episodes == (
        "a.mcap#0", "a.mcap#1", "a.mcap#2", "b.c.mcap#7")
    assert parse_episode_ids("x#y.mcap#4") == ("x#y.mcap#4",)  # the last '#' splits


def test_resume_keys_come_from_the_fields():
    """Each field names the meta entry that checks it on --resume: the keys are those, no list by hand."""
    named = {f.metadata["resume"] for cls in (R.RunOptions, R.TrainConfig) for f in fields(cls)
             if f.metadata.get("resume")}
    assert set(R.RESUME_KEYS) == named
    assert {"policy", "method", "ratio", "force", "data_hash", "phases", "rate_hz", "observation",
            "train.lr", "train.seed"} <= named
    assert "train.log_every" not in named and "train.threads" not in named  # may change on resume


def test_the_form_is_the_options_choices():
    from factr2_teleop.tui import train_ctl as T
    from policies.data.privileged import OBSERVATIONS
    from policies.training.methods import METHODS

    form = T.form()
    assert form["policy"] == P.policy_names() == ("flow", "act") and form["method"] == tuple(METHODS)
    assert form["observation"] == OBSERVATIONS and form["ratio"][0] == "default"
    assert set(form) - {"size"} <= {f.name for f in fields(R.RunOptions)}  # the size: the app's own


@pytest.fixture(scope="module")
def state_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("cfg")
    write_recording(d / "rec" / "a.mcap", episodes=3, seconds=3.0, objects=5)
    torch.set_num_threads(1)
    o = _parse([str(d / "rec"), "--out", str(d / "run"), "--obs", "state", "--steps", "3", "--batch", "8",
                "--thresholds", "1:3", "--threads", "1", "--no-progress", "--set", "hidden=32",
                "--ratio", "C"])
    run_training(o, Dist())
    return o, d / "run"


def test_episodes_trains_on_those_only_and_refuses_an_unknown_one(state_run, tmp_path):
    o, _ = state_run
    o = replace(o, out=tmp_path / "two", episodes=("a.mcap#0", "a.mcap#2"))
    run_training(o, Dist())
    assert json.loads(C.last_checkpoint(o.out).read_text())["episodes"] == ["a.mcap#0", "a.mcap#2"]
    with pytest.raises(UserError, match="1 chosen episode.s. not in the recordings, e.g. a.mcap#9"):
        run_training(replace(o, out=tmp_path / "typo", episodes=("a.mcap#0", "a.mcap#9")), Dist())


def test_meta_reads_back_to_the_run_options(state_run):
    """options -> checkpoint meta -> options: the resolved options of the run (the method's force, the
    preset and the fields it fills, the data's rate)."""
    o, run = state_run
    meta = C.read_meta(run)
    back = R.RunOptions.from_meta(meta, o.inputs, o.out, progress=o.progress)
    assert back == replace(o.resolved(), rate_hz=meta["rate_hz"], episodes=tuple(meta["episodes"]))
    assert back.overrides == {"hidden": 32} and back.ratio == (1.0, 1.0, 5.0)
    keys = ("method", "ratio", "force", "preset", "observation", "train")
    assert {k: meta[k] for k in keys} == {k: v for k, v in json.loads(json.dumps(back.to_meta())).items()
                                          if k in keys}


def test_older_meta_still_reads_and_resumes_check(state_run):
    """A run's meta from before the one config (method, ratio and force in meta["train"] too, no outcome
    filter, a model config without later fields) is still read, and still the same run for --resume."""
    from policies.training.run import _compare

    o, run = state_run
    meta = C.read_meta(run)
    old = dict(meta, train=dict(meta["train"], method="first", ratio=[1, 5, 1], force="tau_ext"),
               policy={k: v for k, v in meta["policy"].items() if k != "aux_weight"})
    for key in ("include_failed", "keep_incomplete"):
        old.pop(key)
    for key in ("ema", "obs_noise", "keep"):  # added since: the values runs before them had
        old["train"].pop(key)
    back = R.RunOptions.from_meta(old, o.inputs, o.out)
    assert back.train == o.train and back.include_failed and back.keep_incomplete  # before: every outcome
    assert _compare(old, meta) == []
    changed = dict(meta, train=dict(meta["train"], lr=1.0), method="base")
    assert _compare(meta, changed) == ["method", "train.lr"]


def test_factory_builds_every_registered_policy_and_a_new_one(monkeypatch):
    table = P.registered()
    assert {name for name, _ in table} == set(P.policy_names())
    cfg = dict(hidden=32, heads=2, enc_layers=1, dec_layers=1, ff=64, chunk=4, observation="state",
               objects_dim=3)
    for (name, head), cls in table.items():
        pcfg = PolicyConfig(policy=name, head=head if head != P.ANY_HEAD else "dit", **cfg)
        assert type(P.make_policy(pcfg)) is cls

    monkeypatch.setattr(P, "_REGISTRY", dict(P._REGISTRY))

    @P.register("copycat")
    class Copycat(P.Policy):
        def __init__(self, c):
            super().__init__(c)
            self.w = torch.nn.Linear(c.state_dim, c.action_dim)

    assert isinstance(P.make_policy(PolicyConfig(policy="copycat")), Copycat)
    with pytest.raises(ValueError, match="no policy 'nope'"):
        P.make_policy(PolicyConfig(policy="nope"))


def test_blur_is_a_batch_input_not_a_model_attribute():
    """FACTR's blur reaches the model with the batch (training only); nothing is set on the model."""
    from policies.models.tokens import ObservationTokens

    cfg = PolicyConfig(hidden=16, heads=2, backbone="convnet-gn", image_size=32, n_cameras=1, force_dim=0)
    torch.manual_seed(0)
    obs = ObservationTokens(cfg)
    assert not hasattr(obs, "blur_sigma")
    g = torch.Generator().manual_seed(0)
    batch = {"images": torch.randint(0, 255, (2, 1, 32, 32, 3), generator=g, dtype=torch.uint8),
             "state": torch.randn(2, 7, generator=g)}
    assert not torch.equal(obs.tokens(batch), obs.tokens(dict(batch, blur_sigma=2.0)))
    obs.eval()
    assert torch.equal(obs.tokens(batch), obs.tokens(dict(batch, blur_sigma=2.0)))
