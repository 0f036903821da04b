"""Ordering the chosen views for a fast execution: point-to-point move times, greedy + 2-opt tours, unwrapping.

Joint values are rad, velocities rad/s, accelerations rad/s^2, durations s. ``limits`` is the station's
:class:`~agiprobot_measurement.station.JointLimits` (lower, upper, max_velocity, max_acceleration per joint).
"""

from __future__ import annotations

import itertools
import logging
import time

import numpy as np

from agiprobot_measurement.errors import AgiprobotError
from agiprobot_measurement.motion.trajectory import JointTrajectory
from agiprobot_measurement.planning.recovery import (
    connect_with_fallbacks,
    cover_dropped_points,
    drop_view,
    reject_view,
)
from agiprobot_measurement.planning.run import PlanningRun, PlanningTools
from agiprobot_measurement.planning.selection.verify import finish_scan_trajectories, verify_mechanics

LOG = logging.getLogger(__name__)

#: the points of dropped views are covered again for at least this long (s), even when the time limit came
RECOVERY_MIN_S = 10.0

__all__ = ["RECOVERY_MIN_S", "connect_views", "order_views", "p2p_durations", "unwrapped_towards", "wrapping_joints"]


def p2p_durations(
    starts: np.ndarray,
    goals: np.ndarray,
    max_velocity: np.ndarray,
    max_acceleration: np.ndarray,
    wraps: np.ndarray | None = None,
):
    """Durations (s) of synchronised point-to-point joint moves, all pairs: (A, n) x (B, n) -> (A, B).

    The time of the straight joint-space move, a lower bound of any collision-free connection and the exact
    time where the straight move is free. Joints flagged in ``wraps`` (a range of at least 2 pi) count their
    shortest angular distance, since the goal can be reached at an angle shifted by 2 pi.
    """
    difference = starts[:, None, :] - goals[None, :, :]
    if wraps is not None:
        wrapped = np.abs((difference + np.pi) % (2 * np.pi) - np.pi)
        distance = np.where(wraps, wrapped, np.abs(difference))
    else:
        distance = np.abs(difference)
    triangular = distance < max_velocity**2 / max_acceleration
    own = np.where(
        triangular,
        2.0 * np.sqrt(distance / max_acceleration),
        distance / max_velocity + max_velocity / max_acceleration,
    )
    return own.max(axis=2)


def wrapping_joints(limits) -> np.ndarray:
    """(n,) bool: the joints whose range spans at least 2 pi."""
    return (limits.upper - limits.lower) >= 2 * np.pi - 1e-6


def unwrapped_towards(trajectory: JointTrajectory, reference: np.ndarray, limits) -> JointTrajectory:
    """The same motion with its wide joints shifted by multiples of 2 pi so that it starts as near
    ``reference`` as the joint limits allow (a revolute joint reaches the same pose at q and q + 2 pi)."""
    wraps = wrapping_joints(limits)
    turns = np.where(wraps, np.round((reference - trajectory.start) / (2 * np.pi)), 0.0)
    for _ in range(3):
        shift = 2 * np.pi * turns
        moved = trajectory.positions + shift
        low = moved.min(axis=0) < limits.lower - 1e-9
        high = moved.max(axis=0) > limits.upper + 1e-9
        if not (low.any() or high.any()):
            if not np.any(shift):
                return trajectory
            shifted = trajectory.copy()
            shifted.positions = moved
            return shifted
        turns = turns + low - high  # step back towards the limits
    return trajectory


