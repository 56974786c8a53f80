"""FIRST phase labels: hysteresis, onsets, pre-contact clipping and overlap, thresholds, the CLI."""

from __future__ import annotations

import numpy as np
import pytest

from policies.labels import phases as P
from tests.policy_helpers import write_recording


def test_hysteresis_switches_at_high_and_low_and_keeps_between():
    s = np.array([0, 2, 3, 2.5, 1.5, 1.0, 2.9, 3.0, np.nan, 0.9])
    c = P.hysteresis(s, t_low=1.0, t_high=3.0)
    assert c.tolist() == [False, False, True, True, True, False, False, True, True, False]


def test_contact_runs_take_the_whole_run_above_low_that_reaches_high():
    # a run that rises through low before it crosses high: its rise is contact too (the causal hysteresis
    # starts at the crossing); a run above low that never reaches high is not contact; NaN keeps the state
    s = np.array([0, 1.5, 2.0, 3.5, 2.0, 1.2, 0.5, 1.5, 2.9, 1.5, 0.5, 2.0, np.nan, 3.0, 0.2])
    c = P.contact_runs(s, t_low=1.0, t_high=3.0)
    assert c.tolist() == [False, True, True, True, True, True, False, False, False, False, False,
                          True, True, True, False]
    causal = P.hysteresis(s, 1.0, 3.0)
    assert not (causal & ~c).any() and c[1] and not causal[1]


def test_hysteresis_rejects_inverted_thresholds():
    with pytest.raises(ValueError):
        P.hysteresis(np.zeros(3), 2.0, 1.0)


def test_contact_score_is_l1_norm():
    tau = np.array([[1.0, -2.0, 0.5], [0, 0, 0]])
    assert P.contact_score(tau).tolist() == [3.5, 0.0]


def test_onset_at_t0_has_no_pre_contact():
    t = np.arange(10) * 0.1
    c = np.array([1, 1, 0, 0, 0, 0, 0, 0, 1, 1], bool)
    assert P.onsets(c).tolist() == [0, 8]
    ph = P.label_phases(t, c, pre_s=0.3)
    # onset at 0: nothing before it; onset at 8 (t=0.8): samples with 0.5 <= t < 0.8 are pre-contact
    assert ph.tolist() == [2, 2, 0, 0, 0, 1, 1, 1, 2, 2]


def test_pre_contact_clipped_at_start_and_never_over_contact():
    t = np.arange(20) * 0.1  # 10 Hz
    c = np.zeros(20, bool)
    c[3:5] = True  # onset at t=0.3: 1 s window clipped at the episode start
    c[7:9] = True  # onset at t=0.7: window [−0.3, 0.7) overlaps the first contact, which stays contact
    ph = P.label_phases(t, c, pre_s=1.0)
    assert ph[:3].tolist() == [1, 1, 1]
    assert ph[3:5].tolist() == [2, 2]
    assert ph[5:7].tolist() == [1, 1]
    assert ph[7:9].tolist() == [2, 2]
    assert (ph[9:] == 0).all()


def test_pre_contact_is_one_second_at_any_rate():
    for rate in (10.0, 30.0, 100.0, 1000.0):
        t = np.arange(int(5 * rate)) / rate
        c = t >= 3.0
        ph = P.label_phases(t, c)
        pre_t = t[ph == P.PRE_CONTACT]
        assert pre_t.min() == pytest.approx(2.0) and pre_t.max() < 3.0
        assert len(pre_t) == int(round(rate))


def test_default_thresholds_scale_with_free_noise_and_parse():
    lo, hi = P.default_thresholds([0.1] * 6)
    assert lo == pytest.approx(P.LOW_X * 0.6) and hi == pytest.approx(P.HIGH_X * 0.6)
    assert P.parse_thresholds("1:2.5") == (1.0, 2.5)
    for bad in ("2:1", "x", "1:2:3", "-1:2"):
        with pytest.raises(ValueError):
            P.parse_thresholds(bad)


def test_phases_cli_prints_shares_and_writes_pngs(tmp_path, capsys):
    from factr2_teleop.cli import main

    write_recording(tmp_path / "a.mcap", episodes=2, seconds=4.0, cameras=())
    rc = main(["episodes", "phases", str(tmp_path), "--thresholds", "1:3", "--out", str(tmp_path / "ph")])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "a.mcap#0" in out and "a.mcap#1" in out
    pngs = sorted((tmp_path / "ph").glob("*.png"))
    assert len(pngs) == 2 and all(p.stat().st_size > 5000 for p in pngs)
    assert [p.name for p in pngs] == ["a_ep0.png", "a_ep1.png"]
    # 4 s episode, contact 1.5..2.5 s, pre-contact 0.5..1.5 s: 25 % / 25 % / 50 % free
    row = next(line for line in out.splitlines() if line.startswith("a.mcap#0"))
    free, pre, con = (float(x.rstrip("%")) for x in row.split()[2:5])
    assert abs(pre - 25) < 1.5 and abs(con - 25) < 1.5 and abs(free - 50) < 1.5


def test_phases_cli_without_tau_ext_or_next_is_one_line(tmp_path, capsys):
    from factr2_teleop.cli import main

    write_recording(tmp_path / "a.mcap", episodes=1, seconds=1.0, cameras=(), tau_ext=False)
    rc = main(["episodes", "phases", str(tmp_path), "--thresholds", "1:3"])
    err = capsys.readouterr().err
    assert (
        rc == 2 and "no estimated tau_ext" in err and "--next" in err and len(err.strip().splitlines()) == 1
    )
    rc = main(["episodes", "phases", str(tmp_path)])  # the default thresholds need tau_ext too
    err = capsys.readouterr().err
    assert rc == 2 and "no estimated tau_ext" in err and len(err.strip().splitlines()) == 1
    rc = main(["episodes", "phases", str(tmp_path), "--thresholds", "next"])  # and no checkpoint is named
    err = capsys.readouterr().err
    assert rc == 2 and "--next" in err and len(err.strip().splitlines()) == 1


