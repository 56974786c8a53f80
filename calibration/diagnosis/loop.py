"""The diagnose loop: fit, held-out error, trace, add the best candidate, refit, until nothing helps.

A candidate is accepted only when it lowers the held-out mean absolute error of its joint by more than
max(rel_gain * that error, abs_gain * RMS of that joint's held-out target) and does not raise the mean over
joints. Candidates are tried in trace order (at most `tries` per step). With an arm description (or around
NEXT) held-out gains compare across candidates, and of those that pass, the effect that removes the most of
the arm's held-out residual is kept (mean square summed over joints, `heldout_explained`): the trace
proposes candidates alternately by the torque they explain in the training residual (`trace.rank_explained`:
an arm-wide payload first when it explains more N*m in total) and by the fraction of their own joint's
residual (`trace.rank`: structure on a small joint); those within `close` of the best of either order are
all fitted, and a later one replaces an earlier one only when it removes more by `rel_gain` of the arm's
held-out mean square (the trace ranks on the training residual before the refit; near-ties are told apart
by what they do after it). With the data-only basis the trial fits keep the ridge chosen before the effect,
so their gains are not comparable: there candidates are tried by fraction and the first that passes is
kept. Of nested families (an offset inside a spring) the simpler is kept unless the extra parameter earns the
acceptance threshold on its own.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np

from .basis import select_ridge
from .effects import Effect
from .greybox import Design, GreyBox, errors
from .trace import Candidate, candidates, rank, rank_explained


@dataclass
class LoopConfig:
    rel_gain: float = 0.02
    abs_gain: float = 0.005
    tries: int = 4  # trial fits per round
    tries_per_joint: int = 2
    close: float = 0.5  # candidates >= close x the best of either trace order are compared on held-out gain
    max_effects: int = 20
    min_score: float = 1e-3
    worst_joint: bool = True  # a round that passes nothing tries the worst joint's best candidate if untried


@dataclass
class Step:
    added: dict | None
    heldout_l1: list
    heldout_rms: list
    train_l1: list
    model: GreyBox = field(repr=False)
    residual_before: tuple | None = field(default=None, repr=False)  # (train residual, heldout residual)


@dataclass
class Diagnosis:
    steps: list[Step]
    model: GreyBox
    train: Design
    heldout: Design
    config: LoopConfig
    rejected: list = field(default_factory=list)
    pruned: list = field(default_factory=list)
    declared: list = field(default_factory=list)  # effects given up front (a first pass), not found here

    def found(self) -> list:
        """The effects this run added (declared ones excluded)."""
        keys = {e.key for e in self.declared}
        return [e for e in self.model.effects if e.key not in keys]


def _eval(model: GreyBox, train: Design, held: Design):
    ltr, _ = errors(train.y, model.predict(train))
    l1, rms = errors(held.y, model.predict(held))
    return l1, rms, ltr


def diagnose(basis, train_segments, heldout_segments, config: LoopConfig | None = None,
             log=lambda s: None, declared=None) -> Diagnosis:
    """declared: effects (effects.Effect; family, joint, hyper) known before this run -- e.g. a first pass
    on other data that explained the arm's own friction -- fitted with the rigid part from the start; the loop
    looks for what is missing on top of them."""
    cfg = config or LoopConfig()
    declared = [copy.copy(e) for e in (declared or [])]
    if hasattr(basis, "per_joint"):
        ridge = select_ridge(basis, train_segments)
        log(f"ridge per joint (leave-one-fold-out on the training data): {ridge}")
    train, held = Design(basis, train_segments), Design(basis, heldout_segments)
    model = GreyBox(basis, [copy.copy(e) for e in declared]).fit(train)
    l1, rms, ltr = _eval(model, train, held)
    steps = [Step(None, l1.tolist(), rms.tolist(), ltr.tolist(), model)]
    floor = cfg.abs_gain * np.sqrt(np.mean(held.y ** 2, 0))
    log(f"rigid part only: held-out L1 {np.round(l1, 4).tolist()} (mean {l1.mean():.4f})")
    rejected = []
    pool: list = []  # candidates of joints whose fit has not changed since they were scored
    changed = list(range(model.n))
    while len(model.effects) < cfg.max_effects:
        res_train = train.y - model.predict(train)
        if not getattr(basis, "separable", False):
            changed = list(range(model.n))
        taken = {e.slot for e in model.effects}
        # arm-wide candidates span every joint: rescored each round with the rest
        pool = [c for c in pool if c.effect.joint not in changed and c.effect.slot not in taken
                and not c.effect.wide]
        pool += candidates(model, train, res_train, joints=changed)
        pool.sort(key=rank)
        cands = [c for c in pool if c.score >= cfg.min_score]
        accepted = None
        # With a data-only basis the trial fits use the ridge chosen before the effect (it is re-chosen only
        # for the effect kept), so their held-out gains are not comparable: the trace order decides there.
        comparable = not hasattr(basis, "per_joint")
        order, near = proposals(cands, cfg.close if comparable else np.inf, comparable)
        order = payload_before_loads(order)
        tries: dict = {}
        compared: list[dict] = []  # every trial fit of the round, with what it removes (the ranking shown)
        for c in order:
            if accepted is not None and not near(c):
                break  # a close candidate passed; the weaker ones are not compared
            if sum(tries.values()) >= cfg.tries:
                break
            # at most `tries_per_joint` of them on one joint: the score is a fraction of each joint's
            # own residual, so a small joint with a structured but unexplainable residual must not use up
            # the tries of a joint with a real effect
            # a load: the payload and the per-joint gravity-like loads share one budget (they compete for the
            # same torque), so loads on four joints cannot use up a round the payload never got
            who = "arm" if c.effect.wide or c.effect.family == "gravity_load" else c.effect.joint
            if tries.get(who, 0) >= cfg.tries_per_joint:
                continue
            tries[who] = tries.get(who, 0) + 1
            tried = _try(model, c, train, held, (l1, rms), floor, cfg)
            compared.append({"effect": c.effect.family, "joint": c.effect.joint, "passed": tried is not None,
                             "heldout_explained_units": c.evidence.get("heldout_explained_units")})
            if tried is None:
                _reject(c, rejected, log)
                continue
            # a later close candidate must explain more of the arm's held-out residual than the kept one, by
            # the relative acceptance threshold
            if accepted is None or tried[-1] > accepted[-1] + cfg.rel_gain * float(np.sum(rms ** 2)):
                accepted = tried
            if not near(c):
                break  # outside the close group the first that passes is kept
        worst = int(np.argmax(l1))
        if accepted is None and cfg.worst_joint and worst not in tries:
            # before giving up, the joint with the largest held-out error gets one trial fit of its best
            # candidate: scores are fractions of each joint's own residual, so near-perfect fits of tiny
            # residuals on other joints can use up a round while that joint is never tried (only that one
            # joint: one extra try per joint added spurious terms on the clean twin)
            c = next((c for c in cands if not c.effect.wide and c.effect.joint == worst), None)
            if c is not None:
                accepted = _try(model, c, train, held, (l1, rms), floor, cfg)
                if accepted is None:
                    _reject(c, rejected, log)
        if accepted is None:
            break
        accepted = _simpler(model, accepted, train, held, (l1, rms), floor, cfg, log)
        accepted = accepted[:5]
        c, trial, l1_new, rms_new, ltr_new = accepted
        added = c.effect.__class__(c.effect.family, c.effect.joint, dict(c.effect.hyper))
        final = next(e for e in trial.effects if e.key == c.effect.key)
        added.coef = final.coef
        held_res = held.y - model.predict(held)
        steps.append(Step({**final.to_json(), "evidence": {**c.evidence, "compared_in_round": compared}},
                          l1_new.tolist(), rms_new.tolist(),
                          ltr_new.tolist(), trial, (res_train, held_res)))
        log(f"added {c.effect.family} on {_where(c.effect)} {final.params()}: held-out L1 "
            f"{_where(c.effect)} {_l1_of(c.effect, l1):.4f} -> {_l1_of(c.effect, l1_new):.4f}")
        changed = list(range(model.n)) if c.effect.wide else [c.effect.joint]
        if hasattr(basis, "per_joint"):  # re-choose the ridge of that joint now that the effect is known
            def effects_of(seg, trial=trial):
                ds = Design(basis, [seg])
                return trial.predict(ds) - trial.rigid(ds)

            select_ridge(basis, train_segments, joints=changed, effects_of=effects_of)
            trial.fit(train)
            l1_new, rms_new, ltr_new = _eval(trial, train, held)
            steps[-1] = Step(steps[-1].added, l1_new.tolist(), rms_new.tolist(), ltr_new.tolist(), trial,
                             steps[-1].residual_before)
        model, l1, rms = trial, l1_new, rms_new
    model, pruned = _prune(model, train, held, l1, floor, cfg, log)
    return Diagnosis(steps, model, train, held, cfg, rejected, pruned, declared)


def proposals(cands: list[Candidate], close: float, by_units: bool):
    """The order in which a round's candidates (sorted by `trace.rank`) are tried, and near(c): whether c is
    close enough to the best to be compared on held-out gain rather than skipped once one has passed.
    by_units (held-out gains comparable: an arm description, NEXT): alternately the next best by torque
    explained (`trace.rank_explained`) and by fraction of its own joint's residual, so the effect removing
    the most N*m is tried first and small joints' structure is still tried; near: within `close` of the best
    fraction or of the most explained (sum of squares). Else the fraction order alone."""
    best = cands[0].score if cands else 0.0
    most = max((c.explained ** 2 for c in cands), default=0.0)

    def near(c: Candidate) -> bool:
        return c.score >= close * best or (by_units and c.explained ** 2 >= close * most)

    if not by_units:
        return list(cands), near
    units = sorted(cands, key=rank_explained)
    order, seen = [], set()
    for pair in zip(units, cands):
        for c in pair:
            if id(c) not in seen:
                seen.add(id(c))
                order.append(c)
    return order, near


def payload_before_loads(order: list[Candidate]) -> list[Candidate]:
    """The best payload candidate right before the first gravity_load of the round (where both are offered,
    around a fixed model with a known arm): the two explain the same torque and are ranked on the held-out
    residual they remove, so the one that goes through the arm's kinematics is always among those fitted
    (on the real UR5 a per-joint load's 42 free columns explained more training residual and then
    extrapolated by orders of magnitude on held-out runs, and four of them used up the round)."""
    loads = [k for k, c in enumerate(order) if c.effect.family == "gravity_load"]
    pays = [k for k, c in enumerate(order) if c.effect.family == "payload"]
    if not loads or not pays or pays[0] < loads[0]:
        return order
    first = order[pays[0]]
    rest = [c for c in order if c is not first]
    rest.insert(loads[0], first)
    return rest


def _reject(c, rejected: list, log) -> None:
    """Record (and log) a candidate that failed its trial fit, with the evidence of what failed."""
    chk = c.evidence["heldout_check"]
    rejected.append({"effect": c.effect.family, "joint": c.effect.joint, "hyper": c.effect.hyper,
                     "score": round(c.score, 4), **chk})
    log(f"  rejected {c.effect.family} on {_where(c.effect)}: " + (chk.get("implausible") or
        f"held-out gain {chk['heldout_gain']:.4g} <= {chk['needed']:.4g}")
        + (f" -- evidence of {chk['evidence_of']} (candidates: {', '.join(chk['candidates'])})"
           if "evidence_of" in chk else ""))


def _where(e: Effect) -> str:
    return "all joints (attached to the last link)" if e.wide else f"joint {e.joint}"


def _l1_of(e: Effect, l1) -> float:
    """The held-out L1 an effect is judged on: its joint's, or the sum over joints for an arm-wide one (so
    that its gain compares with a single-joint effect's in the same units)."""
    return float(np.sum(l1)) if e.wide else float(l1[e.joint])


