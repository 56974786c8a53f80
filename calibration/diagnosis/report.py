"""report.json + report.md + evidence plots (matplotlib Agg PNGs) for a Diagnosis."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .greybox import errors
from .loop import Diagnosis
from .trace import trace_feature


def _mean_l1(x) -> float:
    return float(np.mean(x))


def to_json(dg: Diagnosis, meta: dict) -> dict:
    meta = dict(meta)
    physical = _physical(dg, meta.pop("payload_scale", None))
    n = dg.model.n
    names = list(meta.get("joint_names") or [f"joint{j}" for j in range(n)])
    l1_after, rms_after = errors(dg.heldout.y, dg.model.predict(dg.heldout))
    first = dg.steps[0]
    steps = [{"added": s.added, "heldout_l1": s.heldout_l1, "heldout_rms": s.heldout_rms,
              "heldout_l1_mean": _mean_l1(s.heldout_l1), "train_l1": s.train_l1} for s in dg.steps]
    effects = [e.to_json() for e in dg.model.effects]
    found = dg.found() if hasattr(dg, "found") else dg.model.effects
    if not found:
        verdict = ("the model explains the data: no candidate effect lowers held-out error by more than "
                   f"{100 * dg.config.rel_gain:.0f} % (and the absolute floor) on any joint")
    else:
        verdict = (f"added {len(found)} effect(s); mean held-out L1 {_mean_l1(first.heldout_l1):.4g} -> "
                   f"{_mean_l1(l1_after):.4g} {meta.get('units', '')}")
    return {
        **meta, "joints": names, "headline": headline(dg, names, meta), "verdict": verdict,
        "found_in_words": [e.describe(meta.get("units", "N*m"), names) for e in found],
        "evidence_of_something_else": [r for r in dg.rejected if "evidence_of" in r][-10:],
        "config": {"rel_gain": dg.config.rel_gain, "abs_gain_of_target_rms": dg.config.abs_gain,
                   "tries_per_step": dg.config.tries, "max_effects": dg.config.max_effects},
        "samples": {"train": len(dg.train), "heldout": len(dg.heldout)},
        "steps": steps, "pruned": dg.pruned, "effects": effects,
        "declared": [e.to_json() for e in getattr(dg, "declared", [])],
        "rejected_last": dg.rejected[-20:],
        "before": {"heldout_l1": first.heldout_l1, "heldout_rms": first.heldout_rms,
                   "heldout_l1_mean": _mean_l1(first.heldout_l1)},
        "after": {"heldout_l1": l1_after.tolist(), "heldout_rms": rms_after.tolist(),
                  "heldout_l1_mean": _mean_l1(l1_after)},
        **_rigid(dg.model), **physical,
    }


def _physical(dg: Diagnosis, scale) -> dict:
    """`payload`: the found payload with its reference, mass and centre of mass and their bootstrap interval
    (payload.py); `springs`: each found spring's stiffness checked against a free rigid part (springs.py).
    scale: the payload columns' payload.CurrentScale (None: N*m logs, or no arm description)."""
    from .payload import CurrentScale, bootstrap, summary
    from .springs import spring_checks

    out: dict = {}
    k = next((i for i, e in enumerate(dg.model.effects) if e.family == "payload"), None)
    if k is not None:
        scale = scale if scale is not None else CurrentScale(None, "torque")
        dg.model.effects[k].in_kg = scale.in_kg
        out["payload"] = summary(dg.model.effects[k].coef, bootstrap(dg.model, dg.train, k), scale)
    springs = spring_checks(dg)
    if springs:
        out["springs"] = springs
    return out


def _rigid(model) -> dict:
    """The identified base parameters of an arm description's regressor (basis.reference_prior reads them
    back: `factr2 diagnose --declared` of this report pulls toward this arm, not the description)."""
    cols = getattr(model.basis, "cols", None)
    if cols is None:
        return {}
    return {"rigid_parameters": {"columns": [int(c) for c in cols], "theta": model.theta.tolist(),
                                 "prior_weight": float(model.basis.ridge)}}


