"""The diagnose loop around NEXT (calibration/next): NEXT's prediction is the "rigid part" -- one column
per joint with a gain held near 1 -- and the loop traces NEXT's held-out residual to what the network cannot
see (time/temperature drift, another joint's motion, a position-periodic term finer than it resolves) and
adds grey-box terms on that residual. Also: NEXT trained on top of a grey-box prior (residual learning).

NEXT works on a uniform clock (the checkpoint's rate) with a window of H samples, so segments are resampled
to that rate and their first H-1 samples (no full window yet) are dropped before anything is compared.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from hardware.errors import UserError

from .data import Segment, resample


class NextBasis:
    """One column per joint: a fixed predictor's output (NEXT). Gain prior 1 with a strong ridge, so the
    rigid part stays NEXT's prediction and the effects model only what NEXT leaves."""

    kind = "next"
    separable = True

    def __init__(self, n: int, predictions: dict[int, np.ndarray], label: str, kinematics=None,
                 current_scale=None):
        self.n, self.preds, self.label = n, predictions, label
        # a new load on runs NEXT was not trained for: the payload through the arm's kinematics when the
        # description is known (in current: its columns times current_scale [A per N*m], payload.py), and
        # always the gravity-like family of link orientations, so the loop ranks the two on held-out gain
        self.kinematics = kinematics
        self.current_scale = current_scale
        self.offers_gravity_load = True
        self.n_params = n
        self.prior = np.ones(n)
        self.ridge = np.full(n, 1e3)

    def describe(self) -> str:
        return self.label

    def blocks(self, seg: Segment):
        p = self.preds[id(seg)]
        return [(np.array([j]), p[:, [j]]) for j in range(self.n)]


def _next_inputs(seg: Segment, inputs: str) -> np.ndarray:
    from calibration.next.data import make_inputs

    q_cmd = seg.q if seg.q_cmd is None else seg.q_cmd
    return make_inputs(seg.q, seg.qd, q_cmd, inputs)


def predict_next(model, normalizer, history: int, inputs: str, seg: Segment) -> np.ndarray:
    """(N, n) NEXT prediction in the data's units; the first history-1 rows are NaN."""
    from calibration.next.train import predict_series
    from hardware.threads import limit_threads

    with limit_threads(1, torch=True):
        z = predict_series(model, normalizer.norm_x(_next_inputs(seg, inputs)).astype(np.float32), history)
    return normalizer.denorm_y(z.astype(np.float64))


def prepare(segments: list[Segment], rate_hz: float, history: int) -> list[Segment]:
    """Resampled to NEXT's rate, first history-1 samples dropped (no full window)."""
    out = []
    for s in segments:
        r = resample(s, rate_hz)
        if len(r) > history + 20:
            out.append(r.slice(history - 1, len(r), r.name))
    if not out:
        raise UserError("runs are shorter than one NEXT window", where=", ".join(s.name for s in segments),
                        fix="diagnose longer runs")
    return out


def _predictions(ck_model, normalizer, history, inputs, rate_hz, segments, prior=None
                 ) -> tuple[list[Segment], dict]:
    """ck_model None: the prior alone (the calibration's own physics prior, without the network)."""
    preds, out = {}, []
    for s in segments:
        r = resample(s, rate_hz)
        if len(r) <= history + 20:
            continue
        # the checkpoint was trained on the logged velocity, not on diagnosis's cleaner one
        seen = r if r.qd_logged is None else dataclasses.replace(r, qd=r.qd_logged)
        p = (np.zeros_like(seen.tau) if ck_model is None
             else predict_next(ck_model, normalizer, history, inputs, seen))
        if prior is not None:  # the checkpoint's physics prior is part of its model
            from calibration.next.prior import prior_torque

            p = p + prior_torque(prior, seen.t, seen.q, seen.qd, seen.tau, seen.temperature)
        cut = r.slice(history - 1, len(r), r.name)
        preds[id(cut)] = p[history - 1:]
        out.append(cut)
    if not out:
        raise UserError("runs are shorter than one NEXT window", where=", ".join(s.name for s in segments),
                        fix="diagnose longer runs")
    return out, preds


def fixed_basis(train, heldout, predict, label: str, kinematics=None, scale=None):
    """A NextBasis around any fixed predictor: predict(segments) -> (segments cut, {id: (N, n)})."""
    tr, p_tr = predict(train)
    ho, p_ho = predict(heldout)
    sc = None if scale is None else scale.scale
    return NextBasis(train[0].n, {**p_tr, **p_ho}, label, kinematics, sc), tr, ho


def known_mass_alpha(basis: NextBasis, segments: list[Segment], predict, known_kg: float) -> float:
    """alpha of payload.alpha_from_known_mass on a reference run of known payload mass: the payload fitted
    on the fixed model's residual there, its columns scaled as the basis scales them."""
    from .greybox import Design, GreyBox
    from .payload import alpha_from_known_mass, fit_payload

    segs, preds = predict(segments)
    b = NextBasis(basis.n, preds, basis.label, basis.kinematics, basis.current_scale)
    d = Design(b, segs)
    res = d.y - GreyBox(b).rigid(d)
    return alpha_from_known_mass(float(fit_payload(res, d.payload_columns("full"))[0]), known_kg)


