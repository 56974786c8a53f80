"""The data curve (SIMULATED, PRIVILEGED state; issue #56 item 1): success and task progress against the
number of successful demonstrations a policy is trained on, with `factr2 train`'s defaults.

Per task, one collection large enough for the largest point, counted in SUCCESSFUL demonstrations, made in
parts of --part-episodes (part k from collection seed DATA_CURVE_DEMO_SEED + k, bench/first_config.py) so
that parts run side by side and the small points train while the rest is collected; a part more is collected
when the planned ones hold too few successes. A point of n demonstrations trains on the first n successful
episodes in collection order (part, episode): the nested subsets of a user who records on until they have n
(the 25 are in the 50, ...). Each point is trained with --seeds training seeds (0, 1, ...) as

    factr2 train PART... --obs state --episodes THE_N --seed S        (+ the flags of --defaults NAME)

through the same code path (policies.training.run_config.from_args, run_training): `--defaults current` adds
no flag, so the step count, model and schedule are whatever `factr2 train` does at the commit each training
records (train.json `commit`, `command`, `steps`). Every policy is rolled out --rollouts episodes from
DATA_CURVE_EVAL_SEED: all points on the same initial conditions, which no demonstration and nothing else
used; a re-run with other defaults (`--defaults NAME`, or the same name at a later commit, in another OUT)
collects the same episodes and rolls out on the same seeds: before and after, paired.

    python -m bench.data_curve --out OUT --jobs 2              # the curve: 3 tasks, 10 points, 2 seeds x 24
    python -m bench.data_curve --quick --out OUT --jobs 1      # a few-minute smoke run (its numbers: nothing)
    python -m bench.data_curve --dev --defaults sized --tasks peg-insert,press-fit --points 50 --out DEV
                                                               # development seeds: choosing the defaults
    python -m bench.data_curve --out OUT --report --results data_curve_current   # + results/NAME.json
    python -m bench.data_curve --perturb --tasks peg-insert,press-fit --points 50 --out OUT_PERTURB
                                                               # collection that teaches recovery (DART)
    python -m bench.data_curve --out OUT_PERTURB --report --against OUT   # paired with the curve's points
                                           # (OUT: a folder, or a results file: data_curve_current)
    python -m bench.data_curve --out OUT --tasks peg-insert,press-fit --points 25,50,100,200 \
        --import-results data_curve_current    # a new OUT: the committed points are not trained again

--perturb [SPEC] collects every part with `factr2 collect --perturb SPEC` (teleop/perturb.py; empty: its
defaults) on the same collection seeds, and trains with `--perturbed dart`: the same initial conditions of
the demonstrations and of the rollouts as the unperturbed curve, so each point pairs with the curve's.

Resumable: every collection part, training run and rollout set leaves its JSON as it finishes and is skipped
when there (an interrupted training resumes from its last checkpoint); tasks, points and seeds may be added
to an OUT, the settings that shape a result may not (SAME_ON_RESUME). Across machines, only the repository
lasts: `--import-results NAME` seeds a new OUT with the finished points of results/NAME.json, checked against
the collection it collects again (bench/data_curve_ledger.py). Writes OUT/data_curve.json (a row per
task, n and training seed: success, progress, stages reached, steps, wall and CPU time; rewritten after every
point), OUT/data_curve.md and OUT/data_curve.png (bench/data_curve_report.py). Trainings run on the CPU
(--device auto: a GPU where there is one) with cores / jobs torch threads each. Sizing (docs/data_curve.md,
"The data curve"): 5.1-11.5 core-hours, ~2.6-5.8 h wall on 2 free cores, ~0.6-1 h on 16.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import shutil
import sys
import time
from dataclasses import asdict
from pathlib import Path

from bench import data_curve_ledger as ledger
from bench import harness
from bench.data_curve_config import (  # noqa: F401 (the pure parts, used by tests through this module)
    SAME_ON_RESUME,
    CurveConfig,
    check_demos_from,
    episode_ranges,
    parse_args,
    parts_for,
    successful_ids,
    train_argv,
)
from bench.data_curve_defaults import defaults_flags, defaults_meta
from bench.data_curve_queue import State, part_dir, part_paths
from bench.data_curve_report import (
    chart,
    finished_rows,
    paired_points,
    paired_table,
    point_dir,
    summarize,
    table,
    title,
    write_results,
)
from bench.first_config import DATA_CURVE_PARTS_MAX, check_resume
from bench.first_stages import _json, collect_run, rollout_run


# -- the three jobs (each a function of picklable arguments, run in a worker) --------------------------------
def collect_part(cfg: CurveConfig, task: str, k: int) -> dict:
    ck = Path(cfg.next_checkpoint)
    ck = ck if ck.is_absolute() else harness.ROOT / ck
    return collect_run(task, part_dir(cfg.out, task, k), cfg.part_episodes, cfg.demo_seed + k, str(ck),
                       perturb=perturb_config(cfg.perturb))


def perturb_config(perturb: dict | None):
    """CurveConfig.perturb (PerturbConfig.to_dict(), JSON-safe) as factr2 collect's PerturbConfig, or None."""
    if perturb is None:
        return None
    from factr2_teleop.teleop.perturb import PerturbConfig

    return PerturbConfig(**{**perturb, "joints": tuple(perturb.get("joints") or ())})


