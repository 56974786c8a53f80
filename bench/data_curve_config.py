"""bench/data_curve.py's configuration and its pure parts: the points, the seeds, what an OUT must keep on
resume (SAME_ON_RESUME), the nested subsets of successful demonstrations as `factr2 train` arguments, and the
command line. No I/O beyond reading another OUT's config.json (--demos-from)."""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass, field
from pathlib import Path

from bench import harness
from bench.data_curve_defaults import DEFAULTS, defaults_flags
from bench.first_config import (
    DATA_CURVE_DEMO_SEED,
    DATA_CURVE_EVAL_SEED,
    DEFAULTS_DEV_DEMO_SEED,
    DEFAULTS_DEV_EVAL_SEED,
)

POINTS = {"peg-insert": [25, 50, 100, 200], "press-fit": [25, 50, 100, 200], "wipe": [25, 50]}
# the NEXT checkpoint the demonstrations' feedback uses: the committed one, so a collection is the same on
# every machine with the same software (docs/first.md, "The headline across machines")
NEXT_CHECKPOINT = "bench/assets/next_sim_piper_first/next.json"
QUICK = {"tasks": ["wipe"], "points": {"wipe": [2, 4]}, "seeds": 1, "rollouts": 1, "part_episodes": 3,
         "train_flags": ["--steps", "30", "--batch", "32"]}
SAME_ON_RESUME = ("defaults", "defaults_meta", "train_flags", "rollouts", "part_episodes", "device",
                  "next_checkpoint", "demo_seed", "eval_seed",  # the seeds: a --dev OUT is never the curve's
                  "perturb")  # a perturbed collection is never resumed as an unperturbed one, nor back
# how a perturbed collection's ticks are trained on (factr2 train --perturbed; dart is its default, named
# so that the recorded train flags say it)
PERTURBED_TRAIN = ["--perturbed", "dart"]
# the seeds of a run: the curve's (what is reported), or the development ones a rule is chosen on
SEED_SETS = {"curve": (DATA_CURVE_DEMO_SEED, DATA_CURVE_EVAL_SEED),
             "dev": (DEFAULTS_DEV_DEMO_SEED, DEFAULTS_DEV_EVAL_SEED)}


@dataclass
class CurveConfig:
    out: str = "data_curve"
    defaults: str = "current"
    tasks: list = field(default_factory=lambda: list(POINTS))
    points: dict = field(default_factory=lambda: dict(POINTS))  # task -> successful demonstrations
    seeds: int = 2  # training seeds per point
    rollouts: int = 24  # per policy: 2 x 24 = 48 per point
    part_episodes: int = 25  # episodes per collection part
    jobs: int = 2
    threads: int = 0  # torch threads per training (0: cores / jobs)
    device: str = "cpu"
    next_checkpoint: str = NEXT_CHECKPOINT
    train_flags: list = field(default_factory=list)  # beyond the defaults' (--quick: few steps)
    quick: bool = False
    seed_set: str = "curve"  # SEED_SETS
    demo_seed: int = DATA_CURVE_DEMO_SEED
    eval_seed: int = DATA_CURVE_EVAL_SEED
    demos_from: str = ""  # another OUT whose collection (same seeds, part size) this one trains on
    # factr2 collect --perturb's settings (teleop.perturb.PerturbConfig.to_dict()) every part is collected
    # with; None: no perturbation (what an OUT from before the option holds)
    perturb: dict | None = None
    defaults_meta: dict = field(default_factory=dict)  # what the defaults resolve to here (defaults_meta())

    def point_keys(self) -> list[tuple[str, int, int]]:
        return [(t, n, s) for s in range(self.seeds) for t in self.tasks for n in self.points[t]]


# -- pure parts --------------------------------------------------------------------------------------------
def successful_ids(parts: list[tuple[str, dict]]) -> list[str]:
    """The episode ids (FILE.mcap#N, as `factr2 train --episodes` names them) of the successful episodes of
    the collection parts [(mcap file name, collection summary)], in collection order."""
    return [f"{name}#{r['index']}" for name, summary in parts
            for r in sorted(summary["results"], key=lambda r: r["index"]) if r.get("outcome") == "success"]


def parts_for(successes: list[int], n: int) -> int | None:
    """How many leading parts (of these success counts, in order) hold n successes; None: not enough."""
    total = 0
    for k, s in enumerate(successes):
        total += s
        if total >= n:
            return k + 1
    return None


