"""bench/first_images_workers.py's pure parts: rollout blocks and their episode seeds (issue #31 item 5)."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import factr2_teleop.session.task_episodes as tc  # noqa: E402
from bench.first_images_gpu import parse_args  # noqa: E402
from bench.first_images_workers import blocks, merge_rollouts, shift_episode_seeds  # noqa: E402


def test_blocks_cover_every_episode_once():
    for total, parts in ((40, 20), (7, 3), (3, 8), (1, 1)):
        b = blocks(total, parts)
        assert [k for k0, n in b for k in range(k0, k0 + n)] == list(range(total))
        assert max(n for _, n in b) - min(n for _, n in b) <= 1


def test_shift_is_not_stacked_when_a_process_runs_several_blocks():
    orig = tc.episode_seed
    try:
        for k0 in (4, 2, 10, 0):  # one pool process, four blocks in turn
            shift_episode_seeds(k0)
            assert tc.episode_seed(2, 0) == orig(2, k0) == 200006 + k0
            assert tc.episode_seed(2, 1) == 200007 + k0
    finally:
        tc.episode_seed = tc.__dict__.pop("_episode_seed_unshifted", orig)


def test_merge_keeps_block_order_and_counts():
    def part(k0, outcomes):
        ok = [o == "success" for o in outcomes]
        eps = [{"index": k0 + i, "seed": 200006 + k0 + i, "outcome": o, "progress": 1.0 if y else 0.5,
                "stages": {"reach": 1.0, "coverage": 2.0 if y else None}}
               for i, (o, y) in enumerate(zip(outcomes, ok))]
        timing = {"commands_sent": 10, "command_violations": 0, "chunks": 2, "chunk_latency_mean_ms": 5.0,
                  "chunk_latency_p99_ms": 9.0}
        return {"k0": k0, "episodes": eps, "stage_rates": {"reach": 1.0, "coverage": 0.0}, "cpu_s_part": 1.0,
                "timing": timing}

    parts = [part(2, ["failure", "success"]), part(0, ["success", "success"])]
    r = merge_rollouts("wipe", "first", 0, parts, 3.0)
    assert [e["seed"] for e in r["episodes"]] == [200006, 200007, 200008, 200009]
    assert r["success_rate"] == 0.75 and r["stage_rates"]["coverage"] == 0.75
    assert r["timing"]["commands_sent"] == 20 and r["timing"]["chunk_latency_mean_ms"] == 5.0


def test_benchmark_seeds_refused():
    import pytest

    with pytest.raises(SystemExit):
        parse_args(["--out", "x", "--collect-seeds", "2,5"])
    assert parse_args(["--out", "x", "--collect-seeds", "5-7"]).seeds == [5, 6, 7]
