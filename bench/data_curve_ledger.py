"""The data curve's finished points across machines (bench/data_curve.py, issue #56): a committed results
file (results/NAME.json, written by `--report --results NAME`) as the other side of `--against`, and as the
seed of a new OUT (`--import-results NAME`) whose queue then skips the points already finished.

A scratch OUT does not outlive its machine; the repository does. A results file holds a row per finished
point (task, n, training seed: every rollout episode's seed, outcome and progress; the training's commit and
`factr2 train` command) and, per task, the fingerprint of each collection part (`part_fingerprints`:
bench/first_ledger.py's demos_fingerprint, a hash of every episode's seed, outcome, progress, duration, start
and end and of the NEXT weights). Importing writes each point's train.json and rollout.json back into OUT
(rebuilt from its row, `imported_from` naming the file) when

- the settings that shape a point (SAME_ON_RESUME), the NEXT weights and the MuJoCo version are the same,
- and the point was trained at this tree's commit (a `-dirty` tree counts as its HEAD), or `--any-commit`.

The collection is not in the repository: the queue collects it again (deterministic from its seeds at one
commit, on one machine and software; not across them: docs/first.md). OUT/imported.json keeps what the
re-collection must match, checked as each part comes in: every part's fingerprint, and each imported point's
successful episodes (its recorded `--episodes`); a mismatch stops the run with the reason. A results file
written before part fingerprints were recorded (results/data_curve_current.json) has only the second: its
points come in at their own commit, with a warning, and are refused at any other (`--any-commit` too), since
nothing recorded could show that a later commit's collection is the one they were trained on.
"""

from __future__ import annotations

import json
import shlex
from dataclasses import asdict
from pathlib import Path

from bench import harness
from bench.data_curve_config import SAME_ON_RESUME, episode_ranges, successful_ids
from bench.data_curve_report import finished_rows, point_dir
from bench.first_ledger import demos_fingerprint, next_weights_digest
from bench.first_stages import _json

IMPORTED = "imported.json"  # in OUT: where its imported points came from and what the collection must match


def next_digest(cfg) -> str:
    """The sha256 of the weights of the NEXT checkpoint the run's demonstrations use."""
    ck = Path(cfg.next_checkpoint)
    return next_weights_digest(ck if ck.is_absolute() else harness.ROOT / ck)


def part_fingerprints(summaries: list[dict], digest: str) -> list[str]:
    """The fingerprint of each collection part (factr2 collect's summary), in part order."""
    return [demos_fingerprint(s, digest) for s in summaries]


def _label(p: Path) -> str:
    try:
        return str(p.resolve().relative_to(harness.ROOT))
    except ValueError:
        return str(p)


def read_results(spec: str, flag: str) -> dict:
    """A data-curve results file, by path or by name (results/NAME.json): its payload, `source` (the file)
    and `written_at` (the commit its record was written at). SystemExit in one line when it is none."""
    p = Path(spec) if Path(spec).is_file() else harness.RESULTS / f"{spec}.json"
    if not p.is_file():
        raise SystemExit(f"{flag} {spec}: no such file, nor {_label(p)}")
    try:
        rec = json.loads(p.read_text())
    except (OSError, ValueError) as e:
        raise SystemExit(f"{flag} {spec}: not readable as JSON ({e})") from None
    pay = rec.get("payload") if isinstance(rec, dict) else None
    if not isinstance(pay, dict) or not isinstance(pay.get("rows"), list) or "config" not in pay:
        raise SystemExit(f"{flag} {spec}: not a data curve results file (no payload rows and config)")
    return {**pay, "source": _label(p), "written_at": rec.get("commit", "")}


# -- --against: the other side ------------------------------------------------------------------------------
def against_side(spec: str) -> dict:
    """{source, kind, written_at, rows}: another OUT's finished points (a folder), or a results file's."""
    if Path(spec).is_dir():
        if not (Path(spec) / "config.json").is_file():
            raise SystemExit(f"--against {spec}: no config.json (not a data_curve results folder)")
        return {"source": str(spec), "kind": "out", "written_at": None, "rows": finished_rows(spec)}
    res = read_results(spec, "--against")
    return {"source": res["source"], "kind": "results", "written_at": res["written_at"], "rows": res["rows"]}


def _episodes(seeds: list) -> str:
    return f"{len(seeds)} episode(s), seeds {seeds[0]}-{seeds[-1]}" if seeds else "no episodes"


