#!/usr/bin/env python3
"""rostest: the moveit executor (RosSegmentExecutor over MoveItExecuteClient) against a fake move_group.

The fake stands for MoveIt's execute capability: it serves moveit_msgs/ExecuteTrajectory on /execute_trajectory
(as move_group does, on the root namespace), publishes /joint_states in the UR driver's alphabetical order, moves
its joints to each goal's last point on success, and ends each goal as the test scripts it.
"""

import threading
import time
import unittest

import actionlib
import numpy as np
import rospy
import rostest
from moveit_msgs.msg import ExecuteTrajectoryAction, ExecuteTrajectoryResult, MoveItErrorCodes
from sensor_msgs.msg import JointState

from agiprobot_measurement.motion.point_to_point import point_to_point
from agiprobot_measurement.motion.trajectory import JointTrajectory
from agiprobot_measurement.planning.plan.execution import ExecutionCancelled, ExecutionError
from agiprobot_measurement.ros.executor import ControllerWatch, RosSegmentExecutor
from agiprobot_measurement.ros.joint_states import JointStateCache
from agiprobot_measurement.ros.robot_client import (
    MOVEIT_ACTION,
    MotionSettings,
    MoveItExecuteClient,
    RobotStopped,
    make_motion_client,
)
from agiprobot_measurement.station import load_joint_limits, load_named_states

LIMITS = load_joint_limits()
NAMED = load_named_states()


class FakeMoveGroup:
    """/execute_trajectory: ``outcome`` is 'success', 'preempt' (move_group preempts: PREEMPTED, code PREEMPTED),
    'control_failed' (ABORTED, CONTROL_FAILED) or 'hold' (runs until cancelled)."""

    def __init__(self):
        self.outcome = "success"
        self.goals = []
        self.lock = threading.Lock()
        self.positions = dict(zip(LIMITS.names, NAMED["home"], strict=True))
        self.publisher = rospy.Publisher("/joint_states", JointState, queue_size=10)
        self.server = actionlib.SimpleActionServer(MOVEIT_ACTION, ExecuteTrajectoryAction, self.execute, False)
        self.server.start()
        self.timer = rospy.Timer(rospy.Duration(0.01), self.publish)

    def publish(self, _event=None):
        with self.lock:
            names = sorted(self.positions)  # the UR driver's order
            positions = [self.positions[n] for n in names]
        msg = JointState(name=names, position=positions)
        msg.header.stamp = rospy.Time.now()
        try:
            self.publisher.publish(msg)
        except rospy.ROSException:
            pass  # the test is shutting down

    def execute(self, goal):
        self.goals.append(goal)
        result = ExecuteTrajectoryResult()
        if self.outcome == "hold":
            while not self.server.is_preempt_requested() and not rospy.is_shutdown():
                rospy.sleep(0.01)
            result.error_code.val = MoveItErrorCodes.PREEMPTED
            self.server.set_preempted(result)
            return
        rospy.sleep(0.1)
        if self.outcome == "success":
            last = goal.trajectory.joint_trajectory
            with self.lock:
                self.positions.update(zip(last.joint_names, last.points[-1].positions, strict=True))
            result.error_code.val = MoveItErrorCodes.SUCCESS
            self.server.set_succeeded(result)
        elif self.outcome == "preempt":
            result.error_code.val = MoveItErrorCodes.PREEMPTED
            self.server.set_preempted(result)
        else:
            result.error_code.val = MoveItErrorCodes.CONTROL_FAILED
            self.server.set_aborted(result)


class _NoScanner:
    def set_stitching(self, on):
        return 0


class MoveItExecutorTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("test_moveit_executor")
        cls.fake = FakeMoveGroup()
        cls.joint_states = JointStateCache(list(LIMITS.names))
        assert cls.joint_states.wait(10.0) is not None
        cls.client = make_motion_client(MotionSettings("moveit"), LIMITS, cls.joint_states.latest)
        assert cls.client.wait_for_server(10.0)
        cls.cancel = False
        cls.executor = RosSegmentExecutor(
            cls.client,
            _NoScanner(),
            current_state=cls.joint_states.latest,
            cancel_requested=lambda: cls.cancel,
            controller_problem=ControllerWatch(cls.joint_states, cls.client).problem,
        )

    def setUp(self):
        type(self).cancel = False
        self.fake.outcome = "success"
        self.fake.goals.clear()
        time.sleep(0.1)  # a /joint_states after the last test's motion (the fake publishes at 100 Hz)

    def _move(self, goal_name: str) -> JointTrajectory:
        return point_to_point(self.joint_states.latest(), np.asarray(NAMED[goal_name]), LIMITS, 0.5, 0.5)

    def test_1_success_sends_the_plans_trajectory(self):
        self.assertIsInstance(self.client, MoveItExecuteClient)
        move = self._move("up")
        self.executor.execute_segment(move, "connect")
        sent = self.fake.goals[-1].trajectory.joint_trajectory
        self.assertEqual(list(sent.joint_names), list(move.joint_names))
        self.assertEqual(len(sent.points), len(move))
        self.assertTrue(np.allclose([p.positions for p in sent.points], move.positions))
        self.assertTrue(np.allclose([p.time_from_start.to_sec() for p in sent.points], move.time_from_start))
        time.sleep(0.1)
        self.assertTrue(np.allclose(self.joint_states.latest(), NAMED["up"], atol=1e-6))
        self.executor.execute_segment(self._move("home"), "connect")  # the next one starts where this one ended

    def test_2_preempted_by_move_group_is_a_stop_with_its_reason(self):
        self.fake.outcome = "preempt"
        with self.assertRaises(RobotStopped) as caught:
            self.executor.execute_segment(self._move("up"), "connect")
        self.assertIn("preempted", str(caught.exception))
        self.assertIn(MOVEIT_ACTION, str(caught.exception))

    def test_3_control_failed_names_the_code(self):
        self.fake.outcome = "control_failed"
        with self.assertRaises(ExecutionError) as caught:
            self.executor.execute_segment(self._move("up"), "connect")
        self.assertNotIsInstance(caught.exception, RobotStopped)
        self.assertIn("CONTROL_FAILED (-4)", str(caught.exception))

    def test_4_cancel_cancels_the_goal(self):
        self.fake.outcome = "hold"
        threading.Timer(0.5, lambda: setattr(type(self), "cancel", True)).start()
        started = time.monotonic()
        with self.assertRaises(ExecutionCancelled):
            self.executor.execute_segment(self._move("up"), "connect")
        self.assertLess(time.monotonic() - started, 2.0)
        self.assertEqual(len(self.fake.goals), 1)

    def test_5_a_start_away_from_the_robot_is_refused_before_move_group_sees_it(self):
        away = point_to_point(np.asarray(NAMED["up"]), np.asarray(NAMED["home"]), LIMITS, 0.5, 0.5)
        with self.assertRaises(ExecutionError) as caught:
            self.executor.execute_segment(away, "connect")
        self.assertIn("does not start at the current state", str(caught.exception))
        self.assertEqual(self.fake.goals, [])


if __name__ == "__main__":
    rostest.rosrun("agiprobot_measurement", "moveit_executor", MoveItExecutorTest)
