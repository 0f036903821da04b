#!/usr/bin/env python3
"""rostest: a client that knows only the real driver's package names drives the simulated PhoXi scanner.

The launch file is the driver's (``roslaunch phoxi_camera phoxi_camera.launch``); this client imports nothing of
agiprobot_measurement, only ``phoxi_camera.srv``/``phoxi_camera.msg`` and ROS itself, as a script written for the
real scanner would. It connects explicitly, triggers and publishes the triggered frame with ``get_frame(id)``, saves
frames to a relative and a /tmp path, reconfigures through dynamic_reconfigure and switches coordinate spaces; the
services' types are the driver's (``rosservice type``).
"""

import os
import subprocess
import threading
import time
import unittest

import numpy as np
import rospkg
import rospy
import rosservice
import rostest
from dynamic_reconfigure.client import Client as ReconfigureClient
from geometry_msgs.msg import Quaternion, Transform, Vector3
from phoxi_camera.msg import DeviceInformation
from phoxi_camera.srv import (
    ConnectCamera,
    Empty,
    GetBool,
    GetDeviceList,
    GetFrame,
    GetSupportedCapturingModes,
    SaveFrame,
    SetCoordinatesSpace,
    SetTransformationMatrix,
    TriggerImage,
)
from sensor_msgs.msg import PointCloud2
from std_srvs.srv import Empty as StdEmpty

NODE = "/phoxi_camera"
#: the driver's service names and types (photoneo/phoxi_camera 1.8.0, src/RosInterface.cpp)
DRIVER_SERVICES = {
    "get_device_list": "phoxi_camera/GetDeviceList",
    "connect_camera": "phoxi_camera/ConnectCamera",
    "disconnect_camera": "std_srvs/Empty",
    "is_connected": "phoxi_camera/IsConnected",
    "is_acquiring": "phoxi_camera/IsAcquiring",
    "V2/is_connected": "phoxi_camera/GetBool",
    "V2/is_acquiring": "phoxi_camera/GetBool",
    "start_acquisition": "std_srvs/Empty",
    "stop_acquisition": "std_srvs/Empty",
    "V2/start_acquisition": "phoxi_camera/Empty",
    "V2/stop_acquisition": "phoxi_camera/Empty",
    "trigger_image": "phoxi_camera/TriggerImage",
    "get_frame": "phoxi_camera/GetFrame",
    "save_frame": "phoxi_camera/SaveFrame",
    "V2/save_last_frame": "phoxi_camera/SaveLastFrame",
    "get_hardware_indentification": "phoxi_camera/GetHardwareIdentification",
    "get_supported_capturing_modes": "phoxi_camera/GetSupportedCapturingModes",
    "get_api_version": "phoxi_camera/GetString",
    "get_firmware_version": "phoxi_camera/GetString",
    "V2/set_coordinate_space": "phoxi_camera/SetCoordinatesSpace",
    "V2/set_transformation": "phoxi_camera/SetTransformationMatrix",
}
CAMERA_SPACE, CUSTOM_SPACE = 1, 5
SHIFT_M = 0.1


def proxy(name, kind):
    rospy.wait_for_service(f"{NODE}/{name}", timeout=60.0)
    return rospy.ServiceProxy(f"{NODE}/{name}", kind)


class CloudCatcher:
    """Keeps the clouds published on /phoxi_camera/pointcloud; ``wait_for(seq)`` returns the frame with that seq."""

    def __init__(self):
        self.clouds = []
        self.condition = threading.Condition()
        self.subscriber = rospy.Subscriber(f"{NODE}/pointcloud", PointCloud2, self._keep, queue_size=10)
        deadline = time.monotonic() + 10.0
        while self.subscriber.get_num_connections() == 0 and time.monotonic() < deadline:
            rospy.sleep(0.05)

    def _keep(self, msg):
        with self.condition:
            self.clouds.append(msg)
            self.condition.notify_all()

    def wait_for(self, seq, timeout_s=60.0):
        deadline = time.monotonic() + timeout_s
        with self.condition:
            while True:
                found = [c for c in self.clouds if c.header.seq == seq]
                if found:
                    return found[-1]
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return None
                self.condition.wait(remaining)

    def latest_seq(self):
        with self.condition:
            return max((c.header.seq for c in self.clouds), default=-1)


