#!/usr/bin/env python3
"""rostest: the node cell_check names what a real cell lacks, gives up after its timeout, and turns ready.

With nothing running, a cell_check with ``~timeout_s`` 3 exits with code 2 after about 3 s, its log naming each of
the eight interfaces of the roles robot, scanner and stitcher and their drivers, while the launched one (no timeout)
keeps ``/cell_check/ready`` false. Then the test plays the drivers: the FollowJointTrajectory action server, the
robot's topics (/speed_scaling_factor first of the wrong type), the scanner's profile topic, the stitcher's services
and /robot_description: a second timed check names only the wrong type; with the right type the launched node logs
"cell ready" and latches true, and a topic that goes away turns it false again.
"""

import os
import subprocess
import threading
import time
import unittest

import actionlib
import rospy
import rostest
from control_msgs.msg import FollowJointTrajectoryAction
from rosgraph_msgs.msg import Log
from sensor_msgs.msg import JointState, PointCloud2
from std_msgs.msg import Bool, Float32, Float64
from std_srvs.srv import SetBool, SetBoolResponse, Trigger, TriggerResponse

PKG = "agiprobot_measurement"
FJT = "/scaled_pos_joint_traj_controller/follow_joint_trajectory"
ROLES = "robot scanner stitcher"
NOT_READY_EXIT_CODE = 2
#: every interface of the three roles, as the messages name them
NAMED = (
    f"no action server {FJT} (control_msgs/FollowJointTrajectory)",
    "no publisher of topic /joint_states (sensor_msgs/JointState)",
    "no publisher of topic /ur_hardware_interface/robot_program_running (std_msgs/Bool)",
    "no publisher of topic /speed_scaling_factor (std_msgs/Float64)",
    "no parameter /robot_description",
    "no publisher of topic /scancontrol_pointcloud (sensor_msgs/PointCloud2)",
    "no service /switch_stitch_mode (std_srvs/SetBool)",
    "no service /clear_stitched_point_cloud (std_srvs/Trigger)",
)


def timed_check(timeout_s, name):
    """Run a cell_check with a timeout to its end: (exit code, its output, seconds it ran)."""
    started = time.monotonic()
    process = subprocess.run(
        [
            "rosrun",
            PKG,
            "cell_check",
            f"__name:={name}",
            f"_roles:={ROLES}",
            f"_timeout_s:={timeout_s}",
            "_log_period_s:=1.0",
        ],
        capture_output=True,
        text=True,
        timeout=timeout_s + 60.0,
        env=dict(os.environ),
    )
    return process.returncode, process.stdout + process.stderr, time.monotonic() - started


class CellCheckTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("test_cell_check")
        cls.lock = threading.Lock()
        cls.ready = []
        cls.logs = []
        rospy.Subscriber("/cell_check/ready", Bool, cls._on_ready)
        rospy.Subscriber("/rosout", Log, cls._on_log, queue_size=100)

    @classmethod
    def _on_ready(cls, msg):
        with cls.lock:
            cls.ready.append(msg.data)

    @classmethod
    def _on_log(cls, msg):
        if msg.name == "/cell_check":
            with cls.lock:
                cls.logs.append(msg.msg)

    def wait_ready(self, value, timeout_s=20.0):
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self.lock:
                if self.ready and self.ready[-1] == value:
                    return True
            time.sleep(0.1)
        return False

    def test_a_nothing_present_names_every_missing_interface_and_times_out(self):
        self.assertTrue(self.wait_ready(False), "the launched check latches ready false")
        code, output, took = timed_check(3.0, "cell_check_empty")
        self.assertEqual(NOT_READY_EXIT_CODE, code, output)
        self.assertGreaterEqual(took, 3.0)
        self.assertIn("not ready after 3 s, missing (8)", output)
        for text in NAMED:
            self.assertIn(text, output)
        self.assertIn("is ur_robot_driver's ur10e_bringup.launch running?", output)
        self.assertIn("is micro_epsilon_scancontrol_driver's load_driver.launch running?", output)
        with self.lock:
            self.assertNotIn(True, self.ready)
            self.assertTrue(any("still missing (8)" in log for log in self.logs), self.logs)

    def test_b_drivers_present_the_check_turns_ready(self):
        cls = type(self)
        cls.server = actionlib.SimpleActionServer(FJT, FollowJointTrajectoryAction, auto_start=False)
        cls.server.start()
        cls.publishers = {
            "/joint_states": rospy.Publisher("/joint_states", JointState, queue_size=1),
            "/ur_hardware_interface/robot_program_running": rospy.Publisher(
                "/ur_hardware_interface/robot_program_running", Bool, queue_size=1, latch=True
            ),
            "/scancontrol_pointcloud": rospy.Publisher("/scancontrol_pointcloud", PointCloud2, queue_size=1),
        }
        wrong = rospy.Publisher("/speed_scaling_factor", Float32, queue_size=1)
        cls.services = [
            rospy.Service("/switch_stitch_mode", SetBool, lambda _r: SetBoolResponse(True, "")),
            rospy.Service("/clear_stitched_point_cloud", Trigger, lambda _r: TriggerResponse(True, "")),
        ]
        rospy.set_param("/robot_description", "<robot name='ur10e'/>")

        code, output, _took = timed_check(3.0, "cell_check_wrong_type")
        self.assertEqual(NOT_READY_EXIT_CODE, code, output)
        self.assertIn("missing (1)", output)
        self.assertIn("topic /speed_scaling_factor is std_msgs/Float32, expected std_msgs/Float64", output)
        self.assertFalse(self.wait_ready(True, timeout_s=1.0))

        wrong.unregister()
        cls.publishers["/speed_scaling_factor"] = rospy.Publisher("/speed_scaling_factor", Float64, queue_size=1)
        self.assertTrue(self.wait_ready(True), "the launched check does not turn ready")
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and not any("cell ready" in log for log in self.logs):
            time.sleep(0.1)
        with self.lock:
            self.assertTrue(any("cell_check: cell ready (robot, scanner, stitcher)" in log for log in self.logs))

    def test_c_a_driver_that_goes_away_turns_it_not_ready(self):
        self.assertTrue(self.wait_ready(True))
        self.publishers.pop("/scancontrol_pointcloud").unregister()
        self.assertTrue(self.wait_ready(False), "the check did not notice the scanner going away")
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and not any("no longer ready" in log for log in self.logs):
            time.sleep(0.1)
        with self.lock:
            gone = [log for log in self.logs if "no longer ready" in log]
        self.assertTrue(gone and "no publisher of topic /scancontrol_pointcloud" in gone[-1], gone)


if __name__ == "__main__":
    rostest.rosrun(PKG, "cell_check", CellCheckTest)