def episode_ranges(ids: list[str]) -> str:
    """Episode ids as `--episodes` text, runs of indices joined: a.mcap#0-3,a.mcap#5 (a shorter command)."""
    out: list[list] = []
    for i in ids:
        name, _, idx = i.rpartition("#")
        if out and out[-1][0] == name and out[-1][2] == int(idx) - 1:
            out[-1][2] = int(idx)
        else:
            out.append([name, int(idx), int(idx)])
    return ",".join(f"{n}#{a}" if a == b else f"{n}#{a}-{b}" for n, a, b in out)


def train_argv(cfg: CurveConfig, folders: list[Path], ids: list[str], seed: int, run: Path) -> list[str]:
    """The `factr2 train` arguments of a point: the defaults named (for its size), the subset, the seed."""
    return [*map(str, folders), "--obs", "state", *defaults_flags(cfg.defaults, len(ids)), *cfg.train_flags,
            "--seed", str(seed), "--episodes", episode_ranges(ids), "--out", str(run)]


def check_demos_from(cfg: CurveConfig) -> None:
    """--demos-from OTHER: OTHER is a data-curve OUT collected on this run's seeds, part size and NEXT
    checkpoint (its episodes are then the ones this run would collect); SystemExit naming what differs."""
    other = Path(cfg.demos_from) / "config.json"
    if not other.is_file():
        raise SystemExit(f"--demos-from {cfg.demos_from}: no config.json (not a data_curve results folder)")
    old = json.loads(other.read_text())
    keys = ("seed_set", "demo_seed", "part_episodes", "next_checkpoint", "perturb")
    diff = [k for k in keys if old.get(k, "curve" if k == "seed_set" else None) != getattr(cfg, k)]
    if diff:
        raise SystemExit(f"--demos-from {cfg.demos_from}: collected with other " + ", ".join(
            f"{k} ({old.get(k)} there, {getattr(cfg, k)} here)" for k in diff))


def _train_args(ap: argparse.ArgumentParser, text: str) -> list[str]:
    """--train-args' words, checked by `factr2 train`'s own parser (a bad one stops here, not hours in)."""
    import shlex

    from policies.training.run_config import add_arguments

    class _Refuse(argparse.ArgumentParser):
        def error(self, message):  # one line from the caller's parser, not factr2 train's usage
            raise ValueError(message)

    words = shlex.split(text)
    train = _Refuse(prog="factr2 train")
    add_arguments(train)
    try:
        _, unknown = train.parse_known_args(["FOLDER", "--out", "RUN", *words])
    except ValueError as e:
        ap.error(f"--train-args {text!r}: {e}")
    if unknown:
        ap.error(f"--train-args {text!r}: factr2 train has no {' '.join(unknown)}")
    return words


