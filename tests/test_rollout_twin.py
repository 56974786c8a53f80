"""Policy rollout on the sim-piper twin through the real drivers (SIMULATED, lockstep): a tiny ACT policy
trained here on a short recording of the task rig; NaN / far targets never reach the motors outside the
limits; a stalled policy holds within 250 ms; Ctrl-C leaves the follower held and the leader at zero
torque; a checkpoint for another arm, joint set or cameras is refused with one line (exit 2)."""

import json
import shutil
import time

import numpy as np
import pytest

from factr2_teleop.cli import main
from factr2_teleop.session.rollout import RolloutOptions, run_rollout
from factr2_teleop.session.task_episodes import episode_seed
from hardware.recording import schemas as S
from hardware.recording.reader import Recording
from policies.rollout.runner import PolicyRunner
from policies.rollout.schedule import STALL_S, Chunk
from tests.rollout_helpers import record_task_session, tiny_run_on

pytest.importorskip("mujoco")


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    return tiny_run_on(tmp_path_factory, "rollout", lambda d: record_task_session(d, seconds=1.2))


def _opts(run, **kw):
    base = dict(rig="sim-piper", policy=run, task="peg-insert", episodes=1, seed=5, max_seconds=0.5,
                mode="dob", progress=False)
    return RolloutOptions(**{**base, **kw})


@pytest.fixture(scope="module")
def recorded_rollout(tiny_run, tmp_path_factory):
    """Two recorded episodes of the tiny policy (seed 5) and the seeds its sampler was reseeded with: one run,
    read by the two tests below."""
    seeds = []
    real = PolicyRunner.reseed
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(PolicyRunner, "reseed", lambda self, s: (seeds.append(s), real(self, s))[1])
        out = run_rollout(_opts(tiny_run, episodes=2, record=tmp_path_factory.mktemp("recorded"))).to_dict()
    return out, seeds


def test_tiny_policy_rolls_out_through_the_real_drivers_and_records(recorded_rollout):
    out, _ = recorded_rollout
    t = out["timing"]
    assert [e["seed"] for e in out["episodes"]] == [episode_seed(5, 0), episode_seed(5, 1)]
    assert all(e["outcome"] in ("success", "failure") for e in out["episodes"])
    assert out["schedule"] == "ensemble" and set(out["stage_rates"]) == {"grasp", "align", "insert"}
    assert t["chunks"] >= 15  # a chunk every policy step (ensembling) once both cameras have a frame
    assert t["refused_nonfinite"] == 0 and t["refused_outside_limits"] == 0 and t["holds"] == {}
    assert t["commands_sent"] > 400 and t["command_violations"] == 0
    assert 0 <= t["action_age_mean_ms"] <= 1e3 / 29.4 + 1  # lockstep inference: age < one policy step
    assert t["loop_rate_hz"] == pytest.approx(500, rel=1e-6) and t["end_follower_held"]
    rec = Recording(out["recording"])
    eps = rec.episodes
    assert [e.outcome for e in eps] == [e["outcome"] for e in out["episodes"]] and eps[0].task == "peg-insert"
    assert out["episodes_not_as_judged"] == [] and not out["recording_recovered"]  # the file agrees
    ep = eps[0]
    for topic in (S.command_topic("follower"), S.tau_ext_topic("follower"), S.TOPIC_TASK_OBJECTS):
        assert len(ep.topic(topic)) > 10, topic
    assert set(rec.cameras) == {"scene", "wrist"} and len(eps[-1].frames("wrist")) >= 10
    stop = json.loads([e["text"] for e in ep.events if e["kind"] == "stop"][0])
    assert stop["seed"] == episode_seed(5, 0)


def test_each_episode_draws_the_samplers_noise_from_its_own_seed(recorded_rollout):
    """The flow sampler is reseeded with each episode's seed as the policy takes over: an episode's noise does
    not depend on how the episodes before it went (a benchmark's rollout set is repeatable episode by
    episode)."""
    out, seeds = recorded_rollout
    assert seeds == [e["seed"] for e in out["episodes"]] == [episode_seed(5, 0), episode_seed(5, 1)]


def test_record_without_cameras_keeps_the_policys_frames_out_of_the_file(tiny_run, tmp_path):
    """`factr2 rollout --record DIR --no-cameras`: the policy (it looks) still gets its frames, the file
    holds none."""
    out = run_rollout(_opts(tiny_run, record=tmp_path, record_cameras=False)).to_dict()
    assert out["timing"]["chunks"] >= 5  # the image policy ran: its cameras were served
    rec = Recording(out["recording"])
    assert rec.cameras == [] and len(rec.episodes[0].topic(S.command_topic("follower"))) > 10


def _corrupt(monkeypatch, fn):
    real = PolicyRunner.infer

    def infer(self, obs, t_obs, seq=0):
        c = real(self, obs, t_obs, seq)
        a = fn(seq, c.actions.copy())
        return Chunk(t_obs=c.t_obs, actions=a, dt=c.dt, seq=seq, latency_s=c.latency_s)

    monkeypatch.setattr(PolicyRunner, "infer", infer)


def test_nan_and_far_targets_never_reach_the_motors_outside_the_limits(tiny_run, monkeypatch):
    def bad(seq, a):
        if seq % 3 == 1:
            a[2:, 1] = np.nan
        elif seq % 3 == 2:
            a[:, 1] += 10.0  # rad: far beyond joint 2's range
        return a

    _corrupt(monkeypatch, bad)
    t = run_rollout(_opts(tiny_run, schedule="receding", k_exec=2)).timing
    assert t["refused_nonfinite"] >= 2 and t["refused_outside_limits"] >= 2
    assert t["commands_sent"] > 100 and t["command_violations"] == 0  # checked at the wire
    assert t["holds"].get("policy output not finite", 0) >= 1
    assert t["holds"].get("policy target outside the joint limits", 0) >= 1


