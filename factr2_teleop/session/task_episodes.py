"""The episodes of a twin task, whoever drives the arm (SIMULATED): the rig set up for the task (task_rig),
episode seeds, and TaskEpisodes, the bookkeeping of placing objects per episode, detecting stages, marking
the recording and the outcome. Two drivers subclass it: the scripted operator of `factr2 collect`
(tasks/collect.py EpisodeDriver) and a policy rollout (session/rollout_episodes.py). It lives in the session
layer so that both sit above it (tasks/ imports session/, never the reverse).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace

import mujoco
import numpy as np

from hardware.errors import ConfigError
from hardware.rigs.rig import CameraSpec, Rig, load_rig
from hardware.sim.tasks import StageTracker, Task, get_task

SETTLE_S = 0.3  # s: the hand holds still after the soft start and after each reset
EPISODE_SEED_STRIDE = 100_003  # episode k of a session seeded S has seed S * stride + k
PERCEPTION_STREAM = 0x5EE  # the pose detector's generator is seeded [episode seed, this]: apart from the
# task's and the script's draws, so recordings without it stay as they were


def gripper_mapping(arm_name: str) -> dict:
    """Leader trigger fraction (0 open .. 1 closed) -> follower gripper stroke [m] (max open .. 0)."""
    from hardware.arms import load_arm

    arm = load_arm(arm_name)
    stroke_max = float(arm.gripper_stroke_gain * arm.gripper_range[1])
    return {"gripper_scale": -stroke_max, "gripper_offset": stroke_max, "gripper_min": 0.0,
            "gripper_max": stroke_max}


def task_rig(rig: str | Rig, task: str | Task) -> Rig:
    """The rig set up for a task: the twin builds the task scene, the cameras are the task's scene and wrist
    cameras (at the rig's camera size and rate), the gripper follows the trigger. ConfigError (one line) for a
    real rig, an unknown task or a follower arm whose scene cannot hold it."""
    r = rig if isinstance(rig, Rig) else load_rig(rig)
    t = get_task(task)
    if not r.simulated:
        raise ConfigError(f"rig {r.name} is real hardware: tasks exist only on twins", where=str(r.path),
                          fix="use a sim-* rig (factr2 twin --list)")
    if len(r.pairs) != 1:
        raise ConfigError(f"rig {r.name} has {len(r.pairs)} arm pairs; task demonstrations drive one",
                          where=str(r.path), fix="use a single-arm rig such as sim-piper")
    fol = r.device(r.pairs[0][1])
    t.check_arm(fol.arm, where=f"{r.path}: follower {fol.name} ({fol.arm})")
    twin = replace(r.twin, task=t.name)
    base = r.cameras[0] if r.cameras else CameraSpec("scene", "", 320, 240, 30.0)
    cams = [CameraSpec("scene", f"sim:{t.scene_camera}", base.width, base.height, base.fps),
            CameraSpec("wrist", f"sim:{t.wrist_camera}", base.width, base.height, base.fps)]
    teleop = dict(r.teleop or {})
    mapping = dict(teleop.get("mapping") or {})
    if "gripper_scale" not in mapping:
        mapping.update(gripper_mapping(fol.arm))
    teleop["mapping"] = mapping
    return replace(r, twin=twin, cameras=cams, teleop=teleop)


@dataclass
class EpisodeResult:
    index: int
    seed: int
    outcome: str  # "success" | "failure"
    progress: float  # share of stages reached
    stages: dict  # stage -> time reached [s from episode start] (None: not reached)
    duration_s: float
    retries: int
    felt: int  # contacts the operator reacted to
    gave_up: bool
    t_start: float = 0.0
    t_end: float = 0.0
    params: dict = field(default_factory=dict)


def episode_seed(seed: int, k: int) -> int:
    """The seed of episode k of a session seeded `seed` (collection and rollout alike: a benchmark picks
    rollout seeds whose episodes never met a demonstration's initial conditions)."""
    return int(seed) * EPISODE_SEED_STRIDE + int(k)


class TaskEpisodes:
    """Episode bookkeeping of a twin task, whoever drives the arm (the scripted operator through the leader
    here, a policy in factr2_teleop/session/rollout.py): objects placed per episode from its seed, stage
    detection, the recording's episode start / progress marks / stop with the outcome, the results; the loop
    stops after the last episode. A driver subclass calls _reset_episode, rec_start, _detect_obs and
    _end_episode, and implements _begin_episode (called for every episode after the first too)."""

    def __init__(self, ts, task: Task, episodes: int, seed: int = 0, on_episode=None):
        self.ts, self.task, self.episodes, self.seed = ts, task, int(episodes), int(seed)
        self.on_episode = on_episode  # callable(EpisodeResult) after each episode (progress bar)
        s = ts.session
        self.pair = ts.pairs[0]
        self.twin = s.twin
        fname, self.lname = self.pair.follower.name, self.pair.leader.name
        self.world = self.twin.devices[fname].world
        self.model, self.data = self.world.model, self.world.data
        self.results: list[EpisodeResult] = []
        self.ee_site = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_SITE, "ee")
        self.detector = None  # the task's PoseDetector, made at the first episode (_detector)
        self.seen: dict = {}  # the detector's latest output (name -> hardware.sim.perception.Seen)
        self._k = 0
        self._state = "wait"  # wait (soft start) -> settle -> run -> (next episode) ... -> done
        self._t_state = float("nan")
        self._ep = -1

    def _begin_episode(self, r) -> None:
        raise NotImplementedError

    def _detector(self):
        """The simulated camera pose detector of the task's detectable objects (SIMULATED; settings: the
        defaults, the task's, the rig's [twin.perception]); None for a task that names none."""
        from hardware.sim.perception import PoseDetector
        from hardware.sim.tasks.base import task_perception

        try:
            names = tuple(self.task.detectables(self.model, self.data, self.params))
        except NotImplementedError:
            return None
        rig = self.ts.session.rig
        params = task_perception(self.task, getattr(rig.twin, "perception", None),
                                 where=f"{rig.path}: twin.perception")
        return PoseDetector(params, names)

    def perceive(self, t: float) -> dict:
        """Advance the detector to t [s] (rig clock) with the twin's true poses now; returns (and keeps in
        self.seen) what it reports. Call on the stepping thread, every decision."""
        if self.detector is not None:
            truth = self.task.detectables(self.model, self.data, self.params)
            self.seen = self.detector.update(t, truth, self.data.site_xpos[self.ee_site])
        return self.seen

    def perceived_vector(self) -> np.ndarray:
        """SIMULATED: the latest detections as the policy's input (hardware/sim/perception.py seen_vector)."""
        from hardware.errors import UserError
        from hardware.sim.perception import seen_vector

        if self.detector is None:
            raise UserError(f"task {self.task.name} names no detectable objects", where="--obs perceived",
                            fix="use a task with Task.detectables, or a policy trained with --obs state")
        return seen_vector(self.seen, self.detector.names)

    def _log_perceived(self, t: float) -> None:
        """SIMULATED (not privileged): the detections as one vector on /perceived/objects, beside
        /task/objects, for policies trained with `--obs perceived`."""
        rec = self.ts.recording
        if rec is not None and rec.recording and self.detector is not None and self.seen:
            from hardware.sim.perception import seen_names, seen_vector

            names = self.detector.names
            rec.recorder.log_perceived(t, seen_vector(self.seen, names), seen_names(names))

    def _reset_episode(self) -> np.random.Generator:
        """The next episode's objects placed for its seed; returns the episode's generator."""
        self._ep += 1
        self._ep_seed = episode_seed(self.seed, self._ep)
        rng = np.random.default_rng(self._ep_seed)
        with self.world.lock:
            self.params = self.task.reset(self.model, self.data, rng)
            mujoco.mj_forward(self.model, self.data)
        self.tracker = StageTracker(self.task.stages)
        if self._ep == 0:
            self.detector = self._detector()
        if self.detector is not None:  # this episode's calibration bias, from its seed
            from hardware.sim.perception import NEVER

            self.detector.reset(np.random.default_rng([self._ep_seed, PERCEPTION_STREAM]))
            self.seen = {k: NEVER for k in self.detector.names}
        return rng

    def observe(self) -> dict:
        """The task's objects as the twin has them now (call on the stepping thread)."""
        return self.task.observe(self.model, self.data, self.params)

    def rec_start(self) -> None:
        rec = self.ts.recording
        if rec is not None:
            rec.start_episode(self.task.name)
            rec.recorder.note(self.ts.session.clock.now(), json.dumps(
                {"task": self.task.name, "episode_seed": self._ep_seed, "params": _jsonable(self.params)}))
        self._t_state = self.ts.session.clock.now()

    def _log_objects(self, t: float, obs: dict) -> None:
        """PRIVILEGED (SIMULATED): the objects' state as one vector on /task/objects, at the script's
        decision rate, for policies trained with `--obs state` (policies/data/privileged.py: order, units)."""
        rec = self.ts.recording
        if rec is not None and rec.recording:
            from policies.data.privileged import objects_vector

            rec.recorder.log_task_objects(t, *objects_vector(obs, self.params))

    def _detect_obs(self, t: float, obs: dict) -> None:
        flags = self.task.detect(obs, self.params, self.tracker.memory)
        for name in self.tracker.update(flags, t - self._t_state):
            rec = self.ts.recording
            if rec is not None:
                rec.recorder.mark_progress(t, self.tracker.progress, name)

    def _end_episode(self, r, info: dict) -> None:
        obs = self.task.observe(self.model, self.data, self.params)
        ok = bool(self.tracker.done.all()) and self.task.final_ok(obs, self.params, self.tracker.memory)
        outcome = "success" if ok else "failure"
        res = EpisodeResult(
            index=self._ep, seed=self._ep_seed, outcome=outcome, progress=self.tracker.progress,
            stages={s: (None if np.isnan(x) else round(float(x), 3))
                    for s, x in zip(self.task.stages, self.tracker.t_done)},
            duration_s=r.t - self._t_state, retries=int(info.get("retries", 0)),
            felt=len(info.get("felt", [])), gave_up=bool(info.get("gave_up", False)),
            t_start=self._t_state, t_end=r.t, params=_jsonable(self.params))
        self.results.append(res)
        rec = self.ts.recording
        if rec is not None:
            rec.stop_episode(outcome, json.dumps({k: v for k, v in res.__dict__.items() if k != "params"}))
        if self.on_episode is not None:
            self.on_episode(res)
        if len(self.results) >= self.episodes:
            self._state = "done"
            self.ts.loop.stop()
        else:
            self._begin_episode(r)


def _jsonable(d: dict) -> dict:
    return {k: (np.asarray(v).tolist() if isinstance(v, np.ndarray) else
                float(v) if isinstance(v, np.floating) else v) for k, v in d.items()}
