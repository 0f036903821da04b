#!/usr/bin/env python3
"""rostest: the stitcher switches with the original's SetBool, stitches exactly the profiles stamped while it was
on (the reply to switching off waits for them), clears with the original's Trigger, and its cloud lies on the part
in the world frame."""

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
from sensor_msgs.msg import PointCloud, PointCloud2
from std_msgs.msg import Bool
from std_srvs.srv import SetBool, Trigger

from agiprobot_measurement.ros.conversions import cloud_xyz

sys.path.insert(0, str(Path(__file__).resolve().parent))
from scanner_test_utils import PLATE_SIZE_MM, place_plate

#: the plate's lower face is where the stitched points must lie (mm): the simulated noise is far below this
ON_PLANE_MM = 0.5


class PointCloudStitcherTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("stitcher_client")
        cls.lock = threading.Lock()
        cls.stamps = []
        cls.measured = None
        cls.stitched = None
        cls.stitching = []
        rospy.Subscriber("/scancontrol_pointcloud", PointCloud2, cls._on_profile, queue_size=1000, buff_size=2**24)
        rospy.Subscriber("/laser_scanner/measured_cloud", PointCloud2, cls._on_measured, queue_size=1, buff_size=2**26)
        rospy.Subscriber("/stitched_point_cloud", PointCloud, cls._on_stitched, queue_size=1, buff_size=2**26)
        rospy.Subscriber("/laser_scanner/stitching", Bool, lambda m: cls.stitching.append(m.data), queue_size=10)
        for name in ("/switch_stitch_mode", "/clear_stitched_point_cloud", "/laser_scanner/publish_measured_cloud"):
            rospy.wait_for_service(name, timeout=60.0)
        cls.switch = rospy.ServiceProxy("/switch_stitch_mode", SetBool)
        cls.clear = rospy.ServiceProxy("/clear_stitched_point_cloud", Trigger)
        cls.face = place_plate()

    @classmethod
    def _on_profile(cls, msg):
        with cls.lock:
            cls.stamps.append(msg.header.stamp.to_sec())

    @classmethod
    def _on_measured(cls, msg):
        with cls.lock:
            cls.measured = msg

    @classmethod
    def _on_stitched(cls, msg):
        with cls.lock:
            cls.stitched = msg

    def measured_cloud(self) -> tuple[np.ndarray, str]:
        with self.lock:
            type(self).measured = None  # the callback sets the class attribute
        reply = rospy.ServiceProxy("/laser_scanner/publish_measured_cloud", Trigger)()
        deadline = time.monotonic() + 10.0
        while self.measured is None and time.monotonic() < deadline:
            time.sleep(0.05)
        self.assertIsNotNone(self.measured)
        self.assertEqual(self.measured.header.frame_id, "world")
        return cloud_xyz(self.measured), reply.message

    def test_1_names_and_types(self):
        self.assertEqual(rosservice.get_service_type("/switch_stitch_mode"), "std_srvs/SetBool")
        self.assertEqual(rosservice.get_service_type("/clear_stitched_point_cloud"), "std_srvs/Trigger")
        self.assertEqual(
            dict(rosgraph.Master("/test").getTopicTypes()).get("/stitched_point_cloud"), "sensor_msgs/PointCloud"
        )

    def test_2_stitches_the_profiles_of_the_window_onto_the_part(self):
        self.assertTrue(self.clear().success)
        time.sleep(0.5)
        before_on = rospy.Time.now().to_sec()
        reply = self.switch(True)
        after_on = rospy.Time.now().to_sec()
        self.assertEqual((reply.success, reply.message), (True, "activated stitching"))
        time.sleep(1.0)
        before_off = rospy.Time.now().to_sec()
        reply = self.switch(False)
        after_off = rospy.Time.now().to_sec()
        self.assertEqual((reply.success, reply.message), (True, "deactivated stitching"))
        # the latched state topic travels on its own connection: it may arrive after the service's reply
        deadline = time.monotonic() + 5.0
        while self.stitching[-2:] != [True, False] and time.monotonic() < deadline:
            time.sleep(0.02)
        self.assertEqual(self.stitching[-2:], [True, False])
        points, message = self.measured_cloud()
        profiles = int(message.split(" from ")[1].split()[0])
        # every profile stamped inside the window, and no other (the window's ends lie within the calls)
        time.sleep(0.5)
        with self.lock:
            stamps = np.array(self.stamps)
        surely_in = np.sum((stamps >= after_on) & (stamps <= before_off))
        maybe_in = np.sum((stamps >= before_on) & (stamps <= after_off))
        self.assertGreaterEqual(profiles, surely_in)
        self.assertLessEqual(profiles, maybe_in)
        self.assertGreater(profiles, 80)
        self.assertEqual(len(points), profiles * (640 - 4))
        # the points lie on the plate's lower face, in the world frame
        local = (points * 1000.0 - self.face[:3, 3]) @ self.face[:3, :3]
        self.assertLess(float(np.max(np.abs(local[:, 2]))), ON_PLANE_MM)
        self.assertTrue(np.all(np.abs(local[:, :2]) < PLATE_SIZE_MM[0] / 2.0))
        # the original's latched PointCloud carries the (thinned) cloud: the one published at the switch-off (while
        # stitching it is published at 1 Hz with what had come so far)
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline and (
            self.stitched is None or not self.stitched.points or self.stitched.header.stamp.to_sec() < before_off
        ):
            time.sleep(0.05)
        self.assertEqual(self.stitched.header.frame_id, "world")
        # the robot stands: every profile lies on one line of about 100 mm, about 100 voxels of 1 mm once thinned
        thinned = np.array([(p.x, p.y, p.z) for p in self.stitched.points])
        self.assertGreater(len(thinned), 50)
        local = (thinned * 1000.0 - self.face[:3, 3]) @ self.face[:3, :3]
        self.assertLess(float(np.max(np.abs(local[:, 2]))), ON_PLANE_MM)

    def test_3_clear_and_off_stitch_nothing(self):
        reply = self.clear()
        self.assertTrue(reply.success)
        time.sleep(1.0)  # stitching is off: nothing comes in
        points, _ = self.measured_cloud()
        self.assertEqual(len(points), 0)
        self.assertEqual(self.switch(False).message, "deactivated stitching")  # off twice is fine


if __name__ == "__main__":
    rostest.rosrun("agiprobot_measurement", "point_cloud_stitcher", PointCloudStitcherTest)
