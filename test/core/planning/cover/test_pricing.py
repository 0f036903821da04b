"""Tests of the set cover's column generation and pool pricing (planning.cover.ip, planning.cover.pricing) and of
the requested gap meaning the whole cover's (planning.cover.solve)."""

import itertools
import math

import numpy as np
import pytest
from scipy import sparse

from agiprobot_measurement.planning.cover import columns as cover_columns
from agiprobot_measurement.planning.cover import greedy as cover_greedy
from agiprobot_measurement.planning.cover import ip as cover_ip
from agiprobot_measurement.planning.cover.pricing import full_bound, price_pool
from agiprobot_measurement.planning.cover.solve import solve_set_cover


def _random_mask(rng, n_rows, n_cols, density):
    mask = rng.random((n_rows, n_cols)) < density
    mask[rng.integers(n_rows), :] = False  # one uncoverable row
    return mask


def _cheapest_cover(mask: np.ndarray, costs: np.ndarray) -> float:
    """Brute force over subsets by size (small instances only)."""
    rows = mask.any(axis=1)
    best = math.inf
    for k in range(1, mask.shape[1] + 1):
        for subset in itertools.combinations(range(mask.shape[1]), k):
            cols = list(subset)
            if np.all(mask[:, cols].any(axis=1) | ~rows):
                best = min(best, float(costs[cols].sum()))
        if best < math.inf and k * costs.min() >= best:
            break
    return best


@pytest.mark.parametrize("seed", range(4))
def test_column_generation_reaches_the_lp_optimum_over_all_columns(seed):
    rng = np.random.default_rng(seed)
    n_cols = cover_ip.PRICING_MIN_COLS + 600
    mask = _random_mask(rng, 120, n_cols, 0.05)
    mask = mask[mask.any(axis=1)]
    cols, _ = cover_columns.measurable_columns(sparse.csc_array(mask))
    keep = np.flatnonzero(cols.sizes() > 0)
    cols = cols.take(keep)
    costs = rng.uniform(0.5, 1.0, cols.n_cols) if seed % 2 else np.ones(cols.n_cols)
    start = cover_greedy.greedy_weighted_cover(cols, np.zeros(cols.n_cols), costs)
    x_all, bound_all, _, _ = cover_ip.lp_relaxation(cols, costs, 60.0)
    x_cg, bound_cg, rc_cg, y_cg = cover_ip.lp_relaxation(cols, costs, 60.0, start)
    assert bound_cg == pytest.approx(bound_all, rel=1e-6)
    assert float(costs @ x_cg) == pytest.approx(float(costs @ x_all), rel=1e-6)
    assert np.all(rc_cg >= -1e-6)  # no column prices out: the LP over all columns is solved
    assert np.all(y_cg >= 0.0)
    # the restricted LP left columns out, and its x is a fractional cover of every row
    assert np.count_nonzero(x_cg) < cols.n_cols
    rows = cols.transpose()
    per_row = np.add.reduceat(x_cg[rows.indices], rows.indptr[:-1])
    assert np.all(per_row >= 1.0 - 1e-6)


@pytest.mark.parametrize("seed", range(12))
def test_pool_pricing_bound_holds_over_all_columns_and_names_the_improving_ones(seed):
    rng = np.random.default_rng(seed)
    mask = _random_mask(rng, 14, 12, 0.3)
    costs = rng.choice([1.0, 1.5, 2.0], mask.shape[1]) if seed % 3 == 2 else np.ones(mask.shape[1])
    integral = seed % 3 != 2
    pool = np.sort(rng.choice(mask.shape[1], 6, replace=False))
    pricing = price_pool(sparse.csc_array(mask), pool, costs, 10.0)
    best = _cheapest_cover(mask, costs)
    # the pool's own best (a bound on covers of pool columns only), when the pool covers every row
    pool_best = _cheapest_cover(mask[:, pool], costs[pool]) if pricing.pool_covers_all else None
    if pool_best is not None and not np.all(mask[:, pool].any(axis=1) | ~mask.any(axis=1)):
        pool_best = None
    bound = full_bound(pricing, pool_best, integral)
    assert bound <= best + 1e-9
    assert pricing.lagrangian <= best + 1e-9
    # the LP over the pool plus the columns that price out is the LP over all columns: pricing again names none
    if pricing.pool_covers_all:
        grown = np.union1d(pool, pricing.improving())
        again = price_pool(sparse.csc_array(mask), grown, costs, 10.0)
        while again.improving().size:
            grown = np.union1d(grown, again.improving())
            again = price_pool(sparse.csc_array(mask), grown, costs, 10.0)
        cols, _ = cover_columns.measurable_columns(sparse.csc_array(mask[mask.any(axis=1)]))
        nonempty = np.flatnonzero(cols.sizes() > 0)
        lp_all = cover_ip.lp_relaxation(cols.take(nonempty), costs[nonempty], 10.0)[1]
        assert again.lagrangian == pytest.approx(lp_all, abs=1e-6)
        converged = full_bound(again, None, integral)
        assert converged >= (math.ceil(lp_all - 1e-6) if integral else lp_all - 1e-6)
        assert converged <= best + 1e-9


