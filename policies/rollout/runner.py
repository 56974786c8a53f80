"""A trained policy at rollout: load a run, build the model's input from the flat observation a live rig
gives, predict a chunk, un-normalise it; inference inline (lockstep twins: simulated time stands still
meanwhile) or on a thread of its own (real time: the control loop never waits for the network).

    runner = PolicyRunner("RUN")                      # or RUN/checkpoints/step-*.json
    layout = runner.check_rig(features, arms)       # UserError (one line): other arms, joints, features
    runner.start(threaded=True)
    runner.submit(obs, t_obs)                         # obs: flat feature name -> value (see `observation`)
    for chunk in runner.take(): ...                   # schedule.Chunk, stamped with t_obs
    runner.stop()

The input is built by feature name from the names the checkpoint stores, through the preprocessing it
stores (policies/data/preprocess.py: the training's normaliser and image path, the same batch assembly):
observation.state = the listed follower features concatenated ([rad], [m]), observation.force = tau_ext
[N*m] (or current [A]), observation.state.objects = the PRIVILEGED twin object vector
(policies/data/privileged.py) or observation.perceived.objects = the SIMULATED detector's vector
(hardware/sim/perception.py; the rollout runs the detector live), observation.images.<cam> = the camera's
latest raw RGB frame, JPEG-encoded as the recording encoded that camera and decoded as training decoded it
(the same RGB gives the same input).

force_input (issue #51's ablation, test time only): "live" the estimate as it comes; "zero" tau_ext = 0 N*m
(the policy feels nothing, ever); "shuffle" each chunk's force replaced by one drawn from the forces this
episode has fed so far (its marginal kept, its link to the moment broken). The drop in success from live
to an ablation is what the policy's force input is worth to it.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from pathlib import Path

import numpy as np
import torch

from hardware.errors import UserError
from hardware.features import IMAGES, OBS_FORCE, OBS_IMAGES, OBS_STATE, action_of
from hardware.features import size as feature_size
from hardware.recording.schemas import ACTION, PERCEIVED_FEATURE, TASK_OBJECTS_FEATURE
from policies.rollout.schedule import Chunk
from policies.training.checkpoint import load_policy


def flat_values(obs: dict, names: list[str]) -> np.ndarray:
    """The named features of a flat observation, concatenated (float32 (D,))."""
    return np.concatenate([np.atleast_1d(np.asarray(obs[n], dtype=np.float32)) for n in names])


FORCE_INPUTS = ("live", "zero", "shuffle")


def ablate_force(force: np.ndarray, how: str, seen: list, rng: np.random.Generator) -> np.ndarray:
    """The force input (raw units, (1, D)) a rollout feeds under ablation `how` (FORCE_INPUTS); seen: the
    live forces of this episode so far (appended to here), rng: the episode's draw for "shuffle"."""
    if how == "live":
        return force
    if how == "zero":
        return np.zeros_like(force)
    if how == "shuffle":
        seen.append(force.copy())
        return seen[int(rng.integers(len(seen)))]
    raise ValueError(f"force input {how!r}: one of {', '.join(FORCE_INPUTS)}")


# how a rollout seeds the flow sampler's noise (recorded by the benchmark, whose results of the earlier way,
# one generator running on across the episodes, are not mixed with these): each episode from its own seed
SAMPLER_SEEDING = "per-episode"


