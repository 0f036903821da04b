"""The tour planner's pieces: the exact open tour over views x IK branches against brute force, the 2-opt fallback
never worse than a fixed order, the greedy partial cover, and the sticky plan keeping / dropping views."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from agiprobot_measurement.nbv.volumetric import tour
from agiprobot_measurement.nbv.volumetric.tour import TourPlan, brute_force_tour, greedy_cover, order_tour, tour_cost


def l1(q, qs):
    return np.abs(np.atleast_2d(qs) - q).sum(axis=1)


def slowest_joint(q, qs):  # asymmetric-free but non-Euclidean, like the motion-time estimate
    return np.abs(np.atleast_2d(qs) - q).max(axis=1)


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("cost", [l1, slowest_joint])
def test_exact_tour_matches_brute_force(seed, cost):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 6))
    branches = [rng.uniform(-3, 3, (int(rng.integers(1, 4)), 6)) for _ in range(n)]
    q0 = rng.uniform(-3, 3, 6)
    best, order, choice = order_tour(q0, branches, cost)
    ref, _, _ = brute_force_tour(q0, branches, cost)
    assert best == pytest.approx(ref)
    assert sorted(order) == list(range(n))
    assert tour_cost(q0, branches, order, choice, cost) == pytest.approx(best)


def test_tour_does_not_zig_zag():
    # views on a line at 1, -1, 2, -2 (one joint): from 0 the open tour goes one way, then the other
    branches = [np.array([[x, 0, 0, 0, 0, 0]]) for x in (1.0, -1.0, 2.0, -2.0)]
    best, order, _ = order_tour(np.zeros(6), branches, l1)
    assert best == pytest.approx(6.0)  # e.g. 0 -> 1 -> 2 -> -1 -> -2: the side is changed once
    xs = [(1.0, -1.0, 2.0, -2.0)[v] for v in order]
    assert sum(np.sign(a) != np.sign(b) for a, b in itertools.pairwise(xs)) == 1


def test_branch_choice_matters():
    # the second branch of view 0 is next to view 1: the tour takes it
    branches = [np.array([[5.0, 0, 0, 0, 0, 0], [1.0, 0, 0, 0, 0, 0]]), np.array([[1.5, 0, 0, 0, 0, 0]])]
    best, order, choice = order_tour(np.zeros(6), branches, l1)
    assert best == pytest.approx(1.5) and order == [0, 1] and choice == [1, 0]


def test_large_plans_fall_back_to_two_opt(monkeypatch):
    rng = np.random.default_rng(3)
    branches = [rng.uniform(-3, 3, (2, 6)) for _ in range(7)]
    q0 = np.zeros(6)
    exact, _, _ = order_tour(q0, branches, l1)
    monkeypatch.setattr(tour, "EXACT_MAX_VIEWS", 3)
    heuristic, order, choice = order_tour(q0, branches, l1)
    assert sorted(order) == list(range(7))
    assert heuristic >= exact - 1e-9
    assert heuristic <= 1.25 * exact  # 2-opt + Viterbi stays near the optimum on small random instances
    assert tour_cost(q0, branches, order, choice, l1) == pytest.approx(heuristic)


def test_greedy_cover_partial_and_sticky():
    sets = np.zeros((4, 10), dtype=bool)
    sets[0, :6] = True  # big
    sets[1, 5:9] = True  # the rest but one
    sets[2, :3] = True  # inside view 0
    sets[3, 9] = True  # the last element
    weights = np.array([6.0, 4.0, 3.0, 1.0])
    assert greedy_cover(sets, weights, cover_share=0.9) == [0, 1]
    assert greedy_cover(sets, weights, cover_share=1.0) == [0, 1, 3]
    assert greedy_cover(sets, weights, cover_share=1.0, max_views=2) == [0, 1]
    # a sticky view comes first even if the greedy would not pick it
    assert greedy_cover(sets, weights, cover_share=0.9, first=[2])[:1] == [2]


def _pose(x, axis=(0.0, 0.0, -1.0)):
    p = np.eye(4)
    p[:3, 3] = (x, 0.0, 0.5)
    p[:3, 2] = axis
    return p


def test_replanning_keeps_views_that_still_promise_their_gain_and_drops_the_others():
    plan = TourPlan(np.stack([_pose(0.0), _pose(0.1), _pose(0.2)]), np.array([10.0, 10.0, 10.0]))
    # the new pool: view 0 kept its promise, view 1 lost most of it (seen by the view just taken), view 2 is gone
    # from the pool (no longer feasible), a new view appeared
    pool = np.stack([_pose(0.5), _pose(0.1005), _pose(0.0)])
    gains = np.array([20.0, 2.0, 8.0])
    kept = plan.kept(pool, gains, keep_share=0.5)
    assert kept == [2]
    # with a lower bar view 1 stays too
    assert sorted(plan.kept(pool, gains, keep_share=0.1)) == [1, 2]
    # a view looking elsewhere from the same place is another view
    turned = np.stack([_pose(0.0, axis=(1.0, 0.0, 0.0))])
    assert plan.kept(turned, np.array([50.0]), keep_share=0.5) == []


@pytest.mark.parametrize("greedy_share, first", [(0.5, 0), (1.0, 1)])
def test_the_tour_takes_a_concentrated_gain_first(monkeypatch, greedy_share, first):
    from types import SimpleNamespace

    from agiprobot_measurement.nbv.volumetric.policies import touring
    from agiprobot_measurement.nbv.volumetric.policies.ours import PoolScores
    from agiprobot_measurement.nbv.volumetric.settings import TourSettings

    # view 0 is ours' best and promises most of the plan's gain, far from the current joints; views 1 and 2 are
    # small and on the way: the shortest tour visits them first, a concentrated gain goes first
    joints = np.array([np.full(6, 1.0), np.full(6, 0.1), np.full(6, 0.2)])
    poses = np.stack([_pose(0.0), _pose(0.1), _pose(0.2)])
    sets = np.eye(3, dtype=bool)  # disjoint: every view is in the plan
    monkeypatch.setattr(touring, "coverage_sets", lambda *args: sets)
    policy = touring.TourPolicy.__new__(touring.TourPolicy)
    policy.tour = TourSettings(max_branches=1, min_marginal_share=0.0, greedy_share=greedy_share)
    policy.plan = TourPlan()
    policy.scores = PoolScores(
        np.zeros(0), np.zeros(0)
    )  # no undersampled term: the weights are the predicted surface's
    policy.context = SimpleNamespace(view_model=None, motion_cost=l1)
    policy._elements = lambda: (np.zeros((3, 3)), np.zeros((3, 3)))
    policy._branches = lambda q, cands, picked: [cands.joints[i][None] for i in picked]
    cands = SimpleNamespace(poses=poses, joints=joints, targets_m=np.zeros((3, 3)),
                            source=np.array(["sphere"] * 3, dtype=object))  # fmt: skip
    area = np.array([10.0, 2.0, 2.0])
    choice, _, stats = policy._tour_choice(np.zeros(6), cands, {}, np.arange(3), area, area, np.array([3.0, 1.0, 1.0]))
    assert choice.index == first and stats["tour_views"] == 3
    assert len(policy.plan.planned_gains) == 3  # the rest of the plan is kept for the next view either way


def test_among_near_best_views_the_quickest_move_is_taken():
    from agiprobot_measurement.nbv.volumetric.policies.ours import PoolScores

    utilities = np.array([1.0, 0.97, 0.5, 0.92])
    scores = PoolScores(np.zeros(4), np.array([9.0, 4.0, 0.1, 2.0]))
    assert scores.near_best(utilities, 0.0) is None  # off: the best by utility
    assert scores.near_best(utilities, 0.05) == 1  # within 5 %: views 0 and 1, the quicker one
    assert scores.near_best(utilities, 0.1) == 3
    assert scores.near_best(utilities, 0.6) == 2
    assert PoolScores(np.zeros(0), np.zeros(0)).near_best(utilities, 0.1) is None  # costs of another pool
