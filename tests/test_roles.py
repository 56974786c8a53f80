"""Base roles: the command path passes the safety layer, the watchdog puts devices in their safe state."""

from __future__ import annotations

import numpy as np

from hardware.clock import LockstepClock
from hardware.roles import Follower, Leader
from hardware.safety import DeviceHold, SafeFollowerCommand, SafeLeaderTorque
from hardware.sim.motors import IdealMotorBank
from hardware.types import FollowerCommand, JointLimits, JointState

N = 3
LIM = JointLimits(q_min=-np.ones(N), q_max=np.ones(N), v_max=np.full(N, 2.0), tau_max=np.full(N, 1.0),
                  tau_rate_max=np.full(N, 1000.0))


class BankFollower(Follower):
    """Test-only follower talking straight to an IdealMotorBank (no wire)."""

    def __init__(self, bank, clock):
        super().__init__("f", LIM, clock)
        self.bank, self.connected, self.sent = bank, False, []

    def connect(self):
        self.connected = True

    def _disconnect_bus(self):
        self.connected = False

    @property
    def is_connected(self):
        return self.connected

    def _read(self):
        r = self.bank.read()
        return JointState(t=self.clock.now(), q=r.q, q_dot=r.q_dot, tau_m=r.tau_m, current=r.current,
                          q_cmd=np.full(N, np.nan), temperature=r.temperature, status=np.zeros(N, np.uint32))

    def _send_safe(self, safe: SafeFollowerCommand):
        assert isinstance(safe, SafeFollowerCommand)
        self.sent.append(safe)
        self.bank.command_position(np.arange(N), safe.q)


class BankLeader(Leader):
    def __init__(self, bank, clock):
        super().__init__("l", LIM, clock)
        self.bank, self.connected = bank, False

    def connect(self):
        self.connected = True

    def _disconnect_bus(self):
        self.connected = False

    @property
    def is_connected(self):
        return self.connected

    def _read(self):
        r = self.bank.read()
        return JointState(t=self.clock.now(), q=r.q, q_dot=r.q_dot, tau_m=r.tau_m, current=r.current,
                          q_cmd=np.full(N, np.nan), temperature=r.temperature, status=np.zeros(N, np.uint32))

    def _send_torque_safe(self, safe: SafeLeaderTorque):
        self.bank.command_current(np.arange(N), safe.tau / self.bank.torque_constant)


def test_follower_commands_are_limited_and_watchdog_holds():
    clock, bank = LockstepClock(), IdealMotorBank(N)
    clock.attach(bank.advance)
    with BankFollower(bank, clock) as f:
        f.read()
        for _ in range(400):  # 0.8 s: the target moves at most v_max = 2 rad/s
            sent = f.command(FollowerCommand(q=np.array([5.0, -5.0, np.nan])))
            clock.sleep(0.002)
            f.read()
        assert np.all(np.abs(sent.q) <= 1.0) and sent.q[2] == 0.0
        assert np.allclose(bank.q, [1.0, -1.0, 0.0], atol=0.05)
        n_before = len(f.sent)
        clock.sleep(0.06)  # loop stalls: no command for 60 ms
        f.read()
        assert f.sent[-1].hold and len(f.sent) == n_before + 1 and f.in_safe_state
        assert f.safety.last_fault.kind is DeviceHold.WATCHDOG
        assert f.safety.last_fault.get("stale").kind is DeviceHold.NO_COMMAND
    assert f.sent[-1].hold  # disconnect leaves it holding


def test_leader_torque_limited_and_zeroed_on_stale_feedback():
    clock, bank = LockstepClock(), IdealMotorBank(N)
    clock.attach(bank.advance)
    lead = BankLeader(bank, clock)
    lead.connect()
    lead.read()
    assert np.allclose(lead.command_torque(np.array([10.0, -0.5, np.inf])), 0.0)  # torque ramps from zero
    for _ in range(5):
        clock.sleep(0.002)
        lead.read()
        out = lead.command_torque(np.array([10.0, -0.5, np.inf]))
    assert np.allclose(out, [1.0, -0.5, 0.0])
    clock.sleep(0.03)
    lead.command_torque(np.array([0.2, 0.2, 0.2]))
    clock.sleep(0.03)
    assert lead.check_watchdog() is not None  # feedback 60 ms old
    assert np.all(bank.current_cmd == 0)


def test_command_observers_see_every_safe_command_once_in_wire_order():
    clock, bank = LockstepClock(), IdealMotorBank(N)
    clock.attach(bank.advance)
    seen_f, seen_l = [], []
    with BankFollower(bank, clock) as f, BankLeader(IdealMotorBank(N), clock) as lead:
        f.add_command_observer(lambda t, t_sent, safe: seen_f.append((t, t_sent, safe)))
        lead.add_command_observer(lambda t, t_sent, safe: seen_l.append((t, t_sent, safe)))
        f.read()
        f.command(FollowerCommand(q=np.array([5.0, 0.0, 0.0])))
        clock.sleep(0.002)
        f.hold("test")
        lead.zero_torque("start")  # the rate limit's clock starts here
        clock.sleep(0.01)
        lead.read()
        lead.command_torque(np.array([3.0, 0.0, -3.0]))
        clock.sleep(1.0)  # stale: the watchdog's hold goes through the same path
        f.read()
    # the follower: command, hold, watchdog hold, disconnect hold -- exactly what reached _send_safe
    assert [s for *_, s in seen_f] == f.sent and len(f.sent) >= 3
    assert seen_f[0][2].q[0] <= 1.0 and not seen_f[0][2].hold and all(s.hold for *_, s in seen_f[1:])
    assert seen_f[0][0] == seen_f[0][1] == 0.0 and seen_f[1][0] == 0.002  # t_issued, t_sent [s, clock]
    assert np.all(seen_l[0][2].tau == 0) and np.allclose(seen_l[1][2].tau, [1.0, 0.0, -1.0])
    assert seen_l[1][0] == seen_l[1][1] == 0.012 and np.all(seen_l[-1][2].tau == 0)  # then the watchdog
    f2 = BankFollower(bank, clock)
    obs = seen_f.append
    f2.add_command_observer(obs)
    f2.remove_command_observer(obs)
    f2.command(FollowerCommand(q=np.zeros(N)))
    assert f2._observers == [] and len(f2.sent) == 1


def test_watchdog_check_that_waited_for_a_disconnect_leaves_the_device_alone():
    """The watchdog thread saw stale data and waited for the device's lock while the app disconnected the
    device (a loop ending late on a slowed core, issue #53): it must not write to the closed bus after."""
    import threading

    clock, bank = LockstepClock(), IdealMotorBank(N)
    clock.attach(bank.advance)
    lead = BankLeader(bank, clock)
    lead.connect()
    lead.read()
    lead.command_torque(np.zeros(N))
    clock.sleep(0.06)  # no feedback, no command for 60 ms: the watchdog will go safe
    sends, closed = [], []
    real_send = lead._send_torque_safe

    def send(safe):
        (sends if lead.is_connected else closed).append(safe)  # (a real driver raises on a closed bus)
        real_send(safe)

    lead._send_torque_safe = send
    lead.in_safe_state = False
    with lead._lock:  # the app holds the device while it disconnects it
        t = threading.Thread(target=lead.check_watchdog)
        t.start()
        t.join(0.2)  # the watchdog thread now waits for the lock
        lead._go_safe("disconnect")
        lead._disconnect_bus()
        lead.in_safe_state = True
    t.join(2.0)
    assert not t.is_alive() and len(sends) == 1 and closed == [], "a write to a disconnected leader"
