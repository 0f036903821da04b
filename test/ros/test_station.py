#!/usr/bin/env python3
"""rostest: the station launch file and the simulated UR10e controller (deprecated alias robot_sim/...)."""

import sys
import time
import unittest
from pathlib import Path

import numpy as np
import rospy
import rostest
import tf2_ros
from actionlib_msgs.msg import GoalStatus
from sensor_msgs.msg import JointState

sys.path.insert(0, str(Path(__file__).resolve().parent))
from station_test_utils import (
    JOINTS,
    LIMITS,
    NAMED,
    action_client,
    current_positions,
    make_trajectory,
    place_robot,
)

from agiprobot_measurement.motion.kinematics import KinematicModel
from agiprobot_measurement.motion.point_to_point import point_to_point


class StationTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("test_station_node")
        cls.client = action_client()
        cls.tf_buffer = tf2_ros.Buffer()
        cls.tf_listener = tf2_ros.TransformListener(cls.tf_buffer)

    def setUp(self):
        place_robot("home")

    def _run(self, goal, timeout_s=30.0):
        self.client.send_goal(goal)
        self.assertTrue(self.client.wait_for_result(rospy.Duration(timeout_s)), "no result in time")
        return self.client.get_state(), self.client.get_result()

    def _assert_rejected(self, goal, expected_words):
        state, result = self._run(goal)
        self.assertEqual(state, GoalStatus.ABORTED, f"expected rejection, got state {state}")
        self.assertFalse(result.success)
        for word in expected_words:
            self.assertIn(word, result.error)
        # the node keeps serving: a good trajectory still executes afterwards
        self._assert_executes(NAMED["home"] + np.array([0.05, -0.05, 0.05, 0.0, 0.0, 0.05]))

    def _assert_executes(self, target):
        start = current_positions()
        trajectory = point_to_point(start, target, LIMITS)
        state, result = self._run(
            make_trajectory(
                trajectory.positions,
                trajectory.time_from_start,
                trajectory.velocities,
                trajectory.accelerations,
            )
        )
        self.assertEqual(state, GoalStatus.SUCCEEDED, result.error)
        rospy.sleep(0.05)
        np.testing.assert_allclose(current_positions(), target, atol=1e-3)

    def test_joint_states_rate(self):
        stamps = []
        sub = rospy.Subscriber("/joint_states", JointState, lambda m: stamps.append(time.monotonic()))
        time.sleep(2.0)
        sub.unregister()
        rate = (len(stamps) - 1) / (stamps[-1] - stamps[0])
        print(f"/joint_states rate: {rate:.1f} Hz")
        self.assertGreaterEqual(rate, 50.0)

    def test_tf_base_link_to_laser_emitter(self):
        transform = self.tf_buffer.lookup_transform(
            "base_link", "laser_emitter_frame", rospy.Time(0), rospy.Duration(10.0)
        )
        model = KinematicModel.from_station(base_frame="base_link")
        expected = model.fk(current_positions())
        t = transform.transform.translation
        np.testing.assert_allclose([t.x, t.y, t.z], expected[:3, 3], atol=1e-4)

    def test_two_point_trajectory_executes(self):
        target = NAMED["home"] + np.array([0.3, -0.4, -0.3, -0.2, 0.3, 0.5])
        duration = 4.0
        goal = make_trajectory([NAMED["home"], target], [0.0, duration])
        started = time.monotonic()
        state, result = self._run(goal)
        self.assertEqual(state, GoalStatus.SUCCEEDED, result.error)
        self.assertGreater(time.monotonic() - started, duration * 0.9, "executed faster than its timing")
        rospy.sleep(0.05)
        np.testing.assert_allclose(current_positions(), target, atol=1e-3)

    def test_rejects_position_limit(self):
        target = NAMED["home"].copy()
        target[1] = LIMITS.upper[1] + 0.2  # shoulder_lift above its 0.52 rad limit
        self._assert_rejected(make_trajectory([NAMED["home"], target], [0.0, 10.0]), ["position limit", JOINTS[1]])

    def test_rejects_velocity_limit(self):
        target = NAMED["home"] + np.array([0.0, 0.0, 0.0, 0.0, 0.0, 3.0])
        # 3 rad in 0.5 s: far above wrist_3's 3.14 rad/s
        self._assert_rejected(make_trajectory([NAMED["home"], target], [0.0, 0.5]), ["velocity limit", JOINTS[5]])

    def test_rejects_acceleration_limit(self):
        target = NAMED["home"] + np.array([0.5, 0.0, 0.0, 0.0, 0.0, 0.0])
        accelerations = [[2.5, 0, 0, 0, 0, 0], [-2.5, 0, 0, 0, 0, 0]]  # shoulder_pan's limit is 1.0 rad/s^2
        goal = make_trajectory([NAMED["home"], target], [0.0, 2.0], accelerations=accelerations)
        self._assert_rejected(goal, ["acceleration limit", JOINTS[0]])

    def test_rejects_acceleration_of_interpolated_motion(self):
        target = NAMED["home"] + np.array([0.8, 0.0, 0.0, 0.0, 0.0, 0.0])
        # rest-to-rest cubic over 0.9 s: peak acceleration 6 * 0.8 / 0.81 = 5.9 rad/s^2
        self._assert_rejected(make_trajectory([NAMED["home"], target], [0.0, 0.9]), ["acceleration limit"])

    def test_rejects_non_increasing_time(self):
        mid = NAMED["home"] + 0.05
        goal = make_trajectory([NAMED["home"], mid, mid + 0.05], [0.0, 2.0, 2.0])
        self._assert_rejected(goal, ["not strictly increasing"])

    def test_rejects_wrong_joint_names(self):
        names = [*JOINTS[:5], "gripper_joint"]
        goal = make_trajectory([NAMED["home"], NAMED["home"] + 0.05], [0.0, 3.0], names=names)
        self._assert_rejected(goal, ["wrong joint names", "gripper_joint"])

    def test_rejects_wrong_start(self):
        start = NAMED["home"] + np.array([0.3, 0, 0, 0, 0, 0])
        goal = make_trajectory([start, start + 0.05], [0.0, 3.0])
        self._assert_rejected(goal, ["does not start at the current state"])

    def test_cancel_stops_motion(self):
        target = NAMED["home"] + np.array([1.0, -0.8, -0.8, 0.0, 0.0, 1.0])
        trajectory = point_to_point(NAMED["home"], target, LIMITS, 0.3, 0.3)
        self.assertGreater(trajectory.duration, 3.0)
        self.client.send_goal(
            make_trajectory(
                trajectory.positions,
                trajectory.time_from_start,
                trajectory.velocities,
                trajectory.accelerations,
            )
        )
        rospy.sleep(1.5)
        self.client.cancel_goal()
        self.assertTrue(self.client.wait_for_result(rospy.Duration(5.0)))
        self.assertEqual(self.client.get_state(), GoalStatus.PREEMPTED)
        stopped = current_positions()
        rospy.sleep(1.0)
        np.testing.assert_allclose(current_positions(), stopped, atol=1e-9, err_msg="robot kept moving")
        travelled = np.abs(stopped - NAMED["home"]).max()
        self.assertGreater(travelled, 0.01, "robot never moved")
        self.assertLess(travelled, np.abs(target - NAMED["home"]).max() - 0.05, "robot reached the goal")


if __name__ == "__main__":
    rostest.rosrun("agiprobot_measurement", "station_node", StationTest)
