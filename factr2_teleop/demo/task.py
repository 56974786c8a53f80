"""The demo task on a twin (SIMULATED): virtual operator presses the follower onto the table and wipes,
bilateral feedback on, ground truth and wire-side commands logged for the metrics.

    run = DemoRun(DemoConfig(seconds=60, mode="next", clock="realtime"), next_source=estimator)
    run.run()                  # blocking; run.loop.snapshot() from another thread for a live view
    result = run.result()      # DemoResult: the --json numbers + per-mode wipe numbers

Wiring: open_rig(rig) -> factr2_teleop.session TeleopSession (the pairs `factr2 teleop` builds for the same
options) with a per-tick hook that moves the virtual hand and samples ground truth for the metrics.
The virtual hand torque is applied from the loop's per-tick hook (held by the twin until the next tick).
Commands are logged on the wire side (after the safety layer, where the driver sends them) and checked
against the rig's limits by demo.metrics, independently of the safety layer's code.
"""

from __future__ import annotations

import gc
import time
from dataclasses import dataclass, field

import numpy as np

from calibration.estimators import DOB_GAIN_PER_S, FEEDBACK_MODES, PP_STIFFNESS_NM_PER_RAD
from factr2_teleop.demo import metrics as M
from factr2_teleop.teleop.pair import COUPLED, HOLD
from factr2_teleop.teleop.record import TickRecord
from factr2_teleop.teleop.virtual_operator import (
    OperatorScript,
    Segment,
    VirtualOperator,
    make_task_script,
)
from hardware import sim_cpu
from hardware.sim.twin_driven_clock import TwinDrivenClock
from hardware.threads import limit_threads

# Task on the sim-piper table scene, leader joints [rad]: above the table, and a press target beyond the
# surface (the follower stops near j2 = 1.9 rad: 0.1 rad beyond) so the hand keeps pushing in contact.
ABOVE = np.array([0.0, 1.6, -1.0, 0.0, 0.6, 0.0])
PRESS = np.array([0.0, 2.0, -1.0, 0.0, 0.6, 0.0])
WIPE_AMP = np.array([0.3, 0.0, 0.0, 0.0, 0.0, 0.0])  # rad: wipe = base yaw oscillation while pressing
CYCLE_S = {"free": 1.5, "reach": 2.0, "contact": 1.5, "wipe": 4.0, "release": 2.0}  # one task cycle [s]
PIPER_GAINS = [0.06, 0.08, 0.08, 0.03, 0.03, 0.02]  # K_f, leader N*m per follower N*m (FACTR 2 magnitudes)
SURFACE_NORMAL = np.array([0.0, 0.0, 1.0])  # table normal (world, up)
LAG_GRID_S = 0.001  # s: feedback lag resolution
SETTLE_S = 1.0  # s: the hand holds the leader still at the start (soft start)
# leaders whose joints ABOVE / PRESS are written for; any other arm's poses come from its description
# (factr2_teleop/demo/poses.py)
TASK_LAYOUT_LEADERS = ("gello_piper", "gello_yam")


@dataclass
class DemoConfig:
    """rig: a simulated rig; seconds: task length [s]; mode: FEEDBACK_MODES; rate_hz: loop rate [Hz];
    clock: "realtime" (wall-clock timing; the loop thread steps the twin, TwinDrivenClock), "realtime-thread"
    (the twin's own stepping thread) or "lockstep" (deterministic, as fast as the CPU goes);
    gain: K_f per leader joint; clip_nm: feedback clip per joint [N*m]; hand_*: virtual operator."""

    rig: str = "sim-piper"
    seconds: float = 60.0
    mode: str = "dob"
    rate_hz: float = 500.0
    clock: str = "realtime"
    seed: int = 0
    gain: list = field(default_factory=lambda: list(PIPER_GAINS))
    clip_nm: float = 1.0
    t_high_nm: float = 2.0
    t_low_nm: float = 1.0
    dob_gain: float = DOB_GAIN_PER_S
    pp_stiffness: float = PP_STIFFNESS_NM_PER_RAD
    hand_stiffness: float = 3.0
    hand_damping: float = 0.1
    hand_tau_max_nm: float = 2.0
    contact_force: bool = False  # log the follower's total contact force per tick (wipe table; costs time)
    # "inprocess": the leader's Dynamixel packets (same bytes, sdk unchanged) go to the emulator on the loop's
    # thread, no pty and no emulator thread; "pty": through a pseudo-terminal as for a real USB adapter
    dynamixel_transport: str = "inprocess"
    # ground truth (0.3 ms per read) every this many ticks for the metrics; 0: 2 in real time, 1 in lockstep
    truth_every: int = 0
    next_worker: bool = True  # NEXT in its own process on a real-time clock (TeleopOptions.next_worker)
    faults: tuple = ()  # hardware.sim.faults.FaultSpec the twin plays (empty: the rig's [twin] faults)

    def options(self):
        """The session layer's TeleopOptions of this configuration."""
        from factr2_teleop.session.pairs import TeleopOptions

        fb = {"clip_nm": self.clip_nm, "t_high_nm": self.t_high_nm, "t_low_nm": self.t_low_nm}
        return TeleopOptions(mode=self.mode, rate_hz=self.rate_hz, gain=list(self.gain), feedback=fb,
                             pp_stiffness_nm_per_rad=self.pp_stiffness, dob_gain_per_s=self.dob_gain,
                             next_worker=self.next_worker)


