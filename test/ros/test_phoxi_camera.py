#!/usr/bin/env python3
"""rostest: the simulated PhoXi scanner alone offers the real driver's interface and behaves like it.

Interfaces as the driver's own tests check them (every service, topic and parameter of the reference, by name and
type), then behaviour: every service answers Ok, get_frame(-1) publishes on every enabled topic with seq = frame
index, an unknown frame id fails, save_frame writes a PLY that reloads with the published points, a refused path
(``..``, ``~``, outside the allowed folders, a symlink out, ``.praw``) writes nothing, an absurd transformation is
refused and later frames stay finite, the command-line form works, diagnostics, the custom space and free run.
"""

import os
import subprocess
import sys
import time
import unittest
from pathlib import Path

import numpy as np
import rosgraph
import rospy
import rosservice
import rostest
import rostopic
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import Transform
from std_srvs.srv import Empty as StdEmpty

sys.path.insert(0, str(Path(__file__).resolve().parent))
from phoxi_test_utils import NODE, FrameRecorder, reconfigure, service

from agiprobot_measurement.ros import phoxi_messages
from agiprobot_measurement.sensors.phoxi.models import RESOLUTION_LOW, load_scanner_model
from agiprobot_measurement.sensors.phoxi.point_cloud_io import read_ply
from agiprobot_measurement.srv import (
    ConnectCamera,
    Empty,
    GetBool,
    GetDeviceList,
    GetFrame,
    GetHardwareIdentification,
    GetString,
    GetSupportedCapturingModes,
    IsAcquiring,
    IsConnected,
    SaveFrame,
    SaveLastFrame,
    SetCoordinatesSpace,
    SetTransformationMatrix,
    TriggerImage,
)

PKG = "agiprobot_measurement"
SERVICES = {
    "get_device_list": f"{PKG}/GetDeviceList",
    "connect_camera": f"{PKG}/ConnectCamera",
    "disconnect_camera": "std_srvs/Empty",
    "is_connected": f"{PKG}/IsConnected",
    "is_acquiring": f"{PKG}/IsAcquiring",
    "V2/is_connected": f"{PKG}/GetBool",
    "V2/is_acquiring": f"{PKG}/GetBool",
    "start_acquisition": "std_srvs/Empty",
    "stop_acquisition": "std_srvs/Empty",
    "V2/start_acquisition": f"{PKG}/Empty",
    "V2/stop_acquisition": f"{PKG}/Empty",
    "trigger_image": f"{PKG}/TriggerImage",
    "get_frame": f"{PKG}/GetFrame",
    "save_frame": f"{PKG}/SaveFrame",
    "V2/save_last_frame": f"{PKG}/SaveLastFrame",
    "get_hardware_indentification": f"{PKG}/GetHardwareIdentification",
    "get_supported_capturing_modes": f"{PKG}/GetSupportedCapturingModes",
    "get_api_version": f"{PKG}/GetString",
    "get_firmware_version": f"{PKG}/GetString",
    "V2/set_coordinate_space": f"{PKG}/SetCoordinatesSpace",
    "V2/set_transformation": f"{PKG}/SetTransformationMatrix",
    "set_coordinate_space": f"{PKG}/SetCoordinatesSpace",
    "set_transformation_matrix": f"{PKG}/SetTransformationMatrix",
    "set_parameters": "dynamic_reconfigure/Reconfigure",
}
TOPICS = {
    f"{NODE}/pointcloud": "sensor_msgs/PointCloud2",
    f"{NODE}/depth_map": "sensor_msgs/Image",
    f"{NODE}/texture": "sensor_msgs/Image",
    f"{NODE}/rgb_texture": "sensor_msgs/Image",
    f"{NODE}/confidence_map": "sensor_msgs/Image",
    f"{NODE}/normal_map": "sensor_msgs/Image",
    f"{NODE}/camera_info": "sensor_msgs/CameraInfo",
    f"{NODE}/parameter_descriptions": "dynamic_reconfigure/ConfigDescription",
    f"{NODE}/parameter_updates": "dynamic_reconfigure/Config",
    "/diagnostics": "diagnostic_msgs/DiagnosticArray",
}
PARAMETERS = {
    "scanner_id": "",
    "frame_id": "PhoXi3Dscanner_sensor",
    "latch_topics": False,
    "topic_queue_size": 1,
    "init_from_config": False,
    "organized_cloud": True,
    "resolution": 1,
    "scan_multiplier": 1,
    "shutter_multiplier": 1,
    "confidence": 3.0,
    "send_confidence_map": True,
    "send_depth_map": True,
    "send_normal_map": True,
    "send_point_cloud": True,
    "send_texture": True,
    "timeout": -3,
    "trigger_mode": 1,
    "coordinate_space": 1,
    "ambient_light_suppression": False,
    "single_pattern_exposure": 2,
    "camera_only_mode": False,
}
IMAGE_ENCODINGS = {
    "depth_map": "32FC1",
    "texture": "32FC1",
    "confidence_map": "32FC1",
    "normal_map": "32FC3",
    "rgb_texture": "rgb8",
}


