"""The TUI's hold on a rig: one connected session, a monitor thread, the emergency stop, and exclusive use of
the rig by one activity at a time (teleop or calibration). No Textual here: screens poll snapshots.

Clocks. Real rigs run on the wall clock. Simulated rigs (the MuJoCo twin) run either "lockstep" (default:
physics advances only when the thread owning the rig sleeps the clock -- deterministic, never falls behind
on a loaded machine; `pace` keeps it from running ahead of wall time) or "realtime" (a thread steps physics
to wall time, like real hardware). While no activity runs, the monitor thread owns the clock: it reads
every device, measures the read round trip, and keeps the arms safe (leaders zero torque, followers hold).

Simulated rigs only: a virtual hand (hardware.sim twin input) rests on each leader and holds it near its
start pose, as an operator's hand would; without it an unpowered GELLO leader droops under gravity and
teleop would (rightly) refuse to start. It is labelled SIMULATED wherever it shows.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from hardware import sim_cpu
from hardware.errors import UserError
from hardware.rigs.rig import Rig, list_rigs, load_rig
from hardware.roles import make_safe
from hardware.types import (
    STATUS_COLLISION,
    STATUS_COMM_LOST,
    STATUS_DRIVER_ERROR,
    STATUS_ENABLED,
    STATUS_HOLD,
    STATUS_LIMIT,
    STATUS_OVERCURRENT,
    STATUS_OVERTEMP,
    STATUS_STALE,
    STATUS_STALL,
    STATUS_UNDERVOLTAGE,
)

MONITOR_PERIOD_S = 0.05  # s: idle monitor period on the wall clock (real rigs)
MONITOR_SIM_STEP_S = 0.01  # s: idle lockstep step; the virtual hand needs >= 100 Hz updates to stay stable
HAND_STIFFNESS_NM_RAD = 3.0  # virtual hand holding a simulated leader (a relaxed hand, 2-5 N*m/rad)
HAND_DAMPING_NMS_RAD = 0.1
HAND_TAU_MAX_NM = 2.0
STATUS_WORDS = (
    (STATUS_OVERTEMP, "overtemp"),
    (STATUS_OVERCURRENT, "overcurrent"),
    (STATUS_UNDERVOLTAGE, "undervoltage"),
    (STATUS_COMM_LOST, "comm lost"),
    (STATUS_COLLISION, "collision"),
    (STATUS_DRIVER_ERROR, "driver error"),
    (STATUS_STALL, "stall"),
    (STATUS_LIMIT, "limit"),
    (STATUS_STALE, "stale"),
)


def status_words(status: np.ndarray) -> list[str]:
    """Error words for the per-joint STATUS_* bits, with the joints affected (hold/enabled excluded)."""
    out = []
    st = np.asarray(status, dtype=np.uint32)
    for bit, word in STATUS_WORDS:
        joints = np.flatnonzero(st & bit)
        if joints.size:
            out.append(f"{word} j{','.join(str(j + 1) for j in joints)}")
    return out


@dataclass
class DeviceStatus:
    """One row of the rig screen. read_ms: wall time of the last bus read [ms] (NaN: not measured)."""

    name: str
    role: str
    driver: str
    arm: str
    endpoint: str
    connected: bool = False
    mode: str = "-"
    safe: bool = True
    enabled: bool = False
    temp_max_c: float = float("nan")
    errors: list[str] = field(default_factory=list)
    read_ms: float = float("nan")
    q: np.ndarray | None = None


def _endpoint(spec) -> str:
    c = spec.config
    return str(getattr(c, "port", None) or getattr(c, "channel", None) or "twin")


def _mode(spec) -> str:
    if spec.role == "leader":
        return "current"
    return str(getattr(spec.config, "mode", "position"))


class VirtualHand:
    """SIMULATED: a hand resting on a twin leader, impedance toward a reference pose (or a scripted
    operator's torque when one is set). apply(q, q_dot) once per control period."""

    def __init__(self, twin, leader: str, q_ref: np.ndarray):
        from factr2_teleop.teleop.virtual_operator import hand_torque

        self._hand_torque = hand_torque
        self.twin, self.leader, self.q_ref = twin, leader, np.asarray(q_ref, dtype=float).copy()
        n = self.q_ref.size
        self.k = np.full(n, HAND_STIFFNESS_NM_RAD)
        self.d = np.full(n, HAND_DAMPING_NMS_RAD)
        self.tau_max = np.full(n, HAND_TAU_MAX_NM)
        self.operator = None  # a teleop.virtual_operator.VirtualOperator driving the hand, or None

    def apply(self, t: float, q: np.ndarray, q_dot: np.ndarray) -> None:
        with sim_cpu.simulated():  # the simulated hand: not the app's CPU (hardware/sim_cpu.py)
            self._apply(t, q, q_dot)

    def _apply(self, t: float, q: np.ndarray, q_dot: np.ndarray) -> None:
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(q_dot))):
            return
        if self.operator is not None:
            if self.operator.done(t):
                self.operator.t0 = t  # the script repeats until teleop stops
            tau = self.operator.torque(t, q, q_dot)
        else:
            tau = self._hand_torque(
                q, q_dot, self.q_ref, np.zeros_like(self.q_ref), self.k, self.d, self.tau_max
            )
        self.twin.apply_leader_hand_torque(tau, self.leader)


