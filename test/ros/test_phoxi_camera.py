#!/usr/bin/env python3
"""rostest: the simulated PhoXi scanner alone offers the real driver's interface and behaves like it.

Interfaces as the driver's own tests check them (every service, topic and parameter of the reference, by name and
type, the reconfigure description equal to the driver's cfg), then behaviour as the driver's (release 1.8.0): it
starts disconnected with scanner_id "", reconfiguring without a scanner is put back, connect_camera("") finds no
scanner; trigger_image publishes nothing and get_frame(id) publishes that frame on every enabled topic with seq =
frame index; triggering while acquisition is stopped switches to the software trigger and starts it; an unknown
frame id fails; the cloud's normals are divided by 1000; save_frame writes a PLY that reloads with the published
points, a refused path (``..``, ``~`` outside the allowed folders, a symlink out, ``.praw``) writes nothing;
coordinate spaces 0-5, set_transformation switching the space also with set_space false, an absurd transformation
refused; the command-line form, diagnostics and free run.
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
from dynamic_reconfigure.msg import Config, DoubleParameter, StrParameter
from dynamic_reconfigure.srv import Reconfigure
from geometry_msgs.msg import Transform
from std_srvs.srv import Empty as StdEmpty

sys.path.insert(0, str(Path(__file__).resolve().parent))
from phoxi_camera.srv import (
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
from phoxi_test_utils import NODE, FrameRecorder, reconfigure, service

from agiprobot_measurement.ros import phoxi_messages
from agiprobot_measurement.sensors.phoxi.models import RESOLUTION_LOW, load_scanner_model
from agiprobot_measurement.sensors.phoxi.point_cloud_io import read_ply

PKG = "agiprobot_measurement"
TYPES = "phoxi_camera"  # the driver's package: one set of types
SCANNER_ID = "PhoXi3DScanner-sim"  # the simulated PhoXi Control's scanner (config/phoxi_models.yaml)
REAL_ID = "2019-04-011-LC3"  # a real scanner's id, listed by the .test's ~devices as a PhoXi M
SERVICES = {
    "get_device_list": f"{TYPES}/GetDeviceList",
    "connect_camera": f"{TYPES}/ConnectCamera",
    "disconnect_camera": "std_srvs/Empty",
    "is_connected": f"{TYPES}/IsConnected",
    "is_acquiring": f"{TYPES}/IsAcquiring",
    "V2/is_connected": f"{TYPES}/GetBool",
    "V2/is_acquiring": f"{TYPES}/GetBool",
    "start_acquisition": "std_srvs/Empty",
    "stop_acquisition": "std_srvs/Empty",
    "V2/start_acquisition": f"{TYPES}/Empty",
    "V2/stop_acquisition": f"{TYPES}/Empty",
    "trigger_image": f"{TYPES}/TriggerImage",
    "get_frame": f"{TYPES}/GetFrame",
    "save_frame": f"{TYPES}/SaveFrame",
    "V2/save_last_frame": f"{TYPES}/SaveLastFrame",
    "get_hardware_indentification": f"{TYPES}/GetHardwareIdentification",
    "get_supported_capturing_modes": f"{TYPES}/GetSupportedCapturingModes",
    "get_api_version": f"{TYPES}/GetString",
    "get_firmware_version": f"{TYPES}/GetString",
    "V2/set_coordinate_space": f"{TYPES}/SetCoordinatesSpace",
    "V2/set_transformation": f"{TYPES}/SetTransformationMatrix",
    "set_coordinate_space": f"{TYPES}/SetCoordinatesSpace",
    "set_transformation_matrix": f"{TYPES}/SetTransformationMatrix",
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
    "start_acquisition": True,
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
        # the parameters and the state as the node started (scanner_id ""), before the tests change any
        cls.start_parameters = rospy.get_param(NODE)
        cls.connected_at_start = service("is_connected", IsConnected)().connected
        cls.frame_before_connecting = cls.get_frame(in_=-1)
        cls.reconfigure_before_connecting = reconfigure(resolution=RESOLUTION_LOW)
        cls.output_dir = Path(rospy.get_param(f"{NODE}/output_dir"))
        service("connect_camera", ConnectCamera)(name=SCANNER_ID)
        reconfigure(resolution=RESOLUTION_LOW)  # keeps the frames of this test quick
        cls.recorder = FrameRecorder()

    def setUp(self):
        service("connect_camera", ConnectCamera)(name=SCANNER_ID)
        service("V2/set_coordinate_space", SetCoordinatesSpace)(coordinates_space=1)

    def _published(self, frame_id, topics=None):
        """Publish frame ``frame_id`` with get_frame and return its messages."""
        reply = self.get_frame(in_=frame_id)
        self.assertTrue(reply.success, reply.message)
        messages = self.recorder.wait_for(frame_id, topics)
        self.assertIsNotNone(messages, f"frame {frame_id} was not published on {topics or 'every topic'}")
        return messages

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
        self.assertEqual((devices.success, devices.message, devices.len), (True, "Ok", 2))  # the .test's ~devices
        hardware_id = devices.out[0]
        self.assertEqual(devices.out, [SCANNER_ID, REAL_ID])
        info = devices.device_information_list[0]
        self.assertEqual(info.hwIdentification, hardware_id)
        self.assertEqual((info.variant, info.isAlpha), ("L", False))  # release 1.8.0's fields
        statuses = [i.status.status for i in devices.device_information_list]
        self.assertEqual(statuses, [2, 1], "the connected scanner is Occupied (2), the other Ready (1)")
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
        # the driver answers the versions with an empty message
        for name in ("get_api_version", "get_firmware_version"):
            reply = service(name, GetString)()
            self.assertEqual((reply.success, reply.message), (True, ""), name)
            self.assertTrue(reply.value, name)
        service("disconnect_camera", StdEmpty)()
        self.assertFalse(service("V2/is_connected", GetBool)().value)
        reply = self.get_frame(in_=-1)
        self.assertEqual((reply.success, reply.message), (False, "No scanner connected"))
        firmware = service("get_firmware_version", GetString)()
        self.assertEqual((firmware.success, firmware.value, firmware.message), (True, "", "No scanner connected"))
        for name in ("", "no-such-scanner"):
            reply = service("connect_camera", ConnectCamera)(name=name)
            self.assertFalse(reply.success, name)
            self.assertTrue(reply.message.startswith("Scanner not found"), reply.message)
        self.assertTrue(service("connect_camera", ConnectCamera)(name=SCANNER_ID).success)

    def test_a_real_scanners_id_can_be_simulated(self):
        try:
            reply = service("connect_camera", ConnectCamera)(name=REAL_ID)
            self.assertEqual((reply.success, reply.message), (True, "Ok"))
            hardware = service("get_hardware_indentification", GetHardwareIdentification)()
            self.assertEqual(hardware.hardware_identification, REAL_ID)
            self.assertEqual(service("get_firmware_version", GetString)().value, "1.9.1")
            messages = self._published(self._trigger(), ["camera_info"])
            intrinsics = load_scanner_model("M").intrinsics(RESOLUTION_LOW)  # its model; the settings stay
            np.testing.assert_allclose(np.reshape(messages["camera_info"].K, (3, 3)), intrinsics.matrix())
        finally:
            service("connect_camera", ConnectCamera)(name=SCANNER_ID)

    def test_starts_disconnected_when_scanner_id_is_empty(self):
        self.assertEqual(self.start_parameters["scanner_id"], "")
        self.assertFalse(self.connected_at_start)
        self.assertEqual(
            (self.frame_before_connecting.success, self.frame_before_connecting.message),
            (False, "No scanner connected"),
        )
        # reconfiguring without a scanner is put back, as the driver's callback does
        self.assertEqual(self.reconfigure_before_connecting["resolution"], 1)

    def test_trigger_publishes_nothing_and_get_frame_publishes_that_frame(self):
        before = {name: self.recorder.count(name) for name in self.recorder.messages}
        frame_id = self._trigger()
        rospy.sleep(1.5)
        self.assertEqual({name: self.recorder.count(name) for name in self.recorder.messages}, before)
        messages = self._published(frame_id)  # get_frame(id): its id is the seq of every message
        self.assertEqual({name: msg.header.seq for name, msg in messages.items()}, dict.fromkeys(messages, frame_id))
        reply = self.get_frame(in_=-1)  # a new frame, triggered and published
        self.assertTrue(reply.success, reply.message)
        self.assertIsNotNone(self.recorder.wait_for(frame_id + 1, ["pointcloud"]))

    def test_triggering_while_stopped_switches_to_software_and_starts_acquisition(self):
        reconfigure(trigger_mode=0)
        service("stop_acquisition", StdEmpty)()
        self.assertFalse(service("V2/is_acquiring", GetBool)().value)
        self.assertFalse(rospy.get_param(f"{NODE}/start_acquisition"))
        for call in (self._trigger, lambda: self.get_frame(in_=-1)):
            call()
            self.assertTrue(service("V2/is_acquiring", GetBool)().value)
            self.assertEqual(rospy.get_param(f"{NODE}/trigger_mode"), 1)
            self.assertTrue(rospy.get_param(f"{NODE}/start_acquisition"))
            service("stop_acquisition", StdEmpty)()

    def test_start_acquisition_is_reconfigurable(self):
        try:
            self.assertFalse(reconfigure(start_acquisition=False)["start_acquisition"])
            self.assertFalse(service("is_acquiring", IsAcquiring)().is_acquiring)
            self.assertTrue(reconfigure(start_acquisition=True)["start_acquisition"])
            self.assertTrue(service("is_acquiring", IsAcquiring)().is_acquiring)
            service("V2/stop_acquisition", Empty)()
            self.assertFalse(rospy.get_param(f"{NODE}/start_acquisition"), "the service updates the parameter")
        finally:
            service("V2/start_acquisition", Empty)()

    def test_the_reconfigure_description_is_the_drivers_cfg(self):
        from dynamic_reconfigure.msg import ConfigDescription

        description = rospy.wait_for_message(f"{NODE}/parameter_descriptions", ConfigDescription, timeout=10)
        parameters = [p for group in description.groups for p in group.parameters]
        self.assertEqual(
            [p.name for p in parameters],
            [
                "resolution",
                "scan_multiplier",
                "shutter_multiplier",
                "trigger_mode",
                "start_acquisition",
                "timeout",
                "confidence",
                "send_point_cloud",
                "send_normal_map",
                "send_confidence_map",
                "send_texture",
                "send_depth_map",
                "coordinate_space",
                "organized_cloud",
                "ambient_light_suppression",
                "single_pattern_exposure",
                "camera_only_mode",
            ],
        )
        levels = {p.name: p.level for p in parameters}
        self.assertEqual(levels["start_acquisition"], 1 << 4)
        self.assertEqual(
            [levels[n] for n in ("organized_cloud", "ambient_light_suppression", "single_pattern_exposure")],
            [1 << 13, 1 << 14, 1 << 15],
        )
        self.assertEqual(levels["camera_only_mode"], 1 << 16)
        self.assertEqual(reconfigure(timeout=5000)["timeout"], 0, "timeout is clamped to the driver's [-3, 0]")
        reconfigure(timeout=-3)

    def test_get_frame_publishes_on_every_enabled_topic(self):
        frame_id = self._trigger()
        messages = self._published(frame_id)
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
        # the driver divides the cloud's normals by 1000; the normal map keeps unit normals
        _, normals, _ = phoxi_messages.pointcloud2_arrays(cloud)
        valid = depth > 0
        np.testing.assert_allclose(np.linalg.norm(normals[valid], axis=1), 1e-3, rtol=1e-3)
        normal_map = phoxi_messages.image_array(messages["normal_map"])
        np.testing.assert_allclose(normals[valid] * 1000.0, normal_map[valid], rtol=1e-5, atol=1e-7)
        # switched-off outputs stay silent
        reconfigure(send_texture=False, send_normal_map=False)
        try:
            silent_id = self._trigger()
            self._published(silent_id, ["pointcloud", "depth_map", "confidence_map"])
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
        cloud = self._published(frame_id, ["pointcloud"])["pointcloud"]
        relative = f"rostest/frame_{frame_id}.ply"
        reply = self.save(in_=frame_id, path=relative)
        self.assertTrue(reply.success, reply.message)
        data = read_ply(self.output_dir / relative)
        points, normals, _ = phoxi_messages.pointcloud2_arrays(cloud)
        np.testing.assert_array_equal(np.stack([data["x"], data["y"], data["z"]], 1), points.reshape(-1, 3))
        # the PLY holds unit normals; the cloud the driver's thousandths
        np.testing.assert_allclose(
            np.stack([data["nx"], data["ny"], data["nz"]], 1), normals.reshape(-1, 3) * 1000.0, rtol=1e-5, atol=1e-7
        )

    def test_a_refused_path_writes_nothing(self):
        before = sorted(str(p) for p in self.output_dir.rglob("*"))
        outside = Path(f"/tmp/phoxi_escape_{os.getpid()}.ply")
        first = self._trigger()
        for path in ("../escape.ply", str(outside), "a/../../escape.ply", "/etc/x.ply", "~/escape.ply"):
            reply = self.save(in_=-1, path=path)
            self.assertFalse(reply.success, path)
            self.assertRegex(reply.message, r"is not allowed in|outside the allowed folder", path)
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
                self._published(frame_id, ["pointcloud"])["pointcloud"]
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

    def test_a_reconfigured_value_of_the_wrong_type_is_refused(self):
        """A double for the int resolution broke every later frame; a string for a bool raised a raw TypeError.
        Sent as raw requests: the Python client would cast the values first."""
        before = rospy.get_param(f"{NODE}/resolution")
        set_parameters = service("set_parameters", Reconfigure)
        for request, expected in (
            (Config(doubles=[DoubleParameter("resolution", 0.5)]), "parameter resolution is int: got float '0.5'"),
            (Config(strs=[StrParameter("organized_cloud", "no")]), "parameter organized_cloud is bool: got str 'no'"),
        ):
            with self.assertRaises(rospy.ServiceException) as refused:
                set_parameters(request)
            self.assertIn(expected, str(refused.exception))
        self.assertEqual(rospy.get_param(f"{NODE}/resolution"), before)
        self.assertIs(rospy.get_param(f"{NODE}/organized_cloud"), True)
        self.assertGreaterEqual(self._trigger(), 0, "the node keeps serving")
        reply = service("get_frame", GetFrame)(-1)
        self.assertTrue(reply.success, reply.message)

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
            self.assertEqual(reports[-1].hardware_id, "none")  # as the driver's updater
            values = {v.key: v.value for v in reports[-1].values}
            self.assertEqual(values, {"HardwareIdentification": SCANNER_ID, "Trigger mode": "Software"})
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
            service("connect_camera", ConnectCamera)(name=SCANNER_ID)

    def test_custom_space_from_set_transformation(self):
        reply = service("V2/set_transformation", SetTransformationMatrix)(
            transform=_identity(z=1.0), coordinates_space=5, set_space=True, save_settings=False
        )
        self.assertTrue(reply.success, reply.message)
        self.assertEqual(rospy.get_param(f"{NODE}/coordinate_space"), 5)
        try:
            frame_id = self._trigger()
            messages = self._published(frame_id, ["pointcloud", "depth_map"])
            points, _, _ = phoxi_messages.pointcloud2_arrays(messages["pointcloud"])
            depth = phoxi_messages.image_array(messages["depth_map"])
            valid = depth > 0
            np.testing.assert_allclose(points[valid][:, 2], depth[valid] / 1000.0 + 1.0, atol=1e-5)
        finally:
            service("V2/set_coordinate_space", SetCoordinatesSpace)(coordinates_space=1)
        self.assertEqual(rospy.get_param(f"{NODE}/coordinate_space"), 1)

    def test_coordinate_spaces_0_to_5_and_a_default_transform_as_the_drivers_own_test(self):
        set_space = service("V2/set_coordinate_space", SetCoordinatesSpace)
        try:
            for space in range(6):
                reply = set_space(coordinates_space=space)
                self.assertEqual((reply.success, reply.message), (True, "Ok"), space)
            self.assertEqual(rospy.get_param(f"{NODE}/coordinate_space"), 5, "0 (NoValue) leaves the space")
            reply = service("V2/set_transformation", SetTransformationMatrix)(
                transform=Transform(), coordinates_space=4, set_space=True, save_settings=False
            )
            self.assertEqual((reply.success, reply.message), (True, "Ok"))  # a zero quaternion is the identity
            self.assertEqual(rospy.get_param(f"{NODE}/coordinate_space"), 4)
        finally:
            set_space(coordinates_space=1)

    def test_set_transformation_switches_the_space_also_without_set_space(self):
        reply = service("V2/set_transformation", SetTransformationMatrix)(
            transform=_identity(z=0.25), coordinates_space=4, set_space=False, save_settings=False
        )
        self.assertTrue(reply.success, reply.message)
        try:
            self.assertEqual(rospy.get_param(f"{NODE}/coordinate_space"), 4)
            messages = self._published(self._trigger(), ["pointcloud", "depth_map"])
            points, _, _ = phoxi_messages.pointcloud2_arrays(messages["pointcloud"])
            depth = phoxi_messages.image_array(messages["depth_map"])
            valid = depth > 0
            np.testing.assert_allclose(points[valid][:, 2], depth[valid] / 1000.0 + 0.25, atol=1e-5)
        finally:
            service("V2/set_coordinate_space", SetCoordinatesSpace)(coordinates_space=1)

    def test_free_run_takes_frames_that_only_get_frame_publishes(self):
        start = self.recorder.count("pointcloud")
        first = self._trigger()
        reconfigure(trigger_mode=0)
        try:
            rospy.sleep(4.0)  # ~free_run_rate_hz 1: frames are taken, nothing is published
            self.assertEqual(self.recorder.count("pointcloud"), start, "free run must not publish by itself")
        finally:
            reconfigure(trigger_mode=1)
        later = self._trigger()
        self.assertGreater(later, first + 1, "free run took frames")
        self._published(later - 1, ["pointcloud"])  # the last free-run frame, published on request


if __name__ == "__main__":
    rostest.rosrun(PKG, "phoxi_camera_interface", PhoxiCameraTest)