def task_script(q_home: np.ndarray, seconds: float, above: np.ndarray = ABOVE,
                press: np.ndarray = PRESS) -> OperatorScript:
    """Task cycles (free, reach, contact, wipe, release) filling `seconds`; shorter runs get one scaled
    cycle (>= 5 s recommended so that there is contact). above / press: leader joints [rad]."""
    cycle = sum(CYCLE_S.values())
    seconds = max(seconds - SETTLE_S, 1.0)
    n = max(1, int(seconds // cycle))
    scale = seconds / (n * cycle)
    one = make_task_script(q_home, above, press, WIPE_AMP, free_s=CYCLE_S["free"] * scale,
                           reach_s=CYCLE_S["reach"] * scale, contact_s=CYCLE_S["contact"] * scale,
                           wipe_s=CYCLE_S["wipe"] * scale, release_s=CYCLE_S["release"] * scale)
    # the hand holds still first, as an operator does while the soft start brings the follower over
    hold = Segment("free", SETTLE_S, np.asarray(q_home, dtype=float).copy())
    return OperatorScript(q_start=one.q_start, segments=[hold] + one.segments * n)


def contact_force_n(world) -> float:
    """Sum of contact normal forces [N] in a twin world right now (SIMULATED ground truth)."""
    import mujoco

    m, d = world.model, world.data
    f6, total = np.zeros(6), 0.0
    with world.lock:
        for i in range(d.ncon):
            mujoco.mj_contactForce(m, d, i, f6)
            total += abs(f6[0])
    return total


class _WireLog:
    """What a driver puts on the wire after the safety layer (its command observer, hardware.roles):
    (t, t_sent, values, hold). t is when the command was issued, t_sent when it reached the wire side: the
    safety layer's own clock read lies between the two, so a rate check on [t, t_sent] brackets needs no
    trust in the layer's timing."""

    def __init__(self, device, attr: str):
        self.t: list[float] = []
        self.t_sent: list[float] = []
        self.v: list[np.ndarray] = []
        self.hold: list[bool] = []
        self._attr = attr
        device.add_command_observer(self._on_command)

    def _on_command(self, t_issued: float, t_sent: float, safe) -> None:
        with sim_cpu.simulated():  # the demo's metrics, not the app's work: kept out of the loop's CPU
            self.t.append(t_issued)
            self.t_sent.append(t_sent)
            self.v.append(np.array(getattr(safe, self._attr), dtype=float))
            self.hold.append(bool(getattr(safe, "hold", False)))

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        return np.array(self.t), (np.array(self.v) if self.v else np.zeros((0, 0)))


@dataclass
class DemoResult:
    mode: str
    simulated: bool
    clock: str
    seconds: float
    loop_hz: float
    period_p50_ms: float
    period_p99_ms: float
    period_max_ms: float
    overruns: int
    ticks: int
    feedback_corr: float
    feedback_corr_per_joint: list
    feedback_lag_ms: float
    tau_ext_l1_contact: float
    tau_ext_l1_free: float
    max_command_violation: int
    wall_s: float
    cpu_ms_per_tick: float  # process CPU time per tick (all threads; twin included): load-independent cost
    loop_cpu_ms_per_tick: float = float("nan")  # the loop thread's own CPU per tick (real time: no twin)
    loop_cpu_share: float = float("nan")  # loop_cpu_ms_per_tick over the period (target <= 0.25 at 500 Hz)
    loop_twin_cpu_ms_per_tick: float = float("nan")  # the twin's work on the loop's thread (hardware/sim_cpu)
    next_worker_cpu_ms_per_tick: float = float("nan")  # NEXT's own process, if used (calibration/next/worker)
    target_hz: float = float("nan")  # the loop's rate at the end (lower: it degraded, teleop/degrade.py)
    holds: int = 0  # times the follower went on hold
    hold_s: float = 0.0  # time spent on hold [s]
    refused_resumes: int = 0  # resumes refused (leader too far from the follower), once per refusal
    hand_push_n: float = float("nan")  # mean Cartesian force the virtual hand pushes into the table [N]
    hand_tau_l1_wipe_nm: float = float("nan")
    peak_contact_force_n: float = float("nan")
    mean_contact_force_n: float = float("nan")
    messages: list = field(default_factory=list)

    def to_json(self) -> dict:
        """The metrics; a value not measured in this run is null, and `null_fields` says why (JSON has no
        NaN, and a bare null reads like a bug)."""
        def num(x):
            return None if isinstance(x, float) and not np.isfinite(x) else x
        out = {k: ([num(v) for v in val] if isinstance(val, list) and k != "messages" else num(val))
               for k, val in self.__dict__.items()}
        why = "not measured in this run (docs/demo.md)"
        out["null_fields"] = {k: NULL_WHY.get(k, why) for k, v in out.items() if v is None}
        return out


# why a metric can be null (docs/demo.md)
_FORCE_WHY = ("the follower's contact force is measured only in the wipe-table benchmark runs "
              "(bench/bench_demo.py, contact_force=True), not in `factr2 demo`")
NULL_WHY = {"peak_contact_force_n": _FORCE_WHY, "mean_contact_force_n": _FORCE_WHY}


class DemoRun:
    """Builds the session, pair and operator; run() ticks the loop; result() computes the metrics."""

    def __init__(self, cfg: DemoConfig, next_source=None, next_path: str | None = None):
        from hardware.connect import open_rig

        if cfg.mode not in FEEDBACK_MODES:
            raise ValueError(f"unknown mode {cfg.mode!r}")
        # BLAS on one thread until close(): multi-threaded BLAS makes NEXT 10x slower on a busy machine
        self.threads = limit_threads(1, blas=True, env=True)
        self.cfg, self.next_path, self.session = cfg, next_path, None
        try:
            self.session = open_rig(cfg.rig, clock="lockstep" if cfg.clock == "lockstep" else "realtime",
                                    seed=cfg.seed, dynamixel_transport=cfg.dynamixel_transport,
                                    faults=list(cfg.faults) or None)
            self.clock = self.session.clock
            if cfg.clock == "realtime":  # the loop thread steps the twin from here on (set-up not simulated)
                self.session.twin.stop_realtime()
                self.clock = TwinDrivenClock(self.session.twin)
            self._build(next_source)
        except BaseException:
            self.close()
            raise

    def _build(self, next_source) -> None:
        from factr2_teleop.session.teleop import TeleopSession

        cfg, s = self.cfg, self.session
        self.leader, self.follower = s.pairs[0]
        fspec = s.rig.followers[0]
        opts = cfg.options()
        nexts = {fspec.name: next_source} if cfg.mode == "next" and next_source is not None else None
        self.teleop = TeleopSession(s, opts, clock=self.clock, next_estimators=nexts,
                                    next_paths={fspec.name: self.next_path} if self.next_path else None)
        self.pair = self.teleop.pairs[0]
        self.n = self.follower.n_joints
        world = s.twin.devices[fspec.name].world
        self._gt_world, self._gt_bank = world, world.banks.index(s.twin.bank(fspec.name))
        self._hand_bank = s.twin.bank(s.rig.leaders[0].name)  # what the simulated hand feels (felt_joints)
        self._model_fns = (self.pair.law.gravity_fn, self.pair.law.jacobian_fn)
        self.script = task_script(self.leader.read().q, cfg.seconds, *self._task_poses(s, fspec, world))
        self.operator = VirtualOperator(self.script, cfg.hand_stiffness, cfg.hand_damping,
                                        cfg.hand_tau_max_nm,
                                        jacobian_fn=self.pair.law.jacobian_fn, surface_normal=SURFACE_NORMAL,
                                        t0=s.clock.now(), defer_force=True)
        self.wire_f = _WireLog(self.follower, "q")
        self.wire_l = _WireLog(self.leader, "tau")
        self.teleop.hooks.append(self._on_tick)
        self.loop = self.teleop.loop
        self._rows: list[tuple] = []  # per ground-truth tick: t, phase, fb, est, true, contact, force, task
        self._tick_n = 0
        self._return_goal: np.ndarray | None = None  # leader pose the operator brings it back to [rad]
        self._truth_every = cfg.truth_every or (1 if cfg.clock == "lockstep" else 2)
        self.wall_s = self.cpu_s = float("nan")

    def _task_poses(self, s, fspec, world) -> tuple[np.ndarray, np.ndarray]:
        """ABOVE / PRESS for the leaders they are written for; else derived from the follower's description
        when its leader copies its joints (a generated GELLO)."""
        from hardware.arms import load_arm

        if s.rig.leaders[0].arm in TASK_LAYOUT_LEADERS or self.leader.n_joints != self.n:
            return ABOVE, PRESS
        from factr2_teleop.demo.poses import derived_task_poses

        return derived_task_poses(load_arm(fspec.arm), world.model)

    def _on_tick(self, rec: TickRecord) -> None:
        with sim_cpu.simulated():  # the simulated hand and the metrics' ground truth: not the app's CPU
            # the hand is an impedance the twin applies at its firmware rate from the true joints (a torque
            # held through a late tick flung the light wrist on a slow core, #53); the log keeps the torque it
            # pushes now, for the metrics
            goal = self._operator_goal(rec)
            op = self.operator
            q_ref, qd_ref, _ = op.reference(rec.t, goal)
            self.session.twin.apply_leader_hand_impedance(q_ref, qd_ref, op.k, op.d, op.tau_max)
            q_l, qd_l = (a[: op.n] for a in self._hand_bank.true_state())
            op.torque(rec.t, q_l, qd_l, goal)
            self._tick_n += 1
            if self._tick_n % self._truth_every == 0:
                gt = self._gt_world.ground_truth(self._truth_every / self.cfg.rate_hz)[self._gt_bank]
                f = contact_force_n(self._gt_world) if self.cfg.contact_force else float("nan")
                self._rows.append((rec.t, rec.phase, rec.tau_feedback, rec.tau_ext,
                                   gt.tau_ext[: self.n].copy(), gt.contact, f, self.operator.log[-1].phase))

    def _operator_goal(self, rec: TickRecord) -> np.ndarray | None:
        """What the operator does about a hold, as a person does: stops the task while the follower holds,
        brings the leader back to the follower's pose after a refused resume (the pair resumes by itself
        once they are close), keeps still while the soft start brings the follower over, then carries on
        with the task once the pair is coupled again."""
        if rec.phase == COUPLED:
            self.operator.resume(rec.t)
            self._return_goal = None
        elif rec.phase == HOLD:
            self.operator.pause(rec.t)
            if self.pair.resume_refused:
                self._return_goal = self.pair.map.backward(np.asarray(rec.follower.q, dtype=float))
        return self._return_goal

    def run(self) -> None:
        self._warm_up()
        t0, c0 = time.perf_counter(), time.process_time()
        if isinstance(self.clock, TwinDrivenClock):
            self.clock.start()
        try:
            self.loop.run(duration_s=self.cfg.seconds)
        finally:
            self.wall_s = time.perf_counter() - t0
            self.cpu_s = time.process_time() - c0

    def _warm_up(self) -> None:
        """First calls of the per-tick pieces (numpy/pinocchio/BLAS first-use costs, up to tens of ms)
        happen here, not in the first real-time ticks where they read as stale data."""
        from calibration.estimators import EstimatorInput

        ls, fs = self.leader.read(), self.follower.read()
        self.operator.torque(self.operator.t0, ls.q, np.nan_to_num(ls.q_dot))
        self.operator.log.clear()
        self._gt_world.ground_truth(self._truth_every / self.cfg.rate_hz)  # also starts the per-step history
        if self.cfg.contact_force:
            contact_force_n(self._gt_world)
        g, jac = self._model_fns
        g(ls.q)
        jac(ls.q)
        est = self.pair.estimator
        if self.cfg.mode == "dob":  # not est(): its first call sets the momentum origin
            est.mass(fs.q), est.coriolis(fs.q, np.zeros_like(fs.q)), est.gravity(fs.q)
        elif est is not None:
            q_l = self.pair.map.forward(ls.q)
            est.update(EstimatorInput(t=self.clock.now(), follower=fs, q_leader_f=q_l))
        # A set-up that just recorded and trained NEXT in this process leaves much garbage; a full
        # collection during the loop stalled a tick for ~150 ms (two first runs measured 490-491 Hz with
        # one such stall, later runs 500.0 Hz): collect it now, before the real-time part.
        gc.collect()

    def close(self) -> None:
        try:
            if self.session is not None:
                self.session.close()
        finally:
            self.threads.close()

    def result(self) -> DemoResult:
        cfg, rows = self.cfg, self._rows
        st = self.loop.timing.stats(whole_run=True)
        nl = self.leader.n_joints
        coupled = np.array([r[1] == "coupled" for r in rows], dtype=bool)  # (bool also when no row)
        fb = np.array([r[2] if r[2] is not None else np.zeros(nl) for r in rows])
        est = np.array([r[3] for r in rows])
        true = np.array([r[4] for r in rows])
        contact = np.array([r[5] for r in rows], dtype=bool) & coupled
        force = np.array([r[6] for r in rows])
        mp = self.pair.map
        gain = np.asarray(self.pair.law.cfg.feedback.gain, dtype=float) * np.ones(nl)
        fb_f = M.feedback_on_follower(fb, gain, mp.index, mp.k)
        corr = M.per_joint_corr(fb_f, true, contact)
        lag = float("nan")
        if cfg.mode != "none" and np.sum(coupled) > 10:  # on a 1 ms grid: real-time ticks are not uniform
            tc = np.array([r[0] for r in rows])[coupled]
            lag = M.lag_by_xcorr(M.resample(tc, fb_f[coupled], LAG_GRID_S),
                                 M.resample(tc, true[coupled], LAG_GRID_S), LAG_GRID_S)
        lim_f, lim_l = self.follower.safety.limits, self.leader.safety.limits
        tf, qf = self.wire_f.arrays()
        tl, taul = self.wire_l.arrays()
        viol = M.command_violations(qf, tf, lim_f.q_min, lim_f.q_max, lim_f.v_max, 0.0,
                                    hold=np.array(self.wire_f.hold, dtype=bool),
                                    t_sent=np.array(self.wire_f.t_sent)) \
            + M.torque_violations(taul, lim_l.tau_max)
        summ = self.operator.summary()
        wipe = summ.get("wipe", {})
        wipe_rows = np.array([r[7] == "wipe" for r in rows], dtype=bool)
        fw = force[wipe_rows] if len(rows) else force[:0]
        fw = fw[np.isfinite(fw)]
        return DemoResult(
            mode=cfg.mode, simulated=True, clock=cfg.clock, seconds=cfg.seconds, loop_hz=st.rate_hz,
            period_p50_ms=st.period_p50_ms, period_p99_ms=st.period_p99_ms,
            period_max_ms=st.period_max_ms, overruns=st.overruns,
            ticks=st.ticks,
            feedback_corr=float(np.nanmean(corr)) if np.any(np.isfinite(corr)) else float("nan"),
            feedback_corr_per_joint=[float(c) for c in corr],
            feedback_lag_ms=lag * 1e3, tau_ext_l1_contact=M.l1_mean(est, contact),
            tau_ext_l1_free=M.l1_mean(est, coupled & ~np.array([r[5] for r in rows])),
            max_command_violation=int(viol), wall_s=self.wall_s,
            cpu_ms_per_tick=self.cpu_s / max(st.ticks, 1) * 1e3,
            loop_cpu_ms_per_tick=st.cpu_mean_ms, loop_cpu_share=st.cpu_share,
            loop_twin_cpu_ms_per_tick=st.sim_cpu_mean_ms,
            next_worker_cpu_ms_per_tick=1e3 * getattr(self.pair.estimator, "cpu_s", np.nan) / (st.ticks or 1),
            target_hz=st.target_hz, holds=self.pair.holds, hold_s=self.pair.hold_s,
            refused_resumes=self.pair.resume_refusals,
            hand_push_n=float(wipe.get("force_n", float("nan"))),
            hand_tau_l1_wipe_nm=float(wipe.get("tau_l1_nm", float("nan"))),
            peak_contact_force_n=float(np.max(fw)) if fw.size else float("nan"),
            mean_contact_force_n=float(np.mean(fw)) if fw.size else float("nan"),
            messages=[m[2] for m in self.loop.snapshot().messages])
