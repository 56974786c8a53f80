"""Does one time step of tau_ext carry contact, or does it take a history? (issue #51 item 5, SIMULATED)

    python -m bench.force_history DIR [DIR...] [--steps 1,3,10,30] [--rate-hz 30] [--json OUT]

The policies see tau_ext [N*m] one step at a time, at their rate (30 Hz); the paper's NEXT reads a 50-step
history to separate contact from motion. Here the question is put to the recordings directly: per set (one
folder of a task's `factr2 collect` recordings), a logistic classifier of the twin's TRUE contact
(bench/label_truth.py's hysteresis on ||tau_ext_true||_1) from the estimated tau_ext of the last H policy
steps (signed and absolute per joint, 2 x joints x H inputs), trained on the even episodes and scored on the
odd ones: ROC AUC, and the balanced accuracy at the threshold that is best on the training episodes. If
H = 1 is as good as H = 10-30, one step carries what a history would; if not, a policy fed one step misses
contact the estimate does hold.
"""

from __future__ import annotations

import argparse
import json
import warnings
from pathlib import Path

import numpy as np

from bench.label_truth import truth_contact
from hardware.recording import schemas as S
from hardware.recording.reader import interp_linear
from policies.data.recordings import load_episodes
from policies.labels import labelling as L


def windows(tau: np.ndarray, steps: int) -> np.ndarray:
    """(N, 2 * D * steps) inputs: tau and |tau| of the last `steps` samples (sample 0 repeats before it)."""
    idx = np.arange(len(tau))[:, None] - np.arange(steps)[None, :]
    w = tau[np.clip(idx, 0, None)]  # (N, steps, D)
    return np.concatenate([w, np.abs(w)], axis=2).reshape(len(tau), -1)


def fit_logistic(x: np.ndarray, y: np.ndarray, l2: float = 1e-3, iters: int = 50) -> np.ndarray:
    """Weights (D + 1,) of an L2-regularised logistic regression by Newton's method (x standardised)."""
    xb = np.hstack([x, np.ones((len(x), 1))])
    w = np.zeros(xb.shape[1])
    reg = l2 * np.eye(len(w))
    reg[-1, -1] = 0.0
    for _ in range(iters):
        p = 1.0 / (1.0 + np.exp(-np.clip(xb @ w, -30, 30)))
        g = xb.T @ (p - y) / len(y) + reg @ w
        h = (xb * (p * (1 - p))[:, None]).T @ xb / len(y) + reg
        step = np.linalg.solve(h + 1e-9 * np.eye(len(w)), g)
        w -= step
        if np.max(np.abs(step)) < 1e-8:
            break
    return w


