"""The whole pipeline on a loaded part: generate, solve the set cover, connect; and tilt auto (plan with tilt
none, and with tilt full when tilt none's cover is large or short and time is left; keep the plan with fewer views
at the same coverage).

The stages here work on the facade (``manager``: its ``run``, its documented stage methods and
``coverage_report``), since they chain its steps and tilt auto runs the pipeline twice and keeps one run.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from agiprobot_measurement.motion.collision import CollisionChecker
from agiprobot_measurement.motion.placement_check import check_placement
from agiprobot_measurement.planning.candidates.viewpoint import ViewPoint
from agiprobot_measurement.planning.connection import ConnectionPlanner
from agiprobot_measurement.planning.cover.solve import SOLVER_TYPES
from agiprobot_measurement.planning.deadline import StageClock
from agiprobot_measurement.planning.errors import PlanningError, PlanningTimeLimit
from agiprobot_measurement.planning.part_loading import LoadedPart, part_parameters, place_part
from agiprobot_measurement.planning.report.report import CoverageReport, point_uncertainties
from agiprobot_measurement.planning.request import REQUEST_TILT_MODES, check_choice, check_positive
from agiprobot_measurement.planning.selection.loop import cover_points_with_verified

__all__ = [
    "AUTO_COVERAGE_SHARE",
    "AUTO_MIN_TIME_SHARE",
    "AUTO_SAME_COVERAGE",
    "AUTO_VIEWS",
    "cover_with_verified",
    "plan_auto",
]

LOG = logging.getLogger(__name__)

#: tilt auto tries tilt full when tilt none covers less than this share of the metrologically coverable points
AUTO_COVERAGE_SHARE = 0.98
#: ... or needs more views than this
AUTO_VIEWS = 10
#: ... and at least this share of the time limit is left
AUTO_MIN_TIME_SHARE = 0.4
#: coverages within this share of the samples count as the same
AUTO_SAME_COVERAGE = 0.005


def plan_auto(manager, t0: float, deadline: float, settings: dict) -> list[ViewPoint]:
    """Tilt none, then (when its cover is large or short and time is left) tilt full, and tilt full's
    verified views solved again for the points tilt none covered. Among the plans that cover at least what
    tilt none covers (within :data:`AUTO_SAME_COVERAGE` of the samples), the one with the fewest views wins,
    then the one covering more; the choice and the figures of every plan are in ``parameters['tilt_choice']``.
    Tilt full covering more points with more views is reported, not chosen: the same coverage with fewer
    views is what tilts are tried for."""
    base_warnings = list(manager.run.warnings)
    ordered = plan_once(manager, "none", deadline, settings)
    first = manager.coverage_report()
    first_state = manager.run.snapshot()
    first_points = np.isfinite(point_uncertainties(ordered, len(manager.run.samples)))
    short = first.n_covered < AUTO_COVERAGE_SHARE * first.n_coverable_metrology
    large = first.n_views > AUTO_VIEWS
    left = deadline - time.perf_counter()
    if not (short or large):
        choice = f"none (cover of {first.n_views} views, {first.n_covered} covered: tilts not needed)"
    elif left < AUTO_MIN_TIME_SHARE * (deadline - t0):
        choice = f"none (no time left to try tilt full: {left:.0f} s)"
    else:
        manager.run.warnings = list(base_warnings)
        manager.run.timings_s = {}
        try:
            plan_once(manager, "full", deadline, settings)
            second = manager.coverage_report()
        except (PlanningError, PlanningTimeLimit) as exc:
            second, reason = None, str(exc)
        tolerance = AUTO_SAME_COVERAGE * first.n_samples
        enough = second is not None and second.n_covered >= first.n_covered - tolerance
        third = None
        if second is not None and not (enough and second.n_views < first.n_views):
            # tilt full's cover may buy extra points with extra views: its verified views, solved for the
            # points tilt none covered, give the same coverage with (possibly) fewer views
            full_timings = dict(manager.run.timings_s)
            third = cover_with_verified(manager, first_points, settings, deadline)
            if third is not None:
                manager.run.timings_s = {**full_timings, **manager.run.timings_s}
        third_enough = third is not None and third.n_covered >= first.n_covered - tolerance
        full_detail = (
            f"tilt full: {second.n_views} views, {second.n_covered} covered"
            if second is not None
            else f"tilt full failed: {reason}"
        )
        if enough and second.n_views < first.n_views:
            ordered = list(manager.run.last_ordered)
            choice = (
                f"full ({second.n_views} views, {second.n_covered} covered; tilt none: {first.n_views} views, "
                f"{first.n_covered} covered)"
            )
            manager.run.timings_s["tilt_none_total"] = first.timings_s.get("total", 0.0)
        elif third_enough and third.n_views < first.n_views:
            ordered = list(manager.run.last_ordered)
            choice = (
                f"full, for tilt none's points ({third.n_views} views, {third.n_covered} covered; tilt none: "
                f"{first.n_views} views, {first.n_covered} covered; {full_detail})"
            )
            manager.run.timings_s["tilt_none_total"] = first.timings_s.get("total", 0.0)
        else:
            restricted = (
                f"; for tilt none's points: {third.n_views} views, {third.n_covered} covered"
                if third is not None
                else ""
            )
            choice = f"none ({first.n_views} views, {first.n_covered} covered; {full_detail}{restricted})"
            full_time = time.perf_counter() - t0
            manager.run = first_state
            manager.run.timings_s["tilt_full_total"] = full_time
    manager.run.parameters["viewpoint_tilt_mode_requested"] = "auto"
    manager.run.parameters["tilt_choice"] = choice
    LOG.info("tilt auto: %s", choice)
    return ordered


def cover_with_verified(manager, points: np.ndarray, settings: dict, deadline: float) -> CoverageReport | None:
    """Cover the points of the mask ``points`` with the run's verified executable views, connect the cover and
    report it; None when there is no time, no such view or the samples differ."""
    chosen = cover_points_with_verified(manager.run, manager.tools(), points, settings, deadline)
    if chosen is None:
        return None
    manager.connect_viewpoints(chosen, min_planning_time=settings["min_planning_time"])
    return manager.coverage_report()


def plan(manager, viewpoint_tilt_mode, time_limit_s, started_s=None, **settings) -> list[ViewPoint]:
    """The facade's ``plan`` (see there): the ordered views. ``settings``: its other arguments (``generation``:
    the keyword arguments for the generation). ``started_s``: the ``time.perf_counter()`` value the time limit
    counts from (default: now; the loading of the part when it is part of the request)."""
    check_choice(settings["solver_type"], SOLVER_TYPES, "solver_type")
    check_choice(viewpoint_tilt_mode, REQUEST_TILT_MODES, "viewpoint_tilt_mode")
    limit = check_positive(time_limit_s, "time_limit_s", "time_limit_s (s)")
    t0 = time.perf_counter() if started_s is None else float(started_s)
    deadline = t0 + limit
    manager.run.clock = StageClock(t0, limit)
    try:
        if viewpoint_tilt_mode != "auto":
            ordered = plan_once(manager, viewpoint_tilt_mode, deadline, settings)
        else:
            ordered = plan_auto(manager, t0, deadline, settings)
    finally:
        manager.run.clock = None
    manager.run.timings_s["total"] = time.perf_counter() - t0
    manager.run.parameters["time_limit_s"] = limit
    return ordered


def plan_once(manager, tilt_mode, deadline, settings: dict) -> list[ViewPoint]:
    """Generate at ``tilt_mode``, solve the set cover and connect with the facade's ``plan`` ``settings``, within
    the ``deadline`` (a ``time.perf_counter()`` value)."""
    density, threshold = settings["sampling_density"], settings["uncertainty_threshold"]
    orientations = settings["orientations_around_boresight"]
    _, views = manager.generate_samples_and_viewpoints(
        density, threshold, orientations, tilt_mode, **settings["generation"]
    )
    # the connection needs its share of the time: about a second per view in the worst case, bounded
    left = deadline - time.perf_counter()
    reserve = min(0.25 * left, max(0.1 * left, 20.0))
    chosen = manager.solve_scp(
        views,
        settings["solver_type"],
        time_limit_s=settings["set_cover_time_limit_s"],
        mip_gap=settings["mip_gap"],
        deadline_s=deadline - reserve,
    )
    return manager.connect_viewpoints(chosen, min_planning_time=settings["min_planning_time"])


def load_target(
    manager, file_name, transform, add_wbk_mirrors, remove_downside, remove_threshold_angle_deg, units, placement,
    check_scene_overlap, tessellation_tolerance_mm,
) -> bool:  # fmt: skip
    """The facade's ``load_target_mesh`` (see there): read and place the part, put it into the collision world,
    check its placement and start a new connection planner in that world. Returns True."""
    scene = manager._base_scene if add_wbk_mirrors else manager._base_scene.without_group("wbk_mirrors")
    args = (units, remove_downside, remove_threshold_angle_deg, tessellation_tolerance_mm)

    def prepare() -> tuple[LoadedPart, CollisionChecker, float | None]:
        # builds new objects only: under a time limit it may be left running when the limit ends the wait
        part = place_part(
            file_name, scene, transform, placement, *args, checkpoint=lambda: manager.check_time("sampling")
        )
        collision = CollisionChecker(manager.kinematics, scene, manager.collision.config, load_part=False)
        collision.set_part(part.mesh, pose=np.eye(4), name="part", scale_to_m=1e-3)
        manager.check_time("sampling")
        if not check_scene_overlap:
            return part, collision, None
        started = time.perf_counter()
        check_placement(part.mesh, scene, collision, manager.current_state)
        return part, collision, time.perf_counter() - started

    # reading, merging and putting a huge mesh into the collision world are long steps that cannot check the
    # time themselves: under a time limit, the limit ends the wait for them
    clock = manager.run.clock
    part, manager.collision, placement_check_s = prepare() if clock is None else clock.call("loading", prepare)
    for message in part.warnings:
        LOG.warning("%s", message)
    if placement_check_s is not None:
        manager.timings_s["placement_check"] = placement_check_s
    manager.warnings = list(part.warnings)
    manager.connection = ConnectionPlanner(manager.collision, manager.limits, manager.planner_name, manager.seed)
    manager.part, manager.target_mesh, manager.samples = part, part.mesh, None
    angle, mirrors = remove_threshold_angle_deg, add_wbk_mirrors
    manager.parameters.update(
        part_parameters(part, file_name, units, mirrors, remove_downside, angle, placement, manager.seed)
    )
    return True