def headline(dg: Diagnosis, names: list, meta: dict) -> str:
    """One sentence: the first effect found, in words, and how much of the held-out residual it explains
    (its joint's held-out L1 before -> after adding it; arm-wide effects: summed over joints)."""
    u = meta.get("units", "")
    of = ("the prior's" if meta.get("prior_only") else "NEXT's" if meta.get("next_checkpoint")
          else "the model's")
    found = dg.found() if hasattr(dg, "found") else dg.model.effects
    def key(family, joint, hyper):
        return family, joint, tuple(sorted(hyper.items()))

    kept = {key(e.family, e.joint, e.hyper): e for e in found}
    # the first step whose effect the final model still holds (an early find can be pruned later)
    k = next((k for k, s in enumerate(dg.steps) if k and s.added is not None
              and key(s.added["effect"], s.added["joint"], s.added["hyper"]) in kept), None)
    step = None if k is None else dg.steps[k].added
    if step is None:
        return f"Nothing missing: no effect explains {of} held-out residual beyond the acceptance threshold"
    first = kept[key(step["effect"], step["joint"], step["hyper"])]
    ev = step["evidence"]
    b, a = ev["heldout_l1_joint_before"], ev["heldout_l1_joint_after"]
    where = "summed over joints" if first.wide else f"of {names[first.joint]}"
    more = f"; {len(found) - 1} more effect(s) below" if len(found) > 1 else ""
    # the loop ranks on the held-out mean square it removes (summed over joints; L1 of a sum is not a sum)
    ms = float(np.sum(np.square(dg.steps[k - 1].heldout_rms)))
    sq = (f"; {100 * ev['heldout_explained_units'] ** 2 / ms:.0f} % of the arm's held-out mean square"
          if "heldout_explained_units" in ev and ms > 0 else "")
    return (f"{first.describe(u, names)[0].upper()}{first.describe(u, names)[1:]} explains "
            f"{100 * (b - a) / max(b, 1e-12):.0f} % of {of} held-out residual {where} "
            f"(L1 {b:.3g} -> {a:.3g} {u}{sq}){more}")


def _binned(x, y, bins=50):
    edges = np.quantile(x, np.linspace(0, 1, bins + 1))
    edges = np.unique(edges)
    k = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)
    cnt = np.bincount(k, minlength=len(edges) - 1)
    keep = cnt > 0
    mx = np.bincount(k, weights=x, minlength=len(cnt))[keep] / cnt[keep]
    my = np.bincount(k, weights=y, minlength=len(cnt))[keep] / cnt[keep]
    return mx, my


