"""Operator takeover (issue #33) on the data side: a hand-back re-plans (no executed action older than the
observation at hand-back), the sampler's source weights compose with FIRST's phase weights (shares within
1 % over 1e5 draws), and a rollout's per-tick sources come back from its marks."""

import numpy as np
import pytest

from hardware.recording.interventions import SOURCE_DEMO, SOURCE_OPERATOR, SOURCE_POLICY, SOURCE_PRE
from policies.data.sampler import (
    DEFAULT_SOURCE_WEIGHTS,
    FirstSampler,
    expected_source_shares,
    parse_source_weights,
    sample_probabilities,
)
from policies.rollout.schedule import ENSEMBLE, RECEDING, Chunk, ChunkSchedule, PolicyHold

DT = 1 / 30.0


def _chunk(t_obs, h=8, a=7, value=0.0):
    return Chunk(t_obs=t_obs, actions=np.full((h, a), value), dt=DT)


@pytest.mark.parametrize("mode", [ENSEMBLE, RECEDING])
def test_hand_back_drops_every_chunk_observed_before_it(mode):
    s = ChunkSchedule(mode=mode, dt=DT, q_min=np.full(7, -9.0), q_max=np.full(7, 9.0), k_exec=2)
    for k in range(10):  # the policy ran before the takeover
        s.add(_chunk(k * DT, value=1.0))
    t_hb = 0.5
    s.restart(t_hb)
    assert s.target(t_hb + 0.002)[1].kind is PolicyHold.FIRST_CHUNK  # nothing old is executed meanwhile
    s.add(_chunk(t_hb - 0.01, value=1.0))  # a chunk still in inference when the hand let go
    assert s.stale_dropped == 1 and s.target(t_hb + 0.004)[0] is None
    s.add(_chunk(t_hb + 0.002, value=2.0))  # the fresh observation's chunk
    for t in np.arange(t_hb + 0.004, t_hb + 0.2, 0.002):
        a, why, age = s.target(t)
        assert why is None and np.all(a == 2.0)  # only the fresh chunk's actions
        assert age <= t - t_hb  # no executed action older than the hand-back observation
    assert all(c.t_obs >= t_hb for c in s.chunks)


def test_source_weights_compose_with_phase_weights_within_one_percent():
    rng = np.random.default_rng(3)
    n = 5000
    phases = rng.choice(3, n, p=[0.6, 0.25, 0.15])
    sources = rng.choice(4, n, p=[0.5, 0.3, 0.05, 0.15])
    ratio, weights = (1.0, 5.0, 1.0), (1.0, 1.0, 0.25, 2.0)
    sampler = FirstSampler(phases, ratio, seed=1, samples_per_epoch=100_000, sources=sources,
                           source_weights=weights)
    draws = sampler.epoch_indices(0)
    assert len(draws) == 100_000
    got = np.bincount(sources[draws], minlength=4) / len(draws)
    want = expected_source_shares(phases, ratio, sources, weights)
    assert np.all(np.abs(got - want) <= 0.01), (got, want)
    # per (phase, source) cell too: p ~ w_phase * w_source
    w = np.asarray(ratio)[phases] * np.asarray(weights)[sources]
    for ph in range(3):
        for so in range(4):
            cell = (phases == ph) & (sources == so)
            share = np.mean(cell[draws])
            assert abs(share - w[cell].sum() / w.sum()) <= 0.01
    # dropping the pre-intervention window: never drawn
    p = sample_probabilities(phases, ratio, sources, (1.0, 1.0, 0.0, 2.0))
    assert p[sources == SOURCE_PRE].sum() == 0.0
    # without sources the probabilities are FIRST's, bit for bit
    assert np.array_equal(sample_probabilities(phases, ratio),
                          FirstSampler(phases, ratio, seed=1, sources=None, source_weights=weights).p)


def test_source_weights_flag_parses_and_refuses_in_one_line():
    assert parse_source_weights("pre=0,operator=3") == (1.0, 1.0, 0.0, 3.0)
    assert parse_source_weights("") == DEFAULT_SOURCE_WEIGHTS
    with pytest.raises(ValueError, match="NAME=WEIGHT"):
        parse_source_weights("intervention=2")
    with pytest.raises(ValueError, match="NAME=WEIGHT"):
        parse_source_weights("pre=-1")


class _Rec:
    def __init__(self, info, topics, driver):
        self.info = self.session = info  # Recording.info, and its former name
        self.topics, self._driver = topics, driver

    def topic(self, name):
        from types import SimpleNamespace

        t, d = self._driver
        return SimpleNamespace(t=np.asarray(t, float), fields={"driver": np.asarray(d)})


class _Ep:
    def __init__(self, rec, events, t_start=0.0, t_stop=10.0):
        self.recording, self.events, self.t_start, self.t_stop = rec, events, t_start, t_stop
        self.topics = rec.topics


def test_per_tick_sources_come_back_from_the_driver_marks():
    import json

    from hardware.recording import schemas as S
    from hardware.recording.interventions import driver_on_grid, interventions, source_on_grid

    # a rollout: policy from 0, the operator from 4.0 (takeover) to 6.5 (the policy's fresh chunk), pre 2 s
    rec = _Rec({"operator": "policy"}, [S.TOPIC_ROLLOUT_DRIVER], ([0.0, 4.0, 6.5], [0, 1, 0]))
    info = json.dumps({"by": "hand", "pre_window_s": 2.0})
    ep = _Ep(rec, [{"kind": "takeover", "t": 4.0, "text": info, "value": 0.5},
                   {"kind": "handback", "t": 6.4, "text": json.dumps({"by": "hand"}), "value": 0.0}])
    grid = np.arange(0, 10, 0.002)
    drv = driver_on_grid(ep, grid)
    assert np.array_equal(drv, ((grid >= 4.0) & (grid < 6.5)).astype(np.int8))  # exact per tick
    src = source_on_grid(ep, grid)
    assert np.all(src[(grid >= 2.0) & (grid < 4.0)] == SOURCE_PRE)
    assert np.all(src[(grid >= 4.0) & (grid < 6.5)] == SOURCE_OPERATOR)
    assert np.all(src[grid < 2.0] == SOURCE_POLICY) and np.all(src[grid >= 6.5] == SOURCE_POLICY)
    (m,) = interventions(ep)
    assert (m["t_takeover"], m["t_handback"], m["by"], m["handback_by"]) == (4.0, 6.4, "hand", "hand")
    # a demonstration: every tick is the demonstration's
    demo = _Ep(_Rec({"operator": "ada"}, [], ([], [])), [])
    assert np.all(source_on_grid(demo, grid) == SOURCE_DEMO)


def test_the_rollout_screen_says_who_drives_and_the_hand_against_its_threshold():
    from factr2_teleop.tui.rollout import status_lines
    from factr2_teleop.tui.rollout_ctl import RolloutState

    st = RolloutState(status="running", episodes=1, episode=1, driver="operator", takeovers=2, hand_nm=0.4,
                      grab_nm=0.3)
    line = next(x for x in status_lines(st) if x.startswith("drives:"))
    assert "OPERATOR" in line and "takeovers 2" in line and "hand 0.40 / 0.30 N*m" in line and "o:" in line
    assert not any(x.startswith("drives:") for x in status_lines(RolloutState(status="running")))
