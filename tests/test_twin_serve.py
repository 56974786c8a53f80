"""The twin behind the real drivers (SIMULATED rigs): lockstep determinism, real time, the virtual operator,
every sim rig opening through its drivers, and the `factr2 twin` command."""

from __future__ import annotations

import time

import numpy as np
import pytest
from machine_speed import slowdown

from factr2_teleop.cli import main as cli_main
from hardware.arms.dynamics import gravity
from hardware.connect import open_rig, serve_twin
from hardware.errors import ConfigError
from hardware.types import FollowerCommand

TARGET = np.array([0.3, 0.8, -0.6, 0.1, 0.3, -0.2])


def _run_lockstep(seed: int, steps: int = 150):
    out = []
    with open_rig("sim-piper", clock="lockstep", seed=seed) as s:
        f, lead = s.follower, s.leader
        for k in range(steps):
            st = f.read()
            ls = lead.read()
            f.command(FollowerCommand(q=TARGET))
            lead.command_torque(0.05 * np.sin(0.01 * k) * np.ones(6))
            s.clock.sleep(0.002)
            out.append(np.concatenate([st.q, st.q_dot, st.current, ls.q, ls.current]))
        gt = s.ground_truth()
    return np.array(out), gt


def test_lockstep_through_the_wire_is_deterministic_and_tracks():
    a, gt = _run_lockstep(5)
    b, _ = _run_lockstep(5)
    # follower (physics + CAN path) and leader (physics + Protocol 2.0 through dynamixel-sdk on the lockstep
    # twin's in-process port), bit for bit; the pty path is compared in tests/test_twin_inprocess.py
    np.testing.assert_array_equal(a, b)
    assert np.max(np.abs(a[-1, :6] - TARGET)) < 0.15  # the Piper's position loop got (nearly) there in 0.3 s
    assert gt["follower"].t == pytest.approx(0.3, abs=0.003)
    assert np.all(gt["follower"].tau_ext == 0.0)


def test_serve_twin_runs_in_real_time_and_stops():
    server = serve_twin("sim-piper", effect=lambda t, q, qd: 0.1 * np.ones(6))
    try:
        assert set(server.serial_ports) == {"leader"} and set(server.can_channels) == {"follower"}
        t0, s0 = time.monotonic(), server.sim_time
        time.sleep(0.5)
        ran = server.sim_time - s0
        # never ahead of wall time; behind only on a starved or slow CPU (bench/bench_twin.py: the rate)
        assert 0.1 / slowdown() < ran <= time.monotonic() - t0 + 0.01
        gt = server.ground_truth()
        assert set(gt) == {"leader", "follower"}
        np.testing.assert_allclose(gt["follower"].tau_load - server.twin.bank("follower").tau_ripple,
                                   np.r_[0.1 * np.ones(6), 0.0], atol=1e-3)  # (racing the real-time thread)
    finally:
        server.stop()
    t_stop = server.sim_time
    time.sleep(0.05)
    assert server.sim_time == t_stop


def test_bad_effect_and_real_rig_are_config_errors():
    with pytest.raises(ConfigError, match="MODULE:FUNCTION"):
        serve_twin("sim-piper", effect="no_colon")
    with pytest.raises(ConfigError, match="returned shape"):
        serve_twin("sim-piper", effect=lambda t, q, qd: np.zeros(3))
    with pytest.raises(ConfigError, match="real hardware"):
        serve_twin("piper")
    with pytest.raises(ConfigError, match="lockstep"):
        open_rig("piper", clock="lockstep")


def test_virtual_operator_moves_the_leader_through_the_wire():
    with open_rig("sim-piper", clock="lockstep") as s:
        q0 = s.leader.read().q.copy()
        s.twin.apply_leader_hand_torque(np.array([0.3, 0, 0, 0, 0, 0]))
        for _ in range(100):
            s.leader.command_torque(np.zeros(6))
            s.clock.sleep(0.002)
        q1 = s.leader.read().q
        assert q1[0] - q0[0] > 0.05  # joint 1 (vertical axis) turned under the hand
        gt = s.ground_truth()["leader"]
        assert gt.tau_ext[0] == pytest.approx(-0.3)  # paper convention: the hand is external


