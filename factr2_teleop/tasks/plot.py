"""Figure of one recorded demonstration (SIMULATED): NEXT's tau_ext against the twin's ground truth per joint,
FIRST's phases (free / pre-contact / contact, from the estimate) shaded, the task's stage marks as lines.

    python -m factr2_teleop.tasks.plot RECORDING.mcap OUT.png [--episode K] [--checkpoint next.json]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

PHASE_COLOURS = ("white", "#ffe9a8", "#f6b3b3")  # free, pre-contact, contact


def plot_episode(path: str | Path, out: str | Path, episode: int = 0, thresholds=None) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hardware.recording.reader import Recording
    from policies.labels.phases import PHASE_NAMES, phase_shares, phases_from_torque

    rec = Recording(path, use_cache=False, write_cache=False)
    ep = rec.episodes[episode]
    est, gt = ep.topic("/follower/tau_ext"), ep.topic("/follower/ground_truth")
    t0 = ep.t_start
    te, tau = est.t - t0, np.asarray(est.fields["tau_ext"], float)
    tg, true = gt.t - t0, np.asarray(gt.fields["tau_ext_true"], float)
    n = tau.shape[1]
    ph = phases_from_torque(te, np.nan_to_num(tau), *thresholds) if thresholds else None
    fig, axes = plt.subplots(n, 1, figsize=(10, 1.5 * n + 1), sharex=True)
    for j, ax in enumerate(axes):
        if ph is not None:
            edges = np.flatnonzero(np.diff(ph)) + 1
            for a, b in zip(np.r_[0, edges], np.r_[edges, len(ph)]):
                if ph[a]:
                    ax.axvspan(te[a], te[min(b, len(te) - 1)], color=PHASE_COLOURS[ph[a]], lw=0)
        ax.plot(tg, true[:, j], "k", lw=1.0, label="ground truth (twin)")
        ax.plot(te, tau[:, j], "C0", lw=0.8, label="NEXT estimate")
        for t, _v, label in ep.progress:
            ax.axvline(t - t0, color="C2", lw=0.8, ls="--")
            if j == 0:
                ax.text(t - t0, ax.get_ylim()[1], f" {label}", color="C2", va="top", fontsize=8)
        ax.set_ylabel(f"J{j + 1} [N*m]")
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("time in episode [s]")
    shares = phase_shares(ph) if ph is not None else np.zeros(3)
    title = (f"{ep.task} episode {episode} ({ep.outcome}), SIMULATED: NEXT tau_ext vs ground truth; shaded: "
             + ", ".join(f"{PHASE_NAMES[k]} {shares[k] * 100:.0f} %" for k in (1, 2)))
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return {"episode": episode, "outcome": ep.outcome, "shares": shares.tolist()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("recording")
    ap.add_argument("out")
    ap.add_argument("--episode", type=int, default=0)
    ap.add_argument("--checkpoint", default=None,
                    help="NEXT checkpoint whose free-motion noise sets the phase thresholds")
    a = ap.parse_args(argv)
    thr = None
    if a.checkpoint:
        from policies.labels.phases import default_thresholds

        thr = default_thresholds(json.loads(Path(a.checkpoint).read_text())["metrics"]["val_l1"])
    print(plot_episode(a.recording, a.out, a.episode, thr))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