class RigRuntime:
    """RigRuntime(rig, clock="auto", pace=1.0): connect/disconnect, estop, statuses, claim/release.

    clock: "auto" (lockstep for simulated rigs, realtime otherwise), "lockstep" or "realtime".
    pace: lockstep only, the most sim seconds per wall second (0: as fast as the CPU allows, for tests)."""

    def __init__(
        self, rig: str | Rig = "sim-piper", clock: str = "auto", pace: float = 1.0, seed: int | None = None
    ):
        self.rig: Rig = rig if isinstance(rig, Rig) else load_rig(rig)
        self.clock_mode = clock
        self.pace, self.seed = float(pace), seed
        self.session = None
        self.hands: dict[str, VirtualHand] = {}
        self.activity: str | None = None  # "teleop" | "calibration" while one owns the rig
        self.messages: list[str] = []
        self.estopped = False
        self._lock = threading.RLock()
        self._status: dict[str, DeviceStatus] = {}
        self._mon_stop = threading.Event()
        self._mon: threading.Thread | None = None
        self._pace_origin: tuple[float, float] | None = None
        self._reset_status()

    # -- rig selection ----------------------------------------------------------------------------------
    @staticmethod
    def available_rigs() -> list[str]:
        return list_rigs()

    def select_rig(self, name_or_path: str) -> None:
        """Pick another rig file (disconnects first). ConfigError for a bad file."""
        rig = load_rig(name_or_path)
        self.disconnect()
        self.rig = rig
        self._reset_status()
        self.say(f"rig {rig.name} loaded from {rig.path}")

    def _reset_status(self) -> None:
        with self._lock:
            self._status = {
                d.name: DeviceStatus(d.name, d.role, d.driver, d.arm, _endpoint(d), mode=_mode(d))
                for d in self.rig.leaders + self.rig.followers
            }

    @property
    def simulated(self) -> bool:
        return self.rig.simulated

    @property
    def connected(self) -> bool:
        return self.session is not None

    @property
    def lockstep(self) -> bool:
        return self.session is not None and not self.session.clock.realtime

    def say(self, text: str) -> None:
        with self._lock:
            self.messages.append(f"{time.strftime('%H:%M:%S')} {text}")
            del self.messages[:-200]

    # -- connection -------------------------------------------------------------------------------------
    def connect(self) -> None:
        """Open the rig through its real drivers (and its twin when simulated); arms left safe. Blocking
        (seconds): call from a worker thread. UserError/ConfigError on failure, nothing left open."""
        if self.session is not None:
            return
        if self.activity == "rollout":
            raise UserError("a policy rollout has the rig", where="TUI",
                            fix="stop it on the Rollout screen (x)")
        from hardware.connect import open_rig

        mode = self.clock_mode
        if mode == "auto":
            mode = "lockstep" if self.rig.simulated else "realtime"
        session = open_rig(self.rig, clock=mode, seed=self.seed)
        if not session.clock.realtime and self.pace > 0:
            session.clock.attach(self._pace_step)
        self.session = session
        self.estopped = False
        self.hands = {}
        if session.twin is not None:
            for name, lead in session.leaders.items():
                q0 = lead.read().q
                self.hands[name] = VirtualHand(session.twin, name, np.where(np.isfinite(q0), q0, 0.0))
        self.make_safe("connected: idle")
        with self._lock:
            for d in self._status.values():
                d.connected = True
                if d.name in session.leaders or d.name in session.followers:
                    drv = session.leaders.get(d.name) or session.followers.get(d.name)
                    d.endpoint = (
                        _endpoint(
                            next(s for s in session.rig.leaders + session.rig.followers if s.name == d.name)
                        )
                        if drv is not None
                        else d.endpoint
                    )
        self._mon_stop.clear()
        self._mon = threading.Thread(target=self._monitor, name="factr2-tui-monitor", daemon=True)
        self._mon.start()
        kind = (
            "SIMULATED twin, " + ("lockstep clock" if not session.clock.realtime else "real-time clock")
            if session.twin is not None
            else "real hardware"
        )
        self.say(f"connected to {self.rig.name} ({kind})")

    def disconnect(self) -> None:
        """Stop any activity, leave the arms safe, close the buses (and the twin)."""
        self._stop_monitor()
        s = self.session
        if s is None:
            return
        self.make_safe("disconnect")
        s.close()
        self.session = None
        self.hands = {}
        self._pace_origin = None
        with self._lock:
            for d in self._status.values():
                d.connected = False
        self.say(f"disconnected from {self.rig.name} (arms left safe)")

    def shutdown(self) -> None:
        """Quit path: stop everything and leave the arms safe. Never raises."""
        try:
            self.disconnect()
        except Exception as e:  # noqa: BLE001 -- quitting must finish
            self.say(f"shutdown: {e}")

    def _stop_monitor(self) -> None:
        self._mon_stop.set()
        if self._mon is not None and self._mon is not threading.current_thread():
            self._mon.join(2.0)
        self._mon = None

    # -- safety -----------------------------------------------------------------------------------------
    def devices(self) -> list:
        s = self.session
        return [] if s is None else list(s.leaders.values()) + list(s.followers.values())

    def make_safe(self, reason: str) -> list[str]:
        """Every leader zero torque, every follower hold; each attempted even if another fails."""
        s = self.session
        return [] if s is None else make_safe(s.leaders.values(), s.followers.values(), reason)

    def estop(self, stop_activity: Callable[[], None] | None = None) -> str:
        """EMERGENCY STOP: end the running activity, leaders torque off, followers hold. Returns the line
        to show. Safe from any thread; never raises."""
        self.estopped = True
        if stop_activity is not None:
            try:
                stop_activity()
            except Exception as e:  # noqa: BLE001 -- the arms still go safe below
                self.say(f"e-stop: stopping the activity failed: {e}")
        if self.session is None:
            line = "E-STOP: no rig connected (nothing to stop)"
        else:
            problems = self.make_safe("emergency stop")
            line = "E-STOP: leader torque OFF, follower HOLD" + (
                f" -- PROBLEMS: {problems}" if problems else ""
            )
        self.say(line)
        return line

    # -- exclusive use by one activity ------------------------------------------------------------------
    def claim(self, activity: str, need_connection: bool = True) -> None:
        """Take the rig for `activity`; UserError if not connected (when it needs the connection: a policy
        rollout opens the rig itself) or another activity runs."""
        with self._lock:
            if self.session is None and need_connection:
                raise UserError("no rig connected", where="TUI", fix="connect on the Rig screen (key c)")
            if self.activity is not None:
                raise UserError(f"{self.activity} is running", where="TUI", fix=f"stop {self.activity} first")
            self.activity = activity
            self.estopped = False

    def release(self, activity: str) -> None:
        with self._lock:
            if self.activity == activity:
                self.activity = None
                self._pace_origin = None

    # -- the monitor ------------------------------------------------------------------------------------
    def _pace_step(self, t_sim: float) -> None:
        """Lockstep stepper that sleeps when simulated time runs ahead of wall time x pace."""
        now = time.monotonic()
        if self._pace_origin is None:
            self._pace_origin = (t_sim, now)
        ahead = (t_sim - self._pace_origin[0]) / self.pace - (now - self._pace_origin[1])
        if ahead > 0.0:
            time.sleep(min(ahead, 0.1))
        elif ahead < -0.5:
            self._pace_origin = (t_sim, now)  # far behind (slow CPU): do not try to catch up

    def _monitor(self) -> None:
        s = self.session
        while not self._mon_stop.is_set() and s is not None:
            if self.activity is None:
                self._poll(s, bus=True)
                if s.clock.realtime:
                    time.sleep(MONITOR_PERIOD_S)
                else:
                    s.clock.sleep(MONITOR_SIM_STEP_S)
            else:  # the activity owns the clock and the bus: only look at what it read last
                self._poll(s, bus=False)
                time.sleep(0.2)

    def _poll(self, s, bus: bool) -> None:
        for name, dev in list(s.leaders.items()) + list(s.followers.items()):
            read_ms = float("nan")
            try:
                if bus:
                    t0 = time.perf_counter()
                    st = dev.read()
                    read_ms = (time.perf_counter() - t0) * 1e3
                    if name in self.hands:
                        self.hands[name].apply(s.clock.now(), st.q, st.q_dot)
                else:
                    st = dev.last_state
                err = None
            except Exception as e:  # noqa: BLE001 -- shown on the rig screen, never raised into the UI
                st, err = None, f"{type(e).__name__}: {e}"
            with self._lock:
                d = self._status[name]
                d.connected = dev.is_connected
                d.safe = bool(dev.in_safe_state)
                if not np.isnan(read_ms):
                    d.read_ms = read_ms
                if st is not None:
                    d.q = np.asarray(st.q, dtype=float).copy()
                    temps = np.asarray(st.temperature, dtype=float)
                    d.temp_max_c = float(np.nanmax(temps)) if np.any(np.isfinite(temps)) else float("nan")
                    d.enabled = bool(np.all(np.asarray(st.status, dtype=np.uint32) & STATUS_ENABLED))
                    d.errors = status_words(st.status)
                    if np.any(np.asarray(st.status, dtype=np.uint32) & STATUS_HOLD):
                        d.safe = True
                if err:
                    d.errors = [err]

    def statuses(self) -> list[DeviceStatus]:
        with self._lock:
            return [
                DeviceStatus(**{k: (list(v) if isinstance(v, list) else v) for k, v in d.__dict__.items()})
                for d in self._status.values()
            ]

    def describe(self) -> str:
        r = self.rig
        kind = "SIMULATED (MuJoCo twin)" if r.simulated else "REAL HARDWARE"
        return f"{r.name}  [{kind}]  {r.description}"
