#!/usr/bin/env python3
"""rostest: RobotModelServiceReal.launch (sim:=true) with the approximated IK, the global planner and an unknown
IKAngleRating (test/data/mild_real_overrides.yaml): the real robot's PTU limits, the LP's solution through the
service, planned distances, and the fallback to SIMPLE."""

import math
import sys
import unittest
from pathlib import Path

import numpy as np
import rospy
import rostest
from geometry_msgs.msg import Point, Quaternion, Vector3
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parent))
from mild_test_utils import NS, proxies

from agiprobot_measurement.common.geometry import wrap_to_pi
from agiprobot_measurement.mild.state import RobotState
from agiprobot_measurement.ros.mild_messages import state_to_msg


class RealSettingsTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("test_mild_robot_model_services_real")
        cls.srv = proxies()

    def test_unknown_rating_falls_back_to_simple(self):
        self.assertEqual(rospy.get_param(f"{NS}/IKAngleRating"), "SHORTEST_DETOUR")
        self.assertEqual(rospy.get_param(f"{NS}/IKAngleRatingInUse"), "SIMPLE")

    def test_approximated_ik_through_the_service(self):
        source = RobotState(math.radians(10.0), 0.0, 0.5, 1.0, 1.0)
        for azimuth_deg, elevation_deg in ((20.0, -10.0), (-120.0, 15.0), (170.0, -40.0)):
            q = Rotation.from_euler("ZY", [azimuth_deg, -elevation_deg], degrees=True).as_quat()
            reply = self.srv["CalculateRobotState"](state_to_msg(source), Quaternion(*q), Vector3(2.0, 3.0, 1.2))
            self.assertTrue(reply.success, reply.message)
            state = reply.targetRobotState
            self.assertAlmostEqual((state.x, state.y), (2.0, 3.0))
            self.assertAlmostEqual(float(wrap_to_pi(state.pan + state.rotation - math.radians(azimuth_deg))), 0.0)
            self.assertAlmostEqual(math.degrees(state.tilt), elevation_deg)
            self.assertLessEqual(abs(math.degrees(state.pan)), 20.0 + 1e-9)
            # the cheaper pan (omega 1 vs 10) takes as much of the turn as its limit allows
            turn = math.degrees(float(wrap_to_pi(math.radians(azimuth_deg) - source.pan - source.rotation)))
            expected_pan = float(np.clip(10.0 + turn, -20.0, 20.0))
            self.assertAlmostEqual(math.degrees(state.pan), expected_pan, places=6)

    def test_planned_distances(self):
        open_floor = self.srv["GetDistance"](Point(1.0, 1.0, 0), Point(4.0, 3.0, 0)).distance
        self.assertGreaterEqual(open_floor, math.hypot(3, 2) - 1e-9)
        self.assertLess(open_floor, math.hypot(3, 2) + 0.05)
        around = self.srv["GetDistance"](Point(3.0, 2.0, 0), Point(7.0, 1.0, 0)).distance
        self.assertGreater(around, math.hypot(4, 1) + 3.0)  # around the inner wall's end at y = 5
        self.assertEqual(self.srv["GetDistance"](Point(1.0, 1.0, 0), Point(8.0, 3.0, 0)).distance, -1.0)

    def test_simulated_robot_has_the_real_limits(self):
        refused = self.srv["set_state"](state_to_msg(RobotState(math.radians(30.0), 0.0, 0.0, 1.0, 1.0)))
        self.assertFalse(refused.success)
        self.assertIn("pan", refused.message)
        self.assertTrue(self.srv["set_state"](state_to_msg(RobotState(math.radians(19.0), 0.0, 0.0, 1.0, 1.0))).success)


if __name__ == "__main__":
    rostest.rosrun("agiprobot_measurement", "mild_robot_model_services_real", RealSettingsTest)
