"""Ordering the chosen views for a fast execution: point-to-point move times, greedy + 2-opt tours, unwrapping.

Joint values are rad, velocities rad/s, accelerations rad/s^2, durations s. ``limits`` is the station's
:class:`~agiprobot_measurement.station.JointLimits` (lower, upper, max_velocity, max_acceleration per joint).
"""

from __future__ import annotations

import itertools
import logging
import time

import numpy as np

from agiprobot_measurement.motion.trajectory import JointTrajectory
from agiprobot_measurement.planning.errors import PlanningError
from agiprobot_measurement.planning.run import PlanningRun, PlanningTools
from agiprobot_measurement.planning.selection.verify import finish_scan_trajectories, verify_mechanics

LOG = logging.getLogger(__name__)

__all__ = ["connect_views", "order_views", "p2p_durations", "unwrapped_towards", "wrapping_joints"]


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
    connection time from the current state, either scan direction, then 2-opt; the run's ``last_ordered`` and
    ``unconnected_views`` are set. Returns the ordered list."""
    views = [v for v in unordered_viewpoints]
    t0 = time.perf_counter()
    finish_scan_trajectories(run, tools, views)
    for view in views:
        if not view.mechanics_verified or view.get_trajectory_for_measurement() is None:
            if not verify_mechanics(run, tools, view):
                raise PlanningError(f"{view} has no executable measurement trajectory")
    if not views:
        return []
    starts = np.array([v.get_trajectory_for_measurement().start for v in views])
    ends = np.array([v.get_trajectory_for_measurement().end for v in views])
    order, flips = order_views(tools.current_state, starts, ends, tools.limits)
    ordered, unconnected = [], []
    state = tools.current_state.copy()
    for k, (i, flip) in enumerate(zip(order, flips, strict=True)):
        view = views[i]
        if flip != view.reversed:
            view.reverse_trajectory_for_measurement()
        view.set_trajectory_for_measurement(
            unwrapped_towards(view.get_trajectory_for_measurement(), state, tools.limits)
        )
        entry = view.get_trajectory_for_measurement().start
        tools.report("connection", k / len(order), f"connecting view {k + 1} of {len(order)}")
        connection = tools.connect(state, entry, planning_time_s=min_planning_time)
        if connection is None:
            LOG.warning("view %d cannot be connected from the previous state: left out", i)
            unconnected.append(view)
            continue
        view.set_trajectory_to_view(connection)
        ordered.append(view)
        state = view.get_trajectory_for_measurement().end.copy()
    run.unconnected_views = unconnected
    run.last_ordered = ordered
    run.timings_s["connection"] = time.perf_counter() - t0
    tools.report("connection", 1.0, f"{len(ordered)} views connected, {len(unconnected)} left out")
    return ordered
