"""Moving the bare flange for the calibration: pose solutions, the straight-or-planned joint motion, the robot.

:class:`PlannedFlangeRobot` is the :class:`~agiprobot_measurement.calibration.interfaces.FlangeRobot` over any
:class:`~agiprobot_measurement.calibration.interfaces.JointDriver` (ROS action or simulation): the flange pose at a
point, facing the configured point (optionally any turn about the flange axis, the bare flange being round), solved by
IK nearest to the current state, checked for collisions, and reached straight in joint space when that path is free,
else along a path planned around the obstacles. Metres and rad throughout.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from agiprobot_measurement.calibration.config import tool_rotation
from agiprobot_measurement.calibration.interfaces import JointDriver, UnreachableError
from agiprobot_measurement.motion.collision import CollisionChecker
from agiprobot_measurement.motion.kinematics import KinematicModel
from agiprobot_measurement.motion.motion_planning import MotionPlanner, collision_free_trajectory
from agiprobot_measurement.motion.point_to_point import point_to_point
from agiprobot_measurement.motion.trajectory import JointTrajectory

__all__ = [
    "FREE_YAW_STEP_DEG",
    "PlannedFlangeRobot",
    "flange_collision_checker",
    "flange_pose_solutions",
    "joint_motion",
    "nearest_solution",
]

#: turns about the flange axis tried when any will do
FREE_YAW_STEP_DEG = 30.0


def flange_pose_solutions(position_m: np.ndarray, z_towards_m: np.ndarray, free_yaw: bool = False) -> np.ndarray:
    """tool0 poses (K, 4, 4) at ``position_m`` with z towards ``z_towards_m``: one, or with ``free_yaw`` one per
    turn about the flange axis in steps of :data:`FREE_YAW_STEP_DEG`."""
    rotation = tool_rotation(z_towards_m, position_m)
    turns = np.radians(np.arange(0.0, 360.0, FREE_YAW_STEP_DEG)) if free_yaw else np.zeros(1)
    poses = np.repeat(np.eye(4)[None], len(turns), axis=0)
    for pose, turn in zip(poses, turns, strict=True):
        c, s = np.cos(turn), np.sin(turn)
        pose[:3, :3] = rotation @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        pose[:3, 3] = position_m
    return poses


def nearest_solution(ik, poses: np.ndarray, start_rad: np.ndarray, collision=None, what: str = "pose") -> np.ndarray:
    """The IK solution of one of ``poses`` closest to ``start_rad`` (largest joint step); with ``collision`` only
    collision-free ones count. :class:`UnreachableError` when none is left."""
    count = len(poses)
    solutions, ok = ik.solve_nearest(poses, np.repeat(np.asarray(start_rad)[None], count, axis=0))
    solutions = np.asarray(solutions).reshape(count, -1)
    ok = np.asarray(ok).reshape(-1).astype(bool)
    position = np.round(poses[0][:3, 3], 3).tolist()
    if not ok.any():
        raise UnreachableError(f"no IK solution for {position}")
    if collision is not None:
        ok[ok] = collision.check_states(solutions[ok])
        if not ok.any():
            raise UnreachableError(f"{what} at {position}: every turn of the flange collides")
    candidates = np.flatnonzero(ok)
    return solutions[candidates[np.argmin(np.abs(solutions[candidates] - start_rad).max(axis=1))]]


def joint_motion(
    start_rad: np.ndarray,
    goal_rad: np.ndarray,
    limits,
    velocity_scaling: float,
    collision=None,
    planner: Callable | None = None,
    what: str = "goal",
    planning_time_s: float = 0.5,
) -> JointTrajectory:
    """The trajectory from ``start_rad`` to ``goal_rad``: without ``collision`` the straight point-to-point move;
    with it the straight move when its whole path is free, else planned around the obstacles (``planner``: a
    function returning a MotionPlanner). :class:`UnreachableError` when the goal collides or no path is found."""
    if collision is None:
        return point_to_point(start_rad, goal_rad, limits, velocity_scaling, velocity_scaling)
    problem = collision.explain(goal_rad)
    if problem:
        raise UnreachableError(f"{what}: {problem}")
    trajectory = collision_free_trajectory(
        start_rad,
        goal_rad,
        limits,
        collision,
        planner,
        velocity_scaling=velocity_scaling,
        planning_time_s=planning_time_s,
    )
    if trajectory is None:
        raise UnreachableError(f"{what}: no collision-free motion from the current state")
    return trajectory


def flange_collision_checker(station):
    """The collision checker of a flange station (:func:`~agiprobot_measurement.calibration.config.flange_station`):
    robot, scene obstacles, no part; the disc may touch wrist_3_link, on which it sits."""
    model = KinematicModel.from_station(station, tip_frame="tool0")
    collision = CollisionChecker.from_station(station, model=model, load_part=False)
    collision.allow_collision("wrist_3_link", "flange_disc_link", "Adjacent")
    return collision


class PlannedFlangeRobot:
    """:class:`~agiprobot_measurement.calibration.interfaces.FlangeRobot` over a joint driver.

    ``kinematics``: tool0 in the robot base frame; ``ik``: its solver (``solve_nearest``); ``limits``: the joint
    limits; ``tool_z_towards_m``: where tool0's z axis points by default (base frame, metres); ``collision``: a
    collision checker or None (no checks, straight moves); ``velocity_scaling`` of the joint limits.
    """

    def __init__(
        self,
        driver: JointDriver,
        kinematics,
        ik,
        limits,
        tool_z_towards_m,
        collision=None,
        velocity_scaling: float = 0.3,
        planner_seed: int = 1,
    ):
        self.driver = driver
        self.kinematics = kinematics
        self.ik = ik
        self.limits = limits
        self.tool_z_towards_m = np.asarray(tool_z_towards_m, dtype=float)
        self.collision = collision
        self.velocity_scaling = float(velocity_scaling)
        self.planner_seed = planner_seed
        self._planner = None

    @property
    def joint_names(self) -> list[str]:
        return list(self.limits.names)

    def planner(self):
        """The motion planner, built at the first blocked straight move (OMPL setup takes a while)."""
        if self._planner is None:
            self._planner = MotionPlanner(self.collision, seed=self.planner_seed)
        return self._planner

    def current_joints(self) -> np.ndarray:
        return self.driver.current_joints()

    def flange_position(self, joints_rad: np.ndarray) -> np.ndarray:
        return np.asarray(self.kinematics.fk(np.asarray(joints_rad, dtype=float)))[:3, 3]

    def plan(self, goal_rad: np.ndarray, what: str = "goal") -> JointTrajectory:
        """The motion from the current joint state to ``goal_rad`` (:func:`joint_motion`)."""
        return joint_motion(
            self.current_joints(),
            goal_rad,
            self.limits,
            self.velocity_scaling,
            self.collision,
            self.planner,
            what,
        )

    def move_to_joints(self, joints_rad: np.ndarray, what: str, settle_s: float = 0.3) -> None:
        self.driver.execute(self.plan(np.asarray(joints_rad, dtype=float), what), settle_s)

    def move_to(
        self, position_m: np.ndarray, z_towards_m=None, settle_s: float = 0.3, free_yaw: bool = False
    ) -> np.ndarray:
        towards = self.tool_z_towards_m if z_towards_m is None else z_towards_m
        poses = flange_pose_solutions(position_m, towards, free_yaw)
        what = f"pose at {np.round(position_m, 3).tolist()}"
        q = nearest_solution(self.ik, poses, self.current_joints(), self.collision if free_yaw else None, "pose")
        self.move_to_joints(q, what, settle_s)
        return q
