"""Greedy set covers: the unweighted greedy with a lazy bucket queue (ties to the lowest worst uncertainty),
Chvatal's weighted greedy, and making a selection irredundant.
"""

from __future__ import annotations

import heapq

import numpy as np

from agiprobot_measurement.planning.cover.columns import ColumnSets

__all__ = [
    "fresh_gains",
    "greedy_cover",
    "greedy_weighted_cover",
    "make_irredundant",
]


def fresh_gains(cols: ColumnSets, which: np.ndarray, covered: np.ndarray) -> np.ndarray:
    """Number of rows not yet ``covered`` in each column of ``which`` (all non-empty), in one pass."""
    part = cols.take(which)
    hits = np.add.reduceat(covered[part.indices], part.indptr[:-1], dtype=np.int64)
    return part.sizes() - hits


def greedy_cover(cols: ColumnSets, tie: np.ndarray, n_uncovered: int) -> list[int]:
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
            fresh = fresh_gains(cols, old, covered)
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


def greedy_weighted_cover(cols: ColumnSets, tie: np.ndarray, costs: np.ndarray) -> list[int]:
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


def make_irredundant(cols: ColumnSets, picks: list[int], costs: np.ndarray | None) -> list[int]:
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
