"""After a failed episode the scripted operator re-homes the arm (SIMULATED, lockstep twin): the next episode
starts from the collection's start pose, the move lies outside every recorded episode, and it is made through
the leader and the follower's safety layer (the pair's commands), never by writing the twin's state."""

import numpy as np
import pytest

from factr2_teleop.tasks.run import CollectConfig, collect
from hardware.recording.reader import Recording

EPISODE_S = 3.0  # s: the time limit of the tiny episodes (the wipe script is still on its way: a failure)
HOME_TOL_RAD = 0.05  # rad: the follower at the next episode's first sample, from the start pose (max joint)


def test_a_failed_episode_is_followed_by_a_rehoming_through_leader_and_safety_layer(tmp_path, monkeypatch):
    pytest.importorskip("mujoco")
    from factr2_teleop.tasks.collect import EpisodeDriver
    from hardware.sim.tasks.wipe import Wipe
    from hardware.sim.world import MujocoWorld as World

    monkeypatch.setattr(Wipe, "episode_s", EPISODE_S)
    ticks, writes, driver = [], [], {}
    set_qpos = World.set_qpos

    def spy(self, bank, q):  # the twin's state written directly (resets): must not happen while re-homing
        writes.append(driver["ep"]._state if "ep" in driver else None)
        return set_qpos(self, bank, q)

    monkeypatch.setattr(World, "set_qpos", spy)

    def on_session(ts, s):
        ep = next(h.__self__ for h in ts.hooks if isinstance(getattr(h, "__self__", None), EpisodeDriver))
        driver["ep"], driver["map"] = ep, ep.pair.map
        ts.hooks.append(lambda r: ticks.append((ep._state, r.t, r.leader.q.copy(), r.follower.q.copy(),
                                                np.array(r.action_q, float), r.action_hold)))

    out = collect(CollectConfig(task="wipe", episodes=2, out=str(tmp_path), seed=0, mode="ground_truth",
                                cameras=False, on_session=on_session), progress=False)
    assert [r["outcome"] for r in out["results"]] == ["failure", "failure"]  # timed out, both
    home = driver["ep"]._q_home
    rec = Recording(out["recording"], use_cache=False)
    ep0, ep1 = rec.episodes
    js = rec.topic("/follower/joint_state")

    def first_last(e):
        inside = (js.t >= e.t_start) & (js.t <= e.t_stop)
        return js.fields["q"][inside][0], js.fields["q"][inside][-1]

    # episode 0 ended away from home, episode 1 started at home
    assert np.abs(first_last(ep0)[0] - home).max() < HOME_TOL_RAD
    left = np.abs(first_last(ep0)[1] - home).max()
    assert left > 3 * HOME_TOL_RAD, left  # the failed episode left the arm elsewhere: the re-homing is seen
    assert np.abs(first_last(ep1)[0] - home).max() < HOME_TOL_RAD

    homing = [k for k, x in enumerate(ticks) if x[0] == "home"]
    assert homing, "no re-homing after the failed episode"
    t_home = np.array([ticks[k][1] for k in homing])
    assert ep0.t_stop <= t_home.min() and t_home.max() < ep1.t_start  # outside any recorded episode
    assert not np.any((js.t > ep0.t_stop) & (js.t < ep1.t_start))  # and nothing of it in the file

    # through the leader: the hand moved the leader, whose mapped joints reached home
    q_l = np.array([ticks[k][2] for k in homing])
    fwd = driver["map"].forward
    assert np.abs(fwd(q_l[0]) - home).max() > 2 * HOME_TOL_RAD
    assert np.abs(fwd(q_l[-1]) - home).max() < HOME_TOL_RAD
    # through the safety layer: every re-homing tick's follower target is the pair's, after the layer (sent,
    # finite, no hold), and the follower moved continuously (no state written: at most a joint speed's step)
    act = np.array([ticks[k][4] for k in homing])
    assert np.all(np.isfinite(act)) and not any(ticks[k][5] for k in homing)
    assert np.abs(act[-1] - home).max() < HOME_TOL_RAD
    q_f = np.array([ticks[k][3] for k in homing])
    step = float(np.abs(np.diff(q_f, axis=0)).max())  # rad: the largest change between two ticks' samples
    assert step < HOME_TOL_RAD < left, (step, left)
    assert "home" not in writes
