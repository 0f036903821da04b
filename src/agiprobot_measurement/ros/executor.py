"""Executing a plan in ROS: the robot's motion client (:mod:`.robot_client`) and the scanner (:mod:`.scanner_client`)
behind the core's executor interface (:class:`~agiprobot_measurement.planning.plan.execution.SegmentExecutor`).

:class:`RosSegmentExecutor` runs one segment through the motion client (control_msgs/FollowJointTrajectory or
MoveIt's ExecuteTrajectory), switches stitching on for measurement segments only and cancels the robot when
the caller asks. :class:`ControllerWatch` tells whether the controller is alive (its ``/joint_states``
heartbeat and its action server's status connection); a segment whose controller dies ends within
``heartbeat_timeout_s`` + a poll with :class:`~agiprobot_measurement.planning.plan.execution.ControllerLost`.
Points are mm in the core and m on the wire.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

import numpy as np
import rospy

from agiprobot_measurement.motion.trajectory import JointTrajectory
from agiprobot_measurement.planning.plan.execution import ControllerLost
from agiprobot_measurement.ros.joint_states import JointStateCache
from agiprobot_measurement.ros.robot_client import RobotMotionClient
from agiprobot_measurement.ros.scanner_client import ScannerClient, ScannerError

__all__ = ["ControllerWatch", "RosSegmentExecutor"]


class ControllerWatch:
    """Whether the robot controller is alive: a ``/joint_states`` message (``joint_states``) younger than
    ``heartbeat_timeout_s`` (ROS time) and a live connection to the status topic of its action server
    (``robot``: a :class:`~agiprobot_measurement.ros.robot_client.RobotMotionClient`), which drops as soon as the
    controller's process dies."""

    def __init__(self, joint_states: JointStateCache, robot: RobotMotionClient, heartbeat_timeout_s: float = 1.0):
        self.joint_states = joint_states
        self.robot = robot
        self.heartbeat_timeout_s = float(heartbeat_timeout_s)

    def problem(self) -> str:
        """'' while the controller is alive, else what is missing."""
        stamp = self.joint_states.latest_stamp()
        if stamp is None:
            return f"no {self.joint_states.topic} received yet"
        age_s = (rospy.Time.now() - stamp).to_sec()
        if age_s > self.heartbeat_timeout_s:
            return f"no {self.joint_states.topic} for {age_s:.1f} s"
        if not self.robot.server_connected():
            return "its action server's status topic has no publisher (the controller's process is gone)"
        return ""


class RosSegmentExecutor:
    """Runs plan segments through the robot's motion client (``robot``: a
    :class:`~agiprobot_measurement.ros.robot_client.RobotMotionClient`, which checks each segment's start and limits
    before sending it). ``current_state()`` gives the robot's joint state (rad); ``cancel_requested()`` is
    polled while a segment runs; ``on_measure(view or None, active)`` hears of each measurement segment's start
    and end (the node shows the points it measures)."""

    def __init__(
        self,
        robot: RobotMotionClient,
        scanner: ScannerClient,
        current_state: Callable[[], np.ndarray],
        cancel_requested: Callable[[], bool],
        on_measure: Callable[[object, bool], None] | None = None,
        controller_problem: Callable[[], str] | None = None,
    ):
        self.robot = robot
        self.scanner = scanner
        self._current_state = current_state
        self.cancel_requested = cancel_requested
        self.on_measure = on_measure
        self.controller_problem = controller_problem or (lambda: "")

    def _stitching(self, on: bool) -> None:
        try:
            self.scanner.set_stitching(on)
        except (rospy.ROSException, rospy.ServiceException) as exc:
            raise ScannerError(f"scanner: cannot switch stitching {'on' if on else 'off'}: {exc}") from exc

    def current_state(self) -> np.ndarray:
        return self._current_state()

    def execute_segment(self, trajectory: JointTrajectory, kind: str, viewpoint=None) -> None:
        measuring = kind == "measure"
        problem = self.controller_problem()
        if problem:
            raise ControllerLost(problem)
        if measuring:
            self._stitching(True)
            if self.on_measure is not None:
                self.on_measure(viewpoint, True)
        lost = False
        try:
            self._run(trajectory)
        except ControllerLost:
            lost = True
            raise
        finally:
            if measuring:
                if lost:  # the abort must not wait for the scanner to settle without a robot: stop it meanwhile
                    threading.Thread(target=self._stop_stitching, daemon=True).start()
                else:
                    self._stop_stitching()
                if self.on_measure is not None:
                    self.on_measure(viewpoint, False)

    def _stop_stitching(self) -> None:
        try:
            self._stitching(False)
        except ScannerError as exc:  # the segment's own outcome matters more; the caller stops the scanner again
            rospy.logwarn("trajectory_manager: %s", exc)

    def _run(self, trajectory: JointTrajectory) -> None:
        self.robot.execute(trajectory, self.cancel_requested, self.controller_problem)
