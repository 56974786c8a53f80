"""The FIRST benchmark's report (bench/bench_first.py): per task and method, success and task progress over
the training seeds (mean and sample standard deviation), the validation loss per phase; a markdown table, a
bar chart, and the block of docs/first.md between the markers below."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np

from bench import harness
from bench.first_config import trained_score
from bench.portable import portable, portable_text

PHASES = ("F", "PC", "C")
DOCS_BEGIN = "<!-- bench_first:begin (written by bench/bench_first.py --write-docs) -->"
DOCS_END = "<!-- bench_first:end -->"
METHOD_ORDER = ("base", "base-torque", "first")
TABLE_ORDER = METHOD_ORDER + ("first-motion",)  # the table's rows: first on the motion labels when run
ABLATION_ORDER = ("C", "first", "PC+C")  # the `first` cell is PC (1:5:1)
ABLATION_LABEL = {"C": "C (1:1:5)", "first": "PC (1:5:1) = first", "PC+C": "PC+C (1:3:3)"}


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95 % Wilson score interval (lo, hi) of a success rate k / n; (0, 1) when n is 0."""
    if n <= 0:
        return 0.0, 1.0
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return float(max(0.0, c - h)), float(min(1.0, c + h))


def _mean_std(x: list[float]) -> tuple[float, float]:
    a = np.asarray([v for v in x if v is not None and np.isfinite(v)], float)
    if not a.size:
        return float("nan"), float("nan")
    return float(a.mean()), float(a.std(ddof=1)) if a.size > 1 else 0.0


def pooled_stages(rolls: list[dict]) -> dict[str, float]:
    """Share of all episodes of these rollout sets that reached each stage, in the task's stage order (each
    set's stage_rates weighted by its episodes): where the failing episodes stop."""
    n_all, reached = 0, {}
    for r in rolls:
        n = len(r.get("episodes") or [])
        n_all += n
        for stage, rate in (r.get("stage_rates") or {}).items():
            reached[stage] = reached.get(stage, 0.0) + float(rate) * n
    return {k: v / n_all for k, v in reached.items()} if n_all else {}


def aggregate(trains: list[dict], rolls: list[dict]) -> dict:
    """{task: {cell: {success / progress mean and sd over seeds, val loss per phase (mean), ...}}}"""
    out: dict = {}
    for tr in trains:
        out.setdefault(tr["task"], {}).setdefault(tr["cell"], {"train": [], "roll": []})["train"].append(tr)
    for r in rolls:
        out.setdefault(r["task"], {}).setdefault(r["cell"], {"train": [], "roll": []})["roll"].append(r)
    summary: dict = {}
    for task, cells in out.items():
        for cell, d in cells.items():
            s: dict = {"seeds": len(d["roll"]), "ratio": d["train"][0]["ratio"] if d["train"] else None,
                       "method": d["train"][0]["method"] if d["train"] else cell}
            s["success_mean"], s["success_std"] = _mean_std([r["success_rate"] for r in d["roll"]])
            s["progress_mean"], s["progress_std"] = _mean_std([r["mean_progress"] for r in d["roll"]])
            s["rollouts_per_seed"] = [len(r.get("episodes") or []) for r in d["roll"]]
            succ = [_outcomes(r) for r in sorted(d["roll"], key=lambda r: r["seed"])]
            s["per_seed"] = [float(np.mean(x)) if x else float("nan") for x in succ]
            s["k"], s["n"] = int(sum(map(sum, succ))), int(sum(map(len, succ)))
            s["wilson"] = wilson(s["k"], s["n"])
            s["stages"] = pooled_stages(d["roll"])
            for p in ("",) + tuple(f"_{x}" for x in PHASES):
                s[f"val_loss{p}"], s[f"val_loss{p}_std"] = _mean_std(
                    [t["val"].get(f"val/loss{p}") for t in d["train"]])
            summary.setdefault(task, {})[cell] = s
    return summary


def _outcomes(roll: dict) -> list[int]:
    """1 / 0 per rollout episode, in episode order (the same initial conditions for every policy)."""
    return [int(e.get("outcome") == "success") for e in roll.get("episodes") or [] if isinstance(e, dict)]


