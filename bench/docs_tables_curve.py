"""docs/data_curve.md's tables of the data curve's paired experiments at 50 demonstrations (SIMULATED,
PRIVILEGED state): perturbed collection (issue #56 item 4) and the relabelled peg-insert point, each
against the unperturbed baseline, rollout by rollout. Merged into bench.docs_tables.TABLES
through bench.docs_tables_pages."""

from __future__ import annotations

import numpy as np

from bench import harness


def _payload(name: str):
    return harness.payload(harness.load(harness.RESULTS / f"{name}.json"))


def _paired_diff(a: list[dict], b: list[dict], field: str = "progress_episodes"
                 ) -> tuple[float, float, float]:
    """Mean paired difference a - b of a per-episode field (progress_episodes, or successes as 0/1) over the
    episodes both rolled out (same task, point, training seed and episode seed), with its normal 95 %
    interval."""
    def per(rs):
        return {(r["task"], r["n_demos"], r["seed"], sd): float(v)
                for r in rs for sd, v in zip(r["episode_seeds"], r[field])}
    pa, pb = per(a), per(b)
    d = np.array([pa[k] - pb[k] for k in sorted(set(pa) & set(pb))])
    half = 1.96 * d.std(ddof=1) / np.sqrt(len(d)) if len(d) > 1 else float("nan")
    return float(d.mean()), float(d.mean() - half), float(d.mean() + half)


def _diffs(a: list[dict], b: list[dict]) -> str:
    (ms, ls, hs), (mp, lp, hp) = _paired_diff(a, b, "successes"), _paired_diff(a, b)
    return f"{100 * ms:+.0f} pts [{100 * ls:+.0f}, {100 * hs:+.0f}] / {mp:+.2f} [{lp:+.2f}, {hp:+.2f}]"


def _label_shares(rows: list[dict]) -> str:
    """FIRST's labelled free / pre-contact / contact shares [%] of a point's training (rows recorded before
    the results carried them: 'not in the results')."""
    sh = next((r["phase_shares"] for r in rows if r.get("phase_shares")), None)
    return " / ".join(f"{100 * sh[k]:.0f}" for k in ("free", "pre_contact", "contact")) if sh else \
        "not in the results"


def perturb50() -> str:
    """docs/data_curve.md: collection that teaches recovery (issue #56 item 4) at 50 demonstrations, the
    perturbed run against the unperturbed one at the same commit, episode by episode, per task and pooled."""
    from bench.data_curve_report import paired_points
    from bench.first_report import mcnemar_p, wilson

    pert, base = _payload("data_curve_perturb50"), _payload("data_curve_base50")
    head = ["| task | demonstrator success (collection) unperturbed / perturbed | policy success "
            "[95 % Wilson] unperturbed / perturbed | both / only perturbed / only unperturbed / neither | "
            "exact McNemar p | task progress unperturbed / perturbed | paired difference, perturbed - "
            "unperturbed [95 %]: success / progress | stages reached [%] unperturbed / perturbed | FIRST's "
            "labels F / PC / C [%] unperturbed; perturbed |", "|---|---|---|---|---|---|---|---|---|"]
    paired = paired_points(pert["rows"], base["rows"])
    tot = {"both": 0, "only_this": 0, "only_other": 0, "neither": 0}
    for task in sorted(paired):
        p = paired[task][50]
        for k in tot:
            tot[k] += p[k]
        demo = " / ".join(f"{c[task]['successes']} / {c[task]['episodes']} = "
                          f"{100 * c[task]['successes'] / c[task]['episodes']:.0f} %"
                          for c in (base["collection"], pert["collection"]))
        side = " / ".join(f"{k} / {m} = {100 * k / m:.0f} % [{100 * lo:.0f}, {100 * hi:.0f}]"
                          for k, m, lo, hi in (p["other"], p["this"]))
        rows = {name: [r for r in pl["rows"] if r["task"] == task and r["n_demos"] == 50]
                for name, pl in (("pert", pert), ("base", base))}
        prog = " / ".join(f"{pl['summary'][task]['50']['progress']:.2f}" for pl in (base, pert))
        stages = " / ".join(" ".join(f"{100 * v:.0f}" for v in pl["summary"][task]["50"]["stages"].values())
                            for pl in (base, pert))
        head.append(f"| {task} | {demo} | {side} | {p['both']} / {p['only_this']} / {p['only_other']} / "
                    f"{p['neither']} | {p['mcnemar_p']:.3f} | {prog} | "
                    f"{_diffs(rows['pert'], rows['base'])} | "
                    f"{stages} | {_label_shares(rows['base'])}; {_label_shares(rows['pert'])} |")
    m = sum(tot.values())
    kp, kb = tot["both"] + tot["only_this"], tot["both"] + tot["only_other"]
    side = " / ".join(f"{k} / {m} = {100 * k / m:.0f} % [{100 * lo:.0f}, {100 * hi:.0f}]"
                      for k, (lo, hi) in ((kb, wilson(kb, m)), (kp, wilson(kp, m))))
    head.append(f"| both tasks | - | {side} | {tot['both']} / {tot['only_this']} / {tot['only_other']} / "
                f"{tot['neither']} | {mcnemar_p(tot['only_this'], tot['only_other']):.3f} | - | "
                f"{_diffs(pert['rows'], base['rows'])} | - | - |")
    return "\n".join(head)


def relabel50() -> str:
    """docs/data_curve.md: the unperturbed peg-insert point at 50 trained again on the same demonstrations
    with sound FIRST labels (given thresholds), paired with the collapsed-label training on the same
    episodes."""
    from bench.data_curve_report import paired_points

    new, base = _payload("data_curve_relabel50"), _payload("data_curve_base50")
    out = ["| task | labels T_low : T_high [N*m] (F / PC / C [%]) collapsed / relabelled | success "
           "[95 % Wilson] collapsed / relabelled | both / only relabelled / only collapsed / neither | "
           "exact McNemar p | task progress | paired difference, relabelled - collapsed [95 %]: success / "
           "progress | stages reached [%] |", "|---|---|---|---|---|---|---|---|"]
    paired = paired_points(new["rows"], base["rows"])
    for task in sorted(paired):
        p = paired[task][50]
        rows = {k: [r for r in pl["rows"] if r["task"] == task and r["n_demos"] == 50]
                for k, pl in (("new", new), ("base", base))}
        labels = " / ".join(f"{r[0]['phases']['t_low']:.2f} : {r[0]['phases']['t_high']:.2f} "
                            f"({_label_shares(r)})" for r in (rows["base"], rows["new"]))
        side = " / ".join(f"{k} / {m} = {100 * k / m:.0f} % [{100 * lo:.0f}, {100 * hi:.0f}]"
                          for k, m, lo, hi in (p["other"], p["this"]))
        prog = " / ".join(f"{pl['summary'][task]['50']['progress']:.2f}" for pl in (base, new))
        stages = " / ".join(" ".join(f"{100 * v:.0f}" for v in pl["summary"][task]["50"]["stages"].values())
                            for pl in (base, new))
        out.append(f"| {task} | {labels} | {side} | {p['both']} / {p['only_this']} / {p['only_other']} / "
                   f"{p['neither']} | {p['mcnemar_p']:.3f} | {prog} | {_diffs(rows['new'], rows['base'])} | "
                   f"{stages} |")
    return "\n".join(out)


# page, name -> (results files it reads, renderer)
TABLES = {
    ("data_curve.md", "perturb50"): (("data_curve_perturb50", "data_curve_base50"), perturb50),
    ("data_curve.md", "relabel50"): (("data_curve_relabel50", "data_curve_base50"), relabel50),
}
