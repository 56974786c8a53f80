"""policies/training/cost_hint.py: the up-front cost line of a CPU image training run (issue #31 item 5)."""

from policies.training.cost_hint import CostHint, cost_line, fmt_duration


def _run(hint, step_s, n, t0=100.0, first=5.0):
    """Tick `n` steps: the first takes `first` s, the others `step_s`; the lines said."""
    lines, t = [], t0
    for done in range(1, n + 1):
        t += first if done == 1 else step_s
        line = hint.tick(done, t, wall=0.0)
        if line:
            lines.append((done, line))
    return lines


def test_cpu_image_run_says_cost_once_after_timed_steps():
    h = CostHint(300, observation="images", device="cpu", batch=128)
    lines = _run(h, 3.32, 20)
    assert len(lines) == 1
    done, line = lines[0]
    assert done == 4  # 1 warm-up step (not timed) + 3 timed
    assert abs(h.step_s - 3.32) < 1e-9  # the slow first step is left out
    assert "3.32 s per step at batch 128" in line
    assert "the 296 steps left take about 16.4 min" in line
    assert "--obs state" in line and "GPU" in line and "\n" not in line


def test_silent_on_gpu_state_and_short_runs():
    for kw in ({"observation": "images", "device": "cuda"}, {"observation": "state", "device": "cpu"}):
        assert _run(CostHint(300, batch=128, **kw), 3.0, 20) == []
    assert _run(CostHint(3, observation="images", device="cpu", batch=8), 3.0, 3) == []
    # images+state still renders frames: said too
    assert len(_run(CostHint(300, observation="images+state", device="cpu", batch=8), 1.0, 10)) == 1


def test_skipped_ticks_still_give_the_step_time():
    h = CostHint(1000, observation="images", device="cpu", batch=64)
    t, got = 0.0, None
    for done in (1, 3, 5, 7):  # called every second step
        t = done * 2.0
        got = h.tick(done, t, wall=0.0) or got
    assert got is not None and abs(h.step_s - 2.0) < 1e-9


def test_format():
    assert fmt_duration(12) == "12 s" and fmt_duration(996) == "16.6 min"
    assert fmt_duration(3599) == "60.0 min" and fmt_duration(9000) == "2.5 h"
    line = cost_line(0.5, 7200, batch=128, now=0.0)
    assert "about 1.0 h" in line
