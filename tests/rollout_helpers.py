"""A tiny policy for the rollout tests, trained in a few seconds on a real (short) recording of the
peg-insert twin rig: the follower held still through the full teleop stack, both task cameras recorded."""

from __future__ import annotations

from pathlib import Path

TINY = dict(hidden=32, heads=2, enc_layers=1, dec_layers=1, ff=64, backbone="convnet-gn", image_size=32,
            dropout=0.0, chunk=8)


def record_task_session(out: Path, seconds: float = 1.2) -> Path:
    """One episode of `seconds` on task_rig(sim-piper, peg-insert), lockstep, feedback dob, with cameras."""
    from factr2_teleop.session.task_episodes import task_rig

    return record_rig_session(out, task_rig("sim-piper", "peg-insert"), seconds, task="peg-insert")


def record_rig_session(out: Path, rig, seconds: float = 1.2, task: str = "") -> Path:
    """One episode of `seconds` of teleop on a twin rig (name or Rig), lockstep, feedback dob, with its
    cameras; the arms held still (nobody moves the leaders). Labelled a failure."""
    from factr2_teleop.session.pairs import TeleopOptions
    from factr2_teleop.session.teleop import TeleopSession
    from hardware.connect import open_rig

    path = Path(out) / "held.mcap"
    with open_rig(rig, clock="lockstep", seed=0) as s:
        ts = TeleopSession(s, TeleopOptions(mode="dob"))
        rec = ts.record(out, path=path, task=task)
        rec.start_episode(task)
        try:
            ts.loop.run(duration_s=seconds)
        finally:
            rec.stop_episode("failure")
            ts.close_recording()
    return path


def train_tiny(rec: Path, out: Path, policy: str = "flow", steps: int = 4) -> Path:
    from policies.training.run import RunOptions, run_training
    from policies.training.train import Dist, TrainConfig

    train = TrainConfig(steps=steps, batch=8, lr=1e-3, warmup=1, log_every=1, val_every=1000, ckpt_every=1000,
                        threads=1)
    run_training(RunOptions(inputs=[rec], out=out, policy=policy, method="base-torque", thresholds=(1.0, 3.0),
                            progress=False, overrides=dict(TINY), train=train, val_fraction=0.0,
                            include_failed=True), Dist())  # the held-still episode is labelled a failure
    return out


def tiny_run_on(tmp_path_factory, name: str, record, policy: str = "act", steps: int = 25) -> Path:
    """A module fixture's tiny policy: record(folder) -> recording, trained `steps` steps (skips without
    OpenGL: the twin's cameras render)."""
    import pytest

    try:
        from hardware.cameras.offscreen_gl import make_renderer  # noqa: F401
    except Exception:  # pragma: no cover
        pytest.skip("no OpenGL")
    import torch

    torch.set_num_threads(1)
    d = tmp_path_factory.mktemp(name)
    return train_tiny(record(d), d / "run", policy=policy, steps=steps)


STATE_TINY = {"hidden": 32, "heads": 2, "dec_layers": 1, "enc_layers": 1, "ff": 64, "chunk": 8,
              "dropout": 0.0}


class WipeStateRuns:
    """Tiny state policies (the PRIVILEGED object vector, as bench_first trains) on one scripted wipe
    demonstration (sim-piper, seed 0, dob, no cameras), 3 steps each: runs[method] -> its RUN folder. The
    demonstration is collected once and each method trained once, on first use (tests/conftest.py shares one
    across the session: the rollout tests only read it)."""

    def __init__(self, folder: Path):
        self.folder, self.runs, self.demos = Path(folder), {}, None

    def __getitem__(self, method: str) -> Path:
        if method not in self.runs:
            import torch

            from factr2_teleop.tasks.run import CollectConfig, collect
            from policies.training.run import RunOptions, run_training
            from policies.training.train import Dist, TrainConfig

            torch.set_num_threads(1)
            if self.demos is None:
                collect(CollectConfig(task="wipe", episodes=1, out=str(self.folder / "demos"), seed=0,
                                      mode="dob", cameras=False), progress=False)
                self.demos = self.folder / "demos"
            run = self.folder / method
            run_training(RunOptions(inputs=[self.demos], out=run, observation="state", method=method,
                                    thresholds=(0.5, 1.0), val_fraction=0.0, progress=False,
                                    overrides=dict(STATE_TINY), include_failed=True,
                                    train=TrainConfig(steps=3, batch=8, warmup=1, val_every=3, ckpt_every=3,
                                                      threads=1)), Dist())
            self.runs[method] = run
        return self.runs[method]


def install_smooth_policy(setattr_fn=setattr, call_real: bool = False) -> list:
    """Replace PolicyRunner.infer's chunks by a smooth reference about the first observation's pose: joints
    1-2 on slow sines (<= 0.45 rad/s), as a trained policy moves (the takeover tests and bench time the
    machinery, not a policy). setattr_fn: monkeypatch.setattr in a test; call_real: run the real inference
    first (its latency counts). Returns the list the observation time of every chunk asked for goes into."""
    import numpy as np

    from policies.rollout.runner import PolicyRunner
    from policies.rollout.schedule import Chunk

    asked, home = [], {}
    real = PolicyRunner.infer

    def infer(self, obs, t_obs, seq=0):
        lat = real(self, obs, t_obs, seq).latency_s if call_real else 0.0
        q = np.asarray(obs["follower.joint.pos"], float)
        g = float(np.asarray(obs["follower.gripper.pos"], float).reshape(-1)[0])
        home.setdefault("q", q.copy())
        t = t_obs + np.arange(self.cfg.chunk) * self.dt
        a = np.tile(np.r_[home["q"], g], (self.cfg.chunk, 1))
        a[:, 0] += 0.3 * np.sin(1.5 * t)
        a[:, 1] += 0.15 * np.sin(1.1 * t)
        asked.append(t_obs)
        return Chunk(t_obs=t_obs, actions=a, dt=self.dt, seq=seq, latency_s=lat)

    setattr_fn(PolicyRunner, "infer", infer)
    return asked
