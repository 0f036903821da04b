"""The ``robot_sim`` node: the simulated robot controller (``motion.controller_sim``) on ROS.

Publishes ``/joint_states`` at ``~publish_rate_hz`` and executes joint trajectories through the action
``~execute_trajectory`` (agiprobot_measurement/ExecuteJointTrajectory): the goal's trajectory is checked (joint
names, finite values, strictly increasing time, start at the current state, position / velocity / acceleration
limits of the interpolated motion) and rejected with the reason in the result, or followed in (ROS, so also
simulated) time with the controller's cubic interpolation. Cancel stops the robot where it is. Service
``~set_joint_state`` places the robot at once (simulation only).

Parameters: ~robot_config (config/ur10e.yaml), ~joint_limits (config/joint_limits.yaml),
~named_states (config/named_states.yaml), ~initial_state (a named state or a list, default "home"),
~publish_rate_hz (100), ~start_tolerance_rad (0.01), ~velocity_tolerance_fraction (0.01),
~acceleration_tolerance_fraction (0.05).
"""

from __future__ import annotations

from collections.abc import Sequence

import actionlib
import numpy as np
import rospy
from sensor_msgs.msg import JointState

from agiprobot_measurement.common.config import number
from agiprobot_measurement.errors import AgiprobotError, InputError
from agiprobot_measurement.motion.controller_sim import (
    ExecutionOutcome,
    ExecutionStatus,
    SimulatedController,
    resolve_initial_state,
)
from agiprobot_measurement.motion.trajectory import CheckTolerances, JointTrajectory, TrajectoryError
from agiprobot_measurement.msg import (
    ExecuteJointTrajectoryAction,
    ExecuteJointTrajectoryFeedback,
    ExecuteJointTrajectoryResult,
)
from agiprobot_measurement.ros.node import run_node
from agiprobot_measurement.ros.params import Param, read_params
from agiprobot_measurement.srv import SetJointState, SetJointStateResponse
from agiprobot_measurement.station import load_joint_limits, load_named_states, load_robot_config

__all__ = [
    "RobotSimNode",
    "RosClock",
    "main",
]


class RosClock:
    """ROS time for the controller (simulated time under ``use_sim_time``)."""

    def now_s(self) -> float:
        return rospy.Time.now().to_sec()

    def is_shutdown(self) -> bool:
        return rospy.is_shutdown()

    def rate(self, rate_hz: float) -> rospy.Rate:
        return rospy.Rate(rate_hz)


class _JointStateTopic:
    def __init__(self, topic: str):
        self.publisher = rospy.Publisher(topic, JointState, queue_size=10)

    def publish_joint_state(
        self, joint_names: Sequence[str], positions_rad: Sequence[float], velocities_rad_s: Sequence[float]
    ) -> None:
        msg = JointState()
        msg.header.stamp = rospy.Time.now()
        msg.name = list(joint_names)
        msg.position = list(positions_rad)
        msg.velocity = list(velocities_rad_s)
        self.publisher.publish(msg)


class _ActionGoal:
    """The action server as the controller's goal channel."""

    def __init__(self, server: actionlib.SimpleActionServer):
        self.server = server
        self.feedback = ExecuteJointTrajectoryFeedback()

    def is_cancel_requested(self) -> bool:
        return self.server.is_preempt_requested()

    def publish_feedback(self, progress: float, time_from_start_s: float) -> None:
        self.feedback.progress, self.feedback.time_from_start = progress, time_from_start_s
        self.server.publish_feedback(self.feedback)


#: the node's parameters (name, default, validator), read once at start
PARAMETERS = (
    Param("~robot_config", None),
    Param("~joint_limits", None),
    Param("~named_states", None),
    Param("~start_tolerance_rad", 0.01, number),
    Param("~velocity_tolerance_fraction", 0.01, number),
    Param("~acceleration_tolerance_fraction", 0.05, number),
    Param("~publish_rate_hz", 100.0, number),
    Param("~initial_state", "home"),
)


