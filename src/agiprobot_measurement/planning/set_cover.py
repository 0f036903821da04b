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

All solvers return a :class:`SetCoverResult`; :func:`solve_set_cover` is the entry point.
"""

from __future__ import annotations

import heapq
import itertools
import math
import time
import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy import sparse

from agiprobot_measurement.errors import InputError

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

# Reductions run a few rounds at most: after two or three nothing changes on realistic data.
_MAX_REDUCTION_ROUNDS = 10
# Share of the time limit the reductions may use; the rest is left to the solver.
_REDUCTION_TIME_SHARE = 0.5
# Size and time cap of the quick programme over the LP's favourite columns that tightens the incumbent.
_SUPPORT_MIP_COLS = 400
_SUPPORT_MIP_TIME_S = 2.0


class SetCoverError(InputError):
    """Invalid input to the set-cover solvers."""


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


# --------------------------------------------------------------------------------------------------------
# Input handling


@dataclass
class _Columns:
    """Column-wise sparse sets: column j holds the rows ``indices[indptr[j]:indptr[j + 1]]`` (sorted)."""

    indptr: np.ndarray
    indices: np.ndarray
    n_rows: int

    @property
    def n_cols(self) -> int:
        return self.indptr.size - 1

    def sizes(self) -> np.ndarray:
        return np.diff(self.indptr)

    def col(self, j: int) -> np.ndarray:
        return self.indices[self.indptr[j] : self.indptr[j + 1]]

    def take(self, which: np.ndarray) -> _Columns:
        """The columns ``which`` (same rows), renumbered 0.."""
        sizes = self.indptr[which + 1] - self.indptr[which]
        indptr = np.zeros(which.size + 1, dtype=np.int64)
        np.cumsum(sizes, out=indptr[1:])
        # Flat positions of all entries of the chosen columns, without a Python loop.
        pos = np.repeat(self.indptr[which] - indptr[:-1], sizes) + np.arange(indptr[-1])
        return _Columns(indptr, self.indices[pos], self.n_rows)

    def transpose(self) -> _Columns:
        csc = sparse.csc_array(
            (np.ones(self.indices.size, dtype=bool), self.indices, self.indptr), shape=(self.n_rows, self.n_cols)
        )
        csr = csc.tocsr()
        csr.sort_indices()
        return _Columns(csr.indptr, csr.indices, self.n_cols)


def _measurable_columns(matrix) -> tuple[_Columns, np.ndarray | None]:
    """Canonical column sets of the measurable entries and, for numeric input, their values."""
    if sparse.issparse(matrix):
        csc = matrix.tocsc()
        if csc is matrix and not csc.has_canonical_format:
            csc = csc.copy()  # canonicalising works in place: leave the caller's matrix alone
    else:
        dense = np.asarray(matrix)
        if dense.ndim != 2:
            raise SetCoverError(f"matrix must be 2-D (points x views), got shape {dense.shape}")
        csc = sparse.csc_array(dense)
    csc.sum_duplicates()
    csc.sort_indices()
    n_rows, n_cols = csc.shape
    # int32 positions halve the memory traffic of every gather below (nnz stays far below 2**31 here).
    small = csc.nnz < 2**31 - 1
    indptr = csc.indptr.astype(np.int32, copy=False) if small else csc.indptr
    indices = csc.indices.astype(np.int32, copy=False) if small else csc.indices
    data = csc.data
    if data.dtype == bool:
        keep, values = data, None
        all_kept = bool(keep.all())
    elif np.issubdtype(data.dtype, np.number):
        values = data.astype(np.float64, copy=False)
        # Fast path for the usual input (all stored values positive and finite): two passes, no copies.
        positive = values > 0.0
        all_kept = bool(positive.all()) and (values.size == 0 or math.isfinite(float(values.max())))
        if not all_kept:
            if np.any(values < 0.0) or np.any(np.isinf(values)):
                raise SetCoverError("uncertainty values in the matrix must be finite and non-negative")
            keep = positive  # zero and NaN entries are not measurable
    else:
        raise SetCoverError(f"matrix dtype {data.dtype} is neither boolean nor numeric")
    if all_kept:
        return _Columns(indptr, indices, n_rows), values
    col_of_entry = np.repeat(np.arange(n_cols), np.diff(indptr))
    counts = np.bincount(col_of_entry[keep], minlength=n_cols)
    new_indptr = np.zeros(n_cols + 1, dtype=indptr.dtype)
    np.cumsum(counts, out=new_indptr[1:])
    return _Columns(new_indptr, indices[keep], n_rows), None if values is None else values[keep]


def _column_max(cols: _Columns, values: np.ndarray) -> np.ndarray:
    """Per-column maximum of ``values`` (aligned with ``cols.indices``); 0 for empty columns."""
    out = np.zeros(cols.n_cols)
    nonempty = np.nonzero(cols.sizes() > 0)[0]
    if nonempty.size:
        # reduceat segments run from one start to the next; empty columns in between hold no entries, so
        # every segment is exactly one non-empty column.
        out[nonempty] = np.maximum.reduceat(values, cols.indptr[nonempty])
    return out


def _worst_uncertainty(cols: _Columns, values, uncertainties) -> np.ndarray | None:
    """Worst (maximum) uncertainty per view, or None when nothing gives uncertainties."""
    if uncertainties is None:
        return None if values is None else _column_max(cols, values)
    if sparse.issparse(uncertainties) or np.ndim(uncertainties) == 2:
        if tuple(uncertainties.shape) != (cols.n_rows, cols.n_cols):
            raise SetCoverError(
                f"uncertainties matrix has shape {tuple(uncertainties.shape)}, expected {(cols.n_rows, cols.n_cols)}"
            )
        u = sparse.csc_array(uncertainties, dtype=np.float64)
        mask = sparse.csc_array(
            (np.ones(cols.indices.size), cols.indices, cols.indptr), shape=(cols.n_rows, cols.n_cols)
        )
        u = sparse.csc_array(u.multiply(mask))  # only the measurable entries count
        u.sum_duplicates()
        if u.data.size and (np.any(u.data < 0.0) or not np.all(np.isfinite(u.data))):
            raise SetCoverError("uncertainties must be finite and non-negative")
        return _column_max(_Columns(u.indptr, u.indices, cols.n_rows), u.data)
    per_view = np.asarray(uncertainties, dtype=np.float64)
    if per_view.shape != (cols.n_cols,):
        raise SetCoverError(
            f"uncertainties must be one value per view ({cols.n_cols}) or a points x views matrix, "
            f"got shape {per_view.shape}"
        )
    if not np.all(np.isfinite(per_view)) or np.any(per_view < 0.0):
        raise SetCoverError("uncertainties must be finite and non-negative")
    return per_view


def _normalised(costs: np.ndarray) -> np.ndarray:
    top = float(costs.max()) if costs.size else 0.0
    return costs / top if top > 0.0 else costs.copy()


# --------------------------------------------------------------------------------------------------------
# Greedy


def _fresh_gains(cols: _Columns, which: np.ndarray, covered: np.ndarray) -> np.ndarray:
    """Number of rows not yet ``covered`` in each column of ``which`` (all non-empty), in one pass."""
    part = cols.take(which)
    hits = np.add.reduceat(covered[part.indices], part.indptr[:-1], dtype=np.int64)
    return part.sizes() - hits


def _greedy(cols: _Columns, tie: np.ndarray, n_uncovered: int) -> list[int]:
    """Lazy greedy: each pick covers the most uncovered rows; ties: lower ``tie``, then lower index.

    Gains only shrink as rows get covered, so a stored gain never understates a view. Views sit in buckets by
    stored gain; a heap (heapq) holds the bucket gains. The top bucket's stale members (evaluated before the
    latest pick) are re-evaluated in one vectorised pass and those that lost gain move down; the members
    left are fresh and hold the true maximum, so the best of them by tie-break is the exact greedy choice.
    Only views that reach the top are ever re-evaluated (no re-sort per step), and the Python work per step
    is per bucket, not per view, which keeps 100k+ candidates well under a second.
    """
    n_cols = cols.n_cols
    sizes = cols.sizes()
    order = np.lexsort((np.arange(n_cols), tie))
    rank = np.empty(n_cols, dtype=np.int64)
    rank[order] = np.arange(n_cols)
    buckets: dict[int, list[np.ndarray]] = {}
    heap: list[int] = []

    def file_under(members: np.ndarray, gains: np.ndarray) -> None:
        keep = gains > 0
        members, gains = members[keep], gains[keep]
        if members.size == 0:
            return
        by_gain = np.argsort(gains, kind="stable")
        values, starts = np.unique(gains[by_gain], return_index=True)
        for value, group in zip(values.tolist(), np.split(members[by_gain], starts[1:]), strict=True):
            if value not in buckets:
                buckets[value] = []
                heapq.heappush(heap, -value)
            buckets[value].append(group)

    cand = np.nonzero(sizes > 0)[0]
    file_under(cand, sizes[cand])
    stamp = np.zeros(n_cols, dtype=np.int64)  # number of picks when the stored gain was computed
    covered = np.zeros(cols.n_rows, dtype=bool)
    picks: list[int] = []
    while heap and n_uncovered > 0:
        gain = -heap[0]
        parts = buckets.pop(gain)
        members = parts[0] if len(parts) == 1 else np.concatenate(parts)
        stale = stamp[members] != len(picks)
        if stale.any():
            old = members[stale]
            fresh = _fresh_gains(cols, old, covered)
            stamp[old] = len(picks)
            lost = fresh < gain
            members = np.concatenate([members[~stale], old[~lost]])
            heapq.heappop(heap)  # the moved views go to lower buckets only, so -gain is still on top
            file_under(old[lost], fresh[lost])
            if members.size == 0:
                continue
            heapq.heappush(heap, -gain)
        best = int(members[np.argmin(rank[members])])
        rows = cols.col(best)
        covered[rows] = True
        n_uncovered -= gain
        picks.append(best)
        rest = members[members != best]
        if rest.size:
            buckets[gain] = [rest]
        else:
            heapq.heappop(heap)
    return picks


def _greedy_weighted(cols: _Columns, tie: np.ndarray, costs: np.ndarray) -> list[int]:
    """Chvatal's greedy (least cost per newly covered row) with a lazy heapq, for warm starts.

    Runs on the reduced programme (a few thousand views), so a per-view heap entry is cheap enough. A popped
    entry whose recomputed ratio is unchanged is the true best: ratios only grow as rows get covered.
    """
    sizes = cols.sizes()
    cand = np.nonzero(sizes > 0)[0]
    heap = list(zip((costs[cand] / sizes[cand]).tolist(), tie[cand].tolist(), cand.tolist(), strict=True))
    heapq.heapify(heap)
    covered = np.zeros(cols.n_rows, dtype=bool)
    n_uncovered = int(np.count_nonzero(np.bincount(cols.indices, minlength=cols.n_rows)))
    picks: list[int] = []
    while heap and n_uncovered > 0:
        key, t, j = heap[0]
        rows = cols.col(j)
        gain = rows.size - int(np.count_nonzero(covered[rows]))
        if gain == 0:
            heapq.heappop(heap)
            continue
        fresh = float(costs[j]) / gain
        if fresh == key:
            heapq.heappop(heap)
            covered[rows] = True
            n_uncovered -= gain
            picks.append(j)
        else:
            heapq.heapreplace(heap, (fresh, t, j))
    return picks


def _make_irredundant(cols: _Columns, picks: list[int], costs: np.ndarray | None) -> list[int]:
    """Drop picks whose points are all covered by the other picks (most expensive, else latest, first)."""
    if len(picks) < 2:
        return list(picks)
    count = np.zeros(cols.n_rows, dtype=np.int32)
    for j in picks:
        count[cols.col(j)] += 1
    order = list(reversed(picks))
    if costs is not None:
        order.sort(key=lambda j: -costs[j])  # stable: equal costs keep latest-first
    kept = set(picks)
    for j in order:
        rows = cols.col(j)
        if np.all(count[rows] >= 2):
            count[rows] -= 1
            kept.discard(j)
    return [j for j in picks if j in kept]


# --------------------------------------------------------------------------------------------------------
# Reductions


def _restrict(cols: _Columns, row_keep: np.ndarray, which: np.ndarray) -> _Columns:
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
    return _Columns(indptr, row_map[part.indices[keep]], int(np.count_nonzero(row_keep)))


def _duplicates(cols: _Columns, order: np.ndarray) -> np.ndarray:
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


def _dominated_columns(
    cols: _Columns, costs: np.ndarray, deadline: float, probe_rows: int = 16, max_pool_bytes: int = 256 << 20
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
            dominated[block[_dominated_in_block(acc, pool, block, rows2d, costs, pool_bits, t < size)]] = True
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


def _rows_held(pool_bits: np.ndarray, rows2d: np.ndarray, k: np.ndarray) -> np.ndarray:
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


def _dominated_in_block(
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
            ok[ok] = _rows_held(pool_bits, rows2d[open_rows[ok]], k[ok])
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
        a_pos = a_pos[_rows_held(pool_bits, rows2d[a_pos], k)]
    found[a_pos] = True
    return found


def _bitsets(cols: _Columns) -> np.ndarray:
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


def _implied_rows(rows: _Columns, candidates: np.ndarray, deadline: float) -> tuple[np.ndarray, bool]:
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
    bits = _bitsets(sub)
    work = degree[rarest]
    complete = True
    for start in range(0, candidates.size, 256):
        if time.perf_counter() > deadline:
            complete = False
            break
        group = np.arange(start, min(start + 256, candidates.size))
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
class _Reduction:
    forced: list[int]
    cols_alive: np.ndarray
    rows_alive: np.ndarray
    matrix: _Columns  # rows_alive x cols_alive, renumbered
    stats: dict


def _reduce(cols: _Columns, costs: np.ndarray, tie: np.ndarray, deadline: float) -> _Reduction:
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
    cur = _restrict(cols, row_keep, col_ids)
    forced: list[int] = []

    def drop_empty_columns():
        nonlocal cur, col_ids
        nonempty = cur.sizes() > 0
        if not nonempty.all():
            cur, col_ids = cur.take(np.nonzero(nonempty)[0]), col_ids[nonempty]

    for _ in range(_MAX_REDUCTION_ROUNDS):
        if cur.n_rows == 0:
            break
        if time.perf_counter() > deadline:
            stats["reductions_complete"] = False
            break
        stats["rounds"] += 1
        changed = False
        # Duplicate columns: keep the cheapest, then the lowest worst uncertainty, then the lowest index.
        c = costs[col_ids]
        keep = ~_duplicates(cur, np.lexsort((col_ids, tie[col_ids], c)))
        stats["duplicate_cols"] += int(np.count_nonzero(~keep))
        survivors = np.nonzero(keep)[0]
        dominated, complete = _dominated_columns(cur.take(survivors), c[survivors], deadline)
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
                _restrict(cur, uncovered, np.nonzero(col_keep)[0]),
                row_ids[uncovered],
                col_ids[col_keep],
            )
            drop_empty_columns()
            continue  # the rows changed: redo the column reductions first
        # Rows: identical rows, then rows implied by a row with fewer views.
        drop = _duplicates(rows_t, np.arange(rows_t.n_cols))
        stats["duplicate_rows"] += int(np.count_nonzero(drop))
        implied, complete = _implied_rows(rows_t, np.nonzero(~drop)[0], deadline)
        stats["reductions_complete"] &= complete
        stats["implied_rows"] += int(np.count_nonzero(implied))
        drop |= implied
        if drop.any():
            changed = True
            cur, row_ids = _restrict(cur, ~drop, np.arange(cur.n_cols)), row_ids[~drop]
            drop_empty_columns()
        if not changed:
            break
    return _Reduction(forced, col_ids, row_ids, cur, stats)


# --------------------------------------------------------------------------------------------------------
# Integer programme backends


@dataclass
class _MipOutcome:
    x: np.ndarray | None  # chosen local columns (bool)
    objective: float
    bound: float
    status: str  # "optimal", "time_limit", "infeasible", "error"
    detail: str


def _highs_model(sub: _Columns, costs: np.ndarray, integer: bool, time_limit_s: float):
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


def _lp_relaxation(sub: _Columns, costs: np.ndarray, time_limit_s: float):
    """LP relaxation: primal x, a rigorous lower bound and reduced costs; None if it did not solve.

    The bound is recomputed from the duals clipped to y >= 0 (any such y gives the Lagrangian bound
    ``sum(y) + sum(min(rc, 0))`` with ``rc = c - A^T y``), so solver tolerances cannot make it invalid. For
    any cover that uses column j, ``cost >= bound + max(rc_j, 0)``.
    """
    import highspy

    h = _highs_model(sub, costs, integer=False, time_limit_s=time_limit_s)
    h.run()
    if h.getModelStatus() != highspy.HighsModelStatus.kOptimal:
        return None
    sol = h.getSolution()
    y = np.maximum(np.asarray(sol.row_dual, dtype=np.float64), 0.0)
    x = np.clip(np.asarray(sol.col_value, dtype=np.float64), 0.0, 1.0)
    rc = costs - np.add.reduceat(y[sub.indices], sub.indptr[:-1])
    return x, float(y.sum() + np.minimum(rc, 0.0).sum()), rc


def _solve_highs(
    sub: _Columns, costs: np.ndarray, start: np.ndarray | None, time_limit_s: float, mip_gap: float
) -> _MipOutcome:
    import highspy

    h = _highs_model(sub, costs, integer=True, time_limit_s=time_limit_s)
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


def _solve_cbc(
    sub: _Columns, costs: np.ndarray, start: np.ndarray | None, time_limit_s: float, mip_gap: float
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


# --------------------------------------------------------------------------------------------------------
# Entry point


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
    cols, values = _measurable_columns(matrix)
    worst_u = _worst_uncertainty(cols, values, uncertainties)
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
        picks = _greedy(cols, tie, n_coverable)
        stats["greedy_picks"] = len(picks)
        picks = _make_irredundant(cols, picks, None)
        return finish(picks, None, False, None, f"greedy: {len(picks)} views")

    costs = _normalised(raw_costs)
    scale = float(raw_costs.max()) if raw_costs.max() > 0 else 1.0  # normalised -> raw cost units
    t_red = time.perf_counter()
    if reduce:
        red = _reduce(cols, costs, tie, t_start + _REDUCTION_TIME_SHARE * time_limit_s)
    else:
        col_ids, row_keep = np.nonzero(cols.sizes() > 0)[0], row_degree > 0
        red = _Reduction([], col_ids, np.nonzero(row_keep)[0], _restrict(cols, row_keep, col_ids), {})
    stats.update(red.stats)
    stats["reduce_time_s"] = time.perf_counter() - t_red
    stats["reduced_shape"] = (int(red.rows_alive.size), int(red.cols_alive.size))
    forced = list(red.forced)
    offset = float(costs[forced].sum()) if forced else 0.0
    if red.rows_alive.size == 0:
        picks = _make_irredundant(cols, forced, costs)
        return finish(picks, 0.0, True, float(raw_costs[picks].sum()), "optimal (solved by reductions)")

    sub, sub_costs = red.matrix, costs[red.cols_alive]
    integral = solver_type == "IP_basic"  # every cover's cost is a whole number
    solve = _solve_highs if backend == "highs" else _solve_cbc
    deadline = t_start + time_limit_s
    local, bound_local, detail = _solve_reduced_ip(
        sub, sub_costs, tie[red.cols_alive], integral, solve, deadline, mip_gap, warm_start, reduce, stats
    )
    picks = forced + red.cols_alive[local].tolist()
    picks = _make_irredundant(cols, picks, costs)
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


def _lp_rounding(sub: _Columns, costs: np.ndarray, x: np.ndarray) -> list[int]:
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


def _solve_reduced_ip(sub, costs, tie, integral, solve, deadline, mip_gap, warm_start, lp_fixing, stats):
    """Solve the reduced programme; returns (chosen local columns, lower bound, detail).

    An incumbent comes from the best of Chvatal's greedy, an LP rounding and a small programme over the
    columns of least reduced cost (the last two only with ``lp_fixing``). With the LP's reduced costs,
    a column whose every cover costs more than the incumbent (for counts: more than one less than it) is
    left out of the integer programme: the programme then still holds every strictly better cover and the
    incumbent, so its optimum is the optimum. Covers that use a left-out column cost at least the
    incumbent, so the overall lower bound is ``min(programme bound, incumbent)``, and never below the LP's.
    """
    t0 = time.perf_counter()
    candidates = [_make_irredundant(sub, _greedy_weighted(sub, tie, costs), costs)]
    lp = _lp_relaxation(sub, costs, max(deadline - time.perf_counter(), 0.01)) if lp_fixing else None
    lp_bound = -math.inf
    if lp is not None:
        x_lp, lp_bound, rc = lp
        candidates.append(_make_irredundant(sub, _lp_rounding(sub, costs, x_lp), costs))
        stats["lp_bound"] = lp_bound
    incumbent = min(candidates, key=lambda c: float(costs[c].sum()))
    if lp is not None and sub.n_cols > _SUPPORT_MIP_COLS:
        # A small programme over the columns the LP likes best (least reduced cost) plus the incumbent
        # usually finds a near-optimal cover in a fraction of a second; a tighter incumbent lets the
        # reduced-cost test below leave out far more columns.
        pool = np.union1d(np.argsort(rc, kind="stable")[:_SUPPORT_MIP_COLS], incumbent)
        start = np.isin(pool, incumbent)
        budget = min(_SUPPORT_MIP_TIME_S, 0.2 * max(deadline - time.perf_counter(), 0.0))
        trial = solve(sub.take(pool), costs[pool], start, max(budget, 0.01), 0.0)
        if trial.x is not None and float(costs[pool][trial.x].sum()) < float(costs[incumbent].sum()):
            incumbent = _make_irredundant(sub, pool[trial.x].tolist(), costs)
    ub = float(costs[incumbent].sum())
    stats["incumbent_objective_normalised"] = ub
    stats["lp_time_s"] = time.perf_counter() - t0
    if not math.isfinite(lp_bound):
        settled = False
    elif integral:
        settled = math.ceil(lp_bound - 1e-6) >= ub * (1.0 - mip_gap) - 1e-9
    else:
        settled = lp_bound >= ub * (1.0 - max(mip_gap, 1e-9)) - 1e-12
    if settled:
        stats["mip_shape"] = (0, 0)
        return np.asarray(incumbent, dtype=np.int64), lp_bound, "the LP bound meets the heuristic cover"
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
    outcome = solve(restricted, costs[kept], start if warm_start else None, max(deadline - t_mip, 0.01), mip_gap)
    stats["mip_time_s"] = time.perf_counter() - t_mip
    stats["mip_shape"] = (restricted.n_rows, restricted.n_cols)
    if outcome.x is not None and float(costs[kept][outcome.x].sum()) <= ub:
        chosen = kept[outcome.x]
        detail = outcome.detail
    else:
        chosen = np.asarray(incumbent, dtype=np.int64)
        detail = f"{outcome.detail}; kept the heuristic cover"
    bound = max(lp_bound, min(outcome.bound, ub)) if lp is not None else outcome.bound
    return chosen, bound, detail
