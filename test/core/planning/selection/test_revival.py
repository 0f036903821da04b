"""Dominated candidates dropped at the evaluation come back when the mechanics fail their dominator: the reserve
names each one's dominator, a failed dominator revives exactly its dominated candidates (once, and only when no other
view measures one of its points), and a plan whose dominators cannot be driven covers what the plan without
dropping covers."""

import dataclasses

import numpy as np
import pytest

import agiprobot_measurement.planning.trajectory_manager as tm
from agiprobot_measurement.planning.candidates.streaming import chunk_block
from agiprobot_measurement.planning.report.report import point_uncertainties
from agiprobot_measurement.planning.selection import loop, revival, verify
from agiprobot_measurement.planning.selection.problem import coverage_problem
from agiprobot_measurement.station import PACKAGE_ROOT

CUBE = PACKAGE_ROOT / "parts" / "objectA_wuerfel.stl"
#: the cube at tilt full, coarse: a few hundred samples, ~40,000 candidates
DENSITY, THRESHOLD_MM, ORIENTATIONS = 0.004, 0.1, 4


def _manager(drop: bool) -> tm.TrajectoryManager:
    manager = tm.TrajectoryManager(seed=1)
    manager.evaluation = dataclasses.replace(manager.evaluation, drop_dominated=drop)
    manager.load_target_mesh(str(CUBE))
    return manager


@pytest.fixture(scope="module")
def dropped_generation():
    manager = _manager(True)
    manager.generate_samples_and_viewpoints(DENSITY, THRESHOLD_MM, ORIENTATIONS, "full")
    return manager


def _points(view) -> set:
    return set(np.asarray(view.measurable_indices).tolist())


def test_the_reserve_names_a_dominator_measuring_all_points_of_each_dropped_candidate(dropped_generation):
    manager = dropped_generation
    stats = manager.last_stream_stats
    assert stats.drop_dominated and stats.dropped_views > 0
    reserve = manager.run.reserve.candidates
    assert reserve.size == stats.dropped_views  # every drop here is a dominance drop with its dominator
    views = manager.run.generation_views
    sample = np.linspace(0, reserve.size - 1, min(reserve.size, 200)).astype(int)
    block, columns, _ = chunk_block(
        manager.sensor_model, manager.candidates.poses[reserve[sample]], THRESHOLD_MM, 500.0
    )
    assert columns.size == sample.size  # a dropped candidate measured something
    for j, k in enumerate(sample.tolist()):
        points = set(block.point_indices[block.indptr[j] : block.indptr[j + 1]].tolist())
        dominator = views[manager.run.reserve.dominator_column[k]]
        assert points <= _points(dominator)


