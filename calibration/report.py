"""Calibration from logs: train NEXT, run every baseline on held-out data, write DIR/.

DIR/next.safetensors + next.json   the NEXT checkpoint (calibration.next.checkpoint)
DIR/report.json                    units, train_seconds, data_minutes, device, methods (+ files)
DIR/report.md + DIR/plots/*.png    the table and estimate-vs-truth plots
DIR/estimates/<name>.npz           t and tau_ext_<method> on the resampled grid

Scoring: `free_l1` = per-joint mean |estimate| on free-motion samples (truth is 0 there); `contact_l1` =
per-joint mean |estimate - tau_ext_true| on contact samples (null without ground truth). Free samples are:
samples with contact == False when the log has a contact array; otherwise, the whole of an --eval file
(declared free motion) and nothing of an --eval-unlabeled file. All methods are scored on the same samples
(those where every available method has a finite estimate: NEXT needs H samples of history).
Without --eval files, the top-level scores use the validation blocks of the training logs.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from calibration import baselines
from calibration.next import priors
from calibration.next.checkpoint import NextCheckpoint, save_checkpoint
from calibration.next.data import Segment, build_windows, logged_arm, resample_log, split_blocks
from calibration.next.estimator import batch_tau_f
from calibration.next.logs import read_logs
from calibration.next.prior import prior_torque
from calibration.next.train import TrainConfig, available_cores, train
from hardware.errors import ConfigError

METHODS = ("next", "prior", "observer", "filic", "raw", "ridge")  # prior: NEXT's physics prior alone


@dataclass
class Evaluated:
    name: str
    t: np.ndarray
    estimates: dict[str, np.ndarray | None]  # method -> (N, n) or None (not available)
    truth: np.ndarray | None  # (N, n) tau_ext_true, or None
    free: np.ndarray  # (N,) bool: free-motion samples scored against 0
    contact: np.ndarray  # (N,) bool: contact samples scored against truth


def estimate_segment(seg: Segment, ck: NextCheckpoint, ridge: baselines.RidgeModel | None, pin_model,
                     observer_gain: float = 50.0) -> dict[str, np.ndarray | None]:
    """Every method's tau_ext [ck.units] on one uniformly sampled segment."""
    out: dict[str, np.ndarray | None] = {m: None for m in METHODS}
    prior_tau = (prior_torque(ck.prior, seg.t, seg.q, seg.qd, seg.tau, seg.temperature)
                 if ck.prior is not None else None)
    out["next"] = seg.tau - batch_tau_f(ck, seg.q, seg.qd, seg.q_cmd, prior_tau=prior_tau)
    if prior_tau is not None:
        out["prior"] = seg.tau - prior_tau
    out["raw"] = baselines.raw_torque(seg.tau)
    if ridge is not None:
        out["ridge"] = baselines.ridge_residual(ridge, seg.q, seg.qd, seg.q_cmd, seg.tau)
    if pin_model is not None and ck.units == "N*m":
        out["filic"] = baselines.filic_residual(pin_model, seg.t, seg.q, seg.qd, seg.tau)
        out["observer"] = baselines.momentum_observer(pin_model, seg.t, seg.q, seg.qd, seg.tau, observer_gain)
    return out


def _concat(segs: list[Segment], ests: list[dict], name: str, free_default: bool,
            masks: list[np.ndarray] | None = None) -> Evaluated:
    t = np.concatenate([s.t for s in segs])
    estimates = {m: (np.concatenate([e[m] for e in ests]) if ests[0][m] is not None else None)
                 for m in METHODS}
    truth = (np.concatenate([s.tau_ext_true for s in segs]) if segs[0].tau_ext_true is not None else None)
    if segs[0].contact is not None:
        contact = np.concatenate([s.contact for s in segs])
        free = ~contact
    else:
        contact = np.zeros(len(t), bool)
        free = np.full(len(t), free_default)
    if masks is not None:
        keep = np.concatenate(masks)
        free, contact = free & keep, contact & keep
    return Evaluated(name, t, estimates, truth, free, contact)


