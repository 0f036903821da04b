"""Collision-free joint moves between two configurations, by the cheapest route that is free.

:class:`Router` tries, in this order: the straight joint move; straight moves through via configurations (poses
the robot has already been at without collision, given by the caller) and around a sphere about a centre (retract
along the optical axis and approach, or pass the great circle between the two views); OMPL's best of several
solutions. A via route no longer than :data:`VIA_ACCEPT_RATIO` times the straight joint distance is taken without
asking OMPL; otherwise the shorter (joint path, rad) of the via route and OMPL's path wins.

The collaborators are handed in: a collision checker (``check_states``), the joint limits, a function that builds
the OMPL planner (called once, only when a move needs it) and, for the moves around the sphere, the arm
(``sensor_pose(q)`` and ``ik.solve_nearest(poses, seeds)``) and a function giving sensor poses at a point of the
sphere looking at its centre. :meth:`Router.connect` is the narrow form: straight, else OMPL. Joints rad, lengths m.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from agiprobot_measurement.common.geometry import raise_elevation, slerp_unit
from agiprobot_measurement.motion.motion_planning import collision_free_trajectory, interpolate_path, path_trajectory

__all__ = ["VIA_ACCEPT_RATIO", "VIA_CHECK_STEP_RAD", "RouteSettings", "Router", "path_length_rad"]

#: a move through a via pose at most this times the straight joint distance is taken without asking OMPL
VIA_ACCEPT_RATIO = 1.5
#: joint step (rad) at which the via moves are collision-checked (as the straight move's)
VIA_CHECK_STEP_RAD = 0.02
#: OMPL attempts of a routed move (each with twice the previous budget), after the via routes
ROUTE_OMPL_ATTEMPTS = 2


def path_length_rad(trajectory) -> float:
    """Joint path of a trajectory: sum of |dq| over its samples (rad)."""
    positions = np.asarray(trajectory.positions, dtype=float)
    return float(np.abs(np.diff(positions, axis=0)).sum()) if len(positions) >= 2 else 0.0


@dataclass(frozen=True)
class RouteSettings:
    """How moves are routed. ``via_poses``: how many of the given via configurations (the shortest detours) are
    tried; ``orbit_*``: the moves around the sphere (retract distances m, extra radii m, lifts deg); the velocity
    scaling of every move and OMPL's time budget per attempt (s)."""

    velocity_scaling: float = 1.0
    planning_time_s: float = 0.2
    connect_attempts: int = 3
    via_poses: int = 8
    orbit_retract_m: tuple[float, ...] = ()
    orbit_radius_extra_m: tuple[float, ...] = ()
    orbit_lift_deg: tuple[float, ...] = ()


