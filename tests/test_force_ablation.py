"""The test-time force ablation (issue #51 item 5): zero and shuffle change only the force input, and a
policy trained on a recorded estimator's tau_ext names that estimator."""
import numpy as np
import pytest
import torch

from hardware.errors import UserError
from policies.rollout.runner import FORCE_INPUTS, PolicyRunner, ablate_force


def test_ablate_force_is_pure_and_keeps_the_marginal():
    rng = np.random.default_rng(0)
    live = [np.array([[float(k), -float(k)]]) for k in range(50)]
    assert ablate_force(live[3], "live", [], rng) is live[3]
    assert np.array_equal(ablate_force(live[3], "zero", [], rng), np.zeros((1, 2)))
    seen: list = []
    out = [ablate_force(f, "shuffle", seen, rng) for f in live]
    assert len(seen) == 50
    assert all(any(np.array_equal(o, s) for s in live[: k + 1]) for k, o in enumerate(out))  # only the past
    assert sum(np.array_equal(o, f) for o, f in zip(out, live)) < 25  # mostly another moment's force
    with pytest.raises(ValueError):
        ablate_force(live[0], "noise", [], rng)
    assert FORCE_INPUTS == ("live", "zero", "shuffle")


def test_runner_ablates_only_the_force_and_meta_names_the_estimator(tmp_path):
    from policies.training.run import RunOptions, run_training
    from policies.training.train import Dist, TrainConfig
    from tests.policy_helpers import write_recording

    # a synthetic twin recording (tau_ext with contact bursts, PRIVILEGED objects) whose session felt the
    # disturbance observer
    rec = write_recording(tmp_path / "demo.mcap", cameras=(), objects=3, metadata={"feedback_mode": "dob"})
    run = tmp_path / "run"
    tiny = dict(hidden=32, heads=2, enc_layers=1, dec_layers=1, ff=64, dropout=0.0, chunk=8)
    run_training(RunOptions(inputs=[rec], out=run, method="base-torque", thresholds=(1.0, 3.0),
                            progress=False, observation="state",
                            overrides=tiny, val_fraction=0.0, include_failed=True,
                            train=TrainConfig(steps=2, batch=8, warmup=1, val_every=1000, ckpt_every=1000,
                                              threads=1)), Dist())
    live = PolicyRunner(run)
    assert live.meta["tau_ext_estimator"] == "dob" and live.force_names
    names = live.state_names + live.force_names
    # the synthetic recording's 6 joints and a gripper
    obs = {n: np.full(1 if "gripper" in n else 6, 0.1 * (k + 1), np.float32) for k, n in enumerate(names)}
    obs[live.object_feature] = np.arange(len(live.object_names), dtype=np.float32)
    zeroed = dict(obs) | {n: np.zeros_like(obs[n]) for n in live.force_names}
    b_zero = PolicyRunner(run, force_input="zero").batch(obs)
    b_ref = live.batch(zeroed)
    b_live = live.batch(obs)
    assert set(b_zero) == set(b_ref)
    for k in b_ref:
        if isinstance(b_ref[k], torch.Tensor):
            assert torch.equal(b_zero[k], b_ref[k]), k
    assert any(isinstance(v, torch.Tensor) and not torch.equal(v, b_ref[k]) for k, v in b_live.items())
    with pytest.raises(UserError):
        PolicyRunner(run, force_input="noise")
