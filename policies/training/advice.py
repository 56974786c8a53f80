"""What more data or more training would buy, read from a run's own validation curve (issue #56): one or
two lines `factr2 train` prints at its end and the terminal app's Train screen shows.

The rule, on the validation loss of the evaluated (EMA) weights, "val/loss" in RUN/metrics.jsonl:

- the curve is smoothed by a centred running median over SMOOTH_POINTS evaluations (a single noisy
  evaluation makes no turn);
- its noise is the evaluations' robust spread from their second differences (noise_spread), relative to
  the smoothed minimum;
- **turned up**: the smoothed minimum lies before the last evaluation and the smoothed end is above it by
  more than max(RISE_MIN, NOISE_TIMES x noise): the model fits its demonstrations better and the held-out
  ones worse, so more training cannot help and more data can;
- **still falling**: not turned up, and the last third of the smoothed curve fell by more than
  max(FALL_MIN, NOISE_TIMES x noise): the run stopped before the curve did;
- **flat** otherwise: longer training buys nothing this curve can show;
- no advice (and the line says why) without a validation split or with fewer than MIN_POINTS evaluations.

What more demonstrations bought is cited only where it was measured: the data curve's points for the run's
task on the twin (data_curve_points.json beside this file, written from results/ by `python -m
bench.data_curve_advice`, never by hand), within the measured range only; elsewhere (another task, a real
rig) the line says there is no measured basis. Training shorter is not advised: on the twin it did not raise
success (the same file's shorter_training). The validation loss says which lever, not how much success a
given number of demonstrations would give, nor how many would reach a given loss (each run validates on
other episodes: docs/policies.md, "What the run advises").
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from functools import cache
from importlib import resources
from pathlib import Path

import numpy as np

KEY = "val/loss"
SMOOTH_POINTS = 3  # evaluations in the running median
MIN_POINTS = 5  # evaluations needed to read a curve's shape
RISE_MIN = 0.05  # relative rise of the smoothed curve above its minimum that counts as turned up
FALL_MIN = 0.02  # relative fall over the last third that counts as still falling
NOISE_TIMES = 3.0  # a change must also exceed this many noise spreads

MEASURED = "data_curve_points.json"  # the package copy of the measured curve (bench/data_curve_advice.py)


@dataclass(frozen=True)
class Curve:
    """The shape of a validation curve. kind: "up" | "falling" | "flat" | "none" (no advice: `why`)."""

    kind: str
    step_min: int = 0  # step of the smoothed minimum
    step_end: int = 0  # last evaluated step
    change: float = 0.0  # relative rise above the minimum (up) or fall over the last third (falling)
    noise: float = 0.0  # relative noise spread
    why: str = ""


def running_median(v: np.ndarray, width: int = SMOOTH_POINTS) -> np.ndarray:
    """Centred running median; the window shrinks at the ends."""
    h = width // 2
    return np.array([np.median(v[max(0, i - h): i + h + 1]) for i in range(len(v))])


def noise_spread(v: np.ndarray) -> float:
    """The evaluations' noise (a standard deviation, in v's units) from their second differences, which a
    smooth curve leaves near zero: 1.4826 x the median absolute deviation of v[i-1] - 2 v[i] + v[i+1],
    over sqrt(6) (the variance of a second difference of independent noise is 6 sigma^2)."""
    d2 = v[:-2] - 2.0 * v[1:-1] + v[2:]
    return 1.4826 * float(np.median(np.abs(d2 - np.median(d2)))) / math.sqrt(6.0)


def read_curve(rows: list[dict], key: str = KEY) -> Curve:
    """The shape of the validation curve in metrics rows ({"step", key, ...} dicts, any order)."""
    pts = sorted((int(r["step"]), float(r[key])) for r in rows
                 if key in r and r[key] is not None and math.isfinite(float(r[key])))
    if not pts:
        return Curve("none", why="no validation split")
    if len(pts) < MIN_POINTS:
        return Curve("none", step_end=pts[-1][0],
                     why=f"{len(pts)} validation points, {MIN_POINTS} needed to read the curve")
    steps = np.array([p[0] for p in pts])
    v = np.array([p[1] for p in pts])
    s = running_median(v)
    s[-1] = np.median(v[-SMOOTH_POINTS:])  # the end: as many points as anywhere else, not a shrunk window
    i_min = int(np.argmin(s))
    low = max(float(s[i_min]), 1e-12)
    noise = noise_spread(v) / low
    rise = (float(s[-1]) - low) / low
    if i_min < len(s) - 1 and rise > max(RISE_MIN, NOISE_TIMES * noise):
        return Curve("up", int(steps[i_min]), int(steps[-1]), rise, noise)
    third = s[-max(2, len(s) // 3):]
    fall = (float(third[0]) - float(third[-1])) / max(float(third[0]), 1e-12)
    if fall > max(FALL_MIN, NOISE_TIMES * noise):
        return Curve("falling", int(steps[i_min]), int(steps[-1]), fall, noise)
    return Curve("flat", int(steps[i_min]), int(steps[-1]), fall, noise)


def _k(step: int) -> str:
    return f"{step / 1000:.1f} k" if step >= 1000 else str(step)


@cache
def measured() -> dict:
    """The measured data curve and shorter-training result the advice cites (the package copy)."""
    return json.loads(resources.files(__package__).joinpath(MEASURED).read_text())


def _pct(k: int, n: int) -> int:
    return math.floor(100.0 * k / n + 0.5) if n else 0


def _where(n: int, points: list[dict]) -> str:
    """Where a run's number of demonstrations lies on the measured points; nothing beyond them."""
    ns = [p["n"] for p in points]
    above = [p for p in points if p["n"] > n]
    if not above:
        return (f"this run's {n} is the largest point measured, nothing above it" if n == ns[-1] else
                f"this run's {n} lie above the measured range (up to {ns[-1]}): no basis beyond it")
    nxt = f"{above[0]['n']} ({_pct(above[0]['k'], above[0]['episodes'])} %)"
    if n < ns[0]:
        return f"this run's {n} lie below the measured range; its first point is {nxt}"
    if n in ns:
        return f"this run's {n} is a measured point; the next above is {nxt}"
    below = max(m for m in ns if m < n)
    return f"this run's {n} lie between the measured {below} and {above[0]['n']}; the next above is {nxt}"