def _identity(z=0.0):
    transform = Transform()
    transform.translation.z = z
    transform.rotation.w = 1.0
    return transform


class PhoxiCameraTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("test_phoxi_camera")
        cls.trigger = service("trigger_image", TriggerImage)
        cls.get_frame = service("get_frame", GetFrame)
        cls.save = service("save_frame", SaveFrame)
        # the parameters as the node started, before the tests change any
        cls.start_parameters = rospy.get_param(NODE)
        cls.output_dir = Path(rospy.get_param(f"{NODE}/output_dir"))
        reconfigure(resolution=RESOLUTION_LOW)  # keeps the frames of this test quick
        cls.recorder = FrameRecorder()

    def setUp(self):
        service("connect_camera", ConnectCamera)(name="")
        service("V2/set_coordinate_space", SetCoordinatesSpace)(coordinates_space=1)

    def _trigger(self):
        reply = self.trigger()
        self.assertTrue(reply.success, reply.message)
        self.assertEqual(reply.message, "Ok")
        return reply.id

    # ------------------------------------------------------------------------------------- interfaces
    def test_services_exist_with_the_drivers_types(self):
        for name, kind in SERVICES.items():
            full = f"{NODE}/{name}"
            rospy.wait_for_service(full, timeout=5)
            self.assertEqual(rosservice.get_service_type(full), kind, full)

    def test_topics_exist_with_their_types(self):
        master = rosgraph.Master("/test_phoxi_camera")
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            published = dict(master.getPublishedTopics(""))
            if all(topic in published for topic in TOPICS):
                break
            rospy.sleep(0.2)
        for topic, kind in TOPICS.items():
            self.assertEqual(rostopic.get_topic_type(topic)[0], kind, topic)

    def test_parameters_exist_with_the_reference_defaults(self):
        for name, default in PARAMETERS.items():
            self.assertIn(name, self.start_parameters, f"{NODE}/{name} is missing")
            self.assertEqual(self.start_parameters[name], default, name)
            self.assertIs(type(self.start_parameters[name]), type(default), name)

    # ------------------------------------------------------------------------------------------ services
    def test_every_service_answers_ok(self):
        devices = service("get_device_list", GetDeviceList)()
        self.assertEqual((devices.success, devices.message, devices.len), (True, "Ok", 1))
        hardware_id = devices.out[0]
        self.assertEqual(devices.device_information_list[0].hwIdentification, hardware_id)
        ok = {"success": True, "message": "Ok"}
        for name, kind in (("V2/stop_acquisition", Empty), ("V2/start_acquisition", Empty)):
            reply = service(name, kind)()
            self.assertEqual({"success": reply.success, "message": reply.message}, ok, name)
        service("stop_acquisition", StdEmpty)()
        self.assertFalse(service("is_acquiring", IsAcquiring)().is_acquiring)
        self.assertFalse(service("V2/is_acquiring", GetBool)().value)
        service("start_acquisition", StdEmpty)()
        self.assertTrue(service("V2/is_acquiring", GetBool)().value)
        self.assertTrue(service("is_connected", IsConnected)().connected)
        frame_id = self._trigger()
        calls = [
            ("get_frame", GetFrame, {"in_": frame_id}),
            ("save_frame", SaveFrame, {"in_": frame_id, "path": "every_service/frame.ply"}),
            ("V2/save_last_frame", SaveLastFrame, {"file_path": "every_service/last.ply"}),
            ("get_hardware_indentification", GetHardwareIdentification, {}),
            ("get_supported_capturing_modes", GetSupportedCapturingModes, {}),
            ("get_api_version", GetString, {}),
            ("get_firmware_version", GetString, {}),
            ("V2/set_coordinate_space", SetCoordinatesSpace, {"coordinates_space": 1}),
            ("set_coordinate_space", SetCoordinatesSpace, {"coordinates_space": 1}),
            ("V2/set_transformation", SetTransformationMatrix, {"transform": _identity(), "coordinates_space": 5}),
            ("set_transformation_matrix", SetTransformationMatrix, {"transform": _identity(), "coordinates_space": 5}),
            ("connect_camera", ConnectCamera, {"name": hardware_id}),
            ("V2/is_connected", GetBool, {}),
        ]
        for name, kind, request in calls:
            reply = service(name, kind)(**request)
            self.assertEqual({"success": reply.success, "message": reply.message}, ok, name)
        self.assertEqual(
            service("get_hardware_indentification", GetHardwareIdentification)().hardware_identification, hardware_id
        )
        modes = service("get_supported_capturing_modes", GetSupportedCapturingModes)().supported_capturing_modes
        self.assertEqual([(m.Width, m.Height) for m in modes], [(2064, 1544), (1032, 772)])
        service("disconnect_camera", StdEmpty)()
        self.assertFalse(service("V2/is_connected", GetBool)().value)
        reply = self.get_frame(in_=-1)
        self.assertFalse(reply.success)
        self.assertIn("not connected", reply.message)
        self.assertTrue(service("connect_camera", ConnectCamera)(name="").success)
        self.assertFalse(service("connect_camera", ConnectCamera)(name="no-such-scanner").success)

    def test_get_frame_publishes_on_every_enabled_topic(self):
        reply = self.get_frame(in_=-1)
        self.assertTrue(reply.success, reply.message)
        frame_id = self._trigger()  # trigger_image publishes too; its id is the seq of every message
        messages = self.recorder.wait_for(frame_id)
        self.assertIsNotNone(messages, "not every topic published the triggered frame")
        for name, msg in messages.items():
            self.assertEqual(msg.header.frame_id, "PhoXi3Dscanner_sensor", name)
            self.assertEqual((msg.width, msg.height), (1032, 772), name)
            if name in IMAGE_ENCODINGS:
                self.assertEqual(msg.encoding, IMAGE_ENCODINGS[name], name)
        cloud = messages["pointcloud"]
        self.assertEqual([f.name for f in cloud.fields], [name for name, _ in phoxi_messages.POINT_FIELDS])
        # depth map (mm) and point cloud (m) agree pixel by pixel
        points, _, _ = phoxi_messages.pointcloud2_arrays(cloud)
        depth = phoxi_messages.image_array(messages["depth_map"])
        self.assertGreater((depth > 0).mean(), 0.2)
        np.testing.assert_allclose(points[:, :, 2] * 1000.0, depth, rtol=1e-6)
        intrinsics = load_scanner_model("L").intrinsics(RESOLUTION_LOW)
        np.testing.assert_allclose(np.reshape(messages["camera_info"].K, (3, 3)), intrinsics.matrix())
        # switched-off outputs stay silent
        reconfigure(send_texture=False, send_normal_map=False)
        try:
            silent_id = self._trigger()
            self.assertIsNotNone(self.recorder.wait_for(silent_id, ["pointcloud", "depth_map", "confidence_map"]))
            rospy.sleep(1.0)
            for name in ("texture", "rgb_texture", "normal_map"):
                self.assertIsNone(self.recorder.of(name, silent_id), name)
        finally:
            reconfigure(send_texture=True, send_normal_map=True)

    def test_unknown_frame_id_fails(self):
        reply = self.get_frame(in_=987654)
        self.assertFalse(reply.success)
        self.assertIn("Frame 987654 is not available", reply.message)
        reply = self.save(in_=987654, path="unknown.ply")
        self.assertFalse(reply.success)
        self.assertFalse((self.output_dir / "unknown.ply").exists())

    def test_save_frame_writes_a_ply_that_reloads_with_the_same_points(self):
        frame_id = self._trigger()
        cloud = self.recorder.wait_for(frame_id, ["pointcloud"])["pointcloud"]
        relative = f"rostest/frame_{frame_id}.ply"
        reply = self.save(in_=frame_id, path=relative)
        self.assertTrue(reply.success, reply.message)
        data = read_ply(self.output_dir / relative)
        points, normals, _ = phoxi_messages.pointcloud2_arrays(cloud)
        np.testing.assert_array_equal(np.stack([data["x"], data["y"], data["z"]], 1), points.reshape(-1, 3))
        np.testing.assert_array_equal(np.stack([data["nx"], data["ny"], data["nz"]], 1), normals.reshape(-1, 3))

    def test_a_refused_path_writes_nothing(self):
        before = sorted(str(p) for p in self.output_dir.rglob("*"))
        outside = Path(f"/tmp/phoxi_escape_{os.getpid()}.ply")
        first = self._trigger()
        for path in ("../escape.ply", str(outside), "a/../../escape.ply", "/etc/x.ply", "~/escape.ply"):
            reply = self.save(in_=-1, path=path)
            self.assertFalse(reply.success, path)
            self.assertRegex(reply.message, r"is not allowed in|outside the allowed folder|is not expanded", path)
            self.assertIn(str(self.output_dir), reply.message, "the refusal names the root")
        reply = self.save(in_=-1, path="frame.praw")
        self.assertFalse(reply.success)
        self.assertIn("not supported by the simulator", reply.message)
        self.assertFalse(outside.exists())
        self.assertFalse((self.output_dir.parent / "escape.ply").exists())
        self.assertEqual(sorted(str(p) for p in self.output_dir.rglob("*")), before)
        self.assertEqual(self._trigger(), first + 1, "a refused save must not take a frame")
        reply = service("V2/save_last_frame", SaveLastFrame)(file_path="last.pcd")
        self.assertEqual((reply.success, reply.message), (False, "Wrong extension."))

    def test_a_symlink_out_of_the_root_is_refused_and_allowed_folders_accept_absolute_names(self):
        outside = Path(f"/tmp/phoxi_link_target_{os.getpid()}")
        outside.mkdir(exist_ok=True)
        link = self.output_dir / f"link_{os.getpid()}"
        self.output_dir.mkdir(parents=True, exist_ok=True)
        link.symlink_to(outside, target_is_directory=True)
        try:
            reply = self.save(in_=-1, path=f"{link.name}/x.ply")
            self.assertFalse(reply.success)
            self.assertIn("outside the allowed folder", reply.message)
            self.assertEqual(list(outside.iterdir()), [])
        finally:
            link.unlink()
            outside.rmdir()
        allowed = self.output_dir.parent / f"phoxi_allowed_{os.getpid()}.ply"  # ~allowed_save_dirs of the .test
        reply = self.save(in_=-1, path=str(allowed))
        self.assertTrue(reply.success, reply.message)
        self.assertTrue(allowed.is_file())
        allowed.unlink()

    def test_absurd_transformations_are_refused_and_later_frames_stay_finite(self):
        set_transformation = service("set_transformation_matrix", SetTransformationMatrix)
        try:
            huge = _identity()
            huge.translation.x = 1e308
            bad_rotation = _identity()
            bad_rotation.rotation.x = bad_rotation.rotation.y = bad_rotation.rotation.z = float("nan")
            for transform, words in ((huge, "translation"), (bad_rotation, "finite")):
                reply = set_transformation(
                    transform=transform, coordinates_space=5, set_space=True, save_settings=False
                )
                self.assertFalse(reply.success)
                self.assertIn(words, reply.message)
            self.assertEqual(rospy.get_param(f"{NODE}/coordinate_space"), 1, "a refusal changes no space")
            reply = set_transformation(
                transform=_identity(z=0.5), coordinates_space=5, set_space=True, save_settings=False
            )
            self.assertTrue(reply.success, reply.message)
            frame_id = self._trigger()  # the node still serves, and its frames are finite
            points, normals, _ = phoxi_messages.pointcloud2_arrays(
                self.recorder.wait_for(frame_id, ["pointcloud"])["pointcloud"]
            )
            self.assertTrue(np.all(np.isfinite(points)) and np.all(np.isfinite(normals)))
            self.assertGreater(np.count_nonzero(points[:, :, 2]), 0)
        finally:
            service("V2/set_coordinate_space", SetCoordinatesSpace)(coordinates_space=1)

    def test_a_reconfigured_number_that_is_not_finite_is_put_back(self):
        before = rospy.get_param(f"{NODE}/confidence")
        result = reconfigure(confidence=float("nan"))
        self.assertEqual(result["confidence"], before)
        self.assertEqual(rospy.get_param(f"{NODE}/confidence"), before)
        self.assertGreaterEqual(self._trigger(), 0, "the node keeps serving")

    def test_get_frame_from_the_command_line(self):
        result = subprocess.run(
            ["rosservice", "call", f"{NODE}/get_frame", "in_: -1"], capture_output=True, text=True, timeout=60
        )
        self.assertEqual(result.returncode, 0, result.stderr)
        self.assertIn('message: "Ok"', result.stdout)
        self.assertIn("success: True", result.stdout)

    # ------------------------------------------------------------------------------ status, spaces, modes
    def test_diagnostics_report_the_state(self):
        reports = []
        sub = rospy.Subscriber("/diagnostics", DiagnosticArray, lambda m: reports.extend(m.status))
        try:
            deadline = time.monotonic() + 7.0  # the node reports every 5 s
            while not reports and time.monotonic() < deadline:
                rospy.sleep(0.1)
            self.assertTrue(reports, "no /diagnostics within 7 s")
            self.assertEqual((reports[-1].level, reports[-1].message), (DiagnosticStatus.OK, "Ready"))
            service("stop_acquisition", StdEmpty)()
            rospy.sleep(0.5)
            self.assertEqual(
                (reports[-1].level, reports[-1].message), (DiagnosticStatus.WARN, "Acquisition not started")
            )
            service("disconnect_camera", StdEmpty)()
            rospy.sleep(0.5)
            self.assertEqual((reports[-1].level, reports[-1].message), (DiagnosticStatus.ERROR, "Not connected"))
        finally:
            sub.unregister()
            service("connect_camera", ConnectCamera)(name="")

    def test_custom_space_from_set_transformation(self):
        reply = service("V2/set_transformation", SetTransformationMatrix)(
            transform=_identity(z=1.0), coordinates_space=5, set_space=True, save_settings=False
        )
        self.assertTrue(reply.success, reply.message)
        self.assertEqual(rospy.get_param(f"{NODE}/coordinate_space"), 5)
        try:
            frame_id = self._trigger()
            messages = self.recorder.wait_for(frame_id, ["pointcloud", "depth_map"])
            points, _, _ = phoxi_messages.pointcloud2_arrays(messages["pointcloud"])
            depth = phoxi_messages.image_array(messages["depth_map"])
            valid = depth > 0
            np.testing.assert_allclose(points[valid][:, 2], depth[valid] / 1000.0 + 1.0, atol=1e-5)
            refused = service("V2/set_coordinate_space", SetCoordinatesSpace)(coordinates_space=3)
            self.assertFalse(refused.success)
            self.assertIn("MarkerSpace", refused.message)
        finally:
            service("V2/set_coordinate_space", SetCoordinatesSpace)(coordinates_space=1)
        self.assertEqual(rospy.get_param(f"{NODE}/coordinate_space"), 1)

    def test_free_run_publishes_continuously(self):
        start = self.recorder.count("pointcloud")
        reconfigure(trigger_mode=0, free_run_rate_hz=10.0)
        try:
            deadline = time.monotonic() + 20.0
            while self.recorder.count("pointcloud") < start + 3 and time.monotonic() < deadline:
                rospy.sleep(0.1)
        finally:
            reconfigure(trigger_mode=1)
        with self.recorder.lock:
            seqs = [m.header.seq for m in self.recorder.messages["pointcloud"][start:]]
        self.assertGreaterEqual(len(seqs), 3, "free run did not publish continuously")
        self.assertEqual(seqs, sorted(seqs))
        rospy.sleep(1.5)  # a frame under way when the mode changed may still arrive
        settled = self.recorder.count("pointcloud")
        rospy.sleep(1.5)
        self.assertEqual(self.recorder.count("pointcloud"), settled, "software trigger mode must not publish by itself")


if __name__ == "__main__":
    rostest.rosrun(PKG, "phoxi_camera_interface", PhoxiCameraTest)