def _need(e: Effect, l1, floor, cfg: LoopConfig) -> float:
    return float(max(cfg.rel_gain * _l1_of(e, l1), np.sum(floor) if e.wide else floor[e.joint]))


def _try(model: GreyBox, c, train: Design, held: Design, before, floor, cfg: LoopConfig):
    """Fit the model with candidate c -> (c, trial, l1, rms, train l1, explained) when its joint's held-out
    L1 (arm-wide effects: the sum over joints) drops by more than the threshold and the mean does not rise;
    else None. before: (held-out L1, held-out RMS) per joint without c. explained: what c removes from the
    arm's held-out residual, mean square summed over joints [units^2] (`heldout_explained`)."""
    l1, rms = before
    trial = model.with_effect(c.effect).fit(train)
    t_l1, t_rms, t_ltr = _eval(trial, train, held)
    gain = _l1_of(c.effect, l1) - _l1_of(c.effect, t_l1)
    need = _need(c.effect, l1, floor, cfg)
    ex = heldout_explained(rms, t_rms)
    c.evidence.update({"heldout_l1_joint_before": round(_l1_of(c.effect, l1), 6),
                       "heldout_l1_joint_after": round(_l1_of(c.effect, t_l1), 6),
                       "heldout_explained_units": round(float(np.sqrt(max(ex, 0.0))), 6)})
    c.evidence["heldout_check"] = {"heldout_gain": gain, "needed": need}
    fitted = next(e for e in trial.effects if e.key == c.effect.key)
    why = fitted.implausible()
    if why:
        c.evidence["heldout_check"].update({"implausible": why, **fitted.evidence_of()})
        return None
    if gain > need and t_l1.mean() <= l1.mean():
        return c, trial, t_l1, t_rms, t_ltr, ex
    return None