class Router:
    """Routes joint moves (see the module docstring). ``planner_factory``: returns the OMPL planner (None: no
    OMPL); ``arm`` and ``look_poses(centre, direction, radius_m) -> (K, 4, 4)`` are needed only for the moves
    around a sphere."""

    def __init__(
        self,
        checker,
        limits,
        planner_factory: Callable | None = None,
        settings: RouteSettings | None = None,
        arm=None,
        look_poses: Callable | None = None,
    ):
        self.checker = checker
        self.limits = limits
        self.planner_factory = planner_factory
        self.settings = settings or RouteSettings()
        self.arm = arm
        self.look_poses = look_poses
        self._planner = None

    def planner(self):
        """The OMPL planner, built on first use (None without a factory)."""
        if self._planner is None and self.planner_factory is not None:
            self._planner = self.planner_factory()
        return self._planner

    def connect(
        self, q_from: np.ndarray, q_to: np.ndarray, planning_time_s: float | None = None, attempts: int | None = None
    ):
        """A collision-free trajectory: the straight joint move when it is free, else OMPL; None when neither.
        ``planning_time_s`` (OMPL's first budget, s) and ``attempts`` override the settings for this move."""
        return collision_free_trajectory(
            q_from,
            q_to,
            self.limits,
            self.checker,
            planner=self.planner,
            velocity_scaling=self.settings.velocity_scaling,
            planning_time_s=self.settings.planning_time_s if planning_time_s is None else planning_time_s,
            attempts=self.settings.connect_attempts if attempts is None else attempts,
        )

    def route(self, q_from: np.ndarray, q_to: np.ndarray, vias=(), centre: np.ndarray | None = None):
        """A collision-free trajectory or None: the straight move when it is free; otherwise the shorter (joint path,
        rad) of OMPL's path and a straight move through a via configuration of ``vias`` or around the sphere about
        ``centre`` (:meth:`via_path`)."""
        settings = self.settings
        straight = collision_free_trajectory(q_from, q_to, self.limits, self.checker, planner=None,
                                             velocity_scaling=settings.velocity_scaling)  # fmt: skip
        if straight is not None:
            return straight
        via = self.via_path(q_from, q_to, vias, centre)
        direct_rad = float(np.abs(np.asarray(q_to) - np.asarray(q_from)).sum())
        if via is not None and via[1] <= VIA_ACCEPT_RATIO * direct_rad:
            return via[0]
        planned = collision_free_trajectory(
            q_from,
            q_to,
            self.limits,
            self.checker,
            planner=self.planner,
            velocity_scaling=settings.velocity_scaling,
            planning_time_s=settings.planning_time_s,
            attempts=ROUTE_OMPL_ATTEMPTS,
            straight_first=False,
        )
        if via is None:
            return planned
        if planned is None:
            return via[0]
        return via[0] if via[1] < path_length_rad(planned) else planned

    def via_path(self, q_from: np.ndarray, q_to: np.ndarray, vias=(), centre: np.ndarray | None = None):
        """(trajectory, joint path rad) of the shortest free straight move through via configurations, or None:
        the ``via_poses`` shortest detours through ``vias`` and every move of :meth:`orbit_waypoints`, shortest
        first."""
        q_from, q_to = np.asarray(q_from, dtype=float), np.asarray(q_to, dtype=float)
        vias = np.asarray(vias, dtype=float).reshape(-1, len(q_from))
        lengths = np.abs(vias - q_from).sum(axis=1) + np.abs(q_to - vias).sum(axis=1)
        count = max(self.settings.via_poses, 0)
        routes = [np.asarray([q_from, vias[i], q_to]) for i in np.argsort(lengths, kind="stable")[:count]]
        if centre is not None:
            routes += self.orbit_waypoints(q_from, q_to, centre)
        routes.sort(key=lambda w: float(np.abs(np.diff(w, axis=0)).sum()))
        for waypoints in routes:
            if not self.checker.check_states(interpolate_path(waypoints, VIA_CHECK_STEP_RAD)).all():
                continue
            trajectory = path_trajectory(waypoints, self.limits, self.settings.velocity_scaling)
            samples, _, _ = trajectory.sample(trajectory.dense_times(step_s=0.02, per_segment=2))
            if self.checker.check_states(samples).all():
                return trajectory, path_length_rad(trajectory)
        return None

    def orbit_waypoints(self, q_from: np.ndarray, q_to: np.ndarray, centre: np.ndarray) -> list[np.ndarray]:
        """Joint waypoints (rad) of moves around the sphere about ``centre`` rather than through it:

        - retract the sensor along its optical axis by each of ``orbit_retract_m``, move, approach;
        - pass one pose on the great circle between the two views (directions seen from the centre) at its
          middle, or two at its thirds, at the larger standoff plus each of ``orbit_radius_extra_m``, also
          raised by each of ``orbit_lift_deg``, looking at the centre (the middle pose at each roll of
          ``look_poses``, the thirds at the roll whose joints are nearest the joint interpolation there).

        IK is taken nearest the move's ends, resp. the joint interpolation at the pose's place on the move;
        unreachable poses are left out."""
        settings = self.settings
        arm = self.arm
        ends = np.asarray([q_from, q_to], dtype=float)
        pose_a, pose_b = arm.sensor_pose(ends)
        routes = []
        for d in settings.orbit_retract_m:
            retracted = np.array([pose_a, pose_b])
            retracted[:, :3, 3] -= d * retracted[:, :3, 2]
            q, ok = arm.ik.solve_nearest(retracted, ends)
            if np.all(ok):
                routes.append(np.asarray([q_from, q[0], q[1], q_to]))
        centre = np.asarray(centre, dtype=float)
        offsets = np.array([pose_a[:3, 3] - centre, pose_b[:3, 3] - centre])
        radii = np.linalg.norm(offsets, axis=1)
        if not settings.orbit_radius_extra_m or np.any(radii < 1e-6):
            return routes
        u_a, u_b = offsets / radii[:, None]
        for extra in settings.orbit_radius_extra_m:
            radius = float(radii.max()) + extra
            for lift in (0.0, *settings.orbit_lift_deg):

                def around(t, lift=lift, radius=radius):
                    direction = raise_elevation(slerp_unit(u_a, u_b, t), math.radians(lift))
                    return self.orbit_joints(centre, direction, radius, (1 - t) * ends[0] + t * ends[1])

                routes += [np.asarray([q_from, q, q_to]) for q in around(0.5)]
                first, second = around(1.0 / 3.0), around(2.0 / 3.0)
                if first and second:
                    routes.append(np.asarray([q_from, first[0], second[0], q_to]))
        return routes

    def orbit_joints(self, centre: np.ndarray, direction: np.ndarray, radius_m: float, seed: np.ndarray) -> list:
        """Joints (rad) of the sensor at ``centre + radius * direction`` looking at the centre, one per pose of
        ``look_poses``, each the IK solution nearest ``seed``, nearest first (L1); the unreachable ones are left
        out."""
        poses = self.look_poses(centre, direction, radius_m)
        q, ok = self.arm.ik.solve_nearest(poses, np.broadcast_to(seed, (len(poses), 6)))
        q = q[ok]
        return list(q[np.argsort(np.abs(q - seed).sum(axis=1), kind="stable")])
