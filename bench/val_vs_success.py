"""What the training runs on disk say about stopping on the validation loss (issue #56 item 2): per run, its
task, demonstrations, steps, the step of the validation minimum (raw and smoothed as the run's advice reads
it), the loss there and at the end, and the rollout success where the run was rolled out. Reads only.

    python -m bench.val_vs_success RUNS_ROOT [RUNS_ROOT ...]         # a markdown table of every run found
    python -m bench.val_vs_success /work/runs --json OUT.json         # + the rows as JSON

A run is a folder with metrics.jsonl and checkpoints/ (factr2 train's); its rollout: rollout.json beside it
(bench/first_stages.py, bench/data_curve.py). Runs whose validation curve has fewer than
policies.training.advice.MIN_POINTS points are listed without a minimum.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from policies.training.advice import KEY, MIN_POINTS, read_curve


def val_points(rows: list[dict], key: str = KEY) -> list[tuple[int, float]]:
    """(step, loss) of the validation rows, in step order (a resumed run's rows once per step: the last)."""
    pts = {int(r["step"]): float(r[key]) for r in rows
           if r.get(key) is not None and math.isfinite(float(r[key]))}
    return sorted(pts.items())


def run_row(run: Path) -> dict | None:
    """The row of one run folder, None when it holds no finished training."""
    from policies.training import checkpoint as C
    from policies.training.curves import RunLog

    last = C.last_checkpoint(run)
    if last is None:
        return None
    meta = json.loads(last.read_text())
    rows = RunLog.read(run)
    pts = val_points(rows)
    tasks = sorted(meta.get("tasks", {})) or ["?"]
    out = {"run": str(run), "task": ",".join(tasks), "demos": len(meta.get("episodes", [])),
           "method": meta.get("method", ""), "steps": int(meta["step"]),
           "total_steps": int(meta.get("total_steps", meta["step"])),
           "passes": int(meta["step"]) / meta["steps_per_epoch"] if meta.get("steps_per_epoch") else None,
           "val_points": len(pts)}
    if len(pts) >= MIN_POINTS:
        steps, v = np.array([p[0] for p in pts]), np.array([p[1] for p in pts])
        i = int(np.argmin(v))
        c = read_curve(rows)
        out.update(val_min_step=int(steps[i]), val_min=float(v[i]), val_end=float(v[-1]),
                   rise_pct=100.0 * (float(v[-1]) / float(v[i]) - 1.0), curve=c.kind,
                   smoothed_min_step=c.step_min)
    ro = run / "rollout.json"
    if ro.is_file():
        r = json.loads(ro.read_text())
        eps = r.get("episodes")
        n = len(eps) if isinstance(eps, list) else _count_episodes(eps)
        out.update(success_rate=float(r["success_rate"]), rollouts=n,
                   successes=round(float(r["success_rate"]) * n) if n else None,
                   progress=float(r.get("mean_progress", float("nan"))))
    return out


def _count_episodes(text) -> int | None:
    """rollout.json keeps its episodes as the repr of a list of dicts in older runs: count the dicts."""
    return text.count("'index':") if isinstance(text, str) else None


def find_runs(roots: list[Path]) -> list[Path]:
    return sorted({p.parent for root in roots for p in Path(root).rglob("metrics.jsonl")
                   if (p.parent / "checkpoints").is_dir()})


def table(rows: list[dict]) -> str:
    head = ("| run | task | demos | steps (passes) | val min at (smoothed) | val min / end | curve | "
            "rollout success |\n|---|---|---|---|---|---|---|---|\n")
    lines = []
    for r in rows:
        passes = f" ({r['passes']:.0f})" if r.get("passes") else ""
        passes += "" if r["steps"] == r["total_steps"] else f" of {r['total_steps']}, running"
        vm = (f"{r['val_min_step']} ({r['smoothed_min_step']})" if "val_min" in r
              else f"{r['val_points']} points")
        ve = f"{r['val_min']:.3f} / {r['val_end']:.3f} (+{r['rise_pct']:.0f} %)" if "val_min" in r else ""
        su = f"{r['successes']} / {r['rollouts']}" if r.get("rollouts") else ""
        lines.append(f"| {r['run']} | {r['task']} | {r['demos']} | {r['steps']}{passes} | {vm} | {ve} | "
                     f"{r.get('curve', '')} | {su} |")
    return head + "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("roots", nargs="+", type=Path, help="folders searched for training runs")
    ap.add_argument("--json", type=Path, default=None, help="also write the rows here")
    ap.add_argument("--min-steps", type=int, default=1000, help="leave out runs shorter than this [steps]")
    a = ap.parse_args(argv)
    missing = [str(r) for r in a.roots if not r.is_dir()]
    if missing:
        print(f"no such folder: {', '.join(missing)} (pass folders holding factr2 train runs)",
              file=sys.stderr)
        return 2
    rows = [r for r in map(run_row, find_runs(a.roots)) if r is not None and r["steps"] >= a.min_steps]
    print(table(rows))
    if a.json is not None:
        a.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
