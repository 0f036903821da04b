"""The set cover's close-out near the deadline: the points no verified view measures get their views verified
until each has an executable view or none left unverified, without verifying every view."""

import math
import time

import numpy as np

from agiprobot_measurement.planning.report.report import coverable_mask
from agiprobot_measurement.planning.selection import loop as loop_module
from agiprobot_measurement.planning.selection.loop import CoverLoop, _Round
from agiprobot_measurement.planning.selection.open_points import open_point_views
from agiprobot_measurement.planning.selection.problem import coverage_problem
from agiprobot_measurement.planning.trajectory_manager import TrajectoryManager
from agiprobot_measurement.station import PACKAGE_ROOT

CUBE = PACKAGE_ROOT / "parts" / "objectA_wuerfel.stl"


def _loop(deadline: float):
    manager = TrajectoryManager(seed=5)
    manager.load_target_mesh(str(CUBE))
    _, views = manager.generate_samples_and_viewpoints(0.004, 0.1, 4, "full")
    views = list(views)
    loop = CoverLoop(
        manager.run, manager.tools(), views, "IP_basic", 10.0, 30, 0.0, deadline, None,
        n_points=len(manager.run.samples), provided={id(v) for v in views},
    )  # fmt: skip
    return manager, loop


def _open_points(views, n: int) -> int:
    """Measurable points that only unverified views measure (what the report counts as not verified)."""
    verified = coverable_mask(views, n, None, verified_only=True)
    unverified = coverable_mask([v for v in views if not v.mechanics_verified], n, None, verified_only=False)
    return int((unverified & ~verified).sum())


def test_close_out_settles_every_open_point_without_verifying_every_view():
    manager, loop = _loop(time.perf_counter() + 120.0)
    n = len(manager.run.samples)
    assert all(v.mechanics_verified is False for v in loop.views)
    assert _open_points(loop.views, n) > 100  # nothing verified yet: every measurable point is open
    loop.close_out()
    assert loop.closed_out
    assert _open_points(loop.views, n) == 0
    verified = sum(v.mechanics_verified is True for v in loop.views)
    assert 0 < verified < 0.5 * len(loop.views)
    # every point some view measured before is still measured by a verified valid view, or by no view at all
    assert loop.verified_count >= verified


def test_close_out_is_due_only_when_another_round_would_leave_too_little_time():
    manager, loop = _loop(math.inf)
    matrix, worst, durations = coverage_problem(manager.run, loop.views, loop.n_points)
    columns = np.arange(len(loop.views))
    step = _Round(columns, matrix, worst, durations, matrix, 1.0, [], [], True, time.perf_counter())
    loop.line_s = 0.1  # verifying the open points' views (a few per point, 200 points) takes seconds
    assert not loop._close_out_due(step)  # no deadline
    loop.deadline = time.perf_counter() + 3600.0
    assert not loop._close_out_due(step)
    loop.deadline = time.perf_counter() + 2.0
    assert loop._close_out_due(step)
    loop.line_s = None  # nothing verified yet: no estimate
    assert not loop._close_out_due(step)


def test_close_out_is_due_when_the_longest_round_so_far_would_leave_too_little_time():
    """A short round after a long one (a solve over all views, a loaded machine): the next may be as long as the
    longest, so the close-out starts while its views still fit."""
    manager, loop = _loop(math.inf)
    matrix, worst, durations = coverage_problem(manager.run, loop.views, loop.n_points)
    columns = np.arange(len(loop.views))
    loop.line_s = 0.01
    open_s = open_point_views(matrix, loop.views, len(loop.views)).size * loop.line_s
    short = _Round(columns, matrix, worst, durations, matrix, 1.0, [], [], True, time.perf_counter())
    loop.deadline = time.perf_counter() + open_s + 5.0  # the open points' views and a short round fit
    assert not loop._close_out_due(short)
    loop.longest_round_s = 10.0  # an earlier round took 10 s: another like it would leave too little time
    assert loop._close_out_due(short)


def test_after_a_close_out_the_next_round_is_the_fallback_over_verified_views():
    manager, loop = _loop(time.perf_counter() + 120.0)
    loop.close_out()
    step = loop.solve_round(1)
    assert loop.only_verified and manager.run.time_limit_hit
    assert step.chosen and all(v.mechanics_verified is True and v.mechanics_valid for v in step.chosen)
    assert any("drew near" in w for w in manager.run.warnings)


def test_close_out_after_the_deadline_verifies_nothing():
    _, loop = _loop(time.perf_counter() - 1.0)
    loop.close_out()
    assert loop.closed_out and loop.verified_count == 0


def test_rounds_go_on_after_a_close_out_that_left_time_for_another_round():
    _, loop = _loop(time.perf_counter() + 300.0)
    loop.close_out(round_s=1.0)
    assert not loop.closed_out
    loop.solve_round(1)
    assert not loop.only_verified


def test_the_fallback_past_the_deadline_solves_long_enough_for_the_covers_lower_bound(monkeypatch):
    """The fallback's cover is the plan's: past the deadline its solve still gets FALLBACK_MIN_IP_TIME_S (not the
    0.3 s of LATE_IP_TIME_S), so its LP gives the bound the report puts beside the view count."""
    _, loop = _loop(time.perf_counter() + 120.0)
    loop.close_out()
    loop.deadline = time.perf_counter() - 5.0  # the deadline long past
    limits = []
    solve = loop_module.solve_set_cover

    def recording(*args, **kwargs):
        limits.append(kwargs["time_limit_s"])
        return solve(*args, **kwargs)

    monkeypatch.setattr(loop_module, "solve_set_cover", recording)
    loop.solve_round(1)
    assert loop.only_verified
    assert limits == [min(loop.time_limit_s, loop_module.FALLBACK_MIN_IP_TIME_S)]
    assert loop.result.lower_bound is not None and loop.result.lower_bound <= loop.result.objective