def heldout_explained(rms_before, rms_after) -> float:
    """What an effect removes from the arm's held-out residual: the drop of its mean square summed over
    joints [units^2] (negative when it adds). Squares, not L1: squared residuals of independent parts add, so
    a smooth load under a joint's friction step is credited with its full size, where the L1 of the sum
    falls by much less (on the twin, a 0.3 kg payload lowered the held-out L1 of the loaded joints less than
    the base's friction term lowered the base's, while removing twice its mean square)."""
    return float(np.sum(np.square(rms_before)) - np.sum(np.square(rms_after)))


SIMPLER = {"position_spring": "current_offset"}  # family -> the nested family with fewer parameters


def _simpler(model: GreyBox, accepted, train: Design, held: Design, before, floor, cfg: LoopConfig, log):
    """Occam between nested families: a spring k*(q - q_ref) + c whose slope does not lower the held-out
    error by the acceptance threshold is an offset."""
    c = accepted[0]
    fam = SIMPLER.get(c.effect.family)
    if fam is None:
        return accepted
    alt = Effect(fam, c.effect.joint)
    if alt.slot in {e.slot for e in model.effects}:
        return accepted
    cand = Candidate(alt, c.score, {**c.evidence, "columns": 1, "simpler_than": c.effect.family},
                     c.explained, c.residual)
    tried = _try(model, cand, train, held, before, floor, cfg)
    j = c.effect.joint
    need = max(cfg.rel_gain * accepted[2][j], floor[j])
    if tried is not None and tried[2][j] - accepted[2][j] <= need:
        log(f"  {fam} on joint {j} explains as much as {c.effect.family} (held-out L1 {tried[2][j]:.4f} vs "
            f"{accepted[2][j]:.4f}): the simpler one is kept")
        return tried
    return accepted


