"""FIRST training behind the Training screen (no Textual): which episodes, the phase-label preview, the run's
choices, and one training run in a worker thread -- the same `policies.training.run.run_training` as
`factr2 train` (no second copy), with the progress callback and stop flag of `policies.training.train.train`.

Stopping (key x, the emergency stop, quitting the app) ends the run after its current step and writes a
checkpoint there; `resume` continues it exactly (policies.training.train: step s alone fixes its batch and
noise).
"""

from __future__ import annotations

import json
import threading
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from factr2_teleop.tui.stops import STOPPED
from hardware.errors import UserError
from hardware.reasons import Reason
from hardware.recording.reader import UNMARKED

# which recorded episodes may train (discarded ones never do: policies.data.recordings leaves them out); the
# first is the default, `factr2 train`'s: failed and incomplete episodes are skipped unless asked for
OUTCOME_FILTERS = {
    "success+unlabelled": ("success", "unlabelled", UNMARKED),
    "all": ("success", "failure", "unlabelled", "incomplete", UNMARKED),
    "success": ("success",),
}
DEFAULT_FILTER = next(iter(OUTCOME_FILTERS))
STEP_CHOICES = (0, 20, 100, 500, 2000, 10000)  # optimiser steps; 0: the default length
# (policies.training.run_config default_length: 20 epochs, the paper's; 80 on a state observation, from
# the learning curve)
SIZE_CHOICES = ("small", "paper", "tryout")
# "tryout": a few-second model to walk through the workflow (not a usable policy): the small preset shrunk
TRYOUT_OVERRIDES = dict(
    hidden=64, heads=2, enc_layers=1, dec_layers=2, ff=128, backbone="convnet-gn", image_size=32, dropout=0.0
)
TRYOUT_BATCH = 16
PAPER_CHOICES = "paper: flow or ACT, first 1:5:1, preset paper (hidden 768), 20 epochs, batch 128"
HISTORY = 400  # logged points kept for the charts


def form() -> dict[str, tuple]:
    """What each of the screen's choices cycles through: the options' own
    (policies.training.run_config.form_choices: policy, method, ratio, observation) and the model size."""
    from policies.training.run_config import form_choices

    return {**form_choices(), "size": SIZE_CHOICES}


def usable(row, outcome_filter: str) -> bool:
    """Whether an Episodes-screen row (hardware.recording.episodes.EpisodeRow) may train under the filter."""
    if row.error or row.index < 0 or row.file.suffix != ".mcap":
        return False
    return row.outcome in OUTCOME_FILTERS[outcome_filter]


def episode_key(row) -> str:
    """The row's episode id as policies.data.recordings.episode_id names it ("FILE.mcap#N")."""
    return f"{row.file.name}#{row.index}"


@dataclass
class Choices:
    """What the screen lets the user pick (defaults preselected: flow, first, its 1:5:1, small, 20 epochs)."""

    policy: str = "flow"
    method: str = "first"
    ratio: str = "default"
    size: str = "small"
    steps: int = 0
    # policies.data.privileged.OBSERVATIONS: camera frames, or the twin's object state
    observation: str = "images"
    # [N*m] (LOW, HIGH); "recording": from the episodes' own contact scores, `factr2 train`'s default;
    # "next": from the free-motion noise of the NEXT checkpoint the recordings name
    thresholds: tuple[float, float] | str = "recording"

    def cycle(self, name: str, options, d: int = 1) -> str:
        options = list(options)
        cur = getattr(self, name)
        value = options[(options.index(cur) + d) % len(options)] if cur in options else options[0]
        setattr(self, name, value)
        return value

    def ratio_weights(self) -> tuple[float, float, float]:
        from policies.data.sampler import RATIO_PRESETS
        from policies.training.methods import METHODS

        return METHODS[self.method].ratio if self.ratio == "default" else RATIO_PRESETS[self.ratio]

    def describe(self, epoch_steps: int | None = None) -> str:
        from policies.data.sampler import format_ratio
        from policies.training.run_config import default_length

        about = f" (~{epoch_steps} steps)" if epoch_steps else ""
        epochs = default_length(self.observation)[0]
        steps = f"{self.steps} steps" if self.steps else f"{epochs:g} epochs{about}"
        return (
            f"policy {self.policy} (p)  method {self.method} (m)  ratio {format_ratio(self.ratio_weights())}"
            f" (r)  size {self.size} (z)\nobs {self.observation} (i)  length {steps} ([ ])"
        )

    def step_order(self, epoch_steps: int | None) -> list[int]:
        """STEP_CHOICES ordered by length: 20 epochs (0) sits where its step count falls, so `[` from it
        goes to a shorter run (before, it was first whatever its length, and `[` did nothing)."""
        est = epoch_steps if epoch_steps else STEP_CHOICES[2]  # unknown: between 20 and 500 steps
        return sorted(STEP_CHOICES, key=lambda s: (s or est, s == 0))

    def step(self, d: int, epoch_steps: int | None) -> None:
        order = self.step_order(epoch_steps)
        i = order.index(self.steps) if self.steps in order else order.index(0)
        self.steps = order[max(0, min(len(order) - 1, i + d))]