def raw_results(results: dict) -> dict:
    """The payload of results/first_headline.json: {task: {method: {"seeds": [{"seed", "success": [0/1],
    "progress": [...]}]}}, "config": {...}}: every rollout, so anyone can re-plot or re-test."""
    out: dict = {}
    for r in sorted(results["rollout"], key=lambda r: (r["task"], r["cell"], r["seed"])):
        eps = [e for e in r.get("episodes") or [] if isinstance(e, dict)]
        out.setdefault(r["task"], {}).setdefault(r["cell"], {"seeds": []})["seeds"].append(
            {"seed": r["seed"], "success": _outcomes(r),
             "progress": [float(e.get("progress", 0.0)) for e in eps],
             "episode_seeds": [e.get("seed") for e in eps], "stage_rates": r.get("stage_rates")})
    out["config"] = portable({"command": results.get("command"), "observation": results["observation"],
                              "machine": results["machine"], "bench": results["config"], "simulated": True,
                              "timing": results["timing"]}, _roots(results))  # no machine folder in it
    return out


def _roots(results: dict) -> dict:
    """The folders a bench_first run names: its OUT (bench/portable.py)."""
    out = (results.get("config") or {}).get("out")
    return {"OUT": Path(out).resolve()} if out else {}


def fisher_less(k1: int, n1: int, k2: int, n2: int) -> float:
    """One-sided Fisher exact p that k1 / n1 is below k2 / n2 by chance: P(X <= k1), X hypergeometric
    (k1 + k2 successes drawn into n1 of n1 + n2)."""
    from math import comb

    k, n = k1 + k2, n1 + n2
    return float(sum(comb(k, i) * comb(n - k, n1 - i) for i in range(0, k1 + 1)) / comb(n, n1))


def mcnemar_p(b: int, c: int) -> float:
    """Exact two-sided McNemar p-value for b vs c discordant pairs (binomial, p = 1/2)."""
    from math import comb

    n = b + c
    if n == 0:
        return 1.0
    k = min(b, c)
    return float(min(1.0, 2 * sum(comb(n, i) for i in range(k + 1)) / 2 ** n))


def paired(results: dict, task: str, a: str = "first", b: str = "base-torque") -> dict | None:
    """a against b on one task, paired by training seed (same seed: same demonstrations, sampler seed and
    initial weights) and by rollout episode (every policy starts from the same initial conditions)."""
    ra = {r["seed"]: r for r in results["rollout"] if r["task"] == task and r["cell"] == a}
    rb = {r["seed"]: r for r in results["rollout"] if r["task"] == task and r["cell"] == b}
    seeds = sorted(set(ra) & set(rb))
    if not seeds:
        return None
    diffs, only_a, only_b, both, neither = [], 0, 0, 0, 0
    for sd in seeds:
        xa, xb = _outcomes(ra[sd]), _outcomes(rb[sd])
        n = min(len(xa), len(xb))
        diffs.append(float(np.mean(xa[:n]) - np.mean(xb[:n])) if n else float("nan"))
        for u, v in zip(xa[:n], xb[:n]):
            only_a += u and not v
            only_b += v and not u
            both += u and v
            neither += not u and not v
    return {"seeds": seeds, "diff_per_seed": diffs, "diff_mean": float(np.nanmean(diffs)),
            "only_a": int(only_a), "only_b": int(only_b), "both": int(both), "neither": int(neither),
            "mcnemar_p": mcnemar_p(int(only_a), int(only_b))}


def _pct(m: float, s: float) -> str:
    return "n/a" if not np.isfinite(m) else f"{100 * m:.0f} ± {100 * s:.0f} %"


def _prog(m: float, s: float) -> str:
    return "n/a" if not np.isfinite(m) else f"{m:.2f} ± {s:.2f}"


def _val(s: dict) -> str:
    return " / ".join("n/a" if not np.isfinite(s[f"val_loss_{p}"]) else f"{s[f'val_loss_{p}']:.3f}"
                      for p in PHASES)


def _row(label: str, s: dict) -> str:
    ratio = ":".join(f"{x:g}" for x in s["ratio"]) if s["ratio"] else "?"
    lo, hi = s.get("wilson", (np.nan, np.nan))
    per_seed = " / ".join("n/a" if not np.isfinite(x) else f"{100 * x:.0f}" for x in s.get("per_seed", []))
    pooled = ("n/a" if not s.get("n")
              else f"**{100 * s['k'] / s['n']:.0f} %** [{100 * lo:.0f}, {100 * hi:.0f}]")
    stages = " / ".join(f"{k} {100 * v:.0f}" for k, v in (s.get("stages") or {}).items()) or "n/a"
    return (f"| {label} | {ratio} | {pooled} | {per_seed} | "
            f"{_prog(s['progress_mean'], s['progress_std'])} | {stages} | {_val(s)} | {s['seeds']} x "
            f"{max(s['rollouts_per_seed'] or [0])} |")


