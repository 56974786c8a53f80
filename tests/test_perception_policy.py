"""The perceived observation end to end (SIMULATED): `factr2 collect` records the detector's report live on
/perceived/objects, `--obs perceived` trains on it, a rollout runs the detector live with the episode's seed;
the operator can see through it (tasks/seen.py)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from factr2_teleop.tasks.seen import OperatorView, carried, substitute
from hardware.recording import schemas as S
from hardware.sim.perception import NEVER, Seen
from policies.data.privileged import OBSERVATIONS, low_dimensional, objects_feature, uses_images, uses_objects

mujoco = pytest.importorskip("mujoco")


def test_observation_names():
    assert {"perceived", "images+perceived"} <= set(OBSERVATIONS)
    assert objects_feature("perceived") == S.PERCEIVED_FEATURE == "observation.perceived.objects"
    assert objects_feature("images+state") == S.TASK_OBJECTS_FEATURE and objects_feature("images") is None
    assert uses_objects("images+perceived") and uses_images("images+perceived")
    assert low_dimensional("perceived") and low_dimensional("state") and not low_dimensional("images+state")
    from policies.models.config import default_preset

    assert default_preset("perceived") == "state" and default_preset("images+perceived") == "small"


def _T(p):
    T = np.eye(4)
    T[:3, 3] = p
    return T


def test_operator_view_sees_the_detector_and_carries_a_held_hidden_object():
    obs = {"peg_pos": np.zeros(3), "peg_rot": np.eye(3), "hole_pos": np.zeros(3), "hole_yaw": 0.0,
           "finger_touch": np.array([False, False])}
    params = {"hole_pos": np.zeros(3), "hole_yaw": 0.0, "peg_start": np.ones(3)}
    yaw = 0.3
    Rz = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1.0]])
    seen = {"peg": Seen(np.array([0.30, -0.10, 0.03]), np.eye(3), 0.1, True),
            "hole": Seen(np.array([0.29, 0.11, 0.004]), Rz, 0.1, True)}
    view = OperatorView()
    o, p = view.look(obs, params, seen, _T([0.3, -0.1, 0.1]))
    assert np.allclose(o["peg_pos"], [0.30, -0.10, 0.03]) and np.allclose(p["hole_pos"], [0.29, 0.11, 0.004])
    assert p["hole_yaw"] == pytest.approx(yaw) and o["hole_yaw"] == pytest.approx(yaw)
    assert np.array_equal(p["peg_start"], params["peg_start"])  # not a detectable: untouched
    assert np.array_equal(params["hole_pos"], np.zeros(3))  # the inputs are not changed
    # grasped (fingers on it), then the hand hides it and lifts 5 cm: the operator believes it came along
    held = dict(obs, finger_touch=np.array([True, True]))
    view.look(held, params, seen, _T([0.3, -0.1, 0.05]))
    hidden = dict(seen, peg=Seen(seen["peg"].pos_m, np.eye(3), 0.5, False))
    o, _ = view.look(held, params, hidden, _T([0.3, -0.1, 0.10]))
    assert np.allclose(o["peg_pos"], [0.30, -0.10, 0.08])
    # let go: what the camera last saw again
    o, _ = view.look(obs, params, hidden, _T([0.3, -0.1, 0.10]))
    assert np.allclose(o["peg_pos"], [0.30, -0.10, 0.03])
    # never seen: NaN, never the truth
    o, p = OperatorView().look(obs, params, {"peg": NEVER, "hole": NEVER}, _T([0, 0, 0]))
    assert np.isnan(o["peg_pos"]).all() and np.isnan(p["hole_pos"]).all()


def test_carried_and_substitute_are_pure():
    p, R = carried(_T([0, 0, 0.2]), _T([0, 0, 0.1]), np.array([1.0, 0, 0]), np.eye(3))
    assert np.allclose(p, [1.0, 0, 0.1]) and np.allclose(R, np.eye(3))
    d = {"area_pos": np.zeros(3), "area_yaw": 0.0, "tip_pos": np.ones(3)}
    out = substitute(d, "area", np.array([1.0, 2.0, 0.0]), np.eye(3))
    assert np.allclose(out["area_pos"], [1, 2, 0]) and out["area_yaw"] == 0.0 and d["area_pos"][0] == 0.0


def test_collect_train_rollout_on_the_perceived_observation(tmp_path):
    from factr2_teleop.tasks.run import CollectConfig, collect
    from hardware.recording.reader import Recording
    from policies.rollout.runner import PolicyRunner

    out = collect(CollectConfig(task="wipe", episodes=1, out=str(tmp_path / "demos"), seed=0,
                                mode="ground_truth", cameras=False, perception=True), progress=False)
    assert out["operator_sees"] == "perceived"
    rec = Recording(out["recording"])
    assert {S.TOPIC_PERCEIVED, S.TOPIC_TASK_OBJECTS} <= set(rec.topics)
    names = rec.task_object_names(S.TOPIC_PERCEIVED)
    assert names[:3] == ["area.pos_m.0", "area.pos_m.1", "area.pos_m.2"] and names[-2:] == ["area.visible",
                                                                                             "area.age_s"]
    (ep,) = rec.episodes
    t, seen = ep.signals()[S.PERCEIVED_FEATURE]
    _, truth = ep.signals()[S.TASK_OBJECTS_FEATURE]
    assert seen.shape[1] == 11 and np.isfinite(seen).all() and len(t) > 100
    area = np.asarray(out["results"][0]["params"]["area_pos"])
    err = seen[:, :3] - area
    assert 0 < np.abs(err[seen[:, 9] == 1]).max() < 0.03  # biased and noisy, by millimetres, not the truth
    assert np.allclose(truth[:, 4:7], area, atol=1e-6)  # the privileged vector is still the truth
    assert set(np.unique(seen[:, 9])) <= {0.0, 1.0} and (seen[:, 9] == 0).any()  # occluded while wiping
    meta = json.loads((tmp_path / "demos" / "wipe-sim-piper-seed0.json").read_text())
    assert meta["operator_sees"] == "perceived"

    from tests.policy_helpers import train_tiny

    run = tmp_path / "run"
    _, meta, pre = train_tiny(tmp_path / "demos", run, "perceived")
    assert meta["observation"] == "perceived" and meta["policy"]["objects_dim"] == 11
    assert meta["features"][S.PERCEIVED_FEATURE] == names and S.TASK_OBJECTS_FEATURE not in meta["features"]
    assert PolicyRunner(run).object_feature == S.PERCEIVED_FEATURE

    roll = tmp_path / "roll"
    cmd = ["rollout", "--policy", str(run), "--task", "wipe", "--episodes", "1", "--seed", "7", "--record",
           str(roll), "--max-seconds", "1.5", "--json", str(tmp_path / "roll.json")]
    r = subprocess.run([sys.executable, "-m", "factr2_teleop.cli", *cmd], capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stderr[-800:]
    (path,) = sorted(roll.glob("*.mcap"))
    rrec = Recording(path)
    (rep,) = rrec.episodes
    _, live = rep.signals()[S.PERCEIVED_FEATURE]
    assert live.shape[1] == 11 and np.isfinite(live).all() and (live[:, 9] == 1).any()


def test_collect_flag_and_task_default():
    import argparse

    from factr2_teleop.commands.collect import add_arguments
    from hardware.sim.tasks import get_task

    ap = argparse.ArgumentParser()
    add_arguments(ap)
    base = ["--task", "peg-insert", "--out", "x"]
    assert ap.parse_args(base).perception is None  # the task's choice
    assert ap.parse_args([*base, "--perception"]).perception is True
    assert ap.parse_args([*base, "--no-perception"]).perception is False
    assert not any(get_task(n).operator_perception for n in ("peg-insert", "press-fit", "wipe"))
