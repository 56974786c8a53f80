"""The pieces of the crash campaign that need no real time: the pty CAN link's records (resync after a cut
write), the app rig written for a twin in another process, and the measures of a trial from its samples."""

from __future__ import annotations

from pathlib import Path

import can
import numpy as np

from bench.crash_trials import MESSAGES_MAX, analyse, trial_messages
from hardware.can_bus import open_bus
from hardware.can_pty import PtyCanBus, decode, encode
from hardware.process_twin import app_rig_text


def test_records_survive_garbage_and_cut_writes():
    a, b = encode(0x2A5, b"\x01\x02\x03"), encode(0x12345678, b"x" * 8, ext=True)
    frames, used = decode(b"\x00\xc4" + a[:7] + a + b"junk" + b + b[:5])
    assert frames == [(0x2A5, b"\x01\x02\x03", False, False), (0x12345678, b"x" * 8, True, False)]
    assert used == len(b"\x00\xc4" + a[:7] + a + b"junk" + b)  # the cut tail waits for its rest


def test_pty_link_both_ways():
    srv = PtyCanBus.serve()
    cli = open_bus(srv.channel_info, "pty")
    try:
        srv.send_batch([(0x251, b"a" * 8), (0x252, b"b" * 8)])
        got = cli.recv(1.0), cli.recv(1.0)
        assert [m.arbitration_id for m in got] == [0x251, 0x252] and got[1].data == b"b" * 8
        cli.send(can.Message(arbitration_id=0x7FF, data=b"\x01\x00\x33\x09\0\0\0\0", is_extended_id=False))
        assert srv.recv(1.0).data[3] == 9
        for _ in range(5000):  # nobody reads: the pty fills, writes never block, the excess is counted lost
            srv.send_fresh(0x2A1, b"12345678")
        assert srv.tx_dropped > 0 and len(cli.take_pending_raw()) > 0
    finally:
        cli.shutdown()
        srv.shutdown()


def test_app_rig_reaches_the_twin_as_a_real_rig():
    text = app_rig_text(Path("hardware/rigs/sim-yam.toml").read_text(),
                        {"leader": "/dev/pts/7", "follower": "/dev/pts/8"}, {"follower"})
    assert "simulated = false" in text and 'port = "/dev/pts/7"' in text and 'channel = "/dev/pts/8"' in text
    assert 'interface = "pty"' in text and "[twin" not in text and "[[cameras" not in text


def test_measures_of_a_kill():
    t = np.arange(0.0, 2.0, 0.002) + 100.0
    n = len(t)
    t_sig = 100.5
    tau = np.where((t < t_sig + 0.1)[:, None], 0.3, 0.0) * np.ones((n, 2))
    q = np.zeros((n, 2))
    q[t > t_sig, 0] = 0.01 * (t[t > t_sig] - t_sig)  # a slow sag after the kill
    counts = np.stack([np.where(t < t_sig, np.arange(n), np.arange(n)[t < t_sig][-1])] * 2, axis=1)
    w = {"t": t, "leader_tau": tau, "leader_latched": (t >= t_sig + 0.1)[:, None] * np.ones((n, 2), bool),
         "follower_q": q, "follower_fell": np.zeros((n, 2), bool), "counts": counts.astype(float)}
    ev = {"leaders": {"leader": {"watchdog_trips": [[1, t_sig + 0.099, t_sig + 0.1], [2, t_sig + 0.099,
                                                                                      t_sig + 0.1]],
                                 "watchdog": [255, 255, 0]}},
          "followers": {"follower": {"driver": "piper", "timeouts": [], "motors": 7}}}
    m = analyse(w, ev, t_sig, "app_sigkill")
    assert abs(m["fallback_ms"] - 100.0) < 1e-6 and abs(m["fallback_deadline_ms"] - 99.0) < 1e-6
    assert m["leader_tau_after_nm"] == 0.0 and m["leader_tau_at_signal_nm"] == 0.3
    assert abs(m["follower_motion_rad"] - 0.015) < 1e-3 and m["fallback_ms_per_device"]["follower"] < 2.1


def test_trial_messages_keep_the_recovery_past_many_holds():
    """A slow core's start says many holds before the freeze: the recovery's lines stay in the trial's
    messages (the rollout trial checks 'comes back'), the rest is cut at MESSAGES_MAX."""
    holds = [f"arm: follower on hold: follower data stale ({k})" for k in range(MESSAGES_MAX + 15)]
    back = "arm: the loop did not run for 2023 ms; the follower comes back at the soft start"
    log = "\n".join(["leader on /dev/pts/0: one sync read", *holds, "leader: Bus Watchdog re-armed (1)", back,
                     "arm: follower on hold: follower data stale (late)"])
    got = trial_messages(log)
    assert got == [*holds[:MESSAGES_MAX], "leader: Bus Watchdog re-armed (1)", back]
