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
    "column_bitsets",
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
# candidate row pairs checked between two looks at the deadline in :func:`implied_rows`
IMPLIED_GROUP_PAIRS = 200_000


def restrict(cols: ColumnSets, row_keep: np.ndarray, which: np.ndarray) -> ColumnSets:
    """Columns ``which`` restricted to the rows where the mask ``row_keep`` holds, rows renumbered."""
    part = cols.take(which)
    if row_keep.all():
        return part
    keep = row_keep[part.indices]
    col_of_entry = np.repeat(np.arange(which.size), part.sizes())
    counts = np.bincount(col_of_entry[keep], minlength=which.size)
    indptr = np.zeros(which.size + 1, dtype=np.int64)
    np.cumsum(counts, out=indptr[1:])
    row_map = (np.cumsum(row_keep) - 1).astype(np.int32)
    return ColumnSets(indptr, row_map[part.indices[keep]], int(np.count_nonzero(row_keep)))


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
        rare = indices[a]
        for e in range(a + 1, b):
            r = indices[e]
            if row_ptr[r + 1] - row_ptr[r] < row_ptr[rare + 1] - row_ptr[rare]:
                rare = r
        for q in range(row_ptr[rare], row_ptr[rare + 1]):
            rank = row_ranks[q]
            if rank >= p:
                break  # later ranks are no larger
            d = order[rank]
            if dominated[rank] or indptr[d + 1] - indptr[d] <= size or costs[rank] > costs[p]:
                continue
            # rows(c) within rows(d)? both sorted: one merge, stopped at the first row d lacks
            j, stop = indptr[d], indptr[d + 1]
            subset = True
            for i in range(a, b):
                row = indices[i]
                while j < stop and indices[j] < row:
                    j += 1
                if j == stop or indices[j] != row:
                    subset = False
                    break
                j += 1
            if subset:
                dominated[p] = True
                break


def column_bitsets(cols: ColumnSets) -> np.ndarray:
    """Each column's rows packed into uint64 words, one row of words per column."""
    n_words = max(1, -(-cols.n_rows // 64))
    out = np.zeros((cols.n_cols, n_words * 8), dtype=np.uint8)
    step = max(1, 8_000_000 // max(cols.n_rows, 1))
    for start in range(0, cols.n_cols, step):
        which = np.arange(start, min(start + step, cols.n_cols))
        part = cols.take(which)
        dense = np.zeros((which.size, cols.n_rows), dtype=bool)
        dense[np.repeat(np.arange(which.size), part.sizes()), part.indices] = True
        out[start : start + which.size, : -(-cols.n_rows // 8)] = np.packbits(dense, axis=1, bitorder="little")
    return out.view(np.uint64)


def implied_rows(rows: ColumnSets, candidates: np.ndarray, deadline: float) -> tuple[np.ndarray, bool]:
    """Mask of rows (as sets of views) whose views include all views of another candidate row.

    Any cover of the smaller row also covers the larger one, so the larger is implied and can go. The rows
    that include row a all hold a's rarest view, so they are sought among that view's rows only; identical
    rows must have been merged already (equal sizes are skipped).
    """
    implied = np.zeros(rows.n_cols, dtype=bool)
    if candidates.size < 2:
        return implied, True
    sub = rows.take(candidates)
    by_col = sub.transpose()  # column -> candidate positions
    degree = by_col.sizes()
    sizes = sub.sizes()
    seg = np.repeat(np.arange(candidates.size), sizes)
    ordered = np.lexsort((degree[sub.indices], seg))
    rarest = sub.indices[ordered[sub.indptr[:-1]]]
    if time.perf_counter() > deadline:
        return implied, False  # the bitsets alone cost seconds at tilt full
    bits = column_bitsets(sub)
    work = degree[rarest]
    complete = True
    # groups of rows of about IMPLIED_GROUP_PAIRS candidate pairs: the deadline is checked between groups, and
    # at tilt full one row's rarest view still holds thousands of rows
    cum_work = np.cumsum(work)
    start = 0
    while start < candidates.size:
        if time.perf_counter() > deadline:
            complete = False
            break
        done = int(cum_work[start - 1]) if start else 0
        stop = int(np.searchsorted(cum_work, done + IMPLIED_GROUP_PAIRS, side="right"))
        stop = min(max(stop, start + 1), start + 256)
        group = np.arange(start, stop)
        start = stop
        counts = work[group]
        offsets = np.zeros(group.size, dtype=np.int64)
        np.cumsum(counts[:-1], out=offsets[1:])
        pos = np.repeat(by_col.indptr[rarest[group]] - offsets, counts) + np.arange(int(counts.sum()))
        b = by_col.indices[pos].astype(np.int64)
        a = np.repeat(group, counts)
        keep = sizes[b] > sizes[a]  # equal sizes would be identical rows
        a, b = a[keep], b[keep]
        ok = np.ones(a.size, dtype=bool)
        for w in range(bits.shape[1]):
            ok &= (bits[a, w] & ~bits[b, w]) == 0
        implied[candidates[b[ok]]] = True
    return implied, complete


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