class RobotSimNode:
    def __init__(self):
        settings = read_params(PARAMETERS)
        robot = load_robot_config(settings.robot_config)
        joint_names = list(robot.joint_names)
        limits = load_joint_limits(settings.joint_limits, robot.joint_names)
        named_states = load_named_states(settings.named_states, len(joint_names))
        tolerances = CheckTolerances(
            start_rad=settings.start_tolerance_rad,
            velocity_fraction=settings.velocity_tolerance_fraction,
            acceleration_fraction=settings.acceleration_tolerance_fraction,
        )
        rate_hz = settings.publish_rate_hz
        initial = resolve_initial_state(settings.initial_state, named_states, len(joint_names))
        self.controller = SimulatedController(
            joint_names,
            limits,
            named_states,
            initial,
            RosClock(),
            _JointStateTopic("joint_states"),
            rate_hz=rate_hz,
            tolerances=tolerances,
        )
        self.server = actionlib.SimpleActionServer(
            "~execute_trajectory", ExecuteJointTrajectoryAction, execute_cb=self.execute, auto_start=False
        )
        self.server.start()
        rospy.Service("~set_joint_state", SetJointState, self.set_joint_state)
        self.timer = rospy.Timer(rospy.Duration(1.0 / rate_hz), self.publish)
        rospy.loginfo(
            "robot_sim: %d joints at %s, publishing /joint_states at %.0f Hz",
            len(joint_names),
            np.round(initial, 4).tolist(),
            rate_hz,
        )

    def publish(self, _event=None):
        try:
            self.controller.publish_state()
        except rospy.ROSException as exc:
            # the timer can fire once more while shutdown closes the topics (before is_shutdown() turns true)
            closing = rospy.is_shutdown() or rospy.core.is_shutdown_requested() or "closed topic" in str(exc)
            if not closing:
                raise

    def set_joint_state(self, request):
        try:
            state = self.controller.place(request.named_state, request.positions)
        except InputError as exc:
            return SetJointStateResponse(False, str(exc))
        return SetJointStateResponse(True, f"robot placed at {np.round(state, 4).tolist()}")

    def _abort(self, reason: str) -> None:
        rospy.logwarn("robot_sim: trajectory rejected: %s", reason)
        self.server.set_aborted(ExecuteJointTrajectoryResult(success=False, error=reason), reason)

    def execute(self, goal):
        try:
            trajectory = JointTrajectory.from_msg(goal.trajectory)
        except (TrajectoryError, ValueError) as exc:
            self._abort(f"malformed trajectory: {exc}")
            return
        try:
            outcome = self.controller.execute(trajectory, _ActionGoal(self.server))
        except rospy.ROSInterruptException:
            if not rospy.is_shutdown():
                raise  # simulated time moved backwards: actionlib aborts the goal with the reason
            outcome = ExecutionOutcome(ExecutionStatus.SHUTDOWN)
        except AgiprobotError as exc:
            self._abort(str(exc) if isinstance(exc, InputError) else f"internal error: {exc}")
            return
        if outcome.status is ExecutionStatus.REJECTED:
            self._abort(outcome.message)
        elif outcome.status is ExecutionStatus.CANCELLED:
            rospy.loginfo("robot_sim: %s", outcome.message)
            self.server.set_preempted(
                ExecuteJointTrajectoryResult(success=False, error=outcome.message), outcome.message
            )
        elif outcome.status is ExecutionStatus.SUCCEEDED:
            self.server.set_succeeded(ExecuteJointTrajectoryResult(success=True, error=""))
        else:
            self._end_at_shutdown()

    def _end_at_shutdown(self) -> None:
        text = "robot_sim shut down during the trajectory"
        try:
            self.server.set_aborted(ExecuteJointTrajectoryResult(success=False, error=text), text)
        except rospy.ROSException:
            pass  # the result topic is closed already: no client is left to tell


def main():
    run_node("robot_sim", RobotSimNode)
