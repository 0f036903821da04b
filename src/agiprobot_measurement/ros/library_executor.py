"""The station's robot behind ``TrajectoryManager.execute`` when a user's script runs inside a ROS process.

The original ``TrajectoryManager.execute(execution_list, surface_points)`` drove the robot through MoveIt, switched
the scanner's stitching on for measurement segments only, and, when executing views with ``surface_points``
given, published the points each view measures as a latched ``sensor_msgs/PointCloud`` (frame ``world``, m) on
``/currently_measured_points``. :func:`station_executor` gives the same through this project's station: the
simulated controller's ExecuteJointTrajectory action (``/robot_sim/execute_trajectory``) and the laser scanner's
stitcher (``/switch_stitch_mode``; extras under ``/laser_scanner``). :mod:`agiprobot_measurement.ros.plugins`
registers it with the core's executor registry; the core asks for it only in a process where ``rospy`` is initialised.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import rospy
from sensor_msgs.msg import PointCloud
from std_msgs.msg import Header

from agiprobot_measurement.msg import ExecuteJointTrajectoryAction
from agiprobot_measurement.planning.plan.execution import ExecutionError, PlanPart
from agiprobot_measurement.ros.action_client import ActionClient
from agiprobot_measurement.ros.conversions import xyz_point_cloud
from agiprobot_measurement.ros.executor import ControllerWatch, RosSegmentExecutor
from agiprobot_measurement.ros.joint_states import JointStateCache
from agiprobot_measurement.ros.scanner_client import ScannerClient

__all__ = ["MEASURED_POINTS_TOPIC", "station_executor"]

MEASURED_POINTS_TOPIC = "/currently_measured_points"


class _NoScanner:
    """Stands for an absent scanner node: the robot still moves, nothing is stitched (a warning says so)."""

    def set_stitching(self, on: bool) -> int:
        return 0


def _measured_points_publisher(surface_points_mm: np.ndarray | None):
    if surface_points_mm is None:
        return None
    publisher = rospy.Publisher(MEASURED_POINTS_TOPIC, PointCloud, queue_size=1, latch=True)

    def on_measure(view, active: bool) -> None:
        if view is None or not active:
            return
        indices = np.asarray(view.measurable_indices, dtype=int)
        points_m = surface_points_mm[indices[(indices >= 0) & (indices < len(surface_points_mm))]] / 1000.0
        publisher.publish(xyz_point_cloud(points_m, Header(stamp=rospy.Time.now(), frame_id="world")))

    return on_measure


def station_executor(
    joint_names: Sequence[str],
    surface_points_mm=None,
    part: PlanPart | None = None,
    controller_action: str | None = None,
    scanner_namespace: str | None = None,
    wait_s: float = 2.0,
) -> RosSegmentExecutor | None:
    """An executor on the running station, or None when no controller answers within ``wait_s`` (s).

    ``surface_points_mm``: the sampled surface points ((N, 3) or a list of 3-vectors, mm); when given, each
    view's measurable points are published while it is measured. ``part``: put into the simulated scanner's
    scene first (the real scanner sees the real part). ``controller_action`` / ``scanner_namespace`` default to
    the ROS parameters ``/trajectory_manager/controller_action`` / ``scanner_namespace`` or the station's names.
    """
    controller_action = controller_action or rospy.get_param(
        "/trajectory_manager/controller_action", "/robot_sim/execute_trajectory"
    )
    scanner_namespace = scanner_namespace or rospy.get_param("/trajectory_manager/scanner_namespace", "/laser_scanner")
    robot = ActionClient(controller_action, ExecuteJointTrajectoryAction)
    if not robot.wait_for_server(rospy.Duration(wait_s)):
        return None
    joint_states = JointStateCache(list(joint_names))
    if joint_states.wait(wait_s) is None:
        raise ExecutionError(f"the controller {controller_action} answers, but no {joint_states.topic} arrive")
    scanner = ScannerClient(scanner_namespace, service_timeout_s=wait_s)
    try:
        scanner.wait_for_stitcher(wait_s)
        if part is not None:
            scanner.set_target(part)
    except rospy.ROSException:
        rospy.logwarn("execute: no scanner at %s: the robot moves, nothing is measured", scanner_namespace)
        scanner = _NoScanner()
    surface = None if surface_points_mm is None else np.asarray(surface_points_mm, dtype=float).reshape(-1, 3)
    return RosSegmentExecutor(
        robot,
        scanner,
        current_state=joint_states.latest,
        cancel_requested=rospy.is_shutdown,
        on_measure=_measured_points_publisher(surface),
        controller_problem=ControllerWatch(joint_states, robot).problem,
    )
