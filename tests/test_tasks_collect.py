"""One scripted demonstration through the full teleop stack (SIMULATED, lockstep): the operator's hand on the
leader only, the episode's stages and outcome in the session's MCAP, camera frames that read back."""

import json

import numpy as np
import pytest

from factr2_teleop.tasks.run import CollectConfig, collect
from hardware.recording.reader import Recording


def test_one_wipe_demonstration_is_recorded_with_stages_outcome_and_frames(tmp_path):
    pytest.importorskip("mujoco")
    try:
        from hardware.cameras.offscreen_gl import make_renderer  # noqa: F401
    except Exception:  # pragma: no cover
        pytest.skip("no OpenGL")
    out = collect(CollectConfig(task="wipe", episodes=1, out=str(tmp_path), seed=0, mode="ground_truth"),
                  progress=False)
    assert out["episodes"] == 1 and out["simulated"]
    res = out["results"][0]
    assert res["outcome"] in ("success", "failure")
    rec = Recording(out["recording"])
    (ep,) = rec.episodes
    assert ep.outcome == res["outcome"] and ep.task == "wipe"
    reached = [label for _, _, label in ep.progress]
    assert reached == [s for s in ("reach", "contact", "coverage") if res["stages"][s] is not None]
    assert reached[:2] == ["reach", "contact"]  # the operator got the fingers onto the mark, pressing
    values = [v for _, v, _ in ep.progress]
    assert np.allclose(values, np.arange(1, len(values) + 1) / 3)
    stop = json.loads([e["text"] for e in ep.events if e["kind"] == "stop"][0])
    assert stop["outcome"] == res["outcome"]
    assert set(rec.cameras) == {"scene", "wrist"}
    frames = ep.frames("wrist")
    assert len(frames) > 10 and frames.rgb(0).shape == (240, 320, 3)
    assert (tmp_path / "wipe-sim-piper-seed0.json").is_file()


def test_collect_summary_shows_the_labels_training_makes_of_the_recording(tmp_path):
    """The summary's phase shares are those `factr2 train` / `factr2 episodes phases` give the written file
    (the recording's thresholds on the tared score), not a label of the live scores of another kind."""
    pytest.importorskip("mujoco")
    from pathlib import Path

    from policies.data.recordings import load_episodes
    from policies.labels import labelling as L

    ck = Path(__file__).resolve().parents[1] / "bench/assets/next_sim_piper_first/next.json"
    out = collect(CollectConfig(task="wipe", episodes=1, out=str(tmp_path), seed=0, mode="next",
                                checkpoint=str(ck), cameras=False), progress=False)
    episodes, arms = load_episodes([out["recording"]])
    th = L.resolve_thresholds("recording", None, episodes, arms)
    phases = np.concatenate([L.label_episode(e, arms, th).phases for e in episodes])
    want = np.bincount(phases.astype(np.int64), minlength=3)[:3] / len(phases)
    sh = out["phase_shares"]
    assert [sh["free"], sh["pre_contact"], sh["contact"]] == pytest.approx(want.tolist())
    assert out["phase_thresholds_nm"] == pytest.approx([th.t_low, th.t_high])
    assert sh["contact"] > 0.2 and out["phase_labels"] == f"tare {th.tare}"  # wiping presses most of the time
    from factr2_teleop.tasks.run import summary_lines

    assert any("as `factr2 train` makes them" in ln for ln in summary_lines(out))
