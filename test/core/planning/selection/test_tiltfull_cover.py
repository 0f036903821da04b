"""Tilt full's set cover at scale: the open points' views found chunk-wise equal the plain per-row definition,
the set cover's matrix holds only the live entries (booleans) with the per-view worst uncertainty, the
reductions and the programme stop at their deadline, and tilt auto's restricted cover of tilt none's points
is an executable cover of those points."""

import time

import numpy as np
import pytest
import scipy.sparse

import agiprobot_measurement.planning.trajectory_manager as tm
from agiprobot_measurement.planning import pipeline
from agiprobot_measurement.planning.cover.columns import measurable_columns
from agiprobot_measurement.planning.cover.greedy import greedy_weighted_cover
from agiprobot_measurement.planning.cover.ip import solve_highs, solve_reduced_ip
from agiprobot_measurement.planning.cover.reduction import implied_rows
from agiprobot_measurement.planning.report.report import point_uncertainties
from agiprobot_measurement.planning.selection import open_points
from agiprobot_measurement.planning.selection.problem import coverage_problem
from agiprobot_measurement.station import PACKAGE_ROOT

CUBE = PACKAGE_ROOT / "parts" / "objectA_wuerfel.stl"


class _View:
    def __init__(self, state):
        self.mechanics_verified = state


def _reference_open_point_views(dense: np.ndarray, states, per_point: int) -> list[int]:
    """The definition, row by row: the rows no verified column measures, their ``per_point`` largest
    unverified columns (lower index first on equal size), most shared first, then largest, then lowest."""
    measurable = dense != 0
    sizes = measurable.sum(axis=0)
    verified = np.array([s is True for s in states])
    unverified = np.array([s is False for s in states])
    counts: dict[int, int] = {}
    for i in range(dense.shape[0]):
        if not measurable[i].any() or (measurable[i] & verified).any():
            continue
        cols = [j for j in np.flatnonzero(measurable[i] & unverified)]
        cols.sort(key=lambda j: (-sizes[j], j))
        for j in cols[:per_point]:
            counts[j] = counts.get(j, 0) + 1
    return sorted(counts, key=lambda j: (-counts[j], -sizes[j], j))


@pytest.mark.parametrize("chunk_entries", [1, 7, 2_000_000])
def test_open_point_views_equals_the_per_row_definition(monkeypatch, chunk_entries):
    monkeypatch.setattr(open_points, "OPEN_POINT_CHUNK_ENTRIES", chunk_entries)
    rng = np.random.default_rng(5)
    non_trivial = 0
    for _ in range(60):
        m, n = int(rng.integers(1, 40)), int(rng.integers(1, 120))
        dense = (rng.random((m, n)) < rng.random() * 0.4) * rng.random((m, n))
        matrix = scipy.sparse.csc_matrix(dense)
        matrix.data[rng.random(matrix.data.size) < 0.2] = 0.0  # explicit zeros are not measurable
        dense = matrix.toarray()
        states = [(False, True, None)[k] for k in rng.integers(0, 3, n)]
        per_point = int(rng.integers(1, 6))
        got = open_points.open_point_views(matrix, [_View(s) for s in states], per_point)
        expected = _reference_open_point_views(dense, states, per_point)
        assert got.tolist() == expected
        non_trivial += len(expected) > 3
    assert non_trivial >= 10


def test_implied_rows_finds_the_implied_ones_and_stops_at_its_deadline():
    rng = np.random.default_rng(2)
    dense = rng.random((60, 40)) < 0.3
    dense[:, 0] = True  # every row holds view 0 ...
    dense[5] = False
    dense[5, 0] = True  # ... so every other non-identical row includes row 5's only view: all implied by it
    cols, _ = measurable_columns(scipy.sparse.csc_matrix(dense.T))  # columns = rows of the cover problem
    implied, complete = implied_rows(cols, np.arange(cols.n_cols), time.perf_counter() + 60.0)
    expected = np.array([dense[i].sum() > 1 and i != 5 for i in range(60)])
    assert complete and np.array_equal(implied, expected)
    implied, complete = implied_rows(cols, np.arange(cols.n_cols), time.perf_counter() - 1.0)
    assert not complete and not implied.any()