HEADER = ("| method | w_F:w_PC:w_C | success, pooled [95 % Wilson] | per seed [%] | task progress (mean ± sd "
          "over seeds) | stages reached [% of episodes] | val loss F / PC / C | seeds x rollouts |\n"
          "|---|---|---|---|---|---|---|---|")


def _paired_line(p: dict | None) -> str:
    if p is None:
        return ""
    d = " / ".join(f"{100 * x:+.0f}" for x in p["diff_per_seed"])
    return (f"Paired, first against base-torque: per training seed {d} points "
            f"(mean {100 * p['diff_mean']:+.1f}); "
            f"per initial condition (the same {p['both'] + p['neither'] + p['only_a'] + p['only_b']} "
            f"episodes): both succeed {p['both']}, only first {p['only_a']}, only base-torque {p['only_b']}, "
            f"neither {p['neither']}; exact McNemar p = {p['mcnemar_p']:.3f}.")


def _ranges(seeds: dict) -> str:
    def r(x):
        return f"{x[0]}-{x[1]}" if x else "?"

    return "; ".join(f"{t} demonstrations {r(s['demo_seeds'])}, rollouts {r(s['rollout_seeds'])}"
                     for t, s in seeds.items())


def _labels(results: dict, task: str) -> tuple[float, float, dict]:
    """The thresholds [N*m] and phase shares the training runs used (their meta), else the collection's."""
    for r in results.get("train", []):  # N*m: the default score's (first-motion's are multiples of its noise)
        if (r.get("task") == task and r.get("phase_shares") and "t_low" in (r.get("phases") or {})
                and trained_score(r) == "l1"):
            return r["phases"]["t_low"], r["phases"]["t_high"], r["phase_shares"]
    d = results["demos"].get(task, {})
    lo, hi = d.get("phase_thresholds_nm") or (np.nan, np.nan)
    return lo, hi, d.get("phase_shares") or {}


def table(results: dict) -> str:
    cfg, summ, tm = results["config"], results["summary"], results["timing"]
    smoke = ("**Smoke run (`--quick`): far too small to compare the methods; it shows that the pipeline "
             "runs end to end.** " if cfg.get("quick") else "")
    lines = [f"{smoke}SIMULATED (MuJoCo twin `sim-piper`), observation: {results['observation']}; "
             f"{cfg['policy']} policy, {cfg.get('preset') or 'default'} preset, {cfg['steps']} steps x batch "
             f"{cfg['batch']}, EMA weights; "
             f"{'the given' if cfg.get('demos_from') else cfg['demos']} demonstrations per task, "
             f"{cfg['rollouts']} rollouts per policy on other "
             f"initial conditions (episode seeds: {_ranges(results['seeds'])}).", ""]
    for task in cfg["tasks"]:
        cells = summ.get(task, {})
        d = results["demos"].get(task, {})
        lo, hi, sh = _labels(results, task)
        shares = " / ".join(f"{100 * sh.get(k, np.nan):.0f}" for k in ("free", "pre_contact", "contact"))
        # folder names only: a published table names no machine's paths
        given = f" from {', '.join(Path(f).name for f in d['folders'])}" if d.get("folders") else ""
        lines += [f"**{task}** (demonstrations: {d.get('episodes', '?')} episodes{given}, scripted success "
                  f"{100 * d.get('success_rate', np.nan):.0f} %; FIRST labels at {lo:.2f} / {hi:.2f} N*m: "
                  f"free / pre-contact / contact {shares} % of the training samples)", "", HEADER]
        lines += [_row(m, cells[m]) for m in TABLE_ORDER if m in cells]
        lines += ["", _paired_line(paired(results, task)), ""]
        if "C" in cells:
            lines += [f"**{task}, ablation** (the re-sampling ratio, method `first`)", "", HEADER]
            lines += [_row(ABLATION_LABEL[m], cells[m]) for m in ABLATION_ORDER if m in cells]
            lines.append("")
    m = results["machine"]
    stages = [f"{k[:-7]} {v / 60:.1f}" for k, v in tm.items()
              if k.endswith("_wall_s") and k != "total_wall_s"]
    lines.append(f"Wall time {tm['total_wall_s'] / 60:.1f} min ({', '.join(stages)}) on "
                 f"{m['cpus']} CPUs, {cfg['jobs']} job(s), load average at the end {m['loadavg_end'][0]:.1f} "
                 f"({m['platform']}); CPU time of the jobs: collection {tm['collect_cpu_s'] / 60:.1f}, "
                 f"training {tm['train_cpu_s'] / 60:.1f}, rollouts {tm['rollout_cpu_s'] / 60:.1f} core-min.")
    return "\n".join(lines) + "\n"


