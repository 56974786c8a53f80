"""bench.cap_wrist's turn counter: the monotone runs of a wrist trajectory [rad]."""

import numpy as np

from bench.cap_wrist import runs


def test_runs_split_a_demonstrations_turns():
    # probe quarter turn, back, one full stroke, back (the cap-screw operator's pattern)
    x = np.concatenate([np.linspace(1.85, 0.28, 20), np.linspace(0.28, 1.85, 10),
                        np.linspace(1.85, -1.85, 40), np.linspace(-1.85, 1.85, 10)])
    r = runs(x)
    assert np.allclose(r, [-1.57, 1.57, -3.7, 3.7], atol=1e-9)


def test_runs_steps_under_eps_continue_a_run():
    x = np.array([0.0, -0.5, -0.5005, -1.0, 0.0])  # a 0.5 mrad wobble does not end the clockwise run
    assert np.allclose(runs(x), [-1.0, 1.0])
    assert runs(np.zeros(5)) == []