def test_requested_gap_is_the_whole_covers_gap():
    # 30 views forced by a point each, and a 5-cycle (LP 2.5, best cover 3): a gap of 0.5 in 33, 1.5 %; the reduced
    # programme alone has 0.5 in 3, 17 %. IP_time with unit durations: no rounding of the bound.
    n_forced = 30
    forced = np.eye(n_forced, dtype=bool)
    cycle = np.zeros((5, 5), dtype=bool)
    for j in range(5):
        cycle[j, j] = cycle[(j + 1) % 5, j] = True
    mask = np.block([[forced, np.zeros((n_forced, 5), bool)], [np.zeros((5, n_forced), bool), cycle]])
    durations = np.ones(mask.shape[1])
    within = solve_set_cover(sparse.csc_array(mask), "IP_time", durations_s=durations, mip_gap=0.02)
    assert within.objective == 33.0
    assert within.gap == pytest.approx(0.5 / 33.0)
    assert within.stats["mip_shape"] == (0, 0)  # the LP bound settles it: no integer search
    exact = solve_set_cover(sparse.csc_array(mask), "IP_time", durations_s=durations, mip_gap=0.0)
    assert exact.objective == 33.0 and exact.proven_optimal
    assert exact.stats["mip_shape"] != (0, 0)


@pytest.mark.parametrize("seed", range(6))
def test_reductions_keep_the_optimum_of_the_unreduced_programme(seed):
    # views nested in a few large ones (dominance), points seen by one view only (forced columns, taken a few at a
    # time between the row reductions) and points whose views include another point's (implied rows)
    rng = np.random.default_rng(seed)
    big = rng.random((60, 6)) < 0.4
    cols = [big[:, rng.integers(6)] & (rng.random(60) < rng.uniform(0.3, 1.0)) for _ in range(40)]
    mask = np.column_stack([*cols, rng.random((60, 8)) < 0.08])
    lonely = rng.choice(60, 5, replace=False)
    mask[lonely] = False
    mask[lonely, rng.integers(mask.shape[1], size=5)] = True
    durations = rng.choice([1.0, 2.0, 3.0], mask.shape[1])
    for solver_type in ("IP_basic", "IP_time"):
        reduced = solve_set_cover(sparse.csc_array(mask), solver_type, durations_s=durations, mip_gap=0.0)
        plain = solve_set_cover(sparse.csc_array(mask), solver_type, durations_s=durations, mip_gap=0.0, reduce=False)
        assert reduced.proven_optimal and plain.proven_optimal
        assert reduced.objective == pytest.approx(plain.objective)
        np.testing.assert_array_equal(reduced.covered, plain.covered)
        assert reduced.stats["forced_cols"] > 0 and reduced.stats["dominated_cols"] > 0


