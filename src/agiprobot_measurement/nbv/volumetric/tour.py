"""The tour planner's pieces, ROS-free and independent of the loop: a weighted greedy partial set cover, an open
joint-space tour over views x IK branches (generalised TSP, exact for small plans), and the sticky plan kept
between re-plans.

- :func:`greedy_cover`: views picked by marginal weight (a view's weight x the share of its set not yet covered)
  until ``cover_share`` of the union's weight is covered or ``max_views`` are picked;
- :func:`order_tour`: the open tour from the current joints through one branch of every view, minimising the sum
  of the edge costs (``cost(q_a, Q_b)`` -> (len(Q_b),) for the joint states), by Held-Karp dynamic programming over
  (subset, last view, its branch): exact, ``O(2^n n^2 b^2)``, used up to :data:`EXACT_MAX_VIEWS` views; beyond, the
  nearest-neighbour tour improved by 2-opt with the branches re-chosen by a Viterbi pass along the order;
- :class:`TourPlan`: the last plan's views with the gain each was planned for; :meth:`TourPlan.kept` returns the
  ones that still promise at least ``keep_share`` of it (the others are dropped, the cover is topped up).

No licence-restricted solver (LKH) is used: the plans are small (<= 12 views), where the exact DP takes
milliseconds.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from agiprobot_measurement.errors import InputError

__all__ = ["EXACT_MAX_VIEWS", "TourPlan", "brute_force_tour", "greedy_cover", "order_tour", "tour_cost"]

#: plans up to this many views are ordered exactly (Held-Karp); larger ones by 2-opt + Viterbi
EXACT_MAX_VIEWS = 8

CostFn = Callable[[np.ndarray, np.ndarray], np.ndarray]


def greedy_cover(sets: np.ndarray, weights: np.ndarray, cover_share: float = 0.9, max_views: int = 8,
                 first: list[int] | None = None, min_marginal_share: float = 0.0) -> list[int]:  # fmt: skip
    """Indices of the views picked: ``sets`` (V, M) bool (view v sees element m), ``weights`` (V,) >= 0 the views'
    own predicted gains; a view's marginal value is its weight x the share of its elements not yet covered. The
    views of ``first`` are taken first (the sticky plan), then the best marginal ones until the picked views cover
    ``cover_share`` of the union or ``max_views`` are picked or nothing is left to gain, or the best marginal value
    falls below ``min_marginal_share`` of the first greedy pick's (a plan of the views worth visiting, not of every
    sliver)."""
    sets = np.asarray(sets, dtype=bool)
    weights = np.asarray(weights, dtype=float)
    if sets.ndim != 2 or len(weights) != len(sets):
        raise InputError(f"greedy_cover: sets (V, M) and weights (V,) expected, got {sets.shape}, {weights.shape}")
    if not 0.0 < cover_share <= 1.0:
        raise InputError(f"cover_share must be in (0, 1], got {cover_share}")
    union = sets.any(axis=0)
    total = int(union.sum())
    size = np.maximum(sets.sum(axis=1), 1)
    covered = np.zeros(sets.shape[1], dtype=bool)
    picked: list[int] = []
    for v in first or []:
        if len(picked) < max_views and v not in picked:
            picked.append(int(v))
            covered |= sets[v]
    top = None
    while len(picked) < max_views and (total == 0 or covered.sum() < cover_share * total):
        fresh = (sets & ~covered).sum(axis=1)
        value = weights * fresh / size
        value[picked] = -1.0
        best = int(np.argmax(value))
        if value[best] <= 0 or (top is not None and value[best] < min_marginal_share * top):
            break
        top = value[best] if top is None else top
        picked.append(best)
        covered |= sets[best]
    return picked


def tour_cost(q0: np.ndarray, branches: list[np.ndarray], order, choice, cost: CostFn) -> float:
    """The cost of visiting the views in ``order`` with the branches ``choice`` (one per visited view) from
    ``q0``."""
    total, q = 0.0, np.asarray(q0, dtype=float)
    for v, b in zip(order, choice, strict=True):
        nxt = branches[v][b]
        total += float(cost(q, nxt[None])[0])
        q = nxt
    return total


def brute_force_tour(q0, branches: list[np.ndarray], cost: CostFn) -> tuple[float, list[int], list[int]]:
    """The optimal open tour by enumeration (for tests): (cost, order, branch choice)."""
    best = (np.inf, [], [])
    for order in itertools.permutations(range(len(branches))):
        for choice in itertools.product(*(range(len(branches[v])) for v in order)):
            c = tour_cost(q0, branches, order, choice, cost)
            if c < best[0] - 1e-12:
                best = (c, list(order), list(choice))
    return best


def _pairwise(branches: list[np.ndarray], cost: CostFn):
    """Costs between every branch of every view: {(a, b): (len(Q_a), len(Q_b))}."""
    out = {}
    for a, qa in enumerate(branches):
        for b, qb in enumerate(branches):
            if a != b:
                out[a, b] = np.stack([cost(q, qb) for q in qa])
    return out


def order_tour(q0, branches: list[np.ndarray], cost: CostFn) -> tuple[float, list[int], list[int]]:
    """(cost, order, branch choice) of the open tour from ``q0`` through one branch of every view (``branches``:
    per view an (k_v, 6) array of its joint states, k_v >= 1); see the module docstring."""
    n = len(branches)
    if n == 0:
        return 0.0, [], []
    branches = [np.atleast_2d(np.asarray(b, dtype=float)) for b in branches]
    if any(len(b) == 0 for b in branches):
        raise InputError("order_tour: every view needs at least one joint state")
    start = [np.asarray(cost(np.asarray(q0, dtype=float), b), dtype=float) for b in branches]
    pair = _pairwise(branches, cost)
    if n <= EXACT_MAX_VIEWS:
        return _held_karp(branches, start, pair)
    return _two_opt(branches, start, pair)


def _held_karp(branches, start, pair):
    n = len(branches)
    # dp[mask][v] = (len(Q_v),) the cheapest cost of visiting mask ending in v at each of its branches
    dp: dict[tuple[int, int], np.ndarray] = {}
    parent: dict[tuple[int, int], tuple[int, np.ndarray]] = {}
    for v in range(n):
        dp[1 << v, v] = start[v]
    for size in range(2, n + 1):
        for subset in itertools.combinations(range(n), size):
            mask = sum(1 << v for v in subset)
            for v in subset:
                prev_mask = mask & ~(1 << v)
                best, arg_u, arg_b = None, -1, None
                for u in subset:
                    if u == v:
                        continue
                    # (k_u, k_v): arrive at u's branch i, go to v's branch j
                    total = dp[prev_mask, u][:, None] + pair[u, v]
                    col = total.min(axis=0)
                    if best is None:
                        best, arg_u, arg_b = col, np.full(len(col), u), total.argmin(axis=0)
                    else:
                        better = col < best
                        best = np.where(better, col, best)
                        arg_u = np.where(better, u, arg_u)
                        arg_b = np.where(better, total.argmin(axis=0), arg_b)
                dp[mask, v] = best
                parent[mask, v] = (arg_u, arg_b)
    full = (1 << n) - 1
    last, branch = min(((v, int(np.argmin(dp[full, v]))) for v in range(n)), key=lambda vb: dp[full, vb[0]][vb[1]])
    cost = float(dp[full, last][branch])
    order, choice, mask = [last], [branch], full
    while mask != (1 << order[-1]):
        v, b = order[-1], choice[-1]
        arg_u, arg_b = parent[mask, v]
        mask &= ~(1 << v)
        order.append(int(arg_u[b]))
        choice.append(int(arg_b[b]))
    return cost, order[::-1], choice[::-1]


def _viterbi(order, start, pair):
    """The best branch per view along a fixed order: (cost, choice)."""
    acc = start[order[0]].copy()
    back = []
    for u, v in itertools.pairwise(order):
        total = acc[:, None] + pair[u, v]
        back.append(total.argmin(axis=0))
        acc = total.min(axis=0)
    b = int(np.argmin(acc))
    cost, choice = float(acc[b]), [b]
    for arg in reversed(back):
        choice.append(int(arg[choice[-1]]))
    return cost, choice[::-1]


def _two_opt(branches, start, pair):
    n = len(branches)
    # nearest neighbour on the cheapest branch costs, then 2-opt on the Viterbi cost
    order, left = [], set(range(n))
    cur = int(np.argmin([s.min() for s in start]))
    order.append(cur)
    left.discard(cur)
    while left:
        cur = min(left, key=lambda v, c=cur: pair[c, v].min())
        order.append(cur)
        left.discard(cur)
    best, choice = _viterbi(order, start, pair)
    improved = True
    while improved:
        improved = False
        for i in range(n - 1):
            for j in range(i + 1, n):
                trial = order[:i] + order[i : j + 1][::-1] + order[j + 1 :]
                c, ch = _viterbi(trial, start, pair)
                if c < best - 1e-9:
                    best, order, choice, improved = c, trial, ch, True
    return best, order, choice


@dataclass
class TourPlan:
    """The last plan: its views' sensor poses (K, 4, 4) and the gain each was planned for (K,)."""

    poses: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4)))
    planned_gains: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def match(self, poses: np.ndarray, distance_m: float = 0.01, angle_rad: float = 0.05) -> np.ndarray:
        """For each view of the plan, the index of the pose in ``poses`` (N, 4, 4) that is the same view (within
        ``distance_m`` and ``angle_rad`` of the optical axis), or -1."""
        out = np.full(len(self.poses), -1, dtype=int)
        if len(poses) == 0:
            return out
        for k, p in enumerate(self.poses):
            d = np.linalg.norm(poses[:, :3, 3] - p[:3, 3], axis=1)
            cos = np.einsum("ij,j->i", poses[:, :3, 2], p[:3, 2])
            ok = np.nonzero((d <= distance_m) & (cos >= np.cos(angle_rad)))[0]
            if len(ok):
                out[k] = int(ok[np.argmin(d[ok])])
        return out

    def kept(self, poses: np.ndarray, gains: np.ndarray, keep_share: float) -> list[int]:
        """Indices into ``poses`` of the plan's views that are still in the pool and still promise at least
        ``keep_share`` of the gain they were planned for (their current ``gains``)."""
        out = []
        for k, i in enumerate(self.match(poses)):
            if i >= 0 and gains[i] >= keep_share * self.planned_gains[k] and gains[i] > 0:
                out.append(int(i))
        return out
