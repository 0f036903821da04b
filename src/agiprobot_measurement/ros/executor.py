"""Executing a plan in ROS: the robot controller's action and the scanner (:mod:`.scanner_client`) behind the core's
executor interface (:class:`~agiprobot_measurement.planning.plan.execution.SegmentExecutor`).

:class:`RosSegmentExecutor` runs one segment through the controller's
ExecuteJointTrajectory action, switches stitching on for measurement segments only and cancels the robot when
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
from actionlib_msgs.msg import GoalStatus

from agiprobot_measurement.motion.trajectory import JointTrajectory
from agiprobot_measurement.msg import ExecuteJointTrajectoryGoal
from agiprobot_measurement.planning.plan.execution import ControllerLost, ExecutionCancelled, ExecutionError
from agiprobot_measurement.ros.conversions import joint_trajectory_to_msg
from agiprobot_measurement.ros.joint_states import JointStateCache
from agiprobot_measurement.ros.scanner_client import ScannerClient, ScannerError

__all__ = ["ControllerWatch", "RosSegmentExecutor"]


class ControllerWatch:
    """Whether the robot controller is alive: a ``/joint_states`` message (``joint_states``) younger than
    ``heartbeat_timeout_s`` (ROS time) and a live connection to the status topic of its action server
    (``robot``: an actionlib SimpleActionClient), which drops as soon as the controller's process dies."""

    def __init__(self, joint_states: JointStateCache, robot, heartbeat_timeout_s: float = 1.0):
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
        status = getattr(getattr(self.robot, "action_client", None), "status_sub", None)
        if status is not None and status.get_num_connections() == 0:
            return "its action server's status topic has no publisher (the controller's process is gone)"
        return ""


class RosSegmentExecutor:
    """Runs plan segments through the controller's action (``robot``: an ActionClient of
    ExecuteJointTrajectory). ``current_state()`` gives the robot's joint state (rad); ``cancel_requested()`` is
    polled while a segment runs; ``on_measure(view or None, active)`` hears of each measurement segment's start
    and end (the node shows the points it measures)."""

    def __init__(
        self,
        robot,
        scanner: ScannerClient,
        current_state: Callable[[], np.ndarray],
        cancel_requested: Callable[[], bool],
        on_measure: Callable[[object, bool], None] | None = None,
        poll_s: float = 0.05,
        controller_problem: Callable[[], str] | None = None,
    ):
        self.robot = robot
        self.scanner = scanner
        self._current_state = current_state
        self.cancel_requested = cancel_requested
        self.on_measure = on_measure
        self.poll_s = poll_s
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
        self.robot.send_goal(ExecuteJointTrajectoryGoal(trajectory=joint_trajectory_to_msg(trajectory)))
        while not self.robot.wait_for_result(rospy.Duration(self.poll_s)):
            if self.cancel_requested() or rospy.is_shutdown():
                self.robot.cancel_goal()
                self.robot.wait_for_result(rospy.Duration(2.0))
                raise ExecutionCancelled("cancelled; robot stopped")
            problem = self.controller_problem()
            if problem:
                self.robot.cancel_goal()  # a controller that only stalled must not go on moving
                raise ControllerLost(problem)
        state, result = self.robot.get_state(), self.robot.get_result()
        if state != GoalStatus.SUCCEEDED or result is None or not result.success:
            raise ExecutionError(result.error if result is not None and result.error else f"controller state {state}")