def _prune(model: GreyBox, train: Design, held: Design, l1, floor, cfg: LoopConfig, log):
    """Backward pass: greedy forward selection can add an effect early that a later one makes redundant
    (with shared rigid parameters a scale error on one joint first leaks into the others). Drop every effect
    whose removal does not raise its joint's held-out error by more than the acceptance threshold, and every
    effect whose refitted parameters became impossible for its family (a payload of negative mass after
    later effects took its torque: seen on the twin with the rigid part held to the description)."""
    pruned = []
    for e in list(model.effects):  # declared effects too: one the data does not need is reported as pruned
        why = e.implausible()
        if len(model.effects) <= 1 and not why:
            break
        # copies: a trial fit must not overwrite the coefficients of the effects the kept model shares
        trial = GreyBox(model.basis, [copy.copy(x) for x in model.effects if x is not e]).fit(train)
        t_l1, _, _ = _eval(trial, train, held)
        harmless = t_l1.mean() <= l1.mean() * (1 + cfg.rel_gain)
        if (_l1_of(e, t_l1) - _l1_of(e, l1) <= _need(e, l1, floor, cfg) and harmless) or why:
            pruned.append({**e.to_json(), "heldout_l1_joint_with": _l1_of(e, l1),
                           "heldout_l1_joint_without": _l1_of(e, t_l1),
                           **({"implausible": why} if why else {})})
            log(f"pruned {e.family} on {_where(e)}: held-out L1 {_l1_of(e, l1):.4f} -> {_l1_of(e, t_l1):.4f} "
                "without it" + (f" ({why})" if why else ""))
            model, l1 = trial, t_l1
    return model, pruned
