"""One feature schema from the recording to the wire (#36), proven on two arms (SIMULATED, lockstep): a tiny
policy trained on a bimanual twin recording (sim-bimanual-piper, its scene camera) names its inputs and
outputs by the rig's declared features and rolls out through both followers' safety layers; a single-arm
rig is refused with one line."""

import numpy as np
import pytest

from factr2_teleop.session.rollout import RolloutOptions, run_rollout
from hardware.errors import UserError
from hardware.features import policy_names, rig_features
from hardware.recording.reader import Recording
from hardware.rigs.rig import load_rig
from policies.training.checkpoint import read_meta
from tests.rollout_helpers import record_rig_session, tiny_run_on

pytest.importorskip("mujoco")
RIG = "sim-bimanual-piper"


@pytest.fixture(scope="module")
def bimanual_run(tmp_path_factory):
    return tiny_run_on(tmp_path_factory, "bimanual", lambda d: record_rig_session(d, RIG, seconds=1.0),
                       steps=6)


def test_the_checkpoint_names_what_the_rig_declares(bimanual_run):
    feats = rig_features(load_rig(RIG))
    io = policy_names(feats, ["left_follower", "right_follower"], "tau_ext")
    f = read_meta(bimanual_run)["features"]
    assert f["observation.state"] == io["state"] and f["action"] == io["action"]
    assert f["observation.force"] == io["force"] and f["observation.images"] == ["observation.images.scene"]
    assert all(n in feats for n in f["observation.state"] + f["observation.force"] + f["action"])


def test_a_bimanual_policy_drives_both_arms_through_their_safety_layers(bimanual_run, tmp_path):
    out = run_rollout(RolloutOptions(rig=RIG, policy=bimanual_run, episodes=1, max_seconds=0.4, mode="dob",
                                     progress=False, record=tmp_path))
    t = out.timing
    assert out.arms == ["left_follower", "right_follower"] and len(out.episodes) == 1
    assert t["commands_sent"] > 0 and t["command_violations"] == 0 and t["end_follower_held"]
    rec = Recording(out.recording)
    (ep,) = rec.episodes
    for arm in out.arms:  # each follower took the policy's targets (not a hold) while the policy ran
        cmd = ep.topic(f"/{arm}/command")
        assert len(cmd) > 100 and np.isfinite(cmd.fields["q"]).all(1).mean() > 0.9, arm


def test_a_bimanual_policy_is_refused_on_a_single_arm_rig(bimanual_run):
    with pytest.raises(UserError, match="left_follower, right_follower; the rig has follower"):
        run_rollout(RolloutOptions(rig="sim-piper", policy=bimanual_run, episodes=1, progress=False))