def score(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    return x @ w[:-1] + w[-1]


def roc_auc(s: np.ndarray, y: np.ndarray) -> float:
    """ROC area: the chance a true-contact sample scores above a free one (ties count half)."""
    pos, neg = s[y == 1], s[y == 0]
    if not len(pos) or not len(neg):
        return float("nan")
    order = np.argsort(np.concatenate([pos, neg]), kind="mergesort")
    ranks = np.empty(len(order))
    allv = np.concatenate([pos, neg])[order]
    # average ranks over ties
    _, start, counts = np.unique(allv, return_index=True, return_counts=True)
    avg = start + (counts - 1) / 2.0 + 1
    ranks[order] = np.repeat(avg, counts)
    return float((ranks[: len(pos)].sum() - len(pos) * (len(pos) + 1) / 2) / (len(pos) * len(neg)))


def balanced_accuracy(s: np.ndarray, y: np.ndarray, threshold: float) -> float:
    pred = s >= threshold
    return float(0.5 * (np.mean(pred[y == 1]) + np.mean(~pred[y == 0])))


def best_threshold(s: np.ndarray, y: np.ndarray) -> float:
    cands = np.quantile(s, np.linspace(0.01, 0.99, 99))
    return float(cands[int(np.argmax([balanced_accuracy(s, y, c) for c in cands]))])


def episode_samples(ep, arms, rate_hz: float) -> tuple[np.ndarray, np.ndarray] | None:
    """(tau_ext (N, D) [N*m], true contact (N,)) of one episode on a grid at the policy's rate."""
    t, tau, _ = L.episode_tau_ext(ep, arms)
    gt_topic = S.ground_truth_topic(arms.followers[0])
    if len(t) < 2 or gt_topic not in ep.recording.topics:
        return None
    grid = np.arange(t[0], t[-1], 1.0 / rate_hz)
    gt = ep.topic(gt_topic)
    true_score, truth = truth_contact(grid, gt.t, np.asarray(gt.fields["tau_ext_true"], float))
    x = interp_linear(t, tau, grid)
    keep = np.isfinite(true_score) & np.isfinite(x).all(axis=1)
    return x[keep], truth[keep].astype(float)


def measure(directory: Path, steps: list[int], rate_hz: float) -> list[dict]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        episodes, arms = load_episodes([directory])
    per = [episode_samples(ep, arms, rate_hz) for ep in episodes]
    per = [p for p in per if p is not None and len(p[1])]
    if len(per) < 2:
        raise SystemExit(f"{directory}: fewer than 2 episodes with tau_ext and the twin's ground truth")
    rows = []
    for h in steps:
        xs = [(windows(x, h), y) for x, y in per]
        tr = [p for i, p in enumerate(xs) if i % 2 == 0]
        te = [p for i, p in enumerate(xs) if i % 2 == 1]
        xtr, ytr = np.concatenate([p[0] for p in tr]), np.concatenate([p[1] for p in tr])
        xte, yte = np.concatenate([p[0] for p in te]), np.concatenate([p[1] for p in te])
        mu, sd = xtr.mean(0), xtr.std(0) + 1e-9
        w = fit_logistic((xtr - mu) / sd, ytr)
        s_tr, s_te = score((xtr - mu) / sd, w), score((xte - mu) / sd, w)
        th = best_threshold(s_tr, ytr)
        rows.append({"set": episodes[0].task or directory.name, "dir": str(directory), "steps": h,
                     "history_s": h / rate_hz, "episodes": len(per), "samples_test": int(len(yte)),
                     "contact_share": float(yte.mean()), "auc": roc_auc(s_te, yte),
                     "balanced_accuracy": balanced_accuracy(s_te, yte, th)})
    return rows


def table(rows: list[dict]) -> str:
    out = ["| set | steps (s) | episodes | test samples | true contact | ROC AUC | balanced accuracy |",
           "|---|---|---|---|---|---|---|"]
    for r in rows:
        out.append(f"| {r['set']} | {r['steps']} ({r['history_s']:.2f} s) | {r['episodes']} | "
                   f"{r['samples_test']} | {100 * r['contact_share']:.0f} % | {r['auc']:.3f} | "
                   f"{100 * r['balanced_accuracy']:.1f} % |")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dirs", type=Path, nargs="+", help="one folder of a task's recordings per set")
    ap.add_argument("--steps", default="1,3,10,30", help="history lengths H in policy steps")
    ap.add_argument("--rate-hz", type=float, default=30.0, help="the policy's rate [Hz]")
    ap.add_argument("--json", type=Path, default=None, help="write the rows here")
    ap.add_argument("--results", default="", metavar="NAME",
                    help="also publish the rows as results/NAME.json (a harness record: docs/force.md)")
    a = ap.parse_args(argv)
    try:
        steps = sorted({int(s) for s in a.steps.split(",") if s.strip()})
    except ValueError:
        ap.error(f"--steps {a.steps!r}: comma-separated integers, e.g. 1,3,10,30")
    if not steps or min(steps) < 1:
        ap.error("--steps: at least one history length >= 1")
    for d in a.dirs:
        if not d.is_dir():
            ap.error(f"{d}: not a folder of recordings")
    rows = [r for d in a.dirs for r in measure(d, steps, a.rate_hz)]
    print(table(rows))
    if a.json:
        a.json.write_text(json.dumps({"simulated": True, "command": "python -m bench.force_history "
                                      + " ".join(map(str, argv or [])), "rows": rows}, indent=1))
    if a.results:
        from bench import harness

        cmd = harness.command()
        for r in rows:  # the folders are scratch: the set's last two names say what it was
            d = Path(r["dir"])
            cmd = cmd.replace(str(d), f"SCRATCH/{d.parent.name}/{d.name}")
            r["dir"] = f"{d.parent.name}/{d.name}"
        rec = harness.record(a.results, {"rows": rows, "rate_hz": a.rate_hz}, simulated=True, cmd=cmd)
        harness.write(harness.RESULTS / f"{a.results}.json", rec)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