def chart(results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cfg, summ = results["config"], results["summary"]
    tasks = [t for t in cfg["tasks"] if t in summ]
    abl = next((t for t in tasks if "C" in summ[t]), None)
    n = 2 + (abl is not None)
    fig, axes = plt.subplots(1, n, figsize=(4.2 * n, 3.4), squeeze=False)
    width = 0.8 / len(METHOD_ORDER)
    panels = ((axes[0, 0], "success", "success rate (pooled, 95 % Wilson)"),
              (axes[0, 1], "progress", "task progress (mean ± sd over seeds)"))
    for ax, key, title in panels:
        for k, m in enumerate(METHOD_ORDER):
            if key == "success":  # pooled over seeds, 95 % Wilson interval
                cells = [summ[t].get(m, {}) for t in tasks]
                mean = [c["k"] / c["n"] if c.get("n") else np.nan for c in cells]
                wl = [c.get("wilson", (np.nan, np.nan)) for c in cells]
                err = np.abs(np.array([[mu - w[0] for mu, w in zip(mean, wl)],
                                       [w[1] - mu for mu, w in zip(mean, wl)]]))
            else:
                mean = [summ[t].get(m, {}).get(f"{key}_mean", np.nan) for t in tasks]
                err = [summ[t].get(m, {}).get(f"{key}_std", np.nan) for t in tasks]
            ax.bar(np.arange(len(tasks)) + (k - 1) * width, mean, width, yerr=err, capsize=3, label=m)
        ax.set_xticks(np.arange(len(tasks)), tasks)
        ax.set_ylim(0, 1.05)
        ax.set_title(title)
    axes[0, 0].legend(fontsize=8)
    if abl is not None:
        ax = axes[0, 2]
        cells = [c for c in ABLATION_ORDER if c in summ[abl]]
        x = np.arange(len(cells))
        for k, key in enumerate(("success", "progress")):
            ax.bar(x + (k - 0.5) * 0.38, [summ[abl][c][f"{key}_mean"] for c in cells], 0.38,
                   yerr=[summ[abl][c][f"{key}_std"] for c in cells], capsize=3, label=key)
        ax.set_xticks(x, [ABLATION_LABEL[c].split(" =")[0] for c in cells], fontsize=8)
        ax.set_ylim(0, 1.05)
        ax.set_title(f"ablation ({abl})")
        ax.legend(fontsize=8)
    fig.suptitle(f"FIRST on the twin's tasks (SIMULATED, obs: {cfg['obs']}; {cfg['seeds']} training seed(s))",
                 fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_report(results: dict, out: Path) -> None:
    (out / "table.md").write_text(table(results))
    (out / "first_results.json").write_text(json.dumps(raw_results(results), indent=1, default=float))
    chart(results, out / "first_bench.png")


def write_docs(results: dict, out: Path, docs: Path) -> None:
    """Replace docs/first.md's block between DOCS_BEGIN and DOCS_END with OUT's table; copy the chart, and
    the raw per-rollout results as results/first_headline.json (a bench/harness.py record)."""
    page = docs / "first.md"
    text = page.read_text()
    if DOCS_BEGIN not in text or DOCS_END not in text:
        raise SystemExit(f"{page}: the markers {DOCS_BEGIN!r} ... {DOCS_END!r} are missing")
    head, rest = text.split(DOCS_BEGIN, 1)
    _, tail = rest.split(DOCS_END, 1)
    block = f"{DOCS_BEGIN}\n{table(results)}\n![FIRST benchmark](first_bench.png)\n{DOCS_END}"
    page.write_text(head + block + tail)
    shutil.copyfile(out / "first_bench.png", docs / "first_bench.png")
    raw = json.loads((out / "first_results.json").read_text())
    harness.write(docs.parent / "results" / "first_headline.json",
                  harness.record("first_headline", raw, simulated=True,
                                 cmd=portable_text(results.get("command") or "", _roots(results)) or None))