def test_a_stalled_policy_holds_within_250_ms(tiny_run, monkeypatch):
    delivered = []

    def stall(seq, a):
        if seq > 3:
            time.sleep(1.5)  # wall time; the lockstep twin goes on meanwhile
        return a

    real = PolicyRunner.infer

    def infer(self, obs, t_obs, seq=0):
        c = real(self, obs, t_obs, seq)
        stall(seq, c.actions)
        delivered.append((seq, t_obs))
        return c

    monkeypatch.setattr(PolicyRunner, "infer", infer)
    # a chunk each policy step: the stall (0.2 s after the next was due) comes before the 8-step chunk ends
    out = run_rollout(_opts(tiny_run, schedule="receding", k_exec=1, threaded=True,
                            max_seconds=1.0)).to_dict()
    t = out["timing"]
    assert t["holds"].get("policy stalled", 0) >= 1
    t_last = max(tt for s, tt in delivered if s <= 3)
    due = t_last + 1 / 29.4  # the next chunk was due one request period after the last one's observation
    after = [h - due for h in t["hold_times_s"] if h > due]
    assert after and STALL_S - 0.002 <= after[0] <= 0.25, (after, t["hold_times_s"], due)  # 2 ms: a tick


def test_ctrl_c_leaves_the_follower_held_and_the_leader_at_zero_torque(tiny_run, monkeypatch):
    def interrupt(seq, a):
        if seq == 4:
            raise KeyboardInterrupt
        return a

    _corrupt(monkeypatch, interrupt)
    out = run_rollout(_opts(tiny_run, max_seconds=2.0)).to_dict()
    assert out["interrupted"] and out["episodes"] == []
    assert out["timing"]["end_follower_held"] and out["timing"]["end_leader_tau_max_nm"] == 0.0


def _edited(run, tmp_path, edit):
    dst = tmp_path / "run"
    shutil.copytree(run, dst)
    ck = dst / "checkpoints" / ((dst / "checkpoints" / "last").read_text().strip() + ".json")
    meta = json.loads(ck.read_text())
    edit(meta)
    ck.write_text(json.dumps(meta))
    return dst


@pytest.mark.parametrize("edit, args, says", [
    (lambda m: m["arms"].update(arm_models=["yam"]), ["--task", "peg-insert"], "trained for arm 'yam'"),
    (lambda m: m["arms"]["joint_names"][0].pop(), ["--task", "peg-insert"], "trained on joints"),
    (lambda m: None, [], "needs camera(s)"),
])
def test_another_arm_joints_or_cameras_refused_in_one_line(tiny_run, tmp_path, capsys, edit, args, says):
    run = _edited(tiny_run, tmp_path, edit)
    assert main(["rollout", "--rig", "sim-piper", "--policy", str(run), *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0], err


def test_the_runner_builds_the_input_training_saw(tiny_run):
    """Live values through PolicyRunner.batch == the training batch of the same tick (names, order,
    normaliser). The live frames here are the recorded JPEGs decoded (the twin's raw frames are not kept),
    so the rollout's encode is a second JPEG pass: near, not equal; tests/test_policies_preprocess.py sends
    the raw frame through both paths and gets the same tensor."""
    from policies.data.dataset import build_dataset
    from policies.data.recordings import load_episodes
    from policies.labels.labelling import Thresholds

    runner = PolicyRunner(tiny_run)
    episodes, arms = load_episodes([tiny_run.parent / "held.mcap"])
    data = build_dataset(episodes, arms, th=Thresholds.given(1.0, 3.0), chunk=runner.cfg.chunk,
                         image_size=runner.cfg.image_size, val_fraction=0.0)
    rec = episodes[0].recording
    for i in (0, len(data) // 2, len(data) - 1):
        obs = {"follower.joint.pos": data.state[i, :6], "follower.gripper.pos": data.state[i, 6],
               "follower.joint.tau_ext": data.force[i]}
        for m, cam in enumerate(data.names.cameras):
            obs[f"observation.images.{cam}"] = rec.frames(cam).rgb(int(data.frame_idx[i, m]))
        live, trained = runner.batch(obs), data.batch(np.array([i]))
        for k in ("state", "force"):
            np.testing.assert_allclose(live[k].numpy(), trained[k].numpy(), atol=1e-5)
        diff = np.abs(live["images"].numpy().astype(int) - trained["images"].numpy().astype(int))
        assert live["images"].shape == trained["images"].shape and diff.mean() < 3.0, diff.mean()


def test_a_follower_motor_error_holds_the_rollout_and_it_resumes(tiny_run):
    """SIMULATED fault (hardware/sim/faults.py): a follower motor reporting over-temperature holds the
    policy's follower within one watchdog period, said and counted; the policy drives again once the motor
    is clear."""
    from hardware.sim.faults import parse_fault

    out = run_rollout(_opts(tiny_run, max_seconds=1.0, faults=[parse_fault("motor_overtemp@0.5:0.2")]))
    t = out.timing
    assert t["holds"].get("follower motor error") == 1 and t["command_violations"] == 0
    assert t["end_follower_held"]
    said = [(tt, text) for tt, _who, text in out.messages]
    held = [tt for tt, text in said if text == "follower on hold: follower motor error: j2 over-temperature"]
    assert held and 0.5 <= held[0] <= 0.55
    assert any(tt > 0.7 and "follows the policy" in text for tt, text in said)
    assert [e["kind"] for e in out.faults] == ["motor_overtemp", "motor_overtemp"]
