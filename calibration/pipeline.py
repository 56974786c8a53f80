"""NEXT calibration on a rig, one pipeline for the CLI (`factr2 calibrate --rig`), the terminal app's
Calibration screen and the demo's first-run set-up: plan -> collect -> split -> train -> report.

    cfg = CalibrationConfig(minutes=10)
    traj = plan_trajectory(rig, spec, cfg)
    run = collect(session, spec, traj, cfg, progress)            # one policy for an unexpected contact
    logs = write_logs(out, run, cfg, contact_eval=None)          # one held-out policy (split_mask)
    (calibrate_rig also records the run as MCAP: out/data/calibration.mcap, one episode per replay)
    report = train_and_report(logs, out, spec.arm, cfg)

Held-out policy: every k-th block of HELDOUT_BLOCK_S seconds (k = round(1 / heldout_frac)), spread over the
whole replay, so the held-out part holds every phase of the trajectory (slow, multi-joint, fast); a held-out
tail would be the fast phase alone, which the model never saw. Unexpected contact: the follower holds; the run
is kept, less its last CONTACT_TRIM_S, when at least min_minutes remain, else ContactStop goes up.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calibration.next.train import TrainConfig
from hardware.errors import UserError
from hardware.reasons import Reason, render
from hardware.timeseries import heldout_spans, spans_mask

HELDOUT_FRAC = 0.15  # share of the replay held out for evaluation
HELDOUT_BLOCK_S = 20.0  # held-out free motion comes in blocks of this length [s]
CONTACT_EVAL_S = 300.0  # pushed replay scored for contact L1 [s]: the paper's 5 min of held-out contact data
MIN_MINUTES = 2.0  # an unexpected contact after at least this much data keeps it [min]
CONTACT_TRIM_S = 2.0  # dropped before an unexpected contact [s]
RATE_HZ = 100.0  # the paper's NEXT rate [Hz]
OBSERVER_GAIN = 50.0  # momentum-observer baseline gain K_o [1/s]


@dataclass
class CalibrationConfig:
    """minutes: length of the free-motion replay [min]; rate_hz: its rate and NEXT's [Hz]; heldout_frac;
    contact_eval_s: twins only, length of a held-out replay with scripted pushes scored for contact [s] (0:
    none); min_minutes: see the module; train: NEXT's TrainConfig; observer_gain [1/s]; plots: PNGs."""

    minutes: float = 10.0
    rate_hz: float = RATE_HZ
    heldout_frac: float = HELDOUT_FRAC
    contact_eval_s: float = CONTACT_EVAL_S
    min_minutes: float = MIN_MINUTES
    train: TrainConfig = field(default_factory=TrainConfig)
    observer_gain: float = OBSERVER_GAIN
    plots: bool = True

    def check(self) -> None:
        if not self.minutes > 0:
            raise UserError(f"--minutes {self.minutes} must be positive", where="--minutes", fix="e.g. 10")
        if not 0.0 < self.heldout_frac < 0.9:
            raise UserError(f"--heldout-frac {self.heldout_frac} out of range", where="--heldout-frac",
                            fix="use a value between 0 and 0.9, e.g. 0.15")


def plan_trajectory(rig, spec, cfg: CalibrationConfig):
    """The collision-checked free-motion coverage trajectory for a follower (calibration.trajectories)."""
    from calibration.trajectories import arm_coverage_trajectory

    return arm_coverage_trajectory(spec.arm, cfg.minutes, cfg.rate_hz,
                                   scene=rig.twin.scene if rig.simulated else "table")


