#!/usr/bin/env python3
"""rostest: the Photoneo driver's own interface tests, run against the simulated PhoXi scanner.

photoneo/phoxi_camera release 1.8.0 ships two Python rostests (test/interfaces/, run by test/launch/
phoxi_camera_ros_interfaces_exist.test and phoxi_camera_ros_interfaces.test against PhoXi Control with the file
camera ``InstalledExamples-basic-example``): 5 cases that check the node, its topics, services and parameters exist
(class :class:`InterfacesExist`, argument ``exist``) and 18 that call every service and check the answers (class
:class:`RosInterfaces`, argument ``interfaces``). The 23 cases are re-expressed here with the same names, steps,
waits and expected values.

Changes against the upstream cases (the whole list):

1. Python 3 and this package: one script, the class chosen by the argument the .test passes; ``rospy.init_node``
   once per process instead of in every ``setUp`` (the upstream calls it again with the same arguments, which
   rospy accepts and ignores); ``os.remove`` instead of ``os.system("rm -f ...")``; the message counter of
   test_getFrame is the test's own (upstream: a module global), under a lock.
2. test_getFrame waits (at most 10 s) until its four subscribers are connected before it calls get_frame: the
   upstream calls get_frame right after creating them, which races the subscriptions on any node (a publish before
   the connection is lost, on the real driver as well).
3. test_saveLastFrameV2: ``file.ply`` and ``file.ptx`` are saved and must appear as upstream; for ``file.praw``
   (PhoXi Control's raw format) the case expects the simulator's refusal instead of a file: ``success`` false, a
   message starting "Unsuccessful save" (the driver's own wording for a failed save), no file written. The
   simulator deliberately writes no stand-in that PhoXi Control could not open (docs/phoxi.md, "Raw formats").
4. The machine around the test (test_phoxi_driver_tests.test, not this file): the simulated PhoXi Control lists the
   file camera ``InstalledExamples-basic-example`` whose recording, as the upstream test's comment says, has no
   confidence map (``frame_outputs`` in ``~devices``); the simulator renders every 4th pixel (``~pixel_step``).

Everything else is as upstream: the camera id, the service timeout of 1 s, the 1 s waits after connect and
disconnect, the 5 s waits after get_frame and trigger_image, the files saved in the test's working directory (ROS_HOME
under rostest, an allowed folder of the simulator), and every assertion.
"""

import os
import sys
import threading
import time
import unittest

import geometry_msgs.msg
import rosnode
import rospy
import rostest
import sensor_msgs.msg
import std_srvs.srv
from phoxi_camera import srv as phoxi_srv

PKG = "agiprobot_measurement"
#: the upstream configuration (test/interfaces/config.py): PhoXi Control's example file camera, node, 1 s timeout
CAMERA_ID = "InstalledExamples-basic-example"
NODE = "/phoxi_camera"
SERVICE_TIMEOUT_S = 1.0
#: the upstream waits (s): after connect / disconnect, and for frames after get_frame / trigger_image
SETTLE_S = 1.0
FRAME_WAIT_S = 5.0

TOPICS = ("confidence_map", "normal_map", "parameter_descriptions", "parameter_updates", "pointcloud", "texture")
SERVICES = (
    "connect_camera",
    "disconnect_camera",
    "get_device_list",
    "get_frame",
    "get_hardware_indentification",  # the driver's spelling
    "get_loggers",
    "get_supported_capturing_modes",
    "is_acquiring",
    "is_connected",
    "save_frame",
    "set_logger_level",
    "set_parameters",
    "start_acquisition",
    "stop_acquisition",
    "trigger_image",
    "V2/is_acquiring",
    "V2/is_connected",
    "V2/set_coordinate_space",
    "V2/set_transformation",
    "V2/start_acquisition",
    "V2/stop_acquisition",
    "V2/save_last_frame",
)
PARAMETERS = (
    "confidence",
    "coordinate_space",
    "frame_id",
    "resolution",
    "scan_multiplier",
    "scanner_id",
    "send_confidence_map",
    "send_depth_map",
    "send_normal_map",
    "send_point_cloud",
    "send_texture",
    "shutter_multiplier",
    "timeout",
    "trigger_mode",
)


def name(relative):
    return f"{NODE}/{relative}"


def proxy(relative, kind):
    return rospy.ServiceProxy(name(relative), kind)


def connect(settle=True):
    rospy.wait_for_service(name("connect_camera"))
    proxy("connect_camera", phoxi_srv.ConnectCamera)(CAMERA_ID)
    if settle:
        time.sleep(SETTLE_S)


def disconnect():
    rospy.wait_for_service(name("disconnect_camera"))
    proxy("disconnect_camera", std_srvs.srv.Empty)()
    time.sleep(SETTLE_S)


