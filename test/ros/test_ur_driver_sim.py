#!/usr/bin/env python3
"""rostest: the simulated UR10e behind ur_robot_driver's names: cancel -> PREEMPTED; a program stopped mid-goal ->
PREEMPTED and new goals REJECTED until it runs again; a protective stop; the speed slider stretches a goal's
duration; /joint_states in the driver's alphabetical joint order at the loop rate (500 Hz)."""

import time
import unittest

import actionlib
import numpy as np
import rospy
import rostest
from actionlib_msgs.msg import GoalStatus
from control_msgs.msg import FollowJointTrajectoryAction, FollowJointTrajectoryGoal, FollowJointTrajectoryResult
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64
from std_srvs.srv import SetBool, Trigger
from trajectory_msgs.msg import JointTrajectoryPoint
from ur_msgs.srv import SetSpeedSliderFraction

from agiprobot_measurement.srv import SetJointState

ACTION = "/scaled_pos_joint_traj_controller/follow_joint_trajectory"
JOINTS = [
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
]
TIMEOUT = rospy.Duration(30)


def service(name, kind):
    rospy.wait_for_service(name, timeout=30)
    return rospy.ServiceProxy(name, kind)


def positions():
    msg = rospy.wait_for_message("/joint_states", JointState, timeout=5)
    by_name = dict(zip(msg.name, msg.position, strict=True))
    return np.array([by_name[n] for n in JOINTS])


class UrDriverSimTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("test_ur_driver_sim")
        cls.client = actionlib.SimpleActionClient(ACTION, FollowJointTrajectoryAction)
        assert cls.client.wait_for_server(TIMEOUT), f"no action server at {ACTION}"
        cls.set_running = service("/ur_driver_sim/set_program_running", SetBool)
        cls.protective_stop = service("/ur_driver_sim/protective_stop", Trigger)
        cls.unlock = service("/ur_hardware_interface/dashboard/unlock_protective_stop", Trigger)
        cls.play = service("/ur_hardware_interface/dashboard/play", Trigger)
        cls.slider = service("/ur_hardware_interface/set_speed_slider", SetSpeedSliderFraction)
        cls.place = service("/ur_driver_sim/set_joint_state", SetJointState)

    def setUp(self):
        self.assertTrue(self.set_running(True).success)
        self.assertTrue(self.slider(1.0).success)
        reply = self.place(positions=[0.0] * 6, named_state="")
        self.assertTrue(reply.success, reply.message)
        rospy.sleep(0.1)

    def goal(self, target, duration_s):
        goal = FollowJointTrajectoryGoal()
        goal.trajectory.joint_names = list(JOINTS)
        point = JointTrajectoryPoint()
        point.positions = list(target)
        point.time_from_start = rospy.Duration.from_sec(duration_s)
        goal.trajectory.points.append(point)
        return goal

    def wait(self, timeout_s=30.0):
        self.assertTrue(self.client.wait_for_result(rospy.Duration(timeout_s)), "no result in time")
        return self.client.get_state(), self.client.get_result()

    def program_running(self):
        return rospy.wait_for_message("/ur_hardware_interface/robot_program_running", Bool, timeout=5).data

    def test_cancel_preempts_and_the_robot_stops(self):
        self.client.send_goal(self.goal([1.0] * 6, 4.0))
        rospy.sleep(1.5)
        self.client.cancel_goal()
        state, result = self.wait(5.0)
        self.assertEqual(state, GoalStatus.PREEMPTED)
        self.assertEqual(result.error_code, FollowJointTrajectoryResult.SUCCESSFUL)
        rospy.sleep(1.0)  # the 0.5 s stop trajectory
        stopped = positions()
        rospy.sleep(0.5)
        np.testing.assert_allclose(positions(), stopped, atol=1e-6, err_msg="robot kept moving")
        self.assertGreater(stopped.min(), 0.2)
        self.assertLess(stopped.max(), 0.8)

    def test_stopped_program_preempts_and_rejects_until_it_runs(self):
        self.assertTrue(self.program_running())
        self.client.send_goal(self.goal([0.5] * 6, 3.0))
        rospy.sleep(1.0)
        self.assertTrue(self.set_running(False).success)
        state, _ = self.wait(5.0)
        self.assertEqual(state, GoalStatus.PREEMPTED)
        self.assertFalse(self.program_running())
        halted = positions()
        rospy.sleep(0.5)
        np.testing.assert_allclose(positions(), halted, atol=1e-6)
        self.client.send_goal(self.goal([0.0] * 6, 1.0))
        state, result = self.wait(5.0)
        self.assertEqual(state, GoalStatus.REJECTED)
        self.assertEqual(result.error_code, FollowJointTrajectoryResult.INVALID_GOAL)
        self.assertTrue(self.set_running(True).success)
        self.assertTrue(self.program_running())
        self.client.send_goal(self.goal([0.0] * 6, 1.0))
        state, result = self.wait(10.0)
        self.assertEqual(state, GoalStatus.SUCCEEDED, result.error_string)

    def test_protective_stop(self):
        self.client.send_goal(self.goal([0.5] * 6, 3.0))
        rospy.sleep(1.0)
        self.assertTrue(self.protective_stop().success)
        state, _ = self.wait(5.0)
        self.assertEqual(state, GoalStatus.PREEMPTED)
        self.assertFalse(self.program_running())
        scaling = rospy.wait_for_message("/speed_scaling_factor", Float64, timeout=5).data
        self.assertEqual(scaling, 0.0)
        self.client.send_goal(self.goal([0.0] * 6, 1.0))
        self.assertEqual(self.wait(5.0)[0], GoalStatus.REJECTED)
        self.assertFalse(self.play().success, "play must be refused while protective-stopped")
        self.assertTrue(self.unlock().success)
        self.assertTrue(self.play().success)
        self.client.send_goal(self.goal([0.0] * 6, 1.0))
        state, result = self.wait(10.0)
        self.assertEqual(state, GoalStatus.SUCCEEDED, result.error_string)

    def test_speed_slider_stretches_the_goal(self):
        durations = {}
        for fraction in (1.0, 0.3):
            self.assertTrue(self.slider(fraction).success)
            scaling = rospy.wait_for_message("/speed_scaling_factor", Float64, timeout=5).data
            self.assertAlmostEqual(scaling, fraction)
            target = 0.3 if fraction == 1.0 else 0.0
            started = time.monotonic()
            self.client.send_goal(self.goal([target] * 6, 2.0))
            state, result = self.wait(20.0)
            durations[fraction] = time.monotonic() - started
            self.assertEqual(state, GoalStatus.SUCCEEDED, result.error_string)
        ratio = durations[0.3] / durations[1.0]
        print(f"durations {durations}, ratio {ratio:.2f} (1/0.3 = 3.33)", flush=True)
        self.assertAlmostEqual(ratio, 1 / 0.3, delta=0.35)
        self.assertFalse(self.slider(0.0).success)
        self.assertFalse(self.slider(1.5).success)

    def test_joint_states_alphabetical_at_the_loop_rate(self):
        stamps, names = [], []

        def on_state(msg):
            stamps.append(time.monotonic())
            names.append(list(msg.name))

        sub = rospy.Subscriber("/joint_states", JointState, on_state, queue_size=1000)
        time.sleep(3.0)
        sub.unregister()
        self.assertEqual(names[-1], sorted(JOINTS))
        self.assertEqual(names[-1][0], "elbow_joint")
        rate = (len(stamps) - 1) / (stamps[-1] - stamps[0])
        loop_hz = rospy.get_param("/hardware_control_loop/loop_hz")
        print(f"/joint_states rate: {rate:.1f} Hz (loop_hz {loop_hz})", flush=True)
        self.assertGreater(rate, 0.8 * loop_hz)
        self.assertLess(rate, 1.1 * loop_hz)


if __name__ == "__main__":
    rostest.rosrun("agiprobot_measurement", "ur_driver_sim", UrDriverSimTest)
