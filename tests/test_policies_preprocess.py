"""One preprocessing pipeline (policies/data/preprocess.py): a camera frame recorded by the real recorder and
read by the dataset gives exactly the tensor the rollout builds from the same raw frame, through a checkpoint
written by training and loaded back; the pipeline round-trips through JSON; checkpoints written before it
load with the recorder's settings; recordings encoded differently are refused in one line; the dataset and
the export share one rule for a valid sample."""

from __future__ import annotations

import io

import numpy as np
import pytest
import torch
from PIL import Image

import tests.policy_helpers as H
from hardware.errors import UserError
from policies.data.dataset import valid_samples
from policies.data.preprocess import ImagePath, Preprocess, decode_resized, jpeg_settings, quality_settings

SIZE = 96  # the model's input [px]; 240 x 320 frames decode at half scale (JPEG draft) before the resize


def _raw_frames(monkeypatch) -> dict[int, list[np.ndarray]]:
    """Swap the helper's frames for 240 x 320 textured ones (gradients, noise, a moving square), keeping
    every raw frame handed to the recorder, per camera index, in recording order."""
    sent: dict[int, list[np.ndarray]] = {}

    def frame(k: int, cam: int, h: int = 240, w: int = 320) -> np.ndarray:
        rng = np.random.default_rng([k, cam])
        y, x = np.mgrid[0:h, 0:w]
        img = np.stack([x * 255 / w, y * 255 / h, np.full((h, w), 80.0 + 50 * cam)], -1)
        img = img + rng.normal(0, 12, (h, w, 3))
        img[40:90, (k * 3) % (w - 50):(k * 3) % (w - 50) + 50] = 250
        img = img.clip(0, 255).astype(np.uint8)
        sent.setdefault(cam, []).append(img)
        return img

    monkeypatch.setattr(H, "_frame", frame)
    return sent


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """(recording folder, raw frames per camera index, a run trained on it)."""
    from policies.training.run import RunOptions, run_training
    from policies.training.train import Dist, TrainConfig

    mp = pytest.MonkeyPatch()
    try:
        sent = _raw_frames(mp)
        d = tmp_path_factory.mktemp("prep")
        H.write_recording(d / "rec" / "a.mcap", episodes=2, seconds=2.0)
    finally:
        mp.undo()
    torch.set_num_threads(1)
    tiny = dict(hidden=32, heads=2, enc_layers=1, dec_layers=1, ff=64, backbone="convnet-gn", image_size=SIZE,
                dropout=0.0, chunk=8)
    run = d / "run"
    run_training(RunOptions(inputs=[d / "rec"], out=run, policy="act", thresholds=(1.0, 3.0), progress=False,
                            overrides=tiny, val_fraction=0.0,
                            train=TrainConfig(steps=1, batch=4, warmup=1, val_every=1000, ckpt_every=1000,
                                              threads=1)), Dist())
    return d / "rec", sent, run


def test_the_same_frame_gives_the_same_tensor_in_training_and_at_rollout(recorded):
    """Training path: raw RGB -> the recorder's JPEG (writer process) -> the dataset (frame cache, batch).
    Rollout path: the same raw RGB -> PolicyRunner.batch with the pipeline loaded from the checkpoint.
    Equal to the bit, state and force included; the old rollout path (resize the raw RGB) was not."""
    from policies.data.dataset import build_dataset
    from policies.data.recordings import load_episodes
    from policies.labels.labelling import Thresholds
    from policies.rollout.runner import PolicyRunner

    rec_dir, sent, run = recorded
    runner = PolicyRunner(run)
    episodes, arms = load_episodes([rec_dir])
    data = build_dataset(episodes, arms, th=Thresholds.given(1.0, 3.0), chunk=runner.cfg.chunk,
                         image_size=runner.cfg.image_size, val_fraction=0.0)
    cams = data.names.cameras
    assert cams == ["top", "wrist"] and runner.cameras == cams and len(data) > 20
    cam_index = {"wrist": 0, "top": 1}  # write_recording's camera order
    old_differs = 0
    for i in range(0, len(data), 7):
        obs = {"follower.joint.pos": data.state[i, :6], "follower.gripper.pos": data.state[i, 6],
               "follower.joint.tau_ext": data.force[i]}
        for m, cam in enumerate(cams):
            obs[f"observation.images.{cam}"] = sent[cam_index[cam]][int(data.frame_idx[i, m])]
        live, trained = runner.batch(obs), data.batch(np.array([i]))
        assert set(live) == {"state", "force", "images"}
        for k in live:
            assert live[k].dtype == trained[k].dtype and torch.equal(live[k], trained[k]), (i, k)
        raw = np.stack([np.asarray(Image.fromarray(obs[f"observation.images.{c}"]).resize(
            (SIZE, SIZE), Image.BILINEAR)) for c in cams])[None]
        old_differs += not np.array_equal(raw, trained["images"].numpy())
    assert old_differs > 0  # the test can fail: without the encode, rollout saw other pixels