def score(ev: list[Evaluated]) -> dict:
    """The `methods` object of report.json over one or more evaluated files."""
    res = {}
    ok_all = [np.all([np.all(np.isfinite(v), axis=1) for v in e.estimates.values() if v is not None], axis=0)
              for e in ev]
    for m in METHODS:
        if any(e.estimates[m] is None for e in ev):
            res[m] = {"free_l1": None, "contact_l1": None, "free_l1_mean": None, "contact_l1_mean": None}
            continue
        free_err = [np.abs(e.estimates[m][e.free & ok]) for e, ok in zip(ev, ok_all)]
        free_err = np.concatenate(free_err)
        con = [np.abs(e.estimates[m] - e.truth)[e.contact & ok] for e, ok in zip(ev, ok_all)
               if e.truth is not None]
        con = np.concatenate(con) if con else np.zeros((0, 0))
        free_l1 = free_err.mean(0).tolist() if len(free_err) else None
        con_l1 = con.mean(0).tolist() if con.size else None
        res[m] = {"free_l1": free_l1, "contact_l1": con_l1,
                  "free_l1_mean": float(np.mean(free_l1)) if free_l1 else None,
                  "contact_l1_mean": float(np.mean(con_l1)) if con_l1 else None}
    return res


def _load_segments(paths, rate_hz: float, joint_names=None, say=None
                   ) -> tuple[list[tuple[str, list[Segment], bool]], str, list, dict[str, list[str]]]:
    """Every run of `paths` (calibration.next.logs: .npz or .mcap, defects handled and noted) resampled to
    rate_hz -> ([(name, segments, has_q_cmd)], units, joint names, {name: notes})."""
    runs, units, notes = [], None, {}
    for p in paths:
        for r in read_logs(p, rate_hz):
            log = r.log
            if units is None:
                units, joint_names = log.units, joint_names or log.joint_names
            if log.units != units:
                raise ConfigError(f"torque signal in {log.units}, other logs in {units}", where=str(p),
                                  fix="give all logs the same signal (tau_m or current + torque_constant)")
            if list(log.joint_names) != list(joint_names):
                raise ConfigError(f"joints {log.joint_names} differ from {list(joint_names)}", where=str(p),
                                  fix="use logs of one arm (same joints, same order)")
            segs = resample_log(log, rate_hz)
            if not segs:
                raise ConfigError("no usable samples after dropping corrupt rows", where=str(p),
                                  fix="check the log")
            if r.notes:
                notes[r.name] = r.notes
                if say is not None:
                    for n in r.notes:
                        say(f"{r.name}: {n}")
            runs.append((r.name, segs, r.has_q_cmd))
    return runs, units, list(joint_names), notes


def _to_arm_joints(runs, loaded: dict, joint_names: list, desc, joint_map, say):
    """The logs' columns in the arm's joint order (calibration.joint_map: a common prefix/suffix or no names
    by order with one line, --joint-map, else a one-line refusal whose fix works)."""
    from calibration.joint_map import match_joints, reorder

    want = list(desc.joint_names)
    n = runs[0][1][0].q.shape[1] if runs and runs[0][1] else len(joint_names)
    try:
        order, note = match_joints(joint_names, want, joint_map, desc.name, n)
    except ValueError as e:
        raise ConfigError(getattr(e, "what", str(e)), where="--joint-map" if joint_map else "joint names",
                          fix=getattr(e, "fix", "") or "LOG_NAME=ARM_NAME,... for every log joint") from None
    if note and say is not None:
        say(f"note: {note}")

    def fix(rs):
        return [(name, [reorder(s, order, want) for s in segs], h) for name, segs, h in rs]

    return fix(runs), {k: fix(v) for k, v in loaded.items()}, want


