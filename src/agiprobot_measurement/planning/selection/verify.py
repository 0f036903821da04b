"""The mechanical verification of views: a scan line's Cartesian path, joint jumps and collisions, its
trajectory and its duration, and what that changes in the run's coverage store (rejected views lose their
entries, shortened ones the points they no longer sweep)."""

from __future__ import annotations

import time

import numpy as np

from agiprobot_measurement.motion.time_parameterization import TimeParameterizationError
from agiprobot_measurement.planning.candidates.mechanics import (
    check_scan_line,
    check_scan_lines,
    scan_line_starts_free,
    set_scan_trajectory,
)
from agiprobot_measurement.planning.candidates.viewpoint import ViewPoint
from agiprobot_measurement.planning.run import PlanningRun, PlanningTools

__all__ = [
    "column_range",
    "finish_scan_trajectories",
    "record_duration",
    "screen_scan_lines",
    "set_trajectory",
    "verify_mechanics",
    "verify_mechanics_batch",
]


def column_range(run: PlanningRun, view: ViewPoint):
    """The view's entry range in the generation's coverage store, or None for a foreign view."""
    j = view.coverage_column
    views = run.generation_views
    if j is None or views is None or j >= len(views) or views[j] is not view:
        return None
    return int(run.measurability.indptr[j]), int(run.measurability.indptr[j + 1])


#: OMPL time (s) for a connection from the current state to a scan line's start while verifying
CONNECT_S = 1.0
#: ... and the least it gets when a deadline is near or past
MIN_CONNECT_S = 0.05


def _check_arguments(run: PlanningRun, tools: PlanningTools, settings: dict | None, deadline: float | None = None):
    """The scan-line check's settings and collaborators; a connection from the current state gets :data:`CONNECT_S`,
    or with a ``deadline`` the time left before it (at least :data:`MIN_CONNECT_S`)."""

    def connect_from_current(q):
        budget = CONNECT_S if deadline is None else min(CONNECT_S, max(MIN_CONNECT_S, deadline - time.perf_counter()))
        return tools.connect(tools.current_state, q, planning_time_s=budget)

    return {
        "settings": settings or run.mechanics,
        "ik": tools.ik,
        "collision": tools.collision,
        "preferred_state": tools.preferred_state,
        "scan_speed_mm_s": tools.scan_speed_mm_s,
        "connect_from_current": connect_from_current,
    }


def verify_mechanics(
    run: PlanningRun,
    tools: PlanningTools,
    view: ViewPoint,
    settings: dict | None = None,
    time_parameterize: bool = True,
) -> bool:
    """Compute the view's measurement trajectory; shorten the view to what is executable or reject it.

    With ``time_parameterize=False`` only the scan line's path is checked (the view is verified, valid or
    not, its duration an estimate); the trajectory is computed later by :func:`finish_scan_trajectories`
    for the views a cover keeps (the time parameterisation costs twice the check).
    """
    started = time.perf_counter()
    try:
        path = check_scan_line(view, **_check_arguments(run, tools, settings))
        return _record_check(run, tools, view, path, time_parameterize)
    finally:
        run.add_time("mechanics", time.perf_counter() - started)
        run.mechanics_checked += 1


def _record_check(run: PlanningRun, tools: PlanningTools, view: ViewPoint, path, time_parameterize: bool) -> bool:
    """The coverage store's side of a checked view (rejected: its entries die; shortened: the points it no longer
    sweeps), and its trajectory or its deferred path."""
    valid = path is not None
    if valid:
        if time_parameterize:
            set_trajectory(run, tools, view, path)
        else:
            view.set_trajectory_for_measurement(None)
            run.pending_scan_paths[id(view)] = (view, path)
    span = column_range(run, view)
    if span is not None:
        a, b = span
        if not valid:
            run.entry_alive[a:b] = False
        else:
            if view.measurable_indices.size < b - a:  # shortened: only the points it still sweeps
                kept = np.isin(run.measurability.point_indices[a:b], view.measurable_indices)
                run.entry_alive[a:b] &= kept
            if time_parameterize:
                record_duration(run, view)
    return valid


