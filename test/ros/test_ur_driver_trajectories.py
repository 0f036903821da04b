#!/usr/bin/env python3
"""rostest: ur_robot_driver v2.4.1's own integration test of the trajectory interface, run against the simulated
UR10e (``roslaunch ur_robot_driver ur10e_bringup.launch``).

Ported from Universal_Robots_ROS_Driver v2.4.1 ur_robot_driver/test/integration_test.py,
``test_joint_trajectory_position_interface``: the same four goals, joint order (elbow first), times and expected
error codes, sent through the same ``follow_joint_trajectory`` client remapped by the .test file as driver.test does:

(a) 0 @6 s, -0.5 @9 s, -1.0 @12 s -> SUCCESSFUL;
(b) times 6.0 then 3.0 -> INVALID_GOAL;
(c) 0 @6.0 s, -1.0 @6.5 s -> SUCCESSFUL (the scaled controller's default goal_time 0.6 s);
(d) the same with goal_time_tolerance 0.01 s -> GOAL_TOLERANCE_VIOLATED.

Changes against the original, all in the set-up, none in the goals or the checks:

* ``init_robot`` waits for the set_mode action, the trajectory action and ``resend_robot_program``: the other
  clients (the cartesian and passthrough actions, set_io, switch_controller, get_robot_software_version) and their
  message packages (cartesian_control_msgs, controller_manager_msgs) are not part of the simulated interface.
* The power cycle (``set_robot_to_mode(POWER_OFF)`` / ``RUNNING``, with upstream's ``set_robot_to_mode``) and
  ``send_program_srv.call()`` are upstream's; ``switch_on_controller("scaled_pos_joint_traj_controller")`` is left
  out (the scaled controller is the simulator's only one, always active); instead the test waits until
  ``/ur_hardware_interface/robot_program_running`` is true.
* ``wait_for_result`` has a timeout (60 s), so a silent server fails the test instead of hanging it; the state the
  result arrived in is printed.
* Python 3 / unittest style of this package (rostest.rosrun with this package's name).

``test_z_modes_and_dashboard`` is this package's own, run after upstream's: the robot and safety modes, the
dashboard's queries and ``set_mode`` recovering from a protective stop and a power-off.
"""

import unittest

import actionlib
import rospy
import rostest
import std_msgs.msg
from control_msgs.msg import FollowJointTrajectoryAction, FollowJointTrajectoryGoal, FollowJointTrajectoryResult
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectoryPoint
from ur_dashboard_msgs.msg import RobotMode, SafetyMode, SetModeAction, SetModeGoal
from ur_dashboard_msgs.srv import GetProgramState, GetRobotMode, GetSafetyMode, IsProgramRunning

PKG = "agiprobot_measurement"
NAME = "integration_test"
RESULT_TIMEOUT = rospy.Duration(60)


