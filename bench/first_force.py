"""What force buys a policy (issue #51, SIMULATED): the force table of a `bench_first --table force` run, and
the test-time ablation of its force-conditioned policies.

    python -m bench.first_force --out OUT --ablate zero,shuffle     # ablation rollouts (resumable)
    python -m bench.first_force --out OUT --report                  # OUT/force_table.md + force_results.json

OUT is a `bench_first` results folder (OUT/config.json, OUT/TASK/CELL/seedS/{train,rollout}.json). The
ablation rolls every trained base-torque, first and first-motion policy out again on the SAME evaluation
episodes (the run's --eval-seed and rollout count) with its force input zeroed (0 N*m) or shuffled (each chunk
fed a force the episode had earlier: policies/rollout/runner.py), written beside the live set as
rollout-zero.json / rollout-shuffle.json. The report pairs by training seed and episode: base-torque and first
against base (is a force-conditioned policy better?), first against base-torque (does FIRST's sampling add to
it?), first-motion -- when the run has it (`bench_first --table force-motion`: first trained on
`--contact-score motion` labels) -- against base, base-torque and first (do the labels change it?), and each
force policy live against its ablations (does it use the input?): success with pooled 95 % Wilson intervals,
exact McNemar p on the discordant episodes, task progress (the share of stages completed, the paper's
measure) with the paired mean difference and its 95 % interval, and the stage where the failures stop.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from bench import harness
from bench.first_report import mcnemar_p, wilson
from bench.portable import portable, portable_text

# the cells with a force input; first-motion (first on the motion-discounted labels, `--table force-motion`)
# is reported when the run has it, paired against base, base-torque and first
FORCE_CELLS = ("base-torque", "first", "first-motion")
CELLS = ("base",) + FORCE_CELLS
ABLATIONS = ("zero", "shuffle")
PAIRS = (("base-torque", "base"), ("first", "base"), ("first", "base-torque"),
         ("first-motion", "base"), ("first-motion", "base-torque"), ("first-motion", "first"))


def rollout_file(run: Path, how: str = "live") -> Path:
    return run / ("rollout.json" if how == "live" else f"rollout-{how}.json")


def ablation_rollout(run: str, task: str, how: str, episodes: int, eval_seed: int) -> dict:
    """One trained policy's rollout set with its force input ablated (`how`), on the live set's episodes."""
    from factr2_teleop.session.rollout import RolloutOptions, run_rollout

    path = rollout_file(Path(run), how)
    if path.is_file():
        return json.loads(path.read_text())
    t, c = time.perf_counter(), time.process_time()
    res = run_rollout(RolloutOptions(rig="sim-piper", policy=Path(run), task=task, episodes=episodes,
                                     seed=eval_seed, record=None, progress=False, force_input=how)).to_dict()
    out = {"task": task, "force_input": how, "success_rate": res["success_rate"],
           "mean_progress": res["mean_progress"], "stage_rates": res.get("stage_rates"),
           "episodes": res.get("episodes"), "wall_s": time.perf_counter() - t,
           "cpu_s": time.process_time() - c}
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(out, indent=1, default=float))
    os.replace(tmp, path)
    return out


def _episodes(roll: dict) -> dict[int, tuple[int, float]]:
    """episode seed -> (success 1/0, progress) of one rollout set."""
    return {int(e["seed"]): (int(e.get("outcome") == "success"), float(e.get("progress", 0.0)))
            for e in roll.get("episodes") or [] if isinstance(e, dict) and "seed" in e}


def load_runs(out: Path, live_as: str = "live") -> dict:
    """{(task, cell, seed, how): rollout set} of every finished rollout set in OUT (its live sets keyed
    `live_as`: another observation's run, compared on the same episodes, is keyed by its observation)."""
    runs = {}
    for path in sorted(out.glob("*/*/seed*/rollout*.json")):
        task, cell, seed = path.parts[-4], path.parts[-3], int(path.parts[-2][4:])
        how = live_as if path.name == "rollout.json" else path.stem.split("-", 1)[1]
        if live_as == "live" or how == live_as:
            runs[(task, cell, seed, how)] = json.loads(path.read_text())
    return runs


def against_runs(out: Path, other: Path) -> tuple[str, dict]:
    """The live rollout sets of OTHER, a bench_first run with another observation on the same demonstrations
    and evaluation episodes, keyed by its observation; SystemExit in one line when they are not comparable."""
    mine, theirs = (json.loads((d / "config.json").read_text()) for d in (out, other))
    if mine.get("eval_seed") != theirs.get("eval_seed") or mine.get("rollouts") != theirs.get("rollouts"):
        raise SystemExit(f"--against {other}: evaluation seed / rollouts {theirs.get('eval_seed')} / "
                         f"{theirs.get('rollouts')} differ from OUT's {mine.get('eval_seed')} / "
                         f"{mine.get('rollouts')}: the episodes would not pair")
    obs = theirs.get("obs")
    if not obs or obs == mine.get("obs"):
        raise SystemExit(f"--against {other}: observation {obs!r}, the same as OUT's: nothing to compare")
    return obs, load_runs(other, live_as=obs)


def kept_runs(payload: dict, have: set) -> dict:
    """The rollout sets of an earlier force results file (its payload: summarize()'s data) for every
    (task, cell, seed, how) that `have` lacks: a task, cell or training seed whose run folder is gone comes
    back from the results file's raw rows (episode seed, success, progress). A set's stage reach is its
    cell's pooled one (the file keeps no per-set reach): the kept sets of a cell, of equal size, add up to
    the reach they had, so the pooled stages stay exact."""
    runs = {}
    for task, d in (payload.get("tasks") or {}).items():
        for key, sets in (d.get("raw") or {}).items():
            cell, _, how = key.partition("/")
            summary = d.get("cells", {}).get(_cell_name(cell, how, payload.get("observation"))) or {}
            for seed, rows in sets.items():
                if (task, cell, int(seed), how) in have:
                    continue
                eps = [{"seed": int(k), "outcome": "success" if ok else "failure", "progress": float(prog)}
                       for k, ok, prog in rows]
                runs[(task, cell, int(seed), how)] = {"episodes": eps, "kept_from_results": True,
                                                      "stage_rates": summary.get("stages", {})}
    return runs


def cell_summary(runs: dict, task: str, cell: str, how: str = "live") -> dict | None:
    """Pooled success (k / n, Wilson), progress, per-seed success and stage reach of one cell."""
    sets = {s: r for (t, c, s, h), r in runs.items() if (t, c, h) == (task, cell, how)}
    if not sets:
        return None
    eps = [v for s in sorted(sets) for v in _episodes(sets[s]).values()]
    k, n = sum(e[0] for e in eps), len(eps)
    stages: dict = {}
    for r in sets.values():
        m = len(r.get("episodes") or [])
        for st, rate in (r.get("stage_rates") or {}).items():
            stages[st] = stages.get(st, 0.0) + rate * m / max(n, 1)
    return {"seeds": sorted(sets), "k": k, "n": n, "success": k / n if n else float("nan"),
            "wilson": wilson(k, n), "progress": float(np.mean([e[1] for e in eps])) if eps else float("nan"),
            "per_seed": [float(np.mean([e[0] for e in _episodes(sets[s]).values()])) for s in sorted(sets)],
            "stages": stages, "failing_stage": failing_stage(stages)}


def failing_stage(stages: dict) -> str:
    """The stage that loses the most episodes (the largest drop in reach from the one before it)."""
    if not stages:
        return "-"
    names, rates = list(stages), [1.0] + list(stages.values())
    drops = [rates[i] - rates[i + 1] for i in range(len(names))]
    i = int(np.argmax(drops))
    return f"{names[i]} ({100 * stages[names[i]]:.0f} % reach)" if drops[i] > 0 else "-"


def paired(runs: dict, task: str, a: tuple[str, str], b: tuple[str, str]) -> dict | None:
    """(cell, how) a against b, paired by training seed and episode seed (b may be another cell on the same
    seed, or the same policy live): success discordance + exact McNemar p, and the progress difference."""
    only_a = only_b = 0
    dprog: list[float] = []
    seeds = []
    for (t, c, s, h), ra in runs.items():
        if (t, c, h) != (task, *a) or (task, b[0], s, b[1]) not in runs:
            continue
        ea, eb = _episodes(ra), _episodes(runs[(task, b[0], s, b[1])])
        seeds.append(s)
        for ep in sorted(set(ea) & set(eb)):
            only_a += ea[ep][0] and not eb[ep][0]
            only_b += eb[ep][0] and not ea[ep][0]
            dprog.append(ea[ep][1] - eb[ep][1])
    if not dprog:
        return None
    d = np.asarray(dprog)
    half = 1.96 * d.std(ddof=1) / np.sqrt(len(d)) if len(d) > 1 else float("nan")
    return {"seeds": sorted(seeds), "pairs": len(d), "only_a": int(only_a), "only_b": int(only_b),
            "success_diff": (only_a - only_b) / len(d), "mcnemar_p": mcnemar_p(int(only_a), int(only_b)),
            "progress_diff": float(d.mean()), "progress_ci": (float(d.mean() - half), float(d.mean() + half))}


def summarize(out: Path, against: Path | None = None, keep: dict | None = None) -> dict:
    """The force table's data from every finished rollout set in OUT: per task, each cell's summary
    (cell_summary), each comparison (paired), and every rollout (raw: episode seed, success, progress), so
    that the table can be re-made and re-tested from the results file alone. `against`: a run with another
    observation on the same demonstrations (its cells as "CELL, OBS observation", paired with OUT's).
    `keep`: an earlier results file's payload whose cells OUT and AGAINST lack are taken (kept_runs)."""
    runs = load_runs(out)
    if against is not None:
        runs.update(against_runs(out, against)[1])
    cfg = json.loads((out / "config.json").read_text()) if (out / "config.json").is_file() else {}
    if keep is not None:
        if keep.get("observation") != cfg.get("obs") or keep.get("eval_seed") != cfg.get("eval_seed"):
            raise SystemExit(f"--keep: observation / evaluation seed {keep.get('observation')} / "
                             f"{keep.get('eval_seed')} differ from OUT's {cfg.get('obs')} / "
                             f"{cfg.get('eval_seed')}: its episodes would not pair")
        runs.update(kept_runs(keep, set(runs)))
    others = sorted({h for *_, h in runs if h != "live" and h not in ABLATIONS})  # other observations
    data: dict = {"simulated": True, "observation": cfg.get("obs"), "eval_seed": cfg.get("eval_seed"),
                  "bench": {k: cfg.get(k) for k in ("tasks", "demos", "seeds", "rollouts", "steps", "batch",
                                                    "policy", "precision", "next_checkpoint", "table")},
                  "tasks": {}}
    for task in sorted({k[0] for k in runs}):
        d = data["tasks"][task] = {"cells": {}, "pairs": {}, "raw": {}}
        for cell in CELLS:
            for how in ("live",) + (ABLATIONS if cell in FORCE_CELLS else ()) + tuple(others):
                s = cell_summary(runs, task, cell, how)
                if s is not None:
                    d["cells"][_cell_name(cell, how)] = s
        pairs = [((a, "live"), (b, "live")) for a, b in PAIRS]
        pairs += [((c, "live"), (c, h)) for c in FORCE_CELLS for h in ABLATIONS]
        pairs += [((c, "live"), (c, o)) for o in others for c in CELLS]
        for a, b in pairs:
            p = paired(runs, task, a, b)
            if p is not None:
                d["pairs"][_pair_name(a, b, data["observation"])] = p
        for (t, c, sd, how), r in sorted(runs.items()):
            if t == task:
                d["raw"].setdefault(f"{c}/{how}", {})[str(sd)] = sorted(
                    [k, *v] for k, v in _episodes(r).items())
    return data


def _cell_name(cell: str, how: str, obs: str | None = None) -> str:
    if how in ("live", obs):  # a results file's raw keys its own observation's sets "live"
        return cell
    return f"{cell}, force {how}" if how in ABLATIONS else f"{cell}, {_obs_name(how)} observation"


def _obs_name(obs: str) -> str:
    return "PRIVILEGED state" if obs == "state" else obs


def _pair_name(a: tuple[str, str], b: tuple[str, str], obs: str | None) -> str:
    if a[1] == b[1]:
        return f"{a[0]} vs {b[0]}"
    if b[1] in ABLATIONS:
        return f"{a[0]}: live vs force {b[1]}"
    return f"{a[0]}: {obs} vs {_obs_name(b[1])} observation"


def render(data: dict) -> str:
    """The force table (markdown) of summarize()'s data."""
    lines = [f"SIMULATED, observation `{data.get('observation', '?')}`, evaluation seed "
             f"{data.get('eval_seed', '?')}; success pooled over training seeds [95 % Wilson], progress = "
             "mean share of stages completed.", "",
             "| task | method | seeds | success [95 % Wilson] | per seed [%] | progress | stage that fails |",
             "|---|---|---|---|---|---|---|"]
    comps = ["", "| task | comparison (A vs B) | paired episodes | only A / only B | McNemar p | "
             "success diff | progress diff [95 % CI] |", "|---|---|---|---|---|---|---|"]
    for task, d in data["tasks"].items():
        for name, s in d["cells"].items():
            lo, hi = s["wilson"]
            lines.append(f"| {task} | {name} | {len(s['seeds'])} | {s['k']} / {s['n']} = "
                         f"{100 * s['success']:.0f} % [{100 * lo:.0f}, {100 * hi:.0f}] | "
                         f"{' '.join(f'{100 * x:.0f}' for x in s['per_seed'])} | {s['progress']:.2f} | "
                         f"{s['failing_stage']} |")
        for name, p in d["pairs"].items():
            lo, hi = p["progress_ci"]
            comps.append(f"| {task} | {name} | {p['pairs']} (seeds {','.join(map(str, p['seeds']))}) | "
                         f"{p['only_a']} / {p['only_b']} | {p['mcnemar_p']:.3f} | "
                         f"{100 * p['success_diff']:+.1f} pts | "
                         f"{p['progress_diff']:+.3f} [{lo:+.3f}, {hi:+.3f}] |")
    return "\n".join(lines + comps)


def report(out: Path, against: Path | None = None, keep: dict | None = None) -> tuple[str, dict]:
    """The force table (markdown) and its data from every finished rollout set in OUT (and AGAINST, and
    the cells of KEEP that neither holds)."""
    data = summarize(out, against, keep)
    return render(data) + "\n", data


def run_ablation(out: Path, hows: list[str], jobs: int, tasks: tuple[str, ...] = ()) -> None:
    """Every trained force policy's ablation sets (`hows`) not yet written; only `tasks` when given."""
    cfg = json.loads((out / "config.json").read_text())
    todo = [(str(p.parent), p.parts[-4], how, cfg["rollouts"], cfg["eval_seed"])
            for p in sorted(out.glob("*/*/seed*/train.json")) if p.parts[-3] in FORCE_CELLS
            and (not tasks or p.parts[-4] in tasks)
            for how in hows if not rollout_file(p.parent, how).is_file()]
    print(f"{len(todo)} ablation rollout set(s) on {jobs} worker(s)", flush=True)
    if jobs <= 1:
        for args in todo:
            ablation_rollout(*args)
            print(f"  done {args[0]} {args[2]}", flush=True)
        return
    import multiprocessing as mp

    with ProcessPoolExecutor(jobs, mp_context=mp.get_context("spawn")) as ex:
        for args, _ in zip(todo, ex.map(ablation_rollout, *zip(*todo))):
            print(f"  done {args[0]} {args[2]}", flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, help="a bench_first results folder")
    ap.add_argument("--ablate", default="", help="comma-separated: zero, shuffle")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--tasks", default="", help="with --ablate: only these tasks (comma-separated)")
    ap.add_argument("--report", action="store_true", help="write OUT/force_table.md and force_results.json")
    ap.add_argument("--against", default="", metavar="DIR",
                    help="with --report: a bench_first run with another observation (e.g. state) on the same "
                    "demonstrations and evaluation episodes (--demos-from OUT's), paired cell by cell")
    ap.add_argument("--keep", default="", metavar="NAME",
                    help="with --report: take from results/NAME.json every rollout set (task, method, "
                    "training seed, ablation or observation) that OUT and --against do not hold, from its "
                    "raw rows: a run folder since gone stays in the table")
    ap.add_argument("--results", default="", metavar="NAME",
                    help="with --report: also publish the data as results/NAME.json (a harness record; "
                    "docs/force.md's table is written from it by python -m bench.docs_tables)")
    a = ap.parse_args(argv)
    out = Path(a.out)
    if not (out / "config.json").is_file():
        ap.error(f"--out {out}: no config.json (not a bench_first results folder)")
    hows = harness.names(a.ablate)
    if any(h not in ABLATIONS for h in hows):
        ap.error(f"--ablate {a.ablate!r}: a comma-separated subset of {', '.join(ABLATIONS)}")
    if hows:
        run_ablation(out, hows, max(1, a.jobs), tuple(harness.names(a.tasks)))
    if a.report or not hows:
        against = Path(a.against) if a.against else None
        if against is not None and not (against / "config.json").is_file():
            ap.error(f"--against {against}: no config.json (not a bench_first results folder)")
        keep = None
        if a.keep:
            path = harness.RESULTS / f"{a.keep}.json"
            if not path.is_file():
                ap.error(f"--keep {a.keep}: no {path} (a results name, e.g. force_perceived)")
            keep = json.loads(path.read_text()).get("payload") or {}
        md, data = report(out, against, keep)
        (out / "force_table.md").write_text(md)
        (out / "force_results.json").write_text(json.dumps(data, indent=1, default=float))
        if a.results:  # OUT and OUT_STATE are scratch folders: named, not the machine's paths
            roots = {"OUT": out.resolve(), "OUT_STATE": against.resolve() if against else None}
            cmd = harness.command().replace(str(a.out), "OUT").replace(a.against or "\0", "OUT_STATE")
            print(harness.write(harness.RESULTS / f"{a.results}.json",
                                harness.record(a.results, portable(data, roots), simulated=True,
                                               cmd=portable_text(cmd, roots))))
        print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