def check_same_episodes(rows: list[dict], other: list[dict], source: str) -> None:
    """Every point both sides hold was rolled out on the same episodes (the same rollout episode seeds, in
    order, as the rows record them); SystemExit naming the first that was not."""
    theirs = {(r["task"], r["n_demos"], r["seed"]): r["episode_seeds"] for r in other}
    for r in rows:
        key = (r["task"], r["n_demos"], r["seed"])
        if key in theirs and theirs[key] != r["episode_seeds"]:
            raise SystemExit(f"--against {source}: {key[0]} n={key[1]} seed {key[2]} was rolled out on "
                             f"other episodes ({_episodes(r['episode_seeds'])} here, "
                             f"{_episodes(theirs[key])} there): not paired")


# -- --import-results ---------------------------------------------------------------------------------------
def same_commit(a: str, b: str) -> bool:
    """The same HEAD (short hashes of either length; a '-dirty' tree counts as its HEAD)."""
    a, b = a.split("-")[0], b.split("-")[0]
    return bool(a and b) and (a.startswith(b) or b.startswith(a))


def selection(command: str) -> str:
    """The `--episodes` of a recorded `factr2 train` command: the successful episodes a point trained on."""
    argv = shlex.split(command or "")
    return argv[argv.index("--episodes") + 1] if "--episodes" in argv[:-1] else ""


def point_files(r: dict, run: Path, source: str) -> tuple[dict, dict]:
    """A results row as the train.json and rollout.json of its point (data_curve_report.row reads them back
    to the same row)."""
    key = {"task": r["task"], "n_demos": r["n_demos"], "seed": r["seed"], "imported_from": source}
    train = {**key, "defaults": r["defaults"], "command": r["command"], "commit": r["commit"],
             "steps": r["steps"], "batch": r["batch"], "epochs": r["epochs"], "samples": r["samples"],
             "val": {"val/loss": r["val_loss"]}, "advice": r["advice"], "wall_s": r["train_wall_s"],
             "cpu_s": r["train_cpu_s"], "run": str(run),
             **{k: r[k] for k in ("phases", "phase_shares") if k in r}}
    eps = [{"seed": sd, "outcome": "success" if ok else "failure", "progress": p}
           for sd, ok, p in zip(r["episode_seeds"], r["successes"], r["progress_episodes"])]
    roll = {**key, "success_rate": r["success"], "mean_progress": r["progress"],
            "stage_rates": r["stage_rates"], "episodes": eps, "wall_s": r["rollout_wall_s"],
            "cpu_s": r["rollout_cpu_s"]}
    return train, roll


def commit_check(points: list, fingerprinted: dict, here: str, any_commit: bool) -> tuple[str, list[str]]:
    """Whether points ([task, n, seed, commit]) may stand beside trainings made at commit `here`: ('' or why
    not, the notes to print). A point of another commit needs any_commit and its task's collection
    fingerprinted (fingerprinted: task -> bool); a '-dirty' tree is noted."""
    other = sorted({c for *_, c in points if not same_commit(c, here)})
    blind = sorted({f"{t} at {c}" for t, _, _, c in points
                    if not fingerprinted[t] and not same_commit(c, here)})
    if blind:
        return (f"points trained at another commit than {here} ({', '.join(blind)}) with no fingerprint of "
                "their collection recorded to check a re-collection against; run at the points' commit"), []
    if other and not any_commit:
        return f"points trained at {', '.join(other)}, this is {here}: --any-commit takes them", []
    notes = [f"note: this tree ({here}) differs from its HEAD in tracked files"] if "-dirty" in here else []
    if other:
        notes.append(f"note: points trained at {', '.join(other)}, trained here at {here} (--any-commit): "
                     "the curve spans commits (each row records its own)")
    return "", notes


def _refuse(spec: str, why: str) -> SystemExit:
    return SystemExit(f"--import-results {spec}: {why}; nothing imported")