def order_views(current: np.ndarray, starts: np.ndarray, ends: np.ndarray, limits):
    """Greedy order + 2-opt on estimated connection times from ``current`` through views whose measurement
    runs from ``starts[i]`` to ``ends[i]`` (either direction); returns (order, flipped per position)."""
    n = len(starts)
    vmax, amax = limits.max_velocity, limits.max_acceleration
    # entries[2i] = start of view i (forward), entries[2i+1] = end of view i (reversed scan)
    entries = np.empty((2 * n, starts.shape[1]))
    entries[0::2], entries[1::2] = starts, ends
    exits = np.empty_like(entries)
    exits[0::2], exits[1::2] = ends, starts
    wraps = wrapping_joints(limits)
    from_current = p2p_durations(current[None], entries, vmax, amax, wraps)[0]
    between = p2p_durations(exits, entries, vmax, amax, wraps)  # exit of (i, dir) -> entry of (j, dir')
    remaining = set(range(n))
    tour = []
    cost = from_current.copy()
    while remaining:
        candidates = [(cost[2 * i + d], i, d) for i in remaining for d in (0, 1)]
        _, i, d = min(candidates)
        tour.append((i, d))
        remaining.remove(i)
        cost = between[2 * i + d]

    def tour_cost(t):
        total = from_current[2 * t[0][0] + t[0][1]]
        for (a, da), (b, db) in itertools.pairwise(t):
            total += between[2 * a + da, 2 * b + db]
        return total

    best = tour_cost(tour)
    improved = True
    passes = 0
    while improved and passes < 50:
        improved = False
        passes += 1
        for i in range(n):
            for j in range(i, n):
                # reverse the block i..j: order flips and so does each view's scan direction
                candidate = tour[:i] + [(v, 1 - d) for v, d in reversed(tour[i : j + 1])] + tour[j + 1 :]
                value = tour_cost(candidate)
                if value < best - 1e-9:
                    tour, best, improved = candidate, value, True
    return [v for v, _ in tour], [bool(d) for _, d in tour]


def connect_views(run: PlanningRun, tools: PlanningTools, unordered_viewpoints, min_planning_time=0.2) -> list:
    """Order the views for a fast execution and connect them (the facade's ``connect_viewpoints``): greedy by
    connection time from the current state, either scan direction, then 2-opt; the run's ``last_ordered``,
    ``unconnected_views`` and ``dropped_views`` are set. A view no move connects (after the fallbacks of
    :mod:`~agiprobot_measurement.planning.recovery`) is dropped and its points covered again by other verified
    views. Returns the ordered list."""
    views = [v for v in unordered_viewpoints]
    t0 = time.perf_counter()
    run.unconnected_views, run.dropped_views = [], []
    views = [v for v in views if _executable(run, tools, v)]
    if not views:
        run.last_ordered = []
        return []
    starts = np.array([v.get_trajectory_for_measurement().start for v in views])
    ends = np.array([v.get_trajectory_for_measurement().end for v in views])
    order, flips = order_views(tools.current_state, starts, ends, tools.limits)
    ordered = []
    state = tools.current_state.copy()

    def connect(state, view):
        unwrap = lambda trajectory, reference: unwrapped_towards(trajectory, reference, tools.limits)  # noqa: E731
        return connect_with_fallbacks(tools, state, view, unwrap, min_planning_time)

    for k, (i, flip) in enumerate(zip(order, flips, strict=True)):
        view = views[i]
        if flip != view.reversed:
            view.reverse_trajectory_for_measurement()
        tools.report("connection", k / len(order), f"connecting view {k + 1} of {len(order)}")
        outcome = connect(state, view)
        if outcome is not True:
            drop_view(run, view, f"not connected: {outcome}")
            continue
        ordered.append(view)
        state = view.get_trajectory_for_measurement().end.copy()
    if run.unconnected_views:
        clock = run.clock
        deadline = time.perf_counter() + RECOVERY_MIN_S
        if clock is not None:
            deadline = max(deadline, clock.started_s + clock.limit_s)
        added = cover_dropped_points(run, tools, ordered, state, connect, deadline)
        run.parameters["replacement_views"] = added
    run.last_ordered = ordered
    run.timings_s["connection"] = time.perf_counter() - t0
    tools.report("connection", 1.0, f"{len(ordered)} views connected, {len(run.unconnected_views)} left out")
    return ordered


def _executable(run: PlanningRun, tools: PlanningTools, view) -> bool:
    """The view's measurement trajectory exists (computed now when it was deferred); a view whose scan line
    fails its check or its time parameterisation is dropped (with the reason) instead of failing the plan."""
    try:
        finish_scan_trajectories(run, tools, [view])
        if not view.mechanics_verified or view.get_trajectory_for_measurement() is None:
            if not verify_mechanics(run, tools, view):
                drop_view(run, view, "its scan line is not executable")
                return False
    except AgiprobotError as exc:
        reject_view(run, view)
        drop_view(run, view, f"its scan line cannot be time-parameterised: {exc}")
        return False
    return True
