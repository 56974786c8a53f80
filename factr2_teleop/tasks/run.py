"""`factr2 collect` as a function: validate, open the task rig, run the teleop session with the scripted
operator until every episode is done, write the summary. SIMULATED throughout.

    result = collect(CollectConfig(task="peg-insert", episodes=50, out="demos"))
    print("\\n".join(summary_lines(result)))

Bad input fails before anything is written: an unknown task, a rig that is real or whose follower cannot hold
the task, an output file that exists (never overwritten), no NEXT checkpoint for mode next.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from hardware.errors import UserError


@dataclass
class CollectConfig:
    rig: str = "sim-piper"
    task: str = "peg-insert"
    episodes: int = 10
    out: str = "demos"
    seed: int = 0
    mode: str | None = None  # feedback mode; None: next with a checkpoint, else dob
    checkpoint: str | None = None
    cameras: bool = True
    faults: list | None = None  # hardware.sim.faults.FaultSpec the twin plays (None: the rig's [twin] faults)
    on_session: object = None  # callable(TeleopSession, rig session) before the loop runs (bench/faults.py)
    perception: bool | None = None  # the operator sees through the simulated pose detector (None: the
    # task's Task.operator_perception); the perceived channel is recorded either way
    perturb: object = None  # teleop.perturb.PerturbConfig: DART-style offsets on the follower's target


def output_paths(cfg: CollectConfig, rig_name: str) -> tuple[Path, Path]:
    stem = f"{cfg.task}-{rig_name}-seed{cfg.seed}"
    return Path(cfg.out) / f"{stem}.mcap", Path(cfg.out) / f"{stem}.json"


def _mode_and_checkpoint(cfg: CollectConfig, rig_name: str, task) -> tuple[str, str | None]:
    """(feedback mode, NEXT checkpoint or None): --mode, else the task's operator_feedback, else the rig's."""
    from factr2_teleop.session.next_cache import find_checkpoint

    mode = cfg.mode if cfg.mode is not None else task.operator_feedback
    if mode not in (None, "next"):
        return mode, None
    ck = find_checkpoint(rig_name, cfg.checkpoint)
    if ck is None and cfg.mode == "next":
        raise UserError("no NEXT checkpoint for feedback mode next", where="--mode next",
                        fix="pass --checkpoint DIR/next.json (factr2 calibrate --rig sim-piper --out DIR)")
    return ("next", str(ck)) if ck is not None else ("dob", None)


def collect(cfg: CollectConfig, progress: bool = True) -> dict:
    from factr2_teleop.session.pairs import TeleopOptions
    from factr2_teleop.session.read_back import episode_rates, read_back
    from factr2_teleop.session.task_episodes import task_rig
    from factr2_teleop.session.teleop import TeleopSession
    from factr2_teleop.tasks.collect import EpisodeDriver
    from hardware.connect import open_rig
    from hardware.sim.tasks import get_task

    if cfg.episodes < 1:
        raise UserError(f"--episodes {cfg.episodes} must be at least 1", where="--episodes", fix="e.g. 50")
    task = get_task(cfg.task)
    rig = task_rig(cfg.rig, task)
    mcap, summary_path = output_paths(cfg, rig.name)
    for p in (mcap, summary_path):
        if p.exists():
            raise UserError("output file already exists", where=str(p),
                            fix="choose another --out or --seed (recordings are never overwritten)")
    mode, ck = _mode_and_checkpoint(cfg, rig.name, task)
    perturb_meta = {}
    if cfg.perturb is not None:
        cfg.perturb.validate(rig.device(rig.pairs[0][1]).limits().n)
        perturb_meta = {"perturb": json.dumps(cfg.perturb.to_dict())}
    sees = bool(task.operator_perception if cfg.perception is None else cfg.perception)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=cfg.episodes, desc=f"{task.name} (SIMULATED)", unit="ep", leave=False)
    t_wall, c_cpu = time.perf_counter(), time.process_time()
    with open_rig(rig, clock="lockstep", seed=cfg.seed, faults=cfg.faults) as s:
        ts = TeleopSession(s, TeleopOptions(mode=mode, checkpoint=ck))
        ts.record(cfg.out, path=mcap, task=task.name, cameras=cfg.cameras,
                  extra_meta={"simulated": "true", "collect_seed": cfg.seed, "operator": "scripted",
                              "operator_sees": "perceived" if sees else "truth", **perturb_meta})
        first_tick = FirstTick()

        def done(res):
            if bar is not None:
                bar.update(1)
                bar.set_postfix(ok=sum(r.outcome == "success" for r in ep.results))

        ep = EpisodeDriver(ts, task, cfg.episodes, seed=cfg.seed, on_episode=done, perception=sees,
                           perturb=cfg.perturb)
        ts.hooks.append(ep.on_tick)
        ts.hooks.append(lambda r: first_tick.add(r, ep))
        srec = ts.recording
        if cfg.on_session is not None:
            cfg.on_session(ts, s)
        try:
            ts.loop.run()
        finally:
            status = ts.close_recording("collection interrupted" if len(ep.results) < cfg.episodes else "")
            if bar is not None:
                bar.close()
        sim_s = s.clock.now() - first_tick.t0 if np.isfinite(first_tick.t0) else float("nan")
        cams = {k: asdict(v) for k, v in (srec.camera_stats or {}).items()}  # hardware.cameras.stream stats
        timing = ts.loop.timing.stats(whole_run=True)
        messages = list(ts.loop.snapshot().messages)
        faults = list(s.twin.faults.log) if s.twin is not None and s.twin.faults is not None else []
    wall = time.perf_counter() - t_wall
    # the labels training will use, from the file just written (the session's estimator records tau_ext)
    shares, thresholds, label_note = (recorded_phase_shares(mcap) if mode != "none" and mcap.exists()
                                      else (None, None, "no tau_ext estimate recorded"))
    res = [asdict(r) for r in ep.results]
    # the summary says what the file holds: a writer that stalled can leave the last episode without its stop
    # (the file recovered in place: "incomplete"), the later ones out of it; training and `--episodes` go by
    # the file, and the rates are over the episodes it holds
    in_file = read_back(res, mcap, status)
    rates = episode_rates(res)
    lengths = [r["duration_s"] for r in res]
    out = {"simulated": True, "task": task.name, "rig": rig.name, "seed": cfg.seed, "mode": mode,
           "checkpoint": ck, "operator_sees": "perceived" if sees else "truth",
           "perturb": cfg.perturb.to_dict() if cfg.perturb is not None else None,
           "episodes": len(res), "success_rate": rates["success_rate"],
           "progress_mean": rates["mean_progress"],
           "episode_s_mean": float(np.mean(lengths)) if lengths else 0.0,
           "episode_s_min": float(np.min(lengths)) if lengths else 0.0,
           "episode_s_max": float(np.max(lengths)) if lengths else 0.0,
           "retries_mean": float(np.mean([r["retries"] for r in res])) if res else 0.0,
           "phase_shares": shares, "phase_thresholds_nm": thresholds, "phase_labels": label_note,
           "sim_s": sim_s, "wall_s": wall,
           "x_realtime": sim_s / wall if wall > 0 else float("nan"),
           "cpu_s": time.process_time() - c_cpu, "loop_overruns": timing.overruns,
           "frames_written": getattr(status, "frames_written", 0),
           "samples_dropped": status.dropped_samples if status else 0,
           "frames_dropped": status.dropped_frames if status else 0, "cameras": cams,
           "recording": str(mcap), **in_file, "results": res,
           "messages": messages, "faults": faults}
    summary_path.write_text(json.dumps(out, indent=1, default=float))
    return out


class FirstTick:
    """The rig-clock time [s] of the first tick inside an episode (the simulated time of the collection)."""

    def __init__(self):
        self.t0 = float("nan")

    def add(self, r, ep) -> None:
        if ep._state == "run" and not np.isfinite(self.t0):
            self.t0 = r.t


def recorded_phase_shares(mcap: Path) -> tuple[dict | None, list | None, str]:
    """(free / pre-contact / contact shares, [T_low, T_high] [N*m], note) of a written recording, labelled as
    `factr2 train` and `factr2 episodes phases` label it (the recording's own thresholds on the tared score,
    docs/first.md), so that the summary shows what training will see; (None, None, why) when it cannot be
    labelled (no tau_ext recorded, too few samples)."""
    import warnings

    from policies.data.recordings import load_episodes
    from policies.labels import labelling as L
    from policies.labels.phases import PHASE_NAMES, phase_shares

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            episodes, arms = load_episodes([mcap])
            th = L.resolve_thresholds("recording", None, episodes, arms)
            phases = np.concatenate([L.label_episode(e, arms, th).phases for e in episodes] or [[]])
    except UserError as e:
        return None, None, e.what
    if not len(phases):
        return None, None, "no labelled samples"
    keys = [n.replace("-", "_") for n in PHASE_NAMES]
    return dict(zip(keys, phase_shares(phases).tolist())), [th.t_low, th.t_high], f"tare {th.tare}"


def summary_lines(out: dict) -> list[str]:
    lines = [f"{out['task']} on {out['rig']} (SIMULATED), feedback {out['mode']}, seed {out['seed']}, "
             f"the operator sees {out.get('operator_sees', 'truth')}",
             f"{'episodes':>22s}  {out['episodes']}" + (f"  ({held} in the file: the rates are over those)"
                                                         if (held := out.get("episodes_in_file")) is not None
                                                         and held != out["episodes"] else ""),
             f"{'success rate':>22s}  {out['success_rate'] * 100:.1f} %  "
             f"(task progress {out['progress_mean']:.2f})",
             f"{'episode length [s]':>22s}  mean {out['episode_s_mean']:.1f}  "
             f"min {out['episode_s_min']:.1f}  "
             f"max {out['episode_s_max']:.1f}",
             f"{'retries per episode':>22s}  {out['retries_mean']:.2f}"]
    sh = out["phase_shares"]
    if sh:
        lines.append(f"{'free / pre / contact':>22s}  {sh['free'] * 100:.1f} / "
                     f"{sh['pre_contact'] * 100:.1f} / "
                     f"{sh['contact'] * 100:.1f} %  (FIRST labels as `factr2 train` makes them: "
                     f"{out['phase_thresholds_nm'][0]:.2f} : {out['phase_thresholds_nm'][1]:.2f} N*m, "
                     f"{out.get('phase_labels', '')})")
        from policies.labels.phases import labels_warning

        warn = labels_warning([sh["free"], sh["pre_contact"], sh["contact"]])
        if warn:
            lines.append(f"{'labels':>22s}  {warn}")
    lines += [f"{'wall time':>22s}  {out['wall_s']:.0f} s for {out['sim_s']:.0f} s simulated "
              f"({out['x_realtime']:.2f}x real time)",
              f"{'recording':>22s}  {out['recording']} ({out['frames_written']} frames, "
              f"{out['samples_dropped']} samples dropped)"]
    for name, c in (out.get("cameras") or {}).items():
        lines.append(f"{'camera ' + name:>22s}  {c['captured']} / {c['expected']} frames, "
                     f"{c['dropped']} dropped, "
                     f"{c['failed']} failed")
    if out.get("perturb"):
        pt = out["perturb"]
        lines.append(f"{'perturbed':>22s}  +-{pt['amplitude_rad']:g} rad on "
                     f"{'joints ' + '+'.join(map(str, pt['joints'])) if pt['joints'] else 'every joint'}, "
                     f"windows of {2 * pt['ramp_s'] + pt['hold_s']:g} s (marked on /follower/perturb; "
                     "factr2 train --perturbed)")
    if out.get("recording_error"):
        lines.append(f"{'recording stopped':>22s}  {out['recording_error']}")
    from factr2_teleop.session.read_back import read_back_lines
    from factr2_teleop.session.teleop import message_lines

    lines += read_back_lines(out.get("results", []), out.get("episodes_not_as_judged"),
                             out.get("recording_unread"), 22)
    return lines + message_lines(out.get("messages", []))