def xyz(cloud):
    """(N, 3) float points of a cloud with float32 x, y, z fields (the driver's pcl::PointNormal layout)."""
    offsets = {f.name: f.offset for f in cloud.fields}
    raw = np.frombuffer(bytes(cloud.data), dtype=np.uint8).reshape(-1, cloud.point_step)
    return np.stack([raw[:, offsets[a] : offsets[a] + 4].copy().view("<f4")[:, 0] for a in "xyz"], axis=1)


def valid_centroid(cloud):
    points = xyz(cloud).astype(float)
    valid = np.all(np.isfinite(points), axis=1) & (np.linalg.norm(points, axis=1) > 0)
    assert valid.sum() > 1000, f"only {valid.sum()} valid points"
    return points[valid].mean(axis=0)


class UpstreamNamesClient(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("upstream_names_client", anonymous=True)
        for name in DRIVER_SERVICES:
            rospy.wait_for_service(f"{NODE}/{name}", timeout=60.0)
        cls.clouds = CloudCatcher()
        devices = proxy("get_device_list", GetDeviceList)()
        assert devices.success and devices.len >= 1, devices
        cls.scanner_id = devices.out[0]
        connected = proxy("connect_camera", ConnectCamera)(name=cls.scanner_id)
        assert connected.success, connected.message
        started = proxy("V2/start_acquisition", Empty)()
        assert started.success, started.message

    def frame(self, frame_id=None):
        """Trigger (unless a frame id is given) and publish that frame with get_frame(id); the published cloud."""
        if frame_id is None:
            triggered = proxy("trigger_image", TriggerImage)()
            self.assertTrue(triggered.success, triggered.message)
            frame_id = triggered.id
        self.assertGreaterEqual(frame_id, 0)
        answer = proxy("get_frame", GetFrame)(frame_id)  # the request's field is `in`: positional, as Python must
        self.assertTrue(answer.success, answer.message)
        self.assertEqual(answer.message, "Ok")
        cloud = self.clouds.wait_for(frame_id)
        self.assertIsNotNone(cloud, f"no cloud with seq {frame_id} after get_frame({frame_id})")
        return frame_id, cloud

    def test_services_have_the_driver_types(self):
        for name, kind in DRIVER_SERVICES.items():
            self.assertEqual(rosservice.get_service_type(f"{NODE}/{name}"), kind, name)
        # the command line, as a user checks it
        out = subprocess.run(
            ["rosservice", "type", f"{NODE}/get_frame"], capture_output=True, text=True, timeout=60, check=True
        )
        self.assertEqual(out.stdout.strip(), "phoxi_camera/GetFrame")

    def test_device_list_is_of_release_1_8_0(self):
        devices = proxy("get_device_list", GetDeviceList)()
        self.assertTrue(devices.success, devices.message)
        info = devices.device_information_list[0]
        self.assertIsInstance(info, DeviceInformation)
        self.assertEqual(info.hwIdentification, self.scanner_id)
        self.assertIsInstance(info.variant, str)  # the fields 1.8.0 added
        self.assertIsInstance(info.isAlpha, bool)
        self.assertTrue(proxy("V2/is_connected", GetBool)().value)

    def test_driver_parameters_come_from_the_driver_file(self):
        self.assertEqual(rospy.get_param(f"{NODE}/frame_id"), "PhoXi3Dscanner_sensor")
        self.assertIs(rospy.get_param(f"{NODE}/init_from_config"), False)
        self.assertEqual(rospy.get_param(f"{NODE}/topic_queue_size"), 1)

    def test_trigger_then_get_frame_publishes_that_frame(self):
        frame_id, cloud = self.frame()
        self.assertEqual(cloud.header.frame_id, "PhoXi3Dscanner_sensor")
        self.assertEqual(cloud.header.seq, frame_id)
        self.assertEqual(cloud.point_step, 48)
        # get_frame(-1) takes a new frame and publishes it
        before = self.clouds.latest_seq()
        answer = proxy("get_frame", GetFrame)(-1)
        self.assertTrue(answer.success, answer.message)
        deadline = time.monotonic() + 60.0
        while self.clouds.latest_seq() <= before and time.monotonic() < deadline:
            rospy.sleep(0.05)
        self.assertGreater(self.clouds.latest_seq(), before)

    def test_save_frame_to_a_relative_and_a_tmp_path(self):
        frame_id, _ = self.frame()
        save = proxy("save_frame", SaveFrame)
        relative = f"upstream_names_{os.getpid()}.ply"
        # a relative path is the node's working directory: ROS_HOME, where roslaunch starts nodes
        written = os.path.join(rospkg.get_ros_home(), relative)
        tmp = f"/tmp/upstream_names_{os.getpid()}.ply"
        try:
            for path, expected in ((relative, written), (tmp, tmp)):
                answer = save(frame_id, path)
                self.assertTrue(answer.success, f"{path}: {answer.message}")
                with open(expected, "rb") as ply:
                    self.assertEqual(ply.readline().strip(), b"ply")
                self.assertGreater(os.path.getsize(expected), 1000)
        finally:
            for path in (written, tmp):
                if os.path.exists(path):
                    os.remove(path)

    def test_reconfigure_resolution_through_dynamic_reconfigure(self):
        modes = proxy("get_supported_capturing_modes", GetSupportedCapturingModes)()
        self.assertTrue(modes.success, modes.message)
        sizes = {(m.Width, m.Height) for m in modes.supported_capturing_modes}
        self.assertIn((2064, 1544), sizes)
        client = ReconfigureClient(NODE, timeout=30)
        try:
            try:
                self.assertEqual(client.update_configuration({"resolution": 0})["resolution"], 0)
                _, low = self.frame()
                self.assertEqual((low.width, low.height), (1032, 772))
            finally:
                client.update_configuration({"resolution": 1})
            _, high = self.frame()
            self.assertEqual((high.width, high.height), (2064, 1544))
        finally:
            client.close()

    def test_coordinate_spaces(self):
        set_space = proxy("V2/set_coordinate_space", SetCoordinatesSpace)
        set_transformation = proxy("V2/set_transformation", SetTransformationMatrix)
        self.assertTrue(set_space(CAMERA_SPACE).success)
        try:
            camera = valid_centroid(self.frame()[1])
            shift = Transform(translation=Vector3(0.0, 0.0, SHIFT_M), rotation=Quaternion(0.0, 0.0, 0.0, 1.0))
            answer = set_transformation(shift, CUSTOM_SPACE, True, False)
            self.assertTrue(answer.success, answer.message)
            custom = valid_centroid(self.frame()[1])
            # a pure translation moves every point by it (in one direction or the other, as the space is defined)
            np.testing.assert_allclose(np.abs(custom - camera), [0.0, 0.0, SHIFT_M], atol=0.01)
        finally:
            self.assertTrue(set_space(CAMERA_SPACE).success)
        back = valid_centroid(self.frame()[1])
        np.testing.assert_allclose(back, camera, atol=0.01)

    def test_zz_disconnect_and_connect_again(self):
        proxy("disconnect_camera", StdEmpty)()
        self.assertFalse(proxy("V2/is_connected", GetBool)().value)
        self.assertTrue(proxy("connect_camera", ConnectCamera)(name=self.scanner_id).success)
        self.assertTrue(proxy("V2/is_connected", GetBool)().value)


if __name__ == "__main__":
    rostest.rosrun("agiprobot_measurement", "upstream_names", UpstreamNamesClient)