def diagnose_next(ckpt: str, train: list[Segment], heldout: list[Segment], cfg, log=print, kinematics=None,
                  no_arm: bool = False, kt=None, known_mass: tuple | None = None, prior_only: bool = False,
                  referenced: bool = True):
    """Load a NEXT checkpoint and run the diagnose loop with it as the base model. kinematics: the arm's
    pinocchio model for the payload family (default: the checkpoint's arm, unless no_arm). Logs in current:
    the payload's columns are scaled by kt (vendor torque constants [N*m per A]) or the identified-current
    prior's scales (referenced to the description's masses unless `referenced` is False), times the alpha
    of known_mass = (kg, reference-run segments) (payload.py). prior_only: the checkpoint's physics prior
    alone is the base model (the calibration's own prior, without the network)."""
    from .loop import diagnose
    from .payload import choose_scale

    try:
        from calibration.next.checkpoint import load_checkpoint
    except ImportError:
        raise UserError("NEXT is not available in this install (calibration.next.checkpoint missing)",
                        where="--model", fix="diagnose the physics model instead (drop --model)") from None
    ck = load_checkpoint(ckpt)
    if ck.units != train[0].units:
        raise UserError(f"checkpoint predicts {ck.units}, the logs are in {train[0].units}", where=ckpt,
                        fix="diagnose logs of the kind the model was trained on")
    if ck.normalizer.y_mean.shape[0] != train[0].n:
        raise UserError(f"checkpoint has {ck.normalizer.y_mean.shape[0]} joints, logs {train[0].n}",
                        where=ckpt, fix="use the checkpoint of this arm")
    if prior_only and ck.prior is None:
        raise UserError("the checkpoint has no physics prior", where=ckpt, fix="drop --prior-only")
    net = None if prior_only else ck.model

    def predict(segs):
        return _predictions(net, ck.normalizer, ck.history, ck.inputs, ck.rate_hz, segs, ck.prior)

    if kinematics is None and ck.arm and not no_arm:
        from hardware.arms import load_arm

        kinematics = load_arm(ck.arm).pinocchio_model()
    prior_scale = getattr(ck.prior, "scale", None)  # the identified-current prior's [A per N*m]
    scale = choose_scale(ck.units, kt, prior_scale, None, referenced)
    if scale is None:
        kinematics = None  # current without any per-joint scale: only the gravity-like load
        log("logs in current and no current-per-torque scale (no --kt, prior not identified-current): the "
            "payload cannot go through the arm's kinematics; a gravity-like load is looked for instead")
    what = ("the checkpoint's physics prior alone" if prior_only else
            f"NEXT checkpoint {ckpt} ({ck.model.cfg.arch}, history {ck.history}, inputs {ck.inputs})")
    basis, tr, ho = fixed_basis(train, heldout, predict, f"{what} + grey-box terms on its residual",
                                kinematics, scale)
    if known_mass is not None and scale is not None and kinematics is not None:
        alpha = known_mass_alpha(basis, known_mass[1], predict, known_mass[0])
        scale = choose_scale(ck.units, None, scale.scale, alpha)
        basis.current_scale = scale.scale
        runs = ", ".join(s.name for s in known_mass[1])
        log(f"known mass {known_mass[0]:g} kg on {runs}: alpha {alpha:.4g}")
    dg = diagnose(basis, tr, ho, cfg, log=log)
    return dg, {"basis": basis.describe(), "title": f"{what} + grey-box terms on its residual",
                "next_checkpoint": str(ckpt), "prior_only": prior_only,
                "payload_scale": None if scale is None or kinematics is None else scale}


def train_next(segments: list[Segment], seconds: float, residual_of=None, seed: int = 0,
               rate_hz: float = 100.0, history: int = 50, max_epochs: int = 400, threads: int = 1):
    """Train NEXT (calibration.next) on segments; with `residual_of(seg) -> (N, n)` on y - residual_of
    (grey-box prior: NEXT learns what the physics model leaves). Returns (predict(seg)->(N,n), seconds,
    the training result)."""
    from calibration.next.data import Segment as NSeg
    from calibration.next.data import build_windows
    from calibration.next.train import TrainConfig, train

    nsegs = []
    for s in segments:
        r = resample(s, rate_hz)
        y = r.tau - (residual_of(r) if residual_of is not None else 0.0)
        nsegs.append(NSeg(t=r.t, q=r.q, qd=r.qd, q_cmd=r.q if r.q_cmd is None else r.q_cmd, tau=y,
                          rate_hz=rate_hz, name=r.name))
    t0 = time.perf_counter()
    data = build_windows(nsegs, history=history, inputs="q,qd,dq")
    res = train(data, TrainConfig(history=history, max_seconds=seconds, threads=threads, device="cpu",
                                  seed=seed, max_epochs=max_epochs), progress_bar=False)
    took = time.perf_counter() - t0

    def predict(seg: Segment) -> np.ndarray:
        p = predict_next(res.model, data.normalizer, history, "q,qd,dq", seg)
        return p + (residual_of(seg) if residual_of is not None else 0.0)

    return predict, took, res
