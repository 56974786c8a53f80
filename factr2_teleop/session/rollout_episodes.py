"""The episodes of a policy rollout (factr2_teleop/session/rollout.py): TwinRollout on a twin task (the
episode bookkeeping of `factr2 collect`, task_episodes.py TaskEpisodes: objects placed per episode seed,
stage detection, success, the time limit) and MarkedRollout (the operator marks stages and the outcome with
keys: real rigs, or twins without a task). Both are per-tick hooks on the loop's thread; they move the
PolicyTarget between its phases (home -> settle -> run) and write episodes into the session's recording.
"""

from __future__ import annotations

import json
from dataclasses import asdict

import numpy as np

from factr2_teleop.session.rollout_pair import RUN, PolicyTarget
from factr2_teleop.session.task_episodes import SETTLE_S, EpisodeResult, TaskEpisodes

DETECT_EVERY = 5  # ticks between stage detections (100 Hz at 500 Hz, the scripted operator's rate)


class TwinRollout(TaskEpisodes):
    """Twin task episodes driven by the policy: home -> objects placed for the episode seed -> settle ->
    policy until success (every stage reached and the final condition true) or the time limit."""

    def __init__(self, ts, task, episodes: int, seed: int, target: PolicyTarget, time_limit_s: float,
                 on_episode=None):
        super().__init__(ts, task, episodes, seed, on_episode)
        self.target, self.time_limit_s = target, float(time_limit_s)
        self.t_extended = -np.inf  # s: an operator's takeover restarts the time limit here (its own time)

    def objects(self):
        """The policy's object input now: the PRIVILEGED vector of the task as the twin has it
        (policies/data/privileged.py), or for a policy trained on perceived objects the simulated detector's
        latest report (SIMULATED; the detector runs every DETECT_EVERY ticks, its bias from the episode
        seed)."""
        from hardware.recording.schemas import PERCEIVED_FEATURE
        from policies.data.privileged import task_state_vector

        if getattr(self.target.runner, "object_feature", None) == PERCEIVED_FEATURE:
            return self.perceived_vector()
        return task_state_vector(self.task, self.model, self.data, self.params)

    def _begin_episode(self, r) -> None:
        self.target.home(r.follower)
        self._state = "home"

    def on_tick(self, r) -> None:
        self._k += 1
        st = self._state
        if st == "wait":
            self._begin_episode(r)
        elif st == "home" and self.target.at_home:
            self._reset_episode()  # under the world's lock
            self.target.settle()
            self._state, self._t_state = "settle", r.t
        elif st == "settle" and self._k % DETECT_EVERY == 0:
            self.perceive(r.t)  # the camera runs from the reset: a detection is there when the policy starts
        if st == "settle" and r.t - self._t_state >= SETTLE_S:
            self.rec_start()
            self.target.run(r.t, objects=self.objects, seed=self._ep_seed)
            self._state = RUN
        elif st == RUN and self._k % DETECT_EVERY == 0:
            obs = self.observe()
            self.perceive(r.t)
            self._log_objects(r.t, obs)
            self._log_perceived(r.t)
            self._detect_obs(r.t, obs)
            done = bool(self.tracker.done.all()) and self.task.final_ok(obs, self.params, self.tracker.memory)
            timeout = r.t - max(self._t_state, self.t_extended) >= self.time_limit_s
            if done or timeout:
                self.target.idle()
                self._end_episode(r, {"gave_up": timeout and not done})


class MarkedRollout:
    """Episodes the operator judges (a real rig, or a twin without a task): keys from `marks` (a queue):
    s = the next stage reached, y = success, n = failure (both end the episode), q = end the episode
    unlabelled and stop. The time limit ends an episode unlabelled."""

    def __init__(self, ts, target: PolicyTarget, episodes: int, stages: tuple, time_limit_s: float, marks,
                 task_name: str = "", on_episode=None):
        self.ts, self.target, self.episodes = ts, target, int(episodes)
        self.stages, self.time_limit_s, self.marks = tuple(stages), float(time_limit_s), marks
        self.task_name, self.on_episode = task_name, on_episode
        self.results: list[EpisodeResult] = []
        self._state, self._t_state, self._ep = "wait", float("nan"), -1
        self._reached: dict = {}

    @property
    def reached(self) -> dict[str, float]:
        """The stages marked reached in the running episode: name -> time since its start [s]."""
        return dict(self._reached)

    def _key(self) -> str | None:
        q = self.marks
        return None if q is None or q.empty() else str(q.get_nowait())

    def on_tick(self, r) -> None:
        st = self._state
        if st in ("wait", "next"):
            self.target.home(r.follower)
            self._state = "home"
        elif st == "home" and self.target.at_home:
            self._ep += 1
            self.target.settle()
            self._state, self._t_state = "settle", r.t
        elif st == "settle" and r.t - self._t_state >= SETTLE_S:
            rec = self.ts.recording
            if rec is not None:
                rec.start_episode(self.task_name)
            self._reached, self._t_state = {}, r.t
            self.target.run(r.t)
            self._state = RUN
        elif st == RUN:
            key = self._key()
            if key == "s" and len(self._reached) < max(len(self.stages), 99):
                name = self.stages[len(self._reached)] if len(self._reached) < len(self.stages) else \
                    f"stage{len(self._reached) + 1}"
                self._reached[name] = round(r.t - self._t_state, 3)
                rec = self.ts.recording
                if rec is not None:
                    prog = len(self._reached) / len(self.stages) if self.stages else float("nan")
                    rec.recorder.mark_progress(r.t, prog, name)
            elif key in ("y", "n", "q") or r.t - self._t_state >= self.time_limit_s:
                self._end(r, {"y": "success", "n": "failure"}.get(key), stop=key == "q")

    def _end(self, r, outcome: str | None, stop: bool) -> None:
        self.target.idle()
        stages = {s: self._reached.get(s) for s in self.stages} if self.stages else dict(self._reached)
        prog = (len(self._reached) / len(self.stages) if self.stages else float(outcome == "success"))
        res = EpisodeResult(index=self._ep, seed=-1, outcome=outcome or "unlabelled", progress=prog,
                            stages=stages, duration_s=r.t - self._t_state, retries=0, felt=0,
                            gave_up=outcome is None, t_start=self._t_state, t_end=r.t)
        self.results.append(res)
        rec = self.ts.recording
        if rec is not None:
            rec.stop_episode(outcome, json.dumps({k: v for k, v in asdict(res).items() if k != "params"}))
        if self.on_episode is not None:
            self.on_episode(res)
        if stop or len(self.results) >= self.episodes:
            self._state = "done"
            self.ts.loop.stop()
        else:
            self._state = "next"


def episode_line(res: EpisodeResult, stages: tuple) -> str:
    marks = " ".join(f"{s}{'+' if res.stages.get(s) is not None else '-'}" for s in stages) if stages else ""
    return (f"episode {res.index:3d}  seed {res.seed:>9d}  {res.outcome:10s} progress {res.progress:4.2f}  "
            f"{res.duration_s:5.1f} s  {marks}")
