"""The ROS layer's plugins for the core: importing this module registers them.

- the station executor (:func:`agiprobot_measurement.ros.library_executor.station_executor`) under
  :data:`agiprobot_measurement.planning.plan.executors.STATION`, so ``TrajectoryManager.execute`` drives the
  running station's controller from a script that called ``rospy.init_node`` (the original drove the robot
  through MoveIt). Outside an initialised ROS process the factory gives None and the core simulates.

A script written against the original imports this module next to ``rospy``; the nodes hand their executors to
the session explicitly and need not.
"""

from __future__ import annotations

from collections.abc import Sequence

import rospy

from agiprobot_measurement.planning.plan import executors
from agiprobot_measurement.planning.plan.execution import PlanPart
from agiprobot_measurement.ros.library_executor import station_executor

__all__ = ["in_ros_process", "station_if_running"]


def in_ros_process() -> bool:
    """Whether this process is a ROS node (``rospy.init_node`` was called)."""
    return bool(rospy.core.is_initialized())


def station_if_running(joint_names: Sequence[str], surface_points_mm=None, part: PlanPart | None = None):
    """The running station's executor, or None when this is not a ROS process or no controller answers."""
    if not in_ros_process():
        return None
    return station_executor(joint_names, surface_points_mm=surface_points_mm, part=part)


executors.register(executors.STATION, station_if_running)