def plot_step(dg: Diagnosis, k: int, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    step, prev = dg.steps[k], dg.steps[k - 1]
    e = next(x for x in step.model.effects if x.key[:2] == (step.added["effect"], step.added["joint"]))
    d = dg.heldout
    if e.wide:  # shown on the joint where it acts most
        per_joint = np.einsum("tjk,k->tj", d.features(e), e.coef)
        j = int(np.argmax(per_joint.std(0)))
        contrib = per_joint[:, j]
        label, x = f"fitted {e.family} torque on joint {j} [{dg.train.segments[0].units}]", contrib
    else:
        j = e.joint
        label, x = trace_feature(e, d)
        contrib = d.features(e) @ e.coef
    before = d.y[:, j] - prev.model.predict(d)[:, j]
    after = d.y[:, j] - step.model.predict(d)[:, j]
    if e.family == "position_periodic":
        period = e.hyper["period_rad"]
        x, label = np.mod(d.q[:, j], period) / period, f"phase of q[{j}] modulo {period:.4g} rad"
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.6), sharey=True)
    rng = np.random.default_rng(0)
    sub = rng.choice(len(x), min(len(x), 4000), replace=False)
    for a, r, title in ((ax[0], before, "before"), (ax[1], after, "after")):
        a.scatter(x[sub], r[sub], s=2, alpha=0.25, color="0.5", label="held-out residual")
        a.plot(*_binned(x, r), color="C0", lw=2, label="binned mean")
        if title == "before":
            a.plot(*_binned(x, contrib), color="C3", lw=1.5, ls="--", label=f"fitted {e.family}")
        a.axhline(0, color="k", lw=0.5)
        a.set_xlabel(label)
        a.set_title(f"joint {j} {title}: L1 {np.mean(np.abs(r)):.4g}")
    ax[0].set_ylabel(f"residual [{dg.train.segments[0].units}]")
    ax[0].legend(fontsize=7, loc="best")
    fig.suptitle(f"step {k}: {e.family} on joint {j}", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_summary(report: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    l1 = np.array([s["heldout_l1"] for s in report["steps"]])
    fig, ax = plt.subplots(figsize=(7, 3.5))
    for j in range(l1.shape[1]):
        ax.plot(l1[:, j], marker="o", label=report["joints"][j])
    ax.set_xlabel("step (0 = rigid part only)")
    ax.set_ylabel(f"held-out L1 [{report.get('units', '')}]")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _fmt(v) -> str:
    return ", ".join(f"{k}={x:.4g}" if isinstance(x, float) else f"{k}={x}" for k, x in v.items())


def write(dg: Diagnosis, out: Path, meta: dict, plots: bool = True) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    rep = to_json(dg, meta)
    (out / "report.json").write_text(json.dumps(rep, indent=1, default=float))
    u = rep.get("units", "")
    lines = [f"# {rep['headline']}", "", f"Diagnosis: {meta.get('title', 'grey-box model')}. "
             f"Data: {meta.get('data_source', '')}", "",
             f"Arm: {meta.get('arm') or 'none (data-only basis)'}"
             + (f" ({meta['arm_source']})" if meta.get("arm_source") else ""), "",
             f"Training runs: {', '.join(meta.get('train_runs', []))}; held-out: "
             f"{', '.join(meta.get('heldout_runs', []))} ({rep['samples']['train']} / "
             f"{rep['samples']['heldout']} samples). Rigid part: {meta.get('basis', '')}. Units: {u}.", "",
             f"**Verdict:** {rep['verdict']}.", "",
             "| joint | held-out L1 before | after | held-out RMS before | after |", "|---|---|---|---|---|"]
    for j, name in enumerate(rep["joints"]):
        b, a = rep["before"], rep["after"]
        lines.append(f"| {name} | {b['heldout_l1'][j]:.4g} | {a['heldout_l1'][j]:.4g} | "
                     f"{b['heldout_rms'][j]:.4g} | {a['heldout_rms'][j]:.4g} |")
    lines.append(f"| mean | {rep['before']['heldout_l1_mean']:.4g} | "
                 f"{rep['after']['heldout_l1_mean']:.4g} | | |")
    lines += ["", "## Steps", ""]
    if plots:
        plot_summary(rep, out / "heldout_l1.png")
        lines += ["![held-out L1 per step](heldout_l1.png)", ""]
    for k, s in enumerate(rep["steps"]):
        if s["added"] is None:
            lines.append(f"0. rigid part only: mean held-out L1 {s['heldout_l1_mean']:.4g} {u}")
            continue
        a = s["added"]
        ev = a["evidence"]
        on = ("all joints (at the last link)" if a["effect"] == "payload"
              else f"joint {a['joint']} ({rep['joints'][a['joint']]})")
        lines.append(f"{k}. **{a['effect']}** on {on}: "
                     f"{_fmt(a['params'])}. Evidence: explains "
                     f"{100 * ev['explains_train_residual']:.1f} % of the joint's training residual; "
                     f"held-out L1 of the joint {ev['heldout_l1_joint_before']:.4g} -> "
                     f"{ev['heldout_l1_joint_after']:.4g}"
                     + (f"; periodogram peak/median {ev['periodogram_peak_over_median']}"
                        if "periodogram_peak_over_median" in ev else "") + ".")
        if plots:
            name = f"step{k:02d}_{a['effect']}_j{a['joint']}.png"
            plot_step(dg, k, out / name)
            lines += ["", f"   ![step {k}]({name})", ""]
    if rep["pruned"]:
        lines += ["", "Pruned afterwards (removing them did not raise held-out error beyond the threshold): "
                  + "; ".join(f"{p['effect']} on joint {p['joint']}" for p in rep["pruned"]) + "."]
    lines += ["", "## Final effects", ""]
    finals = [f"- {e['effect']} on joint {e['joint']}: {_fmt(e['params'])}" for e in rep["effects"]]
    lines += finals or ["- none"]
    if rep["found_in_words"]:
        lines += ["", "In words: " + "; ".join(rep["found_in_words"]) + "."]
    if rep.get("payload"):
        lines += ["", "## Payload", "", f"{rep['payload']['words']}."]
    if rep.get("springs"):
        lines += ["", "## Springs", ""] + [f"- joint {s['joint']}: {s['words']}." for s in rep["springs"]]
    if rep["evidence_of_something_else"]:
        lines += ["", "## Evidence of something else", "",
                  "Friction fitted with a sign that feeds energy in was rejected as friction; what it points "
                  "at:", ""]
        lines += [f"- {r['effect']} on joint {r['joint']}: {r['implausible']} -- {r['evidence_of']}; "
                  f"candidates: {', '.join(r['candidates'])}" for r in rep["evidence_of_something_else"]]
    (out / "report.md").write_text("\n".join(lines) + "\n")
    return rep