def verify_mechanics_batch(
    run: PlanningRun,
    tools: PlanningTools,
    views,
    settings: dict | None = None,
    time_parameterize: bool = True,
    deadline: float | None = None,
) -> list[bool]:
    """:func:`verify_mechanics` for many views at once (:func:`check_scan_lines`: batched IK, compiled branch
    walks, one collision check per attempt round); the same verdicts and the same changes to the views and the
    run's coverage store. Returns each view's validity. ``deadline`` (a ``time.perf_counter()`` value): a
    connection from the current state gets the time left before it (at least :data:`MIN_CONNECT_S`, at most
    :data:`CONNECT_S`), not the full :data:`CONNECT_S`."""
    views = list(views)
    if not views:
        return []
    started = time.perf_counter()
    try:
        paths = check_scan_lines(views, **_check_arguments(run, tools, settings, deadline))
        return [_record_check(run, tools, v, p, time_parameterize) for v, p in zip(views, paths, strict=True)]
    finally:
        run.add_time("mechanics", time.perf_counter() - started)
        run.mechanics_checked += len(views)


def set_trajectory(run: PlanningRun, tools: PlanningTools, view: ViewPoint, path: np.ndarray) -> None:
    """Time-parameterise ``view``'s checked scan line ``path`` (rad) and give it the trajectory."""
    run.pending_scan_paths.pop(id(view), None)
    set_scan_trajectory(
        view, path, kinematics=tools.kinematics, limits=tools.limits, scan_speed_mm_s=tools.scan_speed_mm_s
    )


def record_duration(run: PlanningRun, view: ViewPoint) -> None:
    """A verified view's trajectory duration (s) replaces its estimate in the set cover's durations."""
    if column_range(run, view) is None:
        return
    j = view.coverage_column
    # estimates must not be optimistic, or IP_time keeps preferring views not yet verified
    ratio = view.estimated_duration_s / max(run.durations_estimate[j], 1e-9)
    run.duration_bias = max(run.duration_bias, ratio)
    run.durations[j] = view.estimated_duration_s
    run.duration_verified[j] = True


def finish_scan_trajectories(run: PlanningRun, tools: PlanningTools, views) -> None:
    """Time-parameterise the checked scan lines of ``views`` whose trajectory was deferred; a view whose
    time parameterisation the joint limits refuse is left without a trajectory (the connection drops it)."""
    started = time.perf_counter()
    try:
        for view in views:
            pending = run.pending_scan_paths.get(id(view))
            if pending is not None and pending[0] is view and view.get_trajectory_for_measurement() is None:
                try:
                    set_trajectory(run, tools, view, pending[1])
                except TimeParameterizationError:
                    # left without a trajectory: the connection drops it with the reason and covers its points
                    # again (no single move fails a plan)
                    continue
                record_duration(run, view)
    finally:
        run.add_time("mechanics", time.perf_counter() - started)


def screen_scan_lines(run: PlanningRun, tools: PlanningTools, views) -> int:
    """Reject, in one batched pass, the unverified views whose scan line has no collision-free IK branch
    at either end (:func:`scan_line_starts_free`): the full check would reject them too. Returns how many
    it rejected."""
    todo = [v for v in views if v.mechanics_verified is False]
    if not todo:
        return 0
    started = time.perf_counter()
    free = scan_line_starts_free(todo, tools.ik, tools.collision, tools.preferred_state)
    rejected = 0
    for view, ok in zip(todo, free.tolist(), strict=True):
        if ok:
            continue
        view.mechanics_verified = True
        view.mechanics_valid = False
        span = column_range(run, view)
        if span is not None:
            run.entry_alive[span[0] : span[1]] = False
        rejected += 1
    run.mechanics_checked += rejected
    run.add_time("mechanics", time.perf_counter() - started)
    return rejected