def test_reduced_programme_with_no_time_left_returns_the_heuristic_cover():
    rng = np.random.default_rng(4)
    dense = rng.random((80, 300)) < 0.05
    dense[np.arange(80), rng.integers(0, 300, 80)] = True
    cols, _ = measurable_columns(scipy.sparse.csc_matrix(dense))
    costs = np.ones(cols.n_cols)
    tie = np.zeros(cols.n_cols)
    stats: dict = {}
    started = time.perf_counter()
    chosen, _, detail = solve_reduced_ip(
        cols, costs, tie, True, solve_highs, time.perf_counter() - 1.0, 0.0, True, False, stats
    )
    assert time.perf_counter() - started < 2.0
    assert "no time left" in detail and stats["mip_shape"] == (0, 0)
    covered = np.zeros(80, dtype=bool)
    for j in chosen.tolist():
        covered[cols.col(j)] = True
    assert covered.all()
    assert len(chosen) <= len(greedy_weighted_cover(cols, tie, costs))


@pytest.fixture(scope="module")
def cube_plan():
    manager = tm.TrajectoryManager(seed=1)
    manager.load_target_mesh(str(CUBE))
    ordered = manager.plan(0.004, 0.1, 4, "full", "IP_basic", time_limit_s=120.0)
    return manager, ordered


def test_coverage_problem_holds_the_live_entries_and_the_worst_uncertainty(cube_plan):
    manager, _ = cube_plan
    views = manager.last_viewpoints
    store = manager.measurability
    matrix, worst, _ = coverage_problem(manager.run, views, len(manager.samples))
    assert matrix.dtype == bool and matrix.shape == (store.n_points, len(views))
    columns = np.array([v.coverage_column for v in views])
    rejected = shortened = 0
    for k in range(0, len(views), max(1, len(views) // 300)):
        a, b = store.indptr[columns[k]], store.indptr[columns[k] + 1]
        live = manager.run.entry_alive[a:b]
        rows = matrix.indices[matrix.indptr[k] : matrix.indptr[k + 1]]
        assert np.array_equal(np.sort(rows), np.sort(store.point_indices[a:b][live]))
        top = store.uncertainties[a:b][live].max() if live.any() else 0.0
        assert worst[k] == pytest.approx(top)
        rejected += not live.any() and b > a
        shortened += live.any() and not live.all()
    assert rejected > 0  # the plan rejected some views: the test sees empty columns
    verified_only, _, _ = coverage_problem(manager.run, views, len(manager.samples), only_verified=True)
    sizes = np.diff(verified_only.indptr)
    unverified = np.array([v.mechanics_verified is False for v in views])
    assert unverified.any() and not sizes[unverified].any()
    assert np.array_equal(sizes[~unverified], np.diff(matrix.indptr)[~unverified])


def test_restricted_cover_is_an_executable_cover_of_the_given_points(cube_plan):
    manager, ordered = cube_plan
    n = len(manager.samples)
    points = np.isfinite(point_uncertainties(ordered, n))
    points[np.flatnonzero(points)[::2]] = False  # half of them: a smaller cover must do
    report = pipeline.cover_with_verified(
        manager, points, {"solver_type": "IP_basic", "set_cover_time_limit_s": 20.0, "mip_gap": 0.0, "min_planning_time": 0.2},
        time.perf_counter() + 60.0,
    )  # fmt: skip
    assert report is not None
    chosen = manager.last_ordered
    assert report.n_views == len(chosen) <= len(ordered)
    assert all(v.mechanics_verified and v.mechanics_valid for v in chosen)
    assert all(v.get_trajectory_for_measurement() is not None for v in chosen)
    covered = np.isfinite(point_uncertainties(chosen, n))
    assert covered[points].all()


def test_taking_most_columns_by_mask_equals_taking_them_by_position():
    rng = np.random.default_rng(8)
    dense = rng.random((50, 400)) < 0.2
    dense[:, rng.random(400) < 0.1] = False  # empty columns too
    cols, _ = measurable_columns(scipy.sparse.csc_matrix(dense))
    for which in (np.flatnonzero(rng.random(400) < 0.9), np.flatnonzero(rng.random(400) < 0.1), np.arange(400)):
        part = cols.take(which)  # the first and the last take the mask path, the second the positions
        assert part.n_cols == which.size
        for k, j in enumerate(which.tolist()):
            assert np.array_equal(part.col(k), np.flatnonzero(dense[:, j]))