class PolicyRunner:
    def __init__(self, path: str | Path, seed: int = 0, ema: bool = True, force_input: str = "live"):
        if force_input not in FORCE_INPUTS:
            raise UserError(f"force input {force_input!r} unknown", where="--force-input",
                            fix=f"one of {', '.join(FORCE_INPUTS)}")
        self.force_input = force_input
        self._force_seen: list = []
        self._force_rng = np.random.default_rng(seed)
        self.model, self.meta, self.pre = load_policy(path, ema=ema)
        self.path = Path(self.meta["_path"])
        self.cfg = self.model.cfg
        f = self.meta["features"]
        self.state_names: list[str] = list(f[OBS_STATE])
        self.force_names: list[str] = list(f.get(OBS_FORCE) or [])
        # the object input: the PRIVILEGED state or the perceived one (SIMULATED), whichever it trained on
        self.object_feature = PERCEIVED_FEATURE if f.get(PERCEIVED_FEATURE) else TASK_OBJECTS_FEATURE
        self.object_names: list[str] = list(f.get(self.object_feature) or [])
        self.cameras = [n[len(IMAGES):] for n in f.get(OBS_IMAGES) or []]
        self.action_names: list[str] = list(f[ACTION])
        self.rate_hz = float(self.meta["rate_hz"])
        self.dt = 1.0 / self.rate_hz
        self._gen = torch.Generator().manual_seed(int(seed))
        self._seq = 0
        self._cond = threading.Condition()
        self._pending: tuple | None = None  # (obs, t_obs, seq): the newest request (older ones are dropped)
        self._out: deque[Chunk] = deque()
        self._thread: threading.Thread | None = None
        self._stop = False
        self.threaded = False
        self.latencies_s: list[float] = []  # inference wall time per chunk
        self.error: BaseException | None = None

    # -- what the checkpoint was trained for ---------------------------------------------------------
    @property
    def policy(self) -> str:
        return self.cfg.policy

    @property
    def uses_objects(self) -> bool:
        return bool(self.object_names)

    def describe(self) -> str:
        obs = ", ".join(x for x in (
            "joints+gripper", self.force_names and f"force ({self.meta.get('force')})",
            self.cameras and f"cameras {', '.join(self.cameras)}",
            self.object_names and ("perceived objects (SIMULATED detector)"
                                   if self.object_feature == PERCEIVED_FEATURE
                                   else "PRIVILEGED object state")) if x)
        return (f"{self.cfg.policy} policy, method {self.meta.get('method')}, step {self.meta.get('step')}, "
                f"{self.rate_hz:.3g} Hz, chunk {self.cfg.chunk}; observes {obs}")

    @property
    def followers(self) -> list[str]:
        """The follower arms the policy was trained on, by recorded name ("follower", "left_follower")."""
        return list((self.meta.get("arms") or {}).get("followers") or [])

    def check_rig(self, features: dict, arms: dict[str, tuple[str, list[str]]]) -> dict[str, tuple]:
        """UserError (one line) unless a rig with these features (hardware.features.rig_features) and follower
        arms ({recorded arm name: (arm model, joint names)}) is what the policy was trained on: the same
        follower arms, models and joint sets, and every feature the checkpoint reads or writes. Returns
        where each arm's targets sit in the action vector: {arm: (q slice, gripper column or None)}."""
        trained = self.meta.get("arms") or {}
        followers = self.followers
        if sorted(followers) != sorted(arms):
            raise UserError(f"policy trained on follower arm(s) {', '.join(followers) or 'none'}; the rig "
                            f"has {', '.join(arms)}", where=str(self.path),
                            fix="roll it out on a rig with the same arm pairs as the demonstrations")
        models = list(trained.get("arm_models") or [""] * len(followers))
        joint_sets = list(trained.get("joint_names") or [[]] * len(followers))
        for arm, model, joints in zip(followers, models, joint_sets):
            arm_model, joint_names = arms[arm]
            if model and model != arm_model:
                raise UserError(f"policy trained for arm {model!r}, the rig's {arm} is {arm_model!r}",
                                where=str(self.path), fix="roll it out on a rig with that arm")
            if list(joints) != list(joint_names):
                raise UserError(f"policy trained on joints {list(joints)}, the rig's {arm} has "
                                f"{list(joint_names)}", where=str(self.path),
                                fix="roll it out on a rig with that joint set")
        names = self.state_names + self.force_names + self.action_names
        missing = [n for n in names if n not in features]
        if missing:
            raise UserError(f"the rig has no feature {missing[0]} the policy uses", where=str(self.path),
                            fix="roll it out on the rig (arm pairs) it was trained on")
        width = sum(feature_size(features[n]) for n in self.action_names)
        if self.cfg.action_dim != width:
            raise UserError(f"policy acts on {self.cfg.action_dim} values, the rig's arms take {width} "
                            "(joints + gripper)", where=str(self.path),
                            fix="roll it out on the arm it was trained for")
        cols, at = {}, 0
        for n in self.action_names:
            cols[n] = (at, at + feature_size(features[n]))
            at += feature_size(features[n])
        out = {}
        for arm in followers:
            q0, q1 = cols[f"{action_of(arm)}.joint.pos"]
            grip = cols.get(f"{action_of(arm)}.gripper.pos")
            out[arm] = (slice(q0, q1), grip[0] if grip else None)
        return out

    def reseed(self, seed: int) -> None:
        """The flow sampler's noise from `seed` on (a rollout calls it with each episode's seed: an episode's
        draws then do not depend on how long the episodes before it ran). A new generator, not a reseed in
        place: an inference still running on the worker thread keeps the one it started with."""
        self._gen = torch.Generator().manual_seed(int(seed))
        self._force_seen, self._force_rng = [], np.random.default_rng(int(seed))

    # -- one chunk ---------------------------------------------------------------------------------------
    def batch(self, obs: dict) -> dict:
        """The model's input (batch of one) from a flat observation (feature name -> value)."""
        def cat(names):
            return flat_values(obs, names)[None]

        objects = np.asarray(obs[self.object_feature], np.float32)[None] if self.object_names else None
        images = (np.stack([self.pre.image.live(c, obs[IMAGES + c]) for c in self.cameras])[None]
                  if self.cameras else None)
        force = (ablate_force(cat(self.force_names), self.force_input, self._force_seen, self._force_rng)
                 if self.force_names else None)
        return self.pre.inputs(cat(self.state_names), force, objects, images)

    def infer(self, obs: dict, t_obs: float, seq: int = 0) -> Chunk:
        """Predict one chunk (raw units) for an observation taken at t_obs [s]."""
        t0 = time.perf_counter()
        b = self.batch(obs)
        noise = self.model.draw_noise(self.cfg, 1, self._gen)
        with torch.inference_mode():
            z = self.model.predict(b, noise)[0].float().numpy()
        actions = np.asarray(self.pre.actions(z, flat_values(obs, self.state_names)), dtype=float)
        lat = time.perf_counter() - t0
        self.latencies_s.append(lat)
        return Chunk(t_obs=float(t_obs), actions=actions, dt=self.dt, seq=seq, latency_s=lat)

    # -- inline or threaded ------------------------------------------------------------------------------
    def start(self, threaded: bool) -> None:
        """threaded: inference on a daemon thread (real time); else submit() predicts at once."""
        self.threaded = bool(threaded)
        if self.threaded and self._thread is None:
            self._stop = False
            self._thread = threading.Thread(target=self._work, name="factr2-policy", daemon=True)
            self._thread.start()

    def submit(self, obs: dict, t_obs: float) -> int:
        """Ask for a chunk for this observation; returns its request number. Never waits when threaded
        (a request not yet started is replaced by the newer one)."""
        self._seq += 1
        if not self.threaded:
            self._out.append(self.infer(obs, t_obs, self._seq))
            return self._seq
        with self._cond:
            self._pending = (obs, t_obs, self._seq)
            self._cond.notify()
        return self._seq

    def take(self) -> list[Chunk]:
        """The chunks finished since the last call (oldest first)."""
        out = []
        while self._out:
            out.append(self._out.popleft())
        return out

    def stop(self, timeout_s: float = 2.0) -> None:
        with self._cond:
            self._stop = True
            self._cond.notify()
        t, self._thread = self._thread, None
        if t is not None:
            t.join(timeout_s)

    def _work(self) -> None:
        while True:
            with self._cond:
                while self._pending is None and not self._stop:
                    self._cond.wait()
                if self._stop:
                    return
                obs, t_obs, seq = self._pending
                self._pending = None
            try:
                self._out.append(self.infer(obs, t_obs, seq))
            except Exception as e:  # noqa: BLE001 -- the loop sees no new chunk and holds; the error is kept
                self.error = e
                return
