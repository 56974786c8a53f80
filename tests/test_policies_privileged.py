"""The PRIVILEGED state observation (SIMULATED): the twin task's object vector, its order, its recording by
`factr2 collect`, and a policy trained on it (`--obs state`) without camera frames."""

import numpy as np
import pytest

from hardware.errors import UserError
from hardware.recording import schemas as S
from policies.data.privileged import objects_vector, task_state_vector

mujoco = pytest.importorskip("mujoco")


def _live(task_name: str, seed: int = 3):
    from hardware.arms import load_arm
    from hardware.sim.tasks import get_task, scene_model

    task = get_task(task_name)
    model = scene_model(load_arm("piper"), "table", task)
    data = mujoco.MjData(model)
    params = task.reset(model, data, np.random.default_rng(seed))
    mujoco.mj_forward(model, data)
    return task, model, data, params


def test_vector_order_is_observe_then_the_episode_params():
    task, model, data, params = _live("peg-insert")
    vec = task_state_vector(task, model, data, params)
    obs = task.observe(model, data, params)
    same, names = objects_vector(obs, params)
    assert vec.dtype == np.float32 and vec.shape == (25,) and np.array_equal(vec, same)
    keys = list(dict.fromkeys(n.rsplit(".", 1)[0] for n in names))
    assert keys == ["peg_pos", "peg_rot", "hole_pos", "hole_yaw", "finger_touch", "peg_to_hole", "peg_start"]
    assert np.allclose(vec[0:3], obs["peg_pos"]) and np.allclose(vec[3:12], obs["peg_rot"].ravel())
    assert np.allclose(vec[12:15], params["hole_pos"]) and np.isclose(vec[15], params["hole_yaw"])
    assert set(vec[16:18]) <= {0.0, 1.0}  # finger contacts as 0 / 1
    from hardware.sim.tasks.peg_insert import peg_metrics
    m = peg_metrics(obs["peg_pos"], obs["peg_rot"], params["hole_pos"], params["hole_yaw"])
    assert np.allclose(vec[18:20], m["lateral_m"]) and np.isclose(vec[21], m["yaw_err_rad"], atol=1e-6)
    # wipe: observe() has no mark pose; the params supply it (else a policy could not know where to wipe)
    task, model, data, params = _live("wipe")
    vec, names = objects_vector(task.observe(model, data, params), params)
    assert names == ["tip_pos.0", "tip_pos.1", "tip_pos.2", "force_n.0", "area_pos.0", "area_pos.1",
                     "area_pos.2", "area_yaw.0"]
    assert np.allclose(vec[4:7], params["area_pos"])


def test_state_observation_needs_the_recorded_object_vector(tmp_path):
    from policies.data.dataset import build_dataset
    from policies.data.recordings import load_episodes
    from policies.labels.labelling import Thresholds
    from tests.policy_helpers import write_recording

    write_recording(tmp_path / "teleop.mcap", episodes=1, seconds=1.0)  # a teleop session: no task objects
    eps, arms = load_episodes([tmp_path])
    with pytest.raises(UserError, match="privileged object state"):
        build_dataset(eps, arms, th=Thresholds.given(0.5, 1.0), observation="state")


def test_collected_episode_trains_a_state_policy_without_frames(tmp_path):
    from factr2_teleop.tasks.run import CollectConfig, collect
    from hardware.recording.reader import Recording

    out = collect(CollectConfig(task="wipe", episodes=1, out=str(tmp_path / "demos"), seed=0,
                                mode="ground_truth", cameras=False), progress=False)
    rec = Recording(out["recording"])
    assert S.TOPIC_TASK_OBJECTS in rec.topics and not rec.cameras
    assert rec.task_object_names()[4:] == ["area_pos.0", "area_pos.1", "area_pos.2", "area_yaw.0"]
    (ep,) = rec.episodes
    t, vals = ep.signals()[S.TASK_OBJECTS_FEATURE]
    assert vals.shape[1] == 8 and len(t) > 100 and np.isfinite(vals).all()
    area = np.asarray(out["results"][0]["params"]["area_pos"])
    assert np.allclose(vals[:, 4:7], area, atol=1e-6)  # the mark does not move during the episode

    from tests.policy_helpers import train_tiny

    model, meta, pre = train_tiny(tmp_path / "demos", tmp_path / "run", "state")
    assert meta["observation"] == "state" and meta["policy"]["objects_dim"] == 8
    assert meta["features"]["observation.images"] == [] and len(meta["features"][S.TASK_OBJECTS_FEATURE]) == 8
    assert model.obs.backbone is None  # no image encoder at all
    assert "objects" in pre.norm.mean and pre.norm.mean["objects"].shape == (8,)
    # the live input the rollout builds: same vector, normalised with the checkpoint's statistics
    task, m, d, params = _live("wipe")
    import torch

    objects = torch.from_numpy(pre.norm.norm("objects", task_state_vector(task, m, d, params)[None]))
    batch = {"state": torch.zeros(1, 7), "force": torch.zeros(1, 6), "objects": objects}
    noise = type(model).draw_noise(model.cfg, 1, torch.Generator().manual_seed(0))
    chunk = model.predict(batch, noise)
    assert chunk.shape == (1, 8, 7) and torch.isfinite(chunk).all()
