#!/usr/bin/env python3
"""rostest: set_focus_point turns the simulated MILD (real PTU limits, +-20 deg pan) to look at focus points: one
given on its command line (point:=), one clicked (/clicked_point) behind the robot, which the PTU alone cannot
face, so the base has to turn."""

import math
import sys
import unittest
from pathlib import Path

import numpy as np
import rospy
import rostest
import tf2_ros
from geometry_msgs.msg import PointStamped

sys.path.insert(0, str(Path(__file__).resolve().parent))
from mild_test_utils import facing_error_deg

from agiprobot_measurement.ros.conversions import transform_to_matrix


class SetFocusPointTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("test_set_focus_point")
        cls.tf_buffer = tf2_ros.Buffer()
        cls.tf_listener = tf2_ros.TransformListener(cls.tf_buffer)

    def _wait_facing(self, point, timeout_s=25.0) -> float:
        deadline = rospy.get_time() + timeout_s
        error = math.inf
        while rospy.get_time() < deadline and not rospy.is_shutdown():
            try:
                pose = transform_to_matrix(self.tf_buffer.lookup_transform("map", "ptu_mount_link", rospy.Time(0)))
                error = facing_error_deg(pose, point)
                if error < 1.0:
                    return error
            except tf2_ros.TransformException:
                pass
            rospy.sleep(0.1)
        return error

    def test_looks_at_the_given_then_the_clicked_point(self):
        given = np.array([float(v) for v in rospy.get_param("~point").split()])
        self.assertLess(self._wait_facing(given), 1.0, "the MILD does not look at the point given on the command line")
        base = transform_to_matrix(self.tf_buffer.lookup_transform("map", "base_link", rospy.Time(0)))
        clicked = base[:3, 3] + base[:3, :3] @ np.array([-2.0, 0.5, 0.0]) + np.array([0.0, 0.0, 1.0])  # behind it
        publisher = rospy.Publisher("/clicked_point", PointStamped, queue_size=1, latch=True)
        msg = PointStamped()
        msg.header.frame_id = "map"
        msg.point.x, msg.point.y, msg.point.z = clicked
        publisher.publish(msg)
        self.assertLess(self._wait_facing(clicked), 1.0, "the MILD does not look at the clicked point behind it")
        turned = transform_to_matrix(self.tf_buffer.lookup_transform("map", "base_link", rospy.Time(0)))
        self.assertLess(turned[:3, 0] @ base[:3, 0], 0.0, "the base should have turned round")


if __name__ == "__main__":
    rostest.rosrun("agiprobot_measurement", "set_focus_point_check", SetFocusPointTest)