def test_otsu_splits_noise_from_contact_in_log_space():
    rng = np.random.default_rng(0)
    noise = np.exp(rng.normal(np.log(0.4), 0.4, 8000))  # free motion: median 0.4 N*m
    contact = np.exp(rng.normal(np.log(8.0), 0.6, 2000))  # contact: median 8 N*m
    t = P.otsu_log_threshold(np.r_[noise, contact, np.nan, 0.0])  # NaN and 0 are ignored
    assert 1.0 < t < 3.5, t  # the valley: above ~all of the noise, below ~98 % of the contact
    assert np.mean(noise > t) < 0.01 and np.mean(contact < t) < 0.02
    # the same split with contact the majority (a wiping task) and with the classes scaled together
    t2 = P.otsu_log_threshold(np.r_[noise[:2000], contact, contact])
    assert 1.0 < t2 < 3.5 and P.otsu_log_threshold(10 * np.r_[noise, contact]) == pytest.approx(10 * t, 0.05)
    lo, hi = P.recording_thresholds(np.r_[noise, contact])
    assert lo == pytest.approx(P.OTSU_LOW_X * t) and hi == pytest.approx(P.OTSU_HIGH_X * t)
    assert lo < t < hi  # a band around the valley
    with pytest.raises(ValueError):
        P.otsu_log_threshold(np.full(10, 0.5))


def _skewed_noise_and_contact(rng, n: int, contact_share: float) -> tuple[np.ndarray, np.ndarray]:
    """Free-motion scores as the twin's peg-insert recordings show them (median ~0.35 N*m, a wider tail
    below), and a contact class (median 1.5 N*m) holding contact_share of n samples."""
    nc = int(contact_share * n)
    nf = n - nc
    free = np.r_[np.exp(rng.normal(np.log(0.36), 0.3, int(0.85 * nf))),
                 np.exp(rng.normal(np.log(0.2), 0.6, nf - int(0.85 * nf)))]
    return free, np.exp(rng.normal(np.log(1.5), 0.6, nc))


@pytest.mark.parametrize("share", [0.05, 0.08, 0.2])
def test_min_error_split_stays_above_the_noise_when_contact_is_a_small_share(share):
    rng = np.random.default_rng(1)
    free, contact = _skewed_noise_and_contact(rng, 20000, share)
    s = np.r_[free, contact, np.nan, 0.0]  # NaN and 0 are ignored
    t = P.min_error_log_threshold(s)
    assert np.mean(free > t) < 0.01 and np.mean(contact > t) > 0.5, t
    assert P.valley(s, "min-error") == t and P.min_error_log_threshold(10 * s) == pytest.approx(10 * t, 0.05)
    if share == 0.05:  # where Otsu's split falls inside the free motion (docs/first_labels.md)
        assert np.mean(free > P.otsu_log_threshold(s)) > 0.3
    with pytest.raises(ValueError):
        P.min_error_log_threshold(np.full(10, 0.5))
    with pytest.raises(ValueError):
        P.recording_thresholds(s, split="median")


@pytest.mark.parametrize("shares, warned", [
    ((0.13, 0.59, 0.28), True),  # the collapsed peg-insert training (docs/first_labels.md)
    ((0.10, 0.60, 0.30), True),
    ((0.55, 0.32, 0.13), False),  # the same collection's sound parts, press-fit, wipe, tight-insert
    ((0.67, 0.13, 0.20), False), ((0.29, 0.08, 0.63), False), ((0.45, 0.30, 0.25), False),
    ((1.0, 0.0, 0.0), False), ((0.0, 0.0, 0.0), False),  # no force labels: nothing to say
])
def test_labels_warning_flags_onsets_denser_than_the_pre_contact_window(shares, warned):
    w = P.labels_warning(np.array(shares))
    assert bool(w) == warned
    if warned:
        assert w.startswith("warning:") and "--thresholds" in w and "\n" not in w


def test_phases_cli_default_thresholds_come_from_the_recording(tmp_path, capsys):
    from factr2_teleop.cli import main

    # noise 0.01 N*m per joint, contact 2 N*m per joint (score 12) from 1.5 to 2.5 s of each 4 s episode
    write_recording(tmp_path / "a.mcap", episodes=2, seconds=4.0, cameras=())
    rc = main(["episodes", "phases", str(tmp_path), "--out", str(tmp_path / "ph")])
    out = capsys.readouterr().out
    assert rc == 0, out
    head = out.splitlines()[0]
    assert "recording: Otsu" in head and "2 episodes, 800 samples" in head, head
    lo, hi = (float(head.split(w)[1].split(",")[0].split()[0]) for w in ("T_low ", "T_high "))
    assert 0.1 < lo < hi < 12.0, head  # between the noise (score ~0.05) and the contact (12)
    row = next(line for line in out.splitlines() if line.startswith("a.mcap#0"))
    free, pre, con = (float(x.rstrip("%")) for x in row.split()[2:5])
    assert abs(pre - 25) < 1.5 and abs(con - 25) < 1.5 and abs(free - 50) < 1.5
