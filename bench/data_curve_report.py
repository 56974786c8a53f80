"""The data curve's report (bench/data_curve.py): one row per trained point (task, successful demonstrations,
training seed) read from OUT, pooled per point (success with its 95 % Wilson interval, task progress, stages
reached), the figure, and the published record results/NAME.json (bench/harness.py's shape, paths portable).
"""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

from bench import harness
from bench.first_curve import log_axis, save
from bench.first_report import mcnemar_p, pooled_stages, wilson
from bench.portable import portable, portable_text


def point_dir(out: str | Path, task: str, n: int, seed: int) -> Path:
    """Where one point's training run and its rollouts are: OUT/TASK/nNNN/seedS."""
    return Path(out) / task / f"n{n:03d}" / f"seed{seed}"


def _labels(train: dict) -> tuple[dict | None, dict | None]:
    """The training's phase thresholds and shares (free / pre-contact / contact of its training split): from
    train.json, or for one written before it recorded them, from the run's last checkpoint while it exists."""
    if train.get("phase_shares") is not None or not train.get("run"):
        return train.get("phases"), train.get("phase_shares")
    from policies.training.checkpoint import last_checkpoint

    last = last_checkpoint(Path(train["run"]))
    meta = json.loads(last.read_text()) if last is not None else {}
    return meta.get("phases"), meta.get("phase_shares")


def row(train: dict, roll: dict) -> dict:
    """One finished point (its train.json and rollout.json) as a row of data_curve.json: every episode's
    outcome and progress, so the curve can be re-pooled and re-plotted from the results alone."""
    eps = [e for e in roll.get("episodes") or [] if isinstance(e, dict)]
    phases, shares = _labels(train)
    labels = {k: v for k, v in (("phases", phases), ("phase_shares", shares)) if v is not None}
    return {"task": train["task"], "n_demos": int(train["n_demos"]), "seed": int(train["seed"]),
            "success": float(roll["success_rate"]), "progress": float(roll["mean_progress"]),
            "successes": [int(e.get("outcome") == "success") for e in eps],
            "progress_episodes": [float(e.get("progress", 0.0)) for e in eps],
            "episode_seeds": [e.get("seed") for e in eps], "stage_rates": roll.get("stage_rates") or {},
            "steps": train.get("steps"), "batch": train.get("batch"), "epochs": train.get("epochs"),
            "samples": train.get("samples"), "val_loss": (train.get("val") or {}).get("val/loss"),
            "advice": train.get("advice", []), "commit": train.get("commit", ""),
            "defaults": train.get("defaults"), "command": train.get("command"),
            "train_wall_s": train.get("wall_s"), "train_cpu_s": train.get("cpu_s"),
            "rollout_wall_s": roll.get("wall_s"), "rollout_cpu_s": roll.get("cpu_s"), **labels}


def finished_rows(out: str | Path) -> list[dict]:
    """The rows of every point of OUT whose training and rollouts are both done, in (task, n, seed) order."""
    rows = []
    for roll in Path(out).glob("*/n*/seed*/rollout.json"):
        train = roll.with_name("train.json")
        if train.is_file():
            rows.append(row(json.loads(train.read_text()), json.loads(roll.read_text())))
    return sorted(rows, key=lambda r: (r["task"], r["n_demos"], r["seed"]))


def summarize(rows: list[dict]) -> dict:
    """{task: {n: pooled over the training seeds}}: success k / n with its Wilson interval, per-seed success,
    mean task progress, the share of episodes reaching each stage, steps and the cost."""
    groups: dict = {}
    for r in rows:
        groups.setdefault(r["task"], {}).setdefault(r["n_demos"], []).append(r)
    out: dict = {}
    for task, points in groups.items():
        for n, rs in sorted(points.items()):
            k, m = sum(sum(r["successes"]) for r in rs), sum(len(r["successes"]) for r in rs)
            prog = [p for r in rs for p in r["progress_episodes"]]
            rolls = [{"episodes": r["successes"], "stage_rates": r["stage_rates"]} for r in rs]
            out.setdefault(task, {})[n] = {
                "seeds": [r["seed"] for r in rs], "k": k, "episodes": m, "success": k / m if m else None,
                "wilson": list(wilson(k, m)), "per_seed": [r["success"] for r in rs],
                "progress": sum(prog) / len(prog) if prog else None, "stages": pooled_stages(rolls),
                "steps": [r["steps"] for r in rs], "val_loss": [r["val_loss"] for r in rs],
                "train_cpu_s": sum(r["train_cpu_s"] or 0.0 for r in rs),
                "rollout_cpu_s": sum(r["rollout_cpu_s"] or 0.0 for r in rs)}
    return out


