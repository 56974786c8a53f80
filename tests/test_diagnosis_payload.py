"""A payload through the arm's kinematics on logs in motor current, with the reference that sets its scale
(calibration/diagnosis/payload.py): pure arrays on pinocchio's sample manipulator (SIMULATED: RNEA plus a
point payload, current = s * torque + noise), around a fixed model as `factr2 diagnose --model` does."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.diagnosis.basis import payload_columns
from calibration.diagnosis.data import differentiate, make_segment
from calibration.diagnosis.loop import diagnose
from calibration.diagnosis.next_loop import fixed_basis, known_mass_alpha
from calibration.diagnosis.payload import (
    CurrentScale,
    alpha_from_known_mass,
    bootstrap,
    choose_scale,
    fit_payload,
    interval,
    summary,
)
from calibration.diagnosis.report import to_json
from calibration.diagnosis.synthetic import trajectory

pin = pytest.importorskip("pinocchio")
MASS, COM = 0.8, np.array([0.02, -0.01, 0.06])
S_TRUE = np.array([0.12, 0.08, 0.12, 0.5, 0.5, 0.5])  # A per N*m


@pytest.fixture(scope="module")
def arm():
    return pin.buildSampleModelManipulator()


def _run(model, seed, mass=MASS, com=COM, seconds=20.0, noise=0.01):
    data = model.createData()
    t, q = trajectory(seconds, 100.0, model.nv, seed)
    qd = differentiate(t, q, 1)
    qdd = differentiate(t, qd, 1)
    tau = np.stack([pin.rnea(model, data, q[i], qd[i], qdd[i]) for i in range(len(t))])
    tau = tau + payload_columns(model, q, qd, qdd) @ np.concatenate([[mass], mass * com])
    cur = S_TRUE * tau + noise * np.random.default_rng(seed + 7).standard_normal(tau.shape)
    return make_segment(f"run{seed}", t, q, qd, cur, "A", qdd=qdd)


def _predict(model):
    """The arm without payload in current (a fixed model that knows the scale: NEXT / its prior)."""
    data = model.createData()

    def predict(segs):
        return segs, {id(s): S_TRUE * np.stack([pin.rnea(model, data, s.q[i], s.qd[i], s.qdd[i])
                                                for i in range(len(s))]) for s in segs}
    return predict


@pytest.fixture(scope="module")
def runs(arm):
    return [_run(arm, 0), _run(arm, 1)], [_run(arm, 2)]


def _diagnose(arm, runs, scale):
    train, held = runs
    basis, tr, ho = fixed_basis(train, held, _predict(arm), "exact arm", arm, scale)
    return diagnose(basis, tr, ho)


def test_payload_in_current_is_found_first_in_kg_with_the_scale_known(arm, runs):
    dg = _diagnose(arm, runs, CurrentScale(S_TRUE, "torque constants"))
    first = dg.steps[1].added
    assert first["effect"] == "payload"  # ranked against gravity_load on every joint, and kept first
    rep = to_json(dg, {"units": "A", "payload_scale": CurrentScale(S_TRUE, "torque constants")})
    p = rep["payload"]
    assert p["in_kg"] and p["mass_kg"] == pytest.approx(MASS, rel=0.02)
    assert np.allclose(p["com_m"], COM, atol=0.005)
    lo, hi = p["interval"]["mass"]
    assert lo <= p["mass_kg"] <= hi and hi - lo < 0.1 * MASS
    assert lo - 0.01 * MASS <= MASS <= hi + 0.01 * MASS  # noise-free regressors: a narrow, near-exact band
    assert "kg" in rep["headline"] and "torque constants" in p["words"]


def test_without_a_reference_the_mass_is_not_stated_in_kg_but_the_centre_is(arm, runs):
    wrong = CurrentScale(1.3 * S_TRUE, "none")  # the ratios right, the common factor unknown
    dg = _diagnose(arm, runs, wrong)
    rep = to_json(dg, {"units": "A", "payload_scale": wrong})
    p = rep["payload"]
    assert not p["in_kg"] and p["mass_kg"] is None
    assert p["mass"] == pytest.approx(MASS / 1.3, rel=0.02)  # kg times the unknown factor
    assert np.allclose(p["com_m"], COM, atol=0.005)  # the centre does not depend on it
    assert "cannot be stated in kg" in p["words"] and "cannot be stated in kg" in rep["headline"]


def test_a_known_mass_on_a_reference_run_sets_the_common_factor(arm, runs):
    wrong = CurrentScale(1.3 * S_TRUE, "description masses")
    train, held = runs
    basis, _, _ = fixed_basis(train, held, _predict(arm), "exact arm", arm, wrong)
    ref = [_run(arm, 5, mass=0.5, com=np.array([0.0, 0.0, 0.03]))]
    alpha = known_mass_alpha(basis, ref, _predict(arm), 0.5)
    assert alpha == pytest.approx(1 / 1.3, rel=0.02)
    fixed = choose_scale("A", prior_scale=wrong.scale, known_alpha=alpha)
    assert fixed.reference == "known mass" and np.allclose(fixed.scale, S_TRUE, rtol=0.02)


def test_choose_scale_and_alpha_rules():
    assert choose_scale("N*m").reference == "torque" and choose_scale("N*m").in_kg
    kt = choose_scale("A", kt=[2.0, 4.0])
    assert kt.reference == "torque constants" and np.allclose(kt.scale, [0.5, 0.25])
    assert choose_scale("A") is None  # no scale at all: no payload through the kinematics
    assert not choose_scale("A", prior_scale=[1.0], referenced=False).in_kg
    assert alpha_from_known_mass(1.2, 1.0) == pytest.approx(1.2)
    with pytest.raises(ValueError):
        alpha_from_known_mass(-0.1, 1.0)


def test_bootstrap_interval_is_honest_for_white_noise(arm):
    seg = _run(arm, 3, noise=0.05)
    cols = payload_columns(arm, seg.q, seg.qd, seg.qdd) * S_TRUE[None, :, None]
    res = seg.tau - _predict(arm)([seg])[1][id(seg)]
    coef = fit_payload(res, cols)
    assert coef[0] == pytest.approx(MASS, rel=0.03)
    basis, tr, ho = fixed_basis([seg], [seg], _predict(arm), "exact arm", arm,
                                CurrentScale(S_TRUE, "torque constants"))
    from calibration.diagnosis.effects import Effect
    from calibration.diagnosis.greybox import Design, GreyBox

    d = Design(basis, tr)
    model = GreyBox(basis, [Effect("payload", 5, {"dynamics": "full"})]).fit(d)
    draws = bootstrap(model, d, 0, n_boot=100)
    iv = interval(draws)
    assert iv["mass"][0] <= MASS <= iv["mass"][1]
    s = summary(model.effects[0].coef, draws, CurrentScale(S_TRUE, "torque constants"))
    assert s["mass_kg"] == pytest.approx(MASS, rel=0.03) and "interval" in s


def test_cli_prior_only_on_current_logs_states_kg_and_refuses_a_lone_known_mass(tmp_path):
    """`factr2 diagnose LOADED --model next.json --prior-only`: a checkpoint of arm piper in A whose prior is
    identified-current (here the description with scales S, as a calibration of a unit whose CAD masses
    are right would fit it); the loaded runs carry a payload the checkpoint never saw."""
    import json

    torch = pytest.importorskip("torch")
    torch.set_num_threads(1)
    from calibration.next.checkpoint import NextCheckpoint, save_checkpoint
    from calibration.next.data import Segment as NSeg
    from calibration.next.data import build_windows
    from calibration.next.prior import description_prior
    from calibration.next.scaled_prior import ScaledPrior
    from calibration.next.train import TrainConfig, train
    from factr2_teleop.cli import main
    from hardware.arms import load_arm

    desc = load_arm("piper")
    model = desc.pinocchio_model()
    data = model.createData()
    s = np.array([0.2, 0.2, 0.2, 0.5, 0.5, 0.5])
    paths = []
    for seed in range(2):
        t, q = trajectory(15.0, 100.0, 6, seed)
        q = 0.5 * q + np.array([0.0, 1.2, -1.2, 0.0, 0.0, 0.0])
        qd = differentiate(t, q, 1)
        qdd = differentiate(t, qd, 1)
        tau = np.stack([pin.rnea(model, data, q[i], qd[i], qdd[i]) for i in range(len(t))])
        tau += payload_columns(model, q, qd, qdd) @ np.array([0.5, 0.0, 0.0, 0.5 * 0.05])
        cur = s * tau + 0.005 * np.random.default_rng(seed).standard_normal(tau.shape)
        p = tmp_path / f"loaded{seed}.npz"
        np.savez(p, t=t, q=q, qd=qd, q_cmd=q, current=cur, joint_names=np.array(desc.joint_names))
        paths.append(str(p))
    d0 = np.load(paths[0])
    w = build_windows([NSeg(t=d0["t"], q=d0["q"], qd=d0["qd"], q_cmd=d0["q"], tau=d0["current"],
                            rate_hz=100.0)], history=10, inputs="q,qd,dq")
    res = train(w, TrainConfig(arch="mlp", history=10, head_hidden=16, max_epochs=1, threads=1, device="cpu",
                               samples_per_epoch=512), progress_bar=False)
    ck = NextCheckpoint(model=res.model, normalizer=w.normalizer, arm="piper",
                        joint_names=list(desc.joint_names), units="A", inputs="q,qd,dq", rate_hz=100.0,
                        x_min=w.x_min, x_max=w.x_max, prior=ScaledPrior(description_prior("piper"), s))
    ckpt = save_checkpoint(ck, tmp_path / "next")
    out = tmp_path / "diag"
    assert main(["diagnose", *paths, "--model", str(ckpt), "--prior-only", "--out", str(out), "--no-plots",
                 "--max-effects", "1"]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["steps"][1]["added"]["effect"] == "payload"
    assert rep["payload"]["reference"] == "description masses" and rep["payload"]["in_kg"]
    assert rep["payload"]["mass_kg"] == pytest.approx(0.5, rel=0.1)
    assert main(["diagnose", *paths, "--model", str(ckpt), "--prior-only", "--mass-reference", "none",
                 "--out", str(out), "--no-plots", "--max-effects", "1"]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["payload"]["mass_kg"] is None and "cannot be stated in kg" in rep["headline"]
    assert main(["diagnose", *paths, "--known-mass", "0.5", "--out", str(out)]) == 2


UR5 = __import__("pathlib").Path(__file__).resolve().parents[1].parent / "shared" / "data" / "ur5_kufieta2014"


@pytest.mark.skipif(not (UR5 / "Movement_No4_Acc.npz").exists(),
                    reason="UR5 logs not present (shared/data/ur5_kufieta2014)")
def test_real_ur5_current_with_an_added_payload(tmp_path, monkeypatch):
    """Real UR5 current (Kufieta 2014) plus a 1.5 kg payload through the UR5 description's regressor and
    the controller's own current-per-torque ratio; the fixed model is the controller's current_cmd (it
    never saw the payload). Scale known: the mass in kg within 10 %; the ratios without a reference: not
    in kg, the centre within 3 cm. The full three-case run: bench/bench_payload_ur5.py."""
    import subprocess
    import sys

    root = __import__("pathlib").Path(__file__).resolve().parents[1]
    monkeypatch.setenv("FACTR2_ARMS", str(tmp_path / "arms"))
    subprocess.run([sys.executable, "-m", "factr2_teleop.cli", "arm", "import",
                    str(root / "hardware/arms/ur5.urdf"), "--name", "ur5", "--q-home",
                    "0,-1.57,1.57,-1.57,-1.57,0"], check=True, stdout=subprocess.DEVNULL)
    from calibration.diagnosis.data import load_segments
    from hardware.arms import load_arm

    kin = load_arm("ur5").pinocchio_model()
    com = np.array([0.01, -0.02, 0.10])
    segs, cmd = {}, {}
    raws = {r: dict(np.load(UR5 / f"{r}.npz")) for r in ("Movement_No4_Acc", "Movement_No2")}
    i, tq = (np.concatenate([a[k] for a in raws.values()]) for k in ("current_cmd", "torque_cmd"))
    s_true = np.sum(i * tq, 0) / np.sum(tq * tq, 0)
    for r, a in raws.items():
        extra = s_true * (payload_columns(kin, a["q"], a["qd"], a["qdd_cmd"]) @ np.r_[1.5, 1.5 * com])
        p = tmp_path / f"{r}.npz"
        np.savez(p, **{**a, "current": a["current"] + extra, "current_cmd": a["current_cmd"]})
        segs[r] = load_segments(p)
        cmd[r] = a["current_cmd"]

    def friction(qd):
        return np.stack([np.tanh(qd / 0.01), qd, np.ones_like(qd)], -1)

    a = raws["Movement_No4_Acc"]  # the controller's current_cmd has no friction: fitted on the unloaded run
    fr = np.stack([np.linalg.lstsq(friction(a["qd"][:, j]), (a["current"] - a["current_cmd"])[:, j],
                                   rcond=None)[0] for j in range(6)])

    def predict(ss):  # the controller's commanded current + that friction, on the segments' own samples
        out = {}
        for s in ss:
            t0 = raws[s.name]["t"][0]
            c = np.stack([np.interp(s.t, raws[s.name]["t"] - t0, x) for x in cmd[s.name].T], 1)
            out[id(s)] = c + np.einsum("tjk,jk->tj", friction(s.qd), fr)
        return ss, out

    def run(scale):
        basis, tr, ho = fixed_basis(segs["Movement_No4_Acc"], segs["Movement_No2"], predict,
                                    "UR controller's current_cmd", kin, scale)
        dg = diagnose(basis, tr, ho)
        return dg, to_json(dg, {"units": "A", "payload_scale": scale})

    _, rep = run(CurrentScale(s_true, "torque constants"))
    assert rep["steps"][1]["added"]["effect"] == "payload"  # first, against per-joint gravity loads
    assert rep["payload"]["mass_kg"] == pytest.approx(1.5, rel=0.1)
    assert np.linalg.norm(np.array(rep["payload"]["com_m"]) - com) < 0.08  # one 30 s run: 5 cm measured
    assert rep["after"]["heldout_l1"][1] < 0.8 * rep["before"]["heldout_l1"][1]
    _, other = run(CurrentScale(1.25 * s_true, "none"))
    assert other["payload"]["mass_kg"] is None and "cannot be stated in kg" in other["payload"]["words"]
    assert other["payload"]["mass"] == pytest.approx(rep["payload"]["mass_kg"] / 1.25, rel=0.02)
    assert np.allclose(other["payload"]["com_m"], rep["payload"]["com_m"], atol=0.002)


def test_pruning_drops_an_effect_whose_refit_became_impossible(arm):
    """A payload of negative mass (the model over-predicts the load) lowers the held-out error but is not a
    payload: the backward pass drops it and says why."""
    from calibration.diagnosis.effects import Effect
    from calibration.diagnosis.greybox import Design, GreyBox
    from calibration.diagnosis.loop import LoopConfig, _eval, _prune

    train, held = [_run(arm, 0, mass=-0.4)], [_run(arm, 2, mass=-0.4)]
    basis, tr, ho = fixed_basis(train, held, _predict(arm), "exact arm", arm,
                                CurrentScale(S_TRUE, "torque constants"))
    dtr, dho = Design(basis, tr), Design(basis, ho)
    model = GreyBox(basis, [Effect("payload", 5, {"dynamics": "full"})]).fit(dtr)
    assert model.effects[0].implausible()
    l1, rms, _ = _eval(model, dtr, dho)
    kept, pruned = _prune(model, dtr, dho, l1, 0.005 * rms, LoopConfig(), lambda s: None)
    assert kept.effects == [] and "not positive" in pruned[0]["implausible"]
