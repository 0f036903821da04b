"""When a move fails: no single move takes a plan down.

A view whose connection fails is entered from the other end of its scan line; when that fails too, the arm
retracts along the sensor's boresight, moves and approaches again (:func:`retract_and_approach`); a move that
raises (a time parameterisation the joint limits refuse) counts as failed, not as an error. A view nothing
connects, or whose scan line cannot be time-parameterised, is dropped: :func:`drop_view` records it with the
reason (the run's ``dropped_views``, in the summary and the plan metadata), and :func:`cover_dropped_points`
covers the points only dropped views measured with other verified views, connected the same way. Joint values
rad, distances m, times s.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from agiprobot_measurement.errors import AgiprobotError
from agiprobot_measurement.motion.motion_planning import interpolate_path, path_trajectory
from agiprobot_measurement.planning.run import PlanningRun, PlanningTools
from agiprobot_measurement.planning.selection.verify import column_range, finish_scan_trajectories

__all__ = [
    "RETRACT_DISTANCES_M",
    "connect_with_fallbacks",
    "cover_dropped_points",
    "drop_view",
    "reject_view",
    "retract_and_approach",
]

LOG = logging.getLogger(__name__)

#: retract-and-approach moves the sensor back along its boresight by each of these (m), nearest first
RETRACT_DISTANCES_M = (0.1, 0.25)
#: joint step (rad) at which the retract and approach legs are collision-checked
LEG_CHECK_STEP_RAD = 0.02
#: replacement views tried per dropped view (each a connection attempt) before its points are given up
REPLACEMENTS_PER_DROPPED_VIEW = 4


def drop_view(run: PlanningRun, view, reason: str, log=LOG) -> None:
    """Leave ``view`` out of the plan for ``reason``: listed in the run's ``dropped_views`` (and, as before, in
    ``unconnected_views``), warned about once."""
    run.unconnected_views.append(view)
    run.dropped_views.append({"view": _label(view), "reason": reason})
    run.warn(f"view {_label(view)} dropped: {reason}", log)


def _label(view) -> str:
    column = getattr(view, "coverage_column", None)
    return f"#{column}" if column is not None else f"at {np.round(view.get_surface_point(), 1).tolist()} mm"


def _safe_connect(tools: PlanningTools, q_from, q_to, planning_time_s: float):
    """``tools.connect`` with a failure (an error the motion layer raises) as None, and its message."""
    try:
        return tools.connect(q_from, q_to, planning_time_s=planning_time_s), ""
    except AgiprobotError as exc:
        return None, str(exc)


def retract_and_approach(tools: PlanningTools, q_from, q_to, planning_time_s: float):
    """A move from ``q_from`` to ``q_to`` (rad) that first backs the sensor away along its boresight, connects the
    retracted states and approaches again (each of :data:`RETRACT_DISTANCES_M`, nearest first), or None. The
    retract and approach legs are straight joint moves, collision-checked."""
    ends = np.asarray([q_from, q_to], dtype=float)
    poses = tools.kinematics.fk_batch(ends)
    for distance in RETRACT_DISTANCES_M:
        backed = poses.copy()
        backed[:, :3, 3] -= distance * backed[:, :3, 2]
        q, ok = tools.ik.solve_nearest(backed, ends)
        if not np.all(ok):
            continue
        legs = (np.asarray([ends[0], q[0]]), np.asarray([q[1], ends[1]]))
        if not all(tools.collision.check_states(interpolate_path(leg, LEG_CHECK_STEP_RAD)).all() for leg in legs):
            continue
        middle, _ = _safe_connect(tools, q[0], q[1], planning_time_s)
        if middle is None:
            continue
        try:
            return (
                path_trajectory(legs[0], tools.limits)
                .concatenated(middle)
                .concatenated(path_trajectory(legs[1], tools.limits))
            )
        except AgiprobotError as exc:
            LOG.debug("retract and approach by %.2f m failed: %s", distance, exc)
    return None


def connect_with_fallbacks(tools: PlanningTools, state, view, unwrap, planning_time_s: float):
    """Connect ``state`` to ``view``'s measurement: its entry, else its other end (the scan reversed), each
    directly and by retract-and-approach. Sets the view's connection and returns True, or returns the reason it
    failed (a string). ``unwrap(trajectory, reference)`` shifts the wide joints of a trajectory towards a state."""
    reasons = []
    for attempt in range(2):
        if attempt:
            view.reverse_trajectory_for_measurement()
        view.set_trajectory_for_measurement(unwrap(view.get_trajectory_for_measurement(), state))
        entry = view.get_trajectory_for_measurement().start
        connection, error = _safe_connect(tools, state, entry, planning_time_s)
        if connection is None:
            connection = retract_and_approach(tools, state, entry, planning_time_s)
        if connection is not None:
            view.set_trajectory_to_view(connection)
            return True
        reasons.append(error or "no collision-free move found (direct, OMPL, retract and approach)")
    return "; ".join(dict.fromkeys(reasons)) + " (both scan directions)"


def cover_dropped_points(run: PlanningRun, tools: PlanningTools, ordered: list, state, connect, deadline: float):
    """Cover the points only the run's dropped views measured with other verified, executable views (the view
    measuring most of them first), each connected by ``connect(state, view) -> True | reason`` after the last one.
    Appends them to ``ordered``; returns how many were added. Stops at the ``deadline`` (a perf_counter value)."""
    dropped = {id(v) for v in run.unconnected_views}
    n = len(run.samples) if run.samples is not None else 0
    if not dropped or n == 0:
        return 0
    covered = np.zeros(n, dtype=bool)
    for view in ordered:
        covered[view.measurable_indices] = True
    lost = np.zeros(n, dtype=bool)
    for view in run.unconnected_views:
        lost[view.measurable_indices] = True
    lost &= ~covered
    taken = {id(v) for v in ordered} | dropped
    candidates = [
        v for v in run.last_viewpoints
        if id(v) not in taken and v.mechanics_verified and v.mechanics_valid and lost[v.measurable_indices].any()
    ]  # fmt: skip
    added, tries = 0, REPLACEMENTS_PER_DROPPED_VIEW * len(dropped)
    while lost.any() and candidates and tries > 0 and time.perf_counter() < deadline:
        gains = np.array([int(lost[v.measurable_indices].sum()) for v in candidates])
        best = int(np.argmax(gains))
        if gains[best] == 0:
            break
        view = candidates.pop(best)
        tries -= 1
        try:
            finish_scan_trajectories(run, tools, [view])
        except AgiprobotError as exc:
            reject_view(run, view)
            drop_view(run, view, f"its scan line cannot be time-parameterised: {exc}")
            continue
        if view.get_trajectory_for_measurement() is None:
            continue
        outcome = connect(state, view)
        if outcome is not True:
            drop_view(run, view, f"replacement not connected: {outcome}")
            continue
        ordered.append(view)
        state = view.get_trajectory_for_measurement().end.copy()
        lost[view.measurable_indices] = False
        added += 1
    if lost.any():
        run.warn(f"{int(lost.sum())} points only dropped views measured stay uncovered", LOG)
    return added


def reject_view(run: PlanningRun, view) -> None:
    """A view whose scan line failed for good: no longer executable, its coverage entries dead."""
    view.mechanics_valid = False
    span = column_range(run, view)
    if span is not None:
        run.entry_alive[span[0] : span[1]] = False