def train_point(cfg: CurveConfig, task: str, n: int, seed: int, folders: list[Path], ids: list[str]) -> dict:
    """One point's training run, as `factr2 train` with the named defaults; resumed when interrupted."""
    import torch

    from policies.training.advice import run_advice
    from policies.training.checkpoint import last_checkpoint, read_meta
    from policies.training.run import run_training
    from policies.training.run_config import add_arguments, from_args
    from policies.training.train import Dist

    run = point_dir(cfg.out, task, n, seed)
    done = run / "train.json"
    if done.is_file():
        return json.loads(done.read_text())
    argv = train_argv(cfg, folders, ids, seed, run)
    resume = last_checkpoint(run) is not None
    if not resume:  # stopped before its first checkpoint: start it again (factr2 train refuses a used --out)
        shutil.rmtree(run, ignore_errors=True)
    threads = cfg.threads or max(1, (os.cpu_count() or 1) // cfg.jobs)
    how = ["--threads", str(threads), "--no-progress"] + (["--resume"] if resume else [])  # not the result's
    ap = argparse.ArgumentParser(prog="factr2 train")
    add_arguments(ap)
    opts = from_args(ap.parse_args(argv + how))
    device = "cuda" if cfg.device == "auto" and torch.cuda.is_available() else "cpu"
    t, c = time.perf_counter(), time.process_time()
    run_training(opts, Dist(device=torch.device(device)))
    meta, kept = read_meta(last_checkpoint(run)), read_meta(run)  # the end, and what rollouts load (--keep)
    out = {"task": task, "n_demos": n, "seed": seed, "defaults": cfg.defaults,
           "command": "factr2 train " + shlex.join(argv), "commit": harness.commit(), "resumed": resume,
           "steps": meta["step"], "kept_step": kept["step"], "kept_val": kept.get("metrics", {}),
           "batch": meta["train"]["batch"], "epochs": meta["train"]["epochs"],
           "samples": meta["samples"], "episodes": len(meta["episodes"]), "val": meta.get("metrics", {}),
           "phases": meta.get("phases"), "phase_shares": meta.get("phase_shares"),  # FIRST's labels
           "advice": run_advice(run), "device": device, "torch_threads": torch.get_num_threads(),
           "wall_s": time.perf_counter() - t, "cpu_s": time.process_time() - c, "run": str(run)}
    _json(done, out)
    return out


def rollout_point(cfg: CurveConfig, task: str, n: int, seed: int) -> dict:
    return rollout_run(point_dir(cfg.out, task, n, seed), task, cfg.rollouts, cfg.eval_seed,
                       {"n_demos": n, "seed": seed})


def run_curve(cfg: CurveConfig, on_point=lambda: None) -> None:
    """Every job not yet done, cfg.jobs at a time; on_point() after every finished point."""
    import multiprocessing as mp
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    st, t0 = State(cfg), time.perf_counter()
    if st.imported:  # points imported for a queue at another commit are not trained beside here unasked
        ledger.check_imported(st.imported, harness.commit())
    fn = {"collect": collect_part, "train": train_point, "rollout": rollout_point}
    print(f"{len(st.rolled)} of {len(cfg.point_keys())} point(s) already finished; {cfg.jobs} worker(s)",
          flush=True)
    with ProcessPoolExecutor(cfg.jobs, mp_context=mp.get_context("spawn")) as ex:
        running: dict = {}
        while True:
            for _, kind, args in st.ready({(k, a[:3]) for k, a in running.values()}):
                if len(running) >= cfg.jobs:
                    break
                running[ex.submit(fn[kind], cfg, *args)] = (kind, args)
            if not running:
                break
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            for f in done:
                kind, args = running.pop(f)
                res = f.result()
                if kind == "collect":
                    st.parts[args[0]][args[1]] = res
                elif kind == "train":
                    st.trained[args[:3]] = res
                else:
                    st.rolled[args] = res
                    on_point()
                print(f"  {kind} {' '.join(map(str, args[:3]))}: done ({time.perf_counter() - t0:.0f} s)",
                      flush=True)
    missing = [k for k in cfg.point_keys() if k not in st.rolled]
    if missing:
        raise SystemExit(f"points not finished: {missing}")


def collection(cfg: CurveConfig) -> dict:
    """Per task: the parts collected, their episodes and successes, seeds, fingerprints and cost; stops
    when the points OUT imported were trained on another collection (data_curve_ledger.check_collection)."""
    out, imported, digest = {}, ledger.read_imported(cfg.out), ledger.next_digest(cfg)
    for t in cfg.tasks:
        paths = [part_paths(cfg, t, k) for k in range(DATA_CURVE_PARTS_MAX)]
        parts = [json.loads(p.read_text()) for _, p in paths if p.is_file()]
        res = [r for p in parts for r in p["results"]]
        gap = next((k for k, (_, p) in enumerate(paths) if not p.is_file()), len(paths))
        ledger.check_collection(t, imported, [(paths[k][0].name, parts[k]) for k in range(gap)], digest)
        out[t] = {"parts": len(parts), "episodes": len(res), "part_fingerprints":  # of parts 0 .. gap - 1
                  ledger.part_fingerprints(parts[:gap], digest),
                  "successes": sum(r.get("outcome") == "success" for r in res),
                  "episode_seeds": sorted(r["seed"] for r in res),
                  "collection_seeds": [p["seed"] for p in parts],
                  "wall_s": sum(p.get("wall_s", 0.0) for p in parts),
                  "cpu_s": sum(p.get("cpu_s", 0.0) for p in parts)}
    return out


def build_results(cfg: CurveConfig, command: str) -> dict:
    """data_curve.json: the rows, the pooled curve, the collection, the seeds and the machine."""
    rows = [r for r in finished_rows(cfg.out)
            if r["task"] in cfg.tasks and r["n_demos"] in cfg.points[r["task"]]]
    demos = collection(cfg)
    rolled = {t: {s for r in rows if r["task"] == t for s in r["episode_seeds"]} for t in demos}
    overlap = {t: sorted(set(d["episode_seeds"]) & rolled[t]) for t, d in demos.items()}
    if any(overlap.values()):  # never: the two seed ranges are apart (tests/test_data_curve.py)
        raise SystemExit(f"rollout seeds overlap demonstration seeds: {overlap}")
    return {"simulated": True, "observation": "state (PRIVILEGED twin object state, no images)",
            "command": command, "config": asdict(cfg), "defaults": cfg.defaults,
            "train_flags": {str(n): defaults_flags(cfg.defaults, n) + cfg.train_flags
                            for n in sorted({n for t in cfg.tasks for n in cfg.points[t]})},
            "seed_set": cfg.seed_set,
            "commits": sorted({r["commit"] for r in rows}), "commit": harness.commit(),
            "next_weights_sha256": ledger.next_digest(cfg), "imported": ledger.read_imported(cfg.out) or None,
            "seeds": {"collection_seeds": [cfg.demo_seed, cfg.demo_seed + DATA_CURVE_PARTS_MAX - 1],
                      "rollout_seed": cfg.eval_seed},
            "machine": harness.machine(), "collection": demos, "rows": rows,
            "summary": {t: {str(n): s for n, s in pts.items()} for t, pts in summarize(rows).items()}}


def write_outputs(cfg: CurveConfig, chart_too: bool = True, command: str = "", against: str = "") -> dict:
    """OUT/data_curve.json, .md and .png; against: another OUT or a results file (path or name), each point
    paired with its same point there, with the commits each side was made at."""
    out = Path(cfg.out)
    res = build_results(cfg, command or harness.command(module="bench.data_curve"))
    md = table(summarize(res["rows"]))
    if against:
        side = ledger.against_side(against)
        ledger.check_same_episodes(res["rows"], side["rows"], side["source"])
        paired = paired_points(res["rows"], side["rows"])
        res["against"] = {**{k: side[k] for k in ("source", "kind", "written_at")},
                          "across_commits": any(p["trained_at"][0] != p["trained_at"][1]
                                                for pts in paired.values() for p in pts.values()),
                          "paired": {t: {str(n): p for n, p in pts.items()} for t, pts in paired.items()}}
        md += "\n" + (paired_table(paired, "this OUT", side["source"]) if paired else f"No point of "
                      f"{side['source']} shares training seeds and rollout episodes with this OUT.\n")
    _json(out / "data_curve.json", res)
    summary = summarize(res["rows"])
    (out / "data_curve.md").write_text(md)
    if chart_too and summary:
        chart(summary, out / "data_curve.png", title(res["config"]))
    return res


def main(argv=None) -> int:
    cfg, a = parse_args(argv, __doc__.splitlines()[0])
    out = Path(cfg.out)
    if a.against:
        ledger.against_side(a.against)  # not a results folder nor file: one line, before anything runs
    if a.report:
        if not (out / "config.json").is_file():
            print(f"--out {out}: no config.json (not a data_curve results folder)", file=sys.stderr)
            return 2
        cfg = CurveConfig(**{**json.loads((out / "config.json").read_text()), "out": cfg.out})
    else:
        from hardware.sim.tasks import get_task

        for task in cfg.tasks:
            get_task(task)  # an unknown task: one line (ConfigError), before anything runs
        import signal

        signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
        cfg.defaults_meta = defaults_meta(cfg.defaults)
        check_resume(cfg, out, SAME_ON_RESUME)
        if cfg.demos_from:
            check_demos_from(cfg)
        if a.import_results:
            at = a.import_for_commit or None  # None: this tree's commit
            print("\n".join(ledger.import_points(cfg, a.import_results, a.any_commit, at)), flush=True)
        out.mkdir(parents=True, exist_ok=True)
        old = json.loads((out / "config.json").read_text()) if (out / "config.json").is_file() else {}
        # tasks and points added on resume are kept in the record of what OUT holds
        merged = asdict(cfg)
        merged["points"] = {**old.get("points", {}), **cfg.points}
        merged["tasks"] = list(dict.fromkeys(old.get("tasks", []) + cfg.tasks))
        merged["seeds"] = max(old.get("seeds", 0), cfg.seeds)
        _json(out / "config.json", merged)
        if a.import_for_commit:  # the queue runs in another checkout
            print(f"imported; run the same command without --import-results at {a.import_for_commit}")
            return 0
        t, whole = time.perf_counter(), CurveConfig(**merged)
        run_curve(cfg, on_point=lambda: write_outputs(whole, chart_too=False))  # data_curve.json: OUT's all
        print(f"wall {time.perf_counter() - t:.0f} s", flush=True)
        cfg = whole
    cmd = harness.command(module="bench.data_curve")
    res = write_outputs(cfg, command=cmd, against=a.against)
    print((out / "data_curve.md").read_text())
    if a.results:
        print(write_results(res, a.results, cmd, out))
        from bench import data_curve_advice

        if a.results == data_curve_advice.CURVE:  # the app cites this curve: its package copy follows
            data_curve_advice.main([])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