def collect(session, spec, traj, cfg: CalibrationConfig, progress: Callable | None = None, recorder=None):
    """Replay traj on the follower and record it (calibration.next.collect; also to `recorder`, an MCAP
    Recorder, when given). An unexpected contact keeps the data before it when at least cfg.min_minutes
    remain (run.stopped says so), else raises ContactStop."""
    from calibration.next.collect import CollectStop, ContactStop, collect_free_motion

    try:
        return collect_free_motion(session, spec.name, traj, progress=progress, recorder=recorder)
    except ContactStop as e:
        run = e.run
        keep = 0 if run is None else max(0, len(run.t) - int(CONTACT_TRIM_S * cfg.rate_hz))
        if keep < cfg.min_minutes * 60.0 * cfg.rate_hz:
            raise
        for k in ("t", "q", "qd", "q_cmd", "tau_m", "current", "temperature", "tau_ext_true", "contact"):
            setattr(run, k, getattr(run, k)[:keep])
        run.stopped = Reason.of(CollectStop.CONTACT, what=e.what, kept_min=keep / cfg.rate_hz / 60.0)
        return run


def split_mask(n: int, cfg: CalibrationConfig) -> np.ndarray:
    """(n,) bool, True where a sample is held out (the module's policy). A run shorter than k blocks gets
    blocks of n // k samples, so something is held out."""
    k = max(2, int(round(1.0 / cfg.heldout_frac)))
    block = max(1, min(int(round(HELDOUT_BLOCK_S * cfg.rate_hz)), n // k))
    _train, held = heldout_spans([n], cfg.heldout_frac, block_len=block, offset=1)
    return spans_mask(held, [n])[0]


def write_logs(out: str | Path, run, cfg: CalibrationConfig, contact_eval=None) -> dict[str, Path]:
    """out/data/{free_motion, train, heldout[, contact_eval]}.npz; the time gaps left by the split make
    resampling cut both files into segments, so no training window spans a cut. -> {name: path}."""
    from hardware.recording.plain_log import save_plain_log

    data = Path(out) / "data"
    data.mkdir(parents=True, exist_ok=True)
    arrays = run.arrays()
    n = len(arrays["t"])
    held = split_mask(n, cfg)
    per = {k: v for k, v in arrays.items() if v.ndim >= 1 and len(v) == n}
    fixed = {k: v for k, v in arrays.items() if k not in per}
    paths = {"free_motion": save_plain_log(data / "free_motion.npz", **arrays),
             "train": save_plain_log(data / "train.npz", **{k: v[~held] for k, v in per.items()}, **fixed),
             "heldout": save_plain_log(data / "heldout.npz", **{k: v[held] for k, v in per.items()}, **fixed)}
    if contact_eval is not None:
        paths["contact_eval"] = save_plain_log(data / "contact_eval.npz", **contact_eval.arrays())
    return paths


def train_and_report(logs: dict[str, Path], out: str | Path, arm: str, cfg: CalibrationConfig,
                     callback=None, say: Callable[[str], None] | None = None) -> dict:
    """NEXT and the baselines on the logs of write_logs (calibration.report); report.json's dict."""
    from calibration.report import calibrate_from_logs

    evals = [logs["heldout"]] + ([logs["contact_eval"]] if "contact_eval" in logs else [])
    return calibrate_from_logs([logs["train"]], out, evals, arm=arm, cfg=cfg.train, rate_hz=cfg.rate_hz,
                               observer_gain=cfg.observer_gain, callback=callback, plots=cfg.plots, say=say)


def record_pushed_replay(session, spec, seconds: float, rate_hz: float, seed: int = 1, recorder=None):
    """SIMULATED: replay a fresh coverage trajectory (seed >= 1: not the training data's) while the twin
    pushes the links of joints 3-6 (10-40 N, 0.5-1.5 s, one every ~3 s); the log carries the twin's ground
    truth (the mean over each sample period). The calibration's contact evaluation is seed 1; other seeds give
    independent runs (bench/tune_next_filter.py)."""
    import mujoco

    from calibration.next.collect import Push, collect_free_motion
    from calibration.trajectories import arm_coverage_trajectory
    from hardware.arms import load_arm

    traj = arm_coverage_trajectory(spec.arm, seconds / 60.0, rate_hz, scene=session.rig.twin.scene, seed=seed)
    arm = load_arm(spec.arm)
    m = arm.mujoco_model()  # the body each arm joint moves: link3..link6 on the built-in arms
    bodies = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY,
                                int(m.jnt_bodyid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, jn)]))
              for jn in arm.joint_names]
    rng = np.random.default_rng(seed)
    pushes, t = [], 2.0
    while t < traj.duration_s - 2.0:
        d = rng.uniform(0.5, 1.5)
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        pushes.append(Push(t, bodies[min(int(rng.integers(3, 7)), len(bodies)) - 1],
                           tuple(rng.uniform(10, 40) * direction), d))
        t += d + rng.uniform(1.0, 3.0)
    return collect_free_motion(session, spec.name, traj, pushes=pushes, recorder=recorder)


