#!/usr/bin/env python3
"""rostest: asr_robot_model_services on the simulated MILD (RobotModelServiceSim.launch: the original's simulation
settings, pan +-20 deg, visualizeIK on).

Every service under its exact name and type, the rosservice command-line forms, errors for bad requests while the
node keeps serving, poses read from the simulated robot's tf, the IK round trip driven on the simulated robot, and
the markers and map topics.
"""

import math
import subprocess
import sys
import threading
import unittest
from pathlib import Path

import numpy as np
import rospy
import rosservice
import rostest
import tf2_ros
from geometry_msgs.msg import Point, Quaternion, Vector3
from nav_msgs.msg import OccupancyGrid
from visualization_msgs.msg import Marker, MarkerArray

sys.path.insert(0, str(Path(__file__).resolve().parent))
from mild_test_utils import NS, SERVICE_TYPES, facing_error_deg, place, proxies, wait_for_camera

from agiprobot_measurement.common.geometry import matrix_to_quaternion
from agiprobot_measurement.mild.state import RobotState
from agiprobot_measurement.ros.conversions import pose_to_matrix
from agiprobot_measurement.ros.mild_messages import state_to_msg, yaw_of

EXPECTED_TYPES = {
    "CalculateCameraPose": "asr_robot_model_services/CalculateCameraPose",
    "CalculateCameraPoseCorrection": "asr_robot_model_services/CalculateCameraPoseCorrection",
    "GetDistance": "asr_robot_model_services/GetDistance",
    "GetRobotPose": "asr_robot_model_services/GetPose",
    "GetCameraPose": "asr_robot_model_services/GetPose",
    "IsPositionAllowed": "asr_robot_model_services/IsPositionAllowed",
    "CalculateRobotState": "agiprobot_measurement/CalculateRobotState",
}


def rosservice_call(*args) -> str:
    result = subprocess.run(
        ["rosservice", "call", *args], capture_output=True, text=True, timeout=20, check=False
    )  # fmt: skip
    return result.stdout + result.stderr


class RobotModelServicesTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("test_mild_robot_model_services")
        cls.srv = proxies()
        cls.tf_buffer = tf2_ros.Buffer()
        cls.tf_listener = tf2_ros.TransformListener(cls.tf_buffer)

    def setUp(self):
        place(self.srv, RobotState(0.0, 0.0, 0.0, 1.0, 1.0))

    def _assert_still_serving(self):
        self.assertAlmostEqual(self.srv["GetDistance"](Point(0, 0, 0), Point(3, 4, 0)).distance, 5.0)

    def test_every_service_has_its_exact_name_and_type(self):
        names = set(rosservice.get_service_list(namespace=NS))
        for name, expected in EXPECTED_TYPES.items():
            self.assertIn(f"{NS}/{name}", names)
            self.assertEqual(rosservice.get_service_type(f"{NS}/{name}"), expected)
            self.assertEqual(SERVICE_TYPES[name]._type, expected)

    def test_rosservice_call_forms(self):
        out = rosservice_call(
            f"{NS}/GetDistance", "{sourcePosition: {x: 0, y: 0, z: 0}, targetPosition: {x: 3, y: 4, z: 0}}"
        )
        self.assertIn("distance: 5.0", out)
        out = rosservice_call(f"{NS}/GetDistance", "[0, 0, 0]", "[3, 4, 0]")
        self.assertIn("distance: 5.0", out)
        # CalculateCameraPoseCorrection positionally: (state, orientation, position)
        out = rosservice_call(f"{NS}/CalculateCameraPoseCorrection", "[0, 0, 0, 1, 1]", "[0, 0, 0, 1]", "[2, 2, 1]")
        self.assertIn("pan:", out)
        self.assertIn("tilt:", out)
        out = rosservice_call(f"{NS}/IsPositionAllowed", "{targetPosition: {x: 1.0, y: 1.0, z: 0.0}}")
        self.assertIn("isAllowed: True", out)
        out = rosservice_call(f"{NS}/GetRobotPose")
        self.assertIn("x: 1.0", out)
        out = rosservice_call(
            f"{NS}/CalculateCameraPose", "{sourceRobotState: {pan: 0, tilt: 0, rotation: 0, x: 1, y: 1}}"
        )
        self.assertIn("cameraFrame", out)
        out = rosservice_call(f"{NS}/CalculateRobotState", "[0, 0, 0, 1, 1]", "[0, 0, 0, 1]", "[2, 2, 1.3]")
        self.assertIn("success: True", out)

    def test_bad_requests_answer_with_an_error_and_the_node_keeps_serving(self):
        state = state_to_msg(RobotState(0.0, 0.0, 0.0, 1.0, 1.0))
        bad = [
            (lambda: self.srv["CalculateRobotState"](state, Quaternion(0, 0, 0, 0), Vector3(2, 2, 1)), "zero quaternion"),
            (lambda: self.srv["CalculateRobotState"](state, Quaternion(0, 0, 0, 1), Vector3(math.nan, 2, 1)), "not finite"),
            (lambda: self.srv["CalculateCameraPoseCorrection"](state, Quaternion(0, 0, 0, 0), Vector3(2, 2, 1)),
             "zero quaternion"),
            (lambda: self.srv["CalculateCameraPose"](state_to_msg(RobotState(math.nan))), "pan"),
            (lambda: self.srv["GetDistance"](Point(math.nan, 0, 0), Point(1, 1, 0)), "finite"),
            (lambda: self.srv["IsPositionAllowed"](Point(0, math.inf, 0)), "not finite"),
        ]  # fmt: skip
        for call, words in bad:
            with self.assertRaises(rospy.ServiceException) as caught:
                call()
            self.assertIn(words, str(caught.exception))
            self._assert_still_serving()
        out = rosservice_call(f"{NS}/CalculateRobotState", "[0, 0, 0, 1, 1]", "[0, 0, 0, 0]", "[2, 2, 1.3]")
        self.assertIn("zero quaternion", out)
        self._assert_still_serving()

    def test_states_outside_the_ptu_limits_are_refused_like_mild_sim_does(self):
        pan_max = math.radians(rospy.get_param(f"{NS}/panMax"))
        tilt_max = math.radians(rospy.get_param(f"{NS}/tiltMax"))
        here, view = Vector3(2, 2, 1.3), Quaternion(0, 0, 0, 1)
        for state, words in (
            (RobotState(1e12, 0.0, 0.0, 1.0, 1.0), ["pan", "deg outside", f"{math.degrees(pan_max):.1f}]"]),
            (RobotState(0.0, tilt_max + 0.1, 0.0, 1.0, 1.0), ["tilt", "deg outside", f"{math.degrees(tilt_max):.1f}]"]),
            (RobotState(0.0, 0.0, 1e12, 1.0, 1.0), ["rotation", "1e+12 rad"]),
            (RobotState(0.0, 0.0, 0.0, 1e12, 1.0), ["x", "1e+12 m"]),
            (RobotState(0.0, math.inf, 0.0, 1.0, 1.0), ["tilt", "not finite"]),
        ):
            msg = state_to_msg(state)
            for call in (
                lambda msg=msg: self.srv["CalculateCameraPose"](msg),
                lambda msg=msg: self.srv["CalculateCameraPoseCorrection"](msg, view, here),
                lambda msg=msg: self.srv["CalculateRobotState"](msg, view, here),
            ):
                with self.assertRaises(rospy.ServiceException) as caught:
                    call()
                for word in words:
                    self.assertIn(word, str(caught.exception))
            self._assert_still_serving()
        with self.assertRaises(rospy.ServiceException) as caught:
            self.srv["GetDistance"](Point(0, 0, 0), Point(1e300, 0, 0))
        self.assertIn("beyond", str(caught.exception))
        with self.assertRaises(rospy.ServiceException) as caught:
            self.srv["IsPositionAllowed"](Point(-1e12, 0, 0))
        self.assertIn("beyond", str(caught.exception))
        # the limit itself is a state the MILD can take
        self.srv["CalculateCameraPose"](state_to_msg(RobotState(pan_max, tilt_max, 0.0, 1.0, 1.0)))

    def test_robot_and_camera_pose_come_from_tf(self):
        state = RobotState(0.3, -0.2, 2.0, 2.5, 1.5)
        place(self.srv, state)
        expected_camera = pose_to_matrix(self.srv["CalculateCameraPose"](state_to_msg(state)).cameraFrame)
        wait_for_camera(self.tf_buffer, expected_camera)
        robot = self.srv["GetRobotPose"]().pose
        np.testing.assert_allclose([robot.position.x, robot.position.y, robot.position.z], [2.5, 1.5, 0.0], atol=1e-6)
        self.assertAlmostEqual(yaw_of(robot.orientation), 2.0, places=6)
        camera = pose_to_matrix(self.srv["GetCameraPose"]().pose)
        np.testing.assert_allclose(camera, expected_camera, atol=1e-4)

    def test_calculate_camera_pose_is_not_zero(self):
        pose = self.srv["CalculateCameraPose"](state_to_msg(RobotState(0.0, 0.0, 0.0, 1.0, 1.0))).cameraFrame
        self.assertGreater(pose.position.z, 1.0)  # the camera sits on the mast, 1.38 m up
        self.assertAlmostEqual(pose.orientation.w, 1.0, places=9)

    def test_ik_round_trip_on_the_simulated_robot(self):
        rng = np.random.default_rng(12)
        source = RobotState(0.0, 0.0, 0.0, 1.0, 1.0)
        pan = math.radians(rospy.get_param(f"{NS}/panMin")), math.radians(rospy.get_param(f"{NS}/panMax"))
        for _ in range(5):
            # any heading: the base turns where the +-20 deg pan cannot
            generating = RobotState(rng.uniform(*pan), rng.uniform(-0.7, 0.4), rng.uniform(0, 6.28),
                                    rng.uniform(1, 4), rng.uniform(0.5, 3))  # fmt: skip
            requested = pose_to_matrix(self.srv["CalculateCameraPose"](state_to_msg(generating)).cameraFrame)
            reply = self.srv["CalculateRobotState"](
                state_to_msg(source), Quaternion(*matrix_to_quaternion(requested[:3, :3])), Vector3(*requested[:3, 3])
            )
            self.assertTrue(reply.success, reply.message)
            self.assertLess(math.degrees(reply.angleDeviation), 0.5)
            np.testing.assert_allclose(pose_to_matrix(reply.cameraFrame), requested, atol=1e-6)
            place(self.srv, RobotState(reply.targetRobotState.pan, reply.targetRobotState.tilt,
                                       reply.targetRobotState.rotation, reply.targetRobotState.x,
                                       reply.targetRobotState.y))  # fmt: skip
            on_tf = wait_for_camera(self.tf_buffer, requested)
            np.testing.assert_allclose(on_tf, requested, atol=1e-4)

    def test_view_centre_too_high_has_no_solution(self):
        reply = self.srv["CalculateRobotState"](
            state_to_msg(RobotState(0.0, 0.0, 0.0, 1.0, 1.0)), Quaternion(0, 0, 0, 1), Vector3(2, 2, 4.0)
        )
        self.assertFalse(reply.success)
        self.assertIn("above", reply.message)

    def test_pose_correction_aims_the_camera_at_the_view_centre(self):
        state = RobotState(0.0, 0.0, 0.5, 1.0, 1.0)
        position, centre = np.array([2.0, 2.5, 1.1]), np.array([2.95, 2.5, 1.1])  # looking along +x, 0.95 m
        reply = self.srv["CalculateCameraPoseCorrection"](
            state_to_msg(state), Quaternion(0, 0, 0, 1), Vector3(*position)
        )
        corrected = RobotState(reply.pan, reply.tilt, state.rotation, state.x, state.y)
        camera = pose_to_matrix(self.srv["CalculateCameraPose"](state_to_msg(corrected)).cameraFrame)
        self.assertLess(facing_error_deg(camera, centre), 0.1)

    def test_map_services(self):
        self.assertAlmostEqual(self.srv["GetDistance"](Point(3, 2, 0), Point(7, 1, 0)).distance, math.hypot(4, 1))
        self.assertTrue(self.srv["IsPositionAllowed"](Point(1.0, 1.0, 0.0)).isAllowed)
        self.assertFalse(self.srv["IsPositionAllowed"](Point(2.5, 4.5, 0.0)).isAllowed)  # table
        self.assertFalse(self.srv["IsPositionAllowed"](Point(5.3, 2.0, 0.0)).isAllowed)  # beside the wall
        self.assertFalse(self.srv["IsPositionAllowed"](Point(9.8, 0.3, 0.0)).isAllowed)  # unknown

    def test_ik_markers_are_published(self):
        namespaces, done = set(), threading.Event()

        def on_marker(marker):
            namespaces.add(marker.ns)
            if "iterationVector" in namespaces and "camToActualViewCenterVector" in namespaces:
                done.set()

        subscriber = rospy.Subscriber(f"{NS}/IK_Visualization", Marker, on_marker)
        deadline = rospy.get_time() + 10.0
        while subscriber.get_num_connections() == 0 and rospy.get_time() < deadline:
            rospy.sleep(0.05)
        reply = self.srv["CalculateRobotState"](
            state_to_msg(RobotState(0.0, 0.0, 0.0, 1.0, 1.0)), Quaternion(0, 0, 0, 1), Vector3(2, 2, 1.3)
        )
        self.assertTrue(reply.success)
        self.assertTrue(done.wait(10.0), f"IK markers missing; got {sorted(namespaces)}")
        subscriber.unregister()
        self.assertIn("targetCameraVector", namespaces)

    def test_frustum_and_map_topics(self):
        frustum = rospy.wait_for_message("/nbv/frustum_marker_array", MarkerArray, timeout=10.0)
        self.assertEqual(frustum.markers[0].type, Marker.LINE_LIST)
        self.assertEqual(len(frustum.markers[0].points), 24)
        self.assertEqual(frustum.markers[0].header.frame_id, "map")
        grid = rospy.wait_for_message("/map", OccupancyGrid, timeout=10.0)
        self.assertEqual((grid.info.width, grid.info.height), (240, 180))
        self.assertEqual(set(grid.data), {-1, 0, 100})
        costmap = rospy.wait_for_message(f"{NS}/costmap", OccupancyGrid, timeout=10.0)
        self.assertIn(99, set(costmap.data))


if __name__ == "__main__":
    rostest.rosrun("agiprobot_measurement", "mild_robot_model_services", RobotModelServicesTest)
