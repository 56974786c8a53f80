"""The one feature schema (hardware/features.py, #36): a recording declares its rig's features, a reader gets
the same names back (also from recordings made before the declaration was written), and a live follower's
observation is read by those names exactly as the recording holds them."""

import json

import numpy as np
import pytest

from hardware.features import (
    follower_arms,
    follower_values,
    policy_names,
    recorded_features,
    rig_arm_names,
    rig_features,
)
from hardware.recording import schemas as S
from hardware.recording.reader import Recording
from hardware.rigs.rig import load_rig
from hardware.types import JointState
from policies.data.recordings import arm_set, recording_features
from tests.rollout_helpers import record_rig_session

pytest.importorskip("mujoco")


@pytest.mark.parametrize("rig", ["sim-piper", "sim-bimanual-piper"])
def test_a_recording_declares_its_rigs_features(rig, tmp_path):
    rec = Recording(record_rig_session(tmp_path, load_rig(rig), seconds=0.1))
    feats = recording_features(rec)
    assert feats == rig_features(load_rig(rig))
    arms = [a for _p, a in rig_arm_names(load_rig(rig))]
    assert list(arm_set(rec).followers) == follower_arms(feats) == arms
    for f in feats.values():  # every declared numeric feature is where the declaration says
        if f.field and not f.privileged and f.topic in rec.topics:
            assert f.field in rec.topic(f.topic).fields, f.name


def test_old_recordings_give_the_same_policy_names():
    rig = load_rig("sim-bimanual-piper")
    joints = {f"{p}_{r}": [f"joint{i}" for i in range(6)] for p in ("left", "right")
              for r in ("leader", "follower")}
    topics = [S.joint_state_topic(a) for a in joints] + [S.command_topic("left_follower"),
                                                         S.command_topic("right_follower")]
    old = recorded_features({"joint_names": json.dumps(joints)}, topics)  # no "features" entry
    arms = follower_arms(old)
    assert arms == ["left_follower", "right_follower"]
    for force in ("tau_ext", "current", "none"):
        assert policy_names(old, arms, force) == policy_names(rig_features(rig), arms, force)
    damaged = recorded_features({"features": "{not json", "joint_names": json.dumps(joints)}, topics)
    assert damaged == old  # a damaged declaration: rebuilt as for an old recording


def test_a_live_observation_is_read_by_the_recorded_names():
    feats = rig_features(load_rig("sim-piper"))
    js = JointState(t=0.0, q=np.arange(6.0), q_dot=np.ones(6), tau_m=2 * np.ones(6), current=3 * np.ones(6),
                    q_cmd=np.zeros(6), temperature=np.zeros(6), status=np.zeros(6, np.uint32),
                    gripper_pos=0.02)
    tau = np.full(6, 0.5)
    obs = follower_values(feats, "follower", js, tau)
    assert set(obs) == {"follower.joint.pos", "follower.joint.vel", "follower.joint.tau",
                        "follower.joint.current", "follower.joint.tau_ext", "follower.gripper.pos"}
    for name, v in obs.items():
        f = feats[name]
        want = tau if f.topic == S.tau_ext_topic("follower") else getattr(js, f.field)
        assert np.array_equal(v, want), name
