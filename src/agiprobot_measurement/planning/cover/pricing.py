"""Pricing the columns outside a candidate pool: a lower bound over all columns from the LP over the pool, and the
outside columns that could still be part of a cheaper cover (instead of solving the programme over all columns
again).

For any duals ``y >= 0`` of the covering rows, ``L(y) = sum(y) + sum_j min(0, c_j - a_j . y)`` over all columns
is a lower bound on every cover of those rows, and a cover that uses column j costs at least
``L(y) + max(0, c_j - a_j . y)``. The duals of the LP over the pool (the rows the pool measures) give both in one
sparse product over all columns: milliseconds, where the programme over all columns costs its reductions, its LP
and its integer search (seconds each on tens of thousands of columns).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from agiprobot_measurement.planning.cover.columns import ColumnSets, measurable_columns
from agiprobot_measurement.planning.cover.greedy import greedy_weighted_cover
from agiprobot_measurement.planning.cover.ip import PRICING_TOLERANCE, lp_relaxation
from agiprobot_measurement.planning.cover.reduction import restrict

__all__ = ["PoolPricing", "full_bound", "price_pool"]


@dataclass(frozen=True)
class PoolPricing:
    """The pool LP's duals priced over all columns (costs in the units given to :func:`price_pool`).

    ``lagrangian``: ``L(y)``, a lower bound on any cover of the rows the pool measures. ``reduced_costs``: per
    column of the whole matrix. ``in_pool``: mask of the pool's columns. ``pool_covers_all``: whether the pool
    measures every row some column measures (otherwise every cover of all rows uses an outside column).
    ``n_coverable``: how many rows some column measures.
    """

    lagrangian: float
    reduced_costs: np.ndarray
    in_pool: np.ndarray
    pool_covers_all: bool
    n_coverable: int

    def outside_bound(self) -> float:
        """Lower bound on any cover that uses a column outside the pool (inf when every non-empty column is in it)."""
        outside = ~self.in_pool & np.isfinite(self.reduced_costs)
        if not outside.any():
            return math.inf
        return self.lagrangian + float(np.maximum(self.reduced_costs[outside], 0.0).min())

    def improving(self) -> np.ndarray:
        """The outside columns of negative reduced cost (the LP over the pool is not the LP over all columns while
        there are any), most negative first."""
        out = np.flatnonzero(~self.in_pool & (self.reduced_costs < -PRICING_TOLERANCE))
        return out[np.argsort(self.reduced_costs[out], kind="stable")]


def price_pool(matrix, pool: np.ndarray, costs: np.ndarray, time_limit_s: float) -> PoolPricing | None:
    """Solve the LP over the columns ``pool`` of ``matrix`` (points x views; non-zero = measurable) restricted to the
    rows they measure, and price every column with its duals. ``costs``: per column of ``matrix``, positive for the
    non-empty ones. None when the LP did not solve in ``time_limit_s``."""
    cols, _ = measurable_columns(matrix)
    nonempty = cols.sizes() > 0
    pool = np.asarray(pool, dtype=np.int64)
    pool = pool[nonempty[pool]]
    if pool.size == 0:
        return None
    rows = np.zeros(cols.n_rows, dtype=bool)
    rows[cols.take(pool).indices] = True
    all_rows = np.zeros(cols.n_rows, dtype=bool)
    all_rows[cols.indices] = True
    sub = restrict(cols, rows, pool)
    start = greedy_weighted_cover(sub, np.zeros(sub.n_cols), costs[pool])
    lp = lp_relaxation(sub, costs[pool], time_limit_s, start)
    if lp is None:
        return None
    y = np.zeros(cols.n_rows)
    y[rows] = lp[3]
    reduced = _reduced_costs(cols, costs, y)
    reduced[~nonempty] = math.inf  # an empty column is in no cover
    in_pool = np.zeros(cols.n_cols, dtype=bool)
    in_pool[pool] = True
    lagrangian = float(y.sum() + np.minimum(reduced[nonempty], 0.0).sum())
    return PoolPricing(lagrangian, reduced, in_pool, bool(np.all(rows[all_rows])), int(np.count_nonzero(all_rows)))


def full_bound(pricing: PoolPricing, pool_bound: float | None, integral: bool) -> float:
    """Lower bound on every cover of all rows over all columns: covers of pool columns only cost at least
    ``pool_bound`` (the pool programme's own bound, None if unknown: then the LP's) and only exist when the pool
    measures every row; the others use an outside column."""
    inside = pricing.lagrangian if pool_bound is None else max(pool_bound, pricing.lagrangian)
    bound = min(inside, pricing.outside_bound()) if pricing.pool_covers_all else pricing.outside_bound()
    bound = max(bound, pricing.lagrangian)
    return math.ceil(bound - 1e-6) if integral and math.isfinite(bound) else bound


def _reduced_costs(cols: ColumnSets, costs: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``c_j - a_j . y`` for every column (empty columns: their cost)."""
    return cols.reduced_costs(costs, y)
