"""The station's robot behind ``TrajectoryManager.execute`` when a user's script runs inside a ROS process.

The original ``TrajectoryManager.execute(execution_list, surface_points)`` drove the robot through MoveIt, switched
the scanner's stitching on for measurement segments only, and, when executing views with ``surface_points``
given, published the points each view measures as a latched ``sensor_msgs/PointCloud`` (frame ``world``, m) on
``/currently_measured_points``. :func:`station_executor` gives the same through this project's station: the robot's
motion client (:mod:`.robot_client`: control_msgs/FollowJointTrajectory on
``/scaled_pos_joint_traj_controller/follow_joint_trajectory``, a UR driver's or the simulator's, or MoveIt's
``/execute_trajectory``) and the laser scanner's stitcher (``/switch_stitch_mode``; extras under ``/laser_scanner``).
:mod:`agiprobot_measurement.ros.plugins` registers it with the core's executor registry; the core asks for it only in
a process where ``rospy`` is initialised.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import rospy
from sensor_msgs.msg import PointCloud
from std_msgs.msg import Header

from agiprobot_measurement.planning.plan.execution import ExecutionError, PlanPart
from agiprobot_measurement.ros.conversions import xyz_point_cloud
from agiprobot_measurement.ros.executor import ControllerWatch, RosSegmentExecutor
from agiprobot_measurement.ros.joint_states import JointStateCache
from agiprobot_measurement.ros.params import file_param
from agiprobot_measurement.ros.robot_client import MotionSettings, make_motion_client, read_motion_settings
from agiprobot_measurement.ros.scanner_client import ScannerClient
from agiprobot_measurement.station import load_joint_limits

__all__ = ["MEASURED_POINTS_TOPIC", "station_executor"]

MEASURED_POINTS_TOPIC = "/currently_measured_points"
#: the trajectory_manager node's namespace, whose parameters a script's executor shares
MANAGER = "/trajectory_manager/"


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
    executor: str | None = None,
) -> RosSegmentExecutor | None:
    """An executor on the running station, or None when no controller answers within ``wait_s`` (s).

    ``surface_points_mm``: the sampled surface points ((N, 3) or a list of 3-vectors, mm); when given, each
    view's measurable points are published while it is measured. ``part``: put into the simulated scanner's
    scene first (the real scanner sees the real part). ``executor`` ('follow_joint_trajectory' or 'moveit'),
    ``controller_action`` ('' = the executor's action) and ``scanner_namespace`` default to the trajectory_manager
    node's parameters (``/trajectory_manager/executor``, ``controller_action``, ``scanner_namespace``) or the
    defaults; the joint limits the client checks against are ``/trajectory_manager/joint_limits`` or the package's.
    """
    shared = read_motion_settings(MANAGER)
    settings = MotionSettings(executor or shared.executor, controller_action or shared.controller_action)
    scanner_namespace = scanner_namespace or rospy.get_param(f"{MANAGER}scanner_namespace", "/laser_scanner")
    limits = load_joint_limits(file_param(f"{MANAGER}joint_limits"), tuple(joint_names))
    joint_states = JointStateCache(list(joint_names))
    robot = make_motion_client(settings, limits, joint_states.latest)
    if not robot.wait_for_server(wait_s):
        joint_states.unregister()
        return None
    if joint_states.wait(wait_s) is None:
        raise ExecutionError(f"the controller {robot.action} answers, but no {joint_states.topic} arrive")
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
