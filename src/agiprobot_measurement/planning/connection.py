"""Connection moves: collision-free, time-parameterised joint motions between two states of the station's robot.

:class:`ConnectionPlanner` is the motion layer put together for one job (a collision checker, the joint limits,
an OMPL planner set up only when a straight move is blocked) over :class:`~agiprobot_measurement.motion.routing.Router`,
the router NBV moves with too: the planning run connects its views with it and a session adapts a stored plan's start
with it, without building a whole planning run. Joint values are rad, times s.
"""

from __future__ import annotations

import numpy as np

from agiprobot_measurement.motion.collision import CollisionChecker
from agiprobot_measurement.motion.ik import make_ik_solver
from agiprobot_measurement.motion.kinematics import KinematicModel
from agiprobot_measurement.motion.motion_planning import MotionPlanner
from agiprobot_measurement.motion.routing import Router, RouteSettings
from agiprobot_measurement.motion.trajectory import JointTrajectory
from agiprobot_measurement.planning.part_loading import load_part
from agiprobot_measurement.planning.plan.execution import PlanPart
from agiprobot_measurement.station import Station

__all__ = ["DEFAULT_PLANNER", "ConnectionPlanner", "add_plan_part", "station_robot"]

#: the OMPL planner of connection moves
DEFAULT_PLANNER = "RRTConnect"


def station_robot(station: Station) -> tuple[KinematicModel, object, CollisionChecker]:
    """The station's robot: its kinematic model, IK solver and collision world (without a part)."""
    kinematics = KinematicModel.from_station(station)
    collision = CollisionChecker.from_station(station, model=kinematics, load_part=False)
    return kinematics, make_ik_solver(kinematics), collision


def add_plan_part(collision: CollisionChecker, part: PlanPart) -> None:
    """Put a stored plan's ``part`` into ``collision``'s world, as placed in the plan (downward faces kept)."""
    loaded = load_part(part.mesh_file, units=part.units, transform=part.file_units_placement, remove_downside=False)
    collision.set_part(loaded.mesh, name="part", scale_to_m=1e-3)


class ConnectionPlanner:
    """Plans connection moves in the world of ``collision`` within ``limits``.

    :param collision: the :class:`~agiprobot_measurement.motion.collision.CollisionChecker` (robot, scene, part).
    :param limits: the station's joint limits.
    :param planner_name: the OMPL planner used when the straight move is blocked.
    :param seed: seeds OMPL, so moves are reproducible.
    :param planning_time_s: the first attempt's time budget; :param attempts: attempts, each with twice the time.
    """

    def __init__(
        self,
        collision: CollisionChecker,
        limits,
        planner_name: str = DEFAULT_PLANNER,
        seed: int = 0,
        planning_time_s: float = 1.0,
        attempts: int = 3,
    ):
        self.collision = collision
        self.limits = limits
        self.planner_name = planner_name
        self.seed = int(seed)
        self.planning_time_s = float(planning_time_s)
        self.attempts = int(attempts)
        settings = RouteSettings(planning_time_s=self.planning_time_s, connect_attempts=self.attempts)
        self.router = Router(collision, limits, self._make_planner, settings)

    @classmethod
    def for_station(cls, station: Station, part: PlanPart | None = None, **settings) -> ConnectionPlanner:
        """A planner in ``station``'s world, with a stored plan's ``part`` (as placed in the plan, downward faces
        kept) in it when given."""
        _, _, collision = station_robot(station)
        if part is not None:
            add_plan_part(collision, part)
        return cls(collision, station.limits, **settings)

    def _make_planner(self) -> MotionPlanner:
        # OMPL refuses the seed 0 (and says so on every call): seeds count from 1 there
        return MotionPlanner(self.collision, planner=self.planner_name, seed=self.seed + 1)

    @property
    def planner(self) -> MotionPlanner:
        """The OMPL planner (set up on first use)."""
        return self.router.planner()

    def connect(
        self, q_from: np.ndarray, q_to: np.ndarray, planning_time_s: float | None = None, attempts: int | None = None
    ) -> JointTrajectory | None:
        """The collision-free, time-parameterised move from ``q_from`` to ``q_to`` (rad), or None: the straight
        joint move when it is free, else OMPL with a bounded number of attempts."""
        return self.router.connect(q_from, q_to, planning_time_s, attempts)