def _fit_prior(kind: str, arm: str | None, units: str, segments: list[Segment]):
    """The physics prior NEXT trains on top of (None: the paper's plain NEXT). "auto" = the best grey box
    available: identified when the arm description is known (with a current-per-torque scale per joint for
    logs in A), else data-only (no description needed, any units). calibration.next.priors lists the kinds."""
    try:
        return priors.fit(kind, arm, units, [(s.t, s.q, s.qd, s.tau, s.temperature) for s in segments])
    except ValueError as exc:  # a kind that cannot be fitted here, or a least squares that failed
        raise ConfigError(str(exc), where="--prior",
                          fix="pass --arm (a built-in or imported arm) or use --prior data-only") from None


def network_adds(methods: dict) -> dict:
    """What the network adds over its prior, per joint, on held-out data: L1 of the prior alone ("prior";
    the raw torque signal when there is no prior) vs prior + network ("next"), free and contact; `gain` =
    prior - next (> 0: the network helps), `ratio` = next / prior."""
    base = "prior" if methods["prior"]["free_l1"] is not None else "raw"
    out = {"baseline": base}
    for kind in ("free", "contact"):
        p, n = methods[base][f"{kind}_l1"], methods["next"][f"{kind}_l1"]
        if p is None or n is None:
            out[kind] = None
            continue
        p, n = np.asarray(p), np.asarray(n)
        out[kind] = {"prior_l1": p.tolist(), "next_l1": n.tolist(), "gain": (p - n).tolist(),
                     "ratio": (n / np.maximum(p, 1e-12)).tolist(), "ratio_mean": float(n.mean() / p.mean())}
    return out


CONTACT_MARGIN_S = 0.3  # training leaves out samples this close to a logged contact [s]


def free_parts(segs: list[Segment], margin_s: float = CONTACT_MARGIN_S, min_len: int = 2) -> list[Segment]:
    """The free-motion stretches of training segments: a log with a contact flag (a twin recording with
    pushes, e.g. the contact episode of a calibration MCAP) loses its contact samples and margin_s around
    them; the rest is cut into contiguous segments (no window spans a cut)."""
    out = []
    for s in segs:
        if s.contact is None or not np.any(s.contact):
            out.append(s)
            continue
        near = np.convolve(s.contact.astype(float), np.ones(2 * int(margin_s * s.rate_hz) + 1), "same") > 0
        edges = np.flatnonzero(np.diff(np.r_[0, (~near).astype(int), 0]))
        out += [s.slice(lo, hi) for lo, hi in zip(edges[::2], edges[1::2]) if hi - lo >= min_len]
    return out


def _with_q_cmd(segs: list[Segment], use: bool) -> list[Segment]:
    """Segments with q_cmd filled: a run without one gets q (q_cmd - q = 0: no tracking error known), and so
    does every run when `use` is False (the inputs and the ridge then see the same zero feature)."""
    return [replace(s, q_cmd=s.q.copy()) if (s.q_cmd is None or not use) else s for s in segs]