def epoch_steps(rows, chosen: set, choices: Choices) -> int | None:
    """Optimiser steps of 20 epochs over the chosen episodes, estimated from their durations at the policy
    rate of 30 Hz (None: nothing chosen)."""
    from policies.data.dataset import STATE_RATE_HZ
    from policies.training.run_config import default_length

    secs = sum(r.duration_s for r in rows if episode_key(r) in chosen and np.isfinite(r.duration_s))
    if secs <= 0:
        return None
    epochs, batch = default_length(choices.observation)
    batch = TRYOUT_BATCH if choices.size == "tryout" else batch
    return max(1, int(round(epochs * secs * STATE_RATE_HZ / batch)))


def run_options(choices: Choices, recordings: Path, episodes: list[str], out: Path, threads: int = 0,
                outcomes: str = DEFAULT_FILTER):
    """policies.training.run_config.RunOptions for these choices (the CLI's `factr2 train` builds the same).
    `outcomes`: the screen's filter, so that a failed or incomplete episode the user chose is not skipped."""
    from policies.data.sampler import RATIO_PRESETS
    from policies.training.run_config import RunOptions, TrainConfig, default_length

    tryout = choices.size == "tryout"
    epochs, batch = default_length(choices.observation)  # state: the learning curve's length
    tcfg = TrainConfig(steps=choices.steps, threads=threads, epochs=epochs, batch=batch)
    if tryout:
        tcfg = replace(tcfg, batch=TRYOUT_BATCH, warmup=min(tcfg.warmup, 10), log_every=1, val_every=10,
                       ckpt_every=50)
    elif choices.steps:
        every = max(1, choices.steps // 20)
        tcfg = replace(tcfg, log_every=every, val_every=max(every, choices.steps // 10))
    return RunOptions(
        inputs=[recordings],
        out=out,
        policy=choices.policy,
        method=choices.method,
        ratio=None if choices.ratio == "default" else RATIO_PRESETS[choices.ratio],
        # "small" on a state observation: the state preset (the image preset's DiT is 12x slower there)
        preset="small" if tryout else "" if choices.size == "small" else choices.size,
        thresholds=choices.thresholds,
        progress=False,
        train=tcfg,
        overrides=dict(TRYOUT_OVERRIDES) if tryout else None,
        episodes=tuple(episodes),
        observation=choices.observation,
        include_failed="failure" in OUTCOME_FILTERS[outcomes],
        keep_incomplete="incomplete" in OUTCOME_FILTERS[outcomes],
    )


def resume_options(run: Path, recordings: Path, threads: int = 0):
    """RunOptions that continue the run in `run`, read back from its checkpoint (policies.training.run_config
    RunOptions.from_meta: policy, method, ratio, thresholds, model, train settings and episodes); the
    recordings are looked up in `recordings`."""
    from policies.training import checkpoint as C
    from policies.training.run_config import RunOptions

    o = RunOptions.from_meta(C.read_meta(run), [recordings], Path(run), resume=True, progress=False)
    return replace(o, train=replace(o.train, threads=threads))


@dataclass
class RunRow:
    """One training run in OUT/runs: its newest checkpoint's step of total, final or not, validation loss."""

    path: Path
    policy: str
    method: str
    step: int
    total: int
    final: bool
    val_loss: float


def list_runs(folder: Path) -> list[RunRow]:
    """Every run folder with a checkpoint under `folder`, newest first; `folder` itself when it is one run
    (`factr2 train --out RUN` opened as the runs folder)."""
    from policies.training import checkpoint as C

    rows = []
    if not Path(folder).is_dir():
        return rows
    dirs = [Path(folder)] if C.last_checkpoint(folder) is not None else []
    for d in dirs + sorted((p for p in Path(folder).iterdir() if p.is_dir()), reverse=True):
        last = C.last_checkpoint(d)
        if last is None:
            continue
        try:
            m = json.loads(last.read_text())
        except ValueError:
            continue
        val = float(m.get("metrics", {}).get("val/loss", float("nan")))
        rows.append(RunRow(d, m.get("policy", {}).get("policy", "?"), m.get("method", "?"),
                           int(m.get("step", 0)), int(m.get("total_steps", 0)), bool(m.get("final")), val))
    return rows


def listed_advice(rows: list[RunRow]) -> list[str]:
    """The advice of the run listed first when it is finished (policies/training/advice.py; a `factr2 train
    --out` run opened with --runs, or the newest here): the Train screen's lines before it trains another."""
    from policies.training.advice import run_advice

    if not rows or not rows[0].final:
        return []
    try:
        lines = run_advice(rows[0].path)
    except ValueError as e:  # a damaged metrics.jsonl: said, not hidden
        return [f"advice of {rows[0].path.name}: unreadable run ({e})"]
    return [f"advice of {rows[0].path.name}, the first run listed:", *lines] if lines else []


def run_lines(rows: list[RunRow], limit: int = 4) -> list[str]:
    out = []
    for r in rows[:limit]:
        state = f"final, {r.step} steps" if r.final else f"stopped {r.step}/{r.total}: u resumes"
        val = "-" if not np.isfinite(r.val_loss) else f"{r.val_loss:.4g}"
        out.append(f"  {r.path.name[:26]:<26} {r.policy + '/' + r.method:<12} {state:<27} val {val}"[:79])
    return out or ["  (no runs yet)"]


# -- phase-label preview ---------------------------------------------------------------------------------
@dataclass
class LabelPreview:
    """FIRST labels of the chosen episodes: thresholds and, per episode id, its policies.labels.labelling
    labels."""

    thresholds: object  # policies.labels.labelling.Thresholds
    labels: dict = field(default_factory=dict)


def label_preview(recordings: Path, episodes: list[str], thresholds) -> LabelPreview:
    """Label the chosen episodes as `factr2 episodes phases` does. Blocking (reads recordings): a worker.
    UserError when the thresholds cannot be found (no NEXT checkpoint named, none given)."""
    import warnings

    from policies.data.recordings import episode_id, load_episodes
    from policies.labels import labelling as L

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        eps, arms = load_episodes([recordings])
    keep = set(episodes)
    eps = [e for e in eps if episode_id(e) in keep]
    if not eps:
        raise UserError("no usable episode chosen", where=str(recordings), fix="include one (enter)")
    try:
        th = L.resolve_thresholds(thresholds, None, eps, arms)
    except UserError as e:
        if thresholds not in (None, "next"):
            raise UserError(e.what, where="Train", fix="press h and set LOW:HIGH [N*m]") from None
        raise UserError("these recordings name no NEXT checkpoint to take contact thresholds from",
                        where="Train",
                        fix="press h and set LOW:HIGH [N*m] (empty: from the recordings)") from None
    return LabelPreview(th, {episode_id(e): L.label_episode(e, arms, th) for e in eps})


# -- the run ----------------------------------------------------------------------------------------------
@dataclass
class TrainState:
    """What the screen shows. status: idle | preparing | training | stopping | stopped | done | failed."""

    status: str = "idle"
    step: int = 0
    total: int = 0
    start: int = 0
    eta_s: float = float("nan")
    losses: list = field(default_factory=list)  # training loss per logged step
    val: dict = field(default_factory=dict)  # "val/loss", "val/loss_F", ... -> values per evaluation
    line: str = ""
    run_dir: str = ""
    advice: list = field(default_factory=list)  # a finished run's lines (policies/training/advice.py)


class TrainingRun:
    """One training run (new or resumed) in a worker thread; snapshot() for the screen, stop() keeps a
    checkpoint."""

    def __init__(self, opts, say=None):
        self.opts = opts
        self.say = say or (lambda text: None)
        self.state = TrainState(run_dir=str(opts.out))
        self.stop_event = threading.Event()
        self._lock = threading.Lock()
        self._t0, self._step0 = float("nan"), 0
        self.thread: threading.Thread | None = None

    @property
    def running(self) -> bool:
        return self.thread is not None and self.thread.is_alive()

    def start(self) -> None:
        self.thread = threading.Thread(target=self.run, name="factr2-tui-training", daemon=True)
        self.thread.start()

    def stop(self, why: Reason = STOPPED) -> None:
        if self.running and not self.stop_event.is_set():
            self.stop_event.set()
            with self._lock:
                self.state.status = "stopping"
                self.state.line = f"{why}: finishing the step, keeping a checkpoint"

    def join(self, timeout_s: float | None = None) -> None:
        if self.thread is not None:
            self.thread.join(timeout_s)

    def snapshot(self) -> TrainState:
        with self._lock:
            s = self.state
            return replace(s, losses=list(s.losses), val={k: list(v) for k, v in s.val.items()})

    def _progress(self, row: dict) -> None:
        now = time.monotonic()
        with self._lock:
            s = self.state
            if s.status == "preparing":  # the first step is done: time the rest from here
                s.status, self._t0, self._step0 = "training", now, int(row["step"])
                s.line = f"training -> {self.opts.out}"
            s.step, s.total, s.start = int(row["step"]), int(row["total"]), int(row["start"])
            if s.step > self._step0:
                s.eta_s = (s.total - s.step) * (now - self._t0) / (s.step - self._step0)
            if "train/loss" in row:
                s.losses = (s.losses + [float(row["train/loss"])])[-HISTORY:]
            for k, v in row.items():
                if k.startswith("val/"):
                    s.val[k] = (s.val.get(k, []) + [float(v)])[-HISTORY:]

    def run(self) -> None:
        import torch

        from policies.training.run import run_training
        from policies.training.train import Dist

        with self._lock:
            self.state.status = "preparing"
            self.state.line = "reading recordings, labelling phases, building the dataset ..."
        try:
            d = Dist(device=torch.device("cuda" if torch.cuda.is_available() else "cpu"))
            run_training(self.opts, d, on_progress=self._progress, stop=self.stop_event)
        except UserError as e:
            self._end("failed", str(e))
            return
        except Exception as e:  # noqa: BLE001 -- shown on screen; the app keeps running
            self._end("failed", f"{type(e).__name__}: {e}")
            return
        if self.stop_event.is_set() and self.state.step < self.state.total:
            self._end("stopped", f"stopped at step {self.state.step}: checkpoint kept in {self.opts.out}")
        else:
            from policies.training.advice import run_advice

            advice = run_advice(self.opts.out)
            with self._lock:
                self.state.advice = advice
            self._end("done", f"{self.opts.out}/checkpoints (last), curves.png beside")

    def _end(self, status: str, line: str) -> None:
        with self._lock:
            self.state.status, self.state.line = status, line
        self.say(f"training {status}: {line}")
