"""FIRST's contact labels against the twin's truth, with and without the held-load tare (SIMULATED).

    python -m bench.label_truth DIR [DIR...] [--tare off,bias,payload] [--score l1,motion] [--add-payload KG]
                                [--split otsu,min-error] [--band LOW:HIGH,...] [--json OUT] [--results NAME]

Each DIR is one episode set (a task's recordings, as `factr2 collect` writes them). Per set and tare method:
the recording thresholds (Otsu on the set's own, tared, scores: ||tau_ext||_1, or with --score motion the
motion residual of policies.labels.motion_residual), then every episode labelled as `factr2 episodes phases`
does, against the truth of the recorded /follower/ground_truth: contact while the true
external torque's ||tau_ext_true||_1 passes TRUE_ON_NM, until it falls to TRUE_OFF_NM (docs/first_labels.md).

    recall   share of true-contact samples labelled contact
    FP       share of true-free samples labelled contact
    shares   free / pre-contact / contact share of all labelled samples
    onsets   true contact onsets, and those with a labelled onset within ONSET_TOL_S
    held     share of samples the (first) follower's gripper holds an object (tared unless tare is off)
    floor    share of true-contact samples whose TRUE score reaches T_low: what any label above the noise
             floor can find at most (contact below it is indistinguishable from free-motion noise)
    FP@0.5s  share of the false positives in the first 0.5 s of their episode (the estimate's start)
    carry95  95th percentile of the (tared) score while a gripper holds an object and the truth is free
             [N*m]: what is left of the load (compare T_low)

--split and --band (l1 score, no added payload): where the valley o is placed (policies.labels.phases.SPLITS:
Otsu's, the library's default, or the minimum-error split) and the band (T_low, T_high) = (LOW o, HIGH o)
(default the library's OTSU_LOW_X:OTSU_HIGH_X); every combination is a row. The labels are then the
library's (policies.labels.labelling.label_episode) with those thresholds.

--add-payload KG (semi-synthetic): the twins' objects are light (a 30 g peg, a 20 g block: ~0.17 N*m, below
NEXT's free-motion noise), so the recordings barely show the held load tare is for. This adds to the
recorded tau_ext, while the gripper holds, the gravity torque of a KG point mass ADD_COM_M beyond the last
joint along its z axis (the arm description's regressor), as if the object were that heavy; the truth stays
the recorded one (a held object's weight is not contact). The labelling then runs the library's steps on
that tau_ext (policies.labels.tare_recording.episode_tare, policies.labels.phases).
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from pathlib import Path

import numpy as np

from bench import harness
from bench.harness import names
from bench.portable import portable
from hardware.reasons import Reason
from hardware.recording import schemas as S
from hardware.recording.reader import interp_linear
from policies.data.recordings import load_episodes
from policies.labels import labelling as L
from policies.labels import motion_residual as M
from policies.labels import phases as P
from policies.labels import tare as T
from policies.labels import tare_recording as TR

TRUE_ON_NM, TRUE_OFF_NM = 0.5, 0.3  # truth hysteresis on ||tau_ext_true||_1 [N*m] (docs/first_labels.md)
ONSET_TOL_S = 0.5  # a true onset is found when a labelled onset lies within this [s]
ADD_COM_M = 0.15  # --add-payload: the added mass's centre beyond the last joint along its z (fingers) [m]


def truth_contact(t: np.ndarray, t_gt: np.ndarray, tau_true: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(true score (N,) [N*m], contact (N,) bool) of the true external torque at the label times t [s]."""
    s = P.contact_score(interp_linear(t_gt, tau_true, t))
    return s, P.hysteresis(s, TRUE_OFF_NM, TRUE_ON_NM)


def compare(t: np.ndarray, true_score: np.ndarray, truth: np.ndarray, phases: np.ndarray, t_low: float
            ) -> dict:
    """Counts of one episode over the samples with a truth: true/labelled contact, onsets, floor, starts."""
    lab, v = phases == P.CONTACT, np.isfinite(true_score)
    tr, lo = t[P.onsets(truth & v)], t[P.onsets(lab & v)]
    found = sum(bool(len(lo)) and bool(np.min(np.abs(lo - x)) <= ONSET_TOL_S) for x in tr)
    return {"tp": int(np.sum(lab & truth & v)), "pos": int(np.sum(truth & v)),
            "fp": int(np.sum(lab & ~truth & v)), "neg": int(np.sum(~truth & v)),
            "pos_above": int(np.sum(truth & v & (true_score >= t_low))),
            "fp_start": int(np.sum(lab & ~truth & v & (t - t[0] < 0.5))),
            "phase_n": np.bincount(phases[v].astype(np.int64), minlength=3)[:3].tolist(),
            "onsets_true": len(tr), "onsets_found": int(found), "onsets_labelled": len(lo)}


