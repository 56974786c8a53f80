"""A rig's twin in a process of its own, watched (SIMULATED): what the motors do when the app beside it dies.

    python -m hardware.process_twin --rig sim-piper --out DIR [--seed S] [--hand]

serves the twin in real time: Dynamixel leaders on ptys, CAN followers on pty CAN links (hardware/can_pty.py,
python-can's virtual channels do not cross processes). It writes DIR/app_rig.toml, the rig as a real rig
reaching these endpoints (`factr2 teleop --rig DIR/app_rig.toml` is then an app like any other: it does not
know it talks to a twin), and DIR/status.json every STATUS_EVERY_S ({"t": monotonic s, "active_s": how long
both the leaders and the followers have been commanded without a gap}). On SIGTERM it writes
DIR/watch.npz (the samples below) and DIR/events.json (each motor's fallback as its emulator recorded it) and
exits.

Samples, every SAMPLE_EVERY_S of the rig clock (= time.monotonic(): comparable with a parent's kill time):
t, per leader joint the torque its servo applies (commanded current x torque constant [N*m]) and whether its
Bus Watchdog latched, per follower joint the true angle [rad] (PRIVILEGED) and whether its motor fell back
(Damiao: its command timeout's damping), and the emulators' received-frame counters (traffic from the app).
--hand: a scripted operator's hand: it holds each leader still (its world is not stepped) until the app has
been active HAND_AFTER_S, then moves it on a slow sine about that pose; it goes on after the app dies (the
operator does not know).
"""

from __future__ import annotations

import argparse
import json
import math
import re
import signal
import threading
import time
from pathlib import Path

import numpy as np

SAMPLE_EVERY_S = 0.002
STATUS_EVERY_S = 0.05
ACTIVE_GAP_S = 0.05  # s: traffic from the app on every device within this counts as "active"
HAND_AMP_RAD, HAND_HZ, HAND_K, HAND_D, HAND_MAX_NM = 0.2, 0.3, 0.3, 0.01, 0.2  # the scripted hand [rad, Hz,
# N*m/rad, N*m*s/rad, N*m]: a light hand; the app's gravity compensation carries the arm
HAND_AFTER_S = 0.5  # s of activity before the hand starts moving the leader (held still until then)


def app_rig_text(rig_text: str, endpoints: dict[str, str], can_devices: set[str]) -> str:
    """The sim rig's TOML as a real rig reaching endpoints (device name -> pty path): simulated = false,
    each device's "twin" port/channel replaced, CAN on interface "pty", twin-only sections ([twin...],
    [[cameras]]) dropped."""
    out, skip, name = [], False, None
    for line in rig_text.splitlines():
        head = line.strip()
        if head.startswith("["):
            skip = head.startswith(("[twin", "[[cameras", "[cameras"))
            name = None
        if skip:
            continue
        m = re.match(r'\s*name\s*=\s*"([^"]+)"', line)
        if m:
            name = m.group(1)
        if re.match(r"\s*simulated\s*=", line):
            line = "simulated = false"
        elif re.match(r'\s*(port|channel)\s*=\s*"twin"', line) and name in endpoints:
            key = line.split("=")[0].strip()
            line = f'{key} = "{endpoints[name]}"'
        elif re.match(r'\s*interface\s*=\s*"virtual"', line) and name in can_devices:
            line = 'interface = "pty"'
        out.append(line)
    return "\n".join(out) + "\n"