def test_the_checkpoint_holds_the_pipeline_and_the_recorders_settings(recorded):
    from hardware.recording.reader import Recording
    from hardware.recording.writer import JPEG_QUALITY
    from policies.training.checkpoint import load_policy

    rec_dir, _, run = recorded
    _, meta, pre = load_policy(run)
    assert meta["preprocess"] == pre.to_dict() and "normalizer" not in meta
    assert pre.image.size == SIZE and set(pre.image.jpeg) == {"top", "wrist"}
    assert pre.image.jpeg["top"] == quality_settings(JPEG_QUALITY)  # read back from the recorded frames
    again = Preprocess.from_meta({"preprocess": pre.to_dict()})
    assert again.to_dict() == pre.to_dict() and again.image == pre.image
    # a checkpoint from before the pipeline was saved: the normaliser, the policy's size, the recorder's q
    legacy = {k: v for k, v in meta.items() if k != "preprocess"}
    legacy["normalizer"] = pre.norm.to_dict()
    old = Preprocess.from_meta(legacy)
    assert old.to_dict() == pre.to_dict()
    frame = Recording(next(rec_dir.glob("*.mcap"))).frames("wrist").jpeg(0)
    assert jpeg_settings(frame) == old.image.jpeg["wrist"]


def test_a_live_frame_is_encoded_as_the_recording_encoded_it():
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (120, 160, 3), dtype=np.uint8)
    for quality in (40, 85):
        buf = io.BytesIO()
        Image.fromarray(rgb).save(buf, format="JPEG", quality=quality)
        image = ImagePath(48, {"cam": jpeg_settings(buf.getvalue())})
        assert np.array_equal(image.live("cam", rgb), decode_resized(buf.getvalue(), 48))
    assert quality_settings(40) != quality_settings(85)


class _FakeFrames:
    """One camera's recorded frames: a single JPEG of the given quality."""

    def __init__(self, quality: int):
        buf = io.BytesIO()
        Image.new("RGB", (16, 16)).save(buf, format="JPEG", quality=quality)
        self._jpeg = buf.getvalue()

    def __len__(self) -> int:
        return 1

    def jpeg(self, i: int) -> bytes:
        return self._jpeg


def _fake_recording(quality: int, path: str):
    from types import SimpleNamespace

    return SimpleNamespace(path=path, frames=lambda cam: _FakeFrames(quality))


def test_recordings_encoded_differently_are_refused_in_one_line():
    same = ImagePath.from_recordings([_fake_recording(85, "a"), _fake_recording(85, "b")], ["c"], 32)
    assert same.jpeg["c"] == quality_settings(85)
    with pytest.raises(UserError) as e:
        ImagePath.from_recordings([_fake_recording(85, "a"), _fake_recording(60, "b")], ["c"], 32)
    assert "\n" not in str(e.value) and str(e.value).startswith("b: camera c") and "fix:" in str(e.value)


def test_a_checkpoint_with_an_unknown_decode_is_refused_in_one_line():
    from hardware.errors import ConfigError

    pre = Preprocess.from_meta({"preprocess": {"normalizer": {}, "image": {"size": 32}}})
    d = pre.to_dict()
    d["image"]["decode"] = "something-else"
    with pytest.raises(ConfigError) as e:
        Preprocess.from_meta({"preprocess": d, "_path": "RUN/step.json"})
    assert "\n" not in str(e.value) and "RUN/step.json" in str(e.value)


def test_one_rule_for_a_valid_sample():
    state = np.array([[0.0, 1.0], [np.nan, 1.0], [0.0, 1.0], [0.0, 1.0], [0.0, 1.0]])
    action = np.array([[0.0], [0.0], [np.inf], [0.0], [0.0]])
    objects = np.array([[1.0], [1.0], [1.0], [np.nan], [1.0]])
    frames = np.array([[0, 0], [0, 0], [0, 0], [0, 0], [-1, 3]])
    assert valid_samples(state, action).tolist() == [True, False, False, True, True]
    assert valid_samples(state, action, objects, frames).tolist() == [True, False, False, False, False]
    no_camera = np.zeros((5, 0), int)
    assert valid_samples(state, action, None, no_camera).tolist() == [True, False, False, True, True]


def test_relative_action_frame_round_trips_and_keeps_grippers_absolute():
    """to_frame / from_frame are inverses; only joint-position columns move with the observed state; the
    relative frame's normaliser is per chunk step (a checkpoint's preprocess gives it back)."""
    from policies.data.normalizer import Normalizer
    from policies.data.preprocess import ImagePath, Preprocess, from_frame, relative_columns, to_frame

    rel = relative_columns(["a.joint.pos", "a.gripper.pos"], {"a.joint.pos": 3, "a.gripper.pos": 1})
    assert rel == [True, True, True, False]
    rng = np.random.default_rng(0)
    state = rng.normal(size=(5, 4)).astype(np.float32)
    act = rng.normal(size=(5, 6, 4)).astype(np.float32)
    z = to_frame(act, state, np.asarray(rel))
    assert np.allclose(z[..., 3], act[..., 3]) and np.allclose(z[..., :3], act[..., :3] - state[:, None, :3])
    assert np.allclose(from_frame(z, state, np.asarray(rel)), act, atol=1e-6)
    norm = Normalizer.fit({"action": z.reshape(5, -1)})
    pre = Preprocess(norm, ImagePath(8), "relative", rel)
    back = Preprocess.from_meta({"preprocess": pre.to_dict()})
    assert back.action_frame == "relative" and back.relative == rel
    t = back.targets(act, state)
    assert t.shape == act.shape and abs(float(t.mean())) < 1e-5  # normalised per step and value
    assert np.allclose(back.actions(t[2], state[2]), act[2], atol=1e-5)
    absolute = Preprocess(Normalizer.fit({"action": act[:, 0]}), ImagePath(8))
    assert "action_frame" not in absolute.to_dict()  # checkpoints before the choice read back the same