def calibrate_from_logs(train_paths, out_dir, eval_paths=(), unlabeled_paths=(), arm: str | None = None,
                        cfg: TrainConfig | None = None, rate_hz: float = 100.0, observer_gain: float = 50.0,
                        callback=None, plots: bool = True, say=None, joint_map: str | None = None) -> dict:
    """Train NEXT on free-motion logs (.npz or .mcap), evaluate all, write out_dir; returns report.json's
    dict. say(line): warnings about the logs (corrupt rows dropped, no q_cmd, units) as they are read."""
    cfg = cfg or TrainConfig()
    out = Path(out_dir)
    runs, units, joint_names, notes = _load_segments(train_paths, rate_hz, say=say)
    loaded = {}
    for kind, paths in (("eval", eval_paths), ("unlabeled", unlabeled_paths)):
        if paths:
            eval_runs, eval_units, _, more = _load_segments(paths, rate_hz, joint_names, say=say)
            if eval_units != units:
                raise ConfigError(f"evaluation logs are in {eval_units}, training logs in {units}",
                                  where=str(paths[0]), fix="evaluate on logs with the same torque signal")
            loaded[kind] = eval_runs
            notes.update(more)
    has_cmd = all(h for _, _, h in runs) and all(h for rs in loaded.values() for _, _, h in rs)
    fallback = None
    if not has_cmd and "dq" in cfg.inputs.split(","):
        fallback = f"inputs {cfg.inputs} -> q,qd: a log has no q_cmd"
        cfg = replace(cfg, inputs="q,qd")
        if say is not None:
            say(f"warning: {fallback}")
    if arm is None:  # logs this app writes name their arm; an explicit arm overrides
        arm = logged_arm([s for _, segs, _ in runs for s in segs])
    pin_model = None
    if arm is not None:
        from hardware.arms import load_arm

        desc = load_arm(arm)
        runs, loaded, joint_names = _to_arm_joints(runs, loaded, joint_names, desc, joint_map, say)
        pin_model = desc.pinocchio_model()
    out.mkdir(parents=True, exist_ok=True)
    segments = _with_q_cmd(free_parts([s for _, segs, _ in runs for s in segs]), has_cmd)
    prior = _fit_prior(cfg.prior, arm, units, segments)
    data = build_windows([s if prior is None else
                          replace(s, tau=s.tau - prior_torque(prior, s.t, s.q, s.qd, s.tau, s.temperature))
                          for s in segments], cfg.history, cfg.inputs, normalize=cfg.normalize)
    result = train(data, cfg, callback=callback)
    ck = NextCheckpoint(model=result.model, normalizer=data.normalizer, arm=arm or "",
                        joint_names=joint_names, units=units, inputs=cfg.inputs, rate_hz=rate_hz,
                        x_min=data.x_min, x_max=data.x_max,
                        data_hash=data.data_hash, train_config=cfg.to_dict(),
                        metrics={"val_l1": result.val_l1, "best_val_mse_normalized": result.best_val_loss,
                                 "epochs": result.epochs, "train_seconds": result.seconds,
                                 "carried_max_diff": result.carried_max_diff}, prior=prior)
    save_checkpoint(ck, out / "next")
    ridge = baselines.fit_ridge(*(np.concatenate([getattr(s, k) for s in segments]) for k in
                                  ("q", "qd", "q_cmd", "tau")))
    evaluated: list[Evaluated] = []
    files = {}
    for kind in ("eval", "unlabeled"):
        for name, segs, _ in loaded.get(kind, []):
            segs = _with_q_cmd(segs, has_cmd)
            ev = _concat(segs, [estimate_segment(s, ck, ridge, pin_model, observer_gain) for s in segs], name,
                         free_default=(kind == "eval"))
            evaluated.append(ev)
            files[name] = score([ev])
    if evaluated:
        top = score(evaluated)
    else:  # the validation blocks of the training logs
        lengths = [len(s) for s in segments]
        _, val_blocks = split_blocks(lengths, max(int(10 * rate_hz), 2 * cfg.history))
        masks = [np.zeros(n, bool) for n in lengths]
        for si, lo, hi in val_blocks:
            masks[si][lo:hi] = True
        ests = [estimate_segment(s, ck, ridge, pin_model, observer_gain) for s in segments]
        top = score([_concat(segments, ests, "validation", True, masks)])
    report = {"units": units, "train_seconds": result.seconds,
              "train_seconds_to_within_5pct": result.seconds_to_within_5pct,
              "train_stop": result.stop_reason, "train_budget_s": _finite(cfg.max_seconds),
              "data_minutes": sum(len(s) for s in segments) / rate_hz / 60.0, "device": result.device,
              "threads": result.threads or cfg.threads or available_cores(), "epochs": result.epochs,
              "arm": arm, "joint_names": joint_names, "rate_hz": rate_hz,
              "prior": prior.kind if prior is not None else "none", "inputs": cfg.inputs,
              "inputs_fallback": fallback,
              "train_logs": [name for name, _, _ in runs], "methods": top, "network_adds": network_adds(top),
              # the share of the network's correction kept per joint, fitted on runs it never saw
              # (calibration.next.gate; None: no gate, fewer than 3 runs)
              "network_gate": result.gate, "validation": result.validation, "val_runs": result.val_runs}
    if notes:
        report["log_notes"] = notes
    if files:
        report["files"] = files
    (out / "report.json").write_text(json.dumps(report, indent=1))
    (out / "estimates").mkdir(exist_ok=True)
    for ev in evaluated:
        np.savez(out / "estimates" / f"{ev.name}.npz", t=ev.t,
                 **{f"tau_ext_{m}": v for m, v in ev.estimates.items() if v is not None},
                 **({"tau_ext_true": ev.truth} if ev.truth is not None else {}))
    write_markdown(report, evaluated, out, plots)
    return report