class IntegrationTest(unittest.TestCase):
    def __init__(self, *args):
        super().__init__(*args)
        self.init_robot()

    def init_robot(self):
        """Make sure the robot is booted and ready to receive commands"""
        rospy.init_node("ur_robot_driver_integration_test", anonymous=True)
        timeout = rospy.Duration(30)
        self.set_mode_client = actionlib.SimpleActionClient("/ur_hardware_interface/set_mode", SetModeAction)
        if not self.set_mode_client.wait_for_server(timeout):
            self.fail("Could not reach set_mode action. Make sure that the driver is actually running.")
        self.trajectory_client = actionlib.SimpleActionClient("follow_joint_trajectory", FollowJointTrajectoryAction)
        if not self.trajectory_client.wait_for_server(timeout):
            self.fail("Could not reach controller action. Make sure that the driver is actually running.")
        self.send_program_srv = rospy.ServiceProxy("/ur_hardware_interface/resend_robot_program", Trigger)
        try:
            self.send_program_srv.wait_for_service(timeout.to_sec())
        except rospy.exceptions.ROSException as exc:
            self.fail(
                f"Could not reach resend_robot_program service. Make sure that the driver is actually running: {exc}"
            )

    def set_robot_to_mode(self, target_mode):
        goal = SetModeGoal()
        goal.target_robot_mode.mode = RobotMode.RUNNING
        goal.play_program = False  # we use headless mode during tests
        # This might be a bug to hunt down. We have to reset the program before calling `resend_robot_program`
        goal.stop_program = True

        self.set_mode_client.send_goal(goal)
        self.set_mode_client.wait_for_result()
        return self.set_mode_client.get_result().success

    def wait_for_program_running(self):
        running = rospy.wait_for_message("/ur_hardware_interface/robot_program_running", std_msgs.msg.Bool, 30)
        self.assertTrue(running.data, "the robot program is not running")

    def send_and_wait(self, goal):
        self.trajectory_client.send_goal(goal)
        self.assertTrue(self.trajectory_client.wait_for_result(RESULT_TIMEOUT), "no result in time")
        result = self.trajectory_client.get_result()
        print(
            f"state {self.trajectory_client.get_state()} error_code {result.error_code} '{result.error_string}'",
            flush=True,
        )
        return result

    def test_joint_trajectory_position_interface(self):
        """Test robot movement"""
        #### Power cycle the robot in order to make sure it is running correctly####
        self.assertTrue(self.set_robot_to_mode(RobotMode.POWER_OFF))
        rospy.sleep(0.5)
        self.assertTrue(self.set_robot_to_mode(RobotMode.RUNNING))
        rospy.sleep(0.5)

        self.send_program_srv.call()
        self.wait_for_program_running()

        goal = FollowJointTrajectoryGoal()

        goal.trajectory.joint_names = [
            "elbow_joint",
            "shoulder_lift_joint",
            "shoulder_pan_joint",
            "wrist_1_joint",
            "wrist_2_joint",
            "wrist_3_joint",
        ]
        position_list = [[0.0 for i in range(6)]]
        position_list.append([-0.5 for i in range(6)])
        position_list.append([-1.0 for i in range(6)])
        duration_list = [6.0, 9.0, 12.0]

        for i, position in enumerate(position_list):
            point = JointTrajectoryPoint()
            point.positions = position
            point.time_from_start = rospy.Duration(duration_list[i])
            goal.trajectory.points.append(point)

        rospy.loginfo("Sending simple goal")

        self.assertEqual(self.send_and_wait(goal).error_code, FollowJointTrajectoryResult.SUCCESSFUL)
        rospy.loginfo("Received result SUCCESSFUL")

        """Test trajectory server. This is more of a validation test that the testing suite does the
        right thing."""
        goal = FollowJointTrajectoryGoal()

        goal.trajectory.joint_names = [
            "elbow_joint",
            "shoulder_lift_joint",
            "shoulder_pan_joint",
            "wrist_1_joint",
            "wrist_2_joint",
            "wrist_3_joint",
        ]
        position_list = [[0.0 for i in range(6)]]
        position_list.append([-0.5 for i in range(6)])
        # Create illegal goal by making the second point come earlier than the first
        duration_list = [6.0, 3.0]

        for i, position in enumerate(position_list):
            point = JointTrajectoryPoint()
            point.positions = position
            point.time_from_start = rospy.Duration(duration_list[i])
            goal.trajectory.points.append(point)

        rospy.loginfo("Sending illegal goal")
        # As timings are illegal, we expect the result to be INVALID_GOAL
        self.assertEqual(self.send_and_wait(goal).error_code, FollowJointTrajectoryResult.INVALID_GOAL)
        rospy.loginfo("Received result INVALID_GOAL")

        """Test robot movement"""
        goal = FollowJointTrajectoryGoal()

        goal.trajectory.joint_names = [
            "elbow_joint",
            "shoulder_lift_joint",
            "shoulder_pan_joint",
            "wrist_1_joint",
            "wrist_2_joint",
            "wrist_3_joint",
        ]
        position_list = [[0.0 for i in range(6)]]
        position_list.append([-1.0 for i in range(6)])
        duration_list = [6.0, 6.5]

        for i, position in enumerate(position_list):
            point = JointTrajectoryPoint()
            point.positions = position
            point.time_from_start = rospy.Duration(duration_list[i])
            goal.trajectory.points.append(point)

        rospy.loginfo("Sending scaled goal without time restrictions")
        self.assertEqual(self.send_and_wait(goal).error_code, FollowJointTrajectoryResult.SUCCESSFUL)
        rospy.loginfo("Received result SUCCESSFUL")

        # Now do the same again, but with a goal time constraint
        rospy.loginfo("Sending scaled goal with time restrictions")
        goal.goal_time_tolerance = rospy.Duration(0.01)
        self.assertEqual(self.send_and_wait(goal).error_code, FollowJointTrajectoryResult.GOAL_TOLERANCE_VIOLATED)
        rospy.loginfo("Received result GOAL_TOLERANCE_VIOLATED")

    def test_z_modes_and_dashboard(self):
        ns = "/ur_hardware_interface"

        def dashboard(name, kind=Trigger):
            return rospy.ServiceProxy(f"{ns}/dashboard/{name}", kind)()

        def latched(topic, kind):
            return rospy.wait_for_message(f"{ns}/{topic}", kind, 10)

        def set_mode(target, play):
            goal = SetModeGoal(stop_program=False, play_program=play)
            goal.target_robot_mode.mode = target
            self.set_mode_client.send_goal(goal)
            self.assertTrue(self.set_mode_client.wait_for_result(RESULT_TIMEOUT))
            return self.set_mode_client.get_result()

        # a protective stop (simulation only): safety mode PROTECTIVE_STOP, the program stops
        self.assertTrue(rospy.ServiceProxy("/ur_driver_sim/protective_stop", Trigger)().success)
        self.assertEqual(latched("safety_mode", SafetyMode).mode, SafetyMode.PROTECTIVE_STOP)
        self.assertFalse(latched("robot_program_running", std_msgs.msg.Bool).data)
        self.assertEqual(dashboard("get_safety_mode", GetSafetyMode).answer, "Safetymode: PROTECTIVE_STOP")
        state = dashboard("program_state", GetProgramState)
        self.assertEqual((state.state.state, state.success), ("STOPPED", True))
        # set_mode RUNNING with play_program: unlocks and plays
        result = set_mode(RobotMode.RUNNING, True)
        self.assertEqual((result.success, result.message), (True, "Reached target robot mode."))
        self.assertEqual(latched("safety_mode", SafetyMode).mode, SafetyMode.NORMAL)
        running = dashboard("program_running", IsProgramRunning)
        self.assertEqual((running.program_running, running.answer), (True, "Program running: true"))
        # powered off: no program plays, the trajectory goals are refused
        self.assertEqual(dashboard("power_off").message, "Powering off")
        self.assertEqual(latched("robot_mode", RobotMode).mode, RobotMode.POWER_OFF)
        self.assertEqual(dashboard("get_robot_mode", GetRobotMode).answer, "Robotmode: POWER_OFF")
        self.assertFalse(dashboard("play").success)
        self.assertFalse(self.send_program_srv().success)
        # and back: set_mode powers on and releases the brakes
        result = set_mode(RobotMode.RUNNING, True)
        self.assertTrue(result.success, result.message)
        self.assertEqual(latched("robot_mode", RobotMode).mode, RobotMode.RUNNING)
        self.wait_for_program_running()
        # a mode that cannot be selected
        result = set_mode(RobotMode.BOOTING, False)
        self.assertEqual(
            (result.success, result.message),
            (False, "Requested target mode BOOTING which cannot be explicitly selected."),
        )


if __name__ == "__main__":
    rostest.rosrun(PKG, NAME, IntegrationTest)