def import_points(cfg, spec: str, any_commit: bool = False, here: str | None = None) -> list[str]:
    """Write the results file's points that this run plans (tasks, points, training seeds) and OUT lacks
    into OUT, and OUT/imported.json; returns the lines to print. here: the commit the queue trains at (this
    tree's by default). Checks everything before writing anything: SystemExit in one line naming what
    differs."""
    import mujoco

    res = read_results(spec, "--import-results")
    src, here = res["source"], harness.commit() if here is None else here
    old, new = res["config"], json.loads(json.dumps(asdict(cfg)))
    diff = [k for k in SAME_ON_RESUME if old.get(k) != new.get(k)]
    if diff:
        raise _refuse(spec, "made with other settings (" + ", ".join(
            f"{k}: {json.dumps(old.get(k))[:60]} there, {json.dumps(new.get(k))[:60]} here"
            for k in diff) + ")")
    if res.get("next_weights_sha256") != next_digest(cfg):
        raise _refuse(spec, f"collected with other NEXT weights ({res.get('next_weights_sha256')} there)")
    was = (res.get("machine") or {}).get("mujoco")
    if was != mujoco.__version__:
        raise _refuse(spec, f"collected under MuJoCo {was}, this is {mujoco.__version__}")
    plan = set(cfg.point_keys())
    rows = [r for r in res["rows"] if (r["task"], r["n_demos"], r["seed"]) in plan
            and not (point_dir(cfg.out, r["task"], r["n_demos"], r["seed"]) / "rollout.json").is_file()]
    fps = {t: (res.get("collection") or {}).get(t, {}).get("part_fingerprints") for t in cfg.tasks}
    points = [[r["task"], r["n_demos"], r["seed"], r["commit"]] for r in rows]
    why, notes = commit_check(points, {t: f is not None for t, f in fps.items()}, here, any_commit)
    if why:
        raise _refuse(spec, why)
    kept = Path(cfg.out) / IMPORTED
    rec = json.loads(kept.read_text()) if kept.is_file() else {"source": src, "points": [], "tasks": {}}
    if rec["source"] != src:
        raise _refuse(spec, f"{kept} holds points imported from {rec['source']}; use another --out")
    for r in rows:
        run = point_dir(cfg.out, r["task"], r["n_demos"], r["seed"])
        run.mkdir(parents=True, exist_ok=True)
        train, roll = point_files(r, run, src)
        _json(run / "train.json", train)
        _json(run / "rollout.json", roll)
        rec["points"].append([r["task"], r["n_demos"], r["seed"], r["commit"]])
        task = rec["tasks"].setdefault(r["task"], {"part_fingerprints": fps[r["task"]], "selections": {}})
        if selection(r["command"]):  # every row the curve writes records it
            task["selections"][str(r["n_demos"])] = selection(r["command"])
    if rows:  # any_commit: the queue (run_curve) takes them at another commit too
        _json(kept, {**rec, "written_at": res["written_at"], "any_commit": any_commit})
    lines = [f"imported {len(rows)} finished point(s) from {src} (written at {res['written_at']}): "
             + ", ".join(f"{r['task']} n={r['n_demos']} seed {r['seed']}" for r in rows)]
    lines += [f"WARNING {t}: {src} recorded no fingerprint of its collection (written before they were): the "
              "re-collection is checked only by each imported point's successful episodes, not by every "
              "episode's outcome, progress and duration" for t in sorted({r["task"] for r in rows})
              if fps[t] is None]
    return lines + (notes if rows else [])


def read_imported(out: str | Path) -> dict:
    """OUT/imported.json, or {} when OUT imported nothing."""
    p = Path(out) / IMPORTED
    return json.loads(p.read_text()) if p.is_file() else {}


def check_imported(imported: dict, here: str) -> None:
    """OUT's imported points may stand beside trainings at commit `here` (commit_check), or SystemExit: an
    OUT imported for another checkout's queue (--import-for-commit) is not run on by this one unasked."""
    tasks = imported.get("tasks") or {}
    fingerprinted = {t: e.get("part_fingerprints") is not None for t, e in tasks.items()}
    why, _ = commit_check(imported.get("points") or [], fingerprinted, here, bool(imported.get("any_commit")))
    if why:
        raise SystemExit(f"{IMPORTED} ({imported['source']}): {why}")


def check_collection(task: str, imported: dict, parts: list[tuple[str, dict]], digest: str) -> None:
    """The collection parts OUT holds (leading, [(recording file name, summary)]) against what the points
    imported for `task` were trained on: each part's fingerprint where recorded, and each point's successful
    episodes once its parts are in. SystemExit with the reason at the first mismatch."""
    exp = (imported.get("tasks") or {}).get(task)
    if not exp:
        return
    stop = (f"the points imported from {imported['source']} were trained on other demonstrations; start "
            "another OUT without --import-results")
    fps = exp.get("part_fingerprints") or []
    for k, ((name, summary), fp) in enumerate(zip(parts, fps)):
        if demos_fingerprint(summary, digest) != fp:
            raise SystemExit(f"{task} part {k:02d} ({name}): re-collected with fingerprint "
                             f"{demos_fingerprint(summary, digest)}, {fp} at export: {stop}")
    ids = successful_ids(parts)
    for n, text in sorted(exp.get("selections", {}).items(), key=lambda x: int(x[0])):
        if len(ids) >= int(n) and episode_ranges(ids[:int(n)]) != text:
            raise SystemExit(f"{task} n={n}: this collection's first {n} successful episodes are "
                             f"{episode_ranges(ids[:int(n)])}, the point trained on {text}: {stop}")