RECORDING_NAME = "calibration.mcap"  # out/data/: the calibration run's MCAP recording (docs/recording.md)


def open_recording(out: str | Path, session, spec):
    """The calibration run's MCAP Recorder (hardware.recording), out/data/calibration.mcap, named like
    teleop's recordings: the rig, its arms and whether it is a twin in the recording metadata, the follower's
    joint states under its device name. A rerun into the same folder replaces the previous recording."""
    from hardware.arms import load_arm
    from hardware.recording.metadata import describe_recording
    from hardware.recording.writer import Recorder

    rig = session.rig
    arm = load_arm(spec.arm)
    meta = describe_recording(rig_path=rig.path, arm_files=[arm.mjcf_path], task="NEXT calibration",
                              twin=session.twin is not None)
    path = Path(out) / "data" / RECORDING_NAME
    path.parent.mkdir(parents=True, exist_ok=True)
    return Recorder(path, joint_names={spec.name: list(arm.joint_names)}, metadata=meta,
                    t0=session.clock.now(), overwrite=True)


def calibrate_rig(session, spec, out: str | Path, cfg: CalibrationConfig, progress: Callable | None = None,
                  callback=None, say: Callable[[str], None] = lambda s: None) -> dict:
    """The whole pipeline on an open rig session; returns the report (also written to out/report.json)."""
    import json

    cfg.check()
    rig = session.rig
    traj = plan_trajectory(rig, spec, cfg)
    rec = open_recording(out, session, spec)
    clock = session.clock
    try:
        rec.start_episode(clock.now(), "NEXT calibration: free-motion replay")
        run = collect(session, spec, traj, cfg, progress, recorder=rec)
        rec.stop_episode(clock.now(), None, render(run.stopped))
        if run.stopped:
            say(f"warning: {run.stopped}")
        contact_eval = None
        if rig.simulated and cfg.contact_eval_s > 0:
            say(f"contact evaluation: {cfg.contact_eval_s:.0f} s replay with scripted pushes (SIMULATED)")
            rec.start_episode(clock.now(), "NEXT calibration: contact evaluation with scripted pushes "
                                           "(SIMULATED)")
            contact_eval = record_pushed_replay(session, spec, cfg.contact_eval_s, cfg.rate_hz, seed=1,
                                                recorder=rec)
            rec.stop_episode(clock.now())
    finally:
        status = rec.close()
    say(f"recorded {rec.path} ({status.messages_written} messages"
        + (f"; {status.dropped_samples} dropped" if status.dropped_samples else "")
        + (f"; {status.error}" if status.error else "") + ")")
    logs = write_logs(out, run, cfg, contact_eval)
    report = train_and_report(logs, out, spec.arm, cfg, callback, say)
    report.update(rig=rig.name, follower=spec.name, simulated=rig.simulated,
                  collision_checked=traj.collision_checked, stopped=render(run.stopped) or None,
                  heldout={"policy": "blocks", "frac": cfg.heldout_frac, "block_s": HELDOUT_BLOCK_S})
    (Path(out) / "report.json").write_text(json.dumps(report, indent=1))
    return report

