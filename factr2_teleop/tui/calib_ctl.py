"""NEXT calibration on a connected rig, step by step, for the Calibration screen (no Textual here).

Steps (each a method the screen runs in a worker thread; progress goes to a thread-safe CalibState):
  plan()      the free-motion coverage trajectory (calibration.trajectories), collision-checked on the twin
              scene; shortened to `minutes` at a rest point (the recipe's single-joint sweeps come first)
  replay()    calibration.next.collect.collect_free_motion: a slow move to the start pose, then the
              trajectory at its rate through the follower's position loop, logging q, q_dot, q_cmd, tau_m
              (+ the twin's ground truth, SIMULATED); its rigid-body residual guard holds the follower and
              stops on unexpected contact. Live plots here: tau_m and tau_m - RNEA(q, q_dot, qdd_ref).
              User abort / emergency stop: the progress callback stops it (follower hold).
  train()     calibration.pipeline.train_and_report: NEXT + baselines on the pipeline's held-out blocks
  diagnose()  calibration.diagnosis on the same logs (grey-box: effects found, error before/after)
  activate()  the follower's next_checkpoint set for this session + a rig file saved next to the checkpoint
"""

from __future__ import annotations

import json
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from factr2_teleop.tui.runtime import RigRuntime
from factr2_teleop.tui.stops import OperatorStop, operator_stop
from hardware.errors import UserError
from hardware.reasons import Reason

REST_QD = 1e-6  # rad/s: a trajectory sample with every |qd| below this is a rest point (piece boundary)
HISTORY = 50  # NEXT window [samples]


@dataclass
class CalibState:
    """Progress shown by the screen. step: plan|to_start|replay|train|diagnose|done|aborted|failed."""

    step: str = "idle"
    progress: float = 0.0  # 0..1 of the current step
    eta_s: float = float("nan")  # wall seconds left in the current step
    line: str = ""
    tau: deque = field(default_factory=lambda: deque(maxlen=240))  # (n,) measured torque [N*m]
    residual: deque = field(default_factory=lambda: deque(maxlen=240))  # (n,) model-based residual [N*m]
    epoch_losses: list = field(default_factory=list)  # (epoch, train, val)
    report: dict | None = None
    diagnosis: dict | None = None
    out_dir: str = ""
    checkpoint: str = ""
    rig_file: str = ""
    error: str | None = None
    failed_at: str = ""  # the step that was running when it aborted/failed


def shorten(traj, minutes: float):
    """The trajectory cut at its last rest point within `minutes`, then a move back home if needed."""
    from calibration.trajectories import Trajectory, ruckig_move

    rest = np.flatnonzero(np.all(np.abs(traj.qd) < REST_QD, axis=1))
    limit = minutes * 60.0 * traj.rate_hz
    ends = rest[(rest <= limit) & (rest > 0)]
    if ends.size == 0 or ends[-1] >= len(traj.t) - 1:
        return traj
    k = int(ends[-1]) + 1
    q, qd, qdd, ph = traj.q[:k], traj.qd[:k], traj.qdd[:k], traj.phase[:k]
    if not np.allclose(q[-1], traj.q[0]):
        from hardware.arms import load_arm

        lim = load_arm(traj.arm).limits if traj.arm else None
        v = 0.3 * (lim.v_max if lim is not None else np.ones(q.shape[1]))
        bq, bqd, bqdd = ruckig_move(q[-1], traj.q[0], v, 2 * v, 20 * v, traj.rate_hz)
        q, qd, qdd = (np.concatenate([a, b[1:]]) for a, b in ((q, bq), (qd, bqd), (qdd, bqdd)))
        ph = np.concatenate([ph, np.full(len(bq) - 1, ph[-1])])
    return Trajectory(
        t=np.arange(len(q)) / traj.rate_hz,
        q=q,
        qd=qd,
        qdd=qdd,
        phase=ph,
        rate_hz=traj.rate_hz,
        joint_names=traj.joint_names,
        arm=traj.arm,
        collision_checked=traj.collision_checked,
    )


