"""Optimality-preserving reductions of a set-cover problem before the integer programme: duplicate, dominated
and forced columns, duplicate and implied rows, repeated until nothing changes.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numba
import numpy as np

from agiprobot_measurement.planning.cover.columns import ColumnSets

__all__ = [
    "MAX_REDUCTION_ROUNDS",
    "Reduction",
    "dominated_columns",
    "duplicate_columns",
    "implied_rows",
    "reduce_problem",
    "restrict",
]

# Reductions run a few rounds at most: after two or three nothing changes on realistic data.
MAX_REDUCTION_ROUNDS = 10
# once the rows were reduced, a round that removed less than this share of the programme's entries is the last
REDUCTION_MIN_CHANGE = 0.02
# candidate rows visited by one call of the compiled implied-row search: the deadline is checked between calls
IMPLIED_CHUNK_ROWS = 4096


def restrict(cols: ColumnSets, row_keep: np.ndarray, which: np.ndarray) -> ColumnSets:
    """Columns ``which`` restricted to the rows where the mask ``row_keep`` holds, rows renumbered."""
    if row_keep.all():
        return cols.take(which)
    row_map = np.where(row_keep, np.cumsum(row_keep) - 1, -1).astype(np.int64)
    indptr, indices = _restrict_kernel(cols.indptr, cols.indices, np.asarray(which, dtype=np.int64), row_map)
    return ColumnSets(indptr, indices, int(np.count_nonzero(row_keep)))


@numba.njit(cache=True)
def _restrict_kernel(indptr, indices, which, row_map):  # pragma: no cover - compiled
    """:func:`restrict` in two passes over the chosen columns' entries (count, then fill): (indptr, indices)."""
    out_ptr = np.zeros(which.size + 1, np.int64)
    for k in range(which.size):
        c = which[k]
        n = 0
        for e in range(indptr[c], indptr[c + 1]):
            if row_map[indices[e]] >= 0:
                n += 1
        out_ptr[k + 1] = out_ptr[k] + n
    out = np.empty(out_ptr[-1], indices.dtype)
    for k in range(which.size):
        c = which[k]
        f = out_ptr[k]
        for e in range(indptr[c], indptr[c + 1]):
            r = row_map[indices[e]]
            if r >= 0:
                out[f] = r
                f += 1
    return out_ptr, out


def duplicate_columns(cols: ColumnSets, order: np.ndarray) -> np.ndarray:
    """Mask of the (non-empty) columns identical to a column that comes earlier in ``order``."""
    n = cols.n_cols
    dup = np.zeros(n, dtype=bool)
    if n < 2:
        return dup
    # Sums of random weights over sorted indices: identical sets give bit-identical sums. Candidates are
    # then compared exactly, so a collision only costs a missed merge, never a wrong one.
    rng = np.random.default_rng(12345)
    starts = cols.indptr[:-1]
    h1 = np.add.reduceat(rng.random(cols.n_rows)[cols.indices], starts)
    h2 = np.add.reduceat(rng.random(cols.n_rows)[cols.indices], starts)
    sizes = cols.sizes()
    position = np.empty(n, dtype=np.int64)
    position[order] = np.arange(n)
    srt = np.lexsort((position, h2, h1, sizes))
    same = (sizes[srt[1:]] == sizes[srt[:-1]]) & (h1[srt[1:]] == h1[srt[:-1]]) & (h2[srt[1:]] == h2[srt[:-1]])
    if not same.any():
        return dup
    head_pos = np.maximum.accumulate(np.where(np.concatenate([[True], ~same]), np.arange(n), 0))
    cand = srt[1:][same]
    head = srt[head_pos[1:][same]]
    a, b = cols.take(cand), cols.take(head)
    equal = np.logical_and.reduceat(a.indices == b.indices, a.indptr[:-1])
    dup[cand[equal]] = True
    return dup


#: columns visited by one call of the compiled dominance search: the deadline is checked between calls
DOMINANCE_CHUNK_COLS = 2048


def dominated_columns(cols: ColumnSets, costs: np.ndarray, deadline: float) -> tuple[np.ndarray, bool]:
    """Mask of columns whose rows are a strict subset of another column's that costs no more.

    Columns are visited by decreasing size (then cost, then index), so every strict superset of a column is
    visited before it. A dominator holds all rows of the column, so it is sought among the earlier columns of the
    column's rarest row only, and only among those not found dominated themselves: a dominated superset has an
    undominated dominator of its own, which also dominates (subset and cost are transitive). The subset test merges
    the two sorted row lists and stops at the first row the candidate lacks. Compiled (:func:`_rank_lists`, then
    :func:`_dominated_kernel` for :data:`DOMINANCE_CHUNK_COLS` columns per call), without copying the columns.
    Identical columns must have been merged already (they are never flagged here). Returns the mask and whether the
    search finished before ``deadline``.
    """
    n = cols.n_cols
    dominated = np.zeros(n, dtype=bool)
    if n < 2:
        return dominated, True
    sizes = cols.sizes()
    order = np.lexsort((np.arange(n), costs, -sizes))
    row_ptr, row_ranks = _rank_lists(cols.indptr, cols.indices, order, cols.n_rows)
    ranked_costs = np.ascontiguousarray(costs[order], dtype=np.float64)
    found = np.zeros(n, dtype=bool)  # by rank
    complete = True
    for begin in range(0, n, DOMINANCE_CHUNK_COLS):
        if time.perf_counter() > deadline:
            complete = False
            break
        end = min(n, begin + DOMINANCE_CHUNK_COLS)
        _dominated_kernel(cols.indptr, cols.indices, order, row_ptr, row_ranks, ranked_costs, found, begin, end)
    dominated[order] = found
    return dominated, complete