def _with_payload(episodes, arms, tare: str, kg: float) -> tuple[object, list]:
    """(thresholds, [(t, phases, held)] per episode) of the library's steps on tau_ext plus a held KG."""
    arm, names, model = arms.followers[0], arms.joint_names[0], arms.arm_models[0]
    reg = TR.payload_regressor(model, names)
    if len(arms.followers) != 1 or reg is None:
        raise SystemExit("--add-payload needs a single follower with a known arm description")
    theta = np.array([kg, 0.0, 0.0, kg * ADD_COM_M])  # m [kg], m*c [kg*m] in the last joint's frame
    per = []
    for ep in episodes:
        t, tau, _ = L.episode_tau_ext(ep, arms)
        q, stroke, command = TR.gripper_signals(ep, arm, t)
        held = T.held_mask(t, stroke, command)
        tau = tau + held[:, None] * np.einsum("knp,p->kn", reg(q), theta)
        load, _, _ = TR.episode_tare(ep, arms, t, tau, tare)
        per.append((t, P.contact_score(T.tared(tau, load)), held))
    lo, hi = P.recording_thresholds(np.concatenate([s for _, s, _ in per]))
    n = sum(int(np.isfinite(s).sum()) for _, s, _ in per)  # the recordings' own split, semi-synthetic payload
    th = L.Thresholds(lo, hi, Reason.of(L.ThresholdSource.RECORDING, tared=tare != "off", episodes=len(per),
                                          samples=n), tare)
    return th, [(t, P.label_phases(t, P.contact_runs(s, lo, hi)), h, s) for t, s, h in per]


DEFAULT_BAND = (P.OTSU_LOW_X, P.OTSU_HIGH_X)


def _split_thresholds(episodes, arms, tare: str, split: str, band: tuple[float, float]) -> L.Thresholds:
    """The recording source's steps with another valley placement or band (--split, --band)."""
    score = np.concatenate([L.episode_scores(ep, arms, tare)[0] for ep in episodes])
    o = P.valley(score, split)
    return L.Thresholds.given(band[0] * o, band[1] * o, tare)


def measure(directory: Path, tare: str, add_kg: float = 0.0, score_kind: str = "l1", split: str = "otsu",
            band: tuple[float, float] = DEFAULT_BAND) -> dict:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        episodes, arms = load_episodes([directory])
    t0 = time.perf_counter()
    custom = split != "otsu" or tuple(band) != DEFAULT_BAND
    if (add_kg > 0 or custom) and score_kind != "l1":
        raise SystemExit("--add-payload, --split and --band are measured with the l1 score only")
    if add_kg > 0:
        if custom:
            raise SystemExit("--add-payload is measured with the library's split and band only")
        th, labelled = _with_payload(episodes, arms, tare, add_kg)
    elif custom:
        th = _split_thresholds(episodes, arms, tare, split, band)
        labs = [L.label_episode(ep, arms, th) for ep in episodes]
        labelled = [(lab.t, lab.phases, lab.held, lab.score) for lab in labs]
    else:  # exactly what `factr2 episodes phases` does
        th = L.resolve_thresholds(L.LabelChoice("recording", tare, score_kind), None, episodes, arms)
        labs = [L.label_episode(ep, arms, th) for ep in episodes]
        labelled = [(lab.t, lab.phases, lab.held, lab.score) for lab in labs]
    tot: dict = {}
    held_n, carry = 0, []
    for ep, (t, phases, _, score) in zip(episodes, labelled):
        held = T.held_mask(t, *TR.gripper_signals(ep, arms.followers[0], t)[1:])  # whatever the tare
        gt = ep.topic(S.ground_truth_topic(arms.followers[0]))
        true_score, truth = truth_contact(t, gt.t, np.asarray(gt.fields["tau_ext_true"], float))
        c = compare(t, true_score, truth, phases, th.t_low)
        for k, v in c.items():
            tot[k] = (np.add(tot[k], v).tolist() if isinstance(v, list) else tot[k] + v) if k in tot else v
        held_n += int(np.sum(held & np.isfinite(true_score)))
        carry.append(score[held & ~truth & np.isfinite(true_score) & np.isfinite(score)])
    n = tot["pos"] + tot["neg"]
    return {
        "set": episodes[0].task or directory.name, "dir": str(directory), "tare": tare, "score": score_kind,
        "added_kg": add_kg, "split": split, "band": list(band),
        "episodes": len(episodes), "samples": n, "t_low": th.t_low, "t_high": th.t_high,
        "truth_contact": tot["pos"] / max(n, 1),
        "recall": tot["tp"] / max(tot["pos"], 1), "fp": tot["fp"] / max(tot["neg"], 1),
        # the floor compares the TRUE score [N*m] with T_low: only in the l1 score's unit
        "floor": tot["pos_above"] / max(tot["pos"], 1) if score_kind == "l1" else float("nan"),
        "fp_at_start": tot["fp_start"] / max(tot["fp"], 1),
        "shares": (np.asarray(tot["phase_n"]) / max(n, 1)).tolist(), "held": held_n / max(n, 1),
        "onsets_true": tot["onsets_true"], "onsets_found": tot["onsets_found"],
        "onsets_labelled": tot["onsets_labelled"], "seconds": time.perf_counter() - t0,
        "carry_p95": float(np.percentile(np.concatenate(carry), 95)) if sum(map(len, carry)) else np.nan,
    }