def service_exists(full_name):
    try:
        rospy.wait_for_service(full_name, SERVICE_TIMEOUT_S)
    except rospy.ROSException:
        return False
    return True


def topic_published(full_name):
    return any(full_name == topic for topic, _type in rospy.get_published_topics())


class InterfacesExist(unittest.TestCase):
    """test_phoxi_camera_interfaces_exist.py: the node, a connection, the topics, services and parameters."""

    def setUp(self):
        connect(settle=False)  # the upstream's connect here has no wait

    def test1_phoxi_camera_node_exist(self):
        self.assertTrue(any(NODE in node for node in rosnode.get_node_names()), f"node {NODE} is not running")

    def test2_connect_camera(self):
        rospy.wait_for_service(name("connect_camera"), SERVICE_TIMEOUT_S)
        reply = proxy("connect_camera", phoxi_srv.ConnectCamera)(CAMERA_ID)
        self.assertTrue(reply.success, f"connection to {CAMERA_ID} failed: {reply.message}")

    def test3_topics_running(self):
        for topic in ["/diagnostics"] + [name(t) for t in TOPICS]:
            self.assertTrue(topic_published(topic), f"topic {topic} does not exist")

    def test4_services_running(self):
        for relative in SERVICES:
            self.assertTrue(service_exists(name(relative)), f"service {name(relative)} does not exist")

    def test5_parameter_server_variables_exist(self):
        for relative in PARAMETERS:
            self.assertTrue(rospy.has_param(name(relative)), f"parameter {name(relative)} does not exist")