@numba.njit(cache=True)
def _rank_lists(indptr, indices, order, n_rows):  # pragma: no cover - compiled
    """Per row, the ranks (positions in ``order``) of the columns that hold it, ascending: (row_ptr, ranks)."""
    row_ptr = np.zeros(n_rows + 1, np.int64)
    for e in range(indices.size):
        row_ptr[indices[e] + 1] += 1
    for r in range(n_rows):
        row_ptr[r + 1] += row_ptr[r]
    fill = row_ptr[:-1].copy()
    ranks = np.empty(indices.size, np.int64)
    for p in range(order.size):
        c = order[p]
        for e in range(indptr[c], indptr[c + 1]):
            r = indices[e]
            ranks[fill[r]] = p
            fill[r] += 1
    return row_ptr, ranks


@numba.njit(cache=True, inline="always")
def _rarest(indices, a, b, owner_ptr):  # pragma: no cover - compiled
    """Of the entries ``indices[a:b]``, the one held by the fewest sets (``owner_ptr`` of the transpose)."""
    rare = indices[a]
    for e in range(a + 1, b):
        r = indices[e]
        if owner_ptr[r + 1] - owner_ptr[r] < owner_ptr[rare + 1] - owner_ptr[rare]:
            rare = r
    return rare


@numba.njit(cache=True, inline="always")
def _sorted_subset(indices, a0, a1, b0, b1):  # pragma: no cover - compiled
    """Whether the sorted ``indices[a0:a1]`` all occur in the sorted ``indices[b0:b1]``: one merge, stopped at
    the first one missing."""
    j = b0
    for e in range(a0, a1):
        v = indices[e]
        while j < b1 and indices[j] < v:
            j += 1
        if j == b1 or indices[j] != v:
            return False
        j += 1
    return True


@numba.njit(cache=True)
def _dominated_kernel(indptr, indices, order, row_ptr, row_ranks, costs, dominated, begin, end):  # pragma: no cover
    """:func:`dominated_columns` for the ranks ``begin:end`` (rank p is column ``order[p]``; larger first; ``costs``
    and ``dominated`` by rank): sets ``dominated`` in place."""
    for p in range(begin, end):
        c = order[p]
        a, b = indptr[c], indptr[c + 1]
        size = b - a
        if size == 0:
            continue
        rare = _rarest(indices, a, b, row_ptr)
        for q in range(row_ptr[rare], row_ptr[rare + 1]):
            rank = row_ranks[q]
            if rank >= p:
                break  # later ranks are no larger
            d = order[rank]
            if dominated[rank] or indptr[d + 1] - indptr[d] <= size or costs[rank] > costs[p]:
                continue
            # rows(c) within rows(d)? both sorted: one merge, stopped at the first row d lacks
            if _sorted_subset(indices, a, b, indptr[d], indptr[d + 1]):
                dominated[p] = True
                break


def implied_rows(rows: ColumnSets, candidates: np.ndarray, deadline: float) -> tuple[np.ndarray, bool]:
    """Mask of rows (as sets of views) whose views include all views of another candidate row.

    Any cover of the smaller row also covers the larger one, so the larger is implied and can go (a chain of
    strict subsets ends at a row that is not implied, so all of them can go at once). The rows that include row a
    all hold a's rarest view, so they are sought among that view's rows only; identical rows must have been merged
    already (equal sizes are skipped). The subset test merges the two sorted view lists and stops at the first
    view the larger row lacks; compiled (:func:`_implied_kernel`, :data:`IMPLIED_CHUNK_ROWS` rows per call, the
    deadline checked between calls).
    """
    implied = np.zeros(rows.n_cols, dtype=bool)
    if candidates.size < 2:
        return implied, True
    if time.perf_counter() > deadline:
        return implied, False
    sub = rows.take(np.asarray(candidates, dtype=np.int64))
    by_col = sub.transpose()  # view -> candidate positions holding it
    found = np.zeros(candidates.size, dtype=bool)
    complete = True
    for begin in range(0, candidates.size, IMPLIED_CHUNK_ROWS):
        if time.perf_counter() > deadline:
            complete = False
            break
        end = min(candidates.size, begin + IMPLIED_CHUNK_ROWS)
        _implied_kernel(sub.indptr, sub.indices, by_col.indptr, by_col.indices, found, begin, end)
    implied[candidates[found]] = True
    return implied, complete


