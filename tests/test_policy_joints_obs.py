"""`--obs joints`: a policy that sees the joints and force only (no frames, no objects) trains on a teleop
recording without cameras or task objects and is accepted by a rig without cameras (the crash campaign's
rollout against a twin in another process, bench/crash_trials.py)."""

import numpy as np
import pytest

from hardware.errors import UserError
from policies.data.privileged import OBSERVATIONS, low_dimensional, uses_images, uses_objects


def test_joints_observes_neither_frames_nor_objects():
    assert "joints" in OBSERVATIONS
    assert not uses_images("joints") and not uses_objects("joints") and low_dimensional("joints")
    for obs in ("state", "perceived"):  # unchanged: an object vector without frames
        assert low_dimensional(obs)
    for obs in ("images", "images+state", "images+perceived"):
        assert not low_dimensional(obs)


def test_a_joints_policy_trains_without_frames_or_objects_and_runs(tmp_path):
    import torch

    from policies.rollout.runner import PolicyRunner
    from tests.policy_helpers import train_tiny, write_recording

    write_recording(tmp_path / "demos" / "teleop.mcap", episodes=1, seconds=2.0, cameras=())
    model, meta, pre = train_tiny(tmp_path / "demos", tmp_path / "run", "joints")
    assert meta["observation"] == "joints" and meta["policy"]["objects_dim"] == 0
    assert meta["features"]["observation.images"] == [] and model.obs.backbone is None
    assert model.obs.objects is None
    batch = {"state": torch.zeros(1, meta["policy"]["state_dim"]),
             "force": torch.zeros(1, meta["policy"]["force_dim"])}
    noise = type(model).draw_noise(model.cfg, 1, torch.Generator().manual_seed(0))
    chunk = model.predict(batch, noise)
    assert chunk.shape[1] == 8 and torch.isfinite(chunk).all()
    runner = PolicyRunner(tmp_path / "run")
    assert runner.cameras == [] and not runner.uses_objects


def test_state_still_refuses_a_recording_without_objects(tmp_path):
    from policies.data.dataset import build_dataset
    from policies.data.recordings import load_episodes
    from policies.labels.labelling import Thresholds
    from tests.policy_helpers import write_recording

    write_recording(tmp_path / "teleop.mcap", episodes=1, seconds=1.0, cameras=())
    eps, arms = load_episodes([tmp_path])
    with pytest.raises(UserError, match="privileged object state"):
        build_dataset(eps, arms, th=Thresholds.given(0.5, 1.0), observation="state")
    data = build_dataset(eps, arms, th=Thresholds.given(0.5, 1.0), observation="joints")
    assert data.objects is None and np.isfinite(data.state).all()
