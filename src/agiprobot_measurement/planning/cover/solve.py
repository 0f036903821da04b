"""Viewpoint selection as a set-cover problem (ROS-free).

Input is a measurability matrix ``M`` (points x candidate views, any scipy.sparse format or a dense array):
an entry is *measurable* when it is non-zero and not NaN. Boolean matrices only say which point a view
measures; numeric matrices also give the point's uncertainty (in the sensor model's units; negative or
infinite values are an error, and an uncertainty of exactly 0 needs a boolean matrix plus ``uncertainties``).
Points that no view measures are *uncoverable*: they are reported (:attr:`SetCoverResult.uncoverable`), not an
infeasibility.

Solvers (``solver_type``, the names the original documents):

``greedy``
    Each step takes the view that measures the most not-yet-covered points; ties go to the view whose worst
    (maximum) uncertainty is lowest (Gronle et al. 2016, ch. 4.4), then to the lower index. A lazy priority
    queue (heapq over gain buckets) re-evaluates only views whose stale gain reaches the top; nothing is
    re-sorted per step. The selection is then made irredundant.
``IP_basic``
    Minimum number of views (Scott 2009): ``min sum v_j  s.t.  M v >= 1, v binary``.
``IP_uncertainty``
    Cost of a view = its worst uncertainty divided by the worst over all views (so costs lie in [0, 1] and the
    solver's tolerances mean the same whatever the units); the reported objective is in the original units.
``IP_time``
    Cost of a view = its trajectory duration (``durations_s``), normalised the same way.

The integer programmes are reduced before they are solved; every reduction keeps at least one optimal
cover:

* uncoverable rows dropped; columns that cover nothing dropped;
* duplicate columns (same point set) merged into the cheapest (then the lowest worst uncertainty);
* dominated columns (point set a strict subset of a no more expensive column's) dropped;
* forced columns (the only view of some point) taken and their points removed;
* duplicate rows merged, and rows whose views include all views of another row dropped (implied);

repeated until nothing changes. Then the LP relaxation (HiGHS) gives a bound and reduced costs, an incumbent
comes from the better of Chvatal's greedy, an LP rounding and a small programme over the LP's favourite
columns, and every column that cannot be part of a cover better than the incumbent (LP bound plus its
reduced cost exceeds it) is left out. What remains goes to HiGHS (``highspy``, built directly in column-wise
sparse form, binaries as integer columns in [0, 1]) or, with ``backend='cbc'``, to CBC through PuLP
(``LpBinary``), warm-started with the incumbent. Every returned selection is made irredundant (no view can be
removed without uncovering a point), which never increases the cost.

All solvers return a :class:`SetCoverResult`; :func:`solve_set_cover` is the entry point. The steps live in
their own modules: ``cover_columns`` (input), ``cover_greedy``, ``cover_reduction`` and ``cover_ip`` (the integer
programmes); this module holds the result type and the entry point.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from agiprobot_measurement.planning.cover.columns import (
    SetCoverError,
    measurable_columns,
    normalised_costs,
    worst_uncertainty,
)
from agiprobot_measurement.planning.cover.greedy import greedy_cover, make_irredundant
from agiprobot_measurement.planning.cover.ip import solve_cbc, solve_highs, solve_reduced_ip
from agiprobot_measurement.planning.cover.reduction import Reduction, reduce_problem, restrict

__all__ = [
    "BACKENDS",
    "DEFAULT_TIME_LIMIT_S",
    "SOLVER_TYPES",
    "SetCoverError",
    "SetCoverResult",
    "solve_set_cover",
]

SOLVER_TYPES = ("greedy", "IP_basic", "IP_uncertainty", "IP_time")
BACKENDS = ("highs", "cbc")
DEFAULT_TIME_LIMIT_S = 60.0

# Share of the time limit the reductions may use; the rest is left to the solver.
REDUCTION_TIME_SHARE = 0.5


@dataclass(frozen=True)
class SetCoverResult:
    """Outcome of :func:`solve_set_cover`.

    ``selected`` are column (view) indices of the input matrix, ascending. ``objective`` is in the solver's
    own units: number of views (``greedy``, ``IP_basic``), sum of the views' worst uncertainties
    (``IP_uncertainty``, in the matrix's units, not normalised) or of their durations in s (``IP_time``).
    ``gap`` is the relative optimality gap ``(objective - lower_bound) / objective`` the solver proved, None
    when no bound is known (greedy). ``proven_optimal`` is True only when the gap is zero.
    """

    selected: np.ndarray
    covered: np.ndarray
    n_coverable: int
    objective: float
    gap: float | None
    proven_optimal: bool
    solve_time_s: float
    solver: str
    message: str
    lower_bound: float | None = None
    stats: dict = field(default_factory=dict)

    @property
    def n_selected(self) -> int:
        return int(self.selected.size)

    @property
    def n_points(self) -> int:
        return int(self.covered.size)

    @property
    def uncoverable(self) -> np.ndarray:
        """Indices of the points that no candidate view measures."""
        return np.asarray(self.stats.get("uncoverable", np.zeros(0, dtype=np.int64)))

    @property
    def covers_all_coverable(self) -> bool:
        return int(np.count_nonzero(self.covered)) == self.n_coverable


def _validate_per_view(values, n_cols: int, what: str) -> np.ndarray:
    arr = np.asarray(values, dtype=np.float64)
    if arr.shape != (n_cols,):
        raise SetCoverError(f"{what} must have one value per view ({n_cols}), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)) or np.any(arr < 0.0):
        raise SetCoverError(f"{what} must be finite and non-negative")
    return arr


def solve_set_cover(
    matrix,
    solver_type: str = "greedy",
    uncertainties=None,
    durations_s=None,
    time_limit_s: float = DEFAULT_TIME_LIMIT_S,
    mip_gap: float = 0.0,
    backend: str = "highs",
    reduce: bool = True,
    warm_start: bool = True,
) -> SetCoverResult:
    """Choose views (columns of ``matrix``) that together measure every coverable point (row).

    :param matrix: points x views, scipy.sparse or dense; non-zero, non-NaN entries are measurable, numeric
        values are the points' uncertainties.
    :param solver_type: one of :data:`SOLVER_TYPES`.
    :param uncertainties: per-view worst uncertainty (length = number of views) or a points x views matrix of
        uncertainties; default: the values of a numeric ``matrix``. Used for the greedy tie-break and as the
        cost of ``IP_uncertainty`` (required there).
    :param durations_s: per-view trajectory duration in s (required for ``IP_time``).
    :param time_limit_s: wall-clock limit for an IP solve as a whole (reductions get at most half of it, then
        the LP and HiGHS/CBC the rest); when it is hit the best cover found is returned with
        ``proven_optimal=False`` and its gap. Not used by ``greedy``.
    :param mip_gap: relative gap at which the solver may stop (0 = prove optimality).
    :param backend: ``'highs'`` (highspy) or ``'cbc'`` (CBC through PuLP).
    :param reduce: apply the reductions and the LP reduced-cost test before the integer programme (off only
        to test them).
    :param warm_start: give the solver the heuristic cover as its starting incumbent.
    :raises SetCoverError: (a ValueError) for an unknown solver or backend and for malformed inputs.
    """
    if solver_type not in SOLVER_TYPES:
        raise SetCoverError(
            f"unknown solver_type {solver_type!r}; valid names: {', '.join(repr(s) for s in SOLVER_TYPES)}"
        )
    if backend not in BACKENDS:
        raise SetCoverError(f"unknown backend {backend!r}; valid names: {', '.join(repr(b) for b in BACKENDS)}")
    if not (mip_gap >= 0.0) or not (time_limit_s > 0.0):
        raise SetCoverError("mip_gap must be >= 0 and time_limit_s > 0")
    t_start = time.perf_counter()
    cols, values = measurable_columns(matrix)
    worst_u = worst_uncertainty(cols, values, uncertainties)
    durations = None if durations_s is None else _validate_per_view(durations_s, cols.n_cols, "durations_s")
    if solver_type == "IP_uncertainty" and worst_u is None:
        raise SetCoverError("IP_uncertainty needs uncertainties (a numeric matrix or the uncertainties argument)")
    if solver_type == "IP_time" and durations is None:
        raise SetCoverError("IP_time needs durations_s (one duration per view)")

    row_degree = np.bincount(cols.indices, minlength=cols.n_rows)
    uncoverable = np.nonzero(row_degree == 0)[0]
    n_coverable = cols.n_rows - uncoverable.size
    tie = worst_u if worst_u is not None else np.zeros(cols.n_cols)
    stats: dict = {"uncoverable": uncoverable, "n_points": cols.n_rows, "n_views": cols.n_cols}
    note = f"; {uncoverable.size} point(s) measurable by no view" if uncoverable.size else ""
    solver_name = solver_type if solver_type == "greedy" else f"{solver_type}/{backend}"

    if solver_type == "IP_uncertainty":
        raw_costs = worst_u
    elif solver_type == "IP_time":
        raw_costs = durations
    else:
        raw_costs = np.ones(cols.n_cols)

    def finish(picks, gap, proven, lb, message) -> SetCoverResult:
        selected = np.sort(np.asarray(picks, dtype=np.int64))
        covered = np.zeros(cols.n_rows, dtype=bool)
        for j in selected:
            covered[cols.col(j)] = True
        return SetCoverResult(
            selected=selected,
            covered=covered,
            n_coverable=int(n_coverable),
            objective=float(raw_costs[selected].sum()),
            gap=gap,
            proven_optimal=proven,
            solve_time_s=time.perf_counter() - t_start,
            solver=solver_name,
            message=message + note,
            lower_bound=lb,
            stats=stats,
        )

    if n_coverable == 0:
        return finish([], 0.0, True, 0.0, "no coverable points: nothing to select")

    if solver_type == "greedy":
        picks = greedy_cover(cols, tie, n_coverable)
        stats["greedy_picks"] = len(picks)
        picks = make_irredundant(cols, picks, None)
        return finish(picks, None, False, None, f"greedy: {len(picks)} views")

    costs = normalised_costs(raw_costs)
    scale = float(raw_costs.max()) if raw_costs.max() > 0 else 1.0  # normalised -> raw cost units
    t_red = time.perf_counter()
    if reduce:
        red = reduce_problem(cols, costs, tie, t_start + REDUCTION_TIME_SHARE * time_limit_s)
    else:
        col_ids, row_keep = np.nonzero(cols.sizes() > 0)[0], row_degree > 0
        red = Reduction([], col_ids, np.nonzero(row_keep)[0], restrict(cols, row_keep, col_ids), {})
    stats.update(red.stats)
    stats["reduce_time_s"] = time.perf_counter() - t_red
    stats["reduced_shape"] = (int(red.rows_alive.size), int(red.cols_alive.size))
    forced = list(red.forced)
    offset = float(costs[forced].sum()) if forced else 0.0
    if red.rows_alive.size == 0:
        stats["likely_columns"] = np.asarray(forced, dtype=np.int64)
        picks = make_irredundant(cols, forced, costs)
        return finish(picks, 0.0, True, float(raw_costs[picks].sum()), "optimal (solved by reductions)")

    sub, sub_costs = red.matrix, costs[red.cols_alive]
    integral = solver_type == "IP_basic"  # every cover's cost is a whole number
    solve = solve_highs if backend == "highs" else solve_cbc
    deadline = t_start + time_limit_s
    local, bound_local, detail = solve_reduced_ip(
        sub, sub_costs, tie[red.cols_alive], integral, solve, deadline, mip_gap, warm_start, reduce, stats, offset
    )
    picks = forced + red.cols_alive[local].tolist()
    picks = make_irredundant(cols, picks, costs)
    likely_local = stats.pop("likely_local_columns", None)
    if likely_local is None:
        likely_local = np.argsort(-sub.sizes(), kind="stable")
    # what a cover of this problem is likely to use, most likely first: the forced columns, then the reduced
    # programme's columns by LP value (the planner verifies scan lines in this order)
    stats["likely_columns"] = np.concatenate([np.asarray(forced, dtype=np.int64), red.cols_alive[likely_local]])
    objective_n = float(costs[picks].sum())
    bound_n = bound_local + offset
    if integral and math.isfinite(bound_n):
        bound_n = math.ceil(bound_n - 1e-6)
    bound_n = min(bound_n, objective_n)
    gap = (objective_n - bound_n) / objective_n if objective_n > 0 else 0.0
    if not math.isfinite(gap):
        gap = None
    proven = gap is not None and gap <= 1e-9
    if proven:
        gap, bound_n = 0.0, objective_n  # what is left is float noise of the bound, not a gap
    lb = bound_n * scale if math.isfinite(bound_n) else None
    if proven:
        status = "optimal"
    elif gap is None:
        status = "no bound"
    else:
        status = f"gap {100.0 * gap:.3g}%"
    return finish(picks, gap, proven, lb, f"{status}: {len(picks)} views ({detail})")