def curve_line(task: str, n: int, m: dict) -> str:
    """The measured curve of one twin task: success per number of demonstrations with 95 % Wilson
    intervals, the training seeds and rollouts behind each point, and where the run's n lies."""
    pts = m["tasks"][task]
    per = [f"{len(p['seeds'])} x {p['rollouts'][0]}" if len(p["rollouts"]) == 1 else
           f"{len(p['seeds'])} seeds, {p['episodes']} rollouts" for p in pts]
    if len(set(per)) == 1 and len(pts[0]["rollouts"]) == 1:
        s = len(pts[0]["seeds"])
        behind = f"{s} training seed{'s' if s > 1 else ''} x {pts[0]['rollouts'][0]} rollouts each"
    else:
        behind = "training seeds x rollouts " + ", ".join(per)
    labels = ["SIMULATED"] * bool(m["simulated"]) + ["PRIVILEGED state"] * ("PRIVILEGED" in m["observation"])
    return (f"on the twin's {task} ({', '.join(labels)}): "
            f"{' -> '.join(str(p['n']) for p in pts)} demonstrations gave "
            f"{' -> '.join(str(_pct(p['k'], p['episodes'])) for p in pts)} % success (95 % intervals "
            + ", ".join(f"{_pct(p['wilson'][0], 1)}-{_pct(p['wilson'][1], 1)}" for p in pts)
            + f" %), {behind}; {_where(n, pts)}")


def data_line(tasks: dict, rig: str = "", m: dict | None = None) -> str:
    """What more demonstrations bought where it was measured (the run's task on the curve's twin rig), or
    that nothing was. tasks: name -> the run's number of demonstrations of it."""
    m = m or measured()
    known = [curve_line(t, n, m) for t, n in sorted(tasks.items()) if rig == m["rig"] and t in m["tasks"]]
    if known:
        return "measured " + "; ".join(known) + f" ({m['docs']})"
    named = ", ".join(sorted(tasks)) or "this data"
    return (f"no measured data curve for {named} on {rig or 'this rig'}: no basis to say how many "
            "demonstrations would be enough")


def shorter_fact(m: dict | None = None) -> str:
    """What training shorter did to success where it was measured (docs/policies.md, "Choosing the
    defaults")."""
    sh = (m or measured())["shorter_training"]
    return (f"training shorter did not raise success on the twin ({' + '.join(sh['tasks'])}: "
            f"{sh['k_short']} / {sh['n_short']} at {_k(sh['short_steps'])} steps, {sh['k_long']} / "
            f"{sh['n_long']} at {_k(sh['long_steps'])}, one-sided p = {sh['p_one_sided']:.2f}; {sh['docs']})")


def training_advice(rows: list[dict], n_episodes: int, tasks=(), key: str = KEY, rig: str = "",
                    m: dict | None = None) -> list[str]:
    """One or two lines of advice from a run's metrics rows (RUN/metrics.jsonl), its number of
    demonstrations (training and validation episodes), its tasks (names, or name -> demonstrations of it)
    and its rig's name (the measured curve is cited only for the twin rig it was measured on)."""
    c = read_curve(rows, key)
    at = f"at {n_episodes} demonstrations"
    if c.kind == "none":
        return [f"advice: {c.why}: no basis for advice"
                + (" (validation holds out whole episodes: record at least 2)" if not c.step_end else "")]
    spread = f"noise {100 * c.noise:.0f} %"
    per_task = dict(tasks) if isinstance(tasks, dict) else {t: n_episodes for t in tasks}
    if c.kind == "up":
        return [f"advice: validation loss turned up after {_k(c.step_min)} of {_k(c.step_end)} steps {at} "
                f"(+{100 * c.change:.0f} % by the end, {spread}): the data, not the training length, limits "
                f"this policy: record more demonstrations; {shorter_fact(m)}",
                data_line(per_task, rig, m)]
    if c.kind == "falling":
        return [f"advice: validation loss still falling at the end ({_k(c.step_end)} steps, "
                f"-{100 * c.change:.0f} % over the last third, {spread}) {at}: train longer before recording "
                "more"]
    return [f"advice: validation loss flat at the end ({_k(c.step_end)} steps, {spread}) {at}: longer "
            "training buys nothing this curve shows; more demonstrations are the lever",
            data_line(per_task, rig, m)]


def run_advice(run) -> list[str]:
    """training_advice for a finished run folder: its metrics.jsonl and its last checkpoint's episodes,
    tasks and rig ([] when the folder holds no run)."""
    from policies.training import checkpoint as C
    from policies.training.curves import RunLog

    run = Path(run)
    last = C.last_checkpoint(run)
    if last is None:
        return []
    meta = json.loads(last.read_text())
    rig = meta.get("rig") or {}
    name = Path(rig.get("rig_file", "")).stem if isinstance(rig, dict) else ""
    return training_advice(RunLog.read(run), len(meta.get("episodes", [])), meta.get("tasks") or {},
                           rig=name)
