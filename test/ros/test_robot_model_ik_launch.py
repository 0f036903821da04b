#!/usr/bin/env python3
"""rostest: test_IK.launch runs the original's IK test: the start pose on /initialpose, IK markers (the simulation
settings draw them) and the summary in ~result; the reachable poses are solved, the view centres out of the camera's
height range are not (the original's first pose at the map origin's floor and its three "very difficult" ones:
camera 2.5 m up, on the floor, 1 m below it)."""

import unittest

import rospy
import rostest
from geometry_msgs.msg import PoseWithCovarianceStamped
from visualization_msgs.msg import Marker

RESULT = "/asr_robot_model_services/result"


class IKLaunchTest(unittest.TestCase):
    def test_the_original_ik_test_runs(self):
        rospy.init_node("test_robot_model_ik_launch")
        markers = set()
        rospy.Subscriber("/asr_robot_model_services/IK_Visualization", Marker, lambda m: markers.add(m.ns))
        start = rospy.wait_for_message("/initialpose", PoseWithCovarianceStamped, timeout=30.0)
        self.assertAlmostEqual(start.pose.pose.position.x, -0.113948535919)
        self.assertAlmostEqual(start.pose.pose.position.y, -1.60322499275)
        deadline = rospy.get_time() + 60.0
        while not rospy.has_param(RESULT) and rospy.get_time() < deadline:
            rospy.sleep(0.1)
        result = rospy.get_param(RESULT)
        self.assertEqual(result["total"], 28)
        self.assertEqual(result["solved"], 28 - len(result["unsolved"]))
        self.assertEqual(result["unsolved"], [1, 26, 27, 28])
        self.assertIn("targetCameraVector", markers)
        self.assertIn("camToActualViewCenterVector", markers)
        self.assertIn("iterationVector", markers)  # the rated pan samples


if __name__ == "__main__":
    rostest.rosrun("agiprobot_measurement", "robot_model_ik_launch", IKLaunchTest)
