"""The bounded, honest planning run: the three coverage numbers, the whole-plan time limit, reachability share,
tilt auto, the set cover's reductions against the unreduced programme, and the request's new fields."""

import time

import numpy as np
import pytest
import scipy.sparse

from agiprobot_measurement.common.limits import local_worker_limit
from agiprobot_measurement.planning.candidates.streaming import EvaluationSettings
from agiprobot_measurement.planning.cover.solve import solve_set_cover
from agiprobot_measurement.planning.errors import PlanningTimeLimit
from agiprobot_measurement.planning.report.coverage_figure import plot_coverage
from agiprobot_measurement.planning.request import WORKER_PROCESS_BYTES, PlanRequest, PlanRequestError
from agiprobot_measurement.planning.trajectory_manager import TrajectoryManager
from agiprobot_measurement.station import PACKAGE_ROOT

CUBE = PACKAGE_ROOT / "parts" / "objectA_wuerfel.stl"


@pytest.fixture(scope="module")
def cube_run():
    manager = TrajectoryManager()
    manager.load_target_mesh(str(CUBE))
    ordered = manager.plan(0.01, 0.1, 6, "none", "IP_basic", time_limit_s=120.0)
    return manager, ordered


def test_three_coverage_numbers_are_consistent_on_the_cube(cube_run, tmp_path):
    manager, _ = cube_run
    report = manager.coverage_report()
    metrology = manager.metrology_coverable_mask()
    executable = manager.coverable_mask()
    covered = np.isfinite(manager.point_uncertainties())
    # each set contains the next: covered <= executable <= metrology <= samples
    assert not (covered & ~executable).any() and not (executable & ~metrology).any()
    assert report.n_covered == covered.sum() <= report.n_coverable == executable.sum()
    assert report.n_coverable <= report.n_coverable_metrology == metrology.sum() <= report.n_samples
    # executable means a verified scan line measures it
    verified = np.zeros(report.n_samples, dtype=bool)
    for view in manager.last_viewpoints:
        if view.mechanics_verified and view.mechanics_valid:
            verified[view.measurable_indices] = True
    assert np.array_equal(executable, verified | covered)
    # the cube's top and sides are all reachable and drivable: the plan covers what executable views can
    assert report.n_covered >= 0.98 * report.n_coverable
    assert report.n_unverified == 0 and not report.time_limit_hit
    assert report.reachable_share == pytest.approx(1.0)
    meta = manager.plan_metadata()["coverage"]
    assert (meta["coverable_metrology"], meta["coverable_executable"], meta["covered"]) == (
        report.n_coverable_metrology,
        report.n_coverable,
        report.n_covered,
    )
    figure = plot_coverage(
        tmp_path / "c.png",
        manager.samples.points,
        manager.point_uncertainties(),
        manager.scan_lines_mm(),
        metrology_coverable=metrology,
        executable_coverable=executable,
        mesh=manager.part.mesh,
    )
    assert figure.stat().st_size > 10_000


def test_figure_colours_measurable_but_not_executable_apart(tmp_path):
    from matplotlib.colors import to_rgb

    from agiprobot_measurement.planning.report import coverage_figure

    seen = []

    class Capture(Exception):
        pass

    points = np.array([[0.0, 0, 0], [10, 0, 0], [0, 10, 0], [10, 10, 0]])
    u = np.array([0.02, np.inf, np.inf, np.inf])
    metrology = np.array([True, True, True, False])
    executable = np.array([True, False, True, False])
    original = coverage_figure.Figure.add_axes

    def spy(self, *args, **kwargs):
        ax = original(self, *args, **kwargs)
        if kwargs.get("projection") == "3d":
            real = ax.scatter

            def scatter(*a, c=None, **k):
                seen.append(np.asarray(c)[:, :3])
                return real(*a, c=c, **k)

            ax.scatter = scatter
        return ax

    coverage_figure.Figure.add_axes = spy
    try:
        plot_coverage(tmp_path / "f.png", points, u, metrology_coverable=metrology, executable_coverable=executable)
    finally:
        coverage_figure.Figure.add_axes = original
    colors = seen[0]
    order = np.argsort(np.isfinite(u), kind="stable")[::-1]  # the figure's drawing order
    by_point = np.empty_like(colors)
    by_point[order] = colors
    assert np.allclose(by_point[1], to_rgb(coverage_figure.NOT_EXECUTABLE_COLOR))
    assert np.allclose(by_point[2], to_rgb(coverage_figure.NOT_PLANNED_COLOR))
    assert np.allclose(by_point[3], to_rgb(coverage_figure.NOT_MEASURABLE_COLOR))


def test_whole_plan_time_limit_is_honoured_and_the_plan_stays_executable():
    manager = TrajectoryManager()
    manager.load_target_mesh(str(CUBE))
    limit = 4.0
    started = time.perf_counter()
    ordered = manager.plan(0.02, 0.1, 12, "none", "IP_basic", time_limit_s=limit)
    elapsed = time.perf_counter() - started
    report = manager.coverage_report()
    # generation is not interruptible and the first round always verifies its picks: a few seconds of slack
    assert elapsed < limit + 10.0
    assert ordered and all(v.mechanics_verified and v.mechanics_valid for v in ordered)
    assert report.solver_gap is not None
    if report.time_limit_hit:
        assert any("time limit" in w for w in report.warnings)