def _finite(x: float) -> float | None:
    return None if not np.isfinite(x) else float(x)


def _fmt(x) -> str:
    return "--" if x is None else f"{x:.3f}"


def write_markdown(report: dict, evaluated: list[Evaluated], out: Path, plots: bool = True) -> None:
    u = report["units"]
    lines = [f"# NEXT calibration report ({'arm ' + report['arm'] if report['arm'] else 'no arm model'})", "",
             f"Training: {report['data_minutes']:.1f} min of data, {report['train_seconds']:.0f} s on "
             f"{report['device']} ({report['epochs']} epochs). Estimates in {u}.", "",
             "Mean L1 over joints (free motion: vs 0; contact: vs ground truth; -- = no model/truth)", "",
             "| method | free motion | contact |", "|---|---|---|"]
    for m, v in report["methods"].items():
        lines.append(f"| {m} | {_fmt(v['free_l1_mean'])} | {_fmt(v['contact_l1_mean'])} |")
    adds = report.get("network_adds") or {}
    for kind in ("free", "contact"):
        if adds.get(kind):
            a = adds[kind]
            lines += ["", f"What the network adds over {adds['baseline']}, held-out {kind} [{u}]: "
                      f"x{a['ratio_mean']:.2f}", "",
                      "| joint | " + " | ".join(report["joint_names"]) + " |",
                      "|---|" + "---|" * len(report["joint_names"]),
                      f"| {adds['baseline']} | " + " | ".join(_fmt(x) for x in a["prior_l1"]) + " |",
                      "| next | " + " | ".join(_fmt(x) for x in a["next_l1"]) + " |"]
    if report.get("network_gate") is not None:
        lines += ["", "Share of the network's correction kept per joint (gate fitted on runs it never saw, "
                  "calibration/next/gate.py): " + " ".join(f"{g:.2f}" for g in report["network_gate"])]
    for name, methods in report.get("files", {}).items():
        lines += ["", f"## {name}", "", "| method | free motion | contact |", "|---|---|---|"]
        lines += [f"| {m} | {_fmt(v['free_l1_mean'])} | {_fmt(v['contact_l1_mean'])} |"
                  for m, v in methods.items()]
        if plots:
            lines += ["", f"![{name}](plots/{name}.png)"]
    (out / "report.md").write_text("\n".join(lines) + "\n")
    if plots and evaluated:
        _plots(evaluated, out / "plots", u, report["joint_names"])


def _plots(evaluated: list[Evaluated], folder: Path, units: str, joint_names: list[str]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder.mkdir(exist_ok=True)
    for ev in evaluated:
        n = len(joint_names)
        fig, axes = plt.subplots(n, 1, figsize=(10, 1.6 * n), sharex=True)
        for j, ax in enumerate(np.atleast_1d(axes)):
            for m, v in ev.estimates.items():
                if v is not None and m != "raw":
                    ax.plot(ev.t, v[:, j], lw=0.7, label=m)
            truth = ev.truth[:, j] if ev.truth is not None else np.where(ev.free, 0.0, np.nan)
            ax.plot(ev.t, truth, "k", lw=1.0, label="truth")
            ax.set_ylabel(f"{joint_names[j]}\n[{units}]", fontsize=7)
        np.atleast_1d(axes)[0].legend(fontsize=7, ncol=6, loc="upper right")
        np.atleast_1d(axes)[-1].set_xlabel("t [s]")
        fig.suptitle(f"{ev.name}: external torque estimates")
        fig.tight_layout()
        fig.savefig(folder / f"{ev.name}.png", dpi=80)
        plt.close(fig)