class CalibrationRun:
    """One calibration of the rig's first follower. minutes: replay length; epochs: training epochs cap;
    out_dir: where logs, checkpoint and reports go."""

    def __init__(
        self,
        runtime: RigRuntime,
        out_dir: str | Path,
        minutes: float = 10.0,
        epochs: int = 400,
        samples_per_epoch: int = 16384,
    ):
        self.rt = runtime
        self.out = Path(out_dir)
        self.minutes, self.epochs = float(minutes), int(epochs)
        self.samples_per_epoch = int(samples_per_epoch)
        self.state = CalibState(out_dir=str(self.out))
        self.traj = None
        self.abort_reason: Reason | None = None  # an OperatorStop reason once asked to abort
        self._lock = threading.Lock()
        self.spec = runtime.rig.followers[0]
        self.logs: dict[str, Path] = {}
        self.cfg = self._config()

    def _config(self):
        """The calibration pipeline's settings for this screen: no pushed contact replay (a real arm cannot
        be pushed by script), training sized for the screen (epochs, one thread), no PNGs."""
        from calibration.next.train import TrainConfig
        from calibration.pipeline import CalibrationConfig

        train = TrainConfig(history=HISTORY, max_epochs=self.epochs, samples_per_epoch=self.samples_per_epoch,
                            threads=1, device="cpu", warmup=min(10, self.epochs), prior="auto")
        return CalibrationConfig(minutes=self.minutes, contact_eval_s=0.0, train=train, plots=False)

    # -- control --------------------------------------------------------------------------------------------
    def abort(self, reason: Reason | None = None) -> None:
        self.abort_reason = self.abort_reason or reason or operator_stop(OperatorStop.ABORTED)

    def _set(self, **kw) -> None:
        with self._lock:
            for k, v in kw.items():
                setattr(self.state, k, v)

    def _check_abort(self) -> None:
        if self.abort_reason is not None:
            raise _Aborted(self.abort_reason)

    # -- steps ------------------------------------------------------------------------------------
    def plan(self) -> None:
        from calibration.pipeline import plan_trajectory

        self._set(step="plan", progress=0.0, line="planning the free-motion coverage trajectory")
        traj = plan_trajectory(self.rt.rig, self.spec, self.cfg)
        self.traj = shorten(traj, self.minutes)
        chk = "collision-checked on the scene" if self.traj.collision_checked else "NOT collision-checked"
        self._set(progress=1.0, line=f"trajectory {self.traj.duration_s:.0f} s, {chk}")

    def _session(self):
        s = self.rt.session
        if s is None:
            raise UserError("no rig connected", where="Calibration", fix="connect on the Rig screen (key c)")
        return s

    def _hands(self, s) -> None:
        for name, hand in self.rt.hands.items():
            st = s.leaders[name].read()
            hand.apply(s.clock.now(), st.q, st.q_dot)

    def replay(self) -> None:
        """Move to the start pose and replay the trajectory with calibration.next.collect.collect_free_motion
        (its momentum-observer guard stops on unexpected contact); logs saved as plain logs (train /
        held-out)."""
        from calibration.next.collect import CollectStop, ContactStop
        from calibration.pipeline import collect, write_logs
        from hardware.arms.dynamics import ArmDynamics

        s = self._session()
        f = s.followers[self.spec.name]
        dyn = ArmDynamics(self.spec.arm)
        traj, dt = self.traj, 1.0 / self.traj.rate_hz
        n = f.n_joints
        w0 = time.monotonic()
        self._set(step="to_start", progress=0.0, line="moving to the start pose (slow)")

        def progress(done_s: float, total_s: float) -> bool:
            self._hands(s)  # SIMULATED rigs: the virtual hand keeps resting on the leader
            start_s = total_s - len(traj.t) * dt  # the move to the start pose comes first
            k = int(round((done_s - start_s) / dt)) - 1
            if k < 0:
                self._set(
                    progress=done_s / max(start_s, dt), line=f"to start: {done_s:.1f} / {start_s:.1f} s"
                )
                return self.abort_reason is not None
            st = f.last_state
            tau = np.asarray(st.tau_m, float)[:n]
            res = tau - dyn.rnea(st.q[:n], st.q_dot[:n], traj.qdd[min(k, len(traj.t) - 1)])
            with self._lock:
                self.state.tau.append(tau.copy())
                self.state.residual.append(res)
            if k % 10 == 0:
                frac = (k + 1) / len(traj.t)
                el = time.monotonic() - w0
                self._set(
                    step="replay",
                    progress=frac,
                    eta_s=el / frac * (1 - frac),
                    line=f"replay: {(k + 1) * dt:.1f} / {len(traj.t) * dt:.1f} s of trajectory",
                )
            return self.abort_reason is not None

        try:
            run = collect(s, self.spec, traj, self.cfg, progress)
        except ContactStop as e:
            raise _Aborted(f"unexpected contact -- follower on hold ({e.what})") from None
        if run.stopped is not None and run.stopped.kind is not CollectStop.CONTACT:
            raise _Aborted(self.abort_reason or f"stopped ({run.stopped})")
        if run.stopped is not None:
            self.rt.say(f"calibration: {run.stopped}")
        self.logs = write_logs(self.out, run, self.cfg)
        m = len(run.t)
        self._set(progress=1.0, eta_s=0.0, line=f"replay done: {m * dt:.1f} s recorded")

    def train(self) -> dict:
        from calibration.pipeline import train_and_report
        from hardware.threads import limit_threads

        self._set(step="train", progress=0.0, eta_s=float("nan"), line="training NEXT")

        def cb(p) -> bool:
            if not p.stage:  # the loss plot shows the kept model, not the gate's fold models
                with self._lock:
                    self.state.epoch_losses.append((p.epoch, p.train_loss, p.val_loss))
            frac = (p.epoch + 1) / max(p.max_epochs, 1)
            self._set(
                progress=frac,
                eta_s=p.elapsed_s / frac * (1 - frac),
                line=f"{p.stage + ': ' if p.stage else ''}epoch {p.epoch + 1}/{p.max_epochs}  "
                     f"train {p.train_loss:.4f}  val {p.val_loss:.4f}",
            )
            return self.abort_reason is not None

        with limit_threads(1, torch=True):  # this process's other work (the app) beside the training's own
            report = train_and_report(self.logs, self.out, self.spec.arm, self.cfg, callback=cb)
        self._check_abort()
        self._set(report=report, checkpoint=str(self.out / "next"), progress=1.0, line="training done")
        return report

    def diagnose(self) -> dict:
        from calibration.diagnosis.basis import PinocchioBasis
        from calibration.diagnosis.data import load_segment
        from calibration.diagnosis.loop import LoopConfig, diagnose
        from calibration.diagnosis.report import write
        from hardware.arms import load_arm

        self._set(
            step="diagnose", progress=0.0, eta_s=float("nan"), line="diagnosing the residual (grey-box)"
        )
        train = [load_segment(self.logs["train"])]
        held = [load_segment(self.logs["heldout"])]
        basis = PinocchioBasis(load_arm(self.spec.arm).pinocchio_model())
        dg = diagnose(basis, train, held, LoopConfig(max_effects=6))
        meta = {
            "units": train[0].units,
            "joint_names": list(self.traj.joint_names),
            "title": "calibration replay",
            "basis": basis.describe(),
        }
        rep = write(dg, self.out / "diagnosis", meta, plots=False)
        self._set(diagnosis=rep, progress=1.0, line="diagnosis done")
        return rep

    def activate(self) -> str:
        """Use the new checkpoint for this rig now (until the app closes); save a rig file naming it."""
        import dataclasses

        ck = str(self.out / "next")
        rig = self.rt.rig
        followers = [
            dataclasses.replace(f, next_checkpoint=ck) if f.name == self.spec.name else f
            for f in rig.followers
        ]
        self.rt.rig = dataclasses.replace(rig, followers=followers)
        if self.rt.session is not None:
            self.rt.session.rig = dataclasses.replace(
                self.rt.session.rig,
                followers=[
                    dataclasses.replace(f, next_checkpoint=ck) if f.name == self.spec.name else f
                    for f in self.rt.session.rig.followers
                ],
            )
        text = rig.path.read_text()
        rig_file = self.out / f"{rig.name}.toml"
        rig_file.write_text(_with_checkpoint(text, self.spec.name, ck))
        self._set(rig_file=str(rig_file), checkpoint=ck)
        self.rt.say(f"NEXT calibration active for {self.spec.name}")
        return str(rig_file)

    def run_all(self) -> None:
        """Every step in order (the screen's worker calls this); the arms end safe whatever happens."""
        try:
            self.rt.claim("calibration")
        except UserError as e:
            self._set(step="failed", error=str(e), line=f"cannot start: {e}")
            return
        try:
            self.plan()
            self.replay()
            self.rt.make_safe("calibration replay done")
            self.train()
            self.diagnose()
            self.activate()
            self._set(step="done", progress=1.0, eta_s=0.0, line="calibration complete and active")
        except _Aborted as e:
            self._set(failed_at=self.state.step, step="aborted", error=str(e), line=f"ABORTED: {e}")
        except Exception as e:  # noqa: BLE001 -- shown on screen as one line
            self._set(
                failed_at=self.state.step,
                step="failed",
                error=f"{type(e).__name__}: {e}",
                line=f"FAILED: {type(e).__name__}: {e}",
            )
        finally:
            self.rt.make_safe("calibration ended")
            self.rt.release("calibration")

    def snapshot(self) -> CalibState:
        with self._lock:
            st = self.state
            return CalibState(
                **{
                    k: (
                        deque(v, maxlen=v.maxlen)
                        if isinstance(v, deque)
                        else list(v)
                        if isinstance(v, list)
                        else v
                    )
                    for k, v in st.__dict__.items()
                }
            )


class _Aborted(Exception):
    pass


def _with_checkpoint(toml_text: str, follower: str, ck: str) -> str:
    """The rig file text with `next_checkpoint = ck` in the [[followers]] table named `follower`."""
    lines = toml_text.splitlines()
    out, in_target, done = [], False, False
    for line in lines:
        s = line.strip()
        if s.startswith("["):
            if in_target and not done:
                out.append(f"next_checkpoint = {json.dumps(ck)}")
                done = True
            in_target = False
        if in_target and s.startswith("next_checkpoint"):
            continue
        out.append(line)
        if (
            s.startswith("name")
            and s.split("=", 1)[-1].strip().strip('"') == follower
            and _last_header(out) == "[[followers]]"
        ):
            in_target = True
    if in_target and not done:
        out.append(f"next_checkpoint = {json.dumps(ck)}")
    return "\n".join(out) + "\n"


def _last_header(lines: list[str]) -> str:
    for line in reversed(lines):
        if line.strip().startswith("["):
            return line.strip()
    return ""