def test_a_metrology_cut_by_the_time_limit_gives_a_plan_that_says_so(monkeypatch):
    import agiprobot_measurement.planning.candidates.generation as generation

    monkeypatch.setattr(generation, "METROLOGY_TIME_SHARE", 0.0)  # the metrology's deadline: its start
    manager = TrajectoryManager()
    manager.load_target_mesh(str(CUBE))
    ordered = manager.plan(0.02, 0.1, 12, "none", "IP_basic", time_limit_s=120.0)
    report = manager.coverage_report()
    stats = manager.run.last_stream_stats
    assert stats.time_limited and stats.evaluated < stats.candidates
    assert report.time_limit_hit and report.candidates_evaluated_share == stats.evaluated / stats.candidates
    assert any("left the metrology time for" in w for w in report.warnings)
    # a plan, executable, of what the evaluated candidates measure
    assert ordered and all(v.mechanics_verified and v.mechanics_valid for v in ordered)
    assert report.n_covered > 0.5 * report.n_samples


def test_low_reachability_warns_with_the_share():
    manager = TrajectoryManager()
    manager.load_target_mesh(str(CUBE))
    manager.generate_samples_and_viewpoints(0.005, 0.1, 3, "none", min_reachable_share=1.01)
    assert manager.reachable_share == pytest.approx(1.0)
    assert any("reachable anchor" in w and "100.0 %" in w for w in manager.warnings)


def test_tilt_auto_reports_its_choice(cube_run):
    manager = TrajectoryManager()
    manager.load_target_mesh(str(CUBE))
    manager.plan(0.01, 0.1, 6, "auto", "IP_basic", time_limit_s=120.0)
    choice = manager.parameters["tilt_choice"]
    none_views = cube_run[0].coverage_report().n_views
    report = manager.coverage_report()
    assert choice.startswith(("none", "full"))
    # auto never ends up with more views than tilt none at the same coverage
    assert report.n_views <= none_views or report.n_covered > cube_run[0].coverage_report().n_covered


@pytest.mark.parametrize("seed", range(6))
def test_reductions_and_gap_keep_the_unreduced_optimum(seed):
    rng = np.random.default_rng(seed)
    rows, cols = 40, 60
    dense = rng.random((rows, cols)) < 0.12
    dense[:, :8] |= dense[:, 8:16]  # dominated columns
    dense[rng.integers(rows), :] = False
    dense[dense.sum(axis=1) == 0, rng.integers(cols)] = True  # no uncoverable rows here
    lone = rng.integers(rows)
    dense[lone, :] = False
    dense[lone, 5] = True  # a point only one view covers: a forced column
    matrix = scipy.sparse.csc_matrix(dense)
    reduced = solve_set_cover(matrix, "IP_basic", reduce=True)
    plain = solve_set_cover(matrix, "IP_basic", reduce=False)
    assert reduced.proven_optimal and plain.proven_optimal
    assert reduced.n_selected == plain.n_selected
    assert 5 in reduced.selected.tolist()
    assert reduced.covered.all()
    likely = reduced.stats["likely_columns"]
    assert 5 in likely.tolist()[: max(1, reduced.stats["forced_cols"])]
    # a proven small gap: the cover is within it of the optimum
    loose = solve_set_cover(matrix, "IP_basic", mip_gap=0.25)
    assert loose.n_selected <= plain.n_selected / (1 - 0.25) + 1e-9


def test_request_fields_are_validated():
    request = PlanRequest.from_defaults(part_file=str(CUBE), viewpoint_tilt_mode="auto", placement="fixture")
    valid = request.validate()
    assert valid.viewpoint_tilt_mode == "auto" and valid.placement == "fixture"
    assert valid.time_limit_s > 0 and 0 <= valid.set_cover_mip_gap < 1
    for field, value in (
        ("time_limit_s", -1.0),
        ("placement", "floor"),
        ("set_cover_mip_gap", 2.0),
        ("min_reachable_share", 1.5),
        ("tessellation_tolerance_mm", float("nan")),
    ):
        with pytest.raises(PlanRequestError) as info:
            PlanRequest.from_defaults(part_file=str(CUBE), **{field: value}).validate()
        assert info.value.field == field


def test_the_time_limit_reaches_the_stages_before_the_set_cover():
    manager = TrajectoryManager()
    manager.load_target_mesh(str(CUBE))
    started = time.perf_counter()
    # the limit counts from the request's start (the part's loading): here it ran out before the sampling
    with pytest.raises(PlanningTimeLimit, match="time limit of 5 s ran out during sampling"):
        manager.plan(0.02, 0.1, 12, "none", "IP_basic", time_limit_s=5.0, started_s=started - 6.0)
    assert time.perf_counter() - started < 5.0
    assert manager.run.clock is None


def test_local_workers_are_bounded_by_the_machine_and_counted_in_the_memory_budget():
    too_many = local_worker_limit() + 1
    with pytest.raises(PlanRequestError, match="more than this machine allows"):
        PlanRequest(part_file=str(CUBE), workers=too_many).validate()
    with pytest.raises(PlanRequestError, match="local worker processes alone"):
        PlanRequest(part_file=str(CUBE), workers=local_worker_limit(), max_memory_gb=0.2).validate()
    # an existing cluster's workers run elsewhere
    PlanRequest(part_file=str(CUBE), workers=too_many, scheduler="tcp://127.0.0.1:8786").validate()
    settings = EvaluationSettings(workers=2, max_memory_bytes=1e9)
    assert settings.budget_bytes() == pytest.approx(1e9 - 2 * WORKER_PROCESS_BYTES)