def paired_points(rows: list[dict], other: list[dict]) -> dict:
    """{task: {n: ...}}: each point of `rows` against the same point of `other` (another OUT, e.g. the
    unperturbed curve against a perturbed collection), episode by episode where both have the same training
    seed and rollout episode seed (the same initial conditions): both succeed, only this one, only the other,
    neither, the exact McNemar p, each side's pooled success with its Wilson interval over those pairs, and
    the commits each side's trainings were made at (trained_at: [this, other])."""
    def outcomes(rs: list[dict]) -> dict:
        return {(r["task"], r["n_demos"], r["seed"], sd): ok
                for r in rs for sd, ok in zip(r["episode_seeds"], r["successes"])}

    a, b = outcomes(rows), outcomes(other)
    commit = [{(r["task"], r["n_demos"], r["seed"]): r.get("commit", "") for r in rs} for rs in (rows, other)]
    name = {(1, 1): "both", (1, 0): "only_this", (0, 1): "only_other", (0, 0): "neither"}
    out: dict = {}
    for key in sorted(set(a) & set(b)):
        p = out.setdefault(key[0], {}).setdefault(key[1], {"both": 0, "only_this": 0, "only_other": 0,
                                                             "neither": 0, "seeds": set()})
        p["seeds"].add(key[2])
        p[name[(int(a[key]), int(b[key]))]] += 1
    for task, points in out.items():
        for n, p in points.items():
            p["trained_at"] = [sorted({c[(task, n, s)] for s in p["seeds"]}) for c in commit]  # this, other
            m = sum(p[k] for k in ("both", "only_this", "only_other", "neither"))
            ka, kb = p["both"] + p["only_this"], p["both"] + p["only_other"]
            p.update(seeds=sorted(p["seeds"]), pairs=m, this=[ka, m, *wilson(ka, m)],
                     other=[kb, m, *wilson(kb, m)], mcnemar_p=mcnemar_p(p["only_this"], p["only_other"]))
    return out


def paired_table(paired: dict, this: str, other: str) -> str:
    """paired_points as a markdown table: this OUT's point against the other's on the same episodes."""
    lines = [f"Paired on the same training seeds and rollout episodes: {this} against {other}.", "",
             f"| task | successful demonstrations | pairs | {this} [95 % Wilson] | {other} [95 % Wilson] | "
             "both / only this / only other / neither | exact McNemar p | trained at (this; other) |",
             "|---|---|---|---|---|---|---|---|"]
    for task, points in paired.items():
        for n, p in points.items():
            side = [f"{k} / {m} = {100 * k / m:.0f} % [{100 * lo:.0f}, {100 * hi:.0f}]"
                    for k, m, lo, hi in (p["this"], p["other"])]
            lines.append(f"| {task} | {n} | {p['pairs']} | {side[0]} | {side[1]} | {p['both']} / "
                         f"{p['only_this']} / {p['only_other']} / {p['neither']} | {p['mcnemar_p']:.3f} | "
                         f"{'; '.join(', '.join(c) or '?' for c in p['trained_at'])}"
                         f"{'' if p['trained_at'][0] == p['trained_at'][1] else ' (ACROSS COMMITS)'} |")
    return "\n".join(lines) + "\n"


def table(summary: dict) -> str:
    """The curve as a markdown table (the numbers the figure plots)."""
    lines = ["| task | successful demonstrations | success [95 % Wilson] | per seed [%] | task progress | "
             "stages reached [%] | steps |", "|---|---|---|---|---|---|---|"]
    for task, points in summary.items():
        for n, s in points.items():
            lo, hi = s["wilson"]
            stages = " / ".join(f"{100 * v:.0f}" for v in s["stages"].values())
            lines.append(f"| {task} | {n} | {s['k']} / {s['episodes']} = {100 * (s['success'] or 0):.0f} % "
                         f"[{100 * lo:.0f}, {100 * hi:.0f}] | "
                         f"{' / '.join(f'{100 * x:.0f}' for x in s['per_seed'])} | {s['progress']:.2f} | "
                         f"{stages} | {' / '.join(str(x) for x in s['steps'])} |")
    return "\n".join(lines) + "\n"


def chart(summary: dict, path: Path, title: str) -> None:
    """One panel per task: success [%] with 95 % Wilson intervals and task progress [%] against the
    successful demonstrations trained on (log x)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks = list(summary)
    fig, axes = plt.subplots(1, max(1, len(tasks)), figsize=(3.6 * max(1, len(tasks)), 3.4), squeeze=False)
    for ax, task in zip(axes[0], tasks):
        pts = summary[task]
        x = list(pts)
        m = [100 * (pts[n]["success"] or 0.0) for n in x]
        err = [[mi - 100 * pts[n]["wilson"][0] for mi, n in zip(m, x)],
               [100 * pts[n]["wilson"][1] - mi for mi, n in zip(m, x)]]
        ax.errorbar(x, m, yerr=err, fmt="o-", capsize=3, label="success (95 % Wilson)")
        ax.plot(x, [100 * (pts[n]["progress"] or 0.0) for n in x], "s--", label="task progress")
        ax.set_ylim(-3, 103)
        ax.set_title(task, fontsize=9)
        log_axis(ax, x, "successful demonstrations", "%")
    save(fig, path, textwrap.fill(title, 55 * len(axes[0])))  # a panel holds ~55 characters of it


def title(config: dict) -> str:
    dev = ", DEVELOPMENT seeds" if config.get("seed_set") == "dev" else ""
    dev += ", PERTURBED collection (--perturbed dart)" if config.get("perturb") is not None else ""
    return (f"data curve, defaults {config['defaults']}: {config['seeds']} training seed(s) x "
            f"{config['rollouts']} rollouts per point (SIMULATED twin, PRIVILEGED state{dev})")


def write_results(results: dict, name: str, cmd: str, out: Path, results_dir: Path = harness.RESULTS) -> Path:
    """results/NAME.json: the harness record of data_curve.json, OUT named (no machine folder in it)."""
    roots = {"OUT": Path(out).resolve()}
    rec = harness.record(name, portable(results, roots), simulated=True, cmd=portable_text(cmd, roots))
    return harness.write(Path(results_dir) / f"{name}.json", rec)

