#!/usr/bin/env python3
"""rostest: the MILD robot model services as the original package's clients see them.

The client imports only ``asr_robot_model_services.srv`` / ``.msg`` (as the original's rsc/SetFocusPoint.py does),
calls the six services of the original's RobotModel_Service.cpp (CalculateCameraPose, CalculateCameraPoseCorrection,
GetDistance, GetRobotPose and GetCameraPose (both GetPose), IsPositionAllowed) against
RobotModelServiceSim.launch and checks what ``rosservice type`` names them. A second node started with no parameters
runs with the original's defaults (pan +-60 deg, tilt +-45 deg), reads the map from /map and publishes none; a
third, with no map to read, answers the map's services with an error naming /map.
"""

import math
import subprocess
import unittest

import numpy as np
import rosgraph
import rospy
import rostest
from asr_robot_model_services.msg import RobotStateMessage
from asr_robot_model_services.srv import (
    CalculateCameraPose,
    CalculateCameraPoseCorrection,
    GetDistance,
    GetPose,
    IsPositionAllowed,
)
from geometry_msgs.msg import Point, Quaternion
from nav_msgs.msg import OccupancyGrid

SIM = "/asr_robot_model_services"
BARE = "/bare_robot_model_services"
MAPLESS = "/mapless_robot_model_services"
UPSTREAM_SERVICES = {
    "CalculateCameraPose": CalculateCameraPose,
    "CalculateCameraPoseCorrection": CalculateCameraPoseCorrection,
    "GetDistance": GetDistance,
    "GetRobotPose": GetPose,
    "GetCameraPose": GetPose,
    "IsPositionAllowed": IsPositionAllowed,
}
TYPE_NAMES = {
    "CalculateCameraPose": "asr_robot_model_services/CalculateCameraPose",
    "CalculateCameraPoseCorrection": "asr_robot_model_services/CalculateCameraPoseCorrection",
    "GetDistance": "asr_robot_model_services/GetDistance",
    "GetRobotPose": "asr_robot_model_services/GetPose",
    "GetCameraPose": "asr_robot_model_services/GetPose",
    "IsPositionAllowed": "asr_robot_model_services/IsPositionAllowed",
}


def proxies(namespace: str) -> dict:
    out = {}
    for name, service_type in UPSTREAM_SERVICES.items():
        rospy.wait_for_service(f"{namespace}/{name}", timeout=30.0)
        out[name] = rospy.ServiceProxy(f"{namespace}/{name}", service_type)
    return out


def state(pan_deg=0.0, tilt_deg=0.0, rotation=0.0, x=1.0, y=1.0) -> RobotStateMessage:
    return RobotStateMessage(pan=math.radians(pan_deg), tilt=math.radians(tilt_deg), rotation=rotation, x=x, y=y)


def position_of(pose) -> np.ndarray:
    return np.array([pose.position.x, pose.position.y, pose.position.z])


def view_axis(pose) -> np.ndarray:
    """The camera mount's +x (its view axis) from a geometry_msgs/Pose."""
    x, y, z, w = pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w
    return np.array([1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)])


class UpstreamNamesMildTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("test_upstream_names_mild")
        cls.sim = proxies(SIM)
        cls.bare = proxies(BARE)
        cls.mapless = proxies(MAPLESS)

    def test_rosservice_type_names_the_upstream_types(self):
        for name, expected in TYPE_NAMES.items():
            out = subprocess.run(
                ["rosservice", "type", f"{SIM}/{name}"], capture_output=True, text=True, timeout=20, check=True
            ).stdout.strip()
            self.assertEqual(out, expected)
            self.assertEqual(UPSTREAM_SERVICES[name]._type, expected)

    def test_the_six_services_answer(self):
        srv = self.sim
        self.assertAlmostEqual(srv["GetDistance"](Point(0, 0, 0), Point(3, 4, 0)).distance, 5.0)
        here = state()
        camera = srv["CalculateCameraPose"](here).cameraFrame
        self.assertGreater(camera.position.z, 1.0)  # on the mast
        np.testing.assert_allclose(view_axis(camera), [1, 0, 0], atol=1e-9)
        # the simulated MILD stands at the launch file's initial state [0, 0, 0, 1, 1]
        robot = srv["GetRobotPose"]().pose
        np.testing.assert_allclose(position_of(robot), [1.0, 1.0, 0.0], atol=1e-6)
        np.testing.assert_allclose(position_of(srv["GetCameraPose"]().pose), position_of(camera), atol=1e-4)
        # the original's SetFocusPoint.py asks for the camera position (ncp + fcp) / 2 in front of the focus point
        focus = np.array([2.6, 1.3, 0.9])
        distance = 0.5 * (rospy.get_param(f"{SIM}/ncp") + rospy.get_param(f"{SIM}/fcp"))
        correction = srv["CalculateCameraPoseCorrection"](
            here, Quaternion(0, 0, 0, 1), Point(focus[0] - distance, focus[1], focus[2])
        )
        aimed = srv["CalculateCameraPose"](
            state(math.degrees(correction.pan), math.degrees(correction.tilt))
        ).cameraFrame
        to_focus = focus - position_of(aimed)
        angle = math.degrees(math.acos(np.clip(view_axis(aimed) @ to_focus / np.linalg.norm(to_focus), -1, 1)))
        self.assertLess(angle, 0.1)
        self.assertTrue(srv["IsPositionAllowed"](Point(1.0, 1.0, 0.0)).isAllowed)
        self.assertFalse(srv["IsPositionAllowed"](Point(2.5, 4.5, 0.0)).isAllowed)  # the table
        self.assertFalse(srv["IsPositionAllowed"](Point(9.8, 0.3, 0.0)).isAllowed)  # unknown

    def test_simulation_settings_are_the_originals(self):
        self.assertEqual((rospy.get_param(f"{SIM}/panMin"), rospy.get_param(f"{SIM}/panMax")), (-20, 20))
        self.assertIs(rospy.get_param(f"{SIM}/visualizeIK"), True)
        self.assertEqual(rospy.get_param(f"{SIM}/global_costmap/inflation_layer/inflation_radius"), 0.65)
        with self.assertRaises(rospy.ServiceException) as caught:
            self.sim["CalculateCameraPose"](state(pan_deg=30.0))
        self.assertIn("[-20.0, 20.0]", str(caught.exception))

    def test_no_parameters_give_the_originals_defaults(self):
        self.assertFalse(rospy.has_param(f"{BARE}/panMax"))
        # pan within +-60 deg, tilt within +-45 deg
        self.bare["CalculateCameraPose"](state(pan_deg=59.0, tilt_deg=44.0))
        for pan, tilt, words in ((61.0, 0.0, "[-60.0, 60.0]"), (0.0, 46.0, "[-45.0, 45.0]")):
            with self.assertRaises(rospy.ServiceException) as caught:
                self.bare["CalculateCameraPose"](state(pan_deg=pan, tilt_deg=tilt))
            self.assertIn(words, str(caught.exception))
        self.assertEqual(rospy.get_param(f"{BARE}/IKAngleRatingInUse"), "SIMPLE")
        # the frames default to the original's names: its poses come from the same tf
        np.testing.assert_allclose(
            position_of(self.bare["GetCameraPose"]().pose), position_of(self.sim["GetCameraPose"]().pose), atol=1e-4
        )

    def test_map_is_read_from_slash_map_and_published_only_when_asked(self):
        # the bare node (publishMap off) answers from the map the simulation's node publishes on /map
        for point, allowed in ((Point(1.0, 1.0, 0), True), (Point(2.5, 4.5, 0), False), (Point(9.8, 0.3, 0), False)):
            self.assertEqual(self.bare["IsPositionAllowed"](point).isAllowed, allowed)
        publishers = dict(rosgraph.Master("/test_upstream_names_mild").getSystemState()[0])
        self.assertEqual(publishers["/map"], [SIM])
        grid = rospy.wait_for_message(f"{BARE}/costmap", OccupancyGrid, timeout=10.0)  # its inflation of /map
        self.assertIn(99, set(grid.data))

    def test_without_a_map_the_map_services_name_the_topic(self):
        with self.assertRaises(rospy.ServiceException) as caught:
            self.mapless["IsPositionAllowed"](Point(1.0, 1.0, 0.0))
        self.assertIn("no map received on /map", str(caught.exception))
        # services that need no map keep working
        self.assertAlmostEqual(self.mapless["GetDistance"](Point(0, 0, 0), Point(3, 4, 0)).distance, 5.0)
        self.mapless["CalculateCameraPose"](state())


if __name__ == "__main__":
    rostest.rosrun("agiprobot_measurement", "upstream_names_mild", UpstreamNamesMildTest)
