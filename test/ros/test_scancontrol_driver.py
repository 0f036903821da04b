#!/usr/bin/env python3
"""rostest: the simulated scanCONTROL driver offers what micro_epsilon_scancontrol_driver (ROS 1) offers, and its
profiles lie in the sensor frame (x along the line, y = 0, z = distance; no return = +Inf)."""

import sys
import threading
import time
import unittest
from pathlib import Path

import numpy as np
import rosgraph
import rospy
import rosservice
import rostest
from micro_epsilon_scancontrol_msgs.srv import (
    GetAvailableResolutions,
    GetFeature,
    GetResolution,
    SetFeature,
    SetResolution,
)
from sensor_msgs.msg import PointCloud2, PointField
from std_srvs.srv import SetBool

from agiprobot_measurement.common.config import read_yaml
from agiprobot_measurement.sensors.laser_line.scancontrol import (
    FEATURE_FUNCTION_IDLETIME,
    FEATURE_FUNCTION_PROCESSING_PROFILEDATA,
    FEATURE_FUNCTION_SHUTTERTIME,
    GENERAL_FUNCTION_OK,
    INVERT_X_BIT,
)
from agiprobot_measurement.station import PACKAGE_ROOT

sys.path.insert(0, str(Path(__file__).resolve().parent))
from scanner_test_utils import PLATE_DISTANCE_MM, place_plate, profile_array

NODE = "/scancontrol_driver"
TOPIC = "/scancontrol_pointcloud"
UPSTREAM = read_yaml(PACKAGE_ROOT / "test/core/architecture/upstream_md5/micro_epsilon_scancontrol_msgs.yaml")
SERVICES = {
    "get_feature": GetFeature,
    "set_feature": SetFeature,
    "get_resolution": GetResolution,
    "set_resolution": SetResolution,
    "get_available_resolutions": GetAvailableResolutions,
}


class ScanControlDriverTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("scancontrol_client")
        cls.lock = threading.Lock()
        cls.messages = []
        rospy.Subscriber(TOPIC, PointCloud2, cls._on_profile, queue_size=1000, buff_size=2**24)
        for name in [*SERVICES, "invert_x", "invert_z", "set_target"]:
            rospy.wait_for_service(f"{NODE}/{name}", timeout=60.0)

    @classmethod
    def _on_profile(cls, msg):
        with cls.lock:
            cls.messages.append(msg)

    def collect(self, seconds: float) -> list:
        with self.lock:
            self.messages.clear()
        time.sleep(seconds)
        with self.lock:
            return list(self.messages)

    def call(self, name, *args):
        return rospy.ServiceProxy(f"{NODE}/{name}", SERVICES.get(name, SetBool))(*args)

    def test_1_topic_and_message_layout(self):
        publishers = dict(rosgraph.Master("/test").getTopicTypes())
        self.assertEqual(publishers.get(TOPIC), "sensor_msgs/PointCloud2")
        messages = self.collect(2.0)
        self.assertGreater(len(messages), 50, "profiles at 100 Hz")
        msg = messages[-1]
        self.assertEqual(
            [(f.name, f.offset, f.datatype, f.count) for f in msg.fields],
            [(n, 4 * i, PointField.FLOAT32, 1) for i, n in enumerate("x y z intensity".split())],
        )
        self.assertEqual((msg.height, msg.width, msg.point_step), (1, 640, 16))
        self.assertEqual(msg.header.frame_id, "scancontrol_aperture_frame")
        # one profile per sensor period (10 ms), stamped at its exposure
        stamps = np.array([m.header.stamp.to_sec() for m in messages])
        np.testing.assert_allclose(np.diff(stamps), 0.01, atol=1e-6)
        # the timestamp's 4 last points never have a return
        self.assertTrue(np.all(np.isposinf(profile_array(msg)[-4:, 2])))

    def test_2_services_have_the_driver_types_and_md5(self):
        for name, service_class in SERVICES.items():
            full = f"{NODE}/{name}"
            self.assertEqual(rosservice.get_service_type(full), service_class._type)
            self.assertEqual(service_class._md5sum, UPSTREAM[f"srv/{service_class._type.split('/')[1]}.srv"])
        for name in ("invert_x", "invert_z"):
            self.assertEqual(rosservice.get_service_type(f"{NODE}/{name}"), "std_srvs/SetBool")

    def test_3_resolutions(self):
        reply = self.call("get_available_resolutions")
        self.assertEqual(list(reply.resolutions), [640, 320, 160])
        self.assertEqual(reply.return_code, 3)
        self.assertEqual(self.call("get_resolution").resolution, 640)
        self.assertLess(self.call("set_resolution", 500).return_code, 0)
        self.assertEqual(self.call("set_resolution", 320).return_code, GENERAL_FUNCTION_OK)
        try:
            self.assertEqual(self.call("get_resolution").resolution, 320)
            time.sleep(0.5)
            self.assertEqual({m.width for m in self.collect(1.0)}, {320})
        finally:
            self.assertEqual(self.call("set_resolution", 640).return_code, GENERAL_FUNCTION_OK)

    def test_4_features_set_the_profile_rate_and_inversion(self):
        shutter = self.call("get_feature", FEATURE_FUNCTION_SHUTTERTIME)
        idle = self.call("get_feature", FEATURE_FUNCTION_IDLETIME)
        self.assertEqual((shutter.return_code, idle.return_code), (GENERAL_FUNCTION_OK, GENERAL_FUNCTION_OK))
        self.assertEqual(shutter.value + idle.value, 1000)  # 10 ms in 10 us units
        self.assertEqual(self.call("set_feature", FEATURE_FUNCTION_IDLETIME, 400).return_code, GENERAL_FUNCTION_OK)
        try:
            time.sleep(0.5)
            stamps = np.array([m.header.stamp.to_sec() for m in self.collect(1.0)])
            np.testing.assert_allclose(np.diff(stamps), (shutter.value + 400) * 1e-5, atol=1e-6)
        finally:
            self.call("set_feature", FEATURE_FUNCTION_IDLETIME, idle.value)
        self.assertLess(self.call("get_feature", 0x12345678).return_code, 0)
        self.assertTrue(self.call("invert_x", False).success)
        try:
            value = self.call("get_feature", FEATURE_FUNCTION_PROCESSING_PROFILEDATA).value
            self.assertEqual(value & INVERT_X_BIT, 0)
        finally:
            self.assertTrue(self.call("invert_x", True).success)

    def test_5_profiles_lie_in_the_sensor_frame(self):
        # before a target: no return anywhere
        self.assertTrue(all(np.all(np.isposinf(profile_array(m)[:, 2])) for m in self.collect(0.5)))
        place_plate()
        time.sleep(0.5)
        points = profile_array(self.collect(0.5)[-1])
        finite = np.isfinite(points[:, 2])
        self.assertEqual(int(finite.sum()), 640 - 4, "the whole fan sees the plate")
        self.assertTrue(np.all(points[finite, 1] == 0.0))
        np.testing.assert_allclose(points[finite, 2], PLATE_DISTANCE_MM / 1000.0, atol=0.002)
        x = points[finite, 0]
        self.assertTrue(np.all(np.diff(x) > 0), "x runs along the laser line")
        self.assertAlmostEqual(float(x[0] + x[-1]), 0.0, delta=0.002)  # the fan is symmetric about z


if __name__ == "__main__":
    rostest.rosrun("agiprobot_measurement", "scancontrol_driver_interface", ScanControlDriverTest)