class RosInterfaces(unittest.TestCase):
    """test_phoxi_camera_ros_interfaces.py: every service called connected (and disconnected where it matters)."""

    def setUp(self):
        connect()

    def tearDown(self):
        disconnect()

    def assertOk(self, reply):
        self.assertTrue(reply.success, reply.message)
        self.assertEqual("Ok", reply.message)

    def assertRefused(self, reply):
        self.assertFalse(reply.success)
        self.assertNotEqual("Ok", reply.message)

    def test_getDeviceList(self):
        reply = proxy("get_device_list", phoxi_srv.GetDeviceList)()
        self.assertOk(reply)
        self.assertNotEqual(0, reply.len)
        rospy.loginfo("cameras listed: %s", reply.out)

    def test_connect_disconnectCamera(self):
        is_connected = proxy("is_connected", phoxi_srv.IsConnected)
        self.assertOk(proxy("connect_camera", phoxi_srv.ConnectCamera)(CAMERA_ID))
        self.assertTrue(is_connected().connected)
        proxy("disconnect_camera", std_srvs.srv.Empty)()
        self.assertFalse(is_connected().connected)

    def test_isConnected(self):
        is_connected = proxy("is_connected", phoxi_srv.IsConnected)
        disconnect()
        self.assertFalse(is_connected().connected)
        connect()
        self.assertTrue(is_connected().connected)

    def test_isConnectedV2(self):
        is_connected = proxy("V2/is_connected", phoxi_srv.GetBool)
        disconnect()
        reply = is_connected()
        self.assertOk(reply)
        self.assertFalse(reply.value)
        connect()
        reply = is_connected()
        self.assertOk(reply)
        self.assertTrue(reply.value)

    def test_isAcquiring(self):
        is_acquiring = proxy("is_acquiring", phoxi_srv.IsAcquiring)
        self.assertTrue(is_acquiring().is_acquiring)
        disconnect()
        self.assertFalse(is_acquiring().is_acquiring)

    def test_isAcquiringV2(self):
        is_acquiring = proxy("V2/is_acquiring", phoxi_srv.GetBool)
        reply = is_acquiring()
        self.assertOk(reply)
        self.assertTrue(reply.value)
        disconnect()
        reply = is_acquiring()
        self.assertOk(reply)
        self.assertFalse(reply.value)

    def _acquiring(self):
        return proxy("V2/is_acquiring", phoxi_srv.GetBool)().value

    def test_startAcquisition(self):
        proxy("start_acquisition", std_srvs.srv.Empty)()
        self.assertTrue(self._acquiring())

    def test_stopAcquisition(self):
        proxy("stop_acquisition", std_srvs.srv.Empty)()
        self.assertFalse(self._acquiring())

    def test_startAcquisitionV2(self):
        self.assertOk(proxy("V2/start_acquisition", phoxi_srv.Empty)())
        self.assertTrue(self._acquiring())

    def test_stopAcquisitionV2(self):
        self.assertOk(proxy("V2/stop_acquisition", phoxi_srv.Empty)())
        self.assertFalse(self._acquiring())

    def test_triggerImage(self):
        trigger = proxy("trigger_image", phoxi_srv.TriggerImage)
        self.assertOk(trigger())
        disconnect()
        self.assertRefused(trigger())

    def test_getFrame(self):
        counted = {"messages": 0}
        lock = threading.Lock()

        def count(_msg):
            with lock:
                counted["messages"] += 1

        subscribers = [
            rospy.Subscriber(name("pointcloud"), sensor_msgs.msg.PointCloud2, count),
            rospy.Subscriber(name("normal_map"), sensor_msgs.msg.Image, count),
            rospy.Subscriber(name("confidence_map"), sensor_msgs.msg.Image, count),
            rospy.Subscriber(name("texture"), sensor_msgs.msg.Image, count),
        ]
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and any(s.get_num_connections() == 0 for s in subscribers):
            time.sleep(0.05)
        get_frame = proxy("get_frame", phoxi_srv.GetFrame)
        reply = get_frame(-1)
        time.sleep(FRAME_WAIT_S)
        self.assertOk(reply)
        # the example file camera's recording has no confidence map: point cloud, normal map and texture arrive
        with lock:
            self.assertEqual(3, counted["messages"], "some topic was not published after get_frame")
        disconnect()
        self.assertRefused(get_frame(-1))
        for subscriber in subscribers:
            subscriber.unregister()

    def test_saveFrame(self):
        folder = os.getcwd()  # ROS_HOME, as the upstream expects (~/.ros)
        path = os.path.join(folder, "file.ply")
        if os.path.exists(path):
            os.remove(path)
        before = set(os.listdir(folder))
        reply = proxy("save_frame", phoxi_srv.SaveFrame)(-1, path)
        self.assertNotEqual(set(), set(os.listdir(folder)) - before)
        self.assertOk(reply)
        os.remove(path)

    def test_getHardwareIdentification(self):
        get_id = proxy("get_hardware_indentification", phoxi_srv.GetHardwareIdentification)
        reply = get_id()
        self.assertOk(reply)
        self.assertEqual(CAMERA_ID, reply.hardware_identification)
        disconnect()
        reply = get_id()
        self.assertEqual("", reply.hardware_identification)
        self.assertRefused(reply)

    def test_getSupportedCapturingModes(self):
        get_modes = proxy("get_supported_capturing_modes", phoxi_srv.GetSupportedCapturingModes)
        reply = get_modes()
        self.assertOk(reply)
        self.assertNotEqual(0, len(reply.supported_capturing_modes))
        disconnect()
        reply = get_modes()
        self.assertEqual(0, len(reply.supported_capturing_modes))
        self.assertRefused(reply)

    def test_setCoordianteSpace(self):  # the upstream's spelling
        set_space = proxy("V2/set_coordinate_space", phoxi_srv.SetCoordinatesSpace)
        for space in range(6):  # 0 NoValue, 1 Camera, 2 Mounting, 3 Marker, 4 Robot, 5 Custom
            with self.subTest(space=space):
                self.assertOk(set_space(space))

    def test_setTransformation(self):
        set_transformation = proxy("V2/set_transformation", phoxi_srv.SetTransformationMatrix)
        # a default Transform (zero quaternion) for RobotSpace, set_space true, save_settings false
        self.assertOk(set_transformation(geometry_msgs.msg.Transform(), 4, True, False))

    def test_saveLastFrameV2(self):
        proxy("trigger_image", phoxi_srv.TriggerImage)()
        time.sleep(FRAME_WAIT_S)
        save_last = proxy("V2/save_last_frame", phoxi_srv.SaveLastFrame)
        folder = os.getcwd()
        for old in os.listdir(folder):
            if old.endswith((".ply", ".praw", ".ptx")):
                os.remove(os.path.join(folder, old))
        for filename in ("file.ply", "file.praw", "file.ptx"):
            with self.subTest(file=filename):
                before = set(os.listdir(folder))
                reply = save_last(os.path.join(folder, filename))
                created = set(os.listdir(folder)) - before
                if filename.endswith(".praw"):  # change 3: the simulator refuses PhoXi Control's raw format
                    self.assertFalse(reply.success)
                    self.assertTrue(reply.message.startswith("Unsuccessful save"), reply.message)
                    self.assertEqual(set(), created)
                    continue
                self.assertEqual({filename}, created)
                self.assertOk(reply)
                os.remove(os.path.join(folder, filename))


CASES = {"exist": InterfacesExist, "interfaces": RosInterfaces}

if __name__ == "__main__":
    chosen = next((arg for arg in sys.argv[1:] if arg in CASES), None)
    if chosen is None:
        sys.exit(f"usage: test_phoxi_driver_tests.py {{{'|'.join(CASES)}}} (rostest passes it from the .test)")
    rospy.init_node("Test_ROS_interfaces", anonymous=True)
    rostest.rosrun(PKG, f"phoxi_driver_{chosen}", CASES[chosen])