def test_a_failed_dominator_revives_its_dominated_candidates_once_when_its_points_are_left_open(dropped_generation):
    manager = dropped_generation
    views = manager.run.generation_views
    store = manager.measurability
    dominators, counts = np.unique(manager.run.reserve.dominator_column, return_counts=True)
    column = int(dominators[np.argmax(counts)])
    view = views[column]
    a, b = store.indptr[column], store.indptr[column + 1]
    its_points = store.point_indices[a:b]
    assert revival.revive_dominated(manager.run, manager.tools()) == []  # nothing verified yet: nothing to revive
    view.mechanics_verified, view.mechanics_valid = True, False
    manager.run.entry_alive[a:b] = False
    # every point of the failed view is still measured by other views (the cube's are seen from many): the
    # dominated candidates are not needed yet
    others = np.isin(store.point_indices, its_points) & manager.run.entry_alive
    assert np.all(np.isin(its_points, store.point_indices[others]))
    assert revival.revive_dominated(manager.run, manager.tools()) == []
    # the other views of those points fail too (not verified yet, their entries gone): now the points are open
    manager.run.entry_alive[others] = False
    before = len(manager.last_viewpoints)
    revived = revival.revive_dominated(manager.run, manager.tools())
    manager.run.entry_alive[others] = True  # back as they were: the rest of the test reads the store's columns
    expected = manager.run.reserve.candidates[manager.run.reserve.dominator_column == column]
    assert sorted(v.metadata["candidate"] for v in revived) == sorted(expected.tolist())
    assert len(manager.last_viewpoints) == before + len(revived)
    for candidate_view in revived:
        np.testing.assert_allclose(
            candidate_view.get_anchor_pose(), manager.candidates.poses[candidate_view.metadata["candidate"]], atol=1e-6
        )
        assert candidate_view.coverage_column is None and candidate_view.mechanics_verified is False
        assert 0 < len(_points(candidate_view)) and _points(candidate_view) <= set(
            manager.measurability.point_indices[a:b].tolist()
        )
        lo, hi = candidate_view.scan_line
        assert lo < hi and candidate_view.estimated_duration_s > 0
    assert revival.revive_dominated(manager.run, manager.tools()) == []  # the same failure revives nothing twice
    # the per-point count of views that may still be executable: live store entries plus revived valid views
    revived[0].mechanics_valid = False
    expected_counts = np.bincount(store.point_indices[manager.run.entry_alive], minlength=store.n_points)
    for v in revived[1:]:
        expected_counts[np.asarray(v.measurable_indices, dtype=np.int64)] += 1
    np.testing.assert_array_equal(revival._measured_counts(manager.run), expected_counts)
    revived[0].mechanics_valid = True
    # the coverage problem takes the store's columns and the revived views together, in the views' order
    mixed = views[:50] + revived + views[50:100]
    matrix, worst, _ = coverage_problem(manager.run, mixed, len(manager.samples))
    assert matrix.shape == (manager.measurability.n_points, len(mixed))
    for k, v in enumerate(mixed):
        rows = set(matrix.indices[matrix.indptr[k] : matrix.indptr[k + 1]].tolist())
        assert rows == (set() if v is view else _points(v))
        if rows:
            assert worst[k] == pytest.approx(float(np.max(v.measurable_uncertainties)))


def test_a_plan_whose_dominators_fail_covers_what_the_plan_without_dropping_covers(monkeypatch):
    """The mechanics reject every view that dominates a dropped candidate (and pass the others as the real
    check does): with revival the points only those views measured are still covered by the dominated ones."""
    probe = _manager(True)
    probe.generate_samples_and_viewpoints(DENSITY, THRESHOLD_MM, ORIENTATIONS, "full")
    failing = {
        probe.run.generation_views[c].metadata["candidate"] for c in np.unique(probe.run.reserve.dominator_column)
    }
    real_check = verify.check_scan_line

    def check(view, *args, **kwargs):
        if view.metadata.get("candidate") in failing:
            view.mechanics_verified, view.mechanics_valid = True, False  # as the real check marks a rejection
            return None
        return real_check(view, *args, **kwargs)

    real_batch = verify.check_scan_lines

    def check_batch(views, *args, **kwargs):
        views = list(views)
        passing = [v for v in views if v.metadata.get("candidate") not in failing]
        paths = dict(zip(map(id, passing), real_batch(passing, *args, **kwargs), strict=True))
        return [paths[id(v)] if id(v) in paths else check(v) for v in views]

    monkeypatch.setattr(verify, "check_scan_line", check)
    monkeypatch.setattr(verify, "check_scan_lines", check_batch)
    covered = {}
    for name, drop, revive in (("plain", False, True), ("dropped", True, True), ("no revival", True, False)):
        manager = _manager(drop)
        if not revive:
            monkeypatch.setattr(loop, "revive_in", lambda *args: np.zeros(0, dtype=np.int64))
        try:
            ordered = manager.plan(DENSITY, THRESHOLD_MM, ORIENTATIONS, "full", "IP_basic", time_limit_s=240.0)
        except tm.PlanningError:
            assert not revive  # without revival every kept view may fail here
            covered[name] = np.zeros(len(manager.samples), dtype=bool)
            continue
        assert not manager.time_limit_hit
        covered[name] = np.isfinite(point_uncertainties(ordered, len(manager.samples)))
        if name == "dropped":
            assert manager.revived_views > 0
            assert not any(v.metadata["candidate"] in failing for v in ordered)
    assert covered["dropped"].sum() == covered["plain"].sum()
    # without revival the points only the failed dominators measured are lost: the test sees the difference
    assert covered["no revival"].sum() < covered["plain"].sum()
