"""The set cover's batched scan-line verification: the start-pose screen rejects exactly what the full check
would, deferred time parameterisation gives the same trajectory as the eager one, and the substitutes of a
picked view are the unverified views sharing most of its points."""

import copy

import numpy as np
import pytest
import scipy.sparse

from agiprobot_measurement.planning.candidates.mechanics import scan_line_starts_free
from agiprobot_measurement.planning.selection.open_points import substitute_views
from agiprobot_measurement.planning.selection.verify import finish_scan_trajectories, verify_mechanics
from agiprobot_measurement.planning.trajectory_manager import TrajectoryManager
from agiprobot_measurement.station import PACKAGE_ROOT

CUBE = PACKAGE_ROOT / "parts" / "objectA_wuerfel.stl"


@pytest.fixture(scope="module")
def cube_views():
    manager = TrajectoryManager(seed=3)
    manager.load_target_mesh(str(CUBE))
    # tilted views of the cube's sides start low enough for some of them to collide with the fixture or table
    _, views = manager.generate_samples_and_viewpoints(0.004, 0.1, 4, "full")
    return manager, views


def test_start_screen_rejects_exactly_what_the_full_check_rejects(cube_views):
    manager, views = cube_views
    rng = np.random.default_rng(0)
    sample = [views[i] for i in rng.choice(len(views), size=min(160, len(views)), replace=False)]
    free = scan_line_starts_free(sample, manager.ik, manager.collision, manager.preferred_state, chunk=37)
    copies = [copy.deepcopy(v) for v in sample]
    valid = np.array([verify_mechanics(manager.run, manager.tools(), v) for v in copies])
    # a view without a free start at either end never passes the full check ...
    assert not (valid & ~free).any()
    # ... and the screen is not vacuous here: it does reject some views, and keeps the valid ones
    assert (~free).sum() >= 3 and valid.sum() >= 10


def test_deferred_trajectory_equals_the_eager_one(cube_views):
    manager, views = cube_views
    checked = 0
    for view in views[:: max(1, len(views) // 60)]:
        eager, deferred = copy.deepcopy(view), copy.deepcopy(view)
        ok_eager = verify_mechanics(manager.run, manager.tools(), eager)
        ok_deferred = verify_mechanics(manager.run, manager.tools(), deferred, time_parameterize=False)
        assert ok_eager == ok_deferred
        if not ok_eager:
            continue
        assert deferred.get_trajectory_for_measurement() is None
        finish_scan_trajectories(manager.run, manager.tools(), [deferred])
        a, b = eager.get_trajectory_for_measurement(), deferred.get_trajectory_for_measurement()
        assert b is not None and b.duration == pytest.approx(a.duration, rel=1e-12)
        np.testing.assert_allclose(b.start, a.start)
        np.testing.assert_allclose(b.end, a.end)
        assert deferred.scan_line == pytest.approx(eager.scan_line)
        assert deferred.estimated_duration_s == pytest.approx(eager.estimated_duration_s)
        assert np.array_equal(deferred.measurable_indices, eager.measurable_indices)
        checked += 1
    assert checked >= 5


def test_plan_chosen_views_have_trajectories_the_others_none_computed():
    manager = TrajectoryManager(seed=1)
    manager.load_target_mesh(str(CUBE))
    ordered = manager.plan(0.01, 0.1, 6, "none", "IP_basic", time_limit_s=120.0)
    assert ordered and all(v.get_trajectory_for_measurement() is not None for v in ordered)
    for view in ordered:
        assert view.estimated_duration_s == pytest.approx(view.get_trajectory_for_measurement().duration)
    chosen = {id(v) for v in ordered}
    skipped = [v for v in manager.last_viewpoints if v.mechanics_verified and v.mechanics_valid and id(v) not in chosen]
    # verified views the cover did not keep were not time-parameterised
    assert skipped and all(v.get_trajectory_for_measurement() is None for v in skipped)


class _View:
    def __init__(self, verified):
        self.mechanics_verified = verified


def test_substitutes_are_the_unverified_views_sharing_most_points():
    # points x views: view 0 is the picked one (points 0..5); view 1 shares 5 points, view 2 shares 3,
    # view 3 shares 5 but is verified, view 4 shares none
    dense = np.zeros((8, 5))
    dense[0:6, 0] = 1
    dense[0:5, 1] = 1
    dense[3:6, 2] = 1
    dense[0:5, 3] = 1
    dense[6:8, 4] = 1
    views = [_View(False), _View(False), _View(False), _View(True), _View(False)]
    matrix = scipy.sparse.csc_matrix(dense)
    assert substitute_views(matrix, views, np.array([0]), 5).tolist() == [1, 2]
    assert substitute_views(matrix, views, np.array([0]), 1).tolist() == [1]
    assert substitute_views(matrix, views, np.array([], dtype=np.int64), 3).size == 0


class _FixedIK:
    def __init__(self, solutions, valid):
        self.solutions, self.valid = solutions, valid

    def solve_all(self, poses, seeds):
        return self.solutions.copy(), self.valid.copy()


def test_compiled_branch_walk_follows_the_same_branches(monkeypatch):
    from agiprobot_measurement.motion import cartesian

    rng = np.random.default_rng(4)
    for _ in range(200):
        n = int(rng.integers(1, 60))
        solutions = rng.uniform(-6.0, 6.0, (n, 8, 6))
        valid = rng.random((n, 8)) > rng.uniform(0.05, 0.97)
        start = rng.uniform(-3.0, 3.0, 6)
        ik = _FixedIK(solutions, valid)
        monkeypatch.setattr(cartesian, "COMPILED_AFTER_PATHS", 10**9)
        plain = cartesian._follow_all_solutions(ik, start, np.zeros((n, 4, 4)))
        monkeypatch.setattr(cartesian, "COMPILED_AFTER_PATHS", -1)
        compiled = cartesian._follow_all_solutions(ik, start, np.zeros((n, 4, 4)))
        assert compiled[1] == plain[1]
        np.testing.assert_array_equal(compiled[0], plain[0])


def _reference_substitutes(dense, verified, columns, per_view):
    """One picked view at a time: its unverified others by (most shared points, lower column), ``per_view`` each;
    then all of them by (overlap, column), each column once."""
    mask = dense != 0
    entries = []
    for p in columns:
        shared = (mask & mask[:, [p]]).sum(axis=0)
        others = [(int(shared[c]), c) for c in range(mask.shape[1]) if c != p and not verified[c] and shared[c] > 0]
        others.sort(key=lambda t: (-t[0], t[1]))
        entries += others[:per_view]
    entries.sort(key=lambda t: (-t[0], t[1]))
    return list(dict.fromkeys(c for _, c in entries))


def test_substitutes_match_the_one_view_at_a_time_reference_on_random_matrices():
    rng = np.random.default_rng(5)
    for _ in range(30):
        n_points, n_views = int(rng.integers(5, 40)), int(rng.integers(2, 30))
        dense = (rng.random((n_points, n_views)) < rng.uniform(0.1, 0.6)) * rng.uniform(0.5, 2.0, (n_points, n_views))
        dense[rng.random((n_points, n_views)) < 0.05] = 0.0
        verified = rng.random(n_views) < 0.3
        views = [_View(bool(v)) for v in verified]
        columns = rng.choice(n_views, size=int(rng.integers(1, min(n_views, 6) + 1)), replace=False)
        per_view = int(rng.integers(1, 6))
        matrix = scipy.sparse.csc_matrix(dense)
        got = substitute_views(matrix, views, columns, per_view).tolist()
        assert got == _reference_substitutes(dense, verified, columns.tolist(), per_view)