def parse_args(argv=None, description: str = "") -> tuple[CurveConfig, argparse.Namespace]:
    ap = argparse.ArgumentParser(prog="python -m bench.data_curve", description=description)
    ap.add_argument("--out", required=True, help="results folder (resumable)")
    ap.add_argument("--defaults", choices=tuple(DEFAULTS), default="current",
                    help="the training defaults: current = `factr2 train` with no options at this commit; "
                    "noise, dropout, val-min, longer: one lever each; sized: the candidate rule from the "
                    "number of demonstrations (docs/data_curve.md, 'Choosing the defaults')")
    ap.add_argument("--dev", action="store_true",
                    help="development seeds (bench/first_config.py DEFAULTS_DEV_*: collection 5701-5740, "
                    "rollouts 5700) to choose defaults on; never the curve's, never resumed as the curve")
    ap.add_argument("--demos-from", default="", metavar="OUT2",
                    help="train on OUT2's collection (a data_curve OUT on the same seeds and part size): "
                    "each set of defaults compared on the same demonstrations, collected once")
    ap.add_argument("--perturb", nargs="?", const="", default=None, metavar="KEY=VALUE,...",
                    help="collect every part with factr2 collect --perturb SPEC (empty: its defaults; "
                    "docs/tasks.md) and train with --perturbed dart: on the same collection and rollout "
                    "seeds as the curve, paired with its points (--report --against CURVE_OUT)")
    ap.add_argument("--against", default="", metavar="OUT2",
                    help="also report each point paired with OUT2's same point (another OUT, or a results "
                    "file: results/NAME.json, its path or NAME; same training seeds and rollout episodes: "
                    "exact McNemar on the paired rollouts)")
    ap.add_argument("--import-results", default="", metavar="NAME",
                    help="seed OUT with the finished points of results/NAME.json (or a file) that this run "
                    "plans: the queue skips them and collects again what it still needs, checked against "
                    "what they were trained on (bench/data_curve_ledger.py)")
    ap.add_argument("--any-commit", action="store_true",
                    help="with --import-results: take points trained at another commit (fingerprinted only)")
    ap.add_argument("--import-for-commit", default="", metavar="COMMIT",
                    help="with --import-results: import, write OUT/config.json and stop; the queue runs at "
                    "COMMIT (another checkout, e.g. the tree the points were trained in)")
    ap.add_argument("--train-args", default="", metavar="'ARGS'",
                    help="more `factr2 train` options for every point (one quoted string, e.g. "
                    "'--thresholds 0.6:1.1'): recorded in the train flags, so an OUT is never resumed "
                    "with others; pair it with the same collection by --demos-from")
    ap.add_argument("--tasks", default="", help=f"comma-separated (default {','.join(POINTS)})")
    ap.add_argument("--points", default="", metavar="N[,N...]",
                    help="successful demonstrations per point, for every task given (default: "
                    + "; ".join(f"{t} {','.join(map(str, p))}" for t, p in POINTS.items()) + ")")
    ap.add_argument("--seeds", type=int, default=None, help="training seeds per point (default 2)")
    ap.add_argument("--rollouts", type=int, default=None, help="rollout episodes per policy (default 24)")
    ap.add_argument("--part-episodes", type=int, default=None, help="episodes per collection part (25)")
    ap.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    ap.add_argument("--threads", type=int, default=0, help="torch threads per training (cores / jobs)")
    ap.add_argument("--device", choices=("cpu", "auto"), default="cpu",
                    help="where the trainings run (auto: a GPU where there is one)")
    ap.add_argument("--quick", action="store_true", help="a few-minute smoke run: " + json.dumps(QUICK))
    ap.add_argument("--report", action="store_true", help="run nothing: report OUT's finished points")
    ap.add_argument("--results", default="", metavar="NAME", help="also write results/NAME.json")
    a = ap.parse_args(argv)
    if a.import_results and a.report:
        ap.error("--import-results with --report: a report runs nothing; import into a run")
    if (a.any_commit or a.import_for_commit) and not a.import_results:
        ap.error("--any-commit and --import-for-commit go with --import-results")
    cfg = CurveConfig(out=a.out, defaults=a.defaults, jobs=max(1, a.jobs), threads=max(0, a.threads),
                      device=a.device, demos_from=a.demos_from)
    cfg.seed_set = "dev" if a.dev else "curve"
    cfg.demo_seed, cfg.eval_seed = SEED_SETS[cfg.seed_set]
    if a.quick:
        cfg.quick = True
        for k, v in QUICK.items():
            setattr(cfg, k, v)
    for k in ("seeds", "rollouts", "part_episodes"):
        v = getattr(a, k)
        if v is not None and v < 1:
            ap.error(f"--{k.replace('_', '-')} {v}: at least 1")
        if v is not None:
            setattr(cfg, k, v)
    if a.tasks:
        cfg.tasks = harness.names(a.tasks)
    if a.points:
        try:
            pts = sorted({int(x) for x in harness.names(a.points)})
        except ValueError:
            ap.error(f"--points {a.points!r}: comma-separated numbers of demonstrations, e.g. 25,50")
        if not pts or pts[0] < 1:
            ap.error(f"--points {a.points!r}: each at least 1")
        cfg.points = {t: pts for t in cfg.tasks}
    if any(t not in cfg.points for t in cfg.tasks):
        lacking = [t for t in cfg.tasks if t not in cfg.points]
        ap.error(f"--tasks {a.tasks!r}: no default points for {', '.join(lacking)}; give --points")
    cfg.points = {t: cfg.points[t] for t in cfg.tasks}
    if a.train_args:
        cfg.train_flags = [*cfg.train_flags, *_train_args(ap, a.train_args)]
    if a.perturb is not None:
        from factr2_teleop.teleop.perturb import parse_perturb
        from hardware.errors import UserError

        try:
            cfg.perturb = parse_perturb(a.perturb).to_dict()
        except UserError as e:
            ap.error(str(e))
        cfg.train_flags = [*cfg.train_flags, *PERTURBED_TRAIN]  # a new list: never QUICK's
    return cfg, a
