"""Round trip of every channel through Recorder -> MCAP -> Recording (uncached and cached)."""

from __future__ import annotations

import json
import time
import warnings

import numpy as np
from mcap.reader import make_reader
from recording_helpers import NAMES, gradient_frame, joint_state, record_session

from hardware.recording import Recording, cache
from hardware.recording.cache import cache_dir


def test_every_channel_round_trips(tmp_path):
    path = tmp_path / "s.mcap"
    st = record_session(path, n=600, episodes=2).close()
    assert st.error is None and st.dropped_samples == 0 and st.dropped_frames == 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a clean file reads without any warning
        rec = Recording(path)
    assert not rec.truncated and not rec.from_cache
    assert rec.topics == sorted(["/leader/joint_state", "/follower/joint_state", "/follower/tau_ext",
                                 "/leader/tau_cmd", "/follower/ground_truth", "/loop/timing"])
    assert rec.joint_names("follower") == NAMES
    js = rec.topic("/follower/joint_state")
    k = np.arange(1300)
    k = k[(k < 600) | (k >= 700)]
    assert np.array_equal(js.t, k * 1e-3)
    for i in (0, 1, 601, 1299 - 100):
        ref = joint_state(int(k[i]))
        for f in ("q", "q_dot", "tau_m", "current", "q_cmd", "temperature"):
            # 9 significant digits on disk (schemas.encode_numeric); NaN stays NaN
            np.testing.assert_allclose(js.fields[f][i], getattr(ref, f), rtol=1e-8, atol=1e-12)
        np.testing.assert_array_equal(js.fields["status"][i], ref.status)
        assert js.fields["gripper_pos"][i] == ref.gripper_pos and np.isnan(js.fields["gripper_effort"][i])
    te = rec.topic("/follower/tau_ext")
    assert te.fields["contact"].dtype == bool and te.fields["tau_ext"].shape == (1200, 6)
    gt = rec.topic("/follower/ground_truth")
    np.testing.assert_array_equal(gt.fields["force"][5], [1.0, 2.0, 3.0])
    assert np.all(rec.topic("/leader/tau_cmd").fields["gate"] == 0.5)
    assert np.all(rec.topic("/loop/timing").fields["busy_s"] == 2e-4)
    eps = rec.episodes
    assert [e.outcome for e in eps] == ["success", "failure"] and [e.task for e in eps] == ["task0", "task1"]
    assert abs(eps[1].t_start - 0.7) < 1e-12 and abs(eps[0].duration_s - 0.6) < 1e-12
    assert eps[0].notes == ["looked fine"] and eps[0].progress == [(0.25, 0.5, "halfway")]
    assert len(eps[1].topic("/follower/joint_state")) == 600  # ticks 700..1299
    fr = rec.frames("wrist")
    assert len(fr) == len([i for i in k if i % 33 == 0])
    img = fr.rgb(1)
    assert img.shape == (48, 64, 3)
    assert np.abs(img.astype(int) - gradient_frame(shift=33)).mean() < 3  # JPEG, quality 85
    assert abs(fr.t[1] - 0.033) < 1e-6
    # cached: same arrays, no MCAP decoding
    rec2 = Recording(path)
    assert rec2.from_cache and cache_dir(path).is_dir()
    np.testing.assert_array_equal(rec2.topic("/follower/joint_state").fields["q_cmd"], js.fields["q_cmd"])
    assert rec2.episodes[0].progress == eps[0].progress
    assert rec2.frames("wrist").jpeg(2) == fr.jpeg(2)


def test_standard_mcap_reader_and_foxglove_payloads(tmp_path):
    path = tmp_path / "s.mcap"
    record_session(path, n=200).close()
    counts: dict[str, int] = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count > 0
        for schema, channel, message in reader.iter_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            if channel.message_encoding == "json":
                json.loads(schema.data)
                json.loads(message.data, parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))
            else:
                assert schema.name == "foxglove.CompressedImage" and schema.encoding == "protobuf"
    assert counts["/follower/joint_state"] == 200 and counts["/camera/wrist/image"] == 7
    assert counts["/events"] == 4  # start, note, stop, success


def test_resample_and_plain_log(tmp_path):
    path = tmp_path / "s.mcap"
    record_session(path, n=1000, cameras=False).close()
    ep = Recording(path).episodes[0]
    grid = ep.resample(rate_hz=100.0)
    assert grid["t"].shape == (101,)
    np.testing.assert_allclose(grid["follower.joint.pos"][10], joint_state(100).q, rtol=1e-8)
    assert grid["follower.contact"].dtype == bool and grid["follower.joint.status"].dtype.kind in "iu"
    mid = ep.resample(np.array([0.0105, -1.0]))
    np.testing.assert_allclose(mid["follower.joint.pos"][0], (joint_state(10).q + joint_state(11).q) / 2,
                               rtol=1e-8)
    assert np.all(np.isnan(mid["follower.joint.pos"][1]))  # never extrapolated
    log = ep.to_plain("follower")
    assert log.q.shape == (1000, 6) and log.units == "N*m" and log.joint_names == NAMES
    assert log.contact is not None and log.contact.dtype == bool and log.tau_ext_true.shape == (1000, 6)
    np.testing.assert_allclose(log.force[3], [1, 2, 3])


def test_cached_read_speed(tmp_path):
    """>= 1e6 joint-state samples/s from the cache: a short real recording whose cache is then filled with
    200k samples per arm (decoding that many messages would make the test slow; the load path is the same)."""
    path = tmp_path / "s.mcap"
    record_session(path, n=50, cameras=False).close()
    dec = cache.decode(path)
    n = 200_000
    for arm in ("leader", "follower"):
        ta = dec.topics[f"/{arm}/joint_state"]
        ta.t = np.arange(n) * 1e-3
        ta.fields = {k: np.resize(v, (n,) + v.shape[1:]) for k, v in ta.fields.items()}
    cache.save(dec, cache.cache_key(path))
    dts = []
    for _ in range(3):  # best of 3: the disk is shared with other jobs
        t0 = time.perf_counter()
        rec = Recording(path)
        js = [rec.topic(f"/{arm}/joint_state") for arm in ("leader", "follower")]
        # what NEXT training reads: t, q, q_dot, q_cmd, tau_m of both arms
        total = sum(float(j.fields[f].sum()) for j in js for f in ("q", "q_dot", "q_cmd", "tau_m"))
        dts.append(time.perf_counter() - t0)
    dt = min(dts)
    assert rec.from_cache and js[1].fields["q"].shape == (n, 6) and not np.isinf(total)
    assert 2 * n / dt > 1e6, f"{2 * n / dt:.3g} joint-state samples/s from the cache"


def test_caches_stay_out_of_the_data_folder(tmp_path):
    """The array cache and the policies' frame cache live in the user's cache folder, not beside the
    recording: a `factr2 collect` folder holds only what was recorded."""
    from policies.data.frame_cache import camera_frames

    path = tmp_path / "data" / "s.mcap"
    path.parent.mkdir()
    record_session(path, n=200).close()
    rec = Recording(path)
    camera_frames(rec, rec.cameras[0], 16)
    assert Recording(path).from_cache
    assert sorted(p.name for p in path.parent.iterdir()) == ["s.mcap"]