class Watch:
    """The twin's step observer: samples, the hand, activity (module doc)."""

    def __init__(self, twin, hand: bool):
        from hardware.sim.motors import MODE_CURRENT

        self.twin, self.hand, self._mode_current = twin, hand, MODE_CURRENT
        self.leaders = [twin.devices[d.name] for d in twin.rig.leaders]
        self.followers = [twin.devices[d.name] for d in twin.rig.followers]
        self.rows: list[tuple] = []
        self._t_next = -math.inf
        self._q0 = {id(d): d.bank.read().q[: d.n_arm].copy() for d in self.leaders}
        self._t0 = None
        self._t_hand = None  # when the hand started [s]
        if hand:
            for d in self.leaders:
                twin.set_idle(d.spec.name, True)
        self._last_counts = None
        self.t_active_from = None  # since when every device has been commanded without a gap [s]
        self._t_last_all = -math.inf
        # each follower motor's fallback deadlines on the rig clock, converted when seen (a twin that fell
        # behind skips ahead: its offset to sim time changes, so a later conversion would misplace them)
        self.timeouts = {d.spec.name: [] for d in self.followers}

    def _counts(self) -> tuple:
        return tuple(d.emulator.instructions for d in self.leaders) + tuple(
            d.emulator.rx_frames for d in self.followers)

    def __call__(self, t: float) -> None:
        if self.hand:
            self._hand(t)
        off = t - self.twin.t
        for d in self.followers:
            log, seen = getattr(d.emulator, "timeout_log", ()), self.timeouts[d.spec.name]
            if len(log) > len(seen):
                seen += [(k, x + off) for k, x in log[len(seen):]]
        if t < self._t_next:
            return
        self._t_next = t + SAMPLE_EVERY_S
        if self._t0 is None:
            self._t0 = t
        counts = self._counts()
        moved = self._last_counts is not None and all(a != b for a, b in zip(counts, self._last_counts))
        self._last_counts = counts
        if moved:
            if t - self._t_last_all > ACTIVE_GAP_S:
                self.t_active_from = t
            self._t_last_all = t
        tau, latched, q, fell = [], [], [], []
        for d in self.leaders:
            b, n = d.bank, d.n_arm
            on = b.mode[:n] == self._mode_current
            tau.append(np.where(on, b.i_cmd[:n] * b.torque_constant[:n], 0.0))
            latched.append([bool(s.watchdog.latched) for s in d.emulator.servos[:n]])
        for d in self.followers:
            n = d.n_arm
            q.append(d.bank.read().q[:n].copy())
            to = getattr(d.emulator, "timed_out", None)
            fell.append(np.zeros(n, bool) if to is None else np.asarray(to[:n], bool))
        self.rows.append((t, np.concatenate(tau), np.concatenate(latched), np.concatenate(q),
                          np.concatenate(fell), np.asarray(counts, float)))

    def _hand(self, t: float) -> None:
        if self._t_hand is None:
            if self.t_active_from is None or t - self.t_active_from < HAND_AFTER_S:
                return
            self._t_hand = t
            for d in self.leaders:
                self._q0[id(d)] = d.bank.read().q[: d.n_arm].copy()
                self.twin.set_idle(d.spec.name, False)
        for d in self.leaders:
            n = d.n_arm
            r = d.bank.read()
            qd = self._q0[id(d)] + HAND_AMP_RAD * math.sin(2 * math.pi * HAND_HZ * (t - self._t_hand))
            h = HAND_K * (qd - r.q[:n]) - HAND_D * r.q_dot[:n]
            self.twin.apply_leader_hand_torque(np.clip(h, -HAND_MAX_NM, HAND_MAX_NM), d.spec.name)

    def active_s(self, now: float) -> float:
        if self.t_active_from is None or now - self._t_last_all > ACTIVE_GAP_S:
            return 0.0
        return now - self.t_active_from

    def save(self, out: Path) -> None:
        cols = list(zip(*self.rows)) if self.rows else [[]] * 6
        np.savez(out / "watch.npz", t=np.asarray(cols[0], float), leader_tau=np.asarray(cols[1]),
                 leader_latched=np.asarray(cols[2], bool), follower_q=np.asarray(cols[3]),
                 follower_fell=np.asarray(cols[4], bool), counts=np.asarray(cols[5]))
        tw = self.twin
        ev = {"leaders": {d.spec.name: {"watchdog_trips": d.emulator.watchdog_trips,
                                        "watchdog": [int(s.table[98]) for s in d.emulator.servos]}
                          for d in self.leaders},
              "followers": {d.spec.name: {"driver": d.spec.driver,
                                          "timeouts": self.timeouts[d.spec.name],
                                          "motors": int(d.bank.n),
                                          "tx_dropped": int(getattr(d.bus, "tx_dropped", 0))}
                            for d in self.followers},
              "overruns": tw.overruns, "realtime_note": str(tw.realtime_note)}
        (out / "events.json").write_text(json.dumps(ev, indent=1))


def serve(rig_name: str, out: Path, seed: int | None = None, hand: bool = False) -> int:
    from hardware.can_pty import PtyCanBus
    from hardware.rigs import load_rig
    from hardware.rigs.rig import rig_path
    from hardware.sim.twin import Twin

    out.mkdir(parents=True, exist_ok=True)
    rig = load_rig(rig_name)
    twin = Twin(rig, seed=seed, dynamixel_transport="pty")
    can_devices = set()
    for name, d in twin.devices.items():
        if d.wire == "can":  # rebind the emulator to a pty CAN link other processes can open
            bus = PtyCanBus.serve()
            old, d.bus, d.endpoint = d.bus, bus, bus.channel_info
            d.emulator._init_io(bus, d.emulator.drop_prob, twin.seed)
            if old is not None:
                old.shutdown()
            can_devices.add(name)
    watch = Watch(twin, hand)
    twin.add_step_observer(watch)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    text = app_rig_text(rig_path(rig_name).read_text(), twin.endpoints, can_devices)
    (out / "app_rig.toml").write_text(text)
    twin.start_realtime()
    (out / "endpoints.json").write_text(json.dumps(twin.endpoints))
    try:
        while not stop.is_set():
            now = time.monotonic()
            with twin.lock:
                act = watch.active_s(now)
            tmp = out / "status.json.tmp"
            tmp.write_text(json.dumps({"t": now, "active_s": act}))
            tmp.replace(out / "status.json")
            stop.wait(STATUS_EVERY_S)
    finally:
        twin.stop_realtime()
        with twin.lock:
            watch.save(out)
        twin.close()
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rig", default="sim-piper")
    ap.add_argument("--out", required=True)
    ap.add_argument("--seed", type=int, default=None)
    ap.add_argument("--hand", action="store_true")
    a = ap.parse_args(argv)
    return serve(a.rig, Path(a.out), a.seed, a.hand)


if __name__ == "__main__":
    raise SystemExit(main())
