"""The set-cover integer programmes: HiGHS models (column-wise sparse, binaries as integer columns) and its LP
relaxation, CBC through PuLP, the LP rounding and the reduced-programme strategy (incumbent, reduced-cost
fixing, warm start). HiGHS and PuLP are imported when a programme is solved.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass

import numpy as np

from agiprobot_measurement.planning.cover.columns import ColumnSets
from agiprobot_measurement.planning.cover.greedy import greedy_weighted_cover, make_irredundant

__all__ = [
    "SUPPORT_MIP_COLS",
    "SUPPORT_MIP_TIME_S",
    "highs_model",
    "lp_relaxation",
    "lp_rounding",
    "solve_cbc",
    "solve_highs",
    "solve_reduced_ip",
]

# Size and time cap of the quick programme over the LP's favourite columns that tightens the incumbent.
SUPPORT_MIP_COLS = 400
SUPPORT_MIP_TIME_S = 2.0
# Column generation for the LP of programmes with more columns than this; columns added per pricing round (and
# the cheapest per point that start it); reduced costs below minus this price a column in (HiGHS's dual tolerance)
PRICING_MIN_COLS = 1000
PRICING_BATCH_COLS = 300
PRICING_BATCH_SHARE = 20  # ... or this share of the columns, if more
PRICING_TOLERANCE = 1e-7
# The integer programme is not started with less time than this (s) left: it could not improve the incumbent.
MIN_MIP_TIME_S = 0.5


@dataclass
class _MipOutcome:
    x: np.ndarray | None  # chosen local columns (bool)
    objective: float
    bound: float
    status: str  # "optimal", "time_limit", "infeasible", "error"
    detail: str


def highs_model(sub: ColumnSets, costs: np.ndarray, integer: bool, time_limit_s: float):
    import highspy

    h = highspy.Highs()
    h.setOptionValue("output_flag", False)
    h.setOptionValue("time_limit", float(max(time_limit_s, 0.01)))
    h.setOptionValue("random_seed", 0)
    n, m = sub.n_cols, sub.n_rows
    lp = highspy.HighsLp()
    lp.num_col_ = n
    lp.num_row_ = m
    lp.col_cost_ = np.asarray(costs, dtype=np.float64)
    lp.col_lower_ = np.zeros(n)
    lp.col_upper_ = np.ones(n)
    lp.row_lower_ = np.ones(m)
    lp.row_upper_ = np.full(m, highspy.kHighsInf)
    lp.a_matrix_.format_ = highspy.MatrixFormat.kColwise
    lp.a_matrix_.start_ = sub.indptr.astype(np.int32)
    lp.a_matrix_.index_ = sub.indices.astype(np.int32)
    lp.a_matrix_.value_ = np.ones(sub.indices.size)
    if integer:
        # HiGHS has no separate binary type: a binary is an integer column with bounds [0, 1].
        lp.integrality_ = [highspy.HighsVarType.kInteger] * n
    h.passModel(lp)
    return h


def lp_relaxation(sub: ColumnSets, costs: np.ndarray, time_limit_s: float, start=None):
    """LP relaxation: primal x, a rigorous lower bound, reduced costs and the row duals y >= 0 they come from; None
    if it did not solve.

    The bound is recomputed from the duals clipped to y >= 0 (any such y gives the Lagrangian bound
    ``sum(y) + sum(min(rc, 0))`` with ``rc = c - A^T y``), so solver tolerances cannot make it invalid. For
    any cover that uses column j, ``cost >= bound + max(rc_j, 0)``.

    Programmes of more than :data:`PRICING_MIN_COLS` columns are solved by column generation: the LP over the
    columns ``start`` (a cover, so the LP is feasible) and the :data:`PRICING_BATCH_COLS` of least cost per row, then
    the :data:`PRICING_BATCH_COLS` columns (or 1 / :data:`PRICING_BATCH_SHARE` of them) of most negative reduced cost are added (HiGHS goes on from its basis)
    until no column prices out. The optimum is the same as over all columns; a view sees hundreds of points, so the
    full programme is dense, and its simplex takes several times as long. When the time runs out first, the bound
    is still the Lagrangian one of the last duals.
    """
    import highspy

    n = sub.n_cols
    deadline = time.perf_counter() + time_limit_s
    if n <= PRICING_MIN_COLS or start is None:
        active = np.arange(n)
    else:
        by_ratio = np.argsort(costs / np.maximum(sub.sizes(), 1), kind="stable")[:PRICING_BATCH_COLS]
        active = np.union1d(np.asarray(start, dtype=np.int64), by_ratio)
    h = highs_model(
        sub.take(active) if active.size < n else sub, costs[active], integer=False, time_limit_s=time_limit_s
    )
    batch = max(PRICING_BATCH_COLS, n // PRICING_BATCH_SHARE)
    inactive = np.ones(n, dtype=bool)
    inactive[active] = False
    result = None
    while True:
        h.setOptionValue("time_limit", float(max(deadline - time.perf_counter(), 0.01)))
        h.run()
        if h.getModelStatus() != highspy.HighsModelStatus.kOptimal:
            return _informative(result)  # the last pricing round's: its bound holds whatever the columns added since
        sol = h.getSolution()
        y = np.maximum(np.asarray(sol.row_dual, dtype=np.float64), 0.0)
        rc = sub.reduced_costs(costs, y)
        x = np.zeros(n)
        x[active] = np.clip(np.asarray(sol.col_value, dtype=np.float64), 0.0, 1.0)
        result = x, float(y.sum() + np.minimum(rc, 0.0).sum()), rc, y
        priced = np.flatnonzero(inactive & (rc < -PRICING_TOLERANCE))
        if priced.size == 0:
            return result
        if time.perf_counter() > deadline:
            return _informative(result)
        new = priced[np.argsort(rc[priced], kind="stable")[:batch]]
        part = sub.take(new)
        h.addCols(
            new.size, costs[new], np.zeros(new.size), np.ones(new.size), part.indices.size,
            part.indptr[:-1].astype(np.int32), part.indices.astype(np.int32), np.ones(part.indices.size),
        )  # fmt: skip
        active = np.concatenate([active, new])
        inactive[new] = False


def _informative(result):
    """A column generation's figures stopped before the LP optimum; a bound of no more than 0 (every cost is
    positive; the Lagrangian bound of an early round is often far below) says nothing and becomes -inf, the primal
    values and reduced costs still order the columns."""
    if result is None or result[1] > 0.0:
        return result
    x, _, rc, y = result
    return x, -math.inf, rc, y


def solve_highs(
    sub: ColumnSets, costs: np.ndarray, start: np.ndarray | None, time_limit_s: float, mip_gap: float
) -> _MipOutcome:
    import highspy

    h = highs_model(sub, costs, integer=True, time_limit_s=time_limit_s)
    h.setOptionValue("mip_rel_gap", float(mip_gap))
    h.setOptionValue("mip_abs_gap", 1e-9)
    if start is not None:
        sol = highspy.HighsSolution()
        sol.col_value = start.astype(np.float64)
        sol.value_valid = True
        h.setSolution(sol)
    h.run()
    status = h.getModelStatus()
    info = h.getInfo()
    has_solution = info.primal_solution_status == highspy.SolutionStatus.kSolutionStatusFeasible
    x = np.asarray(h.getSolution().col_value) > 0.5 if has_solution else None
    name = h.modelStatusToString(status)
    if status == highspy.HighsModelStatus.kOptimal:
        kind = "optimal"
    elif status == highspy.HighsModelStatus.kInfeasible:
        kind = "infeasible"
    elif status == highspy.HighsModelStatus.kTimeLimit:
        kind = "time_limit"
    else:
        kind = "error"
    bound = float(info.mip_dual_bound) if math.isfinite(info.mip_dual_bound) else -math.inf
    return _MipOutcome(x, float(info.objective_function_value), bound, kind, f"HiGHS: {name}")


def solve_cbc(
    sub: ColumnSets, costs: np.ndarray, start: np.ndarray | None, time_limit_s: float, mip_gap: float
) -> _MipOutcome:
    import pulp

    prob = pulp.LpProblem("set_cover", pulp.LpMinimize)
    v = [prob.add_variable(f"v{j}", cat=pulp.LpBinary) for j in range(sub.n_cols)]
    prob += pulp.LpAffineExpression(list(zip(v, costs.tolist(), strict=True)))
    rows_t = sub.transpose()  # CSR rows of the programme: one covering constraint each
    for i in range(rows_t.n_cols):
        prob += pulp.LpAffineExpression([(v[j], 1) for j in rows_t.col(i).tolist()]) >= 1
    if start is not None:
        for var, val in zip(v, start.tolist(), strict=True):
            var.setInitialValue(1 if val else 0)
    with warnings.catch_warnings():
        # PuLP 3.3 flags its bundled CBC as deprecated in favour of a separately installed one; the bundled
        # binary is the one this environment has.
        warnings.simplefilter("ignore", DeprecationWarning)
        solver = pulp.PULP_CBC_CMD(
            msg=False, timeLimit=max(1, math.ceil(time_limit_s)), gapRel=mip_gap, warmStart=start is not None
        )
        prob.solve(solver)
    values = np.array([var.value() if var.value() is not None else 0.0 for var in v])
    feasible = prob.sol_status in (pulp.LpSolutionOptimal, pulp.LpSolutionIntegerFeasible)
    x = values > 0.5 if feasible else None
    objective = float(costs @ x) if x is not None else math.inf
    if prob.sol_status == pulp.LpSolutionOptimal:
        kind, bound = "optimal", objective if mip_gap == 0.0 else -math.inf
    elif prob.sol_status == pulp.LpSolutionIntegerFeasible:
        kind, bound = "time_limit", -math.inf
    elif prob.status == pulp.LpStatusInfeasible:
        kind, bound = "infeasible", -math.inf
    else:
        kind, bound = "error", -math.inf
    return _MipOutcome(x, objective, bound, kind, f"CBC: {pulp.LpStatus[prob.status]}")


def lp_rounding(sub: ColumnSets, costs: np.ndarray, x: np.ndarray) -> list[int]:
    """Cover built from the LP solution: columns by decreasing LP value (cheaper first) while they add rows."""
    covered = np.zeros(sub.n_rows, dtype=bool)
    left = sub.n_rows
    picks = []
    for j in np.lexsort((costs, -x)).tolist():
        rows = sub.col(j)
        new = rows.size - int(np.count_nonzero(covered[rows]))
        if new:
            covered[rows] = True
            picks.append(j)
            left -= new
            if left == 0:
                break
    return picks


def solve_reduced_ip(sub, costs, tie, integral, solve, deadline, mip_gap, warm_start, lp_fixing, stats, offset=0.0):
    """Solve the reduced programme; returns (chosen local columns, lower bound, detail).

    ``mip_gap`` is the relative gap of the whole cover, whose cost is ``offset`` (the forced columns) more than the
    reduced programme's: a gap of the reduced cover's cost ``ub`` is ``mip_gap * (ub + offset)``.

    An incumbent comes from the best of Chvatal's greedy, an LP rounding and a small programme over the
    columns of least reduced cost (the last two only with ``lp_fixing``). With the LP's reduced costs,
    a column whose every cover costs more than the incumbent (for counts: more than one less than it) is
    left out of the integer programme: the programme then still holds every strictly better cover and the
    incumbent, so its optimum is the optimum. Covers that use a left-out column cost at least the
    incumbent, so the overall lower bound is ``min(programme bound, incumbent)``, and never below the LP's.
    """
    t0 = time.perf_counter()
    candidates = [make_irredundant(sub, greedy_weighted_cover(sub, tie, costs), costs)]
    lp = lp_relaxation(sub, costs, max(deadline - time.perf_counter(), 0.01), candidates[0]) if lp_fixing else None
    lp_bound = -math.inf
    if lp is not None:
        x_lp, lp_bound, rc, _ = lp
        candidates.append(make_irredundant(sub, lp_rounding(sub, costs, x_lp), costs))
        stats["lp_bound"] = lp_bound
        # local columns by how likely a cover is to use them (LP value, then reduced cost): the planner verifies
        # scan lines in this order
        stats["likely_local_columns"] = np.lexsort((rc, -x_lp))
    # the bound the cover comes with: the LP's, or where the LP gave none in time (or none was asked) the dual
    # ascent's, weaker (the reduced-cost test below takes the LP's own bound only: it pairs with the LP's duals)
    floor = lp_bound
    if not math.isfinite(floor):
        floor = sub.dual_ascent_bound(costs)
        stats["dual_ascent_bound"] = floor
    incumbent = min(candidates, key=lambda c: float(costs[c].sum()))
    if lp is not None and sub.n_cols > SUPPORT_MIP_COLS:
        # A small programme over the columns the LP likes best (least reduced cost) plus the incumbent
        # usually finds a near-optimal cover in a fraction of a second; a tighter incumbent lets the
        # reduced-cost test below leave out far more columns.
        pool = np.union1d(np.argsort(rc, kind="stable")[:SUPPORT_MIP_COLS], incumbent)
        start = np.isin(pool, incumbent)
        budget = min(SUPPORT_MIP_TIME_S, 0.2 * max(deadline - time.perf_counter(), 0.0))
        trial = solve(sub.take(pool), costs[pool], start, max(budget, 0.01), 0.0)
        if trial.x is not None and float(costs[pool][trial.x].sum()) < float(costs[incumbent].sum()):
            incumbent = make_irredundant(sub, pool[trial.x].tolist(), costs)
    ub = float(costs[incumbent].sum())
    stats["incumbent_objective_normalised"] = ub
    stats["lp_time_s"] = time.perf_counter() - t0
    if integral:
        settled = math.ceil(floor - 1e-6) >= ub - mip_gap * (ub + offset) - 1e-9
    else:
        settled = floor >= ub - max(mip_gap, 1e-9) * (ub + offset) - 1e-12
    if settled:
        stats["mip_shape"] = (0, 0)
        return np.asarray(incumbent, dtype=np.int64), floor, "the lower bound meets the heuristic cover"
    if deadline - time.perf_counter() < MIN_MIP_TIME_S:
        # no time left: loading a programme of 100k columns into HiGHS alone takes seconds (tilt full)
        stats["mip_shape"] = (0, 0)
        return np.asarray(incumbent, dtype=np.int64), floor, "no time left for the programme; heuristic cover"
    keep = np.ones(sub.n_cols, dtype=bool)
    if lp is not None:
        threshold = ub - 1.0 + 1e-6 if integral else ub + 1e-9 * max(ub, 1.0)
        keep = lp_bound + np.maximum(rc, 0.0) <= threshold
        keep[incumbent] = True
    stats["lp_fixed_cols"] = int(np.count_nonzero(~keep))
    kept = np.nonzero(keep)[0]
    restricted = sub.take(kept)
    start = np.isin(kept, incumbent)
    t_mip = time.perf_counter()
    # the solver's relative gap is of the reduced cover's cost: widened by the offset, it means the same stop
    local_gap = mip_gap * (ub + offset) / ub if ub > 0 else mip_gap
    outcome = solve(restricted, costs[kept], start if warm_start else None, max(deadline - t_mip, 0.01), local_gap)
    stats["mip_time_s"] = time.perf_counter() - t_mip
    stats["mip_shape"] = (restricted.n_rows, restricted.n_cols)
    if outcome.x is not None and float(costs[kept][outcome.x].sum()) <= ub:
        chosen = kept[outcome.x]
        detail = outcome.detail
    else:
        chosen = np.asarray(incumbent, dtype=np.int64)
        detail = f"{outcome.detail}; kept the heuristic cover"
    # the programme holds every cover cheaper than the incumbent (all columns, or those the LP's reduced costs keep)
    bound = max(floor, min(outcome.bound, ub))
    return chosen, bound, detail