@pytest.mark.parametrize("rig", ["sim-yam", "sim-panda"])
def test_other_sim_rigs_open_and_track(rig):
    with open_rig(rig, clock="lockstep") as s:
        f = s.follower
        n = f.n_joints
        q0 = f.read().q.copy()
        lim = f.safety.limits
        target = np.clip(q0 + 0.2, lim.q_min + 0.05, lim.q_max - 0.05)
        arm = s.rig.followers[0].arm
        for _ in range(400):
            st = f.read()
            # gravity feed-forward, as the teleop loop sends it (MIT followers sag by g/kp without it)
            f.command(FollowerCommand(q=target, tau_ff=gravity(arm, st.q), gripper=0.03))
            s.clock.sleep(0.002)
        assert np.max(np.abs(f.read().q - target)) < 0.06, f.read().q - target
        assert f.read().q.shape == (n,)
        assert f.read().gripper_pos == pytest.approx(0.03, abs=0.002)  # yam: motor angle -> finger slide


def test_cli_twin_serves_and_exits(capsys):
    assert cli_main(["twin", "--rig", "sim-piper", "--seconds", "0.3"]) == 0
    out = capsys.readouterr().out
    assert "Dynamixel Protocol 2.0 on /dev/pts/" in out and "SIMULATED" in out
    assert cli_main(["twin", "--rig", "yam", "--seconds", "0.1"]) == 2


def test_rig_camera_renders_the_twin_scene():
    from hardware.cameras.base import CameraError

    with open_rig("sim-piper", clock="lockstep") as s:
        cam = s.cameras["scene"]
        try:
            cam.connect()
        except CameraError as e:  # no OpenGL on this machine: nothing to render with
            pytest.skip(str(e))
        s.clock.sleep(0.01)
        f = cam.read()
        assert f.rgb.shape == (240, 320, 3) and f.rgb.std() > 5  # an actual image, not a blank
        assert f.t == pytest.approx(s.clock.now())


def test_twin_driven_clock_steps_the_twin_to_wall_time_and_skips_a_stall():
    """TwinDrivenClock on a twin, with the wall clock advanced by hand (the outcome must not depend on the
    machine's speed): each sleep steps the twin to now; a stall beyond max_lag_s skips ahead, counted."""
    from hardware.rigs import load_rig
    from hardware.sim.twin import Twin
    from hardware.sim.twin_driven_clock import TwinDrivenClock

    class HandWall(TwinDrivenClock):
        wall = 50.0  # s

        def now(self) -> float:
            return self.wall

        def sleep(self, dt_s: float) -> None:
            self.wall += dt_s
            super().sleep(0.0)  # no real wait; then the twin catches up to the (hand) wall time

    with Twin(load_rig("sim-piper"), dynamixel_transport="inprocess") as tw:
        tw.start_realtime()
        with pytest.raises(RuntimeError, match="stop_realtime"):
            HandWall(tw).start()  # two steppers would race
        tw.stop_realtime()
        clock = HandWall(tw, max_lag_s=0.05)
        clock.start()
        t0, n0 = tw.t, tw.overruns
        assert tw.rig_time() == pytest.approx(clock.now(), abs=1e-9) and abs(tw.lag(clock.now())) < 1e-9
        for _ in range(100):
            clock.sleep(0.002)
            assert abs(tw.lag(clock.now())) <= 0.5 * tw.dt
        assert tw.t - t0 == pytest.approx(0.2, abs=0.5 * tw.dt) and tw.overruns == n0
        clock.wall += 0.3  # a stall of the caller's thread: skipped, not simulated
        t1, steps = tw.t, tw.steps
        clock.sleep(0.001)
        assert clock.overruns == n0 + 1 and tw.steps == steps + 1 and tw.t - t1 == pytest.approx(tw.dt)
        assert abs(tw.lag(clock.now())) <= 0.5 * tw.dt