@numba.njit(cache=True)
def _implied_kernel(indptr, indices, by_ptr, by_rows, implied, begin, end):  # pragma: no cover - compiled
    """:func:`implied_rows` for the rows ``begin:end`` as the smaller row: sets ``implied`` of every larger row
    holding all of its views, in place."""
    for a in range(begin, end):
        a0, a1 = indptr[a], indptr[a + 1]
        size = a1 - a0
        if size == 0:
            continue
        rare = _rarest(indices, a0, a1, by_ptr)
        for q in range(by_ptr[rare], by_ptr[rare + 1]):
            b = by_rows[q]
            b0, b1 = indptr[b], indptr[b + 1]
            if implied[b] or b1 - b0 <= size:
                continue
            if _sorted_subset(indices, a0, a1, b0, b1):
                implied[b] = True


@dataclass
class Reduction:
    forced: list[int]
    cols_alive: np.ndarray
    rows_alive: np.ndarray
    matrix: ColumnSets  # rows_alive x cols_alive, renumbered
    stats: dict


def reduce_problem(cols: ColumnSets, costs: np.ndarray, tie: np.ndarray, deadline: float) -> Reduction:
    """Apply the optimality-preserving reductions until nothing changes (or ``deadline`` passes)."""
    stats = {
        "duplicate_cols": 0,
        "dominated_cols": 0,
        "forced_cols": 0,
        "duplicate_rows": 0,
        "implied_rows": 0,
        "reductions_complete": True,
        "rounds": 0,
    }
    row_ids = np.nonzero(np.bincount(cols.indices, minlength=cols.n_rows) > 0)[0]
    col_ids = np.nonzero(cols.sizes() > 0)[0]
    row_keep = np.zeros(cols.n_rows, dtype=bool)
    row_keep[row_ids] = True
    cur = restrict(cols, row_keep, col_ids)
    forced: list[int] = []

    def drop_empty_columns():
        nonlocal cur, col_ids
        nonempty = cur.sizes() > 0
        if not nonempty.all():
            cur, col_ids = cur.take(np.nonzero(nonempty)[0]), col_ids[nonempty]

    entries, rows_reduced = cur.indices.size, False
    for _ in range(MAX_REDUCTION_ROUNDS):
        if cur.n_rows == 0:
            break
        if time.perf_counter() > deadline:
            stats["reductions_complete"] = False
            break
        if rows_reduced and entries - cur.indices.size < REDUCTION_MIN_CHANGE * entries:
            # the last round took little, and the rows were reduced once: another round costs as much (passes
            # over every entry) for even less
            stats["reductions_complete"] = False
            break
        entries = cur.indices.size
        stats["rounds"] += 1
        changed = False
        # Duplicate columns: keep the cheapest, then the lowest worst uncertainty, then the lowest index.
        c = costs[col_ids]
        keep = ~duplicate_columns(cur, np.lexsort((col_ids, tie[col_ids], c)))
        stats["duplicate_cols"] += int(np.count_nonzero(~keep))
        survivors = np.nonzero(keep)[0]
        dominated, complete = dominated_columns(cur.take(survivors), c[survivors], deadline)
        stats["reductions_complete"] &= complete
        keep[survivors[dominated]] = False
        stats["dominated_cols"] += int(np.count_nonzero(dominated))
        if not keep.all():
            changed = True
            cur, col_ids = cur.take(np.nonzero(keep)[0]), col_ids[keep]
        # Forced columns: the only view left for some point.
        rows_t = cur.transpose()
        single = rows_t.sizes() == 1
        if single.any():
            must = np.unique(rows_t.indices[rows_t.indptr[:-1][single]])
            forced.extend(col_ids[must].tolist())
            stats["forced_cols"] += int(must.size)
            uncovered = np.ones(cur.n_rows, dtype=bool)
            uncovered[cur.take(must).indices] = False
            col_keep = np.ones(cur.n_cols, dtype=bool)
            col_keep[must] = False
            cur, row_ids, col_ids = (
                restrict(cur, uncovered, np.nonzero(col_keep)[0]),
                row_ids[uncovered],
                col_ids[col_keep],
            )
            drop_empty_columns()
            changed = True
            if entries - cur.indices.size >= REDUCTION_MIN_CHANGE * entries:
                continue  # the rows changed much: redo the column reductions first
            rows_t = cur.transpose()  # a few forced columns: the rows' turn first (it may change more)
        # Rows: identical rows, then rows implied by a row with fewer views.
        if time.perf_counter() > deadline:
            stats["reductions_complete"] = False
            break
        drop = duplicate_columns(rows_t, np.arange(rows_t.n_cols))
        stats["duplicate_rows"] += int(np.count_nonzero(drop))
        implied, complete = implied_rows(rows_t, np.nonzero(~drop)[0], deadline)
        stats["reductions_complete"] &= complete
        stats["implied_rows"] += int(np.count_nonzero(implied))
        drop |= implied
        if drop.any():
            changed = True
            cur, row_ids = restrict(cur, ~drop, np.arange(cur.n_cols)), row_ids[~drop]
            drop_empty_columns()
        rows_reduced = True
        if not changed:
            break
    return Reduction(forced, col_ids, row_ids, cur, stats)
