"""The scale benchmark's projection model on hand-made runs: scatter line, pilot on the workers, chunk work."""

from __future__ import annotations

import math

import pytest

from benchmarks.planning import scale as bench


def run(workers=1, scatter_s=1.0):
    # 40 chunks of 1 s, a pilot of 2 s spread work + 6 slices of 0.5 s (5 s of tasks) plus 0.5 s of round trips
    return {
        "workers": workers,
        "chunk_seconds": [1.0] * 40,
        "pilot_s": 5.5,
        "pilot_spread_seconds": [2.0],
        "pilot_dominance_seconds": [0.5] * 6,
        "merge_s": 0.25,
        "scatter_s": scatter_s,
        # merge + scatter + pilot + 40 chunks + 0.1 s overhead per chunk
        "evaluation_s": 0.25 + scatter_s + 5.5 + 40 * 1.1,
    }


def test_scatter_is_a_line_through_two_runs_and_all_per_worker_from_one():
    assert bench.scatter_model([run(1, 1.0), run(2, 1.5)]) == pytest.approx((0.5, 0.5))
    assert bench.scatter_model([run(1, 1.2)]) == pytest.approx((0.0, 1.2))
    # a second worker that made the scatter faster is no negative cost per worker
    assert bench.scatter_model([run(1, 1.0), run(2, 0.8)]) == pytest.approx((1.0, 0.0))


def test_the_pilot_splits_its_spread_and_runs_a_slice_per_worker():
    one = run()
    assert bench.pilot_model(one, 1) == pytest.approx(5.5)
    # 8 workers: spread 2/8, the 6 slices at once (0.5 s), the 0.5 s of round trips
    assert bench.pilot_model(one, 8) == pytest.approx(0.25 + 0.5 + 0.5)
    assert bench.pilot_model(one, 4) == pytest.approx(0.5 + 2 * 0.5 + 0.5)
    # a run without the task times (older JSON) keeps its pilot serial
    old = {k: v for k, v in one.items() if not k.startswith("pilot_") or k == "pilot_s"}
    assert bench.pilot_model(old, 8) == pytest.approx(5.5)


def test_the_projection_reproduces_the_run_and_splits_the_chunks():
    one = run()
    scatter = (0.5, 0.5)
    assert bench.projection(one, 1, scatter) == pytest.approx(one["evaluation_s"])
    expected = 0.25 + 0.5 + 0.5 * 8 + (0.25 + 0.5 + 0.5) + math.ceil(40 / 8) * 1.1
    assert bench.projection(one, 8, scatter) == pytest.approx(expected)
    # more workers than 4 chunks each: the same work in smaller chunks, the overhead per chunk spread with it
    assert bench.projection(one, 16, scatter) == pytest.approx(
        0.25 + 0.5 + 0.5 * 16 + (2 / 16 + 0.5 + 0.5) + math.ceil(64 / 16) * (40 / 64 + 0.1 * 40 / 64)
    )