def table(rows: list[dict]) -> str:
    head = (f"{'set':<14} {'+kg':>4} {'eps':>4} {'truth C':>8} {'tare':<8} {'score':<6} {'T_low:T_high':>13} "
            f"{'recall':>7} {'FP':>6} {'free':>6} {'pre':>6} {'contact':>7} {'held':>6} {'floor':>6} "
            f"{'FP@0.5s':>7} {'carry95':>7} {'onsets (true, found)':>21} {'split':<9} {'band':<9}")
    out = [head, "-" * len(head)]
    for r in rows:
        sh = r["shares"]
        out.append(
            f"{r['set']:<14} {r['added_kg']:4.2g} {r['episodes']:>4} {r['truth_contact']:8.1%} "
            f"{r['tare']:<8} {r.get('score', 'l1'):<6} {r['t_low']:6.3g}:{r['t_high']:<6.3g} "
            f"{r['recall']:7.1%} {r['fp']:6.1%} "
            f"{sh[0]:6.1%} {sh[1]:6.1%} {sh[2]:7.1%} {r['held']:6.1%} {r['floor']:6.1%} "
            f"{r['fp_at_start']:7.0%} {r['carry_p95']:7.3g} "
            f"{r['onsets_labelled']:>6} ({r['onsets_true']}, {r['onsets_found']}) "
            f"{r.get('split', 'otsu'):<9} {':'.join(f'{x:.3g}' for x in r.get('band', DEFAULT_BAND))}")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("dirs", type=Path, nargs="+", help="one folder of recordings per task")
    ap.add_argument("--tare", default="off,bias,payload", help="comma-separated tare methods to compare")
    ap.add_argument("--score", default="l1", help="comma-separated contact scores to compare: l1, motion")
    ap.add_argument("--add-payload", type=float, default=0.0, metavar="KG",
                    help="semi-synthetic: add a held KG point mass to the recorded tau_ext (module doc)")
    ap.add_argument("--split", default="otsu",
                    help=f"comma-separated valley placements: {', '.join(P.SPLITS)}")
    ap.add_argument("--band", default=f"{P.OTSU_LOW_X}:{P.OTSU_HIGH_X}",
                    help="comma-separated LOW:HIGH multiples of the valley (T_low, T_high)")
    ap.add_argument("--json", type=Path, default=None, help="write the rows here")
    ap.add_argument("--results", default="", metavar="NAME",
                    help="also write the rows as results/NAME.json (bench/harness.py's record): docs tables")
    args = ap.parse_args(argv)
    methods, scores, splits = names(args.tare), names(args.score), names(args.split)
    try:
        bands = [P.parse_thresholds(b) for b in names(args.band)]
    except ValueError as e:
        ap.error(f"--band: {e}")
    known = (set(methods) <= set(T.TARE_METHODS) and set(scores) <= set(M.CONTACT_SCORES)
             and set(splits) <= set(P.SPLITS))
    if not known or args.add_payload < 0:
        ap.error(f"--tare takes {', '.join(T.TARE_METHODS)}; --score {', '.join(M.CONTACT_SCORES)}; "
                 f"--split {', '.join(P.SPLITS)}; --add-payload a mass >= 0 kg")
    rows = [measure(d, m, args.add_payload, sc, sp, b) for d in args.dirs for m in methods for sc in scores
            for sp in splits for b in bands]
    print(table(rows))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"date": time.strftime("%Y-%m-%d"), "simulated": True,
                                         "truth_nm": [TRUE_OFF_NM, TRUE_ON_NM], "rows": rows}, indent=1))
    if args.results:
        cmd = harness.command(None if argv is None else ["label_truth", *argv], "bench.label_truth")
        rec = harness.record(args.results, {"truth_nm": [TRUE_OFF_NM, TRUE_ON_NM],
                                                             "rows": rows}, simulated=True, cmd=cmd)
        print(f"wrote {harness.write(harness.RESULTS / f'{args.results}.json', portable(rec))}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