def test_column_generation_cut_short_gives_no_bound_rather_than_a_negative_one(monkeypatch):
    rng = np.random.default_rng(5)
    mask = _random_mask(rng, 200, cover_ip.PRICING_MIN_COLS + 600, 0.3)  # dense, as the programmes of large parts
    mask = mask[mask.any(axis=1)]
    cols, _ = cover_columns.measurable_columns(sparse.csc_array(mask))
    cols = cols.take(np.flatnonzero(cols.sizes() > 0))
    costs = np.ones(cols.n_cols)
    start = cover_greedy.greedy_weighted_cover(cols, np.zeros(cols.n_cols), costs)

    class Clock:  # the deadline passes right after the first restricted LP
        calls = 0

        @classmethod
        def perf_counter(cls):
            cls.calls += 1
            return 0.0 if cls.calls <= 2 else 1e9

    monkeypatch.setattr(cover_ip, "time", Clock)
    result = cover_ip.lp_relaxation(cols, costs, 60.0, start)
    assert result is not None
    x, bound, rc, _ = result
    assert bound > 0.0 or bound == -math.inf
    assert x.shape == rc.shape == (cols.n_cols,)


def test_reduced_costs_equal_the_sparse_product_of_ones_bit_for_bit():
    rng = np.random.default_rng(11)
    mask = _random_mask(rng, 300, 500, 0.05)
    mask[:, 7] = False  # an empty column keeps its cost
    cols, _ = cover_columns.measurable_columns(sparse.csc_array(mask))
    costs, y = rng.random(cols.n_cols) + 0.5, rng.random(cols.n_rows)
    ones = sparse.csr_array((np.ones(cols.indices.size), cols.indices, cols.indptr), shape=(cols.n_cols, cols.n_rows))
    expected = costs - ones @ y
    got = cols.reduced_costs(costs, y)
    assert np.array_equal(got, expected)
    assert got[7] == costs[7]


def test_the_compiled_transpose_equals_scipys():
    rng = np.random.default_rng(12)
    mask = _random_mask(rng, 200, 700, 0.04)
    mask[:, 3] = False  # an empty column
    cols, _ = cover_columns.measurable_columns(sparse.csc_array(mask))
    rows = cols.transpose()
    csr = sparse.csr_array(mask)
    csr.sort_indices()
    assert rows.n_rows == cols.n_cols and rows.n_cols == cols.n_rows
    assert np.array_equal(rows.indptr, csr.indptr) and np.array_equal(rows.indices, csr.indices)
    assert np.array_equal(rows.transpose().indices, cols.indices)  # twice: the columns again


@pytest.mark.parametrize("seed", range(4))
def test_the_dual_ascent_bounds_every_cover_and_stays_below_the_lp(seed):
    rng = np.random.default_rng(seed)
    mask = _random_mask(rng, 14, 9, 0.3)
    costs = rng.uniform(0.5, 2.0, 9)
    cols, _ = cover_columns.measurable_columns(sparse.csc_array(mask))
    dual = cols.dual_ascent_bound(costs)  # the uncoverable row is skipped
    assert 0.0 < dual <= _cheapest_cover(mask, costs) + 1e-9
    coverable, _ = cover_columns.measurable_columns(sparse.csc_array(mask[mask.any(axis=1)]))
    _, lp_bound, _, _ = cover_ip.lp_relaxation(coverable, costs, 10.0)
    assert dual <= lp_bound + 1e-9


def _lp_without_bound(sub, costs, *args, **kwargs):
    """An LP stopped by its time before any dual solution: a primal, no bound."""
    return np.ones(sub.n_cols), -math.inf, np.asarray(costs, dtype=float), np.zeros(sub.n_rows)


@pytest.mark.parametrize("lp", [lambda *args, **kwargs: None, _lp_without_bound], ids=["no_lp", "lp_without_bound"])
def test_a_cover_whose_lp_did_not_solve_still_has_a_lower_bound(monkeypatch, lp):
    """No LP bound within the time (a large cover on a loaded machine): the dual ascent gives the bound the report
    puts beside the view count, never above the cover's cost."""
    rng = np.random.default_rng(7)
    mask = _random_mask(rng, 60, 40, 0.12)
    monkeypatch.setattr(cover_ip, "lp_relaxation", lp)
    monkeypatch.setattr(cover_ip, "MIN_MIP_TIME_S", 1e9)  # ... and no time for the integer programme either
    result = solve_set_cover(sparse.csc_array(mask), "IP_basic", time_limit_s=5.0)
    assert result.lower_bound is not None and 0 < result.lower_bound <= result.objective
    assert "dual_ascent_bound" in result.stats
