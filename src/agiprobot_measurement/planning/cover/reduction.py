"""Optimality-preserving reductions of a set-cover problem before the integer programme: duplicate, dominated
and forced columns, duplicate and implied rows, repeated until nothing changes.
"""

from __future__ import annotations

import itertools
import time
from dataclasses import dataclass

import numpy as np

from agiprobot_measurement.planning.cover.columns import ColumnSets

__all__ = [
    "MAX_REDUCTION_ROUNDS",
    "Reduction",
    "column_bitsets",
    "dominated_columns",
    "dominated_in_block",
    "duplicate_columns",
    "implied_rows",
    "reduce_problem",
    "restrict",
    "rows_held",
]

# Reductions run a few rounds at most: after two or three nothing changes on realistic data.
MAX_REDUCTION_ROUNDS = 10
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


def dominated_columns(
    cols: ColumnSets, costs: np.ndarray, deadline: float, probe_rows: int = 16, max_pool_bytes: int = 256 << 20
) -> tuple[np.ndarray, bool]:
    """Mask of columns whose rows are a subset of another column's that costs no more.

    Columns are visited by decreasing size (then cost, then index), so every strict superset of a column is
    visited before it, and only columns found undominated (the *pool*) need to be searched: a superset
    that is itself dominated has an undominated dominator of its own, which also dominates (subset and cost
    are transitive). Equal-sized columns cannot strictly contain one another, so each size level is checked
    against the pool as a whole, vectorised. For every pool row a bitset over the pool says which pool
    columns hold it; ANDing the bitsets of a column's few rarest rows leaves a handful of candidates, which
    are then checked row by row. Identical columns must have been merged already (they are never flagged
    here). Returns the mask and whether the search finished before ``deadline``.
    """
    n, m = cols.n_cols, cols.n_rows
    dominated = np.zeros(n, dtype=bool)
    if n < 2:
        return dominated, True
    sizes = cols.sizes()
    order = np.lexsort((np.arange(n), costs, -sizes))
    sorted_sizes = sizes[order]
    level_starts = np.flatnonzero(np.concatenate([[True], sorted_sizes[1:] != sorted_sizes[:-1]]))
    level_bounds = [*level_starts.tolist(), n]
    max_words = max(1, min(-(-n // 64), max_pool_bytes // (8 * max(m, 1))))
    pool_bits = np.zeros((m, min(max_words, 16)), dtype=np.uint64)
    pool = np.empty(min(n, 64 * max_words), dtype=np.int64)
    n_pool = 0
    pool_degree = np.zeros(m, dtype=np.int64)
    # Cost mask: pool columns are filed in cost buckets; ANDing with the bitset of the pool columns in the
    # candidate's bucket or a cheaper one keeps the lowest-candidate rounds from trying expensive columns.
    # Same-bucket candidates still get the exact cost test.
    n_buckets = 1 if np.all(costs == costs[0]) else 64
    edges = np.quantile(costs, np.linspace(0.0, 1.0, n_buckets + 1)[1:-1]) if n_buckets > 1 else np.zeros(0)
    bucket = np.searchsorted(edges, costs, side="left")
    cheap_bits = np.zeros((n_buckets, pool_bits.shape[1]), dtype=np.uint64)
    complete = True
    for lo, hi in itertools.pairwise(level_bounds):
        if time.perf_counter() > deadline:
            complete = False
            break
        level = order[lo:hi]
        size = int(sizes[level[0]])
        n_words = -(-n_pool // 64)
        step = max(1, min(4_000_000 // max(n_words, 1), 4_000_000 // size))
        for b0 in range(0, level.size if n_pool else 0, step):
            block = level[b0 : b0 + step]
            rows2d = cols.take(block).indices.reshape(block.size, size)
            degree2d = pool_degree[rows2d]
            possible = degree2d.min(axis=1) > 0  # a row no pool column holds: nothing can dominate
            if not possible.any():
                continue
            block, rows2d, degree2d = block[possible], rows2d[possible], degree2d[possible]
            t = min(size, probe_rows)
            if t < size:
                probe = np.take_along_axis(rows2d, np.argpartition(degree2d, t - 1, axis=1)[:, :t], axis=1)
            else:
                probe = rows2d
            acc = pool_bits[probe[:, 0], :n_words]
            for i in range(1, t):
                acc = acc & pool_bits[probe[:, i], :n_words]
            if n_buckets > 1:
                acc &= cheap_bits[bucket[block], :n_words]
            dominated[block[dominated_in_block(acc, pool, block, rows2d, costs, pool_bits, t < size)]] = True
        kept = level[~dominated[level]]
        room = pool.size - n_pool
        if kept.size > room:
            complete = False  # pool memory cap: later columns are only checked against this pool
            kept = kept[:room]
        if kept.size == 0:
            continue
        idx = n_pool + np.arange(kept.size, dtype=np.int64)
        need = -(-(n_pool + kept.size) // 64)
        if need > pool_bits.shape[1]:
            grown = np.zeros((m, min(max_words, max(need, 2 * pool_bits.shape[1]))), dtype=np.uint64)
            grown[:, : pool_bits.shape[1]] = pool_bits
            pool_bits = grown
            grown = np.zeros((n_buckets, pool_bits.shape[1]), dtype=np.uint64)
            grown[:, : cheap_bits.shape[1]] = cheap_bits
            cheap_bits = grown
        rows = cols.take(kept).indices
        k = np.repeat(idx, size)
        np.bitwise_or.at(pool_bits, (rows, k >> 6), np.left_shift(np.uint64(1), (k & 63).astype(np.uint64)))
        pool_degree += np.bincount(rows, minlength=m)
        if n_buckets > 1:
            # Each new column joins its own bucket's mask and every more expensive one's.
            w0 = n_pool // 64
            new_bits = np.zeros((n_buckets, -(-(n_pool + kept.size) // 64) - w0), dtype=np.uint64)
            np.bitwise_or.at(
                new_bits, (bucket[kept], (idx >> 6) - w0), np.left_shift(np.uint64(1), (idx & 63).astype(np.uint64))
            )
            cheap_bits[:, w0 : w0 + new_bits.shape[1]] |= np.bitwise_or.accumulate(new_bits, axis=0)
        pool[n_pool : n_pool + kept.size] = kept
        n_pool += kept.size
    return dominated, complete


def rows_held(pool_bits: np.ndarray, rows2d: np.ndarray, k: np.ndarray) -> np.ndarray:
    """For pairs (rows2d[i], pool column k[i]): does the pool column hold every one of the rows?

    Rows are checked 16 at a time and failed pairs dropped in between: a non-superset usually misses many
    rows, so it rarely costs more than the first slice.
    """
    word, shift = k >> 6, (k & 63).astype(np.uint64)
    live = np.arange(k.size)
    for j0 in range(0, rows2d.shape[1], 16):
        if live.size == 0:
            break
        held = pool_bits[rows2d[live, j0 : j0 + 16], word[live, None]] >> shift[live, None]
        live = live[np.all(held & np.uint64(1), axis=1)]
    ok = np.zeros(k.size, dtype=bool)
    ok[live] = True
    return ok


def dominated_in_block(
    acc: np.ndarray,
    pool: np.ndarray,
    block: np.ndarray,
    rows2d: np.ndarray,
    costs: np.ndarray,
    pool_bits: np.ndarray,
    verify: bool,
) -> np.ndarray:
    """Positions in ``block`` with a verified dominator among their candidates (set bits of ``acc``).

    One dominator per column is enough and most candidates that survive the probe rows and the cost mask
    are genuine, so each column's lowest candidate is tried first, for a few rounds (a check costs one
    gather per row); only the columns still open after that have all their remaining candidates expanded
    and checked.
    """
    found = np.zeros(block.size, dtype=bool)
    open_rows = np.nonzero(acc.any(axis=1))[0]
    for _ in range(4):
        if open_rows.size == 0:
            return found
        sub = acc[open_rows]
        w = np.argmax(sub != 0, axis=1)
        word = sub[np.arange(open_rows.size), w]
        lowest = word & (~word + np.uint64(1))
        k = w.astype(np.int64) * 64 + np.log2(lowest.astype(np.float64)).astype(np.int64)  # exact: 2**n
        ok = costs[pool[k]] <= costs[block[open_rows]]
        if verify and ok.any():
            ok[ok] = rows_held(pool_bits, rows2d[open_rows[ok]], k[ok])
        found[open_rows[ok]] = True
        acc[open_rows, w] &= ~lowest
        open_rows = open_rows[~ok]
        open_rows = open_rows[acc[open_rows].any(axis=1)]
    if open_rows.size == 0:
        return found
    ai, wi = np.nonzero(acc[open_rows])
    bits = np.unpackbits(acc[open_rows[ai], wi].view(np.uint8).reshape(-1, 8), axis=1, bitorder="little")
    hit, bit = np.nonzero(bits)
    a_pos = open_rows[ai[hit]]
    k = wi[hit].astype(np.int64) * 64 + bit
    ok = costs[pool[k]] <= costs[block[a_pos]]
    a_pos, k = a_pos[ok], k[ok]
    if verify and a_pos.size:
        a_pos = a_pos[rows_held(pool_bits, rows2d[a_pos], k)]
    found[a_pos] = True
    return found


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

    for _ in range(MAX_REDUCTION_ROUNDS):
        if cur.n_rows == 0:
            break
        if time.perf_counter() > deadline:
            stats["reductions_complete"] = False
            break
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
            continue  # the rows changed: redo the column reductions first
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
        if not changed:
            break
    return Reduction(forced, col_ids, row_ids, cur, stats)
